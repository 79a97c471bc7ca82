"""Issue 16, what a new user trips over: output permissions, the folder lock over every stage,
a frame range refused before anything is written, temp files left by a kill."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np
import pytest
import yaml

from blendgen import atomic
from blendgen.errors import UserError
from blendgen.geometry import Camera
from blendgen.job.schema import load_job
from blendgen.pipeline.outputs import JobFolder
from blendgen.pipeline.run import Runner
from blendgen.recording import folder


def test_outputs_get_the_users_umask(tmp_path):
    old = os.umask(0o022)
    try:
        atomic.FILE_MODE = atomic._file_mode()
        atomic.write_text(tmp_path / "a.txt", "x")
        atomic.write_json(tmp_path / "b.json", {"x": 1})
        for name in ("a.txt", "b.json"):
            assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644, name
    finally:
        os.umask(old)
        atomic.FILE_MODE = atomic._file_mode()


def _recording(root: Path, n: int) -> Path:
    root.mkdir(parents=True)
    cam = Camera.from_hfov(64, 48, 60)
    folder.write_calib(root, cam)
    (root / "img").mkdir()
    for i in range(n):
        atomic.write_image(root / f"img/{i}.png", np.full((48, 64, 3), i, np.uint8))
    folder.write_frames_csv(root, np.arange(n) * 0.1, [f"img/{i}.png" for i in range(n)])
    return root


def _job(tmp_path: Path, **extra) -> Path:
    data = {"name": "t", "recording": str(_recording(tmp_path / "rec", 21)), "ground_plane": {},
            "output": "out", **extra}
    p = tmp_path / "job.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def test_frame_range_beyond_the_recording_is_refused_before_any_output(tmp_path):
    job = load_job(_job(tmp_path, frames={"start": 100}))
    with pytest.raises(UserError, match=r"frames.start is 100, but the recording .* has 21 frames \(0..20\)"):
        Runner(job, progress=False).run()
    assert not (tmp_path / "out").exists()  # nothing written: the corrected job is not "a different job"


def test_folder_lock_covers_every_stage(tmp_path):
    job = load_job(_job(tmp_path))
    with JobFolder(job.out_dir).lock():
        with pytest.raises(UserError, match="another blendgen is running on this folder"):
            Runner(job, progress=False).run()
    assert not (job.out_dir / "poses.csv").exists() and not (job.out_dir / "job.resolved.yaml").exists()


def _plan(tmp_path: Path, out: str, **frames) -> list[dict]:
    import json

    # the fixed pose (no frame analysis): the synthetic frames are dark, and a frame without a
    # road region takes no object (tests/test_planner_real_outcomes.py)
    job = load_job(_job(tmp_path, output=out, seed=5, frames=frames, ground_plane={"analysis": False},
                        inject={"objects_per_frame": [3, 3], "classes": {"car": 1}, "min_projected_px": 1}))
    runner = Runner(job, progress=False)
    runner.frames = lambda ids: None  # stop before rendering (no bpy here)
    runner.export = lambda ids: {}
    runner.report = lambda: None
    runner.run()
    return [json.loads(line) for line in (job.out_dir / "plan.jsonl").read_text().splitlines()]


def test_layout_seed_depends_on_the_first_frame(tmp_path):
    a = _plan(tmp_path, "a", stop=3)
    a2 = _plan(tmp_path / "again", "a", stop=3)
    b = _plan(tmp_path / "other", "b", start=3, stop=6)
    assert a == a2  # same job, same seed: the same plan
    assert a[0]["objects"] and b[0]["objects"]
    assert a[0]["objects"] != b[0]["objects"]  # not the same first layout whatever the frame id


def test_stale_temps_of_a_killed_run_are_removed_on_resume(tmp_path):
    job = load_job(_job(tmp_path, frames={"stop": 1}))
    out = job.out_dir
    (out / ".blendgen").mkdir(parents=True)
    left = [out / ".plan.abc123.tmp.jsonl", out / ".blendgen" / ".sync.x1.tmp.done"]
    for p in left:
        p.write_text("half")
    runner = Runner(job, progress=False)
    runner.frames = lambda ids: None  # stop before rendering (no bpy here)
    runner.export = lambda ids: {}
    runner.report = lambda: None
    runner.run()
    assert [p for p in left if p.exists()] == []
    assert (out / "plan.jsonl").exists()
