"""Camera from the frames: horizon (pitch, roll) and camera-height error against known poses,
and CPU seconds per frame, over the main knobs (line detector, segments kept, RANSAC iterations).

    .venv/bin/python benchmarks/analysis/bench_camera.py [--quick]

Ground truth: demo-town frames rendered with Cycles (960x540, 70 deg horizontal field of
view, 4 samples: noisy like a real sensor) at random camera heights (1.2..1.8 m), pitches
(-4..+6 deg), rolls (-3..+3 deg) and yaws (-4..+4 deg off the lane); rendered once into
benchmarks/results/tmp/camera_frames (cached). The baseline is what a user of the ground-
plane path does without an estimate: the job's defaults (pitch 0, roll 0, height 1.5 m).
Timing: `time.process_time` of `camera.estimate_frame` (one core), plus the whole per-frame
analysis this engineer adds (hood + camera) on the real 1280x720 BDD photos.
Writes benchmarks/results/camera.png and docs/benchmarks/camera.md.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import DOCS, REAL, RESULTS, ROOT, ci95  # noqa: E402

from blendgen import atomic  # noqa: E402
from blendgen.analysis.camera import CameraConfig, estimate_frame  # noqa: E402
from blendgen.geometry import Camera  # noqa: E402

FRAMES_DIR = RESULTS / "tmp" / "camera_frames"
CAM = Camera.from_hfov(960, 540, 70)
LANE_W = 3.3                       # the demo town's main-street lanes (3.25 on the cross street)
# ../shared/data beside the project; BLENDGEN_SHARED_DATA points elsewhere (e.g. from a worktree)
BDD = REAL / "bdd_street_photos"
KNOBS = [("default (lsd, 250 seg, 250 it)", {}),
         ("fld", {"detector": "fld"}),
         ("100 segments", {"max_segments": 100}),
         ("500 segments", {"max_segments": 500}),
         ("50 RANSAC it", {"ransac_iters": 50}),
         ("1000 RANSAC it", {"ransac_iters": 1000}),
         ("inlier 1.0 deg", {"inlier_deg": 1.0}),
         ("inlier 2.5 deg", {"inlier_deg": 2.5})]


def pose_specs(n: int, seed: int = 7) -> list[dict]:
    rng = np.random.default_rng(seed)
    return [dict(name=f"c{i:02d}", seed=int(i % 12), s=int(rng.integers(0, 30)),
                 height_m=round(float(rng.uniform(1.2, 1.8)), 3), pitch_deg=round(float(rng.uniform(-4, 6)), 2),
                 roll_deg=round(float(rng.uniform(-3, 3)), 2), yaw_deg=round(float(rng.uniform(-4, 4)), 2))
            for i in range(n)]


def benchmark_frames(n: int = 24) -> dict[str, dict]:
    """name -> pose (with 'image'): renders the missing frames in a bpy subprocess (cached)."""
    specs = pose_specs(n)
    meta = FRAMES_DIR / "poses.json"
    if not all((FRAMES_DIR / f"{s['name']}.png").exists() for s in specs) or not meta.exists():
        code = ("import json,sys; from blendgen.geometry import Camera; "
                "from blendgen.render.posed_frames import render_posed_frames; "
                "a=json.loads(sys.argv[1]); render_posed_frames(a['dir'], a['specs'], Camera(**a['cam']), samples=4)")
        arg = json.dumps({"dir": str(FRAMES_DIR), "specs": specs, "cam": CAM.to_dict()})
        subprocess.run([sys.executable, "-c", code, arg], check=True, cwd=ROOT,
                       env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    poses = json.loads(meta.read_text())["poses"]
    return {s["name"]: {**poses[s["name"]], "image": FRAMES_DIR / f"{s['name']}.png"} for s in specs}


def horizon_error_deg(pitch, roll, true_pitch, true_roll) -> float:
    """The larger of the pitch and roll errors: the horizon's offset and tilt in degrees."""
    return max(abs(pitch - true_pitch), abs(roll - true_roll))


def evaluate(frames: dict, cfg: CameraConfig) -> list[dict]:
    """Per frame: pitch/roll/height errors and CPU seconds of estimate_frame."""
    rows = []
    for name, p in frames.items():
        img = cv2.imread(str(p["image"]))
        t0 = time.process_time()
        r = estimate_frame(img, CAM, cfg=cfg, lane_width_m=LANE_W)
        cpu = time.process_time() - t0
        ok = r.pitch is not None
        rows.append({"name": name, "cpu_s": cpu, "ok": ok, "roll_prior": any(m.startswith("roll") for m in r.reasons),
                     "pitch_err": abs(r.pitch - p["pitch_deg"]) if ok else float("nan"),
                     "roll_err": abs(r.roll - p["roll_deg"]) if ok else float("nan"),
                     "horizon_err": horizon_error_deg(r.pitch, r.roll, p["pitch_deg"], p["roll_deg"]) if ok
                     else float("nan"),
                     "height_err_pct": (100 * abs(r.height_lanes - p["height_m"]) / p["height_m"]
                                        if r.height_lanes else float("nan"))})
    return rows


def bootstrap_median_ci(x, n=2000, seed=0) -> tuple[float, float]:
    x = np.asarray([v for v in x if np.isfinite(v)])
    if len(x) == 0:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    return ci95(np.median(rng.choice(x, (n, len(x))), axis=1))


def real_photo_cpu() -> float | None:
    """Median CPU s per 1280x720 BDD photo of the hood search + camera estimate."""
    from blendgen.analysis.hood import hood_in_still

    files = sorted(BDD.glob("*.jpg"))
    if not files:
        return None
    cam = Camera.from_hfov(1280, 720, 60)
    ts = []
    for _ in range(3):
        for f in files:
            img = cv2.imread(str(f))
            t0 = time.process_time()
            estimate_frame(img, cam, hood=hood_in_still(img)[0], fit_focal=True)
            ts.append(time.process_time() - t0)
    return float(np.median(ts))


def real_gallery(out: Path) -> int:
    """The real photos with the estimate drawn on them: horizon (yellow), hood (magenta), line
    segments by vanishing direction (red: along the road, blue: vertical, green: crosswise)."""
    from blendgen.analysis.camera import horizon_line, road_axes
    from blendgen.analysis.hood import hood_in_still

    real = BDD.parent
    files = (sorted((real / "bdd_street_photos").glob("*.jpg")) + sorted((real / "udacity_highway_images").glob("*.jpg"))
             + sorted((real / "udacity_lane_camera").glob("straight_lines*.jpg")))
    tiles = []
    for f in files:
        img = cv2.imread(str(f))
        h, w = img.shape[:2]
        cam = Camera.from_hfov(w, h, 60 if w == 1280 else 70)
        hood = hood_in_still(img)[0]
        r = estimate_frame(img, cam, hood=hood, fit_focal=True)
        vis = img.copy()
        colours = {0: (0, 0, 255), 1: (0, 200, 0), 2: (255, 0, 0)}
        for sgm, lab in zip(r.segments if r.segments is not None else [],
                            r.labels if r.labels is not None else []):
            if lab >= 0:
                cv2.line(vis, tuple(map(int, sgm[:2])), tuple(map(int, sgm[2:])), colours[int(lab)], 2)
        text = "no estimate"
        if r.pitch is not None:
            c2 = cam if r.fx is None else Camera(w, h, r.fx, r.fx, cam.cx, cam.cy)
            hz = horizon_line(c2, road_axes(math.radians(r.pitch), math.radians(r.roll), 0.0)[2])
            cv2.line(vis, tuple(map(int, hz[0])), tuple(map(int, hz[1])), (0, 255, 255), 3)
            text = f"pitch {r.pitch:+.1f} roll {r.roll:+.1f} h {r.height_lanes or float('nan'):.2f} m"
        if hood:
            cv2.polylines(vis, [np.array(hood, np.int32)], True, (255, 0, 255), 3)
        vis = cv2.resize(vis, (480, 270), interpolation=cv2.INTER_AREA)
        vis[:26] //= 3
        cv2.putText(vis, f"{f.stem[:16]}: {text}", (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1,
                    cv2.LINE_AA)
        tiles.append(vis)
    if not tiles:
        return 0
    while len(tiles) % 3:
        tiles.append(np.zeros_like(tiles[0]))
    grid = np.vstack([np.hstack(tiles[i:i + 3]) for i in range(0, len(tiles), 3)])
    atomic.write_image(out, grid, [cv2.IMWRITE_JPEG_QUALITY, 80])
    return len(files)


def ego_strip(out: Path) -> float | None:
    """udacity_solidWhiteRight.mp4 through calibrate: a virtual parked car (4.5 x 1.8 x 1.5 m on
    the right shoulder, 30 m ahead of frame 0) drawn with the ego-motion poses on frames 0..30.
    Returns the median step (m/frame)."""
    from blendgen.analysis.calibrate import calibrate
    from blendgen.analysis.egomotion import ground_track
    from blendgen.frame_analysis import CameraEstimate
    from blendgen.recording.folder import read_frame, read_recording
    from blendgen.recording.importers.video import import_video

    video = BDD.parent / "udacity_solidWhiteRight.mp4"
    if not video.exists():
        return None
    root = RESULTS / "tmp" / "rec_solidWhiteRight"
    if not (root / "calib.yaml").exists():
        import_video(video, root, force=True, show_progress=False)
    rec = read_recording(root)
    ids = [rec.frame_id(i) for i in range(rec.n_frames)]
    doc = calibrate(rec, ids, None)
    cams = {f["id"]: CameraEstimate(f["height_m"], f["pitch_deg"], f["roll_deg"], yaw_deg=f["yaw_deg"],
                                    confidence=f["confidence"]) for f in doc["frames"]}
    poses = ground_track(rec, ids, cams).poses
    box = np.array([[30.0 + dx, -3.6 + dy, dz] for dx in (0, 4.5) for dy in (0, -1.8) for dz in (0, 1.5)])
    tiles = []
    for k in (0, 10, 20, 30):
        img = read_frame(rec, k)
        uv, ok = rec.camera.project_world(poses[ids[k]], box)
        if ok.all():
            cv2.polylines(img, [cv2.convexHull(uv.astype(np.float32)).astype(np.int32)], True, (0, 0, 255), 3)
        cv2.putText(img, f"frame {k}: ego x = {poses[ids[k]][0, 3]:.1f} m", (10, 32), cv2.FONT_HERSHEY_SIMPLEX, 1.0,
                    (255, 255, 255), 2, cv2.LINE_AA)
        tiles.append(cv2.resize(img, (480, 270), interpolation=cv2.INTER_AREA))
    atomic.write_image(out, np.vstack([np.hstack(tiles[:2]), np.hstack(tiles[2:])]), [cv2.IMWRITE_JPEG_QUALITY, 80])
    xy = np.array([poses[f][:2, 3] for f in ids])
    return float(np.median(np.hypot(*np.diff(xy, axis=0).T)))


# ----------------------------------------------------------------------------- camera zoo

ZOO_BEGIN, ZOO_END = "<!-- zoo: bench_camera.py --zoo -->", "<!-- /zoo -->"


def write_section(md_path: Path, lines: list[str], zoo: bool) -> None:
    """docs/benchmarks/camera.md holds two sections: the rendered demo-town frames (the default
    run) and the camera zoo (--zoo, between the markers); each run rewrites its own."""
    old = md_path.read_text() if md_path.exists() else ""
    if ZOO_BEGIN in old:
        head, rest = old.split(ZOO_BEGIN, 1)
        zoo_part = ZOO_BEGIN + rest.split(ZOO_END, 1)[0] + ZOO_END
    else:
        head, zoo_part = old, ""
    body = "\n".join(lines).rstrip() + "\n"
    new = (head.rstrip() + "\n\n" + ZOO_BEGIN + "\n" + body + ZOO_END + "\n") if zoo else \
        (body + ("\n" + zoo_part + "\n" if zoo_part else ""))
    atomic.write_text(md_path, new)


def _overlay(img, fa, mask, rig) -> np.ndarray:
    """The stage's analysis drawn over the frame (report.draw), the reference horizon in cyan."""
    from blendgen.analysis.camera import horizon_line, road_axes
    from blendgen.geometry import Camera as Cam
    from blendgen.report.draw import draw_analysis

    vis = draw_analysis(img, fa, mask)
    if rig.pitch_exact and rig.pitch_deg is not None:
        fx, fy, cx, cy = rig.camera["intrinsics"]
        cam = Cam(img.shape[1], img.shape[0], fx, fy, cx, cy)
        hz = horizon_line(cam, road_axes(math.radians(rig.pitch_deg), math.radians(rig.roll_deg or 0.0), 0.0)[2])
        cv2.line(vis, tuple(map(int, hz[0])), tuple(map(int, hz[1])), (255, 255, 0), max(1, img.shape[1] // 640),
                 cv2.LINE_AA)
    return vis


def zoo(args) -> None:
    import itertools

    import yaml

    from benchmarks.analysis._camera_zoo import (CROSS_GRID, GRID, TMP, camera_metrics, hood_only, import_rig,
                                                 leave_one_rig_out, load_rigs, objective, per_frame)
    from blendgen.analysis import mount as mount_mod
    from blendgen.analysis import objects
    from blendgen.analysis.camera import estimate_frame
    from blendgen.analysis.stage import run_analysis
    from blendgen.frame_analysis import read_road_mask
    from blendgen.job.schema import GroundPlane
    from blendgen.recording.folder import read_frame, read_recording
    from blendgen.recording.frames import read_frames
    from blendgen.report.draw import contact_sheet

    rigs = load_rigs(args.rigs or None)
    det = objects.load_detector()
    recs = {r.name: read_recording(import_rig(r)) for r in rigs}
    # 1. hood: the crossing-line margin, leave-one-rig-out
    hood_runs = {r.name: {cp: hood_only(r, recs[r.name], cp) for cp in CROSS_GRID} for r in rigs}

    def hood_counts(rig, hoods):
        found = [hoods[recs[rig.name].frame_id(i)] is not None for i in range(rig.n)]
        return (sum(f and t for f, t in zip(found, rig.hood)), sum(rig.hood),
                sum(f and not t for f, t in zip(found, rig.hood)), rig.n - sum(rig.hood))

    hood_score = {r.name: {cp: (lambda c: (c[1] - c[0]) / max(c[1], 1) + c[2] / max(c[3], 1))(hood_counts(r, hood_runs[r.name][cp]))
                           for cp in CROSS_GRID} for r in rigs}
    hood_loro = leave_one_rig_out(hood_score, list(CROSS_GRID))
    print("hood CROSS_PX per held-out rig:", hood_loro)
    # 2. per-frame cues (the deployed hood margin), 3. the mount over a grid of the fusion constants
    pf = {r.name: per_frame(r, recs[r.name], det) for r in rigs}
    keys = list(itertools.product(*GRID.values()))
    met = {}
    for r in rigs:
        met[r.name] = {}
        for k in keys:
            m = mount_mod.estimate_mount(pf[r.name]["cues"], recs[r.name].camera.K, **dict(zip(GRID, k)))
            met[r.name][k] = camera_metrics(r, m)
        print(f"  {r.name}: {len(keys)} mounts", flush=True)
    score = {r: {k: objective(v) for k, v in mk.items()} for r, mk in met.items()}
    loro = leave_one_rig_out(score, keys)
    deployed = min(keys, key=lambda k: sum(score[r][k] for r in score))
    print("deployed (all rigs):", dict(zip(GRID, deployed)))
    # ablation: no shared mount (each still its own angles) and the job defaults
    free = {r.name: camera_metrics(r, mount_mod.estimate_mount(pf[r.name]["cues"], recs[r.name].camera.K,
                                                                 **{**dict(zip(GRID, loro[r.name])), "frame_dev_deg": 30.0}))
            for r in rigs}
    # 4. focal length when the import assumed a field of view
    fx_err = {}
    for r in rigs:
        rec_nc = read_recording(import_rig(r, calibrated=False))
        hoods = pf[r.name]["hoods"]
        per = {}
        for fid, im in read_frames(rec_nc, [rec_nc.frame_id(i) for i in range(rec_nc.n_frames)]):
            fc = estimate_frame(im, rec_nc.camera, hood=hoods.get(fid), fit_focal=True)
            per[fid] = mount_mod.FrameCues(fx=fc.fx, fx_fit=fc.fx_fit, fx_log_std=fc.fx_log_std, confidence=fc.confidence)
        fx, why = mount_mod.focal_consensus(per)
        fx_true = r.camera["intrinsics"][0]
        n_fit = sum(1 for c in per.values() if c.fx_fit and c.fx_log_std < mount_mod.FX_FRAME_MAX_LOG_STD)
        fx_err[r.name] = (n_fit, (fx / fx_true - 1) if fx else None, rec_nc.camera.fx / fx_true - 1)
    # 5. the whole analysis stage as a job runs it (deployed constants): CPU and the gallery
    gp = GroundPlane(camera_height_m="auto", pitch_deg="auto", roll_deg="auto")
    stage_cpu, tiles_mit, tiles_nc = {}, [], []
    for r in rigs:
        rec = recs[r.name]
        folder = TMP / "stage" / r.name
        import shutil
        shutil.rmtree(folder, ignore_errors=True)
        ids = [rec.frame_id(i) for i in range(rec.n_frames)]
        an = run_analysis(rec, ids, folder, gp)
        stage_cpu[r.name] = float(np.median([sum(d["value"] for d in fa.decisions if d["what"] == "cpu_s")
                                             for fa in an.values()]))
        pick = ids if len(ids) <= 4 else [ids[i] for i in np.linspace(0, len(ids) - 1, 4).round().astype(int)]
        for fid in pick:
            fa = an[fid]
            vis = _overlay(read_frame(rec, ids.index(fid)), fa, read_road_mask(folder, fa), r)
            (tiles_mit if r.licence == "mit" else tiles_nc).append((f"{r.name} {fid}", vis))
    if tiles_mit:
        atomic.write_image(ROOT / "docs" / "images" / "camera_zoo.jpg", contact_sheet(tiles_mit, cols=3, tile_w=420),
                           [cv2.IMWRITE_JPEG_QUALITY, 78])
    if tiles_nc:
        atomic.write_image(TMP / "camera_zoo_nc.jpg", contact_sheet(tiles_nc, cols=4, tile_w=420),
                           [cv2.IMWRITE_JPEG_QUALITY, 85])
    # table
    def pct(v):
        return "-" if v is None else f"{100 * v:+.1f} %"

    rows = []
    for r in rigs:
        k = loro[r.name]
        m = met[r.name][k]
        hc = hood_counts(r, hood_runs[r.name][hood_loro[r.name]])
        hood_txt = f"{hc[0]}/{hc[1]}" + (f", {hc[2]} false of {hc[3]}" if hc[3] else "")
        n_fx, e_fx, e_guess = fx_err[r.name]
        ref_h = "-" if r.height_m is None else f"{r.height_m:.2f}{'' if r.height_exact else ' ~'}"
        rows.append(f"| {r.name} | {r.n} | {r.mount} | {m['height_m']:.2f} +-{100 * m['height_std']:.0f} % | {ref_h} | "
                    f"{pct(m['height_err'])} | {m['pitch_p90']:.2f} ({m['pitch_ref']}) | {m['roll_p90']:.2f} ({m['roll_ref']}) | "
                    f"{m['pitch_med']:+.2f} / {m['roll_med']:+.2f} | {m['pitch_spread']:.2f} / {m['roll_spread']:.2f} | "
                    f"{pct(e_fx) if e_fx is not None else 'kept'} ({n_fx} fr; guess {pct(e_guess)}) | {hood_txt} | "
                    f"{'/'.join(f'{v:g}' for v in k)} | {stage_cpu[r.name]:.2f} |")
    abl = []
    for r in rigs:
        m, f = met[r.name][loro[r.name]], free[r.name]
        base_h = (1.5 / r.height_m - 1) if r.height_m else None
        base_p = abs(0.0 - r.pitch_deg) if (r.pitch_exact and r.pitch_deg is not None) else None
        abl.append(f"| {r.name} | {pct(base_h)} | {'-' if base_p is None else f'{base_p:.2f}'} | "
                   f"{f['pitch_p90']:.2f} / {f['roll_p90']:.2f} | {m['pitch_p90']:.2f} / {m['roll_p90']:.2f} | "
                   f"{pct(f['height_err'])} | {pct(m['height_err'])} |")
    checks = []
    for r in rigs:
        if r.n < 3:
            continue
        m = met[r.name][loro[r.name]]
        hc = hood_counts(r, hood_runs[r.name][hood_loro[r.name]])
        ok = lambda c: "yes" if c else "NO"  # noqa: E731
        h_txt = "height n/a" if m["height_err"] is None else f"height <= 5 %: {ok(abs(m['height_err']) <= 0.05)}"
        hood_ok = (hc[2] == 0) if hc[1] == 0 else (hc[0] >= 0.9 * hc[1] and hc[2] == 0)
        checks.append(f"{r.name}: {h_txt}, pitch p90 <= 1 deg: {ok(m['pitch_p90'] <= 1)}, roll p90 <= 1 deg: "
                      f"{ok(m['roll_p90'] <= 1)}, hood: {ok(hood_ok)}")
    cues_txt = "; ".join(f"{r.name}: " + ", ".join(f"{k} {v}" for k, v in met[r.name][loro[r.name]]["cues"].items() if v)
                         for r in rigs)
    px_720 = {r.name: r.camera["resolution"][0] * r.camera["resolution"][1] / (1280 * 720) for r in rigs}
    cmd = "nice -n 5 .venv/bin/python benchmarks/analysis/bench_camera.py --zoo"
    md = ["## Camera zoo: real rigs the method was not tuned on", "",
          f"Command: `{cmd}` (2 shared CPU cores; one thread). Rigs, references and the hood marks: "
          "`benchmarks/analysis/camera_zoo_truth.yaml` (each folder's calib.txt; `~`: an approximate reference). Each rig is "
          "imported with `blendgen import images` and its intrinsics, analysed as stills of one camera.",
          "",
          "**Leave-one-rig-out.** The tuned constants (the cue sizes' scale `SIZE_SCALE`, the vanishing points' error "
          "floor `VP_SYS_DEG` and a still's deviation from the mount `FRAME_DEV_DEG` of `analysis/mount.py`; the hood's "
          "crossing-line margin `hood.CROSS_PX`) are chosen for each rig on the other rigs only (grid "
          + ", ".join(f"{k} {list(v)}" for k, v in GRID.items()) + f", CROSS_PX {list(CROSS_GRID)}; objective: "
          "|height error| / 5 % + pitch p90 / 1 deg + roll p90 / 1 deg summed over the other rigs), then "
          "reported on the held-out rig. Pitch and roll errors are per frame, against the calibration or, where it is "
          "approximate or missing, against the rig's own median (the spread of one rigid mount).", "",
          "| rig | frames | mount | height (m, +-1 sigma of the fit) | reference (m) | height error | pitch err p90 (deg) "
          "| roll err p90 (deg) | pitch / roll median (deg) | spread p90 pitch / roll (deg) | fx error, fx not given "
          "(frames fitting f to 20 %; the import's 70 deg guess) "
          "| hood found / visible | constants (scale/VP floor/dev) | stage CPU s / frame |",
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"] + rows + [
          "", "Baselines and ablation (same held-out constants): the job defaults a user without the analysis has "
          "(height 1.5 m, pitch 0, roll 0), and each still with its own angles (no shared mount: FRAME_DEV_DEG 30).", "",
          "| rig | height error at 1.5 m | pitch error at 0 deg | per-frame angles: pitch / roll p90 | mount: pitch / roll p90 "
          "| per-frame angles: height error | mount: height error |", "|---|---|---|---|---|---|---|"] + abl + [
          "", "Done-when check (rigs with >= 3 frames, held out): " + "; ".join(checks) + ".",
          "", f"Cues that took part (held-out constants): {cues_txt}.", "",
          "Deployed constants (tuned on all rigs): " + ", ".join(f"{k} {v:g}" for k, v in zip(GRID, deployed))
          + f"; CROSS_PX {min(CROSS_GRID, key=lambda c: sum(hood_score[r][c] for r in hood_score))}.", "",
          "Stage CPU is the analysis stage's own `cpu_s` per frame (hood, detector, camera cues and the mount shared "
          "per frame, then road, bands, lanes, footprints), median over the rig's frames; the frames are "
          + ", ".join(f"{r.name} {px_720[r.name]:.2f}x" for r in rigs) + " the pixels of a 1280x720 frame.", "",
          "Gallery: the stage's analysis over the frames (road green, bands yellow, hood magenta, horizon red, the "
          "reference horizon cyan where the calibration gives it): MIT-licensed rigs in `docs/images/camera_zoo.jpg`; "
          "the CC BY-NC-SA rigs (nuScenes, DDAD, Argoverse) only under `benchmarks/results/tmp/zoo/camera_zoo_nc.jpg` "
          "(never committed)."]
    for line in rows:
        print(line)
    write_section(DOCS / "camera.md", md, zoo=True)
    atomic.write_text(TMP / "zoo_results.yaml", yaml.safe_dump(
        {"loro": {r: dict(zip(GRID, map(float, k))) for r, k in loro.items()}, "deployed": dict(zip(GRID, map(float, deployed))),
         "hood_loro": hood_loro, "metrics": {r: met[r][loro[r]] for r in met}, "stage_cpu": stage_cpu,
         "fx": fx_err}, sort_keys=False))
    print("wrote docs/benchmarks/camera.md (zoo section)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="8 frames, default knobs and the baseline only")
    ap.add_argument("--zoo", action="store_true", help="the real rigs of ../shared/data/real/camera_zoo, leave-one-rig-out")
    ap.add_argument("--rigs", nargs="*", help="with --zoo: only these rigs")
    a = ap.parse_args(argv)
    if a.zoo:
        return zoo(a)
    frames = benchmark_frames(8 if a.quick else 24)
    knobs = KNOBS[:1] if a.quick else KNOBS
    evaluate(dict(list(frames.items())[:1]), CameraConfig())    # warm-up: first calls pay for imports
    table, per = [], {}
    base = {"pitch": [abs(p["pitch_deg"]) for p in frames.values()],
            "roll": [abs(p["roll_deg"]) for p in frames.values()],
            "horizon": [max(abs(p["pitch_deg"]), abs(p["roll_deg"])) for p in frames.values()],
            "height": [100 * abs(1.5 - p["height_m"]) / p["height_m"] for p in frames.values()]}
    table.append(("baseline: job defaults (0, 0, 1.5 m)", np.median(base["pitch"]), np.median(base["roll"]),
                  np.median(base["horizon"]), bootstrap_median_ci(base["horizon"]), max(base["horizon"]),
                  np.median(base["height"]),
                  len(frames), 0.0, f"{len(frames)} ({len(frames)})"))
    per["baseline"] = base["horizon"]
    for label, kw in knobs:
        rows = evaluate(frames, CameraConfig(**kw))
        col = {k: [r[k] for r in rows] for k in ("pitch_err", "roll_err", "horizon_err", "height_err_pct", "cpu_s")}
        n_h = sum(np.isfinite(col["height_err_pct"]))
        table.append((label, np.nanmedian(col["pitch_err"]), np.nanmedian(col["roll_err"]),
                      np.nanmedian(col["horizon_err"]), bootstrap_median_ci(col["horizon_err"]),
                      np.nanmax(col["horizon_err"]), np.nanmedian(col["height_err_pct"]) if n_h else float("nan"), n_h,
                      float(np.median(col["cpu_s"])), f'{sum(r["ok"] for r in rows)} ({sum(r["roll_prior"] for r in rows)})'))
        per[label] = col["horizon_err"]
        print(f"{label:34s} horizon {table[-1][3]:.2f} deg  height {table[-1][6]:.1f} %  {table[-1][8] * 1000:.0f} ms")
    real = real_photo_cpu()
    n_gallery = real_gallery(ROOT / "docs" / "images" / "camera_real.jpg")
    step = ego_strip(ROOT / "docs" / "images" / "egomotion_real.jpg")

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(12, 4.5))
    labels = list(per)
    ax[0].boxplot([[v for v in per[k] if np.isfinite(v)] for k in labels], orientation="horizontal")
    ax[0].set_yticks(range(1, len(labels) + 1), labels, fontsize=7)
    ax[0].axvline(0.5, color="r", ls="--", label="goal 0.5 deg")
    ax[0].set_xscale("symlog", linthresh=0.1)
    ax[0].set_xlim(left=0)
    ax[0].set_xlabel("horizon error (max of pitch, roll error), deg")
    ax[0].legend()
    for row in table[1:]:
        ax[1].scatter(row[8] * 1000, row[3])
        ax[1].annotate(row[0], (row[8] * 1000, row[3]), fontsize=7)
    ax[1].set_xlabel("CPU ms per 960x540 frame (estimate_frame)")
    ax[1].set_ylabel("median horizon error, deg")
    fig.tight_layout()
    out_png = RESULTS / "camera.png"
    with atomic.atomic_path(out_png) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    cmd = "nice -n 5 .venv/bin/python benchmarks/analysis/bench_camera.py" + (" --quick" if a.quick else "")
    md = ["# Camera-from-frames benchmark", "",
          f"Command: `{cmd}` (2 shared CPU cores; CPU time is `time.process_time`, one core). "
          f"{len(frames)} demo-town frames rendered at known poses (960x540, 70 deg HFOV; heights 1.2..1.8 m, "
          "pitch -4..+6, roll -3..+3, yaw -4..+4 deg). Horizon error = max(|pitch error|, |roll error|); "
          "height from the lane-width prior (3.3 m lanes).", "",
          "| configuration | pitch err median (deg) | roll err median (deg) | horizon err median (deg) "
          "| 95 % CI (bootstrap) | horizon err max (deg) | height err median (%) | frames with a height "
          "| ms CPU / frame | frames estimated (roll from the prior) |",
          "|---|---|---|---|---|---|---|---|---|---|"]
    for lab, pe, re, he, ci, hmax, hp, nh, cpu, ok in table:
        md.append(f"| {lab} | {pe:.2f} | {re:.2f} | {he:.2f} | {ci[0]:.2f}..{ci[1]:.2f} | {hmax:.2f} | {hp:.1f} "
                  f"| {nh} | {cpu * 1000:.0f} | {ok} |")
    md += ["", "A frame with too few vertical (4) or crosswise (8) segments keeps the roll prior (0) with a logged "
           "reason and confidence <= 0.3: its horizon error is then the true roll (the max column).",
           "", "CPU ms varied by up to 40 % between runs of the same configuration on this shared machine (load average above 10 on 2 cores): compare the accuracy columns, not small timing differences.",
           "", f"Goals: horizon <= 0.5 deg median, height <= 10 %, <= 0.3 s per 1280x720 frame for the whole analysis.",
           (f"Hood search + camera estimate on the three real 1280x720 BDD photos: {real * 1000:.0f} ms CPU per "
            "frame (median of 9)." if real else "BDD photos not found: no 1280x720 timing."),
           "", "Plot: `benchmarks/results/camera.png`."
           + (f" The {n_gallery} real photos with the estimate drawn on them: `docs/images/camera_real.jpg`."
              if n_gallery else "")]
    if step:
        md += ["", f"Ego motion on udacity_solidWhiteRight.mp4 (221 frames, 25 fps, no IMU/GNSS): median step "
               f"{step:.2f} m/frame; a virtual parked car drawn with those poses: `docs/images/egomotion_real.jpg`."]
    write_section(DOCS / "camera.md", md, zoo=False)
    print(f"wrote {out_png} and docs/benchmarks/camera.md")


if __name__ == "__main__":
    main()
