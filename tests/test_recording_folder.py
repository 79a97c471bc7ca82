"""Recording folder reader: every bad input is a clear UserError or a reported, handled gap."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from blendgen.errors import UserError
from blendgen.geometry import Camera
from blendgen.recording import folder
from blendgen.recording.folder import iter_frames, read_frame, read_recording


def _make(root: Path, n_frames=4, imu_rate=200.0, imu_s=1.0, calib=True):
    root.mkdir(parents=True, exist_ok=True)
    cam = Camera.from_hfov(64, 48, 70)
    if calib:
        folder.write_calib(root, cam, np.eye(4))
    t = np.arange(n_frames) * 0.2
    files = []
    rng = np.random.default_rng(0)
    (root / "img").mkdir(exist_ok=True)
    for i in range(n_frames):
        f = f"img/{i}.png"
        cv2.imwrite(str(root / f), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
        files.append(f)
    if n_frames:
        folder.write_frames_csv(root, t, files)
    ti = np.arange(0, imu_s, 1 / imu_rate)
    imu = np.column_stack([ti, np.zeros((len(ti), 3)), np.tile([0, 0, 9.81], (len(ti), 1))])
    folder.write_imu(root, imu)
    tg = np.arange(0, imu_s, 0.1)
    n = len(tg)
    folder.write_gnss(root, np.column_stack([tg, np.full(n, 48.1), np.full(n, 11.5), np.full(n, 500.0)]))
    return root


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


def test_roundtrip(tmp_path):
    rec = read_recording(_make(tmp_path / "r"))
    assert rec.n_frames == 4 and len(rec.imu) == 200 and len(rec.gnss) == 10
    assert rec.issues == []
    assert read_frame(rec, 2).shape == (48, 64, 3)


def test_duplicate_and_nonmonotonic_timestamps(tmp_path):
    root = _make(tmp_path / "r")
    lines = _lines(root / "imu.csv")
    lines[5] = lines[4]
    (root / "imu.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(UserError, match=r"imu.csv.*row 6: duplicate timestamp"):
        read_recording(root)
    lines = _lines(root / "gnss.csv")
    lines[3], lines[4] = lines[4], lines[3]
    (root / "gnss.csv").write_text("\n".join(lines) + "\n")
    root2 = _make(tmp_path / "r2")
    (root2 / "gnss.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(UserError, match=r"gnss.csv.*non-monotonic"):
        read_recording(root2)


def test_imu_gap_is_reported(tmp_path):
    root = _make(tmp_path / "r", imu_s=2.0)
    lines = _lines(root / "imu.csv")
    del lines[101:201]  # 0.5 s without IMU samples
    (root / "imu.csv").write_text("\n".join(lines) + "\n")
    rec = read_recording(root)
    assert any("imu.csv: gap of 0.50" in i for i in rec.issues), rec.issues


def test_nan_rows_dropped_and_reported(tmp_path):
    root = _make(tmp_path / "r")
    lines = _lines(root / "imu.csv")
    parts = lines[10].split(",")
    parts[4] = "nan"
    lines[10] = ",".join(parts)
    (root / "imu.csv").write_text("\n".join(lines) + "\n")
    rec = read_recording(root)
    assert len(rec.imu) == 199 and np.all(np.isfinite(rec.imu))
    assert any("dropped 1 row(s) with NaN IMU values (rows 11)" in i for i in rec.issues)


def test_many_nan_rows_is_an_error(tmp_path):
    root = _make(tmp_path / "r")
    lines = _lines(root / "imu.csv")
    for k in range(1, 40):
        p = lines[k].split(",")
        p[1] = ""
        lines[k] = ",".join(p)
    (root / "imu.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(UserError, match=r"imu.csv.*39 of 200 rows hold NaN"):
        read_recording(root)


def test_nan_time_is_an_error(tmp_path):
    root = _make(tmp_path / "r")
    lines = _lines(root / "gnss.csv")
    lines[2] = "nan" + lines[2][lines[2].index(","):]
    (root / "gnss.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(UserError, match=r"gnss.csv.*row 3: column t"):
        read_recording(root)


def test_frame_that_fails_to_decode(tmp_path):
    root = _make(tmp_path / "r")
    (root / "img" / "2.png").write_bytes(b"not a png")
    rec = read_recording(root)
    with pytest.raises(UserError, match=r"frame 2 \(img/2.png\) does not decode"):
        read_frame(rec, 2)
    got = list(iter_frames(rec, skip_bad=True))
    assert [i for i, im in got if im is None] == [2]
    assert any("frame 2" in i for i in rec.issues)
    with pytest.raises(UserError):
        list(iter_frames(rec))


def test_missing_calibration_fields(tmp_path):
    root = _make(tmp_path / "r")
    (root / "calib.yaml").write_text("camera:\n  resolution: [64, 48]\n")
    with pytest.raises(UserError, match=r"calib.yaml: camera.intrinsics: missing"):
        read_recording(root)
    (root / "calib.yaml").write_text("camera:\n  intrinsics: [50, 50, 31.5, 23.5]\n  resolution: [64, 48]\n")
    rec = read_recording(root)
    assert any("missing T_cam_imu" in i for i in rec.issues)
    assert any("missing imu noise" in i for i in rec.issues)
    (root / "calib.yaml").unlink()
    with pytest.raises(UserError, match="calib.yaml is missing"):
        read_recording(root)
    (root / "calib.yaml").write_text("T_cam_imu: [[1, 0], [0, 1]]\n")
    with pytest.raises(UserError, match="T_cam_imu: expected a 4x4"):
        read_recording(root)


def test_frames_without_camera_section(tmp_path):
    root = _make(tmp_path / "r")
    (root / "calib.yaml").write_text("T_cam_imu: [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]\n")
    with pytest.raises(UserError, match="no `camera:` section"):
        read_recording(root)


def test_imu_and_gnss_only_is_valid(tmp_path):
    root = _make(tmp_path / "r", n_frames=0)
    rec = read_recording(root)
    assert rec.n_frames == 0 and len(rec.imu) and rec.issues == []


def test_bad_frames_fail_alone_with_their_reason(tmp_path):
    """Issue 16: corrupt, zero-byte, wrong-size and missing images: the recording still reads,
    each bad frame raises its own UserError, the good ones decode."""
    root = _make(tmp_path / "r", n_frames=6)
    png = (root / "img/1.png").read_bytes()
    (root / "img/1.png").write_bytes(png[: len(png) // 2])  # truncated
    (root / "img/2.png").write_bytes(b"")
    cv2.imwrite(str(root / "img/3.png"), np.zeros((20, 30, 3), np.uint8))
    (root / "img/4.png").unlink()
    rec = read_recording(root)
    assert any("1 image file(s) missing (rows 6)" in i for i in rec.issues)
    for i, why in ((1, "does not decode"), (2, r"empty \(0 bytes\)"), (3, "is 30x20 but calib.yaml says 64x48"),
                   (4, "image file is missing")):
        with pytest.raises(UserError, match=why):
            read_frame(rec, i)
    assert read_frame(rec, 0).shape == read_frame(rec, 5).shape == (48, 64, 3)
    assert [i for i, img in iter_frames(rec, skip_bad=True) if img is not None] == [0, 5]


@pytest.mark.parametrize("entry", ["../../../../etc/hostname", "/etc/passwd", "link/x.png", "img/../../r2/x.png"])
def test_frame_paths_stay_inside_the_recording(tmp_path, entry):
    root = _make(tmp_path / "r", n_frames=2)
    (tmp_path / "outside").mkdir()
    cv2.imwrite(str(tmp_path / "outside/x.png"), np.zeros((48, 64, 3), np.uint8))
    (root / "link").symlink_to(tmp_path / "outside")
    folder.write_frames_csv(root, [0.0, 0.2], ["img/0.png", entry])
    with pytest.raises(UserError, match=r"frames.csv: row 3: image path .* is not inside the recording folder"):
        read_recording(root)


def test_groundtruth_tum_reads_in_evo(tmp_path):
    """Issue 16: groundtruth.tum beside groundtruth.csv, in the TUM order evo expects."""
    from scipy.spatial.transform import Rotation

    root = _make(tmp_path / "r")
    q = Rotation.from_euler("z", [[0.1], [0.2], [0.3]]).as_quat()  # x y z w
    gt = np.column_stack([[0.0, 0.1, 0.2], np.arange(9).reshape(3, 3), q[:, 3], q[:, :3]])
    folder.write_groundtruth(root, gt)
    assert read_recording(root).groundtruth.shape == (3, 8)
    file_interface = pytest.importorskip("evo.tools.file_interface")
    traj = file_interface.read_tum_trajectory_file(str(root / "groundtruth.tum"))
    assert np.allclose(traj.timestamps, [0.0, 0.1, 0.2])
    assert np.allclose(traj.positions_xyz, np.arange(9).reshape(3, 3))
    assert np.allclose(traj.orientations_quat_wxyz, gt[:, 4:8], atol=1e-8)
