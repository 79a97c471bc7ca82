"""sRGB <-> linear Rec.709 conversions and luminance, shared by the post modules.

Real frames are 8-bit sRGB-encoded BGR (OpenCV order); renders are linear RGB(A).
"""

from __future__ import annotations

import cv2
import numpy as np

# Rec.709 luminance weights in BGR order (OpenCV images are BGR).
LUMA_BGR = np.array([0.0722, 0.7152, 0.2126], dtype=np.float32)

# 8-bit sRGB -> linear lookup table: a table is ~10x faster than the pow per pixel.
_U8 = np.arange(256, dtype=np.float64) / 255.0
SRGB_U8_TO_LINEAR = np.where(_U8 <= 0.04045, _U8 / 12.92, ((_U8 + 0.055) / 1.055) ** 2.4).astype(np.float32)


# linear [0, 1] -> 8-bit sRGB lookup on a 2^16 grid: error < 0.1 level, ~10x faster than pow.
_LIN = np.arange(65536, dtype=np.float64) / 65535.0
LINEAR_TO_SRGB_U8 = np.clip(np.rint(255.0 * np.where(_LIN <= 0.0031308, _LIN * 12.92,
                                                     1.055 * _LIN ** (1 / 2.4) - 0.055)), 0, 255).astype(np.uint8)


def _lut_index(x: np.ndarray) -> np.ndarray:
    """[0, 1] (clipped) -> 16-bit table index, rounded; in place on one temporary."""
    q = np.clip(np.asarray(x, dtype=np.float32), 0.0, 1.0)
    q *= np.float32(65535.0)
    q += np.float32(0.5)
    return q.astype(np.uint16)


def linear_to_srgb_u8(x: np.ndarray) -> np.ndarray:
    """Linear (finite; clipped to [0, 1]) -> 8-bit sRGB through the lookup table."""
    return LINEAR_TO_SRGB_U8.take(_lut_index(x))


def srgb_u8_to_linear(img_u8: np.ndarray) -> np.ndarray:
    return SRGB_U8_TO_LINEAR.take(img_u8)


# sRGB [0, 1] <-> linear [0, 1] on a 2^16 grid (float tables): the error is below 1e-4 of
# full scale (< 0.03 of an 8-bit level at the steepest part of either curve), ~10x faster
# than the pow per pixel.
_SRGB_TO_LINEAR = np.where(_LIN <= 0.04045, _LIN / 12.92, ((_LIN + 0.055) / 1.055) ** 2.4).astype(np.float32)
_LINEAR_TO_SRGB = np.where(_LIN <= 0.0031308, _LIN * 12.92, 1.055 * _LIN ** (1 / 2.4) - 0.055).astype(np.float32)


def _lut16(x: np.ndarray, table: np.ndarray) -> np.ndarray:
    return table.take(_lut_index(x))


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """sRGB-encoded [0, 1] (clipped; NaN -> 0) -> linear, through a 2^16 lookup table."""
    return _lut16(finite(np.asarray(x, dtype=np.float32), 0.0, 1.0), _SRGB_TO_LINEAR)


def srgb_to_linear_exact(x: np.ndarray) -> np.ndarray:
    x = np.clip(np.asarray(x, dtype=np.float32), 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def finite(a: np.ndarray, fill: float = 0.0, big: float | None = None) -> np.ndarray:
    """``a`` with NaN -> fill and +-inf -> big / fill; a cheap check first, since render passes
    are almost always finite and np.nan_to_num costs several full passes over the data."""
    a = np.asarray(a)
    if a.dtype.kind != "f":
        return a
    if a.dtype in (np.float32, np.float64) and a.flags.c_contiguous and a.size:
        # OpenCV's sum (double accumulator: no overflow) is ~3x faster than numpy's on (n, 3) rows
        total = cv2.sumElems(a.reshape(-1, 1))[0]
    elif a.dtype in (np.float32, np.float64) and a.ndim == 3 and a.shape[2] <= 4 and a.size \
            and a.strides[2] == a.itemsize and a.strides[1] == a.itemsize * a.shape[2]:
        total = sum(cv2.sumElems(a)[:a.shape[2]])  # an image window (strided rows): no copy
    else:
        total = a.sum()  # (an overflow to inf only costs the slow path)
    if np.isfinite(total):
        return a
    return np.nan_to_num(a, nan=fill, posinf=fill if big is None else big, neginf=fill)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Linear -> sRGB in [0, 1] through a 2^16 lookup table; values above 1 (HDR) clip, NaN
    becomes 0, +inf 1."""
    return _lut16(finite(np.asarray(x, dtype=np.float32), 0.0, 1.0), _LINEAR_TO_SRGB)


def linear_to_srgb_exact(x: np.ndarray) -> np.ndarray:
    x = np.clip(finite(np.asarray(x, dtype=np.float32), 0.0, 1.0), 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(np.float32)


def to_u8(x_01: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(np.asarray(x_01, dtype=np.float32) * 255.0), 0, 255).astype(np.uint8)


def luminance_bgr(img: np.ndarray) -> np.ndarray:
    return img[..., :3].astype(np.float32, copy=False) @ LUMA_BGR
