"""Walkable bands beside the estimated road: pavements yes; grass, gravel and a highway's
asphalt shoulder no (issue 12: pedestrians stood on highway shoulders)."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from blendgen.analysis import objects, road, stage
from blendgen.frame_analysis import BAND, ROAD, CameraEstimate, hood_mask
from blendgen.geometry import Camera
from blendgen.job.schema import GroundPlane, Inject
from blendgen.scene.ground_plane import GroundPlaneTwin
from blendgen.scene.planner import plan_sequence, unplaced_warnings
from blendgen.scene.real_scene import RealFrame, RealScene

REAL = Path(os.environ.get("BLENDGEN_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")) / "real"


def drawn(side_bgr, seed=0):
    """640x360: asphalt road in the middle third (with grain), `side_bgr` beside it."""
    rng = np.random.default_rng(seed)
    img = np.empty((360, 640, 3), np.float32)
    img[:] = side_bgr
    img[:, 213:427] = (92, 95, 96)
    img += rng.normal(0, 3, img.shape)
    road_px = np.zeros((360, 640), bool)
    road_px[150:, 213:427] = True
    band = np.zeros((360, 640), bool)
    band[150:, 100:213] = band[150:, 427:540] = True
    return np.clip(img, 0, 255).astype(np.uint8), band, road_px


@pytest.mark.parametrize("side,expect", [
    ((175, 178, 180), True),    # light concrete pavement
    ((240, 242, 243), True),    # snow-covered verge
    ((40, 120, 60), False),     # grass
    ((98, 100, 101), False),    # asphalt shoulder: the road's own surface
], ids=["concrete", "snow", "grass", "asphalt shoulder"])
def test_walkable_is_a_pavement_not_grass_or_shoulder(side, expect):
    img, band, road_px = drawn(side)
    walk, how = road.walkable(img, band, road_px)
    assert (walk[band].mean() > 0.8) if expect else not walk.any(), how
    assert not (walk & ~band).any()


def test_textured_verge_is_not_walkable():
    img, band, road_px = drawn((150, 152, 154))
    # gravel: stones of about 8 px at this distance
    stones = np.random.default_rng(1).normal(0, 40, (45, 80))
    noise = cv2.resize(stones, (640, 360), interpolation=cv2.INTER_NEAREST)
    img[band] = np.clip(img[band] + noise[band][:, None], 0, 255).astype(np.uint8)
    walk, how = road.walkable(img, band, road_px)
    assert walk.mean() < 0.01, how


def highway_photo():
    """The Udacity highway photo with white lines only, analysed: (camera, analysis, mask)."""
    path = REAL / "udacity_highway_images" / "solidWhiteRight.jpg"
    if not path.is_file():
        pytest.skip(f"needs {path}")
    img = cv2.imread(str(path))
    cam = Camera.from_hfov(img.shape[1], img.shape[0], 60.0)
    est = CameraEstimate(height_m=1.4, pitch_deg=-1.0, roll_deg=0.0)
    return (cam, *stage.analyse_frame(img, "f000000", cam, est, objects.load_detector()))


def placed_over_seeds(cam, fa, real, ground_plane, cls, distance_m, seeds=12, sequences=False):
    """The objects of `cls` the planner places in this one analysed frame over `seeds` seeds
    (`sequences`: as the first frame of a video, where the camera's speed, 0, is known)."""
    twin = GroundPlaneTwin.from_job(ground_plane)
    inject = Inject(objects_per_frame=(2, 2), classes={cls: 1}, distance_m=distance_m, sequences=sequences)
    out = []
    for seed in range(seeds):
        plan = plan_sequence(twin, cam, [(fa.frame_id, 0.0, np.asarray(fa.T_world_cam))], inject, seed, real=real)[0]
        out += [o for o in plan.objects if o.cls == cls]
    return out


def test_highway_photo_gets_no_pedestrian():
    """A real highway: the band beside the road is dry grass and an asphalt shoulder."""
    cam, fa, mask = highway_photo()
    assert mask is not None and (mask == ROAD).mean() > 0.1
    assert not (mask == BAND).any(), [d for d in fa.decisions if d["what"] == "walkable"]
    real = RealScene([RealFrame(fa, mask, None)], cam)
    twin = GroundPlaneTwin.from_job(GroundPlane(camera_height_m=1.4, pitch_deg=-1.0, analysis=True))
    inject = Inject(objects_per_frame=(2, 2), classes={"person": 1}, distance_m=(8, 35), sequences=False)
    plans = plan_sequence(twin, cam, [("f000000", 0.0, np.asarray(fa.T_world_cam))], inject, 0, real=real)
    assert not plans[0].objects
    assert unplaced_warnings(plans, inject)


def test_highway_photo_gets_no_cyclist_and_slow_video_one_only_at_its_kerb():
    """The same highway (one-way, white lines only). As a photo (no speed) it is a divided
    highway: no centre line, nothing to walk on, so no cyclist at all (they rode its shoulder
    on the Udacity photos). As a slow video frame a bicycle is ridden along the right edge,
    never along the median's (the left edge with all traffic running the ego's way), and none
    is parked: nobody walks there (the real video had a cyclist at the median's edge and a
    parked bicycle on the shoulder)."""
    cam, fa, mask = highway_photo()
    assert fa.centre_line_m is None, fa.decisions
    real = RealScene([RealFrame(fa, mask, None)], cam)
    gp = GroundPlane(camera_height_m=1.4, pitch_deg=-1.0, analysis=True)
    assert not placed_over_seeds(cam, fa, real, gp, "bicycle", (8, 35))
    placed = placed_over_seeds(cam, fa, real, gp, "bicycle", (8, 35), sequences=True)
    T = np.asarray(fa.T_world_cam)
    assert len(placed) >= 6
    for o in placed:
        assert "rider" in o.variant, o.variant
        assert o.position[1] - T[1, 3] < 0, o.position


def test_night_street_pedestrians_stay_out_of_the_oncoming_lane():
    """The BDD night street: its dark far lane, beside the lit road, passed as pavement and a
    pedestrian stood in it, 1.5 m beyond the double yellow line. Pedestrians (not crossing)
    now stand at least a lane's width beyond the centre line."""
    path = REAL / "bdd_street_photos" / "9aa94005-ff1d4c9a.jpg"
    if not path.is_file():
        pytest.skip(f"needs {path}")
    img = cv2.imread(str(path))
    cam = Camera.from_hfov(img.shape[1], img.shape[0], 60.0)
    est = CameraEstimate(height_m=1.08, pitch_deg=-1.4, roll_deg=-0.4)  # the dashcam job's estimate
    fa, mask = stage.analyse_frame(img, "f000002", cam, est, objects.load_detector())
    assert fa.centre_line_m is not None and 0.8 < fa.centre_line_m < 2.0, fa.decisions
    real = RealScene([RealFrame(fa, mask, hood_mask(fa.hood, img.shape[1], img.shape[0]))], cam)
    placed = placed_over_seeds(cam, fa, real, GroundPlane(camera_height_m=1.08, pitch_deg=-1.4, analysis=True),
                               "person", (6, 35))
    lats = [o.position[1] - fa.T_world_cam[1][3] for o in placed]
    assert len(lats) >= 6
    assert not [y for y in lats if fa.centre_line_m < y < fa.centre_line_m + 2.7], (fa.centre_line_m, lats)
