"""`blendgen train-check TRAIN... --test IMAGES --test-labels PATH --test-format yolo`."""

from __future__ import annotations

import sys
from pathlib import Path

from blendgen.errors import UserError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "train-check", help="fine-tune a COCO detector on a training set and score it on real labelled photos "
                            "(AP@0.5 per class, bootstrap intervals, several seeds; needs torch)",
        description="What is a training set worth? Fine-tunes the COCO-pretrained YOLOX-Nano (bundled) on the "
                    "TRAIN sources, once per seed, and scores it and the pretrained model on a real labelled "
                    "test set: AP@0.5 per class (pycocotools), mean over seeds, 95 %% bootstrap intervals over "
                    "test images, and the paired difference fine-tuned - pretrained. Needs torch "
                    "(pip install 'blendgen[train]').")
    p.add_argument("train", nargs="+", type=Path,
                   help="training sources, pooled: blendgen output folders (labels/coco.json), COCO .json files, "
                        "or recordings with their own labels (labels.json)")
    p.add_argument("--test", type=Path, required=True, help="folder of real test images")
    p.add_argument("--test-labels", type=Path, required=True, help="their labels: COCO .json, YOLO or KITTI folder")
    p.add_argument("--test-format", choices=["coco", "yolo", "kitti"], required=True)
    p.add_argument("--class-map", action="append", metavar="NAME=CLASS",
                   help="test label classes that are not blendgen class names (see `blendgen import images`)")
    p.add_argument("--seeds", default="0,1,2", help="training seeds, comma-separated (default 0,1,2)")
    p.add_argument("--epochs", type=float, default=5.0, help="passes over the training images (default 5)")
    p.add_argument("--images", type=int, default=None,
                   help="train on this many images (a seeded subset; default all): equal for compared sets")
    p.add_argument("--batch", type=int, default=8, help="images per step (default 8)")
    p.add_argument("--bootstrap", type=int, default=1000, help="bootstrap draws over test images (default 1000)")
    p.add_argument("--detector", type=Path, default=None,
                   help="a YOLOX-Nano ONNX export to start from (default: the bundled one)")
    p.add_argument("--threads", type=int, default=0, help="CPU threads for torch (default: torch's choice)")
    p.add_argument("--out", type=Path, default=None,
                   help="where train_check.{md,json} go (default: TRAIN/eval/ of the first output folder, else .)")
    p.set_defaults(func=_run)


def _run(args) -> int:
    try:
        import torch
    except ImportError:
        raise UserError("train-check needs PyTorch, which is an optional extra: pip install 'blendgen[train]' "
                        "(the CPU build, torch==2.13.0)") from None
    from blendgen import atomic
    from blendgen.detection.detector import BUNDLED_MODEL
    from blendgen.recording.labels import labelled_folder
    from blendgen.train.check import train_check
    from blendgen.train.data import from_labelled, load_source
    from blendgen.train.report import results_table

    try:
        seeds = [int(s) for s in str(args.seeds).split(",") if s.strip()]
    except ValueError:
        raise UserError(f"--seeds: expected integers separated by commas, got {args.seeds!r}") from None
    if not seeds or args.epochs <= 0 or args.batch < 1 or (args.images is not None and args.images < 1):
        raise UserError("--seeds needs one seed or more; --epochs, --batch and --images must be positive")
    if args.threads:
        torch.set_num_threads(args.threads)
    train = [s for src in args.train for s in load_source(src)]
    test = from_labelled(labelled_folder(args.test, args.test_labels, args.test_format, class_map=args.class_map))
    model = args.detector or BUNDLED_MODEL
    out = args.out or next((p / "eval" for p in args.train if (p / "labels" / "coco.json").is_file()), Path("."))

    def progress(seed, step, steps, loss):
        if sys.stderr.isatty():
            print(f"\rtrain-check: seed {seed} step {step}/{steps} loss {loss:.3f}", end="" if step < steps else "\n",
                  file=sys.stderr)

    res = train_check(train, test, model_path=model, seeds=seeds, epochs=args.epochs, images=args.images,
                      batch=args.batch, n_boot=args.bootstrap, progress=progress)
    cmd = "blendgen train-check " + " ".join(sys.argv[2:]) if len(sys.argv) > 2 else "blendgen train-check"
    table = results_table(res, train_images=min(len(train), args.images or len(train)), test_images=len(test),
                          command=cmd)
    atomic.write_text(out / "train_check.md", table + "\n")
    atomic.write_json(out / "train_check.json", {k: v for k, v in res.items() if k != "records"}, indent=1)
    print(table)
    print(f"\nwritten: {out / 'train_check.md'}")
    return 0
