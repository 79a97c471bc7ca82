"""Vehicles across real lane lines: the ground-plane twin's lanes against the frame's painted lanes.

    PYTHONPATH=. .venv/bin/python benchmarks/plan/bench_lanes.py OUT JOB [--seeds N] [OUT JOB ...]

OUT is a finished ground-plane job's folder (its `analysis/` is read; frames without lane
lines in an older analysis get them from `analysis.lanes`), JOB its job YAML. For N seeds the
planner plans every analysed frame twice on the same real scene: with the frame's lane lines
(`RealScene.lane_centres`, the default since 2026-11-29) and without them (the twin's lanes of
the job's width, the camera on a lane centre: before). Per car, bus and truck:
- across a line: a painted line found in the frame (cover >= 0.3) passes under the body at its
  near end (within its width less 0.15 m a side): the vehicle stands on the line (goal 0);
- on video, a vehicle's lateral step between consecutive frames (cm; goal: below a pixel), also
  for each frame's lines taken unsmoothed (`planner.LANE_SMOOTH_S` near 0);
- plan CPU seconds per frame.
Prints a table and writes benchmarks/results/lanes.png (`--plot`). Planning only: nothing is rendered.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import RESULTS  # noqa: E402

from blendgen.analysis.lanes import lane_lines  # noqa: E402
from blendgen.frame_analysis import read_road_mask  # noqa: E402
from blendgen.job.schema import load_job  # noqa: E402
from blendgen.recording.folder import read_frame, read_recording  # noqa: E402
from blendgen.scene import planner  # noqa: E402
from blendgen.scene.ground_plane import GroundPlaneTwin  # noqa: E402
from blendgen.scene.planner import plan_sequence  # noqa: E402
from blendgen.scene.real_scene import load_real_scene  # noqa: E402

VEHICLES = ("car", "bus", "truck")
STRONG = 0.3   # lines this well covered judge the placement (the planner uses weaker ones too)


def across_line(o, T, lines) -> bool:
    x = o.position[0] - abs(o.dims[0] / 2 * np.cos(o.yaw)) - T[0, 3]  # its near end, ahead of the camera
    y = o.position[1] - T[1, 3]
    xr = float(np.clip(x, 5.0, 30.0)) - 10.0
    return any(abs(l[0] + l[1] * xr - y) < o.dims[1] / 2 - 0.15 for l in lines if l[2] >= STRONG)


def run(out: Path, job_path: Path, seeds: int) -> dict:
    job = load_job(job_path)
    rec = read_recording(job.recording_dir)
    ids = sorted(p.stem for p in (out / "analysis").glob("f*.json"))
    real = load_real_scene(out / "analysis", ids, rec.camera)
    for rf in real.frames:  # an analysis from before the lanes: find them now
        if rf is not None and not rf.fa.lane_lines:
            img = read_frame(rec, int(rf.fa.frame_id.lstrip("f")))
            road = read_road_mask(out / "analysis", rf.fa)
            rf.fa.lane_lines = lane_lines(img, None if road is None else road == 255,
                                          rec.camera.scaled(rf.fa.width, rf.fa.height),
                                          np.asarray(rf.fa.T_world_cam))[0]
    lines = {rf.fa.frame_id: list(rf.fa.lane_lines) for rf in real.frames if rf is not None}
    poses = [(rf.fa.frame_id, float(rec.frames_t[int(rf.fa.frame_id.lstrip("f"))]), np.asarray(rf.fa.T_world_cam))
             for rf in real.frames]
    twin = GroundPlaneTwin.from_job(job.ground_plane)
    variants = {"twin lanes": (False, planner.LANE_SMOOTH_S), "painted lanes": (True, planner.LANE_SMOOTH_S)}
    if job.inject.sequences:  # what the smoothing is for: each frame's lines as they are
        variants = {**variants, "painted, unsmoothed": (True, 1e-3)}
    res, smooth = {}, planner.LANE_SMOOTH_S
    for variant, (painted, planner.LANE_SMOOTH_S) in variants.items():
        for rf in real.frames:
            if rf is not None:
                rf.fa.lane_lines = lines[rf.fa.frame_id] if painted else []
        n = bad = 0
        steps = []
        t0 = time.process_time()
        for seed in range(seeds):
            tracks = {}
            for k, (p, (f, _, T)) in enumerate(zip(plan_sequence(twin, rec.camera, poses, job.inject, seed, real=real),
                                                   poses)):
                for o in p.objects:
                    if o.cls in VEHICLES:
                        n += 1
                        bad += across_line(o, T, lines[f])
                        tracks.setdefault(o.id, []).append((k, o.position[1]))
            for tr in tracks.values():  # a track's lateral step between consecutive frames
                tr = np.asarray(tr)
                steps += list(np.abs(np.diff(tr[:, 1]))[np.diff(tr[:, 0]) == 1])
        res[variant] = (n, bad, (time.process_time() - t0) / (seeds * len(poses)), np.asarray(steps) * 100)
    planner.LANE_SMOOTH_S = smooth
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("pairs", nargs="+", help="OUT JOB [OUT JOB ...]")
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--plot", type=Path, default=RESULTS / "lanes.png")
    a = ap.parse_args(argv)
    if len(a.pairs) % 2:
        ap.error("give OUT and JOB in pairs")
    rows = []
    print("| job folder | lanes | vehicles | across a painted line | share | lateral step per frame, median / p95 (cm) "
          "| plan CPU s/frame |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for out, job in zip(a.pairs[::2], a.pairs[1::2]):
        for variant, (n, bad, cpu, steps) in run(Path(out), Path(job), a.seeds).items():
            rows.append((Path(out).name, variant, n, bad))
            step = f"{np.median(steps):.1f} / {np.percentile(steps, 95):.1f}" if len(steps) else "- (stills)"
            print(f"| {Path(out).name} | {variant} | {n} | {bad} | {bad / max(n, 1):.1%} | {step} | {cpu:.3f} |",
                  flush=True)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    names = sorted({r[0] for r in rows}, key=[r[0] for r in rows].index)
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for i, variant in enumerate(("twin lanes", "painted lanes")):
        share = [next(r[3] / max(r[2], 1) for r in rows if r[0] == nm and r[1] == variant) for nm in names]
        ax.bar(np.arange(len(names)) + 0.4 * i, share, 0.4, label=variant)
    ax.set_xticks(np.arange(len(names)) + 0.2, names, fontsize=8)
    ax.set_ylabel("vehicles across a painted line")
    ax.legend()
    fig.tight_layout()
    a.plot.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.plot, dpi=100)
    print(f"wrote {a.plot}")


if __name__ == "__main__":
    main()
