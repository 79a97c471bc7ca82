"""Procedural mesh parts (NumPy) merged into one Blender mesh per object.

Parts are built as vertex/face arrays with a material slot and a smooth flag, so one object
becomes a single mesh (fast to create, fast for Cycles to sync) with several materials.
"""

from __future__ import annotations

import math

import numpy as np


class MeshBuilder:
    """`bounds_only`: the caller needs only the tight box (the planner sizing an object), so
    costly builders may add just the vertices that can bound it, without faces."""

    def __init__(self, bounds_only: bool = False):
        self.bounds_only = bounds_only
        self.verts: list[np.ndarray] = []
        self.faces: list[list[int]] = []
        self.mat: list[int] = []
        self.smooth: list[bool] = []
        self.slots: list[str] = []
        self._n = 0

    def slot(self, name: str) -> int:
        if name not in self.slots:
            self.slots.append(name)
        return self.slots.index(name)

    def add(self, verts, faces, material: str, smooth: bool = False):
        verts = np.asarray(verts, dtype=float)
        m = self.slot(material)
        self.verts.append(verts)
        if isinstance(faces, np.ndarray):  # (n, k) indices, -1 padding rows of fewer corners
            rows = np.where(faces >= 0, faces + self._n, -1).tolist()
            new = [r if r[-1] >= 0 else [i for i in r if i >= 0] for r in rows]
        else:
            new = [[int(i) + self._n for i in f] for f in faces]
        self.faces.extend(new)
        self.mat.extend([m] * len(new))
        self.smooth.extend([smooth] * len(new))
        self._n += len(verts)
        return self

    @property
    def vertices(self) -> np.ndarray:
        return np.vstack(self.verts) if self.verts else np.zeros((0, 3))

    def to_mesh(self, name: str, materials: dict):
        """A bpy mesh with the parts; `materials` maps slot names to bpy materials."""
        import bpy

        me = bpy.data.meshes.new(name)
        v = self.vertices
        me.from_pydata(v.tolist(), [], self.faces)
        for s in self.slots:
            me.materials.append(materials[s])
        me.polygons.foreach_set("material_index", np.asarray(self.mat, dtype=np.int32))
        sharp = me.attributes.get("sharp_face") or me.attributes.new("sharp_face", "BOOLEAN", "FACE")
        sharp.data.foreach_set("value", ~np.asarray(self.smooth, dtype=bool))
        me.validate(clean_customdata=False)
        import bmesh  # consistent outward normals (glass refraction and backface culling need them)

        bm = bmesh.new()
        bm.from_mesh(me)
        bmesh.ops.recalc_face_normals(bm, faces=bm.faces[:])
        bm.to_mesh(me)
        bm.free()
        me.update()
        return me


# ---------------------------------------------------------------- transforms
def rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def xf(verts, R=None, t=(0, 0, 0)):
    v = np.asarray(verts, float)
    if R is not None:
        v = v @ np.asarray(R).T
    return v + np.asarray(t, float)


# ---------------------------------------------------------------- primitives
def box(size, center=(0, 0, 0)):
    sx, sy, sz = (s / 2 for s in size)
    v = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)]) + np.asarray(center, float)
    f = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    return v, f


def cylinder(radius, depth, n=16, axis="z", center=(0, 0, 0), radius2=None, caps=True):
    """A (possibly tapered) cylinder along `axis`, centred at `center`."""
    r2 = radius if radius2 is None else radius2
    a = np.linspace(0, 2 * math.pi, n, endpoint=False)
    ring = np.stack([np.cos(a), np.sin(a)], 1)
    bot = np.column_stack([ring * radius, np.full(n, -depth / 2)])
    top = np.column_stack([ring * r2, np.full(n, depth / 2)])
    v = np.vstack([bot, top])
    f = [[i, (i + 1) % n, n + (i + 1) % n, n + i] for i in range(n)]
    if caps:
        f += [list(range(n - 1, -1, -1)), list(range(n, 2 * n))]
    R = {"z": np.eye(3), "x": rot_y(math.pi / 2), "y": rot_x(-math.pi / 2)}[axis]
    return xf(v, R, center), f


def tube(p0, p1, radius, n=8, radius2=None):
    """A cylinder between two points."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    length = float(np.linalg.norm(d))
    v, f = cylinder(radius, length, n, radius2=radius2)
    z = d / max(length, 1e-9)
    x = np.cross(z, [0, 0, 1.0]) if abs(z[2]) < 0.95 else np.cross(z, [1.0, 0, 0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.column_stack([x, y, z])
    return xf(v, R, (p0 + p1) / 2), f


def ellipsoid(radii, center=(0, 0, 0), nu=12, nv=8):
    rx, ry, rz = radii
    verts = [[0, 0, -rz]]
    for j in range(1, nv):
        th = -math.pi / 2 + math.pi * j / nv
        for i in range(nu):
            ph = 2 * math.pi * i / nu
            verts.append([rx * math.cos(th) * math.cos(ph), ry * math.cos(th) * math.sin(ph), rz * math.sin(th)])
    verts.append([0, 0, rz])
    top = len(verts) - 1
    f = [[0, 1 + (i + 1) % nu, 1 + i] for i in range(nu)]
    for j in range(nv - 2):
        a, b = 1 + j * nu, 1 + (j + 1) * nu
        f += [[a + i, a + (i + 1) % nu, b + (i + 1) % nu, b + i] for i in range(nu)]
    last = 1 + (nv - 2) * nu
    f += [[last + i, last + (i + 1) % nu, top] for i in range(nu)]
    return np.asarray(verts) + np.asarray(center, float), f


def torus(major, minor, center=(0, 0, 0), axis="y", nu=24, nv=8):
    """A ring (tyre) around `axis`."""
    verts = []
    for i in range(nu):
        a = 2 * math.pi * i / nu
        for j in range(nv):
            b = 2 * math.pi * j / nv
            r = major + minor * math.cos(b)
            verts.append([r * math.cos(a), r * math.sin(a), minor * math.sin(b)])
    f = [[i * nv + j, ((i + 1) % nu) * nv + j, ((i + 1) % nu) * nv + (j + 1) % nv, i * nv + (j + 1) % nv]
         for i in range(nu) for j in range(nv)]
    R = {"z": np.eye(3), "y": rot_x(math.pi / 2), "x": rot_y(math.pi / 2)}[axis]
    return xf(verts, R, center), f


def _corner_radius(half_w, tw, z0, z1, r):
    return min(r, (z1 - z0) / 2.01, tw * 0.99, half_w * 0.99)


def rounded_section(half_w, z0, z1, r, n_corner=3, top_half_w=None):
    """Cross-section (in y, z) of a rounded box, counter-clockwise seen from +x."""
    tw = half_w if top_half_w is None else top_half_w
    r = _corner_radius(half_w, tw, z0, z1, r)
    pts = []
    for (cy, cz, a0) in ((half_w - r, z0 + r, -math.pi / 2), (tw - r, z1 - r, 0.0),
                         (-(tw - r), z1 - r, math.pi / 2), (-(half_w - r), z0 + r, math.pi)):
        for k in range(n_corner + 1):
            a = a0 + (math.pi / 2) * k / n_corner
            pts.append((cy + r * math.cos(a), cz + r * math.sin(a)))
    return pts


def rounded_section_half_width(half_w, z0, z1, r, z, top_half_w=None):
    """Half-width at height z of `rounded_section(half_w, z0, z1, r, top_half_w=...)` (exact
    corners, not the polygon's chords)."""
    tw = half_w if top_half_w is None else top_half_w
    r = _corner_radius(half_w, tw, z0, z1, r)
    if z >= z1 - r:
        return tw - r + math.sqrt(max(r * r - (z - (z1 - r)) ** 2, 0.0))
    if z <= z0 + r:
        return half_w - r + math.sqrt(max(r * r - (z0 + r - z) ** 2, 0.0))
    return half_w + (tw - half_w) * (z - z0 - r) / (z1 - z0 - 2 * r)


def grid(P):
    """Quads over an (nu, nv, 3) grid of points: (vertices, faces)."""
    P = np.asarray(P, float)
    nu, nv = P.shape[:2]
    idx = np.arange(nu * nv).reshape(nu, nv)
    f = [[idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]] for i in range(nu - 1) for j in range(nv - 1)]
    return P.reshape(-1, 3), f


def loft(stations, cap=True):
    """Skin rings of (y, z) points placed at x stations: [(x, [(y, z), ...]), ...]."""
    m = len(stations[0][1])
    verts = [[x, y, z] for x, sec in stations for (y, z) in sec]
    f = []
    for k in range(len(stations) - 1):
        a, b = k * m, (k + 1) * m
        f += [[a + i, b + i, b + (i + 1) % m, a + (i + 1) % m] for i in range(m)]
    if cap:
        f.append(list(range(m))[::-1])
        last = (len(stations) - 1) * m
        f.append(list(range(last, last + m)))
    return np.asarray(verts, float), f


def prism(poly_xy, z0, z1):
    """Vertical extrusion of a convex polygon (counter-clockwise)."""
    p = np.asarray(poly_xy, float)
    n = len(p)
    v = np.vstack([np.column_stack([p, np.full(n, z0)]), np.column_stack([p, np.full(n, z1)])])
    f = [[i, (i + 1) % n, n + (i + 1) % n, n + i] for i in range(n)]
    f += [list(range(n - 1, -1, -1)), list(range(n, 2 * n))]
    return v, f


def strip(left, right, z_left, z_right=None):
    """A ribbon between two polylines (Mx2) at given heights, facing up."""
    left, right = np.asarray(left, float), np.asarray(right, float)
    m = len(left)
    zl = np.broadcast_to(np.asarray(z_left, float), (m,))
    zr = zl if z_right is None else np.broadcast_to(np.asarray(z_right, float), (m,))
    v = np.vstack([np.column_stack([right, zr]), np.column_stack([left, zl])])
    f = [[i, i + 1, m + i + 1, m + i] for i in range(m - 1)]
    return v, f
