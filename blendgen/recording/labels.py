"""A recording's own box labels (`REC/labels.json`) and the readers of COCO, YOLO and KITTI
label files that fill it (bpy-free; also used by `blendgen train-check` for real test sets).

`REC/labels.json` (written by `blendgen import images DIR --labels PATH`):

    {"format": "blendgen-recording-labels", "version": 1,
     "width": 1280, "height": 720,            # the frames' resolution; boxes are in its pixels
     "source": {"path", "format", "class_map"},
     "frames": {"f000000": [{"cls": "car", "box": [x, y, w, h], "ignore": false, "label": "Car"}, ...]}}

A frame listed with [] is labelled and holds no road user; a frame not listed is unlabelled.
`ignore` marks the source's ignore regions (COCO iscrowd, KITTI DontCare, and classes the
class map sends to "ignore"). `label` keeps the source's class name.

Classes: a source name that is a blendgen class (any case, "_" for " ") is that class;
a few unambiguous synonyms are built in (motorbike, pedestrian, ...; KITTI's types in
KITTI_TYPES). Any other name is an error naming it unless the user's class map says what
it is: a blendgen class, "ignore" (an ignore region) or "drop" (not a road user); `*` maps
every name the rest does not.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from blendgen import CLASSES, atomic
from blendgen.errors import UserError
from blendgen.validation import load_yaml_text

FILE = "labels.json"
FORMAT = "blendgen-recording-labels"
VERSION = 1
LABEL_FORMATS = ("coco", "yolo", "kitti")
TARGETS = (*CLASSES, "ignore", "drop")
SYNONYMS = {"motorbike": "motorcycle", "pedestrian": "person", "people": "person", "trafficlight": "traffic light",
            "traffic_light": "traffic light", "traffic-light": "traffic light"}
# KITTI's object types: a Cyclist box holds the rider and the bicycle (neither blendgen box),
# Tram and Misc are no blendgen class, DontCare is KITTI's ignore region.
KITTI_TYPES = {"car": "car", "van": "car", "truck": "truck", "pedestrian": "person", "person_sitting": "person",
               "cyclist": "ignore", "tram": "ignore", "misc": "ignore", "dontcare": "ignore"}
IMAGE_EXTS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")  # what a folder of images may hold
EDGE_TOL_PX = 1.0  # a box may overshoot the image by this much (rounding in the source tool); it is clipped


@dataclass
class LabelledImage:
    """One image of a labelled set: its file, size, and boxes in blendgen classes."""
    path: Path
    width: int
    height: int
    boxes: list[dict] = field(default_factory=list)  # {"cls", "box" [x,y,w,h], "ignore", "label"}


def parse_class_map(items) -> dict[str, str]:
    """`["Van=car", "Tram=ignore", "*=drop"]` (or one comma-separated string) -> {name: target}."""
    out: dict[str, str] = {}
    if isinstance(items, str):
        items = [items]
    for item in items or []:
        for part in str(item).split(","):
            if not part.strip():
                continue
            if "=" not in part:
                raise UserError(f"class map entry {part!r}: expected NAME=CLASS (CLASS one of {list(TARGETS)})",
                                where="--class-map")
            name, target = (s.strip() for s in part.rsplit("=", 1))
            target = SYNONYMS.get(target.lower(), target.lower().replace("_", " "))
            if target not in TARGETS:
                raise UserError(f"class map entry {part!r}: {target!r} is not one of {list(TARGETS)}",
                                where="--class-map")
            out[name] = target
    return out


def resolve_class(name: str, class_map: dict[str, str], fmt: str) -> str | None:
    """The blendgen class / "ignore" / "drop" for a source class name, or None (unknown)."""
    if name in class_map:
        return class_map[name]
    low = name.strip().lower()
    for k, v in class_map.items():
        if k.lower() == low:
            return v
    if fmt == "kitti" and low in KITTI_TYPES:
        return KITTI_TYPES[low]
    cand = low.replace("_", " ")
    if cand in CLASSES:
        return cand
    if low in SYNONYMS:
        return SYNONYMS[low]
    return class_map.get("*")


# ----------------------------------------------------------------------------- source readers

def read_labels(path, fmt: str, images: dict[str, tuple[int, int]], *, class_map=None,
                names: list[str] | None = None) -> dict[str, list[dict]]:
    """Boxes per image of a COCO file, a YOLO label folder or a KITTI label_2 folder.

    images: {image file name: (width, height)} of the images the labels must describe;
    returns {image file name: [boxes]} for every labelled image (an image without a YOLO or
    KITTI label file, or absent from the COCO file, is missing from the result). Raises a
    UserError naming the file and line for a label of an image not in `images`, a box
    outside its image, and every class name the class map does not resolve.
    """
    path = Path(path)
    if fmt not in LABEL_FORMATS:
        raise UserError(f"label format {fmt!r} is not one of {list(LABEL_FORMATS)}", where="--label-format")
    class_map = parse_class_map(class_map) if not isinstance(class_map, dict) else class_map
    if not path.exists():
        raise UserError(f"{fmt} labels not found", where=str(path))
    by_stem = {}
    for name in images:
        stem = Path(name).stem
        if stem in by_stem:
            raise UserError(f"two images share the name {stem!r} ({by_stem[stem]}, {name}): label files are "
                            "matched to images by name", where=str(path))
        by_stem[stem] = name
    raw = {"coco": _read_coco, "yolo": _read_yolo, "kitti": _read_kitti}[fmt](path, by_stem, images, names)
    unknown: dict[str, int] = {}
    out: dict[str, list[dict]] = {}
    for img, entries in raw.items():
        W, H = images[img]
        boxes = []
        for label, (x0, y0, x1, y1), crowd, where in entries:
            target = resolve_class(label, class_map, fmt)
            if target is None:
                unknown[label] = unknown.get(label, 0) + 1
                continue
            if target == "drop":
                continue
            if x0 < -EDGE_TOL_PX or y0 < -EDGE_TOL_PX or x1 > W + EDGE_TOL_PX or y1 > H + EDGE_TOL_PX:
                raise UserError(f"box of {label!r} [{x0:.1f}, {y0:.1f}, {x1:.1f}, {y1:.1f}] (x0 y0 x1 y1) lies "
                                f"outside the image {img} ({W}x{H})", where=where)
            x0, y0, x1, y1 = max(x0, 0.0), max(y0, 0.0), min(x1, float(W)), min(y1, float(H))
            if x1 - x0 <= 0 or y1 - y0 <= 0:
                raise UserError(f"box of {label!r} has no area ({x0:.1f}, {y0:.1f}, {x1:.1f}, {y1:.1f})", where=where)
            ignore = crowd or target == "ignore"
            boxes.append({"cls": None if target == "ignore" else target,
                          "box": [round(x0, 2), round(y0, 2), round(x1 - x0, 2), round(y1 - y0, 2)],
                          "ignore": bool(ignore), "label": label})
        out[img] = boxes
    if unknown:
        listed = ", ".join(f"{k!r} ({n} box{'es' if n > 1 else ''})" for k, n in sorted(unknown.items()))
        raise UserError(f"class name(s) that are no blendgen class: {listed}; say what each is with "
                        f"--class-map NAME=CLASS, CLASS one of {list(TARGETS)} (e.g. --class-map "
                        f"{next(iter(sorted(unknown)))}=drop, or '*=drop' for all the others)", where=str(path))
    for boxes in out.values():  # an ignore region without a class: the class of the region is unknown
        for b in boxes:
            if b["cls"] is None:
                b["cls"] = "ignore"
    return out


def _image_of(name: str, by_stem: dict[str, str], where: str) -> str:
    stem = Path(name).stem
    if stem not in by_stem:
        raise UserError(f"labels for image {name!r}, which is not among the imported images (matched by "
                        "file name without extension)", where=where)
    return by_stem[stem]


def _read_coco(path: Path, by_stem, images, names):
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise UserError(f"not a COCO JSON file ({e})", where=str(path)) from None
    if not isinstance(doc, dict) or not all(isinstance(doc.get(k), list) for k in ("images", "annotations",
                                                                                   "categories")):
        raise UserError("expected a COCO object with lists `images`, `annotations` and `categories`", where=str(path))
    cats = {c.get("id"): str(c.get("name")) for c in doc["categories"] if isinstance(c, dict)}
    img_of, out = {}, {}
    for k, im in enumerate(doc["images"]):
        w = f"{path}: images[{k}]"
        if not isinstance(im, dict) or "id" not in im or not isinstance(im.get("file_name"), str):
            raise UserError("expected {id, file_name, width, height}", where=w)
        img_of[im["id"]] = (im, w)
    annotated = {a.get("image_id") for a in doc["annotations"] if isinstance(a, dict)}
    for iid, (im, w) in img_of.items():
        stem = Path(im["file_name"]).stem
        if stem not in by_stem:
            if iid in annotated:
                _image_of(im["file_name"], by_stem, w)  # raises: labels for an image we do not have
            continue
        name = by_stem[stem]
        W, H = images[name]
        if (im.get("width"), im.get("height")) not in ((W, H), (None, None)):
            raise UserError(f"says {im['file_name']} is {im.get('width')}x{im.get('height')}, but the image is "
                            f"{W}x{H}", where=w)
        out[name] = []
    for k, a in enumerate(doc["annotations"]):
        w = f"{path}: annotations[{k}]"
        if not isinstance(a, dict) or a.get("image_id") not in img_of:
            raise UserError(f"image_id {a.get('image_id') if isinstance(a, dict) else a!r} is not in `images`", where=w)
        if a.get("category_id") not in cats:
            raise UserError(f"category_id {a.get('category_id')!r} is not in `categories`", where=w)
        bbox = a.get("bbox")
        if not (isinstance(bbox, list) and len(bbox) == 4 and all(isinstance(v, (int, float)) for v in bbox)):
            raise UserError(f"bbox must be [x, y, w, h], got {bbox!r}", where=w)
        name = by_stem[Path(img_of[a["image_id"]][0]["file_name"]).stem]
        x, y, bw, bh = (float(v) for v in bbox)
        out[name].append((cats[a["category_id"]], (x, y, x + bw, y + bh), bool(a.get("iscrowd", 0)), w))
    return out


def yolo_names(labels_dir: Path) -> list[str]:
    """Class names of a YOLO label folder: `names` of a data.yaml (or any *.yaml with names) in the
    folder or up to two folders above it (Ultralytics and Roboflow layouts), else classes.txt."""
    for d in (labels_dir, labels_dir.parent, labels_dir.parent.parent):
        for y in sorted(d.glob("*.yaml")) + sorted(d.glob("*.yml")):
            data = load_yaml_text(y, "YOLO dataset")
            names = data.get("names") if isinstance(data, dict) else None
            if isinstance(names, dict):
                names = [names[k] for k in sorted(names)]
            if isinstance(names, list) and names:
                return [str(n) for n in names]
        for txt in ("classes.txt", "obj.names"):
            if (d / txt).is_file():
                return [ln.strip() for ln in (d / txt).read_text().splitlines() if ln.strip()]
    raise UserError("no class names for the YOLO labels: expected a data.yaml with `names` (or classes.txt) in "
                    "the label folder or up to two folders above it", where=str(labels_dir))


def _read_yolo(path: Path, by_stem, images, names):
    if not path.is_dir():
        raise UserError("YOLO labels: expected a folder of <image name>.txt files", where=str(path))
    names = names or yolo_names(path)
    out = {}
    for txt in sorted(path.glob("*.txt")):
        if txt.name in ("classes.txt",):
            continue
        name = _image_of(txt.name, by_stem, str(txt))
        W, H = images[name]
        rows = []
        for ln, line in enumerate(txt.read_text().splitlines(), start=1):
            f = line.split()
            if not f:
                continue
            w = f"{txt}: line {ln}"
            if len(f) != 5:
                raise UserError(f"expected `class cx cy w h` (5 numbers, a box), got {len(f)} fields", where=w)
            try:
                c = int(f[0])
                cx, cy, bw, bh = (float(v) for v in f[1:])
            except ValueError:
                raise UserError(f"not numbers: {line.strip()!r}", where=w) from None
            if not 0 <= c < len(names):
                raise UserError(f"class index {c} but the dataset names {len(names)} classes", where=w)
            rows.append((names[c], ((cx - bw / 2) * W, (cy - bh / 2) * H, (cx + bw / 2) * W, (cy + bh / 2) * H),
                         False, w))
        out[name] = rows
    return out


def _read_kitti(path: Path, by_stem, images, names):
    if not path.is_dir():
        raise UserError("KITTI labels: expected a label_2 folder of <image name>.txt files", where=str(path))
    out = {}
    for txt in sorted(path.glob("*.txt")):
        name = _image_of(txt.name, by_stem, str(txt))
        rows = []
        for ln, line in enumerate(txt.read_text().splitlines(), start=1):
            f = line.split()
            if not f:
                continue
            w = f"{txt}: line {ln}"
            if len(f) < 8:
                raise UserError("expected a KITTI object line `type truncated occluded alpha left top right "
                                f"bottom ...`, got {len(f)} fields", where=w)
            try:
                x0, y0, x1, y1 = (float(v) for v in f[4:8])
            except ValueError:
                raise UserError(f"box is not 4 numbers: {f[4:8]}", where=w) from None
            rows.append((f[0], (x0, y0, x1, y1), f[0].lower() == "dontcare", w))
        out[name] = rows
    return out


# ----------------------------------------------------------------------------- the recording's file

def write_recording_labels(root: Path, frames: dict[str, list[dict]], width: int, height: int,
                           source: dict) -> None:
    doc = {"format": FORMAT, "version": VERSION, "width": int(width), "height": int(height), "source": source,
           "frames": {k: frames[k] for k in sorted(frames)}}
    atomic.write_json(Path(root) / FILE, doc, indent=1)


def read_recording_labels(rec) -> dict[str, list[dict]] | None:
    """{frame_id: boxes} of a recording (`blendgen.recording.model.Recording`), or None when it
    carries no labels. Validated against the recording: frames that exist, boxes inside the
    frames' resolution, blendgen classes."""
    path = Path(rec.root) / FILE
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise UserError(f"not valid JSON ({e.msg} at line {e.lineno})", where=str(path)) from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or doc.get("version") != VERSION:
        raise UserError(f"expected format {FORMAT!r} version {VERSION}", where=str(path))
    W, H = doc.get("width"), doc.get("height")
    if rec.camera is not None and (W, H) != (rec.camera.width, rec.camera.height):
        raise UserError(f"labels are for {W}x{H} frames but calib.yaml says {rec.camera.width}x{rec.camera.height}",
                        where=str(path))
    frames = doc.get("frames")
    if not isinstance(frames, dict):
        raise UserError("`frames` must map frame ids (f000000) to lists of boxes", where=str(path))
    valid = {rec.frame_id(i) for i in range(rec.n_frames)}
    for fid, boxes in frames.items():
        w = f"{path}: frames.{fid}"
        if fid not in valid:
            raise UserError(f"labels for frame {fid}, which the recording does not have (it has {rec.n_frames} "
                            f"frames, f000000..{rec.frame_id(max(rec.n_frames - 1, 0))})", where=w)
        if not isinstance(boxes, list):
            raise UserError("expected a list of boxes", where=w)
        for k, b in enumerate(boxes):
            wk = f"{w}[{k}]"
            if not isinstance(b, dict) or b.get("cls") not in (*CLASSES, "ignore"):
                raise UserError(f"cls must be one of {[*CLASSES, 'ignore']}, got "
                                f"{b.get('cls') if isinstance(b, dict) else b!r}", where=wk)
            box = b.get("box")
            if not (isinstance(box, list) and len(box) == 4 and all(isinstance(v, (int, float)) for v in box)):
                raise UserError(f"box must be [x, y, w, h], got {box!r}", where=wk)
            x, y, bw, bh = box
            if bw <= 0 or bh <= 0 or x < -EDGE_TOL_PX or y < -EDGE_TOL_PX or x + bw > W + EDGE_TOL_PX \
                    or y + bh > H + EDGE_TOL_PX:
                raise UserError(f"box {box} lies outside the {W}x{H} frame or has no area", where=wk)
            b["ignore"] = bool(b.get("ignore")) or b["cls"] == "ignore"
    return frames


def labelled_folder(images_dir: Path, labels: Path, fmt: str, *, class_map=None) -> list[LabelledImage]:
    """A labelled image set (e.g. a real test split): every image of `images_dir` with its boxes.
    An image without labels is an error here (a test set must be fully labelled), except for
    YOLO, where a missing label file means no object (Ultralytics' convention)."""
    import cv2


    images_dir = Path(images_dir)
    if not images_dir.is_dir():
        raise UserError("image folder not found", where=str(images_dir))
    files = sorted(p for p in images_dir.iterdir() if p.suffix.lower() in IMAGE_EXTS)
    if not files:
        raise UserError("no images in the folder", where=str(images_dir))
    sizes = {}
    for p in files:
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise UserError("does not decode as an image", where=str(p))
        sizes[p.name] = (img.shape[1], img.shape[0])
    boxes = read_labels(labels, fmt, sizes, class_map=class_map)
    missing = [n for n in sizes if n not in boxes]
    if missing and fmt != "yolo":
        raise UserError(f"{len(missing)} image(s) have no labels, first {missing[0]}: a test set must be "
                        "fully labelled", where=str(labels))
    return [LabelledImage(images_dir / n, *sizes[n], boxes.get(n, [])) for n in sizes]
