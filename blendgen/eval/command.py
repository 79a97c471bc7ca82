"""`blendgen realism OUT --detector MODEL.onnx [--compare OUT2]`."""

from __future__ import annotations

import sys
from pathlib import Path


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "realism", help="score how well a COCO detector finds the injected objects (P/R/F1/AP@0.5)",
        description="Run an ONNX YOLOX COCO detector over OUT's composites and score it against the "
                    "injected labels, per class, at IoU 0.5.")
    p.add_argument("out", type=Path, help="a job's output folder")
    p.add_argument("--detector", type=Path, required=True, help="YOLOX ONNX model (e.g. yolox_nano.onnx)")
    p.add_argument("--compare", type=Path, default=None, metavar="OUT2", help="a second output, side by side")
    p.add_argument("--iou", type=float, default=0.5, help="match threshold (default 0.5)")
    p.add_argument("--score-threshold", type=float, default=0.3,
                   help="detections at or above it count for Precision/Recall/F1 (default 0.3)")
    p.add_argument("--background", choices=["auto", "none"], default="auto",
                   help="auto: ignore what the detector finds on the real frame (real objects)")
    p.add_argument("--max-frames", type=int, default=None)
    p.set_defaults(func=_run)


def _run(args) -> int:
    from blendgen.errors import UserError
    from blendgen.eval.realism import run_realism

    if not args.out.is_dir():
        raise UserError("output folder does not exist", where=str(args.out))
    if args.compare is not None and not args.compare.is_dir():
        raise UserError("output folder does not exist", where=f"--compare {args.compare}")

    def progress(k, n):
        if sys.stderr.isatty():
            print(f"\rrealism: {k}/{n} frames", end="" if k < n else "\n", file=sys.stderr)

    res = run_realism(args.out, args.detector, compare=args.compare, iou=args.iou,
                      score_threshold=args.score_threshold, background=args.background,
                      max_frames=args.max_frames, progress=progress)
    print(res["table"])
    print(f"\nwritten: {args.out / 'eval' / 'realism.md'}")
    return 0
