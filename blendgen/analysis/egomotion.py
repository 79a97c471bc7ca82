"""Video stays on the road: the camera moves over the ground plane with the ego motion (bpy-free).

Entry point (called by the analysis stage, after `camera.estimate_cameras`):

    ground_plane_poses(rec, frame_ids, cameras) -> {frame_id: T_world_cam (4x4)}

`cameras` maps frame_id -> CameraEstimate (or estimate_cameras' (CameraEstimate, horizon)).
World frame as `scene.ground_plane.GroundPlaneTwin`: ground z = 0, the road along +x, the
camera starts at (0, 0, height). Stills (an images recording without temporal order) keep
a fixed pose per frame, with that frame's own height, pitch and roll.

For a video, between consecutive requested frames (`ground_track`):
  - road points (below the horizon, above the hood, 3..25 m ahead) are tracked with
    pyramidal Lucas-Kanade (forward-backward checked) and put on the ground with each
    frame's height, pitch and roll: a RANSAC rigid 2-D fit of the two point sets is the
    metric step (forward, left, heading change), the camera height giving the scale;
  - ORB visual odometry (blendgen.sync.vo) gives the heading change from the whole image;
    it is averaged in when it agrees with the road's within 1 deg and replaces it when the
    road gives no step;
  - GNSS, when the recording has it, gives the step length (ENU distance between the
    interpolated positions at the two frame times);
  - a step with neither keeps the previous step's motion (constant velocity), said in
    `status`.
The camera's yaw relative to the vehicle is the recording's median vanishing-point yaw
(the mount does not turn), so a parked car beside the road recedes as the ego car passes.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from blendgen.analysis.camera import _ground_points, is_sequence, read_frames, road_axes
from blendgen.geometry import Camera, R_world_cam_from_ypr, make_pose

log = logging.getLogger(__name__)

MAX_WIDTH = 640
NEAR_M, FAR_M = 3.0, 12.0     # road points used for the metric step (farther: noisier)


@dataclass
class Step:
    forward: float = 0.0          # metres, in the previous frame's heading
    left: float = 0.0
    dyaw: float = 0.0             # radians, > 0 turns left
    status: str = "first"        # "ground", "ground+vo", "constant_velocity", "still", "first"; "+gnss"
    inliers: int = 0


@dataclass
class Track:
    poses: dict[str, np.ndarray] = field(default_factory=dict)
    steps: dict[str, Step] = field(default_factory=dict)


def _est(c):
    return c[0] if isinstance(c, tuple) else c


def _pose(x, y, heading, est, mount_yaw=0.0) -> np.ndarray:
    R = R_world_cam_from_ypr(heading + mount_yaw, math.radians(est.pitch_deg), math.radians(est.roll_deg))
    return make_pose(R, [x, y, est.height_m])


def _road_mask(shape, camera: Camera, est, hood, scale: float) -> np.ndarray:
    """Pixels (at the working scale) of the ground between NEAR_M and FAR_M ahead, above the hood."""
    h, w = shape
    R = road_axes(math.radians(est.pitch_deg), math.radians(est.roll_deg), 0.0)
    vs, us = np.mgrid[0:h:4, 0:w:4]
    px = np.c_[us.ravel(), vs.ravel()].astype(float)
    fwd, _ = _ground_points((px + 0.5) / scale - 0.5, camera, R)
    ok = (np.nan_to_num(fwd, nan=-1.0) * est.height_m).reshape(vs.shape)
    small = ((ok > NEAR_M) & (ok < FAR_M)).astype(np.uint8)
    mask = cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST)
    if hood is not None:
        poly = np.round((np.array(hood) + 0.5) * scale - 0.5).astype(np.int32)
        cv2.fillPoly(mask, [poly], 0)
        mask = cv2.erode(mask, np.ones((9, 9), np.uint8))
    return mask


def _to_ground(px: np.ndarray, camera: Camera, est) -> np.ndarray:
    if camera.distorted and len(px):
        px = cv2.undistortPoints(px.reshape(-1, 1, 2), camera.K, camera.D, P=camera.K).reshape(-1, 2)
    R = road_axes(math.radians(est.pitch_deg), math.radians(est.roll_deg), 0.0)
    fwd, left = _ground_points(px, camera, R)
    return np.c_[fwd, left] * est.height_m


def ground_step(prev_gray, gray, camera: Camera, est0, est1, mask, scale: float) -> Step | None:
    """Metric motion between two frames from road points tracked on the ground plane."""
    p0 = cv2.goodFeaturesToTrack(prev_gray, 400, 0.005, 7, mask=mask)
    if p0 is None or len(p0) < 12:
        return None
    p1, st, _ = cv2.calcOpticalFlowPyrLK(prev_gray, gray, p0, None, winSize=(21, 21), maxLevel=3)
    pb, st2, _ = cv2.calcOpticalFlowPyrLK(gray, prev_gray, p1, None, winSize=(21, 21), maxLevel=3)
    good = (st.ravel() == 1) & (st2.ravel() == 1) & (np.linalg.norm((pb - p0).reshape(-1, 2), axis=1) < 0.7)
    if good.sum() < 12:
        return None
    a = (p0.reshape(-1, 2)[good] + 0.5) / scale - 0.5
    b = (p1.reshape(-1, 2)[good] + 0.5) / scale - 0.5
    g0, g1 = _to_ground(a, camera, est0), _to_ground(b, camera, est1)
    ok = np.all(np.isfinite(g0), axis=1) & np.all(np.isfinite(g1), axis=1)
    if ok.sum() < 12:
        return None
    g0, g1 = g0[ok], g1[ok]
    A, inl = cv2.estimateAffinePartial2D(g0.astype(np.float32), g1.astype(np.float32),
                                         method=cv2.RANSAC, ransacReprojThreshold=0.15, maxIters=500)
    if A is None or inl.sum() < 10:
        return None
    if not 0.9 < math.hypot(A[0, 0], A[1, 0]) < 1.1:   # not a rigid motion: not points on the ground
        return None
    inl = inl.ravel() > 0
    # g1 = M g0 + c refitted on the inliers; a pixel's error on the ground grows with distance^2
    M, c = _rigid_2d(g0[inl], g1[inl], 1.0 / np.sum(g0[inl] ** 2, axis=1))
    d = -M.T @ c                            # camera 1's origin in camera 0's ground frame
    fwd1 = M.T @ np.array([1.0, 0.0])
    return Step(float(d[0]), float(d[1]), float(math.atan2(fwd1[1], fwd1[0])), "ground", int(inl.sum()))


def _rigid_2d(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least-squares rotation M and translation c with b = M a + c (2-D Kabsch)."""
    w = w / w.sum()
    ca, cb = w @ a, w @ b
    U, _, Vt = np.linalg.svd((w[:, None] * (b - cb)).T @ (a - ca))
    M = U @ np.diag([1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return M, cb - M @ ca


def _vo_yaw(res, est) -> float | None:
    """Heading change (about the road's up axis) of a VO rotation, radians, > 0 left."""
    if not res.has_rotation:
        return None
    U = road_axes(math.radians(est.pitch_deg), math.radians(est.roll_deg), 0.0)
    R_body = U @ res.R_c1c2 @ U.T         # rotation in the (forward, left, up) frame
    return float(math.atan2(R_body[1, 0], R_body[0, 0]))


def _gnss_steps(rec, times: np.ndarray) -> np.ndarray | None:
    if len(rec.gnss) < 2 or times[0] < rec.gnss[0, 0] or times[-1] > rec.gnss[-1, 0]:
        return None
    from pymap3d import geodetic2enu

    g = rec.gnss
    e, n, _ = geodetic2enu(g[:, 1], g[:, 2], g[:, 3], g[0, 1], g[0, 2], g[0, 3])
    x, y = np.interp(times, g[:, 0], e), np.interp(times, g[:, 0], n)
    return np.hypot(np.diff(x), np.diff(y))


def ground_track(rec, frame_ids, cameras, *, hoods=None, progress: bool = False) -> Track:
    """Poses and the per-step record; see the module doc."""
    from blendgen.sync.vo import OrbVo

    frame_ids = list(frame_ids)
    ests = {f: _est(cameras[f]) for f in frame_ids}
    track = Track()
    if not is_sequence(rec) or len(frame_ids) < 2:
        for f in frame_ids:
            track.poses[f] = _pose(0.0, 0.0, 0.0, ests[f])
            track.steps[f] = Step(status="still")
        return track
    yaws = [e.yaw_deg for e in ests.values() if e.yaw_deg is not None and e.confidence > 0.2]
    mount_yaw = math.radians(float(np.median(yaws))) if yaws else 0.0
    camera = rec.camera
    vo = OrbVo(camera)
    index = {rec.frame_id(i): i for i in range(rec.n_frames)}
    order = sorted(frame_ids, key=index.__getitem__)
    times = np.array([rec.frames_t[index[f]] for f in order])
    gnss = _gnss_steps(rec, times)
    x = y = heading = 0.0
    prev = None
    last = Step(status="first")
    for k, (fid, im) in enumerate(read_frames(rec, order, progress=progress, desc="ego motion")):
        est = ests[fid]
        if im is None:
            step = Step(last.forward, last.left, last.dyaw, "constant_velocity")
            gray = None
        else:
            full = cv2.cvtColor(im, cv2.COLOR_BGR2GRAY)
            res = vo.track(full)
            scale = min(1.0, MAX_WIDTH / full.shape[1])
            gray = cv2.resize(full, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1 else full
            step = Step(status="first")
            if prev is not None:
                pgray, pest, pfid = prev
                mask = _road_mask(pgray.shape, camera, pest, (hoods or {}).get(pfid), scale)
                step = ground_step(pgray, gray, camera, pest, est, mask, scale) if pgray is not None else None
                vy = _vo_yaw(res, est)
                if step is None:
                    step = Step(last.forward, last.left, vy if vy is not None else last.dyaw, "constant_velocity")
                elif vy is not None and abs(vy - step.dyaw) < math.radians(1.0):
                    step.dyaw, step.status = 0.5 * (vy + step.dyaw), "ground+vo"   # they agree: average
        if k > 0 and gnss is not None:
            n = math.hypot(step.forward, step.left)
            direction = (step.forward / n, step.left / n) if n > 1e-6 else (1.0, 0.0)
            step.forward, step.left = direction[0] * gnss[k - 1], direction[1] * gnss[k - 1]
            step.status += "+gnss"
        if k > 0:
            c, s = math.cos(heading), math.sin(heading)
            x += c * step.forward - s * step.left
            y += s * step.forward + c * step.left
            heading += step.dyaw
            last = step
        track.poses[fid] = _pose(x, y, heading, est, mount_yaw)
        track.steps[fid] = step
        prev = (gray, est, fid)
    moved = [f for f in order if track.steps[f].status.startswith("constant_velocity")]
    if moved:
        log.info("ego motion: %d of %d steps kept the previous motion (no road points or VO)", len(moved), len(order))
    return track


def ground_plane_poses(rec, frame_ids, cameras, *, hoods=None, progress: bool = False) -> dict[str, np.ndarray]:
    return ground_track(rec, frame_ids, cameras, hoods=hoods, progress=progress).poses
