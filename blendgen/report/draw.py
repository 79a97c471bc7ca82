"""Contact sheet: clean composites next to the same with mask outlines, boxes and tags."""

from __future__ import annotations

import cv2
import numpy as np

from blendgen import CLASSES
from blendgen.labels.instances import decode_mask

# One colour per class (BGR), distinct on road scenes.
CLASS_BGR = {"person": (60, 20, 220), "bicycle": (0, 200, 255), "car": (255, 144, 30),
             "motorcycle": (180, 0, 180), "bus": (0, 215, 100), "truck": (30, 105, 210),
             "traffic light": (0, 255, 255)}
assert set(CLASS_BGR) == set(CLASSES)


def draw_labels(img: np.ndarray, instances: list[dict], scale: float = 1.0) -> np.ndarray:
    """Mask outlines in the class colour (not fills: the composite stays visible to judge),
    boxes, and `class #track` tags placed so that they do not cover each other; ignored
    objects grey.

    `img` may be the composite resized by `scale`: masks and boxes are scaled to it, so the
    text stays sharp on a contact sheet.
    """
    H, W = img.shape[:2]
    out = img.copy()
    thick = max(1, round(W / 500))
    for inst in instances:
        if inst.get("source", "injected") != "injected":
            continue  # a real object's mask is its box: the box below shows it
        colour = (160, 160, 160) if inst["ignore"] else CLASS_BGR[inst["cls"]]
        m = decode_mask(inst["segmentation"])
        if m.shape != (H, W):
            m = cv2.resize(m, (W, H), interpolation=cv2.INTER_NEAREST)
        contours, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(out, contours, -1, (0, 0, 0), thick + 2, cv2.LINE_AA)  # dark halo: readable on any background
        cv2.drawContours(out, contours, -1, colour, thick, cv2.LINE_AA)
    boxes = []
    for inst in instances:
        colour = (160, 160, 160) if inst["ignore"] else CLASS_BGR[inst["cls"]]
        x, y, w, h = (v * scale for v in inst["bbox"])
        box = (int(x), int(y), max(int(x + w) - 1, int(x)), max(int(y + h) - 1, int(y)))
        cv2.rectangle(out, box[:2], box[2:], colour, 1, cv2.LINE_AA)
        src = inst.get("source", "injected")
        tag = f"{inst['cls']} #{inst.get('track_id', inst['id'])}" if src == "injected" else f"{inst['cls']} ({src})"
        boxes.append((box, colour, tag))
    placed: list[tuple[int, int, int, int]] = []
    font, fs = cv2.FONT_HERSHEY_SIMPLEX, 0.45 * max(1.0, W / 800)
    for (x0, y0, x1, y1), colour, tag in sorted(boxes, key=lambda b: (b[0][1], b[0][0])):
        (tw, th), base = cv2.getTextSize(tag, font, fs, 1)
        rect = _free_spot((x0, y0 - th - base - 2, tw + 4, th + base + 2), placed, W, H)
        placed.append(rect)
        rx, ry, rw, rh = rect
        cv2.rectangle(out, (rx, ry), (rx + rw, ry + rh), (0, 0, 0), -1)  # solid tag: text always legible
        cv2.putText(out, tag, (rx + 2, ry + rh - base - 1), font, fs, colour, 1, cv2.LINE_AA)
    return out


def _free_spot(rect, placed, W, H):
    """`rect` (x, y, w, h) moved down in steps of its height until it overlaps no placed tag."""
    x, y, w, h = rect
    x = min(max(0, x), max(0, W - w - 1))
    y = max(0, y)
    for _ in range(2 * H // max(h, 1) + 1):
        if not any(x < px + pw and px < x + w and y < py + ph and py < y + h for px, py, pw, ph in placed):
            break
        y += h + 1
        if y + h >= H:  # ran off the bottom: try the next column of tags to the right, from the top
            y, x = 0, min(x + w + 2, max(0, W - w - 1))
    return x, y, w, h


def contact_sheet(tiles: list[tuple[str, np.ndarray]], cols: int = 4, tile_w: int = 400) -> np.ndarray:
    """Grid of (caption, BGR image) tiles, each scaled to `tile_w` wide."""
    if not tiles:
        return np.full((60, tile_w, 3), 255, np.uint8)
    scaled = []
    for caption, im in tiles:
        h = max(1, round(im.shape[0] * tile_w / im.shape[1]))
        t = cv2.resize(im, (tile_w, h), interpolation=cv2.INTER_AREA)
        cv2.putText(t, caption, (5, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(t, caption, (5, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        scaled.append(t)
    th = max(t.shape[0] for t in scaled)
    rows = -(-len(scaled) // cols)
    sheet = np.full((rows * (th + 4), min(cols, len(scaled)) * (tile_w + 4), 3), 255, np.uint8)
    for k, t in enumerate(scaled):
        r, c = divmod(k, cols)
        sheet[r * (th + 4):r * (th + 4) + t.shape[0], c * (tile_w + 4):c * (tile_w + 4) + tile_w] = t
    return sheet


def draw_analysis(img: np.ndarray, fa, road_mask: np.ndarray | None = None) -> np.ndarray:
    """A frame's analysis over the frame: road green, bands yellow, hood magenta, horizon
    red, real road users' boxes white with class and distance; `fa` is a FrameAnalysis."""
    H, W = img.shape[:2]
    sx, sy = W / fa.width, H / fa.height
    out = img.copy()
    if road_mask is not None:
        m = cv2.resize(road_mask, (W, H), interpolation=cv2.INTER_NEAREST)
        tint = out.copy()
        tint[m == 255] = (0, 200, 0)
        tint[m == 128] = (0, 220, 255)
        out = cv2.addWeighted(tint, 0.35, out, 0.65, 0)
    thick = max(1, round(W / 640))
    if fa.hood:
        poly = np.round(np.asarray(fa.hood) * [sx, sy]).astype(np.int32)
        tint = out.copy()
        cv2.fillPoly(tint, [poly], (200, 0, 200))
        out = cv2.addWeighted(tint, 0.35, out, 0.65, 0)
    if fa.horizon:
        (u0, v0), (u1, v1) = fa.horizon
        cv2.line(out, (int(u0 * sx), int(v0 * sy)), (int(u1 * sx), int(v1 * sy)), (0, 0, 255), thick, cv2.LINE_AA)
    for o in fa.real_objects:
        x, y, w, h = o.box
        p0, p1 = (int(x * sx), int(y * sy)), (int((x + w) * sx), int((y + h) * sy))
        cv2.rectangle(out, p0, p1, (255, 255, 255), thick)
        tag = o.cls + (f" {o.distance_m:.0f}m" if o.distance_m is not None else "")
        org = (p0[0], max(p0[1] - 3, 10))
        cv2.putText(out, tag, org, cv2.FONT_HERSHEY_SIMPLEX, 0.4 * thick, (0, 0, 0), thick + 2, cv2.LINE_AA)
        cv2.putText(out, tag, org, cv2.FONT_HERSHEY_SIMPLEX, 0.4 * thick, (255, 255, 255), thick, cv2.LINE_AA)
    c = fa.camera
    txt = (f"h {c.height_m:.2f} m  pitch {c.pitch_deg:+.1f}  roll {c.roll_deg:+.1f}  road "
           + (f"{fa.road_direction_deg:+.1f} deg" if fa.road_direction_deg is not None else "dir ?"))
    cv2.putText(out, txt, (5, H - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45 * thick, (0, 0, 0), thick + 2, cv2.LINE_AA)
    cv2.putText(out, txt, (5, H - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45 * thick, (255, 255, 255), thick, cv2.LINE_AA)
    return out
