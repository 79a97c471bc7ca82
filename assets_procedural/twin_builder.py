"""Blender geometry for a twin (bpy): roads with lanes and markings, sidewalks with curbs,
crosswalks and stop lines, buildings with windows, poles, signs, traffic lights, barriers
and trees, each with a procedural PBR material and the custom property `blendgen_role`
in {road, marking, sidewalk, structure, vegetation}. The terrain around the roads is role
`road` (a ground surface; `blendgen_kind = "terrain"`).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

import bpy

from assets_procedural import materials as M
from assets_procedural.meshkit import MeshBuilder, box, cylinder, ellipsoid, rot_z, tube, xf
from assets_procedural.shapes import LAMP_COLORS, build_shape, traffic_light_pole
from blendgen.scene.catalog import sample_variant
from blendgen.twin.model import SIGNAL_POLE_M, RoadGeom, Twin, load_twin

MARK_Z = 0.006   # markings float this far above the asphalt
STEP = 1.0


class _Scene:
    def __init__(self, twin: Twin, collection):
        self.twin = twin
        self.coll = collection
        self.objects: list = []

    def emit(self, name: str, mb: MeshBuilder, mats: dict, role: str, **props):
        if not mb.verts:
            return None
        me = mb.to_mesh(name, mats)
        ob = bpy.data.objects.new(name, me)
        ob["blendgen_role"] = role
        for k, v in props.items():
            ob[k] = v
        self.coll.objects.link(ob)
        self.objects.append(ob)
        return ob


def _sweep(mb, rg: RoadGeom, s: np.ndarray, profile, material, z0=0.0):
    """Sweep an open (d, z) profile along the road centre-line over arc lengths `s`; d may
    be a function of s (a map's lane widths vary along the road), z is above the road
    surface (a map's elevation and superelevation)."""
    n, m = len(s), len(profile)
    if n < 2:
        return
    rings = []
    for d, z in profile:
        d = np.broadcast_to(np.asarray(d(s) if callable(d) else d, dtype=float), (n,))
        surface = rg.height(s, d) if rg.relief else 0.0
        rings.append(np.column_stack([rg.line.offset_point(s, d), np.broadcast_to(surface + z + z0, (n,))]))
    v = np.stack(rings, axis=1).reshape(-1, 3)  # index = i*m + j
    f = [[i * m + j, (i + 1) * m + j, (i + 1) * m + j + 1, i * m + j + 1] for i in range(n - 1) for j in range(m - 1)]
    mb.add(v, f, material)


def _runs(mask: np.ndarray):
    """(start, end) index pairs of consecutive True runs."""
    out, start = [], None
    for i, ok in enumerate(mask):
        if ok and start is None:
            start = i
        if not ok and start is not None:
            out.append((start, i - 1))
            start = None
    if start is not None:
        out.append((start, len(mask) - 1))
    return out


def _refine(valid, a: float, b: float) -> float:
    """Bisect the boundary between s=a (valid) and s=b (invalid)."""
    for _ in range(10):
        c = (a + b) / 2
        if valid(c):
            a = c
        else:
            b = c
    return a


def _one(valid):
    """valid(s) for a single s from the vectorised form."""
    return lambda x: bool(valid(np.array([x]))[0])


def _valid_spans(rg: RoadGeom, valid, s_lo=0.0, s_hi=None, step=STEP):
    """Arc-length spans [s0, s1] where valid(s) holds, with exact ends."""
    s_hi = rg.length if s_hi is None else s_hi
    s = np.linspace(s_lo, s_hi, max(2, int(math.ceil((s_hi - s_lo) / step)) + 1))
    mask = np.asarray(valid(s), dtype=bool)  # `valid` takes an array of s
    spans = []
    for i0, i1 in _runs(mask):
        a = s[i0] if i0 == 0 else _refine(_one(valid), s[i0], s[i0 - 1])
        b = s[i1] if i1 == len(s) - 1 else _refine(_one(valid), s[i1], s[i1 + 1])
        if b - a > 0.05:
            spans.append((a, b))
    return spans


def _samples(a, b, step=STEP):
    return np.linspace(a, b, max(2, int(math.ceil((b - a) / step)) + 1))


def _other_carriageway(twin: Twin, rg: RoadGeom):
    # only roads whose extent overlaps this one's (maps have dozens of roads)
    lo, hi = rg.line.pts.min(0) - rg.half_width - 1, rg.line.pts.max(0) + rg.half_width + 1
    others = [o for o in twin.roads.values() if o is not rg
              and np.all(o.line.pts.min(0) - o.half_width <= hi) and np.all(o.line.pts.max(0) + o.half_width >= lo)]

    def inside(pts) -> np.ndarray:
        """Which of the points (Mx2) lie on another road's carriageway."""
        pts = np.atleast_2d(pts)
        hit = np.zeros(len(pts), dtype=bool)
        for o in others:
            s, d, _ = o.line.project(pts)
            hit |= o.carriageway(s, d)
        return hit
    return inside


def _lift(tw: Twin, mb, k: int, x: float, y: float):
    """Raise the parts added to `mb` since its k-th onto the ground at (x, y) on a twin with
    relief (a map's elevation); flat twins keep their furniture at z = 0."""
    if tw.relief:
        z0 = tw.ground_height(x, y)
        for v in mb.verts[k:]:
            v[:, 2] += z0


def _road_z(k: int) -> float:
    """Later roads sit a hair higher: no z-fighting in junctions (at most 1.7 cm with many roads)."""
    return 0.0015 * (k % 12)


def _top_z(tw: Twin, pt) -> float:
    """Offset of the highest road surface at `pt`: paint there must lie above it, never
    level with another road's asphalt (coplanar faces render black in Cycles)."""
    return max([_road_z(k) for k, o in enumerate(tw.roads.values()) if o.carriageway(*o.line.project(pt)[:2])[0]]
               or [0.0])


def _roads(sc: _Scene, mats_spec):
    tw = sc.twin
    a_spec = mats_spec.get("asphalt")
    asphalt = M.asphalt(*(x for x in ((a_spec.color if a_spec and a_spec.color else (0.05, 0.05, 0.052)),
                                      (a_spec.roughness if a_spec and a_spec.roughness is not None else 0.85),
                                      (a_spec.wear if a_spec and a_spec.wear is not None else 0.5))))
    side_mat = M.concrete((0.52, 0.51, 0.49), tiles=True, name="sidewalk")
    curb_mat = M.concrete((0.62, 0.61, 0.58), tiles=False, name="curb")
    paint = M.road_paint()
    marks = MeshBuilder()
    for k, rg in enumerate(tw.roads.values()):
        zr = _road_z(k)
        mb = MeshBuilder()
        _sweep(mb, rg, _samples(0, rg.length), [(lambda s, rg=rg: -rg.hw_r(s), 0.0), (rg.hw_l, 0.0)], "asphalt", zr)
        sc.emit(f"road_{rg.id}", mb, {"asphalt": asphalt}, "road")
        in_other = _other_carriageway(tw, rg)
        sp = rg.spec
        # sidewalks with curbs, cut where another road crosses
        if sp.sidewalk_m > 0:
            mb = MeshBuilder()
            for side in (-1, 1):
                hw = rg.hw_r if side < 0 else rg.hw_l

                def ok(s, hw=hw, side=side):
                    return ~in_other(rg.line.offset_point(s, side * (hw(s) + sp.sidewalk_m / 2)))
                for a, b in _valid_spans(rg, ok):
                    s = _samples(a, b)
                    edge = side * hw(s)
                    outer = edge + side * sp.sidewalk_m
                    ch = sp.curb_height_m + zr
                    _sweep(mb, rg, s, [(edge, 0.0), (edge, ch)], "curb")
                    _sweep(mb, rg, s, [(edge, ch), (edge + side * 0.15, ch)], "curb")
                    _sweep(mb, rg, s, [(edge + side * 0.15, ch), (outer, ch)], "sidewalk")
                    _sweep(mb, rg, s, [(outer, ch), (outer, 0.0)], "curb")
            sc.emit(f"sidewalk_{rg.id}", mb, {"sidewalk": side_mat, "curb": curb_mat}, "sidewalk")
        # lane markings: skip junctions and crosswalks
        on_cw = [(s0, s1) for r, s0, s1 in tw.crosswalk_info if r == rg.id]

        def free(s, d):
            on = np.zeros(len(s), dtype=bool)
            for s0, s1 in on_cw:
                on |= (s >= s0 - 0.3) & (s <= s1 + 0.3)
            return ~on & ~in_other(rg.line.offset_point(s, d(s)))

        def const(v):
            return lambda s: np.full(np.shape(s), v, dtype=float)

        lines = []  # (d as a function of s: lane widths may vary along a map's road, width, dashed)
        m = sp.median_m
        if sp.lanes_forward and sp.lanes_backward and m == 0 and sp.center_line != "none":
            if sp.center_line == "double":
                lines += [(const(-0.1), 0.12, False), (const(0.1), 0.12, False)]
            else:
                lines.append((const(0.0), 0.12, sp.center_line == "dashed"))
        if m > 0:
            lines += [(const(-m / 2 - 0.1), 0.15, False), (const(m / 2 + 0.1), 0.15, False)]
        for i in range(1, sp.lanes_forward):
            lines.append((lambda s, i=i: -rg.lane_edge(i, +1, s), 0.15, True))
        for i in range(1, sp.lanes_backward):
            lines.append((lambda s, i=i: rg.lane_edge(i, -1, s), 0.15, True))
        if sp.shoulder_m >= 0.2:
            lines += [(lambda s: -(rg.hw_r(s) - sp.shoulder_m) - 0.08, 0.15, False),
                      (lambda s: rg.hw_l(s) - sp.shoulder_m + 0.08, 0.15, False)]
        dash, gap = (6.0, 12.0) if sp.speed_mps > 22 else (3.0, 6.0)
        for d, wd, dashed in lines:
            for a, b in _valid_spans(rg, lambda s, d=d: free(s, d), step=0.5):
                pieces = [(a, b)]
                if dashed:
                    starts = np.arange(math.ceil(a / (dash + gap)) * (dash + gap), b, dash + gap)
                    pieces = [(x, min(x + dash, b)) for x in starts if min(x + dash, b) - x > 0.3]
                for x0, x1 in pieces:
                    _sweep(marks, rg, _samples(x0, x1), [(lambda s, d=d: d(s) - wd / 2, MARK_Z),
                                                         (lambda s, d=d: d(s) + wd / 2, MARK_Z)], "paint", zr)
    # stop lines and zebra crossings
    for sl in tw.stop_lines:
        rg = tw.roads[sl.road]
        _sweep(marks, rg, np.array([sl.s - 0.2, sl.s + 0.2]), [(sl.d0, MARK_Z), (sl.d1, MARK_Z)], "paint",
               _top_z(tw, rg.line.offset_point(sl.s, (sl.d0 + sl.d1) / 2)))
    for road, s0, s1 in tw.crosswalk_info:
        rg = tw.roads[road]
        zr = _top_z(tw, rg.line.offset_point((s0 + s1) / 2, 0.0))
        sm = (s0 + s1) / 2
        for d in np.arange(-float(rg.hw_r(sm)) + 0.4, float(rg.hw_l(sm)) - 0.6, 1.0):
            _sweep(marks, rg, _samples(s0 + 0.2, s1 - 0.2, 0.5), [(d, MARK_Z), (d + 0.5, MARK_Z)], "paint", zr)
    sc.emit("markings", marks, {"paint": paint}, "marking")


def _ground(sc: _Scene, mats_spec):
    tw = sc.twin
    x0, y0, x1, y1 = tw.ground_rect
    spec = mats_spec.get("ground")
    mb = MeshBuilder()
    if tw.relief:  # a grid whose heights follow the nearest road (a little below its surface)
        step = max(5.0, max(x1 - x0, y1 - y0) / 250)
        xs = np.linspace(x0, x1, max(2, int(math.ceil((x1 - x0) / step)) + 1))
        ys = np.linspace(y0, y1, max(2, int(math.ceil((y1 - y0) / step)) + 1))
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        pts = np.column_stack([gx.ravel(), gy.ravel()])
        v = np.column_stack([pts, tw.ground_heights(pts) - 0.05])
        ny = len(ys)
        f = [[i * ny + j, (i + 1) * ny + j, (i + 1) * ny + j + 1, i * ny + j + 1]
             for i in range(len(xs) - 1) for j in range(ny - 1)]
        mb.add(v, f, "ground")
    else:
        v = np.array([[x0, y0, -0.02], [x1, y0, -0.02], [x1, y1, -0.02], [x0, y1, -0.02]])
        mb.add(v, [[0, 1, 2, 3]], "ground")
    sc.emit("terrain", mb, {"ground": M.grass(spec.color if spec and spec.color else (0.10, 0.16, 0.05))}, "road",
            blendgen_kind="terrain")


def _buildings(sc: _Scene):
    for i, b in enumerate(sc.twin.spec.buildings):
        L, W = b.size
        floors = b.floors or max(1, round(b.height_m / 3.2))
        mb = MeshBuilder()
        v, f = box((L, W, b.height_m), (0, 0, b.height_m / 2))
        mb.add(v, f, "facade")
        v, f = box((L + 0.3, W + 0.3, 0.4), (0, 0, b.height_m + 0.2))  # roof parapet
        mb.add(v, f, "roof")
        v, f = box((L + 0.1, W + 0.1, 0.6), (0, 0, 0.3))  # plinth
        mb.add(v, f, "roof")
        ob = sc.emit(f"building_{i}", mb, {"facade": M.facade(b.facade, b.height_m / floors),
                                           "roof": M.concrete((0.35, 0.34, 0.33), tiles=False, name="roof")},
                     "structure", blendgen_kind="building")
        ob.location = (*b.center, sc.twin.ground_height(*b.center) if sc.twin.relief else 0.0)
        ob.rotation_euler = (0, 0, math.radians(b.yaw_deg))


def _street_furniture(sc: _Scene):
    sp = sc.twin.spec
    metal = M.metal((0.42, 0.43, 0.44), 0.5)
    mats = {"metal": metal, "wood": M.principled("wood", (0.22, 0.14, 0.08), roughness=0.8),
            "lampglass": M.principled("lampglass", (0.9, 0.9, 0.85), roughness=0.2),
            "red": M.principled("sign_red", (0.55, 0.02, 0.02), roughness=0.35),
            "white": M.principled("sign_white", (0.85, 0.85, 0.85), roughness=0.35),
            "blue": M.principled("sign_blue", (0.02, 0.08, 0.35), roughness=0.35),
            "concrete": M.concrete((0.6, 0.59, 0.56), tiles=False, name="barrier"),
            "rail": M.metal((0.7, 0.71, 0.72), 0.3)}
    mb = MeshBuilder()
    for p in sp.poles:
        x, y = p.position
        k0 = len(mb.verts)
        if p.kind == "utility":
            v, f = cylinder(0.13, p.height_m, 12, "z", (x, y, p.height_m / 2), radius2=0.1)
            mb.add(v, f, "wood", smooth=True)
            v, f = box((0.1, 1.6, 0.1), (x, y, p.height_m - 0.5))
            mb.add(v, f, "wood")
        else:
            v, f = cylinder(0.1, p.height_m, 12, "z", (x, y, p.height_m / 2), radius2=0.06)
            mb.add(v, f, "metal", smooth=True)
            yaw = math.radians(p.yaw_deg)
            tip = np.array([x, y, p.height_m]) + 1.6 * np.array([math.cos(yaw), math.sin(yaw), 0.1])
            v, f = tube([x, y, p.height_m - 0.1], tip, 0.04, 8)
            mb.add(v, f, "metal")
            v, f = box((0.6, 0.25, 0.12), tip - [0, 0, 0.08])
            mb.add(xf(v - tip, rot_z(yaw), tip), f, "lampglass")
        _lift(sc.twin, mb, k0, x, y)
    for s in sp.signs:
        x, y = s.position
        k0 = len(mb.verts)
        yaw = math.radians(s.yaw_deg)
        v, f = cylinder(0.035, s.height_m, 8, "z", (x, y, s.height_m / 2))
        mb.add(v, f, "metal")
        c = np.array([x, y, s.height_m])
        R = rot_z(yaw)
        if s.kind == "stop":
            v, f = cylinder(0.38, 0.02, 8, "x", (0.05, 0, 0))
            mb.add(xf(v, R, c), f, "red")
        elif s.kind == "yield":
            tri = np.array([[0.06, 0, -0.35], [0.06, 0.4, 0.35], [0.06, -0.4, 0.35]])
            mb.add(xf(tri, R, c), [[0, 1, 2]], "red")
            mb.add(xf(tri * [1, 0.6, 0.6] + [0.005, 0, 0.05], R, c), [[0, 1, 2]], "white")
        elif s.kind == "speed":
            v, f = cylinder(0.32, 0.02, 20, "x", (0.05, 0, 0))
            mb.add(xf(v, R, c), f, "red")
            v, f = cylinder(0.25, 0.02, 20, "x", (0.06, 0, 0))
            mb.add(xf(v, R, c), f, "white")
        else:
            v, f = box((0.03, 1.2, 0.8), (0.05, 0, 0.2))
            mb.add(xf(v, R, c), f, "blue")
        _lift(sc.twin, mb, k0, x, y)
    for b in sp.barriers:
        a, e = np.asarray(b.start, float), np.asarray(b.end, float)
        length = float(np.linalg.norm(e - a))
        yaw = math.atan2(*(e - a)[::-1])
        mid = (a + e) / 2
        R = rot_z(yaw)
        if b.kind == "jersey":
            sec = [(-0.3, 0.0), (-0.2, 0.3), (-0.08, b.height_m), (0.08, b.height_m), (0.2, 0.3), (0.3, 0.0)]
            v = [[x, y, z] for x in (-length / 2, length / 2) for (y, z) in sec]
            f = [[j, 6 + j, 6 + j + 1, j + 1] for j in range(5)] + [[0, 1, 2, 3, 4, 5][::-1], [6, 7, 8, 9, 10, 11]]
            mb.add(xf(v, R, [*mid, 0]), f, "concrete")
        else:
            for t in np.arange(0, length + 1e-6, 4.0):
                p = a + (e - a) * (t / max(length, 1e-9))
                v, f = box((0.1, 0.1, b.height_m), (*p, b.height_m / 2))
                mb.add(v, f, "metal")
            v, f = box((length, 0.06, 0.3), (0, 0, b.height_m - 0.2))
            mb.add(xf(v, R, [*mid, 0]), f, "rail")
    # median barriers along roads
    for rg in sc.twin.roads.values():
        if rg.spec.median_barrier and rg.spec.median_m > 0:
            sec = [(-0.3, 0.0), (-0.2, 0.3), (-0.08, 0.8), (0.08, 0.8), (0.2, 0.3), (0.3, 0.0)]
            _sweep(mb, rg, _samples(0, rg.length, 2.0), sec, "concrete")
    # signal poles at the intersection slots (the planner mounts traffic-light heads on them)
    for sl in sc.twin.signal_slots:
        z0 = sc.twin.ground_height(sl.x, sl.y)
        v, f = cylinder(0.07, SIGNAL_POLE_M, 12, "z", (sl.x, sl.y, z0 + SIGNAL_POLE_M / 2))
        mb.add(v, f, "metal", smooth=True)
        v, f = cylinder(0.12, 0.5, 12, "z", (sl.x, sl.y, z0 + 0.25))
        mb.add(v, f, "metal", smooth=True)
    sc.emit("street_furniture", mb, mats, "structure", blendgen_kind="furniture")
    # static traffic lights (scenery, not labelled)
    rng = np.random.default_rng(0)
    for i, t in enumerate(sp.traffic_lights):
        variant, dims = sample_variant("traffic light", rng)
        variant["mount_height_m"] = t.mount_height_m
        head = build_shape("traffic light", variant, dims, t.state)
        pole = traffic_light_pole(variant, variant["shape_dims"][0], variant["shape_dims"][2])
        mats_tl = {"housing": M.principled("housing_0.02_0.02_0.02", (0.02, 0.02, 0.02), roughness=0.45)}
        for name, col in LAMP_COLORS.items():
            mats_tl[f"lamp_{name}"] = M.lamp(col, 6.0)
            mats_tl[f"lamp_{name}_off"] = M.lamp(col, 0.02)
        ob = sc.emit(f"traffic_light_{i}", head, mats_tl, "structure", blendgen_kind="traffic_light")
        ob.location = (*t.position, sc.twin.ground_height(*t.position) + t.mount_height_m)
        ob.rotation_euler = (0, 0, math.radians(t.yaw_deg))
        pm = sc.emit(f"traffic_light_{i}_pole", pole, {"pole": metal}, "structure", blendgen_kind="traffic_light")
        pm.parent = ob


def _trees(sc: _Scene):
    mb = MeshBuilder()
    rng = np.random.default_rng(1)
    for t in sc.twin.spec.trees:
        x, y = t.position
        h = t.height_m
        k0 = len(mb.verts)
        v, f = cylinder(0.16, h * 0.55, 8, "z", (x, y, h * 0.275), radius2=0.1)
        mb.add(v, f, "bark", smooth=True)
        for k in range(3):
            off = rng.uniform(-0.6, 0.6, 3) * [1, 1, 0.5]
            r = h * rng.uniform(0.2, 0.28)
            v, f = ellipsoid((r, r, r * 1.1), (x + off[0], y + off[1], h * 0.68 + off[2] + k * 0.35 * r), 10, 7)
            mb.add(v, f, "foliage", smooth=True)
        _lift(sc.twin, mb, k0, x, y)
    sc.emit("trees", mb, {"bark": M.bark(), "foliage": M.foliage()}, "vegetation")


def build_twin(twin, collection=None) -> dict:
    """Build the twin (a Twin or a twin YAML path) into `collection` (default: a new
    collection `twin_<name>` in the scene). Returns {collection, objects, roles, counts, build_s}."""
    t0 = time.perf_counter()
    if not isinstance(twin, Twin):
        twin = load_twin(Path(twin))
    if collection is None:
        collection = bpy.data.collections.new(f"twin_{twin.name}")
        bpy.context.scene.collection.children.link(collection)
    sc = _Scene(twin, collection)
    mats_spec = twin.spec.materials
    _ground(sc, mats_spec)
    _roads(sc, mats_spec)
    _buildings(sc)
    _street_furniture(sc)
    _trees(sc)
    roles = {ob.name: ob["blendgen_role"] for ob in sc.objects}
    counts: dict[str, int] = {}
    for r in roles.values():
        counts[r] = counts.get(r, 0) + 1
    return {"collection": collection.name, "objects": [ob.name for ob in sc.objects], "roles": roles,
            "counts": counts, "build_s": time.perf_counter() - t0}
