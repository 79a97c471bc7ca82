"""A ground-plane job on real dashcam photos through the whole pipeline: the analysis stage
runs before planning, its decisions reach the manifest, the hood hides objects, labels
list the real boxes they cover, and a second run redoes nothing."""

from __future__ import annotations

import json
import math

import cv2
import pytest
import yaml

from blendgen.plan import SCENERY_ID

from real_data import BDD, cli

pytestmark = [pytest.mark.bpy, pytest.mark.data]


def test_dashcam_photos_job_analyses_plans_and_resumes(tmp_path):
    if not BDD.is_dir():
        pytest.skip(f"needs {BDD}")
    r = cli("import", "images", str(BDD), str(tmp_path / "rec"), "--hfov", "60", "--no-progress")
    assert r.returncode == 0, r.stderr[-2000:]
    job = tmp_path / "job.yaml"
    job.write_text(yaml.safe_dump({
        "name": "bdd", "seed": 2, "recording": "rec", "ground_plane": "auto",
        "inject": {"objects_per_frame": [3, 3], "classes": {"car": 1, "person": 1, "traffic light": 1},
                   "distance_m": [6, 30], "sequences": False, "min_projected_px": 8},
        "render": {"resolution": [320, 180], "samples": 2, "denoise": False},
        "export": {"formats": ["coco"], "min_visible_px": 4}, "output": "out"}))
    r = cli("run", str(job))
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "[3/7] analysis" in r.stdout and "WARNING: class 'traffic light'" not in r.stdout
    out = tmp_path / "out"
    ids = sorted(p.stem for p in (out / "analysis").glob("f*.json"))
    assert ids == ["f000000", "f000001", "f000002"]
    for fid in ids:
        fa = json.loads((out / "analysis" / f"{fid}.json").read_text())
        assert fa["hood"] and fa["real_objects"] and fa["road_mask"]
    manifest = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines() if x]
    frames = [m for m in manifest if m.get("stage") == "frames"]
    assert len(frames) == 3 and all(m["analysis"]["decisions"] and "plan_decisions" in m for m in frames)
    labels = [json.loads((out / "frames" / f / "labels.json").read_text()) for f in ids]
    inst = [i for lab in labels for i in lab["instances"]]
    assert inst and all("covers_real" in i for i in inst)
    # traffic lights stand on poles of their own beside the road: the pole is drawn, never labelled
    plans = [json.loads(x) for x in (out / "plan.jsonl").read_text().splitlines() if x]
    assert any(o["cls"] == "traffic light" and o["variant"]["pole"] for p in plans for o in p["objects"])
    for fid in ids:
        assert cv2.imread(str(out / "frames" / fid / "instances.png"), cv2.IMREAD_UNCHANGED).max() < SCENERY_ID
    # the day street (f000000) has a double yellow centre line: cars beyond it come towards
    # the camera, the others go with it
    fa0 = json.loads((out / "analysis" / "f000000.json").read_text())
    assert fa0["centre_line_m"] is not None and 1.0 < fa0["centre_line_m"] < 3.5, fa0["decisions"]
    cars = [(o, fa0["T_world_cam"][1][3]) for p in plans if p["frame_id"] == "f000000"
            for o in p["objects"] if o["cls"] == "car"]
    for o, cam_y in cars:
        assert (math.cos(o["yaw"]) < -0.99) == (o["position"][1] - cam_y > fa0["centre_line_m"]), o

    r2 = cli("run", str(job))
    assert r2.returncode == 0, r2.stderr[-2000:]
    skipped = json.loads((out / "run_summary.json").read_text())["skipped_stages"]
    assert {"analysis", "plan", "frames"} <= set(skipped)
