"""`blendgen import images`: a folder of stills becomes a frames-only recording."""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest

from blendgen.errors import UserError
from blendgen.recording.folder import read_frame, read_recording
from blendgen.recording.importers import import_recording


def _stills(folder, sizes):
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i, (w, h) in enumerate(sizes):
        cv2.imwrite(str(folder / f"img_{i}.png"), rng.integers(0, 255, (h, w, 3), dtype=np.uint8))
    return folder


def test_images_round_trip(tmp_path):
    src = _stills(tmp_path / "src", [(64, 48)] * 3)
    dst = import_recording("images", src, tmp_path / "rec", hfov_deg=60.0, show_progress=False)
    rec = read_recording(dst)
    assert rec.n_frames == 3 and list(rec.frames_t) == [0.0, 1.0, 2.0]
    assert (rec.camera.width, rec.camera.height) == (64, 48)
    np.testing.assert_allclose(rec.camera.fx, 32 / np.tan(np.radians(30)))
    np.testing.assert_array_equal(read_frame(rec, 2), cv2.imread(str(src / "img_2.png")))


def test_images_errors_name_the_file(tmp_path):
    src = _stills(tmp_path / "mixed", [(64, 48), (32, 24)])
    with pytest.raises(UserError, match="img_1.png.*32x24"):
        import_recording("images", src, tmp_path / "rec", show_progress=False)
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "broken.jpg").write_bytes(b"\xff\xd8 not a jpeg")
    with pytest.raises(UserError, match="broken.jpg: does not decode"):
        import_recording("images", bad, tmp_path / "rec2", show_progress=False)
    r = subprocess.run([sys.executable, "-m", "blendgen.cli", "import", "images", str(tmp_path / "none"),
                        str(tmp_path / "rec3")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "image folder not found" in r.stderr and "Traceback" not in r.stderr
