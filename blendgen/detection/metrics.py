"""Detection metrics at one IoU threshold, computed exactly as pycocotools' COCOeval does
(bbox, area range "all", maxDets 100, 101-point interpolated AP), plus Precision, Recall
and F1 at a score threshold -- the seed paper's Table 1 columns.

Ground truths with `ignore` (COCO `iscrowd`) neither count as misses nor make detections
false positives: a detection covering one (intersection over the detection's area >= IoU)
is ignored, like COCO's crowd regions.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np

REC_THRS = np.linspace(0.0, 1.0, 101)
AREA_RANGES = {"all": (0.0, 1e10), "small": (0.0, 32.0 ** 2), "medium": (32.0 ** 2, 96.0 ** 2),
               "large": (96.0 ** 2, 1e10)}


def box_iou(dt: np.ndarray, gt: np.ndarray, crowd: np.ndarray) -> np.ndarray:
    """IoU matrix (len(dt) x len(gt)) of [x, y, w, h] boxes; for crowd gts the union is the
    detection's own area (COCO's definition)."""
    if len(dt) == 0 or len(gt) == 0:
        return np.zeros((len(dt), len(gt)))
    dx0, dy0, dw, dh = (dt[:, i:i + 1] for i in range(4))
    gx0, gy0, gw, gh = (gt[None, :, i] for i in range(4))
    iw = np.clip(np.minimum(dx0 + dw, gx0 + gw) - np.maximum(dx0, gx0), 0, None)
    ih = np.clip(np.minimum(dy0 + dh, gy0 + gh) - np.maximum(dy0, gy0), 0, None)
    inter = iw * ih
    union = np.where(crowd[None, :], dw * dh, dw * dh + gw * gh - inter)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def match_image(dts: list[dict], gts: list[dict], iou_thr: float, max_dets: int,
                area_rng: tuple[float, float] = (0.0, 1e10)):
    """Greedy matching in score order (COCOeval.evaluateImg for one image and class).

    Ground truths outside `area_rng` (by their `area`, default the box area) are ignored
    like crowd regions but keep the ordinary IoU; unmatched detections outside it are ignored.
    Returns (scores, matched, det_ignored, n_gt_not_ignored) for the top `max_dets` detections
    and, per input gt (input order), the score of the detection it matched (NaN: none, or ignored).
    """
    def g_area(g):
        return g["area"] if g.get("area") is not None else g["bbox"][2] * g["bbox"][3]

    g_ig_all = [bool(g["ignore"]) or not area_rng[0] <= g_area(g) <= area_rng[1] for g in gts]
    g_order = np.argsort(np.array(g_ig_all, dtype=int), kind="mergesort")  # ignored gts last
    gts = [gts[i] for i in g_order]
    g_ig = np.array([g_ig_all[i] for i in g_order], dtype=bool)
    crowd = np.array([bool(g["ignore"]) for g in gts], dtype=bool)
    d_order = np.argsort([-d["score"] for d in dts], kind="mergesort")[:max_dets]
    dts = [dts[i] for i in d_order]
    ious = box_iou(np.array([d["bbox"] for d in dts], float).reshape(-1, 4),
                   np.array([g["bbox"] for g in gts], float).reshape(-1, 4), crowd)
    g_taken = np.zeros(len(gts), bool)
    g_score = np.full(len(gts), np.nan)
    matched = np.zeros(len(dts), bool)
    d_ig = np.zeros(len(dts), bool)
    for di in range(len(dts)):
        best, m = min(iou_thr, 1 - 1e-10), -1
        for gi in range(len(gts)):
            if g_taken[gi] and not crowd[gi]:
                continue  # a real gt matches one detection; crowd regions absorb many
            if m > -1 and not g_ig[m] and g_ig[gi]:
                break  # already matched a counted gt: do not trade it for an ignored one
            if ious[di, gi] < best:
                continue
            best, m = ious[di, gi], gi
        if m == -1:
            continue
        d_ig[di] = g_ig[m]
        matched[di] = True
        g_taken[m] = True
        if not g_ig[m]:
            g_score[m] = dts[di]["score"]
    d_area = np.array([d["bbox"][2] * d["bbox"][3] for d in dts], float)
    d_ig |= ~matched & ((d_area < area_rng[0]) | (d_area > area_rng[1]))
    scores = np.array([d["score"] for d in dts], float)
    g_score_in = np.full(len(gts), np.nan)
    g_score_in[g_order] = g_score
    return scores, matched, d_ig, int((~g_ig).sum()), g_score_in


def evaluate(gts: list[dict], dts: list[dict], category_ids: list[int], *, iou_thr: float = 0.5,
             score_thr: float = 0.3, max_dets: int = 100, area_rng: tuple[float, float] = (0.0, 1e10),
             return_hits: bool = False) -> dict:
    """gts: [{image_id, category_id, bbox, ignore[, area]}], dts: [{image_id, category_id, bbox, score}].
    `area_rng`: COCO's area range (e.g. small = (0, 32**2)); gts are sized by `area` (mask
    pixels for blendgen labels), detections by their box.

    Returns {category_id: {n_gt, n_det, tp, fp, precision, recall, f1, ap}} (precision/recall/F1
    over detections with score >= score_thr; AP over all detections; ap is None for classes
    without ground truth) and "mean" over classes that have ground truth.
    """
    by_gt, by_dt = defaultdict(list), defaultdict(list)
    for g in gts:
        by_gt[(g["image_id"], g["category_id"])].append(g)
    for d in dts:
        by_dt[(d["image_id"], d["category_id"])].append(d)
    # COCOeval walks images in sorted id order; that order breaks ties between equal scores.
    images = sorted({k[0] for k in by_gt} | {k[0] for k in by_dt}, key=lambda i: (isinstance(i, str), i))
    result, all_hits = {}, []
    for cat in category_ids:
        s_all, m_all, ig_all, npig = [], [], [], 0
        hits = []
        for img in images:
            g, d = by_gt.get((img, cat), []), by_dt.get((img, cat), [])
            if not g and not d:
                continue
            s, m, ig, n, gs = match_image(d, g, iou_thr, max_dets, area_rng)
            hits += [(gt, float(sc)) for gt, sc in zip(g, gs)]
            s_all.append(s), m_all.append(m), ig_all.append(ig)
            npig += n
        s = np.concatenate(s_all) if s_all else np.zeros(0)
        m = np.concatenate(m_all) if m_all else np.zeros(0, bool)
        ig = np.concatenate(ig_all) if ig_all else np.zeros(0, bool)
        order = np.argsort(-s, kind="mergesort")
        s, m, ig = s[order], m[order], ig[order]
        tp_flags, fp_flags = m & ~ig, ~m & ~ig
        at = s >= score_thr
        tp, fp = int(tp_flags[at].sum()), int(fp_flags[at].sum())
        row = {"n_gt": npig, "n_det": int((at & ~ig).sum()), "tp": tp, "fp": fp,
               "precision": tp / (tp + fp) if tp + fp else 0.0,
               "recall": tp / npig if npig else None, "ap": None}
        if npig:
            row["ap"] = interpolated_ap(tp_flags, fp_flags, npig)
        p, r = row["precision"], row["recall"]
        row["f1"] = (2 * p * r / (p + r) if (r is not None and p + r > 0) else (0.0 if r is not None else None))
        result[cat] = row
        all_hits += hits
    scored = [result[c] for c in category_ids if result[c]["n_gt"]]
    mean = {k: (float(np.mean([r[k] for r in scored])) if scored else None)
            for k in ("precision", "recall", "f1", "ap")}
    mean.update({k: sum(r[k] for r in result.values()) for k in ("n_gt", "n_det", "tp", "fp")})
    result["mean"] = mean
    if return_hits:
        # (gt, score of the detection matched to it or NaN) for every gt, to break recall down
        # by attributes (scenario, distance, occlusion) of the injected objects.
        result["hits"] = all_hits
    return result


def interpolated_ap(tp_flags: np.ndarray, fp_flags: np.ndarray, npig: int) -> float:
    """COCO's 101-point interpolated AP from score-sorted TP/FP flags."""
    tp = np.cumsum(tp_flags).astype(float)
    fp = np.cumsum(fp_flags).astype(float)
    if len(tp) == 0:
        return 0.0
    rc = tp / npig
    pr = tp / (fp + tp + np.spacing(1))
    pr = np.maximum.accumulate(pr[::-1])[::-1]  # precision envelope, monotone from the right
    idx = np.searchsorted(rc, REC_THRS, side="left")
    q = np.zeros(len(REC_THRS))
    valid = idx < len(pr)
    q[valid] = pr[idx[valid]]
    return float(q.mean())
