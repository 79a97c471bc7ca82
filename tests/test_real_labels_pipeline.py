"""A job over a real BDD street photo labels its real road users (the detector's, counted per
source in the run summary); with the user's own labels instead, a hand-made box wholly behind
the injected car is dropped and one half behind it shrinks to its visible part."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from real_data import BDD, cli

pytestmark = [pytest.mark.bpy, pytest.mark.data]


def test_real_road_users_labelled_by_detector_then_by_user(tmp_path):
    if not BDD.is_dir():
        pytest.skip(f"needs {BDD}")
    r = cli("import", "images", str(BDD), str(tmp_path / "rec"), "--hfov", "60", "--no-progress")
    assert r.returncode == 0, r.stderr[-2000:]
    job = tmp_path / "job.yaml"
    job.write_text(yaml.safe_dump({
        "name": "bdd_real", "seed": 3, "recording": "rec", "ground_plane": "auto", "frames": {"stop": 1},
        "inject": {"objects_per_frame": [1, 1], "classes": {"car": 1}, "distance_m": [7, 12], "sequences": False},
        "render": {"resolution": [320, 180], "samples": 2, "denoise": False},
        "export": {"formats": ["coco", "kitti", "yolo"], "min_visible_px": 4}, "output": "out"}))
    r = cli("run", str(job))
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    out = tmp_path / "out"
    summary = json.loads((out / "run_summary.json").read_text())
    src = summary["labels_per_source"]
    # the day street's parked cars and people: labels from the detector beside the injected car
    assert src["per_source"]["injected"] == 1 and src["per_source"]["detector"] >= 3, src
    assert "sources: detector" in r.stdout and "injected 1" in r.stdout
    coco = json.loads((out / "labels" / "coco.json").read_text())
    assert {a["attributes"]["source"] for a in coco["annotations"]} >= {"injected", "detector"}
    manifest = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines() if x]
    assert [m["real_labels"]["mode"] for m in manifest if m.get("stage") == "frames"] == ["detector"]

    # the user's own labels, made by hand around the injected car's mask
    index = cv2.imread(str(out / "frames" / "f000000" / "instances.png"), cv2.IMREAD_UNCHANGED)
    car = index > 0
    assert car.sum() > 400
    dist = cv2.distanceTransform(car.astype(np.uint8), cv2.DIST_L2, 3)
    cy, cx = np.unravel_index(np.argmax(dist), dist.shape)
    r_in = int(dist[cy, cx] / 1.5)  # the square [cx +- r_in] x [cy +- r_in] lies inside the car
    assert r_in >= 3
    right = int(np.flatnonzero(car.any(axis=0)).max()) + 1
    hidden = [cx - r_in, cy - r_in, 2 * r_in, 2 * r_in]
    half = [cx, cy - r_in // 2, 2 * (right - cx), max(r_in, 2)]  # left part on the car, right part beside it
    rec = read_rec_size(tmp_path / "rec")
    sx, sy = rec[0] / 320, rec[1] / 180
    frames = {"f000000": [{"cls": "car", "box": scale(hidden, sx, sy), "ignore": False, "label": "car"},
                          {"cls": "person", "box": scale(half, sx, sy), "ignore": False, "label": "person"}]}
    (tmp_path / "rec" / "labels.json").write_text(json.dumps({
        "format": "blendgen-recording-labels", "version": 1, "width": rec[0], "height": rec[1],
        "source": {"format": "hand-made"}, "frames": frames}))
    (out / "frames" / "f000000" / "labels.json").unlink()  # the frame is done again, now with user labels
    r = cli("run", str(job))  # labels.real: auto -> user (the recording has labels now); same job, same plan
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    lab = json.loads((out / "frames" / "f000000" / "labels.json").read_text())
    assert [i["source"] for i in lab["real"]] == ["user"]  # the hidden box is gone
    kept = lab["real"][0]
    assert kept["cls"] == "person"
    x0, y0, w, h = kept["bbox"]
    assert x0 >= cx + r_in - 1 and x0 + w == pytest.approx(half[0] + half[2], abs=1.0)  # shrank to the visible part
    assert 0.15 < kept["occlusion"] < 0.95
    summary = json.loads((out / "run_summary.json").read_text())
    assert summary["labels_per_source"]["per_source"] == {"injected": 1, "user": 1}
    coco = json.loads((out / "labels" / "coco.json").read_text())  # the export follows the redone frame
    assert sorted(a["attributes"]["source"] for a in coco["annotations"]) == ["injected", "user"]


def read_rec_size(rec: Path) -> tuple[int, int]:
    cam = yaml.safe_load((rec / "calib.yaml").read_text())["camera"]
    return tuple(cam["resolution"])


def scale(box, sx, sy):
    return [box[0] * sx, box[1] * sy, box[2] * sx, box[3] * sy]
