"""End to end: a tiny version of the demo job through the real pipeline (Cycles render,
ORB + EKF sync, post, labels), then a second run that redoes nothing."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

pytestmark = pytest.mark.bpy

TINY_JOB = {
    "name": "tiny",
    "seed": 3,
    "synthetic": {"duration_s": 2.0, "fps": 2, "resolution": [192, 108], "samples": 2},
    "twin": "demo_town",
    "sync": {"orb_features": 500, "reanchor_every_s": 1},
    "inject": {"objects_per_frame": [2, 3], "classes": {"car": 2, "person": 1}, "distance_m": [6, 30],
               "min_projected_px": 8},
    "render": {"samples": 4, "denoise": False},
    "export": {"formats": ["coco", "yolo", "kitti"], "min_visible_px": 4},
    "farm": {"workers": 1, "chunk": 2},
    "output": "out",
}


def run(job: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "blendgen.cli", "run", str(job), *extra],
                          capture_output=True, text=True, timeout=900)


def test_tiny_demo_runs_end_to_end_and_resumes(tmp_path):
    job = tmp_path / "job.yaml"
    job.write_text(yaml.safe_dump(TINY_JOB))
    r = run(job)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    out = tmp_path / "out"
    rec = out / "recording"
    for name in ("calib.yaml", "frames.csv", "imu.csv", "gnss.csv", "groundtruth.csv"):
        assert (rec / name).exists(), name
    frames = sorted((out / "frames").iterdir())
    assert len(frames) == 5  # 2 s at 2 fps, both ends
    for d in frames:
        comp = d / "composite.png"
        assert comp.exists() and (d / "instances.png").exists() and (d / "labels.json").exists()
    coco = json.loads((out / "labels" / "coco.json").read_text())
    assert len(coco["images"]) == 5 and len(coco["annotations"]) > 0
    assert {c["id"] for c in coco["categories"]} >= {1, 3}
    manifest = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines() if line]
    assert {m["item"] for m in manifest if m.get("stage") == "frames"} == {d.name for d in frames}
    poses = np.loadtxt(out / "poses.tum")
    assert poses.shape == (5, 8) and np.all(np.isfinite(poses))
    summary = json.loads((out / "run_summary.json").read_text())
    assert summary["frames"]["done"] == 5 and summary["frames"]["failed"] == 0

    # Second run: nothing is redone.
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file() and ".blendgen" not in p.parts}
    r2 = run(job)
    assert r2.returncode == 0, r2.stderr[-3000:]
    changed = [p for p, m in before.items() if p.exists() and p.stat().st_mtime_ns != m
               and p.name not in ("run_summary.json",)]
    assert changed == [], changed

    # Issue 16: the same recording with a truncated, an empty, a wrong-size and a missing
    # frame: the run goes to the end, the good frame is produced, each bad one is listed once
    # with its reason, nothing is retried, and the exit code says frames failed.
    import shutil

    import cv2

    bad_rec = tmp_path / "bad_rec"
    shutil.copytree(rec, bad_rec)
    png = (bad_rec / "frames/f000001.png").read_bytes()
    (bad_rec / "frames/f000001.png").write_bytes(png[: len(png) // 3])
    (bad_rec / "frames/f000002.png").write_bytes(b"")
    cv2.imwrite(str(bad_rec / "frames/f000003.png"), np.zeros((50, 60, 3), np.uint8))
    (bad_rec / "frames/f000004.png").unlink()
    bad_job = {k: v for k, v in TINY_JOB.items() if k != "synthetic"}
    bad_job.update(name="tiny_bad", recording=str(bad_rec), output="out_bad", farm={"workers": 1, "chunk": 5})
    job_b = tmp_path / "bad.yaml"
    job_b.write_text(yaml.safe_dump(bad_job))
    r3 = run(job_b)
    assert r3.returncode == 3, r3.stdout[-3000:] + r3.stderr[-3000:]
    out_b = tmp_path / "out_bad"
    assert (out_b / "frames/f000000/composite.png").exists()
    s3 = json.loads((out_b / "run_summary.json").read_text())
    assert s3["frames"] == {"total": 5, "done": 1, "failed": 4}
    reasons = {f["frame"]: f["reason"] for f in s3["failed_frames"]}
    assert "does not decode" in reasons["f000001"] and "empty (0 bytes)" in reasons["f000002"]
    assert "60x50 but calib.yaml" in reasons["f000003"] and "missing" in reasons["f000004"]
    st = subprocess.run([sys.executable, "-m", "blendgen.cli", "status", str(out_b)],
                        capture_output=True, text=True, timeout=60).stdout
    assert st.count("FAILED frame") == 4 and "FAILED task" not in st, st
    attempts = sqlite3.connect(out_b / ".blendgen/ledger.sqlite").execute(
        "SELECT max(attempts) FROM tasks WHERE stage='frames'").fetchone()[0]
    assert attempts == 1  # no retry spent on bad input
