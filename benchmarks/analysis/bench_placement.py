"""Placement on real footage without a map: the OLD ground-plane path (fixed camera pose,
no frame analysis) against the NEW one (frame analysis: real road users, road, hood).

    PYTHONPATH=. .venv/bin/python benchmarks/analysis/bench_placement.py [--quick]

Runs `blendgen run` on the real photos and video (imported into benchmarks/results/tmp/),
once per path with the same seed, camera values and classes, then scores each run against
the same reference: the NEW path's analysis of the untouched frame (YOLOX-Nano boxes, road
mask, hood). Per injected, labelled object:
- inside/behind: its visible box overlaps a real detected box (> 5 % of its own box) and its
  ground contact is not below the real box's bottom edge in the image, i.e. not nearer on
  flat ground (goal 0); in front: overlaps and nearer;
- off road: a vehicle's (car, bus, truck, motorcycle, bicycle) wheel contact point off the
  estimated road (goal 0), in the rows the road estimate covers (farther is not judged);
  NEW places vehicles by that same estimate, so its 0 holds by construction and the
  estimate itself is checked by eye in the gallery;
- on hood: a contact point on the hood (goal 0);
- recall@0.5: YOLOX-Nano (score >= 0.3) finds the injected object (IoU >= 0.5, same class);
- analysis CPU seconds per frame (goal <= 0.3 s at 1280x720 on one core).
Prints a table, writes benchmarks/results/placement.png, docs/benchmarks/placement.md and
the before/after gallery docs/images/placement_before_after.jpg.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import REAL, RESULTS, ROOT, ci95, write_doc  # noqa: E402

from blendgen import atomic  # noqa: E402
from blendgen.frame_analysis import BAND, ROAD  # noqa: E402
from blendgen.frame_analysis import hood_mask, read_analysis, read_road_mask  # noqa: E402
from blendgen.frame_labels import read_frame_labels  # noqa: E402
from blendgen.job.schema import parse_job  # noqa: E402
from blendgen.pipeline.frame import load_plans  # noqa: E402
from blendgen.pipeline.run import Runner  # noqa: E402
from blendgen.recording.folder import read_frame, read_recording  # noqa: E402
from blendgen.report.draw import draw_analysis  # noqa: E402
from blendgen.scene.real_scene import WHEELED, _inset  # noqa: E402

# ../shared/data beside the project (BLENDGEN_SHARED_DATA overrides, e.g. from a git worktree)
TMP = RESULTS / "tmp" / "placement"
CLASSES = {"car": 3, "truck": 1, "bus": 1, "person": 2, "motorcycle": 1, "bicycle": 1, "traffic light": 1}
# name: (importer, source, hfov, ground_plane values a careful user would set by eye, frames, sequences)
DATASETS = {
    "udacity_highway_images": ("images", "udacity_highway_images", 55, {"camera_height_m": 1.4, "pitch_deg": -1.0},
                               {}, False),
    "udacity_solidWhiteRight": ("video", "udacity_solidWhiteRight.mp4", 55,
                                {"camera_height_m": 1.4, "pitch_deg": -1.0}, {"step": 20}, True),
    "bdd_street_photos": ("images", "bdd_street_photos", 60, {"camera_height_m": 1.4, "pitch_deg": -5.0}, {}, False),
}
# the camera zoo's rigs (benchmarks/analysis/camera_zoo_truth.yaml), imported with their intrinsics; OLD: the
# job's defaults (a user without the analysis has no better values); rendered 960 px wide
ZOO = {"nuscenes_cam_front": {"step": 10}, "ddad_scene01": {}, "ddad_scene02": {}, "argoverse1_stereo_front_left": {},
       "udacity_carnd": {}, "comma2k19_preview": {}}
for _rig, _frames in ZOO.items():
    DATASETS[f"zoo_{_rig}"] = ("zoo", _rig, None, {"camera_height_m": 1.5, "pitch_deg": 0.0}, _frames, False)
ZOO_WIDTH = 960
OVERLAP = 0.05


def recording(name: str) -> Path:
    importer, src, hfov, *_ = DATASETS[name]
    if importer == "zoo":
        from benchmarks.analysis._camera_zoo import import_rig, load_rigs

        return import_rig(load_rigs([src])[0], root=TMP / "zoo_recs")
    dst = TMP / f"rec_{name}"
    if not (dst / "frames.csv").exists():
        subprocess.run([sys.executable, "-m", "blendgen.cli", "import", importer, str(REAL / src), str(dst),
                        "--hfov", str(hfov), "--no-progress"], check=True, cwd=ROOT, capture_output=True)
    return dst


def run_job(name: str, path: str, samples: int, quick: bool) -> Path:
    _, _, _, gp, frames, seq = DATASETS[name]
    frames = dict(frames)
    if quick:
        frames["stop"] = 3 * frames.get("step", 1)
    out = TMP / f"{name}_{path}"
    job = parse_job({
        "name": f"{name}_{path}", "seed": 11, "recording": str(recording(name)),
        # OLD: the values a careful user sets by eye; NEW: camera estimated from the frames
        "ground_plane": {**gp, "analysis": False} if path == "old" else
        {"camera_height_m": "auto", "pitch_deg": "auto", "roll_deg": "auto"}, "frames": frames,
        "inject": {"objects_per_frame": [3, 5], "classes": CLASSES, "distance_m": [6, 35], "sequences": seq},
        "render": {"samples": samples, **({"resolution": zoo_resolution(name)} if name.startswith("zoo_") else {})},
        "export": {"formats": ["coco"], "min_visible_px": 64},
        "output": str(out)})
    Runner(job, progress=False).run()
    return out


def zoo_resolution(name: str) -> list[int]:
    rec = read_recording(recording(name))
    return [ZOO_WIDTH, round(ZOO_WIDTH * rec.camera.height / rec.camera.width / 2) * 2]


def score(out: Path, ref: Path, det, rec) -> dict:
    """Placement counts and detector recall of one run against the reference analysis `ref`."""
    from blendgen.eval.realism import score_output

    plans = load_plans(out / "plan.jsonl")
    n = {"objects": 0, "inside_or_behind": 0, "in_front": 0, "vehicles": 0, "off_road": 0, "on_hood": 0,
         "persons": 0, "off_walkable": 0, "traffic_lights": 0}
    for lp in sorted((out / "frames").glob("*/labels.json")):
        fr = read_frame_labels(lp)
        fa = read_analysis(ref, fr["frame_id"])
        plan = plans[fr["frame_id"]]
        road = read_road_mask(ref, fa)
        hood = hood_mask(fa.hood, fa.width, fa.height)
        T = np.asarray(plan.T_world_cam)
        cam = rec.camera.scaled(fr["width"], fr["height"])
        sx = fr["width"] / fa.width   # the render's pixels per analysis pixel (zoo rigs render smaller)
        objs = {o.id: o for o in plan.objects}
        for inst in fr["instances"]:
            if inst["ignore"]:
                continue
            o = objs[inst["id"]]
            n["objects"] += 1
            corners = o.box_corners_world()[::2, :2]   # the 4 bottom corners (x, y)
            corners = corners[[0, 1, 3, 2]]
            # depth order in the image, whatever either path assumed about the camera: on flat
            # ground the nearer object touches the ground lower in the frame
            foot = o.position[2] - (o.variant.get("mount_height_m", 0.0) if o.variant.get("pole") else 0.0)
            base, _ = cam.project_world(T, np.column_stack([corners, np.full(4, foot)]))
            v_near = float(base[:, 1].max())
            x, y, w, h = inst["bbox"]
            behind = front = False
            for r in fa.real_objects:
                rx, ry, rw, rh = (v * sx for v in r.box)
                ix = max(0.0, min(x + w, rx + rw) - max(x, rx))
                iy = max(0.0, min(y + h, ry + rh) - max(y, ry))
                if ix * iy > OVERLAP * w * h:
                    if v_near <= ry + rh:
                        behind = True
                    else:
                        front = True
            n["inside_or_behind"] += behind
            n["in_front"] += front and not behind
            uv, ok = cam.project_world(T, np.column_stack([_inset(corners), np.full(4, o.position[2])]))
            uv = np.round(uv / sx).astype(int)
            inside = ok & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < fa.width) & (uv[:, 1] < fa.height)
            px = uv[inside]
            if hood is not None and o.cls != "traffic light" and hood[px[:, 1], px[:, 0]].any():
                n["on_hood"] += 1
            n["traffic_lights"] += o.cls == "traffic light"
            if o.cls == "person" and o.scenario is None and not o.variant.get("rides"):  # not crossing, not riding
                n["persons"] += 1
                n["off_walkable"] += road is None or bool(len(px)) and (road[px[:, 1], px[:, 0]] != BAND).all()
            if o.cls in WHEELED:
                n["vehicles"] += 1
                # farther than the road estimate reaches is unknown, not off road (the far
                # asphalt often differs from the seed's colour): only rows it covers count
                top = int(np.argmax((road == ROAD).any(axis=1))) if road is not None and (road == ROAD).any() else None
                known = px[px[:, 1] >= top] if top is not None else px[:0]
                if top is not None and (road[known[:, 1], known[:, 0]] != ROAD).any():
                    n["off_road"] += 1
    s = score_output(out, det, iou=0.5, score_threshold=0.3, background="auto")
    m = s["classes"]["mean"]
    n["recall"] = m["tp"] / m["n_gt"] if m["n_gt"] else float("nan")
    n["recall_ci"] = recall_ci(m["tp"], m["n_gt"])
    n["recall_n"] = m["n_gt"]
    return n


def egomotion_seconds(ref: Path) -> tuple[float, int] | None:
    """(CPU seconds of the video ego motion per recording frame it tracked, frames tracked)."""
    for p in sorted(ref.glob("f*.json")):
        for d in json.loads(p.read_text())["decisions"]:
            if d["what"] == "cpu_s" and d["reason"].startswith("ego motion over"):
                n_dense = int(d["reason"].split()[3])
                n_sel = len(list(ref.glob("f*.json")))
                return d["value"] * n_sel / n_dense, n_dense
    return None


def recall_ci(tp: int, n: int, reps: int = 2000) -> tuple[float, float]:
    """Bootstrap 95 % interval of a recall tp / n (objects resampled with replacement)."""
    rng = np.random.default_rng(0)
    r = rng.binomial(n, tp / n, reps) / n if n else np.full(reps, np.nan)
    return ci95(r)


def analysis_seconds(ref: Path) -> list[float]:
    """CPU seconds per analysed frame (its own work plus its share of hood, camera, ego motion)."""
    return [sum(d["value"] for d in json.loads(p.read_text())["decisions"] if d["what"] == "cpu_s")
            for p in sorted(ref.glob("f*.json"))]


def camera_accuracy(n: int) -> dict:
    """h12cam's camera estimate (`analysis.camera.estimate_frame`) on demo-town frames rendered
    at known height, pitch, roll and yaw (bpy, cached): the errors per frame."""
    from blendgen.analysis.camera import estimate_frame
    from blendgen.geometry import Camera
    from blendgen.render.posed_frames import render_posed_frames

    rng = np.random.default_rng(4)
    specs = [dict(name=f"pose{i}", seed=int(i % 4), s=int(rng.integers(0, 30)), height_m=float(rng.uniform(1.2, 1.9)),
                  pitch_deg=float(rng.uniform(-4, 4)), roll_deg=float(rng.uniform(-3, 3)),
                  yaw_deg=float(rng.uniform(-3, 3))) for i in range(n)]
    cam = Camera.from_hfov(960, 540, 70.0)
    out = TMP / "posed_frames"
    poses = render_posed_frames(out, specs, cam, samples=4)
    err = {"pitch_deg": [], "roll_deg": [], "height_pct": []}
    for name, p in poses.items():
        r = estimate_frame(cv2.imread(str(out / f"{name}.png")), cam, lane_width_m=3.3)  # the demo town's lanes
        err["pitch_deg"].append(abs(r.pitch - p["pitch_deg"]) if r.pitch is not None else float("nan"))
        err["roll_deg"].append(abs(r.roll - p["roll_deg"]) if r.roll is not None else float("nan"))
        h = r.height_lanes or r.height_cars
        err["height_pct"].append(100 * abs(h - p["height_m"]) / p["height_m"] if h else float("nan"))
    return err


def timing_split(name: str = "bdd_street_photos") -> dict:
    """CPU seconds per frame of each part of the analysis on one core (second of two passes)."""
    from blendgen.analysis import objects
    from blendgen.analysis.camera import estimate_cameras
    from blendgen.analysis.hood import find_hood
    from blendgen.analysis.stage import analyse_frame

    rec = read_recording(recording(name))
    ids = [rec.frame_id(i) for i in range(rec.n_frames)]
    det = objects.load_detector()
    gp = parse_job({"name": "t", "recording": str(recording(name)), "ground_plane": "auto", "output": str(TMP)}
                   ).ground_plane
    t = {}
    for _ in range(2):
        t0 = time.process_time()
        hoods = find_hood(rec, ids)
        t1 = time.process_time()
        ims = {f: read_frame(rec, int(f[1:])) for f in ids}
        t2 = time.process_time()
        users = {f: objects.road_users(im, det) for f, im in ims.items()}
        t3 = time.process_time()
        cams = estimate_cameras(rec, ids, user=gp, hoods=hoods, car_boxes={f: [o.box for o in u] for f, u in users.items()})
        t4 = time.process_time()
        for f, im in ims.items():
            analyse_frame(im, f, rec.camera, cams[f][0], det, horizon=cams[f][1], hood=hoods[f], users=users[f])
        t5 = time.process_time()
        t = {"hood": t1 - t0, "detector": t3 - t2, "camera": t4 - t3, "road, direction, footprints": t5 - t4}
    return {k: v / len(ids) for k, v in t.items()}


def gallery(rows: list[tuple[str, Path, Path]]) -> np.ndarray:
    tiles = []
    for name, old, new in rows:
        for lp in sorted((new / "frames").glob("*/composite.png"))[:3]:
            fid = lp.parent.name
            o = cv2.imread(str(old / "frames" / fid / "composite.png"))
            nw = cv2.imread(str(lp))
            fa = read_analysis(new / "analysis", fid)
            real = read_frame(read_recording(recording(name)), int(fid[1:]))
            ov = draw_analysis(real, fa, read_road_mask(new / "analysis", fa))
            row = [cv2.resize(im, (480, 270), interpolation=cv2.INTER_AREA) for im in (ov, o, nw)]
            for im, cap in zip(row, (f"{name} {fid}: analysis", "OLD: fixed pose, no obstacles", "NEW")):
                cv2.putText(im, cap, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
                cv2.putText(im, cap, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
            tiles.append(np.hstack(row))
    return np.vstack(tiles)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 frames per data set")
    ap.add_argument("--samples", type=int, default=8)
    ap.add_argument("--only", nargs="*", default=list(DATASETS))
    ap.add_argument("--timing", action="store_true", help="only the analysis time split on the BDD photos")
    args = ap.parse_args()
    cv2.setNumThreads(1)  # analysis seconds on one core
    if args.timing:
        split = timing_split()
        print(" | ".join(f"{k} {v:.3f}" for k, v in split.items()) + f" | total {sum(split.values()):.3f} CPU s/frame")
        return
    from blendgen import CLASSES as CLASS_IDS
    from blendgen.detection.detector import BUNDLED_MODEL, YoloxDetector

    det = YoloxDetector(BUNDLED_MODEL, category_ids=set(CLASS_IDS.values()))  # as `blendgen realism`: all 7 classes
    results, rows = {}, []
    for name in args.only:
        t0 = time.perf_counter()
        old = run_job(name, "old", args.samples, args.quick)
        new = run_job(name, "new", args.samples, args.quick)
        ref = new / "analysis"
        rec = read_recording(recording(name))
        results[name] = {"old": score(old, ref, det, rec), "new": score(new, ref, det, rec),
                         "analysis_cpu_s": analysis_seconds(ref), "egomotion": egomotion_seconds(ref)}
        rows.append((name, old, new))
        print(f"{name}: {time.perf_counter() - t0:.0f} s", flush=True)
    table = make_table(results)
    cam_err = camera_accuracy(4 if args.quick else 10)
    cam_table = ("| frames | horizon: pitch error deg (median, max) | roll error deg (median, max) "
                 "| camera height error % (median, max) | no estimate |\n|---|---|---|---|---|\n"
                 f"| {len(cam_err['pitch_deg'])} | " + " | ".join(
                     f"{np.nanmedian(v):.2f}, {np.nanmax(v):.2f}" for v in cam_err.values())
                 + f" | {sum(np.isnan(v).sum() for v in map(np.asarray, cam_err.values()))} values |")
    results["camera_accuracy"] = cam_err
    split = timing_split()
    split_line = " | ".join(f"{k} {v:.3f}" for k, v in split.items()) + f" | total {sum(split.values()):.3f}"
    print(table)
    print(cam_table)
    cmd = "PYTHONPATH=. .venv/bin/python benchmarks/analysis/bench_placement.py" + (" --quick" if args.quick else "")
    md = ["# Placement on real footage without a map", "", f"`{cmd}` (render samples {args.samples}; "
          "machine shared with other jobs: CPU seconds, not wall time).", "", __doc__.split("\n\n")[2], "", table, "",
          "Analysis CPU seconds per analysed frame include its share of the recording-wide work (hood, camera, "
          "and for video the ego motion, which tracks every recording frame between the first and last "
          "selected one): " + "; ".join(f"{k}: ego motion {v['egomotion'][0]:.3f} s per tracked frame over "
                                          f"{v['egomotion'][1]} frames" for k, v in results.items()
                                          if k != "camera_accuracy" and v.get("egomotion")) + ".", "",
          "Where the BDD analysis time goes (`PYTHONPATH=. .venv/bin/python benchmarks/analysis/bench_placement.py "
          "--timing`, CPU s per 1280x720 frame, one thread, machine shared): " + split_line + ".", "",
          "![placement](../../benchmarks/results/placement.png)", "",
          "Camera estimate (h12cam's `analysis.camera.estimate_frame`, merged) on demo-town frames rendered "
          "at known poses (960x540, hfov 70, height 1.2-1.9 m, pitch -4..4 deg, roll -3..3 deg, yaw -3..3 deg; "
          "goals: horizon <= 0.5 deg median, height <= 10 %):", "", cam_table, "",
          "Before/after gallery: [docs/images/placement_before_after.jpg](../images/placement_before_after.jpg)", ""]
    write_doc("placement.md", "\n".join(md))
    atomic.write_json(RESULTS / "placement.json", results, indent=1)
    plot(results, RESULTS / "placement.png")
    # CC BY-NC-SA frames (nuScenes, DDAD, Argoverse) never go into the repository
    nc = {f"zoo_{r}" for r in ("nuscenes_cam_front", "ddad_scene01", "ddad_scene02", "argoverse1_stereo_front_left")}
    free = [r for r in rows if r[0] not in nc]
    if free:
        atomic.write_image(ROOT / "docs" / "images" / "placement_before_after.jpg", gallery(free),
                           [cv2.IMWRITE_JPEG_QUALITY, 65])
    if len(free) < len(rows):
        atomic.write_image(TMP / "placement_zoo_nc.jpg", gallery([r for r in rows if r not in free]),
                           [cv2.IMWRITE_JPEG_QUALITY, 85])


def make_table(results: dict) -> str:
    lines = ["| data set | path | objects | inside/behind real | in front of real | vehicles | wheel off road "
             "| on hood | persons | off walkable band | traffic lights | YOLOX recall@0.5 [95 % CI] "
             "| analysis CPU s/frame (median, max) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, r in results.items():
        if name == "camera_accuracy":
            continue
        cpu = r["analysis_cpu_s"]
        for path in ("old", "new"):
            m = r[path]
            t = f"{np.median(cpu):.3f}, {np.max(cpu):.3f}" if path == "new" and cpu else "-"
            lines.append(f"| {name} | {path.upper()} | {m['objects']} | {m['inside_or_behind']} | {m['in_front']} | "
                         f"{m['vehicles']} | {m['off_road']} | {m['on_hood']} | {m.get('persons', '-')} | "
                         f"{m.get('off_walkable', '-')} | {m.get('traffic_lights', '-')} | {m['recall']:.2f} "
                         f"[{m['recall_ci'][0]:.2f}, {m['recall_ci'][1]:.2f}] (n {m['recall_n']}) | {t} |")
    return "\n".join(lines)


def plot(results: dict, out_png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = [("inside_or_behind", "objects"), ("off_road", "vehicles"), ("on_hood", "objects")]
    fig, axes = plt.subplots(1, len(keys) + 1, figsize=(14, 3.6))
    names = [n for n in results if n != "camera_accuracy"]
    x = np.arange(len(names))
    for ax, (k, base) in zip(axes, keys):
        for j, path in enumerate(("old", "new")):
            v = [results[n][path][k] / max(results[n][path][base], 1) for n in names]
            ax.bar(x + (j - 0.5) * 0.38, v, 0.38, label=path.upper())
        ax.set_title(f"{k} / {base}")
        ax.set_xticks(x, [n.replace("_", "\n", 1) for n in names], fontsize=7)
    ax = axes[-1]
    for j, path in enumerate(("old", "new")):
        ax.bar(x + (j - 0.5) * 0.38, [results[n][path]["recall"] for n in names], 0.38, label=path.upper())
    ax.set_title("YOLOX-Nano recall@0.5 of injected objects")
    ax.set_xticks(x, [n.replace("_", "\n", 1) for n in names], fontsize=7)
    axes[0].legend()
    fig.tight_layout()
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)


if __name__ == "__main__":
    main()
