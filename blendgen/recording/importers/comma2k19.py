"""comma2k19 segments (numpy logs without extension) -> recording folder.

Read:  processed_log/IMU/{gyro,accelerometer}/{t,value}  (device frame: x forward, y right, z down)
       processed_log/GNSS/live_gnss_ublox (or _qcom)/{t,value}: lat, lon, alt, unix time [ms], (unused), accuracy [m]
       processed_log/CAN/speed/{t,value}: the car's speed from its CAN bus (m/s), when present
       global_pose/frame_{times,positions,orientations}: ECEF position and R_ecef_device quaternion (w,x,y,z)
       preview.png: one frame of the road camera, when present
Written: imu.csv in the device frame, gnss.csv (lat/lon/alt, heading, h_std), speed.csv, groundtruth.csv as
T_world_cam in a local ENU frame about the first ground-truth position (recorded in calib.yaml as
import.groundtruth_origin), calib.yaml with the openpilot road camera (EON, 1164x874, f=910) and
T_cam_imu = device -> OpenCV camera axes. This example segment has no video, so frames.csv is absent;
the camera's yaw in the car comes from the lane markings in preview.png (`vehicle.camera_yaw_deg`).
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from blendgen.errors import UserError
from blendgen.geometry import Camera, make_pose, matrix_to_quat, quat_to_matrix
from blendgen.recording import folder
from blendgen.recording.importers import common
from blendgen.recording.model import ImuNoise

# openpilot's EON road camera (common/transformations/camera.py): 1164x874, focal 910 px
EON_CAMERA = Camera(1164, 874, 910.0, 910.0, 582.0, 437.0)
# device frame (x forward, y right, z down) -> OpenCV camera frame (x right, y down, z forward)
R_CAM_DEVICE = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])


def _load(path: Path, ncols: int | None = None) -> np.ndarray:
    if not path.is_file():
        raise UserError("missing (expected a numpy array saved without extension)", where=str(path))
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise UserError(f"not a readable numpy array ({e}); truncated or corrupt", where=str(path)) from None
    if ncols is not None and (arr.ndim != 2 or arr.shape[1] < ncols):
        raise UserError(f"shape {arr.shape}, expected (N, {ncols}+)", where=str(path))
    return np.asarray(arr, dtype=float)


def _series(d: Path, ncols: int) -> tuple[np.ndarray, np.ndarray]:
    t = _load(d / "t").ravel()
    v = _load(d / "value", ncols)
    if len(t) != len(v):
        raise UserError(f"{len(t)} times but {len(v)} values (truncated log?)", where=str(d))
    return t, v


def import_comma2k19(src, dst, *, gnss_source: str = "ublox", force: bool = False,
                     show_progress: bool = True, camera_yaw=None) -> Path:
    """`camera_yaw(bgr, camera) -> (yaw_deg | None, std_deg, how)` measures the camera's yaw in
    the car on the segment's preview frame (`blendgen import` passes
    `analysis.lane_direction.still_camera_yaw`); None: not measured."""
    from pymap3d import ecef2enu, ecef2geodetic

    seg = Path(src)
    if not (seg / "processed_log").is_dir() and not (seg / "global_pose").is_dir():
        raise UserError("not a comma2k19 segment: expected processed_log/ and global_pose/", where=str(seg))
    imu_dir = seg / "processed_log" / "IMU"
    tg, gyro = _series(imu_dir / "gyro", 3)
    ta, acc = _series(imu_dir / "accelerometer", 3)
    if len(tg) != len(ta) or np.any(np.abs(tg - ta) > 1e-3):
        # the logs usually share stamps; otherwise resample the accelerometer onto the gyro's
        acc = np.column_stack([np.interp(tg, ta, acc[:, k]) for k in range(3)])
    tg, gyro, acc = common.dedupe_sorted(tg, gyro[:, :3], acc[:, :3])
    imu = np.column_stack([tg, gyro, acc])
    bad = np.flatnonzero(~np.all(np.isfinite(imu), axis=1))
    if bad.size:
        raise UserError(f"sample {bad[0]}: NaN/inf in gyro or accelerometer", where=str(imu_dir))

    gdir = seg / "processed_log" / "GNSS" / f"live_gnss_{gnss_source}"
    tn, gv = _series(gdir, 3)
    tn, gv = common.dedupe_sorted(tn, gv)
    ok = np.all(np.isfinite(gv[:, :3]), axis=1) & (np.abs(gv[:, 0]) > 1e-6)  # (0,0) = no fix
    dropped = int((~ok).sum())
    tn, gv = tn[ok], gv[ok]
    gnss_cols = ["t", "lat", "lon", "alt"]
    gnss = [tn, gv[:, 0], gv[:, 1], gv[:, 2]]
    if gv.shape[1] >= 6:
        # column 5 is the receiver's accuracy estimate (m); column 4 is not the bearing (it does
        # not follow the ground-truth heading on the example segment), so no heading is written
        gnss_cols += ["h_std_m"]
        gnss += [np.where(gv[:, 5] > 0, gv[:, 5], np.nan)]

    speed = None
    can = seg / "processed_log" / "CAN" / "speed"
    if (can / "t").is_file():
        ts, sv = _series(can, 1)
        ts, sv = common.dedupe_sorted(ts, sv[:, :1])
        ok = np.isfinite(sv[:, 0]) & (sv[:, 0] >= 0)
        speed = np.column_stack([ts[ok], sv[ok, 0]])

    gp = seg / "global_pose"
    t_gt = _load(gp / "frame_times").ravel()
    pos = _load(gp / "frame_positions", 3)
    quat = _load(gp / "frame_orientations", 4)
    if not (len(t_gt) == len(pos) == len(quat)):
        raise UserError(f"frame_times {len(t_gt)}, frame_positions {len(pos)}, frame_orientations {len(quat)} "
                        "rows: lengths differ (truncated?)", where=str(gp))
    lat0, lon0, alt0 = (float(v) for v in ecef2geodetic(*pos[0]))
    e, n, u = ecef2enu(pos[:, 0], pos[:, 1], pos[:, 2], lat0, lon0, alt0)
    R_enu_ecef = _R_enu_ecef(np.radians(lat0), np.radians(lon0))
    R_dev_cam = R_CAM_DEVICE.T
    gt = np.empty((len(t_gt), 8))
    gt[:, 0] = t_gt
    gt[:, 1], gt[:, 2], gt[:, 3] = e, n, u
    for i in common.progress(range(len(t_gt)), desc="ground truth", enabled=show_progress):
        q = quat[i]
        nq = np.linalg.norm(q)
        if not np.isfinite(nq) or nq < 1e-6:
            raise UserError(f"row {i}: invalid quaternion {q}", where=str(gp / "frame_orientations"))
        R_w_cam = R_enu_ecef @ quat_to_matrix(q / nq) @ R_dev_cam
        gt[i, 4:8] = matrix_to_quat(R_w_cam)
    t_gt, gt = common.dedupe_sorted(t_gt, gt)

    dst = common.prepare_output(dst, force)
    folder.write_imu(dst, imu)
    folder.write_gnss(dst, np.column_stack(gnss), gnss_cols)
    folder.write_groundtruth(dst, gt)
    extra = {}
    notes = ["no video in this segment: frames.csv is not written",
             "camera intrinsics are openpilot's EON road camera defaults (not per-device calibrated)"]
    if speed is not None and len(speed):
        folder.write_speed(dst, speed)
    else:
        notes.append("no CAN speed (processed_log/CAN/speed): speed.csv is not written")
    if dropped:
        notes.append(f"{dropped} GNSS row(s) without a fix were dropped")
    if gv.shape[1] >= 4 and np.all(gv[:, 3] > 1e11):
        # column 3 is Unix time in ms: the log clock's origin in UTC, for the sun's position
        origin = float(np.median(gv[:, 3] / 1000.0 - tn))
        extra["time_origin_utc"] = datetime.fromtimestamp(origin, tz=timezone.utc).isoformat()
    rate = float(1.0 / np.median(np.diff(tg))) if len(tg) > 1 else 100.0
    vehicle, why = _camera_yaw(seg / "preview.png", camera_yaw)
    if vehicle:
        extra["vehicle"] = vehicle
    notes.append(why)
    meta = common.import_meta(
        "comma2k19", seg, camera="openpilot EON road camera defaults (1164x874, f=910 px)",
        T_cam_imu="device frame (x forward, y right, z down) rotated to camera axes; lever arm 0",
        notes=notes, groundtruth_origin={"lat": lat0, "lon": lon0, "alt": alt0},
        gnss_source=f"live_gnss_{gnss_source}")
    extra["import"] = meta
    # A raw phone-grade receiver: its fixes lag the IMU clock and its reported accuracy is far
    # more cautious than its scatter; both are estimated from the drive (docs/sync.md, GNSS latency).
    extra["gnss"] = {"latency_s": "auto", "h_std_scale": "auto"}
    folder.write_calib(dst, EON_CAMERA, make_pose(R_CAM_DEVICE, np.zeros(3)), ImuNoise(update_rate=rate),
                       extra=extra)
    return dst


# T_cam_imu is the nominal device frame: a phone's IMU chip sits within about a degree of it
T_CAM_IMU_YAW_STD_DEG = 1.0


def _camera_yaw(preview: Path, measure) -> tuple[dict, str]:
    """calib.yaml `vehicle:` keys with the camera's yaw in the car, measured by `measure` on the
    segment's preview frame, and a note for the import."""
    if measure is None:
        return {}, "no camera yaw in the car: not measured at import"
    import cv2

    img = cv2.imread(str(preview)) if preview.is_file() else None
    if img is None:
        return {}, f"no camera yaw in the car: {preview.name} is missing or unreadable"
    yaw, std, how = measure(img, EON_CAMERA)
    if yaw is None:
        return {}, f"no camera yaw in the car from {preview.name}: {how}"
    return ({"camera_yaw_deg": round(yaw, 3), "camera_yaw_std_deg": round(std, 3),
             "T_cam_imu_yaw_std_deg": T_CAM_IMU_YAW_STD_DEG},
            f"camera yaw in the car {yaw:+.2f} +- {std:.2f} deg: {how} in {preview.name}")


def groundtruth_georef(rec) -> tuple[float, float, float]:
    """(lat, lon, alt) of the ground truth's local ENU origin: the georeference to sync an
    imported segment with, so that its poses and its ground truth share one frame."""
    o = rec.extra["import"]["groundtruth_origin"]
    return o["lat"], o["lon"], o["alt"]


def _R_enu_ecef(lat: float, lon: float) -> np.ndarray:
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])
