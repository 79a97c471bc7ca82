"""`blendgen run`'s farm pipeline on the real freeway video: the frame analysis and the plan made
by farm tasks equal what the in-process stages (analysis.stage.run_analysis,
scene.planner.plan_sequence) give for the same job; a worker killed during the analysis loses
nothing; Ray and the local pool give the same labels."""

from __future__ import annotations

import json
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("BLENDGEN_SHARED_DATA", ROOT.parent / "shared" / "data"))
VIDEO = DATA / "real" / "udacity_solidWhiteRight.mp4"
pytestmark = pytest.mark.data


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    if not VIDEO.is_file():
        pytest.skip(f"needs {VIDEO}")
    root = tmp_path_factory.mktemp("rec") / "freeway"
    r = subprocess.run([sys.executable, "-m", "blendgen.cli", "import", "video", str(VIDEO), str(root), "--hfov", "55",
                        "--no-progress"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    return root


def write_job(folder: Path, rec: Path, *, frames=16, workers=2, engine="local", render=None, stills=False) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    job = {"name": "freeway", "seed": 3, "recording": str(rec),
           "ground_plane": "auto",   # video: the height from the job's and 48 other frames' lanes and cars
           "frames": {"start": 0, "stop": None, "step": 1} if stills else {"start": 20, "stop": 20 + frames, "step": 1},
           "inject": {"objects_per_frame": [3, 4], "distance_m": [8, 35], "sequences": not stills,
                      "classes": {"car": 3, "truck": 1, "bus": 1, "motorcycle": 1}},
           "render": render or {"resolution": [320, 180], "samples": 1, "denoise": False},
           "export": {"formats": ["coco"], "min_visible_px": 4},
           "farm": {"workers": workers, "engine": engine}, "output": str(folder / "out")}
    (folder / "job.yaml").write_text(yaml.safe_dump(job))
    return folder / "job.yaml"


def run_until_plan(job_path: Path) -> Path:
    from blendgen.job.schema import load_job
    from blendgen.pipeline.run import Runner

    job = load_job(job_path)
    Runner(job, progress=False, until="plan").run()
    return job.out_dir


def reference(job_path: Path, where: Path):
    """The in-process stages' analyses and plan for the job."""
    from blendgen.analysis.stage import run_analysis
    from blendgen.farm.seeds import frame_seed
    from blendgen.frame_analysis import read_analysis
    from blendgen.job.schema import load_job
    from blendgen.recording.folder import read_recording
    from blendgen.scene.ground_plane import GroundPlaneTwin
    from blendgen.scene.planner import plan_sequence
    from blendgen.scene.real_scene import load_real_scene

    job = load_job(job_path)
    rec = read_recording(job.recording_dir)
    ids = [rec.frame_id(i) for i in range(rec.n_frames)][job.frames.start:job.frames.stop:job.frames.step]
    run_analysis(rec, ids, where, job.ground_plane)
    cam = rec.camera.scaled(*job.render.resolution)
    poses = [(f, float(rec.frames_t[int(f[1:])]), np.asarray(read_analysis(where, f).T_world_cam)) for f in ids]
    plans = plan_sequence(GroundPlaneTwin.from_job(job.ground_plane), cam, poses, job.inject,
                          frame_seed(job.seed, ids[0]), real=load_real_scene(where, ids, cam))
    return ids, [json.loads(json.dumps(p.to_dict())) for p in plans]


def analyses(folder: Path, ids) -> dict:
    out = {}
    for f in ids:
        d = json.loads((folder / f"{f}.json").read_text())
        d["decisions"] = [x for x in d["decisions"] if x["what"] != "cpu_s"]  # timings
        out[f] = d
    return out


@pytest.fixture(scope="module")
def ref(recording, tmp_path_factory):
    where = tmp_path_factory.mktemp("ref")
    job = write_job(where / "job", recording)
    ids, plans = reference(job, where / "analysis")
    return ids, analyses(where / "analysis", ids), plans


def test_farm_analysis_and_plan_equal_the_in_process_stages(recording, ref, tmp_path):
    ids, ref_an, ref_plans = ref
    out = run_until_plan(write_job(tmp_path, recording))
    assert analyses(out / "analysis", ids) == ref_an
    assert [json.loads(x) for x in (out / "plan.jsonl").read_text().splitlines()] == ref_plans
    assert sum(len(p["objects"]) for p in ref_plans) > 0
    assert json.loads((out / "analysis" / "recording.json").read_text())["sample"] == ids


def test_stills_farm_analysis_and_plan_equal_the_in_process_stages(tmp_path):
    """Six photos of one camera: one hood by consensus, one mount fitted jointly (analysis.mount)."""
    photos = DATA / "real" / "udacity_highway_images"
    if not photos.is_dir():
        pytest.skip(f"needs {photos}")
    rec = tmp_path / "rec"
    r = subprocess.run([sys.executable, "-m", "blendgen.cli", "import", "images", str(photos), str(rec), "--hfov", "55",
                        "--no-progress"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    job = write_job(tmp_path / "job", rec, stills=True)
    ids, plans = reference(job, tmp_path / "ref")
    out = run_until_plan(job)
    assert analyses(out / "analysis", ids) == analyses(tmp_path / "ref", ids)
    assert [json.loads(x) for x in (out / "plan.jsonl").read_text().splitlines()] == plans


@pytest.mark.timeout(900)
def test_a_worker_killed_during_the_analysis_loses_nothing(recording, ref, tmp_path):
    """SIGKILL a worker while it runs an analysis task: its task is retried, the job ends well
    and every analysis and the plan are those of an undisturbed run."""
    ids, ref_an, ref_plans = ref
    job = write_job(tmp_path, recording)
    out = tmp_path / "out"
    code = ("import sys; from blendgen.job.schema import load_job; from blendgen.pipeline.run import Runner; "
            f"Runner(load_job({str(job)!r}), progress=False, until='plan').run()")
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    killed = None
    deadline = time.monotonic() + 600
    while killed is None and p.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
        try:
            with sqlite3.connect(f"file:{out / '.blendgen' / 'ledger.sqlite'}?mode=ro", uri=True, timeout=1) as db:
                rows = db.execute("SELECT w.pid, t.stage FROM tasks t JOIN workers w ON w.worker = t.worker "
                                  "WHERE t.state = 'running' AND t.stage IN ('cues', 'analysis', 'motion')").fetchall()
        except sqlite3.Error:
            continue
        if rows and len(list((out / "analysis" / "cues").glob("*.json"))) >= 2:
            killed = rows[0]
            os.kill(int(killed[0]), signal.SIGKILL)
    log = p.communicate(timeout=600)[0]
    assert killed is not None, log[-3000:]
    assert p.returncode == 0, log[-3000:]
    with sqlite3.connect(out / ".blendgen" / "ledger.sqlite") as db:
        errs = [r[0] for r in db.execute("SELECT error FROM attempts WHERE error IS NOT NULL")]
    assert any("SIGKILL" in e for e in errs), errs
    assert analyses(out / "analysis", ids) == ref_an
    assert [json.loads(x) for x in (out / "plan.jsonl").read_text().splitlines()] == ref_plans
    leftovers = [q.name for q in (out / "analysis").rglob(".*tmp*")]
    assert leftovers == [], leftovers


@pytest.mark.bpy
@pytest.mark.ray
@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_ray_and_local_give_the_same_labels(recording, tmp_path):
    pytest.importorskip("ray")
    labels = {}
    for engine in ("local", "ray"):
        job = write_job(tmp_path / engine, recording, frames=10, engine=engine,
                        render={"resolution": [192, 108], "samples": 1, "denoise": False})
        r = subprocess.run([sys.executable, "-m", "blendgen.cli", "run", str(job)], capture_output=True, text=True,
                           timeout=1500)
        assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
        out = tmp_path / engine / "out"
        per_frame = {d.name: json.loads((d / "labels.json").read_text()) for d in sorted((out / "frames").iterdir())}
        coco = json.loads((out / "labels" / "coco.json").read_text())
        labels[engine] = (per_frame, coco["annotations"], (out / "plan.jsonl").read_text())
    assert labels["local"][2] == labels["ray"][2]
    assert labels["local"][0] == labels["ray"][0]
    assert labels["local"][1] == labels["ray"][1] and len(labels["local"][1]) > 0
    shutil.rmtree(tmp_path / "ray" / "out" / "frames", ignore_errors=True)
