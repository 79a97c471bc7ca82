"""The realism score (the seed paper's Experiment 1): does a detector trained only on real
photos find the injected objects, as their class, where the labels say they are?

Detections of a COCO detector on the composites are matched to the injected labels at
IoU 0.5 and scored per class (Precision, Recall, F1, AP@0.5) and as the class mean.

Real objects already in the recording are not labelled, so detecting them would count as
false positives. With `background="auto"` the detector also runs on the real frame under
each composite (found through job.resolved.yaml's recording), and its confident detections
become ignore regions (COCO crowd semantics): a composite detection lying on one is neither
right nor wrong. Injected objects hiding a real one are still matched to their label first.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import cv2
import numpy as np

from blendgen import CLASSES, atomic
from blendgen.detection.metrics import AREA_RANGES, evaluate
from blendgen.errors import UserError
from blendgen.frame_labels import find_frame_labels, read_frame_labels

NAMES = {cid: name for name, cid in CLASSES.items()}
METRICS = ("precision", "recall", "f1", "ap")


def run_realism(out_dir: Path, detector: Path, *, compare: Path | None = None, iou: float = 0.5,
                score_threshold: float = 0.3, background: str = "auto", max_frames: int | None = None,
                write: bool = True, progress=None) -> dict:
    """Score OUT (and OUT2 with `compare`); writes OUT/eval/realism.{json,md} and, with
    `compare`, OUT/eval/realism_compare.md. Returns {"runs": [result, ...], "table": markdown}."""
    from blendgen.detection.detector import YoloxDetector

    if background not in ("auto", "none"):
        raise UserError(f"background must be 'auto' or 'none', got {background!r}", where="--background")
    if not 0 < iou < 1 or not 0 <= score_threshold <= 1:
        raise UserError(f"iou must be in (0, 1) and score threshold in [0, 1], got {iou}, {score_threshold}")
    det = YoloxDetector(Path(detector), category_ids=set(CLASSES.values()))
    runs = [score_output(Path(out_dir), det, iou=iou, score_threshold=score_threshold, background=background,
                         max_frames=max_frames, progress=progress)]
    if compare is not None:
        runs.append(score_output(Path(compare), det, iou=iou, score_threshold=score_threshold,
                                 background=background, max_frames=max_frames, progress=progress))
    table = compare_table(runs) if len(runs) > 1 else results_table(runs[0])
    if write:
        ev = Path(out_dir) / "eval"
        atomic.write_json(ev / "realism.json", runs[0], indent=1)
        atomic.write_text(ev / "realism.md", results_table(runs[0]) + "\n")
        if len(runs) > 1:
            atomic.write_text(ev / "realism_compare.md", table + "\n")
    return {"runs": runs, "table": table}


def score_output(out_dir: Path, det, *, iou: float, score_threshold: float, background: str,
                 max_frames: int | None = None, progress=None, background_score: float = 0.05) -> dict:
    paths = find_frame_labels(out_dir)
    if not paths:
        raise UserError("no frames/*/labels.json: run `blendgen run` on a job first", where=str(out_dir))
    if max_frames:
        paths = paths[:max_frames]
    rec, bg_note = _recording(out_dir) if background == "auto" else (None, "off (--background none)")
    gts, dts, n_bg, t_det = [], [], 0, []
    for k, p in enumerate(paths):
        fr = read_frame_labels(p)
        img = cv2.imread(str(fr["image_path"]), cv2.IMREAD_COLOR)
        if img is None:
            raise UserError(f"cannot read the composite {fr['image_path']}", where=str(p))
        fid = fr["frame_id"]
        for inst in fr["instances"]:
            gts.append({"image_id": fid, "category_id": inst["category_id"], "bbox": inst["bbox"],
                        "area": inst["area"], "ignore": bool(inst["ignore"]), "track_id": inst.get("track_id"),
                        "scenario": inst.get("scenario"), "distance_m": inst.get("distance_m"),
                        "occlusion": inst.get("occlusion")})
        t0 = time.perf_counter()
        found = det(img)
        t_det.append(time.perf_counter() - t0)
        dts += [{**d, "image_id": fid} for d in found]
        real = _real_frame(rec, fid, img.shape) if rec is not None else None
        if real is not None:
            n_bg += 1
            for d in det(real):
                # A real object: ignore region of its class. A low bar on purpose: the pasted
                # objects change the context, and faint real cars then cross the P/R threshold.
                if d["score"] >= background_score:
                    gts.append({"image_id": fid, "category_id": d["category_id"], "bbox": d["bbox"],
                                "ignore": True, "background": True})
        if progress:
            progress(k + 1, len(paths))
    per_class = evaluate(gts, dts, list(CLASSES.values()), iou_thr=iou, score_thr=score_threshold,
                         return_hits=True)
    recall_by = recall_breakdown(per_class.pop("hits"), score_threshold)
    rows = {NAMES[c]: per_class[c] for c in CLASSES.values()}
    rows["mean"] = per_class["mean"]
    by_size = {}
    for size in ("small", "medium", "large"):  # COCO area ranges over the visible mask
        r = evaluate(gts, dts, list(CLASSES.values()), iou_thr=iou, score_thr=score_threshold,
                     area_rng=AREA_RANGES[size])["mean"]
        by_size[size] = {"n_gt": r["n_gt"], "tp": r["tp"], "recall": r["tp"] / r["n_gt"] if r["n_gt"] else None,
                         "ap": r["ap"]}
    return {"out_dir": str(out_dir), "detector": str(getattr(det, "model_path", "")), "frames": len(paths),
            "frames_with_background": n_bg, "background": bg_note, "iou": iou, "score_threshold": score_threshold,
            "detector_ms_median": float(np.median(t_det) * 1000) if t_det else None,
            "classes": rows, "by_size": by_size, "recall_by": recall_by, "detections": dts,
            "ground_truth": [g for g in gts if not g.get("background")]}


# (low, high, label): low <= value < high.
DISTANCE_BINS = [(0, 10, "0–10 m"), (10, 20, "10–20 m"), (20, 40, "20–40 m"), (40, np.inf, ">= 40 m")]
OCCLUSION_BINS = [(0.0, 0.1, "0–0.1"), (0.1, 0.5, "0.1–0.5"), (0.5, np.inf, "0.5–1")]


def recall_breakdown(hits: list[tuple[dict, float]], score_threshold: float) -> dict:
    """Recall at the score threshold of the injected objects, by scenario, distance, occlusion."""
    found = [(g, bool(np.isfinite(sc) and sc >= score_threshold)) for g, sc in hits
             if not g.get("ignore") and not g.get("background")]

    def group(key_of):
        out: dict = {}
        for g, hit in found:
            k = key_of(g)
            if k is None:
                continue
            n, tp = out.get(k, (0, 0))
            out[k] = (n + 1, tp + hit)
        return {k: {"n": n, "recall": tp / n} for k, (n, tp) in out.items()}

    def binned(value, bins):
        if value is None or not np.isfinite(value):
            return None
        return next((label for lo, hi, label in bins if lo <= value < hi), None)

    return {"scenario": group(lambda g: g.get("scenario") or "(none)"),
            "distance": group(lambda g: binned(g.get("distance_m"), DISTANCE_BINS)),
            "occlusion": group(lambda g: binned(g.get("occlusion"), OCCLUSION_BINS))}


def results_table(run: dict) -> str:
    """The seed paper's Table 1 layout: one row per class, P / R / F1 / AP@0.5, then the mean."""
    head = ("| class | labels | detections | Precision | Recall | F1 | AP@0.5 |\n"
            "|---|---:|---:|---:|---:|---:|---:|")
    lines = [head]
    for name, r in run["classes"].items():
        if name != "mean" and not r["n_gt"] and not r["n_det"]:
            continue  # class absent from this output
        label = "**mean**" if name == "mean" else name
        lines.append(f"| {label} | {r['n_gt']} | {r['n_det']} | " + " | ".join(_fmt(r[m]) for m in METRICS) + " |")
    sizes = run.get("by_size") or {}
    if any(v["n_gt"] for v in sizes.values()):
        lines += ["", "| object size (visible px) | labels | Recall (pooled) | AP@0.5 (class mean) |",
                  "|---|---:|---:|---:|"]
        for size, v in sizes.items():
            rng = {"small": "< 32²", "medium": "32²–96²", "large": "> 96²"}[size]
            lines.append(f"| {size} ({rng}) | {v['n_gt']} | {_fmt(v['recall'])} | {_fmt(v['ap'])} |")
    for what, groups in (run.get("recall_by") or {}).items():
        if groups:
            lines += ["", f"| {what} | labels | Recall |", "|---|---:|---:|"]
            lines += [f"| {k} | {v['n']} | {_fmt(v['recall'])} |" for k, v in sorted(groups.items())]
    note = (f"\n{run['frames']} frames of `{run['out_dir']}`; IoU {run['iou']}, P/R/F1 at score >= "
            f"{run['score_threshold']}; real objects ignored on {run['frames_with_background']} frames ({run['background']}).")
    return "\n".join(lines) + "\n" + note


def compare_table(runs: list[dict]) -> str:
    """Two (or more) runs side by side per metric, as the seed paper's ablation table."""
    tags = [chr(ord("A") + i) for i in range(len(runs))]
    cols = [f"{m} {t}" for m in ("P", "R", "F1", "AP@0.5") for t in tags]
    lines = ["| class | " + " | ".join(cols) + " |", "|---|" + "---:|" * len(cols)]
    names = [n for n in list(CLASSES) + ["mean"] if any(
        n == "mean" or r["classes"][n]["n_gt"] or r["classes"][n]["n_det"] for r in runs)]
    for n in names:
        cells = [_fmt(r["classes"][n][m]) for m in METRICS for r in runs]
        lines.append(f"| {'**mean**' if n == 'mean' else n} | " + " | ".join(cells) + " |")
    legend = "\n".join(f"{t}: `{r['out_dir']}` ({r['frames']} frames)" for t, r in zip(tags, runs))
    return "\n".join(lines) + "\n\n" + legend


def _fmt(v) -> str:
    return "–" if v is None else f"{v:.3f}"


def _recording(out_dir: Path):
    """(recording the composites were made over, note): recording None when not found."""
    import yaml

    from blendgen.recording.folder import read_recording

    resolved = out_dir / "job.resolved.yaml"
    try:
        job = yaml.safe_load(resolved.read_text()) if resolved.exists() else {}
        root = Path(job.get("recording") or out_dir / "recording")
        if not root.is_absolute():
            root = (out_dir / root) if (out_dir / root).exists() else root
        if not (root / "frames.csv").exists():
            return None, f"no recording found ({root / 'frames.csv'} missing)"
        return read_recording(root, require_frames=True), f"real frames from {root}"
    except (UserError, OSError, ValueError, AttributeError, yaml.YAMLError) as e:
        return None, f"recording unreadable: {e}"


def _real_frame(rec, frame_id: str, shape) -> np.ndarray | None:
    """The real frame under composite `frame_id` (f<index>, the pipeline's recording index)."""
    from blendgen.recording.folder import read_frame

    m = re.fullmatch(r"f(\d+)", frame_id)
    if not m or int(m.group(1)) >= rec.n_frames:
        return None
    try:
        real = read_frame(rec, int(m.group(1)))
    except (UserError, OSError, ValueError):
        return None
    if real is None:
        return None
    if real.shape[:2] != shape[:2]:
        real = cv2.resize(real, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    return real


def load_result(out_dir: Path) -> dict | None:
    p = Path(out_dir) / "eval" / "realism.json"
    return json.loads(p.read_text()) if p.exists() else None
