"""Export per-frame labels (frames/<id>/labels.json) to COCO, YOLO and KITTI under OUT/labels/."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from blendgen.errors import UserError
from blendgen.frame_labels import all_instances, read_frame_labels
from blendgen.labels.coco import write_coco
from blendgen.labels.kitti import write_kitti
from blendgen.labels.yolo import write_yolo

FORMATS = ("coco", "yolo", "kitti")


def export_labels(out_dir: Path, frame_label_paths: list[Path], formats: list[str], *,
                  kitti_types: str = "kitti", yolo_val_fraction: float = 0.0, seed: int = 0) -> dict:
    """Write OUT/labels/{coco.json, yolo/, kitti/} for the given frames; returns a summary.

    Frames are exported in frame-id order so that re-exports are byte-identical.
    """
    out_dir = Path(out_dir)
    unknown = [f for f in formats if f not in FORMATS]
    if unknown:
        raise UserError(f"unknown label format(s) {unknown}; expected some of {list(FORMATS)}",
                        where="export.formats")
    frames = sorted((read_frame_labels(p) for p in frame_label_paths), key=lambda f: f["frame_id"])
    dup = [k for k, n in Counter(f["frame_id"] for f in frames).items() if n > 1]
    if dup:
        raise UserError(f"frame ids appear in more than one labels file: {dup[:5]}", where=str(out_dir))
    for fr in frames:
        if not fr["image_path"].exists():
            raise UserError(f"image {fr['image']} not found (looked at {fr['image_path']})",
                            where=str(fr["path"]))
    labels = out_dir / "labels"
    insts = [i for f in frames for i in all_instances(f)]
    summary: dict = {"frames": len(frames), "formats": list(formats),
                     "instances": len(insts),
                     "ignored": sum(i["ignore"] for i in insts),
                     "per_class": dict(Counter(i["cls"] for i in insts if not i["ignore"])),
                     **source_counts(insts)}
    if "coco" in formats:
        write_coco(labels / "coco.json", frames, out_dir)
        summary["coco"] = str(labels / "coco.json")
    if "yolo" in formats:
        summary["yolo"] = write_yolo(labels / "yolo", frames, yolo_val_fraction, seed)
    if "kitti" in formats:
        summary["kitti"] = write_kitti(labels / "kitti", frames, kitti_types)
    return summary


def source_counts(insts: list[dict]) -> dict:
    """Labels and ignore regions per source (injected, user, detector)."""
    src = lambda i: i.get("source", "injected")  # noqa: E731
    return {"per_source": dict(sorted(Counter(src(i) for i in insts if not i["ignore"]).items())),
            "ignored_per_source": dict(sorted(Counter(src(i) for i in insts if i["ignore"]).items()))}
