"""The twin (virtual place) without Blender: loads the twin YAML and answers placement
questions (which lane and its direction, sidewalk, crosswalk, free space, ground height),
plans an ego route along a lane and exports the LUT for the sync stage.

Frame: ENU about the twin's georeference (x east, y north, z up), metres. Right-hand
traffic: a road's `lanes_forward` run along its centre-line on the right of it,
`lanes_backward` against it on the left. Roads are flat at z = 0 unless a map gives them
relief (elevation, superelevation: `RoadGeom.height`); sidewalks sit at curb height above
the road edge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from blendgen import atomic
from blendgen.errors import UserError
from blendgen.geom2d import Polyline, convex_overlap, point_in_convex, rect
from blendgen.twin.maps import map_format, map_twin_data
from blendgen.twin.schema import Road, TwinSpec
from blendgen.validation import error_lines, read_yaml_mapping

STEP_M = 1.0  # centre-line sampling
SIGNAL_POLE_M = 4.2  # height of the signal poles built at intersection signal slots


class Georef(tuple):
    """The twin's geodetic origin: a tuple (lat0, lon0, alt0) with conversions to and from
    the twin frame. Without `proj` the twin frame is ENU about the origin; with it (maps
    georeferenced in a projection such as UTM) x/y are the projected coordinates minus
    `origin`, so GNSS fixes map through pyproj and grid north differs from true north by the
    projection's meridian convergence."""

    def __new__(cls, lat0: float, lon0: float, alt0: float = 0.0, proj: str | None = None,
                origin: tuple[float, float] = (0.0, 0.0)):
        self = super().__new__(cls, (float(lat0), float(lon0), float(alt0)))
        self.proj, self.origin = proj, (float(origin[0]), float(origin[1]))
        self._fwd = self._inv = None
        return self

    def __reduce__(self):  # pickles without the cached transformers
        return Georef, (*self, self.proj, self.origin)

    lat0 = property(lambda self: self[0])
    lon0 = property(lambda self: self[1])
    alt0 = property(lambda self: self[2])

    def _transformers(self):
        if self._fwd is None:
            import pyproj

            crs = pyproj.CRS.from_user_input(self.proj)
            self._fwd = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
            self._inv = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
        return self._fwd, self._inv

    def to_geodetic(self, x, y, z):
        if self.proj is None:
            import pymap3d

            return pymap3d.enu2geodetic(x, y, z, self.lat0, self.lon0, self.alt0)
        lon, lat = self._transformers()[1].transform(np.asarray(x, float) + self.origin[0],
                                                     np.asarray(y, float) + self.origin[1])
        return lat, lon, np.asarray(z, float) + self.alt0

    def to_enu(self, lat, lon, alt):
        """Twin-frame x, y, z of geodetic positions (named for the unprojected case)."""
        if self.proj is None:
            import pymap3d

            return pymap3d.geodetic2enu(lat, lon, alt, self.lat0, self.lon0, self.alt0)
        x, y = self._transformers()[0].transform(lon, lat)
        return np.asarray(x) - self.origin[0], np.asarray(y) - self.origin[1], np.asarray(alt, float) - self.alt0

    def north_yaw(self, x, y):
        """Twin-frame direction (rad, CCW from +x) of true north at x/y: pi/2 in ENU; in a
        projection pi/2 minus the meridian convergence (by finite differences: exact for the
        conformal projections maps use)."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        if self.proj is None:
            return np.full(np.broadcast(x, y).shape, math.pi / 2)
        lat, lon, _ = self.to_geodetic(x, y, np.zeros(np.broadcast(x, y).shape))
        d = 1e-5  # ~1 m of latitude
        x1, y1, _ = self.to_enu(np.asarray(lat) + d, lon, 0.0)
        x0, y0, _ = self.to_enu(np.asarray(lat) - d, lon, 0.0)
        return np.arctan2(np.asarray(y1) - y0, np.asarray(x1) - x0)

    def heading_of_yaw(self, x, y, yaw):
        """Compass heading (deg, clockwise from true north) of twin-frame yaw (rad) at x/y."""
        return np.degrees(self.north_yaw(x, y) - np.asarray(yaw, float)) % 360.0


@dataclass(frozen=True)
class Lane:
    """A lane at a query point. `yaw` is the travel direction (rad, CCW from +x)."""

    road: str
    index: int        # 0 = next to the centre-line / median, increasing outward
    direction: int    # +1 along the road's centre-line, -1 against it
    yaw: float
    width: float
    s: float          # arc length of the query point along the road centre-line
    d: float          # lateral offset of the query point from the centre-line (left > 0)
    center_d: float   # lateral offset of the lane centre
    outermost: bool   # the lane next to the curb / shoulder
    in_junction: bool
    speed_mps: float

    @property
    def heading(self) -> np.ndarray:
        return np.array([math.cos(self.yaw), math.sin(self.yaw)])

    @property
    def lateral(self) -> float:
        """Offset of the query point from the lane centre, positive to the left of travel."""
        return (self.d - self.center_d) * self.direction


class RoadGeom:
    """One road: its centre-line and its cross-section.

    A map's road may carry relief (`z`, `superelevation_deg`) and per-lane widths that vary
    along it (`lane_widths_*`), given per centre-line point: they are interpolated in arc
    length. `d` is the plan-view lateral offset (left > 0); the surface height at (s, d) is
    z(s) + d tan(superelevation(s)). The scalar `hw_right` / `hw_left` / `lanes` centre
    offsets are the widest extent / the mean, for callers that need one number."""

    def __init__(self, spec: Road):
        self.spec = spec
        self.id = spec.id
        self.line = Polyline(_centerline(spec))
        self.length = self.line.length
        w, m, sh = spec.lane_width_m, spec.median_m, spec.shoulder_m
        # knots: arc length of the given points (the densified line keeps their arc length)
        if spec.points is not None:
            p = np.asarray(spec.points, dtype=float)
            self._sk = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
        else:
            self._sk = np.array([0.0, self.length])
        nk = len(self._sk)
        self.relief = spec.z is not None or spec.superelevation_deg is not None
        self._zk = np.asarray(spec.z, float) if spec.z is not None else np.zeros(nk)
        self._tk = (np.tan(np.radians(spec.superelevation_deg)) if spec.superelevation_deg is not None
                    else np.zeros(nk))
        wf = (np.asarray(spec.lane_widths_forward, float).reshape(nk, spec.lanes_forward)
              if spec.lane_widths_forward is not None else np.full((nk, spec.lanes_forward), w))
        wb = (np.asarray(spec.lane_widths_backward, float).reshape(nk, spec.lanes_backward)
              if spec.lane_widths_backward is not None else np.full((nk, spec.lanes_backward), w))
        self._wk = {+1: wf, -1: wb}
        # lane edges at the knots, |d| of each lane's inner edge: (nk, n + 1)
        self._ek = {dr: m / 2 + np.concatenate([np.zeros((nk, 1)), np.cumsum(wk, axis=1)], axis=1)
                    for dr, wk in self._wk.items()}
        self._hrk = self._ek[+1][:, -1] + sh   # carriageway extent right (d < 0), per knot
        self._hlk = self._ek[-1][:, -1] + sh
        self.hw_right, self.hw_left = float(self._hrk.max()), float(self._hlk.max())
        self.half_width = max(self.hw_right, self.hw_left)
        self.varying = spec.lane_widths_forward is not None or spec.lane_widths_backward is not None
        # (index, direction, mean centre d)
        self.lanes = [(i, +1, -float(np.mean(self._ek[+1][:, i] + wf[:, i] / 2))) for i in range(spec.lanes_forward)]
        self.lanes += [(i, -1, float(np.mean(self._ek[-1][:, i] + wb[:, i] / 2))) for i in range(spec.lanes_backward)]

    def _interp(self, s, k):
        return np.interp(np.asarray(s, dtype=float), self._sk, k)

    # constant cross-sections (hand-written twins, most map roads) skip the interpolation:
    # these run for every road on every placement query
    def hw_r(self, s):
        """Carriageway extent to the right (> 0) at arc length(s) s."""
        if not self.varying:
            return np.full(np.shape(s), self.hw_right) if np.ndim(s) else self.hw_right
        return self._interp(s, self._hrk)

    def hw_l(self, s):
        if not self.varying:
            return np.full(np.shape(s), self.hw_left) if np.ndim(s) else self.hw_left
        return self._interp(s, self._hlk)

    def lane_d(self, index: int, direction: int, s):
        """Lateral offset of a lane's centre at s (array)."""
        if not self.varying:
            cd = next(c for i, dr, c in self.lanes if i == index and dr == direction)
            return np.full(np.shape(s), cd, dtype=float)
        e = self._ek[direction]
        c = self._interp(s, e[:, index] + self._wk[direction][:, index] / 2)
        return -c if direction > 0 else c

    def lane_edge(self, index: int, direction: int, s):
        """|d| of the outer edge of lane `index` (0: the edge next to the median) at s."""
        return self._interp(s, self._ek[direction][:, index])

    def lane_width(self, index: int, direction: int, s):
        if not self.varying:
            return self.spec.lane_width_m if not np.ndim(s) else np.full(np.shape(s), self.spec.lane_width_m)
        return self._interp(s, self._wk[direction][:, index])

    def height(self, s, d):
        """Road surface height at (s, d)."""
        if not self.relief:
            return np.zeros(np.broadcast(np.asarray(s), np.asarray(d)).shape)
        return self._interp(s, self._zk) + np.asarray(d, float) * self._interp(s, self._tk)

    def carriageway(self, s, d):
        if not self.varying:
            return (s >= 0) & (s <= self.length) & (d >= -self.hw_right) & (d <= self.hw_left)
        return (s >= 0) & (s <= self.length) & (d >= -self.hw_r(s)) & (d <= self.hw_l(s))

    def sidewalk_band(self, s, d):
        sw = self.spec.sidewalk_m
        hr, hl = (self.hw_right, self.hw_left) if not self.varying else (self.hw_r(s), self.hw_l(s))
        inside = (s >= 0) & (s <= self.length)
        return inside & (((d < -hr) & (d >= -hr - sw)) | ((d > hl) & (d <= hl + sw)))

    def lane_index_at(self, d: float, s: float | None = None):
        """(index, direction, centre d) of the lane containing lateral offset d at s, else None."""
        m = self.spec.median_m
        s = self.length / 2 if s is None else s
        if not self.varying:
            w = self.spec.lane_width_m
            if d < -m / 2 or d > m / 2:
                direction = +1 if d < 0 else -1
                i = int((abs(d) - m / 2) // w)
                n = self.spec.lanes_forward if direction > 0 else self.spec.lanes_backward
                if i < n:
                    return i, direction, -direction * (m / 2 + (i + 0.5) * w)
            return None
        if d < -m / 2 or d > m / 2:
            direction = +1 if d < 0 else -1
            edges = np.array([np.interp(s, self._sk, col) for col in self._ek[direction].T])
            i = int(np.searchsorted(edges, abs(d), side="right")) - 1
            n = self.spec.lanes_forward if direction > 0 else self.spec.lanes_backward
            if 0 <= i < n:
                return i, direction, float(self.lane_d(i, direction, s))
        return None

    def tangent_yaw(self, s: float) -> float:
        _, t = self.line.at(s)
        return float(math.atan2(t[0, 1], t[0, 0]))


def _centerline(spec: Road) -> np.ndarray:
    if spec.points is not None:
        pts = np.asarray(spec.points, dtype=float)
        out = [pts[0]]
        for a, b in zip(pts[:-1], pts[1:]):
            n = max(1, int(math.ceil(np.linalg.norm(b - a) / STEP_M)))
            out.extend(a + (b - a) * (k / n) for k in range(1, n + 1))
        return np.array(out)
    p = np.asarray(spec.start, dtype=float)
    yaw = math.radians(spec.heading_deg)
    out = [p.copy()]
    for seg in spec.segments:
        if seg.straight is not None:
            n = max(1, int(math.ceil(seg.straight / STEP_M)))
            d = np.array([math.cos(yaw), math.sin(yaw)])
            out.extend(p + d * seg.straight * k / n for k in range(1, n + 1))
            p = p + d * seg.straight
        else:
            r, ang = seg.arc.radius_m, math.radians(seg.arc.angle_deg)
            sign = 1.0 if ang >= 0 else -1.0
            # centre of the turning circle, left of the heading for a left turn
            c = p + sign * r * np.array([-math.sin(yaw), math.cos(yaw)])
            n = max(2, int(math.ceil(abs(ang) * r / STEP_M)))
            a0 = math.atan2(p[1] - c[1], p[0] - c[0])
            for k in range(1, n + 1):
                a = a0 + ang * k / n
                out.append(c + r * np.array([math.cos(a), math.sin(a)]))
            p = out[-1].copy()
            yaw += ang
    return np.array(out)


@dataclass(frozen=True)
class Structure:
    kind: str           # building | pole | sign | traffic_light | barrier | tree | median_barrier
    polygon: np.ndarray  # convex footprint (Nx2)
    height: float


@dataclass(frozen=True)
class SignalSlot:
    """Where a traffic light may stand at an intersection approach."""

    x: float
    y: float
    yaw: float          # direction the lamps face (toward the approaching traffic)
    intersection: str
    road: str


@dataclass(frozen=True)
class StopLine:
    road: str
    s: float
    d0: float
    d1: float


class Twin:
    """Placement queries over a twin YAML (see module docstring for the frame)."""

    def __init__(self, spec: TwinSpec, path: Path | None = None):
        self.spec = spec
        self.path = path
        self.name = spec.name
        g = spec.georef
        self.georef = Georef(g.lat0, g.lon0, g.alt0, g.proj, g.origin)
        self.roads = {r.id: RoadGeom(r) for r in spec.roads}
        self.crosswalks: list[np.ndarray] = []   # convex polygons
        self.crosswalk_info: list[tuple[str, float, float]] = []  # (road, s0, s1)
        self.stop_lines: list[StopLine] = []
        self.signal_slots: list[SignalSlot] = []
        self._junctions: list[tuple[str, np.ndarray, float]] = []
        self._build_intersections()
        for i, c in enumerate(spec.crosswalks):
            rg = self.roads[c.road]
            if c.s_m > rg.length:
                raise UserError(f"crosswalks[{i}].s_m: {c.s_m} is beyond the end of road {c.road!r} "
                                f"({rg.length:.1f} m)", where=str(path or spec.name))
            self._add_crosswalk(rg, c.s_m - c.width_m / 2, c.s_m + c.width_m / 2)
        self.structures = self._structures()
        self._succ = None  # lane_successors, built on first use
        if self.structures:
            polys = [s.polygon for s in self.structures]
            self._st_center = np.array([p.mean(0) for p in polys])
            self._st_radius = np.array([np.linalg.norm(p - p.mean(0), axis=1).max() for p in polys])
        else:
            self._st_center, self._st_radius = np.zeros((0, 2)), np.zeros(0)

    # ---------------------------------------------------------------- construction
    def _build_intersections(self):
        for k, inter in enumerate(self.spec.intersections):
            c = np.asarray(inter.center, dtype=float)
            members = []
            for rg in self.roads.values():
                s, d, _ = rg.line.project(c)
                if abs(d[0]) < 1.0 and -1.0 <= s[0] <= rg.length + 1.0:
                    members.append((rg, float(np.clip(s[0], 0, rg.length))))
            if len(members) < 2:
                raise UserError(f"intersections[{k}].center: {list(inter.center)} lies on "
                                f"{len(members)} road centre-line(s); an intersection needs two or more",
                                where=str(self.path or self.spec.name))
            self._junctions.append((inter.id, c, max(rg.half_width for rg, _ in members)))
            for rg, s0 in members:
                others = [o for o, _ in members if o is not rg]
                hw_o = max(o.half_width for o in others)
                sw_o = max(o.spec.sidewalk_m for o in others)
                cw = float(np.clip(sw_o, 2.5, 4.0))
                for side in (-1, +1):  # the arm before (-1) and after (+1) the junction
                    s_in, s_out = s0 + side * (hw_o + 0.3), s0 + side * (hw_o + 0.3 + cw)
                    if not (0 <= s_out <= rg.length):
                        continue
                    if inter.crosswalks:
                        self._add_crosswalk(rg, min(s_in, s_out), max(s_in, s_out))
                    s_stop = s0 + side * (hw_o + 0.3 + cw + 0.8)
                    # traffic approaching on this arm: forward lanes on arm -1, backward on +1
                    direction = +1 if side < 0 else -1
                    n_in = rg.spec.lanes_forward if direction > 0 else rg.spec.lanes_backward
                    if n_in == 0:
                        continue
                    m, sh = rg.spec.median_m, rg.spec.shoulder_m
                    if inter.stop_lines and 0 <= s_stop <= rg.length:
                        d_lo, d_hi = ((-rg.hw_right + sh, -m / 2) if direction > 0
                                      else (m / 2, rg.hw_left - sh))
                        self.stop_lines.append(StopLine(rg.id, s_stop, d_lo, d_hi))
                    if inter.signals:
                        yaw_t = rg.tangent_yaw(s0)
                        face = yaw_t + math.pi if direction > 0 else yaw_t
                        d_side = -(rg.hw_right + 0.7) if direction > 0 else rg.hw_left + 0.7
                        for s_sig in (s_stop, s0 - side * (hw_o + 0.7)):  # near and far side
                            if 0 <= s_sig <= rg.length:
                                p = rg.line.offset_point(s_sig, d_side)[0]
                                self.signal_slots.append(SignalSlot(
                                    float(p[0]), float(p[1]), float(math.atan2(math.sin(face), math.cos(face))),
                                    inter.id, rg.id))

    def _add_crosswalk(self, rg: RoadGeom, s0: float, s1: float):
        pts = np.vstack([rg.line.offset_point(s0, -rg.hw_r(s0)), rg.line.offset_point(s1, -rg.hw_r(s1)),
                         rg.line.offset_point(s1, rg.hw_l(s1)), rg.line.offset_point(s0, rg.hw_l(s0))])
        self.crosswalks.append(pts)
        self.crosswalk_info.append((rg.id, s0, s1))

    def _structures(self) -> list[Structure]:
        sp = self.spec
        out = [Structure("building", rect(b.center, b.size[0], b.size[1], math.radians(b.yaw_deg)), b.height_m)
               for b in sp.buildings]
        out += [Structure("pole", rect(p.position, 0.35, 0.35, 0.0), p.height_m) for p in sp.poles]
        out += [Structure("sign", rect(s.position, 0.3, 0.3, 0.0), s.height_m) for s in sp.signs]
        out += [Structure("traffic_light", rect(t.position, 0.5, 0.5, 0.0), t.mount_height_m + 1.0)
                for t in sp.traffic_lights]
        for b in sp.barriers:
            a, e = np.asarray(b.start, float), np.asarray(b.end, float)
            length = float(np.linalg.norm(e - a))
            w = 0.6 if b.kind == "jersey" else 0.4
            out.append(Structure("barrier", rect((a + e) / 2, max(length, 0.1), w,
                                                 math.atan2(*(e - a)[::-1])), b.height_m))
        out += [Structure("tree", rect(t.position, 0.6, 0.6, 0.0), t.height_m) for t in sp.trees]
        # signal poles stand at every signal slot; the planner mounts traffic-light heads on them
        out += [Structure("signal_pole", rect((sl.x, sl.y), 0.3, 0.3, 0.0), SIGNAL_POLE_M) for sl in self.signal_slots]
        for rg in self.roads.values():
            if rg.spec.median_barrier and rg.spec.median_m > 0:
                for s0 in np.arange(0.0, rg.length, 8.0):
                    s1 = min(s0 + 8.0, rg.length)
                    p = rg.line.offset_point([s0, s1], [0.0, 0.0])
                    yaw = math.atan2(*(p[1] - p[0])[::-1])
                    out.append(Structure("median_barrier", rect(p.mean(0), s1 - s0, 0.6, yaw), 0.8))
        return out

    # ---------------------------------------------------------------- queries
    def _roads_containing(self, x: float, y: float):
        hits = []
        for rg in self.roads.values():
            s, d, _ = rg.line.project((x, y))
            hits.append((rg, float(s[0]), float(d[0])))
        return hits

    def lane_at(self, x: float, y: float, heading: float | None = None) -> Lane | None:
        """The lane at (x, y), or None off the lanes (sidewalk, shoulder, median, off-road).

        In a junction the point lies on several roads' lanes; `heading` (rad) picks the
        lane whose direction is closest to it (default: the first road listed)."""
        cands = []
        n_carriage = 0
        for rg, s, d in self._roads_containing(x, y):
            if not rg.carriageway(s, d):
                continue
            n_carriage += 1
            li = rg.lane_index_at(d, s)
            if li is None:
                continue
            i, direction, cd = li
            yaw = rg.tangent_yaw(s) + (0.0 if direction > 0 else math.pi)
            yaw = math.atan2(math.sin(yaw), math.cos(yaw))
            n = rg.spec.lanes_forward if direction > 0 else rg.spec.lanes_backward
            cands.append(Lane(rg.id, i, direction, yaw, float(rg.lane_width(i, direction, s)), s, d, cd, i == n - 1,
                              False, rg.spec.speed_mps))
        if not cands:
            return None
        if heading is not None:
            cands.sort(key=lambda L: abs(math.remainder(L.yaw - heading, 2 * math.pi)))
        lane = cands[0]
        if n_carriage > 1:
            lane = Lane(**{**lane.__dict__, "in_junction": True})
        return lane

    def in_junction(self, x: float, y: float) -> bool:
        return sum(bool(rg.carriageway(s, d)) for rg, s, d in self._roads_containing(x, y)) > 1

    def on_road(self, x: float, y: float) -> bool:
        return any(bool(rg.carriageway(s, d)) for rg, s, d in self._roads_containing(x, y))

    def on_sidewalk(self, x: float, y: float) -> bool:
        hits = self._roads_containing(x, y)
        if any(rg.carriageway(s, d) for rg, s, d in hits):
            return False
        return any(bool(rg.sidewalk_band(s, d)) for rg, s, d in hits)

    # vectorised forms for the planner (M points at once)
    def carriageway_count(self, pts) -> np.ndarray:
        pts = np.atleast_2d(np.asarray(pts, dtype=float))
        n = np.zeros(len(pts), dtype=int)
        for rg in self.roads.values():
            s, d, _ = rg.line.project(pts)
            n += rg.carriageway(s, d)
        return n

    def junction_mask(self, pts) -> np.ndarray:
        """Which points lie in a junction: on a map's junction (connecting) road, or where
        two carriageways overlap (a hand-written intersection)."""
        pts = np.atleast_2d(np.asarray(pts, dtype=float))
        n = np.zeros(len(pts), dtype=int)
        jn = np.zeros(len(pts), dtype=bool)
        for rg in self.roads.values():
            s, d, _ = rg.line.project(pts)
            on = rg.carriageway(s, d)
            n += on
            if rg.spec.junction is not None:
                jn |= on
        return jn | (n > 1)

    def sidewalk_mask(self, pts) -> np.ndarray:
        pts = np.atleast_2d(np.asarray(pts, dtype=float))
        band = np.zeros(len(pts), dtype=bool)
        road = np.zeros(len(pts), dtype=bool)
        for rg in self.roads.values():
            s, d, _ = rg.line.project(pts)
            band |= rg.sidewalk_band(s, d)
            road |= rg.carriageway(s, d)
        return band & ~road

    def ground_heights(self, pts) -> np.ndarray:
        """Vectorised ground_height: the road surface on carriageways (a map's elevation and
        superelevation; the highest where roads overlap), the curb height above the road edge
        on sidewalks, 0 elsewhere."""
        pts = np.atleast_2d(np.asarray(pts, dtype=float))
        z = np.full(len(pts), -np.inf)
        zw = np.full(len(pts), -np.inf)
        relief = self.relief
        z_near, dist = np.zeros(len(pts)), np.full(len(pts), np.inf)
        for rg in self.roads.values():
            s, d, _ = rg.line.project(pts)
            on = rg.carriageway(s, d)
            walk = rg.sidewalk_band(s, d)
            if relief:  # off the roads: the nearest road's edge height (the terrain follows it)
                sc = np.clip(s, 0.0, rg.length)
                dc = np.clip(d, -rg.hw_r(sc), rg.hw_l(sc))
                far = np.hypot(s - sc, d - dc)
                closer = far < dist
                dist, z_near = np.where(closer, far, dist), np.where(closer, rg.height(sc, dc), z_near)
            if not (on.any() or walk.any()):
                continue
            if rg.relief:
                # sidewalks: the curb height above the road's surface extended outward (as built)
                h = rg.height(s, d)
                z = np.where(on, np.maximum(z, h), z)
                zw = np.where(walk, np.maximum(zw, h + rg.spec.curb_height_m), zw)
            else:
                z = np.where(on, np.maximum(z, 0.0), z)
                zw = np.where(walk, np.maximum(zw, rg.spec.curb_height_m), zw)
        return np.where(np.isfinite(z), z, np.where(np.isfinite(zw), zw, z_near))

    @property
    def relief(self) -> bool:
        """Whether any road has elevation or superelevation (else the twin is flat)."""
        if getattr(self, "_relief", None) is None:
            self._relief = any(rg.relief for rg in self.roads.values())
        return self._relief

    def surface_pose(self, xy, yaw, length: float, width: float):
        """(z, pitch, roll) arrays of a wheeled object whose footprint (length x width) is
        centred at xy (n, 2) facing yaw (n,): z the ground at the centre, pitch (> 0 nose up)
        and roll (> 0 left side up) of the plane through the ground under the footprint's
        front, rear, left and right edge midpoints (PlacedObject's rotation convention)."""
        xy = np.atleast_2d(np.asarray(xy, dtype=float))
        yaw = np.broadcast_to(np.asarray(yaw, dtype=float), (len(xy),))
        if not self.relief:
            return self.ground_heights(xy), np.zeros(len(xy)), np.zeros(len(xy))
        h = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
        left = np.stack([-h[:, 1], h[:, 0]], axis=1)
        a, b = length / 2, width / 2
        z = self.ground_heights(np.vstack([xy, xy + a * h, xy - a * h, xy + b * left, xy - b * left]))
        z = z.reshape(5, len(xy))
        g_fwd = (z[1] - z[2]) / length
        g_left = (z[3] - z[4]) / width
        pitch = np.arctan(g_fwd)
        # the body's left axis lies in the plane: tan(roll) = slope to the left * cos(pitch)
        roll = np.arctan(g_left * np.cos(pitch))
        return z[0], pitch, roll

    def crosswalk_mask(self, pts) -> np.ndarray:
        pts = np.atleast_2d(np.asarray(pts, dtype=float))
        m = np.zeros(len(pts), dtype=bool)
        for cw in self.crosswalks:
            m |= point_in_convex(pts, cw)
        return m

    def structures_near(self, center, radius: float) -> list[int]:
        if not len(self.structures):
            return []
        dist = np.linalg.norm(self._st_center - np.asarray(center, float)[:2], axis=1)
        return list(np.nonzero(dist < self._st_radius + radius)[0])

    def on_crosswalk(self, x: float, y: float) -> bool:
        p = np.array([[x, y]])
        return any(bool(point_in_convex(p, cw)[0]) for cw in self.crosswalks)

    def is_free(self, polygon, margin: float = 0.0) -> bool:
        """True when the convex footprint (Nx2) overlaps no structure (building, pole, ...)."""
        poly = np.asarray(polygon, dtype=float)[:, :2]
        if not len(self.structures):
            return True
        c = poly.mean(0)
        r = np.linalg.norm(poly - c, axis=1).max()
        near = np.nonzero(np.linalg.norm(self._st_center - c, axis=1) < self._st_radius + r + margin)[0]
        return not any(convex_overlap(poly, self.structures[i].polygon, margin) for i in near)

    def ground_height(self, x: float, y: float) -> float:
        return float(self.ground_heights([[x, y]])[0])

    # ---------------------------------------------------------------- routes and LUT
    def lane_polyline(self, road: str, index: int, direction: int, s0: float, s1: float,
                      step: float = 1.0) -> np.ndarray:
        """Points along a lane centre from s0 to s1 (road arc length; s1 < s0 for backward)."""
        rg = self.roads[road]
        n = max(2, int(math.ceil(abs(s1 - s0) / step)) + 1)
        s = np.linspace(s0, s1, n)
        return rg.line.offset_point(s, rg.lane_d(index, direction, s))

    def ego_route(self, length_m: float, seed: int) -> np.ndarray:
        """An (N,2) polyline of `length_m` along the centre of one lane, in its direction,
        starting and ending at least 5 m from the road ends (deterministic per seed). On a
        map with junction connecting roads the route turns through a junction."""
        if length_m <= 0:
            raise UserError(f"ego_route: length_m must be > 0 (got {length_m})")
        rng = np.random.default_rng(seed)
        if any(rg.spec.junction is not None for rg in self.roads.values()):
            route = self._turning_route(length_m, rng)  # a map: turn through one of its junctions
            if route is not None:
                return route
        options = [(rg, i, dr) for rg in self.roads.values() for i, dr, _ in rg.lanes
                   if rg.length >= length_m + 10.0]
        if not options:
            longest = max(rg.length for rg in self.roads.values())
            raise UserError(f"ego_route: no road of twin {self.name!r} is long enough for a "
                            f"{length_m:.0f} m route (longest {longest:.0f} m)")
        rg, i, dr = options[rng.integers(len(options))]
        a = float(rng.uniform(5.0, rg.length - 5.0 - length_m))
        s0, s1 = (a, a + length_m) if dr > 0 else (rg.length - a, rg.length - a - length_m)
        return self.lane_polyline(rg.id, i, dr, s0, s1, step=1.0)

    # ---------------------------------------------------------------- lane topology (maps)
    @property
    def lane_successors(self) -> dict:
        """{(road, index, direction): [lanes whose start meets this lane's end]}: where a
        lane goes on through a map's junction (connecting roads). Lanes link when the end
        of one lies within 0.6 m of the start of the other and their headings agree
        within 45 degrees; hand-written twins (crossing roads, no connecting roads) have
        no links."""
        if self._succ is None:
            keys, heads, tails = [], [], []
            for rg in self.roads.values():
                for i, dr, cd in rg.lanes:
                    s0, s1 = (0.0, rg.length) if dr > 0 else (rg.length, 0.0)
                    p = rg.line.offset_point([s0, s1], rg.lane_d(i, dr, [s0, s1]))
                    back = 0.0 if dr > 0 else math.pi
                    keys.append((rg.id, i, dr))
                    heads.append((*p[0], rg.tangent_yaw(s0) + back))
                    tails.append((*p[1], rg.tangent_yaw(s1) + back))
            heads, tails = np.array(heads).reshape(-1, 3), np.array(tails).reshape(-1, 3)
            self._succ = {}
            for a, t in zip(keys, tails):
                near = np.hypot(heads[:, 0] - t[0], heads[:, 1] - t[1]) < 0.6
                agree = np.abs(np.remainder(heads[:, 2] - t[2] + math.pi, 2 * math.pi) - math.pi) < math.pi / 4
                self._succ[a] = [keys[j] for j in np.nonzero(near & agree)[0] if keys[j][0] != a[0]]
        return self._succ

    def lane_chain(self, road: str, index: int, direction: int, s0: float, length_m: float, rng,
                   prefer_turn: bool = False) -> Polyline | None:
        """A lane-centre polyline from (road, s0) onward for `length_m`, continuing through
        successor lanes (a random one at each fork; the sharpest turn if `prefer_turn`).
        None when the lane has no successor (the caller keeps to its road)."""
        key = (road, index, direction)
        if not self.lane_successors.get(key):
            return None
        rg = self.roads[road]
        end = rg.length if direction > 0 else 0.0
        parts, total = [self.lane_polyline(road, index, direction, s0, end, step=0.5)], abs(end - s0)
        while total < length_m:
            nxt = self.lane_successors.get(key, [])
            if not nxt:
                break
            if prefer_turn:
                turn = [abs(self._lane_turn(k)) for k in nxt]
                key = nxt[int(np.argmax(turn))]
            else:
                key = nxt[int(rng.integers(len(nxt)))]
            r2 = self.roads[key[0]]
            a, b = (0.0, r2.length) if key[2] > 0 else (r2.length, 0.0)
            parts.append(self.lane_polyline(key[0], key[1], key[2], a, b, step=0.5)[1:])
            total += r2.length
        return Polyline(np.vstack(parts))

    def _lane_turn(self, key) -> float:
        rg = self.roads[key[0]]
        return math.remainder(rg.tangent_yaw(rg.length) - rg.tangent_yaw(0.0), 2 * math.pi)

    def _turning_route(self, length_m: float, rng) -> np.ndarray | None:
        """A route of `length_m` along a lane that turns through a junction (maps with
        connecting roads); the turn starts about 40% into the route."""
        turns = [k for k in self.lane_successors if self.roads[k[0]].spec.junction is not None
                 and abs(self._lane_turn(k)) > math.radians(45)]
        preds = {k: [a for a, nx in self.lane_successors.items() if k in nx] for k in turns}
        turns = [k for k in turns if preds[k]]
        # prefer junctions with crosswalks: the scenes then have pedestrians crossing
        cw = {self.roads[r].spec.junction for r, _, _ in self.crosswalk_info} - {None}
        turns = [k for k in turns if self.roads[k[0]].spec.junction in cw] or turns
        if not turns:
            return None
        k = turns[int(rng.integers(len(turns)))]
        a = preds[k][int(rng.integers(len(preds[k])))]
        ra = self.roads[a[0]]
        lead = min(0.4 * length_m, ra.length - 5.0)
        if lead <= 0:
            return None
        s0 = ra.length - lead if a[2] > 0 else lead
        chain = self.lane_chain(a[0], a[1], a[2], s0, length_m, rng, prefer_turn=True)
        if chain is None or chain.length < length_m:
            return None
        return chain.at(np.arange(0.0, length_m + 1e-9, 1.0))[0]

    def lut_rows(self, spacing_m: float) -> list[tuple]:
        rows = []
        for rg in self.roads.values():
            s = np.arange(0.0, rg.length + 1e-9, spacing_m)
            _, tan = rg.line.at(s)
            for i, dr, _ in rg.lanes:
                d = rg.lane_d(i, dr, s)
                p = rg.line.offset_point(s, d)
                z = rg.height(s, d)
                lat, lon, alt = self.georef.to_geodetic(p[:, 0], p[:, 1], z)  # vectorised
                yaw = np.arctan2(tan[:, 1], tan[:, 0]) + (0.0 if dr > 0 else math.pi)
                yaw = np.arctan2(np.sin(yaw), np.cos(yaw))
                heading = self.georef.heading_of_yaw(p[:, 0], p[:, 1], yaw)  # true north, not grid north
                for k, (x, y) in enumerate(p):
                    rows.append((float(lat[k]), float(lon[k]), float(alt[k]), float(heading[k]), x, y,
                                 float(z[k]), math.degrees(yaw[k])))
        return rows

    def export_lut(self, path, spacing_m: float = 2.0) -> int:
        """Write the survey LUT (lane centres every `spacing_m`, travel direction) as CSV
        `lat,lon,alt,heading_deg,x,y,z,yaw_deg`; returns the number of rows."""
        if spacing_m <= 0:
            raise UserError(f"export_lut: spacing_m must be > 0 (got {spacing_m})")
        rows = self.lut_rows(spacing_m)
        lines = ["lat,lon,alt,heading_deg,x,y,z,yaw_deg"]
        lines += [f"{a:.9f},{b:.9f},{c:.3f},{h:.3f},{x:.3f},{y:.3f},{z:.3f},{w:.3f}"
                  for a, b, c, h, x, y, z, w in rows]
        atomic.write_text(path, "\n".join(lines) + "\n")
        return len(rows)

    GROUND_MARGIN_M = 40.0

    @property
    def ground_rect(self) -> tuple[float, float, float, float]:
        """(x0, y0, x1, y1) of the terrain: the `ground_m` square about the roads' centre,
        widened where needed to the roads' extent + 40 m (a long map is not cut off)."""
        x0, y0, x1, y1 = self.bounds
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        hx = max(self.spec.ground_m / 2, (x1 - x0) / 2 + self.GROUND_MARGIN_M)
        hy = max(self.spec.ground_m / 2, (y1 - y0) / 2 + self.GROUND_MARGIN_M)
        return cx - hx, cy - hy, cx + hx, cy + hy

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        pts = np.vstack([rg.line.pts for rg in self.roads.values()])
        return (*pts.min(0), *pts.max(0))


def load_twin(path) -> Twin:
    """Load and validate a twin YAML; bad input raises UserError naming the field."""
    path = Path(path)
    if map_format(path):  # a map named directly (`twin: town.xodr`)
        data = map_twin_data(path)
    else:
        data = read_yaml_mapping(path, "twin")
        if not isinstance(data, dict):
            raise UserError("expected a mapping of twin fields at the top level", where=str(path))
        if "source" in data:  # a twin folder from `blendgen twin import`: rebuilt from its map
            src = path.parent / str(data["source"])
            if not map_format(src) or set(data) - {"name", "source"}:
                raise UserError(f"source: expected a map file (.xodr, .osm, .osm.pbf) and only `name` "
                                f"beside it, got {sorted(data)}", where=str(path))
            if not src.is_file():
                raise UserError(f"source: map {src} does not exist", where=str(path))
            data = {**map_twin_data(src), "name": str(data.get("name", src.stem))}
    try:
        spec = TwinSpec.model_validate(data)
    except ValidationError as e:
        msgs = error_lines(e)
        raise UserError("invalid twin:\n  " + "\n  ".join(msgs), where=str(path)) from None
    return Twin(spec, path)
