"""Trajectory accuracy: ATE, RPE, rotation error, reprojection of a point ahead (TUM/KITTI style)."""

from __future__ import annotations

import numpy as np

from blendgen import so3
from blendgen.geometry import Camera, pose_from_xyz_quat


def gt_poses(groundtruth: np.ndarray) -> list[np.ndarray]:
    return [pose_from_xyz_quat(r[1:4], r[4:8]) for r in groundtruth]


def align_se3(est: np.ndarray, ref: np.ndarray, yaw_only: bool = False):
    """Rigid (R, t) minimising |ref - (R est + t)| (Umeyama without scale)."""
    ce, cr = est.mean(axis=0), ref.mean(axis=0)
    A, B = est - ce, ref - cr
    if yaw_only:
        C = A[:, :2].T @ B[:, :2]
        psi = np.arctan2(C[0, 1] - C[1, 0], C[0, 0] + C[1, 1])
        R = so3.yaw_rotation(psi)
    else:
        U, _, Vt = np.linalg.svd(A.T @ B)
        D = np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))])
        R = Vt.T @ D @ U.T
    return R, cr - R @ ce


def trajectory_errors(est: list[np.ndarray], ref: list[np.ndarray], *, align: str = "none",
                      camera: Camera | None = None, ahead_m: float = 20.0, rpe_step: int = 1) -> dict:
    """Errors of T_world_cam lists of equal length.

    align: 'none' (absolute, in the twin frame), 'translation', 'yaw' or 'se3' (TUM ATE).
    """
    E = np.array([T[:3, 3] for T in est])
    G = np.array([T[:3, 3] for T in ref])
    R_al, t_al = np.eye(3), np.zeros(3)
    if align == "translation":
        t_al = (G - E).mean(axis=0)
    elif align in ("yaw", "se3"):
        R_al, t_al = align_se3(E, G, yaw_only=align == "yaw")
    est = [np.block([[R_al @ T[:3, :3], (R_al @ T[:3, 3] + t_al)[:, None]], [np.zeros((1, 3)), 1.0]]) for T in est]
    E = np.array([T[:3, 3] for T in est])
    pos_err = np.linalg.norm(E - G, axis=1)
    rot_err = np.degrees([np.linalg.norm(so3.log(g[:3, :3].T @ e[:3, :3])) for e, g in zip(est, ref)])
    rpe = []
    for k in range(len(est) - rpe_step):
        de = np.linalg.inv(est[k]) @ est[k + rpe_step]
        dg = np.linalg.inv(ref[k]) @ ref[k + rpe_step]
        rpe.append(np.linalg.norm(de[:3, 3] - dg[:3, 3]))
    h_err = np.linalg.norm(E[:, :2] - G[:, :2], axis=1)
    out = {"ate_rmse_m": float(np.sqrt(np.mean(pos_err**2))), "pos_median_m": float(np.median(pos_err)),
           "ate_h_rmse_m": float(np.sqrt(np.mean(h_err**2))),
           "rot_median_deg": float(np.median(rot_err)), "rot_max_deg": float(np.max(rot_err)),
           "rpe_rmse_m": float(np.sqrt(np.mean(np.square(rpe)))) if rpe else 0.0}
    if camera is not None:
        px = []
        for e, g in zip(est, ref):
            X = g[:3, 3] + ahead_m * g[:3, 2]  # a point on the optical axis, ahead_m in front
            uv_g, _ = camera.project_world(g, X)
            uv_e, ok = camera.project_world(e, X)
            px.append(np.linalg.norm(uv_e - uv_g) if ok[0] else np.inf)
        out["reproj_median_px"] = float(np.median(px))
        out["reproj_p90_px"] = float(np.percentile(px, 90))
    return out


def offset_removed_errors(t_est, P_est, yaw_est, gt: np.ndarray, *, window_s: float = 1.0) -> dict:
    """Errors against a ground truth (t, x, y, z, qw, qx, qy, qz of T_world_cam) after removing
    the constant horizontal offset (a receiver bias no filter can see).

    horizontal RMSE, relative horizontal error over `window_s` (RMSE of displacement error),
    and median camera-heading error (optical axis projected on the ground)."""
    t_est = np.asarray(t_est, float)
    sel = (t_est >= gt[0, 0]) & (t_est <= gt[-1, 0])
    t_est, P_est = t_est[sel], np.asarray(P_est, float)[sel]
    ref = np.column_stack([np.interp(t_est, gt[:, 0], gt[:, k]) for k in (1, 2, 3)])
    d = P_est[:, :2] - ref[:, :2]
    off = d.mean(axis=0)
    h = np.linalg.norm(d - off, axis=1)
    out = {"offset_m": float(np.linalg.norm(off)), "h_rmse_m": float(np.sqrt(np.mean(h**2)))}
    dt = np.median(np.diff(t_est))
    k = max(1, int(round(window_s / dt)))
    de = P_est[k:, :2] - P_est[:-k, :2]
    dg = ref[k:, :2] - ref[:-k, :2]
    out["rel_1s_median_m"] = float(np.median(np.linalg.norm(de - dg, axis=1)))
    if yaw_est is not None:
        yaw_est = np.asarray(yaw_est, float)[sel]
        Rg = [pose_from_xyz_quat(r[1:4], r[4:8])[:3, :3] for r in gt]
        yg = np.unwrap([np.arctan2(R[1, 2], R[0, 2]) for R in Rg])
        yaw_ref = np.interp(t_est, gt[:, 0], yg)
        err = np.degrees(np.abs(so3.wrap_angle(yaw_est - yaw_ref)))
        out["heading_median_deg"] = float(np.median(err))
        out["heading_p90_deg"] = float(np.percentile(err, 90))
    return out


def camera_rotation_errors(result, gt: np.ndarray) -> dict:
    """Median full 3-D rotation error and median |pitch error| of the optical axis (deg), with
    the ground truth (t, x, y, z, qw, qx, qy, qz of T_world_cam) interpolated to the pose times;
    plus the horizontal RMSE with nothing removed (m)."""
    t = result.times
    sel = (t >= gt[0, 0]) & (t <= gt[-1, 0])
    rot, pitch, h = [], [], []
    for (_, ti, T), ok in zip(result.poses, sel):
        if not ok:
            continue
        k = int(np.argmin(np.abs(gt[:, 0] - ti)))
        G = pose_from_xyz_quat(gt[k, 1:4], gt[k, 4:8])
        rot.append(np.degrees(np.linalg.norm(so3.log(G[:3, :3].T @ T[:3, :3]))))
        pitch.append(np.degrees(np.arcsin(np.clip(-T[2, 2], -1, 1)) - np.arcsin(np.clip(-G[2, 2], -1, 1))))
        ref = np.array([np.interp(ti, gt[:, 0], gt[:, j]) for j in (1, 2)])
        h.append(np.linalg.norm(T[:2, 3] - ref))
    return {"rot3d_median_deg": float(np.median(rot)), "pitch_median_deg": float(np.median(np.abs(pitch))),
            "h_rmse_raw_m": float(np.sqrt(np.mean(np.square(h))))}


def fix_offset(t_fix, xy_fix, gt: np.ndarray, latency_s: float) -> dict:
    """The GNSS fixes' constant offset from a ground truth, along and across its track, with the
    fixes taken `latency_s` earlier than their stamps. On a drive that never turns, a constant
    offset in the vehicle frame (an antenna lever arm) and one in the world (a receiver bias)
    are the same thing: nothing but the fixes says where the vehicle is, so no estimator's
    horizontal RMSE with nothing removed gets below the offset it inherits (`floor_m`, with
    the along part at this latency). Also the latency and along-track offset that a regression
    of the along-track error on speed gives (a latency error grows with speed, an offset not),
    and the spread of the track's heading (how far from straight the drive is)."""
    t = np.asarray(t_fix, float) - latency_s
    sel = (t >= gt[0, 0]) & (t <= gt[-1, 0])
    t = t[sel]
    ref = np.column_stack([np.interp(t, gt[:, 0], gt[:, j]) for j in (1, 2)])
    err = np.asarray(xy_fix, float)[sel] - ref
    v = np.column_stack([np.gradient(ref[:, j], t) for j in (0, 1)])
    speed = np.linalg.norm(v, axis=1)
    fwd = v / np.maximum(speed, 1e-9)[:, None]
    along = np.sum(err * fwd, axis=1)
    across = fwd[:, 0] * err[:, 1] - fwd[:, 1] * err[:, 0]  # + to the left
    moving = speed > 2.0
    slope, icpt = np.polyfit(speed[moving], along[moving], 1)
    heading = np.degrees(np.unwrap(np.arctan2(fwd[moving, 1], fwd[moving, 0])))
    return {"along_m": float(along.mean()), "across_m": float(across.mean()),
            "floor_m": float(np.hypot(along.mean(), across.mean())),
            "regressed_latency_s": float(latency_s - slope), "regressed_along_offset_m": float(icpt),
            "heading_span_deg": float(np.ptp(heading)) if moving.any() else 0.0}


def comma_errors(result, rec, georef) -> dict:
    """Sync result vs comma2k19 ground truth, plus the same metrics for the raw GNSS fixes."""
    import pymap3d

    P = result.positions()
    yaw = [np.arctan2(T[1, 2], T[0, 2]) for _, _, T in result.poses]
    out = {"sync": offset_removed_errors(result.times, P, yaw, rec.groundtruth)}
    out["sync"].update(camera_rotation_errors(result, rec.groundtruth))
    g = rec.gnss
    e, n, u = pymap3d.geodetic2enu(g[:, 1], g[:, 2], g[:, 3], *georef)
    G = np.column_stack([e, n, u])
    # GNSS velocity heading over consecutive fixes (only when moving > 2 m/s)
    v = np.diff(G[:, :2], axis=0) / np.diff(g[:, 0])[:, None]
    moving = np.linalg.norm(v, axis=1) > 2.0
    tv = 0.5 * (g[1:, 0] + g[:-1, 0])
    gyaw = np.arctan2(v[:, 1], v[:, 0])
    raw = offset_removed_errors(g[:, 0], G, None, rec.groundtruth)
    hv = offset_removed_errors(tv[moving], 0.5 * (G[1:] + G[:-1])[moving], gyaw[moving], rec.groundtruth)
    raw["heading_median_deg"] = hv["heading_median_deg"]
    out["raw_gnss"] = raw
    return {k: {kk: round(vv, 3) for kk, vv in d.items()} for k, d in out.items()}


def sea_horizon(gray: np.ndarray, cols: tuple[int, int], rows: tuple[int, int], *, step: int = 4,
                min_contrast: float = 8.0):
    """The sea horizon in one frame, or None: per column in `cols` the row in `rows` with the
    strongest bright-above / dark-below step (sky over sea), then a line through the upper
    ones refitted on those within 2 px (foam and waves lie below it). Returns (point, unit
    direction) in pixels when >= 60 % of the columns agree. For real footage whose camera
    attitude has no ground truth: the horizon is where the camera's horizontal plane meets
    the image, up to the dip (~0.2 deg at 30-50 m above the sea)."""
    import cv2

    g = cv2.GaussianBlur(np.asarray(gray, np.float32), (5, 5), 0)
    (c0, c1), (r0, r1) = cols, rows
    band = g[r0:r1, c0:c1:step]
    d = band[:-6] - band[6:]
    y = np.argmax(d, axis=0)
    ok = d[y, np.arange(d.shape[1])] > min_contrast
    pts = np.column_stack([np.arange(c0, c1, step)[: d.shape[1]], r0 + y + 3])[ok].astype(np.float32)
    if len(pts) < 20:
        return None
    sel = pts[:, 1] <= np.percentile(pts[:, 1], 60)
    for _ in range(3):
        vx, vy, x0, y0 = cv2.fitLine(pts[sel], cv2.DIST_HUBER, 0, 0.01, 0.01).ravel()
        sel = np.abs((pts[:, 0] - x0) * vy - (pts[:, 1] - y0) * vx) < 2.0
        if sel.sum() < 2:
            return None
    return (np.array([x0, y0]), np.array([vx, vy])) if sel.mean() >= 0.6 else None


def horizon_errors(lines: dict, poses: dict, camera: Camera, half_span_px: float = 150.0) -> np.ndarray:
    """Per frame with a detected horizon (`lines`: index -> sea_horizon result; `poses`:
    index -> T_world_cam, z up): the elevation (deg) above the pose's horizontal plane of two
    points on the detected line `half_span_px` either side of its centre. Rows (left, right);
    a perfect attitude gives -dip for both, their difference is the roll error across them."""
    out = []
    for k, (p, u) in sorted(lines.items()):
        if k not in poses:
            continue
        up_c = poses[k][:3, :3].T @ np.array([0.0, 0.0, 1.0])
        u = u if u[0] >= 0 else -u  # left point first
        ends = camera.normalized(np.vstack([p - half_span_px * u, p + half_span_px * u]))
        rays = np.column_stack([ends, np.ones(2)]).T
        out.append(np.degrees(np.arcsin(up_c @ (rays / np.linalg.norm(rays, axis=0)))))
    return np.array(out).reshape(-1, 2)


def recording_horizon_errors(rec, poses: list, cols: tuple[int, int], rows: tuple[int, int]) -> np.ndarray:
    """`horizon_errors` over a recording's frames (sea in pixel columns `cols`, horizon within
    `rows`) for the synced poses [(id, t, T_world_cam)], one per frame."""
    import cv2

    from blendgen.recording.folder import iter_frames

    lines = {}
    for i, img in iter_frames(rec, skip_bad=True):
        h = None if img is None else sea_horizon(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), cols, rows)
        if h is not None:
            lines[i] = h
    return horizon_errors(lines, {i: T for i, (_, _, T) in enumerate(poses)}, rec.camera)
