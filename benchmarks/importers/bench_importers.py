"""Importer benchmark: conversion time per format, then sync on the imported real recordings.

    .venv/bin/python benchmarks/importers/bench_importers.py [--quick]

Part 1 times every importer (median of repeats) on fixtures built by the tests (video, EuRoC,
KITTI, ROS 1/2 bags) and on the shared real files (comma2k19, GoPro Karma).
Part 2 runs `blendgen.sync.pipeline.run_sync` (default job `sync:` settings) on the imported
comma2k19 and GoPro recordings, compares comma2k19 with its ground truth, and draws the
trajectories into docs/images/import_comma2k19.png and docs/images/import_gopro.png.
Writes benchmarks/results/importers.png and docs/benchmarks/importers.md.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import REAL, RESULTS, ROOT, write_doc  # noqa: E402
sys.path.insert(0, str(ROOT / "tests"))

from blendgen.analysis.lane_direction import still_camera_yaw  # noqa: E402
from blendgen.recording.folder import read_recording  # noqa: E402
from blendgen.recording.importers import import_recording  # noqa: E402


def fixtures(tmp: Path, quick: bool) -> list[tuple[str, str, Path, dict, str]]:
    from test_import_euroc_kitti import make_euroc, make_kitti
    from test_import_video import make_video

    n = 60 if quick else 300
    out = []
    make_video(tmp / "clip.mp4", n=n, fps=30.0, size=(640, 360))
    out.append(("video mp4", "video", tmp / "clip.mp4", {}, f"{n} frames 640x360"))
    make_video(tmp / "clip.avi", n=n, fps=30.0, size=(640, 360), fourcc="MJPG")
    out.append(("video avi", "video", tmp / "clip.avi", {}, f"{n} frames 640x360 (OpenCV timestamps)"))
    out.append(("euroc", "euroc", make_euroc(tmp / "euroc", n_img=n, n_imu=10 * n), {},
                f"{n} images, {10 * n} IMU rows"))
    out.append(("kitti raw", "kitti", make_kitti(tmp / "kitti", n=n // 3), {}, f"{n // 3} frames 1242x375 + OXTS"))
    try:
        from test_import_rosbag import write_bag

        out.append(("rosbag ROS1", "rosbag", write_bag(tmp / "b.bag", 1), {}, "5 Image, 60 Imu, 4 NavSatFix"))
        out.append(("rosbag ROS2", "rosbag", write_bag(tmp / "b2", 2), {}, "5 Image, 60 Imu, 4 NavSatFix"))
    except ImportError:
        pass
    if (REAL / "comma2k19_example1_segment40").exists():
        out.append(("comma2k19", "comma2k19", REAL / "comma2k19_example1_segment40",
                    {"camera_yaw": still_camera_yaw}, "real, 60 s"))  # as `blendgen import`
    if (REAL / "gopro_karma.mp4").exists():
        out.append(("gopro", "gopro", REAL / "gopro_karma.mp4", {}, "real, 12 s, 362 frames"))
    return out


def time_imports(cases, tmp: Path, repeats: int) -> list[dict]:
    rows = []
    for label, fmt, src, opts, what in cases:
        times = []
        for r in range(repeats):
            dst = tmp / f"out_{fmt}_{label.replace(' ', '_')}_{r}"
            t = time.perf_counter()
            import_recording(fmt, src, dst, show_progress=False, **opts)
            times.append(time.perf_counter() - t)
            rec = read_recording(dst)
            if r < repeats - 1:
                shutil.rmtree(dst)
        rows.append({"label": label, "what": what, "median_s": statistics.median(times),
                     "frames": rec.n_frames, "imu": len(rec.imu), "gnss": len(rec.gnss), "dst": dst})
    return rows


def sync_real(rows, quick: bool) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from pymap3d import geodetic2enu

    from blendgen.job.schema import Sync
    from blendgen.sync.pipeline import run_sync

    results = {}
    for row in rows:
        if row["label"] not in ("comma2k19", "gopro") or (quick and row["label"] == "gopro"):
            continue
        rec = read_recording(row["dst"])
        origin = (rec.extra.get("import") or {}).get("groundtruth_origin")
        georef = (origin["lat"], origin["lon"], origin["alt"]) if origin else tuple(rec.gnss[0, 1:4])
        t = time.perf_counter()
        res = run_sync(rec, Sync(), row["dst"] / "sync", georef=georef, progress=False)
        secs = time.perf_counter() - t
        P, tt = res.positions(), res.times
        e, n, u = geodetic2enu(rec.gnss[:, 1], rec.gnss[:, 2], rec.gnss[:, 3], *georef)
        info = {"seconds": secs, "poses": len(P), "summary": res.summary}
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.6))
        ax = axes[0]
        ax.plot(e, n, ".", ms=3, color="tab:orange", label="GNSS fixes (imported gnss.csv)")
        if rec.groundtruth is not None:
            gt = rec.groundtruth
            ax.plot(gt[:, 1], gt[:, 2], "-", color="k", lw=1.2, label="ground truth (groundtruth.csv)")
            ref = np.column_stack([np.interp(tt, gt[:, 0], gt[:, k]) for k in (1, 2, 3)])
            h = np.hypot(*(P[:, :2] - ref[:, :2]).T)
            v = P[:, 2] - ref[:, 2]
            ge, gn = np.interp(rec.gnss[:, 0], gt[:, 0], gt[:, 1]), np.interp(rec.gnss[:, 0], gt[:, 0], gt[:, 2])
            hg = np.hypot(e - ge, n - gn)
            info.update(h_med=float(np.median(h)), h_p95=float(np.percentile(h, 95)), h_max=float(h.max()),
                        v_med=float(np.median(v)), gnss_h_med=float(np.median(hg)),
                        gnss_h_p95=float(np.percentile(hg, 95)))
            axes[1].plot(tt - tt[0], h, label="sync horizontal error")
            axes[1].plot(rec.gnss[:, 0] - tt[0], hg, ".", ms=3, label="raw GNSS horizontal error")
            axes[1].plot(tt - tt[0], v, label="sync vertical error (z - gt z)")
            axes[1].set_ylabel("error (m)")
            axes[1].set_title("error against ground truth")
        else:
            axes[1].plot(tt - tt[0], P[:, 2], label="sync z (m)")
            axes[1].plot(rec.gnss[:, 0] - tt[0], u, ".", ms=3, label="GNSS up (m)")
            axes[1].set_title("height (no ground truth in this recording)")
        ax.plot(P[:, 0], P[:, 1], "-", color="tab:blue", lw=1.2, label="blendgen sync (poses.csv)")
        ax.set_aspect("equal", "datalim")
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
        ax.set_title(f"{row['label']}: imported and synced trajectory")
        ax.legend(fontsize=8)
        axes[1].set_xlabel("time (s)")
        axes[1].legend(fontsize=8)
        fig.tight_layout()
        out = ROOT / "docs" / "images" / f"import_{row['label']}.png"
        fig.savefig(out, dpi=110)
        plt.close(fig)
        info["plot"] = str(out.relative_to(ROOT))
        results[row["label"]] = info
    return results


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="small fixtures, 1 repeat, no GoPro sync")
    args = ap.parse_args()
    repeats = 1 if args.quick else 3
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        rows = time_imports(fixtures(tmp, args.quick), tmp, repeats)
        print(f"{'format':14s} {'input':38s} {'median s':>9s} {'frames':>7s} {'imu':>6s} {'gnss':>5s}")
        for r in rows:
            print(f"{r['label']:14s} {r['what']:38s} {r['median_s']:9.3f} {r['frames']:7d} {r['imu']:6d} {r['gnss']:5d}")
        syncs = sync_real(rows, args.quick)
    for k, s in syncs.items():
        extra = (f", horizontal error median {s['h_med']:.2f} m (p95 {s['h_p95']:.2f}), raw GNSS {s['gnss_h_med']:.2f} m, "
                 f"vertical offset {s['v_med']:.1f} m") if "h_med" in s else ""
        print(f"sync {k}: {s['poses']} poses in {s['seconds']:.1f} s{extra}")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.barh([r["label"] for r in rows], [r["median_s"] for r in rows], color="tab:blue")
    ax.set_xlabel("import time, median (s)")
    ax.set_title("blendgen import: conversion time per format")
    fig.tight_layout()
    RESULTS.mkdir(parents=True, exist_ok=True)
    fig.savefig(RESULTS / "importers.png", dpi=110)
    plt.close(fig)

    from blendgen import atomic

    cmd = "nice -n 5 .venv/bin/python benchmarks/importers/bench_importers.py" + (" --quick" if args.quick else "")
    lines = ["# Importer benchmark", "", f"Produced by `{cmd}` (2 shared CPU cores; medians of "
             f"{repeats} run(s); timings are noisy).", "",
             "| format | input | median import time (s) | frames | IMU rows | GNSS rows |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['label']} | {r['what']} | {r['median_s']:.3f} | {r['frames']} | {r['imu']} | {r['gnss']} |"
              for r in rows]
    lines += ["", "## Sync on imported real recordings (default `sync:` settings)", "",
              "| recording | poses | sync time (s) | sync horizontal error median / p95 (m) | raw GNSS horizontal "
              "error median (m) | sync vertical offset median (m) |", "|---|---|---|---|---|---|"]
    for k, s in syncs.items():
        if "h_med" in s:
            lines.append(f"| {k} | {s['poses']} | {s['seconds']:.1f} | {s['h_med']:.2f} / {s['h_p95']:.2f} | "
                         f"{s['gnss_h_med']:.2f} | {s['v_med']:.1f} |")
        else:
            lines.append(f"| {k} | {s['poses']} | {s['seconds']:.1f} | no ground truth | - | - |")
    lines += ["", "![import times](../../benchmarks/results/importers.png)", ""]
    write_doc("importers.md", "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
