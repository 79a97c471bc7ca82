"""Video stays on the road: the camera moves over the ground plane with the ego motion (bpy-free).

Entry point (called by the analysis stage, after `camera.estimate_cameras`):

    ground_plane_poses(rec, frame_ids, cameras) -> {frame_id: T_world_cam (4x4)}

`cameras` maps frame_id -> CameraEstimate (or estimate_cameras' (CameraEstimate, horizon)).
World frame as `scene.ground_plane.GroundPlaneTwin`: ground z = 0, the road along +x, the
camera starts at (0, 0, height). Stills (an images recording without temporal order) keep
a fixed pose per frame, with that frame's own height, pitch and roll.

For a video, between consecutive requested frames (`ground_track`):
  - the heading change between the frames comes from the IMU's gyro when the recording has
    one (rate about the road's up axis, integrated), else from ORB visual odometry
    (blendgen.vo) over the whole image;
  - the road 12 m long from 5 m ahead (7, 9, 12 when the hood or a narrow field of view
    hides it), +-3 m across, is warped to a bird's-eye view (4 cm/px) with each frame's
    height, pitch and roll, the newer one along the older heading; phase correlation of
    the two views' derivatives along the road is the metric step (forward, left): the
    camera height gives the scale; the derivative removes lines along the road (lane lines,
    kerbs), which match at any forward shift and pinned tracked points and plain
    correlation to a zero step (aperture problem);
  - GNSS, when the recording has it, gives the step length (ENU distance between the
    interpolated positions at the two frame times);
  - a step without a reliable road match (weak phase-correlation peak, no step while VO
    sees parallax, or a step unlike the median of the last good ones) keeps that median
    (constant velocity), said in `status`.
The heading over the (straight) twin road is the camera's vanishing-point yaw relative to
the road (despiked by a 3-frame median), so the twin's lanes stay on the real road; the
gyro or VO carries it through frames without one. The camera's yaw relative to the vehicle is the median of
those (the mount does not turn). A parked car beside the road recedes as the ego car
passes it.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from blendgen.analysis.camera import imu_usable, road_axes

from blendgen.geometry import Camera, R_world_cam_from_ypr, make_pose
from blendgen.recording.frames import is_sequence, read_frames

log = logging.getLogger(__name__)

NEAR_M = (5.0, 7.0, 9.0, 12.0)  # the road patch starts at the first of these fully in view...
PATCH_M = 12.0                  # ...and is this long
LATERAL_M = 3.0                 # +- across: the ego lane's two lines
BEV_RES = 0.04                  # metres per bird's-eye pixel
MIN_RESPONSE = 0.1              # phase-correlation peak below this: no reliable step
VO_FEATURES = 500               # VO only gives the heading here: fewer features than sync's 1500


@dataclass
class Step:
    forward: float = 0.0          # metres, in the previous frame's heading
    left: float = 0.0
    dyaw: float = 0.0             # radians, > 0 turns left
    status: str = "first"        # "ground", "ground+vo", "ground+imu", "constant_velocity", "still", "first"; "+gnss"
    response: float = 0.0         # phase-correlation peak (0..1) of a step from the road


@dataclass
class Track:
    poses: dict[str, np.ndarray] = field(default_factory=dict)
    steps: dict[str, Step] = field(default_factory=dict)


def _est(c):
    return c[0] if isinstance(c, tuple) else c


def _pose(x, y, heading, est, mount_yaw=0.0) -> np.ndarray:
    R = R_world_cam_from_ypr(heading + mount_yaw, math.radians(est.pitch_deg), math.radians(est.roll_deg))
    return make_pose(R, [x, y, est.height_m])


def bird_eye(gray: np.ndarray, camera: Camera, est, hood=None, yaw: float = 0.0,
             near: float = NEAR_M[0]) -> tuple[np.ndarray, bool]:
    """The road patch near..near + PATCH_M ahead, +-LATERAL_M across, seen from above at
    BEV_RES m/px (rows: forward, far at the top; columns: left to right) along a heading
    `yaw` (rad, > 0: the camera looks left of it), and whether all of it was in view
    (inside the frame, above the hood)."""
    fwd = np.arange(near + PATCH_M, near, -BEV_RES)
    left = np.arange(LATERAL_M, -LATERAL_M, -BEV_RES)
    F, L = np.meshgrid(fwd, left, indexing="ij")
    R = road_axes(math.radians(est.pitch_deg), math.radians(est.roll_deg), yaw)
    X = F[..., None] * R[0] + L[..., None] * R[1] - est.height_m * R[2]       # camera frame
    uv, _ = camera.project(X.reshape(-1, 3))
    mx, my = uv[:, 0].reshape(F.shape).astype(np.float32), uv[:, 1].reshape(F.shape).astype(np.float32)
    inside = (mx >= 0) & (mx <= gray.shape[1] - 1) & (my >= 0) & (my <= gray.shape[0] - 1)
    if hood is not None:
        edge = np.array(hood[:-2], dtype=float)
        inside &= my < np.interp(mx, edge[:, 0], edge[:, 1]) - 2
    bev = cv2.remap(gray, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return bev.astype(np.float32), bool(inside.mean() > 0.98)


def ground_step(bev0: np.ndarray, bev1: np.ndarray) -> Step | None:
    """Metric step between two bird's-eye views of the road by phase correlation: the
    ground moves back by the distance the car moves forward."""
    win = cv2.createHanningWindow(bev0.shape[::-1], cv2.CV_32F)
    # the derivative along the road removes lines along it (lane lines, kerbs): they match at
    # every forward shift and would tie the peak to zero
    a = cv2.Sobel(bev0, cv2.CV_32F, 0, 1, ksize=3)
    b = cv2.Sobel(bev1, cv2.CV_32F, 0, 1, ksize=3)
    (dx, dy), response = cv2.phaseCorrelate(a, b, win)
    if response < MIN_RESPONSE:
        return None
    # rows run from far to near: the ground moving back by d metres shifts the patch down (+dy)
    return Step(forward=float(dy * BEV_RES), left=float(dx * BEV_RES), status="ground", response=float(response))


def _vo_yaw(res, est) -> float | None:
    """Heading change (about the road's up axis) of a VO rotation, radians, > 0 left."""
    if not res.has_rotation:
        return None
    U = road_axes(math.radians(est.pitch_deg), math.radians(est.roll_deg), 0.0)
    R_body = U @ res.R_c1c2 @ U.T         # rotation in the (forward, left, up) frame
    return float(math.atan2(R_body[1, 0], R_body[0, 0]))


def _gyro_yaw(rec, t0: float, t1: float, est) -> float | None:
    """Heading change (rad, > 0 left) between two frame times from the IMU's gyro: the rate
    about the road's up axis, integrated."""
    if not imu_usable(rec):
        return None
    t = rec.imu[:, 0]
    t0, t1 = t0 + rec.time_offset_cam_imu, t1 + rec.time_offset_cam_imu
    if t0 < t[0] or t1 > t[-1]:
        return None
    U = road_axes(math.radians(est.pitch_deg), math.radians(est.roll_deg), 0.0)[2]
    rate = rec.imu[:, 1:4] @ np.asarray(rec.T_cam_imu)[:3, :3].T @ U
    a, b = np.searchsorted(t, t0, "right"), np.searchsorted(t, t1)
    ts = np.r_[t0, t[a:b], t1]
    return float(np.trapz(np.interp(ts, t, rate), ts))


def _road_yaw(order, ests) -> dict[str, float | None]:
    """The camera's yaw relative to the road per frame (rad): the vanishing point's, despiked
    by a 3-frame median (a turning car changes it steadily, a wider median would lag);
    None where the frame has no confident one."""
    raw = [math.radians(ests[f].yaw_deg) if ests[f].yaw_deg is not None and ests[f].confidence > 0.2 else None
           for f in order]
    out = {}
    for k, f in enumerate(order):
        near = [v for v in raw[max(k - 1, 0):k + 2] if v is not None]
        out[f] = float(np.median(near)) if raw[k] is not None and len(near) == 3 else raw[k]
    return out


def _gnss_steps(rec, times: np.ndarray) -> np.ndarray | None:
    if len(rec.gnss) < 2 or times[0] < rec.gnss[0, 0] or times[-1] > rec.gnss[-1, 0]:
        return None
    from pymap3d import geodetic2enu

    g = rec.gnss
    e, n, _ = geodetic2enu(g[:, 1], g[:, 2], g[:, 3], g[0, 1], g[0, 2], g[0, 3])
    x, y = np.interp(times, g[:, 0], e), np.interp(times, g[:, 0], n)
    return np.hypot(np.diff(x), np.diff(y))


@dataclass
class PairMotion:
    """What two consecutive frames say about the motion between them: the per-frame part of the
    ego motion, computed for any stretch of a video in parallel (`pair_motions`)."""

    decoded: bool = True              # this frame decoded
    yaw: float | None = None          # heading change since the previous frame (rad, > 0 left)
    yaw_src: str = "vo"               # "imu" | "vo"
    ground: list[float] | None = None  # the road's step [forward, left, response] (None: unreliable)
    has_prev: bool = False            # the previous frame decoded (a step was looked for)

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class ChainState:
    """The recording-wide, sequential part: the pose so far and the recent steps (the chain
    of `chain_step` calls, one per frame in order)."""

    k: int = 0
    x: float = 0.0
    y: float = 0.0
    heading: float = 0.0
    recent: list = field(default_factory=list)      # the last good steps: constant velocity uses their median
    last: Step = field(default_factory=lambda: Step(status="first"))

    def to_dict(self) -> dict:
        return {"k": self.k, "x": self.x, "y": self.y, "heading": self.heading, "recent": self.recent,
                "last": dict(self.last.__dict__)}

    @classmethod
    def from_dict(cls, d: dict) -> "ChainState":
        return cls(d["k"], d["x"], d["y"], d["heading"], [tuple(r) for r in d["recent"]], Step(**d["last"]))


def first_near(gray: np.ndarray, camera: Camera, est, hood) -> float:
    """The nearest road patch start fully in view (the first frame decides it for the video)."""
    return next((n for n in NEAR_M if bird_eye(gray, camera, est, hood, near=n)[1]), NEAR_M[-1])


def pair_motions(rec, frames, ests, hoods, near: float | None = None, *, times=None):
    """Yield (frame_id, PairMotion, near) for frames [(frame_id, BGR or None), ...] in order; the
    first one only primes the VO and the previous bird's-eye view (a stretch of a video starts
    one frame early). `ests`/`hoods`: per frame id; `times`: per frame id (the gyro's interval);
    `near`: the road patch's start (None: `first_near` of the first frame that decodes)."""
    from blendgen.vo import OrbVo, VoConfig

    camera = rec.camera
    vo = OrbVo(camera, VoConfig(n_features=VO_FEATURES))
    prev = None
    t_prev = None
    for fid, im in frames:
        est, hood = _est(ests[fid]), (hoods or {}).get(fid)
        t = None if times is None else times[fid]
        if im is None:
            yield fid, PairMotion(decoded=False), near
            prev, t_prev = None, t
            continue
        gray = cv2.cvtColor(im, cv2.COLOR_BGR2GRAY)
        res = vo.track(gray)
        if near is None:
            near = first_near(gray, camera, est, hood)
        m = PairMotion(has_prev=prev is not None)
        if prev is not None:
            vy, m.yaw_src = (_gyro_yaw(rec, t_prev, t, est), "imu") if t is not None else (None, "imu")
            if vy is None:
                vy, m.yaw_src = _vo_yaw(res, est), "vo"
            m.yaw = vy
            # this frame's road seen along the previous heading: the shift is then the step
            bev, whole = bird_eye(gray, camera, est, hood, yaw=vy if vy is not None else 0.0, near=near)
            step = ground_step(prev[0], bev) if whole and prev[1] else None
            if step is not None and res.status == "ok" and abs(step.forward) < 0.05:
                step = None     # the image moves with parallax but the road would not: distrust
            m.ground = None if step is None else [step.forward, step.left, step.response]
        prev, t_prev = bird_eye(gray, camera, est, hood, near=near), t
        yield fid, m, near


def chain_step(state: ChainState, m: PairMotion, road_yaw: float | None, mount_yaw: float,
               gnss_step: float | None) -> Step:
    """Advance the pose by one frame (in place); returns the frame's step. `road_yaw`: the
    frame's despiked road yaw (`_road_yaw`), `gnss_step`: the GNSS distance since the previous
    frame, when the recording has GNSS."""
    k, last = state.k, state.last
    if not m.decoded:
        step = Step(last.forward, last.left, last.dyaw, "constant_velocity")
    else:
        step = Step(status="first") if k == 0 else Step(last.forward, last.left, last.dyaw, "constant_velocity")
        if m.has_prev:
            vy = m.yaw
            step = None if m.ground is None else Step(m.ground[0], m.ground[1], status="ground", response=m.ground[2])
            typical = np.median(state.recent, axis=0) if len(state.recent) >= 5 else None
            if (step is not None and typical is not None
                    and abs(step.forward - typical[0]) > 0.5 * abs(typical[0]) + 0.2):
                step = None     # a car cannot change speed that much between two frames
            if step is None:
                f_, l_ = typical if typical is not None else (last.forward, last.left)
                step = Step(float(f_), float(l_), vy if vy is not None else last.dyaw, "constant_velocity")
            else:
                state.recent = (state.recent + [(step.forward, step.left)])[-9:]
                step.dyaw = vy if vy is not None else 0.0
                step.status = f"ground+{m.yaw_src}" if vy is not None else "ground"
    if k > 0 and gnss_step is not None:
        n = math.hypot(step.forward, step.left)
        direction = (step.forward / n, step.left / n) if n > 1e-6 else (1.0, 0.0)
        step.forward, step.left = direction[0] * gnss_step, direction[1] * gnss_step
        step.status += "+gnss"
    if k > 0:
        c, s = math.cos(state.heading), math.sin(state.heading)
        state.x += c * step.forward - s * step.left
        state.y += s * step.forward + c * step.left
        # the road's vanishing point holds the heading to the (straight) twin road; the
        # gyro or VO only carries it over frames without one
        state.heading = road_yaw - mount_yaw if road_yaw is not None else state.heading + step.dyaw
        state.last = step
    elif road_yaw is not None:
        state.heading = road_yaw - mount_yaw
    state.k = k + 1
    return step


def chain_pose(state: ChainState, est, mount_yaw: float) -> np.ndarray:
    """The pose of the frame `chain_step` just advanced to."""
    return _pose(state.x, state.y, state.heading, _est(est), mount_yaw)


def mount_yaw_of(road_yaw: dict) -> float:
    """The camera's yaw relative to the vehicle: the median of the frames' road yaw."""
    known = [v for v in road_yaw.values() if v is not None]
    return float(np.median(known)) if known else 0.0


def ground_track(rec, frame_ids, cameras, *, hoods=None, progress: bool = False) -> Track:
    """Poses and the per-step record; see the module doc. In one pass: `pair_motions` (per
    pair of frames) then `chain_step` (the sequence), as the farm runs them (pipeline.analysis_tasks)."""
    frame_ids = list(frame_ids)
    ests = {f: _est(cameras[f]) for f in frame_ids}
    track = Track()
    if not is_sequence(rec) or len(frame_ids) < 2:
        for f in frame_ids:
            track.poses[f] = _pose(0.0, 0.0, 0.0, ests[f])
            track.steps[f] = Step(status="still")
        return track
    index = {rec.frame_id(i): i for i in range(rec.n_frames)}
    order = sorted(frame_ids, key=index.__getitem__)
    times = np.array([rec.frames_t[index[f]] for f in order])
    road_yaw = _road_yaw(order, ests)
    mount_yaw = mount_yaw_of(road_yaw)
    gnss = _gnss_steps(rec, times)
    frames = read_frames(rec, order, progress=progress, desc="ego motion")
    state = ChainState()
    t_of = dict(zip(order, times.tolist()))
    for k, (fid, m, _) in enumerate(pair_motions(rec, frames, ests, hoods, times=t_of)):
        step = chain_step(state, m, road_yaw[fid], mount_yaw, None if gnss is None or k == 0 else float(gnss[k - 1]))
        track.poses[fid] = chain_pose(state, ests[fid], mount_yaw)
        track.steps[fid] = step
    moved = [f for f in order if track.steps[f].status.startswith("constant_velocity")]
    if moved:
        log.info("ego motion: %d of %d steps kept the previous motion (no road points or VO)", len(moved), len(order))
    return track


def ground_plane_poses(rec, frame_ids, cameras, *, hoods=None, progress: bool = False) -> dict[str, np.ndarray]:
    return ground_track(rec, frame_ids, cameras, hoods=hoods, progress=progress).poses
