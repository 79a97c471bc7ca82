"""GoPro MP4 with GPMF telemetry -> recording folder (video kept as it is, frames.csv `t,index`).

The `gpmd` track is read straight from the MP4 sample tables (mp4.py) and parsed as KLV
(gpmf.py). Used streams:
  ACCL (m/s^2), GYRO (rad/s): camera IMU. Columns come in the sensor's axis order (HERO5: z, x, y,
      named in STNM; HERO6+: ORIN, lower case = negated). blendgen writes them in GoPro's IMU
      frame (gpmf-parser's "IMU Orientation" figure: X left, Y back towards the screen, Z up) and
      T_cam_imu rotates that frame to the OpenCV camera axes. Checked on the HERO5/Karma sample:
      gravity is image "up", the forward specific force follows the GNSS speed-up, and with the
      old reading (X right, Y forward) 28 of 47 fixes were rejected, now none.
  GPS5 (lat, lon, alt, 2D speed, 3D speed) with GPSP (DOP x100) from the camera's receiver, or
  the GoPro Karma drone's GPRI (MAVLink GPS_RAW: time, lat, lon, alt, eph, epv, vel, cog, fix, sats).
  CORI (camera orientation quaternions, HERO8+) is written to `cori.csv` beside the recording
  (not part of the recording model; kept for stabilisation-aware users).
Timing: every stream's samples are placed on the video clock by a linear fit of payload start
times against the running sample count (the last payload is usually partial). Karma messages
carry the drone's clock: its offset to the video clock is the median lag between message time
and the payload window that carried it.
Lens: the file names the camera (udta FIRM) but not its lens mode. With `--lens MODE` (and
`--eis` for electronically stabilised footage) the camera model's fisheye profile from Gyroflow's
lens database is written, scaled to the video, with its rolling-shutter readout where the
database lists a real one for the video's own size and frame rate (gopro_lens.py). Without it a pinhole with a 94 deg
horizontal field of view is assumed and flagged by the check; sync then takes VO's rotation at
a loose floor and no direction of travel.
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from blendgen.errors import UserError
from blendgen.geometry import make_pose
from blendgen.recording import folder
from blendgen.recording.importers import common, gopro_lens, gpmf, mp4
from blendgen.recording.model import ImuNoise

DEFAULT_HFOV_DEG = 94.0
# GoPro IMU frame (X left, Y back, Z up) -> OpenCV camera (x right, y down, z forward)
R_CAM_SENSOR = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]])
HERO5_ORDER = "ZXY"  # HERO5 streams without ORIN: "Gyroscope (z,x,y)", "Accelerometer (up/down, right/left, forward/back)"


def read_telemetry(path: Path, *, show_progress: bool = True) -> dict:
    """GPMF payloads of an MP4 -> per-stream samples on the video clock."""
    tracks = mp4.read_tracks(path)
    meta = [t for t in tracks if t.codec == "gpmd"]
    if not meta:
        raise UserError("no GPMF telemetry track ('gpmd'): not a GoPro file, or telemetry was stripped "
                        "by an editor", where=str(path))
    tr = meta[0]
    samples = mp4.read_samples(path, tr)
    starts = tr.presentation_times()
    durs = tr.durations / float(tr.timescale)
    per_key: dict[str, list] = {}
    keys = {"ACCL", "GYRO", "GPS5", "GPSP", "GPSF", "CORI", "GPRI", "SYST", "GPSU"}
    for k, buf in common.progress(list(enumerate(samples)), desc="GPMF", enabled=show_progress):
        try:
            tree = gpmf.parse(buf)
            found = gpmf.streams(tree, keys)
        except gpmf.GpmfError as e:
            raise UserError(f"GPMF payload {k} (at {starts[k]:.3f} s) is corrupt: {e}", where=str(path)) from None
        for s in found:
            per_key.setdefault(s.key, []).append((k, s))
    return {"per_key": per_key, "starts": starts, "durs": durs, "n_payloads": len(samples)}


def stream_times(entries: list, starts: np.ndarray, durs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(t, values) for one stream: sample times from a fit of payload start vs running count."""
    counts = np.array([len(s.values) for _, s in entries])
    values = np.vstack([s.values for _, s in entries]) if entries else np.zeros((0, 1))
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    pay = np.array([k for k, _ in entries])
    full = counts > 0
    if len(pay) >= 3:
        use = full.copy()
        use[-1] = False  # the last payload is cut short by the end of the recording
        b, a = np.polyfit(first[use], starts[pay[use]], 1)
        if b <= 0:
            raise UserError("GPMF sample counts do not increase with time; corrupt telemetry")
        t = a + b * np.arange(len(values))
    else:  # one or two payloads: spread each payload's samples evenly over its duration
        t = np.concatenate([starts[k] + (np.arange(n) / max(n, 1)) * durs[k] for k, n in zip(pay, counts)])
    return t, values


def _axes(entries, key) -> np.ndarray:
    """Reorder (and sign) columns into the sensor frame x, y, z using ORIN or the HERO5 order."""
    orin = next((s.orin for _, s in entries if s.orin), None) or HERO5_ORDER
    M = np.zeros((3, 3))
    for col, ch in enumerate(orin[:3]):
        axis = "XYZ".index(ch.upper())
        M[axis, col] = -1.0 if ch.islower() else 1.0
    if abs(abs(np.linalg.det(M)) - 1) > 1e-9:
        raise UserError(f"{key}: ORIN {orin!r} is not an axis order")
    return M


def import_gopro(src, dst, *, hfov_deg: float | None = None, lens: str | None = None, eis: bool = False,
                 force: bool = False, show_progress: bool = True) -> Path:
    from blendgen.recording.importers.video import video_frame_times

    src = Path(src)
    if not src.is_file():
        raise UserError("GoPro MP4 not found", where=str(src))
    if lens and hfov_deg:
        raise UserError("give either --lens (a GoPro lens mode) or --hfov, not both")
    firmware = mp4.read_user_data(src).get("FIRM", b"").split(b"\0")[0].decode("ascii", "replace")
    model = gopro_lens.model_from_firmware(firmware)
    tel = read_telemetry(src, show_progress=show_progress)
    pk, starts, durs = tel["per_key"], tel["starts"], tel["durs"]
    t_frames = video_frame_times(src, show_progress=show_progress)
    w, h = common.first_frame_size(src)
    found = None
    if lens:
        if model is None:
            raise UserError(f"--lens: the camera model is unknown (firmware {firmware or 'not in the file'!r}); "
                            "give its field of view with --hfov", where=str(src))
        fps = 1.0 / float(np.median(np.diff(t_frames))) if len(t_frames) > 1 else 30.0
        found = gopro_lens.find_lens(model, lens, eis, w, h, fps)  # before anything is written
    notes: list[str] = [f"camera: {model or 'unknown model'} (firmware {firmware or 'not in the file'})"]
    dst = common.prepare_output(dst, force)

    # IMU
    if "ACCL" in pk and "GYRO" in pk:
        ta, acc = stream_times(pk["ACCL"], starts, durs)
        tg, gyr = stream_times(pk["GYRO"], starts, durs)
        acc = acc[:, :3] @ _axes(pk["ACCL"], "ACCL").T
        gyr = gyr[:, :3] @ _axes(pk["GYRO"], "GYRO").T
        # one clock for both: the accelerometer resampled onto the (faster) gyroscope stamps
        inside = (tg >= ta[0]) & (tg <= ta[-1])
        tg, gyr = tg[inside], gyr[inside]
        acc_i = np.column_stack([np.interp(tg, ta, acc[:, k]) for k in range(3)])
        imu = np.column_stack([tg, gyr, acc_i])
        if not np.all(np.isfinite(imu)):
            raise UserError("GPMF ACCL/GYRO contain non-finite values", where=str(src))
        folder.write_imu(dst, imu)
        rate = float(1 / np.median(np.diff(tg)))
        notes.append(f"IMU: GYRO {len(tg)} samples ({rate:.0f} Hz), ACCL {len(ta)} resampled onto GYRO times")
    else:
        rate = 200.0
        notes.append("no ACCL/GYRO streams in the telemetry")

    # GNSS
    utc_origin = None
    if "GPS5" in pk:
        tgps, g = stream_times(pk["GPS5"], starts, durs)
        cols, data = ["t", "lat", "lon", "alt"], [tgps, g[:, 0], g[:, 1], g[:, 2]]
        if "GPSP" in pk:  # dilution of precision x100, one per payload; ~5 m per unit DOP (u-blox class)
            dop = np.repeat([float(s.values.ravel()[0]) for _, s in pk["GPSP"]],
                            [len(s.values) for _, s in pk["GPS5"]][:len(pk["GPSP"])])
            if len(dop) == len(tgps):
                cols.append("h_std_m")
                data.append(dop / 100.0 * 5.0)
        ok_fix = np.abs(g[:, 0]) > 1e-6
        gnss = np.column_stack(data)[ok_fix]
        folder.write_gnss(dst, gnss, cols)
        notes.append("GNSS from the camera's GPS5 stream")
    elif "GPRI" in pk:
        gnss, utc_origin = _karma_gnss(pk, starts, durs)
        folder.write_gnss(dst, gnss, ["t", "lat", "lon", "alt", "heading_deg", "h_std_m"])
        notes.append("GNSS from the Karma drone's GPRI stream; its clock aligned to the video by payload "
                     "windows (about +-0.1 s)")
    else:
        notes.append("no GPS in the telemetry (GPS off, or no fix)")

    if "CORI" in pk:
        tc, q = stream_times(pk["CORI"], starts, durs)
        folder.write_csv(dst / "cori.csv", ["t", "qw", "qx", "qy", "qz"], np.column_stack([tc, q[:, :4]]))
        notes.append("CORI camera orientation written to cori.csv")

    video_name = "video.mp4"
    common.place_file(src, dst / video_name)
    folder.write_frames_index_csv(dst, t_frames, np.arange(len(t_frames)))
    if found is not None:
        camera, cam_desc = found.camera, found.description
        notes.extend(found.notes)
    else:
        hf = float(hfov_deg) if hfov_deg else DEFAULT_HFOV_DEG
        camera = common.default_camera(w, h, hf)
        cam_desc = f"assumed pinhole with {hf:g} deg horizontal field of view (GoPro intrinsics are not in the file)"
        if model and not hfov_deg and gopro_lens.modes(model):
            notes.append(f"the lens mode is not in the file: --lens {' | '.join(gopro_lens.modes(model))} writes "
                         f"the {model}'s calibrated lens instead of this assumption")
    extra = {"video": video_name}
    if "GPRI" in pk:  # only a Karma drone writes GPRI: sync must not hold it to a road vehicle's motion
        extra["vehicle"] = {"road_vehicle": False}
        notes.append("Karma drone telemetry (GPRI): calib.yaml vehicle.road_vehicle false, sync applies no "
                     "road-vehicle constraints")
    if utc_origin is not None:
        extra["time_origin_utc"] = datetime.fromtimestamp(utc_origin, tz=timezone.utc).isoformat()
    extra["import"] = common.import_meta(
        "gopro", src,
        camera=cam_desc,
        T_cam_imu="assumed GoPro IMU axes (X left, Y back, Z up) rotated to camera axes, lever arm 0",
        notes=notes)
    # an uncalibrated consumer IMU: turn-on biases as its class's datasheets allow (+-40 mg, a few
    # deg/s); held to the automotive 0.1 m/s^2 the Karma clip's camera tilted 1.2 deg against the
    # sea horizon, taking the accelerometer's bias for tilt (0.35 deg with these; docs/sync.md)
    noise = ImuNoise(update_rate=rate, accelerometer_bias_std=0.3, gyroscope_bias_std=0.03)
    folder.write_calib(dst, camera, make_pose(R_CAM_SENSOR, np.zeros(3)), noise, extra=extra,
                       rolling_shutter_s=(found.readout_s or 0.0) if found is not None else 0.0)
    return dst


def _karma_gnss(pk: dict, starts: np.ndarray, durs: np.ndarray):
    rows, lags = [], []
    for k, s in pk["GPRI"]:
        v = s.values
        rows.append(v)
        # each message arrived inside payload k's window: drone time - window middle ~ clock offset
        lags.extend(v[:, 0] - (starts[k] + durs[k] / 2))
    v = np.vstack(rows)
    offset = float(np.median(lags))
    t = v[:, 0] - offset
    ok = (np.abs(v[:, 1]) > 1e-6) & (v[:, 8] >= 2)  # fix type >= 2D
    heading = np.where(v[:, 6] > 1.0, np.mod(v[:, 7], 360.0), np.nan)  # course is noise when hovering
    gnss = np.column_stack([t, v[:, 1], v[:, 2], v[:, 3], heading, np.where(v[:, 4] > 0, v[:, 4], np.nan)])[ok]
    gnss = gnss[np.argsort(gnss[:, 0], kind="stable")]
    gnss = gnss[np.concatenate([[True], np.diff(gnss[:, 0]) > 0])]
    utc = None
    if "SYST" in pk:  # (drone time s, Unix time s) pairs
        s = np.vstack([e.values for _, e in pk["SYST"]])
        utc = float(np.median(s[:, 1] - s[:, 0])) + offset
    return gnss, utc
