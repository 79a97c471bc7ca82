"""EuRoC / ASL folders (mav0/cam0, imu0, state_groundtruth_estimate0, sensor.yaml) -> recording.

EuRoC poses are T_world_body for the IMU body (`state_groundtruth_estimate0`, or
`leica0`/`vicon0` positions only, which are skipped); blendgen's ground truth is
T_world_cam, so each pose is composed with T_body_cam from cam0's sensor.yaml.
Timestamps are nanoseconds (Unix time) and become seconds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from blendgen.errors import UserError
from blendgen.geometry import Camera, invert_pose, make_pose, matrix_to_quat, quat_to_matrix
from blendgen.recording import folder
from blendgen.recording.importers import common
from blendgen.recording.model import ImuNoise


def _sensor_yaml(path: Path) -> dict:
    if not path.is_file():
        raise UserError("sensor.yaml missing", where=str(path))
    # EuRoC files start with OpenCV's "%YAML:1.0" directive, which PyYAML does not accept
    text = "\n".join(ln for ln in path.read_text().splitlines() if not ln.startswith("%"))
    try:
        data = yaml.safe_load(text) or {}
    except yaml.YAMLError as e:
        raise UserError(f"not valid YAML: {e}", where=str(path)) from None
    return data


def _T_BS(data: dict, path: Path) -> np.ndarray:
    try:
        T = np.asarray(data["T_BS"]["data"], dtype=float).reshape(4, 4)
    except (KeyError, TypeError, ValueError):
        raise UserError("T_BS: expected {rows: 4, cols: 4, data: [16 numbers]}", where=str(path)) from None
    if abs(np.linalg.det(T[:3, :3]) - 1) > 1e-3:
        raise UserError("T_BS: rotation part is not a rotation (det != 1)", where=str(path))
    return T


def _camera(data: dict, path: Path) -> Camera:
    try:
        fu, fv, cu, cv = (float(v) for v in data["intrinsics"])
        w, h = (int(v) for v in data["resolution"])
    except (KeyError, TypeError, ValueError):
        raise UserError("cam sensor.yaml: expected intrinsics [fu, fv, cu, cv] and resolution [w, h]",
                        where=str(path)) from None
    model = data.get("distortion_model", "radial-tangential")
    dist = [float(v) for v in data.get("distortion_coefficients", [])]
    if model == "equidistant" and len(dist) == 4:  # Kalibr's fisheye (TUM VI and other EuRoC-format sets)
        return Camera(w, h, fu, fv, cu, cv, dist, "equidistant")
    if model not in ("radial-tangential", "radtan", "plumb_bob"):
        raise UserError(f"distortion_model {model!r} is not supported (radial-tangential, or equidistant with "
                        "4 coefficients)", where=str(path))
    return Camera(w, h, fu, fv, cu, cv, (dist + [0.0] * 5)[:5])


def import_euroc(src, dst, *, cam: str = "cam0", force: bool = False, show_progress: bool = True) -> Path:
    src = Path(src)
    mav = src / "mav0" if (src / "mav0").is_dir() else src
    cam_dir = mav / cam
    if not cam_dir.is_dir():
        raise UserError(f"no {cam}/ folder: expected an EuRoC/ASL folder with mav0/{cam}, mav0/imu0",
                        where=str(mav))
    cam_yaml = _sensor_yaml(cam_dir / "sensor.yaml")
    camera = _camera(cam_yaml, cam_dir / "sensor.yaml")
    T_B_C = _T_BS(cam_yaml, cam_dir / "sensor.yaml")

    rows = common.read_table(cam_dir / "data.csv", {"t": ["timestamp"]},
                             required=["t"], what="camera index")
    # filenames are text: read them separately (read_table is numeric)
    lines = [ln for ln in (cam_dir / "data.csv").read_text().splitlines()[1:] if ln.strip()]
    files = [ln.split(",")[1].strip() if "," in ln else "" for ln in lines]
    t_cam = rows["t"] * 1e-9
    common.require_increasing(t_cam, cam_dir / "data.csv", "camera")
    for i, f in enumerate(files):
        if not f or not (cam_dir / "data" / f).is_file():
            raise UserError(f"row {i + 2}: image {f!r} is missing from {cam}/data/", where=str(cam_dir / "data.csv"))

    imu_dir = mav / "imu0"
    T_B_I = np.eye(4)
    noise = ImuNoise()
    T_note = f"from {cam}/sensor.yaml T_BS"
    dst = common.prepare_output(dst, force)
    if imu_dir.is_dir():
        imu_yaml = _sensor_yaml(imu_dir / "sensor.yaml") if (imu_dir / "sensor.yaml").exists() else {}
        if "T_BS" in imu_yaml:
            T_B_I = _T_BS(imu_yaml, imu_dir / "sensor.yaml")
        for k in vars(noise):
            if isinstance(imu_yaml.get(k), (int, float)) and imu_yaml[k] > 0:
                setattr(noise, k, float(imu_yaml[k]))
        if isinstance(imu_yaml.get("rate_hz"), (int, float)):
            noise.update_rate = float(imu_yaml["rate_hz"])
        aliases = {"t": ["timestamp"], "wx": ["w_rs_s_x"], "wy": ["w_rs_s_y"], "wz": ["w_rs_s_z"],
                   "ax": ["a_rs_s_x"], "ay": ["a_rs_s_y"], "az": ["a_rs_s_z"]}
        cols = common.read_table(imu_dir / "data.csv", aliases, required=list(aliases), what="IMU")
        imu = np.stack([cols[c] for c in folder.IMU_COLUMNS], axis=1)
        imu[:, 0] *= 1e-9
        if not np.all(np.isfinite(imu)):
            raise UserError(f"row {np.argwhere(~np.isfinite(imu))[0][0] + 2}: empty or non-numeric value",
                            where=str(imu_dir / "data.csv"))
        common.require_increasing(imu[:, 0], imu_dir / "data.csv", "IMU")
        folder.write_imu(dst, imu)
    T_cam_imu = invert_pose(T_B_C) @ T_B_I

    gt_path = mav / "state_groundtruth_estimate0" / "data.csv"
    if gt_path.is_file():
        aliases = {"t": ["timestamp"], "x": ["p_rs_r_x"], "y": ["p_rs_r_y"], "z": ["p_rs_r_z"],
                   "qw": ["q_rs_w"], "qx": ["q_rs_x"], "qy": ["q_rs_y"], "qz": ["q_rs_z"]}
        cols = common.read_table(gt_path, aliases, required=list(aliases), what="ground truth")
        t = cols["t"] * 1e-9
        common.require_increasing(t, gt_path, "ground truth")
        gt = np.empty((len(t), 8))
        gt[:, 0] = t
        # state_groundtruth_estimate0 is the pose of the body (IMU) frame: T_world_cam = T_world_body T_body_cam
        for i in range(len(t)):
            q = np.array([cols["qw"][i], cols["qx"][i], cols["qy"][i], cols["qz"][i]])
            n = np.linalg.norm(q)
            if not np.isfinite(n) or n < 1e-6:
                raise UserError(f"row {i + 2}: invalid quaternion {q}", where=str(gt_path))
            T_w_b = make_pose(quat_to_matrix(q / n), [cols["x"][i], cols["y"][i], cols["z"][i]])
            T_w_c = T_w_b @ invert_pose(T_B_I) @ T_B_C
            gt[i, 1:4] = T_w_c[:3, 3]
            gt[i, 4:8] = matrix_to_quat(T_w_c[:3, :3])
        folder.write_groundtruth(dst, gt)

    out_files = []
    for i, f in common.progress(list(enumerate(files)), desc="images", enabled=show_progress):
        rel = f"{cam}/{f}"
        common.place_file(cam_dir / "data" / f, dst / rel)
        out_files.append(rel)
    folder.write_frames_csv(dst, t_cam, out_files)
    meta = common.import_meta("euroc", src, camera=f"from {cam}/sensor.yaml",
                              T_cam_imu=T_note if imu_dir.is_dir() else "no IMU")
    folder.write_calib(dst, camera, T_cam_imu, noise, extra={"import": meta})
    return dst
