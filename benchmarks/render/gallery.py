"""Render the gallery of the seven object classes and both twins into docs/images/.

    .venv/bin/python benchmarks/render/gallery.py [--quick] [--samples N] [--old-tiles DIR]

Each class row shows several variants (body types, riders, lamp states) on a neutral
ground in day light and in night light (dark sky, one street lamp, vehicle lamps on);
each twin tile is a dashcam view of the twin with a planned frame of objects (the
planner's output for that pose). Writes docs/images/gallery.png and prints the build and
render times per tile. To compare with older objects, first render their day tiles from
a copy of the old package (e.g. `git show main:assets_procedural/<f>.py` into
OLD/assets_procedural/), then pass the folder as --old-tiles:

    .venv/bin/python benchmarks/render/gallery.py --quick --old-assets OLD --tiles-only DIR
    .venv/bin/python benchmarks/render/gallery.py --quick --old-tiles DIR
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import RESULTS, ROOT  # noqa: E402
if "--old-assets" in sys.argv:  # import that folder's assets_procedural instead of ours
    sys.path.insert(0, str(Path(sys.argv[sys.argv.index("--old-assets") + 1]).resolve()))

import bpy  # noqa: E402
import cv2  # noqa: E402
from mathutils import Matrix, Vector  # noqa: E402

from assets_procedural import materials  # noqa: E402
from assets_procedural.objects import build_object  # noqa: E402
from assets_procedural.twin_builder import build_twin  # noqa: E402
from blendgen import atomic  # noqa: E402
from blendgen.geometry import CV_TO_BLENDER, Camera, R_world_cam_from_ypr, make_pose  # noqa: E402
from blendgen.job.schema import SCENARIOS, Inject  # noqa: E402
from blendgen.plan import PlacedObject  # noqa: E402
from blendgen.scene.catalog import sample_variant  # noqa: E402
from blendgen.scene.planner import plan_sequence  # noqa: E402
from blendgen.twin.model import load_twin  # noqa: E402

TWINS = ROOT / "assets_procedural" / "twins"
TILES = {  # class -> list of variant overrides (kind, rider, state)
    "car": [{"kind": "sedan"}, {"kind": "hatchback"}, {"kind": "suv"}, {"kind": "van"}],
    "truck": [{"kind": "pickup"}, {"kind": "box_truck"}, {"kind": "semi"}],
    "bus": [{"kind": "midi"}, {"kind": "city"}],
    "person": [{"kind": "standing"}, {"kind": "walking"}, {"kind": "walking"}, {"kind": "standing"},
               {"kind": "walking"}],
    "bicycle": [{"kind": "city", "rider": True}, {"kind": "road", "rider": True}, {"kind": "mountain", "rider": False}],
    "motorcycle": [{"kind": "sport", "rider": True}, {"kind": "cruiser", "rider": True}, {"kind": "scooter", "rider": False}],
    "traffic light": [{"state": "red"}, {"state": "amber"}, {"state": "green", "kind": "backplate"}],
}


def reset_scene(res, samples, night=False):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.samples = samples
    sc.cycles.use_denoising = True
    sc.cycles.max_bounces = 4
    sc.render.resolution_x, sc.render.resolution_y = res
    sc.render.film_transparent = False
    sc.view_settings.view_transform = "AgX"
    world = bpy.data.worlds.new("gallery_world")
    if world.node_tree is None:
        world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (0.03, 0.04, 0.08, 1.0) if night else (0.55, 0.65, 0.85, 1.0)
    bg.inputs["Strength"].default_value = 0.9
    sc.world = world
    if night:  # one sodium-ish street lamp high above the row
        light = bpy.data.lights.new("street", "POINT")
        light.energy, light.color, light.shadow_soft_size = 6000.0, (1.0, 0.8, 0.55), 0.3
        lo = bpy.data.objects.new("street", light)
        lo.location = (6.0, -4.0, 8.0)
    else:
        light = bpy.data.lights.new("sun", "SUN")
        light.energy = 4.0
        light.angle = math.radians(2.0)
        lo = bpy.data.objects.new("sun", light)
        lo.rotation_euler = (math.radians(50), math.radians(10), math.radians(-35))
    sc.collection.objects.link(lo)
    cam = bpy.data.cameras.new("cam")
    co = bpy.data.objects.new("cam", cam)
    sc.collection.objects.link(co)
    sc.camera = co
    return sc, co


def sample_like(cls, override, rng):
    for _ in range(400):
        v, d = sample_variant(cls, rng)
        if "kind" in override and v.get("kind") != override["kind"]:
            continue
        if "rider" in override and ("rider" in v) != override["rider"]:
            continue
        return v, d
    return v, d


def render(path):
    bpy.context.scene.render.filepath = str(path)
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    return time.perf_counter() - t0


def class_tile(cls, overrides, res, samples, out, rng, night=False):
    sc, cam = reset_scene(res, samples, night)
    ground = bpy.data.meshes.new("ground")
    ground.from_pydata([(-60, -60, 0), (60, -60, 0), (60, 60, 0), (-60, 60, 0)], [], [(0, 1, 2, 3)])
    gmat = bpy.data.materials.new("ground")
    if gmat.node_tree is None:
        gmat.use_nodes = True
    gmat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.32, 0.32, 0.31, 1)
    ground.materials.append(gmat)
    sc.collection.objects.link(bpy.data.objects.new("ground", ground))
    t0 = time.perf_counter()
    objs, y = [], 0.0
    for k, ov in enumerate(overrides):
        v, d = sample_like(cls, ov, rng)
        if cls == "traffic light":
            v["kind"] = ov.get("kind", v["kind"])
        gap = 0.5 if cls in ("person", "traffic light") else 1.2
        y += (d[1] / 2 + (gap if k else 0))  # along +y: left to right in the view
        z = 0.0 if cls != "traffic light" else 0.5
        o = PlacedObject(k + 1, cls, (0.0, y, z), 0.0, d, v, state=ov.get("state"))
        objs.append((build_object(o), d, y))
        y += d[1] / 2
    build_s = time.perf_counter() - t0
    if night and hasattr(materials, "set_vehicle_lamps"):
        materials.set_vehicle_lamps(True)
    # frame the row from the front-left, three-quarter view
    lo = np.array([min(-d[0] / 2 for _, d, _ in objs), 0.0, 0.0])
    hi = np.array([max(d[0] / 2 for _, d, _ in objs), y, max(d[2] for _, d, _ in objs) + (0.5 if cls == "traffic light" else 0)])
    centre = (lo + hi) / 2
    span = float(np.linalg.norm(hi - lo))
    direction = Vector((0.82, -0.42, 0.38)).normalized()  # front-right, from above
    cam.data.angle = math.radians(40)
    dist = span / 2 / math.tan(cam.data.angle / 2) * 1.05
    cam.location = Vector(centre.tolist()) + direction * dist
    cam.rotation_euler = (-direction).to_track_quat("-Z", "Y").to_euler()
    render_s = render(out)
    return build_s, render_s


def drive(route, fps=5.0, speed=8.0, height=1.5):
    seg = np.linalg.norm(np.diff(route, axis=0), axis=1)
    s = np.concatenate([[0], np.cumsum(seg)])
    poses = []
    for i, t in enumerate(np.arange(0, s[-1] / speed, 1 / fps)):
        p = [np.interp(t * speed, s, route[:, j]) for j in (0, 1)]
        q = [np.interp(min(t * speed + 1, s[-1]), s, route[:, j]) for j in (0, 1)]
        yaw = math.atan2(q[1] - p[1], q[0] - p[0])
        poses.append((f"{i:06d}", float(t), make_pose(R_world_cam_from_ypr(yaw, -0.03), [*p, height])))
    return poses


def twin_tile(name, route, res, samples, out, frame, seed):
    sc, cam = reset_scene(res, samples)
    twin = load_twin(TWINS / f"{name}.yaml")
    info = build_twin(twin)
    camera = Camera.from_hfov(res[0], res[1], 70.0)
    poses = drive(route, speed=8.0 if name == "demo_town" else 20.0)
    classes = {"car": 3, "person": 3, "bicycle": 1, "motorcycle": 1, "bus": 1, "truck": 1.5, "traffic light": 4}
    inject = Inject(objects_per_frame=(5, 8), classes=classes, scenarios=list(SCENARIOS),
                    distance_m=(4.0, 45.0 if name == "demo_town" else 70.0), min_projected_px=16)
    plans = plan_sequence(twin, camera, poses, inject, seed)
    plan = plans[min(frame, len(plans) - 1)]
    t0 = time.perf_counter()
    for o in plan.objects:
        build_object(o)
    obj_s = time.perf_counter() - t0
    T = np.asarray(plan.T_world_cam)
    M = np.eye(4)
    M[:3, :3] = T[:3, :3] @ CV_TO_BLENDER
    M[:3, 3] = T[:3, 3]
    cam.matrix_world = Matrix(M.tolist())
    cam.data.sensor_fit = "HORIZONTAL"
    cam.data.angle = math.radians(70.0)
    cam.data.clip_end = 600
    render_s = render(out)
    return info["build_s"], obj_s, render_s, sorted(o.cls for o in plan.objects)


def label(img, text):
    cv2.rectangle(img, (0, 0), (img.shape[1], 22), (0, 0, 0), -1)
    cv2.putText(img, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return img


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small tiles, few samples")
    ap.add_argument("--samples", type=int, default=None)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "gallery.png")
    ap.add_argument("--old-assets", type=Path, help="folder holding an older assets_procedural package")
    ap.add_argument("--tiles-only", type=Path, help="only render the day class tiles into this folder")
    ap.add_argument("--old-tiles", type=Path, help="day tiles of older objects: shown left of each row")
    ap.add_argument("--no-twins", action="store_true")
    a = ap.parse_args(argv)
    samples = a.samples or (8 if a.quick else 24)
    tile = (320, 240) if a.quick else (480, 360)
    twin_res = (480, 270) if a.quick else (720, 405)
    tmp = a.tiles_only or RESULTS / "gallery_tiles"
    tmp.mkdir(parents=True, exist_ok=True)
    rows, grid_rows = [], []
    for cls, ov in TILES.items():
        row = []
        if a.old_tiles:
            old = cv2.imread(str(a.old_tiles / f"{cls.replace(' ', '_')}_day.png"))
            row.append(label(cv2.resize(old, tile), f"{cls}: OLD objects, day"))
        for night in ((False,) if a.tiles_only else (False, True)):
            p = tmp / f"{cls.replace(' ', '_')}_{'night' if night else 'day'}.png"
            rng = np.random.default_rng(11 + list(TILES).index(cls))  # the same variants in every column
            b, r = class_tile(cls, ov, tile, samples, p, rng, night)
            rows.append((cls, len(ov), b, r))
            print(f"{cls:14s} {'night' if night else 'day':5s} {len(ov)} variants  build {b * 1000:6.0f} ms  "
                  f"render {r:5.1f} s", flush=True)
            kinds = ", ".join(o.get("kind", o.get("state", "")) for o in ov)
            row.append(label(cv2.imread(str(p)), f"{cls} ({kinds}), {'night' if night else 'day'}"))
        grid_rows.append(np.hstack(row))
    if a.tiles_only:
        return rows
    grid = np.vstack(grid_rows)
    if not a.no_twins:
        town = load_twin(TWINS / "demo_town.yaml")
        town_route = town.lane_polyline("main", 1, 1, 90.0, 150.0)   # outer lane toward the intersection
        hw = load_twin(TWINS / "highway.yaml")
        hw_route = hw.lane_polyline("a7", 1, 1, 150.0, 290.0)
        twin_imgs = []
        for name, route, frame, seed in (("demo_town", town_route, 14, 2), ("highway", hw_route, 10, 2)):
            p = tmp / f"twin_{name}.png"
            tb, ob, r, classes = twin_tile(name, route, twin_res, samples, p, frame, seed)
            print(f"twin {name:10s} build {tb:4.2f} s  objects {ob * 1000:5.0f} ms  render {r:5.1f} s  {classes}",
                  flush=True)
            rows.append((f"twin {name}", len(classes), tb + ob, r))
            twin_imgs.append(label(cv2.imread(str(p)), f"twin: {name} + planned objects ({len(classes)})"))
        W = grid.shape[1]
        twins = np.hstack(twin_imgs)
        twins = cv2.resize(twins, (W, int(twins.shape[0] * W / twins.shape[1])), interpolation=cv2.INTER_AREA)
        grid = np.vstack([grid, twins])
    atomic.write_image(a.out, grid)
    print(f"wrote {a.out}")
    return rows


if __name__ == "__main__":
    main()
