"""LUT: surveyed correspondences between the real site (lat, lon, alt, compass heading) and the
twin frame (x, y, z, yaw), and the coarse twin pose of any GNSS fix.

CSV header: `lat,lon,alt,heading_deg,x,y,z,yaw_deg` (heading_deg: compass, clockwise from north;
yaw_deg: vehicle yaw in the twin frame, counter-clockwise from +x).

A query is answered with a local rigid map fitted to the nearest correspondences
(weighted 2-D Procrustes in ENU, height offset separately). The table covers the points within
`coverage_m` of a surveyed row; a query beyond it is answered with the nearest local map but
flagged `inside=False` so callers never use an extrapolation unknowingly.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pymap3d
from scipy.spatial import cKDTree

from blendgen.errors import UserError

LUT_COLUMNS = ["lat", "lon", "alt", "heading_deg", "x", "y", "z", "yaw_deg"]


@dataclass
class LutPose:
    xyz: np.ndarray          # twin-frame position (m)
    yaw: float | None        # twin-frame yaw (rad, CCW from +x); None without a heading
    inside: bool             # within the table's coverage
    distance_m: float        # to the nearest surveyed row


class Lut:
    def __init__(self, table: np.ndarray, *, source: str = "LUT", k: int = 6, coverage_m: float | None = None):
        table = np.asarray(table, dtype=float)
        if table.ndim != 2 or table.shape[1] != 8 or len(table) < 2:
            raise UserError("a LUT needs at least 2 rows of lat,lon,alt,heading_deg,x,y,z,yaw_deg", where=source)
        self.table = table
        self.source = source
        self.origin = tuple(table[0, :3])  # ENU origin of the table's own local frame
        e, n, u = pymap3d.geodetic2enu(table[:, 0], table[:, 1], table[:, 2], *self.origin)
        self.enu = np.stack([e, n, u], axis=1)
        self.xyz = table[:, 4:7]
        # per-row rotation ENU -> twin implied by the heading/yaw pair (used when positions
        # alone cannot fix the rotation, e.g. a single neighbour)
        self.row_rot = np.radians(table[:, 7]) - np.radians(90.0 - table[:, 3])
        self.tree = cKDTree(self.enu[:, :2])
        # spacing between distinct surveyed positions: a LUT with one row per heading at each
        # position (a normal layout) made it 0 and flagged 119 of 600 comma2k19 fixes outside
        uniq = np.unique(np.round(self.enu[:, :2], 2), axis=0)
        spacing = float(np.median(cKDTree(uniq).query(uniq, k=2)[0][:, 1])) if len(uniq) >= 2 else 0.0
        self.spacing_m = spacing
        self.coverage_m = float(coverage_m) if coverage_m is not None else max(3.0 * spacing, 5.0)
        self.k = min(k, len(table))

    @classmethod
    def load(cls, path: str | Path, **kw) -> "Lut":
        path = Path(path)
        if not path.is_file():
            raise UserError("LUT file not found", where=str(path))
        lines = [ln for ln in path.read_text().splitlines() if ln.strip()]
        if not lines:
            raise UserError(f"empty LUT; expected header {','.join(LUT_COLUMNS)}", where=str(path))
        header = [c.strip() for c in lines[0].split(",")]
        missing = [c for c in LUT_COLUMNS if c not in header]
        if missing:
            raise UserError(f"missing column(s) {missing}; expected header {','.join(LUT_COLUMNS)}", where=str(path))
        idx = [header.index(c) for c in LUT_COLUMNS]
        rows = []
        for i, ln in enumerate(lines[1:]):
            parts = ln.split(",")
            if len(parts) < len(header):
                raise UserError(f"row {i + 2}: {len(parts)} fields, expected {len(header)}", where=str(path))
            try:
                vals = [float(parts[j]) for j in idx]
            except ValueError:
                raise UserError(f"row {i + 2}: not all of {LUT_COLUMNS} are numbers", where=str(path)) from None
            if not np.all(np.isfinite(vals)):
                raise UserError(f"row {i + 2}: NaN/inf value", where=str(path))
            if abs(vals[0]) > 90 or abs(vals[1]) > 180:
                raise UserError(f"row {i + 2}: lat/lon out of range ({vals[0]}, {vals[1]})", where=str(path))
            rows.append(vals)
        return cls(np.array(rows).reshape(-1, 8), source=str(path), **kw)

    # --------------------------------------------------------------- queries
    def _local_map(self, en: np.ndarray):
        """Rigid 2-D map (rotation angle, translation) ENU -> twin near `en`, plus height offset."""
        d, j = self.tree.query(en, k=self.k)
        d, j = np.atleast_1d(d), np.atleast_1d(j)
        scale = max(self.spacing_m, 1.0)
        w = np.exp(-0.5 * (d / (2 * scale)) ** 2) + 1e-9
        w /= w.sum()
        A = self.enu[j, :2]
        B = self.xyz[j, :2]
        ca, cb = w @ A, w @ B
        A0, B0 = A - ca, B - cb
        spread = float(np.sqrt(w @ np.sum(A0**2, axis=1)))
        if spread > 0.5:
            C = (A0 * w[:, None]).T @ B0
            ang = np.arctan2(C[0, 1] - C[1, 0], C[0, 0] + C[1, 1])
        else:  # neighbours too close together: trust the surveyed heading/yaw pairs
            ang = np.arctan2(w @ np.sin(self.row_rot[j]), w @ np.cos(self.row_rot[j]))
        c, s = np.cos(ang), np.sin(ang)
        Rm = np.array([[c, -s], [s, c]])
        t = cb - Rm @ ca
        dz = w @ (self.xyz[j, 2] - self.enu[j, 2])
        return ang, Rm, t, dz, float(d[0])

    def query(self, lat: float, lon: float, alt: float, heading_deg: float | None = None) -> LutPose:
        e, n, u = pymap3d.geodetic2enu(lat, lon, alt, *self.origin)
        ang, Rm, t, dz, dist = self._local_map(np.array([e, n]))
        xy = Rm @ np.array([e, n]) + t
        yaw = None
        if heading_deg is not None and np.isfinite(heading_deg):
            yaw = float((np.radians(90.0 - heading_deg) + ang + np.pi) % (2 * np.pi) - np.pi)
        return LutPose(np.array([xy[0], xy[1], u + dz]), yaw, dist <= self.coverage_m, dist)

    def query_many(self, lat, lon, alt):
        """Vectorised positions: (xyz (N,3), inside (N,), rotation ENU->twin (N,) rad)."""
        lat, lon, alt = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (lat, lon, alt))
        out = np.zeros((len(lat), 3))
        inside = np.zeros(len(lat), bool)
        rot = np.zeros(len(lat))
        e, n, u = pymap3d.geodetic2enu(lat, lon, alt, *self.origin)
        for i in range(len(lat)):
            ang, Rm, t, dz, dist = self._local_map(np.array([e[i], n[i]]))
            out[i, :2] = Rm @ np.array([e[i], n[i]]) + t
            out[i, 2] = u[i] + dz
            inside[i] = dist <= self.coverage_m
            rot[i] = ang
        return out, inside, rot


def write_lut(path: str | Path, rows) -> None:
    """Write a LUT CSV (atomic). rows: (N, 8) in LUT_COLUMNS order."""
    from blendgen.recording.folder import write_csv

    write_csv(Path(path), LUT_COLUMNS, rows, fmt="%.10f")
