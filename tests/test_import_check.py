"""`blendgen import --check`: findings on recordings with known defects."""

import numpy as np

from blendgen.geometry import Camera
from blendgen.recording import folder
from blendgen.recording.importers import check_recording


def _levels(root):
    return [(f.level, f.message) for f in check_recording(root)]


def test_missing_and_odd(tmp_path):
    root = tmp_path / "rec"
    root.mkdir()
    folder.write_calib(root, None)
    t = np.arange(0, 10, 0.01)
    imu = np.column_stack([t, np.zeros((len(t), 3)), np.zeros(len(t)), np.zeros(len(t)), np.ones(len(t))])  # in g
    folder.write_imu(root, imu)
    tg = np.concatenate([np.arange(0, 3, 0.1), np.arange(8, 10, 0.1)])  # a 5 s GNSS gap
    lat = 48.0 + 1e-6 * np.arange(len(tg))
    lat[-1] = 48.01  # a 1 km jump in 0.1 s
    folder.write_gnss(root, np.column_stack([tg, lat, np.full(len(tg), 11.0), np.full(len(tg), 500.0)]))
    found = _levels(root)
    text = "\n".join(f"{lv} {m}" for lv, m in found)
    assert "warn no camera frames" in text
    assert "looks like units of g" in text
    assert "GNSS: 1 gap(s), longest 5.10 s after t=2.900" in text
    assert "GNSS: 1 jump(s) faster than 100 m/s" in text
    assert "no ground truth" in text and "h_std_m" in text
    assert not any(lv == "error" for lv, _ in found)


def test_unreadable_and_clock_mismatch(tmp_path):
    assert _levels(tmp_path / "nothing")[0][0] == "error"
    root = tmp_path / "rec"
    root.mkdir()
    (root / "a.png").write_bytes(b"")
    folder.write_calib(root, Camera(64, 48, 50, 50, 31.5, 23.5))
    folder.write_frames_csv(root, [100.0, 100.1], ["a.png", "a.png"])
    t = np.arange(0, 2, 0.01)
    folder.write_imu(root, np.column_stack([t, np.zeros((len(t), 3)), np.tile([0, 0, 9.81], (len(t), 1))]))
    text = "\n".join(f"{lv} {m}" for lv, m in _levels(root))
    assert "streams do not overlap in time" in text
