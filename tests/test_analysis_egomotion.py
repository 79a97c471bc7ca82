"""Ego motion over the ground plane (blendgen.analysis.egomotion) on a synthetic drive."""

import math

import cv2
import numpy as np
import pytest

from blendgen.analysis.egomotion import ground_plane_poses, ground_track
from blendgen.frame_analysis import CameraEstimate
from blendgen.geometry import Camera, R_world_cam_from_ypr, invert_pose, make_pose
from blendgen.recording import folder

CAM = Camera.from_hfov(640, 360, 70)
RES = 0.04                       # texture metres per pixel
X0, Y0 = -10.0, -30.0            # texture origin in the world


def texture(seed=0):
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.normal(0, 1, (1500, 3500)).astype(np.float32), (0, 0), 1.5)
    tex = np.clip(100 + 25 * tex / tex.std(), 0, 255).astype(np.uint8)
    for y in (-1.75, 1.75):     # dashed lane lines, 3 m long every 9 m
        r = int((y - Y0) / RES)
        for x in np.arange(0, 130, 9):
            c = int((x - X0) / RES)
            tex[r - 2:r + 3, c:c + int(3 / RES)] = 230
    return tex


def render_ground(T_world_cam, tex):
    """The textured ground plane z = 0 seen by CAM at T; far texture above it."""
    v, u = np.mgrid[0:CAM.height, 0:CAM.width].astype(np.float64)
    rays = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones_like(u)], -1) @ T_world_cam[:3, :3].T
    t = -T_world_cam[2, 3] / np.where(rays[..., 2] < -1e-6, rays[..., 2], np.nan)
    X = T_world_cam[0, 3] + t * rays[..., 0]
    Y = T_world_cam[1, 3] + t * rays[..., 1]
    mx = ((X - X0) / RES).astype(np.float32)
    my = ((Y - Y0) / RES).astype(np.float32)
    img = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=150)
    # far hills and clouds at infinity: a texture over the rays' azimuth and elevation
    az = np.degrees(np.arctan2(rays[..., 1], rays[..., 0]))
    el = np.degrees(np.arctan2(rays[..., 2], np.hypot(rays[..., 0], rays[..., 1])))
    far = cv2.remap(tex, ((az + 60) * 20).astype(np.float32), ((el + 10) * 20).astype(np.float32) + 200,
                    cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    sky = ~np.isfinite(t) | (t > 150)
    img[sky] = far[sky]
    return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)


def drive(n=12, step=1.0, yaw_rate_deg=0.5, height=1.4, pitch=2.0, roll=-1.0):
    poses, x, y, yaw = [], 0.0, 0.0, 0.0
    for _ in range(n):
        poses.append(make_pose(R_world_cam_from_ypr(yaw, math.radians(pitch), math.radians(roll)), [x, y, height]))
        x += step * math.cos(yaw)
        y += step * math.sin(yaw)
        yaw += math.radians(yaw_rate_deg)
    return poses


def write_drive(root, poses):
    tex = texture()
    root.mkdir(parents=True)
    names = []
    for i, T in enumerate(poses):
        names.append(f"{i:03d}.png")
        cv2.imwrite(str(root / names[-1]), render_ground(T, tex))
    folder.write_frames_csv(root, np.arange(len(poses)) * 0.1, names)   # 10 fps: 10 m/s
    folder.write_calib(root, CAM, None, None)
    return folder.read_recording(root)


def test_parked_object_recedes_as_the_ego_car_passes(tmp_path):
    true = drive()
    rec = write_drive(tmp_path / "drive", true)
    ids = [rec.frame_id(i) for i in range(len(true))]
    cams = {f: CameraEstimate(1.4, 2.0, -1.0, confidence=0.9) for f in ids}
    track = ground_track(rec, ids, cams)
    got = [track.poses[f] for f in ids]
    steps = [track.steps[f] for f in ids[1:]]
    assert all(s.status.startswith("ground") for s in steps), [s.status for s in steps]
    for s in steps:
        assert s.forward == pytest.approx(1.0, rel=0.07) and abs(s.left) < 0.05
        assert math.degrees(s.dyaw) == pytest.approx(0.5, abs=0.6)
    assert math.degrees(sum(s.dyaw for s in steps)) == pytest.approx(0.5 * len(steps), abs=1.0)
    travelled = np.linalg.norm(true[-1][:3, 3] - true[0][:3, 3])
    assert np.linalg.norm(got[-1][:3, 3] - true[-1][:3, 3]) < 0.05 * travelled
    # a parked car's near corner, 25 m ahead and 4 m to the right (14 m at the last frame)
    corner = np.array([[25.0, -4.0, 0.0]])
    uv_true = [CAM.project_world(T, corner)[0][0] for T in (true[0], true[-1])]
    uv_got = [CAM.project_world(T, corner)[0][0] for T in (got[0], got[-1])]
    assert np.linalg.norm(uv_true[1] - uv_true[0]) > 40          # it moves in the image...
    for a, b in zip(uv_true, uv_got):
        assert np.linalg.norm(a - b) < 8, (a, b)                  # ...where the real one would be


def test_stills_keep_a_fixed_pose(tmp_path):
    root = tmp_path / "stills"
    root.mkdir()
    cv2.imwrite(str(root / "a.png"), np.zeros((360, 640, 3), np.uint8))
    cv2.imwrite(str(root / "b.png"), np.zeros((360, 640, 3), np.uint8))
    folder.write_frames_csv(root, [0.0, 1.0], ["a.png", "b.png"])
    folder.write_calib(root, CAM, None, None, extra={"import": {"format": "images"}})
    rec = folder.read_recording(root)
    cams = {"f000000": CameraEstimate(1.2, 3.0, -2.0), "f000001": CameraEstimate(1.6, -1.0, 0.5)}
    poses = ground_plane_poses(rec, list(cams), cams)
    for f, e in cams.items():
        T = poses[f]
        assert T[:3, 3] == pytest.approx([0, 0, e.height_m])
        want = R_world_cam_from_ypr(0.0, math.radians(e.pitch_deg), math.radians(e.roll_deg))
        assert np.allclose(T[:3, :3], want)
    assert np.allclose(invert_pose(poses["f000000"]) @ poses["f000000"], np.eye(4))


def test_ground_plane_twin_has_roll_and_takes_auto_fields():
    from blendgen.job.schema import GroundPlane
    from blendgen.scene.ground_plane import GroundPlaneTwin

    twin = GroundPlaneTwin.from_job(GroundPlane(camera_height_m=1.3, pitch_deg=2.0, roll_deg=-1.5))
    T = twin.camera_pose(4.0)
    assert np.allclose(T[:3, :3], R_world_cam_from_ypr(0.0, math.radians(2.0), math.radians(-1.5)))
    assert T[:3, 3] == pytest.approx([4.0, 0.0, 1.3])
    auto = GroundPlaneTwin.from_job(GroundPlane(camera_height_m="auto", pitch_deg="auto", roll_deg="auto"))
    assert (auto.camera_height_m, auto.pitch_deg, auto.roll_deg) == (1.5, 0.0, 0.0)


def test_heading_follows_the_road_vanishing_point(tmp_path):
    """With the camera's yaw to the road known per frame (vanishing point), the pose keeps the
    twin's straight road on the real one instead of integrating VO's heading drift."""
    true = drive(n=8, yaw_rate_deg=0.8)
    rec = write_drive(tmp_path / "drive", true)
    ids = [rec.frame_id(i) for i in range(len(true))]
    rng = np.random.default_rng(3)
    cams = {f: CameraEstimate(1.4, 2.0, -1.0, yaw_deg=0.8 * i + rng.normal(0, 0.1), confidence=0.8)
            for i, f in enumerate(ids)}
    poses = ground_plane_poses(rec, ids, cams)
    mount = np.median([c.yaw_deg for c in cams.values()])
    for i, f in enumerate(ids):
        fwd = poses[f][:3, 2]
        yaw = math.degrees(math.atan2(fwd[1], fwd[0]))
        assert yaw == pytest.approx(0.8 * i, abs=0.5)           # camera yaw to the road kept
        assert poses[f][0, 3] == pytest.approx(sum(math.cos(math.radians(0.8 * k - mount)) for k in range(i)),
                                               abs=0.1)


def test_gyro_gives_the_heading_change(tmp_path):
    from scipy.spatial.transform import Rotation

    true = drive(n=6, yaw_rate_deg=0.5)                         # 5 deg/s at 10 fps
    rec = write_drive(tmp_path / "drive", true)
    R_cam_imu = Rotation.from_euler("xyz", [-90, 3, -90], degrees=True).as_matrix()
    rec.T_cam_imu = make_pose(R_cam_imu, [0.0, 0.0, 0.0])
    t = np.arange(-0.1, 0.7, 0.005)
    R_world_cam = true[0][:3, :3]
    w_imu = (R_world_cam @ R_cam_imu).T @ [0, 0, math.radians(5.0)]   # yaw rate about world up
    rec.imu = np.c_[t, np.tile(w_imu, (len(t), 1)), np.zeros((len(t), 3))]
    ids = [rec.frame_id(i) for i in range(len(true))]
    track = ground_track(rec, ids, {f: CameraEstimate(1.4, 2.0, -1.0) for f in ids})
    steps = [track.steps[f] for f in ids[1:]]
    assert all(s.status == "ground+imu" for s in steps), [s.status for s in steps]
    for s in steps:
        assert math.degrees(s.dyaw) == pytest.approx(0.5, abs=0.02)
