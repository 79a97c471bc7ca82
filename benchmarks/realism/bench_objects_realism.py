"""Recall@0.5 of injected objects at least N px tall, per class, before/after, from the
`blendgen realism` results (eval/realism.json) of runs on real photos, with bootstrap 95 % CIs.

    .venv/bin/python benchmarks/realism/bench_objects_realism.py --min-height 40 \
        --before OLD/out/m_old_*/eval/realism.json --after NEW/out/m_new_*/eval/realism.json \
        [--md docs/benchmarks/objects_realism.md]

A ground truth counts as found when a detection of its class with score >= 0.3 matches it at
IoU >= 0.5 (COCO's greedy matching, blendgen.detection.metrics.match_image).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen

from blendgen import CLASSES, atomic  # noqa: E402
from blendgen.detection.metrics import match_image  # noqa: E402

NAME = {v: k for k, v in CLASSES.items()}


def hits(paths, min_h: float, score_thr: float = 0.3) -> list[tuple[str, bool]]:
    out = []
    for p in paths:
        d = json.loads(Path(p).read_text())
        for img in sorted({g["image_id"] for g in d["ground_truth"]}):
            for cid in sorted({g["category_id"] for g in d["ground_truth"] if g["image_id"] == img}):
                gts = [g for g in d["ground_truth"] if g["image_id"] == img and g["category_id"] == cid]
                dts = [x for x in d["detections"] if x["image_id"] == img and x["category_id"] == cid
                       and x["score"] >= score_thr]
                g_score = match_image(dts, gts, 0.5, 100)[-1]
                out += [(NAME[cid], bool(np.isfinite(s))) for g, s in zip(gts, g_score)
                        if not g["ignore"] and g["bbox"][3] >= min_h]
    return out


def summary(h, rng) -> str:
    if not h:
        return "- | -"
    a = np.asarray(h, float)
    boot = rng.choice(a, (2000, len(a))).mean(1)
    return f"{len(a)} | {a.mean():.2f} [{np.percentile(boot, 2.5):.2f}, {np.percentile(boot, 97.5):.2f}]"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--before", nargs="+", required=True)
    ap.add_argument("--after", nargs="+", required=True)
    ap.add_argument("--min-height", type=float, default=40.0)
    ap.add_argument("--md", type=Path, default=None)
    a = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    b, n = hits(a.before, a.min_height), hits(a.after, a.min_height)
    lines = [f"| class | before: n | recall@0.5 [95% CI] | after: n | recall@0.5 [95% CI] |",
             "|---|---:|---|---:|---|"]
    for c in CLASSES:
        lines.append(f"| {c} | {summary([x for k, x in b if k == c], rng)} | {summary([x for k, x in n if k == c], rng)} |")
    lines.append(f"| **all** | {summary([x for _, x in b], rng)} | {summary([x for _, x in n], rng)} |")
    table = "\n".join(lines)
    print(table)
    if a.md:
        cmd = " ".join(["benchmarks/realism/bench_objects_realism.py", *(argv or sys.argv[1:])])
        atomic.write_text(a.md, f"# Injected objects on real photos: recall@0.5, objects >= {a.min_height:.0f} px tall\n\n"
                                f"{table}\n\nMade with `{cmd}`.\n")


if __name__ == "__main__":
    main()
