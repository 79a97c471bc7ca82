"""`blendgen import --check`: what a recording folder lacks or what looks odd in it.

Every finding is one line a person can act on. Levels: "error" (the folder does not read),
"warn" (usable, but a stage will be weaker or must assume something), "info" (facts).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from blendgen.errors import UserError

G = 9.80665


@dataclass
class Finding:
    level: str  # error | warn | info
    message: str

    def __str__(self) -> str:
        return f"{self.level.upper():5s} {self.message}"


def check_recording(root: str | Path) -> list[Finding]:
    from blendgen.recording.folder import MISSING_IMAGES, read_recording

    root = Path(root)
    try:
        rec = read_recording(root)
    except UserError as e:
        return [Finding("error", str(e))]
    out: list[Finding] = []
    meta = rec.extra.get("import") or {}
    if meta:
        out.append(Finding("info", f"imported from {meta.get('format')} ({meta.get('source')})"))

    # camera
    cam_src = str(meta.get("camera_calibration", "calib.yaml"))
    if rec.camera is None:
        out.append(Finding("warn", "no camera calibration (calib.yaml has no camera: section)"))
    elif rec.lens_source == "assumed":
        out.append(Finding("warn", f"camera intrinsics are not calibrated: {cam_src}; calibrate the camera "
                                   "(e.g. Kalibr/OpenCV) and edit calib.yaml for metric accuracy"))
    else:
        c = rec.camera
        out.append(Finding("info", f"camera {c.width}x{c.height}, fx {c.fx:.1f} fy {c.fy:.1f} ({cam_src})"))
    if str(meta.get("T_cam_imu", "")).startswith("assumed"):
        out.append(Finding("warn", f"camera-IMU extrinsics not calibrated: {meta['T_cam_imu']}"))

    # frames
    if rec.n_frames == 0:
        out.append(Finding("warn", "no camera frames: sync can use IMU/GNSS only (no visual odometry), "
                                   "and nothing can be composited over real images"))
    else:
        out.extend(_stream_timing("frames", rec.frames_t, gap_factor=1.8))
        if rec.video:
            out.extend(_video_consistency(rec))
        elif rec.camera is not None:
            out.extend(_image_findings(rec))

    # IMU
    if len(rec.imu) == 0:
        out.append(Finding("warn", "no IMU (imu.csv): orientation comes from vision/GNSS only"))
    else:
        out.extend(_stream_timing("IMU", rec.imu[:, 0], gap_factor=5.0))
        acc = np.linalg.norm(rec.imu[:, 4:7], axis=1)
        gyr = np.linalg.norm(rec.imu[:, 1:4], axis=1)
        med_a = float(np.median(acc))
        if abs(med_a - G) > 2.5:
            hint = " (looks like units of g: multiply by 9.80665)" if 0.6 < med_a < 1.5 else ""
            out.append(Finding("warn", f"IMU: median |accel| is {med_a:.2f} m/s^2, expected about {G:.2f} "
                                       f"(specific force including gravity){hint}"))
        if float(np.median(gyr)) > 1.0:
            out.append(Finding("warn", f"IMU: median |gyro| is {np.median(gyr):.2f} rad/s; deg/s by mistake?"))
        out.extend(_imu_physics(rec))

    # GNSS
    if len(rec.gnss) == 0:
        out.append(Finding("warn", "no GNSS (gnss.csv): no global anchoring; poses stay in a local frame"))
    else:
        t = rec.gnss[:, 0]
        out.extend(_stream_timing("GNSS", t, gap_factor=3.0, min_gap_s=1.0))
        if len(t) > 1:
            from pymap3d import geodetic2enu

            e, n, u = geodetic2enu(rec.gnss[:, 1], rec.gnss[:, 2], rec.gnss[:, 3],
                                   rec.gnss[0, 1], rec.gnss[0, 2], rec.gnss[0, 3])
            speed = np.hypot(np.diff(e), np.diff(n)) / np.diff(t)
            jumps = np.flatnonzero(speed > 100.0)
            if jumps.size:
                out.append(Finding("warn", f"GNSS: {jumps.size} jump(s) faster than 100 m/s, first at "
                                           f"t={t[jumps[0]]:.3f} ({speed[jumps[0]]:.0f} m/s)"))
            out.append(Finding("info", f"GNSS track {np.sum(np.hypot(np.diff(e), np.diff(n))):.0f} m long"))
        if "h_std_m" not in rec.gnss_columns:
            out.append(Finding("info", "GNSS has no h_std_m column: sync uses its default GNSS noise"))

    # ground truth and time overlap
    if rec.groundtruth is None:
        out.append(Finding("info", "no ground truth (groundtruth.csv): accuracy cannot be measured"))
    else:
        out.append(Finding("info", f"ground truth: {len(rec.groundtruth)} poses"))
    spans = {k: (v[0], v[-1]) for k, v in (("frames", rec.frames_t), ("IMU", rec.imu[:, 0]),
                                           ("GNSS", rec.gnss[:, 0])) if len(v)}
    if len(spans) > 1:
        lo = max(s[0] for s in spans.values())
        hi = min(s[1] for s in spans.values())
        if hi <= lo:
            # IMU or GNSS beside frames they never overlap cannot place a single frame
            level = "error" if "frames" in spans else "warn"
            out.append(Finding(level, f"{rec.root}: streams do not overlap in time: {_fmt_spans(spans)}; "
                                      "wrong clock, unit (ns?) or time offset?"))
        elif "frames" in spans and "IMU" in spans and (spans["IMU"][0] > spans["frames"][0] + 0.5
                                                        or spans["IMU"][1] < spans["frames"][1] - 0.5):
            out.append(Finding("warn", f"IMU does not cover all frames: {_fmt_spans(spans)}"))
    out.extend(_label_findings(rec))
    images_checked = rec.n_frames and not rec.video and rec.camera is not None
    for issue in rec.issues:
        if images_checked and MISSING_IMAGES in issue:
            continue  # already an error per image above
        out.append(Finding("warn", issue))
    for note in meta.get("notes", []) or []:
        out.append(Finding("info", str(note)))
    return out


def _label_findings(rec) -> list[Finding]:
    """The recording's own labels (labels.json): how many frames they cover, or why they do not read."""
    from collections import Counter

    from blendgen.recording.labels import read_recording_labels

    try:
        labels = read_recording_labels(rec)
    except UserError as e:
        return [Finding("error", str(e))]
    if labels is None:
        return [Finding("info", "no labels of the real road users (labels.json): jobs label them with the detector "
                                "(labels.real)")]
    per = Counter(b["cls"] for boxes in labels.values() for b in boxes)
    out = [Finding("info", f"labels for {len(labels)} of {rec.n_frames} frames: "
                           + (", ".join(f"{c} {n}" for c, n in sorted(per.items())) or "no boxes"))]
    if len(labels) < rec.n_frames:
        out.append(Finding("warn", f"{rec.n_frames - len(labels)} frame(s) have no labels: with labels.real user "
                                   "their real road users come from the detector"))
    return out


# Beyond any automotive MEMS IMU's range (typically +-2000 deg/s = 35 rad/s, +-16 g): a wrong
# unit or a corrupt export, not a drive.
MAX_GYRO_RAD_S = 50.0
MAX_ACCEL_M_S2 = 50 * G
SATURATED_FRACTION = 0.2  # this share of samples pinned at one extreme value: a clipped sensor
MAX_LISTED = 10
SATURATION_MIN = (3.0, 2 * G)  # (gyro rad/s, accel m/s^2): no steady drive reads more


def _imu_physics(rec) -> list[Finding]:
    out = []
    path = rec.root / "imu.csv"
    for cols, limit, unit, what in ((slice(1, 4), MAX_GYRO_RAD_S, "rad/s", "angular rate"),
                                    (slice(4, 7), MAX_ACCEL_M_S2, "m/s^2", "acceleration")):
        v = np.abs(rec.imu[:, cols])
        bad = np.flatnonzero(v.max(axis=1) > limit)
        if bad.size:
            out.append(Finding("error", f"{path}: row {bad[0] + 2}: {what} {v[bad[0]].max():.4g} {unit} is "
                                        f"physically impossible (limit {limit:.0f} {unit}); {bad.size} row(s) "
                                        "like this: wrong unit or corrupt export?"))
    if len(rec.imu) >= 20:
        for k, name in enumerate(IMU_AXES, start=1):
            col = rec.imu[:, k]
            peak = np.abs(col).max()
            share = float(np.mean(np.abs(col) == peak))
            # a resting axis reads a constant too (0, or gravity): only a large pinned value is clipping
            if peak > SATURATION_MIN[k > 3] and share >= SATURATED_FRACTION:
                out.append(Finding("error", f"{path}: column {name} sits at its extreme {peak:.4g} in "
                                            f"{share:.0%} of rows: the sensor is saturated (clipped)"))
    return out


IMU_AXES = ("wx", "wy", "wz", "ax", "ay", "az")


def _image_findings(rec) -> list[Finding]:
    """Every image exists, is not empty, has the calibrated size and decodes (as `run` reads
    it, but at 1/8 scale: a JPEG decodes ~3x faster, and nothing is rendered)."""
    import cv2
    from PIL import Image

    want = (rec.camera.width, rec.camera.height)
    bad = []
    for i, f in enumerate(rec.frame_files):
        p = rec.root / f
        why = None
        if not p.is_file():
            why = "image file is missing"
        elif p.stat().st_size == 0:
            why = "image file is empty (0 bytes)"
        else:
            try:
                with Image.open(p) as im:
                    size = im.size
            except Exception:  # noqa: BLE001 - PIL raises many types for a non-image
                size = None
            if size is None or cv2.imread(str(p), cv2.IMREAD_REDUCED_GRAYSCALE_8) is None:
                why = "does not decode as an image (corrupt or truncated?)"
            elif size != want:
                why = f"is {size[0]}x{size[1]} but calib.yaml says {want[0]}x{want[1]}"
        if why:
            bad.append(f"{rec.root / 'frames.csv'}: row {i + 2}: {f}: {why}")
    out = [Finding("error", b) for b in bad[:MAX_LISTED]]
    if len(bad) > MAX_LISTED:
        out.append(Finding("error", f"... and {len(bad) - MAX_LISTED} more bad image(s) of {rec.n_frames}"))
    if bad:
        out.append(Finding("info", f"{len(bad)} of {rec.n_frames} frames are bad: `blendgen run` produces the "
                                   "others and lists each bad one with its reason"))
    return out


def _stream_timing(name: str, t: np.ndarray, gap_factor: float, min_gap_s: float = 0.0) -> list[Finding]:
    if len(t) < 2:
        return [Finding("warn", f"{name}: only {len(t)} sample(s)")]
    d = np.diff(t)
    med = float(np.median(d))
    out = [Finding("info", f"{name}: {len(t)} samples, {1 / med:.1f} Hz, {t[-1] - t[0]:.2f} s")]
    gaps = np.flatnonzero(d > max(gap_factor * med, min_gap_s))
    if gaps.size and name != "IMU":  # IMU gaps are already reported by the reader
        j = gaps[np.argmax(d[gaps])]
        out.append(Finding("warn", f"{name}: {gaps.size} gap(s), longest {d[j]:.2f} s after t={t[j]:.3f} "
                                   f"(median step {med:.3f} s)"))
    return out


def _video_consistency(rec) -> list[Finding]:
    import cv2

    cap = cv2.VideoCapture(str(rec.root / rec.video))
    if not cap.isOpened():
        return [Finding("error", f"video {rec.video} cannot be opened by OpenCV")]
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    cap.release()
    out = []
    if n > 0 and int(rec.frame_index.max()) >= n:
        out.append(Finding("error", f"frames.csv refers to video frame {int(rec.frame_index.max())} but "
                                    f"{rec.video} has {n} frames"))
    if rec.camera is not None and (w, h) != (rec.camera.width, rec.camera.height):
        out.append(Finding("error", f"video is {w}x{h} but calib.yaml says {rec.camera.width}x{rec.camera.height}"))
    return out


def _fmt_spans(spans: dict) -> str:
    return ", ".join(f"{k} {a:.3f}..{b:.3f}" for k, (a, b) in spans.items())


def format_findings(findings: list[Finding]) -> str:
    return "\n".join(str(f) for f in findings)
