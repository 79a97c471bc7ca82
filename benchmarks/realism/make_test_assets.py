"""Write a small asset library exported from Blender, with sidecars (docs/assets.md).

    python benchmarks/realism/make_test_assets.py OUT_DIR [--formats glb gltf blend obj fbx usd]
    python benchmarks/realism/make_test_assets.py OUT_DIR --procedural 3   # GLBs of every class

Builds a car-like asset (body, cabin, four wheels that are linked duplicates of one mesh,
a textured number plate) and a person-like asset (legs, torso, arms, head) in Blender,
facing -y (glTF's and Blender's convention), and exports each in every requested format:
OUT/<fmt>/car.<ext>, OUT/<fmt>/person.<ext>, each with a `<stem>.yaml` sidecar. The .blend
also holds a collection instance (`car_instanced`) and two variants (collections `car_red`
and `car_blue`). Used by tests/test_assets_library.py, jobs/asset_library.yaml and the
"library assets" variant of benchmarks/realism/bench_realism.py; runs in its own process because it
imports bpy. Prints the true real-size dims of each asset as JSON on the last line.
"""

from __future__ import annotations

import argparse
import warnings
import json
import math
from pathlib import Path

import yaml

CAR_DIMS = (4.40, 1.80, 1.45)    # length, width, height (m) of the built car
PERSON_DIMS = (0.30, 0.50, 1.75)  # depth, shoulder width, height
EXT = {"glb": ".glb", "gltf": ".gltf", "blend": ".blend", "obj": ".obj", "fbx": ".fbx", "usd": ".usdc"}


def _material(bpy, name, rgb, image=None):
    m = bpy.data.materials.new(name)
    with warnings.catch_warnings():  # deprecated in 5.0, still needed to get the node tree
        warnings.simplefilter("ignore", DeprecationWarning)
        m.use_nodes = True
    bsdf = m.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*rgb, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.4
    if image is not None:
        tex = m.node_tree.nodes.new("ShaderNodeTexImage")
        tex.image = image
        m.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    return m


def _box(bpy, name, size, centre, mat, coll):
    import bmesh

    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=1.0)
    for v in bm.verts:
        v.co = (v.co.x * size[0] + centre[0], v.co.y * size[1] + centre[1], v.co.z * size[2] + centre[2])
    bm.to_mesh(me)
    bm.free()
    me.materials.append(mat)
    ob = bpy.data.objects.new(name, me)
    coll.objects.link(ob)
    return ob


def build_car(bpy, coll, tex_dir: Path, paint=(0.45, 0.02, 0.02), prefix="car"):
    """Car facing -y: x is its width, y its length. Root object = body; the rest parented."""
    import bmesh

    L, W, H = CAR_DIMS
    r = 0.33
    img = bpy.data.images.new(f"{prefix}_plate_tex", 16, 4)
    img.pixels = [0.9, 0.9, 0.2, 1.0] * 64
    img.filepath_raw = str(tex_dir / f"{prefix}_plate.png")
    img.file_format = "PNG"
    img.save()
    body = _box(bpy, f"{prefix}_body", (W, L, 0.75), (0, 0, r * 0.6 + 0.375), _material(bpy, f"{prefix}_paint", paint), coll)
    cabin = _box(bpy, f"{prefix}_cabin", (W - 0.2, L * 0.5, H - (r * 0.6 + 0.75)),
                 (0, 0.15, r * 0.6 + 0.75 + (H - r * 0.6 - 0.75) / 2), _material(bpy, f"{prefix}_glass", (0.05, 0.06, 0.07)), coll)
    plate = _box(bpy, f"{prefix}_plate", (0.52, 0.02, 0.12), (0, -L / 2 - 0.01, 0.45),
                 _material(bpy, f"{prefix}_plate", (1, 1, 1), img), coll)
    wheel = bpy.data.meshes.new(f"{prefix}_wheel")
    bm = bmesh.new()
    bmesh.ops.create_cone(bm, cap_ends=True, segments=16, radius1=r, radius2=r, depth=0.22)
    bm.to_mesh(wheel)
    bm.free()
    wheel.materials.append(_material(bpy, f"{prefix}_tyre", (0.02, 0.02, 0.02)))
    for ob in (cabin, plate):
        ob.parent = body
    for i, (sx, sy) in enumerate([(-1, -1), (1, -1), (-1, 1), (1, 1)]):
        w = bpy.data.objects.new(f"{prefix}_wheel_{i}", wheel)  # linked duplicates: one mesh
        w.location = (sx * (W / 2 - 0.11), sy * (L / 2 - 0.8), r)
        w.rotation_euler = (0, math.pi / 2, 0)
        w.parent = body
        coll.objects.link(w)
    return body


def build_person(bpy, coll):
    D, Wd, H = PERSON_DIMS
    cloth = _material(bpy, "shirt", (0.05, 0.08, 0.25))
    skin = _material(bpy, "skin", (0.62, 0.42, 0.30))
    legs = _box(bpy, "person_legs", (0.32, 0.2, 0.85), (0, 0, 0.425), _material(bpy, "pants", (0.1, 0.1, 0.1)), coll)
    torso = _box(bpy, "person_torso", (0.42, D - 0.04, 0.6), (0, -0.02, 0.85 + 0.3), cloth, coll)
    arms = _box(bpy, "person_arms", (Wd, 0.1, 0.08), (0, 0, 1.4), cloth, coll)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.12, location=(0, 0, H - 0.12), segments=12, ring_count=8)
    head = bpy.context.active_object
    head.name = "person_head"
    head.data.materials.append(skin)
    for c in head.users_collection:
        c.objects.unlink(head)
    coll.objects.link(head)
    extra = _box(bpy, "person_bag", (0.1, 0.06, 0.3), (0, D / 2 - 0.03, 1.0), skin, coll)  # sets the depth
    for ob in (torso, arms, head, extra):
        ob.parent = legs
    return legs


def _export(bpy, fmt: str, path: Path) -> None:
    p = str(path)
    if fmt == "glb":
        bpy.ops.export_scene.gltf(filepath=p, export_format="GLB", use_selection=True)
    elif fmt == "gltf":
        bpy.ops.export_scene.gltf(filepath=p, export_format="GLTF_SEPARATE", use_selection=True)
    elif fmt == "obj":
        bpy.ops.wm.obj_export(filepath=p, export_selected_objects=True, path_mode="COPY")
    elif fmt == "fbx":
        bpy.ops.export_scene.fbx(filepath=p, use_selection=True, path_mode="COPY", embed_textures=False)
    elif fmt == "usd":
        bpy.ops.wm.usd_export(filepath=p, selected_objects_only=True)
    else:
        raise ValueError(fmt)


def _select(bpy, root) -> None:
    bpy.ops.object.select_all(action="DESELECT")
    for ob in [root, *root.children_recursive]:
        ob.select_set(True)
    bpy.context.view_layer.objects.active = root


def _sidecar(path: Path, data: dict) -> None:
    path.with_suffix(".yaml").write_text(yaml.safe_dump(data, sort_keys=False))


def make_assets(out: Path, formats=tuple(EXT)) -> dict:
    """Export the car and the person in `formats` under `out/<fmt>/`; returns the true dims."""
    import bpy

    out = Path(out)
    dims = {"car": [CAR_DIMS[0] + 0.02, CAR_DIMS[1], CAR_DIMS[2]], "person": list(PERSON_DIMS)}
    for fmt in formats:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        sc = bpy.context.scene
        d = out / fmt
        d.mkdir(parents=True, exist_ok=True)
        if fmt == "blend":
            colls = {}
            for name, paint in (("car_red", (0.45, 0.02, 0.02)), ("car_blue", (0.02, 0.06, 0.25))):
                c = colls[name] = bpy.data.collections.new(name)
                sc.collection.children.link(c)
                build_car(bpy, c, d, paint, prefix=name)
            # an instanced asset: an empty that draws the red car's collection
            inst_c = bpy.data.collections.new("car_instanced")
            sc.collection.children.link(inst_c)
            inst = bpy.data.objects.new("car_instancer", None)
            inst.instance_type = "COLLECTION"
            inst.instance_collection = colls["car_red"]
            inst_c.objects.link(inst)
            bpy.ops.file.pack_all()
            bpy.ops.wm.save_as_mainfile(filepath=str(d / "car.blend"), compress=True)
            _sidecar(d / "car.blend", {"class": "car", "variants": ["car_red", "car_blue", "car_instanced"],
                                       "licence": "CC0-1.0 (generated by blendgen)"})
            bpy.ops.wm.read_factory_settings(use_empty=True)
            build_person(bpy, bpy.context.scene.collection)
            bpy.ops.wm.save_as_mainfile(filepath=str(d / "person.blend"))
            _sidecar(d / "person.blend", {"class": "person", "height_m": PERSON_DIMS[2], "licence": "CC0-1.0"})
            continue
        car = build_car(bpy, sc.collection, d)
        _select(bpy, car)
        _export(bpy, fmt, d / f"car{EXT[fmt]}")
        person = build_person(bpy, sc.collection)
        _select(bpy, person)
        _export(bpy, fmt, d / f"person{EXT[fmt]}")
        _sidecar(d / f"car{EXT[fmt]}", {"class": "car", "licence": "CC0-1.0 (generated by blendgen)"})
        _sidecar(d / f"person{EXT[fmt]}", {"class": "person", "front": "-y", "licence": "CC0-1.0"})
    return dims


def make_procedural_library(out: Path, per_class: int = 3, classes=None, seed: int = 0) -> dict:
    """Export blendgen's own procedural objects (assets_procedural) as GLB files with sidecars:
    `per_class` random variants of each class, two-wheelers parked (no rider), facing +x.
    A library with every class and the procedural objects' materials, for benchmarks such as
    bench_realism.py's "library assets" variant. Returns {file name: measured dims}."""
    import bpy
    import numpy as np

    from assets_procedural.objects import build_object
    from blendgen import CLASSES
    from blendgen.plan import PlacedObject
    from blendgen.scene.catalog import sample_variant, shape_extent

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    made = {}
    for cls in classes or list(CLASSES):
        for i in range(per_class):
            bpy.ops.wm.read_factory_settings(use_empty=True)
            variant, _ = sample_variant(cls, rng)
            variant.pop("rider", None)  # parked: a rider is a person of their own
            dims = shape_extent(cls, variant)
            state = "red" if cls == "traffic light" else None
            root = build_object(PlacedObject(i + 1, cls, (0.0, 0.0, 0.0), 0.0, dims, variant, state=state))
            _select(bpy, root)
            name = f"{cls.replace(' ', '_')}_{i}.glb"
            _export(bpy, "glb", out / name)
            side = {"class": cls, "front": "+x", "licence": "CC0-1.0 (blendgen procedural object)"}
            if cls == "traffic light":
                side["mount_height_m"] = round(float(variant["mount_height_m"]), 3)
            _sidecar(out / name, side)
            made[name] = [round(float(x), 4) for x in dims]
    return made


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--formats", nargs="+", choices=list(EXT), default=list(EXT))
    ap.add_argument("--procedural", type=int, metavar="N", default=0,
                    help="instead: N GLB exports of blendgen's procedural objects per class")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if args.procedural:
        dims = make_procedural_library(args.out, args.procedural, seed=args.seed)
    else:
        dims = make_assets(args.out, args.formats)
    print(json.dumps(dims))


if __name__ == "__main__":
    main()
