"""Ultralytics YOLO datasets: boxes (detect) and polygons (segment).

Ultralytics finds a label file by replacing `/images/` with `/labels/` in the image path,
and a file holds either boxes or polygons, so there are two datasets side by side:

    labels/yolo/           data.yaml, train.txt, images/<frame>.png (links), labels/<frame>.txt
    labels/yolo/seg/       data.yaml, train.txt, images/<frame>.png (links), labels/<frame>.txt

Box lines: `cls cx cy w h`; polygon lines: `cls x1 y1 x2 y2 ...`, all normalised to 0..1
with pixel (u, v) covering [u, u+1) (COCO's convention). Class index = position in
blendgen.CLASSES.

YOLO has no ignore region. Left out, an ignore region (an uncertain real detection, a
tiny object, the user's own ignore box) would be background to the trainer: the very thing
an ignore region must not be. So its visible pixels are painted grey (114, the value YOLO
letterboxes with) in YOLO's copy of that frame's image, and no line is written: the region
is then neither object nor background. Frames without ignore regions link the composite.
Label files cannot say where a label came from: sources/<frame>.txt holds, line for line,
injected, user or detector.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import cv2
import numpy as np

from blendgen import CLASSES, atomic
from blendgen.frame_labels import all_instances
from blendgen.labels.instances import decode_mask

IGNORE_GREY = 114

NAMES = list(CLASSES)


def box_line(inst: dict, W: int, H: int) -> str:
    x, y, w, h = inst["bbox"]
    return f"{NAMES.index(inst['cls'])} {(x + w / 2) / W:.6f} {(y + h / 2) / H:.6f} {w / W:.6f} {h / H:.6f}"


def mask_polygon(mask: np.ndarray) -> np.ndarray:
    """One polygon (Nx2, pixel-centre coordinates) outlining every component of the mask.

    Components are joined by zero-width bridges at their closest points, as Ultralytics'
    own COCO converter does, because a YOLO segment line holds exactly one polygon.
    """
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    contours = sorted((c.reshape(-1, 2).astype(float) for c in contours), key=lambda c: c[:, 0].min())
    if not contours:
        return np.zeros((0, 2))
    poly = contours[0]
    for c in contours[1:]:
        d = np.linalg.norm(poly[:, None, :] - c[None, :, :], axis=2)
        i, j = np.unravel_index(np.argmin(d), d.shape)
        poly = np.concatenate([poly[:i + 1], c[j:], c[:j + 1], poly[i:]])
    return poly


def segment_line(inst: dict, W: int, H: int) -> str:
    x, y, w, h = (int(v) for v in inst["bbox"])
    # Contours on the box crop only (the box is tight), shifted back to image coordinates.
    poly = mask_polygon(decode_mask(inst["segmentation"])[y:y + h, x:x + w]) + [x, y]
    if len(poly) < 3:  # a line or a single pixel: outline its box instead
        pts = np.array([[x, y], [x + w, y], [x + w, y + h], [x, y + h]], dtype=float)
    else:
        pts = poly + 0.5  # pixel centre -> COCO continuous coordinates
    pts = np.clip(pts / [W, H], 0.0, 1.0)
    return f"{NAMES.index(inst['cls'])} " + " ".join(f"{v:.6f}" for v in pts.ravel())


def data_yaml(root: Path, val: str = "train.txt") -> str:
    names = "\n".join(f"  {i}: {n}" for i, n in enumerate(NAMES))
    return f"path: {root.resolve()}\ntrain: train.txt\nval: {val}\nnames:\n{names}\n"


def val_frames(frame_ids: list[str], fraction: float, seed: int) -> set[str]:
    """The frames of the validation split: round(fraction * n) of them (at least one when
    fraction > 0 and there are two frames), drawn with the job's seed, so the split is the
    same on every export of the same frames."""
    if fraction <= 0 or len(frame_ids) < 2:
        return set()
    k = min(len(frame_ids) - 1, max(1, round(fraction * len(frame_ids))))
    pick = np.random.default_rng(seed).permutation(len(frame_ids))[:k]
    return {sorted(frame_ids)[i] for i in pick}


def write_yolo(root: Path, frames: list[dict], val_fraction: float = 0.0, seed: int = 0) -> dict:
    """With val_fraction 0, `val` = `train` (one split); otherwise val.txt holds that share of
    the frames (by frame, seeded) and train.txt the rest."""
    files = 0
    val = val_frames([fr["frame_id"] for fr in frames], val_fraction, seed)
    for sub, make_line in ((root, box_line), (root / "seg", segment_line)):
        listing, val_listing = [], []
        for fr in frames:
            name = fr["frame_id"] + Path(fr["image_path"]).suffix
            insts = all_instances(fr)
            ignored = [i for i in insts if i["ignore"]]
            if not ignored:
                link_image(sub / "images" / name, fr["image_path"])
            elif sub == root:
                write_masked(sub / "images" / name, fr["image_path"], ignored)
            else:  # the segment set shares the detect set's painted copy
                link_image(sub / "images" / name, root / "images" / name)
            kept = [i for i in insts if not i["ignore"]]
            lines = [make_line(i, fr["width"], fr["height"]) for i in kept]
            atomic.write_text(sub / "labels" / f"{fr['frame_id']}.txt", "".join(l + "\n" for l in lines))
            atomic.write_text(sub / "sources" / f"{fr['frame_id']}.txt",
                              "".join(i.get("source", "injected") + "\n" for i in kept))
            (val_listing if fr["frame_id"] in val else listing).append(f"./images/{name}")
            files += 1
        atomic.write_text(sub / "train.txt", "".join(l + "\n" for l in listing))
        if val:
            atomic.write_text(sub / "val.txt", "".join(l + "\n" for l in val_listing))
        else:
            (sub / "val.txt").unlink(missing_ok=True)
        atomic.write_text(sub / "data.yaml", data_yaml(sub, "val.txt" if val else "train.txt"))
    return {"dir": str(root), "label_files": files, "train_frames": len(frames) - len(val),
            "val_frames": len(val)}


def write_masked(path: Path, image: Path, ignored: list[dict]) -> None:
    """A copy of `image` with the ignore regions' pixels grey (see the module docstring)."""
    img = cv2.imread(str(image), cv2.IMREAD_UNCHANGED)
    for inst in ignored:
        img[decode_mask(inst["segmentation"]) > 0] = IGNORE_GREY
    if path.is_symlink():
        path.unlink()  # an earlier export's link: never write through it onto the composite
    atomic.write_image(path, img)


def link_image(link: Path, target: Path) -> None:
    """A relative symlink to the composite (a copy where links are not allowed), atomically."""
    link.parent.mkdir(parents=True, exist_ok=True)
    rel = os.path.relpath(Path(target).resolve(), link.parent.resolve())
    tmp = link.with_name(f".{link.name}.tmp{os.getpid()}")
    if tmp.is_symlink() or tmp.exists():
        tmp.unlink()
    try:
        os.symlink(rel, tmp)
    except OSError:
        shutil.copyfile(target, tmp)
    os.replace(tmp, link)
