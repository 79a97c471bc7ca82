"""Realism score: metrics agree with pycocotools' COCOeval; the YOLOX detector runs on real photos."""

import contextlib
import io
from pathlib import Path

import cv2
import numpy as np
import pytest
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval

from blendgen import CLASSES
from blendgen.detection.metrics import evaluate

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
MODEL = DATA / "models" / "yolox_nano.onnx"
PHOTOS = DATA / "real" / "udacity_highway_images"
CATS = list(CLASSES.values())


def _fixture(seed: int, n_images: int = 12):
    """Random gts (some ignored/crowd) and detections: jittered copies, duplicates, wrong
    classes, pure false positives, tied scores."""
    rng = np.random.default_rng(seed)
    gts, dts = [], []
    for img in range(1, n_images + 1):
        for _ in range(rng.integers(0, 7)):
            x, y = rng.uniform(0, 500, 2)
            w, h = rng.uniform(2, 120, 2)
            cat = int(rng.choice(CATS[:5]))
            gts.append({"image_id": img, "category_id": cat, "bbox": [x, y, w, h],
                        "ignore": bool(rng.random() < 0.15)})
            for _ in range(rng.integers(0, 3)):
                j = rng.normal(0, 0.15, 4) * [w, h, w, h]
                c = cat if rng.random() < 0.85 else int(rng.choice(CATS))
                dts.append({"image_id": img, "category_id": c, "bbox": [x + j[0], y + j[1], abs(w + j[2]) + 1,
                                                                        abs(h + j[3]) + 1],
                            "score": float(np.round(rng.random(), 1 if rng.random() < 0.3 else 6))})
        for _ in range(rng.integers(0, 4)):
            dts.append({"image_id": img, "category_id": int(rng.choice(CATS)),
                        "bbox": list(rng.uniform(0, 400, 2)) + list(rng.uniform(5, 80, 2)),
                        "score": float(rng.random())})
    return gts, dts


def _cocoeval(gts, dts, score_thr=None):
    images = sorted({g["image_id"] for g in gts} | {d["image_id"] for d in dts})
    gt_doc = {"images": [{"id": i, "width": 1000, "height": 1000} for i in images],
              "categories": [{"id": c, "name": n} for n, c in CLASSES.items()],
              "annotations": [{"id": k + 1, "image_id": g["image_id"], "category_id": g["category_id"],
                               "bbox": g["bbox"], "area": g.get("area", g["bbox"][2] * g["bbox"][3]),
                               "iscrowd": int(g["ignore"])} for k, g in enumerate(gts)]}
    if score_thr is not None:
        dts = [d for d in dts if d["score"] >= score_thr]
    with contextlib.redirect_stdout(io.StringIO()):
        coco = COCO()
        coco.dataset = gt_doc
        coco.createIndex()
        res = coco.loadRes([dict(d) for d in dts]) if dts else COCO()
        ev = COCOeval(coco, res, "bbox")
        ev.params.iouThrs = np.array([0.5])
        ev.evaluate()
        ev.accumulate()
    return ev


@pytest.mark.parametrize("area", ["small", "medium", "large"])
def test_metrics_match_cocoeval_by_size(area):
    from blendgen.detection.metrics import AREA_RANGES

    gts, dts = _fixture(5, n_images=20)
    for g in gts:  # COCO sizes gts by their (mask) area, not the box
        g["area"] = g["bbox"][2] * g["bbox"][3] * 0.8
    ours = evaluate(gts, dts, CATS, area_rng=AREA_RANGES[area])
    ev = _cocoeval(gts, dts)
    a = ["all", "small", "medium", "large"].index(area)
    for k, c in enumerate(ev.params.catIds):
        prec = ev.eval["precision"][0, :, k, a, -1]
        if (prec > -1).any():
            assert ours[c]["ap"] == pytest.approx(float(prec.mean()), abs=1e-6)
            assert ours[c]["n_gt"] > 0
        else:
            assert ours[c]["ap"] is None


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_metrics_match_cocoeval(seed):
    gts, dts = _fixture(seed)
    ours = evaluate(gts, dts, CATS, iou_thr=0.5, score_thr=0.4)
    ev = _cocoeval(gts, dts)
    cats = ev.params.catIds
    n_checked = 0
    for k, c in enumerate(cats):
        prec = ev.eval["precision"][0, :, k, 0, -1]  # T, R, K, A(all), M(100)
        if (prec > -1).any():
            assert ours[c]["ap"] == pytest.approx(float(prec.mean()), abs=1e-6)
            n_checked += 1
        else:
            assert ours[c]["ap"] is None and ours[c]["n_gt"] == 0
    assert n_checked >= 4

    # Recall, precision at the score threshold: COCOeval on the detections above it.
    ev_t = _cocoeval(gts, dts, score_thr=0.4)
    for k, c in enumerate(cats):
        rec = ev_t.eval["recall"][0, k, 0, -1]
        if rec > -1:
            assert ours[c]["recall"] == pytest.approx(float(rec), abs=1e-6)
        tp = fp = 0
        for e in ev_t.evalImgs:
            if e is None or e["category_id"] != c or e["aRng"] != [0, 1e10]:
                continue
            m, ig = np.asarray(e["dtMatches"][0]) > 0, np.asarray(e["dtIgnore"][0]).astype(bool)
            tp += int((m & ~ig).sum())
            fp += int((~m & ~ig).sum())
        assert (ours[c]["tp"], ours[c]["fp"]) == (tp, fp)
        if tp + fp:
            assert ours[c]["precision"] == pytest.approx(tp / (tp + fp), abs=1e-12)
    m = ours["mean"]
    scored = [ours[c] for c in CATS if ours[c]["n_gt"]]
    assert m["ap"] == pytest.approx(np.mean([r["ap"] for r in scored]))
    assert all(np.isfinite(v) for r in scored for v in (r["precision"], r["recall"], r["f1"], r["ap"]))


def test_metrics_edge_cases():
    # Perfect detections -> everything 1; no detections -> zeros, finite; no gt -> None.
    gts = [{"image_id": "a", "category_id": 3, "bbox": [10, 10, 20, 20], "ignore": False}]
    r = evaluate(gts, [{"image_id": "a", "category_id": 3, "bbox": [10, 10, 20, 20], "score": 0.9}], CATS)
    assert (r[3]["precision"], r[3]["recall"], r[3]["f1"]) == (1.0, 1.0, 1.0)
    assert r[3]["ap"] == pytest.approx(1.0, abs=1e-12)  # COCO adds eps to the precision's denominator
    r = evaluate(gts, [], CATS)
    assert (r[3]["precision"], r[3]["recall"], r[3]["f1"], r[3]["ap"]) == (0.0, 0.0, 0.0, 0.0)
    assert r[1]["ap"] is None and r["mean"]["ap"] == 0.0
    # A detection on an ignore region is neither TP nor FP; a zero-size box stays finite.
    ig = [{"image_id": "a", "category_id": 3, "bbox": [100, 100, 50, 50], "ignore": True}]
    d = [{"image_id": "a", "category_id": 3, "bbox": [110, 110, 20, 20], "score": 0.8},
         {"image_id": "a", "category_id": 3, "bbox": [5, 5, 0, 0], "score": 0.7}]
    r = evaluate(gts + ig, d, CATS)
    assert (r[3]["tp"], r[3]["fp"]) == (0, 1)


def test_detector_finds_cars_on_real_photos():
    if not MODEL.exists():
        pytest.skip(f"needs {MODEL}")
    photo = PHOTOS / "solidYellowCurve.jpg"
    if not photo.exists():
        pytest.skip(f"needs {photo}")
    from blendgen.detection.detector import YoloxDetector

    det = YoloxDetector(MODEL)
    img = cv2.imread(str(photo))
    found = [d for d in det(img) if d["score"] > 0.5]
    cars = [d for d in found if d["category_id"] == CLASSES["car"]]
    assert cars, "YOLOX-Nano finds the car on the right of solidYellowCurve.jpg"
    x, y, w, h = cars[0]["bbox"]
    assert x > 700 and 250 < y < 350 and 40 < w < 200  # the car in the right lane
    # Letterbox is scale-invariant: the same car at half resolution maps back to the same place.
    small = det(cv2.resize(img, (480, 270)))
    best = max((d for d in small if d["category_id"] == 3), key=lambda d: d["score"])
    assert abs(best["bbox"][0] * 2 - x) < 25


def _make_out(tmp, photos, inject_size=200):
    """An OUT over real photos: a real car photo crop pasted as the 'injected' object, and a
    recording folder so that background='auto' can find the real frames."""
    from blendgen.frame_labels import write_frame_labels
    from blendgen.geometry import Camera
    from blendgen.labels.instances import encode_mask
    from blendgen.recording.folder import write_calib, write_frames_csv

    out, rec = tmp / "out", tmp / "rec"
    donor = cv2.imread(str(PHOTOS / "solidYellowCurve.jpg"))[285:355, 825:935]  # a real car
    files = []
    for k, p in enumerate(photos):
        real = cv2.imread(str(p))
        (rec / "frames").mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(rec / "frames" / f"{k}.png"), real)
        files.append(f"frames/{k}.png")
        comp = real.copy()
        x0, y0 = 420, 330
        car = cv2.resize(donor, (inject_size, int(inject_size * 70 / 110)))
        comp[y0:y0 + car.shape[0], x0:x0 + car.shape[1]] = car
        mask = np.zeros(real.shape[:2], bool)
        mask[y0:y0 + car.shape[0], x0:x0 + car.shape[1]] = True
        inst = [{"id": 1, "track_id": 1, "cls": "car", "category_id": 3,
                 "bbox": [x0, y0, car.shape[1], car.shape[0]], "area": int(mask.sum()),
                 "segmentation": encode_mask(mask), "ignore": False}]
        d = out / "frames" / f"f{k:06d}"
        d.mkdir(parents=True)
        cv2.imwrite(str(d / "composite.png"), comp)
        write_frame_labels(d / "labels.json", f"f{k:06d}", f"frames/f{k:06d}/composite.png",
                           real.shape[1], real.shape[0], inst)
    write_calib(rec, Camera.from_hfov(960, 540, 60.0))
    write_frames_csv(rec, np.arange(len(photos)) * 0.1, files)
    (out / "job.resolved.yaml").write_text(f"name: t\nrecording: {rec}\noutput: {out}\n")
    return out


def _three_real_photos():
    """The detector and three Udacity photos, or a skip naming what is missing."""
    if not MODEL.exists():
        pytest.skip(f"needs {MODEL}")
    photos = sorted(PHOTOS.glob("*.jpg"))[:3] if PHOTOS.exists() else []
    if len(photos) < 3:
        pytest.skip(f"needs {PHOTOS}/*.jpg")
    return photos


def test_realism_end_to_end_on_real_photos(tmp_path):
    photos = _three_real_photos()
    from blendgen.cli import main
    from blendgen.eval.realism import run_realism

    out = _make_out(tmp_path, photos)
    res = run_realism(out, MODEL, background="auto")
    run = res["runs"][0]
    car = run["classes"]["car"]
    assert run["frames"] == 3 and run["frames_with_background"] == 3
    assert car["n_gt"] == 3 and car["recall"] == 1.0 and car["ap"] == pytest.approx(1.0)
    # The real cars on the photos are ignore regions, not false positives.
    assert car["fp"] == 0 and car["precision"] == 1.0
    none = run_realism(out, MODEL, background="none", write=False)["runs"][0]["classes"]["car"]
    assert none["fp"] > 0 and none["precision"] < 1.0  # without it the real cars count against us
    assert (out / "eval/realism.md").read_text().count("| car |") == 1

    # CLI with --compare: two columns per metric; bad detector path -> exit 2, message names it.
    assert main(["realism", str(out), "--detector", str(MODEL), "--compare", str(out)]) == 0
    assert "AP@0.5 B" in (out / "eval/realism_compare.md").read_text()
    assert main(["realism", str(out), "--detector", str(tmp_path / "nope.onnx")]) == 2


def test_size_probe_shrinks_found_objects(tmp_path, capsys):
    """benchmarks/realism/bench_size_probe.py: real cars pasted ~127 px tall are found, then found less
    often or not at all when the frame is shrunk until they are 20 px tall."""
    photos = _three_real_photos()
    import importlib.util

    from blendgen.eval.realism import run_realism

    out = _make_out(tmp_path, photos)
    run_realism(out, MODEL, background="auto")
    script = Path(__file__).resolve().parents[1] / "benchmarks" / "realism" / "bench_size_probe.py"
    spec = importlib.util.spec_from_file_location("probe", script)
    probe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(probe)
    probe.main(["--runs", str(out), "--class", "car", "--to", "120", "20", "--detector", str(MODEL)])
    rows = {line.split("|")[1].strip(): line.split("|")[3] for line in capsys.readouterr().out.splitlines()
            if line.startswith("| ")}
    assert rows["natively 80-160 px"].strip().startswith("3 ")
    found_120 = int(rows["found at >= 100 px, shrunk to 120 px"].split()[0])
    found_20 = int(rows["found at >= 100 px, shrunk to 20 px"].split()[0])
    assert found_120 == 3 and found_20 < 3


def test_recall_breakdown_by_attributes():
    from blendgen.eval.realism import recall_breakdown

    gts = [{"image_id": "a", "category_id": 1, "bbox": [0, 0, 10, 20], "ignore": False, "scenario": "jaywalker",
            "distance_m": 8.0, "occlusion": 0.0},
           {"image_id": "a", "category_id": 1, "bbox": [50, 0, 10, 20], "ignore": False, "scenario": "jaywalker",
            "distance_m": 25.0, "occlusion": 0.7},
           {"image_id": "a", "category_id": 3, "bbox": [100, 0, 40, 20], "ignore": False, "scenario": None,
            "distance_m": 12.0, "occlusion": None}]
    dts = [{"image_id": "a", "category_id": 1, "bbox": [0, 0, 10, 20], "score": 0.9},
           {"image_id": "a", "category_id": 1, "bbox": [50, 0, 10, 20], "score": 0.1},  # below threshold
           {"image_id": "a", "category_id": 3, "bbox": [100, 0, 40, 20], "score": 0.5}]
    res = evaluate(gts, dts, CATS, score_thr=0.3, return_hits=True)
    by = recall_breakdown(res["hits"], 0.3)
    assert by["scenario"] == {"jaywalker": {"n": 2, "recall": 0.5}, "(none)": {"n": 1, "recall": 1.0}}
    assert by["distance"]["0–10 m"] == {"n": 1, "recall": 1.0}
    assert by["distance"]["20–40 m"] == {"n": 1, "recall": 0.0}
    assert by["occlusion"] == {"0–0.1": {"n": 1, "recall": 1.0}, "0.5–1": {"n": 1, "recall": 0.0}}
