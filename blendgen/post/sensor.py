"""Sensor matching: measure the real camera's noise, blur, JPEG compression and vignetting,
and give the rendered pixels the same, each only when it is measured above a threshold.

Measurements (no reference needed):
- noise: Immerkaer's 1996 fast sigma estimate (Laplacian-difference mask) on non-edge pixels;
- blur: the re-blur metric of Crete et al. 2007 (0 sharp .. 1 blurred); the render is given
  the Gaussian sigma that brings its own metric to the real frame's;
- JPEG: 8x8 block-boundary gradient ratio (blockiness); quality from the JPEG-ghost minimum
  (re-compressing at the original quality changes the image least);
- vignetting: radial falloff k of I(r) = I0 (1 - k r^2), fitted per row so that the
  vertical sky/road layout does not count as falloff.

The profile is a property of the camera and changes slowly, so a recording measures it once
per block of SENSOR_BLOCK frames (`SensorCache`, used by the frame processor); a single
`composite_frame` call without a profile measures its own frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, replace

import cv2
import numpy as np

from blendgen.errors import UserError

NOISE_MIN_SIGMA = 1.5  # 8-bit levels (quantisation and fine texture read as ~1)
BLUR_MIN_DELTA = 0.03  # re-blur metric above the render's
BLOCKINESS_MIN = 1.12  # boundary / interior gradient ratio
VIGNETTE_MIN_K = 0.15  # 15% darker at the corner radius (scene content can fake ~10%)
BLUR_SIGMAS = (0.0, 0.6, 1.0, 1.5, 2.2)
GHOST_QUALITIES = (30, 40, 50, 60, 70, 80, 90)
# Refresh rule of SensorCache: noise, JPEG and vignetting measured once per block of frames
# (1-3 s at 10-30 fps); a frame whose brightness differs from its block's measured frame by
# more than this ratio is measured itself (gain, hence noise, follows the light).
SENSOR_BLOCK = 30
REFRESH_LEVEL_RATIO = 1.25
CROP = 384  # the measurement's centre crop (px): the statistics are global, this keeps them fast


@dataclass
class SensorProfile:
    noise_sigma: float
    blur_metric: float
    blockiness: float
    jpeg_quality: int | None
    vignette_k: float

    def to_dict(self) -> dict:
        return asdict(self)


def centre_crop(img: np.ndarray, size: int = CROP) -> np.ndarray:
    """A central crop on the 8x8 grid (the JPEG measures need the frame's grid)."""
    h, w = img.shape[:2]
    ch, cw = min(h, size) // 8 * 8 or h, min(w, size) // 8 * 8 or w
    y0, x0 = (h - ch) // 2 // 8 * 8, (w - cw) // 2 // 8 * 8
    return img[y0:y0 + ch, x0:x0 + cw]


def measure_frame(real_bgr: np.ndarray) -> SensorProfile:
    """The profile of a whole frame, measured on its centre crop."""
    return measure(centre_crop(real_bgr))


class SensorCache:
    """Sensor profiles of one recording. Noise, JPEG and vignetting belong to the camera and
    change slowly: frame i takes them from frame a = i - i % block (read with ``read_frame``
    when this worker has not seen it), or from itself when its brightness differs from frame
    a's by more than REFRESH_LEVEL_RATIO (gain follows the light) or frame a cannot be read.
    Blur follows the motion and is measured on every frame (~0.5 ms). Deterministic per frame
    whatever order a worker processes frames in (composites are bit-identical however the
    farm spreads the work)."""

    def __init__(self, read_frame: Callable[[int], np.ndarray], block: int = SENSOR_BLOCK):
        if block < 1:
            raise ValueError(f"block must be >= 1, got {block}")
        self.read_frame, self.block = read_frame, int(block)
        self._anchors: dict[int, tuple[SensorProfile, float]] = {}
        self.measured = 0  # full measurements made (for the benchmark and the tests)

    def profile(self, i: int, real_bgr: np.ndarray) -> tuple[SensorProfile, dict]:
        """(profile for frame i, where it came from) given frame i's pixels ``real_bgr``."""
        a = i - i % self.block
        gray = cv2.cvtColor(centre_crop(real_bgr), cv2.COLOR_BGR2GRAY)
        level = float(cv2.mean(gray)[0])
        if a == i or a not in self._anchors:
            try:
                anchor = gray if a == i else cv2.cvtColor(centre_crop(self.read_frame(a)), cv2.COLOR_BGR2GRAY)
            except (UserError, OSError) as e:  # a bad frame must not fail the good ones of its block
                self.measured += 1
                return measure(gray), {"frame": i, "reason": f"frame {a} unreadable: {e}"}
            if a not in self._anchors:
                self._anchors[a] = (measure(anchor), float(cv2.mean(anchor)[0]))
                self.measured += 1
                if len(self._anchors) > 8:  # a worker moves forward through the recording
                    self._anchors.pop(next(iter(self._anchors)))
        prof, a_level = self._anchors[a]
        if a == i:
            return prof, {"frame": i}
        ratio = (level + 1.0) / (a_level + 1.0)
        if max(ratio, 1.0 / ratio) > REFRESH_LEVEL_RATIO:
            self.measured += 1
            return measure(gray), {"frame": i, "reason": f"brightness x{ratio:.2f} of frame {a}"}
        return replace(prof, blur_metric=blur_metric(gray)), {"frame": a, "blur_frame": i}


def measure(real_bgr: np.ndarray) -> SensorProfile:
    """The profile of an 8-bit BGR or grey image (all of it)."""
    gray = cv2.cvtColor(real_bgr, cv2.COLOR_BGR2GRAY) if real_bgr.ndim == 3 else real_bgr
    blockiness = _blockiness(gray)
    return SensorProfile(noise_sigma=noise_sigma(gray), blur_metric=blur_metric(gray), blockiness=blockiness,
                         jpeg_quality=_jpeg_quality(gray) if blockiness >= BLOCKINESS_MIN else None,
                         vignette_k=vignette_k(gray))


def noise_sigma(gray: np.ndarray) -> float:
    """Immerkaer's estimate on the flat part of the image (8-bit units)."""
    g = gray.astype(np.float32)
    if min(g.shape) < 3:
        return 0.0
    m = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    resp = np.abs(cv2.filter2D(g, -1, m, borderType=cv2.BORDER_REFLECT))[1:-1, 1:-1]
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0)[1:-1, 1:-1]
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1)[1:-1, 1:-1]
    edge = cv2.add(np.abs(gx), np.abs(gy))
    # Exclude edges and texture, but not the noise itself: a tight threshold would keep only
    # the quietest pixels and underestimate sigma.
    flat = edge < max(2.0 * np.median(edge), 1e-3)
    inner = gray[1:-1, 1:-1]
    sel = (flat & (inner >= 3) & (inner <= 252)).view(np.uint8)  # clipped pixels carry no noise
    if cv2.countNonZero(sel) < 64:
        return 0.0
    return float(np.sqrt(np.pi / 2) * cv2.mean(resp, mask=sel)[0] / 6.0)


def sum_masks(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The uint8 and uint16 all-ones masks blur_metric sums under (computed once when one
    mask serves several calls, as in apply's blur search)."""
    m8 = (mask[:-1, :-1] != 0).view(np.uint8) * np.uint8(255)
    return m8, m8.astype(np.uint16) * np.uint16(257)


def blur_metric(gray: np.ndarray, mask: np.ndarray | None = None, *,
                masks: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    """Crete et al. re-blur metric in [0, 1] (0: sharp), over ``mask`` when given (``masks``:
    sum_masks(mask), precomputed)."""
    if min(gray.shape) < 10:
        return 0.0
    if gray.dtype == np.uint8:
        # Exact integer arithmetic (2.5x faster than float, called 3-4 times per object): 9x
        # the box means are integer box sums, so 9 * max(d_f - d_b, 0) = 9 d_f - |S diff|,
        # clamped at 0 by the unsigned saturating subtract.
        g, k, n9 = gray, None, 9.0
        bv = cv2.boxFilter(g, cv2.CV_16U, (1, 9), normalize=False)
        bh = cv2.boxFilter(g, cv2.CV_16U, (9, 1), normalize=False)
    else:
        g, n9 = gray.astype(np.float32), 1.0
        k = np.ones((1, 9), np.float32) / 9
        bv = cv2.filter2D(g, -1, k.T)
        bh = cv2.filter2D(g, -1, k)
    # absolute neighbour differences on the common (h-1)x(w-1) grid
    d_f_v = cv2.absdiff(g[1:, :-1], g[:-1, :-1])
    d_f_h = cv2.absdiff(g[:-1, 1:], g[:-1, :-1])
    if k is None:
        v_v = cv2.subtract(cv2.multiply(d_f_v, 9, dtype=cv2.CV_16U), cv2.absdiff(bv[1:, :-1], bv[:-1, :-1]))
        v_h = cv2.subtract(cv2.multiply(d_f_h, 9, dtype=cv2.CV_16U), cv2.absdiff(bh[:-1, 1:], bh[:-1, :-1]))
    else:
        v_v = np.maximum(d_f_v - cv2.absdiff(bv[1:, :-1], bv[:-1, :-1]), 0)
        v_h = np.maximum(d_f_h - cv2.absdiff(bh[:-1, 1:], bh[:-1, :-1]), 0)
    if mask is None:
        s_f_v, s_f_h, s_v_v, s_v_h = (cv2.sumElems(x)[0] for x in (d_f_v, d_f_h, v_v, v_h))
    elif k is None:
        # masked sums as AND with an all-ones/zero mask + sum: 10x faster than cv2.mean(mask=)
        m8, m16 = masks if masks is not None else sum_masks(mask)
        s_f_v, s_f_h = (cv2.sumElems(cv2.bitwise_and(x, m8))[0] for x in (d_f_v, d_f_h))
        s_v_v, s_v_h = (cv2.sumElems(cv2.bitwise_and(x, m16))[0] for x in (v_v, v_h))
    else:
        m = (mask[:-1, :-1] != 0).view(np.uint8)
        n = cv2.countNonZero(m)  # means over the mask -> sums
        s_f_v, s_f_h, s_v_v, s_v_h = (cv2.mean(x, mask=m)[0] * n for x in (d_f_v, d_f_h, v_v, v_h))
    if s_f_v < 1e-3 or s_f_h < 1e-3:
        return 0.0
    b_v = (s_f_v - s_v_v / n9) / s_f_v
    b_h = (s_f_h - s_v_h / n9) / s_f_h
    return float(max(b_v, b_h))


def _blockiness(gray: np.ndarray) -> float:
    g = gray.astype(np.float32)
    if g.shape[1] < 32 or g.shape[0] < 32:
        return 1.0
    # Per-line mean steps, then medians: one scene edge that happens to lie on the 8-px grid
    # must not look like blocking.
    col_step = np.abs(np.diff(g, axis=1)).mean(axis=0)  # step between columns j and j+1
    row_step = np.abs(np.diff(g, axis=0)).mean(axis=1)
    cb = np.arange(col_step.size) % 8 == 7
    rb = np.arange(row_step.size) % 8 == 7
    boundary = 0.5 * (np.median(col_step[cb]) + np.median(row_step[rb]))
    interior = 0.5 * (np.median(col_step[~cb]) + np.median(row_step[~rb]))
    return float(boundary / max(interior, 1e-3))


def _jpeg_quality(gray: np.ndarray) -> int:
    """JPEG-ghost estimate on a central crop aligned to the 8x8 grid."""
    h, w = gray.shape
    s = min(256, h // 8 * 8, w // 8 * 8)
    y0, x0 = (h - s) // 2 // 8 * 8, (w - s) // 2 // 8 * 8
    crop = gray[y0:y0 + s, x0:x0 + s]
    diffs = []
    for q in GHOST_QUALITIES:
        ok, enc = cv2.imencode(".jpg", crop, [cv2.IMWRITE_JPEG_QUALITY, q])
        rec = cv2.imdecode(enc, cv2.IMREAD_GRAYSCALE)
        diffs.append(float(np.mean((rec.astype(np.float32) - crop) ** 2)))
    d = np.array(diffs)
    # The ghost: the lowest quality whose re-compression error is already near the floor.
    floor = d.min()
    ok = np.nonzero(d <= floor + 0.15 * (d.max() - floor) + 1e-6)[0]
    return int(GHOST_QUALITIES[ok[0]])


def vignette_k(gray: np.ndarray) -> float:
    """Fitted radial falloff k (0: none); rows are normalised by their central band."""
    small = cv2.resize(gray, (96, max(8, round(96 * gray.shape[0] / gray.shape[1]))),
                       interpolation=cv2.INTER_AREA).astype(np.float32)
    h, w = small.shape
    ys, xs = np.mgrid[0:h, 0:w]
    cx, cy = (w - 1) / 2, (h - 1) / 2
    rmax2 = cx * cx + cy * cy
    r2 = ((xs - cx) ** 2 + (ys - cy) ** 2) / rmax2
    band = np.abs(xs - cx) < w * 0.1
    centre = np.median(small[:, band[0]], axis=1)
    ok = (small > 8) & (small < 247) & (centre[:, None] > 8)
    rel = np.log(np.maximum(small, 1) / np.maximum(centre[:, None], 1))
    dr = r2 - (((ys - cy) ** 2) / rmax2)  # extra r^2 relative to the row's centre
    sel = ok & ~band
    if sel.sum() < 50:
        return 0.0
    x, y = dr[sel], rel[sel]
    # log(1 - k r^2) ~ -k r^2; least squares through the origin, robust to scene content by
    # symmetric averaging: a scene brighter on one side cancels against the other.
    k = -float((x * y).sum() / max((x * x).sum(), 1e-9))
    return float(np.clip(k, 0.0, 0.9))


def apply(obj_bgr: np.ndarray, alpha: np.ndarray, profile: SensorProfile, *, origin: tuple[int, int],
          frame_size: tuple[int, int], seed: int) -> tuple[np.ndarray, dict]:
    """Give the rendered crop (float BGR in [0, 1]) the real camera's degradations.

    ``alpha`` is the object coverage of the crop; ``origin`` (x0, y0) places the crop in a
    frame of ``frame_size`` (w, h) for vignetting. Returns the new crop and what was applied.
    """
    applied: dict = {}
    out = obj_bgr
    inside = alpha > 0.5
    if inside.sum() >= 16:
        real_blur = profile.blur_metric
        rows, cols = np.flatnonzero(inside.any(axis=1)), np.flatnonzero(inside.any(axis=0))
        box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))  # measure on the object only
        inside = inside[box]
        g = cv2.cvtColor(np.clip(out[box] * 255, 0, 255).astype(np.uint8), cv2.COLOR_BGR2GRAY)
        masks = sum_masks(inside)
        own = blur_metric(g, inside, masks=masks)
        if real_blur - own > BLUR_MIN_DELTA:
            best, best_err = 0.0, abs(real_blur - own)
            for s in BLUR_SIGMAS[1:]:
                gb = cv2.GaussianBlur(g, (0, 0), s)
                err = abs(blur_metric(gb, inside, masks=masks) - real_blur)
                if err >= best_err:
                    break  # the metric grows with sigma: past the best match it only gets worse
                best, best_err = s, err
            if best > 0:
                out = cv2.GaussianBlur(out, (0, 0), best)
                applied["blur_sigma"] = best
    if profile.vignette_k >= VIGNETTE_MIN_K:
        W, H = frame_size
        x0, y0 = origin
        h, w = out.shape[:2]
        # a row and a column broadcast: no HxW coordinate grids
        ys = np.arange(y0, y0 + h, dtype=np.float32)[:, None]
        xs = np.arange(x0, x0 + w, dtype=np.float32)[None, :]
        r2 = ((xs - (W - 1) / 2) ** 2 + (ys - (H - 1) / 2) ** 2) / (((W - 1) / 2) ** 2 + ((H - 1) / 2) ** 2)
        out = out * (1.0 - profile.vignette_k * r2)[..., None]
        applied["vignette_k"] = profile.vignette_k
    if profile.noise_sigma >= NOISE_MIN_SIGMA:
        rng = np.random.default_rng(seed)
        cov = alpha > 0  # noise only where the object shows: drawing it for the whole crop is slow
        out = out.copy()
        out[cov] += rng.normal(0.0, profile.noise_sigma / 255.0, size=(int(cov.sum()), 3)).astype(np.float32)
        applied["noise_sigma"] = profile.noise_sigma
    if profile.jpeg_quality is not None:
        u8 = np.clip(np.rint(out * 255), 0, 255).astype(np.uint8)
        ok, enc = cv2.imencode(".jpg", u8, [cv2.IMWRITE_JPEG_QUALITY, int(profile.jpeg_quality)])
        if ok:
            out = cv2.imdecode(enc, cv2.IMREAD_COLOR).astype(np.float32) / 255.0
            applied["jpeg_quality"] = profile.jpeg_quality
    return np.clip(out, 0.0, 1.0).astype(np.float32, copy=False), applied
