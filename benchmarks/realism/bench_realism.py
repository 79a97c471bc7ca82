"""Realism on real backgrounds: does a COCO detector (YOLOX-Nano) find the objects we inject
into real dashcam photos and video frames, as their class?

Backgrounds (../shared/data/real/): the six Udacity highway photos and frames of
udacity_solidWhiteRight.mp4 (one 960x540 camera), and the three BDD street photos (day,
snow, night; 1280x720, ego hood visible), each still used several times (a different random
object set per copy); and every frame of real/camera_zoo/ once (five other rigs: 100
nuScenes CAM_FRONT stills, 6 DDAD, 1 Argoverse, 8 Udacity CarND), scaled to 960 px wide
(the detector reads 416 px: the scale changes nothing it sees, and the renders stay cheap on
2 CPU cores), the CarND frames undistorted with their chessboard calibration, each rig's
camera from its calib.txt (intrinsics, height, pitch; the CarND camera's height and pitch
estimated, as calib.txt gives none). camera_zoo's nuScenes, DDAD and Argoverse frames are
CC BY-NC-SA: their composites stay under benchmarks/results/tmp/ (git-ignored).

An *object set* is one `blendgen run` over those backgrounds (renders at the photos'
native resolution, 16 samples + denoise, render region on, multilayer EXRs kept):
- `procedural`: the procedural objects of this checkout (`--objects-rev REV` renders the
  objects of another commit: its assets_procedural/ is put first on PYTHONPATH; with the
  venv's editable install that does not take effect, and the bench stops saying so: render
  the before set from a checkout of REV);
- `procedural_illum_off`: the same objects rendered under the pipeline's default daylight
  and composited without light matching (`post.illumination: off`);
- `assets`: library assets (glTF exported from Blender with sidecars) through `inject.assets`;
- `thirdparty`: the third-party models of ../shared/data/assets_thirdparty as they come
  (OpenMATERIAL car, walking man and box truck in glTF; Gazebo Prius, SUV, hatchback, bus and
  traffic light in OBJ), named in the job (`inject.assets: [{path, class, ...}]`,
  THIRDPARTY below); classes the library lacks (bicycle, motorcycle) stay procedural. Its
  plans are the procedural set's (library draws have their own random stream), so the two
  pair object by object where the library object's size did not change the planner's
  choice.
Post-processing variants re-composite the same EXRs (composite_frame): colour transfer
none / reinhard / mkl / histogram after light matching. Variants of one set share objects,
so their differences are paired: bootstrap over frames (objects in a frame are not
independent), 2000 resamples, 95 % percentile intervals.

Scores: an injected object is found when a detection of its class with score >= 0.3 has
IoU >= 0.5 with its box (COCO matching, blendgen/detection/metrics.py); real objects that the
detector finds in the untouched background (score >= 0.05) are ignore regions. Mean
confidence = mean over objects of the matched detection's score (0 when none).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/realism/bench_realism.py [--quick] [--set procedural]
        [--name before --objects-rev main] [--copies-udacity 5 --copies-bdd 14 --video-frames 15]
        [--no-zoo]

The `before` set renders the objects of `--objects-rev` with the post-processing and lighting
(illumination estimate, night contact shadows, light matching) of the checkout that runs it,
and is scored with that checkout's post. To score a cached set's renders with another
checkout's post (e.g. after merging), run `--name before --rescore` there: the render-time
lighting (sun, street-light key, shadow catcher) stays the one it was rendered with.

Renders and results are cached under benchmarks/results/tmp/realism/ (re-running resumes), or
under `--cache DIR` / $BLENDGEN_REALISM_CACHE (e.g. another checkout's cache, so that a set
rendered there, such as `before`, is scored and tabled with this one's); the table combines every cached set: docs/benchmarks/realism.md, plot
benchmarks/results/realism.png, composites for looking at in benchmarks/results/tmp/realism/<set>/look/.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import DETECTOR, DOCS, REAL, RESULTS, ROOT, SHARED_DATA, blendgen_cmd, ci95, sh  # noqa: E402

from blendgen import CLASSES, atomic  # noqa: E402
from blendgen.detection.metrics import evaluate  # noqa: E402
from blendgen.job.schema import Post  # noqa: E402
from blendgen.scene.planner import NO_PLACE  # noqa: E402

MODEL = DETECTOR
TMP = Path(os.environ.get("BLENDGEN_REALISM_CACHE") or RESULTS / "tmp" / "realism")
DOC = DOCS / "realism.md"
PLOT = RESULTS / "realism.png"
NAMES = {cid: n for n, cid in CLASSES.items()}
SCORE_THR, IOU_THR, BG_SCORE = 0.3, 0.5, 0.05
HEIGHT_BINS = [(0, 20, "< 20 px"), (20, 40, "20-40 px"), (40, 80, "40-80 px"), (80, 160, "80-160 px"),
               (160, 1e9, ">= 160 px")]
TRANSFERS = ("none", "reinhard", "mkl", "histogram")
DEFAULT_VARIANT = f"ct={Post().color_transfer}"  # the pipeline's default post
BDD_NIGHT = "9aa94005-ff1d4c9a"
# Ground planes as the example jobs have them: Udacity as jobs/udacity_photos.yaml (1.23 m from
# `blendgen calibrate`, pitch and roll per photo from its lane lines), BDD all estimated. The three
# BDD photos come from three cars: each is its own recording (a recording is one camera, one mount).
BDD_PHOTOS = sorted((REAL / "bdd_street_photos").glob("*.jpg"))
BDD_PLANE = {"camera_height_m": "auto", "pitch_deg": "auto", "roll_deg": "auto", "lane_width_m": 3.5}
RECORDINGS = {
    "udacity": {"hfov": 55, "ground_plane": {"camera_height_m": 1.23, "pitch_deg": "auto", "roll_deg": "auto",
                                             "lane_width_m": 3.7}},
    **{f"bdd-{p.stem[:8]}": {"hfov": 60, "ground_plane": BDD_PLANE, "photo": p} for p in BDD_PHOTOS},
}
# camera_zoo rigs: folder, camera height and pitch from its calib.txt (pitch > 0 looks up;
# roll < 0.6 deg everywhere: 0), "auto" where calib.txt gives none
ZOO = REAL / "camera_zoo"
ZOO_RIGS = {
    "zoo_nuscenes": ("nuscenes_cam_front", 1.51, -0.3),
    "zoo_ddad01": ("ddad_scene01", 1.55, -1.57),
    "zoo_ddad02": ("ddad_scene02", 1.45, -0.48),
    "zoo_argoverse": ("argoverse1_stereo_front_left", 1.70, 0.36),
    "zoo_carnd": ("udacity_carnd", "auto", "auto"),
}
ZOO_WIDTH = 960
NIGHT_SOURCES = (BDD_NIGHT,)  # the one night photo: camera_zoo has none (calib.txt: brightness scan)
VEHICLE_PX = 80  # vehicles' target holds at >= 80 px tall
# The third-party library as a user gets it (../shared/data/README.md), named in the job.
THIRDPARTY_DIR = SHARED_DATA / "assets_thirdparty"
THIRDPARTY = [("openmaterial3d", {}),  # class, licence and axes from each .xoma
              ("openmaterial_validation", {"class": "truck", "missing_textures": "ignore"}),  # its plate PNG is not shipped
              ("gazebo_models/prius_hybrid", {"class": "car"}), ("gazebo_models/suv", {"class": "car"}),
              ("gazebo_models/hatchback", {"class": "car"}), ("gazebo_models/bus", {"class": "bus"}),
              ("gazebo_models/stop_light", {"class": "traffic light", "front": "-x"})]  # lamps face -x


def make_recordings(args) -> dict[str, dict]:
    """Recordings of the backgrounds (stills repeated), with frame index -> source name."""
    out = {}
    for rec, spec in RECORDINGS.items():
        src = TMP / f"src_{rec}"
        dst = TMP / f"rec_{rec}"
        if rec == "udacity":
            stills = sorted((REAL / "udacity_highway_images").glob("*.jpg"))
            copies = args.copies_udacity
        else:
            stills = [spec["photo"]]
            copies = args.copies_bdd
        missing = [p for p in stills if not p.is_file()]
        if not stills or missing or not BDD_PHOTOS:
            raise SystemExit(f"needs {REAL}/ (udacity_highway_images, bdd_street_photos)")
        key = json.dumps([copies, args.video_frames, [p.name for p in stills]])
        if not (dst / "frames.csv").is_file() or (TMP / f"rec_{rec}.key").read_text() != key:
            shutil.rmtree(src, ignore_errors=True)
            src.mkdir(parents=True)
            names = []
            for c in range(copies):
                for p in stills:
                    names.append(p.stem)
                    os.symlink(p, src / f"{len(names) - 1:04d}_{p.stem}.jpg")
            if rec == "udacity" and args.video_frames:
                cap = cv2.VideoCapture(str(REAL / "udacity_solidWhiteRight.mp4"))
                n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
                for k in np.linspace(0, n - 1, args.video_frames).astype(int):
                    cap.set(cv2.CAP_PROP_POS_FRAMES, int(k))
                    ok, fr = cap.read()
                    if ok:
                        names.append(f"solidWhiteRight_video_{k:04d}")
                        cv2.imwrite(str(src / f"{len(names) - 1:04d}_{names[-1]}.png"), fr)
            sh(blendgen_cmd("import", "images", src, dst, "--hfov", spec["hfov"], "--force", "--no-progress"))
            atomic.write_json(TMP / f"rec_{rec}.names.json", names)
            (TMP / f"rec_{rec}.key").write_text(key)
        out[rec] = {"dir": dst, "names": json.loads((TMP / f"rec_{rec}.names.json").read_text())}
    if not args.no_zoo:
        out.update(make_zoo_recordings(1 if args.quick else None, args.zoo_every))
    return out


def _zoo_calib(calib_txt: Path) -> dict:
    vals = {}
    for line in calib_txt.read_text().splitlines():
        k, _, v = line.partition(":")
        if k.strip() in ("width", "height", "fx", "fy", "cx", "cy", "dist_k1_k2_p1_p2_k3"):
            vals[k.strip()] = [float(x) for x in v.replace("~", " ").split()[:5]] if k.startswith("dist") else \
                float(v.replace("~", " ").split()[0])
    return vals


def make_zoo_recordings(per_rig: int | None = None, every: int = 1) -> dict[str, dict]:
    """One recording per camera_zoo rig: its frames scaled to ZOO_WIDTH px wide, its calib.txt's
    intrinsics (and distortion) as the recording's camera (blendgen import images --calib)."""
    import yaml

    out = {}
    for rec, (folder, _, _) in ZOO_RIGS.items():
        rig = ZOO / folder
        stills = sorted(p for p in rig.glob("*.jpg"))[::every if len(list(rig.glob("*.jpg"))) > 20 else 1][:per_rig]
        if not stills or not (rig / "calib.txt").is_file():
            raise SystemExit(f"needs {rig}/ (*.jpg and calib.txt); or run with --no-zoo")
        src, dst = TMP / f"src_{rec}", TMP / f"rec_{rec}"
        key = json.dumps([ZOO_WIDTH, [p.name for p in stills]])
        if not (dst / "frames.csv").is_file() or (TMP / f"rec_{rec}.key").read_text() != key:
            shutil.rmtree(src, ignore_errors=True)
            src.mkdir(parents=True)
            c = _zoo_calib(rig / "calib.txt")
            for i, p in enumerate(stills):
                img = cv2.imread(str(p))
                h = int(round(img.shape[0] * ZOO_WIDTH / img.shape[1]))
                cv2.imwrite(str(src / f"{i:04d}_{p.stem}.png"), cv2.resize(img, (ZOO_WIDTH, h), interpolation=cv2.INTER_AREA))
            cam = {"intrinsics": [c["fx"], c["fy"], c["cx"], c["cy"]], "resolution": [int(c["width"]), int(c["height"])]}
            if "dist_k1_k2_p1_p2_k3" in c:
                cam.update(distortion_model="radtan", distortion_coeffs=c["dist_k1_k2_p1_p2_k3"])
            (TMP / f"{rec}_calib.yaml").write_text(yaml.safe_dump({"camera": cam}))
            sh(blendgen_cmd("import", "images", src, dst, "--calib", TMP / f"{rec}_calib.yaml", "--force",
                            "--no-progress"))
            atomic.write_json(TMP / f"rec_{rec}.names.json", [f"{rec}_{p.stem}" for p in stills])
            (TMP / f"rec_{rec}.key").write_text(key)
        out[rec] = {"dir": dst, "names": json.loads((TMP / f"rec_{rec}.names.json").read_text())}
    return out


def ground_plane(rec: str) -> dict:
    if rec in RECORDINGS:
        return RECORDINGS[rec]["ground_plane"]
    _, height, pitch = ZOO_RIGS[rec]
    return {"camera_height_m": height, "pitch_deg": pitch, "roll_deg": 0.0 if pitch != "auto" else "auto",
            "lane_width_m": 3.5}


def job_yaml(name: str, rec: str, rec_dir: Path, out_dir: Path, *, illumination: str, assets: list | None,
             per_frame: tuple[int, int], classes=CLASSES) -> dict:
    inject = {"objects_per_frame": list(per_frame),
              "classes": {c: 1.0 for c in classes}, "distance_m": [9, 35], "sequences": False}
    if assets is not None:
        inject["assets"] = assets
    return {"name": f"realism_{name}_{rec}", "seed": 13, "recording": str(rec_dir),
            "ground_plane": ground_plane(rec), "inject": inject,
            "render": {"samples": 16, "denoise": True, "region": True},
            "post": {"illumination": illumination, "color_transfer": Post().color_transfer, "shadows": True},
            "export": {"formats": ["coco"], "min_visible_px": 64, "save_exr": True},
            "output": str(out_dir)}


def render_set(name: str, recs: dict, args) -> dict[str, Path]:
    import yaml

    env = dict(os.environ, PYTHONPATH=str(ROOT))
    if args.objects_rev:
        old = TMP / f"objects_{args.objects_rev.replace('/', '_')}"
        if not old.is_dir():
            old.mkdir(parents=True)
            arch = subprocess.run(["git", "archive", args.objects_rev, "assets_procedural"], cwd=ROOT,
                                  capture_output=True, check=True).stdout
            subprocess.run(["tar", "-x", "-C", str(old)], input=arch, check=True)
        env["PYTHONPATH"] = f"{old}{os.pathsep}{ROOT}"
        # An editable install resolves assets_procedural to this checkout before PYTHONPATH
        # is searched: the "before" set would silently render today's objects.
        found = subprocess.run([sys.executable, "-c", "import assets_procedural; print(assets_procedural.__file__)"],
                               env=env, capture_output=True, text=True).stdout.strip()
        if not found.startswith(str(old)):
            sys.exit(f"--objects-rev {args.objects_rev}: assets_procedural still resolves to {found} "
                     "(editable install); render the before set from a checkout of that revision instead")
    assets = None
    if args.set == "assets":
        assets = [str(make_assets(TMP / "assets"))]
    elif args.set == "thirdparty":
        missing = [p for p, _ in THIRDPARTY if not (THIRDPARTY_DIR / p).exists()]
        if missing:
            raise SystemExit(f"needs {THIRDPARTY_DIR}/ ({', '.join(missing)})")
        assets = [{"path": str(THIRDPARTY_DIR / p), **f} for p, f in THIRDPARTY]
    outs = {}
    for rec, r in recs.items():
        out_dir = TMP / name / rec
        job = job_yaml(name, rec, r["dir"], out_dir, illumination="off" if args.set == "procedural_illum_off" else "auto",
                       assets=assets, per_frame=tuple(args.per_frame), classes=args.classes)
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        jp = TMP / name / f"{rec}.yaml"
        jp.write_text(yaml.safe_dump(job, sort_keys=False))
        if args.set == "thirdparty":
            same_plans(TMP / "procedural" / rec, out_dir, library_catalog(assets, env), wait_s=args.wait_plans)
        print(f"[{name}] rendering {rec} ({len(r['names'])} frames) ...", flush=True)
        sh(blendgen_cmd("run", jp), env=env)
        outs[rec] = out_dir
    return outs


def library_catalog(assets: list[dict], env) -> list[dict]:
    """The library's catalog entries (what the pipeline's assets step writes to OUT/assets.json),
    measured in a Blender process of its own."""
    cache = TMP / "thirdparty_catalog.json"
    if cache.is_file() and json.loads(cache.read_text())["sources"] == assets:
        return json.loads(cache.read_text())["assets"]
    code = ("import json, sys; from pathlib import Path; from blendgen.job.assets import discover; "
            "from blendgen.render.assets import inspect; import bpy\n"
            "out = []\n"
            "for r in discover([(Path(a.pop('path')), a) for a in json.loads(sys.argv[1])]):\n"
            "    bpy.ops.wm.read_factory_settings(use_empty=True); out.append(inspect(r))\n"
            "print('CATALOG' + json.dumps(out))")
    r = subprocess.run([sys.executable, "-c", code, json.dumps(assets)], cwd=ROOT, env=env, capture_output=True, text=True)
    line = next((ln for ln in r.stdout.splitlines() if ln.startswith("CATALOG")), None)
    if r.returncode != 0 or line is None:
        raise RuntimeError(f"measuring the library failed:\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}")
    catalog = json.loads(line[len("CATALOG"):])
    atomic.write_json(cache, {"sources": assets, "assets": catalog}, indent=1)
    return catalog


def same_plans(proc_dir: Path, out_dir: Path, catalog: list[dict], wait_s: float = 0.0) -> None:
    """The library set on the procedural set's plans: its output folder starts with the
    procedural run's sync, analysis and plan, where every object of a class the library has
    (pedestrians, not riders) becomes a library asset (drawn uniformly per object, seeded by
    frame and id) at the same place, heading and time; `blendgen run` then renders it."""
    from blendgen.job.assets import asset_variant

    if (out_dir / ".blendgen" / "plan.done").is_file():
        return
    for _ in range(int(wait_s // 30)):  # a procedural run of the same cache may be planning it now
        if (proc_dir / ".blendgen" / "plan.done").is_file():
            break
        time.sleep(30)
    if not (proc_dir / ".blendgen" / "plan.done").is_file():
        raise SystemExit(f"the thirdparty set renders on the procedural set's plans: run --set procedural first "
                         f"(no {proc_dir}/plan.jsonl)")
    by_cls: dict[str, list] = {}
    for e in catalog:
        by_cls.setdefault(e["cls"], []).append(e)
    (out_dir / ".blendgen").mkdir(parents=True, exist_ok=True)
    shutil.copytree(proc_dir / "analysis", out_dir / "analysis", dirs_exist_ok=True)
    for f in ("poses.csv", "poses.tum"):
        shutil.copy2(proc_dir / f, out_dir / f)
    for stage in ("sync", "analysis"):
        shutil.copy2(proc_dir / ".blendgen" / f"{stage}.done", out_dir / ".blendgen" / f"{stage}.done")
    lines, swapped = [], 0
    for line in (proc_dir / "plan.jsonl").read_text().splitlines():
        p = json.loads(line)
        for o in p["objects"]:
            entries = by_cls.get(o["cls"])
            if not entries or o.get("scenario") or o["variant"].get("kind") == "riding" or "rider" in o["variant"]:
                continue
            e = entries[int(np.random.default_rng([13, int(p["frame_id"].lstrip("f")), o["id"]]).integers(len(entries)))]
            o["variant"], o["dims"] = asset_variant(e), list(e["dims"])
            swapped += 1
        lines.append(json.dumps(p) + "\n")
    atomic.write_text(out_dir / "plan.jsonl", "".join(lines))
    info = json.loads((proc_dir / ".blendgen" / "plan.done").read_text())
    atomic.write_json(out_dir / ".blendgen" / "plan.done", {**info, "library_swapped": swapped})


def make_assets(folder: Path) -> Path:
    """Library assets: GLB exports of every class's procedural objects with sidecars, written
    by Blender's glTF exporter (benchmarks/realism/make_test_assets.py, its own bpy process)."""
    if not (folder / ".done").is_file():
        sh([sys.executable, Path(__file__).with_name("make_test_assets.py"), folder, "--procedural", "4"],
           env=dict(os.environ, PYTHONPATH=str(ROOT)))
        (folder / ".done").write_text("ok")
    return folder


def score_set(name: str, recs: dict, outs: dict[str, Path], args) -> dict:
    """Detector results per object, for every post variant of the set's renders."""
    from blendgen.detection.detector import YoloxDetector
    from blendgen.farm.seeds import frame_seed
    from blendgen.frame_labels import find_frame_labels, read_frame_labels
    from blendgen.post.composite import composite_frame
    from blendgen.post.illumination import estimate_illumination
    from blendgen.recording.folder import read_frame, read_recording
    from blendgen.render.exr import read_passes

    cache, key_file = TMP / name / "scores.json", TMP / name / "scores.key"
    key = json.dumps({rec: recs[rec]["names"] for rec in sorted(recs)})  # the scores hold these backgrounds
    if cache.is_file() and key_file.is_file() and key_file.read_text() == key:
        return json.loads(cache.read_text())
    det = YoloxDetector(MODEL, category_ids=set(CLASSES.values()))
    illum_on = args.set != "procedural_illum_off"
    variants = {f"ct={m}": Post(color_transfer=m, illumination="auto" if illum_on else "off") for m in TRANSFERS}
    if illum_on:  # light matching in post off (no relight; colour transfer at its no-match strength)
        variants[f"{DEFAULT_VARIANT}, post light match off"] = Post(illumination="off")
    objects = []  # one row per injected object: class, height, frame, source, {variant: score}
    bg_cache: dict[str, list] = {}
    for rec, out_dir in outs.items():
        recording = read_recording(recs[rec]["dir"])
        assets_of = {}  # (frame id, object id) -> the plan's variant (library asset or procedural kind)
        for line in (out_dir / "plan.jsonl").read_text().splitlines():
            p = json.loads(line)
            for o in p["objects"]:
                assets_of[p["frame_id"], o["id"]] = o
        look = TMP / name / "look"
        look.mkdir(parents=True, exist_ok=True)
        for lp in find_frame_labels(out_dir):
            fr = read_frame_labels(lp)
            fid = fr["frame_id"]
            i = int(fid.lstrip("f"))
            src = recs[rec]["names"][i]
            real = read_frame(recording, i)
            gts = [{"image_id": fid, "category_id": g["category_id"], "bbox": g["bbox"], "area": g["area"],
                    "ignore": bool(g["ignore"]), "h": g["bbox"][3], "cls": NAMES[g["category_id"]]}
                   for g in fr["instances"]]
            if src not in bg_cache:  # real objects of the background: ignore regions
                bg_cache[src] = [d for d in det(real) if d["score"] >= BG_SCORE]
            bg = [{"image_id": fid, "category_id": d["category_id"], "bbox": d["bbox"], "ignore": True,
                   "background": True} for d in bg_cache[src]]
            passes = read_passes(lp.parent / "render.exr")
            illum = estimate_illumination(real) if illum_on else None
            inst = {g["id"]: g for g in fr["instances"]}
            rows = [{"frame": f"{rec}/{fid}", "source": src, "cls": g["cls"], "h": g["h"], "scores": {},
                     "id": i_["id"], "bbox": [round(float(v), 1) for v in g["bbox"]],
                     "distance_m": round(float(i_.get("distance_m") or 0), 2), "occlusion": i_.get("occlusion"),
                     "truncation": i_.get("truncation"), "rides": i_.get("rides"),
                     "asset": _plan(assets_of, fid, i_["id"])["variant"].get("asset"),
                     "variant_kind": _plan(assets_of, fid, i_["id"])["variant"].get("kind"),
                     "position": [round(float(v), 2) for v in _plan(assets_of, fid, i_["id"]).get("position", [])],
                     "yaw": round(float(_plan(assets_of, fid, i_["id"]).get("yaw", 0.0)), 3)}
                    for g, i_ in zip(gts, fr["instances"]) if not g["ignore"]]
            for vname, post in variants.items():
                comp, _ = composite_frame(real, passes, settings=post,
                                          illumination=illum if post.illumination == "auto" else None,
                                          seed=frame_seed(13, fid))
                if vname == DEFAULT_VARIANT and (i < 2 * len(set(recs[rec]["names"])) or BDD_NIGHT in src):
                    cv2.imwrite(str(look / f"{rec}_{fid}_{src}.png"), _draw(comp, gts))
                dts = [{**d, "image_id": fid} for d in det(comp)]
                res = evaluate(gts + bg, dts, list(CLASSES.values()), iou_thr=IOU_THR, score_thr=SCORE_THR,
                               return_hits=True)
                hit = {id(g): s for g, s in res["hits"]}
                k = 0
                for g in gts:
                    if g["ignore"]:
                        continue
                    s = hit.get(id(g), float("nan"))
                    rows[k]["scores"][vname] = 0.0 if not np.isfinite(s) else float(s)
                    k += 1
            objects += rows
        print(f"[{name}] scored {rec}: {len(objects)} objects so far", flush=True)
    atomic.write_json(cache, objects, indent=0)
    atomic.write_text(key_file, key)
    return objects


def _plan(objects: dict, fid: str, oid: int) -> dict:
    o = objects.get((fid, oid)) or {}
    return {**o, "variant": o.get("variant") or {}}


def _draw(img, gts):
    out = img.copy()
    for g in gts:
        x, y, w, h = (int(round(v)) for v in g["bbox"])
        cv2.rectangle(out, (x, y), (x + w, y + h), (0, 255, 255) if not g["ignore"] else (128, 128, 128), 1)
        cv2.putText(out, g["cls"], (x, max(10, y - 3)), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 255, 255), 1)
    return out


# ---------------------------------------------------------------- statistics

def found(rows, variant) -> np.ndarray:
    return np.array([r["scores"][variant] >= SCORE_THR for r in rows], float)


def boot_ci(rows, stat, n=2000, seed=0) -> tuple[float, float, float]:
    """stat(rows) and its 95 % bootstrap interval, resampling frames (clusters of objects)."""
    if not rows:
        return float("nan"), float("nan"), float("nan")
    frames = sorted({r["frame"] for r in rows})
    by = {f: [r for r in rows if r["frame"] == f] for f in frames}
    rng = np.random.default_rng(seed)
    vals = []
    for _ in range(n):
        pick = rng.integers(0, len(frames), len(frames))
        sample = [r for k in pick for r in by[frames[k]]]
        vals.append(stat(sample))
    lo, hi = ci95(vals)
    return float(stat(rows)), lo, hi


def recall_stat(variant):
    return lambda rows: float(found(rows, variant).mean()) if rows else float("nan")


def conf_stat(variant):
    return lambda rows: float(np.mean([r["scores"][variant] for r in rows])) if rows else float("nan")


def diff_stat(a, b):
    return lambda rows: float((found(rows, a) - found(rows, b)).mean()) if rows else float("nan")


def fmt(v) -> str:
    m, lo, hi = v
    return "–" if not np.isfinite(m) else f"{m:.2f} [{lo:.2f}, {hi:.2f}]"


MIN_PAIRS = 20  # fewer paired objects of a class decide nothing
LIBRARY_SETS = ("thirdparty", "assets")  # sets whose library objects pair with the procedural set's
TWO_WHEELERS = ("motorcycle", "bicycle")


def is_night(r) -> bool:
    return any(n in r["source"] for n in NIGHT_SOURCES)


def pairs(a_rows, b_rows) -> list[tuple[dict, dict]]:
    """Objects of two sets planned alike: same frame, id and class, within 5 cm and 0.01 rad."""
    idx = {(r["frame"], r.get("id"), r["cls"]): r for r in a_rows}
    out = []
    for r in b_rows:
        q = idx.get((r["frame"], r.get("id"), r["cls"]))
        if q is not None and q.get("position") and r.get("position") and \
                np.allclose(q["position"], r["position"], atol=0.05) and abs(q.get("yaw", 0) - r.get("yaw", 0)) < 0.01:
            out.append((q, r))
    return out


def paired_diff(pr, variant) -> tuple[float, float, float]:
    """found(b) - found(a) over paired objects, bootstrap over frames."""
    rows = [{"frame": a["frame"], "d": float(b["scores"][variant] >= SCORE_THR) - float(a["scores"][variant] >= SCORE_THR)}
            for a, b in pr]
    return boot_ci(rows, lambda rs: float(np.mean([r["d"] for r in rs])) if rs else float("nan"))


def choose_defaults(proc: list, lib: list, variant: str) -> dict[str, str]:
    """Per class, the library where the detector finds its objects measurably more often than the
    procedural ones on >= MIN_PAIRS paired objects (the paired difference's 95 % interval above zero);
    else procedural, which needs no library."""
    out = {}
    for c in CLASSES:
        pr = [(a, b) for a, b in pairs(proc, lib) if a["cls"] == c and a["h"] >= 40 and b.get("asset")]
        out[c] = "library" if len(pr) >= MIN_PAIRS and paired_diff(pr, variant)[1] > 0 else "procedural"
    return out


def target_cells(rows, v) -> dict[str, tuple]:
    big = [r for r in rows if r["h"] >= 40]
    no_tl = [r for r in big if r["cls"] != "traffic light"]
    cells = {"no_tl": (boot_ci(no_tl, recall_stat(v)), len(no_tl)),
             "tl": (boot_ci([r for r in big if r["cls"] == "traffic light"], recall_stat(v)),
                    sum(r["cls"] == "traffic light" for r in big)),
             "night": (boot_ci([r for r in no_tl if is_night(r)], recall_stat(v)), sum(map(is_night, no_tl)))}
    for c in ("car", "truck", "bus"):
        rc = [r for r in rows if r["cls"] == c and r["h"] >= VEHICLE_PX]
        cells[c] = (boot_ci(rc, recall_stat(v)), len(rc))
    for c in TWO_WHEELERS:
        rc = [r for r in big if r["cls"] == c]
        cells[c] = (boot_ci(rc, recall_stat(v)), len(rc))
    return cells


def _cell(cell, target=None) -> str:
    (m, lo, hi), n = cell
    if not np.isfinite(m):
        return "– (n=0)"
    ok = "" if target is None else (" ✓" if (m >= target[0] and (len(target) < 2 or lo >= target[1])) else " ✗")
    return f"{m:.2f} [{lo:.2f}, {hi:.2f}] (n={n}){ok}"


def build_table(sets: dict[str, list], cmdline: str) -> tuple[str, dict]:
    v = DEFAULT_VARIANT
    lines = ["# Realism on real backgrounds (YOLOX-Nano, COCO-pretrained)", "",
             f"Made by `{cmdline}` (benchmarks/realism/bench_realism.py; its docstring says what is measured: "
             "backgrounds, renders, matching). Recall@0.5 = share of injected objects matched (IoU >= "
             f"{IOU_THR}, same class, score >= {SCORE_THR}); [95 % bootstrap interval over frames]. Renders: "
             "Cycles 16 samples + OIDN, render region on, 2 shared CPU cores; default post (light matching, "
             f"{v}). Night = the BDD night photo (camera_zoo holds no night frame).", "",
             "Sets: " + ", ".join(f"`{k}` {len(rs)} objects on {len({r['frame'] for r in rs})} frames "
                                  f"({len({r['source'] for r in rs})} backgrounds)" for k, rs in sets.items())
             + ". Sets rendered by other checkouts carry their own lighting and post (meta.json names the revision).",
             ""]
    summary = {}
    # ---- targets
    lines += ["## Targets (objects >= 40 px tall unless stated)", "",
              "| set | without traffic lights (>= 0.65, lower bound >= 0.58) | car >= 80 px (>= 0.6) | "
              "truck >= 80 px (>= 0.6) | bus >= 80 px (>= 0.6) | motorcycle (>= 0.4) | bicycle (>= 0.4) | "
              "night, without traffic lights (>= 0.5) | traffic lights (apart) |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    rowsets = dict(sets)
    proc = sets.get("procedural")
    lib_name = next((k for k in LIBRARY_SETS if k in sets), None)
    defaults = choose_defaults(proc, sets[lib_name], v) if proc and lib_name else None
    if defaults:  # per class, the chosen set's objects: what the default per class gives
        rowsets[f"default per class ({lib_name} where chosen)"] = \
            [r for r in proc if defaults[r["cls"]] == "procedural"] + \
            [r for r in sets[lib_name] if defaults[r["cls"]] == "library"]
    for name, rows in rowsets.items():
        c = target_cells(rows, v)
        summary[name] = {k: {"recall": list(val[0]), "n": val[1]} for k, val in c.items()}
        lines.append(f"| {name} | {_cell(c['no_tl'], (0.65, 0.58))} | {_cell(c['car'], (0.6,))} | "
                     f"{_cell(c['truck'], (0.6,))} | {_cell(c['bus'], (0.6,))} | {_cell(c['motorcycle'], (0.4,))} | "
                     f"{_cell(c['bicycle'], (0.4,))} | {_cell(c['night'], (0.5,))} | {_cell(c['tl'])} |")
    # ---- library vs procedural, per class, day and night
    if proc and lib_name:
        lib = sets[lib_name]
        pr_all = pairs(proc, lib)
        lines += ["", f"## Library (`{lib_name}`) beside procedural, per class (objects >= 40 px)", "",
                  f"Same plans: {len(pr_all)} of {len(lib)} library-set objects pair with a procedural one (same "
                  "frame, slot, class and place; the rest moved where the library object's size changed the "
                  "planner's choice). `library` counts the library set's objects of a class the library has; the "
                  "paired difference is library minus procedural on the paired objects.", "",
                  "| class | procedural day | library day | procedural night | library night | "
                  "paired difference (all) | default |", "|---|---:|---:|---:|---:|---:|---|"]
        for c in CLASSES:
            pc = [r for r in proc if r["cls"] == c and r["h"] >= 40]
            lc = [r for r in lib if r["cls"] == c and r["h"] >= 40 and r.get("asset")]
            cells = []
            for rs in (pc, lc):
                for night in (False, True):
                    sub = [r for r in rs if is_night(r) == night]
                    cells.append(_cell((boot_ci(sub, recall_stat(v)), len(sub))))
            pr = [(a, b) for a, b in pr_all if a["cls"] == c and a["h"] >= 40 and b.get("asset")]
            d = paired_diff(pr, v) if pr else (float("nan"),) * 3
            dtxt = f"{100 * d[0]:+.1f} points [{100 * d[1]:+.1f}, {100 * d[2]:+.1f}] (n={len(pr)})" if pr else "–"
            lines.append(f"| {c} | {cells[0]} | {cells[2]} | {cells[1]} | {cells[3]} | {dtxt} | {defaults[c]} |")
        assets_used = sorted({r["asset"].rsplit("/", 1)[-1] for r in lib if r.get("asset")})
        lines += ["", "Library objects in the set: " + ", ".join(
            f"{a} {sum(1 for r in lib if r.get('asset', '') and r['asset'].endswith(a) and r['h'] >= 40)}"
            for a in assets_used) + " (objects >= 40 px)."]
    # ---- post variants
    lines += ["", "## Post-processing variants (paired: same renders, same objects, >= 40 px)", "",
              "| set | variant | recall@0.5 | mean conf | minus ct=none (paired) |", "|---|---|---:|---:|---:|"]
    for name, rows in sets.items():
        big = [r for r in rows if r["h"] >= 40]
        for var in (big[0]["scores"] if big else []):
            d = boot_ci(big, diff_stat(var, "ct=none"))
            lines.append(f"| {name} | {var} | {fmt(boot_ci(big, recall_stat(var)))} | {fmt(boot_ci(big, conf_stat(var)))} | "
                         f"{'–' if var == 'ct=none' else f'{100 * d[0]:+.1f} points [{100 * d[1]:+.1f}, {100 * d[2]:+.1f}]'} |")
    # ---- per set: class x height, backgrounds
    for name, rows in sets.items():
        lines += ["", f"## {name}: per class and pixel height", "",
                  "| class | " + " | ".join(b[2] for b in HEIGHT_BINS) + " | >= 40 px | mean conf |",
                  "|---|" + "---:|" * (len(HEIGHT_BINS) + 2)]
        for c in CLASSES:
            rc = [r for r in rows if r["cls"] == c]
            cells = []
            for lo, hi, _ in HEIGHT_BINS:
                rb = [r for r in rc if lo <= r["h"] < hi]
                cells.append(f"{found(rb, v).mean():.2f} (n={len(rb)})" if rb else "–")
            big = [r for r in rc if r["h"] >= 40]
            lines.append(f"| {c} | " + " | ".join(cells) + f" | {fmt(boot_ci(big, recall_stat(v)))} (n={len(big)}) | "
                         f"{fmt(boot_ci(big, conf_stat(v)))} |")
        lines += ["", "| backgrounds | objects >= 40 px | recall@0.5 | without traffic lights |", "|---|---:|---:|---:|"]
        for g in sorted({_bg_group(r) for r in rows}):
            rb = [r for r in rows if _bg_group(r) == g and r["h"] >= 40]
            nt = [r for r in rb if r["cls"] != "traffic light"]
            lines.append(f"| {g} | {len(rb)} | {fmt(boot_ci(rb, recall_stat(v)))} | {fmt(boot_ci(nt, recall_stat(v)))} |")
    return "\n".join(lines) + "\n", summary


def _bg_group(r) -> str:
    f = r["frame"].split("/")[0]
    if f.startswith("zoo_"):
        return f"camera_zoo {f[4:]}"
    f = f.split("-")[0]  # bdd-<photo>: one recording per BDD photo
    src = r["source"].split("_video_")[0]
    return f"{f} {src}" + (" (night)" if is_night(r) else "")


def plot(sets: dict[str, list], path: Path = PLOT) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(13, 4.5))
    labels = [b[2] for b in HEIGHT_BINS]
    for s, rows in sets.items():
        ys = [found([r for r in rows if lo <= r["h"] < hi], DEFAULT_VARIANT).mean()
              if any(lo <= r["h"] < hi for r in rows) else np.nan for lo, hi, _ in HEIGHT_BINS]
        axes[0].plot(labels, ys, marker="o", label=s)
    axes[0].set_ylabel("recall@0.5 (default post)")
    axes[0].set_title("by object height")
    axes[0].axhline(0.6, ls=":", c="grey")
    axes[0].legend()
    x = np.arange(len(CLASSES))
    w = 0.8 / max(1, len(sets))
    for k, (s, rows) in enumerate(sets.items()):
        ys = [found([r for r in rows if r["cls"] == c], DEFAULT_VARIANT).mean() if any(r["cls"] == c for r in rows)
              else 0 for c in CLASSES]
        axes[1].bar(x + k * w, ys, w, label=s)
    axes[1].set_xticks(x + 0.4 - w / 2, list(CLASSES), rotation=20)
    axes[1].set_title("by class")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", choices=("procedural", "procedural_illum_off", "assets", "thirdparty"),
                    default="procedural")
    ap.add_argument("--name", help="name of the object set in the table (default: --set)")
    ap.add_argument("--objects-rev", help="render the procedural objects of this git revision")
    ap.add_argument("--copies-udacity", type=int, default=5)
    ap.add_argument("--copies-bdd", type=int, default=14)
    ap.add_argument("--video-frames", type=int, default=15)
    ap.add_argument("--per-frame", type=int, nargs=2, default=(4, 6), metavar=("MIN", "MAX"),
                    help="objects per frame")
    ap.add_argument("--cache", type=Path,
                    help="folder of the cached recordings, renders and scores (default "
                         "benchmarks/results/tmp/realism or env BLENDGEN_REALISM_CACHE)")
    ap.add_argument("--classes", nargs="+", choices=list(CLASSES), default=list(CLASSES), metavar="CLASS",
                    help="inject only these classes (a probe of a few classes; default all seven)")
    ap.add_argument("--doc", type=Path, default=DOC, help=f"markdown table to write (default {DOC.relative_to(ROOT)}, plot "
                    f"{PLOT.relative_to(ROOT)}; another doc gets its plot beside it)")
    ap.add_argument("--quick", action="store_true", help="1 copy of each still, 2 video frames (smoke run)")
    ap.add_argument("--no-zoo", action="store_true", help="without the camera_zoo backgrounds")
    ap.add_argument("--wait-plans", type=float, default=0.0, metavar="S",
                    help="thirdparty: wait up to S seconds for each procedural plan (a procedural run of the "
                         "same cache running beside it)")
    ap.add_argument("--zoo-every", type=int, default=1, metavar="N",
                    help="every N-th frame of a camera_zoo rig with more than 20 (nuScenes' 100)")
    ap.add_argument("--table-only", action="store_true", help="rebuild the table from cached sets")
    ap.add_argument("--rescore", action="store_true", help="score the set's existing renders again (no rendering)")
    args = ap.parse_args()
    global TMP
    TMP = (args.cache or TMP).resolve()
    if args.quick:
        args.copies_udacity, args.copies_bdd, args.video_frames = 1, 1, 2
        TMP = TMP.parent / "realism_quick"
    name = args.name or args.set
    if not MODEL.is_file():
        raise SystemExit(f"needs {MODEL}")
    if not args.table_only:
        recs = make_recordings(args)
        if args.rescore:
            outs = {rec: TMP / name / rec for rec in recs}
            (TMP / name / "scores.json").unlink(missing_ok=True)
        else:
            outs = render_set(name, recs, args)
            top = subprocess.run(["git", "rev-parse", "--show-toplevel"], cwd=ROOT, capture_output=True,
                                 text=True).stdout.strip()
            meta = {"set": args.set, "objects_rev": args.objects_rev,  # a snapshot inside a checkout is not its HEAD
                    "rev": subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                          text=True).stdout.strip() if top and Path(top) == ROOT else "unknown"}
            atomic.write_json(TMP / name / "meta.json", meta)
        score_set(name, recs, outs, args)
    sets = {p.parent.name: json.loads(p.read_text()) for p in sorted(TMP.glob("*/scores.json"))}
    cmd = "PYTHONPATH=$PWD .venv/bin/python benchmarks/realism/bench_realism.py " + " ".join(sys.argv[1:])
    table, summary = build_table(sets, cmd)
    print(table)
    if not args.quick:
        atomic.write_text(args.doc, table)
        plot(sets, PLOT if args.doc == DOC else args.doc.with_suffix(".png"))
    atomic.write_json(TMP / "summary.json", summary)


if __name__ == "__main__":
    main()
