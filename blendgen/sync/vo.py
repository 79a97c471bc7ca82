"""Monocular ORB visual odometry between consecutive frames (OpenCV).

Per frame pair: ORB keypoints spread over a grid (best response per cell), Hamming matching
with Lowe's ratio test and a mutual (cross) check, essential-matrix RANSAC on undistorted
normalised points, `recoverPose`. The result is a relative rotation and a translation
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

from blendgen.geometry import Camera
from blendgen.sync import so3


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
    n_levels: int = 6
    max_width: int | None = 640            # larger frames are downscaled for detection (speed)


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
        self.orb = cv2.ORB_create(nfeatures=int(c.n_features * 2.5), scaleFactor=1.2, nlevels=c.n_levels,
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
        # OpenCV maps a pyramid level's pixel x_L to x_L * s; with pixel centres at integers the
        # full-resolution position is (x_L + 0.5) * s - 0.5. The missing 0.5 (s - 1) is the same
        # in both frames, so it moves the focus of expansion (a bias of ~1 px = 0.2 deg here).
        s = self.orb.getScaleFactor() ** np.array([k.octave for k in kps], dtype=np.float64)
        return pts + 0.5 * (s - 1.0)[:, None], desc

    def _bearings(self, px: np.ndarray) -> np.ndarray:
        cam = self.camera
        if len(px) == 0:
            return np.zeros((0, 3))
        n = cv2.undistortPoints(px.reshape(-1, 1, 2), cam.K, cam.D).reshape(-1, 2)
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

    def track(self, image: np.ndarray) -> VoResult:
        """Relative motion from the previous image to this one (first call: status 'first')."""
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        prev = self.prev
        if prev is not None and prev[0].shape == gray.shape and _same_image(prev[0], gray):
            if len(prev[1]) < self.cfg.min_features:
                # two identical featureless frames (black, lens cap): nothing seen, not a
                # good "repeated" pair (the summary counted them as good)
                return VoResult("few_features", n_features=len(prev[1]))
            return VoResult("repeated", n_features=len(prev[1]))
        px, desc = self._features(gray)
        b = self._bearings(px)
        self.prev = (gray, px, b, desc)
        if prev is None:
            return VoResult("first", n_features=len(px))
        _, px1, b1, d1 = prev
        res = VoResult("few_features", n_features=min(len(px), len(px1)))
        if desc is None or d1 is None or len(px) < self.cfg.min_features or len(px1) < self.cfg.min_features:
            return res
        pairs = self._match(d1, desc)
        res.n_matches = len(pairs)
        if len(pairs) < self.cfg.min_inliers:
            res.status = "few_matches"
            return res
        p1, p2 = px1[pairs[:, 0]], px[pairs[:, 1]]
        q1, q2 = b1[pairs[:, 0]], b[pairs[:, 1]]
        res.flow_px = float(np.median(np.linalg.norm(p2 - p1, axis=1)))
        if res.flow_px < self.cfg.stationary_px:
            res.status, res.n_inliers = "stationary", len(pairs)
            return res
        n1, n2 = q1[:, :2] / q1[:, 2:], q2[:, :2] / q2[:, 2:]
        # USAC (LO-RANSAC) is about twice as fast as classic RANSAC here, same accuracy after the refit
        E, mask = cv2.findEssentialMat(n1, n2, focal=1.0, pp=(0.0, 0.0), method=cv2.USAC_DEFAULT,
                                       prob=0.999, threshold=self.cfg.ransac_px / self.f)
        ok_E = E is not None and E.shape == (3, 3)
        if ok_E:
            n_in, R, t, mask2 = cv2.recoverPose(E, n1, n2, focal=1.0, pp=(0.0, 0.0), mask=mask.copy())
            inl = mask2.ravel() > 0
            R21 = R  # x2 = R x1 + t
        if not ok_E or inl.sum() < self.cfg.min_inliers:
            # essential matrix failed (e.g. pure rotation): fit the rotation alone
            R21, inl = _rotation_ransac(q1, q2, self.cfg.ransac_px * 2 / self.f)
            if inl.sum() < self.cfg.min_inliers:
                res.status = "few_matches"
                res.n_inliers = int(inl.sum())
                return res
            t = None
        res.n_inliers = int(inl.sum())
        # parallax: what is left of the motion once the best pure rotation is taken out (the
        # E decomposition's own R is arbitrary when there is no translation)
        R_rot = so3.orthonormalize(_kabsch(q1[inl] / np.linalg.norm(q1[inl], axis=1, keepdims=True),
                                           q2[inl] / np.linalg.norm(q2[inl], axis=1, keepdims=True)))
        q1r = (R_rot @ q1[inl].T).T
        q1r = q1r[:, :2] / q1r[:, 2:]
        res.parallax_px = float(np.median(np.linalg.norm(q1r - n2[inl], axis=1)) * self.f)
        if t is None or res.parallax_px < self.cfg.min_parallax_px:
            R21, inl_r = _rotation_ransac(q1, q2, self.cfg.ransac_px * 2 / self.f)
            res.status = "rotation"
            res.n_inliers = int(inl_r.sum())
            res.R_c1c2 = R21.T
            return res
        # RANSAC's E comes from one minimal sample: refit R, t on all inliers (Sampson error)
        R21, t = _refine_rt(R21, t.ravel(), n1[inl], n2[inl])
        res.status = "ok"
        res.R_c1c2 = R21.T
        u = -R21.T @ t.ravel()
        res.u_dir = u / np.linalg.norm(u)
        return res


def _sampson(params: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    R = so3.exp(params[:3])
    th, ph = params[3], params[4]
    t = np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
    E = so3.hat(t) @ R
    Ex1 = x1 @ E.T
    Etx2 = x2 @ E
    num = np.sum(x2 * Ex1, axis=1)
    den = Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2
    return num / np.sqrt(den + 1e-15)


def _refine_rt(R: np.ndarray, t: np.ndarray, n1: np.ndarray, n2: np.ndarray):
    """Levenberg-Marquardt on the Sampson distance over the inliers; keeps the RANSAC solution
    if the refit does not lower the cost."""
    from scipy.optimize import least_squares

    if len(n1) < 8:
        return R, t
    x1 = np.hstack([n1, np.ones((len(n1), 1))])
    x2 = np.hstack([n2, np.ones((len(n2), 1))])
    t = t / np.linalg.norm(t)
    p0 = np.concatenate([so3.log(R), [np.arccos(np.clip(t[2], -1, 1)), np.arctan2(t[1], t[0])]])
    c0 = np.sum(_sampson(p0, x1, x2) ** 2)
    try:
        # RANSAC already removed the outliers: plain LM (MINPACK) is several times faster than
        # a robust trust-region solve and gave the same accuracy here
        sol = least_squares(_sampson, p0, args=(x1, x2), method="lm", max_nfev=40)
    except (ValueError, np.linalg.LinAlgError):
        return R, t
    if not np.all(np.isfinite(sol.x)) or np.sum(_sampson(sol.x, x1, x2) ** 2) > c0:
        return R, t
    th, ph = sol.x[3], sol.x[4]
    return so3.exp(sol.x[:3]), np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])


def _same_image(a: np.ndarray, b: np.ndarray) -> bool:
    # a duplicated frame (encoder repeat) is identical up to compression noise
    return float(cv2.norm(a, b, cv2.NORM_L1)) / a.size < 0.5


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
