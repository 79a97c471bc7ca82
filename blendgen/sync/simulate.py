"""Synthetic drives with exact ground truth, for tests and benchmarks (no Blender).

A trajectory is a smooth body pose T_world_body(t) (body: x forward, y left, z up). From it:
IMU samples (specific force and angular rate by differentiating the pose, plus white noise and
a constant bias), GNSS fixes (noise, optional dropout), and camera images ray-cast through a
textured street: a ground plane and two building facades at y = +-W, with mip-mapped
procedural textures so that far surfaces do not alias into fake features.

`hard_recording` is the same drive with sensors that do not match what the filter assumes
(issue 14): IMU white noise above the assumed density, bias random walks, scale and axis
misalignment, GNSS errors that are correlated in time (Gauss-Markov) with a multipath burst,
rolling-shutter frames (each row rendered at its own time) with camera shake, exposure
flicker, vignetting and JPEG compression.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
import pymap3d
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation

from blendgen import so3
from blendgen.geometry import Camera, invert_pose, make_pose, pose_to_xyz_quat
from blendgen.recording.model import ImuNoise, Recording

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

def bias_random_walk(t: np.ndarray, density: float, b0=(0.0, 0.0, 0.0),
                     rng: np.random.Generator | None = None) -> np.ndarray:
    """(N, 3) bias b(t) = b0 + Wiener process of `density` (units/s/sqrt(Hz) for a gyro in rad/s,
    Kalibr's *_random_walk): increments over dt are N(0, density^2 dt), so Var b(t) - b0 grows
    as density^2 (t - t0)."""
    rng = rng or np.random.default_rng(0)
    dt = np.diff(np.asarray(t, dtype=float), prepend=t[0])
    steps = rng.normal(0.0, 1.0, (len(t), 3)) * (density * np.sqrt(dt))[:, None]
    return np.asarray(b0, dtype=float) + np.cumsum(steps, axis=0)


@dataclass
class ImuErrors:
    """The IMU's real errors when they differ from the recording's ImuNoise (what the filter assumes).

    noise_scale: white noise = this x the assumed densities. *_walk: bias random-walk densities
    (Kalibr units; 0 = constant bias). *_scale: scale-factor error per axis (fraction);
    *_misalign: the sensor axes' non-orthogonality, small angles (rad) off-diagonal."""

    noise_scale: float = 1.0
    gyro_walk: float = 0.0
    acc_walk: float = 0.0
    gyro_scale: tuple = (0.0, 0.0, 0.0)
    acc_scale: tuple = (0.0, 0.0, 0.0)
    gyro_misalign: float = 0.0
    acc_misalign: float = 0.0
    seed: int = 101


def _scale_misalign(scale, misalign: float, rng) -> np.ndarray:
    """I + diag(scale) + off-diagonal coupling drawn once (a real sensor's factory error)."""
    M = rng.normal(0.0, misalign, (3, 3)) if misalign > 0 else np.zeros((3, 3))
    np.fill_diagonal(M, 0.0)
    return np.eye(3) + np.diag(scale) + M


def simulate_imu(traj: Trajectory, rate: float = 200.0, noise: ImuNoise | None = None, seed: int = 0,
                 bias_g=(0.002, -0.003, 0.001), bias_a=(0.05, -0.03, 0.04),
                 errors: ImuErrors | None = None) -> np.ndarray:
    noise = noise or ImuNoise()
    rng = np.random.default_rng(seed)
    t = np.arange(traj.t[0] + 0.01, traj.t[-1] - 0.01, 1.0 / rate)
    w, f = traj.imu(t)
    sq = np.sqrt(rate)
    k = errors.noise_scale if errors is not None else 1.0
    bg, ba = np.asarray(bias_g, float), np.asarray(bias_a, float)
    if errors is not None:  # own generator: the easy drive's draws stay exactly as they were
        rng_e = np.random.default_rng(errors.seed)
        w = w @ _scale_misalign(errors.gyro_scale, errors.gyro_misalign, rng_e).T
        f = f @ _scale_misalign(errors.acc_scale, errors.acc_misalign, rng_e).T
        bg = bias_random_walk(t, errors.gyro_walk, bg, rng_e)
        ba = bias_random_walk(t, errors.acc_walk, ba, rng_e)
    w = w + bg + rng.normal(0, k * noise.gyroscope_noise_density * sq, w.shape)
    f = f + ba + rng.normal(0, k * noise.accelerometer_noise_density * sq, f.shape)
    return np.column_stack([t, w, f])


def gauss_markov(t: np.ndarray, std: np.ndarray, tau_s: float, rng: np.random.Generator) -> np.ndarray:
    """(N, len(std)) first-order Gauss-Markov process: stationary std, correlation exp(-dt/tau)."""
    std = np.asarray(std, dtype=float)
    x = np.zeros((len(t), len(std)))
    x[0] = rng.normal(0.0, std)
    for i in range(1, len(t)):
        a = np.exp(-(t[i] - t[i - 1]) / tau_s)
        x[i] = a * x[i - 1] + np.sqrt(1 - a * a) * rng.normal(0.0, std)
    return x


def simulate_gnss(traj: Trajectory, rate: float = 10.0, std_m: float = 1.0, seed: int = 1,
                  georef=GEOREF, dropout: tuple[float, float] | None = None, lever=None,
                  gm_std_m: float = 0.0, gm_tau_s: float = 30.0,
                  burst: tuple[float, float, tuple] | None = None, latency_s: float = 0.0) -> np.ndarray:
    """t, lat, lon, alt of the body origin (+ lever arm) with white horizontal noise std_m.

    latency_s: receiver latency, a fix stamped t is the position at t - latency_s.

    gm_std_m: plus a Gauss-Markov error (horizontal std; vertical 1.5x) of correlation time
    gm_tau_s, the slow wander of a real receiver. burst = (t0, t1, offset_xyz): multipath, the
    fixes in [t0, t1) jump by offset_xyz (m) with 3x the white noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(traj.t[0] + 0.05, traj.t[-1] - 0.05, 1.0 / rate)
    p = traj.position(t - latency_s)
    if lever is not None:
        p = p + np.einsum("nij,j->ni", traj.R(t - latency_s), lever)
    white = rng.normal(0, 1, p.shape) * np.array([std_m, std_m, 1.5 * std_m])
    if burst is not None:
        white[(t >= burst[0]) & (t < burst[1])] *= 3.0
    p = p + white
    if gm_std_m > 0:  # own generator: the easy drive's draws stay exactly as they were
        p = p + gauss_markov(t, [gm_std_m, gm_std_m, 1.5 * gm_std_m], gm_tau_s, np.random.default_rng(seed + 1000))
    if burst is not None:
        p[(t >= burst[0]) & (t < burst[1])] += np.asarray(burst[2], dtype=float)
    if dropout is not None:
        keep = (t < dropout[0]) | (t >= dropout[1])
        t, p = t[keep], p[keep]
    lat, lon, alt = pymap3d.enu2geodetic(p[:, 0], p[:, 1], p[:, 2], *georef)
    return np.column_stack([t, lat, lon, alt])


def simulate_odometer(traj: Trajectory, rate: float = 100.0, scale: float = 0.99, noise_mps: float = 0.03,
                      quantum_mps: float = 0.01, latency_s: float = 0.0, seed: int = 2) -> np.ndarray:
    """t, speed of a CAN wheel-speed signal: the vehicle's forward speed at t - latency_s times
    `scale` (tyre radius), plus white noise, rounded to `quantum_mps`, never negative
    (comma2k19's CAN speed: 83 Hz, scale 0.991, 0.04 m/s about the ground truth)."""
    rng = np.random.default_rng(seed + 2000)  # own generator: the other sensors' draws stay as they were
    t = np.arange(traj.t[0] + 0.05, traj.t[-1] - 0.05, 1.0 / rate)
    ts = t - latency_s
    v_fwd = np.einsum("nji,nj->ni", traj.R(ts), traj.velocity(ts))[:, 0]
    # wheels that do not turn read 0: no noise while standing (a wheel-speed sensor counts teeth)
    s = np.where(np.abs(v_fwd) < 0.05, 0.0, scale * v_fwd + rng.normal(0.0, noise_mps, len(t)))
    if quantum_mps > 0:
        s = np.round(s / quantum_mps) * quantum_mps
    return np.column_stack([t, np.maximum(s, 0.0)])


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
        """Grey uint8 image (H, W) seen by a pinhole camera (distortion ignored).

        T_world_cam: one pose (4, 4), or one per image row (H, 4, 4): a rolling shutter, row r
        exposed at its own time (`rolling_shutter_poses`)."""
        H, W = camera.height, camera.width
        u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        dc = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], -1)
        T_world_cam = np.asarray(T_world_cam, dtype=float)
        if T_world_cam.ndim == 3:
            if T_world_cam.shape[0] != H:
                raise ValueError(f"{T_world_cam.shape[0]} row poses for an image of {H} rows")
            d = np.einsum("hij,hwj->hwi", T_world_cam[:, :3, :3], dc)
            c = T_world_cam[:, None, :3, 3]  # (H, 1, 3): broadcasts over columns
        else:
            R, c = T_world_cam[:3, :3], T_world_cam[:3, 3]
            d = dc @ R.T
        cy_, cz_ = c[..., 1], c[..., 2]
        inf = np.inf
        with np.errstate(divide="ignore", invalid="ignore"):
            tg = np.where(d[..., 2] < -1e-9, -cz_ / d[..., 2], inf)
            wall_y = np.where(d[..., 1] > 0, self.half_width, -self.half_width)
            tw = np.where(np.abs(d[..., 1]) > 1e-9, (wall_y - cy_) / d[..., 1], inf)
        tw = np.where(tw > 0, tw, inf)
        zw = cz_ + tw * d[..., 2]
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


def rolling_shutter_poses(traj: Trajectory, t: float, rows: int, readout_s: float,
                          T_body_cam: np.ndarray) -> np.ndarray:
    """(rows, 4, 4) T_world_cam of each image row: row r is exposed at t + r * readout_s / rows."""
    tr = t + np.arange(rows) * (readout_s / rows)
    R_wb, p_wb = traj.R(tr), np.atleast_2d(traj.position(tr))
    T = np.zeros((rows, 4, 4))
    T[:, :3, :3] = R_wb @ T_body_cam[:3, :3]
    T[:, :3, 3] = p_wb + R_wb @ T_body_cam[:3, 3]
    T[:, 3, 3] = 1.0
    return T


PHOTOMETRY_PARTS = ("flicker", "vignetting", "gamma", "jpeg")


def _camera_look(img: np.ndarray, rng: np.random.Generator, parts=PHOTOMETRY_PARTS) -> np.ndarray:
    """A real camera's photometry on a rendered frame: exposure/gain flicker (+-8 %, auto
    exposure hunting), vignetting (radial falloff to ~70 % in the corners), gamma, and JPEG
    compression at quality 75 (block artefacts and ringing that corner detectors see).
    parts: which of PHOTOMETRY_PARTS to apply (to measure each one's effect on VO); the
    flicker's random draw is made either way, so a frame's other parts do not change."""
    unknown = set(parts) - set(PHOTOMETRY_PARTS)
    if unknown:
        raise ValueError(f"unknown photometry parts {sorted(unknown)}; expected some of {PHOTOMETRY_PARTS}")
    H, W = img.shape
    gain = 1.0 + 0.08 * rng.uniform(-1, 1)
    x = img.astype(np.float32) / 255.0
    if "vignetting" in parts:
        yy, xx = np.mgrid[0:H, 0:W]
        r2 = ((xx - W / 2) ** 2 + (yy - H / 2) ** 2) / ((W / 2) ** 2 + (H / 2) ** 2)
        x = x * (1.0 / (1.0 + 0.2 * r2)) ** 2
    if "flicker" in parts:
        x = x * gain
    x = np.clip(x, 0, 1)
    if "gamma" in parts:
        x = x ** (1 / 1.1)
    x = (x * 255.0).astype(np.uint8)
    if "jpeg" not in parts:
        return x
    ok, buf = cv2.imencode(".jpg", x, [cv2.IMWRITE_JPEG_QUALITY, 75])
    return cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)


# The hard variant's error levels (issue 14): against the recording's ImuNoise defaults
# (accel 2e-3 m/s^2/sqrt(Hz), gyro 1.7e-4 rad/s/sqrt(Hz), walks 3e-3 and 2e-5).
HARD_IMU = ImuErrors(noise_scale=2.5, gyro_walk=1e-4, acc_walk=1.5e-2,
                     gyro_scale=(0.004, -0.003, 0.005), acc_scale=(0.003, 0.002, -0.004),
                     gyro_misalign=1e-3, acc_misalign=1e-3)
HARD_GNSS_STD = 0.5  # m, white, plus HARD_GNSS
HARD_GNSS = {"gm_std_m": 1.0, "gm_tau_s": 60.0, "burst": None}  # burst set per duration
HARD_READOUT_S = 0.03
HARD_SHAKE_DEG = 0.3


def hard_recording(duration: float = 60.0, *, seed: int = 0, **kw):
    """The easy drive (same path, frame rate, camera) with sensors unlike the filter's model:
    HARD_IMU (white noise 2.5x the assumed density; bias random walks 5x the assumed ones,
    over 60 s a 1-sigma drift of 0.04 deg/s and 0.12 m/s^2; 0.2-0.5 % scale and 1 mrad axis
    misalignment), GNSS 0.5 m white + 1 m Gauss-Markov (60 s correlation) with a 5 s multipath burst (+4, -6, +3 m) at 40 %
    of the drive, rolling shutter (30 ms readout), 0.3 deg camera shake (1-6 Hz) and real-camera
    photometry. Returns what synthetic_recording returns."""
    b0 = 0.4 * duration
    gnss = {**HARD_GNSS, "burst": (b0, b0 + 5.0, (4.0, -6.0, 3.0))}
    return synthetic_recording("drive", duration, seed=seed, imu_errors=HARD_IMU, gnss_std=HARD_GNSS_STD,
                               gnss_errors=gnss,
                               rolling_shutter_s=HARD_READOUT_S, shake_deg=HARD_SHAKE_DEG, photometric=True, **kw)


def shaken(traj: Trajectory, shake_deg: float, seed: int = 0) -> Trajectory:
    """The trajectory with camera shake (rough road, a hand): the body's yaw, pitch and roll
    get sums of 1-6 Hz sinusoids of about `shake_deg`."""
    rng_s = np.random.default_rng(seed + 11)
    shake = np.zeros_like(traj.ypr)
    for axis, k in ((0, 0.6), (1, 1.0), (2, 0.8)):  # yaw, pitch, roll
        for hz in (1.1, 2.3, 3.7, 5.9):
            shake[:, axis] += k * np.sin(2 * np.pi * (hz * (1 + 0.1 * rng_s.normal())) * traj.t
                                         + rng_s.uniform(0, 2 * np.pi)) / 2.0
    return Trajectory(traj.t, traj.xyz, traj.ypr + np.radians(shake_deg) * shake)


def synthetic_recording(kind: str = "drive", duration: float = 20.0, *, fps: float = 5.0,
                        resolution=(480, 270), hfov_deg: float = 70.0, speed: float = 8.0,
                        imu: bool = True, gnss: bool = True, gnss_std: float = 1.0, frames: bool = True,
                        dropout=None, imu_gap=None, dark_frames=None, seed: int = 0,
                        scene: StreetScene | None = None, imu_mount_rpy_deg=(0.0, 0.0, 0.0),
                        shake_deg: float = 0.0, stabilise_s: float | None = None, margin: float = 0.12,
                        imu_errors: ImuErrors | None = None, gnss_errors: dict | None = None,
                        rolling_shutter_s: float = 0.0, photometric=False,
                        cam_time_offset_s: float = 0.0, odometer: dict | None = None):
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
    imu_errors: the IMU's real errors (ImuErrors) where they differ from `rec.imu_noise`.
    gnss_errors: extra simulate_gnss arguments (gm_std_m, gm_tau_s, burst, latency_s).
    rolling_shutter_s: readout time; row r of a frame stamped t is exposed at t + r * readout / H
    (ground truth: the pose at t, the first row's). photometric: per-frame exposure flicker,
    vignetting and JPEG compression (quality 75), as from a real camera; or a sequence of some
    of PHOTOMETRY_PARTS to apply only those.
    cam_time_offset_s: the camera clock lags the IMU's (Kalibr timeshift_cam_imu: t_imu = t_cam
    + shift): the frame stamped t is exposed at t + shift on the IMU clock; `rec` keeps the
    calib value 0 (an unknown offset). Ground truth rows: the stamp t, the pose at t + shift.
    odometer: simulate_odometer arguments (scale, noise_mps, latency_s, ...) for a CAN speed
    in `rec.speed`; None: no odometer.
    Returns (rec, traj, T_cam_imu). `rec.groundtruth` holds T_world_cam per frame (the body's camera).
    """
    traj = make_trajectory(kind, duration + 1.0, speed=speed)
    traj_smooth = None
    if shake_deg > 0:
        traj = shaken(traj, shake_deg, seed)
    if stabilise_s is not None:
        from scipy.ndimage import gaussian_filter1d

        dt = float(traj.t[1] - traj.t[0])
        ypr_s = gaussian_filter1d(np.unwrap(traj.ypr, axis=0), stabilise_s / dt, axis=0, mode="nearest")
        traj_smooth = Trajectory(traj.t, traj.xyz, ypr_s)
    R_body_imu = Rotation.from_euler("xyz", np.radians(imu_mount_rpy_deg)).as_matrix()
    T_cam_imu = default_T_cam_imu() @ make_pose(R_body_imu, np.zeros(3))
    T_imu_cam = invert_pose(T_cam_imu)
    cam = Camera.from_hfov(resolution[0], resolution[1], hfov_deg)
    # the readout is a camera property a calibration gives (calib.yaml camera.rolling_shutter_s)
    rec = Recording(root=None, camera=cam if frames else None, T_cam_imu=T_cam_imu,
                    rolling_shutter_s=float(rolling_shutter_s))
    if imu:
        data = simulate_imu(traj, seed=seed, errors=imu_errors)
        data[:, 1:4] = data[:, 1:4] @ R_body_imu  # body -> IMU axes (R^T x, row-wise)
        data[:, 4:7] = data[:, 4:7] @ R_body_imu
        if imu_gap is not None:
            data = data[(data[:, 0] < imu_gap[0]) | (data[:, 0] >= imu_gap[1])]
        rec.imu = data
    if gnss:
        rec.gnss = simulate_gnss(traj, std_m=gnss_std, seed=seed + 1, dropout=dropout, **(gnss_errors or {}))
    if odometer is not None:
        rec.speed = simulate_odometer(traj, seed=seed, **odometer)
    t0 = 0.5
    ft = np.arange(t0, t0 + duration, 1.0 / fps) if frames else np.zeros(0)
    rec.frames_t = ft
    gt = []
    images = []
    scene = scene or (StreetScene() if frames else None)
    rng = np.random.default_rng(seed + 7)
    T_body_cam = make_pose(R_body_imu, np.zeros(3)) @ T_imu_cam
    img_gt, corrections = [], []
    rng_p = np.random.default_rng(seed + 13)
    if traj_smooth is not None and frames:
        mx, my = int(round(margin * cam.width)), int(round(margin * cam.height))
        cam_big = Camera(cam.width + 2 * mx, cam.height + 2 * my, cam.fx, cam.fy, cam.cx + mx, cam.cy + my)
    for i, t_stamp in enumerate(ft):
        t = t_stamp + cam_time_offset_s  # the exposure on the IMU (true) clock
        T_wc = traj.pose(t) @ T_body_cam
        gt.append(T_wc)
        if traj_smooth is not None:
            T_img = traj_smooth.pose(t) @ T_body_cam
            T_img[:3, 3] = T_wc[:3, 3]
            C = T_wc[:3, :3].T @ T_img[:3, :3]  # the image's camera in the true camera
            img_gt.append(T_img)
            corrections.append(C)
        if frames and traj_smooth is not None:
            big = scene.render(cam_big, rolling_shutter_poses(traj, t, cam_big.height, rolling_shutter_s, T_body_cam)
                               if rolling_shutter_s > 0 else T_wc, rng=rng)
            # output pixel -> ray in the image camera -> C -> ray in the true camera -> big pixel
            M = cam_big.K @ C @ np.linalg.inv(cam.K)
            img = cv2.warpPerspective(big, M, (cam.width, cam.height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                      borderMode=cv2.BORDER_REPLICATE)
        elif frames:
            img = scene.render(cam, rolling_shutter_poses(traj, t, cam.height, rolling_shutter_s, T_body_cam)
                               if rolling_shutter_s > 0 else T_wc, rng=rng)
        if frames and photometric:
            img = _camera_look(img, rng_p, PHOTOMETRY_PARTS if photometric is True else tuple(photometric))
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
