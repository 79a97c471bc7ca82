"""The report: contact sheet, plots, realism table and stage times linked from index.md."""

import json
import re

import cv2
import numpy as np

from blendgen.atomic import append_line
from blendgen.cli import main
from blendgen.labels.frame_labels import write_frame_labels
from blendgen.labels.instances import extract_instances
from blendgen.report import build_report

from labels_fixtures import CAMERA, H, W, make_frame, synthetic_instances


def _out(tmp_path, n=5):
    out = tmp_path / "out"
    rng = np.random.default_rng(1)
    index, plan, amodal = make_frame()
    for k in range(n):
        fid = f"f{k:06d}"
        d = out / "frames" / fid
        d.mkdir(parents=True)
        cv2.imwrite(str(d / "composite.png"), rng.integers(0, 255, (H, W, 3), dtype=np.uint8))
        inst = (extract_instances(index, plan, CAMERA, amodal_px=amodal, min_visible_px=2, small_objects="ignore")
                if k % 2 == 0 else synthetic_instances(rng, 4))
        write_frame_labels(d / "labels.json", fid, f"frames/{fid}/composite.png", W, H, inst)
        append_line(out / "manifest.jsonl", json.dumps(
            {"stage": "frames", "frame_id": fid, "timings": {"render": 2.0 + k, "post": 0.5, "labels": 0.01,
                                                              "total": 2.51 + k}}))
    with open(out / "manifest.jsonl", "a") as f:
        f.write('{"frame_id": "torn')  # a torn last line is skipped
    return out


def test_report_links_everything(tmp_path):
    out = _out(tmp_path)
    (out / "eval").mkdir()
    (out / "eval/realism.md").write_text("| class | labels |\n|---|---:|\n| car | 3 |\n")
    index = build_report(out)
    assert index == out / "report/index.md"
    text = index.read_text()
    for target in re.findall(r"\]\(([^)]+)\)", text):
        assert (index.parent / target).exists(), target
    for name in ("contact_sheet.jpg", "class_counts.png", "box_sizes.png", "distances.png", "stage_times.png"):
        assert f"({name})" in text and (out / "report" / name).stat().st_size > 1000
    sheet = cv2.imread(str(out / "report/contact_sheet.jpg"))
    assert sheet is not None and sheet.shape[1] >= 4 * 400
    assert "| car | 3 |" in text  # realism table included
    # Median render time over the 5 frames (2, 3, 4, 5, 6 s) is 4 s.
    assert re.search(r"\| render \| 5 \| 4\.000 \|", text)


def test_report_on_empty_output_and_cli(tmp_path):
    out = tmp_path / "empty"
    out.mkdir()
    text = build_report(out).read_text()
    assert "No finished frames yet" in text and "Not run" in text
    assert main(["report", str(out)]) == 0
    assert main(["report", str(tmp_path / "missing")]) == 2
