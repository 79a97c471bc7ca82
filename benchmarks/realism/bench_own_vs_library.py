"""Hand-written pieces vs the libraries that do the same (issue 16): agreement and time.

    .venv/bin/python benchmarks/realism/bench_own_vs_library.py

- detection AP: blendgen.detection.metrics.evaluate vs pycocotools' COCOeval (same detections);
- ATE / RPE: blendgen.sync.metrics.trajectory_errors vs evo (APE / RPE, SE(3) alignment);
- SO(3): blendgen.so3.exp/log vs scipy.spatial.transform.Rotation, one call at a time
  (the error-state filter calls them once per IMU sample);
- MP4 boxes: blendgen.recording.importers.mp4 reads the GoPro GPMF track (no dependency in
  blendgen's list reads data tracks: OpenCV decodes only video).

Times are CPU seconds (time.process_time) on the shared 2-core machine; ratios are measured in
the same run. Prints a table and writes docs/benchmarks/own_vs_library.md and
benchmarks/results/own_vs_library.png.
"""

from __future__ import annotations

import contextlib
import io
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import RESULTS, ROOT, SHARED_DATA, write_doc  # noqa: E402
sys.path.insert(0, str(ROOT / "tests"))

from blendgen import CLASSES  # noqa: E402


def cpu(fn, repeat=1):
    t = time.process_time()
    for _ in range(repeat):
        out = fn()
    return (time.process_time() - t) / repeat, out


def bench_ap():
    from test_realism import CATS, _cocoeval, _fixture

    from blendgen.detection.metrics import evaluate

    gts, dts = _fixture(3, n_images=400)
    t_ours, ours = cpu(lambda: evaluate(gts, dts, CATS))
    t_lib, ev = cpu(lambda: _cocoeval(gts, dts))
    diffs = []
    for k, c in enumerate(ev.params.catIds):
        prec = ev.eval["precision"][0, :, k, 0, -1]
        if (prec > -1).any() and ours[c]["ap"] is not None:
            diffs.append(abs(float(prec[prec > -1].mean()) - ours[c]["ap"]))
    return {"piece": "detection AP@0.5 (400 images, %d gts, %d dets)" % (len(gts), len(dts)),
            "ours_s": t_ours, "lib_s": t_lib, "max_abs_diff": max(diffs), "lib": "pycocotools COCOeval"}


def _traj(n=400, seed=0):
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.1
    pos = np.column_stack([8 * t, 3 * np.sin(t / 3), 0.1 * np.sin(t)])
    R = Rotation.from_euler("zyx", np.column_stack([t / 5, 0.02 * np.sin(t), 0.01 * np.cos(t)]))
    gt = [np.block([[r, p[:, None]], [np.zeros((1, 3)), 1.0]]) for r, p in zip(R.as_matrix(), pos)]
    noise = Rotation.from_rotvec(rng.normal(0, 0.01, (n, 3))).as_matrix()
    est = [np.block([[g[:3, :3] @ q, (g[:3, 3] + rng.normal(0, 0.3, 3))[:, None]], [np.zeros((1, 3)), 1.0]])
           for g, q in zip(gt, noise)]
    # est lives in another frame: rotate and shift it
    Ra = Rotation.from_euler("z", 0.4).as_matrix()
    est = [np.block([[Ra @ T[:3, :3], (Ra @ T[:3, 3] + [5, -2, 0.3])[:, None]], [np.zeros((1, 3)), 1.0]])
           for T in est]
    return t, est, gt


def evo_ate_rpe(est, gt, t) -> tuple[float, float]:
    """evo's SE(3)-aligned APE and 1-frame RPE (translation RMSE, m): the reference for ours."""
    from evo.core import metrics
    from evo.core.trajectory import PoseTrajectory3D

    e = PoseTrajectory3D(poses_se3=[T.copy() for T in est], timestamps=t)
    g = PoseTrajectory3D(poses_se3=[T.copy() for T in gt], timestamps=t)
    e.align(g, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((g, e))
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=1, delta_unit=metrics.Unit.frames,
                      all_pairs=False)
    rpe.process_data((g, e))
    return ape.get_statistic(metrics.StatisticsType.rmse), rpe.get_statistic(metrics.StatisticsType.rmse)


def bench_ate():
    from blendgen.sync.metrics import trajectory_errors

    t, est, gt = _traj()
    t_ours, ours = cpu(lambda: trajectory_errors(est, gt, align="se3"), 5)
    t_lib, (ate, rpe) = cpu(lambda: evo_ate_rpe(est, gt, t), 5)
    return {"piece": "ATE + RPE, SE(3)-aligned (400 poses)", "ours_s": t_ours, "lib_s": t_lib,
            "max_abs_diff": max(abs(ate - ours["ate_rmse_m"]), abs(rpe - ours["rpe_rmse_m"])),
            "lib": "evo APE/RPE", "extra": f"ATE {ours['ate_rmse_m']:.4f} vs {ate:.4f} m"}


def bench_so3():
    from scipy.spatial.transform import Rotation

    from blendgen import so3

    rng = np.random.default_rng(1)
    ws = np.concatenate([rng.normal(0, 1, (3000, 3)), rng.normal(0, 1e-9, (500, 3)),
                         (np.pi - 1e-6) * rng.normal(0, 1, (500, 3)) / 1.0])
    ws[-500:] /= np.linalg.norm(ws[-500:], axis=1, keepdims=True) / (np.pi - 1e-6)
    t_ours, Rs = cpu(lambda: [so3.exp(w) for w in ws])
    t_lib, Rl = cpu(lambda: [Rotation.from_rotvec(w).as_matrix() for w in ws])
    d_exp = max(np.abs(a - b).max() for a, b in zip(Rs, Rl))
    t_log, ls = cpu(lambda: [so3.log(R) for R in Rs])
    t_llog, ll = cpu(lambda: [Rotation.from_matrix(R).as_rotvec() for R in Rs])
    d_log = max(np.abs(a - b).max() for a, b in zip(ls, ll))
    n = len(ws)
    return {"piece": f"SO(3) exp + log, one call at a time ({n} each)", "ours_s": t_ours + t_log,
            "lib_s": t_lib + t_llog, "max_abs_diff": max(d_exp, d_log), "lib": "scipy Rotation",
            "extra": f"per call: ours {1e6 * (t_ours + t_log) / (2 * n):.1f} us, scipy "
                     f"{1e6 * (t_lib + t_llog) / (2 * n):.1f} us"}


def bench_mp4():
    from blendgen.recording.importers import mp4

    found = [p / "real" / "gopro_karma.mp4" for p in (SHARED_DATA,)]
    found = [p for p in found if p.exists()]
    if not found:
        return None
    path = found[0]
    t, tracks = cpu(lambda: mp4.read_tracks(path))
    return {"piece": f"MP4 box reader: tracks of {path.name} ({path.stat().st_size / 2**20:.0f} MB)",
            "ours_s": t, "lib_s": float("nan"), "max_abs_diff": float("nan"),
            "lib": "none in the dependencies (OpenCV decodes video only)", "extra": f"{len(tracks)} tracks: " + ", ".join(f"{tr.handler}/{tr.codec} {tr.n_samples}" for tr in tracks)}


def main():
    rows = [r for r in (bench_ap(), bench_ate(), bench_so3(), bench_mp4()) if r]
    head = "| piece | library | ours (CPU s) | library (CPU s) | library / ours | max abs difference | note |"
    lines = [head, "|---|---|---:|---:|---:|---:|---|"]
    for r in rows:
        ratio = r["lib_s"] / r["ours_s"] if r["ours_s"] > 0 else float("nan")
        lines.append(f"| {r['piece']} | {r['lib']} | {r['ours_s']:.4f} | {r['lib_s']:.4f} | {ratio:.2f} | "
                     f"{r['max_abs_diff']:.2e} | {r.get('extra', '')} |")
    table = "\n".join(lines)
    print(table)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rs = [r for r in rows if np.isfinite(r["lib_s"])]
    fig, ax = plt.subplots(figsize=(7, 2.8))
    y = np.arange(len(rs))
    ax.barh(y - 0.2, [r["ours_s"] for r in rs], 0.4, label="blendgen")
    ax.barh(y + 0.2, [r["lib_s"] for r in rs], 0.4, label="library")
    ax.set_yticks(y, [r["piece"].split(" (")[0] for r in rs]), ax.set_xscale("log")
    ax.set_xlabel("CPU seconds"), ax.legend()
    fig.tight_layout()
    RESULTS.mkdir(parents=True, exist_ok=True)
    fig.savefig(RESULTS / "own_vs_library.png", dpi=100)
    doc = ("# Hand-written pieces vs libraries\n\n`.venv/bin/python benchmarks/realism/bench_own_vs_library.py` "
           "(CPU seconds on the shared 2-core machine; ratios from the same run).\n\n" + table + "\n\n"
           "![own vs library](../../benchmarks/results/own_vs_library.png)\n")
    write_doc("own_vs_library.md", doc)


if __name__ == "__main__":
    main()
