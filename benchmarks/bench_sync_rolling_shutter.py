"""Rolling-shutter correction of VO in the full sync (docs/sync.md, "Rolling shutter").

    PYTHONPATH=$PWD nice -n 5 .venv/bin/python benchmarks/bench_sync_rolling_shutter.py [--fps 5] [--case rs|hard|easy]

The 60 s drive of bench_sync.py, full sync (VO) with each frame's rows read out over 30 ms
(calib `camera.rolling_shutter_s`), 0.3 deg shake and real-camera photometry; the frames are
rendered once and synced with the correction off (readout 0 in the recording), with one
angular velocity per frame (the first attempt, reverted), and with the gyro integrated over
the readout (`pipeline._rs_spins`, landed); "off" also drops the rolling-shutter direction noise
(`vo_trust.VO_DIR_RS`), "floor" keeps that noise without the correction. Prints the camera rotation error (median, and per
camera axis: x pitch, y yaw, z roll), ATE, the 20 m point's reprojection, VO pairs rejected,
and the per-pair VO rotation error and least-squares gain against the truth.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from blendgen.job.schema import Sync  # noqa: E402
from blendgen.sync import pipeline, so3, vo_trust  # noqa: E402
from blendgen.sync.metrics import gt_poses, trajectory_errors  # noqa: E402
from blendgen.sync.simulate import GEOREF, StreetScene, hard_recording, synthetic_recording  # noqa: E402

DUR = 60.0
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
    from blendgen.sync.vo_trust import vo_noise

    V, T, S = [], [], []
    for i in range(1, len(ref)):
        r = res_vo.get(i)
        if r is None or r.status not in ("ok", "rotation"):
            continue
        Rt = ref[i - 1][:3, :3].T @ ref[i][:3, :3]
        V.append(so3.log(r.R_c1c2))
        T.append(so3.log(Rt))
        S.append(np.sqrt(np.diag(vo_noise(r)[0])))
    V, T = np.array(V), np.array(T)
    E = np.array([so3.log(so3.exp(t).T @ so3.exp(v)) for v, t in zip(V, T)])
    return (np.degrees(np.median(np.linalg.norm(E, axis=1))), (V * T).sum(0) / (T * T).sum(0),
            np.degrees(E.mean(0)), np.degrees(np.median(np.abs(E), 0)), np.degrees(np.median(S, 0)))


_VO_CONFIG, _DIR_RS = pipeline._vo_config, vo_trust.VO_DIR_RS


def run(name, rec, ref, spins, road: bool, photo_norm: str | None = None, dir_rs_deg: float | None = None):
    """One sync. photo_norm: KLT's VoConfig.photo_norm for this run (None: the default);
    dir_rs_deg: vo_trust.VO_DIR_RS for this run (None: the default)."""
    readout = rec.rolling_shutter_s
    if spins == "off":
        rec.rolling_shutter_s = 0.0
    if photo_norm is not None:
        pipeline._vo_config = lambda *a, **k: dataclasses.replace(_VO_CONFIG(*a, **k), photo_norm=photo_norm)
    if dir_rs_deg is not None:
        vo_trust.VO_DIR_RS = np.radians(dir_rs_deg)
    # "floor": no correction, but the rolling-shutter direction noise (vo_trust.VO_DIR_RS)
    pipeline._rs_spins = {"constant": _constant_rate, "floor": lambda *a, **k: None}.get(spins, _TABLE)
    # the VO results, to measure the pairs the filter was given
    cache = {}
    orig = pipeline._vo_all

    def _vo_all(*a, **k):
        orig(*a, **k)
        cache.update(a[3])

    pipeline._vo_all = _vo_all
    rec.extra.pop("vehicle", None)
    if road:
        rec.extra["vehicle"] = {"camera_height_m": 1.5}
    c0 = time.process_time()
    try:
        with tempfile.TemporaryDirectory() as d:
            res = pipeline.run_sync(rec, Sync(), Path(d), georef=GEOREF, progress=False,
                                    road_surface=flat_road if road else None)
    finally:
        pipeline._vo_all, pipeline._rs_spins, rec.rolling_shutter_s = orig, _TABLE, readout
        pipeline._vo_config, vo_trust.VO_DIR_RS = _VO_CONFIG, _DIR_RS
    cpu = time.process_time() - c0
    est = [p[2] for p in res.poses]
    a = trajectory_errors(est, ref, camera=rec.camera.scaled(1280, 720))
    e = np.degrees(np.abs([so3.log(g[:3, :3].T @ x[:3, :3]) for g, x in zip(ref, est)]))
    verr, gain, mean, med, std = _vo_pairs(cache, ref)
    print(f"  {name:34s} rot {a['rot_median_deg']:.3f} deg (cam x/y/z {np.median(e[:, 0]):.3f}/"
          f"{np.median(e[:, 1]):.3f}/{np.median(e[:, 2]):.3f}) ATE {a['ate_rmse_m']:.3f} m "
          f"px20 {a['reproj_median_px']:.2f} rejected {res.summary.get('rejected')} | "
          f"VO pairs: err {verr:.3f} deg gain x/y/z {gain[0]:.3f}/{gain[1]:.3f}/{gain[2]:.3f} | CPU {cpu:.0f} s\n"
          f"    per axis x/y/z (deg): mean error {mean.round(4)} median |error| {med.round(4)} filter's std {std.round(4)}",
          flush=True)


def main() -> None:
    import cv2

    cv2.setNumThreads(1)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fps", type=float, default=5.0)
    ap.add_argument("--case", choices=("rs", "hard", "easy"), default="rs")
    ap.add_argument("--duration", type=float, default=DUR)
    ap.add_argument("--seed", type=int, default=0, help="the recording's noise seed")
    ap.add_argument("--spins", default="off,floor,constant,table", help="rs case: which corrections, comma-separated")
    ap.add_argument("--rows", default=None,
                    help="rs/hard case instead of --spins: rows spins/photo_norm/VO_DIR_RS deg, e.g. "
                         "'off/off/1,table/gain/0' (hard: road is on, 'full + twin road')")
    args = ap.parse_args()
    rows = [r.split("/") for r in args.rows.split(",")] if args.rows else None
    if args.case == "rs" and rows:
        rec, _, _ = synthetic_recording("drive", args.duration, fps=args.fps, rolling_shutter_s=0.03, shake_deg=0.3,
                                        photometric=True, scene=StreetScene(), seed=args.seed)
        print(f"rolling-shutter frames (30 ms, 0.3 deg shake, photometry), {args.fps:g} fps, seed {args.seed}, "
              "full + twin road")
        for sp, pn, dr in rows:
            run(f"correction {sp}, photo_norm {pn}, dir_rs {dr}", rec, gt_poses(rec.groundtruth), sp, True, pn, float(dr))
    elif args.case == "hard" and rows:
        rec, _, _ = hard_recording(args.duration, scene=StreetScene(), fps=args.fps, seed=args.seed)
        print(f"hard drive (bench_sync --section hard), {args.fps:g} fps, seed {args.seed}, full + twin road")
        for sp, pn, dr in rows:
            run(f"correction {sp}, photo_norm {pn}, dir_rs {dr}", rec, gt_poses(rec.groundtruth), sp, True, pn, float(dr))
    elif args.case == "rs":
        rec, _, _ = synthetic_recording("drive", args.duration, fps=args.fps, rolling_shutter_s=0.03, shake_deg=0.3,
                                        photometric=True, scene=StreetScene())
        print(f"rolling-shutter frames (30 ms, 0.3 deg shake, photometry), {args.fps:g} fps, full + twin road")
        for spins in args.spins.split(","):
            run(f"correction {spins}", rec, gt_poses(rec.groundtruth), spins, road=True)
    elif args.case == "hard":
        rec, _, _ = hard_recording(args.duration, scene=StreetScene(), fps=args.fps)
        print(f"hard drive (bench_sync --section hard), {args.fps:g} fps")
        for road in (False, True):
            for spins in ("off", "floor", "table"):
                run(f"{'full + twin road' if road else 'full'}, correction {spins}", rec,
                    gt_poses(rec.groundtruth), spins, road)
    else:
        rec, _, _ = synthetic_recording("drive", args.duration, fps=args.fps, scene=StreetScene())
        print(f"easy drive (global shutter, no readout in calib), {args.fps:g} fps")
        for road in (False, True):
            run(f"{'full + twin road' if road else 'full'}", rec, gt_poses(rec.groundtruth), "table", road)


if __name__ == "__main__":
    main()
