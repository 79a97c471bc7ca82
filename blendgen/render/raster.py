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


# Pixel tests per vectorised batch (bounds the temporaries to a few tens of MB).
BATCH_PX = 1 << 19


def _pow2_at_least(n: np.ndarray) -> np.ndarray:
    """Smallest power of two >= n (n >= 1), elementwise."""
    p = np.left_shift(1, np.ceil(np.log2(np.maximum(n, 1))).astype(np.int64))
    return np.where(p < n, 2 * p, p)  # guard against log2 rounding down


def fill_triangles(mask: np.ndarray, P: np.ndarray) -> None:
    """Set the pixels whose centres lie inside any triangle of P (N, 3, 2), in place.

    This is the rule a one-sample-per-pixel renderer follows (the object index pass);
    OpenCV's polygon fill also marks pixels an edge merely touches, which overcounts
    by about half a pixel along every silhouette. Triangles are grouped by their
    bounding box rounded up to powers of two per side and each group is tested in
    vectorised batches on that fixed grid (a Python loop over the ~2300 triangles
    larger than 8 px of five cars at 1280x720 cost ~0.15 CPU s per frame, now ~0.04).
    Every pixel gets the same floating-point edge values as a per-pixel evaluation, so
    the mask does not depend on the grouping (tests/test_raster_exact.py).
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
    idx_ok = np.nonzero(ok)[0]
    if len(idx_ok) == 0:
        return
    # Power-of-two sides, capped at the frame (huge triangles: one frame-sized grid).
    gw = np.minimum(_pow2_at_least(x1[idx_ok] - x0[idx_ok] + 1), W)
    gh = np.minimum(_pow2_at_least(y1[idx_ok] - y0[idx_ok] + 1), H)
    group = gw * (2 * max(W, H) + 2) + gh  # unique per (gw, gh) pair
    order = np.argsort(group, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(group[order]) != 0])
    ends = np.r_[starts[1:], len(order)]
    # Each edge function d_x * (py - a_y) - d_y * (px - a_x) is a row term minus a column
    # term: both are computed once per row / column and the pixel test is one subtraction,
    # with the very same floating-point operations as evaluating it per pixel. The sign of
    # the area (orientation) is folded into the terms; negation is exact.
    sgn = np.sign(area)
    for s, e in zip(starts, ends):
        w, h = int(gw[order[s]]), int(gh[order[s]])
        rows, cols = np.arange(h), np.arange(w)
        step = max(1, BATCH_PX // (w * h))
        for k in range(s, e, step):
            idx = idx_ok[order[k:min(e, k + step)]]
            py = y0[idx, None] + rows  # (n, h)
            px = x0[idx, None] + cols  # (n, w)
            fy, fx = py.astype(float), px.astype(float)
            sg = sgn[idx, None]
            sel = None
            for p, q in ((a[idx], b[idx]), (b[idx], c[idx]), (c[idx], a[idx])):
                ty = sg * ((q[:, 0] - p[:, 0])[:, None] * (fy - p[:, 1, None]))
                tx = sg * ((q[:, 1] - p[:, 1])[:, None] * (fx - p[:, 0, None]))
                if sel is None:  # rows / columns past the bounding box: never inside
                    ty[py > y1[idx, None]] = -np.inf
                    tx[px > x1[idx, None]] = np.inf
                    sel = ty[:, :, None] - tx[:, None, :] >= 0
                else:
                    sel &= ty[:, :, None] - tx[:, None, :] >= 0
            t, r, q = np.nonzero(sel)
            mask[py[t, r], px[t, q]] = 1
