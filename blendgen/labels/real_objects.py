"""Labels for the real road users already in a background frame, updated for what the
injected objects now cover (bpy-free).

A composite's labels are the injected objects (exact masks from the render) plus the real
objects of the frame: the user's own labels (`REC/labels.json`) or the frame analysis'
detections. Without them a detector trained on the composites is told that every real car
and person is background. Every real label says where it came from (`source`: "user" or
"detector"; injected objects say "injected").

Occlusion: injected objects are always in front of real ones (the planner puts none behind
a real road user), so a real object keeps the part of its box that no rendered pixel covers.
No mask of a real object is known, so its visible region is its box less the covered pixels:
`visible_px`, the tight `bbox` of that region, `occlusion` = covered share of the box. The
rule that drops tiny injected objects drops or ignores the real ones too (`min_visible_px`,
`small_objects`); a box covered completely is dropped.

Detections: the analysis keeps detections with score >= 0.25 (`analysis.objects.SCORE_MIN`).
Those at or above DETECTOR_LABEL_SCORE become labels; those below are uncertain and become
ignore regions (COCO `iscrowd`, KITTI `DontCare`), neither object nor background for a trainer.
The threshold is measured against human boxes (benchmarks/labels/bench_real_labels.py,
docs/benchmarks/real_labels.md).
"""

from __future__ import annotations

import numpy as np

from blendgen import CLASSES
from blendgen.labels.instances import encode_mask, tight_box

# Precision of YOLOX-Nano's detections against human boxes is >= 0.8 from this score on
# (docs/benchmarks/real_labels.md); below it a detection is as likely wrong as right.
DETECTOR_LABEL_SCORE = 0.5
REAL_MODES = ("user", "detector", "ignore", "none")


def detector_boxes(objects: list[dict], label_score: float = DETECTOR_LABEL_SCORE) -> list[dict]:
    """Real boxes from detections ({"cls", "box", "score"[, "distance_m"]}): confident ones are
    labels, the others ignore regions."""
    return [{"cls": o["cls"], "box": list(o["box"]), "ignore": o["score"] < label_score, "source": "detector",
             "score": round(float(o["score"]), 4), "distance_m": o.get("distance_m")} for o in objects]


def user_boxes(boxes: list[dict], sx: float = 1.0, sy: float = 1.0) -> list[dict]:
    """The recording's labels of one frame (recording.labels), scaled to the render resolution."""
    return [{"cls": b["cls"], "box": [b["box"][0] * sx, b["box"][1] * sy, b["box"][2] * sx, b["box"][3] * sy],
             "ignore": bool(b["ignore"]), "source": "user", "label": b.get("label")} for b in boxes]


def real_instances(real: list[dict], covered: np.ndarray, *, min_visible_px: int = 64,
                   small_objects: str = "drop") -> list[dict]:
    """Frame-label instances for the real boxes `real` ({"cls", "box" [x,y,w,h], "ignore",
    "source"[, "score", "label", "distance_m"]}, render resolution) given `covered`, the HxW
    pixels the injected objects (and any rendered scenery) now paint over.

    cls "ignore" is an ignore region of no known class (KITTI DontCare): category_id 0.
    Ids are negative (-1, -2, ...): real objects have no id in instances.png.
    """
    covered = np.asarray(covered, bool)
    H, W = covered.shape
    out = []
    for k, r in enumerate(real):
        x, y, w, h = (float(v) for v in r["box"])
        x0, y0 = max(0, int(np.floor(x))), max(0, int(np.floor(y)))
        x1, y1 = min(W, int(np.ceil(x + w))), min(H, int(np.ceil(y + h)))
        if x1 <= x0 or y1 <= y0:
            continue
        region = np.zeros((H, W), bool)
        region[y0:y1, x0:x1] = True
        region &= ~covered
        n = int(region.sum())
        box_px = (x1 - x0) * (y1 - y0)
        if n == 0:
            continue  # wholly behind injected objects
        ignore = bool(r.get("ignore")) or r["cls"] == "ignore"
        if n < min_visible_px:
            if small_objects == "drop":
                continue
            ignore = True
        occlusion = 1.0 - n / box_px
        # the box as given when nothing covers it (keeps sub-pixel edges); else the visible part's
        bbox = [x, y, w, h] if occlusion == 0 else tight_box(region)
        out.append({
            "id": -(k + 1), "track_id": None, "cls": r["cls"], "category_id": CLASSES.get(r["cls"], 0),
            "bbox": [round(float(v), 2) for v in bbox], "area": n, "visible_px": n, "amodal_px": box_px,
            "segmentation": encode_mask(region), "occlusion": round(float(occlusion), 4), "truncation": None,
            "distance_m": r.get("distance_m"), "box3d_cam": None, "scenario": None, "state": None, "rides": None,
            "ignore": ignore, "source": r["source"], "score": r.get("score"), "label": r.get("label"),
        })
    return out
