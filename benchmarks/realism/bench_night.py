"""Night recall: YOLOX-Nano recall@0.5 of objects >= 40 px injected into the BDD night street
photo, for two renders of the same plans (same job seeds, same objects), e.g. before and
after a change to the night lighting. Differences are paired (same objects): bootstrap over
frames, 2000 resamples, 95 % percentile intervals (bench_realism's statistics).

Make the renders (a recording of the night photo repeated, jobs with different seeds), once
with each checkout, then score:

    blendgen import images DIR_OF_12_COPIES_OF_9aa94005-ff1d4c9a.jpg out/night/rec --hfov 60
    blendgen run out/night/before_21.yaml ...   # run from the "before" checkout
    blendgen run out/night/after_21.yaml ...    # this checkout
    PYTHONPATH=$PWD .venv/bin/python benchmarks/realism/bench_night.py --before out/night/before_21 out/night/before_22 \
        --after out/night/after_21 out/night/after_22

Writes docs/benchmarks/night.md (table + command; `--doc`, `--title` for other photos).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import DOCS  # noqa: E402
from benchmarks.realism.bench_realism import (BG_SCORE, IOU_THR, MODEL, NAMES, SCORE_THR, boot_ci,  # noqa: E402
                                              diff_stat, fmt, recall_stat)

from blendgen import CLASSES, atomic  # noqa: E402
from blendgen.detection.metrics import evaluate  # noqa: E402

DOC = DOCS / "night.md"


def score(outs: list[Path], det) -> list[dict]:
    """One row per injected object: frame, class, height, {"v": score of its match or 0}."""
    from blendgen.frame_labels import find_frame_labels, read_frame_labels
    from blendgen.recording.folder import read_frame, read_recording

    rows = []
    for out in outs:
        job = (out / "job.resolved.yaml").read_text()
        rec = read_recording(Path(next(ln.split(":", 1)[1].strip() for ln in job.splitlines()
                                       if ln.startswith("recording:"))))
        for lp in find_frame_labels(out):
            fr = read_frame_labels(lp)
            fid = fr["frame_id"]
            real = read_frame(rec, int(fid.lstrip("f")))
            bg = [{"image_id": fid, "category_id": d["category_id"], "bbox": d["bbox"], "ignore": True}
                  for d in det(real) if d["score"] >= BG_SCORE]
            gts = [{"image_id": fid, "category_id": g["category_id"], "bbox": g["bbox"], "area": g["area"],
                    "ignore": bool(g["ignore"])} for g in fr["instances"]]
            comp = cv2.imread(str(lp.parent / "composite.png"))
            dts = [{**d, "image_id": fid} for d in det(comp)]
            res = evaluate(gts + bg, dts, list(CLASSES.values()), iou_thr=IOU_THR, score_thr=SCORE_THR,
                           return_hits=True)
            hit = {id(g): s for g, s in res["hits"]}
            for g in gts:
                if not g["ignore"]:
                    s = hit.get(id(g), float("nan"))
                    rows.append({"frame": f"{out.name.split('_')[-1]}/{fid}", "cls": NAMES[g["category_id"]],
                                 "h": g["bbox"][3], "scores": {"v": 0.0 if s != s else float(s)}})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", type=Path, nargs="+", required=True, help="job outputs rendered before")
    ap.add_argument("--after", type=Path, nargs="+", required=True, help="the same jobs rendered after")
    ap.add_argument("--min-h", type=float, default=40.0)
    ap.add_argument("--doc", type=Path, default=DOC, help="where the table goes (default %(default)s)")
    ap.add_argument("--title", default="Night recall (BDD night street, YOLOX-Nano)")
    args = ap.parse_args()
    from blendgen.detection.detector import YoloxDetector

    det = YoloxDetector(MODEL, category_ids=set(CLASSES.values()))
    b, a = score(args.before, det), score(args.after, det)
    # same plans: the same objects in the same order (heights may differ by a rim pixel of noise)
    paired = [(r["frame"], r["cls"]) for r in b] == [(r["frame"], r["cls"]) for r in a]
    big = [i for i, r in enumerate(b) if r["h"] >= args.min_h]
    bb = [b[i] for i in big]
    ab = [a[i] for i in big] if paired else [r for r in a if r["h"] >= args.min_h]
    lines = [f"# {args.title}", "",
             "Made by `PYTHONPATH=$PWD .venv/bin/python benchmarks/realism/bench_night.py " + " ".join(sys.argv[1:]) + "`",
             f"(benchmarks/realism/bench_night.py). Objects >= {args.min_h:g} px tall; recall@0.5 at score >= {SCORE_THR}; "
             "real objects the detector finds in the untouched photo are ignore regions. [95 % bootstrap over frames]", "",
             "| renders | frames | objects >= 40 px | recall@0.5 |", "|---|---:|---:|---:|"]
    for name, rows in (("before", bb), ("after", ab)):
        lines.append(f"| {name} | {len({r['frame'] for r in rows})} | {len(rows)} | {fmt(boot_ci(rows, recall_stat('v')))} |")
    if paired:
        both = [{"frame": x["frame"], "scores": {"a": y["scores"]["v"], "b": x["scores"]["v"]}} for x, y in zip(bb, ab)]
        m, lo, hi = boot_ci(both, diff_stat("a", "b"))
        lines += ["", f"Paired (same objects in both): after − before = {100 * m:+.1f} points [{100 * lo:+.1f}, {100 * hi:+.1f}]."]
    else:
        lines += ["", "The two sides hold different objects (plans differ): unpaired."]
    lines += ["", "| class | before | after |", "|---|---:|---:|"]
    for c in CLASSES:
        rb, ra = [r for r in bb if r["cls"] == c], [r for r in ab if r["cls"] == c]
        if rb or ra:
            lines.append(f"| {c} | {fmt(boot_ci(rb, recall_stat('v')))} (n={len(rb)}) | "
                         f"{fmt(boot_ci(ra, recall_stat('v')))} (n={len(ra)}) |")
    text = "\n".join(lines) + "\n"
    print(text)
    atomic.write_text(args.doc, text)


if __name__ == "__main__":
    main()
