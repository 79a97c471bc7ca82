"""Labels in (COCO / YOLO / KITTI -> the recording's labels.json) and real objects out
(the real boxes updated for what injected objects cover, exported with their source)."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest
from pycocotools.coco import COCO

from blendgen.errors import UserError
from blendgen.frame_labels import find_frame_labels, read_frame_labels, write_frame_labels
from blendgen.labels.export import export_labels
from blendgen.labels.instances import extract_instances
from blendgen.labels.kitti import parse_label_line
from blendgen.labels.real_objects import detector_boxes, real_instances
from blendgen.recording.folder import read_recording
from blendgen.recording.importers import check_recording, import_recording
from blendgen.recording.labels import read_recording_labels
from labels_fixtures import CAMERA, H, W, make_frame

IW, IH = 64, 48


def _stills(folder, n=3):
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(n):
        cv2.imwrite(str(folder / f"img_{i}.png"), rng.integers(0, 255, (IH, IW, 3), dtype=np.uint8))
    return folder


def _coco(path, anns, images=("img_0.png", "img_1.png"), cats=((1, "Car"), (2, "Pedestrian"), (3, "Tram"))):
    doc = {"images": [{"id": k + 1, "file_name": f"some/dir/{n}", "width": IW, "height": IH}
                      for k, n in enumerate(images)],
           "annotations": [{"id": k + 1, "image_id": a[0], "category_id": a[1], "bbox": list(a[2]),
                            "iscrowd": a[3] if len(a) > 3 else 0} for k, a in enumerate(anns)],
           "categories": [{"id": i, "name": n} for i, n in cats]}
    path.write_text(json.dumps(doc))
    return path


def test_import_images_with_coco_labels(tmp_path):
    src = _stills(tmp_path / "src")
    coco = _coco(tmp_path / "c.json", [(1, 1, (2, 3, 20, 10)), (1, 2, (30, 5, 5, 20)), (2, 3, (0, 0, 10, 10)),
                                       (2, 1, (40, 30, 10, 10), 1)])
    rec_dir = import_recording("images", src, tmp_path / "rec", hfov_deg=60, show_progress=False,
                               labels=coco, label_format="coco", class_map=["Tram=ignore"])
    labels = read_recording_labels(read_recording(rec_dir))
    # img_2 is not in the COCO file: unlabelled (absent), not "no objects"
    assert sorted(labels) == ["f000000", "f000001"]
    assert [(b["cls"], b["box"], b["ignore"]) for b in labels["f000000"]] == [
        ("car", [2, 3, 20, 10], False), ("person", [30, 5, 5, 20], False)]
    assert [(b["cls"], b["ignore"], b["label"]) for b in labels["f000001"]] == [
        ("ignore", True, "Tram"), ("car", True, "Car")]  # class-map ignore, and COCO's iscrowd
    text = "\n".join(str(f) for f in check_recording(rec_dir))
    assert "labels for 2 of 3 frames" in text and "1 frame(s) have no labels" in text


@pytest.mark.parametrize("case, match", [
    ("unknown", r"c.json: class name\(s\) that are no blendgen class: 'Tram' \(1 box\).*--class-map Tram=drop"),
    ("outside", r"annotations\[0\]: box of 'Car' .* outside the image img_0.png \(64x48\)"),
    ("missing", r"images\[2\]: labels for image 'some/dir/img_9.png', which is not among the imported images"),
])
def test_coco_label_errors_name_what_is_wrong(tmp_path, case, match):
    src = _stills(tmp_path / "src")
    anns = {"unknown": [(2, 3, (0, 0, 10, 10))], "outside": [(1, 1, (50, 40, 20, 10))],
            "missing": [(3, 1, (0, 0, 10, 10))]}[case]
    coco = _coco(tmp_path / "c.json", anns, images=("img_0.png", "img_1.png", "img_9.png"))
    with pytest.raises(UserError, match=match):
        import_recording("images", src, tmp_path / "rec", show_progress=False, labels=coco, label_format="coco")
    assert not (tmp_path / "rec").exists()  # nothing half-written


def test_import_yolo_and_kitti_labels(tmp_path):
    src = _stills(tmp_path / "src")
    yolo = tmp_path / "ds" / "labels"
    yolo.mkdir(parents=True)
    (tmp_path / "ds" / "data.yaml").write_text("names: [bus, car, motorbike, person, truck]\n")
    (yolo / "img_0.txt").write_text("2 0.5 0.5 0.25 0.5\n1 0.25 0.25 0.125 0.125\n")
    (yolo / "img_1.txt").write_text("")
    rec = import_recording("images", src, tmp_path / "rec_y", show_progress=False, labels=yolo, label_format="yolo")
    lab = read_recording_labels(read_recording(rec))
    assert sorted(lab) == ["f000000", "f000001"] and lab["f000001"] == []
    assert [(b["cls"], b["box"]) for b in lab["f000000"]] == [("motorcycle", [24.0, 12.0, 16.0, 24.0]),
                                                              ("car", [12.0, 9.0, 8.0, 6.0])]
    (yolo / "img_1.txt").write_text("0 0.9 0.5 0.4 0.2\n")  # reaches x = 1.1: outside
    with pytest.raises(UserError, match=r"img_1.txt: line 1: box of 'bus'.*outside"):
        import_recording("images", src, tmp_path / "rec_y2", show_progress=False, labels=yolo, label_format="yolo")
    (yolo / "img_7.txt").write_text("0 0.5 0.5 0.1 0.1\n")
    (yolo / "img_1.txt").write_text("")
    with pytest.raises(UserError, match=r"img_7.txt: labels for image 'img_7.txt'"):
        import_recording("images", src, tmp_path / "rec_y3", show_progress=False, labels=yolo, label_format="yolo")

    kitti = tmp_path / "label_2"
    kitti.mkdir()
    (kitti / "img_0.txt").write_text(
        "Car 0.00 0 1.5 10.0 5.0 30.0 25.0 1.5 1.6 3.9 1.0 1.5 20.0 1.57\n"
        "Cyclist 0.00 1 -1.0 40.0 10.0 50.0 40.0 1.7 0.6 1.8 -2.0 1.6 15.0 1.5\n"
        "DontCare -1 -1 -10 0.0 0.0 5.0 5.0 -1 -1 -1 -1000 -1000 -1000 -10\n")
    rec = import_recording("images", src, tmp_path / "rec_k", show_progress=False, labels=kitti,
                           label_format="kitti")
    lab = read_recording_labels(read_recording(rec))
    assert [(b["cls"], b["box"], b["ignore"]) for b in lab["f000000"]] == [
        ("car", [10.0, 5.0, 20.0, 20.0], False), ("ignore", [40.0, 10.0, 10.0, 30.0], True),
        ("ignore", [0.0, 0.0, 5.0, 5.0], True)]


def test_import_labels_cli_error_has_no_traceback(tmp_path):
    src = _stills(tmp_path / "src")
    coco = _coco(tmp_path / "c.json", [(1, 3, (0, 0, 10, 10))])
    r = subprocess.run([sys.executable, "-m", "blendgen.cli", "import", "images", str(src), str(tmp_path / "rec"),
                        "--labels", str(coco), "--label-format", "coco", "--no-progress"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "'Tram'" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, "-m", "blendgen.cli", "import", "images", str(src), str(tmp_path / "rec"),
                        "--labels", str(coco), "--label-format", "coco", "--class-map", "Tram=drop", "--no-progress"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "rec" / "labels.json").read_text())["frames"]["f000000"] == []


def test_recording_labels_are_validated_against_the_recording(tmp_path):
    src = _stills(tmp_path / "src", 2)
    rec_dir = import_recording("images", src, tmp_path / "rec", show_progress=False)
    doc = {"format": "blendgen-recording-labels", "version": 1, "width": IW, "height": IH, "source": {},
           "frames": {"f000005": [{"cls": "car", "box": [0, 0, 5, 5]}]}}
    (rec_dir / "labels.json").write_text(json.dumps(doc))
    with pytest.raises(UserError, match=r"frames.f000005: labels for frame f000005, which the recording does not"):
        read_recording_labels(read_recording(rec_dir))
    doc["frames"] = {"f000001": [{"cls": "car", "box": [60, 0, 10, 5]}]}
    (rec_dir / "labels.json").write_text(json.dumps(doc))
    with pytest.raises(UserError, match=r"f000001\[0\]: box \[60, 0, 10, 5\] lies outside the 64x48 frame"):
        read_recording_labels(read_recording(rec_dir))
    assert any(f.level == "error" and "outside" in f.message for f in check_recording(rec_dir))


def test_real_boxes_updated_for_what_injected_objects_cover():
    covered = np.zeros((40, 60), bool)
    covered[5:25, 10:30] = True  # an injected car
    real = [{"cls": "car", "box": [12, 8, 10, 10], "ignore": False, "source": "user"},       # wholly behind it
            {"cls": "person", "box": [20, 10, 20, 10], "ignore": False, "source": "user"},   # half behind it
            {"cls": "truck", "box": [40.5, 2.25, 12, 20], "ignore": False, "source": "user"},  # clear of it
            {"cls": "car", "box": [26, 20, 6, 8], "ignore": False, "source": "detector", "score": 0.9}]
    out = real_instances(real, covered, min_visible_px=40)
    by = {i["id"]: i for i in out}
    assert -1 not in by  # fully covered: dropped
    half = by[-2]
    assert half["bbox"] == [30, 10, 10, 10] and half["occlusion"] == pytest.approx(0.5)
    assert half["visible_px"] == 100 and half["amodal_px"] == 200 and not half["ignore"]
    assert by[-3]["bbox"] == [40.5, 2.25, 12, 20] and by[-3]["occlusion"] == 0  # untouched: its own box
    assert -4 not in by  # 48 - 12 covered = 36 px < min_visible_px: dropped like a tiny injected object
    ign = real_instances(real, covered, min_visible_px=40, small_objects="ignore")
    assert {i["id"]: i["ignore"] for i in ign} == {-2: False, -3: False, -4: True}
    assert all(i["source"] == "user" for i in out[:2]) and {i["source"] for i in ign} == {"user", "detector"}


def test_detections_become_labels_or_ignore_regions_by_score():
    boxes = detector_boxes([{"cls": "car", "box": [0, 0, 5, 5], "score": 0.8},
                            {"cls": "person", "box": [0, 0, 5, 5], "score": 0.3}], 0.5)
    assert [(b["ignore"], b["source"]) for b in boxes] == [(False, "detector"), (True, "detector")]


def test_export_writes_real_labels_with_their_source(tmp_path):
    index, plan, amodal = make_frame()
    out = tmp_path / "out"
    d = out / "frames" / "f000000"
    d.mkdir(parents=True)
    img = np.full((H, W, 3), 200, np.uint8)
    cv2.imwrite(str(d / "composite.png"), img)
    real = [{"cls": "car", "box": [100, 40, 30, 20], "ignore": False, "source": "user", "label": "Car"},
            {"cls": "person", "box": [140, 10, 8, 20], "ignore": True, "source": "detector", "score": 0.3},
            {"cls": "ignore", "box": [2, 70, 10, 10], "ignore": True, "source": "user", "label": "DontCare"}]
    inst = extract_instances(index, plan, CAMERA, amodal_px=amodal, min_visible_px=2,
                             real_boxes=[{"cls": r["cls"], "box": r["box"]} for r in real])
    real_inst = real_instances(real, index > 0, min_visible_px=2)
    write_frame_labels(d / "labels.json", "f000000", "composite.png", W, H, inst, camera=CAMERA, real=real_inst)
    doc = read_frame_labels(d / "labels.json")
    assert len(doc["real"]) == 3 and all(i["source"] == "injected" for i in doc["instances"])
    summary = export_labels(out, find_frame_labels(out), ["coco", "yolo", "kitti"])
    n_inj = len(inst)
    assert summary["per_source"] == {"injected": n_inj, "user": 1}
    assert summary["ignored_per_source"] == {"detector": 1, "user": 1}

    coco = COCO(str(out / "labels/coco.json"))
    anns = coco.loadAnns(coco.getAnnIds())
    user = [a for a in anns if a["attributes"]["source"] == "user"]
    assert len([a for a in user if not a["iscrowd"]]) == 1 and len([a for a in user if a["iscrowd"]]) == 7
    assert {a["category_id"] for a in user if a["iscrowd"]} == set(coco.getCatIds())  # classless: every class
    det = [a for a in anns if a["attributes"]["source"] == "detector"]
    assert len(det) == 1 and det[0]["iscrowd"] == 1 and det[0]["attributes"]["score"] == 0.3

    k = (out / "labels/kitti/label_2/f000000.txt").read_text().splitlines()
    src = (out / "labels/kitti/source_2/f000000.txt").read_text().splitlines()
    assert len(k) == len(src) == n_inj + 3
    car = parse_label_line(k[src.index("user")])
    assert car["type"] == "Car" and car["bbox"] == [100, 40, 130, 60] and car["location"] == [-1000] * 3
    assert [parse_label_line(x)["type"] for x, s in zip(k, src) if s != "injected"][1:] == ["DontCare", "DontCare"]

    y = out / "labels/yolo"
    lines = (y / "labels/f000000.txt").read_text().splitlines()
    srcs = (y / "sources/f000000.txt").read_text().splitlines()
    assert len(lines) == len(srcs) and srcs.count("user") == 1 and "detector" not in srcs
    painted = cv2.imread(str(y / "images/f000000.png"))
    assert not (y / "images/f000000.png").is_symlink()  # a painted copy, not the composite
    assert (painted[10:30, 140:148] == 114).all() and (painted[70:80, 2:12] == 114).all()
    assert (painted[40:60, 100:130] == 200).all()  # labelled: untouched
    assert (cv2.imread(str(d / "composite.png")) == 200).all()  # the composite itself is never painted


def test_job_labels_section(tmp_path):
    from blendgen.job.schema import parse_job

    src = _stills(tmp_path / "src", 1)
    rec = import_recording("images", src, tmp_path / "rec", show_progress=False)
    base = {"name": "j", "recording": str(rec), "ground_plane": "auto", "output": str(tmp_path / "out")}
    assert parse_job(base).labels.real == "auto"
    with pytest.raises(UserError, match=r"labels.real: user, but the recording .* has no labels.json"):
        parse_job({**base, "labels": {"real": "user"}})
    with pytest.raises(UserError, match=r"labels.real"):
        parse_job({**base, "labels": {"real": "maybe"}})
    with pytest.raises(UserError, match=r"detector_score"):
        parse_job({**base, "labels": {"detector_score": 1.5}})
    synthetic = {"name": "j", "synthetic": {}, "twin": "demo_town", "output": str(tmp_path / "o2"),
                 "labels": {"real": "user"}}
    with pytest.raises(UserError, match="a synthetic recording has no real road users"):
        parse_job(synthetic)
