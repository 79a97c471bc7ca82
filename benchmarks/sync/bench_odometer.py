"""The vehicle's odometer (CAN speed, speed.csv) in sync: with and without it, over noise seeds.

    PYTHONPATH=$PWD nice -n 5 .venv/bin/python benchmarks/sync/bench_odometer.py [--seeds 0,1,...] [--frames 0,1,2,3]

1. The 60 s synthetic drive of bench_sync.py, IMU + GNSS (no frames, no twin), per noise seed,
   with a simulated CAN speed 2 % low, 50 ms early, 0.03 m/s noise, 0.01 m/s steps at 100 Hz:
   the camera position's horizontal RMSE and the median rotation error against the truth,
   and the odometer scale and latency the filter found.
2. `--frames`: the same drive with its rendered frames (VO), the twin's road and
   `camera_height_m` (the issue-14 setting), a CAN speed 1 % low and 40 ms early: 3-D ATE,
   median rotation error and its mean per camera axis (~2 CPU-min per seed).

Prints the tables and writes benchmarks/results/odometer.png and docs/benchmarks/odometer.md.
comma2k19 with and without its CAN speed, and the GTSAM peer given the same readings:
`bench_sync.py --section comma`; the easy and hard drives: `bench_sync.py --section hard`.
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import RESULTS, write_doc  # noqa: E402

from blendgen import so3  # noqa: E402
from blendgen.job.schema import Sync  # noqa: E402
from blendgen.sync.metrics import gt_poses  # noqa: E402
from blendgen.sync.pipeline import run_sync  # noqa: E402
from blendgen.sync.simulate import GEOREF, StreetScene, simulate_odometer, synthetic_recording  # noqa: E402
from blendgen.sync.threads import single_thread_blas  # noqa: E402

ODO_PLAIN = {"scale": 0.98, "latency_s": -0.05}
ODO_FRAMES = {"scale": 0.99, "latency_s": -0.04, "noise_mps": 0.03}


def _sync(rec, **kw):
    c0 = time.process_time()
    with tempfile.TemporaryDirectory() as d, single_thread_blas():
        res = run_sync(rec, Sync(use_speed=True), Path(d), georef=GEOREF, progress=False, **kw)
    return res, time.process_time() - c0


def plain(seeds: list[int]) -> list[dict]:
    rows = []
    for seed in seeds:
        row = {"seed": seed}
        for key, odo in (("without", None), ("with", ODO_PLAIN)):
            rec, traj, T_cam_imu = synthetic_recording("drive", 60.0, frames=False, seed=seed, odometer=odo)
            res, cpu = _sync(rec)
            T_bc = np.linalg.inv(T_cam_imu)
            e, r = [], []
            for _, t, T_wc in res.poses:
                T_true = traj.pose(t) @ T_bc
                e.append(T_wc[:2, 3] - T_true[:2, 3])
                r.append(np.degrees(np.linalg.norm(so3.log(T_true[:3, :3].T @ T_wc[:3, :3]))))
            row[key] = {"h": float(np.sqrt(np.mean(np.sum(np.square(e), axis=1)))), "rot": float(np.median(r)),
                        "cpu": cpu, "cal": res.summary["calibration"]}
        c = row["with"]["cal"]
        print(f"  seed {seed}: h. RMSE {row['without']['h']:.3f} -> {row['with']['h']:.3f} m, rotation "
              f"{row['without']['rot']:.3f} -> {row['with']['rot']:.3f} deg, odometer latency "
              f"{c['speed_latency_s']:+.3f} +- {c['speed_latency_std_s']:.3f} s (truth {ODO_PLAIN['latency_s']:+.3f}), "
              f"scale {c['speed_scale']:.4f} (truth {1 / ODO_PLAIN['scale']:.4f}), CPU "
              f"{row['without']['cpu']:.1f} / {row['with']['cpu']:.1f} s", flush=True)
        rows.append(row)
    return rows


def with_frames(seeds: list[int]) -> list[dict]:
    import cv2

    cv2.setNumThreads(1)
    rows = []
    for seed in seeds:
        rec, traj, _ = synthetic_recording("drive", 60.0, scene=StreetScene(), seed=seed)
        rec.extra["vehicle"] = {"camera_height_m": 1.5}
        ref = gt_poses(rec.groundtruth)
        row = {"seed": seed}
        for key, speed in (("without", np.zeros((0, 2))), ("with", simulate_odometer(traj, seed=seed, **ODO_FRAMES))):
            r = copy.copy(rec)
            r.speed = speed
            res, cpu = _sync(r, road_surface=lambda p: np.zeros(len(np.atleast_2d(p))))
            est = [p[2] for p in res.poses]
            err = np.array([so3.log(g[:3, :3].T @ q[:3, :3]) for q, g in zip(est, ref)])
            dp = np.array([q[:3, 3] - g[:3, 3] for q, g in zip(est, ref)])
            row[key] = {"ate": float(np.sqrt(np.mean(np.sum(dp**2, axis=1)))),
                        "rot": float(np.degrees(np.median(np.linalg.norm(err, axis=1)))),
                        "axis_mean": np.degrees(err.mean(axis=0)).round(3).tolist(), "cpu": cpu}
        print(f"  seed {seed} (frames, twin road): ATE {row['without']['ate']:.4f} -> {row['with']['ate']:.4f} m, "
              f"rotation {row['without']['rot']:.3f} -> {row['with']['rot']:.3f} deg (mean per camera axis x, y, z: "
              f"{row['without']['axis_mean']} -> {row['with']['axis_mean']})", flush=True)
        rows.append(row)
    return rows


def write(plain_rows, frame_rows, argv: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    md = ["# Odometer (CAN speed) in sync", "", f"`PYTHONPATH=$PWD nice -n 5 .venv/bin/python benchmarks/sync/bench_odometer.py{argv}`"
          " (one run, shared 2-core machine).", "",
          "IMU + GNSS, 60 s drive, CAN speed 2 % low and 50 ms early:", "",
          "| seed | h. RMSE without -> with (m) | rotation without -> with (deg) | latency found (s) | scale found |",
          "|---|---|---|---|---|"]
    for r in plain_rows:
        c = r["with"]["cal"]
        md.append(f"| {r['seed']} | {r['without']['h']:.3f} -> {r['with']['h']:.3f} | {r['without']['rot']:.3f} -> "
                  f"{r['with']['rot']:.3f} | {c['speed_latency_s']:+.3f} +- {c['speed_latency_std_s']:.3f} | "
                  f"{c['speed_scale']:.4f} |")
    if plain_rows:
        m = {k: [np.mean([r[w][k] for r in plain_rows]) for w in ("without", "with")] for k in ("h", "rot")}
        md.append(f"| mean | {m['h'][0]:.3f} -> {m['h'][1]:.3f} | {m['rot'][0]:.3f} -> {m['rot'][1]:.3f} | | |")
    if frame_rows:
        md += ["", "With frames (VO), the twin's road and camera_height_m, CAN speed 1 % low and 40 ms early:", "",
               "| seed | 3-D ATE without -> with (m) | rotation without -> with (deg) |", "|---|---|---|"]
        md += [f"| {r['seed']} | {r['without']['ate']:.4f} -> {r['with']['ate']:.4f} | {r['without']['rot']:.3f} -> "
               f"{r['with']['rot']:.3f} |" for r in frame_rows]
    write_doc("odometer.md", "\n".join(md) + "\n")
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.5))
    for a, k, label in ((ax[0], "h", "horizontal RMSE (m)"), (ax[1], "rot", "rotation median (deg)")):
        x = np.arange(len(plain_rows))
        a.bar(x - 0.2, [r["without"][k] for r in plain_rows], 0.4, label="IMU + GNSS")
        a.bar(x + 0.2, [r["with"][k] for r in plain_rows], 0.4, label="+ odometer")
        a.set_xticks(x, [str(r["seed"]) for r in plain_rows])
        a.set_xlabel("noise seed")
        a.set_ylabel(label)
    ax[0].legend()
    fig.suptitle("60 s synthetic drive: sync with and without the car's CAN speed")
    fig.tight_layout()
    out = RESULTS / "odometer.png"
    out.parent.mkdir(exist_ok=True)
    fig.savefig(out, dpi=100)
    print(f"wrote {out} and docs/benchmarks/odometer.md")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1,2,3,4,5,6,7", help="noise seeds of the IMU + GNSS runs ('' for none)")
    ap.add_argument("--frames", default="", help="noise seeds of the runs with frames and twin road (e.g. 0,1,2,3)")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    frames = [int(s) for s in args.frames.split(",") if s.strip()]
    plain_rows = plain(seeds)
    frame_rows = with_frames(frames)
    argv = "".join(f" --{k} {v}" for k, v in (("seeds", args.seeds), ("frames", args.frames)) if v)
    write(plain_rows, frame_rows, argv)


if __name__ == "__main__":
    main()
