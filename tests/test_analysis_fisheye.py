"""Frame analysis through a wide fisheye (a GoPro HERO5 Wide, 118 deg, as a dashcam): the road
mask, the road's direction and the centre line come out as through a pinhole. The horizon the
road search is cut at is a pinhole's straight line (`ground.horizon`) and the road's direction
comes from straight Hough lines of the raw image; the fisheye bends both towards the frame's
sides, but the colour model bounds the road and the lines meet near the image centre, where the
lens is nearly a pinhole. (So these numbers barely tell the lens models apart: the same frames
read through a pinhole of the same centre focal length give IoU 0.99, direction within 0.3 deg
and the centre line 1.79-1.94 m.)"""

from __future__ import annotations

import numpy as np
import pytest

from blendgen.analysis import objects, road, stage
from blendgen.analysis.ground import camera_pose
from blendgen.analysis.model import CameraEstimate
from blendgen.geometry import Camera
from blendgen.recording.importers import gopro_lens

YELLOW, WHITE = (40, 190, 220), (225, 228, 230)
LINES = [(1.75, YELLOW), (2.05, YELLOW), (-1.75, WHITE)]  # lateral offset (m, left > 0), colour BGR


def street(cam: Camera, est: CameraEstimate, yaw_deg: float, seed: int = 0):
    """Ray-cast view of a straight road from 5.5 m right to 6 m left of the camera, turned
    yaw_deg left of the camera's heading, with a double yellow centre line at +1.9 m; grass
    beside it, sky above. Returns (BGR image, true road mask)."""
    T = camera_pose(est)
    uv = np.stack(np.meshgrid(np.arange(cam.width), np.arange(cam.height)), -1).reshape(-1, 2).astype(float)
    d = np.column_stack([cam.normalized(uv), np.ones(len(uv))]) @ T[:3, :3].T
    ground = d[:, 2] < -1e-6
    s = np.where(ground, -T[2, 3] / np.where(ground, d[:, 2], -1.0), 0.0)
    x, y = T[0, 3] + s * d[:, 0], T[1, 3] + s * d[:, 1]
    a = np.radians(yaw_deg)
    lateral = -np.sin(a) * x + np.cos(a) * y
    on_road = ground & (lateral >= -5.5) & (lateral <= 6.0)
    img = np.empty((len(uv), 3), np.float32)
    img[:] = (200, 170, 150)
    img[ground] = (60, 110, 70)
    img[on_road] = (92, 95, 96)
    for off, col in LINES:
        img[ground & (np.abs(lateral - off) < 0.06)] = col
    img = img.reshape(cam.height, cam.width, 3) + np.random.default_rng(seed).normal(0, 2.5, (cam.height, cam.width, 3))
    return np.clip(img, 0, 255).astype(np.uint8), on_road.reshape(cam.height, cam.width)


@pytest.mark.parametrize("pitch, roll, yaw", [(-6.0, 0.0, 8.0), (-2.0, 3.0, 0.0), (-8.0, 2.0, -10.0)])
def test_road_through_a_wide_fisheye(pitch, roll, yaw):
    cam = gopro_lens.find_lens("HERO5 Black", "wide", False, 960, 540, 29.97).camera
    assert cam.hfov_deg > 115
    est = CameraEstimate(height_m=1.4, pitch_deg=pitch, roll_deg=roll)
    img, truth = street(cam, est, yaw)
    fa, mask = stage.analyse_frame(img, "f000000", cam, est, objects.load_detector())
    est_road = mask == road.ROAD
    iou = (est_road & truth).sum() / (est_road | truth).sum()
    assert iou > 0.97, fa.decisions
    assert fa.road_direction_deg is not None and abs(fa.road_direction_deg - yaw) < 0.6, fa.decisions
    assert fa.centre_line_m is not None and abs(fa.centre_line_m - 1.9) < 0.2, fa.decisions
