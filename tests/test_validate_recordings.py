"""Issue 16: `blendgen validate JOB` checks the recording the job names, as `import --check`
does. Every malformed recording gets one precise message naming the file, row or field, exit
code 2, no traceback (the CLI runs in-process, so this stays fast)."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from blendgen.cli import main
from blendgen.geometry import Camera
from blendgen.recording import folder

N = 6


def good_recording(root: Path) -> Path:
    root.mkdir(parents=True)
    folder.write_calib(root, Camera.from_hfov(64, 48, 60), np.eye(4))
    (root / "img").mkdir()
    rng = np.random.default_rng(0)
    for i in range(N):
        cv2.imwrite(str(root / f"img/{i}.png"), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    folder.write_frames_csv(root, np.arange(N) * 0.2, [f"img/{i}.png" for i in range(N)])
    t = np.arange(0, 1.2, 0.005)
    imu = np.column_stack([t, rng.normal(0, 0.01, (len(t), 3)), rng.normal(0, 0.1, (len(t), 2)),
                           9.81 + rng.normal(0, 0.1, len(t))])
    folder.write_imu(root, imu)
    tg = np.arange(0, 1.2, 0.1)
    folder.write_gnss(root, np.column_stack([tg, 48.1 + 1e-6 * np.arange(len(tg)), np.full(len(tg), 11.5),
                                             np.full(len(tg), 500.0)]))
    gt = np.column_stack([tg, np.zeros((len(tg), 3)), np.ones(len(tg)), np.zeros((len(tg), 3))])
    folder.write_groundtruth(root, gt)
    return root


def edit(name, fn):
    """A mutation of one file of the recording: fn(text) -> new text."""
    def apply(root: Path):
        p = root / name
        p.write_text(fn(p.read_text()))
    return apply


def calib(fn):
    def apply(root: Path):
        d = yaml.safe_load((root / "calib.yaml").read_text())
        fn(d)
        (root / "calib.yaml").write_text(yaml.safe_dump(d))
    return apply


def row(name, k, new):  # replace data row k (0-based) of a CSV
    def fn(text):
        lines = text.splitlines()
        lines[k + 1] = new(lines[k + 1])
        return "\n".join(lines) + "\n"
    return edit(name, fn)


def imu_col(k, fn):
    def apply(root: Path):
        a = np.loadtxt(root / "imu.csv", delimiter=",", skiprows=1)
        a[:, k] = fn(a[:, k])
        folder.write_imu(root, a)
    return apply


def image(i, fn):
    def apply(root: Path):
        fn(root / f"img/{i}.png")
    return apply


def symlink_out(root: Path):
    outside = root.parent / "outside"
    outside.mkdir()
    cv2.imwrite(str(outside / "x.png"), np.zeros((48, 64, 3), np.uint8))
    (root / "link").symlink_to(outside)
    row("frames.csv", 2, lambda r: r.split(",")[0] + ",link/x.png")(root)


def set_(d, path, v):
    *head, last = path
    for k in head:
        d = d[k]
    d[last] = v


# (id, mutation, file the message names, text it must contain)
CASES = [
    ("calib missing", lambda r: (r / "calib.yaml").unlink(), "calib.yaml", "calib.yaml is missing"),
    ("negative focal length", calib(lambda d: set_(d, ["camera", "intrinsics", 0], -50.0)), "calib.yaml",
     "focal lengths and resolution must be positive"),
    ("NaN fx", calib(lambda d: set_(d, ["camera", "intrinsics", 0], float("nan"))), "calib.yaml",
     "intrinsics and distortion must be finite"),
    ("NaN cx", calib(lambda d: set_(d, ["camera", "intrinsics", 2], float("nan"))), "calib.yaml",
     "intrinsics and distortion must be finite"),
    ("three intrinsics", calib(lambda d: set_(d, ["camera", "intrinsics"], [1, 2, 3])), "calib.yaml",
     "intrinsics must be 4 numbers"),
    ("bad UTC", calib(lambda d: set_(d, ["time_origin_utc"], "yesterday noon")), "calib.yaml",
     "time_origin_utc: 'yesterday noon' is not an ISO 8601 time"),
    ("calib not YAML", edit("calib.yaml", lambda t: "camera: [unclosed\n"), "calib.yaml", "not valid YAML"),
    ("calib duplicate key", edit("calib.yaml", lambda t: t + "timeshift_cam_imu: 0.1\n"), "calib.yaml",
     "duplicate key 'timeshift_cam_imu'"),
    ("T_cam_imu not rigid", calib(lambda d: set_(d, ["T_cam_imu"], (2 * np.eye(4)).tolist())), "calib.yaml",
     "T_cam_imu: expected a 4x4 rigid transform"),
    ("T_cam_imu words", calib(lambda d: set_(d, ["T_cam_imu"], "identity")), "calib.yaml",
     "T_cam_imu: expected a 4x4 rigid transform"),
    ("negative IMU noise", calib(lambda d: set_(d, ["imu", "gyroscope_noise_density"], -1e-4)), "calib.yaml",
     "imu.gyroscope_noise_density: expected a positive number"),
    ("unknown distortion", calib(lambda d: set_(d, ["camera", "distortion_model"], "fisheye9")), "calib.yaml",
     "camera.distortion_model: 'fisheye9' is not supported"),
    ("fisheye with 5 coefficients", calib(lambda d: set_(d, ["camera", "distortion_model"], "equidistant")),
     "calib.yaml", "the equidistant model expects 4 numbers"),
    ("no camera section", calib(lambda d: d.pop("camera")), "calib.yaml", "has no `camera:` section"),
    ("frames header", edit("frames.csv", lambda t: t.replace("t,file", "time,path", 1)), "frames.csv",
     "expected 't,file' (images) or 't,index'"),
    ("frames not monotonic", row("frames.csv", 3, lambda r: "0.1," + r.split(",")[1]), "frames.csv",
     "row 5: non-monotonic timestamp"),
    ("frames time not a number", row("frames.csv", 2, lambda r: "soon," + r.split(",")[1]), "frames.csv",
     "row 4: 'soon' is not a number"),
    ("frames.csv ../ escape", row("frames.csv", 2, lambda r: r.split(",")[0] + ",../../../../etc/hostname"),
     "frames.csv", "row 4: image path '../../../../etc/hostname' is not inside the recording folder"),
    ("frames.csv absolute path", row("frames.csv", 2, lambda r: r.split(",")[0] + ",/etc/passwd"), "frames.csv",
     "row 4: image path '/etc/passwd' is not inside the recording folder"),
    ("frames.csv symlink out", symlink_out, "frames.csv", "row 4: image path 'link/x.png' is not inside"),
    ("truncated image", image(1, lambda p: p.write_bytes(p.read_bytes()[:200])), "frames.csv",
     "row 3: img/1.png: does not decode as an image"),
    ("zero-byte image", image(2, lambda p: p.write_bytes(b"")), "frames.csv", "row 4: img/2.png: image file is empty"),
    ("wrong-size image", image(3, lambda p: cv2.imwrite(str(p), np.zeros((20, 30, 3), np.uint8))), "frames.csv",
     "row 5: img/3.png: is 30x20 but calib.yaml says 64x48"),
    ("missing image", image(4, lambda p: p.unlink()), "frames.csv", "row 6: img/4.png: image file is missing"),
    ("text as image", image(5, lambda p: p.write_text("not a png")), "frames.csv", "row 7: img/5.png: does not decode"),
    ("IMU not monotonic", row("imu.csv", 10, lambda r: "0.01," + r.split(",", 1)[1]), "imu.csv",
     "row 12: non-monotonic timestamp"),
    ("IMU 1e6 rad/s", imu_col(2, lambda c: np.where(np.arange(len(c)) == 7, 1e6, c)), "imu.csv",
     "row 9: angular rate 1e+06 rad/s is physically impossible"),
    ("IMU 1000 g", imu_col(6, lambda c: np.where(np.arange(len(c)) == 3, 9810.0, c)), "imu.csv",
     "row 5: acceleration 9810 m/s^2 is physically impossible"),
    ("IMU in ns never overlaps frames", imu_col(0, lambda c: c * 1e9 + 1.7e18), "rec",
     "streams do not overlap in time"),
    ("IMU saturated", imu_col(4, lambda c: np.full_like(c, 156.96)), "imu.csv",
     "column ax sits at its extreme 157 in 100% of rows: the sensor is saturated"),
    ("IMU missing column", edit("imu.csv", lambda t: t.replace(",az", ",a_z", 1)), "imu.csv",
     "missing column(s) ['az']"),
    ("IMU NaN time", row("imu.csv", 5, lambda r: "nan," + r.split(",", 1)[1]), "imu.csv",
     "row 7: column t is nan"),
    ("GNSS latitude 200", row("gnss.csv", 2, lambda r: ",".join([r.split(",")[0], "200"] + r.split(",")[2:])),
     "gnss.csv", "row 4: latitude/longitude out of range"),
    ("GNSS no lon", edit("gnss.csv", lambda t: t.replace(",lon", ",longitude", 1)), "gnss.csv",
     "missing column(s) ['lon']"),
    ("ground truth quaternion", row("groundtruth.csv", 1, lambda r: ",".join(r.split(",")[:4] + ["2", "0", "0", "0"])),
     "groundtruth.csv", "row 3: quaternion is not unit length"),
    ("frames index without video", edit("frames.csv", lambda t: "t,index\n0.0,0\n0.2,1\n"), "frames.csv",
     "does not hold exactly one video"),
]


@pytest.mark.parametrize("case,mutate,names,expected", CASES, ids=[c[0] for c in CASES])
def test_validate_checks_the_recording(tmp_path, capsys, case, mutate, names, expected):
    rec = good_recording(tmp_path / "rec")
    job = tmp_path / "job.yaml"
    job.write_text(yaml.safe_dump({"name": "t", "recording": str(rec), "ground_plane": {}, "output": "out"}))
    assert main(["validate", str(job)]) == 0, capsys.readouterr()  # the good one passes
    capsys.readouterr()
    mutate(rec)
    rc = main(["validate", str(job)])
    out, err = capsys.readouterr()
    assert rc == 2, err
    assert "valid job" not in out, out  # never called valid before its recording's errors
    assert (out + err).count("img/4.png") <= 2, out + err  # listed once with the findings, once in the error
    assert expected in err, err
    assert "Traceback" not in err
    named = str(rec if names == "rec" else rec / names)
    assert named in err, f"message does not name {named}: {err}"


def test_validate_is_fast_on_many_images(tmp_path, capsys):
    """500 images checked (header + decode at 1/8 scale) well under a second per 100."""
    import time

    root = tmp_path / "rec"
    root.mkdir()
    folder.write_calib(root, Camera.from_hfov(640, 360, 60))
    (root / "img").mkdir()
    img = cv2.imencode(".jpg", np.random.default_rng(0).integers(0, 255, (360, 640, 3), np.uint8))[1].tobytes()
    for i in range(500):
        (root / f"img/{i}.jpg").write_bytes(img)
    folder.write_frames_csv(root, np.arange(500) * 0.1, [f"img/{i}.jpg" for i in range(500)])
    job = tmp_path / "job.yaml"
    job.write_text(yaml.safe_dump({"name": "t", "recording": str(root), "ground_plane": {}, "output": "out"}))
    t0 = time.process_time()
    assert main(["validate", str(job)]) == 0, capsys.readouterr()
    cpu = time.process_time() - t0
    assert cpu < 5.0, f"validate took {cpu:.2f} CPU-s for 500 images"
    assert re.search(r"frames: 500 samples", capsys.readouterr().out)
