"""Scene planner: time per frame and fill rate (objects placed vs the requested count).

    .venv/bin/python benchmarks/plan/bench_planner.py [--quick]

For each twin (demo_town, highway, a ground-plane twin) and each requested range of
objects per frame, plans a drive (5 fps) with all seven classes and all scenarios and
reports the median planning time per frame over repeats, the mean number of objects per
frame, and the share of frames that reach the requested minimum. Writes a plot to
benchmarks/results/planner.png and a table to docs/benchmarks/planner.md.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import RESULTS, ROOT, write_doc  # noqa: E402

from blendgen import atomic  # noqa: E402
from blendgen.geometry import Camera, R_world_cam_from_ypr, make_pose  # noqa: E402
from blendgen.job.schema import SCENARIOS, Inject  # noqa: E402
from blendgen.scene.ground_plane import GroundPlaneTwin  # noqa: E402
from blendgen.scene.planner import plan_sequence  # noqa: E402
from blendgen.twin.model import load_twin  # noqa: E402

CLASSES = {"car": 3, "person": 3, "bicycle": 1, "motorcycle": 1, "bus": 1, "truck": 1, "traffic light": 1}


def drive(route, fps, speed, height=1.5):
    seg = np.linalg.norm(np.diff(route, axis=0), axis=1)
    s = np.concatenate([[0], np.cumsum(seg)])
    out = []
    for i, t in enumerate(np.arange(0, s[-1] / speed, 1 / fps)):
        p = [np.interp(t * speed, s, route[:, j]) for j in (0, 1)]
        q = [np.interp(min(t * speed + 1, s[-1]), s, route[:, j]) for j in (0, 1)]
        yaw = math.atan2(q[1] - p[1], q[0] - p[0])
        out.append((f"{i:06d}", float(t), make_pose(R_world_cam_from_ypr(yaw, -0.02), [*p, height])))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args(argv)
    repeats = 2 if a.quick else 3
    ranges = [(1, 2), (3, 5), (6, 8)] if a.quick else [(1, 2), (3, 5), (6, 8), (10, 12)]
    cam = Camera.from_hfov(960, 540, 70.0)
    town, hw = (load_twin(ROOT / "assets_procedural" / "twins" / f"{n}.yaml") for n in ("demo_town", "highway"))
    gp = GroundPlaneTwin(1.4, -2.0, 3.6)
    setups = [("demo_town", town, lambda s: drive(town.ego_route(80.0, s), 5.0, 8.0), (4.0, 40.0)),
              ("highway", hw, lambda s: drive(hw.ego_route(200.0, s), 5.0, 20.0), (5.0, 70.0)),
              ("ground_plane", gp, lambda s: drive(gp.ego_route(80.0, s), 5.0, 8.0), (4.0, 40.0))]
    rows = []
    for name, twin, poses_for, dist in setups:
        for lo, hi in ranges:
            per_frame, counts, reach = [], [], []
            for rep in range(repeats):
                poses = poses_for(rep)
                inj = Inject(objects_per_frame=(lo, hi), classes=CLASSES, scenarios=list(SCENARIOS), distance_m=dist)
                t0 = time.perf_counter()
                plans = plan_sequence(twin, cam, poses, inj, rep)
                per_frame.append((time.perf_counter() - t0) / len(plans) * 1000)
                n = np.array([len(p.objects) for p in plans])
                counts.append(n.mean())
                reach.append(np.mean(n >= lo))
            rows.append((name, f"{lo}-{hi}", float(np.median(per_frame)), float(np.mean(counts)),
                         float(np.mean(reach)), len(plans)))
            print(f"{name:13s} {lo:2d}-{hi:<2d} {rows[-1][2]:7.1f} ms/frame  {rows[-1][3]:5.2f} obj/frame  "
                  f"{100 * rows[-1][4]:5.1f}% frames >= min", flush=True)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for name, *_ in setups:
        r = [x for x in rows if x[0] == name]
        ax[0].plot([x[1] for x in r], [x[2] for x in r], "o-", label=name)
        ax[1].plot([x[1] for x in r], [x[3] for x in r], "o-", label=name)
    ax[0].set(xlabel="objects_per_frame", ylabel="median planning time per frame (ms)", yscale="log")
    ax[1].set(xlabel="objects_per_frame", ylabel="mean objects per frame")
    ax[0].legend()
    fig.tight_layout()
    out_png = RESULTS / "planner.png"
    with atomic.atomic_path(out_png) as tmp:
        fig.savefig(tmp, dpi=110)
    cmd = "nice -n 5 .venv/bin/python benchmarks/plan/bench_planner.py" + (" --quick" if a.quick else "")
    md = ["# Scene planner benchmark", "", f"Command: `{cmd}` (2 shared CPU cores; timings are medians over "
          f"{repeats} drives, 960x540 camera, all classes and all five scenarios).", "",
          "| twin | objects_per_frame | ms / frame (median) | objects / frame | frames reaching the minimum | frames per drive |",
          "|---|---|---|---|---|---|"]
    md += [f"| {n} | {r} | {t:.1f} | {c:.2f} | {100 * f:.0f}% | {k} |" for n, r, t, c, f, k in rows]
    md += ["", "Plot: `benchmarks/results/planner.png`. Highway has no sidewalks or signals, so persons and traffic",
           "lights are not placed there and their share goes to the other classes only when they fail to place."]
    write_doc("planner.md", "\n".join(md) + "\n")
    print(f"wrote {out_png} and docs/benchmarks/planner.md")


if __name__ == "__main__":
    main()
