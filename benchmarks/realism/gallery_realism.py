"""Side by side: injected objects next to real objects of the same class and size, cropped from
the same photos, by day and by night (docs/gallery_realism.md).

Reads the realism benchmark's cache (benchmarks/realism/bench_realism.py: its renders, their scores and
its recordings) and uses only the MIT-licensed backgrounds (the BDD street photos and the
Udacity highway photos; camera_zoo's frames are CC BY-NC-SA and never enter these images). For
every real object YOLOX-Nano finds in a background photo (score >= 0.6, not on the ego hood), it looks for injected
objects of the same class whose box is within a third of its height in composites of that same
photo, one from each object set (procedural, and the third-party library where cached), and
puts the three crops in a row: real | procedural | library, each scaled to the same tile height,
labelled with the box height and, for injected objects, YOLOX-Nano's score for its class.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/realism/gallery_realism.py [--cache DIR]

Writes docs/images/realism_gallery_day.jpg and realism_gallery_night.jpg (JPEG, a few hundred
KB) and prints, per class and condition, how many rows it found.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import DETECTOR, RESULTS, ROOT  # noqa: E402

from blendgen import CLASSES  # noqa: E402

OUT = ROOT / "docs" / "images"
MIT_RECS = ("bdd-", "udacity")  # name prefixes; camera_zoo's nuScenes, DDAD and Argoverse frames are CC BY-NC-SA
NIGHT = "9aa94005-ff1d4c9a"
REAL_SCORE = 0.6
SIZE_TOL = 1 / 3  # an injected object's height within this fraction of the real one's
TILE_H = 112
ROWS_PER_CLASS = 2
SETS = ("procedural", "thirdparty")
NAMES = {cid: n for n, cid in CLASSES.items()}


def crop(img, box, tile_h=TILE_H):
    """The box with a margin of a quarter of its height, scaled to tile_h px high."""
    x, y, w, h = box
    m = 0.25 * h
    x0, y0 = int(max(0, x - m)), int(max(0, y - m))
    x1, y1 = int(min(img.shape[1], x + w + m)), int(min(img.shape[0], y + h + m))
    c = img[y0:y1, x0:x1]
    s = tile_h / max(1, c.shape[0])
    return cv2.resize(c, (max(1, int(round(c.shape[1] * s))), tile_h),
                      interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_CUBIC)


def on_hood(box, analysis: Path) -> bool:
    """Whether a detection lies mostly on the ego hood the frame analysis found (YOLOX-Nano
    calls the BDD camera car's own hood a car)."""
    if not analysis.is_file():
        return False
    hood = json.loads(analysis.read_text()).get("hood")
    if not hood:
        return False
    x, y, w, h = (int(round(v)) for v in box)
    poly = np.asarray(hood, np.float32)
    mask = np.zeros((int(poly[:, 1].max()) + h + y + 2, int(poly[:, 0].max()) + w + x + 2), np.uint8)
    cv2.fillPoly(mask, [np.round(poly).astype(np.int32)], 1)
    return mask[y:y + h, x:x + w].mean() > 0.3


def label(tile, text):
    if tile.shape[1] < 150:  # room for the label
        tile = cv2.copyMakeBorder(tile, 0, 0, 0, 150 - tile.shape[1], cv2.BORDER_CONSTANT, value=(255, 255, 255))
    out = cv2.copyMakeBorder(tile, 16, 0, 0, 0, cv2.BORDER_CONSTANT, value=(30, 30, 30))
    cv2.putText(out, text, (3, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (235, 235, 235), 1, cv2.LINE_AA)
    return out


def composites(cache: Path, name: str, rec: str, frames: set[str]) -> dict[str, np.ndarray]:
    """Default-post composites of the set's frames (re-made from the cached EXRs)."""
    from blendgen.farm.seeds import frame_seed
    from blendgen.job.schema import Post
    from blendgen.post.composite import composite_frame
    from blendgen.post.illumination import estimate_illumination
    from blendgen.recording.folder import read_frame, read_recording
    from blendgen.render.exr import read_passes

    recording = read_recording(cache / f"rec_{rec}")
    out = {}
    for fid in sorted(frames):
        exr = cache / name / rec / "frames" / fid / "render.exr"
        if not exr.is_file():
            continue
        real = read_frame(recording, int(fid.lstrip("f")))
        out[fid], _ = composite_frame(real, read_passes(exr), settings=Post(), illumination=estimate_illumination(real),
                                      seed=frame_seed(13, fid))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", type=Path, default=RESULTS / "tmp" / "realism")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    from blendgen.detection.detector import YoloxDetector
    from blendgen.recording.folder import read_frame, read_recording

    cache = args.cache.resolve()
    sets = {s: json.loads((cache / s / "scores.json").read_text()) for s in SETS if (cache / s / "scores.json").is_file()}
    if "procedural" not in sets:
        raise SystemExit(f"needs {cache}/procedural/scores.json: run benchmarks/realism/bench_realism.py first")
    det = YoloxDetector(DETECTOR, category_ids=set(CLASSES.values()))
    rows = {"day": [], "night": []}
    found = {}
    recs = sorted(f.name[4:-len(".names.json")] for f in cache.glob("rec_*.names.json"))
    for rec in [r for r in recs if r.startswith(MIT_RECS)]:
        names = json.loads((cache / f"rec_{rec}.names.json").read_text())
        recording = read_recording(cache / f"rec_{rec}")
        first = {}  # photo -> its first frame index (the untouched photo)
        for i, n in enumerate(names):
            first.setdefault(n, i)
        for photo, i in first.items():
            if "_video_" in photo:
                continue
            cond = "night" if NIGHT in photo else "day"
            real_img = read_frame(recording, i)
            reals = [d for d in det(real_img) if d["score"] >= REAL_SCORE and d["bbox"][3] >= 40
                     and not on_hood(d["bbox"], cache / "procedural" / rec / "analysis" / f"f{i:06d}.json")]
            # injected objects of this photo, per set: rows of scores.json on any of its copies
            inj = {s: [r for r in rs if r["frame"].startswith(f"{rec}/") and r["source"] == photo and r["h"] >= 40]
                   for s, rs in sets.items()}
            needed = {s: {r["frame"].split("/")[1] for r in v} for s, v in inj.items()}
            comps = {s: composites(cache, s, rec, needed[s]) for s in inj}
            for d in sorted(reals, key=lambda d: -d["bbox"][3]):
                cls = NAMES[d["category_id"]]
                if sum(1 for r in rows[cond] if r[0] == cls) >= ROWS_PER_CLASS:
                    continue
                hr = d["bbox"][3]
                tiles = [label(crop(real_img, d["bbox"]), f"real {cls} {hr:.0f}px")]
                for s in sets:
                    cand = [r for r in inj[s] if r["cls"] == cls and abs(r["h"] - hr) <= SIZE_TOL * hr
                            and r["frame"].split("/")[1] in comps[s] and (s == "procedural" or r.get("asset"))]
                    if not cand:
                        tiles.append(label(np.full((TILE_H, TILE_H, 3), 60, np.uint8), f"{s}: none"))
                        continue
                    r = min(cand, key=lambda r: abs(r["h"] - hr))
                    sc = r["scores"]["ct=none"]
                    tiles.append(label(crop(comps[s][r["frame"].split("/")[1]], r["bbox"]),
                                       f"{s[:5]} {r['h']:.0f}px " + (f"found {sc:.2f}" if sc >= 0.3 else "missed")))
                rows[cond].append((cls, tiles))
                found[cond, cls] = found.get((cond, cls), 0) + 1
    args.out.mkdir(parents=True, exist_ok=True)
    for cond, rs in rows.items():
        if not rs:
            continue
        rs.sort(key=lambda r: list(CLASSES).index(r[0]))
        width = max(sum(t.shape[1] for t in tiles) + 6 * (len(tiles) - 1) for _, tiles in rs)
        lines = []
        for _, tiles in rs:
            line = tiles[0]
            for t in tiles[1:]:
                line = np.hstack([line, np.full((line.shape[0], 6, 3), 255, np.uint8), t])
            lines.append(cv2.copyMakeBorder(line, 0, 6, 0, width - line.shape[1], cv2.BORDER_CONSTANT, value=(255, 255, 255)))
        img = np.vstack(lines)
        path = args.out / f"realism_gallery_{cond}.jpg"
        cv2.imwrite(str(path), img, [cv2.IMWRITE_JPEG_QUALITY, 85])
        print(f"{path}: {len(rs)} rows, {path.stat().st_size // 1024} KB")
    for c in CLASSES:
        print(f"{c}: day {found.get(('day', c), 0)} rows, night {found.get(('night', c), 0)} rows")


if __name__ == "__main__":
    main()
