"""Camera from the frames: horizon (pitch, roll) and camera-height error against known poses,
and CPU seconds per frame, over the main knobs (line detector, segments kept, RANSAC iterations).

    .venv/bin/python benchmarks/bench_camera.py [--quick]

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
import os
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from blendgen import atomic  # noqa: E402
from blendgen.analysis.camera import CameraConfig, estimate_frame  # noqa: E402
from blendgen.geometry import Camera  # noqa: E402

FRAMES_DIR = ROOT / "benchmarks" / "results" / "tmp" / "camera_frames"
CAM = Camera.from_hfov(960, 540, 70)
LANE_W = 3.3                       # the demo town's main-street lanes (3.25 on the cross street)
# ../shared/data beside the project; BLENDGEN_SHARED_DATA points elsewhere (e.g. from a worktree)
BDD = Path(os.environ.get("BLENDGEN_SHARED_DATA", ROOT.parent / "shared" / "data")) / "real" / "bdd_street_photos"
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
    meds = np.median(rng.choice(x, (n, len(x))), axis=1)
    return float(np.percentile(meds, 2.5)), float(np.percentile(meds, 97.5))


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
    from blendgen.analysis.model import CameraEstimate
    from blendgen.recording.folder import read_frame, read_recording
    from blendgen.recording.importers.video import import_video

    video = BDD.parent / "udacity_solidWhiteRight.mp4"
    if not video.exists():
        return None
    root = ROOT / "benchmarks" / "results" / "tmp" / "rec_solidWhiteRight"
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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="8 frames, default knobs and the baseline only")
    a = ap.parse_args(argv)
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
    out_png = ROOT / "benchmarks" / "results" / "camera.png"
    with atomic.atomic_path(out_png) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    cmd = "nice -n 5 .venv/bin/python benchmarks/bench_camera.py" + (" --quick" if a.quick else "")
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
    atomic.write_text(ROOT / "docs" / "benchmarks" / "camera.md", "\n".join(md) + "\n")
    print(f"wrote {out_png} and docs/benchmarks/camera.md")


if __name__ == "__main__":
    main()
