"""ROS 1 / ROS 2 bag importer on bags written here with rosbags' writers."""

from pathlib import Path

import cv2
import numpy as np
import pytest

rosbags = pytest.importorskip("rosbags", reason="needs the rosbags package (pip install rosbags)")

from rosbags.typesys import Stores, get_typestore  # noqa: E402

from blendgen.errors import UserError  # noqa: E402
from blendgen.recording.folder import read_frame, read_recording  # noqa: E402
from blendgen.recording.importers import check_recording, import_recording  # noqa: E402

T0 = 1_700_000_000 * 10**9


def _msgs(ros, store, n_img=5, compressed=False, odom_topics=("/vehicle/odom",)):
    M = store.types
    Time, Header = M["builtin_interfaces/msg/Time"], M["std_msgs/msg/Header"]
    V3, Q = M["geometry_msgs/msg/Vector3"], M["geometry_msgs/msg/Quaternion"]

    def hdr(t_ns, frame="cam"):
        extra = {"seq": 0} if ros == 1 else {}
        return Header(stamp=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id=frame, **extra)

    out = []
    for i in range(n_img):
        t = T0 + i * 100_000_000
        img = np.zeros((24, 32, 3), np.uint8)
        img[..., 0] = 200  # red in RGB order
        img[i, :, 1] = 255
        if compressed:
            ok, buf = cv2.imencode(".png", img[..., ::-1])
            out.append(("/cam/image_raw/compressed", t, M["sensor_msgs/msg/CompressedImage"](
                header=hdr(t), format="png", data=buf.ravel())))
        else:
            out.append(("/cam/image_raw", t, M["sensor_msgs/msg/Image"](
                header=hdr(t), height=24, width=32, encoding="rgb8", is_bigendian=0, step=32 * 3,
                data=img.ravel())))
        K = np.array([30.0, 0, 15.5, 0, 31.0, 11.5, 0, 0, 1])
        mats = {"d": np.array([0.1, -0.01, 0, 0, 0.0]), "k": K, "r": np.eye(3).ravel(), "p": np.zeros(12)}
        if ros == 1:  # ROS 1 spells the matrices in capitals
            mats = {k.upper(): v for k, v in mats.items()}
        out.append(("/cam/camera_info", t, M["sensor_msgs/msg/CameraInfo"](
            header=hdr(t), height=24, width=32, distortion_model="plumb_bob", **mats, binning_x=0, binning_y=0,
            roi=M["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))))
    for i in range(60):
        t = T0 - 50_000_000 + i * 10_000_000
        out.append(("/imu", t, M["sensor_msgs/msg/Imu"](
            header=hdr(t, "imu"), orientation=Q(x=0, y=0, z=0, w=1), orientation_covariance=np.zeros(9),
            angular_velocity=V3(x=0.01, y=0.0, z=0.1 * i), angular_velocity_covariance=np.zeros(9),
            linear_acceleration=V3(x=0.0, y=0.0, z=9.81), linear_acceleration_covariance=np.zeros(9))))
    for i in range(4):
        t = T0 + i * 200_000_000
        out.append(("/fix", t, M["sensor_msgs/msg/NavSatFix"](
            header=hdr(t, "gps"), status=M["sensor_msgs/msg/NavSatStatus"](status=-1 if i == 3 else 0, service=1),
            latitude=48.1 + 1e-5 * i, longitude=11.5, altitude=520.0,
            position_covariance=np.diag([4.0, 4.0, 9.0]).ravel(), position_covariance_type=2)))
    P, Tw = M["geometry_msgs/msg/Pose"], M["geometry_msgs/msg/Twist"]
    cov = np.zeros(36)
    for i, topic in ((i, tp) for tp in odom_topics for i in range(20)):
        t = T0 + i * 50_000_000  # wheel odometry at 20 Hz; the last two readings reversing
        vx = 5.0 + 0.1 * i if i < 18 else -0.5
        out.append((topic, t, M["nav_msgs/msg/Odometry"](
            header=hdr(t, "odom"), child_frame_id="base_link",
            pose=M["geometry_msgs/msg/PoseWithCovariance"](
                pose=P(position=M["geometry_msgs/msg/Point"](x=0, y=0, z=0), orientation=Q(x=0, y=0, z=0, w=1)),
                covariance=cov),
            twist=M["geometry_msgs/msg/TwistWithCovariance"](
                twist=Tw(linear=V3(x=vx, y=0.0, z=0.0), angular=V3(x=0.0, y=0.0, z=0.0)), covariance=cov))))
    return sorted(out, key=lambda m: m[1])


def write_bag(path: Path, ros: int, compressed=False, **kw) -> Path:
    if ros == 2:
        from rosbags.rosbag2 import Writer

        store = get_typestore(Stores.ROS2_HUMBLE)
        writer, ser = Writer(path, version=8), store.serialize_cdr
    else:
        from rosbags.rosbag1 import Writer

        store = get_typestore(Stores.ROS1_NOETIC)
        writer, ser = Writer(path), store.serialize_ros1
    msgs = _msgs(ros, store, compressed=compressed, **kw)
    with writer:
        conns = {}
        for topic, t, msg in msgs:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=store)
            writer.write(conns[topic], t, ser(msg, msg.__msgtype__))
    return path


@pytest.mark.parametrize("ros,compressed", [(1, False), (2, False), (2, True)])
def test_rosbag(tmp_path, ros, compressed):
    bag = write_bag(tmp_path / ("test.bag" if ros == 1 else "bag2"), ros, compressed)
    rec = read_recording(import_recording("rosbag", bag, tmp_path / "rec", show_progress=False))
    assert rec.n_frames == 5
    np.testing.assert_allclose(rec.frames_t - rec.frames_t[0], np.arange(5) * 0.1, atol=1e-6)
    assert rec.frames_t[0] == pytest.approx(T0 * 1e-9)
    img = read_frame(rec, 2)
    assert tuple(img[0, 0]) == (0, 0, 200) and tuple(img[2, 0]) == (0, 255, 200)  # RGB -> BGR, row 2 marked
    assert (rec.camera.fx, rec.camera.cy, rec.camera.dist[0]) == (30.0, 11.5, pytest.approx(0.1))
    assert rec.imu.shape == (60, 7) and rec.imu[-1, 3] == pytest.approx(5.9)
    assert len(rec.gnss) == 3 and rec.gnss_col("h_std_m")[0] == pytest.approx(2.0)  # no-fix row dropped
    # the vehicle's odometer: twist.linear.x, the reversing readings dropped
    assert rec.speed.shape == (18, 2) and rec.speed[-1, 1] == pytest.approx(6.7)
    assert "2 speed reading(s) < 0 (reversing) dropped" in str(read_recording(rec.root).extra["import"]["notes"])
    text = "\n".join(map(str, check_recording(rec.root)))
    assert "camera-IMU extrinsics not calibrated" in text and "ERROR" not in text


def test_rosbag_truncated_and_ambiguous(tmp_path):
    bag = write_bag(tmp_path / "test.bag", 1)
    data = bag.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 3])
    with pytest.raises(UserError, match="cut.bag"):
        import_recording("rosbag", cut, tmp_path / "r1", show_progress=False)
    with pytest.raises(UserError, match="--imu-topic '/nope' is not in the bag"):
        import_recording("rosbag", bag, tmp_path / "r2", imu_topic="/nope", show_progress=False)


def test_rosbag_speed_topic_is_not_guessed(tmp_path):
    """Two odometry topics (wheels and, say, an INS): no speed.csv unless one is named."""
    bag = write_bag(tmp_path / "bag2", 2, odom_topics=("/vehicle/odom", "/ins/odom"))
    rec = read_recording(import_recording("rosbag", bag, tmp_path / "a", show_progress=False))
    assert len(rec.speed) == 0 and "choose one with --speed-topic" in str(rec.extra["import"]["notes"])
    rec = read_recording(import_recording("rosbag", bag, tmp_path / "b", speed_topic="/vehicle/odom",
                                          show_progress=False))
    assert rec.speed.shape == (18, 2)
    with pytest.raises(UserError, match="--speed-topic '/odom' is not in the bag"):
        import_recording("rosbag", bag, tmp_path / "c", speed_topic="/odom", show_progress=False)


def test_camera_info_models():
    """CameraInfo: plumb_bob and equidistant (ROS's name for the Kannala-Brandt fisheye) become
    blendgen cameras, scaled to the images' size; rational_polynomial is not representable."""
    from types import SimpleNamespace

    from blendgen.recording.importers.rosbag import _camera_from_info

    K = [400.0, 0, 320, 0, 400, 240, 0, 0, 1]
    info = lambda model, d: SimpleNamespace(k=K, d=d, distortion_model=model, width=640, height=480)  # noqa: E731
    fish = _camera_from_info(info("equidistant", [0.01, -0.002, 0.0003, 0.0]), 320, 240)
    assert fish.fisheye and fish.fx == pytest.approx(200.0) and fish.dist == [0.01, -0.002, 0.0003, 0.0]
    plain = _camera_from_info(info("plumb_bob", [-0.1, 0.01, 0, 0, 0]), 640, 480)
    assert not plain.fisheye and plain.dist[0] == -0.1
    assert _camera_from_info(info("rational_polynomial", [0.0] * 8), 640, 480) is None
