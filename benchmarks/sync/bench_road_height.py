"""Road-height constraint (issue 14 "Height"): the 60 s synthetic drive of bench_sync.py with and
without the twin's road surface, and comma2k19 (no twin: must be unchanged).

    PYTHONPATH=$PWD nice -n 5 .venv/bin/python benchmarks/sync/bench_road_height.py [--quick]

Synthetic: 480x270 frames at 5 fps through the textured street (road = the plane z = 0), IMU
200 Hz, GNSS 10 Hz with 1 m horizontal / 1.5 m vertical noise; camera 1.5 m above the road.
Variants: no twin (today's default), twin road + calib.yaml `vehicle.camera_height_m: 1.5`,
twin road with the antenna height estimated from the fixes. Prints ATE (3-D and horizontal),
height error, median rotation error and the reprojection of a point 20 m ahead at 1280x720
(absolute, and after a 4-DoF alignment), CPU seconds per run (the machine is shared).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import REAL  # noqa: E402

from blendgen.job.schema import Sync  # noqa: E402
from blendgen.sync.metrics import comma_errors, gt_poses, trajectory_errors  # noqa: E402
from blendgen.sync.pipeline import run_sync  # noqa: E402
from blendgen.sync.simulate import GEOREF, StreetScene, synthetic_recording  # noqa: E402


def flat_road(pts):
    """The simulated street's road surface: z = 0 everywhere."""
    return np.zeros(len(np.atleast_2d(pts)))


def synthetic(quick: bool) -> None:
    import cv2

    cv2.setNumThreads(1)
    dur = 20.0 if quick else 60.0
    rec, _, _ = synthetic_recording("drive", dur, scene=StreetScene())
    ref = gt_poses(rec.groundtruth)
    cam720 = rec.camera.scaled(1280, 720)
    print(f"synthetic drive {dur:.0f} s, {rec.n_frames} frames")
    for name, surface, vehicle in (("no twin (GNSS heights)", None, None),
                                   ("twin road + camera_height_m", flat_road, {"camera_height_m": 1.5}),
                                   ("twin road, antenna height estimated", flat_road, None)):
        rec.extra.pop("vehicle", None)
        if vehicle:
            rec.extra["vehicle"] = vehicle
        c0 = time.process_time()
        with tempfile.TemporaryDirectory() as d:
            res = run_sync(rec, Sync(), Path(d), georef=GEOREF, progress=False, road_surface=surface)
        cpu = time.process_time() - c0
        est = [p[2] for p in res.poses]
        a = trajectory_errors(est, ref, camera=cam720)
        y = trajectory_errors(est, ref, align="yaw", camera=cam720)
        dz = np.array([e[2, 3] - g[2, 3] for e, g in zip(est, ref)])
        print(f"  {name:38s} ATE {a['ate_rmse_m']:.3f} m (horiz {a['ate_h_rmse_m']:.3f})  "
              f"z {dz.mean():+.3f} +- {dz.std():.3f} m  rot {a['rot_median_deg']:.3f} deg  "
              f"px {a['reproj_median_px']:.2f} (aligned {y['reproj_median_px']:.2f})  CPU {cpu:.1f} s  "
              f"road {res.summary.get('road_height')}")


def comma() -> None:
    seg = REAL / "comma2k19_example1_segment40"
    if not seg.exists():
        print("  comma2k19 not found: skipped")
        return
    from blendgen.analysis.lane_direction import still_camera_yaw
    from blendgen.recording.folder import read_recording
    from blendgen.recording.importers.comma2k19 import groundtruth_georef, import_comma2k19

    with tempfile.TemporaryDirectory() as d:
        rec = read_recording(import_comma2k19(seg, Path(d) / "rec", camera_yaw=still_camera_yaw, show_progress=False))
        georef = groundtruth_georef(rec)
        c0 = time.process_time()
        res = run_sync(rec, Sync(), Path(d) / "out", georef=georef, progress=False)
        e = comma_errors(res, rec, georef)["sync"]
    print(f"comma2k19 (no twin) CPU {time.process_time() - c0:.1f} s: rot3d {e['rot3d_median_deg']:.3f} deg, "
          f"pitch {e['pitch_median_deg']:.3f} deg, horizontal raw {e['h_rmse_raw_m']:.3f} m / offset removed "
          f"{e['h_rmse_m']:.3f} m, rel 1 s {e['rel_1s_median_m']:.3f} m")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="20 s drive")
    args = ap.parse_args()
    synthetic(args.quick)
    comma()


if __name__ == "__main__":
    main()
