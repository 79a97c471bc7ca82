"""Twins from real maps: `blendgen twin import opendrive|osm SRC OUT` and `blendgen twin show TWIN`.

A twin folder holds a copy of the map, `twin.yaml` (`name` + `source: <map file>`; the twin
is rebuilt from the map on load), `twin_lut.csv` (the survey LUT the sync stage picks up
beside the YAML) and `twin.png` (top-down plot of lanes, junctions, crosswalks, signals).
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

import numpy as np

from blendgen import atomic
from blendgen.errors import UserError
from blendgen.twin.maps import FORMATS, map_format, map_twin_data
from blendgen.twin.model import load_twin

LUT_SPACING_M = 2.0


def import_twin(fmt: str, src: Path, out: Path) -> dict:
    """Write the twin folder; returns timings and counts."""
    src = Path(src)
    if not src.is_file():
        raise UserError("no such map file", where=str(src))
    if map_format(src) != fmt:
        raise UserError(f"expected a {fmt} map ({', '.join(k for k, v in FORMATS.items() if v == fmt)})",
                        where=str(src))
    t0 = time.perf_counter()
    map_twin_data(src, fmt)  # validate before writing anything
    out.mkdir(parents=True, exist_ok=True)
    dst = out / src.name
    if dst.resolve() != src.resolve():
        with atomic.atomic_path(dst) as tmp:
            shutil.copyfile(src, tmp)
    atomic.write_text(out / "twin.yaml", f"# blendgen twin built from the {fmt} map beside this file\n"
                                         f"name: {src.stem}\nsource: {src.name}\n")
    twin = load_twin(out / "twin.yaml")
    t_load = time.perf_counter() - t0
    n = twin.export_lut(out / "twin_lut.csv", LUT_SPACING_M)
    plot_twin(twin, out / "twin.png")
    return {"seconds": t_load, "roads": len(twin.roads), "lut_rows": n, "crosswalks": len(twin.crosswalks)}


def plot_twin(twin, png: Path) -> None:
    """Top-down plot: carriageways, lane centres with direction, junction roads, crosswalks,
    sidewalks, signals, buildings."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon
    from matplotlib.collections import LineCollection, PolyCollection

    x0, y0, x1, y1 = twin.bounds
    aspect = float(np.clip((y1 - y0 + 40) / (x1 - x0 + 40), 0.25, 2.0))
    fig, ax = plt.subplots(figsize=(14, 14 * aspect + 1.0) if aspect < 1 else (10 / aspect + 1.0, 10), dpi=110)
    areas, lanes, walks, arrows = {True: [], False: []}, {True: [], False: []}, [], []
    for rg in twin.roads.values():
        s = np.linspace(0, rg.length, max(2, int(rg.length / 2) + 1))
        junction = rg.spec.junction is not None
        areas[junction].append(np.vstack([rg.line.offset_point(s, -rg.hw_r(s)),
                                          rg.line.offset_point(s[::-1], rg.hw_l(s[::-1]))]))
        if rg.spec.sidewalk_m > 0:
            walks += [rg.line.offset_point(s, sign * (hw(s) + rg.spec.sidewalk_m / 2))
                      for sign, hw in ((-1, rg.hw_r), (1, rg.hw_l))]
        for i, dr, _ in rg.lanes:
            p = rg.line.offset_point(s, rg.lane_d(i, dr, s))
            lanes[junction].append(p)
            m = len(p) // 2  # an arrow in the travel direction at the middle
            arrows.append((*p[m], *((p[m] - p[m - 1]) * dr)))
    for junction, fc, lc in ((False, "#5b6670", "#1f5fbf"), (True, "#9aa7b0", "#d04a02")):
        ax.add_collection(PolyCollection(areas[junction], fc=fc, ec="none", alpha=0.45))
        ax.add_collection(LineCollection(lanes[junction], colors=lc, lw=0.8))
    ax.add_collection(LineCollection(walks, colors="#c8b27a", lw=1.5))
    a = np.asarray(arrows)
    ax.quiver(a[:, 0], a[:, 1], a[:, 2], a[:, 3], color="#1f5fbf", angles="xy", scale_units="xy",
              scale=0.4, width=0.002)
    for cw in twin.crosswalks:
        ax.add_patch(Polygon(cw, closed=True, fc="white", ec="k", lw=0.6, zorder=3))
    for st in twin.structures:
        if st.kind == "building":
            ax.add_patch(Polygon(st.polygon, closed=True, fc="#8c6d5a", ec="k", lw=0.5, alpha=0.8))
    tl = [t.position for t in twin.spec.traffic_lights] + [(s.x, s.y) for s in twin.signal_slots]
    if tl:
        tl = np.asarray(tl)
        ax.scatter(tl[:, 0], tl[:, 1], marker="o", s=22, c="#e02020", ec="k", zorder=4, label="traffic light")
    ax.plot([], [], color="#1f5fbf", label="lane centre (arrow: travel)")
    ax.plot([], [], color="#c8b27a", label="sidewalk")
    ax.plot([], [], color="#d04a02", label="junction connecting lane")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x east [m]")
    ax.set_ylabel("y north [m]")
    ax.set_title(f"twin {twin.name}: {len(twin.roads)} roads, {len(twin.crosswalks)} crosswalks")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    png = Path(png)
    with atomic.atomic_path(png) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("twin", help="twins from maps: import an OpenDRIVE/OSM map, plot a twin")
    tsub = p.add_subparsers(dest="twin_command", metavar="ACTION", required=True)
    q = tsub.add_parser("import", help="build a twin folder from a map",
                        description="Write OUT/twin.yaml (referencing a copy of the map), OUT/twin_lut.csv "
                                    "and OUT/twin.png.")
    q.add_argument("format", choices=["opendrive", "osm"])
    q.add_argument("src", type=Path, help="the map (.xodr, .osm or .osm.pbf)")
    q.add_argument("out", type=Path, help="the twin folder to write")
    q.set_defaults(func=_cmd_import)
    q = tsub.add_parser("show", help="redraw a twin's top-down plot")
    q.add_argument("twin", type=Path, help="twin folder, twin YAML or map file")
    q.add_argument("--out", type=Path, help="PNG to write (default: twin.png beside the YAML)")
    q.set_defaults(func=_cmd_show)


def _cmd_import(args) -> int:
    r = import_twin(args.format, args.src, args.out)
    print(f"twin {args.out}: {r['roads']} roads, {r['crosswalks']} crosswalks, LUT {r['lut_rows']} rows, "
          f"built in {r['seconds']:.2f} s")
    return 0


def _cmd_show(args) -> int:
    path = args.twin / "twin.yaml" if args.twin.is_dir() else args.twin
    twin = load_twin(path)
    png = args.out or path.with_suffix(".png")
    plot_twin(twin, png)
    print(f"wrote {png}")
    return 0
