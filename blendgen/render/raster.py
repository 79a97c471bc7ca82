"""Amodal masks by rasterising object meshes with OpenCV (bpy-free, no Blender render).

An object's amodal pixel count (its silhouette with nothing in front) is what the
occlusion label compares the visible mask against. Rasterising the mesh triangles costs
milliseconds; a second Blender render would cost a scene sync and a render call.
"""

from __future__ import annotations

import numpy as np

from blendgen.geometry import Camera, invert_pose

NEAR_M = 0.05
SUBPIX_BITS = 4  # cv2.fillPoly fixed-point precision: 1/16 px


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

    Pixel centres inside the projected triangles are set (OpenCV's fill rule), which is
    what a one-sample-per-pixel index pass would mark.
    """
    H, W = cam.height, cam.width
    mask = np.zeros((H, W), np.uint8)
    if len(tris) == 0:
        return mask
    T = invert_pose(np.asarray(T_world_cam, dtype=float))
    Xc = np.asarray(verts_world, dtype=float) @ T[:3, :3].T + T[:3, 3]
    tri = Xc[np.asarray(tris)]                       # (N, 3, 3)
    front = tri[..., 2] >= NEAR_M
    polys = []
    full = np.all(front, axis=1)
    some = np.any(front, axis=1) & ~full
    clipped = [p for t in tri[some] for p in _clip_near(t)]
    scale = float(1 << SUBPIX_BITS)

    def to_px(P: np.ndarray) -> np.ndarray:
        u = cam.fx * P[..., 0] / P[..., 2] + cam.cx
        v = cam.fy * P[..., 1] / P[..., 2] + cam.cy
        uv = np.stack([u, v], axis=-1)
        # Keep coordinates inside int32 fixed-point range; far-off vertices are clamped.
        lim = 4 * max(W, H)
        return np.rint(np.clip(uv, -lim, lim) * scale).astype(np.int32)

    if np.any(full):
        pts = to_px(tri[full])
        polys.extend(list(pts))
    polys.extend(to_px(p) for p in clipped)
    if polys:
        import cv2

        # One call per triangle: fillPoly on many polygons uses an even-odd rule, which
        # would punch holes where a mesh's front and back faces overlap.
        for p in polys:
            cv2.fillConvexPoly(mask, p, 1, lineType=cv2.LINE_8, shift=SUBPIX_BITS)
    return mask
