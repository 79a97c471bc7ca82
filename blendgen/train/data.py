"""Training and test images for `blendgen train-check` (numpy only; no torch here).

A training source is a blendgen output folder (its labels/coco.json: injected objects and,
per labels.real, the real road users, ignore regions as iscrowd), any COCO file, or a
recording with its own labels (`REC/labels.json`, e.g. the user's labelled frames). A test set
is a labelled image folder (COCO file, YOLO or KITTI label folder; blendgen.recording.labels).

Boxes are kept in blendgen classes and COCO category ids; the detector's 80-class head is kept,
so a class is trained on its COCO index (COCO80_TO_ID).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from blendgen import CLASSES
from blendgen.detection.detector import COCO80_TO_ID, letterbox
from blendgen.errors import UserError

ID_TO_INDEX = {cid: k for k, cid in enumerate(COCO80_TO_ID)}
CLASS_OF_ID = {cid: name for name, cid in CLASSES.items()}


@dataclass
class Sample:
    """One image: its file, size, boxes [x0, y0, x1, y1] with COCO category ids, ignore regions."""
    path: Path
    width: int
    height: int
    boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    category_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    ignores: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    sources: list[str] = field(default_factory=list)  # per box: injected / user / detector (blendgen outputs)


def _xyxy(b) -> list[float]:
    x, y, w, h = (float(v) for v in b)
    return [x, y, x + w, y + h]


def from_coco(path: Path, root: Path | None = None) -> list[Sample]:
    """Samples of a COCO file; image file names relative to `root` (default: the file's folder,
    or for a blendgen OUT/labels/coco.json, OUT)."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as e:
        raise UserError(f"not a readable COCO file ({e})", where=str(path)) from None
    if root is None:
        root = path.parent.parent if path.parent.name == "labels" else path.parent
    by_img: dict = {im["id"]: [] for im in doc.get("images", [])}
    for a in doc.get("annotations", []):
        by_img.setdefault(a["image_id"], []).append(a)
    out = []
    for im in doc.get("images", []):
        p = Path(im["file_name"])
        p = p if p.is_absolute() else Path(root) / p
        if not p.is_file():
            raise UserError(f"image {im['file_name']} not found (looked at {p})", where=str(path))
        anns = by_img[im["id"]]
        keep = [a for a in anns if not a.get("iscrowd") and a["category_id"] in CLASS_OF_ID]
        crowd = [a for a in anns if a.get("iscrowd")]
        out.append(Sample(p, int(im["width"]), int(im["height"]),
                          np.array([_xyxy(a["bbox"]) for a in keep], float).reshape(-1, 4),
                          np.array([a["category_id"] for a in keep], int),
                          np.unique(np.array([_xyxy(a["bbox"]) for a in crowd], float).reshape(-1, 4), axis=0),
                          [(a.get("attributes") or {}).get("source", "injected") for a in keep]))
    return out


def from_recording(root: Path) -> list[Sample]:
    """The labelled frames of a recording with its own labels (labels.json)."""
    from blendgen.recording.folder import read_recording
    from blendgen.recording.labels import read_recording_labels

    rec = read_recording(root, require_frames=True)
    labels = read_recording_labels(rec)
    if labels is None:
        raise UserError("the recording has no labels.json (import its labels with `blendgen import images "
                        "DIR REC --labels PATH --label-format ...`)", where=str(root))
    if rec.frame_files is None:
        raise UserError("training from a video recording's labels is not supported: import stills", where=str(root))
    out = []
    for fid, boxes in sorted(labels.items()):
        i = int(fid.lstrip("f"))
        out.append(_sample(Path(rec.root) / rec.frame_files[i], rec.camera.width, rec.camera.height, boxes, "user"))
    return out


def from_labelled(images) -> list[Sample]:
    """recording.labels.LabelledImage list -> samples."""
    return [_sample(im.path, im.width, im.height, im.boxes, "user") for im in images]


def _sample(path, W, H, boxes, source) -> Sample:
    keep = [b for b in boxes if not b["ignore"] and b["cls"] in CLASSES]
    ign = [b for b in boxes if b["ignore"]]
    return Sample(Path(path), int(W), int(H), np.array([_xyxy(b["box"]) for b in keep], float).reshape(-1, 4),
                  np.array([CLASSES[b["cls"]] for b in keep], int),
                  np.array([_xyxy(b["box"]) for b in ign], float).reshape(-1, 4), [source] * len(keep))


def load_source(path: Path) -> list[Sample]:
    """A training source: blendgen output folder, COCO file, or recording with labels.json."""
    path = Path(path)
    if path.is_file() and path.suffix == ".json":
        return from_coco(path)
    if (path / "labels" / "coco.json").is_file():
        return from_coco(path / "labels" / "coco.json", path)
    if (path / "calib.yaml").is_file():
        return from_recording(path)
    raise UserError("expected a blendgen output folder (with labels/coco.json: export.formats must include coco), "
                    "a COCO .json file, or a recording folder with labels.json", where=str(path))


def load_image(sample: Sample, size: int, flip: bool = False):
    """(3 x size x size float32 BGR 0-255 letterboxed as the ONNX export expects, boxes and
    ignores in input pixels, class indices of the 80-class head)."""
    img = cv2.imread(str(sample.path), cv2.IMREAD_COLOR)
    if img is None:
        raise UserError("does not decode as an image", where=str(sample.path))
    if img.shape[:2] != (sample.height, sample.width):
        raise UserError(f"is {img.shape[1]}x{img.shape[0]}, its labels say {sample.width}x{sample.height}",
                        where=str(sample.path))
    boxes, ign = sample.boxes.copy(), sample.ignores.copy()
    if flip:
        img = img[:, ::-1]
        for b in (boxes, ign):
            b[:, [0, 2]] = sample.width - b[:, [2, 0]]
    padded, r = letterbox(np.ascontiguousarray(img), (size, size))
    x = np.ascontiguousarray(padded.transpose(2, 0, 1), dtype=np.float32)
    cls = np.array([ID_TO_INDEX[c] for c in sample.category_ids], int)
    return x, boxes * r, cls, ign * r
