"""The per-frame labels file `frames/<frame_id>/labels.json`, written by the frame worker
and read by the exporters, the realism score and the report.

Format (JSON object, version 1):
    {"format": "blendgen-frame-labels", "version": 1,
     "frame_id": "f000012",
     "image": "composite.png",        # relative to this file's folder (or to OUT)
     "width": 1280, "height": 720,
     "camera": {"fx", "fy", "cx", "cy", ...} | null,   # intrinsics at this resolution
     "instances": [ ...dicts from blendgen.labels.instances.extract_instances... ],
     "real": [ ...dicts from blendgen.labels.real_objects.real_instances... ]}   # optional

Each instance holds: id, track_id, cls, category_id, bbox [x,y,w,h], area, visible_px,
amodal_px, segmentation (COCO RLE, counts as str), occlusion, truncation, distance_m,
box3d_cam {location, dimensions_hwl, rotation_y, alpha, R_cam_obj, corners}, scenario,
state, ignore, source ("injected").

`instances` are the injected objects; `real` the real road users of the background frame
(source "user" or "detector"; no 3-D box; their mask is the visible part of their box; cls
"ignore" with category_id 0 is an ignore region of no known class). `all_instances(doc)` is
both, what the exporters write.
"""

from __future__ import annotations

import json
from pathlib import Path

from blendgen import CLASSES, atomic
from blendgen.errors import UserError

FORMAT = "blendgen-frame-labels"
VERSION = 1
_REQUIRED_INSTANCE = {"id": int, "cls": str, "category_id": int, "bbox": list, "area": (int, float),
                      "segmentation": dict, "ignore": bool}


def write_frame_labels(path, frame_id: str, image_relpath: str, width: int, height: int,
                       instances: list[dict], *, camera=None, real: list[dict] | None = None) -> None:
    """Write one frame's labels atomically. `camera`: optional blendgen Camera (for KITTI calib);
    `real`: labels of the real road users (labels.real_objects)."""
    doc = {
        "format": FORMAT, "version": VERSION,
        "frame_id": str(frame_id), "image": str(image_relpath),
        "width": int(width), "height": int(height),
        "camera": camera.to_dict() if camera is not None else None,
        "instances": list(instances),
    }
    if real is not None:
        doc["real"] = list(real)
    _validate(doc, Path(path))
    atomic.write_json(path, doc)


def read_frame_labels(path) -> dict:
    """Read and validate a labels file. Adds `path` and `image_path` (resolved, absolute)."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UserError("labels file does not exist", where=str(path)) from None
    except json.JSONDecodeError as e:
        raise UserError(f"not valid JSON ({e.msg} at line {e.lineno})", where=str(path)) from None
    _validate(doc, path)
    doc["path"] = path
    doc["image_path"] = resolve_image(path, doc["image"])
    return doc


def all_instances(doc: dict) -> list[dict]:
    """Injected and real labels of a frame (read_frame_labels() dict), injected first."""
    return list(doc["instances"]) + list(doc.get("real") or [])


def find_frame_labels(out_dir: Path) -> list[Path]:
    """All frames/<id>/labels.json under OUT, sorted."""
    return sorted(Path(out_dir).glob("frames/*/labels.json"))


def resolve_image(labels_path: Path, image: str) -> Path:
    """The image is relative to the labels file's folder; OUT-relative paths are accepted too."""
    p = Path(image)
    if p.is_absolute():
        return p
    candidates = [labels_path.parent / p]
    if len(labels_path.parents) >= 3:  # OUT/frames/<id>/labels.json -> OUT
        candidates.append(labels_path.parents[2] / p)
    for c in candidates:
        if c.exists():
            return c.resolve()
    return candidates[0].resolve()


def _validate(doc, path: Path) -> None:
    where = str(path)
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise UserError(f"expected a JSON object with format {FORMAT!r}", where=where)
    if doc.get("version") != VERSION:
        raise UserError(f"version {doc.get('version')!r} not supported (expected {VERSION})", where=where)
    for key, typ in (("frame_id", str), ("image", str), ("width", int), ("height", int),
                     ("instances", list)):
        if not isinstance(doc.get(key), typ):
            raise UserError(f"field {key!r} missing or not {typ.__name__}", where=where)
    if doc["width"] <= 0 or doc["height"] <= 0:
        raise UserError(f"width/height must be positive, got {doc['width']}x{doc['height']}", where=where)
    if not isinstance(doc.get("real", []), list):
        raise UserError("field 'real' must be a list", where=where)
    items = [("instances", i, x) for i, x in enumerate(doc["instances"])]
    items += [("real", i, x) for i, x in enumerate(doc.get("real") or [])]
    for part, i, inst in items:
        w = f"{where}: {part}[{i}]"
        if not isinstance(inst, dict):
            raise UserError("expected an object", where=w)
        for key, typ in _REQUIRED_INSTANCE.items():
            if not isinstance(inst.get(key), typ):
                raise UserError(f"field {key!r} missing or of the wrong type", where=w)
        if part == "real" and (inst["cls"], inst["category_id"]) == ("ignore", 0):
            pass  # an ignore region of no known class (KITTI DontCare)
        elif inst["cls"] not in CLASSES or CLASSES[inst["cls"]] != inst["category_id"]:
            raise UserError(f"class {inst['cls']!r} / category_id {inst['category_id']} is not one of "
                            f"{CLASSES}", where=w)
        if len(inst["bbox"]) != 4 or inst["bbox"][2] <= 0 or inst["bbox"][3] <= 0:
            raise UserError(f"bbox must be [x, y, w, h] with w, h > 0, got {inst['bbox']}", where=w)
        if list(inst["segmentation"].get("size", [])) != [doc["height"], doc["width"]]:
            raise UserError(f"segmentation size {inst['segmentation'].get('size')} does not match the "
                            f"image {doc['height']}x{doc['width']} (height, width)", where=w)
