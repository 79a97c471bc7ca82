"""OUT/report/: contact sheet, label statistics, realism table, time per stage, index.md."""

from __future__ import annotations

import json
from collections import Counter, defaultdict
from pathlib import Path

import cv2
import numpy as np

from blendgen import CLASSES, atomic
from blendgen.errors import UserError
from blendgen.frame_labels import all_instances, find_frame_labels, read_frame_labels
from blendgen.report.draw import CLASS_BGR, contact_sheet, draw_labels

SHEET_FRAMES = 8
TILE_W = 480


def build_report(out_dir: Path) -> Path:
    """Write OUT/report/ and return the path of its index.md."""
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise UserError("output folder does not exist", where=str(out_dir))
    rep = out_dir / "report"
    frames = [read_frame_labels(p) for p in find_frame_labels(out_dir)]
    frames.sort(key=lambda f: f["frame_id"])
    md = [f"# blendgen report: `{out_dir.name}`", ""]
    md += _summary_section(out_dir, frames)
    md += _sheet_section(rep, frames)
    md += _analysis_section(out_dir, rep)
    md += _stats_section(rep, frames)
    md += _realism_section(out_dir)
    md += _timing_section(rep, out_dir)
    index = rep / "index.md"
    atomic.write_text(index, "\n".join(md) + "\n")
    return index


def _summary_section(out_dir: Path, frames: list[dict]) -> list[str]:
    inst = [i for f in frames for i in f["instances"]]
    n_ign = sum(i["ignore"] for i in inst)
    lines = ["## Summary", "", f"- frames with labels: {len(frames)}",
             f"- labelled objects: {len(inst) - n_ign} (+ {n_ign} marked ignore)"]
    real = [i for f in frames for i in f.get("real") or []]
    if real:
        by = Counter((i["source"], i["ignore"]) for i in real)
        lines.append("- real road users of the backgrounds (labels.real): " + ", ".join(
            f"{src} {by[src, False]} labels + {by[src, True]} ignore regions" for src in sorted({s for s, _ in by})))
    labels = out_dir / "labels"
    for name, rel in (("COCO", "coco.json"), ("YOLO", "yolo/data.yaml"), ("KITTI", "kitti/label_2")):
        if (labels / rel).exists():
            lines.append(f"- {name}: [`labels/{rel}`](../labels/{rel})")
    return lines + [""]


def _sheet_section(rep: Path, frames: list[dict]) -> list[str]:
    lines = ["## Contact sheet", ""]
    if not frames:
        return lines + ["No finished frames yet.", ""]
    pick = np.unique(np.linspace(0, len(frames) - 1, min(SHEET_FRAMES, len(frames))).round().astype(int))
    tiles = []
    for k in pick:
        f = frames[k]
        img = cv2.imread(str(f["image_path"]), cv2.IMREAD_COLOR)
        if img is None:
            img = np.full((f["height"], f["width"], 3), 64, np.uint8)  # missing composite: grey tile
        scale = TILE_W / img.shape[1]
        small = cv2.resize(img, (TILE_W, max(1, round(img.shape[0] * scale))), interpolation=cv2.INTER_AREA)
        # the clean composite (to judge how it looks) beside the same with its labels
        tiles += [(f["frame_id"], small),
                  (f"{f['frame_id']} labels", draw_labels(small, all_instances(f), scale=scale))]
    atomic.write_image(rep / "contact_sheet.jpg", contact_sheet(tiles, cols=4, tile_w=TILE_W),
                       [cv2.IMWRITE_JPEG_QUALITY, 90])
    legend = ", ".join(f"{n} = rgb{tuple(reversed(c))}" for n, c in CLASS_BGR.items())
    return lines + [f"{len(tiles) // 2} of {len(frames)} frames: each composite as written, then with mask outlines, "
                    f"boxes and `class #track` tags ({legend}; grey = ignore; real road users of the "
                    "background are tagged with their source, user or detector).",
                    "", "![contact sheet](contact_sheet.jpg)", ""]


def _analysis_section(out_dir: Path, rep: Path) -> list[str]:
    """Ground-plane jobs: each frame's horizon, road, bands, hood and real road users, drawn
    over the real frame, so a person can check the analysis the planner trusted at a glance."""
    import yaml

    from blendgen.frame_analysis import read_analysis, read_road_mask
    from blendgen.recording.folder import read_frame, read_recording
    from blendgen.report.draw import draw_analysis

    folder = out_dir / "analysis"
    ids = sorted(p.stem for p in folder.glob("f*.json"))
    if not ids:
        return []
    try:
        rec = read_recording(yaml.safe_load((out_dir / "job.resolved.yaml").read_text())["recording"])
    except (OSError, KeyError, TypeError, UserError):
        return ["## Frame analysis", "", "The recording is not readable from here: no overlay.", ""]
    pick = [ids[k] for k in np.unique(np.linspace(0, len(ids) - 1, min(SHEET_FRAMES, len(ids))).round().astype(int))]
    tiles, fell_back = [], 0
    for fid in pick:
        fa = read_analysis(folder, fid)
        img = cv2.resize(read_frame(rec, int(fid.lstrip("f"))), (TILE_W, round(TILE_W * fa.height / fa.width)),
                         interpolation=cv2.INTER_AREA)
        tiles.append((fid, draw_analysis(img, fa, read_road_mask(folder, fa))))
    for fid in ids:
        fa = read_analysis(folder, fid)
        fell_back += fa.road_mask is None or fa.road_direction_deg is None
    atomic.write_image(rep / "analysis_sheet.jpg", contact_sheet(tiles, tile_w=TILE_W), [cv2.IMWRITE_JPEG_QUALITY, 88])
    return ["## Frame analysis", "",
            f"{len(tiles)} of {len(ids)} frames: horizon red, road green, walkable bands yellow, hood magenta, "
            f"real road users white (class, distance). {fell_back} frame(s) fell back for road or direction; "
            "the reasons are in `analysis/<frame>.json` (decisions) and in the manifest.", "",
            "![frame analysis](analysis_sheet.jpg)", ""]


def _stats_section(rep: Path, frames: list[dict]) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    inst = [i for f in frames for i in f["instances"] if not i["ignore"]]
    lines = ["## Labels", ""]
    if not inst:
        return lines + ["No labelled objects.", ""]
    names = [n for n in CLASSES if any(i["cls"] == n for i in inst)]
    colour = {n: np.array(CLASS_BGR[n][::-1]) / 255 for n in CLASSES}
    counts = Counter(i["cls"] for i in inst)

    fig, ax = plt.subplots(figsize=(6, 3.2))
    ax.bar(names, [counts[n] for n in names], color=[colour[n] for n in names], edgecolor="k")
    ax.set_ylabel("objects"), ax.set_title("labelled objects per class")
    plt.setp(ax.get_xticklabels(), rotation=20)
    _save(fig, rep / "class_counts.png")

    by = defaultdict(list)
    for i in inst:
        by[i["cls"]].append(i)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.4))
    bins = np.logspace(0, np.log10(max(max(i["bbox"][3] for i in inst), 2)) + 0.05, 25)
    for n in names:
        axes[0].hist([i["bbox"][3] for i in by[n]], bins=bins, histtype="step", lw=2, color=colour[n], label=n)
        axes[1].hist([i["area"] for i in by[n]], bins=np.logspace(0, np.log10(max(i["area"] for i in inst) + 1) + 0.05, 25),
                     histtype="step", lw=2, color=colour[n], label=n)
    axes[0].set_xscale("log"), axes[0].set_xlabel("box height (px)"), axes[0].set_ylabel("objects")
    axes[1].set_xscale("log"), axes[1].set_xlabel("visible mask area (px)")
    axes[0].legend(fontsize=8)
    fig.suptitle("box sizes")
    _save(fig, rep / "box_sizes.png")

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.4))
    dist = [i for i in inst if i.get("distance_m") is not None and np.isfinite(i["distance_m"])]
    if dist:
        dbins = np.linspace(0, max(i["distance_m"] for i in dist) * 1.02 + 1e-6, 25)
        for n in names:
            axes[0].hist([i["distance_m"] for i in dist if i["cls"] == n], bins=dbins, histtype="step", lw=2,
                         color=colour[n], label=n)
    axes[0].set_xlabel("distance to the camera (m)"), axes[0].set_ylabel("objects"), axes[0].legend(fontsize=8)
    occ = [i["occlusion"] for i in inst if i.get("occlusion") is not None]
    tru = [i["truncation"] for i in inst if i.get("truncation") is not None]
    axes[1].hist([occ, tru], bins=np.linspace(0, 1, 11), label=["occlusion", "truncation"])
    axes[1].set_xlabel("fraction"), axes[1].legend(fontsize=8)
    fig.suptitle("distances, occlusion and truncation")
    _save(fig, rep / "distances.png")

    table = ["| class | objects | median box h (px) | median distance (m) | median occlusion |",
             "|---|---:|---:|---:|---:|"]
    for n in names:
        rows = by[n]
        occ_n = [i["occlusion"] for i in rows if i.get("occlusion") is not None]
        d_n = [i["distance_m"] for i in rows if i.get("distance_m") is not None]
        h_med = np.median([i["bbox"][3] for i in rows])
        d_med = f"{np.median(d_n):.1f}" if d_n else "–"
        o_med = f"{np.median(occ_n):.2f}" if occ_n else "–"
        table.append(f"| {n} | {len(rows)} | {h_med:.0f} | {d_med} | {o_med} |")
    return lines + table + ["", "![class counts](class_counts.png)", "", "![box sizes](box_sizes.png)", "",
                            "![distances](distances.png)", ""]


def _realism_section(out_dir: Path) -> list[str]:
    lines = ["## Realism score", ""]
    ev = out_dir / "eval"
    found = False
    for name, title in (("realism.md", None), ("realism_compare.md", "Side by side")):
        if (ev / name).exists():
            if title:
                lines += [f"### {title}", ""]
            lines += [(ev / name).read_text().strip(), ""]
            found = True
    if not found:
        lines += [f"Not run. `blendgen realism {out_dir} --detector MODEL.onnx` adds it here.", ""]
    return lines


def read_manifest(path: Path) -> list[dict]:
    """manifest.jsonl records; a torn or foreign line is skipped (append_line's contract)."""
    out = []
    if path.exists():
        for line in path.read_text(encoding="utf-8").splitlines():
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(rec, dict):
                out.append(rec)
    return out


STAGE_TITLES = {"record": "Recording synthesis (`record`: Cycles renders the synthetic recording's own "
                          "frames; a real recording skips it)",
                "frames": "Frame work (`frames`: render + post + labels of each augmented frame)"}
# what a real recording costs; `record` is not part of it; `pipeline`: analysis, plan and frames on the farm, overlapping
FRAME_WORK = ("sync", "analysis", "plan", "frames", "pipeline", "export")


def _timing_section(rep: Path, out_dir: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lines = ["## Time per stage", ""]
    latest = {}
    for rec in read_manifest(out_dir / "manifest.jsonl"):
        if isinstance(rec.get("timings"), dict) and "frame_id" in rec:
            latest[(rec.get("stage"), rec["frame_id"])] = rec  # a redone frame counts once
    by_stage: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for (stage, _), rec in latest.items():
        for k, v in rec["timings"].items():
            if isinstance(v, (int, float)) and np.isfinite(v):
                by_stage[stage][k].append(float(v))
    if not by_stage:
        lines += ["No `manifest.jsonl` records with timings yet.", ""]
    for stage in sorted(by_stage, key=lambda st: (st != "record", str(st))):
        parts = by_stage[stage]
        n = max(len(v) for v in parts.values())
        lines += [f"### {STAGE_TITLES.get(stage, f'`{stage}`')}", "",
                  f"Per frame, from `manifest.jsonl` ({n} frames):", "",
                  "| step | frames | median (s) | mean (s) | total (s) |", "|---|---:|---:|---:|---:|"]
        for k, v in parts.items():
            lines.append(f"| {k} | {len(v)} | {np.median(v):.3f} | {np.mean(v):.3f} | {np.sum(v):.1f} |")
        lines.append("")
        if stage == "frames":
            steps = [k for k in parts if k != "total"]
            fig, ax = plt.subplots(figsize=(6, 3))
            ax.barh(steps, [np.median(parts[k]) for k in steps], color="tab:blue")
            ax.set_xlabel("median seconds per frame"), ax.set_title("frame work, per frame")
            ax.invert_yaxis()
            _save(fig, rep / "stage_times.png")
            lines += ["![time per step of the frame work](stage_times.png)", ""]
    lines += _run_times(out_dir)
    return lines


def _run_times(out_dir: Path) -> list[str]:
    try:
        s = json.loads((out_dir / "run_summary.json").read_text())
    except (OSError, json.JSONDecodeError):
        return []
    times = s.get("seconds_per_stage") if isinstance(s, dict) else None
    if not isinstance(times, dict) or not times:
        return []
    times = {k: v for k, v in times.items() if isinstance(v, (int, float))}
    lines = ["### Whole run", "", "From `run_summary.json` (the previous run when this report is part of it).", ""]
    if "record" in times:
        lines += ["| recording synthesis | seconds |", "|---|---:|", f"| record | {times['record']:.1f} |", ""]
    work = {k: v for k, v in times.items() if k in FRAME_WORK}
    lines += ["| frame work | seconds |", "|---|---:|"] + [f"| {k} | {v:.1f} |" for k, v in work.items()]
    lines.append(f"| **total frame work** | **{sum(work.values()):.1f}** |")
    tp = s.get("throughput") or {}
    if tp.get("frames_per_min"):
        lines += ["", f"Frame work throughput: **{tp['frames_per_min']:.1f} frames/min** ({tp['frames']} frames in "
                      f"{tp['frame_work_s']:.1f} s; recording synthesis not counted)."]
    return lines + [""]


def _save(fig, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    with atomic.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)
