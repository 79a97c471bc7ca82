"""Real road users as obstacles: COCO detections -> footprints on the ground (bpy-free).

Each person, bicycle, car, motorcycle, bus and truck the detector finds becomes a ground
polygon: the bottom edge of its box (where it touches the road) back-projected through the
camera estimate, widened to the class's typical width and extended away from the camera by
its typical length (`dimensions.TYPICAL_DIMS`). A box cut off by the image bottom or the
hood hides its contact point, so its footprint also reaches a typical length toward the
camera. Boxes whose bottom edge lies at or above the horizon get a distance from their
height and no footprint.

The detector is YOLOX-Nano (Apache-2.0), shipped inside the package
(`detection.detector.BUNDLED_MODEL`); a job may name another YOLOX-format ONNX model.
Nothing is downloaded.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from blendgen import CLASSES
from blendgen.detection.detector import BUNDLED_MODEL, BUNDLED_SHA256, YoloxDetector
from blendgen.dimensions import TYPICAL_DIMS
from blendgen.errors import UserError
from blendgen.frame_analysis import CameraEstimate, RealObject
from blendgen.geometry import Camera
from blendgen.ground import camera_pose, horizon_v, to_ground

OBSTACLE_CLASSES = ("person", "bicycle", "car", "motorcycle", "bus", "truck")
# Low on purpose: a missed real car is an object we may place inside it; a false one
# only costs a placement.
SCORE_MIN = 0.25
_ID_TO_CLS = {CLASSES[c]: c for c in OBSTACLE_CLASSES}


def load_detector(model: Path | None = None, *, threads: int = 1) -> YoloxDetector:
    """The obstacle detector: the bundled YOLOX-Nano unless `model` names another ONNX file."""
    if model is None:
        model = BUNDLED_MODEL
        digest = hashlib.sha256(model.read_bytes()).hexdigest() if model.is_file() else None
        if digest != BUNDLED_SHA256:
            raise UserError(f"the bundled detector is missing or altered (sha256 {digest}, expected "
                            f"{BUNDLED_SHA256}); reinstall blendgen", where=str(model))
    return YoloxDetector(model, score_min=SCORE_MIN, category_ids=set(_ID_TO_CLS), threads=threads)


def detect_real_objects(image: np.ndarray, camera: Camera, cam_est: CameraEstimate, detector, *,
                        T_world_cam: np.ndarray | None = None, horizon=None,
                        hood_top_v: float | None = None) -> list[RealObject]:
    """Real road users in a BGR frame (at the camera's resolution) with their footprints.

    `T_world_cam`: the camera over the ground (default `ground.camera_pose(cam_est)`);
    `horizon`: the frame's horizon line (default: none, every box is back-projected);
    `hood_top_v`: the highest row of the hood (boxes reaching it hide their contact point)."""
    T = camera_pose(cam_est) if T_world_cam is None else T_world_cam
    return with_footprints(road_users(image, detector), camera, T, image.shape[0], horizon=horizon,
                           hood_top_v=hood_top_v)


def road_users(image: np.ndarray, detector) -> list[RealObject]:
    """The detector's road users in a BGR frame (boxes and scores, no footprint yet)."""
    out = []
    for d in detector(image):
        cls = _ID_TO_CLS.get(d["category_id"])
        if cls is not None:
            out.append(RealObject(cls=cls, score=round(float(d["score"]), 4),
                                  box=[round(float(v), 2) for v in d["bbox"]]))
    return out


def with_footprints(objs: list[RealObject], camera: Camera, T_world_cam: np.ndarray, image_h: int, *,
                    horizon=None, hood_top_v: float | None = None) -> list[RealObject]:
    """Set each object's ground footprint and distance for the camera pose `T_world_cam`."""
    T = np.asarray(T_world_cam, float)
    cam_xy = T[:2, 3]
    for obj in objs:
        x, y, w, h = obj.box
        L, W, Ht = TYPICAL_DIMS[obj.cls]
        bottom = y + h
        hz = float(horizon_v(horizon, x + w / 2)) if horizon is not None else None
        g = to_ground(camera, T, [[x, bottom], [x + w, bottom], [x + w / 2, bottom]])
        if (hz is not None and bottom <= hz + 1.0) or not np.isfinite(g).all():
            obj.footprint = None
            obj.distance_m = round(float(camera.fy * Ht / max(h, 1.0)), 2)  # from its typical height
            continue
        left, right, mid = g
        ray = mid - cam_xy
        dist = float(np.linalg.norm(ray))
        along = ray / max(dist, 1e-6)
        across = np.array([-along[1], along[0]])
        # the box's bottom corners give the lateral extent; never narrower than the class
        lat = np.sort([float((left - mid) @ across), float((right - mid) @ across), -W / 2, W / 2])
        lo, hi = lat[0], lat[-1]
        hidden = bottom >= image_h - 2 or (hood_top_v is not None and bottom >= hood_top_v - 2)
        near = -L if hidden else 0.0
        poly = [mid + lo * across + near * along, mid + hi * across + near * along,
                mid + hi * across + L * along, mid + lo * across + L * along]
        obj.footprint = [[round(float(p[0]), 3), round(float(p[1]), 3)] for p in poly]
        obj.distance_m = round(dist, 2)
    return objs
