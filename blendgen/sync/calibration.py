"""Priors for the quantities sync estimates (calib.yaml `vehicle:` and `gnss:`), and their report.

calib.yaml (all optional; the defaults below are the priors when a key is absent):

    vehicle:
      mount_std_deg: [2.0, 5.0, 2.0]  # roll, pitch, yaw of the vehicle frame in the IMU frame
      camera_height_m: 1.45            # camera centre above the road (with a twin: road-height constraint)
      speed_std_mps: 0.1               # odometer (speed.csv) noise of a 0.1 s mean of its readings
      speed_scale_std: 0.02            # prior std of the odometer's scale (tyre radius), estimated
      speed_latency_s: auto            # a reading stamped t is the speed at t - latency; `auto`:
                                       # estimated (prior 0 +- 0.2 s; blendgen.sync.odometer)
      camera_yaw_deg: 0.77             # the camera's yaw in the vehicle (> 0 looks left), measured
                                       # without the IMU: the lane markings' vanishing point in a
                                       # frame (blendgen.analysis.lane_direction), a calibration target
      camera_yaw_std_deg: 0.5          # its 1-sigma
      T_cam_imu_yaw_std_deg: 0.0       # how well T_cam_imu's yaw is known (0: calibrated)
    gnss:
      latency_s: 0.0                   # a fix stamped t is the antenna's position at t - latency;
                                       # `auto`: estimated (profile likelihood over 0..latency_max_s)
      latency_std_s: 0.0             # > 0 estimates it with this prior about latency_s (e.g. 0.05)
      latency_max_s: 0.4             # search range of `auto`
      h_std_scale: 1.0                 # times the fixes' stated horizontal noise (gnss.csv h_std_m);
                                       # `auto`: the scale their innovations show (mean NIS 2 per fix)
      lever_arm_m: [0.0, 0.0, 0.0]     # antenna in the vehicle frame (x forward, y left, z up)
      lever_arm_std_m: 0.0           # > 0 estimates it (e.g. 0.3)

The vehicle frame (x forward, y left, z up) is the frame in which the car neither slides
sideways nor leaves the road; its nominal orientation in the IMU frame is built from the
camera's optical axis (forward) and gravity at the start (up), and the filter estimates the
rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from blendgen.errors import UserError

# the optical axis is pointed roughly along the road by whoever mounted the camera: a few
# degrees of pitch are normal; yaw is held tighter because on a straight drive only the car's
# acceleration observes it (and the prior then decides); roll comes from the level-on-average road
DEFAULT_MOUNT_STD_DEG = (2.0, 5.0, 2.0)


@dataclass
class CalibPriors:
    mount_std: np.ndarray  # rad, roll/pitch/yaw
    latency_s: float = 0.0
    latency_std_s: float = 0.0
    lever_arm_v: np.ndarray = None  # vehicle frame
    lever_arm_std_m: float = 0.0
    camera_height_m: float | None = None  # camera centre above the road surface
    latency_auto: bool = False  # `latency_s: auto`: estimated with a flat prior on [0, latency_max_s]
    latency_max_s: float = 0.4
    h_std_scale: float = 1.0  # times the stated horizontal fix noise
    h_std_auto: bool = False  # `h_std_scale: auto`: measured from the innovations
    speed_std_mps: float = 0.1  # odometer noise (speed.csv), m/s per 0.1 s mean
    speed_scale_std: float = 0.02  # prior std of the odometer's scale factor
    speed_latency_s: float = 0.0
    speed_latency_auto: bool = True
    camera_yaw_deg: float | None = None  # the camera's yaw in the vehicle, measured without the IMU
    camera_yaw_std_deg: float = 0.5
    t_cam_imu_yaw_std_deg: float = 0.0


def _vec(section: dict, key: str, n: int, default, where: str) -> np.ndarray:
    v = section.get(key, default)
    try:
        arr = np.asarray(v, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        arr = np.zeros(0)
    if arr.size == 1 and n > 1:
        arr = np.full(n, float(arr[0]))
    if arr.size != n or not np.all(np.isfinite(arr)):
        raise UserError(f"{key}: expected {n} finite number(s), got {v!r}", where=where)
    return arr


def read_priors(rec) -> CalibPriors:
    where = str(rec.root / "calib.yaml") if rec.root is not None else "calib.yaml"
    out = []
    for name in ("vehicle", "gnss"):
        sec = rec.extra.get(name) or {}
        if not isinstance(sec, dict):
            raise UserError(f"{name}: expected a mapping, got {sec!r}", where=where)
        out.append(sec)
    veh, gnss = out
    mount = np.radians(_vec(veh, "mount_std_deg", 3, DEFAULT_MOUNT_STD_DEG, where + " vehicle"))
    auto = isinstance(gnss.get("latency_s"), str) and gnss["latency_s"].strip().lower() == "auto"
    if isinstance(gnss.get("latency_s"), str) and not auto:
        raise UserError(f"latency_s: expected seconds or 'auto', got {gnss['latency_s']!r}", where=where + " gnss")
    lat = 0.0 if auto else _vec(gnss, "latency_s", 1, 0.0, where + " gnss")[0]
    lat_std = _vec(gnss, "latency_std_s", 1, 0.0, where + " gnss")[0]
    lat_max = _vec(gnss, "latency_max_s", 1, 0.4, where + " gnss")[0]
    if not 0.0 < lat_max <= 2.0:
        raise UserError(f"latency_max_s: expected seconds in (0, 2], got {lat_max}", where=where + " gnss")
    lever = _vec(gnss, "lever_arm_m", 3, [0.0, 0.0, 0.0], where + " gnss")
    lever_std = _vec(gnss, "lever_arm_std_m", 1, 0.0, where + " gnss")[0]
    if np.any(mount < 0) or lat_std < 0 or lever_std < 0:
        raise UserError("standard deviations must not be negative", where=where)
    sc = gnss.get("h_std_scale", 1.0)
    h_auto = isinstance(sc, str) and sc.strip().lower() == "auto"
    if isinstance(sc, str) and not h_auto:
        raise UserError(f"h_std_scale: expected a number or 'auto', got {sc!r}", where=where + " gnss")
    h_scale = 1.0 if h_auto else float(_vec(gnss, "h_std_scale", 1, 1.0, where + " gnss")[0])
    if not 0.01 <= h_scale <= 100.0:
        raise UserError(f"h_std_scale: expected a factor in [0.01, 100], got {h_scale}", where=where + " gnss")
    cam_h = None
    if veh.get("camera_height_m") is not None:
        cam_h = float(_vec(veh, "camera_height_m", 1, 0.0, where + " vehicle")[0])
        if not 0.0 < cam_h < 10.0:
            raise UserError(f"camera_height_m: expected metres above the road in (0, 10), got {cam_h}",
                            where=where + " vehicle")
    sp_std = _vec(veh, "speed_std_mps", 1, 0.1, where + " vehicle")[0]
    sp_scale = _vec(veh, "speed_scale_std", 1, 0.02, where + " vehicle")[0]
    if not (0.0 < sp_std <= 10.0 and 0.0 <= sp_scale <= 0.5):
        raise UserError(f"speed_std_mps / speed_scale_std: expected m/s in (0, 10] and a fraction in [0, 0.5], "
                        f"got {sp_std} / {sp_scale}", where=where + " vehicle")
    sl = veh.get("speed_latency_s", "auto")
    sl_auto = isinstance(sl, str) and sl.strip().lower() == "auto"
    if isinstance(sl, str) and not sl_auto:
        raise UserError(f"speed_latency_s: expected seconds or 'auto', got {sl!r}", where=where + " vehicle")
    sl = 0.0 if sl_auto else float(_vec(veh, "speed_latency_s", 1, 0.0, where + " vehicle")[0])
    if abs(sl) > 2.0:
        raise UserError(f"speed_latency_s: expected seconds in [-2, 2], got {sl}", where=where + " vehicle")
    cam_yaw = None
    if veh.get("camera_yaw_deg") is not None:
        cam_yaw = float(_vec(veh, "camera_yaw_deg", 1, 0.0, where + " vehicle")[0])
        if abs(cam_yaw) > 45.0:
            raise UserError(f"camera_yaw_deg: expected degrees in [-45, 45], got {cam_yaw}", where=where + " vehicle")
    yaw_std = _vec(veh, "camera_yaw_std_deg", 1, 0.5, where + " vehicle")[0]
    t_std = _vec(veh, "T_cam_imu_yaw_std_deg", 1, 0.0, where + " vehicle")[0]
    if not (0.0 < yaw_std <= 45.0 and 0.0 <= t_std <= 45.0):
        raise UserError(f"camera_yaw_std_deg / T_cam_imu_yaw_std_deg: expected degrees in (0, 45] and [0, 45], "
                        f"got {yaw_std} / {t_std}", where=where + " vehicle")
    return CalibPriors(mount, float(lat), float(lat_std), lever, float(lever_std), cam_h,
                       latency_auto=auto, latency_max_s=float(lat_max), h_std_scale=h_scale, h_std_auto=h_auto,
                       speed_std_mps=float(sp_std), speed_scale_std=float(sp_scale), speed_latency_s=sl,
                       speed_latency_auto=sl_auto, camera_yaw_deg=cam_yaw, camera_yaw_std_deg=float(yaw_std),
                       t_cam_imu_yaw_std_deg=float(t_std))


def road_vehicle(rec) -> bool:
    """calib.yaml `vehicle: {road_vehicle: false}`: the recording says its sensors were not on a
    road vehicle (the GoPro importer writes it for Karma drone telemetry), so the vehicle-frame
    constraints and the calibration states are off whatever the job says."""
    veh = rec.extra.get("vehicle") or {}
    v = veh.get("road_vehicle", True) if isinstance(veh, dict) else True
    if not isinstance(v, bool):
        where = str(rec.root / "calib.yaml") if rec.root is not None else "calib.yaml"
        raise UserError(f"road_vehicle: expected true or false, got {v!r}", where=where + " vehicle")
    return v


def nominal_vehicle_frame(forward_b: np.ndarray, up_b: np.ndarray) -> np.ndarray:
    """R_body_vehicle with x along the forward axis made horizontal, z up."""
    z = up_b / np.linalg.norm(up_b)
    x = forward_b - z * (z @ forward_b)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def camera_mount_angles(R_bv: np.ndarray, R_bc: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) in degrees of the camera relative to the vehicle: pitch > 0 looks
    down, yaw > 0 looks left, roll > 0 turns the image clockwise."""
    R_vc = R_bv.T @ R_bc
    z, x = R_vc[:, 2], R_vc[:, 0]
    pitch = np.arcsin(np.clip(-z[2], -1, 1))
    yaw = np.arctan2(z[1], z[0])
    roll = np.arcsin(np.clip(-x[2], -1, 1))
    return np.degrees([roll, pitch, yaw])


def fuse_camera_yaw(cal: dict, pri: CalibPriors, R_bc: np.ndarray, with_vo: bool) -> np.ndarray | None:
    """calib.yaml `vehicle.camera_yaw_deg`: the camera's yaw in the vehicle measured without
    the IMU, fused with the one the estimated IMU mount and T_cam_imu give. Without video,
    nothing in sync sees the camera itself, so the latter is uncertain by the mount's yaw and
    T_cam_imu's (`T_cam_imu_yaw_std_deg`); with VO the camera's direction of travel was seen,
    and only the mount's counts. The difference turns the camera about the vehicle's up axis
    (a correction of T_cam_imu's yaw; the IMU's own orientation, used by the filter, stays).
    Returns C to right-multiply every camera rotation with (None: nothing measured), and
    records both yaws and the result in `cal`."""
    if pri.camera_yaw_deg is None:
        return None
    y_chain, s_mount = cal["camera_mount_rpy_deg"][2], cal["mount_std_deg"][2]
    var_chain = s_mount**2 + (0.0 if with_vo else pri.t_cam_imu_yaw_std_deg**2)
    var_meas = pri.camera_yaw_std_deg**2
    y = y_chain + var_chain / (var_chain + var_meas) * (pri.camera_yaw_deg - y_chain)
    R_bv = np.asarray(cal["imu_to_vehicle_R"]).T
    a = np.radians(y - y_chain)
    Rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    C = R_bc.T @ R_bv @ Rz @ R_bv.T @ R_bc
    cal["camera_yaw"] = {
        "measured_deg": round(pri.camera_yaw_deg, 3), "measured_std_deg": round(pri.camera_yaw_std_deg, 3),
        "imu_chain_deg": round(y_chain, 3), "imu_chain_std_deg": round(float(np.sqrt(var_chain)), 3),
        "yaw_deg": round(float(y), 3),
        "yaw_std_deg": round(float(np.sqrt(var_chain * var_meas / (var_chain + var_meas))), 3)}
    cal["camera_mount_rpy_deg"] = np.round(camera_mount_angles(R_bv, R_bc @ C), 3).tolist()
    return C


def describe(cal: dict) -> str:
    """One line for the command: the estimated mount, latency and lever arm with 1-sigma."""
    r, p, y = cal["camera_mount_rpy_deg"]
    sr, sp, sy = cal["mount_std_deg"]
    cy = cal.get("camera_yaw")
    yaw = (f"yaw {y:+.2f} +- {sy:.2f} deg (left)" if cy is None else
           f"yaw {cy['yaw_deg']:+.2f} +- {cy['yaw_std_deg']:.2f} deg (left; measured {cy['measured_deg']:+.2f} +- "
           f"{cy['measured_std_deg']:.2f}, IMU mount and T_cam_imu {cy['imu_chain_deg']:+.2f} +- "
           f"{cy['imu_chain_std_deg']:.2f})")
    out = f"camera in vehicle: pitch {p:+.2f} +- {sp:.2f} deg (down), {yaw}, roll {r:+.2f} +- {sr:.2f} deg"
    tau, st = cal["gnss_latency_s"], cal["gnss_latency_std_s"]
    how = f" ({cal['gnss_latency_method']})" if cal.get("gnss_latency_method") else ""
    if st is None:  # estimated, but the profile was flat
        out += f"; GNSS latency {tau:+.3f} s, undetermined (flat profile){how}"
    else:
        out += (f"; GNSS latency {tau:+.3f} +- {st:.3f} s{how}" if st > 0 else
                f"; GNSS latency {tau:.3f} s as given (set gnss.latency_s: auto in calib.yaml to estimate it)")
    if "gnss_h_std_scale_measured" in cal or cal.get("gnss_h_std_scale", 1.0) != 1.0:
        m = cal.get("gnss_h_std_scale_measured")
        out += f"; fix noise x{cal.get('gnss_h_std_scale', 1.0):.3f} of gnss.csv's" + (
            f" (the innovations say x{m:.3f})" if m is not None else "")
    la, ls = cal["lever_arm_m"], cal["lever_arm_std_m"]
    lever = f"[{la[0]:+.2f}, {la[1]:+.2f}, {la[2]:+.2f}] m"
    out += f"; lever arm {lever} +- {max(ls):.2f} m" if max(ls) > 0 else f"; lever arm {lever} as given"
    if "speed_scale" in cal:
        out += (f"; odometer scale {cal['speed_scale']:.4f} +- {cal['speed_scale_std']:.4f}, latency "
                f"{cal['speed_latency_s'] * 1e3:+.0f} " + (f"+- {cal['speed_latency_std_s'] * 1e3:.0f} ms"
                                                          if cal['speed_latency_std_s'] > 0 else "ms as given"))
    return out


def report(ekf_state, var: np.ndarray, R_bc: np.ndarray) -> dict:
    """The estimated calibration with 1-sigma uncertainties (from the smoothed covariance)."""
    R_bv, tau, lever_b, *odo = ekf_state
    sd = np.sqrt(np.maximum(var, 0.0))
    out = {
        "camera_mount_rpy_deg": np.round(camera_mount_angles(R_bv, R_bc), 3).tolist(),
        "mount_std_deg": np.round(np.degrees(sd[0:3]), 3).tolist(),
        "imu_to_vehicle_R": np.round(R_bv.T, 6).tolist(),
        "gnss_latency_s": round(float(tau), 4), "gnss_latency_std_s": round(float(sd[3]), 4),
        "lever_arm_m": np.round(R_bv.T @ lever_b, 3).tolist(), "lever_arm_std_m": np.round(sd[4:7], 3).tolist(),
    }
    if odo:  # only when the recording has an odometer (speed.csv)
        out["speed_scale"], out["speed_scale_std"] = round(float(odo[0]), 5), round(float(sd[7]), 5)
        out["speed_latency_s"], out["speed_latency_std_s"] = round(float(odo[1]), 4), round(float(sd[8]), 4)
    return out
