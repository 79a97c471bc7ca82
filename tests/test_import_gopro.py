"""GoPro GPMF: KLV parser on hand-built payloads, an MP4 metadata track built here, the real sample."""

import shutil
import struct
from pathlib import Path

import numpy as np
import pytest

from blendgen.errors import UserError
from blendgen.recording.folder import read_recording
from blendgen.recording.importers import check_recording, gpmf, import_recording
from blendgen.recording.importers.gopro import R_CAM_SENSOR, read_telemetry, stream_times

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
KARMA = DATA / "real" / "gopro_karma.mp4"


def klv(key: str, t: str, size: int, repeat: int, payload: bytes) -> bytes:
    head = struct.pack(">4scBH", key.encode(), t.encode() if t else b"\0", size, repeat)
    return head + payload + b"\0" * ((-len(payload)) % 4)


def nest(key: str, *children: bytes) -> bytes:
    body = b"".join(children)
    return klv(key, "", 1, len(body), body)  # nested: size 1, repeat = byte length (as GoPro writes)


def accl_payload(n=10, scale=100, orin=None) -> bytes:
    raw = np.tile(np.array([[981, 5, -20]], ">i2"), (n, 1))  # up, right, forward (x100)
    strm = [klv("STNM", "c", 1, 13, b"Accelerometer"), klv("SIUN", "c", 4, 1, "m/s²".encode("latin-1")),
            klv("SCAL", "s", 2, 1, struct.pack(">h", scale)), klv("TSMP", "L", 4, 1, struct.pack(">I", n))]
    if orin:
        strm.append(klv("ORIN", "c", 3, 1, orin.encode()))
    strm.append(klv("ACCL", "s", 6, n, raw.tobytes()))
    gps = np.array([[331253680, -1173310641, 15445, 100, 120]], ">i4")
    gps_strm = [klv("SCAL", "l", 4, 5, np.array([1e7, 1e7, 1000, 1000, 100], ">i4").tobytes()),
                klv("GPSP", "S", 2, 1, struct.pack(">H", 150)), klv("GPS5", "l", 20, 1, gps.tobytes())]
    return nest("DEVC", klv("DVNM", "c", 1, 6, b"Camera"), nest("STRM", *strm), nest("STRM", *gps_strm))


def test_klv_parse_and_scale():
    tree = gpmf.parse(accl_payload())
    (devc,) = tree
    assert devc.key == "DEVC" and devc.children[0].value() == "Camera"
    acc, gps = gpmf.streams(tree, {"ACCL", "GPS5"})
    assert acc.units == "m/s²" and acc.name == "Accelerometer" and acc.tsmp == 10
    np.testing.assert_allclose(acc.values[0], [9.81, 0.05, -0.2])
    np.testing.assert_allclose(gps.values[0], [33.125368, -117.3310641, 15.445, 0.1, 1.2])


def test_klv_truncated_and_garbage():
    buf = accl_payload()
    with pytest.raises(gpmf.GpmfError, match="truncated"):
        gpmf.parse(buf[: len(buf) - 40])
    with pytest.raises(gpmf.GpmfError, match="invalid key"):
        gpmf.parse(b"\x01\x02\x03\x04" + buf[4:])


def test_orin_axis_order():
    from blendgen.recording.importers.gopro import _axes

    tree = gpmf.parse(accl_payload(orin="ZxY"))
    (acc,) = gpmf.streams(tree, {"ACCL"})
    M = _axes([(0, acc)], "ACCL")
    np.testing.assert_allclose(acc.values[0] @ M.T, [-0.05, -0.2, 9.81])  # x = -col1, y = col2, z = col0


def write_gpmd_mp4(path: Path, payloads: list[bytes], ms_per_payload=1001):
    """A minimal MP4 with one `gpmd` metadata track (ISO-BMFF boxes written by hand)."""
    def box(kind, body):
        return struct.pack(">I4s", 8 + len(body), kind) + body

    def full(kind, body, version=0):
        return box(kind, struct.pack(">I", version << 24) + body)

    ftyp = box(b"ftyp", b"mp41" + b"\0\0\0\0" + b"mp41")
    mdat_body = b"".join(payloads)
    mdat_start = len(ftyp) + 8
    offsets, pos = [], mdat_start
    for p in payloads:
        offsets.append(pos)
        pos += len(p)
    n = len(payloads)
    stsd = full(b"stsd", struct.pack(">I", 1) + box(b"gpmd", b"\0" * 6 + struct.pack(">H", 1) + b"\0" * 4))
    stbl = box(b"stbl", stsd + full(b"stts", struct.pack(">III", 1, n, ms_per_payload)) +
               full(b"stsc", struct.pack(">IIII", 1, 1, 1, 1)) +
               full(b"stsz", struct.pack(">II", 0, n) + b"".join(struct.pack(">I", len(p)) for p in payloads)) +
               full(b"stco", struct.pack(">I", n) + b"".join(struct.pack(">I", o) for o in offsets)))
    mdhd = full(b"mdhd", struct.pack(">IIIIHH", 0, 0, 1000, n * ms_per_payload, 0, 0))
    hdlr = full(b"hdlr", struct.pack(">I4s12s", 0, b"meta", b"\0" * 12) + b"GoPro MET\0")
    moov = box(b"moov", box(b"trak", box(b"mdia", mdhd + hdlr + box(b"minf", stbl))))
    path.write_bytes(ftyp + box(b"mdat", mdat_body) + moov)


def test_telemetry_track_timing(tmp_path):
    src = tmp_path / "GOPR0001.MP4"
    payloads = [accl_payload(n=200)] * 4 + [accl_payload(n=50)]  # the last payload is partial
    write_gpmd_mp4(src, payloads)
    tel = read_telemetry(src, show_progress=False)
    t, v = stream_times(tel["per_key"]["ACCL"], tel["starts"], tel["durs"])
    assert len(t) == 850 and v.shape == (850, 3)
    np.testing.assert_allclose(np.diff(t), 1.001 / 200, rtol=1e-9)  # rate from the full payloads
    assert t[-1] == pytest.approx(849 * 1.001 / 200)
    # a payload overwritten with garbage names the payload and the file
    bad = bytearray(src.read_bytes())
    i = bytes(bad).index(b"DEVC", bytes(bad).index(b"mdat") + 2000)
    bad[i:i + 4] = b"\xff\xfe\x00\x01"
    (tmp_path / "bad.MP4").write_bytes(bytes(bad))
    with pytest.raises(UserError, match=r"bad.MP4: GPMF payload \d .* corrupt: invalid key"):
        read_telemetry(tmp_path / "bad.MP4", show_progress=False)
    (tmp_path / "cut.MP4").write_bytes(src.read_bytes()[:-60])
    with pytest.raises(UserError, match="cut.MP4"):
        read_telemetry(tmp_path / "cut.MP4", show_progress=False)


@pytest.mark.data
def test_real_gopro_karma(tmp_path):
    if not KARMA.exists():
        pytest.skip("needs ../shared/data/real/gopro_karma.mp4")
    rec = read_recording(import_recording("gopro", KARMA, tmp_path / "rec", show_progress=False))
    assert rec.n_frames == 362 and rec.camera.width == 854 and rec.video == "video.mp4"
    assert abs(rec.frames_t[-1] - 361 / 29.97) < 0.01
    dt = np.median(np.diff(rec.imu[:, 0]))
    assert 1 / dt == pytest.approx(400, rel=0.05) and rec.imu[-1, 0] == pytest.approx(12.05, abs=0.2)
    assert np.all(np.isfinite(rec.imu))
    # gravity: the level, forward-looking gimbal camera sees the specific force "up" = image -y
    f_cam = R_CAM_SENSOR @ rec.imu[:, 4:7].mean(axis=0)
    assert np.linalg.norm(f_cam) == pytest.approx(9.8, abs=0.3) and f_cam[1] < -9.3
    # GoPro's IMU frame is X left, Y back, Z up: the drone speeds up from ~1 to ~7 m/s along the
    # camera's axis in the first 4 s (the fixes), so the forward specific force is positive
    # (+1.45 m/s^2; read as X right, Y forward it was -1.45), and in the right turn at the end
    # (camera y, down, turning +8 deg/s) the centripetal force points to the image's right
    t, f = rec.imu[:, 0], rec.imu[:, 4:7] @ R_CAM_SENSOR.T
    w = rec.imu[:, 1:4] @ R_CAM_SENSOR.T
    assert f[t < 4.0, 2].mean() > 1.0
    turn = t > 10.8
    assert np.degrees(w[turn, 1].mean()) > 5.0 and f[turn, 0].mean() > 0.3
    assert rec.extra["vehicle"] == {"road_vehicle": False}  # Karma drone telemetry
    assert rec.imu_noise.accelerometer_bias_std == 0.3 and rec.imu_noise.gyroscope_bias_std == 0.03
    lat, lon = rec.gnss_col("lat"), rec.gnss_col("lon")
    assert len(lat) > 40 and np.all(np.abs(lat - 33.1255) < 0.01) and np.all(np.abs(lon + 117.331) < 0.01)
    assert rec.gnss[0, 0] > -0.5 and rec.gnss[-1, 0] < 13.0  # GNSS on the video clock
    assert rec.utc(0.0).year == 2017
    levels = {f.message.split(":")[0]: f.level for f in check_recording(rec.root)}
    assert levels["camera intrinsics are not calibrated"] == "warn"


@pytest.mark.data
def test_real_gopro_truncated(tmp_path):
    if not KARMA.exists():
        pytest.skip("needs ../shared/data/real/gopro_karma.mp4")
    cut = tmp_path / "karma_cut.mp4"
    with open(KARMA, "rb") as f, open(cut, "wb") as g:
        shutil.copyfileobj(f, g)
        g.truncate(KARMA.stat().st_size // 2)
    with pytest.raises(UserError, match="karma_cut.mp4"):
        import_recording("gopro", cut, tmp_path / "rec", show_progress=False)


def test_gopro_lens_profiles():
    """The bundled lens database: a HERO5 Black's Linear and Wide lenses at GoPro's published
    16:9 fields of view, scaled to any size of that aspect, with the readout of the frame rate;
    clear errors for a mode, aspect or camera it does not have."""
    from blendgen.recording.importers import gopro_lens

    assert gopro_lens.model_from_firmware("HD5.02.02.00.00") == "HERO5 Black"
    assert gopro_lens.model_from_firmware("XX9.99") is None
    lin = gopro_lens.find_lens("HERO5 Black", "linear", False, 854, 480, 29.97)
    assert lin.camera.fisheye and (lin.camera.width, lin.camera.height) == (854, 480)
    # 33.37 ms = 1 / 29.97 s is all the database lists there: a placeholder, not written
    assert lin.readout_s is None and "placeholder" in lin.notes[0]
    assert 83.0 < lin.camera.hfov_deg < 89.0  # GoPro's Linear
    wide = gopro_lens.find_lens("HERO5 Black", "Wide", False, 2704, 1520, 29.97)
    assert abs(wide.camera.hfov_deg - 118.2) < 3.0  # GoPro: HERO5 Black 16:9 Wide, 118.2 deg
    assert wide.readout_s == pytest.approx(0.02669, abs=1e-5) and "2704x1520 at 29.97 fps" in wide.notes[0]
    assert "Wide NO-EIS" in wide.description and "CC0" in wide.description
    # a copy's recorded size is unknown, and the readout depends on it
    copy = gopro_lens.find_lens("HERO5 Black", "wide", False, 1366, 768, 29.97)
    assert copy.readout_s is None and "is a copy" in copy.notes[0] and "26.7 ms at 2704x1520" in copy.notes[0]
    with pytest.raises(UserError, match="it has: linear; linear --eis; wide; wide --eis"):
        gopro_lens.find_lens("HERO5 Black", "superview", False, 1920, 1080, 29.97)
    with pytest.raises(UserError, match="none with this video's aspect"):
        gopro_lens.find_lens("HERO5 Black", "linear", False, 1000, 1000, 29.97)
    with pytest.raises(UserError, match="no lens profile for a GoPro MAX"):
        gopro_lens.find_lens("MAX", "wide", False, 1920, 1080, 29.97)


@pytest.mark.data
def test_real_gopro_karma_with_its_lens(tmp_path):
    if not KARMA.exists():
        pytest.skip("needs ../shared/data/real/gopro_karma.mp4")
    rec = read_recording(import_recording("gopro", KARMA, tmp_path / "rec", lens="linear", show_progress=False))
    assert rec.lens_source == "profile" and rec.camera.fisheye and rec.camera.fx == pytest.approx(462.9, abs=0.1)
    assert rec.rolling_shutter_s == 0.0  # the database's 29.97 fps readout is a placeholder
    assert "camera: HERO5 Black (firmware HD5.02.02.00.00)" in rec.extra["import"]["notes"]
    assert not any("not calibrated" in f.message and "intrinsics" in f.message for f in check_recording(rec.root))
    with pytest.raises(UserError, match="either --lens"):
        import_recording("gopro", KARMA, tmp_path / "rec2", lens="linear", hfov_deg=90, show_progress=False)
    assert not (tmp_path / "rec2").exists()


def test_every_bundled_lens_inverts_or_is_refused():
    """Each profile in the database, at its calibrated size: every pixel's ray projects back to
    it (1e-6 px), or the lens sees past what a pinhole canvas holds and find_lens says so. The
    Max modes are refused; OpenCV's own fisheye inverse lands on the polynomial's far branch for
    some of them and for the HERO11 Linear 4:3 corners, which blendgen's inverse does not."""
    from blendgen.geometry import MAX_VIEW_ANGLE_DEG, Camera
    from blendgen.recording.importers import gopro_lens

    refused = set()
    for p in gopro_lens.profiles():
        W, H = p["size"]
        cam = Camera(W, H, *p["intrinsics"], list(p["distortion"]), "equidistant")
        us, vs = np.meshgrid(np.linspace(-0.5, W - 0.5, 21), np.linspace(-0.5, H - 0.5, 15))
        px = np.column_stack([us.ravel(), vs.ravel()])
        if cam.max_view_angle_deg() > MAX_VIEW_ANGLE_DEG:
            refused.add(f"{p['camera']} {p['lens']}")
            with pytest.raises(UserError, match="blendgen handles up to 85 deg"):
                gopro_lens.find_lens(p["camera"], p["lens"], p["stabilisation"] not in ("", "NO-EIS"), W, H, 30.0)
            continue
        n = cam.normalized(px)
        uv, front = cam.project(np.column_stack([n, np.ones(len(n))]))
        assert front.all() and np.abs(uv - px).max() < 1e-6, p["source"]
    assert {"HERO10 Black Max", "HERO9 Black Max"} <= refused and "HERO5 Black Linear" not in refused
