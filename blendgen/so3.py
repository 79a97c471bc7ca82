"""Small SO(3) helpers (rotation vectors, hat map) used by the filter and VO."""

from __future__ import annotations

import numpy as np


def hat(w) -> np.ndarray:
    x, y, z = w
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def exp(w) -> np.ndarray:
    """Rodrigues: rotation vector -> matrix (exact for small angles too)."""
    w = np.asarray(w, dtype=float)
    th = float(np.sqrt(w @ w))
    K = hat(w)
    if th < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + (np.sin(th) / th) * K + ((1 - np.cos(th)) / th**2) * K @ K


def log(R) -> np.ndarray:
    """Matrix -> rotation vector, stable near 0 and near pi."""
    R = np.asarray(R, dtype=float)
    c = np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)
    th = float(np.arccos(c))
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-6:
        return 0.5 * v
    if np.pi - th < 1e-4:
        # near pi the antisymmetric part vanishes: take the axis from the symmetric part
        B = (R + np.eye(3)) / 2
        k = int(np.argmax(np.diag(B)))
        axis = B[:, k] / np.sqrt(max(B[k, k], 1e-12))
        axis /= np.linalg.norm(axis)
        if axis @ v < 0:
            axis = -axis
        return th * axis
    return th / (2 * np.sin(th)) * v


def orthonormalize(R) -> np.ndarray:
    U, _, Vt = np.linalg.svd(R)
    Rn = U @ Vt
    if np.linalg.det(Rn) < 0:
        U[:, -1] *= -1
        Rn = U @ Vt
    return Rn


def yaw_rotation(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def wrap_angle(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi
