"""Blender objects for the seven classes, built from a PlacedObject (bpy).

`build_object(obj)` builds the geometry of `assets_procedural.shapes` for `obj.variant`
(fitted to `obj.dims`, the tight box), assigns PBR materials and returns a single mesh
object: origin at the centre of the bottom face, placed at `obj.position` turned by `obj.yaw`,
`pass_index = obj.id`. A traffic light is the signal head only (labels box the head, as
COCO does); it is mounted on the signal pole the twin builds at each intersection slot, or,
in a ground-plane scene (`variant["pole"]`), on a pole of its own: a child object marked
`blendgen_scenery`, which the render driver gives the id SCENERY_ID + id.
"""

from __future__ import annotations

import numpy as np

import bpy

from assets_procedural import materials as M
from assets_procedural.shapes import LAMP_COLORS, build_shape, traffic_light_pole
from blendgen.plan import PlacedObject
from blendgen.scene.catalog import helmet_colour, sample_variant

# seat backs to headrests (shares of the height) where they differ from a car's: a bus's passengers
SEATS = {"bus": (0.40, 0.50)}
WINDOW_SEE_THROUGH = 0.12  # tinted glass twice (rear window, windscreen) and the seats in between
LIT_STRENGTH = 6.0  # emission of a lit signal lamp: bright, still saturated in colour


def _materials(obj: PlacedObject, slots: list[str]) -> dict:
    v = obj.variant
    rider = v.get("rider", {})
    paint = v.get("paint") or (0.5, 0.5, 0.5)  # a rider's instance has none
    seed = int(v.get("seed", obj.id))
    # metallic flake paint on mid and dark colours (light metallic paint flared into big sun
    # highlights on real photos); solid on light colours and buses; grime in 4 levels
    metallic = 0.0 if (obj.cls == "bus" or max(paint[:3]) > 0.6) else 0.5
    wear = (seed // 7 % 4) / 4 * (0.9 if obj.cls in ("truck", "bus") else 0.6)
    out = {}
    for s in slots:
        if s == "paint":
            out[s] = M.paint(paint, metallic, wear)
        elif s == "well":  # the dark wheel well behind a tyre
            out[s] = M.plastic((0.006, 0.006, 0.006))
        elif s == "cargo":
            out[s] = M.principled(M._key("cargo", v.get("cargo", (0.8, 0.8, 0.78))), v.get("cargo", (0.8, 0.8, 0.78)),
                                  roughness=0.5, coat=0.3)
        elif s == "glass":  # windows: the street beyond shows through them
            out[s] = M.glass(see_through=WINDOW_SEE_THROUGH, seats=SEATS.get(obj.cls, M.CABIN_SEATS))
        elif s == "visor":
            out[s] = M.glass()
        elif s == "helmet":  # glossy, mostly black, white or grey (catalog.HELMETS)
            out[s] = M.paint(helmet_colour(v.get("mount", {}).get("variant", v)), 0.0)
        elif s == "rubber":
            out[s] = M.rubber()
        elif s == "chrome":
            out[s] = M.chrome()
        elif s == "alloy":
            out[s] = M.alloy()
        elif s in ("metal", "spoke"):  # brushed steel (a silencer, a bicycle's spokes)
            out[s] = M.metal((0.42, 0.42, 0.43), 0.35)
        elif s == "engine":  # a motorcycle's crankcase and cylinders: dark cast metal
            out[s] = M.metal((0.05, 0.05, 0.055), 0.45)
        elif s == "wheel":  # black-painted metal: two-wheelers' wheels, hugger, stalks
            out[s] = M.metal((0.03, 0.03, 0.032), 0.4)
        elif s in ("plastic", "saddle"):
            out[s] = M.plastic((0.025, 0.025, 0.025))
        elif s in ("tape_red", "tape_white"):  # retroreflective sheeting: saturated, a little glossy
            out[s] = M.principled(s, (0.55, 0.01, 0.01) if s == "tape_red" else (0.85, 0.85, 0.85), roughness=0.25)
        elif s == "plate":
            out[s] = M.principled("plate", (0.85, 0.85, 0.8), roughness=0.4)
        elif s == "plate_text":
            out[s] = M.principled("plate_text", (0.02, 0.025, 0.04), roughness=0.4)
        elif s == "indicator":  # an amber lens, never lit (lit at night both read as hazard lights)
            out[s] = M.principled("indicator", (0.45, 0.2, 0.01), roughness=0.1, coat=1.0)
        elif s in ("lamp_head", "lamp_tail", "lamp_sign"):  # switched per frame by the render driver
            out[s] = M.vehicle_lamp(s[5:])
        elif s.startswith("lamp_"):  # traffic-light lamps: lit one emits strongly
            name = s.split("_")[1]
            col = LAMP_COLORS[name]
            out[s] = (M.lamp(col, 0.02) if s.endswith("_off") else M.lamp(col, LIT_STRENGTH))
        elif s == "housing":
            out[s] = M.principled(M._key("housing", v.get("housing", (0.02, 0.02, 0.02))),
                                  v.get("housing", (0.02, 0.02, 0.02)), roughness=0.45)
        elif s == "pole":
            out[s] = M.metal((0.45, 0.46, 0.47), 0.45)
        else:  # person parts: pedestrians, or the rider of a two-wheeler
            pv = rider if obj.cls in ("bicycle", "motorcycle") else v
            col = {"skin": pv.get("skin"), "hair": pv.get("hair"), "shirt": pv.get("shirt"),
                   "pants": pv.get("pants"), "shoes": pv.get("shoes"), "bag": (0.08, 0.05, 0.03)}.get(s)
            col = col or (0.3, 0.3, 0.3)
            if s == "skin":
                out[s] = M.skin(col)
            elif s == "hair":
                out[s] = M.hair(col)
            elif s == "shoes":
                out[s] = M.principled(M._key("leather", col), col, roughness=0.5, coat=0.3)
            else:
                out[s] = M.fabric(col)
    return out


def _link(ob, collection):
    (collection or bpy.context.scene.collection).objects.link(ob)


def build_object(obj: PlacedObject, collection=None):
    """Build one object; returns its root mesh object (children parented)."""
    if not obj.variant:  # a plan made by hand: draw a variant, keep the given dims
        variant, _ = sample_variant(obj.cls, np.random.default_rng(obj.id))
        variant.pop("shape_dims")
        obj = PlacedObject(**{**obj.__dict__, "variant": variant})
    mb = build_shape(obj.cls, obj.variant, obj.dims, obj.state)
    name = f"obj_{obj.id}_{obj.cls.replace(' ', '_')}"
    me = mb.to_mesh(name, _materials(obj, mb.slots))
    root = bpy.data.objects.new(name, me)
    root.location = tuple(float(x) for x in obj.position)
    root.rotation_euler = (0.0, 0.0, float(obj.yaw))
    root.pass_index = int(obj.id)
    root["blendgen_id"] = int(obj.id)
    root["blendgen_cls"] = obj.cls
    _link(root, collection)
    if obj.cls == "traffic light" and obj.variant.get("pole"):  # ground-plane scenes bring their own pole
        L, _, H = obj.variant.get("shape_dims", obj.dims)
        pm = traffic_light_pole(obj.variant, L, H)
        pole = bpy.data.objects.new(f"{name}_pole", pm.to_mesh(f"{name}_pole", _materials(obj, pm.slots)))
        pole.parent = root
        pole["blendgen_scenery"] = True  # rendered with id SCENERY_ID + id: composited, never labelled
        _link(pole, collection)
    return root


def remove_object(root) -> None:
    """Delete an object built by build_object with its children and meshes (keeps RSS flat)."""
    for ob in [root, *root.children_recursive]:
        me = ob.data
        bpy.data.objects.remove(ob, do_unlink=True)
        if me is not None and me.users == 0:
            bpy.data.meshes.remove(me)
