"""Small 2D geometry for placement: polylines with arc length, oriented boxes, convex overlap.

Everything the planner checks (lanes, sidewalks, collisions) reduces to these few
vectorised NumPy primitives, so the twin needs no GIS library.
"""

from __future__ import annotations

import numpy as np


def rect(center, length: float, width: float, yaw: float) -> np.ndarray:
    """Corners (4x2, counter-clockwise) of an oriented rectangle."""
    c, s = np.cos(yaw), np.sin(yaw)
    hl, hw = length / 2.0, width / 2.0
    local = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
    return local @ np.array([[c, s], [-s, c]]) + np.asarray(center, dtype=float)[:2]


def convex_overlap(a: np.ndarray, b: np.ndarray, margin: float = 0.0) -> bool:
    """Separating-axis test for two convex polygons (Nx2). `margin` > 0 demands that much
    clearance (the polygons count as overlapping when closer than `margin`)."""
    for poly in (a, b):
        edges = np.concatenate([poly[1:], poly[:1]]) - poly
        normals = np.stack([-edges[:, 1], edges[:, 0]], axis=1)
        norms = np.linalg.norm(normals, axis=1)
        keep = norms > 1e-12
        normals = normals[keep] / norms[keep, None]
        pa, pb = a @ normals.T, b @ normals.T
        sep = np.maximum(pb.min(0) - pa.max(0), pa.min(0) - pb.max(0))
        if np.any(sep >= margin):
            return False
    return True


def point_in_convex(pts: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Which of the points (Mx2) lie inside the convex polygon (either winding)."""
    pts = np.atleast_2d(pts)
    e = np.roll(poly, -1, axis=0) - poly
    rel = pts[:, None, :] - poly[None, :, :]
    cross = e[None, :, 0] * rel[..., 1] - e[None, :, 1] * rel[..., 0]
    return np.all(cross >= -1e-9, axis=1) | np.all(cross <= 1e-9, axis=1)


class Polyline:
    """A densified 2D centre-line with arc length; projects points to (s, d), d > 0 left."""

    def __init__(self, pts):
        pts = np.asarray(pts, dtype=float)
        seg = np.diff(pts, axis=0)
        seglen = np.linalg.norm(seg, axis=1)
        keep = np.concatenate([[True], seglen > 1e-9])
        self.pts = pts[keep]
        self.seg = np.diff(self.pts, axis=0)
        self.seglen = np.linalg.norm(self.seg, axis=1)
        self.s = np.concatenate([[0.0], np.cumsum(self.seglen)])
        self.tan = self.seg / self.seglen[:, None]
        self.length = float(self.s[-1])
        from scipy.spatial import cKDTree

        self._tree = cKDTree(self.pts)

    def project(self, xy) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s, d, segment index) of the nearest point on the line for each query point.
        Beyond the ends s runs outside [0, length] along the end tangents."""
        q = np.atleast_2d(np.asarray(xy, dtype=float))
        # candidate segments: the two beside the nearest vertex (KD-tree), plus both ends
        nseg = len(self.seglen)
        _, v = self._tree.query(q)
        cand = np.stack([v - 2, v - 1, v, v + 1, np.zeros_like(v), np.full_like(v, nseg - 1)], axis=1)
        cand = np.clip(cand, 0, nseg - 1)
        rel = q[:, None, :] - self.pts[cand]
        tan = self.tan[cand]
        u = np.einsum("mkj,mkj->mk", rel, tan)
        lo = np.where(cand == 0, -np.inf, 0.0)  # open ends: the end segments extend outward
        hi = np.where(cand == nseg - 1, np.inf, self.seglen[cand])
        uc = np.clip(u, lo, hi)
        foot = self.pts[cand] + uc[..., None] * tan
        dist = np.linalg.norm(q[:, None, :] - foot, axis=2)
        j = np.argmin(dist, axis=1)
        idx = np.arange(len(q))
        k = cand[idx, j]
        s = self.s[k] + uc[idx, j]
        t = self.tan[k]
        r = q - self.pts[k]
        d = t[:, 0] * r[:, 1] - t[:, 1] * r[:, 0]
        return s, d, k

    def at(self, s) -> tuple[np.ndarray, np.ndarray]:
        """Point (Mx2) and unit tangent (Mx2) at arc length(s), extrapolating past the ends."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        k = np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.seglen) - 1)
        p = self.pts[k] + (s - self.s[k])[:, None] * self.tan[k]
        return p, self.tan[k]

    def offset_point(self, s, d) -> np.ndarray:
        p, t = self.at(s)
        n = np.stack([-t[:, 1], t[:, 0]], axis=1)
        return p + np.atleast_1d(np.asarray(d, dtype=float))[:, None] * n


def wrap_angle(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi
