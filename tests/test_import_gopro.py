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
