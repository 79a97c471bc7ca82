"""The bpy-free twin model: lanes, sidewalks, crosswalks, free space, ego route, LUT."""

import csv
import math
from pathlib import Path

import numpy as np
import pymap3d
import pytest

from blendgen.errors import UserError
from blendgen.scene.ground_plane import GroundPlaneTwin
from blendgen.twin.model import load_twin

TWINS = Path(__file__).resolve().parents[1] / "assets_procedural" / "twins"


@pytest.fixture(scope="module")
def town():
    return load_twin(TWINS / "demo_town.yaml")


@pytest.fixture(scope="module")
def highway():
    return load_twin(TWINS / "highway.yaml")


def test_lanes_and_directions(town):
    # main road runs +x; right-hand traffic: forward lanes at y < 0
    lane = town.lane_at(-40.0, -2.0)
    assert lane.road == "main" and lane.direction == 1 and lane.index == 0
    assert abs(lane.yaw) < 1e-6
    lane = town.lane_at(-40.0, 5.0)
    assert lane.direction == -1 and lane.index == 1 and lane.outermost
    assert abs(abs(lane.yaw) - math.pi) < 1e-6
    # cross road runs +y
    lane = town.lane_at(1.5, -40.0)
    assert lane.road == "cross" and abs(lane.yaw - math.pi / 2) < 1e-6  # forward lane, right of +y
    lane = town.lane_at(-1.5, -40.0)
    assert lane.direction == -1 and abs(lane.yaw + math.pi / 2) < 1e-6
    assert town.lane_at(-40.0, -9.0) is None  # sidewalk
    assert town.lane_at(-40.0, -30.0) is None  # building block


def test_junction_uses_heading_hint(town):
    a = town.lane_at(1.0, -1.0, heading=0.0)
    b = town.lane_at(1.0, -1.0, heading=math.pi / 2)
    assert a.in_junction and b.in_junction
    assert a.road == "main" and b.road == "cross"


def test_sidewalk_crosswalk_free_space(town):
    assert town.on_sidewalk(-40.0, -8.5) and town.on_sidewalk(-40.0, 9.0)
    assert not town.on_sidewalk(-40.0, -2.0)
    assert town.on_sidewalk(-8.0, -9.0)  # corner of the block
    assert town.ground_height(-40.0, -8.5) == pytest.approx(0.15)
    assert town.ground_height(-40.0, -2.0) == 0.0
    # mid-block crosswalk at s=70 m -> x=-80; intersection crosswalks on both roads
    assert town.on_crosswalk(-80.0, 0.0) and not town.on_crosswalk(-60.0, 0.0)
    assert town.on_crosswalk(-5.0, 0.0) and town.on_crosswalk(0.0, 9.0)
    b = town.spec.buildings[0]
    inside = np.array(b.center) + np.array([[0.5, 0.5], [-0.5, 0.5], [-0.5, -0.5], [0.5, -0.5]])
    assert not town.is_free(inside)
    on_road = np.array([[-41, -3], [-39, -3], [-39, -1], [-41, -1]], float)
    assert town.is_free(on_road)
    assert len(town.signal_slots) == 8 and len(town.stop_lines) == 4


def test_ego_route_stays_in_one_lane(town, highway):
    for tw in (town, highway):
        for seed in range(12):
            r = tw.ego_route(50.0, seed)
            assert r.shape[1] == 2 and np.isfinite(r).all()
            length = np.linalg.norm(np.diff(r, axis=0), axis=1).sum()
            assert length == pytest.approx(50.0, rel=0.05)
            lanes = [tw.lane_at(x, y, heading=math.atan2(*(r[min(i + 1, len(r) - 1)] - r[max(i - 1, 0)])[::-1]))
                     for i, (x, y) in enumerate(r)]
            assert all(L is not None for L in lanes)
            assert len({(L.road, L.index, L.direction) for L in lanes}) == 1
            assert max(abs(L.lateral) for L in lanes) < 0.05
            d = np.diff(r, axis=0)
            yaw = np.arctan2(d[:, 1], d[:, 0])
            assert all(abs(math.remainder(y - L.yaw, 2 * math.pi)) < math.radians(3) for y, L in zip(yaw, lanes))
        np.testing.assert_array_equal(tw.ego_route(50.0, 3), tw.ego_route(50.0, 3))


def test_lut_export_roundtrip(town, tmp_path):
    path = tmp_path / "lut.csv"
    n = town.export_lut(path, spacing_m=5.0)
    rows = list(csv.DictReader(path.open()))
    assert len(rows) == n > 100
    assert list(rows[0]) == ["lat", "lon", "alt", "heading_deg", "x", "y", "z", "yaw_deg"]
    g = town.georef
    for r in rows[:: max(1, n // 40)]:
        e, nn, u = pymap3d.geodetic2enu(float(r["lat"]), float(r["lon"]), float(r["alt"]), g.lat0, g.lon0, g.alt0)
        assert e == pytest.approx(float(r["x"]), abs=1e-3) and nn == pytest.approx(float(r["y"]), abs=1e-3)
        assert float(r["heading_deg"]) == pytest.approx((90.0 - float(r["yaw_deg"])) % 360.0, abs=1e-3)
        lane = town.lane_at(float(r["x"]), float(r["y"]), heading=math.radians(float(r["yaw_deg"])))
        assert abs(math.remainder(lane.yaw - math.radians(float(r["yaw_deg"])), 2 * math.pi)) < 1e-3


@pytest.mark.parametrize("name", ["demo_town", "highway"])
def test_shipped_luts_are_current(name, tmp_path):
    tw = load_twin(TWINS / f"{name}.yaml")
    tw.export_lut(tmp_path / "lut.csv", spacing_m=2.0)
    assert (tmp_path / "lut.csv").read_text() == (TWINS / f"{name}_lut.csv").read_text()


@pytest.mark.parametrize("text, field", [
    ("name: x\nroads: []\ngeoref: {lat0: 1, lon0: 2}\n", "roads"),
    ("name: x\ngeoref: {lat0: 100, lon0: 2}\nroads: [{id: a, points: [[0,0],[10,0]]}]\n", "georef.lat0"),
    ("name: x\ngeoref: {lat0: 1, lon0: 2}\nroads: [{id: a, points: [[0,0]]}]\n", "roads[0]"),
    ("name: x\ngeoref: {lat0: 1, lon0: 2}\nroads: [{id: a, points: [[0,0],[9,0]], lane_widht_m: 3}]\n",
     "roads[0].lane_widht_m"),
    ("name: x\ngeoref: {lat0: 1, lon0: 2}\nroads: [{id: a, start: [0,0], segments: [{arc: {radius_m: 1, angle_deg: 9}}]}]\n",
     "roads[0].segments[0].arc.radius_m"),
    ("name: x\ngeoref: {lat0: 1, lon0: 2}\nroads: [{id: a, points: [[0,0],[9,0]]}]\nintersections: [{id: i, center: [50, 50]}]\n",
     "intersections[0].center"),
    ("name: x\ngeoref: {lat0: 1, lon0: 2}\nroads: [{id: a, points: [[0,0],[9,0]]}]\ncrosswalks: [{road: b, s_m: 1}]\n",
     "crosswalks[0].road"),
    ("name: [x\n", "not valid YAML"),
])
def test_bad_twin_yaml_names_the_field(tmp_path, text, field):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(UserError) as e:
        load_twin(p)
    assert field in str(e.value) and str(p) in str(e.value)


def test_missing_twin_file(tmp_path):
    with pytest.raises(UserError, match="not found"):
        load_twin(tmp_path / "nope.yaml")


def test_ground_plane_twin():
    g = GroundPlaneTwin(camera_height_m=1.3, pitch_deg=-3.0, lane_width_m=3.6)
    ego = g.lane_at(20.0, 0.0)
    assert ego.direction == 1 and abs(ego.lateral) < 1e-9 and abs(ego.yaw) < 1e-9
    assert g.lane_at(20.0, 3.6).index != ego.index and g.lane_at(20.0, -3.6) is not None
    assert g.lane_at(20.0, -7.0) is None and g.on_sidewalk(20.0, -7.0)
    T = g.camera_pose()
    assert T[2, 3] == pytest.approx(1.3)
    assert T[:3, 2][2] == pytest.approx(-math.sin(math.radians(3.0)))  # optical axis tilted down
    r = g.ego_route(50.0, 0)
    assert np.isfinite(r).all()
    with pytest.raises(UserError, match="camera_height_m"):
        GroundPlaneTwin(camera_height_m=0.0)
