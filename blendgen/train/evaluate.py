"""AP@0.5 per class on a labelled test set: pycocotools' COCOeval for the number, the same
matching per image (blendgen.detection.metrics, which reproduces COCOeval) for bootstrap intervals
over test images, across one or several training seeds. No torch here.

Detections for an image come from any detector as [{bbox [x, y, w, h], score, category_id}].
A per-image match record (class -> scores, true-positive and ignored flags, ground-truth
count) is computed once; a bootstrap draw concatenates the records of the drawn images, so
thousands of draws cost little, and two arms drawn with the same images give a paired
difference.
"""

from __future__ import annotations

import contextlib
import io
import warnings

import numpy as np

from blendgen.detection.metrics import interpolated_ap, match_image

MAX_DETS = 100


def coco_gt(samples, category_ids) -> dict:
    """A COCO ground-truth dict of the test samples (data.Sample; ignore regions as iscrowd)."""
    images, anns = [], []
    for k, s in enumerate(samples, start=1):
        images.append({"id": k, "file_name": str(s.path), "width": s.width, "height": s.height})
        for b, c in zip(s.boxes, s.category_ids):
            anns.append({"id": len(anns) + 1, "image_id": k, "category_id": int(c), "iscrowd": 0,
                         "bbox": [float(b[0]), float(b[1]), float(b[2] - b[0]), float(b[3] - b[1])],
                         "area": float((b[2] - b[0]) * (b[3] - b[1]))})
        for b in s.ignores:
            for c in category_ids:
                anns.append({"id": len(anns) + 1, "image_id": k, "category_id": int(c), "iscrowd": 1,
                             "bbox": [float(b[0]), float(b[1]), float(b[2] - b[0]), float(b[3] - b[1])],
                             "area": float((b[2] - b[0]) * (b[3] - b[1]))})
    return {"images": images, "annotations": anns, "categories": [{"id": int(c)} for c in category_ids]}


def cocoeval_ap50(samples, detections: list[list[dict]], category_ids) -> dict[int, float]:
    """AP@0.5 per category with pycocotools (maxDets 100, area all); NaN for a category without
    ground truth."""
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    gt = COCO()
    gt.dataset = coco_gt(samples, category_ids)
    with contextlib.redirect_stdout(io.StringIO()):
        gt.createIndex()
        dts = [{"image_id": k, "category_id": d["category_id"], "bbox": d["bbox"], "score": d["score"]}
               for k, dets in enumerate(detections, start=1) for d in dets if d["category_id"] in category_ids]
        dt = gt.loadRes(dts) if dts else COCO()
        if not dts:
            return {int(c): 0.0 for c in category_ids}
        ev = COCOeval(gt, dt, "bbox")
        ev.params.iouThrs = np.array([0.5])
        ev.params.maxDets = [MAX_DETS]
        ev.params.areaRng = [ev.params.areaRng[0]]
        ev.params.areaRngLbl = ["all"]
        ev.evaluate()
        ev.accumulate()
    out = {}
    for k, c in enumerate(ev.params.catIds):
        prec = ev.eval["precision"][0, :, k, 0, 0]
        out[int(c)] = float(prec[prec > -1].mean()) if (prec > -1).any() else float("nan")
    return out


def match_records(samples, detections: list[list[dict]], category_ids) -> list[dict]:
    """Per image, per category: (scores, tp flags, ignored flags, gt count) as COCOeval matches."""
    recs = []
    for s, dets in zip(samples, detections):
        rec = {}
        for c in category_ids:
            gts = [{"bbox": [b[0], b[1], b[2] - b[0], b[3] - b[1]], "ignore": False}
                   for b, cc in zip(s.boxes, s.category_ids) if cc == c]
            gts += [{"bbox": [b[0], b[1], b[2] - b[0], b[3] - b[1]], "ignore": True} for b in s.ignores]
            d = [x for x in dets if x["category_id"] == c]
            scores, matched, ignored, n_gt, _ = match_image(d, gts, 0.5, MAX_DETS)
            rec[c] = (scores, matched & ~ignored, ~matched & ~ignored, n_gt)
        recs.append(rec)
    return recs


def ap_from_records(records: list[dict], idx, category_id) -> float:
    """AP@0.5 of one category over the images `idx` (with repeats: a bootstrap draw)."""
    parts = [records[i][category_id] for i in idx]
    n_gt = sum(p[3] for p in parts)
    if n_gt == 0:
        return float("nan")
    s = np.concatenate([p[0] for p in parts])
    order = np.argsort(-s, kind="mergesort")
    tp = np.concatenate([p[1] for p in parts])[order]
    fp = np.concatenate([p[2] for p in parts])[order]
    return interpolated_ap(tp, fp, n_gt)


def bootstrap(arms: dict[str, list[list[dict]]], category_ids, n_images: int, *, n_boot: int = 1000,
              seed: int = 0, pairs: list[tuple[str, str]] = ()) -> dict:
    """arms: name -> per-seed match records (match_records). Per arm and category (and "mean",
    the class mean): AP@0.5 as the mean over seeds, its 95 % percentile interval over test-image
    draws (the same draws for every arm), each seed's AP; and for each (a, b) in `pairs` the
    paired difference a - b with its interval."""
    rng = np.random.default_rng(seed)
    draws = [np.arange(n_images)] + [rng.integers(0, n_images, n_images) for _ in range(n_boot)]
    cats = list(category_ids)
    out: dict = {"arms": {}, "pairs": {}, "n_boot": n_boot, "n_images": n_images}
    vals: dict = {}
    for name, recs in arms.items():
        # (draw, seed, category) AP; draw 0 is the test set itself
        ap = np.array([[[ap_from_records(r, d, c) for c in cats] for r in recs] for d in draws])
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a draw without a class: NaN, left out
            per_cat = np.nanmean(ap, axis=1)                   # mean over seeds
            mean = np.nanmean(per_cat, axis=1)                  # class mean
            seed_means = np.nanmean(ap[0], axis=1)              # each seed's class mean
        row = {}
        for j, c in enumerate(cats + ["mean"]):
            v = mean if c == "mean" else per_cat[:, j]
            vals[name, str(c)] = v
            lo, hi = _interval(v[1:])
            seeds = seed_means if c == "mean" else ap[0, :, j]
            row[str(c)] = {"ap": float(v[0]), "lo": lo, "hi": hi, "seeds": [float(x) for x in seeds]}
        out["arms"][name] = row
    for a, b in pairs:
        row = {}
        for c in [str(x) for x in cats] + ["mean"]:
            d = vals[a, c] - vals[b, c]
            lo, hi = _interval(d[1:])
            row[c] = {"diff": float(d[0]), "lo": lo, "hi": hi}
        out["pairs"][f"{a} - {b}"] = row
    return out


def _interval(v: np.ndarray) -> tuple[float, float]:
    v = v[np.isfinite(v)]
    if not len(v):
        return float("nan"), float("nan")
    lo, hi = np.percentile(v, [2.5, 97.5])
    return float(lo), float(hi)
