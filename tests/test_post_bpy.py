"""Post stage on a real Cycles render (tiny): passes from the EXR composite into a frame."""

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from blendgen.job.schema import Post
from blendgen.post.composite import composite_frame
from blendgen.post.illumination import enu_from_az_el, estimate_illumination

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.bpy

SUNNY = {"sun_direction": list(enu_from_az_el(200.0, 35.0)), "sun_strength": 4.0, "sun_color": [1.0, 0.95, 0.9],
         "sun_angle_deg": 0.53, "sky_color": [0.6, 0.75, 1.0], "sky_strength": 0.4, "sun_visible": True}


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    pytest.importorskip("bpy")
    work = tmp_path_factory.mktemp("post_bpy")
    spec = {"resolution": [128, 72], "samples": 4, "denoise": False, "hfov_deg": 60, "pitch_deg": 4,
            "objects": [{"cls": "car", "colour": [0.5, 0.05, 0.05], "position": [0.5, 9.0, 0.0], "yaw_deg": 80,
                         "id": 7}],
            "renders": [{"mode": "background", "out": str(work / "bg.png"), "lighting": SUNNY},
                        {"mode": "object", "out": str(work / "obj.exr"), "lighting": SUNNY}]}
    (work / "spec.json").write_text(json.dumps(spec))
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": os.environ.get("HOME", "/tmp")}
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "post" / "_post_scene.py"), str(work / "spec.json")],
                       env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    return work


def test_render_passes_composite_with_shadow(renders):
    from blendgen.render.exr import read_passes

    bg = cv2.imread(str(renders / "bg.png"))
    passes = read_passes(renders / "obj.exr")
    for key in ("rgba", "index", "shadow_catcher", "diffuse_direct", "diffuse_indirect", "diffuse_color"):
        assert key in passes, key
    obj = passes["index"] == 7
    assert obj.sum() > 50
    est = estimate_illumination(bg, sun_az_el=(200.0, 35.0))
    out, info = composite_frame(bg, passes, settings=Post(), illumination=est, seed=0)
    assert out.shape == bg.shape and out.dtype == np.uint8
    assert info["relight"]["relight"] == "applied"
    # a red car appears where the index says; a shadow darkens road pixels that are not object
    assert out[obj][:, 2].mean() > out[obj][:, 1].mean() + 20
    assert info["shadows"] and info["shadow_px"] > 20
    near = cv2.dilate(obj.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    changed = (np.abs(out.astype(int) - bg.astype(int)).sum(2) > 6) & ~near
    assert changed.sum() > 10  # the shadow, outside the (label) object mask
