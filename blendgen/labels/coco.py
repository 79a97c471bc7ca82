"""COCO instance-segmentation file: RLE masks, COCO category ids for the seven classes.

Objects marked `ignore` (below min_visible_px, uncertain real detections, the user's own
ignore regions) become `iscrowd: 1`, which is how COCO tools (COCOeval) treat regions that
must neither count as misses nor as false positives. An ignore region of no known class
(KITTI's DontCare in the user's labels) is written once per category. Every annotation's
`attributes.source` says where it came from: injected, user or detector.
"""

from __future__ import annotations

import os
from pathlib import Path

from blendgen import CLASSES, __version__, atomic
from blendgen.frame_labels import all_instances

SUPERCATEGORY = {"person": "person", "bicycle": "vehicle", "car": "vehicle", "motorcycle": "vehicle",
                 "bus": "vehicle", "truck": "vehicle", "traffic light": "outdoor"}
ATTRIBUTES = ("source", "track_id", "occlusion", "truncation", "distance_m", "scenario", "state", "visible_px",
              "amodal_px", "box3d_cam", "score", "label")


def build_coco(frames: list[dict], root: Path) -> dict:
    """frames: read_frame_labels() dicts. Image file names are relative to `root` (OUT)."""
    images, annotations = [], []
    for image_id, fr in enumerate(frames, start=1):
        images.append({"id": image_id, "file_name": _rel(fr["image_path"], root), "width": fr["width"],
                       "height": fr["height"], "frame_id": fr["frame_id"]})
        for inst in all_instances(fr):
            for cat in ([inst["category_id"]] if inst["category_id"] else CLASSES.values()):
                ann = {"id": len(annotations) + 1, "image_id": image_id, "category_id": cat,
                       "segmentation": dict(inst["segmentation"]), "area": int(inst["area"]),
                       "bbox": [float(v) for v in inst["bbox"]], "iscrowd": int(bool(inst["ignore"]))}
                ann["attributes"] = {k: inst.get(k) for k in ATTRIBUTES}
                ann["attributes"]["source"] = inst.get("source", "injected")
                annotations.append(ann)
    categories = [{"id": cid, "name": name, "supercategory": SUPERCATEGORY[name]}
                  for name, cid in CLASSES.items()]
    info = {"description": "blendgen synthetic-on-real composites", "version": __version__}
    return {"info": info, "images": images, "annotations": annotations, "categories": categories}


def write_coco(path: Path, frames: list[dict], root: Path) -> dict:
    doc = build_coco(frames, root)
    atomic.write_json(path, doc)
    return doc


def _rel(p: Path, root: Path) -> str:
    return Path(os.path.relpath(Path(p).resolve(), Path(root).resolve())).as_posix()
