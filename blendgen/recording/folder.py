"""Read and write the recording folder of DESIGN.md.

The reader validates what it loads: every problem names the file and the row, and is a
UserError (bad input) or an entry in `Recording.issues` (a gap it handled and reports).
"""

from __future__ import annotations

import csv
import io
import math
from datetime import datetime
from pathlib import Path

import numpy as np
import yaml

from blendgen import atomic
from blendgen.errors import UserError
from blendgen.geometry import Camera
from blendgen.recording.model import ImuNoise, Recording
from blendgen.validation import load_yaml_text, quote

IMU_COLUMNS = ["t", "wx", "wy", "wz", "ax", "ay", "az"]
GT_COLUMNS = ["t", "x", "y", "z", "qw", "qx", "qy", "qz"]
GNSS_REQUIRED = ["t", "lat", "lon", "alt"]
GNSS_OPTIONAL = ["heading_deg", "h_std_m"]
SPEED_COLUMNS = ["t", "speed"]
MAX_SPEED = 150.0  # m/s: a larger odometer reading is a unit mistake (km/h, mph) or garbage
IMU_GAP_FACTOR = 5.0  # an IMU interval this many times the median is reported as a gap
MISSING_IMAGES = "image file(s) missing"  # the reader's issue text; `import --check` lists each image instead


# ----------------------------------------------------------------------------- reading

def read_recording(root: str | Path, *, require_frames: bool = False) -> Recording:
    root = Path(root)
    if not root.is_dir():
        raise UserError("recording folder not found (expected calib.yaml, frames.csv, imu.csv, gnss.csv)",
                        where=str(root))
    rec = _read_calib(root)
    _read_frames(rec)
    if require_frames and rec.n_frames == 0:
        raise UserError("this command needs camera frames, but frames.csv is missing or empty",
                        where=str(root / "frames.csv"))
    imu_path = root / "imu.csv"
    if imu_path.exists():
        rec.imu = _drop_nan_rows(_read_numeric_csv(imu_path, IMU_COLUMNS, allow_nan=set(IMU_COLUMNS[1:])),
                                 imu_path, rec, "IMU")
        _check_times(rec.imu[:, 0], imu_path, rec, gaps=True)
    gnss_path = root / "gnss.csv"
    if gnss_path.exists():
        header = _header(gnss_path)
        missing = [c for c in GNSS_REQUIRED if c not in header]
        if missing:
            raise UserError(f"missing column(s) {missing}; expected t, lat, lon, alt[, heading_deg][, h_std_m]",
                            where=str(gnss_path))
        cols = GNSS_REQUIRED + [c for c in GNSS_OPTIONAL if c in header]
        rec.gnss = _read_numeric_csv(gnss_path, cols, allow_nan=set(GNSS_OPTIONAL) | {"lat", "lon", "alt"})
        rec.gnss = _drop_nan_rows(rec.gnss, gnss_path, rec, "GNSS", check=[1, 2, 3])
        rec.gnss_columns = cols
        _check_times(rec.gnss[:, 0], gnss_path, rec)
        lat, lon = rec.gnss[:, 1], rec.gnss[:, 2]
        bad = np.flatnonzero((np.abs(lat) > 90) | (np.abs(lon) > 180))
        if bad.size:
            raise UserError(f"row {bad[0] + 2}: latitude/longitude out of range (lat {lat[bad[0]]}, "
                            f"lon {lon[bad[0]]})", where=str(gnss_path))
    speed_path = root / "speed.csv"
    if speed_path.exists():
        rec.speed = _drop_nan_rows(_read_numeric_csv(speed_path, SPEED_COLUMNS, allow_nan={"speed"}),
                                   speed_path, rec, "speed", check=[1])
        _check_times(rec.speed[:, 0], speed_path, rec)
        bad = np.flatnonzero((rec.speed[:, 1] < 0) | (rec.speed[:, 1] > MAX_SPEED))
        if bad.size:
            raise UserError(f"row {bad[0] + 2}: speed {rec.speed[bad[0], 1]!r} m/s is outside [0, {MAX_SPEED:g}] "
                            "(the vehicle's forward speed in m/s, unsigned)", where=str(speed_path))
    gt_path = root / "groundtruth.csv"
    if gt_path.exists():
        rec.groundtruth = _read_numeric_csv(gt_path, GT_COLUMNS)
        _check_times(rec.groundtruth[:, 0], gt_path, rec)
        norms = np.linalg.norm(rec.groundtruth[:, 4:8], axis=1)
        bad = np.flatnonzero(np.abs(norms - 1) > 1e-3)
        if bad.size:
            raise UserError(f"row {bad[0] + 2}: quaternion is not unit length (|q| = {norms[bad[0]]:.4f})",
                            where=str(gt_path))
    # calibration only matters for the sensors that are there
    if len(rec.imu) == 0:
        rec.issues = [i for i in rec.issues if "missing imu noise" not in i]
    if len(rec.imu) == 0 or rec.n_frames == 0:
        rec.issues = [i for i in rec.issues if "missing T_cam_imu" not in i]
    if rec.n_frames == 0 and len(rec.imu) == 0 and len(rec.gnss) == 0:
        raise UserError("recording has no frames, no IMU and no GNSS: nothing to use", where=str(root))
    return rec


def _read_calib(root: Path) -> Recording:
    path = root / "calib.yaml"
    if not path.exists():
        raise UserError("calib.yaml is missing (camera intrinsics, T_cam_imu, IMU noise)", where=str(path))
    data = load_yaml_text(path, "calib") or {}
    if not isinstance(data, dict):
        raise UserError("expected a mapping at the top level", where=str(path))
    camera = None
    if "camera" in data and data["camera"] is not None:
        camera = _parse_camera(data["camera"], path)
    T = np.eye(4)
    missing_calib = []
    if "T_cam_imu" not in data:
        missing_calib.append("T_cam_imu (identity assumed: camera and IMU axes coincide)")
    if "imu" not in data:
        missing_calib.append("imu noise (Kalibr defaults of an automotive MEMS IMU assumed)")
    if "T_cam_imu" in data:
        try:
            T = np.asarray(data["T_cam_imu"], dtype=float)
        except (TypeError, ValueError):
            T = np.zeros(0)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)) or abs(np.linalg.det(T[:3, :3]) - 1) > 1e-3:
            raise UserError("T_cam_imu: expected a 4x4 rigid transform (rotation with det 1)", where=str(path))
    noise = ImuNoise()
    for k, v in (data.get("imu") or {}).items():
        if not hasattr(noise, k):
            raise UserError(f"imu.{k}: unknown field; expected one of {list(vars(noise))}", where=str(path))
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < math.inf:
            raise UserError(f"imu.{k}: expected a positive number, got {v!r}", where=str(path))
        setattr(noise, k, float(v))
    if data.get("time_origin_utc") is not None:
        try:
            datetime.fromisoformat(str(data["time_origin_utc"]).replace("Z", "+00:00"))
        except ValueError:
            raise UserError(f"time_origin_utc: {quote(str(data['time_origin_utc']))} is not an ISO 8601 "
                            "time; expected e.g. 2024-06-21T10:30:00Z", where=str(path)) from None
    rs = data["camera"].get("rolling_shutter_s", 0.0) if isinstance(data.get("camera"), dict) else 0.0
    rs_auto = rs == "auto"
    rs = 0.0 if rs_auto else rs
    if isinstance(rs, bool) or not isinstance(rs, (int, float)) or not 0 <= rs < 1:
        raise UserError(f"camera.rolling_shutter_s: expected the readout time from the top row to the bottom "
                        f"row in seconds (0 for a global shutter, e.g. 0.03) or 'auto', got {rs!r}", where=str(path))
    known = {"camera", "T_cam_imu", "imu", "timeshift_cam_imu", "timeshift_cam_imu_estimate",
             "timeshift_cam_imu_search_s"}
    ts, est, search = _read_timeshift(data, path)
    rec = Recording(root=root, camera=camera, T_cam_imu=T, imu_noise=noise, time_offset_cam_imu=ts,
                     time_offset_estimate=est, time_offset_search_s=search, rolling_shutter_s=float(rs),
                     rolling_shutter_estimate=rs_auto,
                     extra={k: v for k, v in data.items() if k not in known})
    rec.issues.extend(f"{path.name}: missing {m}" for m in missing_calib)
    return rec


def _read_timeshift(data: dict, path: Path) -> tuple[float, bool, float]:
    """(timeshift_cam_imu, estimate it?, search half-width) from calib.yaml.

    `timeshift_cam_imu: auto` is 0 s, estimated; `timeshift_cam_imu_estimate: true` estimates
    about the given value (kept when the data cannot determine it)."""
    ts = data.get("timeshift_cam_imu", 0.0)
    auto = isinstance(ts, str) and ts.strip().lower() == "auto"
    if auto:
        ts = 0.0
    if isinstance(ts, bool) or not isinstance(ts, (int, float)) or not np.isfinite(ts) or abs(ts) > 10.0:
        raise UserError(f"timeshift_cam_imu: expected seconds (|shift| <= 10, t_imu = t_cam + shift) or 'auto', "
                        f"got {ts!r}", where=str(path))
    est = data.get("timeshift_cam_imu_estimate", auto)
    if not isinstance(est, bool):
        raise UserError(f"timeshift_cam_imu_estimate: expected true or false, got {est!r}", where=str(path))
    if auto and not est:
        raise UserError("timeshift_cam_imu: 'auto' contradicts timeshift_cam_imu_estimate: false", where=str(path))
    search = data.get("timeshift_cam_imu_search_s", 0.1)
    if isinstance(search, bool) or not isinstance(search, (int, float)) or not 0.0 < search <= 0.5:
        raise UserError(f"timeshift_cam_imu_search_s: expected seconds in (0, 0.5], got {search!r}", where=str(path))
    return float(ts), bool(est), float(search)


def _parse_camera(cam: dict, path: Path) -> Camera:
    try:
        fx, fy, cx, cy = (float(v) for v in cam["intrinsics"])
        w, h = (int(v) for v in cam["resolution"])
    except KeyError as e:
        raise UserError(f"camera.{e.args[0]}: missing (expected intrinsics [fx, fy, cx, cy] and "
                        "resolution [w, h])", where=str(path)) from None
    except (TypeError, ValueError):
        raise UserError("camera: intrinsics must be 4 numbers and resolution 2 integers", where=str(path)) from None
    model = cam.get("distortion_model", "radtan")
    if model not in ("radtan", "equidistant", "none"):
        raise UserError(f"camera.distortion_model: {model!r} is not supported; expected radtan, equidistant "
                        "(fisheye, Kannala-Brandt k1..k4) or none", where=str(path))
    dist = [float(v) for v in cam.get("distortion_coeffs", [])] if model != "none" else []
    if model == "equidistant":
        if len(dist) != 4:
            raise UserError("camera.distortion_coeffs: the equidistant model expects 4 numbers (k1 k2 k3 k4)",
                            where=str(path))
    elif len(dist) not in (0, 4, 5):
        raise UserError("camera.distortion_coeffs: expected 4 or 5 numbers (k1 k2 p1 p2 [k3])", where=str(path))
    else:
        dist = (dist + [0.0] * 5)[:5]
    if not all(math.isfinite(v) for v in (fx, fy, cx, cy, *dist)):
        raise UserError(f"camera: intrinsics and distortion must be finite numbers, got intrinsics "
                        f"{[fx, fy, cx, cy]}", where=str(path))
    if min(fx, fy) <= 0 or min(w, h) <= 0:
        raise UserError("camera: focal lengths and resolution must be positive", where=str(path))
    camera = Camera(w, h, fx, fy, cx, cy, dist, "equidistant" if model == "equidistant" else "radtan")
    why = camera.too_wide() if camera.fisheye else None
    if why:
        raise UserError(f"camera: this equidistant lens {why}", where=str(path))
    return camera


def _read_frames(rec: Recording) -> None:
    path = rec.root / "frames.csv"
    if not path.exists():
        return
    header = _header(path)
    if header[:2] == ["t", "file"]:
        rows = _rows(path)
        ts = np.array([_num(r[0], path, i) for i, r in enumerate(rows)], dtype=float)
        files = [r[1].strip() for r in rows]
        root = rec.root.resolve()
        missing = []
        for i, f in enumerate(files):
            p = rec.root / f
            # confined to the recording folder: no absolute paths, `..`, or symlinks out of it
            if not f or Path(f).is_absolute() or not p.resolve().is_relative_to(root):
                raise UserError(f"row {i + 2}: image path {quote(f)} is not inside the recording "
                                f"folder; expected a relative path such as frames/000000.png",
                                where=str(path))
            if not p.is_file():
                missing.append(i)
        if missing:  # those frames fail alone (read_frame names each); the others still work
            rows_s = ", ".join(str(i + 2) for i in missing[:5]) + (" ..." if len(missing) > 5 else "")
            rec.issues.append(f"{path.name}: {len(missing)} {MISSING_IMAGES} (rows {rows_s}), "
                              f"first {quote(files[missing[0]])}")
        rec.frames_t, rec.frame_files = ts, files
    elif header[:2] == ["t", "index"]:
        videos = [p for p in rec.root.iterdir() if p.suffix.lower() in (".mp4", ".mov", ".avi", ".mkv")]
        video = rec.extra.get("video") or (videos[0].name if len(videos) == 1 else None)
        if video is None:
            raise UserError("frames.csv has t,index but the folder does not hold exactly one video "
                            "(or name it with `video:` in calib.yaml)", where=str(path))
        arr = _read_numeric_csv(path, ["t", "index"])
        rec.frames_t, rec.frame_index, rec.video = arr[:, 0], arr[:, 1].astype(int), video
    else:
        raise UserError(f"header {header}: expected 't,file' (images) or 't,index' (with a video)", where=str(path))
    if rec.camera is None and rec.n_frames:
        raise UserError("frames are present but calib.yaml has no `camera:` section", where=str(rec.root / "calib.yaml"))
    _check_times(rec.frames_t, path, rec)


def read_frame(rec: Recording, i: int) -> np.ndarray:
    """Frame i as BGR uint8. Raises UserError naming the frame when it does not decode."""
    import cv2

    if rec.frame_files is not None:
        path = rec.root / rec.frame_files[i]
        if not path.is_file():
            raise UserError(f"frame {i} ({rec.frame_files[i]}): image file is missing", where=str(path))
        if path.stat().st_size == 0:
            raise UserError(f"frame {i} ({rec.frame_files[i]}): image file is empty (0 bytes)", where=str(path))
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise UserError(f"frame {i} ({rec.frame_files[i]}) does not decode as an image "
                            "(corrupt or truncated?)", where=str(path))
    else:
        cap = _video(rec)
        cap.set(cv2.CAP_PROP_POS_FRAMES, int(rec.frame_index[i]))
        ok, img = cap.read()
        if not ok:
            raise UserError(f"frame {i} (video index {rec.frame_index[i]}) could not be decoded",
                            where=str(rec.root / rec.video))
    if rec.camera is not None and img.shape[:2] != (rec.camera.height, rec.camera.width):
        raise UserError(f"frame {i} is {img.shape[1]}x{img.shape[0]} but calib.yaml says "
                        f"{rec.camera.width}x{rec.camera.height}", where=str(rec.root))
    return img


def iter_frames(rec: Recording, *, skip_bad: bool = False):
    """Yield (i, BGR frame) in order, decoding a video sequentially (much faster than seeking).

    With skip_bad, a frame that does not decode yields (i, None) and is reported in
    `rec.issues` instead of raising, so a long recording survives one corrupt frame.
    """
    import cv2

    if rec.frame_files is not None:
        for i in range(rec.n_frames):
            try:
                yield i, read_frame(rec, i)
            except UserError as e:
                if not skip_bad:
                    raise
                rec.issues.append(str(e))
                yield i, None
        return
    cap = cv2.VideoCapture(str(rec.root / rec.video))
    if not cap.isOpened():
        raise UserError("video cannot be opened", where=str(rec.root / rec.video))
    pos = 0
    for i, idx in enumerate(rec.frame_index):
        if idx != pos:
            cap.set(cv2.CAP_PROP_POS_FRAMES, int(idx))
            pos = int(idx)
        ok, img = cap.read()
        pos += 1
        if not ok or img is None:
            msg = f"frame {i} (video index {idx}) could not be decoded"
            if not skip_bad:
                raise UserError(msg, where=str(rec.root / rec.video))
            rec.issues.append(f"{rec.root / rec.video}: {msg}")
            yield i, None
            continue
        yield i, img


_VIDEO_CACHE: dict = {}


def _video(rec: Recording):
    import cv2

    key = str(rec.root / rec.video)
    if key not in _VIDEO_CACHE:
        cap = cv2.VideoCapture(key)
        if not cap.isOpened():
            raise UserError("video cannot be opened", where=key)
        _VIDEO_CACHE[key] = cap
    return _VIDEO_CACHE[key]


def _header(path: Path) -> list[str]:
    with open(path, newline="") as f:
        first = f.readline()
    return [c.strip().lstrip("#").strip() for c in first.split(",")]


def _rows(path: Path) -> list[list[str]]:
    with open(path, newline="") as f:
        rows = list(csv.reader(f))[1:]
    return [r for r in rows if r and any(c.strip() for c in r)]


def _num(s: str, path: Path, i: int) -> float:
    try:
        return float(s)
    except ValueError:
        raise UserError(f"row {i + 2}: {s!r} is not a number", where=str(path)) from None


def _read_numeric_csv(path: Path, columns: list[str], allow_nan: set[str] = frozenset()) -> np.ndarray:
    header = _header(path)
    missing = [c for c in columns if c not in header]
    if missing:
        raise UserError(f"missing column(s) {missing}; header is {header}, expected {columns}", where=str(path))
    idx = [header.index(c) for c in columns]
    rows = _rows(path)
    out = np.empty((len(rows), len(columns)))
    for i, r in enumerate(rows):
        if len(r) < len(header):
            raise UserError(f"row {i + 2}: {len(r)} fields, expected {len(header)}", where=str(path))
        out[i] = [_num(r[j], path, i) if r[j].strip() != "" else math.nan for j in idx]
    for k, c in enumerate(columns):
        bad = np.flatnonzero(~np.isfinite(out[:, k]))
        if bad.size and c not in allow_nan:
            raise UserError(f"row {bad[0] + 2}: column {c} is {out[bad[0], k]} (NaN/inf/empty); "
                            "remove or fill the row", where=str(path))
    return out


NAN_ROWS_MAX_FRACTION = 0.05  # more NaN rows than this is a broken file, not a dropout


def _drop_nan_rows(arr: np.ndarray, path: Path, rec: Recording, what: str, check=None) -> np.ndarray:
    """Drop rows with NaN sensor values (a logger's missed sample) and report them; too many
    is a UserError. The time column must always be finite (checked by the caller)."""
    cols = check if check is not None else list(range(1, arr.shape[1]))
    bad = ~np.all(np.isfinite(arr[:, cols]), axis=1)
    if not bad.any():
        return arr
    rows = np.flatnonzero(bad)
    if bad.mean() > NAN_ROWS_MAX_FRACTION:
        raise UserError(f"{bad.sum()} of {len(arr)} rows hold NaN/empty {what} values (first: row {rows[0] + 2}); "
                        f"more than {NAN_ROWS_MAX_FRACTION:.0%} means a broken export: fix the file",
                        where=str(path))
    rec.issues.append(f"{path.name}: dropped {bad.sum()} row(s) with NaN {what} values "
                      f"(rows {', '.join(str(r + 2) for r in rows[:5])}{'...' if len(rows) > 5 else ''})")
    return arr[~bad]


def _check_times(t: np.ndarray, path: Path, rec: Recording, gaps: bool = False) -> None:
    if len(t) < 2:
        return
    d = np.diff(t)
    bad = np.flatnonzero(d <= 0)
    if bad.size:
        kind = "duplicate" if d[bad[0]] == 0 else "non-monotonic"
        raise UserError(f"row {bad[0] + 3}: {kind} timestamp {t[bad[0] + 1]!r} after {t[bad[0]]!r}; "
                        "timestamps must increase strictly", where=str(path))
    if gaps:
        med = float(np.median(d))
        for j in np.flatnonzero(d > IMU_GAP_FACTOR * med):
            rec.issues.append(f"{path.name}: gap of {d[j]:.3f} s after t={t[j]:.3f} (median step {med:.4f} s)")


# ----------------------------------------------------------------------------- writing

def write_calib(root: Path, camera: Camera | None, T_cam_imu=None, imu_noise: ImuNoise | None = None,
                time_offset: float = 0.0, extra: dict | None = None, rolling_shutter_s: float = 0.0) -> None:
    data: dict = {}
    if camera is not None:
        data["camera"] = {
            "model": "pinhole",
            "intrinsics": [float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy)],
            "distortion_model": camera.distortion_model,
            "distortion_coeffs": [float(v) for v in camera.dist],
            "resolution": [int(camera.width), int(camera.height)],
        }
        if rolling_shutter_s > 0:
            data["camera"]["rolling_shutter_s"] = float(rolling_shutter_s)
    data["T_cam_imu"] = np.asarray(T_cam_imu if T_cam_imu is not None else np.eye(4), dtype=float).tolist()
    data["imu"] = {k: float(v) for k, v in vars(imu_noise or ImuNoise()).items()}
    data["timeshift_cam_imu"] = float(time_offset)
    data.update(extra or {})
    atomic.write_text(root / "calib.yaml", yaml.safe_dump(data, sort_keys=False))


def write_csv(path: Path, columns: list[str], rows, fmt: str = "%.9f") -> None:
    buf = io.StringIO()
    buf.write(",".join(columns) + "\n")
    arr = np.asarray(rows, dtype=float).reshape(-1, len(columns))
    if len(arr):
        np.savetxt(buf, arr, delimiter=",", fmt=fmt)
    atomic.write_text(path, buf.getvalue())


def write_frames_csv(root: Path, t, files: list[str]) -> None:
    lines = ["t,file"] + [f"{float(ti):.9f},{f}" for ti, f in zip(t, files)]
    atomic.write_text(root / "frames.csv", "\n".join(lines) + "\n")


def write_frames_index_csv(root: Path, t, index) -> None:
    """frames.csv as `t,index` for a recording whose frames live in one video file."""
    lines = ["t,index"] + [f"{float(ti):.9f},{int(k)}" for ti, k in zip(t, index)]
    atomic.write_text(root / "frames.csv", "\n".join(lines) + "\n")


def write_imu(root: Path, imu) -> None:
    write_csv(root / "imu.csv", IMU_COLUMNS, imu)


def write_gnss(root: Path, gnss, columns: list[str] | None = None) -> None:
    write_csv(root / "gnss.csv", columns or GNSS_REQUIRED, gnss, fmt="%.10f")


def write_speed(root: Path, speed) -> None:
    """speed.csv: the vehicle's forward speed (m/s) from its odometer or CAN bus."""
    write_csv(root / "speed.csv", SPEED_COLUMNS, speed)


def write_groundtruth(root: Path, gt) -> None:
    """groundtruth.csv, and the same poses as groundtruth.tum (`t x y z qx qy qz qw`, space
    separated) so that evo reads them: `evo_ape tum recording/groundtruth.tum poses.tum`."""
    write_csv(root / "groundtruth.csv", GT_COLUMNS, gt)
    arr = np.asarray(gt, dtype=float).reshape(-1, len(GT_COLUMNS))
    buf = io.StringIO()
    np.savetxt(buf, arr[:, [0, 1, 2, 3, 5, 6, 7, 4]], fmt="%.9f")
    atomic.write_text(root / "groundtruth.tum", buf.getvalue())
