"""Amodal masks by rasterising object meshes in NumPy (bpy-free, no Blender render).

An object's amodal pixel count (its silhouette with nothing in front) is what the
occlusion label compares the visible mask against. Rasterising the mesh triangles costs
milliseconds; a second Blender render would cost a scene sync and a render call.
"""

from __future__ import annotations

import numpy as np

from blendgen.geometry import Camera, invert_pose

NEAR_M = 0.05


def _clip_near(tri: np.ndarray) -> list[np.ndarray]:
    """Clip one triangle (3x3, camera frame) against z >= NEAR_M (Sutherland-Hodgman)."""
    out = []
    for i in range(3):
        a, b = tri[i], tri[(i + 1) % 3]
        ina, inb = a[2] >= NEAR_M, b[2] >= NEAR_M
        if ina:
            out.append(a)
        if ina != inb:
            s = (a[2] - NEAR_M) / (a[2] - b[2])
            out.append(a + s * (b - a))
    return [np.array(out)] if len(out) >= 3 else []


def rasterize_mask(cam: Camera, T_world_cam, verts_world: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Binary mask (H, W uint8) of a triangle mesh seen by the pinhole `cam`.

    Pixel centres inside the projected triangles are set: what an index pass marks.
    """
    H, W = cam.height, cam.width
    mask = np.zeros((H, W), np.uint8)
    if len(tris) == 0:
        return mask
    T = invert_pose(np.asarray(T_world_cam, dtype=float))
    Xc = np.asarray(verts_world, dtype=float) @ T[:3, :3].T + T[:3, 3]
    tri = Xc[np.asarray(tris)]                       # (N, 3, 3)
    front = tri[..., 2] >= NEAR_M
    full = np.all(front, axis=1)
    some = np.any(front, axis=1) & ~full
    clipped = [p for t in tri[some] for p in _clip_near(t)]

    def to_px(P: np.ndarray) -> np.ndarray:
        u = cam.fx * P[..., 0] / P[..., 2] + cam.cx
        v = cam.fy * P[..., 1] / P[..., 2] + cam.cy
        return np.stack([u, v], axis=-1)

    parts = [to_px(tri[full])] if np.any(full) else []
    for poly in clipped:  # fan-triangulate the clipped (convex) polygons
        q = to_px(poly)
        parts.append(np.stack([np.repeat(q[:1], len(q) - 2, 0), q[1:-1], q[2:]], axis=1))
    if parts:
        fill_triangles(mask, np.concatenate(parts))
    return mask


def fill_triangles(mask: np.ndarray, P: np.ndarray, small: int = 8) -> None:
    """Set the pixels whose centres lie inside any triangle of P (N, 3, 2), in place.

    This is the rule a one-sample-per-pixel renderer follows (the object index pass);
    OpenCV's polygon fill also marks pixels an edge merely touches, which overcounts
    by about half a pixel along every silhouette. Small triangles are tested in one
    vectorised batch on a fixed grid, large ones one by one over their bounding box.
    """
    H, W = mask.shape
    P = P[np.all(np.isfinite(P), axis=(1, 2))]
    if len(P) == 0:
        return
    lo, hi = P.min(axis=1), P.max(axis=1)
    x0 = np.clip(np.ceil(lo[:, 0]), 0, W - 1).astype(np.int64)
    x1 = np.clip(np.floor(hi[:, 0]), 0, W - 1).astype(np.int64)
    y0 = np.clip(np.ceil(lo[:, 1]), 0, H - 1).astype(np.int64)
    y1 = np.clip(np.floor(hi[:, 1]), 0, H - 1).astype(np.int64)
    ok = (x1 >= x0) & (y1 >= y0) & (hi[:, 0] >= 0) & (hi[:, 1] >= 0) & (lo[:, 0] <= W - 1) & (lo[:, 1] <= H - 1)
    a, b, c = P[:, 0], P[:, 1], P[:, 2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    ok &= np.abs(area) > 1e-12
    sw, sh = x1 - x0 + 1, y1 - y0 + 1
    is_small = ok & (sw <= small) & (sh <= small)

    def inside(px, py, a, b, c, sgn):
        e0 = (b[..., 0] - a[..., 0]) * (py - a[..., 1]) - (b[..., 1] - a[..., 1]) * (px - a[..., 0])
        e1 = (c[..., 0] - b[..., 0]) * (py - b[..., 1]) - (c[..., 1] - b[..., 1]) * (px - b[..., 0])
        e2 = (a[..., 0] - c[..., 0]) * (py - c[..., 1]) - (a[..., 1] - c[..., 1]) * (px - c[..., 0])
        return (sgn * e0 >= 0) & (sgn * e1 >= 0) & (sgn * e2 >= 0)

    oy, ox = np.divmod(np.arange(small * small), small)
    small_idx = np.nonzero(is_small)[0]
    for k in range(0, len(small_idx), 16384):  # bounded memory for dense meshes
        idx = small_idx[k:k + 16384]
        px = x0[idx, None] + ox[None, :]
        py = y0[idx, None] + oy[None, :]
        sel = (px <= x1[idx, None]) & (py <= y1[idx, None])
        sgn = np.sign(area[idx])[:, None]
        sel &= inside(px.astype(float), py.astype(float), a[idx, None], b[idx, None], c[idx, None], sgn)
        mask[py[sel], px[sel]] = 1
    for i in np.nonzero(ok & ~is_small)[0]:
        ys, xs = np.mgrid[y0[i]:y1[i] + 1, x0[i]:x1[i] + 1]
        sel = inside(xs.astype(float), ys.astype(float), a[i], b[i], c[i], np.sign(area[i]))
        mask[ys[sel], xs[sel]] = 1
