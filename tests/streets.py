"""Ray-cast dashcam views of a straight road for the frame-analysis tests: every pixel's ray
(through any lens model, `Camera.normalized`) meets the ground z = 0 or the sky."""

from __future__ import annotations

import numpy as np

from blendgen.frame_analysis import CameraEstimate
from blendgen.geometry import Camera
from blendgen.ground import camera_pose

ASPHALT, GRASS, SKY = (92, 95, 96), (60, 110, 70), (200, 170, 150)
YELLOW, WHITE = (40, 190, 220), (225, 228, 230)


def street(cam: Camera, est: CameraEstimate, *, yaw_deg: float = 0.0, road=(-5.5, 6.0), lines=(),
           shoulder: tuple[float, float] | None = None, seed: int = 0):
    """A straight road from road[0] to road[1] metres lateral (left > 0) of the camera, turned
    yaw_deg left of its heading; `lines`: (lateral offset, BGR, dash) with dash None for a solid
    stripe or (paint m, period m); `shoulder`: an asphalt band (lateral from, to) that is not the
    road's (it is painted, not in the true road mask). Grass beside, sky above.
    Returns (BGR image, true road mask)."""
    T = camera_pose(est)
    uv = np.stack(np.meshgrid(np.arange(cam.width), np.arange(cam.height)), -1).reshape(-1, 2).astype(float)
    d = np.column_stack([cam.normalized(uv), np.ones(len(uv))]) @ T[:3, :3].T
    ground = d[:, 2] < -1e-6
    s = np.where(ground, -T[2, 3] / np.where(ground, d[:, 2], -1.0), 0.0)
    x, y = T[0, 3] + s * d[:, 0], T[1, 3] + s * d[:, 1]
    a = np.radians(yaw_deg)
    along, lateral = np.cos(a) * x + np.sin(a) * y, -np.sin(a) * x + np.cos(a) * y
    on_road = ground & (lateral >= road[0]) & (lateral <= road[1])
    img = np.empty((len(uv), 3), np.float32)
    img[:] = SKY
    img[ground] = GRASS
    if shoulder is not None:
        img[ground & (lateral >= shoulder[0]) & (lateral <= shoulder[1])] = ASPHALT
    img[on_road] = ASPHALT
    for off, col, dash in lines:
        paint = ground & (np.abs(lateral - off) < 0.06)
        if dash is not None:
            paint &= np.mod(along, dash[1]) < dash[0]
        img[paint] = col
    img = img.reshape(cam.height, cam.width, 3) + np.random.default_rng(seed).normal(0, 2.5, (cam.height, cam.width, 3))
    return np.clip(img, 0, 255).astype(np.uint8), on_road.reshape(cam.height, cam.width)
