"""The built-in synthetic recording: a drive along a twin route with a simulated IMU and GNSS.

The trajectory, IMU and GNSS are computed here (bpy-free); the camera frames are rendered
from the twin by `BackgroundRenderer`, a farm processor that runs inside a bpy worker.
The result is an ordinary recording folder (DESIGN.md), with ground truth beside it, so
the pipeline treats it exactly like a real one.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pymap3d
from scipy.interpolate import CubicSpline

from blendgen.geometry import Camera, R_world_cam_from_ypr, invert_pose, make_pose, pose_to_xyz_quat
from blendgen.recording import folder
from blendgen.recording.model import ImuNoise

GRAVITY = 9.80665
# IMU mounted 1.2 m behind and 0.3 m below the camera, axes x forward, y left, z up.
IMU_IN_BODY = np.array([0.0, 0.0, 0.0])
CAM_IN_BODY = np.array([1.2, 0.0, 0.3])


@dataclass
class Trajectory:
    """Body (= IMU) trajectory sampled on a time grid: position, yaw and their derivatives."""

    t: np.ndarray
    p: np.ndarray  # (N,3) world position of the IMU
    v: np.ndarray  # (N,3)
    a: np.ndarray  # (N,3)
    yaw: np.ndarray  # (N,)
    yaw_rate: np.ndarray  # (N,)

    def R_world_body(self, k: int) -> np.ndarray:
        c, s = np.cos(self.yaw[k]), np.sin(self.yaw[k])
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def T_imu_cam() -> np.ndarray:
    """Camera pose in the IMU frame (IMU = body axes: x forward, y left, z up)."""
    R_body_cam = R_world_cam_from_ypr(0.0)
    return make_pose(R_body_cam, CAM_IN_BODY - IMU_IN_BODY)


def drive_along(route_xy: np.ndarray, duration_s: float, speed_mps: float, rate_hz: float,
                imu_height_m: float, seed: int) -> Trajectory:
    """A smooth drive along a polyline: speed varies gently (+-15%) so that the IMU sees
    acceleration and visual scale is observable; heading follows the path tangent."""
    route_xy = np.asarray(route_xy, dtype=float)
    seg = np.linalg.norm(np.diff(route_xy, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-6])
    route_xy = route_xy[keep]
    s_knots = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(route_xy, axis=0), axis=1))])
    path = CubicSpline(s_knots, route_xy, bc_type="natural")

    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * np.pi)
    n = int(round(duration_s * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    w = 2 * np.pi / max(duration_s, 1.0) * 0.8
    # s(t) = v0 t + A/w (cos(phase) - cos(w t + phase))  =>  speed = v0 (1 + 0.15 sin(w t + phase))
    amp = 0.15 * speed_mps
    s = speed_mps * t + amp / w * (np.cos(phase) - np.cos(w * t + phase))
    sd = speed_mps + amp * np.sin(w * t + phase)
    sdd = amp * w * np.cos(w * t + phase)
    if s[-1] > s_knots[-1]:
        raise ValueError(f"route is {s_knots[-1]:.1f} m long but the drive needs {s[-1]:.1f} m")
    xy, dxy, ddxy = path(s), path(s, 1), path(s, 2)
    # Velocity/acceleration by the chain rule; dxy is a unit tangent (arc-length spline, ~).
    v_xy = dxy * sd[:, None]
    a_xy = ddxy * (sd ** 2)[:, None] + dxy * sdd[:, None]
    yaw = np.unwrap(np.arctan2(dxy[:, 1], dxy[:, 0]))
    # yaw rate = d(yaw)/ds * ds/dt, with curvature from the spline derivatives.
    curv = (dxy[:, 0] * ddxy[:, 1] - dxy[:, 1] * ddxy[:, 0]) / np.maximum(np.sum(dxy ** 2, axis=1), 1e-9) ** 1.5
    yaw_rate = curv * sd
    z = np.full(n, imu_height_m)
    p = np.column_stack([xy, z])
    v = np.column_stack([v_xy, np.zeros(n)])
    a = np.column_stack([a_xy, np.zeros(n)])
    return Trajectory(t, p, v, a, yaw, yaw_rate)


def simulate_imu(traj: Trajectory, noise: ImuNoise, seed: int) -> np.ndarray:
    """IMU samples (t, wx, wy, wz, ax, ay, az) in the IMU frame with white noise and
    random-walk biases of the given continuous-time densities."""
    rng = np.random.default_rng(seed)
    n = len(traj.t)
    dt = float(np.median(np.diff(traj.t)))
    out = np.empty((n, 7))
    out[:, 0] = traj.t
    bg = rng.normal(0, 5e-4, 3)  # turn-on biases
    ba = rng.normal(0, 2e-2, 3)
    sg, sa = noise.gyroscope_noise_density / np.sqrt(dt), noise.accelerometer_noise_density / np.sqrt(dt)
    rg, ra = noise.gyroscope_random_walk * np.sqrt(dt), noise.accelerometer_random_walk * np.sqrt(dt)
    g = np.array([0.0, 0.0, GRAVITY])
    for k in range(n):
        R = traj.R_world_body(k)
        omega_b = np.array([0.0, 0.0, traj.yaw_rate[k]])  # flat road: rotation about body z only
        f_b = R.T @ (traj.a[k] + g)  # specific force
        out[k, 1:4] = omega_b + bg + rng.normal(0, sg, 3)
        out[k, 4:7] = f_b + ba + rng.normal(0, sa, 3)
        bg += rng.normal(0, rg, 3)
        ba += rng.normal(0, ra, 3)
    return out


def simulate_gnss(traj: Trajectory, rate_hz: float, noise_m: float, georef, seed: int) -> np.ndarray:
    """GNSS fixes (t, lat, lon, alt, heading_deg, h_std_m) with white metre-level noise plus a
    slowly wandering error (as real receivers show)."""
    rng = np.random.default_rng(seed)
    step = max(1, int(round((1.0 / rate_hz) / np.median(np.diff(traj.t)))))
    idx = np.arange(0, len(traj.t), step)
    n = len(idx)
    walk = np.cumsum(rng.normal(0, 0.05 * noise_m, (n, 3)), axis=0)
    walk -= walk.mean(axis=0)
    err = rng.normal(0, noise_m, (n, 3)) * [1, 1, 2] * 0.7 + walk * [1, 1, 2] * 0.3
    e, nn, u = (traj.p[idx] + err).T
    speed = np.linalg.norm(traj.v[idx, :2], axis=1)
    if getattr(georef, "proj", None):  # a projected twin (a UTM map): pyproj, true north
        lat, lon, alt = georef.to_geodetic(e, nn, u)
        heading = georef.heading_of_yaw(e, nn, np.arctan2(traj.v[idx, 1], traj.v[idx, 0]))
    else:
        lat, lon, alt = pymap3d.enu2geodetic(e, nn, u, *georef)
        heading = np.degrees(np.arctan2(traj.v[idx, 0], traj.v[idx, 1])) % 360.0  # compass, from ENU velocity
    heading = np.where(speed > 1.0, heading + rng.normal(0, 1.0, n), np.nan)
    return np.column_stack([traj.t[idx], lat, lon, alt, heading % 360.0, np.full(n, noise_m)])


def camera_poses(traj: Trajectory, frame_times: np.ndarray) -> list[np.ndarray]:
    """Ground-truth T_world_cam at the frame times (interpolated on the dense grid)."""
    T_ic = T_imu_cam()
    poses = []
    for t in frame_times:
        k = int(np.clip(np.searchsorted(traj.t, t), 1, len(traj.t) - 1))
        f = (t - traj.t[k - 1]) / (traj.t[k] - traj.t[k - 1])
        p = (1 - f) * traj.p[k - 1] + f * traj.p[k]
        yaw = (1 - f) * traj.yaw[k - 1] + f * traj.yaw[k]
        c, s = np.cos(yaw), np.sin(yaw)
        T_wi = make_pose(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), p)
        poses.append(T_wi @ T_ic)
    return poses


def clear_sky_lighting(georef, when_utc) -> dict:
    """Sun and sky of a clear day at the twin's place and time, for the synthetic frames
    (the lighting dict of docs/architecture.md)."""
    from blendgen.post.illumination import enu_from_az_el, sun_position

    el, az = sun_position(when_utc, georef[0], georef[1])
    up = el > 0
    return {"sun_direction": enu_from_az_el(az, el).tolist(), "sun_strength": 4.0 if up else 0.0,
            "sun_color": [1.0, 0.93, 0.84], "sun_angle_deg": 0.53, "sky_color": [0.55, 0.7, 1.0],
            "sky_strength": 1.0 if up else 0.05, "sun_visible": bool(up)}


def write_sensor_data(root: Path, twin, settings, seed: int) -> np.ndarray:
    """Write calib.yaml, imu.csv, gnss.csv, groundtruth.csv of a synthetic drive through `twin`.

    Returns the frame times; frames.csv is written once the frames exist.
    """
    width, height = settings.resolution
    camera = Camera.from_hfov(width, height, settings.hfov_deg)
    duration = settings.duration_s
    route = twin.ego_route(settings.speed_mps * duration * 1.3 + 10.0, seed)
    imu_height = settings.camera_height_m - CAM_IN_BODY[2]
    traj = drive_along(route, duration, settings.speed_mps, settings.imu_rate_hz, imu_height, seed)
    noise = ImuNoise(update_rate=settings.imu_rate_hz)
    imu = simulate_imu(traj, noise, seed + 1)
    gnss = simulate_gnss(traj, settings.gnss_rate_hz, settings.gnss_noise_m, twin.georef, seed + 2)
    n_frames = int(np.floor(duration * settings.fps + 1e-9)) + 1
    frame_t = np.arange(n_frames) / settings.fps
    poses = camera_poses(traj, frame_t)
    gt = [np.concatenate([[t], *pose_to_xyz_quat(T)]) for t, T in zip(frame_t, poses)]

    root.mkdir(parents=True, exist_ok=True)
    extra = {"time_origin_utc": settings.start_time_utc,
             "synthetic": {"twin": str(getattr(twin, "path", "")), "seed": seed}}
    if not getattr(twin, "relief", False):
        # the rig's camera height above the road (sync's road-height constraint); not on a map
        # with relief, where this drive still keeps the camera at a constant height
        extra["vehicle"] = {"camera_height_m": float(settings.camera_height_m)}
    folder.write_calib(root, camera, invert_pose(T_imu_cam()), noise, 0.0, extra=extra)
    folder.write_imu(root, imu)
    folder.write_gnss(root, gnss, ["t", "lat", "lon", "alt", "heading_deg", "h_std_m"])
    folder.write_groundtruth(root, gt)
    return frame_t


class BackgroundRenderer:
    """Farm processor (runs in a bpy worker): renders the twin as the recording's frames."""

    def __init__(self, recording_dir: str, twin_path: str, render: dict, samples: int, lighting: dict):
        from blendgen.job.schema import Render
        from blendgen.recording.folder import read_recording

        self.root = Path(recording_dir)
        rec = read_recording(self.root)
        self.poses = {rec.frame_id(i): row for i, row in enumerate(rec.groundtruth)}
        self.camera = rec.camera
        self.twin_path = Path(twin_path)
        self.render = Render(**render)
        self.samples = samples
        self.lighting = lighting
        self.session = None

    def path(self, item: str) -> Path:
        return self.root / "frames" / f"{item}.png"

    def is_done(self, item: str) -> bool:
        return self.path(item).exists()

    def process(self, item: str) -> dict:
        import time

        from blendgen.geometry import pose_from_xyz_quat

        t0 = time.perf_counter()
        if self.session is None:
            from blendgen.render.session import RenderSession

            self.session = RenderSession(self.twin_path, None, self.render, self.camera)
        t1 = time.perf_counter()
        row = self.poses[item]
        T = pose_from_xyz_quat(row[1:4], row[4:8])
        info = self.session.render_background(T, self.lighting, self.path(item), self.samples)
        t2 = time.perf_counter()
        return {"stage": "record", "frame_id": item,
                "timings": {"session": round(t1 - t0, 3), "render_background": round(t2 - t1, 3)},
                "render": info}

    def close(self):
        if self.session is not None:
            self.session.close()
