"""OpenStreetMap twins: an extract written here (a junction, sidewalks, a signal, a crossing,
buildings with height and levels) becomes a twin; the bpy test builds and renders it."""

import numpy as np
import pytest

from blendgen.cli import main as cli
from blendgen.errors import UserError
from blendgen.twin.model import load_twin

TOWN = """<?xml version="1.0" encoding="UTF-8"?>
<osm version="0.6" generator="blendgen-test">
  <node id="1" lat="48.13700" lon="11.57400"/>
  <node id="2" lat="48.13700" lon="11.57600"/>
  <node id="3" lat="48.13700" lon="11.57800"/>
  <node id="4" lat="48.13610" lon="11.57600"/>
  <node id="5" lat="48.13790" lon="11.57600"/>
  <node id="6" lat="48.13700" lon="11.57560"><tag k="highway" v="crossing"/><tag k="crossing" v="zebra"/></node>
  <node id="7" lat="48.13702" lon="11.57610"><tag k="highway" v="traffic_signals"/></node>
  <node id="10" lat="48.13730" lon="11.57450"/><node id="11" lat="48.13730" lon="11.57490"/>
  <node id="12" lat="48.13755" lon="11.57490"/><node id="13" lat="48.13755" lon="11.57450"/>
  <node id="20" lat="48.13660" lon="11.57650"/><node id="21" lat="48.13660" lon="11.57700"/>
  <node id="22" lat="48.13680" lon="11.57700"/><node id="23" lat="48.13680" lon="11.57650"/>
  <way id="100"><nd ref="1"/><nd ref="6"/><nd ref="2"/><nd ref="3"/>
    <tag k="highway" v="secondary"/><tag k="lanes" v="4"/><tag k="sidewalk" v="both"/><tag k="maxspeed" v="50"/></way>
  <way id="101"><nd ref="4"/><nd ref="2"/><nd ref="5"/>
    <tag k="highway" v="residential"/><tag k="oneway" v="yes"/><tag k="width" v="3.5"/><tag k="sidewalk" v="both"/></way>
  <way id="200"><nd ref="10"/><nd ref="11"/><nd ref="12"/><nd ref="13"/><nd ref="10"/>
    <tag k="building" v="yes"/><tag k="height" v="14 m"/></way>
  <way id="201"><nd ref="20"/><nd ref="21"/><nd ref="22"/><nd ref="23"/><nd ref="20"/>
    <tag k="building" v="apartments"/><tag k="building:levels" v="5"/></way>
</osm>
"""


@pytest.fixture
def town(tmp_path):
    f = tmp_path / "town.osm"
    f.write_text(TOWN)
    return f


def test_osm_extract_becomes_a_twin(town, tmp_path):
    twin = load_twin(town)
    main, side = twin.roads["w100"], twin.roads["w101"]
    assert (main.spec.lanes_forward, main.spec.lanes_backward, main.spec.lane_width_m) == (2, 2, 3.25)
    assert (side.spec.lanes_forward, side.spec.lanes_backward, side.spec.lane_width_m) == (1, 0, 3.5)  # one-way, tagged width
    assert main.spec.sidewalk_m > 0 and main.spec.speed_mps == pytest.approx(50 / 3.6)
    assert main.length == pytest.approx(297.7, abs=1.0)  # 0.004 deg of longitude at 48.137 N
    # the junction at the shared node is signalised (the signal node is 8 m away): signal poles there
    (x,) = twin.spec.intersections
    assert x.signals and len(twin.signal_slots) >= 4
    assert all(np.hypot(s.x - x.center[0], s.y - x.center[1]) < 20 for s in twin.signal_slots)
    # the zebra crossing 30 m west of the junction
    (cw,) = twin.crosswalks
    assert np.linalg.norm(cw.mean(0) - np.asarray(x.center)) == pytest.approx(29.8, abs=1.0)
    heights = sorted(s.height for s in twin.structures if s.kind == "building")
    assert heights == [14.0, 16.0]  # tagged height; 5 levels x 3 m + roof
    lane = twin.lane_at(x.center[0] + 1.75, x.center[1] - 50)  # right of the way's centre-line
    assert lane.road == "w101" and lane.direction == 1  # one-way northbound
    assert twin.on_sidewalk(x.center[0] - 60, x.center[1] + 2 * 3.25 + 0.3 + 1.0)  # lanes, shoulder, walk
    assert cli(["twin", "import", "osm", str(town), str(tmp_path / "tw")]) == 0
    assert (tmp_path / "tw" / "twin.png").stat().st_size > 10000


def test_osm_errors(tmp_path):
    f = tmp_path / "empty.osm"
    f.write_text('<?xml version="1.0"?><osm version="0.6"><node id="1" lat="48" lon="11"/></osm>')
    with pytest.raises(UserError, match="no roads"):
        load_twin(f)
    g = tmp_path / "broken.osm"
    g.write_text('<?xml version="1.0"?><osm version="0.6"><node id="1" lat="48" lon="11">')
    with pytest.raises(UserError, match="cannot read the OSM extract"):
        load_twin(g)


@pytest.mark.bpy
def test_osm_twin_builds_and_renders(town, tmp_path):
    pytest.importorskip("bpy")
    import cv2

    from blendgen.geometry import Camera, R_world_cam_from_ypr, make_pose
    from blendgen.job.schema import Render
    from blendgen.render.session import RenderSession

    twin = load_twin(town)
    x0, y0 = twin.spec.intersections[0].center
    # on the main road's eastbound lane 60 m west of the junction, looking east
    T = make_pose(R_world_cam_from_ypr(0.0), [x0 - 60, y0 - 5, 1.5])
    sun = {"sun_direction": [0.45, -0.35, 0.82], "sun_strength": 3.0, "sun_color": [1, 1, 1],
           "sun_angle_deg": 0.5, "sky_color": [0.5, 0.6, 0.8], "sky_strength": 1.0, "sun_visible": True}
    s = RenderSession(town, None, Render(samples=4, denoise=False), Camera.from_hfov(160, 90, 70))
    try:
        roles = set(s._roles.values())
        assert {"road", "sidewalk", "structure"} <= roles
        s.render_background(T, sun, tmp_path / "osm.png", 4)
        img = cv2.imread(str(tmp_path / "osm.png"))
        assert img.shape == (90, 160, 3) and img[:25].mean() > img[-15:].mean()  # sky over the road
    finally:
        s.close()


def test_osm_pbf_reads_like_xml(town, tmp_path):
    import osmium

    pbf = tmp_path / "town.osm.pbf"
    with osmium.SimpleWriter(str(pbf)) as w:  # the reader library's own writer
        for o in osmium.FileProcessor(str(town)):
            w.add(o)
    a, b = load_twin(town), load_twin(pbf)
    assert set(a.roads) == set(b.roads) and len(b.crosswalks) == 1 and len(b.signal_slots) == len(a.signal_slots)
    assert np.allclose(a.roads["w100"].line.pts, b.roads["w100"].line.pts, atol=1e-3)
