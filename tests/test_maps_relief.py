"""OpenDRIVE relief and lane widths applied to the twin: heights, road pitch/roll under
placed objects, 3-D labels; width polynomials and <border> records along s; projected
geoReferences (UTM, EPSG) for GNSS fixes and headings. Maps are written in the tests and
checked against values computed independently from their XML records."""

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from blendgen.geometry import Camera, R_world_cam_from_ypr, make_pose
from blendgen.job.schema import Inject
from blendgen.labels.instances import box3d_cam
from blendgen.plan import FramePlan, PlacedObject
from blendgen.scene.planner import Planner
from blendgen.twin.model import load_twin

CAM = Camera.from_hfov(480, 270, 70.0)

# a straight road along +x (hdg 0): the reference line is y = 0, so road coordinates (s, t)
# sit at plan (s, t cos(theta)) and height z(s) + t sin(theta)
RELIEF = """<?xml version="1.0"?>
<OpenDRIVE><header name="relief"><geoReference><![CDATA[+proj=tmerc +lat_0=48.1 +lon_0=11.5 +x_0=0 +y_0=0 +datum=WGS84 +units=m]]></geoReference></header>
<road id="1" length="200" junction="-1"><planView><geometry s="0" x="0" y="0" hdg="0" length="200"><line/></geometry></planView>
<elevationProfile>
  <elevation s="0" a="1.0" b="0.05" c="0" d="0"/>
  <elevation s="100" a="6.0" b="0.05" c="-0.0006" d="0.000002"/>
</elevationProfile>
<lateralProfile>
  <superelevation s="0" a="0" b="0" c="0" d="0"/>
  <superelevation s="120" a="0.06" b="0" c="0" d="0"/>
</lateralProfile>
<lanes><laneSection s="0"><center><lane id="0" type="none"/></center>
<left><lane id="1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></left>
<right><lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
<lane id="-2" type="driving"><width sOffset="0" a="3.25" b="0" c="0" d="0"/></lane></right>
</laneSection></lanes></road></OpenDRIVE>"""


def _z(s):
    """The elevation profile of RELIEF, evaluated here from its records."""
    if s < 100:
        return 1.0 + 0.05 * s
    u = s - 100
    return 6.0 + 0.05 * u - 0.0006 * u ** 2 + 0.000002 * u ** 3


def _theta(s):
    return 0.06 if s >= 120 else 0.0


@pytest.fixture(scope="module")
def relief_twin(tmp_path_factory):
    f = tmp_path_factory.mktemp("relief") / "relief.xodr"
    f.write_text(RELIEF)
    return load_twin(f)


def test_heights_and_roll_follow_elevation_and_superelevation(relief_twin):
    tw = relief_twin
    rg = tw.roads["1"]
    assert rg.relief and tw.relief
    # lane centres (road coordinate t): lane -1 at -1.75, -2 at -5.125, 1 at 1.75
    for t in (-1.75, -5.125, 1.75):
        for s in (10.0, 60.0, 110.0, 150.0, 190.0):
            th = _theta(s)
            p = np.array([[s, t * math.cos(th)]])
            assert abs(tw.ground_heights(p)[0] - (_z(s) + t * math.sin(th))) < 0.005, (s, t)
    # a car along lane -1 (heading +x) on the 5 % slope, and one on the superelevated stretch
    z, pitch, roll = tw.surface_pose([[50.0, -1.75], [160.0, -1.75 * math.cos(0.06)]], [0.0, 0.0], 4.5, 1.8)
    assert abs(pitch[0] - math.atan(0.05)) < 1e-4 and abs(roll[0]) < 1e-6
    assert abs(z[0] - _z(50.0)) < 0.005
    dz = 0.05 - 2 * 0.0006 * 60 + 3 * 0.000002 * 60 ** 2  # dz/ds at s = 160
    assert abs(pitch[1] - math.atan(dz)) < 1e-3
    # falls to the right: the left side is up; the body's left axis in the tilted plane
    assert abs(roll[1] - math.atan(math.tan(0.06) * math.cos(pitch[1]))) < 1e-4
    # driving the other way (lane 1, heading -x): nose down, right side up
    _, p2, r2 = tw.surface_pose([[50.0, 1.75], [160.0, 1.75 * math.cos(0.06)]], [math.pi, math.pi], 4.5, 1.8)
    assert abs(p2[0] + math.atan(0.05)) < 1e-4 and r2[1] < -0.05
    # the LUT carries the heights
    rows = np.array([r[4:7] for r in tw.lut_rows(10.0)])
    assert rows[:, 2].max() > 7.0 and np.abs(tw.ground_heights(rows[:, :2]) - rows[:, 2]).max() < 0.005


def test_placed_car_on_slope_has_road_pitch_and_3d_label(relief_twin):
    tw = relief_twin
    poses = [(f"{k:06d}", k * 0.5, make_pose(R_world_cam_from_ypr(0.0), [5.0 + 4 * k * 0.5, -1.75, 1.5 + _z(5.0)]))
             for k in range(6)]
    pl = Planner(tw, CAM, poses, Inject(classes={"car": 1}), 0)
    from blendgen.scene.catalog import sample_variant

    v, dims = sample_variant("car", np.random.default_rng(0))
    tr = pl.lane_track(0, "car", v, dims, "1", 1, +1, 30.0, 6.0)  # lane -2, moving up the slope
    assert tr is not None and len(tr.xy) == 6
    assert np.allclose(tr.pitch, math.atan(0.05), atol=1e-4) and np.allclose(tr.roll, 0.0, atol=1e-6)
    assert np.allclose(tr.z, [_z(x) for x in tr.xy[:, 0]], atol=0.005)
    obj = PlacedObject(1, "car", (float(tr.xy[0, 0]), float(tr.xy[0, 1]), float(tr.z[0])), float(tr.yaw[0]),
                       tuple(dims), pitch=float(tr.pitch[0]), roll=float(tr.roll[0]))
    c = obj.box_corners_world()  # corner index ix*4 + iy*2 + iz: bottom face front (ix=1) vs rear (ix=0)
    L = dims[0]
    assert abs((c[4, 2] - c[0, 2]) - L * math.sin(math.atan(0.05))) < 1e-6
    # the bottom corners lie on the road (the slope is linear here)
    for i in (0, 2, 4, 6):
        assert abs(c[i, 2] - _z(c[i, 0])) < 0.01
    box = box3d_cam(obj, poses[0][2])
    R = np.asarray(box["R_cam_obj"])
    fwd_world = np.asarray(poses[0][2])[:3, :3] @ R[:, 0]
    assert abs(math.asin(fwd_world[2]) - math.atan(0.05)) < 1e-9
    # the plan (and so the render and labels) carries pitch/roll through JSON
    fp = FramePlan.from_dict(FramePlan("f", 0.0, np.eye(4).tolist(), [obj]).to_dict())
    assert fp.objects[0].pitch == obj.pitch and fp.objects[0].euler_xyz == (obj.roll, -obj.pitch, obj.yaw)


# ---------------------------------------------------------------- lane widths along s, <border>
WIDTHS = """<?xml version="1.0"?>
<OpenDRIVE><header name="widths"/>
<road id="7" length="120" junction="-1"><planView><geometry s="0" x="10" y="5" hdg="0.3" length="120"><line/></geometry></planView>
<lanes><laneOffset s="0" a="0.2" b="0.01" c="0" d="0"/>
<laneSection s="0"><center><lane id="0" type="none"/></center>
<left><lane id="1" type="driving"><width sOffset="0" a="3.4" b="0" c="0.0005" d="0"/></lane></left>
<right><lane id="-1" type="driving"><width sOffset="0" a="3.0" b="0.01" c="0.0002" d="-0.000002"/></lane>
<lane id="-2" type="driving"><width sOffset="0" a="3.2" b="0" c="0" d="0"/><width sOffset="30" a="3.2" b="0.02" c="0" d="0"/></lane>
<lane id="-3" type="shoulder"><width sOffset="0" a="0.5" b="0" c="0" d="0"/></lane></right>
</laneSection>
<laneSection s="60"><center><lane id="0" type="none"/></center>
<left><lane id="1" type="driving"><border sOffset="0" a="5.2" b="-0.02" c="0" d="0"/></lane></left>
<right><lane id="-1" type="driving"><width sOffset="0" a="3.5" b="-0.01" c="0" d="0"/></lane>
<lane id="-2" type="driving"><border sOffset="0" a="-6.5" b="-0.03" c="0.0004" d="0"/></lane></right>
</laneSection></lanes></road></OpenDRIVE>"""


def _rec(recs, ds):
    """Piecewise cubic records [(sOffset, a, b, c, d)], evaluated here independently."""
    r = [x for x in recs if x[0] <= ds + 1e-12][-1]
    u = ds - r[0]
    return r[1] + r[2] * u + r[3] * u * u + r[4] * u ** 3


def _independent_width_lanes(xml):
    """{(section, lane id): (N, 2) lane-centre points} from the XML records."""
    root = ET.fromstring(xml)
    road = root.find("road")
    g = road.find("planView/geometry")
    x0, y0, h, L = (float(g.get(k)) for k in ("x", "y", "hdg", "length"))
    attrs = ("sOffset", "a", "b", "c", "d")
    lo = [(float(e.get("s")), *(float(e.get(k)) for k in attrs[1:])) for e in road.findall("lanes/laneOffset")]
    secs = road.findall("lanes/laneSection")
    starts = [float(sec.get("s")) for sec in secs] + [L]
    out = {}
    for k, sec in enumerate(secs):
        s0, s1 = starts[k], starts[k + 1]
        for side, sign in (("left", 1), ("right", -1)):
            lanes = sorted(sec.findall(f"{side}/lane"), key=lambda e: abs(int(e.get("id"))))
            for s in np.linspace(s0 + 0.1, s1 - 0.1, 40):
                ds, inner = s - s0, 0.0
                for ln in lanes:
                    wr = [tuple(float(e.get(a)) for a in attrs) for e in ln.findall("width")]
                    br = [tuple(float(e.get(a)) for a in attrs) for e in ln.findall("border")]
                    outer = inner + _rec(wr, ds) if wr else abs(_rec(br, ds))
                    if ln.get("type") == "driving":
                        t = _rec(lo, s) + sign * (inner + outer) / 2
                        p = (x0 + s * math.cos(h) - t * math.sin(h), y0 + s * math.sin(h) + t * math.cos(h))
                        out.setdefault((k, int(ln.get("id"))), []).append(p)
                    inner = outer
    return {key: np.array(v) for key, v in out.items()}


def test_lane_widths_along_s_and_borders_match_the_records(tmp_path):
    from blendgen.geom2d import Polyline

    f = tmp_path / "widths.xodr"
    f.write_text(WIDTHS)
    tw = load_twin(f)
    ref = _independent_width_lanes(WIDTHS)
    assert len(ref) == 6
    worst = 0.0
    for (k, lid), pts in ref.items():
        rg = tw.roads[f"7.{k}"]
        direction, index = (1, -lid - 1) if lid < 0 else (-1, lid - 1)
        s0, s1 = (0.0, rg.length) if direction > 0 else (rg.length, 0.0)
        lane = Polyline(tw.lane_polyline(rg.id, index, direction, s0, s1, step=0.25))
        s, d, _ = lane.project(pts)
        assert np.all((s > -0.05) & (s < lane.length + 0.05))
        worst = max(worst, float(np.abs(d).max()))
        # lane_at finds the lane, with its local width, at the independent centres
        for p in pts[::8]:
            ln = tw.lane_at(*p)
            assert ln is not None and (ln.road, ln.index, ln.direction) == (rg.id, index, direction)
    assert worst < 0.02, f"lane centre off by {worst * 100:.2f} cm"
    # the widths vary along the road (not one mean width): lane -2 of section 0 widens 3.2 -> 3.8 m
    rg = tw.roads["7.0"]
    assert abs(rg.lane_width(1, +1, 5.0) - 3.2) < 0.01 and abs(rg.lane_width(1, +1, 59.0) - (3.2 + 0.02 * 29)) < 0.01


# ---------------------------------------------------------------- projected geoReferences
UTM = """<?xml version="1.0"?>
<OpenDRIVE><header name="utm"><geoReference><![CDATA[{PROJ}]]></geoReference></header>
<road id="1" length="300" junction="-1"><planView>
<geometry s="0" x="691000" y="5335000" hdg="0.7" length="150"><line/></geometry>
<geometry s="150" x="{X1}" y="{Y1}" hdg="0.7" length="150"><arc curvature="0.01"/></geometry></planView>
<lanes><laneSection s="0"><center><lane id="0" type="none"/></center>
<left><lane id="1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></left>
<right><lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></right>
</laneSection></lanes></road></OpenDRIVE>"""


@pytest.mark.parametrize("proj", ["+proj=utm +zone=32 +datum=WGS84 +units=m +no_defs", "EPSG:32632"])
def test_utm_georeference_round_trips_fixes_and_headings(tmp_path, proj):
    import pyproj

    f = tmp_path / "utm.xodr"
    x1, y1 = 691000 + 150 * math.cos(0.7), 5335000 + 150 * math.sin(0.7)
    f.write_text(UTM.replace("{PROJ}", proj).replace("{X1}", f"{x1:.6f}").replace("{Y1}", f"{y1:.6f}"))
    tw = load_twin(f)
    g = tw.georef
    assert g.proj == proj and abs(g.origin[0] - 691000) < 200 and abs(g.origin[1] - 5335000) < 200
    # the twin frame is the map's x/y less the origin (coordinates near 0 for Blender)
    assert np.abs(np.asarray(tw.bounds)).max() < 300
    crs = pyproj.CRS.from_user_input(proj)
    fwd = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    inv = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    geod = pyproj.Geod(ellps="WGS84")
    rows = np.array(tw.lut_rows(3.0))
    lat, lon, hdg, x, y, yaw = rows[:, 0], rows[:, 1], rows[:, 3], rows[:, 4], rows[:, 5], np.radians(rows[:, 7])
    X, Y = fwd.transform(lon, lat)
    assert np.hypot(X - g.origin[0] - x, Y - g.origin[1] - y).max() < 0.01  # LUT fixes are the map's x/y
    e, n, _ = g.to_enu(lat, lon, rows[:, 2])
    assert np.hypot(e - x, n - y).max() < 0.01  # GNSS fixes map back into the twin
    # true heading: geodesic azimuth of the lane direction (central difference, +-5 cm)
    d = 0.05 * np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
    lo1, la1 = inv.transform(x - d[:, 0] + g.origin[0], y - d[:, 1] + g.origin[1])
    lo2, la2 = inv.transform(x + d[:, 0] + g.origin[0], y + d[:, 1] + g.origin[1])
    az, _, _ = geod.inv(lo1, la1, lo2, la2)
    err = np.abs((hdg - az + 180.0) % 360.0 - 180.0)
    assert err.max() < 0.01, err.max()
    # grid north is not true north here (zone 32's central meridian is 9 E): ~1.9 deg apart
    conv = np.degrees(np.pi / 2 - g.north_yaw(0.0, 0.0))
    assert 1.5 < abs(conv) < 2.5
