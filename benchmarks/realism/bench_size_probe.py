"""Is a small injected object missed because it is small, or because it renders badly small?

Each object of a class found at full size and at least --min-height px tall in the given runs'
composites is shrunk with its whole frame (area resampling, the rest of the canvas filled by
reflection, so the detector's letterbox scale stays) until it is N px tall, and detected again.
If well-detected objects are lost by shrinking alone, the natively small ones are at the
detector's size limit; if the natively small ones fare no worse than the shrunk ones, how they
render small is not the problem. The whole frame shrinks, so the context does too: a lower bound
(cars found 42 of 44 natively at 80-160 px, 66 of 88 larger ones shrunk to 100 px).

    .venv/bin/python benchmarks/realism/bench_size_probe.py --runs 'out/b_*' --class bicycle --to 100 60 \\
        [--detector ../shared/data/models/yolox_nano.onnx] [--plot out/size_probe.png]

Runs are `blendgen run` outputs with `blendgen realism` results (eval/realism.json). A match is
a detection of the class with score >= 0.3 at IoU >= 0.5 (as `blendgen realism`).
"""

from __future__ import annotations

import argparse
import glob
import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import DETECTOR  # noqa: E402

from blendgen import CLASSES  # noqa: E402
from blendgen.detection.detector import YoloxDetector  # noqa: E402
from blendgen.detection.metrics import match_image  # noqa: E402


def found(det, image, gt, cid) -> bool:
    dts = [x for x in det(image) if x["category_id"] == cid and x["score"] >= 0.3]
    return bool(np.isfinite(match_image(dts, [gt], 0.5, 100)[-1][0]))


def shrunk(image, gt, px):
    """The frame scaled so that the object is `px` tall, on a canvas of the frame's size."""
    H, W = image.shape[:2]
    s = px / gt["bbox"][3]
    small = cv2.resize(image, (max(1, int(W * s)), max(1, int(H * s))), interpolation=cv2.INTER_AREA)
    canvas = cv2.copyMakeBorder(small, 0, H - small.shape[0], 0, W - small.shape[1], cv2.BORDER_REFLECT)
    return canvas, {**gt, "bbox": [v * s for v in gt["bbox"]]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", required=True, help="glob of run directories")
    ap.add_argument("--class", dest="cls", required=True, choices=sorted(CLASSES))
    ap.add_argument("--to", type=float, nargs="+", default=[100.0, 60.0], help="target heights (px)")
    ap.add_argument("--min-height", type=float, default=100.0)
    ap.add_argument("--detector", type=Path, default=DETECTOR)
    ap.add_argument("--plot", type=Path, default=None)
    a = ap.parse_args(argv)
    cid = CLASSES[a.cls]
    det = YoloxDetector(a.detector)
    native = {}  # height band -> [found, n] of the natively sized objects
    large, kept = 0, {px: 0 for px in a.to}
    runs = sorted(glob.glob(a.runs))
    if not runs:
        sys.exit(f"no run directories match {a.runs}")
    for run in runs:
        res = Path(run) / "eval" / "realism.json"
        if not res.is_file():
            continue
        d = json.loads(res.read_text())
        for img in sorted({x["image_id"] for x in d["ground_truth"]}):
            gts = [x for x in d["ground_truth"] if x["image_id"] == img and x["category_id"] == cid
                   and not x["ignore"] and x["bbox"][3] >= 40]
            if not gts:
                continue
            dts = [x for x in d["detections"] if x["image_id"] == img and x["category_id"] == cid and x["score"] >= 0.3]
            hit = np.isfinite(match_image(dts, gts, 0.5, 100)[-1])  # at full size: `blendgen realism`'s detections
            for g, ok in zip(gts, hit):
                band = 40 * 2 ** int(np.log2(g["bbox"][3] / 40))
                native.setdefault(band, [0, 0])
                native[band][0] += bool(ok)
                native[band][1] += 1
            probe = [g for g, ok in zip(gts, hit) if ok and g["bbox"][3] >= a.min_height]
            if not probe:
                continue
            image = cv2.imread(str(Path(run) / "frames" / img / "composite.png"))
            for g in probe:
                large += 1
                for px in a.to:
                    kept[px] += found(det, *shrunk(image, g, px), cid)
    print(f"{a.cls}: {len(runs)} runs\n\n| objects | n | found |\n|---|---:|---:|")
    for band in sorted(native):
        f, n = native[band]
        print(f"| natively {band}-{2 * band} px | {n} | {f} ({f / n:.2f}) |")
    for px in a.to:
        print(f"| found at >= {a.min_height:.0f} px, shrunk to {px:.0f} px | {large} | {kept[px]}"
              + (f" ({kept[px] / large:.2f}) |" if large else " |"))
    if a.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(5, 3.5))
        bands = sorted(native)
        ax.plot([b * 1.41 for b in bands], [native[b][0] / native[b][1] for b in bands], "o-", label="natively")
        if large:
            ax.plot(a.to, [kept[px] / large for px in a.to], "s--", label="found large ones, shrunk")
        ax.set(xscale="log", xlabel="object height (px)", ylabel="found (score >= 0.3, IoU >= 0.5)",
               title=a.cls, ylim=(0, 1.05))
        ax.legend()
        fig.tight_layout()
        a.plot.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(a.plot, dpi=120)
        print(f"\nplot: {a.plot}")


if __name__ == "__main__":
    main()
