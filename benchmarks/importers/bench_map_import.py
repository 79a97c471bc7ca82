"""Map import times and lane accuracy: every shared OpenDRIVE map, loaded as a twin.

    PYTHONPATH=. python benchmarks/importers/bench_map_import.py

Prints a table (CPU seconds to parse + convert + build the Twin, median of 5; LUT export;
worst lane-centre error against tests/test_maps_opendrive.py's independent evaluation),
writes docs/benchmarks/map_import.md and a plot of each map to docs/images/maps/.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import DOCS, RESULTS, ROOT  # noqa: E402

from blendgen import atomic  # noqa: E402
from blendgen.geom2d import Polyline  # noqa: E402
from blendgen.twin.command import plot_twin  # noqa: E402
from blendgen.twin.model import load_twin  # noqa: E402
from tests.test_maps_opendrive import ALL, _independent_lane_points  # noqa: E402
from tests import test_maps_relief as R  # noqa: E402


def lane_error(twin, path) -> float:
    worst = 0.0
    for (rid, lid), pts in _independent_lane_points(path).items():
        rg = twin.roads[rid]
        direction, index = (1, -lid - 1) if lid < 0 else (-1, lid - 1)
        s0, s1 = (0.0, rg.length) if direction > 0 else (rg.length, 0.0)
        d = Polyline(twin.lane_polyline(rid, index, direction, s0, s1, step=0.25)).project(pts)[1]
        worst = max(worst, float(np.abs(d).max()))
    return worst


def main() -> None:
    rows = []
    img = ROOT / "docs" / "images" / "maps"
    img.mkdir(parents=True, exist_ok=True)
    for path in ALL:
        cpu = []
        for _ in range(5):
            t = time.process_time()
            twin = load_twin(path)
            cpu.append(time.process_time() - t)
        t = time.process_time()
        n = twin.export_lut(RESULTS / "tmp" / f"{path.stem}_lut.csv", 2.0)
        lut = time.process_time() - t
        plot_twin(twin, img / f"{path.stem}.png")
        lanes = sum(len(rg.lanes) for rg in twin.roads.values())
        rows.append((path.stem, len(twin.roads), lanes, len(twin.crosswalks), float(np.median(cpu)), lut, n,
                     lane_error(twin, path) * 100))
    head = "| map | roads | lanes | crosswalks | import CPU-s (median of 5) | LUT CPU-s | LUT rows | worst lane-centre error [cm] |"
    lines = [head, "|" + "---|" * 8]
    lines += [f"| {a} | {b} | {c} | {d} | {e:.2f} | {f:.2f} | {g} | {h:.2f} |" for a, b, c, d, e, f, g, h in rows]
    table = "\n".join(lines) + "\n\n" + test_maps()
    print(table)
    atomic.write_text(DOCS / "map_import.md",
                      "# OpenDRIVE map import\n\nCommand: `PYTHONPATH=. python benchmarks/importers/bench_map_import.py` "
                      "(2-core machine shared with other jobs; CPU seconds, not wall time).\n\n" + table + "\n")


def test_maps() -> str:
    """The maps written in tests/test_maps_relief.py: relief, widths along s / <border>, UTM."""
    import math
    import tempfile

    import pyproj

    tmp = Path(tempfile.mkdtemp())
    out = ["| test map | what | worst error |", "|---|---|---|"]
    f = tmp / "relief.xodr"
    f.write_text(R.RELIEF)
    tw = load_twin(f)
    err = 0.0
    for t in (-1.75, -5.125, 1.75):
        s = np.linspace(1, 199, 199)
        th = np.array([R._theta(x) for x in s])
        z = tw.ground_heights(np.column_stack([s, t * np.cos(th)]))
        err = max(err, float(np.abs(z - (np.array([R._z(x) for x in s]) + t * np.sin(th))).max()))
    _, pitch, roll = tw.surface_pose([[50.0, -1.75], [160.0, -1.75 * math.cos(0.06)]], [0.0, 0.0], 4.5, 1.8)
    out.append(f"| relief (5 % slope, cubic elevation, superelevation 0.06 rad) | surface height at lane centres "
               f"| {err * 100:.2f} cm |")
    out.append(f"| relief | car pitch on the 5 % slope vs atan(0.05); roll on the superelevated stretch vs "
               f"atan(tan(0.06) cos(pitch)) "
               f"| {abs(pitch[0] - math.atan(0.05)):.1e} rad; {abs(roll[1] - math.atan(math.tan(0.06) * math.cos(pitch[1]))):.1e} rad |")
    f = tmp / "widths.xodr"
    f.write_text(R.WIDTHS)
    tw = load_twin(f)
    worst = 0.0
    for (k, lid), pts in R._independent_width_lanes(R.WIDTHS).items():
        rg = tw.roads[f"7.{k}"]
        direction, index = (1, -lid - 1) if lid < 0 else (-1, lid - 1)
        s0, s1 = (0.0, rg.length) if direction > 0 else (rg.length, 0.0)
        d = Polyline(tw.lane_polyline(rg.id, index, direction, s0, s1, step=0.25)).project(pts)[1]
        worst = max(worst, float(np.abs(d).max()))
    out.append(f"| widths (cubic widths, two records, <border> lanes, lane offset) | lane centres | {worst * 100:.2f} cm |")
    f = tmp / "utm.xodr"
    x1, y1 = 691000 + 150 * math.cos(0.7), 5335000 + 150 * math.sin(0.7)
    proj = "+proj=utm +zone=32 +datum=WGS84 +units=m +no_defs"
    f.write_text(R.UTM.replace("{PROJ}", proj).replace("{X1}", f"{x1:.6f}").replace("{Y1}", f"{y1:.6f}"))
    tw = load_twin(f)
    g = tw.georef
    rows = np.array(tw.lut_rows(3.0))
    inv = pyproj.Transformer.from_crs(proj, "EPSG:4326", always_xy=True)
    e, n, _ = g.to_enu(rows[:, 0], rows[:, 1], rows[:, 2])
    yaw = np.radians(rows[:, 7])
    d = 0.05 * np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
    lo1, la1 = inv.transform(rows[:, 4] - d[:, 0] + g.origin[0], rows[:, 5] - d[:, 1] + g.origin[1])
    lo2, la2 = inv.transform(rows[:, 4] + d[:, 0] + g.origin[0], rows[:, 5] + d[:, 1] + g.origin[1])
    az = pyproj.Geod(ellps="WGS84").inv(lo1, la1, lo2, la2)[0]
    herr = np.abs((rows[:, 3] - az + 180) % 360 - 180).max()
    out.append(f"| UTM zone 32 (x ~ 691 km), {len(rows)} LUT rows | GNSS fix round trip; heading vs geodesic azimuth "
               f"| {np.hypot(e - rows[:, 4], n - rows[:, 5]).max() * 1000:.3f} mm; {herr:.1e} deg "
               f"(true north {np.degrees(g.north_yaw(0.0, 0.0)) - 90:.2f} deg CCW of grid north) |")
    return "\n".join(out)


if __name__ == "__main__":
    main()
