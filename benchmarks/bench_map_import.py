"""Map import times and lane accuracy: every shared OpenDRIVE map, loaded as a twin.

    PYTHONPATH=. python benchmarks/bench_map_import.py

Prints a table (CPU seconds to parse + convert + build the Twin, median of 5; LUT export;
worst lane-centre error against tests/test_maps_opendrive.py's independent evaluation),
writes docs/benchmarks/map_import.md and a plot of each map to docs/images/maps/.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from blendgen import atomic  # noqa: E402
from blendgen.scene.geom2d import Polyline  # noqa: E402
from blendgen.scene.map_import import plot_twin  # noqa: E402
from blendgen.scene.twin import load_twin  # noqa: E402
from tests.test_maps_opendrive import ALL, _independent_lane_points  # noqa: E402


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
        n = twin.export_lut(ROOT / "benchmarks" / "results" / "tmp" / f"{path.stem}_lut.csv", 2.0)
        lut = time.process_time() - t
        plot_twin(twin, img / f"{path.stem}.png")
        lanes = sum(len(rg.lanes) for rg in twin.roads.values())
        rows.append((path.stem, len(twin.roads), lanes, len(twin.crosswalks), float(np.median(cpu)), lut, n,
                     lane_error(twin, path) * 100))
    head = "| map | roads | lanes | crosswalks | import CPU-s (median of 5) | LUT CPU-s | LUT rows | worst lane-centre error [cm] |"
    lines = [head, "|" + "---|" * 8]
    lines += [f"| {a} | {b} | {c} | {d} | {e:.2f} | {f:.2f} | {g} | {h:.2f} |" for a, b, c, d, e, f, g, h in rows]
    table = "\n".join(lines)
    print(table)
    atomic.write_text(ROOT / "docs" / "benchmarks" / "map_import.md",
                      "# OpenDRIVE map import\n\nCommand: `PYTHONPATH=. python benchmarks/bench_map_import.py` "
                      "(2-core machine shared with other jobs; CPU seconds, not wall time).\n\n" + table + "\n")


if __name__ == "__main__":
    main()
