"""Every outcome of a real frame's analysis, with every class: the planner places what the
frame allows, names what it cannot (per class, with the reason) and never fails the job
(a frame without a road estimate once crashed `sample_ground` on traffic lights)."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from streets import WHITE, YELLOW, street

from blendgen import CLASSES
from blendgen.analysis import objects, stage
from blendgen.frame_analysis import BAND, ROAD, CameraEstimate, hood_mask
from blendgen.geometry import Camera
from blendgen.job.schema import GroundPlane, Inject
from blendgen.scene.ground_plane import GroundPlaneTwin
from blendgen.scene.planner import plan_sequence, unplaced_warnings
from blendgen.scene.real_scene import RealFrame, RealScene

CAM = Camera.from_hfov(640, 360, 70.0)
EST = CameraEstimate(height_m=1.5, pitch_deg=-1.0, roll_deg=0.0)
OUTCOMES = ("normal", "no_road", "no_horizon", "all_hood", "no_band", "uncertain_camera", "camera_unusable",
            "no_analysis", "road_users_everywhere")


@pytest.fixture(scope="module")
def base():
    """A two-way street with a yellow centre line, grass verges, analysed by the real stage."""
    img, _ = street(CAM, EST, road=(-3.8, 5.5), lines=[(-3.6, WHITE, None), (1.8, YELLOW, None)])
    fa, mask = stage.analyse_frame(img, "f000000", CAM, EST, objects.load_detector())
    assert mask is not None and (mask == ROAD).any()
    return fa, mask


def outcome(name: str, fa, mask) -> RealFrame | None:
    fa, mask = copy.deepcopy(fa), None if mask is None else mask.copy()
    hood = None
    if name == "no_analysis":
        return None
    if name in ("no_road", "all_hood"):
        why = ("no free ground in front of the camera (all hood, horizon or road users)" if name == "all_hood"
               else "the seed patch in front of the hood does not look like road (no connected region)")
        fa.decisions = [d for d in fa.decisions if d["what"] != "road"] + [{"what": "road", "value": None,
                                                                            "reason": why}]
        mask, fa.road_mask = None, None
        if name == "all_hood":
            fa.hood = [[0, 0], [CAM.width - 1, 0], [CAM.width - 1, CAM.height - 1], [0, CAM.height - 1]]
            hood = hood_mask(fa.hood, CAM.width, CAM.height)
    elif name == "no_horizon":
        fa.horizon = None
    elif name == "no_band":
        mask[mask == BAND] = 0
    elif name == "uncertain_camera":
        fa.placement_max_m = 15.0
        fa.decisions.append({"what": "placement_max_m", "value": 15.0, "reason": "pitch +-1.0 deg (test)"})
    elif name == "camera_unusable":
        fa.placement_max_m = 3.0
        fa.decisions.append({"what": "placement_max_m", "value": 3.0, "reason": "pitch unknown (test)"})
    elif name == "road_users_everywhere":  # parked cars across the whole view
        fa.real_objects = [objects.RealObject("car", 0.9, [float(x), 150.0, 80.0, 100.0]) for x in range(0, 640, 80)]
        objects.with_footprints(fa.real_objects, CAM, np.asarray(fa.T_world_cam), CAM.height, horizon=fa.horizon)
    return RealFrame(fa, mask, hood)


@pytest.mark.parametrize("name", OUTCOMES)
@pytest.mark.parametrize("cls", list(CLASSES))
def test_every_outcome_and_class_places_or_says_why(base, name, cls):
    fa, mask = base
    rf = outcome(name, fa, mask)
    real = RealScene([rf], CAM)
    twin = GroundPlaneTwin.from_job(GroundPlane(camera_height_m=1.5, pitch_deg=-1.0, analysis=True))
    T = np.asarray(fa.T_world_cam)
    inject = Inject(objects_per_frame=(3, 3), classes={cls: 1.0}, distance_m=(5, 35), sequences=False,
                    min_projected_px=8)
    plans = plan_sequence(twin, CAM, [("f000000", 0.0, T)], inject, seed=3, real=real)
    placed = [o for o in plans[0].objects if o.cls == cls or (o.cls == "person" and cls in ("bicycle", "motorcycle"))]
    reasons = [d["reason"] for d in plans[0].decisions if d.get("what") == "rejected" and d["cls"] == cls]
    assert placed or reasons, (name, cls, plans[0].decisions)
    assert all(r for r in reasons)
    if not placed:  # the job's warning names the class and the reason
        assert any(repr(cls) in w and any(r in w for r in reasons) for w in unplaced_warnings(plans, inject))
    if name in ("no_road", "all_hood", "camera_unusable"):
        assert not plans[0].objects
        assert any(("no road region" if name != "camera_unusable" else "is safe") in r for r in reasons)
    if name == "uncertain_camera":
        for o in plans[0].objects:
            assert math.dist(o.position[:2], T[:2, 3]) <= 15.0 + 1e-6, o
        if plans[0].objects:
            assert any(d.get("what") == "max_distance_m" for d in plans[0].decisions)
