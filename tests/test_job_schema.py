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
    ("all class weights zero", lambda j: j.update(inject={"classes": {"car": 0}}),
     "at least one class with a positive weight"),
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


# Issue 16: what a new user tried (fuzzed jobs), each with its precise message.
MALFORMED += [
    ("seed true", lambda j: j.update(seed=True), "seed: Input should be a valid integer"),
    ("no classes", lambda j: j.update(inject={"classes": {}}), "inject.classes: expected at least one class"),
    ("infinite class weight", lambda j: j.update(inject={"classes": {"car": float("inf")}}),
     "inject.classes.car: Input should be a finite number"),
    ("NaN distance", lambda j: j.update(inject={"distance_m": [float("nan"), 5]}), "inject.distance_m[0]"),
    ("5000 objects per frame", lambda j: j.update(inject={"objects_per_frame": [5000, 5000]}),
     "inject.objects_per_frame[0]: Input should be less than or equal to 100"),
    ("classes as a list", lambda j: j.update(inject={"classes": ["car"]}), "inject.classes: Input should be a valid dict"),
    ("scenarios as a string", lambda j: j.update(inject={"scenarios": "jaywalker"}), "inject.scenarios"),
    ("section not a mapping", lambda j: j.update(render="fast"), "render: Input should be a valid dictionary"),
    ("motion blur number", lambda j: j.update(render={"motion_blur": 5}), "render.motion_blur"),
    ("illumination unknown", lambda j: j.update(post={"illumination": "maybe"}), "post.illumination"),
    ("frames step zero", lambda j: j.update(frames={"step": 0}), "frames.step"),
    ("negative frames start", lambda j: j.update(frames={"start": -2}), "frames.start"),
    ("name too long", lambda j: j.update(name="x" * 5000), "name: String should have at most 100 characters"),
    ("twin a number", lambda j: (j.pop("ground_plane"), j.update(twin=5)), "twin: Input should be a valid string"),
    ("farm address a list", lambda j: j.update(farm={"address": [1, 2]}), "farm.address"),
    ("small_objects unknown", lambda j: j.update(export={"small_objects": "keep"}), "export.small_objects"),
    ("reanchor negative", lambda j: j.update(sync={"reanchor_every_s": -1}), "sync.reanchor_every_s"),
    ("pitch out of range", lambda j: j.update(ground_plane={"pitch_deg": 90}), "ground_plane.pitch_deg"),
    ("synthetic fps 1000", lambda j: (j.pop("recording"), j.pop("ground_plane"),
                                      j.update(twin="demo_town", synthetic={"fps": 1000})), "synthetic.fps"),
    ("synthetic without twin", lambda j: (j.pop("recording"), j.update(synthetic={})), "give `twin` too"),
    ("output names a file", lambda j: j.update(output=__file__), "is a file, expected a folder"),
    ("output unwritable", lambda j: j.update(output="/proc/blendgen_out"), "output: cannot write in /proc"),
    ("huge value is quoted briefly", lambda j: j.update(seed="9" * 100_000), "seed:"),
]


@pytest.mark.parametrize("case,mutate,expected", MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_job_names_the_field(tmp_path, rec_dir, capsys, case, mutate, expected):
    from blendgen.cli import main

    data = base_job(rec_dir)
    mutate(data)
    path = write_job(tmp_path, data)
    assert main(["validate", str(path)]) == 2  # the CLI in-process: exit code 2
    err = capsys.readouterr().err
    assert expected in err, err
    assert str(path) in err and "Traceback" not in err  # the message names the file
    assert len(err) < 2000  # what it quotes of the value is bounded


@pytest.mark.parametrize("text,expected", [
    ("name: [unclosed", "not valid YAML"),
    ("- just\n- a list\n", "expected a mapping"),
    ("", "expected a mapping"),
])
def test_unparsable_job(tmp_path, text, expected):
    with pytest.raises(UserError, match=expected):
        load_job(write_job(tmp_path, text))


def test_cli_exit_code_2_without_traceback(tmp_path, rec_dir):
    # The real entry point, as a subprocess, for two malformed jobs; every case above already
    # ran through blendgen.cli.main in-process (same error path).
    for _, mutate, expected in MALFORMED[:1] + MALFORMED[-1:]:
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


# raw job texts that are not a sane YAML document: (id, text or bytes, expected message)
BOMB = "".join(f"{c}: &{c} [{', '.join([f'*{p}'] * 9) if p else ', '.join(['lol'] * 9)}]\n"
               for p, c in zip([None, *"abcdefgh"], "abcdefghi")) + "name: *i\noutput: out\n"
RAW = [
    ("duplicate key", "name: a\nseed: 1\nseed: 2\noutput: out\n", ":3: not valid YAML: duplicate key 'seed' (first on line 2)"),
    ("binary garbage", bytes(range(256)) * 8, "not a text (UTF-8) file"),
    ("anchor bomb", BOMB, "expands to more than 100000 values"),
    ("50 MB job", "name: a\n" + "# padding\n" * 5_000_000, "job file is 47.7 MB"),
    ("deep nesting", "name: " + "[" * 5000 + "]" * 5000, ":1: not valid YAML: nested more than 50 levels"),
    ("tab indentation", "name: a\nrender:\n\tsamples: 4\n", "not valid YAML"),
    ("top-level scalar", "just words", "expected a mapping"),
]


@pytest.mark.parametrize("case,text,expected", RAW, ids=[r[0] for r in RAW])
def test_malformed_job_text_in_process_cli(tmp_path, capsys, case, text, expected):
    """Exit 2, one message naming the file, no traceback, and a bounded message."""
    from blendgen.cli import main

    path = tmp_path / "job.yaml"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    rc = main(["validate", str(path)])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert expected in err and str(path) in err and "Traceback" not in err, err
    assert len(err) < 2000  # what the message quotes is bounded


def test_yaml_booleans_and_yaml12_floats_are_accepted(tmp_path, rec_dir):
    text = yaml.safe_dump(base_job(rec_dir)) + "post: {illumination: off}\nrender: {motion_blur: on}\n"
    job = load_job(write_job(tmp_path, text))
    assert job.post.illumination == "off" and job.render.motion_blur == "on"
    # calib.yaml written by hand with a YAML 1.2 float (no dot): read as a number
    calib = (rec_dir / "calib.yaml").read_text()
    import re

    (rec_dir / "calib.yaml").write_text(re.sub(r"gyroscope_noise_density: .*", "gyroscope_noise_density: 5e-05", calib))
    from blendgen.recording.folder import read_recording

    assert read_recording(rec_dir).imu_noise.gyroscope_noise_density == 5e-05


def test_gpu_device_without_a_gpu(tmp_path, rec_dir, monkeypatch):
    from blendgen.job import schema

    monkeypatch.setattr(schema, "_has_gpu", lambda: False)
    data = base_job(rec_dir)
    data["render"] = {"device": "GPU"}
    with pytest.raises(UserError, match="render.device: GPU, but this machine shows no GPU"):
        load_job(write_job(tmp_path, data))
    monkeypatch.setattr(schema, "_has_gpu", lambda: True)
    assert load_job(write_job(tmp_path, data)).render.device == "GPU"


def test_example_jobs_match_the_schema():
    """The jobs/ examples the README points to stay valid as the schema changes (their recordings
    are made by the commands in their headers, so only the fields are checked here)."""
    from blendgen.job.schema import Job

    paths = sorted((Path(__file__).resolve().parents[1] / "jobs").glob("*.yaml"))
    assert len(paths) >= 6
    for p in paths:
        Job.model_validate(yaml.safe_load(p.read_text()))
