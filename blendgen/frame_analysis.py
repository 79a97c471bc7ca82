"""What the frame analysis knows about one real background frame (bpy-free, plain data).

The analysis stage runs once per background frame, before planning, and leaves
`OUT/analysis/<frame_id>.json` (this model) plus `OUT/analysis/<frame_id>_road.png`
(uint8 mask, 255 = drivable road, same size as the frame) when a road region was
estimated. The planner, renderer, labels and report read these files; nothing else
re-derives camera, hood, road or real objects.

Conventions: pixels at the recording's resolution (u right, v down); world points in the
ground-plane twin frame of the camera pose `T_world_cam` stored here (z up, ground z = 0);
pitch > 0 tilts the optical axis up and roll > 0 turns the image clockwise as in
`geometry.R_world_cam_from_ypr`.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from blendgen import atomic

SCHEMA_VERSION = 1
ROAD, BAND = 255, 128  # the road mask's values: drivable road, the walkable band beside it


@dataclass
class CameraEstimate:
    height_m: float
    pitch_deg: float
    roll_deg: float
    fx: float | None = None                 # focal length (px) when re-estimated from vanishing points
    yaw_deg: float | None = None            # camera heading relative to the road's vanishing point (> 0: looks left of it)
    confidence: float = 0.0                 # 0..1, the weakest of the estimates that were used
    source: dict[str, str] = field(default_factory=dict)   # quantity -> "vanishing_point" | "imu" | "lane_width" | "cars" | "user" | "default" | "smoothed"
    reasons: list[str] = field(default_factory=list)        # why a quantity fell back, one sentence each
    # 1-sigma uncertainties (None: not known), from the camera mount estimate (analysis.mount)
    pitch_std_deg: float | None = None
    roll_std_deg: float | None = None
    height_std_rel: float | None = None    # of height_m (0.1: +-10 %)


@dataclass
class RealObject:
    cls: str                                 # one of blendgen.CLASSES
    score: float
    box: list[float]                         # [x, y, w, h] px
    footprint: list[list[float]] | None = None   # ground polygon (world x, y), None above the horizon
    distance_m: float | None = None


@dataclass
class FrameAnalysis:
    frame_id: str
    width: int
    height: int
    camera: CameraEstimate
    T_world_cam: list[list[float]] | None = None     # pose over the ground plane (ego motion for video)
    horizon: list[list[float]] | None = None         # [[u0, v0], [u1, v1]] at u0 = 0 and u1 = width - 1
    hood: list[list[float]] | None = None            # polygon (u, v) of the ego hood/dashboard; None: none seen
    road_mask: str | None = None                     # file name of the road mask beside this JSON
    road_direction_deg: float | None = None          # road yaw relative to the camera's heading (0 = straight ahead)
    centre_line_m: float | None = None               # lateral offset (left > 0) of the line beyond which traffic comes towards the camera
    edge_line_m: float | None = None                 # lateral offset (< 0) of the solid right edge line: no traffic beyond it
    lane_lines: list[list[float]] = field(default_factory=list)  # painted lines [y10, slope, cover] (analysis.lanes)
    real_objects: list[RealObject] = field(default_factory=list)
    placement_max_m: float | None = None             # objects farther than this would float or sink (camera uncertainty); None: no limit
    decisions: list[dict[str, Any]] = field(default_factory=list)  # {"what", "value", "reason"}: what the manifest records
    version: int = SCHEMA_VERSION

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "FrameAnalysis":
        d = dict(d)
        d["camera"] = CameraEstimate(**d["camera"])
        d["real_objects"] = [RealObject(**o) for o in d.get("real_objects", [])]
        return cls(**d)


def write_analysis(folder: Path, fa: FrameAnalysis, mask: np.ndarray | None) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    if mask is not None:
        atomic.write_image(folder / f"{fa.frame_id}_road.png", mask)
    atomic.write_json(folder / f"{fa.frame_id}.json", fa.to_dict())  # last: marks the frame done


def read_analysis(folder: Path, frame_id: str) -> FrameAnalysis | None:
    p = Path(folder) / f"{frame_id}.json"
    return FrameAnalysis.from_dict(json.loads(p.read_text())) if p.is_file() else None


def read_road_mask(folder: Path, fa: FrameAnalysis) -> np.ndarray | None:
    if not fa.road_mask:
        return None
    return cv2.imread(str(Path(folder) / fa.road_mask), cv2.IMREAD_GRAYSCALE)


def hood_mask(hood, width: int, height: int) -> np.ndarray | None:
    if hood is None or len(hood) == 0:
        return None
    m = np.zeros((height, width), np.uint8)
    cv2.fillPoly(m, [np.round(np.asarray(hood)).astype(np.int32)], 1)
    return m > 0
