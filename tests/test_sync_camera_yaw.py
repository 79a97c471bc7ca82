"""calib.yaml `vehicle.camera_yaw_deg`: the camera's yaw in the car measured without the IMU
(lane markings), fused with the one the IMU mount and T_cam_imu give (blendgen.sync.calibration)."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from blendgen import so3
from blendgen.errors import UserError
from blendgen.geometry import invert_pose, make_pose
from blendgen.job.schema import Sync
from blendgen.sync import calibration
from blendgen.sync.pipeline import run_sync
from blendgen.sync.simulate import synthetic_recording

# camera axes in a body frame x forward, y left, z up (camera x right, y down, z forward)
R_BC = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _rec(vehicle: dict):
    return SimpleNamespace(extra={"vehicle": vehicle}, root=Path("rec"))


def test_priors_parse_and_say_what_is_wrong():
    pri = calibration.read_priors(_rec({"camera_yaw_deg": 0.8, "camera_yaw_std_deg": 0.3, "T_cam_imu_yaw_std_deg": 1}))
    assert (pri.camera_yaw_deg, pri.camera_yaw_std_deg, pri.t_cam_imu_yaw_std_deg) == (0.8, 0.3, 1.0)
    assert calibration.read_priors(_rec({})).camera_yaw_deg is None
    for bad, what in [({"camera_yaw_deg": "left"}, "camera_yaw_deg"), ({"camera_yaw_deg": 60}, "[-45, 45]"),
                      ({"camera_yaw_deg": 1, "camera_yaw_std_deg": 0}, "camera_yaw_std_deg"),
                      ({"T_cam_imu_yaw_std_deg": -1}, "T_cam_imu_yaw_std_deg")]:
        with pytest.raises(UserError, match=what) as e:
            calibration.read_priors(_rec(bad))
        assert "calib.yaml vehicle" in str(e.value)


def test_fusion_weights_and_turns_the_camera_about_the_vehicle_up_axis():
    R_bv = Rotation.from_euler("xyz", [2.0, 4.0, 0.5], degrees=True).as_matrix()  # a tilted IMU

    def cal():
        return {"camera_mount_rpy_deg": calibration.camera_mount_angles(R_bv, R_BC).tolist(),
                "mount_std_deg": [0.3, 0.3, 0.3], "imu_to_vehicle_R": R_bv.T.tolist()}

    before = calibration.camera_mount_angles(R_bv, R_BC)
    pri = calibration.CalibPriors(np.zeros(3), camera_yaw_deg=1.0, camera_yaw_std_deg=0.3, t_cam_imu_yaw_std_deg=1.0)
    c = cal()
    C = calibration.fuse_camera_yaw(c, pri, R_BC, with_vo=False)
    # no video: the chain's yaw is as uncertain as T_cam_imu, the measurement decides
    y = before[2] + (0.09 + 1.0) / (0.09 + 1.0 + 0.09) * (1.0 - before[2])
    after = calibration.camera_mount_angles(R_bv, R_BC @ C)
    assert after[2] == pytest.approx(y, abs=1e-6) and c["camera_yaw"]["yaw_deg"] == pytest.approx(y, abs=1e-3)
    assert after[:2] == pytest.approx(before[:2], abs=0.01)  # pitch and roll in the vehicle stay
    assert np.allclose(C.T @ C, np.eye(3)) and c["camera_mount_rpy_deg"][2] == pytest.approx(y, abs=1e-3)
    assert "measured +1.00 +- 0.30" in calibration.describe({**c, "gnss_latency_s": 0.0, "gnss_latency_std_s": 0.0,
                                                            "lever_arm_m": [0, 0, 0], "lever_arm_std_m": [0, 0, 0]})
    # with VO the camera itself was seen: only the mount's uncertainty counts, half way here
    c = cal()
    calibration.fuse_camera_yaw(c, pri, R_BC, with_vo=True)
    assert c["camera_yaw"]["yaw_deg"] == pytest.approx((before[2] + 1.0) / 2, abs=1e-3)
    assert calibration.fuse_camera_yaw(cal(), calibration.CalibPriors(np.zeros(3)), R_BC, with_vo=False) is None


def test_a_camera_turned_in_the_car_follows_its_measured_yaw(tmp_path):
    """IMU + GNSS drive (no video) whose camera looks 1.5 deg further left in the car than
    calib's T_cam_imu says (comma2k19's case: nothing but the camera sees that): the poses
    carry it; with the camera's yaw in the car measured to 0.2 deg they follow the
    true camera."""
    rec, traj, T_cam_imu = synthetic_recording("drive", 30, frames=False, seed=3)
    turn = Rotation.from_rotvec([0.0, np.radians(-1.5), 0.0]).as_matrix()  # about the camera's y (down)
    T_body_cam = invert_pose(T_cam_imu) @ make_pose(turn, np.zeros(3))  # the true camera (IMU = body)
    truth_yaw = calibration.camera_mount_angles(np.eye(3), T_body_cam[:3, :3])[2]
    calib_yaw = calibration.camera_mount_angles(np.eye(3), invert_pose(T_cam_imu)[:3, :3])[2]
    assert truth_yaw == pytest.approx(calib_yaw + 1.5, abs=0.01)

    def yaw_errors(res):
        return np.array([np.degrees(so3.log((traj.pose(t) @ T_body_cam)[:3, :3].T @ T[:3, :3]))[1]
                         for _, t, T in res.poses])

    res = run_sync(rec, Sync(), tmp_path / "a", georef=rec.extra["georef"], progress=False)
    assert np.median(np.abs(yaw_errors(res))) > 1.2  # 2.2: the 1.5 and the mount's own yaw error
    rec.extra["vehicle"] = {"camera_yaw_deg": truth_yaw + 0.1, "camera_yaw_std_deg": 0.2, "T_cam_imu_yaw_std_deg": 2.0}
    res = run_sync(rec, Sync(), tmp_path / "b", georef=rec.extra["georef"], progress=False)
    assert np.median(np.abs(yaw_errors(res))) < 0.3
    cy = res.summary["calibration"]["camera_yaw"]
    assert abs(cy["imu_chain_deg"] - truth_yaw) > 1.0 and abs(cy["yaw_deg"] - truth_yaw) < 0.3
