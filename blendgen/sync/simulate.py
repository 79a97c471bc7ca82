"""Synthetic drives with exact ground truth, for tests and benchmarks (no Blender).

A trajectory is a smooth body pose T_world_body(t) (body: x forward, y left, z up). From it:
IMU samples (specific force and angular rate by differentiating the pose, plus white noise and
a constant bias), GNSS fixes (noise, optional dropout), and camera images ray-cast through a
textured street: a ground plane and two building facades at y = +-W, with mip-mapped
procedural textures so that far surfaces do not alias into fake features.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
import pymap3d
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation

from blendgen.geometry import Camera, invert_pose, make_pose, pose_to_xyz_quat
from blendgen.recording.model import ImuNoise, Recording
from blendgen.sync import so3

GRAVITY = np.array([0.0, 0.0, -9.80665])
GEOREF = (48.137, 11.575, 520.0)


def default_T_cam_imu(pitch_deg: float = -3.0, yaw_deg: float = 1.5, lever=(1.2, 0.1, 0.3)) -> np.ndarray:
    """Camera looking forward from a body (FLU) frame, slightly pitched down and yawed."""
    R_body_cam = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    tilt = Rotation.from_euler("ZY", [np.radians(yaw_deg), np.radians(-pitch_deg)]).as_matrix()
    T_body_cam = make_pose(tilt @ R_body_cam, lever)
    return invert_pose(T_body_cam)


@dataclass
class Trajectory:
    """Body pose from dense samples: cubic splines for position and unwrapped Euler angles."""

    t: np.ndarray
    xyz: np.ndarray
    ypr: np.ndarray  # yaw, pitch, roll (rad), ZYX intrinsic, pitch positive nose-down in FLU

    def __post_init__(self):
        self._p = CubicSpline(self.t, self.xyz, axis=0)
        self._a = CubicSpline(self.t, np.unwrap(self.ypr, axis=0), axis=0)

    def R(self, t) -> np.ndarray:
        e = np.atleast_2d(self._a(np.atleast_1d(t)))
        return Rotation.from_euler("ZYX", e).as_matrix()

    def pose(self, t: float) -> np.ndarray:
        return make_pose(self.R(t)[0], self._p(t))

    def position(self, t):
        return self._p(t)

    def velocity(self, t):
        return self._p(t, 1)

    def imu(self, t: np.ndarray, h: float = 1e-3):
        """Exact (noise-free) specific force and angular rate in the body frame at times t."""
        R = self.R(t)
        acc_w = self._p(t, 2)
        f = np.einsum("nji,nj->ni", R, acc_w - GRAVITY)
        Rm, Rp = self.R(t - h), self.R(t + h)
        w = np.array([so3.log(a.T @ b) for a, b in zip(Rm, Rp)]) / (2 * h)
        return w, f


def make_trajectory(kind: str = "drive", duration: float = 60.0, speed: float = 8.0,
                    rate: float = 100.0) -> Trajectory:
    """Named test trajectories: drive (gentle S-curves), straight, turns, stop_and_go,
    rotate_in_place, pitch90 (pitch sweeps through +-90 deg), yaw_wrap (crosses +-180 deg)."""
    t = np.arange(0.0, duration + 1e-9, 1.0 / rate)
    n = len(t)
    yaw = np.zeros(n)
    pitch = np.zeros(n)
    roll = np.zeros(n)
    v = np.full(n, speed)
    if kind == "straight":
        pass
    elif kind in ("drive", "turns"):
        amp = 0.12 if kind == "drive" else 0.35
        yaw = amp * np.sin(2 * np.pi * t / 20.0) + 0.5 * amp * np.sin(2 * np.pi * t / 7.3 + 1.0)
        v = speed * (1 + 0.15 * np.sin(2 * np.pi * t / 17.0))
        roll = 0.01 * np.sin(2 * np.pi * t / 3.1)
        pitch = 0.01 * np.sin(2 * np.pi * t / 4.3)
    elif kind == "stop_and_go":
        # 10 s driving, 15 s standstill, repeated; smooth accelerations
        phase = (t % 25.0)
        v = speed * np.clip(np.minimum(phase / 2.0, (10.0 - phase) / 2.0), 0, 1)
        v[phase >= 10.0] = 0.0
        v = np.convolve(v, np.ones(25) / 25, mode="same")
        v[:13] = v[13]
    elif kind == "rotate_in_place":
        v[:] = 0.0
        yaw = 0.6 * t  # ~34 deg/s
    elif kind == "pitch90":
        v[:] = 0.0
        pitch = (np.pi / 2) * np.sin(2 * np.pi * t / 8.0)  # reaches +-90 deg
    elif kind == "yaw_wrap":
        yaw = np.pi - 0.3 + 0.15 * t  # starts at 163 deg, turns through 180
    else:
        raise ValueError(f"unknown trajectory kind {kind!r}")
    head = np.stack([np.cos(yaw), np.sin(yaw)], axis=1) * v[:, None]
    xy = np.vstack([np.zeros(2), np.cumsum(0.5 * (head[1:] + head[:-1]) / rate, axis=0)])
    xyz = np.column_stack([xy, np.full(n, 1.2)])
    return Trajectory(t, xyz, np.column_stack([yaw, pitch, roll]))


# ---------------------------------------------------------------------- sensors

def simulate_imu(traj: Trajectory, rate: float = 200.0, noise: ImuNoise | None = None, seed: int = 0,
                 bias_g=(0.002, -0.003, 0.001), bias_a=(0.05, -0.03, 0.04)) -> np.ndarray:
    noise = noise or ImuNoise()
    rng = np.random.default_rng(seed)
    t = np.arange(traj.t[0] + 0.01, traj.t[-1] - 0.01, 1.0 / rate)
    w, f = traj.imu(t)
    sq = np.sqrt(rate)
    w = w + np.asarray(bias_g) + rng.normal(0, noise.gyroscope_noise_density * sq, w.shape)
    f = f + np.asarray(bias_a) + rng.normal(0, noise.accelerometer_noise_density * sq, f.shape)
    return np.column_stack([t, w, f])


def simulate_gnss(traj: Trajectory, rate: float = 10.0, std_m: float = 1.0, seed: int = 1,
                  georef=GEOREF, dropout: tuple[float, float] | None = None, lever=None) -> np.ndarray:
    """t, lat, lon, alt of the body origin (+ lever arm) with white horizontal noise std_m."""
    rng = np.random.default_rng(seed)
    t = np.arange(traj.t[0] + 0.05, traj.t[-1] - 0.05, 1.0 / rate)
    p = traj.position(t)
    if lever is not None:
        p = p + np.einsum("nij,j->ni", traj.R(t), lever)
    p = p + rng.normal(0, 1, p.shape) * np.array([std_m, std_m, 1.5 * std_m])
    if dropout is not None:
        keep = (t < dropout[0]) | (t >= dropout[1])
        t, p = t[keep], p[keep]
    lat, lon, alt = pymap3d.enu2geodetic(p[:, 0], p[:, 1], p[:, 2], *georef)
    return np.column_stack([t, lat, lon, alt])


# ---------------------------------------------------------------------- images

def _periodic_blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur on a torus (the textures tile seamlessly)."""
    fy = np.fft.fftfreq(img.shape[0])[:, None]
    fx = np.fft.rfftfreq(img.shape[1])[None, :]
    g = np.exp(-2 * (np.pi * sigma) ** 2 * (fx**2 + fy**2))
    return np.fft.irfft2(np.fft.rfft2(img) * g, s=img.shape).astype(np.float32)


def _texture(size: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = np.zeros((size, size), np.float32)
    # blobs with sharp edges at 10-60 cm (cracks, patches, stains) over smooth shading
    for sigma, w in ((3.0, 0.8), (8.0, 1.0), (20.0, 0.8)):
        n = _periodic_blur(rng.normal(0, 1, (size, size)), sigma)
        img += w * np.tanh(3 * n / (n.std() + 1e-6))
    n = _periodic_blur(rng.normal(0, 1, (size, size)), 60.0)
    img += 0.5 * n / (n.std() + 1e-6)
    img = (img - img.mean()) / img.std()
    return np.clip(128 + 45 * img, 0, 255).astype(np.float32)


def _pyramid(tex: np.ndarray, levels: int) -> list[np.ndarray]:
    out = [tex]
    for _ in range(levels - 1):
        out.append(_periodic_blur(out[-1], 1.0)[::2, ::2].copy() if out[-1].shape[0] > 8 else out[-1])
    return out


@dataclass
class StreetScene:
    """Ground plane z=0 and facades at y=+-half_width (height `wall_h`), textured, tiled."""

    half_width: float = 12.0
    wall_h: float = 25.0
    tile_m: float = 20.0
    tex_px: int = 1024
    seed: int = 3
    levels: int = 8
    _tex: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        self._tex["ground"] = _pyramid(_texture(self.tex_px, self.seed), self.levels)
        self._tex["wall"] = _pyramid(0.6 * _texture(self.tex_px, self.seed + 1) + 60, self.levels)

    def render(self, camera: Camera, T_world_cam: np.ndarray, noise_std: float = 2.0,
               rng: np.random.Generator | None = None) -> np.ndarray:
        """Grey uint8 image (H, W) seen by a pinhole camera (distortion ignored)."""
        H, W = camera.height, camera.width
        u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        dc = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], -1)
        R, c = T_world_cam[:3, :3], T_world_cam[:3, 3]
        d = dc @ R.T
        inf = np.inf
        with np.errstate(divide="ignore", invalid="ignore"):
            tg = np.where(d[..., 2] < -1e-9, -c[2] / d[..., 2], inf)
            wall_y = np.where(d[..., 1] > 0, self.half_width, -self.half_width)
            tw = np.where(np.abs(d[..., 1]) > 1e-9, (wall_y - c[1]) / d[..., 1], inf)
        tw = np.where(tw > 0, tw, inf)
        zw = c[2] + tw * d[..., 2]
        tw = np.where((zw >= 0) & (zw <= self.wall_h), tw, inf)
        use_g = tg <= tw
        tt = np.where(use_g, tg, tw)
        hit = np.isfinite(tt)
        tt = np.where(hit, tt, 0.0)
        P = c + tt[..., None] * d
        # texture coordinates and per-pixel footprint (texels per pixel) for mip-mapping
        scale = self.tex_px / self.tile_m
        su = P[..., 0] * scale  # x runs along the street on the ground and on both facades
        sv = np.where(use_g, P[..., 1], P[..., 2]) * scale
        normal_comp = np.where(use_g, np.abs(d[..., 2]), np.abs(d[..., 1])) / np.linalg.norm(d, axis=-1)
        foot = tt * np.linalg.norm(d, axis=-1) / camera.fx / np.sqrt(np.maximum(normal_comp, 0.02)) * scale
        lvl = np.clip(np.log2(np.maximum(foot, 1.0)), 0, self.levels - 1.001)
        out = np.full((H, W), 200.0, np.float32)  # sky
        for name, sel in (("ground", use_g & hit), ("wall", ~use_g & hit)):
            if not sel.any():
                continue
            pyr = self._tex[name]
            acc = np.zeros((H, W), np.float32)
            l0 = np.floor(lvl).astype(int)
            fr = (lvl - l0).astype(np.float32)
            for L in range(int(l0[sel].min()), int(l0[sel].max()) + 2):
                wgt = np.where(l0 == L, 1 - fr, 0) + np.where(l0 == L - 1, fr, 0)
                m = sel & (wgt > 0)
                if not m.any() or L >= len(pyr):
                    continue
                s = 0.5 ** L
                img = cv2.remap(pyr[L], (su * s).astype(np.float32), (sv * s).astype(np.float32),
                                cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
                acc += np.where(m, wgt * img, 0)
            out = np.where(sel, acc, out)
        if noise_std > 0:
            rng = rng or np.random.default_rng(0)
            out = out + rng.normal(0, noise_std, out.shape).astype(np.float32)
        return np.clip(out, 0, 255).astype(np.uint8)


def synthetic_recording(kind: str = "drive", duration: float = 20.0, *, fps: float = 5.0,
                        resolution=(480, 270), hfov_deg: float = 70.0, speed: float = 8.0,
                        imu: bool = True, gnss: bool = True, gnss_std: float = 1.0, frames: bool = True,
                        dropout=None, imu_gap=None, dark_frames=None, seed: int = 0,
                        scene: StreetScene | None = None, imu_mount_rpy_deg=(0.0, 0.0, 0.0),
                        shake_deg: float = 0.0, stabilise_s: float | None = None, margin: float = 0.12):
    """An in-memory Recording (images kept in `rec.extra['images']`) and its ground truth.

    imu_mount_rpy_deg: the IMU rotated (roll, pitch, yaw; about the vehicle's x, y, z) in the
    vehicle; the camera stays where it is, so T_cam_imu includes that rotation.
    shake_deg: camera shake (rough road, a hand): the body's roll, pitch and yaw get sums of
    1-6 Hz sinusoids of about this amplitude; the IMU feels it.
    stabilise_s: simulated electronic stabiliser. Each frame is rendered `margin` larger on
    every side and warped by the homography K C K^-1 of the stabiliser's correction C (the
    rotation from the true camera to one that follows the body orientation low-passed with a
    Gaussian of this std in seconds), then cropped: the image rotates with the smoothed body,
    not the body. `rec.extra['image_groundtruth']` holds T_world_cam of the image (the true
    position, the smoothed orientation) and `rec.extra['stabiliser_correction']` the C per frame.
    Returns (rec, traj, T_cam_imu). `rec.groundtruth` holds T_world_cam per frame (the body's camera).
    """
    traj = make_trajectory(kind, duration + 1.0, speed=speed)
    traj_smooth = None
    if shake_deg > 0:
        rng_s = np.random.default_rng(seed + 11)
        shake = np.zeros_like(traj.ypr)
        for axis, k in ((0, 0.6), (1, 1.0), (2, 0.8)):  # yaw, pitch, roll
            for hz in (1.1, 2.3, 3.7, 5.9):
                shake[:, axis] += k * np.sin(2 * np.pi * (hz * (1 + 0.1 * rng_s.normal())) * traj.t
                                             + rng_s.uniform(0, 2 * np.pi)) / 2.0
        traj = Trajectory(traj.t, traj.xyz, traj.ypr + np.radians(shake_deg) * shake)
    if stabilise_s is not None:
        from scipy.ndimage import gaussian_filter1d

        dt = float(traj.t[1] - traj.t[0])
        ypr_s = gaussian_filter1d(np.unwrap(traj.ypr, axis=0), stabilise_s / dt, axis=0, mode="nearest")
        traj_smooth = Trajectory(traj.t, traj.xyz, ypr_s)
    R_body_imu = Rotation.from_euler("xyz", np.radians(imu_mount_rpy_deg)).as_matrix()
    T_cam_imu = default_T_cam_imu() @ make_pose(R_body_imu, np.zeros(3))
    T_imu_cam = invert_pose(T_cam_imu)
    cam = Camera.from_hfov(resolution[0], resolution[1], hfov_deg)
    rec = Recording(root=None, camera=cam if frames else None, T_cam_imu=T_cam_imu)
    if imu:
        data = simulate_imu(traj, seed=seed)
        data[:, 1:4] = data[:, 1:4] @ R_body_imu  # body -> IMU axes (R^T x, row-wise)
        data[:, 4:7] = data[:, 4:7] @ R_body_imu
        if imu_gap is not None:
            data = data[(data[:, 0] < imu_gap[0]) | (data[:, 0] >= imu_gap[1])]
        rec.imu = data
    if gnss:
        rec.gnss = simulate_gnss(traj, std_m=gnss_std, seed=seed + 1, dropout=dropout)
    t0 = 0.5
    ft = np.arange(t0, t0 + duration, 1.0 / fps) if frames else np.zeros(0)
    rec.frames_t = ft
    gt = []
    images = []
    scene = scene or (StreetScene() if frames else None)
    rng = np.random.default_rng(seed + 7)
    T_body_cam = make_pose(R_body_imu, np.zeros(3)) @ T_imu_cam
    img_gt, corrections = [], []
    if traj_smooth is not None and frames:
        mx, my = int(round(margin * cam.width)), int(round(margin * cam.height))
        cam_big = Camera(cam.width + 2 * mx, cam.height + 2 * my, cam.fx, cam.fy, cam.cx + mx, cam.cy + my)
    for i, t in enumerate(ft):
        T_wc = traj.pose(t) @ T_body_cam
        gt.append(T_wc)
        if traj_smooth is not None:
            T_img = traj_smooth.pose(t) @ T_body_cam
            T_img[:3, 3] = T_wc[:3, 3]
            C = T_wc[:3, :3].T @ T_img[:3, :3]  # the image's camera in the true camera
            img_gt.append(T_img)
            corrections.append(C)
        if frames and traj_smooth is not None:
            big = scene.render(cam_big, T_wc, rng=rng)
            # output pixel -> ray in the image camera -> C -> ray in the true camera -> big pixel
            M = cam_big.K @ C @ np.linalg.inv(cam.K)
            img = cv2.warpPerspective(big, M, (cam.width, cam.height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                      borderMode=cv2.BORDER_REPLICATE)
        elif frames:
            img = scene.render(cam, T_wc, rng=rng)
        if frames:
            if dark_frames is not None and dark_frames[0] <= i < dark_frames[1]:
                img = np.clip(rng.normal(3, 1.5, img.shape), 0, 255).astype(np.uint8)  # lens cap
            images.append(img)
    rows = []
    for t, T in zip(ft, gt):
        xyz, q = pose_to_xyz_quat(T)
        rows.append([t, *xyz, *q])
    rec.groundtruth = np.array(rows).reshape(-1, 8)
    rec.extra["images"] = images
    rec.extra["georef"] = GEOREF
    if traj_smooth is not None:
        rec.extra["image_groundtruth"] = img_gt
        rec.extra["stabiliser_correction"] = np.array(corrections)
    return rec, traj, T_cam_imu
