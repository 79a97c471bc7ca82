"""Where VO's relative-rotation bias on the 60 s synthetic drive comes from (issue 14, docs/sync.md
"VO: the relative rotation's bias").

    PYTHONPATH=$PWD nice -n 5 .venv/bin/python benchmarks/sync/bench_vo_bias.py [--seed 0] [--parts exact,frames,pp]
        [--parts frames,old,coarse] [--parts flow --duration 20] [--supersample 2] [--width 640]

Per frame pair of the drive (5 fps, 480x270, `synthetic_recording("drive", 60, seed=...)`), the
VO's R_c1c2 against the ground truth's: error e = log(R_gt^T R_vo) (rad, camera axes x right,
y down, z forward); printed as mean +- standard error (deg per pair) of each component, and the
direction of travel's error (deg, camera x / y). Parts:
  exact    exact correspondences: 600 random pixels of frame 1 ray-cast into the street (ground
           z = 0, facades y = +-W), projected into frame 2, with 0 / 0.3 / 1 px Gaussian noise,
           through the same `solve_pair` (RANSAC + cheirality + Sampson refit): the estimator alone;
  frames   the rendered frames through the ORB front end (the pipeline's at 5 fps) with the true K;
           with `old` also as before the fix (pyramid 1.2 x 6, nominal level scale);
  coarse   the frames with OpenCV's default pyramid 1.2 x 6 (level sizes fixed);
  levels1  ORB on the full-resolution image only;
  pp       the frames with the principal point moved by +-0.5 px in x / y (a pixel-centre
           convention mismatch would show as a bias that one of these removes);
  flow     per ORB match, the frame-2 keypoint minus where the frame-1 keypoint's scene point
           projects (by image rows, ground / facades, same / next pyramid level), and solve_pair
           on ORB's frame-1 keypoints with exact frame-2 positions; `old`: also the old mapping.
--supersample k renders each frame k x k larger and box-averages it down; --width another size.
CPU seconds per part (process time; shared 2-core machine).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen

from blendgen import so3  # noqa: E402
from blendgen.geometry import Camera  # noqa: E402
from blendgen.sync.metrics import gt_poses  # noqa: E402
from blendgen.sync.simulate import StreetScene, synthetic_recording  # noqa: E402
from blendgen.vo import VoConfig, VoResult, make_vo, solve_pair  # noqa: E402


def pair_errors(results, gt):
    """(n, 3) rotation errors (deg, camera axes) and (n, 2) direction errors (deg) of 'ok' pairs."""
    rot, dirs = [], []
    for i, r in enumerate(results):
        if r is None or r.status != "ok":
            continue
        T1, T2 = gt[i], gt[i + 1]
        R_gt = T1[:3, :3].T @ T2[:3, :3]
        rot.append(np.degrees(so3.log(R_gt.T @ r.R_c1c2)))
        u = T1[:3, :3].T @ (T2[:3, 3] - T1[:3, 3])
        u /= np.linalg.norm(u)
        # direction error as angles of x/z and y/z (camera pan / tilt of the direction)
        dirs.append(np.degrees([np.arctan2(r.u_dir[0], r.u_dir[2]) - np.arctan2(u[0], u[2]),
                                np.arctan2(r.u_dir[1], r.u_dir[2]) - np.arctan2(u[1], u[2])]))
    return np.array(rot).reshape(-1, 3), np.array(dirs).reshape(-1, 2)


def report(name, results, gt, cpu):
    rot, dirs = pair_errors(results, gt)
    n = len(rot)
    m, se = rot.mean(0), rot.std(0, ddof=1) / np.sqrt(max(n, 1))
    dm, dse = dirs.mean(0), dirs.std(0, ddof=1) / np.sqrt(max(n, 1))
    print(f"  {name:40s} pairs {n:3d}  rot x {m[0]:+.4f}+-{se[0]:.4f} y {m[1]:+.4f}+-{se[1]:.4f} "
          f"z {m[2]:+.4f}+-{se[2]:.4f}  (RMS x {np.sqrt(np.mean(rot[:, 0]**2)):.4f})  "
          f"dir x {dm[0]:+.3f}+-{dse[0]:.3f} y {dm[1]:+.3f}+-{dse[1]:.3f}  CPU {cpu:.1f} s", flush=True)
    return m, se


def raycast(scene: StreetScene, cam: Camera, T_wc: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """World points seen at pixels uv (N, 2) (pixel centres at integers, as the renderer)."""
    dc = np.column_stack([(uv[:, 0] - cam.cx) / cam.fx, (uv[:, 1] - cam.cy) / cam.fy, np.ones(len(uv))])
    d = dc @ T_wc[:3, :3].T
    c = T_wc[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        tg = np.where(d[:, 2] < -1e-9, -c[2] / d[:, 2], np.inf)
        wy = np.where(d[:, 1] > 0, scene.half_width, -scene.half_width)
        tw = np.where(np.abs(d[:, 1]) > 1e-9, (wy - c[1]) / d[:, 1], np.inf)
    tw = np.where(tw > 0, tw, np.inf)
    zw = c[2] + tw * d[:, 2]
    tw = np.where((zw >= 0) & (zw <= scene.wall_h), tw, np.inf)
    t = np.minimum(tg, tw)
    ok = np.isfinite(t)
    return c + t[:, None] * d, ok


def exact_pairs(scene, cam, gt, noise_px, rng, n_pts=600):
    """solve_pair on exact (+ noise) correspondences of every frame pair."""
    cfg = VoConfig(method="orb")
    f = 0.5 * (cam.fx + cam.fy)
    Kinv = np.linalg.inv(cam.K)
    out = []
    for i in range(len(gt) - 1):
        uv1 = np.column_stack([rng.uniform(0, cam.width - 1, n_pts), rng.uniform(0, cam.height - 1, n_pts)])
        P, ok = raycast(scene, cam, gt[i], uv1)
        Xc2 = (P - gt[i + 1][:3, 3]) @ gt[i + 1][:3, :3]
        ok &= Xc2[:, 2] > 0.1
        uv2 = Xc2[:, :2] / Xc2[:, 2:] * [cam.fx, cam.fy] + [cam.cx, cam.cy]
        ok &= (uv2[:, 0] >= 0) & (uv2[:, 0] <= cam.width - 1) & (uv2[:, 1] >= 0) & (uv2[:, 1] <= cam.height - 1)
        p1 = uv1[ok] + rng.normal(0, noise_px, (ok.sum(), 2))
        p2 = uv2[ok] + rng.normal(0, noise_px, (ok.sum(), 2))
        q1 = np.column_stack([p1, np.ones(len(p1))]) @ Kinv.T
        q2 = np.column_stack([p2, np.ones(len(p2))]) @ Kinv.T
        out.append(solve_pair(VoResult("few_features"), p1, p2, q1, q2, cfg, f))
    return out


def run_frames(images, cam, method="orb", levels=None, scale_factor=None):
    cfg = VoConfig(method=method)
    cfg.n_levels = levels or cfg.n_levels
    cfg.orb_scale_factor = scale_factor or cfg.orb_scale_factor
    vo = make_vo(cam, cfg)
    out = []
    for k, img in enumerate(images):
        r = vo.track(img)
        if k > 0:
            out.append(r)
    return out


def OLD_MAPPING(pts, octave, scale_factor, shape):
    """The ORB level mapping before the fix: nominal scale s^k and the half-pixel term only."""
    return pts + 0.5 * (scale_factor ** np.asarray(octave, float) - 1.0)[:, None]


def flow_errors(images, cam, gt, scene, old_mapping=False):
    """ORB matches of each pair: the frame-2 keypoint minus where the frame-1 keypoint's scene
    point truly projects in frame 2 (px), with the two octaves; and solve_pair on the matched
    frame-1 keypoints with exact frame-2 positions (the estimator on ORB's feature layout)."""
    from blendgen import vo as vo_mod

    vo = vo_mod.OrbVo(cam, VoConfig(method="orb"))
    vo_mod_orig = vo_mod.orb_level_to_full
    mapping = OLD_MAPPING if old_mapping else vo_mod_orig
    seen = {}

    def recording(pts, octave, sf, shape):  # keeps the octaves of the last frame's keypoints
        seen["octave"] = np.asarray(octave)
        return mapping(pts, octave, sf, shape)

    vo_mod.orb_level_to_full = recording
    rows, exact = [], []
    f = 0.5 * (cam.fx + cam.fy)
    Kinv = np.linalg.inv(cam.K)
    prev = None
    for i, img in enumerate(images):
        px, desc = vo._orb_features(img)
        octv = seen.get("octave", np.zeros(len(px)))
        if prev is not None and desc is not None:
            px1, d1, oc1 = prev
            pairs = vo._match(d1, desc)
            a, b = px1[pairs[:, 0]], px[pairs[:, 1]]
            P, ok = raycast(scene, cam, gt[i - 1], a)
            Xc2 = (P - gt[i][:3, 3]) @ gt[i][:3, :3]
            ok &= Xc2[:, 2] > 0.1
            b_true = Xc2[:, :2] / np.where(ok, Xc2[:, 2], 1.0)[:, None] * [cam.fx, cam.fy] + [cam.cx, cam.cy]
            e = b - b_true
            good = ok & (np.abs(e).max(axis=1) < 2.0)
            ground = np.abs(P[:, 2]) < 1e-6
            do = (octv[pairs[:, 1]] - prev[2][pairs[:, 0]])[good]
            rows.append(np.column_stack([np.full(good.sum(), i), a[good], e[good], ground[good], do]))
            q1 = np.column_stack([a[ok], np.ones(ok.sum())]) @ Kinv.T
            q2 = np.column_stack([b_true[ok], np.ones(ok.sum())]) @ Kinv.T
            exact.append(solve_pair(VoResult("few_features"), a[ok], b_true[ok], q1, q2, VoConfig(method="orb"), f))
        prev = (px, desc, octv)
    vo_mod.orb_level_to_full = vo_mod_orig
    return np.vstack(rows), exact


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--parts", default="exact,frames,pp",
                    help="comma separated: exact, frames, coarse, levels1, pp, flow; 'old' adds the state before the fix")
    ap.add_argument("--supersample", type=int, default=1,
                    help="render each frame at this many times the resolution and box-average it down (pixels "
                         "that integrate their footprint, as a sensor) instead of one ray per pixel")
    ap.add_argument("--width", type=int, default=480, help="frame width (height 9/16 of it)")
    ap.add_argument("--method", default="orb", help="front end for frames / pp (the pipeline's at 5 fps: orb)")
    args = ap.parse_args()
    import cv2

    cv2.setNumThreads(1)
    parts = set(args.parts.split(","))
    c0 = time.process_time()
    need_frames = bool(parts & {"frames", "pp", "flow", "levels1", "coarse"})
    scene = StreetScene()
    rec, traj, _ = synthetic_recording("drive", args.duration, seed=args.seed, frames=need_frames, scene=scene,
                                       resolution=(args.width, args.width * 9 // 16))
    cam = rec.camera or Camera.from_hfov(args.width, args.width * 9 // 16, 70.0)
    if args.supersample > 1 and need_frames:
        import cv2

        k = args.supersample
        big = cam.scaled(cam.width * k, cam.height * k)
        rng = np.random.default_rng(args.seed + 7)
        rec.extra["images"] = [cv2.resize(scene.render(big, T, noise_std=2.0 * k, rng=rng), (cam.width, cam.height),
                                          interpolation=cv2.INTER_AREA) for T in gt_poses(rec.groundtruth)]
    if need_frames:
        gt = gt_poses(rec.groundtruth)
    else:
        T_body_cam = np.linalg.inv(rec.T_cam_imu)
        gt = [traj.pose(t) @ T_body_cam for t in np.arange(0.5, 0.5 + args.duration, 0.2)]
    print(f"seed {args.seed}, {len(gt)} frames, K cx {cam.cx} cy {cam.cy} f {cam.fx:.2f} "
          f"(built in {time.process_time() - c0:.1f} CPU s)", flush=True)
    if "exact" in parts:
        for noise in (0.0, 0.3, 1.0):
            c0 = time.process_time()
            res = exact_pairs(scene, cam, gt, noise, np.random.default_rng(args.seed))
            report(f"exact correspondences, noise {noise} px", res, gt, time.process_time() - c0)
    if "frames" in parts:
        c0 = time.process_time()
        report(f"frames, {args.method}, true K", run_frames(rec.extra["images"], cam, args.method), gt,
               time.process_time() - c0)
        if "old" in parts:
            from blendgen import vo as vo_mod

            keep = vo_mod.orb_level_to_full
            vo_mod.orb_level_to_full = OLD_MAPPING
            c0 = time.process_time()
            report("frames, orb, before: 1.2 x 6, old level map", run_frames(rec.extra["images"], cam, "orb", 6, 1.2),
                   gt, time.process_time() - c0)
            vo_mod.orb_level_to_full = keep
    if "flow" in parts:
        for old in ((True, False) if "old" in parts else (False,)):
            c0 = time.process_time()
            fe, exact = flow_errors(rec.extra["images"], cam, gt, scene, old_mapping=old)
            tag = "old level mapping" if old else "true level sizes"
            e = fe[:, 3:5]
            se = e.std(0) / np.sqrt(len(e))
            print(f"  ORB matches ({tag}): {len(e)} inliers (|e| < 2 px), frame-2 position error mean "
                  f"u {e[:, 0].mean():+.4f}+-{se[0]:.4f} v {e[:, 1].mean():+.4f}+-{se[1]:.4f} px", flush=True)
            for lo, hi in ((0, 90), (90, 180), (180, 270)):
                m = (fe[:, 2] >= lo) & (fe[:, 2] < hi)
                print(f"    rows {lo:3d}-{hi:3d}: {m.sum():6d}  u {e[m, 0].mean():+.4f} v {e[m, 1].mean():+.4f}")
            for name, m in (("ground", fe[:, 5] > 0), ("facades", fe[:, 5] == 0), ("same octave", fe[:, 6] == 0),
                            ("octave up", fe[:, 6] > 0), ("octave down", fe[:, 6] < 0)):
                print(f"    {name:8s}: {m.sum():6d}  u {e[m, 0].mean():+.4f} v {e[m, 1].mean():+.4f}")
            report(f"ORB's frame-1 keypoints, exact frame 2 ({tag})", exact, gt, time.process_time() - c0)
    if "coarse" in parts:  # OpenCV's default pyramid, 1.2 x 6 levels (blendgen's before the bias fix)
        c0 = time.process_time()
        report("frames, orb, pyramid 1.2 x 6 levels", run_frames(rec.extra["images"], cam, "orb", 6, 1.2), gt,
               time.process_time() - c0)
    if "levels1" in parts:  # ORB on the full-resolution image only: no pyramid mapping at all
        c0 = time.process_time()
        report(f"frames, orb, 1 level, true K", run_frames(rec.extra["images"], cam, "orb", 1), gt,
               time.process_time() - c0)
    if "pp" in parts:
        for dx, dy in ((0.5, 0), (-0.5, 0), (0, 0.5), (0, -0.5)):
            c2 = Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx + dx, cam.cy + dy)
            c0 = time.process_time()
            report(f"frames, {args.method}, cx{dx:+.1f} cy{dy:+.1f}", run_frames(rec.extra["images"], c2, args.method),
                   gt, time.process_time() - c0)


if __name__ == "__main__":
    main()
