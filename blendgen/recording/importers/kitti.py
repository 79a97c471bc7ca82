"""KITTI raw drives (image_02 + oxts + calib_*.txt) -> recording folder.

SRC is a drive folder (…/2011_09_26_drive_0001_sync or _extract); the calibration files
lie beside it (in the date folder) or inside it. `_sync` drives hold rectified images,
described by P_rect_0X/S_rect_0X; `_extract` drives raw images with K_0X/D_0X.
OXTS packets give the IMU (body frame x forward, y left, z up; wx..wz, ax..az are specific
forces), GNSS (lat, lon, alt, pos_accuracy) and ground truth (RTK pose: roll, pitch, yaw)
which is written as T_world_cam in a local ENU frame at the first fix.
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from blendgen.errors import UserError
from blendgen.geometry import Camera, invert_pose, make_pose, matrix_to_quat
from blendgen.recording import folder
from blendgen.recording.importers import common
from blendgen.recording.model import ImuNoise

OXTS_FIELDS = 30  # lat lon alt roll pitch yaw vn ve vf vl vu ax ay az af al au wx wy wz wf wl wu pos_acc ...


def _read_calib_txt(path: Path) -> dict[str, np.ndarray]:
    out = {}
    for n, line in enumerate(path.read_text().splitlines()):
        if ":" not in line:
            continue
        key, val = line.split(":", 1)
        if key.strip() == "calib_time":
            continue
        try:
            out[key.strip()] = np.array([float(v) for v in val.split()])
        except ValueError:
            raise UserError(f"line {n + 1}: {key.strip()} is not a list of numbers", where=str(path)) from None
    return out


def _find_calib(drive: Path, name: str) -> Path:
    for d in (drive, drive.parent):
        if (d / name).is_file():
            return d / name
    raise UserError(f"{name} not found beside or inside the drive folder (KITTI raw keeps it in the date "
                    "folder, e.g. 2011_09_26/)", where=str(drive))


def _need(calib: dict, key: str, n: int, path: Path) -> np.ndarray:
    if key not in calib or calib[key].size != n:
        raise UserError(f"{key}: expected {n} numbers", where=str(path))
    return calib[key]


def _rt(calib: dict, path: Path) -> np.ndarray:
    return make_pose(_need(calib, "R", 9, path).reshape(3, 3), _need(calib, "T", 3, path))


def _timestamps(path: Path) -> np.ndarray:
    if not path.is_file():
        raise UserError("timestamps.txt missing", where=str(path))
    out = []
    for i, line in enumerate(path.read_text().splitlines()):
        s = line.strip()
        if not s:
            continue
        try:
            day, frac = (s.split(".") + ["0"])[:2]
            base = datetime.strptime(day, "%Y-%m-%d %H:%M:%S").replace(tzinfo=timezone.utc).timestamp()
            out.append(base + float("0." + frac))  # nanosecond digits kept exactly
        except ValueError:
            raise UserError(f"line {i + 1}: {s!r} is not 'YYYY-MM-DD HH:MM:SS.fffffffff'", where=str(path)) from None
    return np.asarray(out)


def import_kitti(src, dst, *, cam: int = 2, force: bool = False, show_progress: bool = True) -> Path:
    drive = Path(src)
    if not drive.is_dir():
        raise UserError("KITTI drive folder not found", where=str(drive))
    img_dir = drive / f"image_{cam:02d}"
    if not (img_dir / "data").is_dir():
        raise UserError(f"image_{cam:02d}/data missing: expected a KITTI raw drive folder", where=str(drive))
    cc_path = _find_calib(drive, "calib_cam_to_cam.txt")
    cc = _read_calib_txt(cc_path)
    rectified = not drive.name.endswith("_extract")
    c = f"{cam:02d}"
    if rectified:
        P = _need(cc, f"P_rect_{c}", 12, cc_path).reshape(3, 4)
        w, h = (int(v) for v in _need(cc, f"S_rect_{c}", 2, cc_path))
        K = P[:, :3]
        camera = Camera(w, h, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
        # rectified cam X = [I | K^-1 p4] * rectified cam0; rectified cam0 = R_rect_00 * cam0
        T_camX_rect0 = make_pose(np.eye(3), np.linalg.solve(K, P[:, 3]))
        R_rect = make_pose(_need(cc, "R_rect_00", 9, cc_path).reshape(3, 3), np.zeros(3))
        T_camX_cam0 = T_camX_rect0 @ R_rect
    else:
        K = _need(cc, f"K_{c}", 9, cc_path).reshape(3, 3)
        w, h = (int(v) for v in _need(cc, f"S_{c}", 2, cc_path))
        camera = Camera(w, h, K[0, 0], K[1, 1], K[0, 2], K[1, 2], list(_need(cc, f"D_{c}", 5, cc_path)))
        T_camX_cam0 = make_pose(_need(cc, f"R_{c}", 9, cc_path).reshape(3, 3), _need(cc, f"T_{c}", 3, cc_path))
    vc_path = _find_calib(drive, "calib_velo_to_cam.txt")
    iv_path = _find_calib(drive, "calib_imu_to_velo.txt")
    T_cam0_velo = _rt(_read_calib_txt(vc_path), vc_path)
    T_velo_imu = _rt(_read_calib_txt(iv_path), iv_path)
    T_cam_imu = T_camX_cam0 @ T_cam0_velo @ T_velo_imu

    images = sorted(p for p in (img_dir / "data").iterdir() if p.suffix.lower() in (".png", ".jpg"))
    t_img = _timestamps(img_dir / "timestamps.txt")
    if len(t_img) != len(images):
        raise UserError(f"{len(t_img)} timestamps for {len(images)} images (truncated drive?)",
                        where=str(img_dir / "timestamps.txt"))
    common.require_increasing(t_img, img_dir / "timestamps.txt", "camera")

    oxts_dir = drive / "oxts"
    packets = sorted((oxts_dir / "data").glob("*.txt")) if (oxts_dir / "data").is_dir() else []
    if not packets:
        raise UserError("oxts/data/*.txt missing: no IMU/GNSS", where=str(drive))
    t_ox = _timestamps(oxts_dir / "timestamps.txt")
    if len(t_ox) != len(packets):
        raise UserError(f"{len(t_ox)} timestamps for {len(packets)} OXTS packets", where=str(oxts_dir / "timestamps.txt"))
    ox = np.empty((len(packets), OXTS_FIELDS))
    for i, p in common.progress(list(enumerate(packets)), desc="oxts", enabled=show_progress):
        try:
            vals = [float(v) for v in p.read_text().split()]
        except ValueError:
            raise UserError("not a list of numbers", where=str(p)) from None
        if len(vals) != OXTS_FIELDS:
            raise UserError(f"{len(vals)} values, expected {OXTS_FIELDS} (truncated packet?)", where=str(p))
        ox[i] = vals
    # KITTI sync drives sometimes repeat an OXTS timestamp; keep the first of each
    t_ox, ox = common.dedupe_sorted(t_ox, ox)

    dst = common.prepare_output(dst, force)
    imu = np.column_stack([t_ox, ox[:, 17:20], ox[:, 11:14]])
    folder.write_imu(dst, imu)
    folder.write_gnss(dst, np.column_stack([t_ox, ox[:, 0:3], _compass_deg(ox[:, 5]), ox[:, 23]]),
                      ["t", "lat", "lon", "alt", "heading_deg", "h_std_m"])
    folder.write_groundtruth(dst, _groundtruth(t_ox, ox, T_cam_imu))

    files = []
    for p in common.progress(images, desc="images", enabled=show_progress):
        rel = f"image_{c}/{p.name}"
        common.place_file(p, dst / rel)
        files.append(rel)
    folder.write_frames_csv(dst, t_img, files)
    noise = ImuNoise(update_rate=float(1.0 / np.median(np.diff(t_ox))) if len(t_ox) > 1 else 10.0)
    lat0, lon0, alt0 = (float(v) for v in ox[0, 0:3])
    meta = common.import_meta(
        "kitti", drive, camera=f"from {cc_path.name} ({'rectified P_rect' if rectified else 'raw K/D'}_{c})",
        T_cam_imu=f"from {vc_path.name} and {iv_path.name}",
        notes=["timestamps.txt read as UTC (KITTI writes local time without a zone)",
               "ground truth is the OXTS RTK/INS pose in ENU about groundtruth_origin"],
        groundtruth_origin={"lat": lat0, "lon": lon0, "alt": alt0})
    folder.write_calib(dst, camera, T_cam_imu, noise, extra={"import": meta})
    return dst


def _compass_deg(yaw_enu: np.ndarray) -> np.ndarray:
    """OXTS yaw (rad, 0 = east, counter-clockwise) -> compass heading (deg, 0 = north, clockwise)."""
    return np.mod(90.0 - np.degrees(yaw_enu), 360.0)


def _groundtruth(t, ox, T_cam_imu) -> np.ndarray:
    from pymap3d import geodetic2enu

    e, n, u = geodetic2enu(ox[:, 0], ox[:, 1], ox[:, 2], ox[0, 0], ox[0, 1], ox[0, 2])
    # OXTS: roll about x (forward), pitch about y (left), yaw about z (up), 0 yaw = east
    R_w_imu = Rotation.from_euler("ZYX", np.column_stack([ox[:, 5], ox[:, 4], ox[:, 3]])).as_matrix()
    T_imu_cam = invert_pose(T_cam_imu)
    gt = np.empty((len(t), 8))
    gt[:, 0] = t
    for i in range(len(t)):
        T = make_pose(R_w_imu[i], [e[i], n[i], u[i]]) @ T_imu_cam
        gt[i, 1:4] = T[:3, 3]
        gt[i, 4:8] = matrix_to_quat(T[:3, :3])
    return gt
