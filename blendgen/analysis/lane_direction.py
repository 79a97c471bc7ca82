"""The lane's direction in one frame: the vanishing point of its painted markings (bpy-free).

    lane_direction(bgr, camera, *, hood=None) -> LaneDirection

A car drives along its lane, so where the lane markings meet is the vehicle's forward axis
seen by the camera: its column gives the camera's yaw in the vehicle, its row the pitch
against the road ahead (which bends up and down, so the pitch is the weaker of the two).
openpilot calibrates its camera the same way. Sync uses the yaw (calib.yaml
`vehicle.camera_yaw_deg`, `blendgen.sync.calibration`) where no video shows the direction of
travel; the comma2k19 importer measures it on the segment's preview frame.

Markings, not all straight edges: `analysis.camera`'s Manhattan fit also takes car rears,
kerbs and the horizon's clutter, and on comma2k19's preview its yaw moved 0.4-1.2 deg with
the RANSAC seed and the working resolution (11 deg at full resolution). Here:
  1. thin bright stripes: L* top-hat across each row (`road.CL_WHITE_TOPHAT_L`) below the
     highest possible horizon and above the hood;
  2. each stripe's pixels (undistorted) as a line: centroid and principal axis, kept when
     elongated (4:1) and between 12 and 85 deg from the image rows (lane lines recede);
  3. the vanishing point: every pair's intersection scored by the length of the lines that
     point at it within 1 deg, from both sides of it, beyond each line; then weighted least
     squares on the inliers, relabelled once; at least 3 lines more than 2 deg apart seen from
     it (two lines always meet; a double centre line is one); its covariance from the
     residuals (>= 0.1 deg per line), propagated to yaw and pitch;
  4. all of it again with only what lies 2 % of the height below that point (a hillside
     beyond the road was collinear with a lane line).
Roll is taken as 0: it enters the yaw as roll x pitch (0.05 deg at 1 deg roll, 3 deg pitch).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares

from blendgen.analysis.road import CL_WHITE_TOPHAT_L
from blendgen.geometry import Camera

WORK_WIDTH = 1280          # larger frames are searched at this width
TOPHAT_FRAC = 25 / 640     # top-hat width as a share of the image width (a near stripe is narrower)
MAX_PITCH_UP_DEG = 10.0    # no marking above the horizon of a camera pitched up this much
MIN_AREA_FRAC = 20 / 1164**2  # smallest stripe, as a share of the image (20 px at 1164 wide)
MIN_ELONGATION = 4.0       # principal axes' ratio of a stripe
ANGLE_RANGE_DEG = (12.0, 85.0)  # from the image rows: near-flat ones are stop lines, car rears
INLIER_DEG = 1.0
LINE_FLOOR_DEG = 0.1       # a stripe's direction is not known better than this
MAX_LINES = 40
MIN_LINES = 3              # two lines always meet somewhere: a third one checks it
MIN_RAY_GAP_DEG = 2.0      # markings closer in angle seen from the vanishing point are one line (double lines)
BELOW_VP_FRAC = 0.02      # second pass: markings start this far (of the height) below the first vanishing point
MERGE_PX = 1.0            # dashes on one line: their union is at most this much wider
# the car's heading within its lane at the moment of a frame (lane keeping wanders by this
# much): what one frame's yaw says about the camera's yaw in the car, beyond its fit
LANE_HEADING_STD_DEG = 0.3


@dataclass
class LaneDirection:
    yaw_deg: float | None = None       # camera's optical axis left of the lane (> 0: looks left)
    pitch_deg: float | None = None     # camera looks down on the road ahead (> 0)
    yaw_std_deg: float = float("inf")
    pitch_std_deg: float = float("inf")
    vp: tuple[float, float] | None = None  # undistorted pixels
    lines: int = 0                     # markings that point at it
    reason: str = ""                   # why there is none

    def summary(self) -> dict:
        if self.yaw_deg is None:
            return {"reason": self.reason}
        return {"yaw_deg": round(self.yaw_deg, 3), "yaw_std_deg": round(self.yaw_std_deg, 3),
                "pitch_deg": round(self.pitch_deg, 3), "pitch_std_deg": round(self.pitch_std_deg, 3),
                "vanishing_point": [round(self.vp[0], 1), round(self.vp[1], 1)], "markings": self.lines}


def _stripes(bgr: np.ndarray, camera: Camera, hood, top: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centroids (N, 2), unit directions (N, 2) and lengths (N,) of the painted stripes below
    row `top`, in undistorted full-resolution pixels."""
    H, W = bgr.shape[:2]
    s = min(1.0, WORK_WIDTH / W)
    img = cv2.resize(bgr, (round(W * s), round(H * s)), interpolation=cv2.INTER_AREA) if s < 1 else bgr
    h, w = img.shape[:2]
    L = cv2.cvtColor(img, cv2.COLOR_BGR2LAB)[..., 0]
    k = max(9, int(round(TOPHAT_FRAC * w)))
    mask = (cv2.morphologyEx(L, cv2.MORPH_TOPHAT, cv2.getStructuringElement(cv2.MORPH_RECT, (k, 1)))
            > CL_WHITE_TOPHAT_L).astype(np.uint8)
    mask[: max(int(top * s), 0)] = 0
    if hood is not None:
        edge = np.asarray(hood[:-2], float)  # hood.py: the edge, then the two bottom corners
        rows = np.interp(np.arange(w) / s, edge[:, 0], edge[:, 1]) * s - 3
        mask[np.arange(h)[:, None] >= rows[None, :]] = 0
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    min_area = max(6, MIN_AREA_FRAC * h * w)
    stripes = []
    for i in np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= min_area) + 1:
        x, y, bw, bh = stats[i, :4]
        v, u = np.nonzero(lab[y:y + bh, x:x + bw] == i)
        px = (np.column_stack([u + x, v + y]) + 0.5) / s - 0.5
        if camera.distorted:
            px = camera.normalized(px, P=camera.K)
        line = _line(px)
        if line is not None:
            stripes.append(px)
    lines = [_line(px) for px in _merge_collinear(stripes)]
    lines = sorted((ln for ln in lines if ln is not None), key=lambda r: -r[2])[:MAX_LINES]
    if not lines:
        return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0)
    return tuple(np.array([ln[k] for ln in lines]) for k in range(3))


def _line(px: np.ndarray):
    """(centroid, unit direction, length) of an elongated stripe at a lane line's angle, or None."""
    c = px.mean(axis=0)
    ev, evec = np.linalg.eigh(np.cov((px - c).T))
    if ev[1] < MIN_ELONGATION**2 * max(ev[0], 1e-9):
        return None
    d = evec[:, 1]
    ang = math.degrees(math.atan2(abs(d[1]), abs(d[0])))
    return (c, d, 4.0 * math.sqrt(ev[1])) if ANGLE_RANGE_DEG[0] <= ang <= ANGLE_RANGE_DEG[1] else None


def _width(px: np.ndarray) -> float:
    """Spread across a stripe's axis (px, 1-sigma)."""
    return float(math.sqrt(max(np.linalg.eigvalsh(np.cov((px - px.mean(axis=0)).T))[0], 0.0)))


def _merge_collinear(stripes: list[np.ndarray]) -> list[np.ndarray]:
    """The dashes of one lane line as one line (a single dash's direction is degrees off; the
    line through several is not): longest first, a stripe joins a line when the union is no
    wider across its axis than the wider of the two (+ MERGE_PX), i.e. they lie on one line."""
    stripes = sorted(stripes, key=len, reverse=True)
    out = []
    while stripes:
        px = stripes.pop(0)
        k = 0
        while k < len(stripes):
            both = np.vstack([px, stripes[k]])
            if _width(both) <= max(_width(px), _width(stripes[k])) + MERGE_PX and _line(both) is not None:
                px = both
                stripes.pop(k)
                k = 0
            else:
                k += 1
        out.append(px)
    return out


def _sin_off(vp: np.ndarray, C: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Sine of the angle between each line's direction and the ray from its centroid to vp."""
    r = vp[None, :] - C
    r = r / np.maximum(np.linalg.norm(r, axis=1, keepdims=True), 1e-9)
    return D[:, 0] * r[:, 1] - D[:, 1] * r[:, 0]


def _consistent(vp: np.ndarray, C: np.ndarray, sel: np.ndarray) -> bool:
    """Markings on both sides of the vanishing point, all below it (they recede towards it)."""
    c = C[sel]
    return bool(np.any(c[:, 0] < vp[0]) and np.any(c[:, 0] > vp[0]) and np.all(c[:, 1] > vp[1]))


def _vanishing_point(C: np.ndarray, D: np.ndarray, Lw: np.ndarray):
    """(vanishing point, inliers, least-squares solution) of the lines, or why there is none."""
    if len(C) < MIN_LINES:
        return f"{len(C)} lane marking(s) found (need {MIN_LINES}, on both sides)"
    thr = math.sin(math.radians(INLIER_DEG))
    best = (0.0, None, None)
    for i, j in itertools.combinations(range(len(C)), 2):
        A = np.array([[D[i, 1], -D[i, 0]], [D[j, 1], -D[j, 0]]])
        if abs(np.linalg.det(A)) < 1e-3:
            continue
        vp = np.linalg.solve(A, [A[0] @ C[i], A[1] @ C[j]])
        inl = np.abs(_sin_off(vp, C, D)) < thr
        score = float(Lw[inl].sum())
        if score > best[0] and _consistent(vp, C, inl):
            best = (score, vp, inl)
    if best[1] is None:
        return f"no vanishing point with markings on both sides among {len(C)} stripes"
    vp, inl = best[1], best[2]
    w = np.sqrt(Lw)
    for _ in range(2):  # fit, relabel with the fit, fit again
        idx = np.flatnonzero(inl)
        sol = least_squares(lambda x, idx=idx: _sin_off(x, C[idx], D[idx]) * w[idx], vp)
        vp = sol.x
        inl = np.abs(_sin_off(vp, C, D)) < thr
        if not _consistent(vp, C, inl):
            return "the markings' vanishing point does not hold after the fit"
    rays = np.sort(np.arctan2(C[inl, 1] - vp[1], C[inl, 0] - vp[0]))
    n_rays = 1 + int(np.sum(np.diff(rays) > np.radians(MIN_RAY_GAP_DEG))) if len(rays) else 0
    if n_rays < MIN_LINES:
        return (f"only {n_rays} distinct lines meet (need {MIN_LINES}: two always do; "
                f"{int(inl.sum())} markings, a double line counts once)")
    return vp, inl, sol


def lane_direction(bgr: np.ndarray, camera: Camera, *, hood=None) -> LaneDirection:
    """The camera's yaw and pitch against the lane from the frame's lane markings (degrees);
    `hood`: the ego hood polygon of `analysis.hood` (its reflections are not markings)."""
    if bgr is None or bgr.ndim != 3:
        return LaneDirection(reason="not a colour image")
    if bgr.shape[:2] != (camera.height, camera.width):
        return LaneDirection(reason=f"image is {bgr.shape[1]}x{bgr.shape[0]}, the camera "
                                    f"{camera.width}x{camera.height}")
    # first below the highest possible horizon, then below the vanishing point found: what
    # lies beyond it (a hillside, bright sky between trees) can be collinear with a lane line
    top = camera.cy - camera.fy * math.tan(math.radians(MAX_PITCH_UP_DEG))
    for _ in range(2):
        C, D, Lw = _stripes(bgr, camera, hood, top)
        fit = _vanishing_point(C, D, Lw)
        if isinstance(fit, str):
            return LaneDirection(reason=fit)
        vp, inl, sol = fit
        top = vp[1] + BELOW_VP_FRAC * camera.height
    idx = np.flatnonzero(inl)
    dof = len(idx) - 2
    s2 = max(float(np.sum(sol.fun**2)) / dof, math.sin(math.radians(LINE_FLOOR_DEG)) ** 2 * float(np.mean(Lw[idx])))
    try:
        cov = np.linalg.inv(sol.jac.T @ sol.jac) * s2
    except np.linalg.LinAlgError:
        return LaneDirection(reason="the markings' vanishing point is undetermined (parallel markings)")

    def angles(p):
        F = np.linalg.solve(camera.K, [p[0], p[1], 1.0])
        F /= np.linalg.norm(F)
        yaw = math.asin(float(F[0]))
        return np.degrees([yaw, math.asin(float(np.clip(-F[1] / math.cos(yaw), -1, 1)))])

    a = angles(vp)
    J = np.column_stack([(angles(vp + e) - angles(vp - e)) / 2.0 for e in np.eye(2)])
    sd = np.sqrt(np.maximum(np.diag(J @ cov @ J.T), 0.0))
    return LaneDirection(float(a[0]), float(a[1]), float(sd[0]), float(sd[1]), (float(vp[0]), float(vp[1])),
                         len(idx))


def still_camera_yaw(bgr: np.ndarray, camera: Camera) -> tuple[float | None, float, str]:
    """The camera's yaw in the vehicle from one still, its hood left out (the comma2k19 importer
    measures it on a segment's preview frame): (yaw_deg, standard deviation with the lane's own
    heading error, how), or (None, nan, why not)."""
    from blendgen.analysis.hood import hood_in_still

    r = lane_direction(bgr, camera, hood=hood_in_still(bgr)[0])
    if r.yaw_deg is None:
        return None, float("nan"), r.reason
    return r.yaw_deg, float(np.hypot(r.yaw_std_deg, LANE_HEADING_STD_DEG)), f"vanishing point of {r.lines} lane markings"
