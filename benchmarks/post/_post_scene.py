"""bpy side of benchmarks/post/bench_post.py: render the ground-truth lighting scenes.

Run in its own process (it imports bpy):  python benchmarks/post/_post_scene.py spec.json
The spec lists renders; each is either
- "background": the "real" frame: road, roadside buildings, sky, under a lighting (PNG,
  8-bit sRGB, Standard view transform), objects hidden;
- "object": the inserted objects over a shadow-catcher road (buildings are holdouts),
  transparent film, multilayer EXR with the passes the post stage reads.
Lighting dicts follow docs/architecture.md. Objects are simple procedural stand-ins for the
seven classes (or assets_procedural.objects.build_object when it is available).
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import bpy
from mathutils import Vector

ROOT = Path(__file__).resolve().parents[2]


def material(name, rgb, rough=0.5, metal=0.0, emit=None):
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    b = m.node_tree.nodes["Principled BSDF"]
    b.inputs["Base Color"].default_value = (*rgb, 1.0)
    b.inputs["Roughness"].default_value = rough
    b.inputs["Metallic"].default_value = metal
    if emit is not None:
        b.inputs["Emission Color"].default_value = (*emit, 1.0)
        b.inputs["Emission Strength"].default_value = 3.0
    return m


def _named(name, mat, parent):
    """The object the last primitive_*_add made, named, with its material and parent."""
    o = bpy.context.object
    o.name = name
    o.data.materials.append(mat)
    if parent is not None:
        o.parent = parent
    return o


def box(name, size, loc, mat, parent=None, rot_z=0.0):
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=loc)
    o = _named(name, mat, parent)
    o.scale = size
    o.rotation_euler[2] = rot_z
    return o


def cyl(name, r, depth, loc, mat, parent=None, rot=(0, 0, 0)):
    bpy.ops.mesh.primitive_cylinder_add(radius=r, depth=depth, location=loc, rotation=rot, vertices=16)
    return _named(name, mat, parent)


def sphere(name, r, loc, mat, parent=None):
    bpy.ops.mesh.primitive_uv_sphere_add(radius=r, location=loc, segments=16, ring_count=8)
    return _named(name, mat, parent)


def stand_in(cls: str, colour, name: str):
    """A recognisable low-poly object of the class, local frame: x forward, z up, origin at the
    bottom centre."""
    root = bpy.data.objects.new(name, None)
    bpy.context.scene.collection.objects.link(root)
    paint = material(f"{name}_paint", colour, rough=0.3)
    dark = material(f"{name}_dark", (0.02, 0.02, 0.02), rough=0.6)
    glass = material(f"{name}_glass", (0.05, 0.07, 0.08), rough=0.05)
    skin = material(f"{name}_skin", (0.45, 0.3, 0.22), rough=0.6)
    wheels = lambda L, W, r: [cyl(f"{name}_w{i}", r, 0.25, (sx * L / 2.6, sy * W / 2, r), dark, root, (math.pi / 2, 0, 0))
                              for i, (sx, sy) in enumerate([(1, 1), (1, -1), (-1, 1), (-1, -1)])]
    if cls == "car":
        box(f"{name}_body", (4.3, 1.8, 0.75), (0, 0, 0.65), paint, root)
        box(f"{name}_cabin", (2.2, 1.6, 0.6), (-0.3, 0, 1.3), glass, root)
        box(f"{name}_roof", (1.9, 1.55, 0.06), (-0.35, 0, 1.62), paint, root)
        wheels(4.3, 1.8, 0.33)
    elif cls == "truck":
        box(f"{name}_cab", (2.0, 2.3, 2.4), (3.0, 0, 1.6), paint, root)
        box(f"{name}_box", (5.5, 2.45, 2.9), (-1.0, 0, 1.95), material(f"{name}_white", (0.75, 0.75, 0.73), 0.5), root)
        wheels(7.5, 2.3, 0.5)
    elif cls == "bus":
        box(f"{name}_body", (11.0, 2.5, 2.6), (0, 0, 1.7), paint, root)
        box(f"{name}_windows", (10.0, 2.52, 0.9), (0, 0, 2.2), glass, root)
        wheels(11.0, 2.4, 0.5)
    elif cls == "person":
        box(f"{name}_legs", (0.25, 0.35, 0.85), (0, 0, 0.43), dark, root)
        box(f"{name}_torso", (0.28, 0.45, 0.65), (0, 0, 1.2), paint, root)
        sphere(f"{name}_head", 0.12, (0, 0, 1.65), skin, root)
    elif cls in ("bicycle", "motorcycle"):
        r = 0.34 if cls == "bicycle" else 0.32
        for i, x in enumerate((0.55, -0.55)):
            bpy.ops.mesh.primitive_torus_add(major_radius=r, minor_radius=0.03 if cls == "bicycle" else 0.08,
                                             location=(x, 0, r), rotation=(math.pi / 2, 0, 0))
            t = bpy.context.object
            t.data.materials.append(dark)
            t.parent = root
        if cls == "bicycle":
            box(f"{name}_frame", (1.0, 0.05, 0.05), (0, 0, 0.6), paint, root)
            box(f"{name}_post", (0.05, 0.05, 0.45), (-0.2, 0, 0.75), paint, root)
            box(f"{name}_rider", (0.3, 0.4, 0.7), (-0.15, 0, 1.25), material(f"{name}_shirt", (0.1, 0.25, 0.6)), root)
            sphere(f"{name}_head", 0.12, (-0.05, 0, 1.72), skin, root)
        else:
            box(f"{name}_body", (1.1, 0.35, 0.4), (0, 0, 0.65), paint, root)
            box(f"{name}_rider", (0.35, 0.45, 0.7), (-0.15, 0, 1.2), dark, root)
            sphere(f"{name}_helmet", 0.15, (-0.05, 0, 1.7), paint, root)
    elif cls == "traffic light":
        cyl(f"{name}_pole", 0.07, 3.0, (0, 0, 1.5), dark, root)
        box(f"{name}_housing", (0.3, 0.35, 0.95), (0.0, 0, 3.3), material(f"{name}_yel", (0.35, 0.3, 0.05), 0.5), root)
        sphere(f"{name}_red", 0.09, (0.16, 0, 3.6), material(f"{name}_lr", (0.8, 0.05, 0.02), 0.3, emit=(1, 0.1, 0.05)), root)
    else:
        raise ValueError(cls)
    return root


def place(root, pos, yaw, pass_index):
    root.location = pos
    root.rotation_euler[2] = yaw
    for ch in [root, *root.children_recursive]:
        ch.pass_index = pass_index


def built_object(o):
    """The project's class model (assets_procedural.objects), or None where it is unavailable."""
    try:
        import numpy as np

        sys.path.insert(0, str(ROOT))
        from assets_procedural.objects import build_object
        from blendgen.plan import PlacedObject
        from blendgen.scene.catalog import sample_variant
    except Exception as e:  # the stand-ins below still give a real render
        print(f"build_object unavailable ({e}); using stand-ins", flush=True)
        return None
    variant, dims = sample_variant(o["cls"], np.random.default_rng(o.get("seed", o["id"])))
    obj = PlacedObject(id=o["id"], cls=o["cls"], position=tuple(o["position"]),
                       yaw=math.radians(o.get("yaw_deg", 0.0)), dims=tuple(dims), variant=variant,
                       state=o.get("state"))
    return build_object(obj)


def build(spec):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.samples = spec.get("samples", 16)
    sc.cycles.use_denoising = spec.get("denoise", False)
    sc.cycles.max_bounces = 4
    sc.render.resolution_x, sc.render.resolution_y = spec["resolution"]
    sc.render.resolution_percentage = 100
    sc.view_settings.view_transform = "Standard"
    sc.render.threads_mode = "FIXED"
    sc.render.threads = spec.get("threads", 2)

    cam_d = bpy.data.cameras.new("cam")
    cam_d.sensor_fit = "HORIZONTAL"
    cam_d.angle = math.radians(spec.get("hfov_deg", 60.0))
    cam = bpy.data.objects.new("cam", cam_d)
    sc.collection.objects.link(cam)
    sc.camera = cam
    cam.location = (0.0, 0.0, spec.get("camera_height", 1.5))
    # Looking north (+y), pitched down by pitch_deg (Blender camera: -z forward, y up).
    cam.rotation_euler = (math.radians(90.0 - spec.get("pitch_deg", 4.0)), 0.0, 0.0)

    ground_mat = material("asphalt", spec.get("ground_rgb", (0.13, 0.13, 0.14)), rough=0.9)
    bpy.ops.mesh.primitive_plane_add(size=400, location=(0, 100, 0))
    ground = bpy.context.object
    ground.name = "ground"
    ground.data.materials.append(ground_mat)
    markings = []
    mark = material("marking", (0.7, 0.7, 0.68), rough=0.7)
    for x in (-1.8, 1.8):
        for k in range(12):
            m = box(f"mark_{x}_{k}", (0.15, 3.0, 0.005), (x, 6 + 9 * k, 0.003), mark)
            markings.append(m)
    buildings = []
    if spec.get("buildings", True):
        cols = [(0.45, 0.4, 0.35), (0.3, 0.32, 0.38), (0.5, 0.45, 0.42), (0.35, 0.3, 0.3)]
        for i, (x, y, sx, sy, h) in enumerate([(-9, 12, 4, 8, 6), (9, 18, 5, 10, 9), (-10, 30, 5, 12, 12),
                                               (10, 40, 6, 12, 7), (-7, 5, 2, 3, 4), (7, 8, 2.5, 3, 5)]):
            buildings.append(box(f"bld{i}", (sx, sy, h), (x, y, h / 2), material(f"bm{i}", cols[i % 4], 0.8)))
    objects = []
    for i, o in enumerate(spec.get("objects", [])):
        root = built_object(o) if spec.get("builder", False) else None
        if root is None:
            root = stand_in(o["cls"], tuple(o["colour"]), f"obj{i}")
        place(root, tuple(o["position"]), math.radians(o.get("yaw_deg", 0.0)), o["id"])
        objects.append(root)

    world = bpy.data.worlds.new("world")
    sc.world = world
    world.use_nodes = True
    sun_d = bpy.data.lights.new("sun", "SUN")
    sun = bpy.data.objects.new("sun", sun_d)
    sc.collection.objects.link(sun)

    vl = sc.view_layers[0]
    vl.use_pass_object_index = True
    for p in ("diffuse_direct", "diffuse_indirect", "diffuse_color", "glossy_direct", "glossy_indirect",
              "glossy_color"):
        setattr(vl, f"use_pass_{p}", True)
    vl.cycles.use_pass_shadow_catcher = True
    return dict(scene=sc, ground=ground, buildings=buildings, markings=markings, objects=objects, world=world,
                sun=sun)


def set_lighting(env, L):
    bg = env["world"].node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*L["sky_color"], 1.0)
    bg.inputs["Strength"].default_value = float(L["sky_strength"])
    sun = env["sun"]
    sun.data.energy = float(L["sun_strength"]) if L.get("sun_visible", True) else 0.0
    sun.data.color = tuple(L["sun_color"])
    sun.data.angle = math.radians(L.get("sun_angle_deg", 0.53))
    sun.rotation_mode = "QUATERNION"
    sun.rotation_quaternion = Vector(L["sun_direction"]).normalized().to_track_quat("Z", "Y")
    sun.hide_render = sun.data.energy <= 0


def render(env, job):
    sc = env["scene"]
    set_lighting(env, job["lighting"])
    obj_mode = job["mode"] == "object"
    for o in env["objects"]:
        for ch in [o, *o.children_recursive]:
            ch.hide_render = not obj_mode
    env["ground"].is_shadow_catcher = obj_mode
    for m in env["markings"]:
        m.hide_render = obj_mode  # the catcher is flat grey; markings would print into its pass
    for b in env["buildings"]:
        # The twin's structures are in the real frame already, shadows included: as holdouts
        # they must not print their own shadow / sky occlusion into the catcher pass again.
        b.is_holdout = obj_mode
        b.visible_shadow = not obj_mode
    sc.render.film_transparent = obj_mode
    s = sc.render.image_settings
    if obj_mode:
        s.media_type = "MULTI_LAYER_IMAGE"
        s.file_format = "OPEN_EXR_MULTILAYER"
        s.color_depth = "32"
        s.exr_codec = "ZIP"
    else:
        s.media_type = "IMAGE"
        s.file_format = "PNG"
        s.color_mode = "RGB"
        s.color_depth = "8"
    border = job.get("border")  # (xmin, xmax, ymin, ymax) in [0, 1], Blender's bottom-up y
    sc.render.use_border = border is not None
    sc.render.use_crop_to_border = False
    if border is not None:
        sc.render.border_min_x, sc.render.border_max_x, sc.render.border_min_y, sc.render.border_max_y = border
    sc.render.filepath = job["out"]
    bpy.ops.render.render(write_still=True)


def main():
    spec = json.loads(Path(sys.argv[1]).read_text())
    env = build(spec)
    for job in spec["renders"]:
        render(env, job)
        print(f"rendered {job['out']}", flush=True)


if __name__ == "__main__":
    main()
