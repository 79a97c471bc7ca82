"""The vehicle's odometer (speed.csv, CAN wheel speed): reading, calib.yaml priors, the EKF
update, and scale + latency recovered on a synthetic drive."""

import copy

import numpy as np
import pytest

from blendgen import so3
from blendgen.errors import UserError
from blendgen.job.schema import Sync
from blendgen.recording import folder
from blendgen.recording.folder import read_recording
from blendgen.recording.model import Recording
from blendgen.sync.calibration import describe, read_priors
from blendgen.sync.ekf import N, EkfConfig, ErrorStateEkf
from blendgen.sync.odometer import initial_scale, means
from blendgen.sync.pipeline import run_sync
from blendgen.sync.simulate import GEOREF, synthetic_recording


def test_means_bin_the_readings_and_the_imu():
    t = np.arange(100) * 0.01 + 0.0005
    t[0] = 0.0  # the bins start at the first reading; the others clear of their edges
    speed = np.column_stack([t, np.linspace(5.0, 6.0, 100)])
    imu = np.column_stack([np.arange(0.0, 1.0, 0.005), np.zeros((200, 3)),
                           np.tile([0.5, 0.0, 9.8], (200, 1))])
    imu[100:, 4] = 1.5  # the car accelerates harder from 0.5 s (the sixth bin)
    m = means(speed, imu)
    assert m.shape == (10, 5)
    np.testing.assert_allclose(m[:, :2], [speed[10 * k:10 * k + 10].mean(axis=0) for k in range(10)])
    np.testing.assert_allclose(m[:5, 2], 0.5, atol=1e-9)
    np.testing.assert_allclose(m[5:, 2], 1.5, atol=1e-9)
    assert means(np.zeros((0, 2)), imu).shape == (0, 5)


def test_initial_scale_from_the_first_pass_speed():
    t = np.arange(0.0, 30.0, 0.1)
    v = 8.0 + np.sin(t)
    odo = np.column_stack([t + 0.05, v / 1.03, np.zeros((len(t), 3))])
    track = np.column_stack([t, v])
    assert initial_scale(odo, track) == pytest.approx(1.03, abs=0.003)
    assert initial_scale(odo, track[:10]) == 1.0  # too few moving poses: the prior
    assert initial_scale(odo, None) == 1.0
    track[:, 1] = 0.5  # standing / creeping: no scale from it
    assert initial_scale(odo, track) == 1.0


def _ekf() -> ErrorStateEkf:
    ekf = ErrorStateEkf(EkfConfig(), 0.0, [1.0, 2.0, 0.5], [7.0, 3.0, 0.4], so3.exp(np.array([0.02, -0.03, 0.6])),
                        np.full(15, 0.1))
    ekf.enable_calibration(so3.exp(np.array([0.01, 0.06, -0.02])), 0.05, 0.0, 0.0, np.zeros(3), 0.0,
                           speed_scale_std=0.02, speed_latency=-0.04, speed_latency_std=0.2)
    ekf.speed_scale = 1.01
    ekf.ba = np.array([0.05, -0.02, 0.03])
    return ekf


def test_speed_update_jacobian_matches_finite_differences():
    """H of `update_vehicle_speed` against the residual's change when each error state moves."""
    f_b = np.array([0.8, 0.1, 9.7])
    reading = 7.4
    captured = {}

    def residual(ekf):
        e = copy.deepcopy(ekf)
        e._update = lambda kind, r, H, Rm, gate=True: captured.update(r=r, H=H) or True
        e.update_vehicle_speed(reading, 0.1, f_b)
        return captured["r"].copy(), captured["H"].copy()

    base = _ekf()
    r0, H = residual(base)
    eps = 1e-6
    for k in range(24):  # core states (the clone is not involved)
        dx = np.zeros(N)
        dx[k] = eps
        e = copy.deepcopy(base)
        e._inject(dx)
        r1, _ = residual(e)
        # r = -(h(x) - z): a move dx changes r by -H dx
        num = -(r1 - r0) / eps
        assert num[0] == pytest.approx(H[0, k], abs=1e-4 + 1e-4 * abs(H[0, k])), k


def test_speed_csv_is_read_and_checked(tmp_path):
    root = tmp_path / "r"
    root.mkdir()
    folder.write_calib(root, None)
    ti = np.arange(0, 2, 0.01)
    folder.write_imu(root, np.column_stack([ti, np.zeros((len(ti), 3)), np.tile([0, 0, 9.81], (len(ti), 1))]))
    folder.write_speed(root, np.column_stack([ti, np.full(len(ti), 8.0)]))
    rec = read_recording(root)
    assert rec.speed.shape == (200, 2) and rec.issues == []
    lines = (root / "speed.csv").read_text().splitlines()
    lines[5] = lines[5].split(",")[0] + ",nan"
    (root / "speed.csv").write_text("\n".join(lines) + "\n")
    rec = read_recording(root)
    assert len(rec.speed) == 199 and any("speed.csv: dropped 1 row(s) with NaN speed values (rows 6)" in i
                                         for i in rec.issues)
    lines[5] = lines[5].split(",")[0] + ",28.8"
    lines[7] = lines[7].split(",")[0] + ",180.0"  # km/h written as m/s
    (root / "speed.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(UserError, match=r"speed.csv.*row 8: speed 180.0 m/s is outside \[0, 150\]"):
        read_recording(root)
    lines[7] = lines[7].split(",")[0] + ",-1.0"
    (root / "speed.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(UserError, match=r"row 8: speed -1.0 m/s is outside"):
        read_recording(root)


def test_calib_yaml_odometer_priors():
    rec = Recording(root=None, camera=None)
    pri = read_priors(rec)
    assert pri.speed_latency_auto and pri.speed_std_mps == 0.1 and pri.speed_scale_std == 0.02
    rec.extra["vehicle"] = {"speed_latency_s": 0.05, "speed_std_mps": 0.04, "speed_scale_std": 0.0}
    pri = read_priors(rec)
    assert not pri.speed_latency_auto and pri.speed_latency_s == 0.05 and pri.speed_std_mps == 0.04
    for bad, msg in [({"speed_latency_s": "late"}, "expected seconds or 'auto'"),
                     ({"speed_latency_s": 3.0}, r"expected seconds in \[-2, 2\]"),
                     ({"speed_std_mps": 0.0}, "speed_std_mps / speed_scale_std"),
                     ({"speed_scale_std": 0.9}, "speed_std_mps / speed_scale_std")]:
        rec.extra["vehicle"] = bad
        with pytest.raises(UserError, match=msg):
            read_priors(rec)


def _sync(odometer, tmp_path, **vehicle):
    rec, traj, T_cam_imu = synthetic_recording("drive", 40.0, frames=False, seed=1, odometer=odometer)
    if vehicle:
        rec.extra["vehicle"] = vehicle
    res = run_sync(rec, Sync(use_speed=True), tmp_path, georef=GEOREF, progress=False)
    T_bc = np.linalg.inv(T_cam_imu)
    err = [Twc[:2, 3] - (traj.pose(t) @ T_bc)[:2, 3] for _, t, Twc in res.poses]
    return res, float(np.sqrt(np.mean(np.sum(np.square(err), axis=1))))


def test_odometer_scale_and_latency_are_recovered(tmp_path):
    """A CAN speed reading 2 % low and 60 ms early: the filter finds both, and the horizontal
    error is not worse than without it (40 s drive, IMU + GNSS)."""
    res, err = _sync({"scale": 0.98, "latency_s": -0.06}, tmp_path / "a")
    cal = res.summary["calibration"]
    assert cal["speed_scale"] == pytest.approx(1 / 0.98, abs=0.002)
    assert abs(cal["speed_latency_s"] + 0.06) < max(2.5 * cal["speed_latency_std_s"], 0.01)
    assert cal["speed_latency_std_s"] < 0.05
    assert res.summary["sensors"]["speed"] and res.summary["updates"]["speed"] > 350
    assert f"odometer scale {cal['speed_scale']:.4f} +- " in describe(cal)
    _, err_without = _sync(None, tmp_path / "b")
    assert err <= err_without
    # its latency as given in calib.yaml: held there
    res, _ = _sync({"scale": 0.98, "latency_s": -0.06}, tmp_path / "c", speed_latency_s=-0.06)
    assert res.summary["calibration"]["speed_latency_s"] == -0.06
    assert res.summary["calibration"]["speed_latency_std_s"] == 0.0
    assert "latency -60 ms as given" in describe(res.summary["calibration"])


def test_command_uses_the_odometer_by_default(tmp_path, capsys):
    from blendgen.cli import main

    rec, _, _ = synthetic_recording("drive", 20.0, frames=False, seed=0, odometer={"scale": 0.98})
    root = tmp_path / "rec"
    root.mkdir()
    folder.write_calib(root, None)
    folder.write_imu(root, rec.imu)
    folder.write_gnss(root, rec.gnss)
    folder.write_speed(root, rec.speed)
    assert main(["sync", str(root), "--out", str(tmp_path / "a"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "odometer 209 used / 0 rejected" in out and "odometer scale 1.02" in out
    assert main(["sync", str(root), "--out", str(tmp_path / "b"), "--quiet", "--no-speed"]) == 0  # left out, said
    out = capsys.readouterr().out
    assert "odometer scale" not in out and "speed.csv is not used (sync.use_speed: false / --no-speed)" in out
    # without GNSS there is no vehicle frame to put the speed in: said, not silently dropped
    assert main(["sync", str(root), "--out", str(tmp_path / "c"), "--quiet", "--no-gnss"]) == 0
    assert "speed.csv is not used: the odometer needs the IMU and GNSS" in capsys.readouterr().out


def test_stop_and_go_with_the_odometer(tmp_path):
    """Stop-and-go (0 -> 8 m/s in 2 s, 15 s standing, twice): with the odometer the track is not
    worse than without. Before the final pass was iterated from its own smoothed start it was:
    1.1 m off at the start (the filter split pitch and accelerometer bias against the speed)."""
    errs = {}
    for key, odo in (("without", None), ("with", {"scale": 0.98, "latency_s": -0.05})):
        rec, traj, T_cam_imu = synthetic_recording("stop_and_go", 50.0, frames=False, seed=0, odometer=odo)
        res = run_sync(rec, Sync(use_speed=True), tmp_path / key, georef=GEOREF, progress=False)
        T_bc = np.linalg.inv(T_cam_imu)
        errs[key] = np.linalg.norm([Twc[:2, 3] - (traj.pose(t) @ T_bc)[:2, 3] for _, t, Twc in res.poses], axis=1)
    assert errs["with"].max() < 0.3 and np.sqrt(np.mean(errs["with"] ** 2)) <= np.sqrt(np.mean(errs["without"] ** 2))
