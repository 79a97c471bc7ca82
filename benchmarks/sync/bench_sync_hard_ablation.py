"""Why the hard synthetic drive is hard: one of its error sources at a time (docs/sync.md,
"the hard synthetic drive").

    PYTHONPATH=$PWD nice -n 5 .venv/bin/python benchmarks/sync/bench_sync_hard_ablation.py

1. IMU + GNSS (no frames, no twin): GNSS Gauss-Markov, multipath burst, both (the lockout).
2. IMU + GNSS + twin road: HARD_IMU's parts, and the filter told the true densities, with the
   camera rotation error split into the camera's axes (x: pitch, y: yaw, z: roll).
3. Full sync (VO) + twin road: the hard frames (rolling shutter, shake, photometry), shake
   alone, HARD_IMU alone.
All on the 60 s drive of bench_sync.py; prints one line per case.
"""

from __future__ import annotations

import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen

from blendgen import so3  # noqa: E402
from blendgen.job.schema import Sync  # noqa: E402
from blendgen.recording.model import ImuNoise  # noqa: E402
from blendgen.sync.metrics import gt_poses, trajectory_errors  # noqa: E402
from blendgen.sync.pipeline import run_sync  # noqa: E402
from blendgen.sync.simulate import GEOREF, HARD_GNSS_STD, HARD_IMU, ImuErrors, synthetic_recording  # noqa: E402

DUR = 60.0
BURST = (0.4 * DUR, 0.4 * DUR + 5.0, (4.0, -6.0, 3.0))
GM = {"gm_std_m": 1.0, "gm_tau_s": 60.0}


def flat_road(pts):
    return np.zeros(len(np.atleast_2d(pts)))


def run(name, kw, *, vo=False, road=False, told=False):
    rec, traj, _ = synthetic_recording("drive", DUR, frames=vo, **kw)
    if not vo:  # poses at 5 Hz without rendering
        rec.frames_t = np.arange(0.5, 0.5 + DUR, 0.2)
        ref = [traj.pose(t) @ np.linalg.inv(rec.T_cam_imu) for t in rec.frames_t]
    else:
        ref = gt_poses(rec.groundtruth)
    if told:  # the filter told the true IMU errors (HARD_IMU's densities)
        n = ImuNoise()
        rec.imu_noise = replace(n, accelerometer_noise_density=HARD_IMU.noise_scale * n.accelerometer_noise_density,
                                gyroscope_noise_density=HARD_IMU.noise_scale * n.gyroscope_noise_density,
                                accelerometer_random_walk=HARD_IMU.acc_walk, gyroscope_random_walk=HARD_IMU.gyro_walk)
    if road:
        rec.extra["vehicle"] = {"camera_height_m": 1.5}
    with tempfile.TemporaryDirectory() as d:
        res = run_sync(rec, Sync(use_vo=vo), Path(d), georef=GEOREF, progress=False,
                       road_surface=flat_road if road else None)
    est = [p[2] for p in res.poses]
    a = trajectory_errors(est, ref)
    e = np.degrees(np.abs([so3.log(g[:3, :3].T @ x[:3, :3]) for g, x in zip(ref, est)]))
    print(f"  {name:48s} ATE {a['ate_rmse_m']:.3f} m horiz {a['ate_h_rmse_m']:.3f} rot {a['rot_median_deg']:.3f} deg "
          f"(cam x/y/z {np.median(e[:, 0]):.2f}/{np.median(e[:, 1]):.2f}/{np.median(e[:, 2]):.2f}) "
          f"RPE {a['rpe_rmse_m']:.3f} rejected {res.summary.get('rejected')}", flush=True)


def main() -> None:
    print("1. IMU + GNSS, no twin")
    for name, kw in (("easy", {}), ("GNSS Gauss-Markov", {"gnss_std": HARD_GNSS_STD, "gnss_errors": GM}),
                     ("GNSS burst", {"gnss_errors": {"burst": BURST}}),
                     ("GNSS Gauss-Markov + burst", {"gnss_std": HARD_GNSS_STD, "gnss_errors": {**GM, "burst": BURST}})):
        run(name, kw)
    print("2. IMU + GNSS + twin road")
    for name, kw, told in (("HARD_IMU", {"imu_errors": HARD_IMU}, False),
                           ("HARD_IMU, filter told the true densities", {"imu_errors": HARD_IMU}, True),
                           ("accelerometer walk only", {"imu_errors": ImuErrors(acc_walk=HARD_IMU.acc_walk)}, False),
                           ("gyro walk only", {"imu_errors": ImuErrors(gyro_walk=HARD_IMU.gyro_walk)}, False),
                           ("white noise 2.5x only", {"imu_errors": ImuErrors(noise_scale=2.5)}, False)):
        run(name, kw, road=True, told=told)
    print("3. full sync (VO) + twin road")
    for name, kw in (("hard frames (rolling shutter, shake, photometry)",
                      {"rolling_shutter_s": 0.03, "shake_deg": 0.3, "photometric": True}),
                     ("shake only", {"shake_deg": 0.3}), ("HARD_IMU only", {"imu_errors": HARD_IMU})):
        run(name, kw, vo=True, road=True)


if __name__ == "__main__":
    main()
