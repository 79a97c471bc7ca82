"""The job schema: every user mistake names the field and what was expected, exit code 2,
no traceback; a valid job gets its defaults filled in and a stable content hash."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from blendgen.errors import UserError
from blendgen.geometry import Camera
from blendgen.job.schema import load_job
from blendgen.recording import folder


@pytest.fixture()
def rec_dir(tmp_path: Path) -> Path:
    root = tmp_path / "rec"
    root.mkdir()
    folder.write_calib(root, Camera.from_hfov(64, 48, 60))
    folder.write_imu(root, np.column_stack([np.arange(10) * 0.01, np.zeros((10, 5)), np.full(10, 9.81)]))
    return root


def base_job(rec_dir: Path) -> dict:
    return {"name": "t", "recording": str(rec_dir), "ground_plane": {"camera_height_m": 1.4},
            "output": "out"}


def write_job(tmp_path: Path, data) -> Path:
    p = tmp_path / "job.yaml"
    p.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return p


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "blendgen.cli", *args], capture_output=True, text=True,
                          timeout=120)


# (mutation of the valid base job, text the error must contain)
MALFORMED = [
    ("unknown top-level key", lambda j: j.update(outptu="x"), "outptu: unknown key"),
    ("missing output", lambda j: j.pop("output"), "output: required field is missing"),
    ("missing name", lambda j: j.pop("name"), "name: required field is missing"),
    ("bad name characters", lambda j: j.update(name="my job!"), "name:"),
    ("seed wrong type", lambda j: j.update(seed="seven"), "seed:"),
    ("negative seed", lambda j: j.update(seed=-1), "seed: Input should be greater than or equal to 0"),
    ("unknown class", lambda j: j.update(inject={"classes": {"cat": 1}}), "inject.classes: unknown class 'cat'"),
    ("all class weights zero", lambda j: j.update(inject={"classes": {"car": 0}}), "must not all be zero"),
    ("objects_per_frame reversed", lambda j: j.update(inject={"objects_per_frame": [5, 2]}),
     "objects_per_frame: min 5 is greater than max 2"),
    ("unknown scenario", lambda j: j.update(inject={"scenarios": ["alien_landing"]}),
     "unknown scenario 'alien_landing'"),
    ("samples zero", lambda j: j.update(render={"samples": 0}), "render.samples: Input should be greater than"),
    ("resolution one number", lambda j: j.update(render={"resolution": [640]}), "render.resolution"),
    ("unknown colour transfer", lambda j: j.update(post={"color_transfer": "magic"}), "post.color_transfer"),
    ("unknown export format", lambda j: j.update(export={"formats": ["coco", "voc"]}), "export.formats[1]"),
    ("negative min_visible_px", lambda j: j.update(export={"min_visible_px": -3}), "export.min_visible_px"),
    ("unknown key in section", lambda j: j.update(sync={"orb_feature": 500}), "sync.orb_feature: unknown key"),
    ("orb_features too few", lambda j: j.update(sync={"orb_features": 10}), "sync.orb_features"),
    ("recording and synthetic", lambda j: j.update(synthetic={}), "exactly one of `recording`"),
    ("neither twin nor ground plane", lambda j: j.pop("ground_plane"), "exactly one of `twin`"),
    ("both twin and ground plane", lambda j: j.update(twin="demo_town"), "exactly one of `twin`"),
    ("missing recording folder", lambda j: j.update(recording="does/not/exist"), "recording: folder"),
    ("missing twin file", lambda j: (j.pop("ground_plane"), j.update(twin="nowhere.yaml")),
     "twin: 'nowhere.yaml'"),
    ("missing LUT file", lambda j: j.update(sync={"lut": "missing_lut.csv"}), "sync.lut: file"),
    ("farm engine unknown", lambda j: j.update(farm={"engine": "slurm"}), "farm.engine"),
    ("workers zero", lambda j: j.update(farm={"workers": 0}), "farm.workers"),
    ("frames stop before start", lambda j: j.update(frames={"start": 5, "stop": 3}), "frames.stop (3)"),
    ("distance range reversed", lambda j: j.update(inject={"distance_m": [30, 5]}), "distance_m: near 30"),
]


@pytest.mark.parametrize("case,mutate,expected", MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_job_names_the_field(tmp_path, rec_dir, case, mutate, expected):
    data = base_job(rec_dir)
    mutate(data)
    path = write_job(tmp_path, data)
    with pytest.raises(UserError) as e:
        load_job(path)
    assert expected in str(e.value), str(e.value)
    assert str(path) in str(e.value)  # the message names the file


@pytest.mark.parametrize("text,expected", [
    ("name: [unclosed", "not valid YAML"),
    ("- just\n- a list\n", "expected a mapping"),
    ("", "expected a mapping"),
])
def test_unparsable_job(tmp_path, text, expected):
    with pytest.raises(UserError, match=expected):
        load_job(write_job(tmp_path, text))


def test_cli_exit_code_2_without_traceback(tmp_path, rec_dir):
    # Spot-check the CLI path for a few malformed jobs (all share the same error path).
    for _, mutate, expected in MALFORMED[:4] + MALFORMED[-4:]:
        data = base_job(rec_dir)
        mutate(data)
        r = run_cli("validate", str(write_job(tmp_path, data)))
        assert r.returncode == 2, r.stderr
        assert expected in r.stderr
        assert "Traceback" not in r.stderr
    r = run_cli("validate", str(tmp_path / "no_such_job.yaml"))
    assert r.returncode == 2 and "job file not found" in r.stderr and "Traceback" not in r.stderr


def test_valid_job_defaults_and_hash(tmp_path, rec_dir):
    path = write_job(tmp_path, base_job(rec_dir))
    job = load_job(path)
    assert job.render.samples == 16 and job.export.formats == ["coco", "yolo", "kitti"]
    assert job.out_dir == tmp_path / "out"  # relative to the job file
    h = job.content_hash()
    # farm settings do not change results, so they do not change the hash
    data = base_job(rec_dir)
    data["farm"] = {"workers": 4}
    assert load_job(write_job(tmp_path, data)).content_hash() == h
    data["seed"] = 99
    assert load_job(write_job(tmp_path, data)).content_hash() != h
    r = run_cli("validate", str(path))
    assert r.returncode == 0 and "valid job" in r.stdout
