"""Vehicles in the real lanes: the frame's painted lines are found and the ground-plane twin's
vehicles drive between them, not at the twin's lane centres (on the Udacity highway photos a
car ahead stood on the dashed line: the camera sat 0.4 m off its lane's centre and the lane
measured 2.7 m in the frame's metric for the job's 3.7 m)."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from streets import WHITE, YELLOW, street

from blendgen.analysis import objects, stage
from blendgen.analysis.lanes import lane_lines
from blendgen.frame_analysis import CameraEstimate
from blendgen.geometry import Camera
from blendgen.job.schema import GroundPlane, Inject
from blendgen.lane_geometry import lane_centres
from blendgen.scene.ground_plane import GroundPlaneTwin
from blendgen.scene.planner import plan_sequence
from blendgen.scene.real_scene import RealFrame, RealScene

REAL = Path(os.environ.get("BLENDGEN_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")) / "real"
CAM = Camera.from_hfov(960, 540, 70.0)
EST = CameraEstimate(height_m=1.4, pitch_deg=-2.0, roll_deg=0.0)
DASHED = (3.0, 12.0)
# a three-lane carriageway, 3.5 m lanes, the camera 0.6 m right of its lane's centre
LINES = [(-2.35, WHITE, None), (1.15, WHITE, DASHED), (4.65, WHITE, DASHED), (8.15, YELLOW, None)]


def _off_centre():
    img, _ = street(CAM, EST, road=(-2.5, 8.3), lines=LINES)
    return stage.analyse_frame(img, "f000000", CAM, EST, objects.load_detector())


def test_painted_lines_are_found_where_they_are():
    fa, _ = _off_centre()
    found = sorted(l[0] for l in fa.lane_lines)
    assert len(found) == 3, fa.decisions  # the yellow one at 8 m is beyond the search's 8 m
    for y, (want, _, _) in zip(found, LINES):
        assert abs(y - want) < 0.12, (found, fa.decisions)
    assert all(abs(l[1]) < 0.01 for l in fa.lane_lines)  # parallel to the road
    c = lane_centres(fa.lane_lines, 12.0, 3.5)
    assert abs(c[0] - (-0.6)) < 0.12 and abs(c[1] - 2.9) < 0.12 and abs(c[-1] - (-4.1)) < 0.15, c


def test_vehicles_drive_in_the_real_lanes_not_the_twins():
    fa, mask = _off_centre()
    T = np.asarray(fa.T_world_cam)
    twin = GroundPlaneTwin.from_job(GroundPlane(camera_height_m=1.4, pitch_deg=-2.0, lane_width_m=3.5, analysis=True))
    inject = Inject(objects_per_frame=(3, 3), classes={"car": 1}, distance_m=(8, 30), sequences=False)

    def offsets(lines):
        fa.lane_lines = lines
        real = RealScene([RealFrame(fa, mask, None)], CAM)
        return [o.position[1] - T[1, 3] for seed in range(8)
                for o in plan_sequence(twin, CAM, [("f000000", 0.0, T)], inject, seed, real=real)[0].objects]

    lines = list(fa.lane_lines)
    ys = offsets(lines)
    assert len(ys) >= 12
    centres = np.array([-0.6, 2.9, 6.4])
    assert max(np.min(np.abs(y - centres)) for y in ys) < 0.15, ys
    # without the lines the cars keep the twin's lanes, centred on the camera: 0.6 m off
    assert min(np.min(np.abs(y - centres)) for y in offsets([])) > 0.4


def test_lane_centres_from_one_line_weak_tracks_and_implausible_pairs():
    w = 3.5
    c = lane_centres([[1.9, 0.0, 0.8]], 10.0, w)  # a centre line only: the ego lane right of it
    assert abs(c[0] - 0.15) < 1e-9 and abs(c[-1] - (0.15 - w)) < 1e-9
    # a faint stripe inside the lane (a tyre track, a crack) gives way to the lines either side
    c = lane_centres([[1.8, 0.0, 0.6], [-0.2, 0.0, 0.22], [-1.9, 0.0, 0.9]], 10.0, w)
    assert abs(c[0] - (-0.05)) < 1e-9
    # two strong lines 1.5 m apart bound no lane; a line 0.2 m beside the camera alone neither
    assert lane_centres([[0.8, 0.0, 0.6], [-0.7, 0.0, 0.6]], 10.0, w) is None
    assert lane_centres([[0.2, 0.0, 0.6]], 10.0, w) is None
    assert lane_centres([], 10.0, w) is None
    # fanned lines (a pitch that is off) are evaluated where the vehicle is, within their range
    fan = [[1.8, 0.03, 0.6], [-1.8, -0.03, 0.6]]
    c = lane_centres(fan, 20.0, w)  # lines at +-2.1 m there: a 4.2 m lane, its neighbours as wide
    assert abs(c[0]) < 1e-9 and abs(c[1] - 4.2) < 1e-9 and abs(c[-2] + 8.4) < 1e-9
    assert lane_centres(fan, 100.0, w) == lane_centres(fan, 30.0, w)


def test_no_lines_on_plain_asphalt_black_and_tiny_frames():
    img, _ = street(CAM, EST, road=(-5.0, 5.0))
    fa, _ = stage.analyse_frame(img, "f000000", CAM, EST, objects.load_detector())
    assert fa.lane_lines == [] and any(d["what"] == "lane_lines" and d["value"] == 0 for d in fa.decisions)
    assert lane_lines(np.zeros((540, 960, 3), np.uint8), np.ones((540, 960), bool), CAM,
                      np.asarray(fa.T_world_cam))[0] == []
    assert lane_lines(img, None, CAM, np.asarray(fa.T_world_cam)) == ([], "no road region")


def test_real_freeway_frame_lanes():
    p = REAL / "udacity_solidWhiteRight.mp4"
    if not p.is_file():
        pytest.skip(f"needs {p}")
    cap = cv2.VideoCapture(str(p))
    ok, img = cap.read()
    assert ok
    cam = Camera.from_hfov(960, 540, 55.0)
    est = CameraEstimate(height_m=1.2, pitch_deg=2.1, roll_deg=0.0)
    fa, _ = stage.analyse_frame(img, "f000000", cam, est, objects.load_detector())
    ys = sorted(l[0] for l in fa.lane_lines)
    # the solid right edge line and the dashed line on the left, ~3.6 m apart at this height
    right = [y for y in ys if y < 0]
    left = [y for y in ys if y > 0]
    assert right and left, fa.decisions
    width = left[0] - right[-1]
    assert 2.8 < width < 4.4 and abs((left[0] + right[-1]) / 2) < 0.6, ys


def test_a_camera_that_does_not_fit_the_lanes_is_said():
    """The job's height 1.4 m and the lanes 3.5 m apart: analysed as 1.1 m high, the lane
    measures 2.75 m, and the analysis says the camera does not fit the frame."""
    img, _ = street(CAM, EST, road=(-2.5, 8.3), lines=LINES)
    low = CameraEstimate(height_m=1.1, pitch_deg=-2.0, roll_deg=0.0)
    fa, _ = stage.analyse_frame(img, "f000000", CAM, low, objects.load_detector(), lane_width_m=3.5)
    why = next(d["reason"] for d in fa.decisions if d["what"] == "lane_lines")
    assert "measures 2.7" in why and "does not fit" in why, why
    fa, _ = stage.analyse_frame(img, "f000000", CAM, EST, objects.load_detector(), lane_width_m=3.5)
    assert "does not fit" not in next(d["reason"] for d in fa.decisions if d["what"] == "lane_lines")


def test_a_video_track_follows_its_lane_through_frames_without_lines():
    """On video each frame's lines move the track; frames without lines, even 30 s from the
    nearest with them, take their neighbours' shift (no NaN from vanishing weights), and a
    vehicle that first appears in a frame without lines takes the nearest frame's lanes."""
    fa, mask = _off_centre()
    T = np.asarray(fa.T_world_cam)
    twin = GroundPlaneTwin.from_job(GroundPlane(camera_height_m=1.4, pitch_deg=-2.0, lane_width_m=3.5, analysis=True))
    bare = RealFrame(dataclasses.replace(fa, lane_lines=[]), mask, None)
    frames = [RealFrame(fa, mask, None)] + [bare] * 3
    real = RealScene(frames, CAM)
    poses = [(f"f{i:06d}", t, T) for i, t in enumerate((0.0, 10.0, 20.0, 40.0))]
    inject = Inject(objects_per_frame=(2, 2), classes={"car": 1}, distance_m=(8, 30), sequences=True)
    ys = {}
    for seed in range(4):
        for p in plan_sequence(twin, CAM, poses, inject, seed, real=real):
            for o in p.objects:
                ys.setdefault((seed, o.id), []).append(o.position[1] - T[1, 3])
    assert any(len(track) == 4 for track in ys.values()) and any(len(track) < 4 for track in ys.values()), ys
    centres = np.array([-0.6, 2.9, 6.4])
    for y in (v for track in ys.values() for v in track):
        assert np.isfinite(y) and np.min(np.abs(y - centres)) < 0.15, ys


def test_lane_shifts_over_a_long_video_stay_finite_smooth_and_cheap():
    """A track as long as a 10-minute video at 25 fps, lines in 70 % of its frames with 5 cm of
    noise: the shifts are finite and smoothed (the cost of the smoothing is in benchmarks/plan/bench_lanes.py)."""
    from blendgen.scene.planner import Planner

    rng = np.random.default_rng(0)
    n = 15000
    vals = np.where(rng.random(n) < 0.7, rng.normal(0.3, 0.05, n), np.nan)
    stub = type("Stub", (), {"real": object(), "inject": Inject(sequences=True), "_real_lanes": lambda self, k, *a:
                             None if np.isnan(vals[k]) else (0, 0.0, {0: float(vals[k])}, 3.5)})()
    out = Planner._real_lane_shifts(stub, 0, None, 0, 1, np.zeros(n), np.arange(n) / 25.0)
    assert np.isfinite(out).all() and abs(out.mean() - 0.3) < 0.01 and out.std() < 0.015


def test_a_vehicle_keeps_its_lane_when_the_camera_changes_lanes():
    """The camera drifts from one real lane into the next over 100 frames; the twin's lanes lie
    0.4 m beside the real ones, so the camera crosses a twin boundary at another moment than the
    real one. A vehicle in the twin lane centred at y = 0.4 m keeps to the real lane at y = 0
    (a first version took the lane by its number from the twin's ego lane and jumped a lane)."""
    from blendgen.scene.planner import Planner

    w, n = 3.5, 100
    cam_y = np.linspace(0.0, w, n)

    def real_lanes(self, k, *a):
        ego_centre = round(cam_y[k] / w) * w  # the real lane the camera is in
        twin_ego = round((cam_y[k] - 0.4) / w)  # the twin lane it is in (centres at 0.4 + w m)
        return 0 - twin_ego, 0.4, {m: ego_centre + m * w for m in range(-3, 4)}, w

    stub = type("Stub", (), {"real": object(), "inject": Inject(sequences=True), "_real_lanes": real_lanes})()
    out = Planner._real_lane_shifts(stub, 0, None, 0, 1, np.zeros(n), np.arange(n) / 25.0)
    assert np.allclose(out, -0.4), out
