"""Video importer: container timestamps, CSV aliases/units, no re-encoding, corrupt sources."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from blendgen.cli import main
from blendgen.errors import UserError
from blendgen.recording.folder import iter_frames, read_recording
from blendgen.recording.importers import check_recording, import_recording
from blendgen.recording.importers.mp4 import read_tracks


def make_video(path: Path, n=12, fps=10.0, size=(64, 48), fourcc="mp4v") -> list[np.ndarray]:
    w, h = size
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
    assert vw.isOpened()
    frames = []
    for i in range(n):
        img = np.full((h, w, 3), 30, np.uint8)
        cv2.rectangle(img, (4 + 3 * i, 10), (14 + 3 * i, 30), (0, 200, 255), -1)
        vw.write(img)
        frames.append(img)
    vw.release()
    return frames


def write_csvs(tmp: Path):
    t = np.arange(0, 1.3, 0.01)
    imu = tmp / "imu.csv"
    # other header names and milliseconds: exercised by --time-unit and the aliases
    lines = ["timestamp,gyro_x,gyro_y,gyro_z,acc_x,acc_y,acc_z"]
    lines += [f"{ti * 1000:.3f},0.01,0.02,-0.01,0.1,9.8,0.2" for ti in t]
    imu.write_text("\n".join(lines) + "\n")
    gnss = tmp / "gnss.csv"
    tg = np.arange(0, 1.3, 0.2)
    gnss.write_text("time,latitude,longitude,altitude,accuracy\n" +
                    "".join(f"{ti * 1000:.1f},48.1,11.5{k},520.0,1.5\n" for k, ti in enumerate(tg)))
    return imu, gnss


def test_mp4_video_with_csvs(tmp_path):
    src = tmp_path / "clip.mp4"
    make_video(src)
    imu, gnss = write_csvs(tmp_path)
    dst = import_recording("video", src, tmp_path / "rec", imu_csv=imu, gnss_csv=gnss, time_unit="ms",
                           hfov_deg=60, time_offset=0.05, show_progress=False)
    rec = read_recording(dst, require_frames=True)
    assert rec.n_frames == 12 and rec.video == "video.mp4"
    np.testing.assert_allclose(rec.frames_t, 0.05 + np.arange(12) / 10.0, atol=1e-6)
    assert (dst / "video.mp4").read_bytes() == src.read_bytes()  # copied, not re-encoded
    assert rec.imu.shape == (130, 7) and abs(rec.imu[1, 0] - 0.01) < 1e-9
    assert rec.gnss_columns == ["t", "lat", "lon", "alt", "h_std_m"]
    np.testing.assert_allclose(rec.camera.fx, 0.5 * 64 / np.tan(np.radians(30)))
    frames = list(iter_frames(rec))
    assert len(frames) == 12 and frames[-1][1].shape == (48, 64, 3)
    text = "\n".join(str(f) for f in check_recording(dst))
    assert "camera intrinsics are not calibrated" in text and "camera-IMU extrinsics" in text


def test_avi_uses_opencv_timestamps(tmp_path):
    src = tmp_path / "clip.avi"
    make_video(src, n=8, fps=20.0, fourcc="MJPG")
    dst = import_recording("video", src, tmp_path / "rec", show_progress=False)
    rec = read_recording(dst)
    np.testing.assert_allclose(rec.frames_t, np.arange(8) / 20.0, atol=1e-3)
    assert rec.extra["import"]["camera_calibration"].startswith("assumed")


def test_mp4_sample_table_matches_opencv(tmp_path):
    src = tmp_path / "clip.mp4"
    make_video(src, n=15, fps=25.0)
    (video,) = [t for t in read_tracks(src) if t.handler == "vide"]
    assert video.n_samples == 15
    cap = cv2.VideoCapture(str(src))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 15
    np.testing.assert_allclose(np.sort(video.presentation_times()), np.arange(15) / 25.0, atol=1e-6)


def test_truncated_and_garbage_video(tmp_path):
    src = tmp_path / "clip.mp4"
    make_video(src, n=30)
    data = src.read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(UserError, match="cut.mp4"):
        import_recording("video", cut, tmp_path / "r1", show_progress=False)
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"\x00\x01garbage" * 100)
    with pytest.raises(UserError, match="junk.mp4"):
        import_recording("video", junk, tmp_path / "r2", show_progress=False)


def test_bad_csv_and_nonempty_destination(tmp_path):
    src = tmp_path / "clip.mp4"
    make_video(src)
    bad = tmp_path / "imu.csv"
    bad.write_text("t,wx,wy,wz,ax,ay\n0,0,0,0,0,0\n")
    with pytest.raises(UserError, match=r"imu.csv.*missing column\(s\) \['az'\]"):
        import_recording("video", src, tmp_path / "r", imu_csv=bad, show_progress=False)
    bad.write_text("t,wx,wy,wz,ax,ay,az\n0,0,0,0,0,0,9.8\n0.01,0,0,x,0,0,9.8\n")
    with pytest.raises(UserError, match="row 3: column 'wz' is 'x'"):
        import_recording("video", src, tmp_path / "r", imu_csv=bad, show_progress=False)
    full = tmp_path / "full"
    full.mkdir()
    (full / "x").write_text("keep")
    with pytest.raises(UserError, match="not empty"):
        import_recording("video", src, full, show_progress=False)


def test_cli_import_and_check(tmp_path, capsys):
    src = tmp_path / "clip.mp4"
    make_video(src)
    imu, gnss = write_csvs(tmp_path)
    rc = main(["import", "video", str(src), str(tmp_path / "rec"), "--imu", str(imu), "--gnss", str(gnss),
               "--time-unit", "ms", "--no-progress"])
    out = capsys.readouterr().out
    assert rc == 0 and "frames: 12 samples, 10.0 Hz" in out and "IMU: 130 samples" in out
    assert main(["import", "--check", str(tmp_path / "rec")]) == 0
    assert main(["import", "video", str(tmp_path / "nope.mp4"), str(tmp_path / "r2")]) == 2
    assert "nope.mp4: video file not found" in capsys.readouterr().err
    assert main(["import", "--check", str(tmp_path / "missing")]) == 2
