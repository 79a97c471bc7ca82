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

def _reinhard(s: np.ndarray, s_fit: np.ndarray, r: np.ndarray) -> np.ndarray:
    mu_s, sd_s = s_fit.mean(0, dtype=np.float64), s_fit.std(0, dtype=np.float64)
    mu_r, sd_r = r.mean(0, dtype=np.float64), r.std(0, dtype=np.float64)
    # A flat source has nothing to scale (x - mu = 0), so the ratio only matters when sd_s > 0.
    ratio = np.where(sd_s > EPS, sd_r / np.maximum(sd_s, EPS), 1.0)
    ratio = np.clip(ratio, 1.0 / MAX_STD_RATIO, MAX_STD_RATIO)
    if np.allclose(mu_s, mu_r, rtol=0, atol=1e-9) and np.allclose(sd_s, sd_r, rtol=0, atol=1e-9):
        return s.copy()  # same statistics: exactly the identity (no Lab round-trip error)
    return ((s - mu_s) * ratio + mu_r).astype(np.float32)


def _mkl(s: np.ndarray, s_fit: np.ndarray, r: np.ndarray) -> np.ndarray:
    mu_s, mu_r = s_fit.mean(0, dtype=np.float64), r.mean(0, dtype=np.float64)
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
    out = np.empty_like(s)
    for c in range(s.shape[1]):
        sv, sc = np.unique(s_fit[:, c], return_counts=True)
        rv, rc = np.unique(r[:, c], return_counts=True)
        # Mid-point ECDF so identical distributions map each value onto itself exactly.
        s_cdf = (np.cumsum(sc) - 0.5 * sc) / sc.sum()
        r_cdf = (np.cumsum(rc) - 0.5 * rc) / rc.sum()
        s_to_q = np.interp(s[:, c], sv, s_cdf)
        out[:, c] = np.interp(s_to_q, r_cdf, rv)
    return out


# ---- helpers

def _cov(x: np.ndarray, mu: np.ndarray) -> np.ndarray:
    d = x.astype(np.float64) - mu
    return d.T @ d / max(len(x), 1)


def _lab(bgr_pix: np.ndarray) -> np.ndarray:
    """Nx3 float BGR ([0, 1], HDR allowed) -> Nx3 Lab (float32, OpenCV's ranges)."""
    img = np.ascontiguousarray(np.maximum(bgr_pix, 0.0), dtype=np.float32).reshape(-1, 1, 3)
    return cv2.cvtColor(img, cv2.COLOR_BGR2Lab).reshape(-1, 3)


def _from_lab(lab_pix: np.ndarray) -> np.ndarray:
    lab = np.ascontiguousarray(lab_pix, dtype=np.float32).copy()
    lab[:, 0] = np.maximum(lab[:, 0], 0.0)
    out = cv2.cvtColor(lab.reshape(-1, 1, 3), cv2.COLOR_Lab2BGR).reshape(-1, 3)
    return np.maximum(np.nan_to_num(out, nan=0.0, posinf=1.0, neginf=0.0), 0.0)


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
