"""Frame conventions (DESIGN.md) and the synthetic recording's sensor simulation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from blendgen import atomic
from blendgen.geometry import (CV_TO_BLENDER, Camera, R_world_cam_from_ypr, invert_pose, make_pose,
                               matrix_to_quat, quat_to_matrix, yaw_of_camera)
from blendgen.recording.model import ImuNoise
from blendgen.pipeline.synthetic import (GRAVITY, T_imu_cam, camera_poses, drive_along, simulate_gnss,
                                          simulate_imu)


def test_quaternion_round_trip_and_sign():
    rng = np.random.default_rng(0)
    for _ in range(100):
        R = Rotation.random(random_state=rng).as_matrix()
        q = matrix_to_quat(R)
        assert q[0] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
        np.testing.assert_allclose(quat_to_matrix(q), R, atol=1e-12)


def test_camera_axes_for_heading():
    R = R_world_cam_from_ypr(np.pi / 2)  # heading north
    np.testing.assert_allclose(R[:, 2], [0, 1, 0], atol=1e-12)  # optical axis north
    np.testing.assert_allclose(R[:, 0], [1, 0, 0], atol=1e-12)  # image right = east
    np.testing.assert_allclose(R[:, 1], [0, 0, -1], atol=1e-12)  # image down = world down
    assert abs(yaw_of_camera(R) - np.pi / 2) < 1e-12
    up = R_world_cam_from_ypr(0.0, pitch=0.1)
    assert up[2, 2] > 0  # positive pitch looks up
    # Blender camera looks down its -z: after the conversion -z_blender is the optical axis
    np.testing.assert_allclose(-(R @ CV_TO_BLENDER)[:, 2], R[:, 2])


def test_projection_of_a_point_ahead():
    cam = Camera.from_hfov(1280, 720, 90.0)
    T = make_pose(R_world_cam_from_ypr(0.0), [0, 0, 1.5])
    uv, front = cam.project_world(T, [[20.0, 0.0, 1.5], [20.0, -20.0, 1.5], [-5, 0, 1.5]])
    np.testing.assert_allclose(uv[0], [cam.cx, cam.cy], atol=1e-9)
    np.testing.assert_allclose(uv[1], [cam.cx + cam.fx, cam.cy], atol=1e-9)  # 45 deg right = fx pixels
    assert front.tolist() == [True, True, False]
    np.testing.assert_allclose(invert_pose(invert_pose(T)), T, atol=1e-12)


def test_scaled_camera_keeps_rays():
    cam = Camera(640, 480, 500, 510, 320.5, 239.5)
    half = cam.scaled(320, 240)
    X = np.array([[0.3, -0.2, 4.0]])
    uv_full, _ = cam.project(X)
    uv_half, _ = half.project(X)
    np.testing.assert_allclose((uv_full + 0.5) / 2 - 0.5, uv_half, atol=1e-9)


@pytest.mark.parametrize("cam", [Camera(640, 480, 500, 510, 320.5, 239.5, [-0.2, 0.05, 0.001, -0.0005, 0.0]),
                                 Camera(854, 480, 463, 462, 427.1, 239.7, [0.335, 0.128, 0.078, 0.022], "equidistant"),
                                 Camera(854, 480, 390, 390, 428.0, 242.6, [0.043, 0.036, -0.034, 0.012],
                                        "equidistant")], ids=["radtan", "fisheye linear", "fisheye wide"])
def test_lens_projection_and_normalized_are_inverse(cam, tmp_path):
    """Camera.normalized undoes Camera.project to 1e-6 over the whole frame (a 120 deg fisheye
    too), keeps its model when scaled, and the calib.yaml round trip keeps the lens."""
    from blendgen.recording import folder

    us, vs = np.meshgrid(np.linspace(0, cam.width - 1, 23), np.linspace(0, cam.height - 1, 13))
    px = np.column_stack([us.ravel(), vs.ravel()])
    n = cam.normalized(px, iterations=40)
    uv, front = cam.project(np.column_stack([n, np.ones(len(n))]))
    assert front.all() and np.abs(uv - px).max() < 1e-6
    np.testing.assert_allclose(cam.normalized(px, iterations=40, P=cam.K), n * [cam.fx, cam.fy] + [cam.cx, cam.cy],
                               atol=1e-6)
    half = cam.scaled(cam.width // 2, cam.height // 2)
    assert half.distortion_model == cam.distortion_model and half.distorted
    folder.write_calib(tmp_path, cam, np.eye(4))
    assert folder._read_calib(tmp_path).camera == cam


def test_fisheye_is_not_a_pinhole_without_coefficients():
    cam = Camera(640, 480, 300, 300, 319.5, 239.5, [0.0] * 4, "equidistant")
    assert cam.distorted  # r = f theta
    uv, _ = cam.project([[1.0, 0.0, 1.0]])  # 45 deg right
    assert uv[0, 0] == pytest.approx(319.5 + 300 * np.pi / 4)
    assert cam.hfov_deg == pytest.approx(np.degrees(640 / 300))
    assert Camera.from_hfov(640, 480, 70.0).hfov_deg == pytest.approx(70.0)


def test_atomic_write_leaves_no_partial_file(tmp_path):
    target = tmp_path / "a" / "out.json"
    with pytest.raises(RuntimeError):
        with atomic.atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("crash mid-write")
    assert not target.exists() and list(target.parent.iterdir()) == []
    atomic.write_json(target, {"x": np.float32(1.5)})
    assert target.read_text().strip() == '{"x": 1.5}'


def _route():
    s = np.linspace(0, 120, 200)
    return np.column_stack([s, 15 * np.sin(s / 40)])  # a gentle S-curve


def test_noise_free_imu_integrates_back_to_the_trajectory():
    traj = drive_along(_route(), 6.0, 8.0, 200.0, 1.2, seed=3)
    zero = ImuNoise(1e-12, 1e-12, 1e-12, 1e-12, 200.0)
    imu = simulate_imu(traj, zero, seed=1)
    # turn-on biases are part of the simulation; remove them from the noise-free check
    imu[:, 1:4] -= imu[0, 1:4] - [0, 0, traj.yaw_rate[0]]
    R0 = traj.R_world_body(0)
    imu[:, 4:7] -= imu[0, 4:7] - R0.T @ (traj.a[0] + [0, 0, GRAVITY])
    # strapdown integration (yaw only: flat road)
    dt = np.diff(traj.t)
    yaw = traj.yaw[0] + np.concatenate([[0], np.cumsum(0.5 * (imu[1:, 3] + imu[:-1, 3]) * dt)])
    assert np.max(np.abs(yaw - traj.yaw)) < 1e-3
    p, v = traj.p[0].copy(), traj.v[0].copy()
    for k in range(len(dt)):
        c, s = np.cos(yaw[k]), np.sin(yaw[k])
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        a = R @ imu[k, 4:7] - [0, 0, GRAVITY]
        p = p + v * dt[k] + 0.5 * a * dt[k] ** 2
        v = v + a * dt[k]
    assert np.linalg.norm(p - traj.p[-1]) < 0.25  # metres after 6 s / ~48 m of dead reckoning
    speed = np.linalg.norm(traj.v[:, :2], axis=1)
    assert 6.5 < speed.min() and speed.max() < 9.5


def test_gnss_noise_level_and_camera_height():
    traj = drive_along(_route(), 6.0, 8.0, 200.0, 1.2, seed=3)
    georef = (48.137, 11.575, 520.0)
    gnss = simulate_gnss(traj, 10.0, 1.0, georef, seed=2)
    assert len(gnss) == 61 and np.all(np.isfinite(gnss[:, :4]))
    import pymap3d

    e, n, u = pymap3d.geodetic2enu(gnss[:, 1], gnss[:, 2], gnss[:, 3], *georef)
    err = np.hypot(e - traj.p[::20, 0], n - traj.p[::20, 1])
    assert 0.3 < np.sqrt(np.mean(err ** 2)) < 2.5
    poses = camera_poses(traj, np.array([0.0, 1.0]))
    assert abs(poses[0][2, 3] - (1.2 + T_imu_cam()[2, 3])) < 1e-9
    # camera looks along the direction of travel
    heading = np.array([np.cos(traj.yaw[0]), np.sin(traj.yaw[0]), 0])
    assert poses[0][:3, 2] @ heading > 0.999
