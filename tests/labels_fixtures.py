"""Synthetic frames for the label tests: index images rasterised from planned 3D boxes."""

from __future__ import annotations

import cv2
import numpy as np

from blendgen.geometry import Camera, R_world_cam_from_ypr, invert_pose, make_pose
from blendgen.labels.instances import encode_mask
from blendgen.plan import FramePlan, PlacedObject

W, H = 160, 90
CAMERA = Camera.from_hfov(W, H, 90.0)
T_WORLD_CAM = make_pose(R_world_cam_from_ypr(0.0), [0.0, 0.0, 1.5])  # looks along world +x


def hull_mask(obj: PlacedObject, pad: int = 0) -> np.ndarray:
    """Filled projected box of `obj` on a canvas padded by `pad` pixels on every side."""
    corners = obj.box_corners_world()
    T = invert_pose(T_WORLD_CAM)
    Xc = corners @ T[:3, :3].T + T[:3, 3]
    assert (Xc[:, 2] > 0.1).all(), "fixture objects must lie in front of the camera"
    uv, _ = CAMERA.project(Xc)
    hull = cv2.convexHull((uv + pad).astype(np.float32))
    canvas = np.zeros((H + 2 * pad, W + 2 * pad), np.uint8)
    # Fixed-point fill (4 fractional bits) so the raster follows the float polygon closely.
    cv2.fillConvexPoly(canvas, np.round(hull * 16).astype(np.int32), 1, shift=4)
    return canvas.astype(bool)


def make_frame():
    """A car in front, a person partly behind it, a truck cut by the left border,
    a one-pixel object and an object that is planned but not visible."""
    objs = [
        PlacedObject(1, "car", (12.0, 0.5, 0.0), 0.3, (4.5, 1.8, 1.5), scenario="cut_in"),
        PlacedObject(2, "person", (20.0, 1.0, 0.0), 0.0, (0.5, 0.6, 1.8), scenario="jaywalker"),
        PlacedObject(3, "truck", (9.0, 8.5, 0.0), 1.2, (8.0, 2.5, 3.5)),
        PlacedObject(4, "traffic light", (60.0, -5.0, 4.0), 0.0, (0.3, 0.3, 0.9)),
        PlacedObject(5, "bus", (30.0, -40.0, 0.0), 0.0, (12.0, 2.5, 3.2)),  # outside the view
    ]
    # Index: paint far to near so nearer objects occlude.
    index = np.zeros((H, W), np.int32)
    amodal = {}
    for o in sorted(objs[:3], key=lambda o: -np.linalg.norm(o.position)):
        m = hull_mask(o)
        amodal[o.id] = int(m.sum())
        index[m] = o.id
    index[5, 150] = 4  # a one-pixel object
    amodal[4] = 1
    plan = FramePlan("f000001", 0.0, T_WORLD_CAM.tolist(), objs)
    return index, plan, amodal


def synthetic_instances(rng: np.random.Generator, n: int) -> list[dict]:
    """Random rectangles as instances (for export tests that need many frames fast)."""
    from blendgen import CLASSES

    out = []
    names = list(CLASSES)
    for k in range(n):
        x, y = int(rng.integers(0, W - 20)), int(rng.integers(0, H - 20))
        w, h = int(rng.integers(1, 20)), int(rng.integers(1, 20))
        mask = np.zeros((H, W), bool)
        mask[y:y + h, x:x + w] = True
        cls = names[int(rng.integers(len(names)))]
        out.append({"id": k + 1, "track_id": k + 1, "cls": cls, "category_id": CLASSES[cls],
                    "bbox": [x, y, w, h], "area": w * h, "visible_px": w * h, "amodal_px": None,
                    "segmentation": encode_mask(mask), "occlusion": None, "truncation": 0.0,
                    "distance_m": 10.0, "box3d_cam": {"location": [0, 1.5, 10], "dimensions_hwl": [1, 1, 1],
                                                      "rotation_y": 0.0, "alpha": 0.0},
                    "scenario": None, "state": None, "ignore": bool(w * h < 4)})
    return out
