"""Per-object labels from the instance-id pass (`instances.png` / EXR `index`).

Everything the renderer knows exactly is taken from the plan (class, 3D box, scenario);
everything that depends on visibility is measured on the id image (mask, tight box, area).

Conventions (DESIGN.md): boxes are COCO `[x, y, w, h]` where pixel (u, v) covers
[u, u+1) x [v, v+1) -- the same convention as `pycocotools.mask.toBbox`, so boxes are
tight to the RLE masks by construction. 3D boxes are in OpenCV camera coordinates.
"""

from __future__ import annotations

import math

import numpy as np
from pycocotools import mask as mask_utils

from blendgen import CLASSES
from blendgen.errors import UserError
from blendgen.geometry import Camera, invert_pose
from blendgen.plan import FramePlan, PlacedObject

# Points nearer than this (metres, camera z) are clipped before projection: the part of a
# box behind the camera has no image, and projecting it would flip through infinity.
NEAR_PLANE_M = 0.05

# The 12 edges of PlacedObject.box_corners_world (corner index = ix*4 + iy*2 + iz).
_BOX_EDGES = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]


def encode_mask(mask: np.ndarray) -> dict:
    """Binary HxW mask -> COCO compressed RLE with `counts` as str (JSON-able)."""
    m = mask.view(np.uint8) if mask.dtype == bool else mask.astype(np.uint8)
    rle = mask_utils.encode(np.asfortranarray(m))
    return {"size": [int(rle["size"][0]), int(rle["size"][1])], "counts": rle["counts"].decode("ascii")}


def decode_mask(rle: dict) -> np.ndarray:
    """COCO RLE (counts str or bytes) -> HxW uint8 mask."""
    counts = rle["counts"]
    if isinstance(counts, str):
        counts = counts.encode("ascii")
    return mask_utils.decode({"size": list(rle["size"]), "counts": counts})


def tight_box(mask: np.ndarray) -> list[int]:
    """COCO [x, y, w, h] of the pixels set in `mask` (must be non-empty)."""
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    return [int(cols[0]), int(rows[0]), int(cols[-1] - cols[0] + 1), int(rows[-1] - rows[0] + 1)]


def box3d_cam(obj: PlacedObject, T_world_cam) -> dict:
    """The object's 3D box in camera coordinates, plus KITTI's parametrisation.

    `location` is the bottom-face centre (KITTI's convention), `rotation_y` the yaw about the
    camera's y axis of the object's forward (local x) direction. `rotation_y` is exact only
    for a camera without pitch/roll relative to the object; `R_cam_obj` is always exact.
    """
    T_cam_world = invert_pose(np.asarray(T_world_cam, dtype=float))
    R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
    R_cam_obj = R @ obj.R_world_obj()  # yaw and the road's pitch/roll
    loc = R @ np.asarray(obj.position, dtype=float) + t
    corners = obj.box_corners_world() @ R.T + t
    fwd = R_cam_obj[:, 0]
    ry = math.atan2(-fwd[2], fwd[0])
    alpha = _wrap(ry - math.atan2(loc[0], loc[2]))
    L, W, H = (float(v) for v in obj.dims)
    return {
        "location": loc.tolist(),              # bottom-face centre, camera frame (m)
        "dimensions_hwl": [H, W, L],           # KITTI order
        "rotation_y": ry,
        "alpha": alpha,
        "R_cam_obj": R_cam_obj.tolist(),
        "corners": corners.tolist(),           # 8x3, camera frame
    }


def truncation(corners_cam: np.ndarray, camera: Camera) -> float:
    """Fraction of the projected 3D box (its 2D convex hull) that lies outside the image.

    The box is first clipped against the near plane so that an object reaching behind the
    camera projects to a large but finite polygon. Image edges are at -0.5 and W-0.5
    (pixel centres at integers). Returns 1.0 when nothing of the box is in front of the camera.
    """
    import cv2

    pts = [p for p in corners_cam if p[2] >= NEAR_PLANE_M]
    for a, b in _BOX_EDGES:
        za, zb = corners_cam[a][2], corners_cam[b][2]
        if (za - NEAR_PLANE_M) * (zb - NEAR_PLANE_M) < 0:
            f = (NEAR_PLANE_M - za) / (zb - za)
            pts.append(corners_cam[a] + f * (corners_cam[b] - corners_cam[a]))
    if len(pts) < 3:
        return 1.0
    # Pinhole projection: the radtan polynomial diverges far outside the image, and the
    # renderer draws an undistorted pinhole image anyway.
    pinhole = Camera(camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy)
    uv, _ = pinhole.project(np.asarray(pts))
    hull = cv2.convexHull(uv.astype(np.float32))
    total = float(cv2.contourArea(hull))
    if not np.isfinite(total) or total <= 1e-9:
        # Degenerate (edge-on) projection: fall back to the fraction of points outside.
        inside = _inside(uv, camera)
        return float(1.0 - inside.mean())
    w, h = camera.width - 0.5, camera.height - 0.5
    rect = np.array([[-0.5, -0.5], [w, -0.5], [w, h], [-0.5, h]], dtype=np.float32)
    inter, _ = cv2.intersectConvexConvex(hull, rect)
    return float(np.clip(1.0 - max(inter, 0.0) / total, 0.0, 1.0))


def extract_instances(index: np.ndarray, plan: FramePlan, camera: Camera, *,
                      amodal_px: dict[int, int] | None = None, min_visible_px: int = 64,
                      small_objects: str = "drop", real_boxes: list[dict] | None = None) -> list[dict]:
    """Labels for every planned object that has at least one visible pixel in `index`.

    index: HxW integer object ids (0 = background), the renderer's instance pass.
    amodal_px: per object id, the pixels the object covers with nothing in front of it
        (inside the image); gives occlusion = 1 - visible/amodal. None -> occlusion None.
    Objects with fewer than `min_visible_px` visible pixels are dropped
    (`small_objects="drop"`) or kept with `ignore=True` (`"ignore"`).
    real_boxes: the real road users of the background frame ({"cls", "box" [x,y,w,h]} at
        this resolution); each instance then lists in `covers_real` the real boxes its
        visible pixels cover, with the covered fraction of the box, so that labels of the
        real objects can be updated.
    """
    index = np.asarray(index)
    where = f"frame {plan.frame_id}"
    if index.ndim != 2 or not np.issubdtype(index.dtype, np.integer):
        raise UserError(f"instance index must be an HxW integer array, got {index.dtype} {index.shape}",
                        where=where)
    if small_objects not in ("drop", "ignore"):
        raise UserError(f"small_objects must be 'drop' or 'ignore', got {small_objects!r}", where=where)
    H, W = index.shape
    if (camera.width, camera.height) != (W, H):
        if abs(camera.width / camera.height - W / H) > 0.01:
            raise UserError(f"instance image is {W}x{H} but the camera is {camera.width}x{camera.height} "
                            "(different aspect ratio)", where=where)
        camera = camera.scaled(W, H)  # rendered at another resolution than the recording
    amodal_px = {int(k): int(v) for k, v in (amodal_px or {}).items()}

    # Pixel counts per id in one pass (ids are 0..65535; negative values are not objects).
    visible = np.bincount(np.clip(index, 0, None).ravel())
    index_f = np.asfortranarray(index)  # masks come out Fortran-ordered, as pycocotools wants
    out = []
    for obj in plan.objects:
        n = int(visible[obj.id]) if obj.id < len(visible) else 0
        if n == 0:
            continue  # not visible at all: no mask, no box
        ignore = n < min_visible_px
        if ignore and small_objects == "drop":
            continue
        mask = index_f == obj.id
        b3 = box3d_cam(obj, plan.T_world_cam)
        corners = np.asarray(b3["corners"])
        if not np.isfinite(corners).all():
            raise UserError(f"object {obj.id} ({obj.cls}) has a non-finite pose or size "
                            f"(position {obj.position}, dims {obj.dims}, yaw {obj.yaw})", where=where)
        centre = corners.mean(axis=0)
        amodal = amodal_px.get(int(obj.id))
        occlusion = None
        if amodal is not None and amodal > 0:
            occlusion = float(np.clip(1.0 - n / amodal, 0.0, 1.0))
        out.append({
            "id": int(obj.id),
            "track_id": int(obj.id),
            "cls": obj.cls,
            "category_id": CLASSES[obj.cls],
            "bbox": tight_box(mask),
            "area": n,
            "visible_px": n,
            "amodal_px": amodal,
            "segmentation": encode_mask(mask),
            "occlusion": occlusion,
            "truncation": truncation(corners, camera),
            "distance_m": float(np.linalg.norm(centre)),
            "box3d_cam": b3,
            "scenario": obj.scenario,
            "state": obj.state,
            "rides": ({"id": int(obj.variant["rides"]), "cls": obj.variant["mount"]["cls"]}
                      if obj.variant.get("rides") else None),  # a rider: the two-wheeler it rides
            "ignore": bool(ignore),
            "source": "injected",
        })
        if real_boxes is not None:
            out[-1]["covers_real"] = covered_real(mask, real_boxes)
    return out


def covered_real(mask: np.ndarray, real_boxes: list[dict], min_fraction: float = 0.01) -> list[dict]:
    """The real boxes whose area the object's visible `mask` covers by >= min_fraction."""
    H, W = mask.shape
    out = []
    for r in real_boxes:
        x, y, w, h = r["box"]
        x0, y0, x1, y1 = max(0, int(x)), max(0, int(y)), min(W, int(np.ceil(x + w))), min(H, int(np.ceil(y + h)))
        if x1 <= x0 or y1 <= y0:
            continue
        frac = float(mask[y0:y1, x0:x1].sum()) / max(w * h, 1.0)
        if frac >= min_fraction:
            out.append({"cls": r["cls"], "bbox": [round(float(v), 1) for v in (x, y, w, h)],
                        "covered_fraction": round(frac, 3)})
    return out


def _inside(uv: np.ndarray, camera: Camera) -> np.ndarray:
    return ((uv[:, 0] >= -0.5) & (uv[:, 0] <= camera.width - 0.5)
            & (uv[:, 1] >= -0.5) & (uv[:, 1] <= camera.height - 0.5))


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi
