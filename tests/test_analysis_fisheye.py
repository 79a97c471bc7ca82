"""Frame analysis through a wide fisheye (a GoPro HERO5 Wide, 118 deg, as a dashcam): the road
mask, the road's direction and the centre line come out as through a pinhole. The horizon the
road search is cut at is a pinhole's straight line (`ground.horizon`) and the road's direction
comes from straight Hough lines of the raw image; the fisheye bends both towards the frame's
sides, but the colour model bounds the road and the lines meet near the image centre, where the
lens is nearly a pinhole. (So these numbers barely tell the lens models apart: the same frames
read through a pinhole of the same centre focal length give IoU 0.99, direction within 0.3 deg
and the centre line 1.79-1.94 m.)"""

from __future__ import annotations

import pytest
from streets import WHITE, YELLOW, street

from blendgen.analysis import objects, stage
from blendgen.frame_analysis import ROAD, CameraEstimate
from blendgen.recording.importers import gopro_lens

LINES = [(1.75, YELLOW, None), (2.05, YELLOW, None), (-1.75, WHITE, None)]  # a double yellow centre line at +1.9 m


@pytest.mark.parametrize("pitch, roll, yaw", [(-6.0, 0.0, 8.0), (-2.0, 3.0, 0.0), (-8.0, 2.0, -10.0)])
def test_road_through_a_wide_fisheye(pitch, roll, yaw):
    cam = gopro_lens.find_lens("HERO5 Black", "wide", False, 960, 540, 29.97).camera
    assert cam.hfov_deg > 115
    est = CameraEstimate(height_m=1.4, pitch_deg=pitch, roll_deg=roll)
    img, truth = street(cam, est, yaw_deg=yaw, lines=LINES)
    fa, mask = stage.analyse_frame(img, "f000000", cam, est, objects.load_detector())
    est_road = mask == ROAD
    iou = (est_road & truth).sum() / (est_road | truth).sum()
    assert iou > 0.97, fa.decisions
    assert fa.road_direction_deg is not None and abs(fa.road_direction_deg - yaw) < 0.6, fa.decisions
    assert fa.centre_line_m is not None and abs(fa.centre_line_m - 1.9) < 0.2, fa.decisions
