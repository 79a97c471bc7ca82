"""Scenarios on twins with junctions and crosswalks: the jaywalker crosses just beside a
crosswalk when the twin has them, else mid-block away from junctions; cut-ins happen on a
multi-lane segment, never in a junction."""

from pathlib import Path

import numpy as np
import pytest

from blendgen.job.schema import Inject
from blendgen.scene.planner import plan_sequence
from blendgen.twin.model import Twin, load_twin
from blendgen.twin.schema import TwinSpec
from test_planner import CAM, TWINS, drive

MAPS = Path(__file__).resolve().parents[2] / "shared" / "data" / "maps" / "opendrive"
if not MAPS.is_dir():
    MAPS = Path("/work/shared/data/maps/opendrive")


def _crossing_twin() -> Twin:
    """A 2+2-lane main street crossed by a 1+1 street at x = 200, no crosswalks."""
    return Twin(TwinSpec.model_validate({
        "name": "crossing", "georef": {"lat0": 48.1, "lon0": 11.5},
        "roads": [{"id": "main", "points": [[0, 0], [400, 0]], "lanes_forward": 2, "lanes_backward": 2,
                   "lane_width_m": 3.4, "sidewalk_m": 3.0},
                  {"id": "cross", "points": [[200, -150], [200, 150]], "lanes_forward": 1, "lanes_backward": 1,
                   "sidewalk_m": 3.0}],
        "intersections": [{"id": "x", "center": [200, 0], "crosswalks": False, "stop_lines": False,
                           "signals": False}]}))


def _scenario_tracks(twin, route, name, seeds, fps=2.5):
    out = {}
    for seed in seeds:
        poses = drive(route, fps=fps)
        inj = Inject(classes={"car": 1}, objects_per_frame=(0, 1), scenarios=[name])
        for fp in plan_sequence(twin, CAM, poses, inj, seed):
            for o in fp.objects:
                if o.scenario == name and o.cls != "person" or (name == "jaywalker" and o.cls == "person"):
                    out.setdefault((seed, o.id), []).append(np.array(o.position[:2]))
    return {k: np.array(v) for k, v in out.items()}


def test_cut_in_on_a_multilane_segment_never_in_a_junction():
    tw = _crossing_twin()
    route = tw.lane_polyline("main", 0, +1, 10.0, 390.0)  # through the junction at x = 200
    tracks = _scenario_tracks(tw, route, "cut_in", range(3))
    assert len(tracks) >= 3, "cut-ins staged"
    for pts in tracks.values():
        assert not tw.junction_mask(pts).any()
        for p in pts:
            lane = tw.lane_at(*p)
            assert lane is not None and lane.road == "main"  # the 2-lane direction of the main street


def test_jaywalker_mid_block_without_crosswalks():
    tw = _crossing_twin()
    route = tw.lane_polyline("main", 1, +1, 10.0, 390.0)
    tracks = _scenario_tracks(tw, route, "jaywalker", range(3))
    assert len(tracks) >= 3
    for pts in tracks.values():
        assert not tw.junction_mask(pts).any() and not tw.crosswalk_mask(pts).any()
        d = pts[-1] - pts[0]
        assert abs(d[0]) <= 0.05 * abs(d[1]) + 1e-9  # straight across the main street (along x)
        assert tw.sidewalk_mask(pts[:1]).all() or abs(abs(pts[0, 1]) - tw.roads["main"].hw_right - 0.4) < 0.01


def _near_crosswalk(tw, p, margin=4.6):
    for road, s0, s1 in tw.crosswalk_info:
        rg = tw.roads[road]
        s, d, _ = rg.line.project(p)
        if s0 - margin <= s[0] <= s1 + margin and -rg.hw_r(s[0]) - 0.6 <= d[0] <= rg.hw_l(s[0]) + 0.6:
            return True
    return False


@pytest.mark.parametrize("where", ["demo_town", "intersection_map"])
def test_jaywalker_crosses_beside_a_crosswalk(where):
    if where == "demo_town":
        tw = load_twin(TWINS / "demo_town.yaml")
        routes = [tw.lane_polyline("main", 0, +1, 5.0, 140.0), tw.lane_polyline("main", 1, -1, 140.0, 5.0)]
    else:
        if not (MAPS / "intersection_3_5m_width_crosswalk.xodr").is_file():
            pytest.skip("needs ../shared/data/maps/opendrive")
        tw = load_twin(MAPS / "intersection_3_5m_width_crosswalk.xodr")
        routes = [tw.ego_route(70.0, s) for s in range(2)]
    assert tw.crosswalks
    n = 0
    for route in routes:
        for pts in _scenario_tracks(tw, route, "jaywalker", range(2)).values():
            n += 1
            assert _near_crosswalk(tw, pts[0]), pts[0]  # starts at the kerb beside a crosswalk
            assert not tw.on_crosswalk(*pts[0])
    assert n >= 2
