"""Camera-IMU time offset from VO vs gyro rotations (blendgen.sync.time_offset): a known offset
is recovered, an unobservable one is reported and the calib value kept, calib.yaml options."""

import numpy as np
import pytest

from blendgen import so3
from blendgen.errors import UserError
from blendgen.geometry import Camera, invert_pose
from blendgen.recording import folder
from blendgen.sync.simulate import default_T_cam_imu, make_trajectory, shaken, simulate_imu
from blendgen.sync.time_offset import MAX_STD_S, describe, estimate_time_offset
from blendgen.sync.vo_trust import GyroIntegrator
from blendgen.vo import VoResult


def _pairs(kind="drive", shake_deg=1.0, shift=0.025, fps=10.0, dur=20.0, noise_deg=0.03, outliers=0.0, seed=0):
    """VO pair rotations from the true trajectory (frames exposed at stamp + shift on the IMU
    clock, `noise_deg` per axis, a share of pairs off by 2 deg) and the simulated gyro."""
    traj = make_trajectory(kind, dur + 1.0)
    if shake_deg:
        traj = shaken(traj, shake_deg, seed)
    imu = simulate_imu(traj, seed=seed)  # default noise and a constant gyro bias
    R_bc = invert_pose(default_T_cam_imu())[:3, :3]
    t_cam = np.arange(0.5, 0.5 + dur, 1.0 / fps)
    Rw = traj.R(t_cam + shift)
    rng = np.random.default_rng(seed + 5)
    res = [VoResult("first")]
    for k in range(1, len(t_cam)):
        R = R_bc.T @ Rw[k - 1].T @ Rw[k] @ R_bc
        e = rng.normal(0, np.radians(noise_deg), 3)
        if rng.uniform() < outliers:
            e = e + np.radians(2.0) * rng.normal(0, 1, 3) / np.sqrt(3)
        res.append(VoResult("rotation", R_c1c2=R @ so3.exp(e)))
    return res, GyroIntegrator(imu, 0.05), t_cam, R_bc


@pytest.mark.parametrize("shift", [0.025, 0.0, -0.06])
def test_known_offset_is_recovered(shift):
    res, gyro, t, R_bc = _pairs(shift=shift)
    est = estimate_time_offset(res, gyro, t, R_bc, 0.0)
    assert est.method == "estimated", est.reason
    assert abs(est.shift_s - shift) < 0.002 and est.std_s < 0.001
    # the residual at the calib value (0) shrinks to the VO noise (0.03 deg per axis: 0.05 deg RMS)
    assert est.residual_used_deg < 0.07
    if shift:
        assert est.residual_calib_deg > 3 * est.residual_used_deg


def test_outlier_pairs_and_a_calib_start_are_handled():
    """10 % of the pairs 2 deg off (moving objects, a bad fit): Huber keeps the estimate; the
    search is about the calib value."""
    res, gyro, t, R_bc = _pairs(shift=0.03, outliers=0.1)
    est = estimate_time_offset(res, gyro, t, R_bc, 0.05, search_s=0.05)
    assert est.method == "estimated" and abs(est.shift_s - 0.03) < 0.003
    # a pair the trust check flagged is left out
    flags = [None] * len(res)
    flags[5] = "gyro_gated"
    assert estimate_time_offset(res, gyro, t, R_bc, 0.0, flags=flags).pairs == est.pairs - 1


def test_without_rotation_changes_the_offset_is_unobservable():
    """A straight drive without shake: the gyro's rate never changes, any shift fits: the calib
    value is kept and the reason given."""
    res, gyro, t, R_bc = _pairs(kind="straight", shake_deg=0.0, shift=0.025)
    est = estimate_time_offset(res, gyro, t, R_bc, 0.01)
    assert est.method != "estimated" and est.shift_s == 0.01
    assert est.std_s is None or est.std_s > MAX_STD_S or "end of the search" in est.reason
    assert "rotation" in est.reason or "search" in est.reason
    assert "not estimated" in describe(est.summary())
    # too few pairs, stabilised video
    few = estimate_time_offset(res[:10], gyro, t[:10], R_bc, 0.0)
    assert few.method != "estimated" and "usable VO pairs" in few.reason
    stab = estimate_time_offset(res, gyro, t, R_bc, 0.0, stabilised=True)
    assert stab.method != "estimated" and "stabilised" in stab.reason


def _folder(root, timeshift_lines: str):
    root.mkdir(parents=True, exist_ok=True)
    folder.write_calib(root, Camera.from_hfov(64, 48, 70), np.eye(4))
    txt = (root / "calib.yaml").read_text().replace("timeshift_cam_imu: 0.0\n", timeshift_lines)
    (root / "calib.yaml").write_text(txt)
    ti = np.arange(0, 1.0, 0.005)
    folder.write_imu(root, np.column_stack([ti, np.zeros((len(ti), 3)), np.tile([0, 0, 9.81], (len(ti), 1))]))
    tg = np.arange(0, 1.0, 0.1)
    folder.write_gnss(root, np.column_stack([tg, np.full(len(tg), 48.1), np.full(len(tg), 11.5),
                                             np.full(len(tg), 500.0)]))
    return root


def test_calib_yaml_options_and_bad_values(tmp_path):
    from blendgen.cli import main
    from blendgen.recording.folder import read_recording

    r = read_recording(_folder(tmp_path / "a", "timeshift_cam_imu: auto\n"))
    assert r.time_offset_estimate and r.time_offset_cam_imu == 0.0 and r.time_offset_search_s == 0.1
    r = read_recording(_folder(tmp_path / "b", "timeshift_cam_imu: 0.012\ntimeshift_cam_imu_estimate: true\n"
                                               "timeshift_cam_imu_search_s: 0.05\n"))
    assert r.time_offset_estimate and r.time_offset_cam_imu == 0.012 and r.time_offset_search_s == 0.05
    assert "timeshift_cam_imu_estimate" not in r.extra
    r = read_recording(_folder(tmp_path / "c", "timeshift_cam_imu: -0.004\n"))
    assert not r.time_offset_estimate and r.time_offset_cam_imu == -0.004
    bad = {"often": "timeshift_cam_imu", "true": "timeshift_cam_imu", "20": "timeshift_cam_imu",
           "0.0\ntimeshift_cam_imu_estimate: yes please": "timeshift_cam_imu_estimate",
           "auto\ntimeshift_cam_imu_estimate: false": "contradicts",
           "auto\ntimeshift_cam_imu_search_s: 0": "timeshift_cam_imu_search_s",
           "auto\ntimeshift_cam_imu_search_s: 2.0": "timeshift_cam_imu_search_s"}
    for i, (val, key) in enumerate(bad.items()):
        root = _folder(tmp_path / f"bad{i}", f"timeshift_cam_imu: {val}\n")
        with pytest.raises(UserError, match=key) as e:
            read_recording(root)
        assert "calib.yaml" in str(e.value)
    # through the command: exit code 2, no traceback
    assert main(["sync", str(tmp_path / "bad0"), "--out", str(tmp_path / "out"), "--quiet"]) == 2


def test_describe_says_how_the_offset_was_found():
    res, gyro, t, R_bc = _pairs(shift=0.025)
    s = estimate_time_offset(res, gyro, t, R_bc, 0.0).summary()
    line = describe(s)
    assert "+25.0 +-" in line and "estimated from" in line and "residual" in line
    assert s["profile"] and min(c for _, c in s["profile"]) == 0.0


@pytest.fixture(scope="module")
def offset_drive():
    from blendgen.sync.simulate import synthetic_recording

    return synthetic_recording("drive", 12.0, fps=10.0, resolution=(320, 180), shake_deg=1.0,
                               cam_time_offset_s=0.025)


def test_sync_estimates_the_offset_and_the_rotation_improves(offset_drive, tmp_path):
    """Rendered frames exposed 25 ms after their stamps (on a shaky 12 s drive): sync with
    `timeshift_cam_imu: auto` finds the offset within 3 ms and the camera rotation error drops
    below what the calib value (0) gives."""
    import copy

    from blendgen.job.schema import Sync
    from blendgen.sync.metrics import gt_poses
    from blendgen.sync.pipeline import run_sync

    rec0, _, _ = offset_drive
    ref = gt_poses(rec0.groundtruth)

    def run(estimate, out):
        rec = copy.copy(rec0)
        rec.time_offset_estimate = estimate
        res = run_sync(rec, Sync(), out, georef=rec.extra["georef"], progress=False)
        err = np.degrees([np.linalg.norm(so3.log(g[:3, :3].T @ p[2][:3, :3])) for g, p in zip(ref, res.poses)])
        return res, err

    res, err = run(True, tmp_path / "a")
    _, err0 = run(False, tmp_path / "b")
    s = res.summary["camera_imu_time_offset"]
    assert s["method"] == "estimated" and abs(s["shift_s"] - 0.025) < 0.003, s
    assert s["residual_used_deg"] < 0.5 * s["residual_calib_deg"]
    assert np.median(err) < 0.7 * np.median(err0)


def test_a_real_stabiliser_is_not_taken_for_an_offset(tmp_path):
    """Stabilised frames (1 deg shake smoothed over 0.3 s) with `auto`: whatever shift the
    profile finds, the frames still look stabilised there, so the calib value is kept and the
    stabiliser handled as before."""
    from blendgen.job.schema import Sync
    from blendgen.sync.pipeline import run_sync
    from blendgen.sync.simulate import synthetic_recording

    rec, _, _ = synthetic_recording("drive", 8.0, fps=10.0, resolution=(320, 180), shake_deg=1.0, stabilise_s=0.3)
    rec.time_offset_estimate = True
    res = run_sync(rec, Sync(), tmp_path, georef=rec.extra["georef"], progress=False)
    s = res.summary["camera_imu_time_offset"]
    assert s["method"] != "estimated" and s["shift_s"] == 0.0 and "stabilised" in s["reason"]
    assert res.summary["vo_trust"]["stabiliser_detected"]


def test_inconsistent_parts_of_a_recording_are_not_trusted():
    """Two halves whose frames lag the IMU differently (-70 and +10 ms, what the GoPro clip's
    halves looked like): the curvature alone is confident, the block jackknife is not, and the
    calib value is kept."""
    res_a, gyro, t, R_bc = _pairs(shake_deg=0.3, shift=-0.07, dur=20.0)
    res_b, _, _, _ = _pairs(shake_deg=0.3, shift=0.01, dur=20.0)
    n = len(res_a) // 2
    est = estimate_time_offset(res_a[:n] + res_b[n:], gyro, t, R_bc, 0.0)
    assert est.method != "estimated" and est.shift_s == 0.0
    assert est.std_jackknife_s > MAX_STD_S > est.std_curvature_s
