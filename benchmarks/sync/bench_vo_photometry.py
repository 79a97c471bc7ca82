"""Which part of a real camera's photometry biases VO's direction of travel, and whether the
photometric normalisation removes it (issue 14, docs/sync.md "VO under real-camera photometry").

    PYTHONPATH=$PWD nice -n 5 .venv/bin/python benchmarks/sync/bench_vo_photometry.py [--fps 10]
        [--duration 20] [--shake 0.3] [--readout 0] [--method klt|orb] [--seed 0]
        [--variants none,flicker,vignetting,gamma,jpeg,all] [--norm off,gain]
    ... --timing                      (960x540 CPU ms per frame, off / gain)
    ... --sync rs|hard|easy [--seed S] [--fps 10] [--norm off,gain] [--method klt,orb]
                                      (the 60 s drive through the full sync)

The drive of bench_sync.py (480x270, 70 deg) is rendered once without photometry
(`synthetic_recording(..., photometric=False)`); each variant then applies some of
`simulate.PHOTOMETRY_PARTS` to the same frames with the same random draws (the flicker's gain
per frame), and the VO front end (KLT at >= 10 fps as the pipeline, or ORB) runs on them with
each `--norm` value of `VoConfig.photo_norm` (off, gain, ratio, hp, lcn; `lcn:8` = a box of
width / 8). Per frame pair with a full ("ok") result, the errors against the ground truth
(bench_vo_bias.pair_errors): the direction of travel's error as camera pan (x) / tilt (y, + =
down), the relative rotation's per camera axis; mean +- standard error over the pairs and the
pair count; with flicker, the direction's fit against the pair's gain change, and for `gain`
the applied gain against the true one. CPU seconds (process time) per VO run; the machine is
shared.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.sync.bench_vo_bias import pair_errors  # noqa: E402

from blendgen.sync.metrics import gt_poses  # noqa: E402
from blendgen.sync.simulate import PHOTOMETRY_PARTS, StreetScene, _camera_look, synthetic_recording  # noqa: E402
from blendgen.vo import VoConfig, make_vo  # noqa: E402


def photometry(images, parts, seed: int):
    """The frames with some photometric parts, the same per-frame draws as synthetic_recording."""
    if not parts:
        return list(images)
    rng = np.random.default_rng(seed + 13)
    return [_camera_look(img, rng, parts) for img in images]


def norm_fields(norm: str) -> dict:
    """VoConfig fields of a --norm value: lcn:8 -> a box of width / 8; off:klt_win=21+klt_levels=2."""
    mode, _, rest = norm.partition(":")
    if rest.isdigit():
        return {"photo_norm": mode, "photo_norm_box": int(rest)}
    return {"photo_norm": mode, **{k: type(getattr(VoConfig, k))(v) for k, v in (kv.split("=") for kv in rest.split("+") if kv)}}


def gains(n: int, seed: int) -> np.ndarray:
    """The flicker's gain of each frame (the draws _camera_look makes, one per frame)."""
    rng = np.random.default_rng(seed + 13)
    return np.array([1.0 + 0.08 * rng.uniform(-1, 1) for _ in range(n)])


def run_vo(cam, images, cfg: VoConfig):
    vo = make_vo(cam, cfg)
    c0 = time.process_time()
    res, est = [], []
    for img in images:
        res.append(vo.track(img))
        est.append(getattr(vo, "gain", 1.0))  # KLT's estimated gain from the previous frame
    vo.gains_est = np.array(est)
    cpu = time.process_time() - c0
    return res, cpu, vo


def summarise(results, gt, g=None):
    """Pairs, direction x/y mean, its standard error, rotation mean and standard error (deg);
    with the frames' gains g also the direction's slope against the pair's log gain ratio."""
    pairs = results[1:]  # result i is the pair (i-1, i); pair_errors pairs entry k with gt k, k+1
    rot, dirs = pair_errors(pairs, gt)
    n = len(dirs)
    se = lambda a: a.std(0, ddof=1) / np.sqrt(max(n, 1))  # noqa: E731
    out = {"n": n, "dir": dirs.mean(0), "dir_se": se(dirs), "dir_std": dirs.std(0, ddof=1),
           "dir_med": np.median(dirs, 0), "rot": rot.mean(0), "rot_se": se(rot)}
    if g is not None:
        ok = [k for k, r in enumerate(pairs) if r is not None and r.status == "ok"]
        lg = np.log(g[1:] / g[:-1])[ok]
        # least squares dir_y = a + b log(g2 / g1) + c |log(g2 / g1)| (deg per 1 % of gain change: b / 100)
        A = np.column_stack([np.ones(n), lg, np.abs(lg)])
        out["gain_fit"] = np.linalg.lstsq(A, dirs[:, 1], rcond=None)[0]
    return out


VARIANTS = {"none": (), "all": PHOTOMETRY_PARTS, **{p: (p,) for p in PHOTOMETRY_PARTS},
            **{f"all-{p}": tuple(q for q in PHOTOMETRY_PARTS if q != p) for p in PHOTOMETRY_PARTS},
            "vig+flicker": ("vignetting", "flicker")}


def timing(rounds: int = 4) -> None:
    from benchmarks.sync.bench_vo import run, sequence

    cam, poses, imgs = sequence(StreetScene(), 960, 540, 25.0, 40)
    for name, parts in (("no photometry", ()), ("photometry", PHOTOMETRY_PARTS)):
        frames = photometry(imgs, parts, 0)
        ms = {"off": [], "gain": []}
        for _ in range(rounds):  # interleaved: the machine is shared, its load changes
            for norm in ms:
                r = run(cam, poses, frames, VoConfig(method="klt", photo_norm=norm))
                ms[norm].append(r["ms"])
        for norm, v in ms.items():
            print(f"  960x540 KLT 1500, {name:14s} photo_norm {norm:4s}: best {min(v):.1f} ms/frame "
                  f"({1e3 / min(v):.0f} fps), rounds {' '.join(f'{x:.1f}' for x in v)}", flush=True)
        for norm in ms:
            r = run(cam, poses, frames, VoConfig(method="klt", photo_norm=norm), reps=1)
            print(f"    {norm}: rot median {r['rot_med']:.4f} deg, dir median {r['dir_med']:.3f} deg, "
                  f"ok {r['ok']}/{r['pairs']}", flush=True)


def full_sync(kind: str, seed: int, fps: float, norms, methods=("klt",)) -> None:
    """The 60 s drive through the full sync (twin road + camera_height_m, as bench_sync's
    rolling-shutter rows): kind rs (30 ms readout, 0.3 deg shake, photometry), hard
    (simulate.hard_recording) or easy (no photometry); per VoConfig.photo_norm and front end."""
    import dataclasses
    import tempfile

    from blendgen import so3
    from blendgen.job.schema import Sync
    from blendgen.sync import pipeline
    from blendgen.sync.metrics import trajectory_errors
    from blendgen.sync.simulate import GEOREF, hard_recording

    if kind == "hard":
        rec, _, _ = hard_recording(60.0, scene=StreetScene(), fps=fps, seed=seed)
    else:
        kw = dict(rolling_shutter_s=0.03, shake_deg=0.3, photometric=True) if kind == "rs" else {}
        rec, _, _ = synthetic_recording("drive", 60.0, fps=fps, scene=StreetScene(), seed=seed, **kw)
    rec.extra["vehicle"] = {"camera_height_m": 1.5}
    ref = gt_poses(rec.groundtruth)
    orig = pipeline._vo_config
    for method in methods:
        for norm in norms:
            pipeline._vo_config = lambda *a, _f=norm_fields(norm), **k: dataclasses.replace(orig(*a, **k), **_f)
            c0 = time.process_time()
            try:
                with tempfile.TemporaryDirectory() as d:
                    res = pipeline.run_sync(rec, Sync(vo_method=method), Path(d), georef=GEOREF, progress=False,
                                            road_surface=lambda p: np.zeros(len(np.atleast_2d(p))))
            finally:
                pipeline._vo_config = orig
            est = [p[2] for p in res.poses]
            a = trajectory_errors(est, ref, camera=rec.camera.scaled(1280, 720))
            e = np.degrees(np.abs([so3.log(g[:3, :3].T @ x[:3, :3]) for g, x in zip(ref, est)]))
            print(f"  {kind} seed {seed} {fps:g} fps {method} photo_norm {norm}: rotation median "
                  f"{a['rot_median_deg']:.3f} deg (camera x/y/z {np.median(e[:, 0]):.3f}/{np.median(e[:, 1]):.3f}/"
                  f"{np.median(e[:, 2]):.3f}) ATE {a['ate_rmse_m']:.3f} m 20 m point {a['reproj_median_px']:.2f} px "
                  f"rejected {res.summary.get('rejected')} CPU {time.process_time() - c0:.0f} s", flush=True)


def main() -> None:
    cv2.setNumThreads(1)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fps", type=float, default=10.0)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--shake", type=float, default=0.0)
    ap.add_argument("--readout", type=float, default=0.0, help="rolling-shutter readout (s)")
    ap.add_argument("--method", default="klt")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--width", type=int, default=480)
    ap.add_argument("--variants", default="none,flicker,vignetting,gamma,jpeg,all")
    ap.add_argument("--norm", default="off,gain",
                    help="VoConfig.photo_norm values to run: mode[:box divisor] or mode:key=value+key=value "
                         "(other VoConfig fields, e.g. off:klt_win=21)")
    ap.add_argument("--sigmas", type=float, default=None, help="vo.GAIN_SIGMAS for this run")
    ap.add_argument("--timing", action="store_true",
                    help="instead: CPU ms per frame at 960x540, 25 fps (bench_vo.py's case A, 40 frames, best of 3 "
                         "medians), photo_norm off / gain, frames without and with photometry")
    ap.add_argument("--sync", choices=("rs", "hard", "easy"), default=None,
                    help="instead: the 60 s drive through the full sync, photo_norm per --norm, front ends "
                         "per --method (comma-separated)")
    args = ap.parse_args()
    if args.sync:
        full_sync(args.sync, args.seed, args.fps, args.norm.split(","), args.method.split(","))
        return
    if args.sigmas is not None:
        import blendgen.vo as vo_mod

        vo_mod.GAIN_SIGMAS = args.sigmas
    if args.timing:
        timing()
        return
    c0 = time.process_time()
    rec, _, _ = synthetic_recording("drive", args.duration, fps=args.fps, shake_deg=args.shake,
                                    rolling_shutter_s=args.readout, seed=args.seed, scene=StreetScene(),
                                    resolution=(args.width, round(args.width * 9 / 16)), imu=False, gnss=False)
    gt = gt_poses(rec.groundtruth)
    base = rec.extra["images"]
    print(f"{args.method} on {len(base)} frames, {args.fps:g} fps, {args.width} px wide, shake {args.shake} deg, "
          f"readout {args.readout * 1e3:.0f} ms, seed {args.seed} (render {time.process_time() - c0:.0f} CPU s)")
    print("  variant          norm  pairs  dir x (deg)      dir y (deg, + down)  dir std x/y   "
          "rot x (deg/pair)   rot y              rot z              VO CPU s")
    for name in args.variants.split(","):
        imgs = photometry(base, VARIANTS[name], args.seed)
        for norm in args.norm.split(","):
            cfg = VoConfig(method=args.method, **norm_fields(norm))
            res, cpu, vo = run_vo(rec.camera, imgs, cfg)
            s = summarise(res, gt, gains(len(imgs), args.seed) if "flicker" in VARIANTS[name] else None)
            f = lambda k, i: f"{s[k][i]:+.3f}+-{s[k + '_se'][i]:.3f}"  # noqa: E731
            print(f"  {name:16s} {norm:18s} {s['n']:5d}  {f('dir', 0):16s} {f('dir', 1):20s} "
                  f"{s['dir_std'][0]:.2f}/{s['dir_std'][1]:.2f}    {f('rot', 0)}  {f('rot', 1)}  {f('rot', 2)}  "
                  f"{cpu:.1f}" + (f"  dir y median {s['dir_med'][1]:+.3f}" + (f", = {s['gain_fit'][0]:+.3f} "
                  f"{s['gain_fit'][1] / 100:+.3f} per % gain change {s['gain_fit'][2] / 100:+.3f} per % of its size" if "gain_fit" in s else "")), flush=True)
            if cfg.photo_norm == "gain":
                g = gains(len(imgs), args.seed) if "flicker" in VARIANTS[name] else np.ones(len(imgs))
                g = g ** (1 / 1.1) if "gamma" in VARIANTS[name] else g  # the gain in the image, after gamma
                err = 100 * (vo.gains_est[1:] / (g[1:] / g[:-1]) - 1)
                print(f"    applied frame-to-frame gain (1 where not significant): error {np.mean(err):+.2f} % mean, {np.sqrt(np.mean(err**2)):.2f} % "
                      f"RMS, max {np.abs(err).max():.2f} % (true changes {100 * np.std(g[1:] / g[:-1]):.1f} % RMS)")


if __name__ == "__main__":
    main()
