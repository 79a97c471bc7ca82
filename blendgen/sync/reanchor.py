"""Drift re-anchoring: pull the filtered trajectory onto the global fixes (LUT/GNSS) segment by
segment, and spread each correction smoothly so the trajectory never jumps.

Each segment of `every_s` seconds gets one anchor correction, a planar rigid transform plus a
height offset (yaw dpsi, translation b): the robust mean of the fix residuals in the segment.
Both parts are kept only beyond what the fix noise explains (3 sigma, soft threshold), so a
trajectory that already agrees with the fixes (the smoothed EKF usually does) is left alone,
and one that drifted (e.g. fixes rejected or filtered out, a biased LUT segment) is pulled back.
Between anchors the (dpsi, b) parameters are interpolated linearly in distance travelled, so
the corrected trajectory is continuous (no step at segment borders) and a parked vehicle is
not made to creep.
"""

from __future__ import annotations

import numpy as np

from blendgen import so3

MERGE_M = 1.0


def _interp_positions(t_q, t, P):
    return np.stack([np.interp(t_q, t, P[:, k]) for k in range(3)], axis=1)


def reanchor(result, fix_t, fix_xyz, fix_inside, fix_std, every_s: float, T_imu_cam) -> int:
    """Correct `result.poses` in place. Returns the number of anchors used."""
    if len(result.poses) < 2 or len(fix_t) < 5:
        return 0
    t = np.array([p[1] for p in result.poses])
    T_cam_imu = np.linalg.inv(T_imu_cam)
    # body (GNSS antenna ~ IMU) positions from the camera poses
    body = np.array([(p[2] @ T_cam_imu)[:3, 3] for p in result.poses])
    sel = fix_inside & (fix_t >= t[0]) & (fix_t <= t[-1])
    ft, fx, fs = fix_t[sel], fix_xyz[sel], fix_std[sel]
    if len(ft) < 5:
        return 0
    est = _interp_positions(ft, t, body)
    res = fx - est
    # reject gross outliers (multipath) with a MAD test before averaging
    med = np.median(res, axis=0)
    mad = 1.4826 * np.median(np.abs(res - med), axis=0) + 1e-6
    good = np.all(np.abs(res - med) < 5 * mad, axis=1)
    edges = np.arange(t[0], t[-1] + every_s, every_s)
    anchors = []
    for a, b in zip(edges[:-1], edges[1:]):
        m = good & (ft >= a) & (ft < b)
        if m.sum() < 5:
            continue
        e, r, s = est[m], res[m], fs[m]
        c = e.mean(axis=0)
        # planar Procrustes of estimate -> fixes about the segment centroid
        A = e[:, :2] - c[:2]
        B = (e + r)[:, :2] - (c[:2] + r[:, :2].mean(axis=0))
        spread = np.sqrt(np.mean(np.sum(A**2, axis=1)))
        psi = 0.0
        if spread > 1.0:
            C = A.T @ B
            psi = float(np.arctan2(C[0, 1] - C[1, 0], C[0, 0] + C[1, 1]))
            sigma_psi = float(np.mean(s)) / (spread * np.sqrt(len(A)))
            if abs(psi) < 3 * sigma_psi:
                psi = 0.0
        shift = np.median(r, axis=0)
        # keep only what the fixes can actually tell apart from zero (the median of n fixes
        # has a standard deviation of ~1.25 sigma / sqrt(n)); a smoothed trajectory that already
        # agrees with the fixes is left alone instead of inheriting their noise
        sig = 1.2533 * float(np.mean(s)) / np.sqrt(len(r)) * np.array([1.0, 1.0, 2.0])
        shift = np.where(np.abs(shift) > 3 * sig, shift - 3 * sig * np.sign(shift), 0.0)
        Rz = so3.yaw_rotation(psi)
        bvec = c + shift - Rz @ c  # x' = Rz x + b maps the segment onto the fixes
        anchors.append((0.5 * (a + b), psi, bvec))
    if not anchors:
        return 0
    ta = np.array([a[0] for a in anchors])
    psi = np.array([a[1] for a in anchors])
    bv = np.array([a[2] for a in anchors])
    # spread along the distance travelled, not time: a parked car gets a constant correction
    # (so it does not creep), a moving one a gradual one. The small time term keeps the
    # parameter strictly increasing through standstills.
    step = np.linalg.norm(np.diff(body, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(step)]) + 1e-3 * (t - t[0])
    sa = np.interp(ta, t, s)
    # anchors less than MERGE_M apart along the path (a standstill) become one: otherwise the
    # correction would swing between them while the car does not move
    groups = np.concatenate([[0], np.cumsum(np.diff(sa) > MERGE_M)])
    sa = np.array([sa[groups == g].mean() for g in np.unique(groups)])
    psi = np.array([psi[groups == g].mean() for g in np.unique(groups)])
    bv = np.array([bv[groups == g].mean(axis=0) for g in np.unique(groups)])
    psi_t = np.interp(s, sa, psi)
    b_t = _interp_positions(s, sa, bv)
    for k, (fid, tk, T) in enumerate(result.poses):
        Rz = so3.yaw_rotation(psi_t[k])
        T2 = T.copy()
        T2[:3, :3] = Rz @ T[:3, :3]
        T2[:3, 3] = Rz @ T[:3, 3] + b_t[k]
        result.poses[k] = (fid, tk, T2)
        result.quality[k]["flags"] = sorted(set(result.quality[k]["flags"]) | {"reanchored"})
    return len(anchors)
