"""ROS 1 (.bag) and ROS 2 (folder with metadata.yaml, .db3/.mcap) bags -> recording folder.

Reads with the `rosbags` library (pure Python, no ROS install): sensor_msgs Image (raw
encodings, written as PNG) or CompressedImage (bytes kept, no re-encoding), Imu, NavSatFix,
CameraInfo for the intrinsics, and the vehicle's speed (speed.csv) from nav_msgs Odometry or
geometry_msgs TwistStamped (twist.linear.x: forward in the vehicle's own frame; readings while
reversing are dropped, speed.csv is unsigned). Message times are header stamps (the bag's receive time
when a stamp is zero). Topics are found by type; pass a topic when a bag has several.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from blendgen import atomic
from blendgen.errors import UserError
from blendgen.geometry import Camera
from blendgen.recording import folder
from blendgen.recording.importers import common

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
IMU = "sensor_msgs/msg/Imu"
NAVSAT = "sensor_msgs/msg/NavSatFix"
CAMINFO = "sensor_msgs/msg/CameraInfo"
SPEED_TYPES = ("nav_msgs/msg/Odometry", "geometry_msgs/msg/TwistStamped")
DEFAULT_HFOV_DEG = 70.0

_CHANNELS = {"mono8": (1, np.uint8), "mono16": (1, np.uint16), "bgr8": (3, np.uint8), "rgb8": (3, np.uint8),
             "bgra8": (4, np.uint8), "rgba8": (4, np.uint8), "8UC1": (1, np.uint8), "8UC3": (3, np.uint8),
             "16UC1": (1, np.uint16), "bayer_rggb8": (1, np.uint8), "bayer_bggr8": (1, np.uint8),
             "bayer_gbrg8": (1, np.uint8), "bayer_grbg8": (1, np.uint8)}


def _stamp(msg, fallback_ns: int) -> float:
    st = getattr(getattr(msg, "header", None), "stamp", None)
    if st is not None:
        ns = int(getattr(st, "sec", 0)) * 1_000_000_000 + int(getattr(st, "nanosec", 0))
        if ns > 0:
            return ns * 1e-9
    return fallback_ns * 1e-9


def image_to_bgr(msg, where: str) -> np.ndarray:
    """sensor_msgs/Image -> numpy image (BGR, or single channel), honouring step and endianness."""
    import cv2

    enc = msg.encoding
    if enc not in _CHANNELS:
        raise UserError(f"image encoding {enc!r} is not supported; expected one of {sorted(_CHANNELS)}", where=where)
    ch, dt = _CHANNELS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    item = np.dtype(dt).itemsize
    if step < w * ch * item or data.size < step * h:
        raise UserError(f"image data has {data.size} bytes, expected {step * h} ({w}x{h}, step {step}, {enc}); "
                        "truncated message", where=where)
    rows = data[: step * h].reshape(h, step)[:, : w * ch * item]
    img = rows.copy().view(np.dtype(dt).newbyteorder(">" if msg.is_bigendian else "<")).astype(dt)
    img = img.reshape(h, w, ch) if ch > 1 else img.reshape(h, w)
    if enc == "rgb8":
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    elif enc == "rgba8":
        img = cv2.cvtColor(img, cv2.COLOR_RGBA2BGR)
    elif enc == "bgra8":
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    elif enc.startswith("bayer_"):
        # OpenCV names Bayer patterns by the second row; ROS by the first
        code = {"rggb": cv2.COLOR_BayerBG2BGR, "bggr": cv2.COLOR_BayerRG2BGR,
                "gbrg": cv2.COLOR_BayerGR2BGR, "grbg": cv2.COLOR_BayerGB2BGR}[enc[6:10]]
        img = cv2.cvtColor(img, code)
    return img


def _pick(topics: dict[str, str], types: tuple[str, ...], wanted: str | None, what: str,
          several_ok: bool = False) -> str | None:
    if wanted:
        if wanted not in topics:
            raise UserError(f"--{what}-topic {wanted!r} is not in the bag; topics: {sorted(topics)}")
        if topics[wanted] not in types:
            raise UserError(f"topic {wanted!r} has type {topics[wanted]}, expected {' or '.join(types)}")
        return wanted
    cands = sorted(t for t, ty in topics.items() if ty in types)
    if len(cands) > 1:
        if several_ok:  # optional stream: none rather than a guess
            return None
        raise UserError(f"several {what} topics {cands}: choose one with --{what}-topic")
    return cands[0] if cands else None


def _by_time(rows: list) -> np.ndarray:
    """Message rows (t first) sorted by time, repeated stamps dropped."""
    arr = np.asarray(rows, dtype=float)
    return common.dedupe_sorted(arr[:, 0], arr)[1]


def import_rosbag(src, dst, *, image_topic: str | None = None, imu_topic: str | None = None,
                  gnss_topic: str | None = None, speed_topic: str | None = None, hfov_deg: float | None = None,
                  force: bool = False, show_progress: bool = True) -> Path:
    import cv2

    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise UserError("ROS bags need the `rosbags` package: pip install rosbags") from None

    src = Path(src)
    if not src.exists():
        raise UserError("bag not found (a .bag file for ROS 1, a folder with metadata.yaml for ROS 2)", where=str(src))
    try:
        reader = AnyReader([src], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as e:  # rosbags raises its own reader errors for corrupt/truncated bags
        raise UserError(f"cannot read the bag: {e}", where=str(src)) from None
    dst = common.prepare_output(dst, force)
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        img_t = _pick(topics, (IMAGE, COMPRESSED), image_topic, "image")
        imu_t = _pick(topics, (IMU,), imu_topic, "imu")
        gnss_t = _pick(topics, (NAVSAT,), gnss_topic, "gnss")
        # odometry topics are often fused estimates, not the wheels: with several, none unless named
        speed_t = _pick(topics, SPEED_TYPES, speed_topic, "speed", several_ok=True)
        speed_cands = sorted(t for t, ty in topics.items() if ty in SPEED_TYPES)
        info_t = sorted(t for t, ty in topics.items() if ty == CAMINFO)
        if img_t and len(info_t) > 1:  # prefer the camera_info beside the image topic
            base = img_t.rsplit("/", 1)[0]
            info_t = [t for t in info_t if t.startswith(base)] or info_t[:1]
        if not (img_t or imu_t or gnss_t):
            raise UserError(f"no Image/CompressedImage, Imu or NavSatFix topics; topics: {topics}", where=str(src))
        wanted = [c for c in reader.connections if c.topic in {img_t, imu_t, gnss_t, speed_t, *info_t[:1]}]
        frames_t, files, imu, gnss, speed, cam_info = [], [], [], [], [], None
        shape = None
        total = sum(c.msgcount for c in wanted)
        it = reader.messages(connections=wanted)
        for n, (conn, ts, raw) in enumerate(common.progress(it, total=total, desc="bag", enabled=show_progress)):
            where = f"{src} topic {conn.topic} message {n}"
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as e:
                raise UserError(f"message does not deserialize as {conn.msgtype}: {e}", where=where) from None
            t = _stamp(msg, ts)
            if conn.topic == img_t:
                k = len(files)
                if conn.msgtype == COMPRESSED:
                    data = bytes(np.asarray(msg.data, dtype=np.uint8))
                    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
                    if img is None:
                        raise UserError("compressed image does not decode (corrupt or truncated)", where=where)
                    ext = ".png" if data[:4] == b"\x89PNG" else ".jpg"
                    rel = f"images/{k:06d}{ext}"
                    atomic.write_bytes(dst / rel, data)
                else:
                    img = image_to_bgr(msg, where)
                    rel = f"images/{k:06d}.png"
                    atomic.write_image(dst / rel, img)
                if shape is None:
                    shape = img.shape[:2]
                elif img.shape[:2] != shape:
                    raise UserError(f"image size changed from {shape[::-1]} to {img.shape[1::-1]}", where=where)
                frames_t.append(t)
                files.append(rel)
            elif conn.topic == imu_t:
                w, a = msg.angular_velocity, msg.linear_acceleration
                imu.append([t, w.x, w.y, w.z, a.x, a.y, a.z])
            elif conn.topic == gnss_t:
                if int(msg.status.status) < 0 or not np.isfinite(msg.latitude):  # STATUS_NO_FIX
                    continue
                cov = np.asarray(msg.position_covariance, dtype=float)
                std = float(np.sqrt(max((cov[0] + cov[4]) / 2, 0))) if msg.position_covariance_type > 0 else np.nan
                gnss.append([t, msg.latitude, msg.longitude, msg.altitude, std if std > 0 else np.nan])
            elif conn.topic == speed_t:
                tw = msg.twist.twist if conn.msgtype == SPEED_TYPES[0] else msg.twist
                speed.append([t, float(tw.linear.x)])
            elif cam_info is None:
                cam_info = msg
    except UserError:
        raise
    except Exception as e:
        raise UserError(f"reading the bag failed (truncated or corrupt?): {e}", where=str(src)) from None
    finally:
        reader.close()

    notes = [f"topics used: image {img_t}, imu {imu_t}, gnss {gnss_t}, speed {speed_t}, "
             f"camera_info {info_t[:1] or None}"]
    if speed_t is None and len(speed_cands) > 1:
        notes.append(f"several odometry/twist topics {speed_cands}: none used as the vehicle's speed "
                     "(choose one with --speed-topic)")
    if speed:
        arr = _by_time(speed)
        arr = arr[np.isfinite(arr[:, 1])]
        back = arr[:, 1] < 0
        if back.any():
            notes.append(f"{int(back.sum())} speed reading(s) < 0 (reversing) dropped: speed.csv is unsigned")
        folder.write_speed(dst, arr[~back])
    if imu:
        folder.write_imu(dst, _by_time(imu))
    if gnss:
        arr = _by_time(gnss)
        cols = ["t", "lat", "lon", "alt"] + (["h_std_m"] if np.any(np.isfinite(arr[:, 4])) else [])
        folder.write_gnss(dst, arr[:, : len(cols)], cols)
    camera, cam_note = None, "no images"
    if files:
        order = np.argsort(frames_t, kind="stable")
        t_sorted = np.asarray(frames_t)[order]
        if np.any(np.diff(t_sorted) <= 0):
            raise UserError(f"image topic {img_t} has repeated timestamps", where=str(src))
        folder.write_frames_csv(dst, t_sorted, [files[i] for i in order])
        h, w = shape
        camera = _camera_from_info(cam_info, w, h) if cam_info is not None else None
        if camera is not None:
            cam_note = f"from {info_t[0]}"
        else:
            hf = float(hfov_deg) if hfov_deg else DEFAULT_HFOV_DEG
            camera = common.default_camera(w, h, hf)
            cam_note = f"assumed pinhole with {hf:g} deg horizontal field of view (no usable CameraInfo)"
    meta = common.import_meta("rosbag", src, camera=cam_note,
                              T_cam_imu="assumed identity (tf is not read; set T_cam_imu in calib.yaml)",
                              notes=notes)
    folder.write_calib(dst, camera, None, None, extra={"import": meta})
    return dst


def _camera_from_info(info, w: int, h: int) -> Camera | None:
    K = np.asarray(getattr(info, "k", getattr(info, "K", np.zeros(9))), dtype=float).ravel()
    D = [float(v) for v in np.asarray(getattr(info, "d", getattr(info, "D", [])), dtype=float).ravel()]
    model = getattr(info, "distortion_model", "plumb_bob")
    if K.size != 9 or K[0] <= 0 or K[4] <= 0:
        return None
    size = (int(info.width) or w, int(info.height) or h)
    if model == "equidistant" and len(D) == 4:  # ROS's name for the Kannala-Brandt fisheye
        cam = Camera(*size, K[0], K[4], K[2], K[5], D, "equidistant")
    elif model not in ("plumb_bob", "radtan", "") or len(D) not in (0, 4, 5):
        return None  # e.g. rational_polynomial: not representable by blendgen's Camera
    else:
        cam = Camera(*size, K[0], K[4], K[2], K[5], (D + [0.0] * 5)[:5])
    return cam.scaled(w, h) if (cam.width, cam.height) != (w, h) else cam
