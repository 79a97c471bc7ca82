"""Monocular visual odometry between consecutive frames (OpenCV).

Two front ends: `KltVo` (default: track-then-detect, Lucas-Kanade tracks of the previous
frame's corners, FAST corners only in grid cells that lost theirs) and `OrbVo`.
ORB per frame pair: keypoints spread over a grid (best response per cell), Hamming matching
with Lowe's ratio test and a mutual (cross) check, essential-matrix RANSAC on undistorted
normalised points, cheirality (as `recoverPose`). The result is a relative rotation and a translation
*direction* (monocular: no scale) with a quality record. Frames that must not be trusted are
classified instead of producing a wrong pose:

  few_features  textureless / dark / lens cap            -> no measurement
  few_matches   too few consistent matches                -> no measurement
  repeated      the same image twice (encoder duplicate)   -> no information (not a standstill:
                                                              the car may well be moving)
  stationary    a new image whose features do not move      -> identity, zero velocity
  rotation      no parallax after removing the rotation   -> rotation only (Kabsch fit)
  ok            rotation + translation direction
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from blendgen import so3
from blendgen.geometry import Camera


@dataclass
class VoConfig:
    n_features: int = 1500
    grid: tuple[int, int] = (8, 6)         # cells across, down
    ratio: float = 0.8                     # Lowe ratio test
    min_features: int = 40
    min_inliers: int = 20
    ransac_px: float = 1.0                 # essential-matrix RANSAC threshold in pixels
    stationary_px: float = 0.3             # median flow below this: not moving
    min_parallax_px: float = 1.0           # rotation-compensated flow below this: pure rotation
    fast_threshold: int = 12
    # ORB pyramid: steps of 1.1 over the same range as OpenCV's default 1.2 x 6 (x2.6). A ground
    # feature grows 15-30 % between frames at 5 fps; with 1.2 steps more matches are found at the
    # same level in both frames, where the detected corner moves with the feature's size (60 s
    # synthetic drive, bench_vo_bias.py: rotation bias about the camera's x axis +0.012 deg per
    # pair and a direction bias +0.10 deg with 1.2 steps, +0.003 / +0.02 with 1.1; CPU about the same)
    n_levels: int = 11
    orb_scale_factor: float = 1.1
    max_width: int | None = 640            # ORB: larger frames are downscaled for detection (speed)
    method: str = "klt"                    # klt (track-then-detect) or orb (detect + match every frame)
    klt_levels: int = 3                    # pyramid levels above the base image (bench_vo.py)
    klt_win: int = 11                      # LK window (px): small windows also suffer less from perspective warp
    klt_fb_px: float = 0.5                 # forward-backward disagreement above this drops a track
    klt_min_dist: int = 8                  # new corners keep this far from kept tracks (px)
    klt_max_width: int | None = None       # KLT tracks at full resolution by default
    klt_iters: int = 10                    # LK iterations per level
    klt_fast_threshold: int = 20           # FAST threshold for new corners (halved where a cell finds none)
    # KLT under exposure changes: "gain" scales the previous frame by the frame-to-frame exposure
    # gain, where significant, before LK (bench_vo_photometry.py: 10 fps drive with real-camera
    # photometry, direction of travel bias 0.34 -> 0.09 deg down, as without photometry; 0.3 ms
    # a frame at 960x540); "off", or photo_normalise's local modes (unbiased too, 30 % noisier)
    photo_norm: str = "gain"
    photo_norm_box: int = 16               # photo_normalise's local mean over a box of width / this
    readout_s: float = 0.0                 # rolling shutter: top-to-bottom readout time (0: global shutter)
    keep_matches: bool = False             # keep each pair's inlier pixels and bearings (readout estimate)


@dataclass
class VoResult:
    status: str
    R_c1c2: np.ndarray = field(default_factory=lambda: np.eye(3))
    u_dir: np.ndarray | None = None        # unit direction of camera 2 in camera 1
    n_features: int = 0
    n_matches: int = 0
    n_inliers: int = 0
    flow_px: float = 0.0                   # median feature motion
    parallax_px: float = 0.0               # median motion left after removing the rotation
    residual_px: float = 0.0               # RMS residual of the inliers to the fitted model
    inliers: np.ndarray | None = field(default=None, repr=False)  # mask over the correspondences
    # first-order covariances of the fit (pixel noise from the inliers' residuals, no floor):
    # rotation error of R_c1c2 (right perturbation, rad^2) and of u_dir (3x3, rank 2)
    rot_cov: np.ndarray | None = field(default=None, repr=False)
    dir_cov: np.ndarray | None = field(default=None, repr=False)
    # with VoConfig.keep_matches, for "ok" and "rotation": the inliers' pixels and bearings (z = 1)
    # in both frames, (p1, p2, q1, q2), what blendgen.sync.readout refits the rotation from;
    # without it, for "rotation" only, (None, None, q1, q2) of up to ALONG_POINTS (float32) for refit_along
    matches: tuple | None = field(default=None, repr=False)

    @property
    def has_rotation(self) -> bool:
        return self.status in ("ok", "rotation", "stationary")

    @property
    def has_direction(self) -> bool:
        return self.status == "ok"

    @property
    def stationary(self) -> bool:
        return self.status == "stationary"


class OrbVo:
    def __init__(self, camera: Camera, cfg: VoConfig | None = None):
        self.camera = camera
        self.cfg = cfg or VoConfig()
        c = self.cfg
        # detect generously, then keep the strongest per grid cell (spread features)
        self.orb = cv2.ORB_create(nfeatures=int(c.n_features * 2.5), scaleFactor=c.orb_scale_factor, nlevels=c.n_levels,
                                  edgeThreshold=19, patchSize=19, fastThreshold=c.fast_threshold)
        self.matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        self.f = 0.5 * (camera.fx + camera.fy)
        self.prev = None  # (gray, bearings Nx3, desc)

    def reset(self) -> None:
        self.prev = None

    def _features(self, gray: np.ndarray):
        c = self.cfg
        k_down = 1.0
        if c.max_width and gray.shape[1] > c.max_width:
            k_down = gray.shape[1] / c.max_width
            gray = cv2.resize(gray, (c.max_width, int(round(gray.shape[0] / k_down))), interpolation=cv2.INTER_AREA)
        px, desc = self._orb_features(gray)
        if k_down != 1.0 and len(px):
            px = (px + 0.5) * k_down - 0.5  # pixel centres at integers at both sizes
        return px, desc

    def _orb_features(self, gray: np.ndarray):
        c = self.cfg
        kps = self.orb.detect(gray, None)
        if len(kps) > c.n_features:
            h, w = gray.shape
            gx, gy = c.grid
            per_cell = max(1, int(np.ceil(c.n_features / (gx * gy))))
            resp = np.array([k.response for k in kps])
            pts = np.array([k.pt for k in kps])
            cell = (np.minimum((pts[:, 1] * gy / h).astype(int), gy - 1) * gx
                    + np.minimum((pts[:, 0] * gx / w).astype(int), gx - 1))
            order = np.lexsort((-resp, cell))
            cs = cell[order]
            start = np.searchsorted(cs, cs, side="left")
            rank = np.arange(len(cs)) - start
            keep = order[rank < per_cell]
            # fill up with the globally strongest leftovers when some cells are empty
            if len(keep) < c.n_features:
                rest = np.setdiff1d(np.arange(len(kps)), keep)
                rest = rest[np.argsort(-resp[rest])][: c.n_features - len(keep)]
                keep = np.concatenate([keep, rest])
            kps = [kps[i] for i in keep[: c.n_features]]
        kps, desc = self.orb.compute(gray, kps)
        if desc is None or len(kps) == 0:
            return np.zeros((0, 2)), None
        pts = np.array([k.pt for k in kps], dtype=np.float64)
        octave = np.array([k.octave for k in kps])
        return orb_level_to_full(pts, octave, self.orb.getScaleFactor(), gray.shape), desc

    def _bearings(self, px: np.ndarray) -> np.ndarray:
        cam = self.camera
        if len(px) == 0:
            return np.zeros((0, 3))
        n = cam.normalized(px)
        return np.hstack([n, np.ones((len(n), 1))])

    def _match(self, d1, d2) -> np.ndarray:
        """Ratio test 1->2, then a cross check 2->1 (only for the survivors: cheaper)."""
        knn = self.matcher.knnMatch(d1, d2, k=2)
        cand = [(m[0].queryIdx, m[0].trainIdx) for m in knn
                if len(m) == 1 or (len(m) == 2 and m[0].distance < self.cfg.ratio * m[1].distance)]
        if not cand:
            return np.zeros((0, 2), int)
        cand = np.array(cand, dtype=int)
        targets = np.unique(cand[:, 1])
        back = self.matcher.match(d2[targets], d1)
        best_back = np.full(len(d2), -1)
        for m in back:
            best_back[targets[m.queryIdx]] = m.trainIdx
        return cand[best_back[cand[:, 1]] == cand[:, 0]]

    def track(self, image: np.ndarray, spin: np.ndarray | None = None) -> VoResult:
        """Relative motion from the previous image to this one (first call: status 'first').
        `spin`: the camera's turn while this frame was read out (camera axes, `rs_bearings`);
        with `cfg.readout_s` > 0 it undoes the rolling shutter's rotation."""
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        prev = self.prev
        rep = _repeated(prev[0], len(prev[1]), gray, self.cfg.min_features) if prev is not None else None
        if rep is not None:
            return rep
        px, desc = self._features(gray)
        b = rs_bearings(self._bearings(px), px, spin, self.cfg.readout_s, self.camera.height)
        self.prev = (gray, px, b, desc)
        if prev is None:
            return VoResult("first", n_features=len(px))
        _, px1, b1, d1 = prev
        res = VoResult("few_features", n_features=min(len(px), len(px1)))
        if desc is None or d1 is None or len(px) < self.cfg.min_features or len(px1) < self.cfg.min_features:
            return res
        pairs = self._match(d1, desc)
        return solve_pair(res, px1[pairs[:, 0]], px[pairs[:, 1]], b1[pairs[:, 0]], b[pairs[:, 1]], self.cfg, self.f)


def orb_level_to_full(pts: np.ndarray, octave: np.ndarray, scale_factor: float, shape) -> np.ndarray:
    """Full-resolution pixel positions (centres at integers) of OpenCV ORB keypoints.

    OpenCV reports a keypoint found at pixel x_L of pyramid level k as x_L * s, s =
    scale_factor^k, but level k is the image resized to round(W / s) x round(H / s): its true
    scale is W / W_k (and H / H_k, a different one), and with pixel centres at integers the
    position is (x_L + 0.5) W / W_k - 0.5. Without the +0.5 a constant offset of 0.5 (s - 1) moves
    the focus of expansion (~1 px, 0.2 deg at 480x270). Without the rounded sizes positions are
    scaled by s W_k / W about the corner (up to 0.45 % at 480x270: ~0.6 px at the bottom rows), and
    differently per level: a ground feature that grows between frames and is found one level up
    moves by up to ~0.6 px. Fixed, the pair's rotation error on the 60 s synthetic drive drops
    from 0.042 to 0.033 deg RMS (docs/sync.md, "VO: the relative rotation's bias")."""
    h, w = shape[:2]
    # as OpenCV's getScale and computeLayerInfo: float scale, float division, cvRound (half to even)
    s = np.power(float(np.float32(scale_factor)), np.asarray(octave, dtype=np.float64)).astype(np.float32)
    wk = np.rint(np.float32(w) / s).astype(np.float64)
    hk = np.rint(np.float32(h) / s).astype(np.float64)
    x_l = np.asarray(pts, dtype=np.float64) / s.astype(np.float64)[:, None]
    return np.column_stack([(x_l[:, 0] + 0.5) * (w / wk) - 0.5, (x_l[:, 1] + 0.5) * (h / hk) - 0.5])


def rs_bearings(q: np.ndarray, px: np.ndarray, spin: np.ndarray | None, readout_s: float,
                height: int) -> np.ndarray:
    """Bearings (z = 1) of a rolling-shutter frame as the camera saw them when its top row was
    exposed (the frame's time stamp). Row v is exposed tau = readout_s * (v + 0.5) / height later,
    the camera having turned by R(tau) in its own axes meanwhile, so its bearing seen from the top
    row's orientation is R(tau) b_row.

    `spin`: the camera's turn during the readout, from the gyro (camera axes): a (K, 3) table of
    rotation vectors R(tau_k) at K >= 2 times tau_k evenly from 0 to readout_s (row 0 to the
    bottom row), interpolated per point; or one (3,) angular velocity (rad/s), R(tau) =
    exp([spin] tau). The table matters: camera shake of a few Hz changes the rate within a 30 ms
    readout (at 6 Hz by 1 rad of phase), and a constant rate then over-corrects the middle rows
    (measured: relative rotations 3-5 % too large, docs/sync.md). Rotation only: the camera's
    travel during the readout (0.24 m at 8 m/s over 30 ms) is not modelled."""
    if spin is None or readout_s <= 0 or len(q) == 0:
        return q
    spin = np.asarray(spin, float)
    tau = readout_s * (px[:, 1] + 0.5) / height
    if spin.ndim == 1:
        rv = tau[:, None] * spin[None, :]
    else:
        knots = np.linspace(0.0, readout_s, len(spin))
        rv = np.stack([np.interp(tau, knots, spin[:, k]) for k in range(3)], axis=1)
    th = np.linalg.norm(rv, axis=1, keepdims=True)
    k = rv / np.maximum(th, 1e-12)
    # Rodrigues, one rotation per point
    out = (q * np.cos(th) + np.cross(k, q) * np.sin(th)
           + k * np.sum(k * q, axis=1, keepdims=True) * (1.0 - np.cos(th)))
    return out / out[:, 2:]


def make_vo(camera: Camera, cfg: VoConfig | None = None):
    """The configured front end: KltVo (default) or OrbVo."""
    cfg = cfg or VoConfig()
    if cfg.method == "klt":
        return KltVo(camera, cfg)
    if cfg.method == "orb":
        return OrbVo(camera, cfg)
    raise ValueError(f"unknown VO method {cfg.method!r}; expected 'klt' or 'orb'")


PHOTO_NORMS = ("off", "gain", "ratio", "hp", "lcn")
GAIN_GRID = (16, 9)  # blocks for the frame-to-frame gain
GAIN_SIGMAS = 3.0  # a gain is applied only this many standard errors away from 1
# ... and only this far from 1: LK's pull is ~0.07 deg of direction per % of gain change, so
# below 0.5 % it is under the pair's noise; and changes that small come from the content and
# the codec as much as from the exposure (the GoPro clip's mean steps 0.1-0.3 % with its GOP)
GAIN_MIN = 5e-3


def block_means(gray: np.ndarray) -> np.ndarray:
    """The image's mean over a GAIN_GRID of blocks (float32): what frame_gain compares. Area
    resize to 4x4 sub-blocks each (uint8, rounded), averaged in float: one rounded mean per
    block would quantise a gain near mid-grey to steps of ~0.8 %."""
    gx, gy = GAIN_GRID
    sub = cv2.resize(gray, (4 * gx, 4 * gy), interpolation=cv2.INTER_AREA).astype(np.float32)
    return sub.reshape(gy, 4, gx, 4).mean(axis=(1, 3))


def frame_gain(b0: np.ndarray, b1: np.ndarray) -> tuple[float, float]:
    """Exposure gain from frame 0 to frame 1 and the standard error of its log: the median of
    the log ratios of their block means (blocks too dark or saturated in either left out), its
    error from their spread (1.25 x 1.48 MAD / sqrt(n), the median's under normal scatter).
    The median keeps the gain from following the blocks whose content changed; how much the
    content changes sets the error: 0.12-0.2 % RMS on a smooth 10 fps drive, 0.5 % (max 1.6 %)
    with 1 deg of shake at 320x180 (bench_vo_photometry.py)."""
    ok = (b0 > 8) & (b1 > 8) & (b0 < 250) & (b1 < 250)
    if ok.sum() < 8:
        return 1.0, np.inf
    r = np.log(b1[ok] / b0[ok])
    med = float(np.median(r))
    return float(np.exp(med)), 1.2533 * 1.4826 * float(np.median(np.abs(r - med))) / np.sqrt(r.size)


def photo_normalise(gray: np.ndarray, mode: str, box_div: int = 16) -> np.ndarray:
    """A uint8 image for Lucas-Kanade that is (locally) insensitive to brightness changes.

    LK assumes brightness constancy. A patch whose gain changes by g between the frames pulls
    LK's solution by (g - 1) G^-1 sum grad(I^2) over the window; exposure flicker does that to
    every patch at once and tilted KLT's direction of travel down by 0.3 deg on the synthetic
    drive (vignetting, a per-patch gain change for a feature moving outward, did not measurably;
    docs/sync.md, "VO under real-camera photometry"). "gain" (the default) undoes the frame's
    gain in KltVo.track; these local modes undo any gain that is constant over the box, at
    ~30 % more direction scatter:
      ratio  I / local mean (x128): gain-invariant where the gain is constant over the box;
      hp     I - local mean (+128): offset-invariant, and no large-scale gradient left;
      lcn    (I - local mean) / local std: gain- and offset-invariant."""
    if mode in ("off", "gain"):
        return gray
    h, w = gray.shape
    k = max(5, (w // box_div) | 1)
    if mode == "ratio":
        m = cv2.blur(gray, (k, k), borderType=cv2.BORDER_REFLECT)
        return cv2.divide(gray, np.maximum(m, 1), scale=128.0)
    f = gray.astype(np.float32)
    m = cv2.blur(f, (k, k), borderType=cv2.BORDER_REFLECT)
    if mode == "hp":
        return cv2.convertScaleAbs(f - m + 128.0)
    if mode == "lcn":
        v = cv2.blur(f * f, (k, k), borderType=cv2.BORDER_REFLECT) - m * m
        return cv2.convertScaleAbs((f - m) * (45.0 / np.sqrt(np.maximum(v, 4.0))) + 128.0)
    raise ValueError(f"unknown photo_norm {mode!r}; expected one of {PHOTO_NORMS}")


class KltVo:
    """Track-then-detect front end: the previous frame's corners are tracked with pyramidal
    Lucas-Kanade (forward-backward checked), FAST corners are detected only in grid cells that
    lost their tracks. No descriptors and no matching: at 960x540 and 1500 features this is
    what reaches >= 60 fps on one core (ORB: 30 fps, docs/benchmarks/vo.md). The pair geometry
    (essential matrix, rotation-only, stationary) is the same `solve_pair` as ORB's."""

    def __init__(self, camera: Camera, cfg: VoConfig | None = None):
        self.camera = camera
        self.cfg = cfg or VoConfig(method="klt")
        self.f = 0.5 * (camera.fx + camera.fy)
        self.fast = cv2.FastFeatureDetector_create(threshold=self.cfg.klt_fast_threshold, nonmaxSuppression=True)
        self.fast_low = cv2.FastFeatureDetector_create(threshold=max(self.cfg.klt_fast_threshold // 2, 5),
                                                       nonmaxSuppression=True)
        self.win = (self.cfg.klt_win, self.cfg.klt_win)
        self.criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, self.cfg.klt_iters, 0.03)
        self.barren: np.ndarray | None = None  # per cell: frames to skip (no corners found there)
        self.spin = None  # the previous frame's readout turn (rs_bearings)
        self.prev = None  # (gray full-res, tracking image, corners (N, 2) float32 at tracking scale)
        self.blocks = None  # photo_norm "gain": the previous tracking image's block means
        self.gain = 1.0     # its exposure gain to the last frame (frame_gain)
        self.k_down = 1.0

    def reset(self) -> None:
        self.prev = None

    def _small(self, gray: np.ndarray) -> np.ndarray:
        mw = self.cfg.klt_max_width
        if mw and gray.shape[1] > mw:
            self.k_down = gray.shape[1] / mw
            return cv2.resize(gray, (mw, int(round(gray.shape[0] / self.k_down))), interpolation=cv2.INTER_AREA)
        self.k_down = 1.0
        return gray

    def _to_full(self, pts: np.ndarray) -> np.ndarray:
        pts = pts.astype(np.float64)
        return (pts + 0.5) * self.k_down - 0.5 if self.k_down != 1.0 else pts

    def _bearings(self, px: np.ndarray) -> np.ndarray:
        if len(px) == 0:
            return np.zeros((0, 3))
        cam = self.camera
        n = cam.normalized(px)
        return np.hstack([n, np.ones((len(n), 1))])

    def _replenish(self, img: np.ndarray, kept: np.ndarray) -> np.ndarray:
        """Top up the grid cells that have fewer corners than their share with FAST corners
        detected in those cells only (one full-image pass when many cells need it), strongest
        first, away from the kept tracks."""
        c = self.cfg
        h, w = img.shape
        gx, gy = c.grid
        per_cell = max(1, int(np.ceil(c.n_features / (gx * gy))))
        cw, ch = w / gx, h / gy

        def cell_of(pts):
            return (np.minimum((pts[:, 1] / ch).astype(int), gy - 1) * gx
                    + np.minimum((pts[:, 0] / cw).astype(int), gx - 1))

        count = np.bincount(cell_of(kept) if len(kept) else np.zeros(0, int), minlength=gx * gy)
        if self.barren is None or self.barren.size != gx * gy or len(kept) < c.min_features:
            self.barren = np.zeros(gx * gy, int)  # nothing to track (after a lens cap): look everywhere
        self.barren = np.maximum(self.barren - 1, 0)
        # only cells that lost a noticeable part of their share (a cell one corner short is not
        # worth a detector run); a cell where FAST found nothing (sky, a wall in shadow) is
        # retried only every few frames
        need = np.flatnonzero((count < 0.75 * per_cell) & (self.barren == 0))
        if need.size == 0:
            return kept
        def in_cells(det, cells):
            out = []
            for ci in cells:
                y0, x0 = int((ci // gx) * ch), int((ci % gx) * cw)
                y1, x1 = int(min(h, (ci // gx + 1) * ch)), int(min(w, (ci % gx + 1) * cw))
                for k in det.detect(img[y0:y1, x0:x1], None):
                    k.pt = (k.pt[0] + x0, k.pt[1] + y0)
                    out.append(k)
            return out

        kps = list(self.fast.detect(img, None)) if need.size > gx * gy // 4 else in_cells(self.fast, need)
        # low-contrast cells (dusk, fog, plain walls): retry them at half the threshold
        n_found = np.bincount(cell_of(cv2.KeyPoint_convert(kps)), minlength=gx * gy) if kps else np.zeros(gx * gy, int)
        weak = need[n_found[need] < 2]
        if weak.size:
            kps += in_cells(self.fast_low, weak)
        if not kps:
            self.barren[need] = 5
            return kept
        pts = cv2.KeyPoint_convert(kps).astype(np.float32)
        border = 4  # LK needs a window around the corner
        cell = cell_of(pts)
        wanted = np.zeros(gx * gy, bool)
        wanted[need] = True
        ok = (wanted[cell] & (pts[:, 0] >= border) & (pts[:, 0] < w - border) & (pts[:, 1] >= border)
              & (pts[:, 1] < h - border))
        found = np.bincount(cell[ok], minlength=gx * gy)
        self.barren[need[found[need] < 2]] = 5
        idx = np.flatnonzero(ok)  # responses only of these: a full-image detection finds ~3x as many
        pts, cell = pts[idx], cell[idx]
        resp = np.fromiter((kps[i].response for i in idx), np.float32, len(idx))
        # strongest first within each cell, at most 3x the quota as candidates
        order = np.lexsort((-resp, cell))
        cs = cell[order]
        rank = np.arange(len(cs)) - np.searchsorted(cs, cs, side="left")
        quota = per_cell - count
        order = order[rank < 3 * quota[cs]]
        md = max(1, c.klt_min_dist)
        occ = np.zeros((h // md + 3, w // md + 3), bool)
        if len(kept):  # a kept track blocks its md-cell and the 8 around it: new corners stay >= md away
            ky = (kept[:, 1] / md).astype(int).clip(0, h // md) + 1
            kx = (kept[:, 0] / md).astype(int).clip(0, w // md) + 1
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    occ[ky + dy, kx + dx] = True
        oy = (pts[order, 1] / md).astype(int) + 1
        ox = (pts[order, 0] / md).astype(int) + 1
        free = ~occ[oy, ox]  # most candidates sit by a kept track: out before the greedy loop
        order, oy, ox = order[free], oy[free], ox[free]
        new = []
        for j, y, x, ci in zip(order, oy, ox, cell[order]):
            if quota[ci] <= 0 or occ[y, x]:
                continue
            occ[y, x] = True  # new corners among themselves: one per md-cell
            new.append(j)
            quota[ci] -= 1
        if not new:
            return kept
        return np.vstack([kept.reshape(-1, 2), pts[new]])

    def track(self, image: np.ndarray, spin: np.ndarray | None = None) -> VoResult:
        """As `OrbVo.track` (`spin`: the rolling-shutter correction's angular velocity)."""
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        prev_spin = self.spin
        prev = self.prev
        rep = _repeated(prev[0], len(prev[2]), gray, self.cfg.min_features) if prev is not None else None
        if rep is not None:
            return rep
        small = self._small(gray)
        # (OpenCV's Python binding cannot take prebuilt pyramids: each LK call builds its own)
        pyr = photo_normalise(small, self.cfg.photo_norm, self.cfg.photo_norm_box)
        blocks0, self.blocks = self.blocks, block_means(small) if self.cfg.photo_norm == "gain" else None
        if prev is None or len(prev[2]) == 0:
            pts = self._replenish(small, np.zeros((0, 2), np.float32))
            self.prev = (gray, pyr, pts)
            self.spin = spin
            return VoResult("first" if prev is None else "few_features", n_features=len(pts))
        _, pyr0, p0 = prev
        if blocks0 is not None and self.blocks is not None:
            # exposure changed between the frames: bring the previous frame to this one's gain,
            # LK assumes constant brightness (docs/sync.md "VO under real-camera photometry")
            # (only a significant one: scaling by the estimate's own noise biases LK as a flicker
            # of that size would; without flicker on a shaky drive the estimate scatters 0.5 %)
            g, se = frame_gain(blocks0, self.blocks)
            self.gain = g if abs(np.log(g)) > max(GAIN_SIGMAS * se, GAIN_MIN) else 1.0
            if self.gain != 1.0:
                pyr0 = cv2.convertScaleAbs(pyr0, alpha=self.gain)
        lk = dict(winSize=self.win, maxLevel=self.cfg.klt_levels, criteria=self.criteria)
        p1, st, _ = cv2.calcOpticalFlowPyrLK(pyr0, pyr, p0.reshape(-1, 1, 2), None, **lk)
        # backward check started at the original corner with one pyramid level (as VINS-Mono's
        # reverse check): a consistent track converges in a few iterations; a cold start on the
        # full pyramid doubled the tracking time for the same rejections (bench_vo.py)
        lk_b = dict(lk, maxLevel=min(1, self.cfg.klt_levels))
        p0b, st_b, _ = cv2.calcOpticalFlowPyrLK(pyr, pyr0, p1, p0.reshape(-1, 1, 2).copy(),
                                                flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk_b)
        p1, p0b = p1.reshape(-1, 2), p0b.reshape(-1, 2)
        h, w = small.shape
        # a track is kept only if tracking it back lands where it started (occlusions, drift)
        good = ((st.ravel() == 1) & (st_b.ravel() == 1)
                & (np.linalg.norm(p0b - p0, axis=1) < self.cfg.klt_fb_px)
                & (p1[:, 0] >= 0) & (p1[:, 0] <= w - 1) & (p1[:, 1] >= 0) & (p1[:, 1] <= h - 1))
        a, b = p0[good], p1[good]
        res = VoResult("few_features", n_features=len(p0))
        if len(p0) < self.cfg.min_features:
            kept = b
        else:
            f1, f2 = self._to_full(a), self._to_full(b)
            ro, H = self.cfg.readout_s, self.camera.height
            res = solve_pair(res, f1, f2, rs_bearings(self._bearings(f1), f1, prev_spin, ro, H),
                             rs_bearings(self._bearings(f2), f2, spin, ro, H), self.cfg, self.f)
            # RANSAC outliers (moving objects, bad tracks) are not tracked further
            kept = b[res.inliers] if res.inliers is not None and res.status in ("ok", "rotation") else b
        self.prev, self.spin = (gray, pyr, self._replenish(small, kept.astype(np.float32))), spin
        return res


def solve_pair(res: VoResult, p1: np.ndarray, p2: np.ndarray, q1: np.ndarray, q2: np.ndarray,
               cfg: VoConfig, f: float) -> VoResult:
    """Relative motion from corresponding pixels p1 -> p2 (and their bearings q1, q2 with z = 1):
    stationary / pure rotation / essential matrix + Sampson refit. Shared by ORB and KLT."""
    res.n_matches = len(p1)
    if len(p1) < cfg.min_inliers:
        res.status = "few_matches"
        return res
    res.flow_px = float(np.median(np.linalg.norm(p2 - p1, axis=1)))
    if res.flow_px < cfg.stationary_px:
        res.status, res.n_inliers = "stationary", len(p1)
        res.inliers = np.ones(len(p1), bool)
        res.residual_px = res.flow_px
        res.rot_cov = _rotation_covariance(q1, max(res.flow_px, 0.1) / f)
        return res
    n1, n2 = q1[:, :2] / q1[:, 2:], q2[:, :2] / q2[:, 2:]
    # USAC (LO-RANSAC) is about twice as fast as classic RANSAC here, same accuracy after the refit
    E, mask = cv2.findEssentialMat(n1, n2, focal=1.0, pp=(0.0, 0.0), method=cv2.USAC_DEFAULT,
                                   prob=0.999, threshold=cfg.ransac_px / f)
    ok_E = E is not None and E.shape == (3, 3)
    if ok_E:
        ransac = mask.ravel() > 0
        R21, t, inl = _recover_pose(E, n1, n2, ransac)  # x2 = R x1 + t
    if not ok_E or inl.sum() < cfg.min_inliers:
        # essential matrix failed (e.g. pure rotation): fit the rotation alone
        R21, inl = _rotation_ransac(q1, q2, cfg.ransac_px * 2 / f)
        if inl.sum() < cfg.min_inliers:
            res.status = "few_matches"
            res.n_inliers = int(inl.sum())
            return res
        t = None
    res.n_inliers = int(inl.sum())
    # parallax: what is left of the motion once the best pure rotation is taken out (the
    # E decomposition's own R is arbitrary when there is no translation), over all of RANSAC's
    # inliers: under a pure rotation E is degenerate and the cheirality subset of its spurious
    # translation is the points whose noise fits that translation (median 0.7-1.3 px at 480x270)
    sel = ransac if t is not None else inl
    R_rot = so3.orthonormalize(_kabsch(q1[sel] / np.linalg.norm(q1[sel], axis=1, keepdims=True),
                                       q2[sel] / np.linalg.norm(q2[sel], axis=1, keepdims=True)))
    q1r = (R_rot @ q1[sel].T).T
    q1r = q1r[:, :2] / q1r[:, 2:]
    res.parallax_px = float(np.median(np.linalg.norm(q1r - n2[sel], axis=1)) * f)
    if t is None or res.parallax_px < cfg.min_parallax_px:
        R21, inl_r = _rotation_ransac(q1, q2, cfg.ransac_px * 2 / f)
        res.status = "rotation"
        res.n_inliers = int(inl_r.sum())
        res.R_c1c2 = R21.T
        res.residual_px = _rotation_residual_px(R21, q1[inl_r], q2[inl_r], f)
        res.inliers = inl_r
        res.rot_cov = _rotation_covariance(q1[inl_r], max(res.residual_px, 0.1) / f)
        if cfg.keep_matches:
            res.matches = (p1[inl_r], p2[inl_r], q1[inl_r], q2[inl_r])
        else:  # for refit_along: a moving camera's translation is in this rotation
            res.matches = along_subset(q1[inl_r], q2[inl_r])
        return res
    # RANSAC's E comes from one minimal sample: refit R, t on all its inliers (Sampson error).
    # All, not only those recoverPose would keep (in front, nearer than 50 baselines): far
    # points pin the rotation; refitting without them doubled the rotation error (bench_vo.py)
    R21, t, r, J, basis = _refine_rt(R21, t.ravel(), n1[ransac], n2[ransac])
    res.status = "ok"
    res.R_c1c2 = R21.T
    u = -R21.T @ t.ravel()
    res.u_dir = u / np.linalg.norm(u)
    res.n_inliers = int(ransac.sum())
    res.rot_cov, res.dir_cov, rms = _covariance_from(R21, r, J, basis)
    res.residual_px = rms * f
    # tracks to keep: all that fit the epipolar geometry (far points are fine for tracking)
    res.inliers = ransac
    if cfg.keep_matches:
        res.matches = (p1[ransac], p2[ransac], q1[ransac], q2[ransac])
    return res


ALONG_POINTS = 100  # inliers a "rotation" pair keeps for refit_along (3 parameters; 2.4 kB a frame)


def along_subset(q1: np.ndarray, q2: np.ndarray) -> tuple:
    """What a "rotation" pair keeps for refit_along: (None, None, q1, q2) of up to ALONG_POINTS
    inlier bearings spread over the list, float32."""
    k = np.linspace(0, len(q1) - 1, min(ALONG_POINTS, len(q1))).astype(int)
    return None, None, np.asarray(q1)[k].astype(np.float32), np.asarray(q2)[k].astype(np.float32)


def refit_along(res: VoResult, u_dir: np.ndarray, iters: int = 5) -> np.ndarray:
    """R_c1c2 of a "rotation" pair refitted with the camera's direction of travel `u_dir`
    (camera 1 axes, from the IMU + GNSS filter) held fixed: Gauss-Newton on the Sampson
    distance of E = [t]x R over R alone. A pure-rotation fit takes a moving camera's
    translation flow for rotation: on the real GoPro Karma clip (30 fps, 8 m/s, parallax below
    a pixel) those pairs put the gyro's bias 2 deg/s off about the camera's x axis, the pairs
    with a two-view fit 0.1 deg/s; refitted along the filter's direction, 0.07 deg/s. With no
    translation every direction fits the true rotation, so a poor `u_dir` costs nothing."""
    _, _, q1, q2 = res.matches
    x1 = np.asarray(q1, float)
    x2 = np.asarray(q2, float)
    x1, x2 = x1 / x1[:, 2:], x2 / x2[:, 2:]
    u = np.asarray(u_dir, float) / np.linalg.norm(u_dir)
    R0 = np.asarray(res.R_c1c2).T  # R21

    def stack(d):  # E for d and its forward differences, in one batch
        Rs = [R0 @ so3.exp(d + 1e-7 * e) for e in np.vstack([np.zeros(3), np.eye(3)])]
        return np.stack([so3.hat(-R @ u) @ R for R in Rs])

    d = np.zeros(3)
    for _ in range(iters):
        r = _sampson_E(stack(d), x1, x2)
        J = ((r[1:] - r[0]) / 1e-7).T
        step = np.linalg.solve(J.T @ J + 1e-12 * np.eye(3), -J.T @ r[0])
        if not np.all(np.isfinite(step)):
            return np.asarray(res.R_c1c2)
        d = d + step
        if np.linalg.norm(step) < 1e-9:
            break
    return (R0 @ so3.exp(d)).T


def _recover_pose(E: np.ndarray, n1: np.ndarray, n2: np.ndarray, mask: np.ndarray,
                  max_depth: float = 50.0):
    """cv2.recoverPose's cheirality test, vectorised: of the four (R, +-t) decompositions keep
    the one with most RANSAC inliers in front of both cameras (depth in baselines, below
    max_depth as recoverPose's distanceThresh). recoverPose triangulated every point four times
    with SVDs: 16 ms of a 25 ms KLT frame at 960x540."""
    R1, R2, t = cv2.decomposeEssentialMat(E)
    t = t.ravel()
    idx = np.flatnonzero(mask)
    x1 = np.hstack([n1[idx], np.ones((len(idx), 1))])
    x2 = np.hstack([n2[idx], np.ones((len(idx), 1))])
    best, best_n = None, -1
    for R, tt in ((R1, t), (R1, -t), (R2, t), (R2, -t)):
        # depths d1, d2 minimising |d1 R x1 + t - d2 x2|
        a = x1 @ R.T
        aa, ab, bb = np.sum(a * a, 1), np.sum(a * x2, 1), np.sum(x2 * x2, 1)
        at, bt = a @ tt, x2 @ tt
        det = aa * bb - ab * ab
        ok = det > 1e-12
        det = np.where(ok, det, 1.0)
        d1 = (ab * bt - bb * at) / det
        d2 = (aa * bt - ab * at) / det
        front = ok & (d1 > 0) & (d2 > 0) & (d1 < max_depth) & (d2 < max_depth)
        if front.sum() > best_n:
            best, best_n = (R, tt, front), int(front.sum())
    R, tt, front = best
    inl = np.zeros(len(n1), bool)
    inl[idx[front]] = True
    return R, tt.reshape(3, 1), inl


def _rotation_covariance(q: np.ndarray, sigma: float) -> np.ndarray:
    """Covariance of a rotation fitted to bearings q (rows) with angular noise sigma (rad):
    sigma^2 (sum (I - b b^T))^-1, the linearised Kabsch information. Roll about the optical
    axis comes out less certain than pan / tilt, as it should for a narrow field of view."""
    if len(q) < 3:
        return np.eye(3) * 1e2
    b = q / np.linalg.norm(q, axis=1, keepdims=True)
    info = len(b) * np.eye(3) - b.T @ b
    return sigma**2 * np.linalg.pinv(info)


def _tangent_basis(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to the unit vector t (the tangent plane of its sphere)."""
    a = np.array([1.0, 0, 0]) if abs(t[0]) < 0.9 else np.array([0, 1.0, 0])
    b1 = np.cross(t, a)
    b1 /= np.linalg.norm(b1)
    return b1, np.cross(t, b1)


def _perturb_rt(R21: np.ndarray, t: np.ndarray, d: np.ndarray, basis) -> tuple[np.ndarray, np.ndarray]:
    """(R21 exp(d[:3]), t moved by d[3:] along its tangent basis, renormalised)."""
    tt = t + d[3] * basis[0] + d[4] * basis[1]
    return R21 @ so3.exp(d[:3]), tt / np.linalg.norm(tt)


def _sampson_rt(R21: np.ndarray, t: np.ndarray, x1: np.ndarray, x2: np.ndarray, h: float = 1e-7):
    """Signed Sampson distances of E = [t]x R21 (t unit) over the homogeneous points x1, x2, and
    their forward-difference Jacobian (n, 5) with respect to a right rotation perturbation of
    R21 and a tangent perturbation of t (`_tangent_basis`): the six models in one batch.
    Returns (r, J, basis)."""
    basis = _tangent_basis(t)
    E = so3.hat(t) @ R21
    # to first order (the error is O(h^2)): R exp(h e_i) = R + h R [e_i]x, t + h b_j stays unit
    dE = [E @ so3.hat(e) for e in np.eye(3)] + [so3.hat(b) @ R21 for b in basis]
    r = _sampson_E(np.stack([E] + [E + h * d for d in dE]), x1, x2)
    return r[0], ((r[1:] - r[0]) / h).T, basis


def _covariance_from(R21: np.ndarray, r: np.ndarray, J: np.ndarray, basis):
    """First-order covariance of the two-view fit from its Sampson residuals r and Jacobian J
    (`_sampson_rt`): s^2 (J^T J)^-1, s^2 the residuals' mean square. It grows with fewer
    inliers, larger residuals and less parallax (a short baseline or far scene makes the
    direction columns of J small). Returns (cov of the right perturbation of R_c1c2, cov of
    u_dir (3x3, rank 2), RMS Sampson distance)."""
    if len(r) < 8:
        return np.eye(3) * 1e2, np.eye(3) * 1e2, float("nan")
    s2 = float(np.mean(r**2))
    C = s2 * np.linalg.pinv(J.T @ J)
    # R_c1c2 = R21^T; R21 exp(d) -> R21^T exp(-R21 d): right perturbation -R21 d
    rot = R21 @ C[:3, :3] @ R21.T
    A = -R21.T @ np.stack(basis, axis=1)  # u = -R21^T t
    return 0.5 * (rot + rot.T), A @ C[3:, 3:] @ A.T, float(np.sqrt(s2))


def _homogeneous(n: np.ndarray) -> np.ndarray:
    return np.hstack([n, np.ones((len(n), 1))])


def _pair_covariance(R21: np.ndarray, t: np.ndarray, n1: np.ndarray, n2: np.ndarray):
    """`_covariance_from` at (R21, t) for the normalised points n1 -> n2."""
    r, J, basis = _sampson_rt(R21, t / np.linalg.norm(t), _homogeneous(n1), _homogeneous(n2))
    return _covariance_from(R21, r, J, basis)


def _rotation_residual_px(R21, q1, q2, f) -> float:
    if len(q1) == 0:
        return 0.0
    a = q1 / np.linalg.norm(q1, axis=1, keepdims=True)
    b = q2 / np.linalg.norm(q2, axis=1, keepdims=True)
    return float(np.sqrt(np.mean(np.sum((b - a @ R21.T) ** 2, axis=1))) * f)


def _sampson_E(E: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Signed Sampson distances for one E (3x3) or a stack of them (k, 3, 3) -> (n,) / (k, n)."""
    Es = E.reshape(-1, 3, 3)
    k = len(Es)
    # one (n, 3) x (3, 3k) product each: numpy's broadcast matmul over a stack is ~10x slower
    Ex1 = (x1 @ np.swapaxes(Es, 1, 2).transpose(1, 0, 2).reshape(3, 3 * k)).reshape(-1, k, 3)
    Etx2 = (x2 @ Es.transpose(1, 0, 2).reshape(3, 3 * k)).reshape(-1, k, 3)
    num = np.einsum("nj,nkj->kn", x2, Ex1)
    den = (Ex1[..., 0] ** 2 + Ex1[..., 1] ** 2 + Etx2[..., 0] ** 2 + Etx2[..., 1] ** 2).T
    r = num / np.sqrt(den + 1e-15)
    return r if E.ndim == 3 else r[0]


def _refine_rt(R: np.ndarray, t: np.ndarray, n1: np.ndarray, n2: np.ndarray, max_iter: int = 20,
               damping: float = 1e-3):
    """Levenberg-Marquardt on the Sampson distance over the inliers, on the manifold (right
    rotation perturbation, t on its sphere), from RANSAC's (R, t); a step is taken only if it
    lowers the cost. RANSAC already removed the outliers: no robust kernel. Returns (R, t, r, J,
    basis) at the solution, r and J as `_sampson_rt` gives them (for `_covariance_from`); a
    hand-written loop because MINPACK's through scipy cost 2 ms a pair in call overhead and
    needed the Jacobian again for the covariance."""
    t = t / np.linalg.norm(t)
    x1, x2 = _homogeneous(n1), _homogeneous(n2)
    r, J, basis = _sampson_rt(R, t, x1, x2)
    if len(n1) < 8:
        return R, t, r, J, basis
    cost = float(r @ r)
    for _ in range(max_iter):
        A, g = J.T @ J, J.T @ r
        d = np.linalg.solve(A + damping * np.diag(np.diag(A)) + 1e-12 * np.eye(5), -g)
        if not np.all(np.isfinite(d)):
            break
        R1, t1 = _perturb_rt(R, t, d, basis)
        r1, J1, basis1 = _sampson_rt(R1, t1, x1, x2)
        cost1 = float(r1 @ r1)
        if not cost1 <= cost:
            damping *= 10.0
            if damping > 1e6:
                break
            continue
        converged = cost - cost1 <= 1e-6 * cost or np.linalg.norm(d) < 1e-7  # MINPACK's ftol, xtol before
        R, t, r, J, basis, cost = R1, t1, r1, J1, basis1, cost1
        damping = max(damping / 10.0, 1e-7)
        if converged:
            break
    return R, t, r, J, basis


def _same_image(a: np.ndarray, b: np.ndarray) -> bool:
    # a duplicated frame (encoder repeat) is identical up to compression noise
    return float(cv2.norm(a, b, cv2.NORM_L1)) / a.size < 0.5


def _repeated(prev: np.ndarray, n_prev: int, gray: np.ndarray, min_features: int) -> VoResult | None:
    """The result for a frame that repeats the previous one, or None. Two identical featureless
    frames (black, lens cap) saw nothing: not a good "repeated" pair."""
    if prev.shape != gray.shape or not _same_image(prev, gray):
        return None
    return VoResult("few_features" if n_prev < min_features else "repeated", n_features=n_prev)


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """R minimising |b - R a| for unit vectors (rows)."""
    H = a.T @ b
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T


def _rotation_ransac(q1: np.ndarray, q2: np.ndarray, thresh: float, iters: int = 64):
    """Pure-rotation model q2 ~ R q1 with a small RANSAC (2-point minimal sets) and refit."""
    a = q1 / np.linalg.norm(q1, axis=1, keepdims=True)
    b = q2 / np.linalg.norm(q2, axis=1, keepdims=True)
    n = len(a)
    rng = np.random.default_rng(0)
    best = np.zeros(n, bool)
    R_best = np.eye(3)
    for _ in range(iters if n > 2 else 0):
        i = rng.choice(n, 2, replace=False)
        R = _kabsch(a[i], b[i])
        err = np.linalg.norm(b - a @ R.T, axis=1)
        inl = err < thresh
        if inl.sum() > best.sum():
            best, R_best = inl, R
    if best.sum() >= 3:
        for _ in range(2):
            R_best = _kabsch(a[best], b[best])
            best = np.linalg.norm(b - a @ R_best.T, axis=1) < thresh
    return so3.orthonormalize(R_best), best
