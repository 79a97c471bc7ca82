"""Asset-library benchmark: does a library asset cost detector recall or render time?

    .venv/bin/python benchmarks/realism/bench_assets.py [--per-class 3] [--repeat 2]

The seven procedural classes are exported to GLB (benchmarks/realism/make_test_assets.py
--procedural) and injected through `inject.assets` (asset_share 1) into the six real Udacity
highway photos (each used `--repeat` times, different objects each time); the baseline is
the same job with the procedural objects themselves (asset_share 0). Same backgrounds, same
class weights, same post-processing. Reported: YOLOX-Nano recall@0.5 pooled over objects
(`blendgen realism`) with a bootstrap 95 % interval of the difference, per-frame render time
(median, wall; the machine is shared), and the inspection step's time per asset.
Writes benchmarks/results/assets.png and docs/benchmarks/assets.md.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import DETECTOR, REAL, RESULTS, TMP, blendgen_cmd, sh, write_doc  # noqa: E402

from blendgen import atomic  # noqa: E402

PHOTOS = REAL / "udacity_highway_images"


def _job(work: Path, share: float, name: str) -> Path:
    job = {"name": name, "seed": 5, "recording": "rec",
           "ground_plane": {"camera_height_m": 1.4, "pitch_deg": -1.0, "lane_width_m": 3.7},
           "inject": {"objects_per_frame": [5, 6], "distance_m": [8, 30], "sequences": False,
                      "classes": {"car": 3, "truck": 1, "bus": 1, "person": 1, "motorcycle": 1, "bicycle": 1},
                      "assets": ["lib"], "asset_share": share},
           "render": {"resolution": [640, 360], "samples": 16, "denoise": True},
           "post": {"illumination": "auto", "color_transfer": "reinhard", "shadows": True},
           "export": {"formats": ["coco"], "min_visible_px": 64}, "output": f"out_{name}"}
    p = work / f"{name}.yaml"
    p.write_text(yaml.safe_dump(job, sort_keys=False))
    return p


def _area(region) -> int:
    return (region[2] - region[0]) * (region[3] - region[1]) if region else 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--per-class", type=int, default=3)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--work", type=Path, default=TMP / "assets")
    ap.add_argument("--resume", action="store_true", help="keep the work folder's finished runs (rescore)")
    args = ap.parse_args()
    if not PHOTOS.is_dir() or not DETECTOR.is_file():
        raise SystemExit(f"needs {PHOTOS} and {DETECTOR}")
    work = args.work
    if not (args.resume and (work / "rec").is_dir()):
        shutil.rmtree(work, ignore_errors=True)
        (work / "photos").mkdir(parents=True)
        for f in sorted(PHOTOS.glob("*.jpg")):
            for k in range(args.repeat):
                shutil.copy(f, work / "photos" / f"{f.stem}_{k}.jpg")
        sh(blendgen_cmd("import", "images", "photos", "rec", "--hfov", "55"), cwd=work)
        r = subprocess.run([sys.executable, str(HERE / "make_test_assets.py"), str(work / "lib"), "--procedural",
                            str(args.per_class)], capture_output=True, text=True)
        if r.returncode != 0:
            raise SystemExit(r.stderr[-3000:])

    from blendgen.eval.realism import run_realism

    arms = {"procedural": 0.0, "library": 1.0}
    for name, share in arms.items():
        sh(blendgen_cmd("run", str(_job(work, share, name)), "--quiet"), cwd=work)
    res = run_realism(work / "out_procedural", DETECTOR, compare=work / "out_library", write=False)
    rows, hits = {}, {}
    for name, run in zip(arms, res["runs"]):
        tp = sum(c["tp"] for c in run["classes"].values())
        n = sum(c["n_gt"] for c in run["classes"].values())
        hits[name] = np.r_[np.ones(tp), np.zeros(n - tp)]
        manifest = (work / f"out_{name}" / "manifest.jsonl").read_text().splitlines()
        recs = [json.loads(line) for line in manifest if line.strip()]
        frames = [r for r in recs if r.get("stage") == "frames"]
        render = [r["timings"]["render"] for r in frames]
        # the plans differ (library dims), so also per rendered pixel: the region, else the frame
        px = [_area(r["render"].get("region")) or r["render"]["canvas"][0] * r["render"]["canvas"][1] for r in frames]
        inspect = [r["farm"]["process_s"] for r in recs if r.get("stage") == "assets"]
        rows[name] = {"objects": n, "found": tp, "recall": tp / n, "render_s": statistics.median(render),
                      "us_per_px": statistics.median(1e6 * t / p for t, p in zip(render, px)),
                      "mpx": sum(px) / 1e6, "frames": len(render), "assets": len(inspect),
                      "inspect_s": statistics.median(inspect)}
    rng = np.random.default_rng(0)
    a, b = hits["procedural"], hits["library"]
    diff = [rng.choice(b, len(b)).mean() - rng.choice(a, len(a)).mean() for _ in range(5000)]
    lo, hi = np.percentile(diff, [2.5, 97.5])
    per_class = res["table"]

    table = ["| objects from | objects | found | recall@0.5 | render s/frame (median) | rendered Mpx | "
             "render us/px (median) | frames |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for name, r in rows.items():
        table.append(f"| {name} | {r['objects']} | {r['found']} | {r['recall']:.3f} | {r['render_s']:.2f} | "
                     f"{r['mpx']:.2f} | {r['us_per_px']:.1f} | {r['frames']} |")
    text = "\n".join(table)
    lib, proc = rows["library"], rows["procedural"]
    summary = (f"library - procedural recall: {b.mean() - a.mean():+.3f} (bootstrap 95 % CI {lo:+.3f} .. {hi:+.3f}); "
               f"render time ratio library/procedural {lib['render_s'] / proc['render_s']:.2f} per frame, "
               f"{lib['us_per_px'] / proc['us_per_px']:.2f} per rendered pixel; assets step: "
               f"{lib['inspect_s']:.3f} s per asset (median import + measure, {lib['assets']} assets)")
    print(text)
    print(summary)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(8, 3.2))
    names = list(rows)
    ax[0].bar(names, [rows[n]["recall"] for n in names], color=["#888", "#3a7"])
    ax[0].set_ylabel("YOLOX-Nano recall@0.5")
    ax[0].set_ylim(0, 1)
    ax[1].bar(names, [rows[n]["us_per_px"] for n in names], color=["#888", "#3a7"])
    ax[1].set_ylabel("render us / rendered pixel (median)")
    fig.suptitle("procedural objects vs the same objects as a GLB library (Udacity photos)")
    fig.tight_layout()
    png = RESULTS / "assets.png"
    with atomic.atomic_path(png) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    md = ["# Asset libraries: recall and render time", "",
          "Command: `.venv/bin/python benchmarks/realism/bench_assets.py "
          f"--per-class {args.per_class} --repeat {args.repeat}` (2 shared CPU cores; times are wall, noisy).", "",
          f"{len(sorted(PHOTOS.glob('*.jpg')))} real Udacity highway photos x {args.repeat}, 640x360, 16 spp + OIDN, "
          f"illumination auto, Reinhard; library: {rows['library']['assets']} GLB exports of the procedural "
          "objects (`make_test_assets.py --procedural`), asset_share 1 vs 0.", "", text, "", summary, "",
          "Per class (A: procedural, B: library):", "", per_class, ""]
    write_doc("assets.md", "\n".join(md))
    print(f"wrote {png} and docs/benchmarks/assets.md")


if __name__ == "__main__":
    main()
