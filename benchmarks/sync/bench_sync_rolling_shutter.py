"""Rolling-shutter correction of VO in the full sync (docs/sync.md, "Rolling shutter").

    PYTHONPATH=$PWD nice -n 5 .venv/bin/python benchmarks/sync/bench_sync_rolling_shutter.py \
        [--case rs|hard|easy] [--fps 10] [--seed 0] [--spins off,table] [--assumed 0.02,0.04]

rs: the 60 s drive of bench_sync.py with each frame's rows read out over 30 ms (calib
`camera.rolling_shutter_s`), 0.3 deg shake and real-camera photometry; hard: bench_sync's hard
drive (the same readout, plus IMU and GNSS errors the filter does not assume); easy: global
shutter. The frames are rendered once, then synced (full, twin road + camera height) with the
correction off (readout 0 given to the sync), with one angular velocity per frame ("constant",
the first attempt, reverted), with the gyro integrated over the readout ("table",
`pipeline._rs_spins`, what the sync does) and with the readout estimated ("auto", calib
`rolling_shutter_s: auto`, `blendgen.sync.readout`); `--assumed` adds "table" rows with a wrong readout
in the calibration. Prints the camera rotation error (median, and per camera axis: x pitch, y
yaw, z roll), ATE, the 20 m point's reprojection, rejected measurements, and the per-pair VO
rotation error and least-squares gain against the truth.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen

from blendgen import so3  # noqa: E402
from blendgen.job.schema import Sync  # noqa: E402
from blendgen.sync import pipeline  # noqa: E402
from blendgen.sync.metrics import gt_poses, trajectory_errors  # noqa: E402
from blendgen.sync.simulate import GEOREF, StreetScene, hard_recording, synthetic_recording  # noqa: E402

_TABLE = pipeline._rs_spins


def _constant_rate(imu, t_frames, readout_s, R_bc, knots=16):
    """The reverted correction: one angular velocity per frame (its readout's mean), as a table."""
    tab = _TABLE(imu, t_frames, readout_s, R_bc, knots)
    if tab is None:
        return None
    return tab[:, -1:, :] * np.linspace(0.0, 1.0, knots)[None, :, None]


def flat_road(pts):
    return np.zeros(len(np.atleast_2d(pts)))


def _vo_pairs(res_vo, ref):
    """Per-pair VO rotation error against the truth: median (deg), least-squares gain per axis."""
    V, T = [], []
    for i in range(1, len(ref)):
        r = res_vo.get(i)
        if r is None or r.status not in ("ok", "rotation"):
            continue
        V.append(so3.log(r.R_c1c2))
        T.append(so3.log(ref[i - 1][:3, :3].T @ ref[i][:3, :3]))
    V, T = np.array(V), np.array(T)
    E = np.array([so3.log(so3.exp(t).T @ so3.exp(v)) for v, t in zip(V, T)])
    return np.degrees(np.median(np.linalg.norm(E, axis=1))), (V * T).sum(0) / (T * T).sum(0)


def run(name, rec, ref, spins: str, readout_s: float):
    """One sync with the correction `spins` (off | constant | table) and `readout_s` in the calib."""
    true_readout = rec.rolling_shutter_s
    rec.rolling_shutter_s = 0.0 if spins in ("off", "auto") else readout_s
    rec.rolling_shutter_estimate = spins == "auto"  # calib `rolling_shutter_s: auto`
    pipeline._rs_spins = _constant_rate if spins == "constant" else _TABLE
    cache = {}
    orig = pipeline._vo_all

    def _vo_all(*a, **k):  # keep the VO results, to measure the pairs the filter was given
        orig(*a, **k)
        cache.update(a[3])

    pipeline._vo_all = _vo_all
    rec.extra["vehicle"] = {"camera_height_m": 1.5}
    c0 = time.process_time()
    try:
        with tempfile.TemporaryDirectory() as d:
            res = pipeline.run_sync(rec, Sync(), Path(d), georef=GEOREF, progress=False, road_surface=flat_road)
    finally:
        pipeline._vo_all, pipeline._rs_spins, rec.rolling_shutter_s = orig, _TABLE, true_readout
        rec.rolling_shutter_estimate = False
    cpu = time.process_time() - c0
    est = [p[2] for p in res.poses]
    a = trajectory_errors(est, ref, camera=rec.camera.scaled(1280, 720))
    e = np.degrees(np.abs([so3.log(g[:3, :3].T @ x[:3, :3]) for g, x in zip(ref, est)]))
    verr, gain = _vo_pairs(cache, ref)
    ro = res.summary.get("rolling_shutter")
    if ro:
        name += f" ({ro['readout_s'] * 1e3:.1f} +- {(ro['std_s'] or 0) * 1e3:.1f} ms, {ro['method']})"
    print(f"  {name:34s} rot {a['rot_median_deg']:.3f} deg (cam x/y/z {np.median(e[:, 0]):.3f}/"
          f"{np.median(e[:, 1]):.3f}/{np.median(e[:, 2]):.3f}) ATE {a['ate_rmse_m']:.3f} m "
          f"px20 {a['reproj_median_px']:.2f} rejected {res.summary.get('rejected')} | "
          f"VO pairs: err {verr:.3f} deg gain x/y/z {gain[0]:.3f}/{gain[1]:.3f}/{gain[2]:.3f} | CPU {cpu:.0f} s",
          flush=True)


def main() -> None:
    import cv2

    cv2.setNumThreads(1)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=("rs", "hard", "easy"), default="rs")
    ap.add_argument("--fps", type=float, default=10.0)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=0, help="the recording's noise seed")
    ap.add_argument("--spins", default="off,table", help="corrections, comma-separated: off, constant, table, auto")
    ap.add_argument("--assumed", default="", help="wrong readouts (s) for extra 'table' rows, comma-separated")
    args = ap.parse_args()
    kw = dict(scene=StreetScene(), fps=args.fps, seed=args.seed)
    if args.case == "hard":
        rec, _, _ = hard_recording(args.duration, **kw)
    elif args.case == "rs":
        rec, _, _ = synthetic_recording("drive", args.duration, rolling_shutter_s=0.03, shake_deg=0.3,
                                        photometric=True, **kw)
    else:
        rec, _, _ = synthetic_recording("drive", args.duration, **kw)
    print(f"{args.case} drive, readout {rec.rolling_shutter_s * 1e3:g} ms, {args.fps:g} fps, seed {args.seed}, "
          "full + twin road + camera height")
    ref = gt_poses(rec.groundtruth)
    for spins in args.spins.split(","):
        run(f"correction {spins}", rec, ref, spins, rec.rolling_shutter_s)
    for ro in filter(None, args.assumed.split(",")):
        run(f"correction table, readout {float(ro) * 1e3:g} ms", rec, ref, "table", float(ro))


if __name__ == "__main__":
    main()
