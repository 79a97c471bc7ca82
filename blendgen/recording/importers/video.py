"""Plain video (mp4/mov/avi/mkv) + optional IMU/GNSS CSVs -> recording folder.

Frame timestamps come from the container: the video track's presentation times (MP4/MOV
sample tables, exact, no decoding); for other containers OpenCV's per-frame position
while grabbing every frame. The video is copied as it is (no re-encoding) and frames.csv
holds `t,index`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from blendgen.errors import UserError
from blendgen.recording import folder
from blendgen.recording.importers import common, mp4
from blendgen.recording.model import ImuNoise

VIDEO_EXTS = (".mp4", ".mov", ".avi", ".mkv", ".m4v")
DEFAULT_HFOV_DEG = 70.0  # a typical dashcam / phone main camera

IMU_ALIASES = {
    "t": ["time", "timestamp", "stamp"],
    "wx": ["gx", "gyro_x", "w_rs_s_x", "omega_x"], "wy": ["gy", "gyro_y", "w_rs_s_y", "omega_y"],
    "wz": ["gz", "gyro_z", "w_rs_s_z", "omega_z"],
    "ax": ["acc_x", "accel_x", "a_rs_s_x"], "ay": ["acc_y", "accel_y", "a_rs_s_y"],
    "az": ["acc_z", "accel_z", "a_rs_s_z"],
}
GNSS_ALIASES = {
    "t": ["time", "timestamp", "stamp"], "lat": ["latitude"], "lon": ["lng", "longitude"],
    "alt": ["altitude", "height"], "heading_deg": ["heading", "course", "bearing"],
    "h_std_m": ["h_acc", "hacc", "accuracy", "horizontal_accuracy"],
}


def video_frame_times(path: Path, *, show_progress: bool = True) -> np.ndarray:
    """Presentation time (s, from the start of the video) of every frame in display order."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise UserError("OpenCV cannot open this video (unknown codec or corrupt file)", where=str(path))
    n_cv = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    if path.suffix.lower() in (".mp4", ".mov", ".m4v"):
        video = [t for t in mp4.read_tracks(path) if t.handler == "vide"]
        if not video:
            raise UserError("the file has no video track", where=str(path))
        t = np.sort(video[0].presentation_times())
        t = t - t[0]
        cap.release()
        if n_cv > 0 and abs(n_cv - len(t)) > 1:
            raise UserError(f"container lists {len(t)} video samples but OpenCV sees {n_cv} frames", where=str(path))
        return t
    # other containers: read the demuxer's timestamp of each frame (grab() skips the colour conversion)
    times = []
    for _ in common.progress(iter(int, 1), total=n_cv or None, desc="frame times", enabled=show_progress):
        if not cap.grab():
            break
        times.append(cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0)
    cap.release()
    t = np.asarray(times)
    if len(t) == 0:
        raise UserError("no frame could be decoded", where=str(path))
    if np.any(np.diff(t) <= 0):  # backend without timestamps: fall back to the nominal rate
        fps = cv2.VideoCapture(str(path)).get(cv2.CAP_PROP_FPS) or 30.0
        t = np.arange(len(t)) / fps
    return t - t[0]


def import_video(src, dst, *, imu_csv=None, gnss_csv=None, calib=None, hfov_deg: float | None = None,
                 time_offset: float = 0.0, time_unit: str = "s", force: bool = False,
                 show_progress: bool = True) -> Path:
    """Convert a video (+ IMU/GNSS CSVs on the same clock) into a recording folder.

    time_offset: seconds added to the video's own timestamps (which start at 0) to put them
    on the clock of the CSVs. time_unit: unit of the CSVs' `t` column (s, ms, us, ns).
    """
    src = Path(src)
    if not src.is_file():
        raise UserError("video file not found", where=str(src))
    if src.suffix.lower() not in VIDEO_EXTS:
        raise UserError(f"unsupported video extension {src.suffix!r}; expected one of {VIDEO_EXTS}", where=str(src))
    if time_unit not in common.TIME_UNITS:
        raise UserError(f"--time-unit {time_unit!r}: expected one of {list(common.TIME_UNITS)}")
    t = video_frame_times(src, show_progress=show_progress) + float(time_offset)
    w, h = common.first_frame_size(src, "the first frame")
    dst = common.prepare_output(dst, force)

    notes = []
    T_cam_imu, noise, cam_note, T_note = None, None, None, "assumed identity (no calibration given)"
    if calib is not None:
        camera, T_cam_imu, noise = _load_user_calib(Path(calib), w, h)
        cam_note = f"from {calib}"
        if T_cam_imu is not None:
            T_note = f"from {calib}"
    else:
        hf = float(hfov_deg) if hfov_deg else DEFAULT_HFOV_DEG
        camera = common.default_camera(w, h, hf)
        cam_note = (f"assumed pinhole with {hf:g} deg horizontal field of view" +
                    (" (--hfov)" if hfov_deg else " (default; pass --hfov or --calib)"))
    unit = common.TIME_UNITS[time_unit]
    if imu_csv is not None:
        cols = common.read_table(Path(imu_csv), IMU_ALIASES, required=list(IMU_ALIASES), what="IMU")
        imu = np.stack([cols[c] for c in folder.IMU_COLUMNS], axis=1)
        imu[:, 0] *= unit
        _finite(imu, Path(imu_csv), "IMU")
        common.require_increasing(imu[:, 0], imu_csv, "IMU")
        folder.write_imu(dst, imu)
    if gnss_csv is not None:
        cols = common.read_table(Path(gnss_csv), GNSS_ALIASES, required=["t", "lat", "lon", "alt"], what="GNSS")
        names = folder.GNSS_REQUIRED + [c for c in folder.GNSS_OPTIONAL if c in cols]
        gnss = np.stack([cols[c] for c in names], axis=1)
        gnss[:, 0] *= unit
        _finite(gnss[:, :4], Path(gnss_csv), "GNSS")
        common.require_increasing(gnss[:, 0], gnss_csv, "GNSS")
        folder.write_gnss(dst, gnss, names)
    video_name = "video" + src.suffix.lower()
    common.place_file(src, dst / video_name)
    folder.write_frames_index_csv(dst, t, np.arange(len(t)))
    meta = common.import_meta("video", src, camera=cam_note, T_cam_imu=T_note, notes=notes,
                              time_offset_s=float(time_offset))
    folder.write_calib(dst, camera, T_cam_imu, noise, extra={"video": video_name, "import": meta})
    return dst


def _finite(arr: np.ndarray, path: Path, what: str) -> None:
    bad = np.argwhere(~np.isfinite(arr))
    if bad.size:
        raise UserError(f"{what}: row {bad[0][0] + 2} has an empty or non-numeric value", where=str(path))


def _load_user_calib(path: Path, w: int, h: int):
    """A calib.yaml in blendgen's format (camera:, T_cam_imu:, imu:) given with --calib."""
    from blendgen.recording.folder import _parse_camera

    if not path.is_file():
        raise UserError("calibration file not found", where=str(path))
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as e:
        raise UserError(f"not valid YAML: {e}", where=str(path)) from None
    if "camera" not in data:
        raise UserError("no camera: section (intrinsics [fx, fy, cx, cy], resolution [w, h])", where=str(path))
    camera = _parse_camera(data["camera"], path)
    if (camera.width, camera.height) != (w, h):
        if abs(camera.width / camera.height - w / h) > 0.01:
            raise UserError(f"calibration is {camera.width}x{camera.height} but the video is {w}x{h} "
                            "(different aspect ratio)", where=str(path))
        camera = camera.scaled(w, h)
    T = np.asarray(data["T_cam_imu"], dtype=float) if "T_cam_imu" in data else None
    noise = ImuNoise(**{k: float(v) for k, v in (data.get("imu") or {}).items()
                        if k in vars(ImuNoise())}) if data.get("imu") else None
    return camera, T, noise
