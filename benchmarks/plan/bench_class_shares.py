"""How closely the placed objects follow the job's class weights on real footage.

    .venv/bin/python benchmarks/plan/bench_class_shares.py JOB.yaml [JOB.yaml ...] [--seeds 20] [--md FILE]

Each job must have run once (`blendgen run JOB.yaml`): its frame analysis and poses are
reused, and the planner is run again over `--seeds` seeds on them (no rendering). Per class:
its share of the weights (over the classes with weight > 0) and its share of the placed tracks
(riders of two-wheelers are not counted: they come with their vehicle), with the plan's time.
A class far below its weight is one the real frames reject (the reasons are in each plan's
`decisions`, and `blendgen run` warns about classes that no frame holds). Writes
benchmarks/results/class_shares.png.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import RESULTS  # noqa: E402

from blendgen import atomic  # noqa: E402
from blendgen.job.schema import load_job  # noqa: E402
from blendgen.pipeline.run import Runner  # noqa: E402
from blendgen.recording.folder import read_recording  # noqa: E402
from blendgen.scene.planner import plan_sequence  # noqa: E402
from blendgen.scene.real_scene import load_real_scene  # noqa: E402


def shares(job_path: Path, seeds: int) -> tuple[dict, dict, float, float]:
    """(weight share, placed-track share, median plan seconds, objects per frame) per class of
    one finished job (objects: riders not counted)."""
    job = load_job(job_path)
    runner = Runner(job, progress=False)
    if not runner.folder.plan.exists():
        sys.exit(f"{job_path}: no plan in {runner.folder.root}: run `blendgen run {job_path}` first")
    plans = [json.loads(line) for line in runner.folder.plan.read_text().splitlines()]
    poses = [(p["frame_id"], p["t"], np.asarray(p["T_world_cam"])) for p in plans]
    rec = read_recording(job.recording_dir)
    camera = rec.camera.scaled(*(job.render.resolution or (rec.camera.width, rec.camera.height)))
    real = load_real_scene(runner.folder.analysis, [p[0] for p in poses], camera) if job.twin_path is None else None
    tracks, secs, per_frame = set(), [], []
    for seed in range(seeds):
        t0 = time.perf_counter()
        out = plan_sequence(runner.twin, camera, poses, job.inject, seed, real=real)
        secs.append(time.perf_counter() - t0)
        tracks |= {(seed, o.id, o.cls) for p in out for o in p.objects if "rides" not in o.variant}
        per_frame += [sum("rides" not in o.variant for o in p.objects) for p in out]
    placed = Counter(cls for _, _, cls in tracks)
    w = {c: v for c, v in job.inject.classes.items() if v > 0}
    total_w, total_p = sum(w.values()), max(sum(placed.values()), 1)
    return ({c: v / total_w for c, v in w.items()}, {c: placed[c] / total_p for c in w}, float(np.median(secs)),
            float(np.mean(per_frame)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("jobs", nargs="+", type=Path)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--md", type=Path, default=None)
    a = ap.parse_args(argv)
    rows, lines = [], ["| job | class | weight share | placed share | plan s (median) | objects per frame |",
                       "|---|---|---:|---:|---:|---:|"]
    for j in a.jobs:
        w, p, s, n = shares(j, a.seeds)
        for c in w:
            lines.append(f"| {j.stem} | {c} | {w[c]:.2f} | {p[c]:.2f} | {s:.2f} | {n:.2f} |")
        rows.append((j.stem, w, p))
    print("\n".join(lines))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(rows), figsize=(4.5 * len(rows), 3.2), squeeze=False)
    for ax, (name, w, p) in zip(axes[0], rows):
        x = np.arange(len(w))
        ax.bar(x - 0.2, list(w.values()), 0.4, label="weight share")
        ax.bar(x + 0.2, [p[c] for c in w], 0.4, label="placed share")
        ax.set_xticks(x, list(w), rotation=45, ha="right")
        ax.set_title(name)
    axes[0][0].legend()
    fig.tight_layout()
    out = RESULTS / "class_shares.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")
    if a.md:
        atomic.write_text(a.md, "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
