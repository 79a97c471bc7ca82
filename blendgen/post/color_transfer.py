"""Masked colour transfer: make a source region's colour statistics match a reference region.

Methods (the job's `post.color_transfer`):
- ``reinhard``: Reinhard et al. 2001, per-channel mean/std in CIE Lab.
- ``mkl``: Pitié & Kokaram 2007, the linear Monge-Kantorovich map between the two RGB
  Gaussians (matches the full 3x3 covariance, not only per-channel spread).
- ``histogram``: per-channel CDF matching in Lab (exact quantile mapping).
- ``none``: the source unchanged.

Every method is stable on degenerate input: zero-variance regions, one-pixel and empty
masks, saturated/black regions, HDR values and NaN (non-finite pixels are excluded from the
statistics). The same region onto itself is the identity, and an empty mask returns the
source unchanged bit for bit.
"""

from __future__ import annotations

import cv2
import numpy as np

from blendgen.errors import UserError

METHODS = ("reinhard", "mkl", "histogram", "none")

# Reinhard's std ratio is clamped: a flat reference (e.g. a one-pixel or saturated region)
# would otherwise flatten the object, and a flat source would blow up its noise.
MAX_STD_RATIO = 3.0
EPS = 1e-6
STATS_PIXELS = 20000
HIST_BINS = 1024


def transfer(src: np.ndarray, src_mask: np.ndarray | None, ref: np.ndarray, ref_mask: np.ndarray | None,
             method: str = "reinhard", *, strength: float = 1.0) -> np.ndarray:
    """Recolour ``src`` inside ``src_mask`` so its statistics match ``ref`` inside ``ref_mask``.

    ``src``/``ref`` are HxWx3 BGR images (uint8, or float in [0, 1] where HDR values > 1 are
    allowed); the masks are HxW booleans of their image's size (None: the whole image).
    ``strength`` in [0, 1] blends between the source (0) and the full transfer (1).
    Returns an image of ``src``'s dtype; pixels outside ``src_mask`` are untouched.
    """
    if method not in METHODS:
        raise UserError(f"unknown colour transfer method {method!r}; expected one of {list(METHODS)}",
                        where="post.color_transfer")
    src_mask = _check(src, src_mask, "src")
    ref_mask = _check(ref, ref_mask, "ref")
    out = src.copy()
    if method == "none" or strength <= 0:
        return out
    s_pix = _pixels(src, src_mask)
    r_pix = _pixels(ref, ref_mask)
    s_ok = np.isfinite(s_pix).all(axis=1)
    r_ok = np.isfinite(r_pix).all(axis=1)
    if not s_ok.any() or not r_ok.any():
        return out  # nothing to measure: leave the source as it is
    s_pix = np.where(s_ok[:, None], s_pix, 0.0).astype(np.float32)
    r_pix = r_pix[r_ok]
    mapped = transfer_pixels(s_pix, r_pix, method, fit_rows=s_ok)
    if strength < 1:
        mapped = s_pix + float(strength) * (mapped - s_pix)
    if src.dtype == np.uint8:
        out[src_mask] = np.clip(np.rint(mapped * 255.0), 0, 255).astype(np.uint8)
    else:
        out[src_mask] = np.maximum(mapped, 0.0).astype(src.dtype)
    return out


def transfer_pixels(s_pix: np.ndarray, r_pix: np.ndarray, method: str,
                    fit_rows: np.ndarray | None = None) -> np.ndarray:
    """The transfer on Nx3 float BGR pixel lists (values in [0, 1], HDR allowed).

    ``fit_rows`` selects the source pixels used for the statistics (default: all).
    """
    s_fit = s_pix if fit_rows is None else s_pix[fit_rows]
    if s_fit.shape == r_pix.shape and np.array_equal(s_fit, r_pix):
        return s_pix.copy()  # a region onto itself: the identity, without colour-space round trips
    # Statistics need no more than ~20k pixels: a regular subsample keeps them and the time.
    r_pix = r_pix[::-(-len(r_pix) // STATS_PIXELS)]
    if fit_rows is None and len(s_pix) > STATS_PIXELS:
        fit_rows = np.zeros(len(s_pix), bool)
        fit_rows[::-(-len(s_pix) // STATS_PIXELS)] = True
        s_fit = s_pix[fit_rows]
    if method == "reinhard":
        s_lab, r_lab = _lab(s_pix), _lab(r_pix)
        s_fit_lab = s_lab if fit_rows is None else s_lab[fit_rows]
        return _from_lab(_reinhard(s_lab, s_fit_lab, r_lab))
    if method == "mkl":
        return _mkl(s_pix, s_fit, r_pix)
    if method == "histogram":
        s_lab, r_lab = _lab(s_pix), _lab(r_pix)
        s_fit_lab = s_lab if fit_rows is None else s_lab[fit_rows]
        return _from_lab(_histogram(s_lab, s_fit_lab, r_lab))
    return s_pix.copy()


# ---- the three methods on pixel lists

def _mean_std(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel mean and std of Nx3 float32 (cv2.meanStdDev: numpy's column reductions
    over an Nx3 array are strided and ~10x slower)."""
    mu, sd = cv2.meanStdDev(np.ascontiguousarray(x, dtype=np.float32).reshape(-1, 1, 3))
    return mu.ravel(), sd.ravel()


def _reinhard(s: np.ndarray, s_fit: np.ndarray, r: np.ndarray) -> np.ndarray:
    mu_s, sd_s = _mean_std(s_fit)
    mu_r, sd_r = _mean_std(r)
    # A flat source has nothing to scale (x - mu = 0), so the ratio only matters when sd_s > 0.
    ratio = np.where(sd_s > EPS, sd_r / np.maximum(sd_s, EPS), 1.0)
    ratio = np.clip(ratio, 1.0 / MAX_STD_RATIO, MAX_STD_RATIO)
    if np.allclose(mu_s, mu_r, rtol=0, atol=1e-9) and np.allclose(sd_s, sd_r, rtol=0, atol=1e-9):
        return s.copy()  # same statistics: exactly the identity (no Lab round-trip error)
    return ((s - mu_s) * ratio + mu_r).astype(np.float32)


def _mkl(s: np.ndarray, s_fit: np.ndarray, r: np.ndarray) -> np.ndarray:
    mu_s, mu_r = _mean_std(s_fit)[0], _mean_std(r)[0]
    A = _cov(s_fit, mu_s)
    B = _cov(r, mu_r)
    if np.allclose(A, B, rtol=0, atol=1e-12) and np.allclose(mu_s, mu_r, rtol=0, atol=1e-9):
        return s.copy()
    # Regularise: a flat or one-pixel region has a singular covariance.
    reg = 1e-5 * max(np.trace(A), np.trace(B), 1e-6) / 3 + 1e-8
    A = A + reg * np.eye(3)
    B = B + reg * np.eye(3)
    Da2, Ua = np.linalg.eigh(A)
    Da = np.sqrt(np.clip(Da2, reg, None))
    A_half = (Ua * Da) @ Ua.T
    A_ihalf = (Ua / Da) @ Ua.T
    C = A_half @ B @ A_half
    Dc2, Uc = np.linalg.eigh((C + C.T) / 2)
    C_half = (Uc * np.sqrt(np.clip(Dc2, 0, None))) @ Uc.T
    T = A_ihalf @ C_half @ A_ihalf
    # Bound the gain as Reinhard's ratio is bounded: eigenvalues of T in [1/3, 3].
    Dt, Ut = np.linalg.eigh((T + T.T) / 2)
    T = (Ut * np.clip(Dt, 1.0 / MAX_STD_RATIO, MAX_STD_RATIO)) @ Ut.T
    return ((s - mu_s) @ T + mu_r).astype(np.float32)


def _histogram(s: np.ndarray, s_fit: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Per-channel quantile mapping through CDFs on a 1024-bin grid over the joint range."""
    out = np.empty_like(s)
    for c in range(s.shape[1]):
        lo = float(min(s_fit[:, c].min(), r[:, c].min()))
        hi = float(max(s_fit[:, c].max(), r[:, c].max()))
        if hi - lo < 1e-9:
            out[:, c] = r[0, c]  # both flat and equal
            continue
        scale = (HIST_BINS - 1) / (hi - lo)
        centres = lo + np.arange(HIST_BINS) / scale
        hs = np.bincount(np.rint((s_fit[:, c] - lo) * scale).astype(np.int64), minlength=HIST_BINS)[:HIST_BINS]
        hr = np.bincount(np.rint((r[:, c] - lo) * scale).astype(np.int64), minlength=HIST_BINS)[:HIST_BINS]
        # Mid-point ECDF: identical histograms map each bin onto itself.
        s_cdf = (np.cumsum(hs) - 0.5 * hs) / hs.sum()
        r_cdf = (np.cumsum(hr) - 0.5 * hr) / hr.sum()
        keep_s, keep_r = hs > 0, hr > 0
        q = np.interp(s[:, c], centres[keep_s], s_cdf[keep_s])
        out[:, c] = np.interp(q, r_cdf[keep_r], centres[keep_r])
    return out


# ---- helpers

def _cov(x: np.ndarray, mu: np.ndarray) -> np.ndarray:
    d = x - mu.astype(np.float32)
    return (d.T @ d).astype(np.float64) / max(len(x), 1)  # float32 BLAS; centred, so precise enough


# CIE Lab (D65) in NumPy: OpenCV's float BGR->Lab is ~50x slower on pixel lists.
_RGB2XYZ = np.array([[0.4124564, 0.3575761, 0.1804375],
                     [0.2126729, 0.7151522, 0.0721750],
                     [0.0193339, 0.1191920, 0.9503041]])
_WHITE = np.array([0.95047, 1.0, 1.08883])
_BGR2XYZ_N = (_RGB2XYZ[:, ::-1] / _WHITE[:, None]).T.astype(np.float32)  # row vectors, white-normalised
_XYZ_N2BGR = np.linalg.inv(_BGR2XYZ_N.astype(np.float64)).astype(np.float32)
_D = 6.0 / 29.0
# (fx, fy, fz) -> (L, a, b) = f @ _F2LAB + _LAB0
_F2LAB = np.array([[0.0, 500.0, 0.0], [116.0, -500.0, 200.0], [0.0, 0.0, -200.0]], np.float32)
_LAB0 = np.array([-16.0, 0.0, 0.0], np.float32)
_LAB2F = np.linalg.inv(_F2LAB.astype(np.float64)).astype(np.float32)


def _lab(bgr_pix: np.ndarray) -> np.ndarray:
    """Nx3 sRGB-encoded BGR in [0, 1] (HDR > 1 allowed) -> Nx3 CIE Lab (L in 0..100)."""
    x = np.maximum(np.asarray(bgr_pix, dtype=np.float32), 0.0)
    lin = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    t = lin @ _BGR2XYZ_N
    f = np.where(t > _D ** 3, np.cbrt(t), t / (3 * _D * _D) + 4.0 / 29.0)
    return (f @ _F2LAB + _LAB0).astype(np.float32)  # the linear f -> Lab step as one matmul


def _from_lab(lab_pix: np.ndarray) -> np.ndarray:
    lab = np.asarray(lab_pix, dtype=np.float32).copy()
    np.maximum(lab[:, :1], 0.0, out=lab[:, :1])
    f = (lab - _LAB0) @ _LAB2F
    t = np.where(f > _D, f ** 3, 3 * _D * _D * (f - 4.0 / 29.0))
    lin = np.maximum(t @ _XYZ_N2BGR, 0.0)
    out = np.where(lin <= 0.0031308, lin * 12.92, 1.055 * np.power(lin, 1 / 2.4) - 0.055)
    return np.maximum(np.nan_to_num(out, nan=0.0, posinf=1.0, neginf=0.0), 0.0).astype(np.float32)


def _pixels(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    pix = img[mask][:, :3]
    if img.dtype == np.uint8:
        return pix.astype(np.float32) / 255.0
    return pix.astype(np.float32)


def _check(img: np.ndarray, mask: np.ndarray | None, name: str) -> np.ndarray:
    if not isinstance(img, np.ndarray) or img.ndim != 3 or img.shape[2] < 3:
        raise UserError(f"expected an HxWx3 image, got shape {getattr(img, 'shape', None)}", where=f"transfer {name}")
    if mask is None:
        return np.ones(img.shape[:2], dtype=bool)
    mask = np.asarray(mask)
    if mask.shape != img.shape[:2]:
        raise UserError(f"mask shape {mask.shape} does not match image shape {img.shape[:2]}",
                        where=f"transfer {name}_mask")
    return mask.astype(bool, copy=False)
