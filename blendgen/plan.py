"""The per-frame scene plan: plain data the render driver realises and labels trust.

Object local frame: x forward, y left, z up, origin at the centre of the bottom face.
`yaw` turns local x toward world +y; on a sloped road (maps with elevation and
superelevation) `pitch` (> 0 nose up) and `roll` (> 0 left side up) tilt the object onto
the road: R_world_obj = Rz(yaw) Ry(-pitch) Rx(roll), Blender's XYZ Euler (roll, -pitch, yaw). `id` is the track id: it is the object's identity
across frames, its Blender `pass_index` and its value in the instance-id image (0 is
background), so it must be 1..SCENERY_ID-1. Scenery an object brings with it (the pole of a
traffic light in a ground-plane scene) is rendered with id SCENERY_ID + id: composited like
the object, never labelled (labels list plan objects only).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from blendgen import CLASSES

SCENERY_ID = 16384  # Blender's pass_index stops at 32767: objects 1..16383, their scenery 16384 + id


@dataclass
class PlacedObject:
    id: int
    cls: str
    position: tuple[float, float, float]
    yaw: float
    dims: tuple[float, float, float]  # length (x), width (y), height (z) in metres
    variant: dict[str, Any] = field(default_factory=dict)  # builder parameters (shape, colours, seed)
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)  # world m/s, for motion-blur decisions
    state: str | None = None  # e.g. traffic light "red" | "amber" | "green"
    scenario: str | None = None
    pitch: float = 0.0
    roll: float = 0.0

    def __post_init__(self):
        if self.cls not in CLASSES:
            raise ValueError(f"unknown class {self.cls!r}; expected one of {sorted(CLASSES)}")
        if not 1 <= int(self.id) < SCENERY_ID:
            raise ValueError(f"object id {self.id} outside 1..{SCENERY_ID - 1}")

    def R_world_obj(self) -> np.ndarray:
        """Rotation of the object frame in the world: Rz(yaw) Ry(-pitch) Rx(roll)."""
        return R_from_ypr(self.yaw, self.pitch, self.roll)

    @property
    def euler_xyz(self) -> tuple[float, float, float]:
        """Blender's rotation_euler (mode XYZ) for R_world_obj."""
        return (float(self.roll), -float(self.pitch), float(self.yaw))

    def box_corners_world(self) -> np.ndarray:
        """The 8 corners of the object's 3D box in world coordinates (8x3)."""
        L, W, H = self.dims
        xs, ys, zs = np.meshgrid([-L / 2, L / 2], [-W / 2, W / 2], [0.0, H], indexing="ij")
        local = np.stack([xs.ravel(), ys.ravel(), zs.ravel()], axis=1)
        return local @ self.R_world_obj().T + np.asarray(self.position, dtype=float)


def R_from_ypr(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """Rz(yaw) Ry(-pitch) Rx(roll): x forward, y left, z up; pitch > 0 nose up, roll > 0 left up."""
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(-pitch), np.sin(-pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return Rz @ Ry @ Rx


@dataclass
class FramePlan:
    frame_id: str
    t: float
    T_world_cam: list[list[float]]
    objects: list[PlacedObject] = field(default_factory=list)
    lighting: dict[str, Any] | None = None  # sun/sky settings from the post stage's estimate
    decisions: list[dict[str, Any]] = field(default_factory=list)  # planner: rejected placements and why, covered real objects
    camera_velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)  # world m/s: motion blur is relative to the camera

    def to_dict(self) -> dict:
        d = asdict(self)
        d["T_world_cam"] = np.asarray(self.T_world_cam, dtype=float).tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "FramePlan":
        objs = [PlacedObject(**{**o, "position": tuple(o["position"]), "dims": tuple(o["dims"]),
                                "velocity": tuple(o.get("velocity", (0, 0, 0)))})
                for o in d.get("objects", [])]
        return cls(d["frame_id"], float(d["t"]), d["T_world_cam"], objs, d.get("lighting"), d.get("decisions", []),
                   tuple(d.get("camera_velocity", (0.0, 0.0, 0.0))))
