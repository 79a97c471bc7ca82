"""The lane markings' vanishing point (blendgen.analysis.lane_direction): a projected road with
known camera yaw and pitch, frames without markings, and the real comma2k19 preview frame."""

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from blendgen.analysis.lane_direction import lane_direction
from blendgen.geometry import Camera, R_world_cam_from_ypr

CAM = Camera(960, 540, 800.0, 800.0, 479.5, 269.5)
PREVIEW = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real" / \
    "comma2k19_example1_segment40" / "preview.png"


def road_frame(yaw_deg: float, pitch_deg: float, *, lines=(-5.25, -1.75, 1.75, 5.25), dashed=(-1.75, 1.75),
               seed: int = 0, ss: int = 4) -> np.ndarray:
    """Grey asphalt with 0.15 m white markings along world x, seen from 1.4 m; the camera
    turned `yaw_deg` left of the road and pitched `pitch_deg` down. Drawn at `ss` x the size
    and averaged down (the pixels integrate the paint's edges)."""
    R_wc = R_world_cam_from_ypr(math.radians(yaw_deg), math.radians(-pitch_deg), 0.0)
    c = np.array([0.0, 0.0, 1.4])
    K = CAM.K.copy()
    K[:2] *= ss
    K[:2, 2] += (ss - 1) / 2.0  # pixel centres of the big image
    img = np.full((CAM.height * ss, CAM.width * ss), 90, np.uint8)
    for y in lines:
        pieces = [(x, x + 3.0) for x in np.arange(4.0, 120.0, 12.0)] if y in dashed else [(4.0, 120.0)]
        for x0, x1 in pieces:
            quad = np.array([[x0, y - 0.075, 0], [x1, y - 0.075, 0], [x1, y + 0.075, 0], [x0, y + 0.075, 0]])
            X = (quad - c) @ R_wc  # world -> camera
            uv = (X @ K.T)[:, :2] / X[:, 2:]
            cv2.fillConvexPoly(img, np.round(uv * 16).astype(np.int32), 200, cv2.LINE_AA, shift=4)
    img = cv2.resize(img, (CAM.width, CAM.height), interpolation=cv2.INTER_AREA).astype(float)
    img += np.random.default_rng(seed).normal(0, 3, img.shape)
    return cv2.cvtColor(np.clip(img, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)


@pytest.mark.parametrize("yaw,pitch", [(0.0, 2.0), (1.5, 4.0), (-3.0, -1.0)])
def test_yaw_and_pitch_of_a_projected_road(yaw, pitch):
    r = lane_direction(road_frame(yaw, pitch), CAM)
    assert r.yaw_deg is not None, r.reason
    assert abs(r.yaw_deg - yaw) < 0.05 and abs(r.pitch_deg - pitch) < 0.05, r.summary()
    assert r.lines >= 3 and 0 < r.yaw_std_deg < 0.2 and 0 < r.pitch_std_deg < 0.2


def test_no_markings_no_answer():
    """Blank, black and saturated frames, one marking, and a wrong size: a reason, no angles."""
    grey = np.full((CAM.height, CAM.width, 3), 90, np.uint8)
    cases = {"blank": grey, "black": np.zeros_like(grey), "white": np.full_like(grey, 255),
             "one line": road_frame(1.0, 2.0, lines=(-1.75,), dashed=())}
    for name, img in cases.items():
        r = lane_direction(img, CAM)
        assert r.yaw_deg is None and r.reason, name
        assert "reason" in r.summary()
    r = lane_direction(grey[:100], CAM)
    assert r.yaw_deg is None and "960x540" in r.reason
    # two lines always meet: without a third there is nothing to check them with
    r = lane_direction(road_frame(1.0, 2.0, lines=(-1.75, 1.75), dashed=()), CAM)
    assert r.yaw_deg is None and "need 3" in r.reason


def test_comma2k19_preview_gives_the_ground_truths_camera_yaw():
    """The real comma2k19 frame: the ground truth's device points 0.72-1.16 deg left of the
    direction of travel over the segment (median 0.89; evaluation only)."""
    if not PREVIEW.exists():
        pytest.skip("needs ../shared/data/real/comma2k19_example1_segment40/preview.png")
    from blendgen.analysis.hood import hood_in_still
    from blendgen.recording.importers.comma2k19 import EON_CAMERA

    img = cv2.imread(str(PREVIEW))
    r = lane_direction(img, EON_CAMERA, hood=hood_in_still(img)[0])
    assert r.yaw_deg is not None, r.reason
    assert 0.6 < r.yaw_deg < 1.2 and r.yaw_std_deg < 0.3 and r.lines >= 3
    assert 2.5 < r.pitch_deg < 4.5  # 3.0 (first 2 s) to 3.8 deg (median) below the travel
