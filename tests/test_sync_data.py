"""Sync on real data (../shared/data): comma2k19 IMU + GNSS vs ground truth, udacity video VO,
the GoPro Karma clip against its sea horizon."""

from pathlib import Path

import numpy as np
import pytest

from blendgen.job.schema import Sync
from blendgen.recording.folder import read_recording
from blendgen.sync.metrics import comma_errors, recording_horizon_errors
from blendgen.sync.pipeline import run_sync

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
COMMA = DATA / "real" / "comma2k19_example1_segment40"
UDACITY = DATA / "real" / "udacity_solidWhiteRight.mp4"
KARMA = DATA / "real" / "gopro_karma.mp4"
pytestmark = pytest.mark.data


def test_comma2k19_imu_gnss_beats_raw_gnss(tmp_path):
    if not COMMA.exists():
        pytest.skip("needs ../shared/data/real/comma2k19_example1_segment40")
    from blendgen.analysis.lane_direction import still_camera_yaw
    from blendgen.recording.importers.comma2k19 import groundtruth_georef, import_comma2k19

    rec = read_recording(import_comma2k19(COMMA, tmp_path / "rec", camera_yaw=still_camera_yaw, show_progress=False))
    assert rec.n_frames == 0
    georef = groundtruth_georef(rec)
    res = run_sync(rec, Sync(), tmp_path / "out", georef=georef, progress=False)
    err = comma_errors(res, rec, georef)
    s, g = err["sync"], err["raw_gnss"]
    print(err)
    # the raw receiver, measured the same way (issue 3: 0.28 m, 0.13 m, 0.9 deg)
    assert g["h_rmse_m"] == pytest.approx(0.28, abs=0.02)
    assert g["rel_1s_median_m"] == pytest.approx(0.13, abs=0.02)
    assert g["heading_median_deg"] == pytest.approx(0.9, abs=0.1)
    # the filter beats it on all three and meets the targets
    assert s["h_rmse_m"] < g["h_rmse_m"]
    assert s["rel_1s_median_m"] < g["rel_1s_median_m"] and s["rel_1s_median_m"] <= 0.10
    assert s["heading_median_deg"] <= 1.0
    # issue 14: the camera's pitch was 5.2 deg off (accelerometer bias taken for pitch); with the
    # vehicle-frame constraints, the estimated mount and the bias prior enforced it is ~0.3 deg
    assert s["pitch_median_deg"] <= 0.4
    cal = res.summary["calibration"]
    assert 3.0 < cal["camera_mount_rpy_deg"][1] < 4.5 and cal["mount_std_deg"][1] < 0.5  # truth ~3.8
    # The importer asks for the GNSS latency (profile likelihood) and the fixes' noise from their
    # innovations. The ground truth puts the latency at 0.06-0.08 s (evaluation only); found
    # 0.068 +- 0.014 s and x0.084 of the stated 2.1 m: offset-removed, 1 s and pitch targets met
    # (0.180 m, 0.024 m, 0.20 deg), raw 0.50 m (1.47 with the latency ignored).
    assert rec.extra["gnss"] == {"latency_s": "auto", "h_std_scale": "auto"}
    assert 0.04 < cal["gnss_latency_s"] < 0.11 and 0 < cal["gnss_latency_std_s"] < 0.05
    assert 0.05 < cal["gnss_h_std_scale"] < 0.2
    assert s["h_rmse_m"] <= 0.2 and s["rel_1s_median_m"] <= 0.03 and s["pitch_median_deg"] <= 0.3
    assert s["h_rmse_raw_m"] < 0.6
    # The camera's yaw in the car from the lane markings of the segment's preview frame
    # (+0.77 +- 0.31 deg; the IMU mount and the nominal T_cam_imu said -0.07): the full 3-D
    # camera rotation error 1.02 -> 0.42 deg (target 0.5)
    assert 0.5 < rec.extra["vehicle"]["camera_yaw_deg"] < 1.1
    assert 0.5 < cal["camera_yaw"]["yaw_deg"] < 1.1 and s["rot3d_median_deg"] <= 0.5
    assert np.all(np.isfinite(res.cov))


def test_udacity_video_vo_tracks_all_frames(tmp_path):
    if not UDACITY.exists():
        pytest.skip("needs ../shared/data/real/udacity_solidWhiteRight.mp4")
    from blendgen.recording.importers.video import import_video

    rec = read_recording(import_video(UDACITY, tmp_path / "rec", show_progress=False))
    assert rec.n_frames == 221
    res = run_sync(rec, Sync(), tmp_path / "out", progress=False)
    assert len(res.poses) == 221
    status = res.summary["vo_status"]
    assert status.get("first") == 1
    assert sum(status.get(k, 0) for k in ("ok", "rotation")) == 220, status  # no failures
    assert status.get("ok", 0) >= 180  # the rest: too little parallax, rotation only (direction held)
    P = res.positions()
    d = P[-1] - P[0]
    # a highway drive straight ahead: the first camera looks along +x of the VO world
    assert d[0] > 0.98 * np.linalg.norm(d)
    fwd = np.array([T[:3, 2] for _, _, T in res.poses])
    assert np.degrees(np.arccos(np.clip(fwd[:, 0], -1, 1))).max() < 15.0  # no wild heading swings
    steps = np.linalg.norm(np.diff(P, axis=0), axis=1)
    assert np.all(np.isfinite(P)) and steps.max() < 1.0


# the Karma clip's sea: the left third of the frame, the horizon near the middle row
KARMA_SEA = ((10, 240), (150, 330))


def test_gopro_karma_follows_its_fixes_and_the_sea_horizon(tmp_path):
    """The real drone clip: the GoPro importer read the IMU as X right, Y forward (GoPro's frame
    is X left, Y back): the accelerometer then contradicted the fixes, 28 of 47 were rejected,
    the track ended 55 m off them and the camera's horizon was 9.5 deg off the sea's."""
    if not KARMA.exists():
        pytest.skip("needs ../shared/data/real/gopro_karma.mp4")
    from blendgen.recording.importers import import_recording

    rec = read_recording(import_recording("gopro", KARMA, tmp_path / "rec", show_progress=False))
    res = run_sync(rec, Sync(), tmp_path / "out", progress=False)
    assert res.summary["rejected"].get("gnss", 0) == 0 and res.summary["updates"]["gnss"] == 47
    assert "calibration" not in res.summary  # a drone: no road-vehicle constraints or mount
    # the lens is a guessed 94 deg pinhole: VO weighted as for an exact lens pulled the camera to
    # 1.9 deg off the horizon (IMU + GNSS alone 1.2); rotation only, at the assumed-lens floor, and
    # a consumer IMU's bias priors (the importer's): 0.35 deg (truth: the dip, ~0.2)
    assert "lens is the importer's assumption" in res.summary["vo_trust"]["trusted"]
    e = recording_horizon_errors(rec, res.poses, *KARMA_SEA)
    assert len(e) >= 80
    assert abs(np.median(e.mean(axis=1))) < 0.8 and abs(np.median(e[:, 1] - e[:, 0])) < 0.5
