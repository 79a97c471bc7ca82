"""What are blendgen's composites worth for training? Fine-tune YOLOX-Nano on them and score it
on real labelled photos (blendgen train-check, blendgen/train/).

Backgrounds: every real driving frame in ../shared/data/real/ (BLENDGEN_SHARED_DATA), each
camera imported as its own recording (`blendgen import images`, the field of view from the
camera's calibration where one is given): nuScenes CAM_FRONT stills, frames of the Udacity
highway video, the Udacity highway photos, the BDD street photos, the Udacity CarND camera's
frames, DDAD (2 rigs) and Argoverse. Small sets are used several times (a different object set
per copy). The GoPro clip (a drone over cliffs) and comma2k19 (no video) are not driving frames.
nuScenes, DDAD and Argoverse are CC BY-NC-SA: their composites stay under benchmarks/results/tmp/.

Object sets (one `blendgen run` per recording, ground_plane: auto, the frame analysis on,
render at --width px wide, objects of the test set's classes; labels.real: detector):
- `aware`: road-aware placement (the frame analysis), colour transfer none (the default);
- `reinhard`: the same jobs with post.color_transfer: reinhard;
- `noanalysis` (road-unaware placement): ground_plane.analysis: false, the camera fixed at the
  median of `aware`'s per-frame height, pitch and roll for that recording, objects placed on
  that flat plane by the same planner with no knowledge of the real road, road users or hood
  (they may stand in real cars, off the road, on the hood). Not random placement: the same
  distances, lanes of a flat road and classes; only the frame's own road is unknown. The real
  road users are labelled as in `aware` (the detector runs on the frame either way);
- `assets`: `aware` with the third-party models of ../shared/data/assets_thirdparty as a user
  gets them, named in the job as docs/assets.md shows (THIRDPARTY below: OpenMATERIAL man and
  truck, Gazebo Prius, SUV, hatchback and bus); every car, truck, bus and person comes from
  that library (asset_share 1), motorcycles stay procedural (the library has none).

Arms, each the same number of training images (--images, a seeded subset per training seed)
and the same schedule (--epochs, --batch):
- `base`: the COCO-pretrained model, no fine-tuning;
- `unlabelled`: `aware` composites, injected objects labelled only (the export before
  labels.real: the real road users are background);
- `real_labelled`: `aware` composites with the real road users labelled (detector score >=
  0.5) or ignored (below it);
- then on the better of those two: `reinhard`, `noanalysis`, `assets`;
- with --real-reference, `real_photos`: the same number of the labelled set's own real
  training photos (train split, human boxes) -- what in-domain real labels give, for scale.

Test: ../shared/data/real/labelled/highway_objects_cc_by/test (251 real photos, human boxes,
bus car motorcycle person truck; roadside photos, NOT dashcam views). AP@0.5 per class with
pycocotools, mean over --seeds, 95 % bootstrap intervals over test images, paired differences.

    PYTHONPATH=$PWD nice -n 5 .venv/bin/python benchmarks/labels/bench_train_check.py \
        [--images 200 --epochs 3 --seeds 0,1,2 --width 640 --copies 1] [--cache DIR]
        [--render-only]

Everything is cached under --cache (default benchmarks/results/tmp/train_check/; keep it
outside a git worktree for long runs): re-running resumes, and --render-only renders the sets
and stops, so a second process can render while the first trains. Writes
docs/benchmarks/train_check.md and benchmarks/results/train_check.png.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import DOCS, RESULTS, SHARED_DATA, blendgen_cmd, sh  # noqa: E402

from blendgen import atomic  # noqa: E402

REAL = SHARED_DATA / "real"
TEST = REAL / "labelled" / "highway_objects_cc_by" / "test"
TMP = RESULTS / "tmp" / "train_check"
DOC = DOCS / "train_check.md"
PLOT = RESULTS / "train_check.png"
CLASSES = {"car": 2.0, "truck": 1.5, "bus": 1.5, "person": 1.5, "motorcycle": 1.5}  # the test set's classes
SEED = 46
# The third-party library as a user gets it (../shared/data/README.md), named in the job as
# docs/assets.md shows; classes it lacks (motorcycle) stay procedural.
THIRDPARTY = [("openmaterial3d", {}),  # class, licence and axes from each .xoma (a walking man, a car)
              ("openmaterial_validation", {"class": "truck", "missing_textures": "ignore"}),  # plate PNG not shipped
              ("gazebo_models/prius_hybrid", {"class": "car"}), ("gazebo_models/suv", {"class": "car"}),
              ("gazebo_models/hatchback", {"class": "car"}), ("gazebo_models/bus", {"class": "bus"})]


def zoo_hfov(folder: Path) -> float:
    """Horizontal field of view from a camera_zoo calib.txt (fx, width)."""
    text = (folder / "calib.txt").read_text()
    fx = float(re.search(r"^fx:\s*~?([\d.]+)", text, re.M).group(1))
    w = float(re.search(r"^width:\s*(\d+)", text, re.M).group(1))
    return math.degrees(2 * math.atan(w / 2 / fx))


def sources(args) -> dict[str, dict]:
    """name -> {files: [image paths or (video, index)], hfov, copies}."""
    zoo = REAL / "camera_zoo"
    out = {
        "nuscenes": {"files": sorted((zoo / "nuscenes_cam_front").glob("*.jpg"))[:args.nuscenes],
                     "hfov": zoo_hfov(zoo / "nuscenes_cam_front"), "copies": 1},
        "udacity_video": {"video": REAL / "udacity_solidWhiteRight.mp4", "frames": args.video_frames, "hfov": 55,
                          "copies": 1},
        "udacity_photos": {"files": sorted((REAL / "udacity_highway_images").glob("*.jpg")), "hfov": 55,
                           "copies": 3 * args.copies},
        "bdd": {"files": sorted((REAL / "bdd_street_photos").glob("*.jpg")), "hfov": 60, "copies": 6 * args.copies},
        "udacity_carnd": {"files": sorted((zoo / "udacity_carnd").glob("*.jpg")), "hfov": zoo_hfov(zoo / "udacity_carnd"),
                          "copies": 2 * args.copies},
        "ddad01": {"files": sorted((zoo / "ddad_scene01").glob("*.jpg")), "hfov": zoo_hfov(zoo / "ddad_scene01"),
                   "copies": 2 * args.copies},
        "ddad02": {"files": sorted((zoo / "ddad_scene02").glob("*.jpg")), "hfov": zoo_hfov(zoo / "ddad_scene02"),
                   "copies": 2 * args.copies},
        "argoverse": {"files": sorted((zoo / "argoverse1_stereo_front_left").glob("*.jpg")),
                      "hfov": zoo_hfov(zoo / "argoverse1_stereo_front_left"), "copies": 4 * args.copies},
    }
    return out


def make_recordings(args) -> dict[str, dict]:
    recs = {}
    for name, spec in sources(args).items():
        src, dst = TMP / f"src_{name}", TMP / f"rec_{name}"
        key = json.dumps({k: str(v) for k, v in spec.items()})
        if not (dst / "frames.csv").is_file() or (TMP / f"rec_{name}.key").read_text() != key:
            shutil.rmtree(src, ignore_errors=True)
            shutil.rmtree(dst, ignore_errors=True)
            src.mkdir(parents=True)
            k = 0
            if "video" in spec:
                cap = cv2.VideoCapture(str(spec["video"]))
                n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
                for idx in np.linspace(0, n - 1, spec["frames"]).astype(int):
                    cap.set(cv2.CAP_PROP_POS_FRAMES, int(idx))
                    ok, fr = cap.read()
                    if ok:
                        cv2.imwrite(str(src / f"{k:04d}_video_{idx:04d}.png"), fr)
                        k += 1
            else:
                if not spec["files"]:
                    raise SystemExit(f"needs the {name} frames in {REAL}")
                for c in range(spec["copies"]):
                    for p in spec["files"]:
                        os.symlink(p, src / f"{k:04d}_{p.stem}{p.suffix}")
                        k += 1
            sh(blendgen_cmd("import", "images", src, dst, "--hfov", f"{spec['hfov']:.3f}", "--force", "--no-progress"))
            (TMP / f"rec_{name}.key").write_text(key)
        cam = read_camera(dst)
        recs[name] = {"dir": dst, "width": cam[0], "height": cam[1],
                      "frames": len((dst / "frames.csv").read_text().splitlines()) - 1}
    return recs


def read_camera(rec: Path) -> tuple[int, int]:
    import yaml

    return tuple(yaml.safe_load((rec / "calib.yaml").read_text())["camera"]["resolution"])


def job_for(set_name: str, rec_name: str, rec: dict, args, ground_plane) -> dict:
    w = args.width
    h = int(round(rec["height"] * w / rec["width"]))
    inject = {"objects_per_frame": [3, 6], "classes": CLASSES, "distance_m": [6, 35], "sequences": False}
    post = {}
    if set_name == "reinhard":
        post["color_transfer"] = "reinhard"
    if set_name == "assets":
        inject["assets"] = [{"path": str(args.assets / sub), **fields} for sub, fields in THIRDPARTY]
    return {"name": f"tc_{set_name}_{rec_name}", "seed": SEED, "recording": str(rec["dir"]),
            "ground_plane": ground_plane, "inject": inject,
            "render": {"resolution": [w, h], "samples": 16, "denoise": True},
            "post": post, "export": {"formats": ["coco"], "save_exr": False},
            "labels": {"real": "detector"}, "farm": {"workers": 1}, "output": str(TMP / set_name / rec_name)}


SEVERAL_CARS = ("bdd",)  # stills from different cars: a camera mount per image


def fixed_ground_plane(rec_name: str) -> dict:
    """The median of the aware set's per-frame camera estimates: the pose a careful user would fix."""
    done = TMP / "aware" / rec_name / "run_summary.json"
    while not done.is_file():  # the aware set may still run in another process (--render-only)
        print(f"[noanalysis] {rec_name}: waiting for the aware set's analysis ...", flush=True)
        time.sleep(60)
    cams = [json.loads(p.read_text())["camera"] for p in sorted((TMP / "aware" / rec_name / "analysis").glob("f*.json"))]
    med = {k: float(np.median([c[src] for c in cams])) for k, src in
           (("camera_height_m", "height_m"), ("pitch_deg", "pitch_deg"), ("roll_deg", "roll_deg"))}
    return {**med, "analysis": False}


def render_set(set_name: str, recs: dict, args) -> dict:
    import yaml

    times = {}
    for rec_name, rec in recs.items():
        gp = fixed_ground_plane(rec_name) if set_name == "noanalysis" else \
            {"camera_height_m": "auto", "pitch_deg": "auto", "roll_deg": "auto", "stills": "per_image"} \
            if rec_name in SEVERAL_CARS else "auto"
        job = job_for(set_name, rec_name, rec, args, gp)
        jp = TMP / set_name / f"{rec_name}.yaml"
        jp.parent.mkdir(parents=True, exist_ok=True)
        jp.write_text(yaml.safe_dump(job, sort_keys=False))
        t = time.perf_counter()
        print(f"[{set_name}] {rec_name}: {rec['frames']} frames ...", flush=True)
        sh(blendgen_cmd("run", jp))
        times[rec_name] = round(time.perf_counter() - t, 1)
    return times


def training_samples(set_name: str, recs: dict, *, real_labels: bool):
    """The set's composites as training samples; without real labels, only the injected objects
    (what the export held before labels.real)."""
    from blendgen.train.data import from_coco

    out = []
    for rec_name in recs:
        for s in from_coco(TMP / set_name / rec_name / "labels" / "coco.json", TMP / set_name / rec_name):
            if not real_labels:
                keep = np.array([src == "injected" for src in s.sources], bool)
                s.boxes, s.category_ids = s.boxes[keep], s.category_ids[keep]
                s.sources = [x for x, k in zip(s.sources, keep) if k]
                s.ignores = np.zeros((0, 4))  # the ignore regions are the real objects' too
            out.append(s)
    return out


def run_arm(arm: str, samples, test, cats, args) -> list:
    """Per seed: match records of the fine-tuned model on the test set (cached per arm and seed)."""
    from blendgen.detection.detector import BUNDLED_MODEL
    from blendgen.train.check import fine_tune, predict, subset
    from blendgen.train.evaluate import cocoeval_ap50, match_records
    from blendgen.train.yolox import load_onnx

    recs = []
    for seed in args.seeds:
        tag = f"{arm}_n{args.images}_e{args.epochs:g}_b{args.batch}_w{args.width}"
        tag += f"_nu{args.nuscenes}_v{args.video_frames}_c{args.copies}"
        if args.recordings:
            tag += "_" + args.recordings.replace(",", "+")
        cache = TMP / "runs" / f"{tag}_s{seed}.json"
        if not cache.is_file():
            if arm == "base":
                model, log = load_onnx(BUNDLED_MODEL).eval(), {"train_s": 0.0}
            else:
                chosen = subset(samples, args.images, seed)
                model, log = fine_tune(BUNDLED_MODEL, chosen, seed=seed, epochs=args.epochs, batch=args.batch)
                log["labels"] = int(sum(len(s.boxes) for s in chosen))
                log["ignores"] = int(sum(len(s.ignores) for s in chosen))
            dets = predict(model, test, cats)
            atomic.write_json(cache, {"log": log, "dets": dets, "cocoeval": cocoeval_ap50(test, dets, cats)})
            print(f"  {arm} seed {seed}: {json.dumps(log)}", flush=True)
        d = json.loads(cache.read_text())
        recs.append({"records": match_records(test, d["dets"], cats), "log": d["log"],
                     "cocoeval": {int(k): v for k, v in d["cocoeval"].items()}})
        if arm == "base":
            break  # no training: one seed is all seeds
    return recs


def main() -> None:
    global TMP
    ap = argparse.ArgumentParser()
    ap.add_argument("--images", type=int, default=200, help="training images per arm and seed")
    ap.add_argument("--epochs", type=float, default=3.0)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--width", type=int, default=640, help="render width (px)")
    ap.add_argument("--nuscenes", type=int, default=100, help="nuScenes stills used (of 100)")
    ap.add_argument("--video-frames", type=int, default=60, help="frames of the Udacity highway video")
    ap.add_argument("--copies", type=int, default=1, help="multiplies the reuse of the small still sets")
    ap.add_argument("--assets", type=Path, default=SHARED_DATA / "assets_thirdparty",
                    help="the third-party library of the `assets` set (THIRDPARTY names its models)")
    ap.add_argument("--cache", type=Path, default=TMP, help="recordings, renders and fine-tuned runs (resumable)")
    ap.add_argument("--render-only", action="store_true", help="render the sets and stop")
    ap.add_argument("--sets", default="aware,reinhard,noanalysis,assets")
    ap.add_argument("--recordings", default=None, help="only these backgrounds (comma-separated names)")
    ap.add_argument("--real-reference", action="store_true",
                    help="also fine-tune on the labelled set's real training photos (same image count)")
    ap.add_argument("--bootstrap", type=int, default=1000)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    args.seeds = [int(s) for s in args.seeds.split(",")]
    TMP = args.cache.resolve()
    if not TEST.is_dir():
        raise SystemExit(f"needs {TEST}")
    import torch

    torch.set_num_threads(args.threads)
    from blendgen.recording.labels import labelled_folder
    from blendgen.train.data import from_labelled

    TMP.mkdir(parents=True, exist_ok=True)
    recs = make_recordings(args)
    if args.recordings:
        recs = {k: v for k, v in recs.items() if k in args.recordings.split(",")}
    print("recordings: " + ", ".join(f"{k} {v['frames']}" for k, v in recs.items()), flush=True)
    render_times, pending = {}, {}
    for s in args.sets.split(","):
        try:
            render_times[s] = render_set(s, recs, args)
        except RuntimeError as e:
            if s != "assets":
                raise
            pending[s] = str(e).splitlines()[-1][:400]
            print(f"[{s}] pending: {pending[s]}", flush=True)
    if args.render_only:
        return
    test = from_labelled(labelled_folder(TEST / "images", TEST / "labels", "yolo"))
    cats = sorted({int(c) for s in test for c in s.category_ids})
    arms = {"base": None,
            "unlabelled": training_samples("aware", recs, real_labels=False),
            "real_labelled": training_samples("aware", recs, real_labels=True)}
    results = {a: run_arm(a, smp, test, cats, args) for a, smp in arms.items()}
    from blendgen.train.evaluate import bootstrap

    first = bootstrap({a: [r["records"] for r in results[a]] for a in ("unlabelled", "real_labelled")}, cats,
                      len(test), n_boot=200)
    better = max(("unlabelled", "real_labelled"), key=lambda a: first["arms"][a]["mean"]["ap"])
    for s in ("reinhard", "noanalysis", "assets"):
        if s in render_times:
            arms[s] = training_samples(s, recs, real_labels=better == "real_labelled")
            results[s] = run_arm(s, arms[s], test, cats, args)
    if args.real_reference:
        train_dir = TEST.parent / "train"
        arms["real_photos"] = from_labelled(labelled_folder(train_dir / "images", train_dir / "labels", "yolo"))
        results["real_photos"] = run_arm("real_photos", arms["real_photos"], test, cats, args)
    pairs = [("unlabelled", "base"), ("real_labelled", "base"), ("real_labelled", "unlabelled")]
    pairs += [(s, better) for s in ("reinhard", "noanalysis", "assets") if s in results]
    pairs += [("real_photos", "base")] if "real_photos" in results else []
    summary = bootstrap({a: [r["records"] for r in results[a]] for a in results}, cats, len(test),
                        n_boot=args.bootstrap, pairs=pairs)
    meta = {"args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items() if k != "assets"},
            "recordings": {k: v["frames"] for k, v in recs.items()}, "render_s": render_times, "pending": pending,
            "better": better, "composites": {a: len(s) for a, s in arms.items() if s is not None},
            "logs": {a: [r["log"] for r in results[a]] for a in results},
            "cocoeval": {a: [r["cocoeval"] for r in results[a]] for a in results}}
    atomic.write_json(TMP / "summary.json", {"summary": summary, "meta": meta}, indent=1)
    write_doc(summary, meta, cats, " ".join(sys.argv[1:]))


ARM_TEXT = {
    "base": "COCO-pretrained, no fine-tuning",
    "unlabelled": "composites, real road users unlabelled (injected objects only)",
    "real_labelled": "composites, real road users labelled (detector >= 0.5) or ignored",
    "reinhard": "… with colour transfer reinhard",
    "noanalysis": "… placed without the frame analysis (fixed camera, flat plane)",
    "assets": "… with third-party assets",
    "real_photos": "reference: the labelled set's own real training photos",
}


def write_doc(summary: dict, meta: dict, cats: list, argv: str) -> None:
    from blendgen.train.data import CLASS_OF_ID
    from blendgen.train.report import fmt

    a = meta["args"]
    names = [CLASS_OF_ID[c] for c in cats]
    arms = summary["arms"]
    lines = ["# Training check: what the composites are worth to a detector", "",
             f"Made by `PYTHONPATH=$PWD nice -n 5 .venv/bin/python benchmarks/labels/bench_train_check.py {argv}` "
             "(benchmarks/labels/bench_train_check.py; its docstring says what each set and arm is). "
             "Machine: 2 shared CPU cores, no GPU.", "",
             f"Size: backgrounds {sum(meta['recordings'].values())} real frames from "
             f"{len(meta['recordings'])} cameras ({', '.join(f'{k} {v}' for k, v in meta['recordings'].items())}), "
             f"rendered {a['width']} px wide; each arm fine-tunes on {a['images']} of its composites (a seeded "
             f"subset per seed), {a['epochs']:g} epochs, batch {a['batch']}, seeds {', '.join(map(str, a['seeds']))}. "
             f"Test: {summary['n_images']} real photos of highway_objects_cc_by/test. AP@0.5 per class by "
             "pycocotools, mean over seeds; [95 % bootstrap interval over test images, "
             f"{summary['n_boot']} draws].", "",
             "| arm | " + " | ".join(names) + " | class mean (mAP@0.5) |",
             "|---|" + "---|" * (len(names) + 1)]
    for arm, row in arms.items():
        lines.append(f"| {arm}: {ARM_TEXT.get(arm, arm)} | " + " | ".join(fmt(row[str(c)]) for c in cats)
                     + f" | **{fmt(row['mean'])}** |")
    lines += ["", "Paired differences (same test-image draws for both arms):", "",
              "| difference | " + " | ".join(names) + " | class mean |", "|---|" + "---|" * (len(names) + 1)]
    for pair, row in summary["pairs"].items():
        lines.append(f"| {pair} | " + " | ".join(fmt(row[str(c)], "diff") for c in cats)
                     + f" | **{fmt(row['mean'], 'diff')}** |")
    lines += ["", "Per seed (class mean): " + "; ".join(
        f"{arm} " + ", ".join(f"{v:.3f}" for v in row["mean"]["seeds"]) for arm, row in arms.items()) + "."]
    if meta["pending"]:
        lines += ["", "Pending: " + "; ".join(f"`{k}`: {v}" for k, v in meta["pending"].items())]
    lines += ["", f"The better of the two labelling arms ({meta['better']}) is the base of the colour, placement "
              "and asset arms.", "", "## What it shows", ""]
    lines += [f"- {sentence(pair, row)}" for pair, row in summary["pairs"].items()]
    lines += ["", "## What it cannot show", "",
              CANNOT_SHOW.format(images=a["images"], epochs=a["epochs"], seeds=len(a["seeds"])), ""]
    atomic.write_text(DOC, "\n".join(lines) + "\n")
    print("\n".join(lines))
    _plot(summary, cats, names)


CANNOT_SHOW = (
    "The test photos are roadside and street photos (mostly close views of buses and trucks, "
    "Indonesia), not dashcam views: they measure whether training on the composites keeps or "
    "improves the detector's grip on real appearance, not on a dashcam's viewpoint, distances or "
    "occlusions, where composites of dashcam frames should matter most. The fine-tuning is short "
    "({images} images, {epochs:g} epochs, YOLOX-Nano, CPU): it shows which way a dataset pulls a "
    "COCO-pretrained detector, not what a full training run reaches, and effects that need many "
    "epochs to appear (or to wash out) are not seen. Real road users in the composites are labelled "
    "by the same detector that is fine-tuned (detector >= 0.5): its own mistakes become labels. "
    "Intervals cover the test images and the {seeds} training seeds, not other backgrounds, object sets or "
    "detectors.")


def sentence(pair: str, row: dict) -> str:
    m = row["mean"]
    if not math.isfinite(m["diff"]):
        return f"{pair}: no value."
    what = ("higher" if m["lo"] > 0 else "lower") if (m["lo"] > 0 or m["hi"] < 0) else "not resolved from zero"
    classes = [c for c, v in row.items() if c != "mean" and (v["lo"] > 0 or v["hi"] < 0)]
    from blendgen.train.data import CLASS_OF_ID

    per = ("; per class resolved from zero: " + ", ".join(f"{CLASS_OF_ID[int(c)]} {row[c]['diff']:+.3f}"
                                                           for c in classes)) if classes else ""
    return (f"`{pair}`: mAP@0.5 {m['diff']:+.3f} [{m['lo']:+.3f}, {m['hi']:+.3f}], {what}{per}.")


def _plot(summary: dict, cats: list, names: list) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    arms = list(summary["arms"])
    keys = [str(c) for c in cats] + ["mean"]
    fig, ax = plt.subplots(figsize=(10, 4))
    w = 0.8 / len(arms)
    for k, arm in enumerate(arms):
        row = summary["arms"][arm]
        x = np.arange(len(keys)) + k * w
        y = [row[c]["ap"] for c in keys]
        err = [[row[c]["ap"] - row[c]["lo"] for c in keys], [row[c]["hi"] - row[c]["ap"] for c in keys]]
        ax.bar(x, y, w, yerr=err, capsize=2, label=arm)
    ax.set_xticks(np.arange(len(keys)) + 0.4 - w / 2, names + ["mean"])
    ax.set_ylabel("AP@0.5 on real test photos")
    ax.legend(fontsize=8, ncol=3)
    fig.tight_layout()
    PLOT.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(PLOT, dpi=110)


if __name__ == "__main__":
    main()
