"""The camera from the frames: pitch, roll, height and focal length over the road (bpy-free).

Entry point (called by the analysis stage):

    estimate_cameras(rec, frame_ids, *, user=None, users=None, car_boxes=None, progress=False, hoods=None)
        -> {frame_id: (CameraEstimate, horizon)}

`user` is the job's `ground_plane` section (numbers are fixed, "auto" is estimated; None:
all estimated), `users` maps frame_id -> [(cls, [x, y, w, h]), ...] of the detector's road
users (`car_boxes`: frame_id -> boxes of cars only), `horizon` is [[0, v0], [width - 1, v1]]
(model.py) or None when it leaves the frame's rows far behind.

Per frame (`frame_cues`, independent of the other frames):
  1. line segments (OpenCV LSD or FLD on a <= 640 px wide grey image), undistorted;
  2. a Manhattan frame by RANSAC (`estimate_frame`): the road direction F (lane markings, road
     edges, kerbs, building lines along the street), the vertical U (building edges, poles)
     and the crosswise L, hypothesised from two segments for one vanishing point and one
     segment for the other (orthogonality), scored by the length of the segments that point
     at one of the three vanishing points; priors |pitch|, |roll| < 25 deg, the road's
     vanishing point near the view; near-level segments never point along the road;
  3. least squares (soft L1) on pitch, roll, yaw over the inliers; roll is only estimated
     when vertical or crosswise segments support it, otherwise it is the prior (reason
     logged); the focal length too when the calibration was a guessed field of view;
  4. the road users standing whole on the road and the ego lane's two painted lines.
Over the recording, one reduction (`mount.estimate_mount`): stills share one mount (pitch,
roll, height) with small per-frame deviations; a video's pitch and roll are smoothed over
+-0.5 s here (gravity from the IMU averaged in where there is one) and the reduction fits
its one height.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from scipy.optimize import least_squares

from blendgen.analysis.mount import FrameCues, Mount, focal_consensus
from blendgen.frame_analysis import CameraEstimate
from blendgen.geometry import Camera, R_world_cam_from_ypr
from blendgen.recording.frames import frame_indices, is_sequence, read_frames

log = logging.getLogger(__name__)

DEFAULT_HEIGHT_M = 1.5      # a car's dashcam
DEFAULT_LANE_WIDTH_M = 3.5
CAR_WIDTH_M = 1.8           # typical passenger car (mirrors folded out of the box)
CAR_LENGTH_M = 4.5
SMOOTH_S = 0.5              # video: pitch and roll are a weighted median over +- this
HEIGHT_SAMPLE_FRAMES = 48   # video: frames spread over the recording that may give the height (lanes: ~1 in 10)
FRAME_FALLBACK_STD_DEG = 1.0   # video: a frame without its own pitch/roll takes the recording's median, this uncertain
DEFAULT_STD_DEG = 3.0       # nothing to estimate from: dashcams are mounted within a few degrees of level


@dataclass
class CameraConfig:
    detector: str = "lsd"             # "lsd" (cv2.createLineSegmentDetector) or "fld" (ximgproc)
    max_width: int = 640              # frames are downscaled to this for line detection
    max_segments: int = 250           # the longest ones are kept
    min_length_frac: float = 0.025    # of the (downscaled) image diagonal
    ransac_iters: int = 250
    inlier_deg: float = 1.5           # angle between a segment and the line to its vanishing point
    min_support: int = 4              # segments an axis needs before it constrains anything
    min_segments: int = 8             # fewer usable segments: the frame falls back
    max_pitch_deg: float = 25.0
    max_roll_deg: float = 25.0
    max_yaw_deg: float = 50.0
    yaw_margin_deg: float = 10.0      # the road's vanishing point at most this far outside the view
    level_deg: float = 4.0            # segments this close to level never point along the road
    seed: int = 0


@dataclass
class FrameCamera:
    """One frame's estimate before smoothing (angles in degrees)."""

    pitch: float | None
    roll: float | None
    yaw: float | None = None
    fx: float | None = None
    pitch_std: float = float("inf")
    roll_std: float = float("inf")
    confidence: float = 0.0
    support: dict[str, int] = field(default_factory=dict)   # axis -> inlier segments
    fx_fit: float | None = None           # the focal length this frame's lines fit (any precision) ...
    fx_log_std: float = float("inf")      # ... and its standard deviation (of log fx)
    height_lanes: float | None = None     # height from the lane-width prior, m
    height_cars: float | None = None      # from real cars' widths, m
    reasons: list[str] = field(default_factory=list)
    segments: np.ndarray | None = None    # (N, 4) undistorted pixel endpoints, for drawing
    labels: np.ndarray | None = None      # (N,) axis index 0 F, 1 L, 2 U, -1 none


# ----------------------------------------------------------------------------- geometry

def road_axes(pitch: float, roll: float, yaw: float) -> np.ndarray:
    """Rows: the road's forward F, left L and up U axes in the camera frame (radians in):
    R_world_cam of `geometry.R_world_cam_from_ypr` with the road along world x."""
    return R_world_cam_from_ypr(yaw, pitch, roll)


def angles_from_axes(F: np.ndarray, U: np.ndarray) -> tuple[float, float, float]:
    """(pitch, roll, yaw) in radians from the forward and up axes in the camera frame;
    yaw > 0: the camera looks left of the road."""
    U = U / np.linalg.norm(U)
    pitch = math.asin(float(np.clip(U[2], -1, 1)))
    roll = math.atan2(-U[0], -U[1])
    # yaw: F in the camera's level frame (undo roll and pitch)
    R0 = road_axes(pitch, roll, 0.0)           # rows: F0, L0, U at yaw 0
    yaw = math.atan2(-float(F @ R0[1]), float(F @ R0[0]))
    return pitch, roll, yaw


def horizon_line(camera: Camera, U: np.ndarray) -> list[list[float]] | None:
    """The ground plane's vanishing line K^-T U as [[0, v0], [w - 1, v1]] (None if ~vertical)."""
    lh = np.linalg.inv(camera.K).T @ U
    if abs(lh[1]) < 1e-9:
        return None
    u = np.array([0.0, camera.width - 1.0])
    v = -(lh[0] * u + lh[2]) / lh[1]
    return [[float(u[0]), float(v[0])], [float(u[1]), float(v[1])]]


# ----------------------------------------------------------------------------- segments

def detect_segments(bgr: np.ndarray, camera: Camera, cfg: CameraConfig) -> np.ndarray:
    """(N, 4) x1 y1 x2 y2 in undistorted full-resolution pixels, longest first."""
    gray = bgr if bgr.ndim == 2 else cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    h, w = gray.shape
    s = min(1.0, cfg.max_width / w)
    small = cv2.resize(gray, (round(w * s), round(h * s)), interpolation=cv2.INTER_AREA) if s < 1 else gray
    min_len = cfg.min_length_frac * math.hypot(*small.shape)
    if cfg.detector == "lsd":
        lines = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD).detect(small)[0]
    elif cfg.detector == "fld":
        lines = cv2.ximgproc.createFastLineDetector(int(min_len), 1.414, 50, 50, 3, True).detect(small)
    else:
        raise ValueError(f"detector: expected 'lsd' or 'fld', got {cfg.detector!r}")
    if lines is None or len(lines) == 0:
        return np.zeros((0, 4))
    seg = lines.reshape(-1, 4).astype(float)
    length = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    keep = np.argsort(-length)[: cfg.max_segments]
    seg = seg[keep][length[keep] >= min_len]
    seg = (seg + 0.5) / s - 0.5
    if camera.distorted and len(seg):
        seg = camera.normalized(seg.reshape(-1, 2), P=camera.K).reshape(-1, 4)
    return seg


class _Segments:
    """Segments prepared for residuals against many vanishing points at once."""

    def __init__(self, seg: np.ndarray):
        self.seg = seg
        p1 = np.c_[seg[:, :2], np.ones(len(seg))]
        p2 = np.c_[seg[:, 2:], np.ones(len(seg))]
        self.c = 0.5 * np.cross(p1, p2)          # p1 x midpoint
        self.mid = 0.5 * (seg[:, :2] + seg[:, 2:])
        self.half = np.maximum(0.5 * np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]), 1e-9)

    def residuals(self, vps: np.ndarray, idx=slice(None)) -> np.ndarray:
        """(N, k): sin of the angle between each segment and the line from its midpoint to
        each homogeneous vanishing point (rows of vps)."""
        vps = np.atleast_2d(vps)
        mx, my = self.mid[idx, :1], self.mid[idx, 1:]
        lx = my * vps[:, 2] - vps[:, 1]
        ly = vps[:, 0] - mx * vps[:, 2]
        return np.abs(self.c[idx] @ vps.T) / (self.half[idx, None] * np.maximum(np.hypot(lx, ly), 1e-12))


def _unit(v: np.ndarray) -> np.ndarray | None:
    n = math.sqrt(float(v @ v))
    return v / n if n > 1e-9 else None


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


# ----------------------------------------------------------------------------- one frame

def estimate_frame(bgr: np.ndarray, camera: Camera, *, cfg: CameraConfig | None = None,
                   roll_prior_deg: float = 0.0, fit_focal: bool = False,
                   lane_width_m: float = DEFAULT_LANE_WIDTH_M, car_boxes=None, hood=None) -> FrameCamera:
    """Pitch, roll (and yaw of the road, the focal length if asked) from one frame's lines.
    `hood`: the ego hood polygon (hood.py); its edges are not the world's lines."""
    cfg = cfg or CameraConfig()
    seg = detect_segments(bgr, camera, cfg)
    if hood is not None and len(seg):
        edge = np.array(hood[:-2], dtype=float)
        mid = 0.5 * (seg[:, :2] + seg[:, 2:])
        seg = seg[mid[:, 1] < np.interp(mid[:, 0], edge[:, 0], edge[:, 1]) - 3]
    if len(seg) < cfg.min_segments:
        why = _why_no_structure(bgr, len(seg), cfg)
        return FrameCamera(None, None, reasons=[why], segments=seg)
    K = camera.K
    Kinv = np.linalg.inv(K)
    S = _Segments(seg)
    length = 2 * S.half
    rays1 = np.c_[seg[:, :2], np.ones(len(seg))] @ Kinv.T
    rays2 = np.c_[seg[:, 2:], np.ones(len(seg))] @ Kinv.T
    normals = np.cross(rays1, rays2)            # of the plane through the camera and the segment
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    ang = np.degrees(np.arctan2(np.abs(seg[:, 3] - seg[:, 1]), np.abs(seg[:, 2] - seg[:, 0])))
    # a level segment on the horizon's row (a car's rear, a kerb far ahead) fits any vanishing
    # point on the horizon: it says where the horizon is only as a crosswise line
    level = np.abs(ang - abs(roll_prior_deg)) < cfg.level_deg
    steep = np.flatnonzero(ang > 60)            # candidates for the vertical
    flat = np.flatnonzero(ang <= 60)            # candidates for the road direction / crosswise
    thr = math.sin(math.radians(cfg.inlier_deg))
    rng = np.random.default_rng(cfg.seed)
    sin_p, max_r = math.sin(math.radians(cfg.max_pitch_deg)), math.radians(cfg.max_roll_deg)
    # the road's vanishing point is in view (or near it): a camera looks along the road
    half_fov = math.degrees(math.atan(max(camera.cx, camera.width - camera.cx) / camera.fx))
    cos_y = math.cos(math.radians(min(cfg.max_yaw_deg, half_fov + cfg.yaw_margin_deg)))
    roll0 = math.radians(roll_prior_deg)
    up0 = road_axes(0.0, roll0, 0.0)[2]
    n_it = cfg.ransac_iters
    coin = rng.random((n_it, 2))
    pick_s = rng.integers(0, max(len(steep), 1), (n_it, 2))
    pick_f = rng.integers(0, max(len(flat), 1), (n_it, 2))
    best = (0.0, None, None)
    for it in range(n_it):
        if len(steep) >= 2 and len(flat) and coin[it, 0] < 0.5:
            # vertical from two steep segments, road direction from one more
            U = _unit(_cross(normals[steep[pick_s[it, 0]]], normals[steep[pick_s[it, 1]]]))
            F = None if U is None else _unit(_cross(U, normals[flat[pick_f[it, 0]]]))
        elif len(flat) >= 2:
            F = _unit(_cross(normals[flat[pick_f[it, 0]]], normals[flat[pick_f[it, 1]]]))
            if F is None:
                continue
            F = F if F[2] > 0 else -F
            if len(steep) and coin[it, 1] < 0.5:
                U = _unit(_cross(F, normals[steep[pick_s[it, 0]]]))
            else:  # the up axis nearest the prior roll
                U = _unit(up0 - F * (F @ up0))
        else:
            break
        if U is None or F is None:
            continue
        U = U if U[1] < 0 else -U
        F = _unit(F - U * (F @ U))
        if F is None or F[2] < cos_y or abs(U[2]) > sin_p or abs(math.atan2(-U[0], -U[1])) > max_r:
            continue
        R = np.array([F, _cross(U, F), U])
        res = S.residuals(R @ K.T)
        res[level, 0] = np.inf
        lab = res.argmin(axis=1)
        inl = res[np.arange(len(seg)), lab] < thr
        sc = float(length[inl].sum())
        if sc > best[0]:
            best = (sc, angles_from_axes(F, U), np.where(inl, lab, -1))
    if best[1] is None:
        return FrameCamera(None, None, reasons=[f"no vanishing point within the priors among {len(seg)} segments"],
                           segments=seg)
    labels = best[2]
    support = {ax: int(np.count_nonzero(labels == i)) for i, ax in enumerate("FLU")}
    out = FrameCamera(None, None, support=support, segments=seg, labels=labels)
    if support["F"] + support["U"] + support["L"] < cfg.min_segments:
        out.reasons.append(f"only {support['F'] + support['U'] + support['L']} segments agree on vanishing points "
                           f"(need {cfg.min_segments})")
        return out
    # near-horizontal clutter (car rears, kerb stones, the hood) also points at a far crosswise
    # vanishing point: crosswise lines alone must be twice as many as vertical ones
    roll_free = support["U"] >= cfg.min_support or support["L"] >= 2 * cfg.min_support
    if not roll_free:
        out.reasons.append(f"roll: {support['U']} vertical and {support['L']} crosswise segments "
                           f"(need {cfg.min_support} or {2 * cfg.min_support}): roll from the prior")
    if support["F"] < cfg.min_support and support["U"] < cfg.min_support:
        out.reasons.append(f"pitch: {support['F']} segments along the road and {support['U']} vertical ones "
                           f"(need {cfg.min_support})")
        return out
    # the focal length needs two finite orthogonal vanishing points: the road's and the vertical
    fit_focal = fit_focal and support["F"] >= cfg.min_support and support["U"] >= cfg.min_support
    def Kf(f):      # the focal lengths scaled, the principal point kept
        return K * np.array([[f, 1.0, 1.0], [1.0, f, 1.0], [1.0, 1.0, 1.0]]) if f != 1.0 else K

    def fit(p, r, y, labels, with_focal):
        """Fit on the inliers, relabel with the fit, fit again; (p, r, y, f, labels, sd)."""
        f = 1.0

        def unpack(x):
            return x[0], (x[2] if roll_free else roll0), x[1], (math.exp(x[-1]) if with_focal else 1.0)

        for _ in range(2):
            idx = np.flatnonzero(labels >= 0)
            sw, lab, rows = np.sqrt(length[idx]), labels[idx], np.arange(len(idx))

            def fun(x):
                p_, r_, y_, f_ = unpack(x)
                return S.residuals(road_axes(p_, r_, y_) @ Kf(f_).T, idx)[rows, lab] * sw

            x0 = [p, y] + ([r] if roll_free else []) + ([math.log(f)] if with_focal else [])
            sol = least_squares(fun, x0, loss="soft_l1", f_scale=thr * float(np.median(sw)))
            p, r, y, f = unpack(sol.x)
            res = S.residuals(road_axes(p, r, y) @ Kf(f).T)
            res[level, 0] = np.inf
            lab_all = res.argmin(axis=1)
            labels = np.where(res[np.arange(len(seg)), lab_all] < thr, lab_all, -1)
        # standard deviations from the Jacobian (residual scale from the fit)
        sigma2 = float(np.sum(sol.fun ** 2)) / max(len(idx) - len(x0), 1)
        try:
            sd = np.sqrt(np.clip(np.diag(np.linalg.inv(sol.jac.T @ sol.jac) * sigma2), 0, None))
        except np.linalg.LinAlgError:
            sd = np.full(len(x0), 1.0)
        return p, r, y, f, labels, sd

    p, r, y, f, labels, sd = fit(*best[1], labels, fit_focal)
    if fit_focal and 0.5 < f < 2.0 and math.isfinite(sd[-1]):
        out.fx_fit, out.fx_log_std = float(camera.fx * f), float(sd[-1])   # for the recording's joint focal length
    if fit_focal and not (0.5 < f < 2.0 and sd[-1] < 0.03):
        # the focal length is not known to 3 %: keep the calibration's, and angles that agree with it
        fit_focal = False
        p, r, y, f, labels, sd = fit(p, r, y, labels, False)
    out.labels = labels
    support = {ax: int(np.count_nonzero(labels == i)) for i, ax in enumerate("FLU")}
    out.support = support
    std = np.degrees(sd)
    out.pitch, out.yaw = math.degrees(p), math.degrees(y)
    out.pitch_std = float(std[0])
    out.roll = math.degrees(r)
    out.roll_std = float(std[2]) if roll_free else float("inf")
    if fit_focal:
        out.fx = float(camera.fx * f)
    n_used = support["F"] + (support["U"] + support["L"] if roll_free else 0)
    worst_std = max(out.pitch_std, out.roll_std if roll_free else 0.0)
    out.confidence = float(n_used / (n_used + 10.0) / (1.0 + (worst_std / 0.5) ** 2))
    if not roll_free:
        out.confidence = min(out.confidence, 0.3)
    cam = camera if out.fx is None else Camera(camera.width, camera.height, out.fx, out.fx * camera.fy / camera.fx,
                                               camera.cx, camera.cy)
    R = road_axes(p, r, y)
    out.height_lanes = height_from_lanes(seg[labels == 0], cam, R, lane_width_m)
    if car_boxes:
        out.height_cars = height_from_cars(car_boxes, cam, R)
    return out


def _why_no_structure(bgr: np.ndarray, n: int, cfg: CameraConfig) -> str:
    gray = bgr if bgr.ndim == 2 else cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    mean, std = float(gray.mean()), float(gray.std())
    what = ("the frame is dark" if mean < 20 else "the frame is nearly uniform" if std < 8
            else "no straight edges (texture or noise only)")
    return f"{n} line segments (need {cfg.min_segments}): {what}"


# ----------------------------------------------------------------------------- height

def _ground_points(px: np.ndarray, camera: Camera, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels -> (forward, left) on the ground for a camera 1 m above it; rays above the
    horizon give NaN."""
    rays = np.c_[px, np.ones(len(px))] @ np.linalg.inv(camera.K).T
    down = -(rays @ R[2])
    with np.errstate(divide="ignore", invalid="ignore"):
        X = rays / down[:, None]
    X[down <= 1e-3] = np.nan
    return X @ R[0], X @ R[1]


def height_from_lanes(seg_f: np.ndarray, camera: Camera, R: np.ndarray, lane_width_m: float,
                      max_range: float = 25.0) -> float | None:
    """Camera height from the ego lane's two marking lines: their spacing on the ground,
    for a camera 1 m high, is lane_width / height. `seg_f`: segments along the road."""
    if len(seg_f) < 2:
        return None
    ends = seg_f.reshape(-1, 2)
    fwd, left = _ground_points(ends, camera, R)
    fwd, left = fwd.reshape(-1, 2), left.reshape(-1, 2)
    ok = np.all(np.isfinite(fwd), axis=1) & np.all(fwd > 0, axis=1) & np.all(fwd < max_range, axis=1)
    if ok.sum() < 2:
        return None
    y = left[ok].mean(axis=1)
    w = np.abs(fwd[ok, 1] - fwd[ok, 0])       # ground length: long markings weigh more
    # a line's two paint edges and its dashes fall together: cluster the lateral offsets
    order = np.argsort(y)
    y, w = y[order], w[order]
    clusters, cur = [], [0]
    for i in range(1, len(y)):
        if y[i] - y[cur[-1]] < 0.12:
            cur.append(i)
        else:
            clusters.append(cur)
            cur = [i]
    clusters.append(cur)
    lines = [(float(np.average(y[c], weights=w[c])), float(w[c].sum())) for c in clusters if w[c].sum() > 0.5]
    left_l = [c for c in lines if c[0] > 0]
    right_l = [c for c in lines if c[0] < 0]
    if not left_l or not right_l:
        return None
    d = min(c[0] for c in left_l) - max(c[0] for c in right_l)
    h = lane_width_m / d
    return float(h) if 0.8 <= h <= 3.5 else None


def height_from_cars(boxes, camera: Camera, R: np.ndarray) -> float | None:
    """Camera height from real cars' boxes (cars along the road, CAR_WIDTH_M x CAR_LENGTH_M).
    For a camera 1 m high the box's bottom row is the rear face's distance `a`, its left and
    right columns the bearings tL > tR (lateral / forward). The box spans the outer rear
    corner to the inner front corner (or the rear face when the car straddles the optical
    axis), so for a car left of the axis  tR (h a + L) = tL h a - W, and mirrored on the
    right: solved for h. Median over the cars."""
    hs = []
    for x, y, w, hb in boxes:
        if w <= 8:
            continue
        px = np.array([[x + w / 2, y + hb], [x, y + hb], [x + w, y + hb]])
        if camera.distorted:  # the box is in the distorted image; the geometry below is a pinhole's
            px = camera.normalized(px, P=camera.K)
        fwd, left = _ground_points(px, camera, R)
        if not np.all(np.isfinite(fwd)) or np.any(fwd <= 0):
            continue
        a = float(fwd[0])
        tL, tR = float(left[1] / fwd[1]), float(left[2] / fwd[2])
        if tL - tR <= 0:
            continue
        if tR > 0:      # left of the axis: its right (inner) side is seen, the front ends it
            num = CAR_WIDTH_M + tR * CAR_LENGTH_M
        elif tL < 0:    # right of the axis
            num = CAR_WIDTH_M - tL * CAR_LENGTH_M
        else:           # straddling: the rear face only
            num = CAR_WIDTH_M
        hs.append(num / (a * (tL - tR)))
    hs = [h for h in hs if 0.5 <= h <= 4.0]
    return float(np.median(hs)) if hs else None


# ----------------------------------------------------------------------------- recording

AUTO = "auto"


def _user_value(user, name: str):
    """A number the user fixed, or None when the field is "auto" (or there is no section)."""
    v = getattr(user, name, AUTO) if user is not None and user != AUTO else AUTO
    return None if v is None or v == AUTO else float(v)


def _import_note(rec, key: str) -> str:
    meta = rec.extra.get("import") or {}
    return str(meta.get(key, "")) if isinstance(meta, dict) else ""


def focal_was_guessed(rec) -> bool:
    """The importer assumed a field of view instead of reading a calibration."""
    return _import_note(rec, "camera_calibration").startswith("assumed")


def imu_usable(rec) -> bool:
    """The recording has IMU samples and a T_cam_imu that was given, not assumed."""
    return len(rec.imu) > 0 and not _import_note(rec, "T_cam_imu").startswith("assumed")


def gravity_up(rec, t: float, window_s: float = 0.5) -> tuple[np.ndarray, float] | None:
    """The up axis in the camera frame from the accelerometer around t (mean specific force),
    and its standard deviation in degrees (larger while the vehicle accelerates)."""
    if not imu_usable(rec):
        return None
    ti = t + rec.time_offset_cam_imu
    m = np.abs(rec.imu[:, 0] - ti) <= window_s / 2
    if m.sum() < 3:
        return None
    a = rec.imu[m, 4:7].mean(axis=0)
    g = float(np.linalg.norm(a))
    if g < 5:
        return None
    U = np.asarray(rec.T_cam_imu)[:3, :3] @ (a / g)
    # a car's longitudinal acceleration tilts the apparent vertical by atan(a / g)
    std = 0.5 + math.degrees(math.atan(abs(g - 9.81) / 9.81)) + 2.0 * float(rec.imu[m, 4:7].std(axis=0).max())
    return U, std


# ----------------------------------------------------------------------------- per-frame cues

def _object_points(cls: str, box, camera: Camera, others, image_h: int, image_w: int, floor_v: float):
    """A road user's box as undistorted pinhole points [bottom centre, bottom left, bottom right,
    top centre], or None when the box does not show the whole object standing on the ground:
    cut by the frame's edge or the hood, its bottom hidden behind a nearer road user, or a rider
    (the person box of a cyclist or motorcyclist)."""
    x, y, w, h = box
    if x <= 2 or y <= 2 or x + w >= image_w - 3 or y + h >= min(image_h - 3, floor_v - 3):
        return None
    for ocls, (ox, oy, ow, oh) in others:
        if (ox, oy, ow, oh) == tuple(box):
            continue
        overlap = max(0.0, min(x + w, ox + ow) - max(x, ox))
        if cls == "person" and ocls in ("bicycle", "motorcycle") and overlap > 0.3 * w:
            return None
        # a nearer object (lower bottom) over this one's bottom: its contact point is hidden
        if oy + oh > y + h and oy < y + h and overlap > 0.5 * w:
            return None
    px = np.array([[x + w / 2, y + h], [x, y + h], [x + w, y + h], [x + w / 2, y]], float)
    if camera.distorted:
        px = camera.normalized(px, P=camera.K)
    return px.tolist()


def _lane_cue(bgr: np.ndarray, camera: Camera, fc: FrameCamera, hood, boxes, lane_width_m: float):
    """The ego lane's two painted lines (analysis.lanes) as two undistorted pinhole pixels each,
    found with the frame's own pitch, roll and road direction and a provisional 1.5 m height
    (the mount reduction measures their spacing again at its own angles), or None."""
    from blendgen import ground, lane_geometry
    from blendgen.analysis import lanes, road
    from blendgen.frame_analysis import CameraEstimate

    if fc.pitch is None:
        return None
    est = CameraEstimate(DEFAULT_HEIGHT_M, fc.pitch, fc.roll or 0.0)
    T = ground.camera_pose(est, None if fc.yaw is None else -fc.yaw)
    H, W = bgr.shape[:2]
    hmask = None
    if hood is not None:
        hmask = np.zeros((H, W), np.uint8)
        cv2.fillPoly(hmask, [np.round(np.asarray(hood)).astype(np.int32)], 1)
        hmask = hmask > 0
    road_px, _ = road.estimate_road(bgr, ground.horizon(camera, T), hmask, boxes)
    lines, _ = lanes.lane_lines(bgr, road_px, camera, T)
    ego = lane_geometry.ego_lane(lines, lane_geometry.X_REF, lane_width_m)
    if ego is None:
        return None
    lo, hi, _ = ego
    pair = [ln for ln in lines if min(abs(ln[0] - lo), abs(ln[0] - hi)) < 1e-6]
    if len(pair) != 2:  # one side was a lane width beyond a single line, not paint
        return None
    xs = np.array([lane_geometry.RANGE_M[0] + 1.0, 20.0])
    Rcw, t = T[:3, :3].T, T[:3, 3]
    out = []
    for y10, slope, _ in pair:
        P = np.column_stack([xs, y10 + slope * (xs - lane_geometry.X_REF), np.zeros(2)])
        Xc = (P - t) @ Rcw.T
        uv = (Xc @ camera.K.T)[:, :2] / Xc[:, 2:3]
        out.append(uv.tolist())
    return out


def frame_cues(bgr: np.ndarray, camera: Camera, *, t: float = 0.0, hood=None, users=None,
               lane_width_m: float = DEFAULT_LANE_WIDTH_M, cfg: CameraConfig | None = None,
               roll_prior_deg: float = 0.0, fit_focal: bool = False) -> FrameCues:
    """The per-frame part of the camera estimate: the vanishing points' pitch, roll and yaw
    (`estimate_frame`), the road users standing whole on the road, and the ego lane's lines;
    `users`: [(cls, [x, y, w, h]), ...] from the detector. The mount reduction
    (`mount.estimate_mount`) turns the cues of all frames into the camera's mount."""
    fc = estimate_frame(bgr, camera, cfg=cfg, roll_prior_deg=roll_prior_deg, fit_focal=fit_focal,
                        lane_width_m=lane_width_m, hood=hood)
    H, W = bgr.shape[:2]
    floor_v = float(np.asarray(hood)[:, 1].min()) if hood is not None else float(H)
    users = [(c, list(b)) for c, b in (users or [])]
    objs = []
    for cls, box in users:
        if cls in ("car", "person"):
            pts = _object_points(cls, box, camera, users, H, W, floor_v)
            if pts is not None:
                objs.append((cls, pts))
    ok = fc.pitch is not None and math.isfinite(fc.pitch_std)
    return FrameCues(t=t, pitch=fc.pitch if ok else None, roll=fc.roll, pitch_std=fc.pitch_std if ok else float("inf"),
                     roll_std=fc.roll_std if ok else float("inf"), yaw=fc.yaw, fx=fc.fx, fx_fit=fc.fx_fit,
                     fx_log_std=fc.fx_log_std, confidence=fc.confidence,
                     reasons=list(fc.reasons), objects=objs,
                     lane=_lane_cue(bgr, camera, fc, hood, [b for _, b in users], lane_width_m) if ok else None)


# ----------------------------------------------------------------------------- recording

def _cues_elsewhere(rec, frame_ids, hood, cfg, fit_focal, roll_prior, lane_w, progress: bool) -> dict[str, FrameCues]:
    """Video: lane cues from frames spread over the whole recording (besides the job's own):
    one camera's height must not depend on which frames a job renders. Lanes bound the ego lane
    in about 1 frame in 10; on the freeway video frames 0-56 had none."""
    chosen = set(frame_ids)
    idx = np.unique(np.linspace(0, rec.n_frames - 1, HEIGHT_SAMPLE_FRAMES).round().astype(int))
    extra = [rec.frame_id(int(i)) for i in idx if rec.frame_id(int(i)) not in chosen]
    out = {}
    for fid, im in read_frames(rec, extra, progress=progress, desc="calibrate (height)"):
        if im is not None:
            c = frame_cues(im, rec.camera, hood=hood, cfg=cfg, fit_focal=fit_focal, roll_prior_deg=roll_prior,
                           lane_width_m=lane_w)
            if c.lane is not None and c.pitch is not None:
                out["height:" + fid] = FrameCues(t=c.t, pitch=c.pitch, roll=c.roll or 0.0, pitch_std=c.pitch_std,
                                                 roll_std=c.roll_std, lane=c.lane)
    return out


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    o = np.argsort(values)
    c = np.cumsum(weights[o])
    return float(values[o][np.searchsorted(c, 0.5 * c[-1])])


def _smooth(per: dict[str, FrameCues], frame_ids, t_of, seq: bool, rec, fixed) -> dict[str, dict]:
    """Video: pitch and roll per frame, a confidence-weighted median over +- SMOOTH_S (frames
    that fell back take it), averaged with the IMU's gravity where there is one. Stills: the
    IMU alone where there is one (the mount reduction does the rest)."""
    by_time = sorted(per, key=t_of.__getitem__)
    t_sorted = np.array([t_of[g] for g in by_time])
    out = {}
    for fid in frame_ids:
        fc = per[fid]
        t = t_of[fid]
        near = by_time[np.searchsorted(t_sorted, t - SMOOTH_S):np.searchsorted(t_sorted, t + SMOOTH_S, "right")] \
            if seq else []
        up = gravity_up(rec, t)
        row = {"reasons": [], "confidence": fc.confidence}
        for name, std_name, key in (("pitch", "pitch_std", "pitch_deg"), ("roll", "roll_std", "roll_deg")):
            if fixed[key] is not None:
                row[name], row[name + "_src"], row[std_name] = fixed[key], "user", 0.0
                continue
            vals = [(getattr(per[g], name), per[g].confidence) for g in near
                    if getattr(per[g], name) is not None and math.isfinite(getattr(per[g], std_name))]
            own = getattr(fc, name)
            if len(vals) >= 2:       # video: confidence-weighted median over +-0.5 s
                v = np.array(vals)
                value, src = _weighted_median(v[:, 0], v[:, 1] + 1e-6), "smoothed"
                std = max(0.05, float(np.median([getattr(per[g], std_name) for g in near
                                                 if math.isfinite(getattr(per[g], std_name))])))
            elif own is not None and math.isfinite(getattr(fc, std_name)):
                value, src, std = own, "vanishing_point", max(0.05, getattr(fc, std_name))
            else:
                value, src, std = None, None, float("inf")
            if up is not None:
                p_i, r_i, _ = angles_from_axes(np.array([0.0, 0.0, 1.0]), up[0])
                gv = math.degrees(p_i if name == "pitch" else r_i)
                if value is None:
                    value, src, std = gv, "imu", up[1]
                    row["confidence"] = max(row["confidence"], 1.0 / (1.0 + (up[1] / 1.0) ** 2))
                else:   # inverse-variance average of lines and gravity
                    w1, w2 = 1 / std ** 2, 1 / up[1] ** 2
                    value, src, std = (w1 * value + w2 * gv) / (w1 + w2), src + "+imu", (w1 + w2) ** -0.5
            row[name], row[name + "_src"], row[std_name] = value, src, std
        out[fid] = row
    return out


def estimate_cameras(rec, frame_ids, *, user=None, car_boxes=None, users=None, progress: bool = False,
                     hoods=None, cfg: CameraConfig | None = None) -> dict[str, tuple[CameraEstimate, list | None]]:
    """Camera (height, pitch, roll, focal length) and horizon per frame; see the module doc.
    `users`: {frame_id: [(cls, [x, y, w, h]), ...]} the detector's road users (`car_boxes`:
    {frame_id: [box, ...]} of cars only); `hoods`: find_hood's result when the caller has it
    (otherwise it is found here). Per-frame cues (`frame_cues`), then one recording-wide
    reduction (`recording_camera`: focal length, `mount.estimate_mount`), then each frame's
    estimate (`camera_of_frame`); the farm runs the same three parts as tasks
    (analysis.split)."""
    from blendgen.analysis.hood import find_hood

    cfg = cfg or CameraConfig()
    camera: Camera = rec.camera
    users = dict(users or {})
    for f, boxes in (car_boxes or {}).items():
        users.setdefault(f, [("car", b) for b in boxes])
    st = CameraSettings(rec, user, cfg)
    frame_ids = list(frame_ids)
    t_of = {rec.frame_id(i): float(rec.frames_t[i]) for i in frame_indices(rec, frame_ids)}
    if hoods is None:
        hoods = find_hood(rec, frame_ids, shared=not st.per_image)
    per: dict[str, FrameCues] = {}
    for fid, im in read_frames(rec, frame_ids, progress=progress, desc="calibrate"):
        per[fid] = (FrameCues(t=t_of[fid], reasons=["frame does not decode"]) if im is None else
                    frame_cues(im, camera, t=t_of[fid], hood=hoods.get(fid), users=users.get(fid), **st.cue_kw()))
    angles = _smooth(per, frame_ids, t_of, st.seq, rec, st.fixed)
    elsewhere = None
    if st.seq and st.fixed["camera_height_m"] is None:
        hood = next((h for h in hoods.values() if h is not None), None)  # the hood does not move
        elsewhere = _cues_elsewhere(rec, frame_ids, hood, cfg, st.fit_focal, st.fixed["roll_deg"] or 0.0, st.lane_w,
                                    progress)
    rc = recording_camera(per, angles, st, elsewhere or {})
    return {fid: camera_of_frame(fid, per[fid], angles[fid], rc, camera) for fid in frame_ids}


class CameraSettings:
    """The job's ground_plane section and the recording, as the camera estimate reads them."""

    def __init__(self, rec, user=None, cfg: CameraConfig | None = None):
        self.cfg = cfg or CameraConfig()
        self.camera: Camera = rec.camera
        self.fixed = {k: _user_value(user, k) for k in ("camera_height_m", "pitch_deg", "roll_deg")}
        self.lane_w = _user_value(user, "lane_width_m") or DEFAULT_LANE_WIDTH_M
        # a lane width the user gave is this road's: the height scales with it, not with the prior
        self.lane_known = self.lane_w if "lane_width_m" in (getattr(user, "model_fields_set", None) or ()) else None
        self.fit_focal = focal_was_guessed(rec)
        self.seq = is_sequence(rec)
        self.per_image = getattr(user, "stills", "shared") == "per_image" and not self.seq

    def cue_kw(self) -> dict:
        return dict(cfg=self.cfg, lane_width_m=self.lane_w, roll_prior_deg=self.fixed["roll_deg"] or 0.0,
                    fit_focal=self.fit_focal)


@dataclass
class RecordingCamera:
    """The recording-wide part of the camera estimate, from the frames it saw (`recording_camera`)."""

    fx: float | None
    seq: bool
    imu: bool                                  # a frame's angles came from the IMU: the mount fit takes them as given
    fixed: dict
    median: dict[str, float]                   # pitch/roll a frame without one takes (video, IMU)
    have: dict[str, bool]                      # whether any frame had its own pitch/roll
    mount: Mount
    cues: dict[str, FrameCues] = field(default_factory=dict)   # stills: the frames the mount was fitted on
    lane_known: float | None = None
    per_image: bool = False                    # stills each from a camera of its own: a mount per frame

    def camera(self, camera: Camera) -> Camera:
        return camera if self.fx is None else Camera(camera.width, camera.height, self.fx,
                                                     self.fx * camera.fy / camera.fx, camera.cx, camera.cy,
                                                     list(camera.dist))


def recording_camera(per: dict[str, FrameCues], angles: dict[str, dict], st: CameraSettings,
                     elsewhere: dict[str, FrameCues]) -> RecordingCamera:
    """The focal length and the mount (`mount.estimate_mount`) from the cues of `per` (every frame
    of a job, or a sample of a long one) with their angles (`_smooth`); `elsewhere`: the video's
    lane cues outside the job (`_cues_elsewhere`)."""
    from blendgen.analysis.mount import estimate_mount

    fixed, seq = st.fixed, st.seq
    # the recording's focal length
    fx, why_fx = focal_consensus(per) if st.fit_focal else (None, "")
    if st.fit_focal:
        log.info("focal length: %s", why_fx)
    cam = st.camera if fx is None else Camera(st.camera.width, st.camera.height, fx, fx * st.camera.fy / st.camera.fx,
                                              st.camera.cx, st.camera.cy, list(st.camera.dist))
    imu = any(a[n + "_src"] and "imu" in a[n + "_src"] for a in angles.values() for n in ("pitch", "roll"))
    # the mount: stills jointly (pitch and roll per frame shrink to the camera's), video with
    # its smoothed angles given (frames without one take the recording's median)
    cues = {}
    for fid, c in per.items():
        a = angles[fid]
        if seq or imu:
            c = FrameCues(**{**c.__dict__, "pitch": a["pitch"], "roll": a["roll"],
                             "pitch_std": a["pitch_std"], "roll_std": a["roll_std"]})
        cues[fid] = c
    median = {}
    if seq or imu:
        for name, std_name in (("pitch", "pitch_std"), ("roll", "roll_std")):
            have = [getattr(c, name) for c in cues.values() if getattr(c, name) is not None]
            median[name] = float(np.median(have)) if have else 0.0
            for fid, c in cues.items():
                if getattr(c, name) is None or not math.isfinite(getattr(c, std_name)):
                    setattr(c, name, median[name])
                    setattr(c, std_name, float("inf"))
        if seq and fixed["camera_height_m"] is None:
            cues.update(elsewhere)
    mount = estimate_mount(cues, cam.K, sequence=seq or imu, fixed=fixed, lane_width_m=st.lane_known)
    have = {n: any(x[n + "_src"] for x in angles.values()) for n in ("pitch", "roll")}
    return RecordingCamera(fx=fx, seq=seq, imu=imu, fixed=fixed, median=median, have=have, mount=mount,
                           cues={} if seq or imu else dict(per), lane_known=st.lane_known, per_image=st.per_image)


def camera_of_frame(fid: str, fc: FrameCues, a: dict, rc: RecordingCamera, camera: Camera
                    ) -> tuple[CameraEstimate, list | None]:
    """One frame's estimate and horizon from its cues `fc`, its angles `a` (`_smooth`), the
    recording-wide part and the recording's `camera`. A still the mount was not fitted on (a long
    job's, outside the sample) gets its pitch and roll from the mount fitted again with it added."""
    from blendgen.analysis.mount import estimate_mount

    if rc.per_image and not (rc.seq or rc.imu):  # a camera of its own: the mount its own cues give, as alone
        own = estimate_mount({fid: fc}, rc.camera(camera).K, sequence=False, fixed=rc.fixed, lane_width_m=rc.lane_known)
        rc = replace(rc, mount=own, cues={fid: fc})
    mount, seq, imu = rc.mount, rc.seq, rc.imu
    if seq or imu:  # the mount fit takes the frame's angles as given (the recording's median where none)
        pf = {}
        for name, std_name in (("pitch", "pitch_std"), ("roll", "roll_std")):
            v = a[name]
            pf[name] = rc.median[name] if v is None or not math.isfinite(a[std_name]) else v
        frame_p, frame_r = pf["pitch"], pf["roll"]   # what the fit took (mount.frame_pitch of its frames)
        frame_std = {}
    else:
        if fid not in mount.frame_pitch:
            mount = estimate_mount({**rc.cues, fid: fc}, rc.camera(camera).K, sequence=False, fixed=rc.fixed,
                                   lane_width_m=rc.lane_known)
        frame_p, frame_r = mount.frame_pitch[fid], mount.frame_roll[fid]
        frame_std = {"pitch": mount.frame_pitch_std[fid], "roll": mount.frame_roll_std[fid]}
    est = CameraEstimate(height_m=rc.mount.height_m, pitch_deg=frame_p, roll_deg=frame_r, fx=rc.fx, yaw_deg=fc.yaw,
                         confidence=a["confidence"], reasons=list(fc.reasons),
                         height_std_rel=round(rc.mount.height_std_log, 4))
    if rc.fx is not None:
        est.source["fx"] = "vanishing_point"
    for name, std_name in (("pitch", "pitch_std"), ("roll", "roll_std")):
        if seq or imu:
            src, std = a[name + "_src"], a[std_name]
            if src is None:
                have = rc.have[name]
                src, std = ("recording_median", FRAME_FALLBACK_STD_DEG) if have else ("default", DEFAULT_STD_DEG)
                est.reasons.append(f"{name}: no estimate in this frame, the recording's median" if have else
                                   f"{name}: nothing to estimate it from, assumed {getattr(est, name + '_deg'):g} deg")
                est.confidence = 0.0 if src == "default" else min(est.confidence, 0.3)
        else:
            src = mount.source[name]
            std = frame_std[name]
            if src == "mount" and not (mount.cues["vanishing_points"] or mount.cues.get("car_width")):
                src, std = "default", DEFAULT_STD_DEG
                est.reasons.append(f"{name}: nothing to estimate it from in any frame of this camera")
                est.confidence = 0.0
        est.source[name] = src
        setattr(est, std_name + "_deg", round(float(std), 3))
    est.source["height"] = rc.mount.source["height"]
    est.reasons += rc.mount.reasons
    if est.source["pitch"] == "user" and est.source["roll"] == "user":
        est.confidence = 1.0
    for r in est.reasons:
        log.info("%s: %s", fid, r)
    U = road_axes(math.radians(est.pitch_deg), math.radians(est.roll_deg), 0.0)[2]
    return est, horizon_line(rc.camera(camera), U)
