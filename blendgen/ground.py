"""Pixels <-> the flat ground under a dashcam (bpy-free).

The ground-plane world frame (as `scene.ground_plane`): the road runs along +x, ground at
z = 0, the camera at (0, 0, height) with the estimated pitch and roll, yawed by minus the
road direction, so that the twin's straight lanes follow the road seen in the frame.
"""

from __future__ import annotations

import math

import numpy as np

from blendgen.frame_analysis import CameraEstimate
from blendgen.geometry import Camera, R_world_cam_from_ypr, make_pose


def camera_pose(est: CameraEstimate, road_direction_deg: float | None = None) -> np.ndarray:
    """T_world_cam of the dashcam over the road for a camera estimate."""
    yaw = -math.radians(road_direction_deg or 0.0)
    R = R_world_cam_from_ypr(yaw, math.radians(est.pitch_deg), math.radians(est.roll_deg))
    return make_pose(R, [0.0, 0.0, est.height_m])


def rays_world(camera: Camera, T_world_cam: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """World-frame directions (N, 3) of the pixels `uv` (N, 2), lens distortion removed."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    xy = camera.normalized(uv)
    rays = np.column_stack([xy, np.ones(len(xy))])
    return rays @ np.asarray(T_world_cam)[:3, :3].T


def to_ground(camera: Camera, T_world_cam: np.ndarray, uv: np.ndarray, min_down: float = 1e-3) -> np.ndarray:
    """Ground points (N, 2) world x, y hit by the pixels `uv`; NaN for pixels at or above the
    horizon (their ray never reaches the ground in front of the camera)."""
    T = np.asarray(T_world_cam)
    d = rays_world(camera, T, uv)
    down = -d[:, 2]
    ok = down > min_down
    s = np.where(ok, T[2, 3] / np.where(ok, down, 1.0), np.nan)
    return T[:2, 3][None] + s[:, None] * d[:, :2]


def horizon(camera: Camera, T_world_cam: np.ndarray) -> list[list[float]] | None:
    """The horizon line [[0, v0], [W-1, v1]]: image of the points at infinity on the ground."""
    R = np.asarray(T_world_cam)[:3, :3]
    up_cam = R.T @ np.array([0.0, 0.0, 1.0])   # the ground's normal in camera coordinates
    # the horizon is the line l with l . (u, v, 1) = 0, l = K^-T n (pinhole)
    n = np.linalg.inv(camera.K).T @ up_cam
    if abs(n[1]) < 1e-9:
        return None
    u0, u1 = 0.0, camera.width - 1.0
    return [[u0, float(-(n[0] * u0 + n[2]) / n[1])], [u1, float(-(n[0] * u1 + n[2]) / n[1])]]


def horizon_v(hz: list[list[float]] | None, u: np.ndarray | float) -> np.ndarray:
    """Row of the horizon at column(s) u (-inf without a horizon)."""
    if hz is None:
        return np.full(np.shape(u), -np.inf)
    (u0, v0), (u1, v1) = hz
    return v0 + (np.asarray(u, float) - u0) * (v1 - v0) / (u1 - u0)
