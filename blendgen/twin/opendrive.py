"""OpenDRIVE (.xodr) HD maps: parse with lxml, evaluate the reference lines and lane
geometry in closed form, and convert the map into a twin (TwinSpec) so that placement,
the planner, the LUT and the Blender builder work on it unchanged.

Why our own reader: see docs/design_decisions.md ("OpenDRIVE reader"). Errors name the
element and its line number (lxml's sourceline).

Frame: the map's own inertial x/y (metres), which for a local transverse-Mercator
geoReference about the map origin is the twin's ENU frame about that origin; for other
projections (UTM, EPSG codes) the map's x/y less an origin in the middle of the map
(`map_georef`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from blendgen.errors import UserError

SAMPLE_M = 0.5        # reference-line sampling for the twin's polylines (chord error < 1 cm at R = 5 m)
DRIVE_KINDS = {"driving", "bidirectional", "entry", "exit", "onRamp", "offRamp", "connectingRamp",
               "slipLane", "bus", "taxi", "HOV"}
EDGE_KINDS = {"shoulder", "parking", "biking", "border", "curb", "restricted", "stop"}
TRAFFIC_LIGHT_TYPES = {"1000001", "1000002", "1000011", "1000013", "1000020"}  # German StVO light codes


class _Src:
    """Where a map element came from, for error messages."""

    def __init__(self, path: Path):
        self.path = str(path)

    def err(self, el, msg: str) -> UserError:
        return UserError(f"line {el.sourceline}: <{el.tag}>: {msg}", where=self.path)

    def num(self, el, name: str, default: float | None = None) -> float:
        v = el.get(name)
        if v is None:
            if default is None:
                raise self.err(el, f"missing attribute {name!r}")
            return default
        try:
            x = float(v)
        except ValueError:
            raise self.err(el, f"attribute {name}={v!r} is not a number") from None
        if not math.isfinite(x):
            raise self.err(el, f"attribute {name}={v!r} is not finite")
        return x


# ------------------------------------------------------------------------ plan view
@dataclass
class Geometry:
    s: float
    x: float
    y: float
    hdg: float
    length: float
    kind: str            # line | arc | spiral | poly3 | paramPoly3
    params: dict = field(default_factory=dict)
    _table: tuple | None = None  # (arc length, u, v) for the polynomial kinds

    def local(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position (x, y) and heading at local arc lengths u in [0, length]."""
        x0, y0, h = self.x, self.y, self.hdg
        k = self.kind
        if k == "arc" and abs(self.params["curvature"]) > 1e-12:
            c = self.params["curvature"]
            th = h + c * u
            return x0 + (np.sin(th) - math.sin(h)) / c, y0 + (math.cos(h) - np.cos(th)) / c, th
        if k == "spiral":
            c0, c1 = self.params["curvStart"], self.params["curvEnd"]
            cd = (c1 - c0) / self.length if self.length > 0 else 0.0
            if abs(cd) > 1e-12:
                return _clothoid(x0, y0, h, c0, cd, u)
            k, c = "arc", c0
            if abs(c) > 1e-12:
                th = h + c * u
                return x0 + (np.sin(th) - math.sin(h)) / c, y0 + (math.cos(h) - np.cos(th)) / c, th
        if k in ("line", "arc", "spiral"):
            return x0 + u * math.cos(h), y0 + u * math.sin(h), np.full_like(u, h)
        # poly3 / paramPoly3: local (uu, vv) by parameter, arc length by dense integration
        s_tab, uu, vv, du, dv = self._poly_table()
        lu, lv = np.interp(u, s_tab, uu), np.interp(u, s_tab, vv)
        th = h + np.arctan2(np.interp(u, s_tab, dv), np.interp(u, s_tab, du))
        ch, sh = math.cos(h), math.sin(h)
        return x0 + lu * ch - lv * sh, y0 + lu * sh + lv * ch, th

    def _poly_table(self):
        if self._table is None:
            p = self.params
            n = max(200, int(self.length * 20))
            if self.kind == "poly3":
                # v(u) over the local u axis; u reaches the end where the arc length does
                t = np.linspace(0.0, self.length * 1.5 + 1.0, n * 2)
                uu, vv = t, p["a"] + p["b"] * t + p["c"] * t ** 2 + p["d"] * t ** 3
                du, dv = np.ones_like(t), p["b"] + 2 * p["c"] * t + 3 * p["d"] * t ** 2
            else:
                pmax = self.length if p["pRange"] == "arcLength" else 1.0
                t = np.linspace(0.0, pmax, n)
                uu = p["aU"] + p["bU"] * t + p["cU"] * t ** 2 + p["dU"] * t ** 3
                vv = p["aV"] + p["bV"] * t + p["cV"] * t ** 2 + p["dV"] * t ** 3
                du = p["bU"] + 2 * p["cU"] * t + 3 * p["dU"] * t ** 2
                dv = p["bV"] + 2 * p["cV"] * t + 3 * p["dV"] * t ** 2
            seg = np.hypot(np.diff(uu), np.diff(vv))
            s_tab = np.concatenate([[0.0], np.cumsum(seg)])
            self._table = (s_tab, uu, vv, du, dv)
        return self._table


def _clothoid(x0, y0, h, c0, cd, u):
    """Euler spiral with curvature c0 + cd*u: heading h + c0 u + cd u^2/2, position by Fresnel integrals."""
    from scipy.special import fresnel

    sig = 1.0 if cd > 0 else -1.0
    a = math.sqrt(math.pi / abs(cd))
    w0 = c0 / cd
    phi0 = h - c0 * c0 / (2 * cd)
    s_a, c_a = fresnel((u + w0) / a)
    s_b, c_b = fresnel(w0 / a)
    dc, ds = c_a - c_b, s_a - s_b
    x = x0 + a * (math.cos(phi0) * dc - sig * math.sin(phi0) * ds)
    y = y0 + a * (math.sin(phi0) * dc + sig * math.cos(phi0) * ds)
    return x, y, h + c0 * u + cd * u * u / 2


def _poly(recs, s):
    """Evaluate piecewise cubic records [(s0, a, b, c, d)] at s (array); 0 where none."""
    s = np.asarray(s, dtype=float)
    if not recs:
        return np.zeros_like(s)
    starts = np.array([r[0] for r in recs])
    i = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(recs) - 1)
    co = np.array([r[1:] for r in recs])[i]
    ds = s - starts[i]
    return co[:, 0] + co[:, 1] * ds + co[:, 2] * ds ** 2 + co[:, 3] * ds ** 3


# ------------------------------------------------------------------------ lanes, roads
@dataclass
class OdrLane:
    id: int
    kind: str
    widths: list            # [(sOffset, a, b, c, d)] relative to the section start
    mark: str = "none"      # the lane's outer road mark type
    line: int = 0
    border: list = field(default_factory=list)  # <border> records (outer border |t|) when no <width>


@dataclass
class LaneSection:
    s0: float
    s1: float
    left: list              # lanes 1, 2, ... outward
    right: list             # lanes -1, -2, ... outward
    center_mark: str = "none"


@dataclass
class OdrSignal:
    s: float
    t: float
    kind: str               # traffic_light | stop | yield | speed | info
    orientation: str        # + | - | none
    z_offset: float
    h_offset: float


@dataclass
class OdrObject:
    kind: str
    s: float
    t: float
    length: float
    width: float
    height: float
    hdg: float
    corners_st: list        # outline cornerRoad (s, t) points, if any


@dataclass
class OdrRoad:
    id: str
    name: str
    length: float
    junction: str           # "-1" outside junctions
    geoms: list
    lane_offset: list
    elevation: list
    superelevation: list
    sections: list
    signals: list
    objects: list
    predecessor: tuple | None
    successor: tuple | None
    speed_mps: float | None
    line: int

    def ref(self, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Reference line (x, y, heading) at road arc lengths s."""
        s = np.clip(np.atleast_1d(np.asarray(s, dtype=float)), 0.0, self.length)
        starts = np.array([g.s for g in self.geoms])
        gi = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(self.geoms) - 1)
        x, y, th = np.empty_like(s), np.empty_like(s), np.empty_like(s)
        for k in np.unique(gi):
            m = gi == k
            g = self.geoms[k]
            x[m], y[m], th[m] = g.local(np.clip(s[m] - g.s, 0.0, g.length))
        return x, y, th

    def point(self, s, t) -> np.ndarray:
        """Inertial (x, y) of road coordinates (s, t); t > 0 to the left. With
        superelevation the cross-section is rolled: t runs along the tilted surface, so its
        plan-view offset is t cos(theta) (OpenDRIVE 1.6, 10.5.1)."""
        x, y, th = self.ref(s)
        t = np.asarray(t, dtype=float) * np.cos(self.theta(s))
        return np.stack([x - t * np.sin(th), y + t * np.cos(th)], axis=-1)

    def z(self, s, t=0.0) -> np.ndarray:
        """Surface height at (s, t): the elevation profile plus t sin(superelevation)."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        return _poly(self.elevation, s) + np.asarray(t, dtype=float) * np.sin(self.theta(s))

    def theta(self, s) -> np.ndarray:
        """Superelevation (roll of the cross-section about the reference line, rad; > 0
        falls to the right) at s."""
        return _poly(self.superelevation, np.atleast_1d(np.asarray(s, dtype=float)))

    @property
    def relief(self) -> bool:
        return any(any(r[1:]) for r in self.elevation + self.superelevation)

    def lane_center_t(self, sec: LaneSection, lane_id: int, s) -> np.ndarray:
        """Lateral offset t of a lane's centre at s within its section."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        side = sec.left if lane_id > 0 else sec.right
        w = side_widths(side, s - sec.s0)
        k = abs(lane_id) - 1
        sign = 1.0 if lane_id > 0 else -1.0
        return _poly(self.lane_offset, s) + sign * (w[:k].sum(0) + w[k] / 2)


@dataclass
class OdrJunction:
    id: str
    connections: list       # (incoming road, connecting road, contactPoint)


@dataclass
class OdrMap:
    path: Path
    name: str
    proj: str | None
    roads: dict
    junctions: dict


# ------------------------------------------------------------------------ parsing
def read_opendrive(path) -> OdrMap:
    """Parse an .xodr file; malformed input raises UserError naming the element and line."""
    from lxml import etree

    path = Path(path)
    src = _Src(path)
    if not path.is_file():
        raise UserError("no such OpenDRIVE file", where=str(path))
    try:
        root = etree.parse(str(path), etree.XMLParser(remove_comments=True, huge_tree=True)).getroot()
    except etree.XMLSyntaxError as e:
        line = e.position[0] if e.position else "?"
        raise UserError(f"line {line}: broken XML: {e.msg}", where=str(path)) from None
    if root.tag != "OpenDRIVE":
        raise src.err(root, "the root element is not <OpenDRIVE>")
    header = root.find("header")
    name = (header.get("name") if header is not None else None) or path.stem
    proj = None
    geo = header.find("geoReference") if header is not None else None
    if geo is not None and (geo.text or "").strip():
        proj = geo.text.strip()
        _check_proj(src, geo, proj)
    roads = {}
    for el in root.findall("road"):
        r = _road(src, el)
        if r.id in roads:
            raise src.err(el, f"duplicate road id {r.id!r}")
        roads[r.id] = r
    if not roads:
        raise src.err(root, "the map has no <road>")
    junctions = {}
    for el in root.findall("junction"):
        conns = []
        for c in el.findall("connection"):
            inc, con = c.get("incomingRoad"), c.get("connectingRoad")
            for ref in (inc, con):
                if ref not in roads:
                    raise src.err(c, f"references unknown road {ref!r}")
            conns.append((inc, con, c.get("contactPoint", "start")))
        junctions[el.get("id")] = OdrJunction(el.get("id"), conns)
    return OdrMap(path, name, proj, roads, junctions)


def _check_proj(src: _Src, el, proj: str):
    import pyproj

    try:
        crs = pyproj.CRS.from_user_input(proj)
    except pyproj.exceptions.CRSError as e:
        raise src.err(el, f"PROJ cannot parse the geoReference {proj!r}: {e}") from None
    if not crs.is_projected:
        raise src.err(el, f"the geoReference {proj!r} is not a projected CRS (the map's x/y are metres)")


def _records(src, els, s_name="s"):
    return sorted((src.num(e, s_name), src.num(e, "a"), src.num(e, "b", 0.0), src.num(e, "c", 0.0),
                   src.num(e, "d", 0.0)) for e in els)


def _road(src: _Src, el) -> OdrRoad:
    rid = el.get("id")
    if rid is None:
        raise src.err(el, "missing attribute 'id'")
    length = src.num(el, "length")
    pv = el.find("planView")
    geoms = [] if pv is None else [_geometry(src, g) for g in pv.findall("geometry")]
    if not geoms:
        raise src.err(el, f"road {rid!r} has no <planView><geometry>")
    geoms.sort(key=lambda g: g.s)
    lanes = el.find("lanes")
    secs_el = [] if lanes is None else lanes.findall("laneSection")
    if not secs_el:
        raise src.err(el, f"road {rid!r} has no <lanes><laneSection>")
    lane_offset = [] if lanes is None else _records(src, lanes.findall("laneOffset"))
    starts = [src.num(s, "s") for s in secs_el]
    sections = []
    for k, (sel, s0) in enumerate(zip(secs_el, starts)):
        s1 = starts[k + 1] if k + 1 < len(starts) else length
        sections.append(_section(src, sel, s0, s1, rid))
    ep, lp = el.find("elevationProfile"), el.find("lateralProfile")
    elevation = [] if ep is None else _records(src, ep.findall("elevation"))
    supere = [] if lp is None else _records(src, lp.findall("superelevation"))
    speed = None
    for t in el.findall("type"):
        sp = t.find("speed")
        if sp is not None and sp.get("max") not in (None, "no limit", "undefined"):
            unit = sp.get("unit", "m/s")
            speed = src.num(sp, "max") * {"km/h": 1 / 3.6, "mph": 0.44704}.get(unit, 1.0)
    link = el.find("link")

    def _lk(tag):
        e = None if link is None else link.find(tag)
        return None if e is None else (e.get("elementType", "road"), e.get("elementId"),
                                       e.get("contactPoint"))

    signals = []
    for sg in el.findall("signals/signal"):
        typ = sg.get("type", "")
        dyn = sg.get("dynamic", "no") == "yes"
        kind = ("traffic_light" if dyn or typ in TRAFFIC_LIGHT_TYPES else
                {"206": "stop", "205": "yield", "274": "speed"}.get(typ, "info"))
        signals.append(OdrSignal(src.num(sg, "s"), src.num(sg, "t"), kind, sg.get("orientation", "+"),
                                 src.num(sg, "zOffset", 0.0), src.num(sg, "hOffset", 0.0)))
    objects = []
    for ob in el.findall("objects/object"):
        corners = [(src.num(c, "s"), src.num(c, "t")) for c in ob.findall("outlines/outline/cornerRoad")]
        corners += [(src.num(c, "s"), src.num(c, "t")) for c in ob.findall("outline/cornerRoad")]
        objects.append(OdrObject((ob.get("type") or ob.get("name") or "none").lower(), src.num(ob, "s"),
                                 src.num(ob, "t"), src.num(ob, "length", 0.0), src.num(ob, "width", 0.0),
                                 src.num(ob, "height", 0.0), src.num(ob, "hdg", 0.0), corners))
    return OdrRoad(rid, el.get("name", ""), length, el.get("junction", "-1"), geoms, lane_offset, elevation,
                   supere, sections, signals, objects, _lk("predecessor"), _lk("successor"), speed,
                   el.sourceline)


def _geometry(src: _Src, g) -> Geometry:
    s, x, y, h, L = (src.num(g, a) for a in ("s", "x", "y", "hdg", "length"))
    kids = [c for c in g if isinstance(c.tag, str)]
    if not kids:
        raise src.err(g, "no geometry record inside (expected line, arc, spiral, poly3 or paramPoly3)")
    c = kids[0]
    if c.tag == "line":
        return Geometry(s, x, y, h, L, "line")
    if c.tag == "arc":
        return Geometry(s, x, y, h, L, "arc", {"curvature": src.num(c, "curvature")})
    if c.tag == "spiral":
        return Geometry(s, x, y, h, L, "spiral", {"curvStart": src.num(c, "curvStart"),
                                                  "curvEnd": src.num(c, "curvEnd")})
    if c.tag == "poly3":
        return Geometry(s, x, y, h, L, "poly3", {k: src.num(c, k) for k in "abcd"})
    if c.tag == "paramPoly3":
        p = {k: src.num(c, k) for k in ("aU", "bU", "cU", "dU", "aV", "bV", "cV", "dV")}
        p["pRange"] = c.get("pRange", "normalized")
        if p["pRange"] not in ("normalized", "arcLength"):
            raise src.err(c, f"pRange={p['pRange']!r}; expected 'normalized' or 'arcLength'")
        return Geometry(s, x, y, h, L, "paramPoly3", p)
    raise src.err(c, f"unknown geometry {c.tag!r}; expected line, arc, spiral, poly3 or paramPoly3")


def _section(src: _Src, sel, s0, s1, rid) -> LaneSection:
    def side(tag, sign):
        out = []
        el = sel.find(tag)
        for ln in ([] if el is None else el.findall("lane")):
            lid = int(src.num(ln, "id"))
            if lid * sign <= 0:
                raise src.err(ln, f"lane id {lid} does not belong in <{tag}>")
            widths = _records(src, ln.findall("width"), "sOffset")
            border = [] if widths else _records(src, ln.findall("border"), "sOffset")
            if not widths and not border:
                raise src.err(ln, f"lane {lid} has no <width> or <border>")
            marks = ln.findall("roadMark")
            out.append(OdrLane(lid, ln.get("type", "none"), widths,
                               marks[0].get("type", "none") if marks else "none", ln.sourceline, border))
        out.sort(key=lambda L: abs(L.id))
        if [abs(L.id) for L in out] != list(range(1, len(out) + 1)):
            raise src.err(el, f"lane ids in <{tag}> are not 1..{len(out)} consecutive")
        return out

    left, right = side("left", +1), side("right", -1)
    if not left and not right:
        raise src.err(sel, f"road {rid!r}: laneSection at s={s0} has no lanes")
    cm = sel.find("center/lane/roadMark")
    return LaneSection(s0, s1, left, right, "none" if cm is None else cm.get("type", "none"))


# ------------------------------------------------------------------------ to a twin
_CENTER_MARKS = {"solid": "solid", "broken": "dashed", "solid solid": "double", "broken broken": "double",
                 "solid broken": "double", "broken solid": "double"}


def map_georef(odr: OdrMap) -> dict:
    """The twin's georef for the map's geoReference.

    A local projection about the map origin (the shared maps' +proj=tmerc +lat_0 +lon_0
    +x_0=0 +y_0=0) makes the map's x/y the ENU frame about the origin's lat/lon: georef
    (lat0, lon0). Any other projected CRS (UTM with its false easting, an EPSG code, a
    tmerc about another point) keeps the map's x/y but moves the origin to the middle of
    the map (Blender's single-precision vertices need coordinates near 0): the geometry is
    shifted by `origin` here, and GNSS fixes map through pyproj (Georef.proj)."""
    if odr.proj is None:
        return {"lat0": 0.0, "lon0": 0.0, "alt0": 0.0}
    import pymap3d
    import pyproj

    crs = pyproj.CRS.from_user_input(odr.proj)  # parsed and checked by _check_proj
    tr = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    pts = np.array([[g.x, g.y] for r in odr.roads.values() for g in r.geoms])
    lon0, lat0 = tr.transform(0.0, 0.0)
    if math.isfinite(lat0) and math.isfinite(lon0):
        far = pts[np.argmax(np.linalg.norm(pts, axis=1))]
        lon, lat = tr.transform(far[0], far[1])
        e, n, _ = pymap3d.geodetic2enu(lat, lon, 0.0, lat0, lon0, 0.0)
        err = math.hypot(e - far[0], n - far[1])
        if err <= 0.05 + 1e-4 * float(np.linalg.norm(far)):  # local about the origin: ENU
            return {"lat0": float(lat0), "lon0": float(lon0), "alt0": 0.0}
    origin = np.round((pts.min(0) + pts.max(0)) / 2)
    lon0, lat0 = tr.transform(*origin)
    if not (math.isfinite(lat0) and math.isfinite(lon0)):
        raise UserError(f"geoReference {odr.proj!r} does not map the map's centre {origin.tolist()} to a "
                        "latitude/longitude", where=str(odr.path))
    for r in odr.roads.values():
        for g in r.geoms:
            g.x, g.y = g.x - origin[0], g.y - origin[1]
    return {"lat0": float(lat0), "lon0": float(lon0), "alt0": 0.0, "proj": odr.proj,
            "origin": [float(origin[0]), float(origin[1])]}


def side_widths(side: list, ds) -> np.ndarray:
    """(lanes, len(ds)) widths of one side's lanes (inner first) at section offsets ds.
    A lane with <width> records adds its width to the inner edge; one with only <border>
    records gives its outer edge |t| directly, so its width is that minus the inner edge
    (OpenDRIVE 1.6, 9.5.2: width takes precedence where both are given)."""
    ds = np.atleast_1d(np.asarray(ds, dtype=float))
    out, inner = [], np.zeros_like(ds)
    for ln in side:
        if ln.widths:
            w = _poly(ln.widths, ds)
        else:
            w = np.abs(_poly(ln.border, ds)) - inner
        w = np.maximum(w, 0.0)
        out.append(w)
        inner = inner + w
    return np.array(out).reshape(len(side), len(ds))


def _cross_section(side: list, w: np.ndarray):
    """(driving lanes, their widths (n, samples), edge width, sidewalk width) on one side,
    from the side's lane widths `w` (lanes, samples)."""
    n, widths, edge, walk = 0, [], 0.0, 0.0
    for ln, wl in zip(side, w):
        if ln.kind in DRIVE_KINDS and n == len(widths) and edge == 0.0:
            n += 1
            widths.append(wl)
        elif ln.kind in ("sidewalk", "walking"):
            walk += float(wl.max())
        elif ln.kind in EDGE_KINDS or ln.kind in DRIVE_KINDS:
            edge += float(wl.max())
    return n, np.array(widths).reshape(n, w.shape[1]), edge, walk


def _widths_along(wf: np.ndarray, wb: np.ndarray) -> dict:
    """The twin's per-point lane widths when they are not one constant (1 mm)."""
    w = np.vstack([wf, wb])
    if w.size == 0 or np.ptp(w) < 1e-3:
        return {}
    return {"lane_widths_forward": np.round(wf.T, 4).tolist(), "lane_widths_backward": np.round(wb.T, 4).tolist()}


def twin_data(odr: OdrMap) -> dict:
    """The map as twin fields (TwinSpec data): each lane section becomes a road whose
    centre-line is the reference line shifted by the lane offset, sampled every SAMPLE_M."""
    from blendgen.geom2d import Polyline

    georef = map_georef(odr)
    roads, lines, where = [], {}, {}
    for r in odr.roads.values():
        for k, sec in enumerate(r.sections):
            if sec.s1 - sec.s0 < 0.05:
                continue
            s = np.linspace(sec.s0, sec.s1, max(2, int(math.ceil((sec.s1 - sec.s0) / SAMPLE_M)) + 1))
            # lane widths along s, in plan view (a superelevated cross-section is foreshortened)
            cos_t = np.cos(r.theta(s))
            nf, wf, ef, sf = _cross_section(sec.right, side_widths(sec.right, s - sec.s0) * cos_t)
            nb, wb, eb, sb = _cross_section(sec.left, side_widths(sec.left, s - sec.s0) * cos_t)
            if nf + nb == 0:
                continue
            loff = _poly(r.lane_offset, s)
            pts = r.point(s, loff)
            rid = r.id if len(r.sections) == 1 else f"{r.id}.{k}"
            in_junction = r.junction != "-1"
            relief = {}
            if r.relief:  # the twin's centre-line (reference line + lane offset) carries the relief
                relief = {"z": np.round(r.z(s, loff), 4).tolist(),
                          "superelevation_deg": np.round(np.degrees(r.theta(s)), 5).tolist()}
            roads.append({**relief,
                "id": rid, "points": [[round(float(x), 4), round(float(y), 4)] for x, y in pts],
                "lanes_forward": nf, "lanes_backward": nb,
                "lane_width_m": float(np.clip(np.mean(np.vstack([wf, wb])), 2.0, 6.0)),
                **_widths_along(wf, wb),
                "shoulder_m": round(max(ef, eb), 3), "sidewalk_m": round(max(sf, sb), 3),
                "center_line": "none" if in_junction else _CENTER_MARKS.get(sec.center_mark, "none"),
                "speed_mps": float(np.clip(r.speed_mps or (8.3 if in_junction else 13.9), 1.0, 45.0)),
                "junction": r.junction if in_junction else None,
            })
            lines[rid] = Polyline(pts)
            where.setdefault(r.id, []).append((sec.s0, sec.s1, rid))
    if not roads:
        raise UserError("the map has no road with a driving lane", where=str(odr.path))

    def twin_road(r: OdrRoad, s: float):
        for s0, s1, rid in where.get(r.id, []):
            if s0 - 1e-6 <= s <= s1 + 1e-6:
                return rid
        return None

    data = {"name": odr.name, "georef": georef, "roads": roads,
            "crosswalks": [], "traffic_lights": [], "signs": [], "poles": [], "buildings": []}
    for r in odr.roads.values():
        for o in r.objects:
            if o.kind == "crosswalk":
                ss = [c[0] for c in o.corners_st] or [o.s - o.length / 2, o.s + o.length / 2]
                sm = (min(ss) + max(ss)) / 2
                rid = twin_road(r, sm)
                if rid is None:
                    continue
                c = r.point(sm, _poly(r.lane_offset, [sm]))[0]
                s_tw = float(np.clip(lines[rid].project(c)[0][0], 0.0, lines[rid].length))
                if any(cw["road"] == rid and abs(cw["s_m"] - s_tw) < 0.5 for cw in data["crosswalks"]):
                    continue  # one twin crosswalk spans the whole carriageway
                data["crosswalks"].append({"road": rid, "s_m": round(s_tw, 3),
                                           "width_m": float(np.clip(max(ss) - min(ss), 0.6, 10.0))})
            elif o.kind in ("pole", "streetlamp", "street_lamp"):
                p = r.point(o.s, o.t)[0]
                data["poles"].append({"position": p.round(3).tolist(),
                                      "height_m": float(np.clip(o.height or 7.0, 0.6, 30.0))})
            elif o.kind == "building" and o.length > 0 and o.width > 0:
                p = r.point(o.s, o.t)[0]
                yaw = float(r.ref(o.s)[2][0]) + o.hdg
                data["buildings"].append({"center": p.round(3).tolist(), "size": [o.length, o.width],
                                          "yaw_deg": math.degrees(yaw),
                                          "height_m": float(np.clip(o.height or 12.0, 2.1, 300.0))})
        for sg in r.signals:
            p = r.point(sg.s, sg.t)[0]
            yaw = float(r.ref(sg.s)[2][0]) + sg.h_offset + (math.pi if sg.orientation != "-" else 0.0)
            yaw_deg = math.degrees(math.atan2(math.sin(yaw), math.cos(yaw)))
            if sg.kind == "traffic_light":
                data["traffic_lights"].append({"position": p.round(3).tolist(), "yaw_deg": yaw_deg,
                                               "mount_height_m": float(np.clip(sg.z_offset or 2.6, 1.6, 8.0))})
            else:
                data["signs"].append({"position": p.round(3).tolist(), "yaw_deg": yaw_deg, "kind": sg.kind,
                                      "height_m": float(np.clip(sg.z_offset or 2.4, 0.6, 8.0))})
    allp = np.vstack([np.asarray(rd["points"]) for rd in roads])
    # the terrain square is centred on the roads (Twin.ground_rect): their extent + 40 m each side
    data["ground_m"] = float(np.clip(np.ptp(allp, axis=0).max() + 80.0, 10.0, 20000.0))
    return data
