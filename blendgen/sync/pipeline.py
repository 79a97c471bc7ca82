"""Sync stage: the camera pose of every frame in the twin frame.

recording -> GNSS fixes in the twin frame (through the LUT, or ENU about a georeference)
          -> error-state EKF (IMU propagation; GNSS, VO and zero-velocity updates)
          -> re-anchoring to the global fixes (correction spread smoothly over segments)
          -> OUT/poses.csv, OUT/poses.tum

Times: frame poses are reported at the frame timestamps of frames.csv; the filter runs on the
IMU clock (t_imu = t_cam + timeshift_cam_imu).
"""

from __future__ import annotations

import contextvars
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pymap3d

from blendgen import atomic, so3
from blendgen.errors import StageError, UserError
from blendgen.geometry import invert_pose, make_pose, matrix_to_quat
from blendgen.recording.model import Recording
from blendgen.sync import calibration, odometer, road_height
from blendgen.sync.ekf import CALIB, NC, EkfConfig, ErrorStateEkf
from blendgen.sync.latency import LatencyProfile, profile_latency
from blendgen.sync.lut import Lut
from blendgen.sync.readout import Readout, estimate_readout
from blendgen.sync.reanchor import reanchor
from blendgen.sync.threads import single_thread_blas
from blendgen.sync.time_offset import TimeOffset, estimate_time_offset, not_estimated
from blendgen.sync.vo_trust import VO_ROT_FLOOR_ASSUMED_LENS, GyroIntegrator, TrustReport, assess, vo_noise
from blendgen.vo import VoConfig, VoResult, along_subset, make_vo, refit_along

# vehicle-frame constraints (per GNSS fix while moving): lateral slip and vertical (suspension)
# velocity of a car, and how far from level across a road is (crown, banking)
NHC_LAT_STD, NHC_UP_STD, NHC_EVERY_S = 0.3, 0.1, 0.1
LEVEL_STD = 0.05  # rad
LATENCY_STEP_S = 0.1  # grid of the latency profile (then half steps and a parabola about the best)
# below NHC_MIN_SPEED (pulling away, stopping) they biased the accelerometer (stop-and-go: 0.23 m/s^2)
NHC_MIN_SPEED = 6.0  # m/s

POSES_COLUMNS = ["t", "x", "y", "z", "qw", "qx", "qy", "qz",
                 "var_x", "var_y", "var_z", "var_rx", "var_ry", "var_rz",
                 "vo_status", "vo_inliers", "vo_parallax_px", "flags", "frame_id"]


@dataclass
class SyncResult:
    poses: list  # (frame_id, t, T_world_cam 4x4)
    cov: np.ndarray  # (N, 6) variance of position (m^2) and rotation error (rad^2) per pose
    quality: list[dict]  # per pose: vo status, inliers, parallax, flags
    summary: dict = field(default_factory=dict)
    speed_track: np.ndarray | None = None  # smoothed (t on the IMU clock, vehicle forward speed) per pose

    @property
    def times(self) -> np.ndarray:
        return np.array([p[1] for p in self.poses])

    def positions(self) -> np.ndarray:
        return np.array([p[2][:3, 3] for p in self.poses]).reshape(-1, 3)


# ----------------------------------------------------------------------------- inputs

def gnss_to_world(rec: Recording, lut: Lut | None, georef):
    """GNSS fixes -> (t, xyz in the world frame, inside-coverage flags, yaw or NaN, origin)."""
    g = rec.gnss
    if len(g) == 0:
        return np.zeros(0), np.zeros((0, 3)), np.zeros(0, bool), np.zeros(0), None
    t, lat, lon, alt = g[:, 0], g[:, 1], g[:, 2], g[:, 3]
    heading = rec.gnss_col("heading_deg")
    if lut is not None:
        xyz, inside, rot = lut.query_many(lat, lon, alt)
        yaw = np.radians(90.0 - heading) + rot if heading is not None else np.full(len(t), np.nan)
        return t, xyz, inside, so3.wrap_angle(yaw), None
    origin = tuple(georef) if georef is not None else (lat[0], lon[0], alt[0])
    if getattr(georef, "proj", None):  # a projected twin (a UTM map): pyproj, grid vs true north
        e, n, u = georef.to_enu(lat, lon, alt)
        north = georef.north_yaw(e, n)
    else:
        e, n, u = pymap3d.geodetic2enu(lat, lon, alt, *origin)
        north = np.pi / 2
    yaw = north - np.radians(heading) if heading is not None else np.full(len(t), np.nan)
    return t, np.stack([e, n, u], axis=1), np.ones(len(t), bool), so3.wrap_angle(yaw), origin


def _gravity_level(acc_mean: np.ndarray) -> np.ndarray:
    """R_world_body with zero yaw whose z axis agrees with the measured specific force."""
    z_b = acc_mean / np.linalg.norm(acc_mean)  # world up, in body coordinates
    x_ref = np.array([1.0, 0, 0]) if abs(z_b[0]) < 0.9 else np.array([0, 1.0, 0])
    x_b = x_ref - z_b * (z_b @ x_ref)
    x_b /= np.linalg.norm(x_b)
    y_b = np.cross(z_b, x_b)
    return np.stack([x_b, y_b, z_b])  # rows: world axes in body -> R_world_body


def _forward_axis(R_bc: np.ndarray) -> np.ndarray:
    """The body axis that points where the vehicle drives: the camera's optical axis."""
    return R_bc[:, 2]


def _initial_heading(t_fix, xyz, yaw_col, t_start, min_dist: float = 12.0):
    """(yaw, velocity, yaw std) at the start: velocity from a line fit to the first fixes that
    span min_dist; yaw from the receiver's heading column when it has one, else from that fit.

    The vertical velocity is set to zero: it would be GNSS altitude noise (~2x the horizontal),
    not motion, and a wrong climb rate tilts the camera through the VO direction update. A
    vehicle already moving at the start must not start at zero velocity either, for the same
    reason (the first VO directions would pull the attitude toward the wrong motion).
    """
    ok = np.isfinite(yaw_col)
    yaw_rx = float(yaw_col[np.flatnonzero(ok)[0]]) if ok.any() else None
    vel = None
    if len(xyz) >= 3:
        d = np.linalg.norm(xyz[:, :2] - xyz[0, :2], axis=1)
        far = np.flatnonzero(d > min_dist)
        if far.size:
            j = max(int(far[0]), 5)
            tt, P = t_fix[: j + 1], xyz[: j + 1]
            A = np.column_stack([np.ones_like(tt), tt - tt[0]])
            coef, *_ = np.linalg.lstsq(A, P, rcond=None)
            if np.linalg.norm(coef[1][:2]) >= 0.5:
                vel = np.array([coef[1][0], coef[1][1], 0.0])
    if yaw_rx is not None:
        if vel is not None:  # the fit's speed along the receiver's heading
            vel = np.linalg.norm(vel) * np.array([np.cos(yaw_rx), np.sin(yaw_rx), 0.0])
        return yaw_rx, vel if vel is not None else np.zeros(3), 0.05
    if vel is None:
        return None, np.zeros(3), None
    return float(np.arctan2(vel[1], vel[0])), vel, 0.1


def _stationary_imu(imu: np.ndarray, cfg: EkfConfig, window_s: float = 0.5) -> np.ndarray:
    """Per IMU sample: quiet enough to be standing still (moving windows of gyro and accel)."""
    if len(imu) < 5:
        return np.zeros(len(imu), bool)
    rate = 1.0 / max(np.median(np.diff(imu[:, 0])), 1e-4)
    n = max(3, int(window_s * rate))
    k = np.ones(n) / n
    gn = np.linalg.norm(imu[:, 1:4], axis=1)
    an = np.linalg.norm(imu[:, 4:7], axis=1)

    def mstd(x):
        m = np.convolve(x, k, mode="same")
        return np.sqrt(np.maximum(np.convolve(x * x, k, mode="same") - m * m, 0))

    sg = cfg.gyro_noise * np.sqrt(rate)
    sa = cfg.acc_noise * np.sqrt(rate)
    thr_g, thr_a = max(6 * sg, 0.01), max(6 * sa, 0.08)
    return (mstd(gn) < thr_g) & (mstd(an) < thr_a) & (np.convolve(gn, k, mode="same") < max(thr_g * 3, 0.03))


# ----------------------------------------------------------------------------- main

_REPORT: contextvars.ContextVar = contextvars.ContextVar("sync_on_progress", default=None)


def run_sync(rec: Recording, settings, out_dir: Path, *, lut_path: Path | None = None,
             georef: tuple[float, float, float] | None = None, progress: bool = True,
             road_surface=None, on_progress=None) -> SyncResult:
    """Estimate T_world_cam for every frame (or at settings.pose_rate_hz without frames).
    road_surface: the twin's road height, (N, 2) xy -> (N,) z (`Twin.ground_heights`).
    on_progress(done, phase, total): called as VO and the filter passes go
    (pipeline.outputs.StageProgress)."""
    token = _REPORT.set(on_progress)
    try:
        with single_thread_blas():
            return _run_sync(rec, settings, Path(out_dir), lut_path, georef, progress, road_surface)
    finally:
        _REPORT.reset(token)


def _run_sync(rec, settings, out_dir, lut_path, georef, progress, road_surface=None) -> SyncResult:
    t_wall = time.perf_counter()
    out_dir = Path(out_dir)
    use_imu = bool(settings.use_imu and len(rec.imu) >= 2)
    use_gnss = bool(settings.use_gnss and len(rec.gnss) >= 1)
    use_vo = bool(settings.use_vo and rec.n_frames >= 2 and rec.camera is not None)
    if not (use_imu or use_gnss or use_vo):
        raise UserError("sync has nothing to work with: enable at least one of IMU, GNSS or VO with data "
                        f"(frames {rec.n_frames}, IMU rows {len(rec.imu)}, GNSS rows {len(rec.gnss)})",
                        where=str(rec.root))
    lut_file = lut_path if lut_path is not None else getattr(settings, "lut", None)
    lut = Lut.load(lut_file) if (lut_file is not None and use_gnss) else None

    T_imu_cam = invert_pose(np.asarray(rec.T_cam_imu, dtype=float))
    R_bc, p_bc = T_imu_cam[:3, :3], T_imu_cam[:3, 3]
    shift = float(rec.time_offset_cam_imu)

    # output times (IMU clock) and their ids
    if rec.n_frames:
        out_t_cam = np.asarray(rec.frames_t, dtype=float)
        ids = [rec.frame_id(i) for i in range(rec.n_frames)]
    else:
        srcs = [a[:, 0] for a in (rec.imu, rec.gnss) if len(a)]
        t0, t1 = min(s[0] for s in srcs), max(s[-1] for s in srcs)
        out_t_cam = np.arange(t0, t1 + 1e-9, 1.0 / settings.pose_rate_hz)
        ids = [f"p{i:06d}" for i in range(len(out_t_cam))]
    out_t = out_t_cam + (shift if rec.n_frames else 0.0)

    # GNSS in the world frame
    gt_t, g_xyz, g_inside, g_yaw, origin = (gnss_to_world(rec, lut, georef) if use_gnss
                                            else (np.zeros(0), np.zeros((0, 3)), np.zeros(0, bool), np.zeros(0), None))
    g_std = _gnss_std(rec, settings) if use_gnss else np.zeros(0)

    if not use_imu and not use_gnss:
        result = _vo_only(rec, settings, ids, out_t_cam, R_bc, progress)
    else:
        result = _filter(rec, settings, use_imu, use_gnss, use_vo, ids, out_t, out_t_cam, gt_t, g_xyz, g_inside,
                         g_yaw, g_std, R_bc, p_bc, progress, road_surface)
        if use_gnss and settings.reanchor_every_s:
            # a fix stamped t is where the antenna was at t - latency: compare it there (with
            # the latency ignored, re-anchoring pulled a 0.25 s latency's 4 m back onto the fixes)
            tau = float(result.summary.get("calibration", {}).get("gnss_latency_s", 0.0))
            shift = float(result.summary.get("camera_imu_time_offset", {}).get("shift_s", shift))
            n_anch = reanchor(result, gt_t - tau - (shift if rec.n_frames else 0.0), g_xyz, g_inside,
                              g_std, settings.reanchor_every_s, T_imu_cam)
            result.summary["reanchor_segments"] = n_anch
    result.summary.update({
        "frames": rec.n_frames, "poses": len(result.poses), "lut": str(lut_file) if lut is not None else None,
        "georef": list(origin) if origin is not None else None, "reader_issues": list(rec.issues),
        "gnss_outside_lut": int((~g_inside).sum()) if use_gnss else 0,
        "seconds": round(time.perf_counter() - t_wall, 3),
        "sensors": {"imu": use_imu, "gnss": use_gnss, "vo": use_vo,
                    "speed": "speed_scale" in result.summary.get("calibration", {})},
    })
    if len(rec.speed) and not result.summary["sensors"]["speed"]:
        result.summary["odometer_unused"] = (
            "speed.csv is not used: the odometer needs the IMU and GNSS of a road vehicle (sync.road_vehicle, "
            "calib.yaml vehicle.road_vehicle)"
            if getattr(settings, "use_speed", True) else "speed.csv is not used (sync.use_speed: false / --no-speed)")
    _check_finite(result)
    write_poses(out_dir, result)
    return result


def _gnss_std(rec: Recording, settings) -> np.ndarray:
    if settings.gnss_std_m is not None:
        return np.full(len(rec.gnss), float(settings.gnss_std_m))
    col = rec.gnss_col("h_std_m")
    if col is not None:
        return np.where(np.isfinite(col) & (col > 0), col, 1.5)
    return np.full(len(rec.gnss), 1.5)


def _frames(rec: Recording):
    if "images" in rec.extra:  # in-memory frames (synthetic recordings, tests)
        yield from enumerate(rec.extra["images"])
        return
    from blendgen.recording.folder import iter_frames

    yield from iter_frames(rec, skip_bad=True)


KLT_MIN_FPS = 10.0  # vo_method auto: below this LK tracks patches that change scale too much


def vo_method(settings, rec: Recording) -> str:
    """The VO front end: the job's, or for `auto` KLT (track-then-detect, fast) at >= KLT_MIN_FPS
    and ORB below, where the ground ahead grows between frames and LK's direction of travel is
    biased (60 s synthetic drive at 5 fps: rotation 0.153 deg with KLT, 0.103 with ORB)."""
    method = str(getattr(settings, "vo_method", "auto"))
    if method != "auto":
        return method
    dt = np.diff(rec.frames_t)
    fps = 1.0 / float(np.median(dt)) if len(dt) and np.median(dt) > 0 else 0.0
    # 1 % slack: stamps of a 10 fps camera (np.arange(0.5, 60.5, 0.1): median step 0.1 + 1.4e-15 s)
    # must not fall to ORB by rounding (the 60 s drive at 10 fps did, the 20 s one did not)
    return "klt" if fps >= 0.99 * KLT_MIN_FPS else "orb"


def _vo_config(settings, rec: Recording, keep_matches: bool = False) -> VoConfig:
    return VoConfig(n_features=int(settings.orb_features), method=vo_method(settings, rec),
                    readout_s=float(rec.rolling_shutter_s), keep_matches=keep_matches)


def _rs_spins(imu: np.ndarray, t_frames: np.ndarray, readout_s: float, R_bc: np.ndarray,
              knots: int = 16) -> np.ndarray | None:
    """The camera's turn during each frame's readout (camera axes) from the gyro (IMU clock frame
    times): (frames, knots, 3) rotation vectors from the top row's time to `knots` times evenly
    over the readout, the gyro rate interpolated and integrated (small angles: rotation vectors
    add). What the rolling-shutter correction of VO needs (`vo.rs_bearings`). Integrated, not
    one rate per frame: shake of a few Hz changes the rate within the readout."""
    if readout_s <= 0 or len(imu) < 2:
        return None
    sub = 4  # integration steps per knot interval
    s = np.linspace(0.0, readout_s, sub * (knots - 1) + 1)
    tt = np.asarray(t_frames, float)[:, None] + s[None, :]
    w = np.stack([np.interp(tt, imu[:, 0], imu[:, k]) for k in (1, 2, 3)], axis=-1) @ R_bc  # R_bc^T w_imu
    ds = s[1] - s[0]
    rv = np.concatenate([np.zeros((len(tt), 1, 3)), np.cumsum(0.5 * (w[:, 1:] + w[:, :-1]) * ds, axis=1)], axis=1)
    return rv[:, ::sub]


def _quality(vo: VoResult | None, flags: list[str]) -> dict:
    return {"vo_status": vo.status if vo is not None else "none",
            "vo_inliers": vo.n_inliers if vo is not None else 0,
            "vo_parallax_px": round(vo.parallax_px, 2) if vo is not None else 0.0,
            "flags": sorted(set(flags))}


def _filter(rec, settings, use_imu, use_gnss, use_vo, ids, out_t, out_t_cam, gt_t, g_xyz, g_inside, g_yaw,
            g_std, R_bc, p_bc, progress, road_surface=None) -> SyncResult:
    noise = rec.imu_noise
    cfg = EkfConfig(acc_noise=noise.accelerometer_noise_density, gyro_noise=noise.gyroscope_noise_density,
                    acc_walk=noise.accelerometer_random_walk, gyro_walk=noise.gyroscope_random_walk)
    imu = rec.imu if use_imu else np.zeros((0, 7))
    if use_imu:
        cfg.max_imu_dt = max(5.0 * float(np.median(np.diff(imu[:, 0]))), 0.02)
    vo_cache: dict[int, VoResult | None] = {}
    trust, toff, readout = None, None, None
    if use_vo:
        # VO first, over all frames: each pair is checked against the gyro, and whether the
        # frames move rigidly with the IMU at all is decided, before the filter trusts any
        if rec.rolling_shutter_estimate and use_imu:
            rec, readout = _estimate_readout(rec, settings, imu, out_t, R_bc, cfg, vo_cache, progress)
        else:
            _vo_all(rec, settings, len(out_t), vo_cache, progress,
                    _rs_spins(imu, out_t, rec.rolling_shutter_s, R_bc) if use_imu else None)
        if use_imu:
            trust, toff, out_t = _trust_and_time_offset(rec, [vo_cache.get(i) for i in range(len(out_t))], imu,
                                                        out_t_cam, out_t, R_bc, cfg)
            if rec.rolling_shutter_s > 0:
                trust.reason += (f"; rows turned back to the frame's top row with the gyro (rolling shutter, "
                                 f"{rec.rolling_shutter_s * 1e3:.1f} ms readout"
                                 f"{', estimated' if readout is not None else ''})")
            if rec.lens_source == "assumed":
                trust.reason += (f"; the lens is the importer's assumption, so VO gives rotation only, no better "
                                 f"than {np.degrees(VO_ROT_FLOOR_ASSUMED_LENS):.1f} deg per pair, and no direction "
                                 f"of travel (calibrate the camera for more)")
            elif rec.lens_source == "profile":
                trust.reason += ("; the lens is the camera model's profile, not this camera's calibration, so VO "
                                 "gives rotation only, no direction of travel (its principal point is not known "
                                 "to the pixel; calibrate the camera for more)")
    if toff is None and rec.n_frames and rec.time_offset_estimate:
        toff = not_estimated(rec.time_offset_cam_imu, "it needs frames, VO and an IMU")
    starts = [a[0] for a in (imu[:, 0], gt_t if use_gnss else np.zeros(0), out_t) if len(a)]
    t_start = min(starts)
    fwd = _forward_axis(R_bc)

    # --- initial state
    yaw0, v0, yaw_std = (_initial_heading(gt_t, g_xyz, g_yaw, t_start) if use_gnss else (None, np.zeros(3), None))
    if use_imu:
        head = imu[imu[:, 0] < imu[0, 0] + 1.0]
        f_mean = head[:, 4:7].mean(axis=0)
        # a turning car feels a centripetal acceleration w x v: remove it before levelling
        v_body = np.linalg.norm(v0) * fwd / np.linalg.norm(fwd)
        R0 = _gravity_level(f_mean - np.cross(head[:, 1:4].mean(axis=0), v_body))
    else:
        # level camera: optical axis horizontal, image y down
        R_wc = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
        R0 = R_wc @ R_bc.T
    f0 = R0 @ fwd
    if np.hypot(f0[0], f0[1]) < 0.3:  # camera looks up/down: steer by the body x axis instead
        fwd = np.array([1.0, 0, 0])
        f0 = R0 @ fwd
    if yaw0 is None and not use_gnss:
        yaw0 = 0.0  # no global heading at all: the world's +x is where the camera first looks
    if yaw0 is not None:
        R0 = so3.yaw_rotation(yaw0 - np.arctan2(f0[1], f0[0])) @ R0
    p0 = g_xyz[0].copy() if use_gnss else np.zeros(3)
    # the vehicle frame: forward along the camera's optical axis made level, up from gravity;
    # the filter estimates how the IMU is really mounted in it (road vehicles only)
    calib, road, odo = None, None, np.zeros((0, 5))  # odo: odometer.means of speed.csv
    if use_imu and use_gnss and getattr(settings, "road_vehicle", True) and calibration.road_vehicle(rec):
        pri = calibration.read_priors(rec)
        R_bv0 = calibration.nominal_vehicle_frame(fwd, R0.T @ np.array([0.0, 0.0, 1.0]))
        if getattr(settings, "use_speed", True) and len(rec.speed):
            odo = odometer.means(rec.speed, imu)
        calib = (R_bv0, pri.mount_std, pri.latency_s, pri.latency_std_s, R_bv0 @ pri.lever_arm_v,
                 pri.lever_arm_std_m, *((pri.speed_scale_std, pri.speed_latency_s,
                                         odometer.LATENCY_PRIOR_STD_S if pri.speed_latency_auto else 0.0)
                                        if len(odo) else (0.0, 0.0, 0.0)))
        # the car stays on the road: with a twin, its height follows the road surface
        # (blendgen.sync.road_height), not the fixes' vertical noise
        road = road_height.build(gt_t, g_xyz, _height_error_correlation_s(gt_t, g_xyz), road_surface,
                                 pri.camera_height_m)
    # the levelling above cannot see the car's own longitudinal acceleration: start with a
    # loose tilt prior, then (with the smoother) run again from the smoothed initial state
    acc_bias_std = float(rec.imu_noise.accelerometer_bias_std)
    P0 = np.concatenate([np.full(3, 4.0 if use_gnss else 1e-4), np.full(3, 4.0),
                         [0.15**2, 0.15**2, (yaw_std or 0.05) ** 2],
                         np.full(3, float(rec.imu_noise.gyroscope_bias_std) ** 2), np.full(3, acc_bias_std**2)])
    smooth = bool(getattr(settings, "smooth", True))
    # The odometer pins the speed, so an offset of its clock moves the whole trajectory in
    # time: the passes that measure the GNSS latency and noise run without it (with it and its
    # latency fixed at 0, comma2k19's GNSS latency came out 0.12 s instead of 0.068 s, raw
    # error 0.50 -> 0.78 m); the final pass has it, its latency a filter state
    two_pass = smooth and use_imu
    with_odo = (odo, pri.speed_std_mps if calib is not None else 0.0)
    args = (t_start, use_imu, use_gnss, use_vo, smooth, ids, out_t, out_t_cam, gt_t, g_xyz, g_inside, g_yaw, g_std,
            R_bc, p_bc, fwd, imu, vo_cache, calib, trust, (np.zeros((0, 5)), 0.0) if two_pass else with_odo)
    # the GNSS latency by profile likelihood (blendgen.sync.latency): forward passes with it
    # fixed, from the smoothed initial state when there is one (the first pass's loose start
    # dominates its cost: comma2k19's profile then had its minimum at 0), then it stays fixed.
    # Both it and gnss.h_std_scale: auto need the fixes' horizontal noise scale their
    # innovations show (one forward pass at the given latency)
    want_latency = calib is not None and (pri.latency_auto or pri.latency_std_s > 0)
    want_scale = calib is not None and pri.h_std_auto
    h_scale = pri.h_std_scale if calib is not None else 1.0
    if want_latency:
        args = _with_latency(args, pri.latency_s)
    lat_prof, noise = None, None
    x0 = (p0, v0, R0, np.zeros(3), np.zeros(3))
    if (want_latency or want_scale) and not (smooth and use_imu):
        noise = _innovation_scale(rec, settings, cfg, x0, P0, args, road, h_scale)
        h_scale = noise if want_scale else h_scale
        if want_latency:
            lat_prof = _profile_latency(rec, settings, cfg, x0, P0, args, pri, road, noise)
            args = _with_latency(args, lat_prof.tau_s)
    res, x0_s, var0 = _filter_pass(rec, settings, cfg, x0, P0, *args, progress, road=road, h_scale=h_scale)
    res.summary["passes"] = 1
    if smooth and use_imu:
        # second pass, relinearised at the smoothed initial state. The accelerometer-bias prior
        # stays the original one (mean 0, calib.yaml imu.accelerometer_bias_std) and the tilt
        # prior no tighter than that bias allows: starting from the first pass's bias with a
        # tight prior counted the data twice and compounded the pitch / bias ambiguity
        # (comma2k19: -0.47 -> -0.96 m/s^2).
        p, v, R, bg = x0_s[:4]
        x1 = (p, v, R, bg, np.zeros(3))
        floor = np.concatenate([np.full(6, 1e-4), np.full(3, (acc_bias_std / 9.81) ** 2), np.full(3, 1e-8),
                                np.zeros(3)])
        P1 = np.maximum(var0[:15] * 4.0, floor)
        P1[12:15] = acc_bias_std**2
        if want_latency or want_scale:
            # position and velocity loose again: their smoothed values were fitted with the
            # prior latency, and a tight start would pull the profile towards it
            P_lat = P1.copy()
            P_lat[0:6] = P0[0:6]
            noise = _innovation_scale(rec, settings, cfg, x1, P_lat, args, road, h_scale)
            if want_latency:
                lat_prof = _profile_latency(rec, settings, cfg, x1, P_lat, args, pri, road, noise)
                args = _with_latency(args, lat_prof.tau_s)
            if want_scale:
                h_scale = noise
        if len(odo):
            # the odometer's scale starts from the first pass's speed: from its prior (1 +- 0.02)
            # the final pass integrated a 2 % wrong speed before the fixes pinned it, and the
            # smoother does not re-linearise (stop-and-go: 1.05 m off at the start)
            k0 = odometer.initial_scale(odo, res.speed_track)
            args = args[:_ARG_CALIB] + (args[_ARG_CALIB][:9] + (k0,),) + args[_ARG_CALIB + 1:_ARG_ODO] + (with_odo,)
        res2, x2_s, _ = _filter_pass(rec, settings, cfg, x1, P1, *args, False, road=road, h_scale=h_scale)
        if len(odo):
            # once more from this pass's own smoothed start: started from the pass without the
            # odometer, the filter took the pitch / accelerometer-bias split the speed contradicts
            # (x bias -0.29 m/s^2) and the smoother cannot re-linearise (stop-and-go: 0.23 m RMSE,
            # 1.1 m at the start; iterated 0.03 / 0.13 m)
            res2, _, _ = _filter_pass(rec, settings, cfg, (*x2_s[:4], np.zeros(3)), P1, *args, False, road=road,
                                      h_scale=h_scale)
        # keep the pass whose accelerometer bias sits closer to its prior (never the worse one)
        z1, z2 = (float(np.max(np.abs(r.summary["accel_bias"]))) / acc_bias_std for r in (res, res2))
        if z2 <= max(z1, 3.0):
            res = res2
            res.summary["passes"] = 2
        else:
            if want_latency or want_scale or len(odo):  # the first pass again, with what was estimated
                res, _, _ = _filter_pass(rec, settings, cfg, x0, P0, *args, False, road=road, h_scale=h_scale)
            res.summary["second_pass"] = f"discarded: accelerometer bias {z2:.1f} sigma from its prior (first {z1:.1f})"
    if lat_prof is not None:
        res.summary["calibration"]["gnss_latency_s"] = round(lat_prof.tau_s, 4)
        # None: the profile had no curvature (the drive says nothing about the latency)
        res.summary["calibration"]["gnss_latency_std_s"] = (round(lat_prof.std_s, 4) if np.isfinite(lat_prof.std_s)
                                                            else None)
        res.summary["calibration"]["gnss_latency_method"] = (
            "profile likelihood" + (", at the search limit" if lat_prof.at_limit else ""))
        res.summary["gnss_latency"] = lat_prof.summary()
    if calib is not None:
        res.summary["calibration"]["gnss_h_std_scale"] = round(float(h_scale), 3)
        if noise is not None:
            res.summary["calibration"]["gnss_h_std_scale_measured"] = round(float(noise), 3)
        C = calibration.fuse_camera_yaw(res.summary["calibration"], pri, R_bc, with_vo=use_vo)
        if C is not None:
            res.poses = [(fid, t, T @ make_pose(C, np.zeros(3))) for fid, t, T in res.poses]
    if use_vo:
        res.summary["vo_method"] = vo_method(settings, rec)
    if toff is not None:
        res.summary["camera_imu_time_offset"] = toff.summary()
    if readout is not None:
        res.summary["rolling_shutter"] = readout.summary()
    if trust is not None:
        res.summary["vo_trust"] = trust.summary()
        if trust.stabilised:
            # composites must follow the image: the body's camera turned by the stabiliser's correction
            res.poses = [(fid, t, T @ make_pose(C, np.zeros(3))) for (fid, t, T), C in zip(res.poses, trust.correction)]
    return res


READOUT_RELINEARISE = 4  # at most this many readout estimates with the time offset unknown too


def _estimate_readout(rec, settings, imu, out_t, R_bc, cfg, vo_cache: dict, progress: bool):
    """calib `rolling_shutter_s: auto`: VO without correction (inliers kept), the readout from
    VO against the gyro (`blendgen.sync.readout`), jointly with the time offset when that is
    `auto` too, then VO again with it when it is not 0. Returns (the recording with the readout
    used, the Readout report; its shift_s is from the calib offset)."""
    _vo_all(rec, settings, len(out_t), vo_cache, progress, keep_matches=True)
    results, gyro = [vo_cache.get(i) for i in range(len(out_t))], GyroIntegrator(imu, cfg.max_imu_dt)
    joint = rec.time_offset_estimate  # the time offset is unknown too: the two trade (r ~ 2 x shift)
    if not joint and assess(results, gyro.pair_rotations(out_t), R_bc, out_t, cfg.gyro_noise).stabilised:
        # the image does not turn with the body: VO against the gyro says nothing about rows
        ro = Readout(0.0, "not estimated", reason="the frames do not turn with the body at the calib time offset "
                                                  "(stabilised video, or a wrong timeshift_cam_imu)")
    else:
        # with the offset unknown, each candidate's shift is profiled out, and the gyro tables
        # of the correction are built again at the shift found until it settles (they move with it)
        moved, n = 0.0, READOUT_RELINEARISE if joint else 1
        for it in range(n):
            t_ref = np.asarray(out_t, float) + moved
            ro = estimate_readout(results, gyro, t_ref, R_bc, lambda r, t=t_ref: _rs_spins(imu, t, r, R_bc),
                                  rec.camera.height, shift_search_s=rec.time_offset_search_s if joint else 0.0)
            ro.shift_s += moved  # from the calib offset
            if ro.method != "estimated" or abs(ro.shift_s - moved) < 5e-4 or it == n - 1:
                break
            moved = ro.shift_s
    t_spin = np.asarray(out_t, float) + ro.shift_s  # where the gyro says the rows were read
    rec = replace(rec, rolling_shutter_s=ro.readout_s, rolling_shutter_estimate=False)
    if ro.readout_s > 0:
        vo_cache.clear()
        _vo_all(rec, settings, len(out_t), vo_cache, progress, _rs_spins(imu, t_spin, ro.readout_s, R_bc))
    _drop_matches(vo_cache)
    return rec, ro


def _drop_matches(vo_cache: dict) -> None:
    """After the readout estimate only refit_along needs inliers: the "rotation" pairs keep its
    subset (without it the filter took their translation-biased rotations), the rest none."""
    for r in vo_cache.values():
        if r is not None and r.matches is not None:
            r.matches = along_subset(*r.matches[2:]) if r.status == "rotation" else None


def _trust_and_time_offset(rec, results: list, imu, out_t_cam, out_t, R_bc, cfg):
    """(trust report, TimeOffset, frame times on the IMU clock). With `timeshift_cam_imu: auto`
    the offset is estimated from VO vs gyro (`blendgen.sync.time_offset`) leaving out the pairs
    the trust check flags; the check is then redone at the estimate, and the estimate once more
    with its flags. The offset comes first: a wrong one makes rigid frames look stabilised (a
    25 ms offset on a 1 deg shake: gain 0.76, disagreement 37x the noise); a real stabiliser is
    one whose frames still look stabilised at the estimated offset, which is then not used."""
    gyro = GyroIntegrator(imu, cfg.max_imu_dt)
    shift0 = float(rec.time_offset_cam_imu)

    def check(t):
        return assess(results, gyro.pair_rotations(t), R_bc, t, cfg.gyro_noise,
                      direction=rec.lens_source == "calibrated")

    trust = check(out_t)
    toff = TimeOffset(shift_s=shift0, calib_s=shift0, method="calib.yaml")
    if not rec.time_offset_estimate:
        return trust, toff, out_t
    looked_stabilised = trust.stabilised
    toff = estimate_time_offset(results, gyro, out_t_cam, R_bc, shift0, rec.time_offset_search_s, flags=trust.flags)
    for _ in range(2):
        if toff.method != "estimated":
            break
        t_new = out_t_cam + toff.shift_s
        trust_new = check(t_new)
        if trust_new.stabilised:
            toff = not_estimated(shift0, f"the frames look stabilised at the estimate ({toff.shift_s * 1e3:+.1f} ms) "
                                         "too: the image does not turn with the body")
            break
        if np.allclose(t_new, out_t):
            break
        out_t, trust = t_new, trust_new
        toff = estimate_time_offset(results, gyro, out_t_cam, R_bc, shift0, rec.time_offset_search_s,
                                    flags=trust.flags)
    if toff.method == "estimated" and looked_stabilised:
        toff.reason += "; at the calib value the frames looked stabilised: it was the time offset"
    elif looked_stabilised and "stabilised" not in toff.reason:
        toff.reason += "; the frames look stabilised (the image does not turn with the body)"
    return trust, toff, out_t


# positions in _filter_pass's argument tuple (built in _filter) and of the latency in `calib`
_ARG_SMOOTH, _ARG_CALIB, _ARG_ODO, _CALIB_LATENCY = 4, 18, 20, 2


def _with_latency(args: tuple, tau: float) -> tuple:
    """The filter-pass arguments with the GNSS latency fixed at tau (its prior std 0)."""
    c = args[_ARG_CALIB]
    calib = c[:_CALIB_LATENCY] + (float(tau), 0.0) + tuple(c[_CALIB_LATENCY + 2:])
    return args[:_ARG_CALIB] + (calib,) + args[_ARG_CALIB + 1:]


def _forward(rec, settings, cfg, x0, P0, args, road, tau: float, h_scale: float) -> dict:
    """Summary of one forward pass (no smoother: it does not change the likelihood) with the
    latency fixed at tau, without the odometer (the GNSS latency and noise are measured against
    the IMU's clock)."""
    a = _with_latency(args[:_ARG_SMOOTH] + (False,) + args[_ARG_SMOOTH + 1:_ARG_ODO] + ((np.zeros((0, 5)), 0.0),), tau)
    return _filter_pass(rec, settings, cfg, x0, P0, *a, False, road=road, h_scale=h_scale)[0].summary


def _innovation_scale(rec, settings, cfg, x0, P0, args, road, h_scale: float) -> float:
    """The factor on the fixes' stated horizontal noise that makes their horizontal innovations
    consistent (mean NIS 2 per fix) in a forward pass at the given latency: a receiver's own
    h_std_m is often pessimistic (comma2k19: 2.1 m stated, the innovations say 0.18 m; against
    the ground truth the fixes scatter 0.28 m about their mean offset, partly slow wander)."""
    s = _forward(rec, settings, cfg, x0, P0, args, road, args[_ARG_CALIB][_CALIB_LATENCY], h_scale)
    n = s["updates"].get("gnss", 0)
    if n < 10:
        return h_scale
    return float(np.clip(h_scale * np.sqrt(s["innovation_nis"]["gnss_h"] / (2.0 * n)), 0.05, 10.0))


def _profile_latency(rec, settings, cfg, x0, P0, args, pri, road, h_scale: float) -> LatencyProfile:
    """GNSS latency minimising the negative log-likelihood of all innovations of a forward
    pass run with the latency fixed, the fixes' horizontal noise scaled to what their
    innovations show (`_innovation_scale`): with comma2k19's stated 2.1 m the profile is flat
    (its minimum moved between 0 and 0.06 s with the start of the pass); scaled, it has a
    clear minimum."""
    def cost(tau: float) -> float:
        return float(sum(_forward(rec, settings, cfg, x0, P0, args, road, tau, h_scale)["innovation_nll"].values()))

    if pri.latency_auto:
        prof = profile_latency(cost, 0.0, pri.latency_max_s, step=LATENCY_STEP_S)
    else:
        lo, hi = pri.latency_s - 3 * pri.latency_std_s, pri.latency_s + 3 * pri.latency_std_s
        prof = profile_latency(cost, lo, hi, step=min(LATENCY_STEP_S, (hi - lo) / 4),
                               prior=(pri.latency_s, pri.latency_std_s))
    prof.gnss_noise_scale = h_scale
    return prof


def _vo_step(vo, img, spin=None) -> VoResult | None:
    """VO of the pair ending at `img`; a frame that does not decode (None) restarts the tracker."""
    if img is None:
        vo.reset()
        return None
    return vo.track(img, spin)


def _vo_all(rec, settings, n: int, cache: dict, progress: bool, spins=None, keep_matches: bool = False) -> None:
    vo = make_vo(rec.camera, _vo_config(settings, rec, keep_matches))
    frames = _frames(rec)
    bar = _Bar(progress, n, "VO")
    for i in range(n):
        cache[i] = _vo_step(vo, next(frames)[1], spins[i] if spins is not None else None)
        bar.update(1)
    bar.close()


def _height_error_correlation_s(gt_t, g_xyz, window_s: float = 20.0, max_s: float = 30.0) -> float:
    """How long the GNSS height errors stay correlated: the lag at which the autocorrelation of
    the fixes' heights about their 20 s moving average drops below 1/e (white noise: one fix).
    Measured on the fixes alone, so a wrong filter cannot talk itself into distrusting them."""
    if len(gt_t) < 20:
        return 1.0
    dt = float(np.median(np.diff(gt_t)))
    n_win = max(3, int(window_s / dt) | 1)
    z = g_xyz[:, 2]
    pad = np.pad(z, n_win // 2, mode="edge")
    r = z - np.convolve(pad, np.ones(n_win) / n_win, mode="valid")
    r = r - r.mean()
    n = len(r)
    acf = np.correlate(r, r, mode="full")[n - 1:] / max(float(r @ r), 1e-12)
    below = np.flatnonzero(acf < np.exp(-1.0))
    lag = int(below[0]) if below.size else n
    return float(np.clip(lag * dt, dt, max_s))


# a "rotation" VO pair is refitted along the filter's direction of travel (vo.refit_along) once
# the camera moved this far between the frames (any direction fits a camera that stood still)
ALONG_MIN_M = 1e-3
GNSS_REOPEN_S = 10.0   # fixes rejected this long, agreeing with each other: the filter drifted
# in a GNSS outage (no fix for GNSS_GAP_S, or 3 fix intervals if longer) the IMU's white noise counts GAP_IMU_NOISE times
# its stated density: the drift that dead reckoning builds up must fit the fixes after the gap,
# or they are rejected (comma2k19 without fixes 10-50 s: 70 of the last 100 rejected, 0.90 m;
# x3: 0.53 m; x10: 1.39 m). A stated density is a lower bound for a phone-grade IMU.
GNSS_GAP_S, GAP_IMU_NOISE = 2.0, 3.0


def _gnss_reopen(streak: list, std: float) -> np.ndarray | None:
    """The latest residual (fix - filter) when the fixes rejected in a row span GNSS_REOPEN_S and
    those of the last GNSS_REOPEN_S agree with each other (about a straight line in time, within
    2 sigma horizontally: one consistent story, not multipath scatter); else None."""
    if len(streak) < 10 or streak[-1][0] - streak[0][0] < GNSS_REOPEN_S:
        return None
    t = np.array([a for a, _ in streak])
    r = np.array([b for _, b in streak])
    keep = t >= t[-1] - GNSS_REOPEN_S
    t, r = t[keep], r[keep]
    if len(t) < 10:
        return None
    A = np.column_stack([np.ones(len(t)), t - t[-1]])
    coef, *_ = np.linalg.lstsq(A, r[:, :2], rcond=None)
    rms = np.sqrt(np.mean(np.sum((r[:, :2] - A @ coef) ** 2, axis=1)))
    return r[-1] if rms < 2.0 * std else None


def _filter_pass(rec, settings, cfg, x0, P0, t_start, use_imu, use_gnss, use_vo, smooth, ids, out_t, out_t_cam,
                 gt_t, g_xyz, g_inside, g_yaw, g_std, R_bc, p_bc, fwd, imu, vo_cache, calib, trust: TrustReport | None,
                 odometer, progress, road=None, h_scale: float = 1.0):
    """One filter pass (+ RTS smoother when `smooth`). h_scale multiplies the fixes'
    horizontal noise (calib.yaml gnss.h_std_scale); odometer: (odometer.means rows, std m/s)."""
    p0, v0, R0, bg0, ba0 = x0
    lens = rec.lens_source
    ekf = ErrorStateEkf(cfg, t_start, p0, v0, R0, P0, use_imu=use_imu)
    if calib is not None:
        ekf.enable_calibration(*calib)
    ekf.yaw_only_motion = not use_imu and not use_vo
    if use_imu:
        ekf.bg, ekf.ba = bg0.copy(), ba0.copy()
    if smooth:
        ekf.history = []
    marks = [ekf.mark()] if smooth else []

    stationary = _stationary_imu(imu, cfg) if use_imu else np.zeros(0, bool)
    next_nhc_t = next_road_t = -np.inf
    gnss_streak: list[tuple[float, np.ndarray]] = []  # fixes rejected in a row
    # GNSS height errors can be slow (comma2k19: 15 m swings over 10 s): with the car held on
    # the road surface (vehicle-frame constraint), fixes within their correlation time z_corr_s
    # (measured on the fixes) count as one height measurement, else the height -- and
    # through it the pitch -- follows the receiver's wander (vertical std 2x horizontal)
    rate = 1.0 / max(float(np.median(np.diff(gt_t))), 1e-3) if len(gt_t) > 1 else 1.0
    z_corr_s = _height_error_correlation_s(gt_t, g_xyz) if calib is not None else 0.0
    z_scale = 2.0 * np.sqrt(max(z_corr_s * rate, 1.0))
    # the vehicle constraints ride on the fixes; beyond 3 fix intervals without one, on the IMU's clock
    last_fix_t = float(gt_t[0]) if use_gnss and len(gt_t) else np.inf
    fix_gap_s = 3.0 / rate

    # --- event queue: (time, order, kind, index); order makes IMU come before others at equal t
    odo, odo_std = odometer
    if calib is None:  # a forward speed needs the vehicle frame
        odo = np.zeros((0, 5))
    ev_t = [imu[1:, 0], gt_t if use_gnss else np.zeros(0), out_t, odo[:, 0]]
    ev_k = [np.zeros(max(len(imu) - 1, 0), int), np.ones(len(gt_t) if use_gnss else 0, int),
            np.full(len(out_t), 2), np.full(len(odo), 3)]
    ev_i = [np.arange(1, len(imu)), np.arange(len(gt_t) if use_gnss else 0), np.arange(len(out_t)),
            np.arange(len(odo))]
    T = np.concatenate(ev_t)
    K = np.concatenate(ev_k)
    I = np.concatenate(ev_i)
    order = np.lexsort((K, T))

    poses, covs, quality = [], [], []
    pending = []  # flags since the last pose
    last_zupt_t = -np.inf
    clone_i = -1  # frame whose image the clone belongs to
    last = None  # latest IMU sample: carries the state to a GNSS fix or frame between samples

    def vehicle_constraints(t, speed):
        nonlocal next_road_t, next_nhc_t
        if road is not None and t >= next_road_t:
            pending.append("road" if road_height.apply(ekf, road, p_bc) else "road_rejected")
            next_road_t = t + road_height.EVERY_S
        if calib is not None and speed > NHC_MIN_SPEED and t >= next_nhc_t:
            # the car neither slides sideways nor leaves the road (in the vehicle frame, the
            # mount estimated) and is level across on average: this is what separates the
            # mount from the heading and from the accelerometer bias
            ekf.update_vehicle_velocity(NHC_LAT_STD, NHC_UP_STD)
            ekf.update_vehicle_level(LEVEL_STD)
            next_nhc_t = t + NHC_EVERY_S

    def advance(t):
        if last is not None and 0 < t - ekf.t <= cfg.max_imu_dt:
            ekf.propagate_imu(t, last[1:4], last[4:7])
        else:
            ekf.propagate_to(t)

    bar = _Bar(progress, len(out_t), "sync")
    for j in order:
        t, kind, i = float(T[j]), int(K[j]), int(I[j])
        if kind == 0:
            a, b = imu[i - 1], imu[i]
            if ekf.t < a[0]:  # first sample after a start before the IMU: bridge
                ekf.propagate_to(a[0])
            ekf.propagate_imu(b[0], 0.5 * (a[1:4] + b[1:4]), 0.5 * (a[4:7] + b[4:7]))
            last = b
            if b[0] - a[0] > cfg.max_imu_dt:
                pending.append("imu_gap")
            if stationary[i] and np.linalg.norm(ekf.v) < 0.5 and t - last_zupt_t > 0.1:
                ekf.update_zero_velocity(0.02)
                ekf.update_zero_rate(b[1:4], 3 * cfg.gyro_noise * np.sqrt(1.0 / cfg.max_imu_dt))
                last_zupt_t = t
                pending.append("zupt")
            ekf.noise_scale = GAP_IMU_NOISE**2 if t - last_fix_t > max(GNSS_GAP_S, fix_gap_s) else 1.0
            if t - last_fix_t > fix_gap_s:
                # the vehicle's constraints hold without GNSS too: while the fixes are missing
                # they follow the IMU's clock (applied only at fixes, a 32 s dropout lost the
                # synthetic drive: 271 m off and every fix after it rejected; now 0.5 m)
                vehicle_constraints(t, float(np.linalg.norm(ekf.v[:2])))
        elif kind == 1:
            advance(t)
            s = float(g_std[i]) * (1.0 if g_inside[i] else 3.0)
            # an antenna height estimated from the fixes is their vertical information: no double count
            sz = 1e3 if road is not None and road.replaces_fix_heights else s * z_scale
            s *= h_scale
            ok = ekf.update_position(g_xyz[i], (s, s, sz), kind="gnss")
            if ok:
                gnss_streak.clear()
            else:
                gnss_streak.append((t, g_xyz[i] - ekf.p))
                r = _gnss_reopen(gnss_streak, s)
                if r is not None:  # the filter drifted, not the fixes: widen it, take the fix
                    ekf.reopen(r**2 + s**2, float(r @ r) / GNSS_REOPEN_S**2)
                    ok = ekf.update_position(g_xyz[i], (s, s, sz), kind="gnss")
                    pending.append("gnss_reopened")
                    gnss_streak.clear()
            pending.append("gnss" if ok else "gnss_rejected")
            speed = float(np.linalg.norm(ekf.v[:2]))
            last_fix_t = t
            vehicle_constraints(t, speed)
            if not g_inside[i]:
                pending.append("lut_outside")
            if not use_imu and not use_vo:
                # GNSS alone: the camera is taken to look along the heading column, else along
                # the velocity the fixes imply (when moving fast enough for it to mean much)
                if np.isfinite(g_yaw[i]):
                    ekf.update_yaw(g_yaw[i], fwd, 0.1)
                elif speed > 2.0:
                    ekf.update_yaw(float(np.arctan2(ekf.v[1], ekf.v[0])), fwd, 0.05 + 1.0 / speed)
        elif kind == 3:
            advance(t)
            pending.append("speed" if ekf.update_vehicle_speed(float(odo[i, 1]), odo_std, odo[i, 2:5])
                           else "speed_rejected")
        else:
            advance(t)
            flags = pending
            pending = []
            res = None
            if use_vo:
                res = vo_cache[i]  # VO ran over all frames before the filter (_filter)
                if res is None:
                    flags.append("decode_failed")
                elif res.status == "repeated":
                    # a duplicated frame (encoder repeat) says nothing about motion: no update,
                    # and the clone stays at the frame whose image this is
                    flags.append("repeated_frame")
                elif trust is not None and trust.stabilised and res.has_rotation:
                    # the image turns with the stabiliser, not the body: take the estimated
                    # correction out (image camera -> body camera) and use what is left
                    if ekf.has_clone and clone_i >= 0:
                        C0, C1 = trust.correction[clone_i], trust.correction[i]
                        rot_cov, dir_cov = vo_noise(res, lens)
                        u = C0 @ res.u_dir if dir_cov is not None else None
                        if u is not None:
                            dir_cov = C0 @ dir_cov @ C0.T + trust.correction_std**2 * (np.eye(3) - np.outer(u, u))
                        ok = ekf.update_relative(C0 @ res.R_c1c2 @ C1.T, u, R_bc, p_bc, C1 @ rot_cov @ C1.T,
                                                 dir_cov if u is not None else None)
                        flags.append("vo_destabilised" if ok else "vo_rejected")
                elif trust is not None and trust.flags[i] is not None:
                    flags.append("vo_" + trust.flags[i])  # disagrees with the gyro over this pair
                else:
                    if res.has_rotation and ekf.has_clone:
                        # noise from this pair's own fit (inliers, residuals, parallax), not a constant
                        rot_std, dir_std = vo_noise(res, lens)
                        # features that do not move mean "standing" only if the IMU agrees and
                        # the filter is slow: a far scene (highway, drone) barely moves either
                        imu_quiet = (not use_imu) or bool(
                            stationary[min(np.searchsorted(imu[:, 0], t), len(imu) - 1)])
                        if res.stationary and imu_quiet and np.linalg.norm(ekf.v) < 1.0:
                            ekf.update_zero_velocity(0.05)
                            flags.append("zupt")
                        R_vo = res.R_c1c2
                        if res.status == "rotation" and res.matches is not None:
                            d = ekf.predicted_travel(R_bc, p_bc)
                            if np.linalg.norm(d) > ALONG_MIN_M:
                                R_vo = refit_along(res, d)
                        ok = ekf.update_relative(R_vo, res.u_dir if res.has_direction else None,
                                                 R_bc, p_bc, rot_std, dir_std)
                        flags.append("vo" if ok else "vo_rejected")
                    elif res.status not in ("first",):
                        flags.append("vo_failed")
                if res is None or res.status != "repeated":
                    ekf.clone()
                    clone_i = i
            if smooth:
                marks.append(ekf.mark())
            T_wb = make_pose(ekf.R, ekf.p)
            T_wc = T_wb @ make_pose(R_bc, p_bc)
            poses.append((ids[i], float(out_t_cam[i]), T_wc))
            c = ekf.cov_diag()
            covs.append(np.concatenate([c[0:3], c[6:9]]))
            quality.append(_quality(res, flags))
            if not ekf.healthy():
                raise StageError(f"filter became numerically unstable at t={t:.3f}")
            bar.update(1)
    bar.close()
    x0_s, var0, speed_track = None, None, None
    if smooth:
        T_bc = make_pose(R_bc, p_bc)
        sm = ekf.smooth(marks)
        x0_s, var0 = sm[0]
        speed_track = np.array([[t, (post[5].T @ post[2].T @ post[1])[0]] for t, (post, _) in zip(out_t, sm[1:])])
        for k, ((p, v, R, *_), var) in enumerate(sm[1:]):
            if np.all(np.isfinite(p)) and np.all(np.isfinite(R)):
                poses[k] = (poses[k][0], poses[k][1], make_pose(R, p) @ T_bc)
                covs[k] = np.concatenate([var[0:3], var[6:9]])
    st = ekf.stats
    P = ekf.P[:NC, :NC]
    summary = {"cov_min_eig": float(np.linalg.eigvalsh(0.5 * (P + P.T)).min()),
               "cov_asym": float(np.abs(P - P.T).max()), "imu_steps": st.imu_steps, "imu_gaps": st.imu_gaps,
               "imu_saturated": st.saturated,
               "updates": dict(st.updates), "rejected": dict(st.rejected),
               "innovation_nll": {k: round(v, 3) for k, v in st.nll.items()},
               "innovation_nis": {k: round(v, 3) for k, v in st.nis.items()},
               "gyro_bias": ekf.bg.round(5).tolist(), "accel_bias": ekf.ba.round(4).tolist(),
               "vo_status": _count(q["vo_status"] for q in quality)}
    if calib is not None:
        # constant states: the last filtered estimate is the smoothed one
        summary["gnss_height_corr_s"] = round(z_corr_s, 2)
        if road is not None:
            summary["road_height"] = road.summary()
        state = (ekf.R_bv, ekf.tau, ekf.lever) + ((ekf.speed_scale, ekf.speed_latency) if len(odo) else ())
        summary["calibration"] = calibration.report(state, np.diag(ekf.P)[CALIB], R_bc)
    return SyncResult(poses, np.array(covs).reshape(-1, 6), quality, summary, speed_track), x0_s, var0


def _vo_only(rec, settings, ids, out_t_cam, R_bc, progress) -> SyncResult:
    """Camera only: chain relative poses; scale from the assumed speed (flag scale_unknown)."""
    vo = make_vo(rec.camera, _vo_config(settings, rec))
    R_wc = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # level, looking along +x
    T = make_pose(R_wc, np.zeros(3))
    last_step, last_dir = None, None
    t_last = float(out_t_cam[0]) if len(out_t_cam) else 0.0
    poses, covs, quality = [], [], []
    bar = _Bar(progress, len(out_t_cam), "sync (VO only)")
    var_p, var_r = 0.0, 0.0
    for (i, img), t in zip(_frames(rec), out_t_cam):
        flags = ["scale_unknown"]
        res = None
        if img is None:
            flags.append("decode_failed")
            vo.reset()
        else:
            res = vo.track(img)
        dt = t - t_last if i > 0 else 0.0
        if res is not None and res.status == "repeated":
            flags.append("repeated_frame")  # same image as before: hold the pose, time runs on
            poses.append((ids[i], float(t), T.copy()))
            covs.append(np.array([var_p] * 3 + [var_r] * 3))
            quality.append(_quality(res, flags))
            bar.update(1)
            continue
        t_last = t
        if res is not None and res.has_rotation and i > 0:
            if res.has_direction:
                step = make_pose(res.R_c1c2, res.u_dir * settings.vo_speed_mps * dt)
                last_dir = res.u_dir
            elif res.stationary or last_dir is None:
                step = make_pose(res.R_c1c2, np.zeros(3))
            else:  # no parallax while driving (far scene): keep the last direction of travel
                step = make_pose(res.R_c1c2, last_dir * settings.vo_speed_mps * dt)
                flags.append("vo_direction_held")
            last_step = step
        elif i > 0:
            flags.append("vo_failed")
            step = last_step if last_step is not None else np.eye(4)  # constant-velocity bridge
            var_p += 1.0
        else:
            step = np.eye(4)
        T = T @ step
        var_p += (0.05 * settings.vo_speed_mps * dt) ** 2
        var_r += 0.004**2
        poses.append((ids[i], float(t), T.copy()))
        covs.append(np.array([var_p] * 3 + [var_r] * 3))
        quality.append(_quality(res, flags))
        bar.update(1)
    bar.close()
    return SyncResult(poses, np.array(covs).reshape(-1, 6), quality,
                      {"vo_status": _count(q["vo_status"] for q in quality)})


def _count(items) -> dict:
    out: dict = {}
    for x in items:
        out[x] = out.get(x, 0) + 1
    return out


class _Bar:
    """A console bar (tqdm) that also tells run_sync's `on_progress`."""

    def __init__(self, progress: bool, total: int, desc: str):
        from tqdm import tqdm

        self.tq = tqdm(total=total, desc=desc, unit="pose", disable=not progress or total < 50, leave=False)
        self.report, self.desc, self.total, self.n = _REPORT.get(), desc, total, 0
        if self.report is not None:
            self.report(0, desc, total)

    def update(self, k: int) -> None:
        self.tq.update(k)
        self.n += k
        if self.report is not None:
            self.report(self.n, self.desc, self.total)

    def close(self) -> None:
        self.tq.close()


def _check_finite(result: SyncResult) -> None:
    for fid, t, T in result.poses:
        if not np.all(np.isfinite(T)):
            raise StageError(f"pose of {fid} (t={t}) is not finite")


# ----------------------------------------------------------------------------- output

def write_poses(out_dir: Path, result: SyncResult) -> None:
    lines = [",".join(POSES_COLUMNS)]
    tum = []
    last = (None, None)  # a ground-plane job's frames share one pose object: one quaternion
    for (fid, t, T), c, q in zip(result.poses, result.cov, result.quality):
        x, y, z = T[:3, 3]
        if T is not last[0]:
            last = (T, matrix_to_quat(T[:3, :3]))
        qw, qx, qy, qz = last[1]
        lines.append(",".join([f"{t:.6f}", f"{x:.6f}", f"{y:.6f}", f"{z:.6f}", f"{qw:.9f}", f"{qx:.9f}",
                               f"{qy:.9f}", f"{qz:.9f}", *(f"{v:.6g}" for v in c), q["vo_status"],
                               str(q["vo_inliers"]), f"{q['vo_parallax_px']:.2f}", "|".join(q["flags"]), fid]))
        tum.append(f"{t:.6f} {x:.6f} {y:.6f} {z:.6f} {qx:.9f} {qy:.9f} {qz:.9f} {qw:.9f}")
    atomic.write_text(out_dir / "poses.csv", "\n".join(lines) + "\n")
    atomic.write_text(out_dir / "poses.tum", "\n".join(tum) + ("\n" if tum else ""))


def read_poses(path: Path, rec: Recording | None = None) -> list:
    """poses.csv -> [(frame_id, t, T_world_cam)] (for stages that resume from disk)."""
    from blendgen.geometry import pose_from_xyz_quat

    path = Path(path)
    if not path.is_file():
        raise UserError("poses.csv not found (run `blendgen sync` first)", where=str(path))
    rows = path.read_text().splitlines()
    header = rows[0].split(",")
    if header[:8] != POSES_COLUMNS[:8]:
        raise UserError(f"unexpected header {header[:8]}; expected {POSES_COLUMNS[:8]}", where=str(path))
    fi = header.index("frame_id") if "frame_id" in header else None
    out = []
    for k, ln in enumerate(rows[1:]):
        parts = ln.split(",")
        vals = [float(v) for v in parts[:8]]
        fid = parts[fi] if fi is not None else f"f{k:06d}"
        out.append((fid, vals[0], pose_from_xyz_quat(vals[1:4], vals[4:8])))
    return out
