"""The report: contact sheet, plots, realism table and stage times linked from index.md."""

import json
import re

import cv2
import numpy as np

from blendgen.atomic import append_line
from blendgen.cli import main
from blendgen.frame_labels import write_frame_labels
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


def test_report_shows_clean_composites_and_separate_stage_tables(tmp_path):
    """Issue 16: clean composites beside annotated ones (outlines, not fills), and the
    recording synthesis timed apart from the frame work, with frames/min of the latter."""
    out = _out(tmp_path, n=2)
    with open(out / "manifest.jsonl", "a") as f:
        f.write("\n")  # after the fixture's torn line
    append_line(out / "manifest.jsonl", json.dumps(
        {"stage": "record", "frame_id": "f000000", "timings": {"render_background": 9.0}}))
    (out / "run_summary.json").write_text(json.dumps(
        {"seconds_per_stage": {"record": 50.0, "sync": 1.0, "plan": 1.0, "frames": 10.0, "export": 0.0},
         "throughput": {"frames": 2, "frame_work_s": 12.0, "frames_per_min": 10.0}}))
    for k in range(2):  # smooth composites: JPEG keeps them, so tiles compare to them
        yy, xx = np.mgrid[0:H, 0:W]
        cv2.imwrite(str(out / f"frames/f{k:06d}/composite.png"),
                    np.dstack([xx * 255 // W, yy * 255 // H, np.full((H, W), 90)]).astype(np.uint8))
    text = build_report(out).read_text()
    rec, frames = text.index("### Recording synthesis"), text.index("### Frame work")
    assert rec < frames and "render_background" in text[rec:frames] and "render_background" not in text[frames:]
    assert "| **total frame work** | **12.0** |" in text and "**10.0 frames/min**" in text
    sheet = cv2.imread(str(out / "report/contact_sheet.jpg"))
    tile = 480
    clean, annotated = sheet[:, :tile].astype(int), sheet[:, tile + 4:2 * tile + 4].astype(int)
    composite = cv2.imread(str(out / "frames/f000000/composite.png"))
    small = cv2.resize(composite, (tile, round(composite.shape[0] * tile / composite.shape[1])),
                       interpolation=cv2.INTER_AREA).astype(int)
    h = small.shape[0]
    # the clean tile is the composite (JPEG-close, caption aside); the annotated one differs
    # only on outlines, boxes and tags: most of its pixels still show the composite
    assert np.median(np.abs(clean[20:h] - small[20:h])) < 12
    same = np.abs(annotated[:h] - small).max(axis=2) < 24
    assert 0.5 < same.mean() < 0.99


def test_label_tags_do_not_overlap():
    from blendgen.report.draw import _free_spot

    placed = []
    for _ in range(12):  # twelve objects whose boxes start at the same place
        placed.append(_free_spot((100, 40, 80, 14), placed, 480, 270))
    for i, (x, y, w, h) in enumerate(placed):
        for px, py, pw, ph in placed[i + 1:]:
            assert not (x < px + pw and px < x + w and y < py + ph and py < y + h)
        assert 0 <= x and x + w < 480 and 0 <= y and y + h < 270
