"""A twin for footage without a map: a flat, straight road under the camera.

The world frame puts the camera at (0, 0, camera_height) looking along +x (yaw 0) with
the given pitch (> 0 tilts up) and roll (> 0 clockwise, as `geometry.R_world_cam_from_ypr`);
the ego lane is centred on y = 0 and the road runs along +x. It is a `Twin`, so the planner and the
render driver use the same query interface (lane_at, on_sidewalk, is_free, ...).
"""

from __future__ import annotations

import math

import numpy as np

from blendgen.errors import UserError
from blendgen.geometry import R_world_cam_from_ypr, make_pose
from blendgen.twin.model import Twin
from blendgen.twin.schema import TwinSpec


class GroundPlaneTwin(Twin):
    def __init__(self, camera_height_m: float = 1.5, pitch_deg: float = 0.0, lane_width_m: float = 3.5,
                 *, roll_deg: float = 0.0, lanes_left: int = 1, lanes_right: int = 1, oncoming_left: bool = False,
                 sidewalk_m: float = 3.0, x_range: tuple[float, float] = (-100.0, 1000.0),
                 georef: tuple[float, float, float] = (0.0, 0.0, 0.0)):
        if not 0.2 < camera_height_m <= 5:
            raise UserError(f"ground_plane.camera_height_m: expected 0.2 < h <= 5 m, got {camera_height_m}")
        if not 1 < lane_width_m <= 6:
            raise UserError(f"ground_plane.lane_width_m: expected 1 < w <= 6 m, got {lane_width_m}")
        if not -45 <= pitch_deg <= 45:
            raise UserError(f"ground_plane.pitch_deg: expected -45..45, got {pitch_deg}")
        if not -30 <= roll_deg <= 30:
            raise UserError(f"ground_plane.roll_deg: expected -30..30, got {roll_deg}")
        self.roll_deg = float(roll_deg)
        self.camera_height_m = float(camera_height_m)
        self.pitch_deg = float(pitch_deg)
        self.lane_width_m = float(lane_width_m)
        w = lane_width_m
        if oncoming_left:
            fwd, bwd, yc = 1 + lanes_right, lanes_left, 0.5 * w
        else:
            fwd, bwd, yc = lanes_left + 1 + lanes_right, 0, (lanes_left + 0.5) * w
        road = {"id": "ground", "points": [[x_range[0], yc], [x_range[1], yc]],
                "lanes_forward": fwd, "lanes_backward": bwd, "lane_width_m": w, "shoulder_m": 0.3,
                "sidewalk_m": sidewalk_m, "curb_height_m": 0.0,
                "center_line": "solid" if oncoming_left else "none"}
        spec = TwinSpec.model_validate({
            "name": "ground_plane", "georef": dict(zip(("lat0", "lon0", "alt0"), georef)),
            "roads": [road], "ground_m": float(x_range[1] - x_range[0])})
        super().__init__(spec, None)

    @classmethod
    def from_job(cls, gp) -> "GroundPlaneTwin":
        """From a `blendgen.job.schema.GroundPlane` section; a field set to "auto" takes the
        default here (the frame analysis estimates it per frame: blendgen.analysis.camera).
        With the frame analysis on, the real road mask bounds where vehicles go, so the twin
        offers lanes across any street width (six lanes, the twin's most) and the mask keeps
        the real ones."""
        def num(v, default):
            return default if v == "auto" else v
        left, right = (2, 3) if getattr(gp, "analysis", False) else (1, 1)
        return cls(num(gp.camera_height_m, 1.5), num(gp.pitch_deg, 0.0), gp.lane_width_m,
                   roll_deg=num(gp.roll_deg, 0.0), lanes_left=left, lanes_right=right)

    def camera_pose(self, x: float = 0.0) -> np.ndarray:
        """T_world_cam of the dashcam at distance x along the road."""
        return make_pose(R_world_cam_from_ypr(0.0, math.radians(self.pitch_deg), math.radians(self.roll_deg)),
                         [x, 0.0, self.camera_height_m])
