"""comma2k19 importer: the real example segment, and truncated arrays."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from blendgen.analysis.lane_direction import still_camera_yaw
from blendgen.errors import UserError
from blendgen.geometry import quat_to_matrix
from blendgen.recording.folder import read_recording
from blendgen.recording.importers import check_recording, import_recording

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
SEG = DATA / "real" / "comma2k19_example1_segment40"
pytestmark = pytest.mark.data


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    if not SEG.exists():
        pytest.skip("needs ../shared/data/real/comma2k19_example1_segment40")
    return read_recording(import_recording("comma2k19", SEG, tmp_path_factory.mktemp("c") / "rec",
                                           camera_yaw=still_camera_yaw, show_progress=False))


def test_streams(rec):
    assert rec.n_frames == 0 and rec.camera.width == 1164
    assert len(rec.imu) == 6256 and 95 < 1 / np.median(np.diff(rec.imu[:, 0])) < 110
    assert np.median(np.linalg.norm(rec.imu[:, 4:7], axis=1)) == pytest.approx(9.8, abs=0.3)
    assert len(rec.gnss) == 579 and rec.gnss_columns == ["t", "lat", "lon", "alt", "h_std_m"]
    assert len(rec.groundtruth) == 1200 and np.all(np.isfinite(rec.groundtruth))
    assert rec.utc(rec.imu[0, 0]).isoformat().startswith("2018-08-02")
    # the car's CAN speed as the odometer (speed.csv), about the ground truth's speed
    assert len(rec.speed) == 4974 and 7.9 < rec.speed[:, 1].min() and rec.speed[:, 1].max() < 20.0


def test_camera_yaw_from_the_preview_frame(rec):
    """preview.png's lane markings give the camera's yaw in the car (the ground truth's device
    points 0.72-1.16 deg left of its travel); T_cam_imu is the nominal device frame."""
    v = rec.extra["vehicle"]
    assert 0.5 < v["camera_yaw_deg"] < 1.1 and 0.3 <= v["camera_yaw_std_deg"] < 0.45
    assert v["T_cam_imu_yaw_std_deg"] == 1.0
    assert any("lane markings in preview.png" in n for n in rec.extra["import"]["notes"])


def test_without_preview_the_note_says_why(tmp_path):
    if not SEG.exists():
        pytest.skip("needs ../shared/data/real/comma2k19_example1_segment40")
    seg = tmp_path / "seg"
    shutil.copytree(SEG, seg, ignore=shutil.ignore_patterns("preview.png", "raw_can", "radar"))
    r = read_recording(import_recording("comma2k19", seg, tmp_path / "rec", camera_yaw=still_camera_yaw,
                                        show_progress=False))
    assert "vehicle" not in r.extra
    assert any("preview.png is missing" in n for n in r.extra["import"]["notes"])


def test_groundtruth_frame(rec):
    from pymap3d import geodetic2enu

    gt = rec.groundtruth
    np.testing.assert_allclose(gt[0, 1:4], 0, atol=1e-6)  # ENU about the first pose
    path = np.sum(np.linalg.norm(np.diff(gt[:, 1:4], axis=0), axis=1))
    assert path == pytest.approx(1012, abs=15)  # data README: 1012 m
    # the camera looks along the direction of travel and its y axis points down
    vel = np.gradient(gt[:, 1:4], gt[:, 0], axis=0)
    moving = np.linalg.norm(vel, axis=1) > 3
    z = np.array([quat_to_matrix(q)[:, 2] for q in gt[moving, 4:8]])
    cosang = np.sum(z * vel[moving], axis=1) / np.linalg.norm(vel[moving], axis=1)
    assert np.median(cosang) > 0.99
    y = np.array([quat_to_matrix(q)[:, 1] for q in gt[::50, 4:8]])
    assert np.all(y[:, 2] < -0.95)
    # GNSS agrees with the ground truth horizontally (u-blox, a few metres)
    o = rec.extra["import"]["groundtruth_origin"]
    e, n, _ = geodetic2enu(rec.gnss[:, 1], rec.gnss[:, 2], rec.gnss[:, 3], o["lat"], o["lon"], o["alt"])
    ge, gn = np.interp(rec.gnss[:, 0], gt[:, 0], gt[:, 1]), np.interp(rec.gnss[:, 0], gt[:, 0], gt[:, 2])
    assert np.median(np.hypot(e - ge, n - gn)) < 5.0


def test_check_says_no_frames(rec):
    msgs = [f.message for f in check_recording(rec.root) if f.level == "warn"]
    assert any("no camera frames" in m for m in msgs)


def test_truncated_array(tmp_path):
    if not SEG.exists():
        pytest.skip("needs ../shared/data/real/comma2k19_example1_segment40")
    seg = tmp_path / "seg"
    shutil.copytree(SEG / "global_pose", seg / "global_pose")
    shutil.copytree(SEG / "processed_log" / "IMU" / "gyro", seg / "processed_log" / "IMU" / "gyro")
    shutil.copytree(SEG / "processed_log" / "IMU" / "accelerometer", seg / "processed_log" / "IMU" / "accelerometer")
    shutil.copytree(SEG / "processed_log" / "GNSS" / "live_gnss_ublox", seg / "processed_log" / "GNSS" / "live_gnss_ublox")
    f = seg / "processed_log" / "IMU" / "gyro" / "value"
    f.chmod(0o644)
    data = f.read_bytes()
    f.write_bytes(data[: len(data) // 2])
    with pytest.raises(UserError, match=r"gyro/value: not a readable numpy array"):
        import_recording("comma2k19", seg, tmp_path / "r1", show_progress=False)
    with pytest.raises(UserError, match="not a comma2k19 segment"):
        import_recording("comma2k19", tmp_path, tmp_path / "r2", show_progress=False)
