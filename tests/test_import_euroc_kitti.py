"""EuRoC/ASL and KITTI raw importers on small folders built here."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from blendgen.errors import UserError
from blendgen.geometry import invert_pose, pose_from_xyz_quat, quat_to_matrix
from blendgen.recording.folder import read_frame, read_recording
from blendgen.recording.importers import check_recording, import_recording

# EuRoC MH_01 cam0 extrinsics (body = IMU)
T_BS_CAM0 = [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
             0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
             -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
             0.0, 0.0, 0.0, 1.0]


def make_euroc(root: Path, n_img=4, n_imu=60) -> Path:
    mav = root / "mav0"
    (mav / "cam0" / "data").mkdir(parents=True)
    (mav / "imu0").mkdir()
    (mav / "state_groundtruth_estimate0").mkdir()
    (mav / "cam0" / "sensor.yaml").write_text(
        "%YAML:1.0\nsensor_type: camera\nT_BS:\n  cols: 4\n  rows: 4\n  data: [" +
        ", ".join(map(str, T_BS_CAM0)) + "]\nrate_hz: 20\nresolution: [40, 30]\ncamera_model: pinhole\n"
        "intrinsics: [45.8, 45.7, 19.6, 15.1]\ndistortion_model: radial-tangential\n"
        "distortion_coefficients: [-0.28, 0.07, 0.0002, 0.00002]\n")
    (mav / "imu0" / "sensor.yaml").write_text(
        "%YAML:1.0\nT_BS:\n  cols: 4\n  rows: 4\n  data: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, "
        "0.0, 0.0, 0.0, 0.0, 1.0]\nrate_hz: 200\ngyroscope_noise_density: 1.6968e-04\n"
        "gyroscope_random_walk: 1.9393e-05\naccelerometer_noise_density: 2.0000e-3\n"
        "accelerometer_random_walk: 3.0000e-3\n")
    t0 = 1403636579758555392
    rows = ["#timestamp [ns],filename"]
    for i in range(n_img):
        ts = t0 + i * 50_000_000
        img = np.full((30, 40), 10 * i, np.uint8)
        cv2.imwrite(str(mav / "cam0" / "data" / f"{ts}.png"), img)
        rows.append(f"{ts},{ts}.png")
    (mav / "cam0" / "data.csv").write_text("\n".join(rows) + "\n")
    rows = ["#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
            "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"]
    rows += [f"{t0 - 10_000_000 + i * 5_000_000},-0.099,0.14,0.029,8.1,-0.37,-2.4" for i in range(n_imu)]
    (mav / "imu0" / "data.csv").write_text("\n".join(rows) + "\n")
    rows = ["#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
            "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], "
            "b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], "
            "b_a_RS_S_z [m s^-2]"]
    q = [0.534108, -0.153029, -0.827383, -0.082152]
    rows += [f"{t0 + i * 5_000_000},{4.688 + 0.01 * i},-1.786,0.783,{q[0]},{q[1]},{q[2]},{q[3]},"
             "0,0,0,0,0,0,0,0,0" for i in range(40)]
    (mav / "state_groundtruth_estimate0" / "data.csv").write_text("\n".join(rows) + "\n")
    return root


def test_euroc(tmp_path):
    src = make_euroc(tmp_path / "MH_01")
    rec = read_recording(import_recording("euroc", src, tmp_path / "rec", show_progress=False))
    assert rec.n_frames == 4 and rec.frame_files[0].startswith("cam0/")
    np.testing.assert_allclose(np.diff(rec.frames_t), 0.05, atol=1e-6)
    assert rec.camera.width == 40 and rec.camera.dist[0] == pytest.approx(-0.28)
    assert rec.imu.shape == (60, 7) and rec.imu_noise.gyroscope_random_walk == pytest.approx(1.9393e-05)
    T_B_C = np.array(T_BS_CAM0).reshape(4, 4)
    np.testing.assert_allclose(rec.T_cam_imu, invert_pose(T_B_C), atol=1e-9)
    # ground truth is the camera pose: T_world_body @ T_body_cam
    T_wb = pose_from_xyz_quat([4.688, -1.786, 0.783], [0.534108, -0.153029, -0.827383, -0.082152])
    T_wc = pose_from_xyz_quat(rec.groundtruth[0, 1:4], rec.groundtruth[0, 4:8])
    np.testing.assert_allclose(T_wc, T_wb @ T_B_C, atol=1e-5)
    assert read_frame(rec, 3)[0, 0, 0] == 30
    assert not [f for f in check_recording(rec.root) if f.level == "error"]


def test_euroc_equidistant_fisheye(tmp_path):
    """TUM VI and other EuRoC-format sets with Kalibr's fisheye: read as blendgen's equidistant
    lens (round trip through calib.yaml); other models stay a clear error."""
    src = make_euroc(tmp_path / "a")
    yml = src / "mav0" / "cam0" / "sensor.yaml"
    yml.write_text(yml.read_text().replace("distortion_model: radial-tangential", "distortion_model: equidistant")
                   .replace("[-0.28, 0.07, 0.0002, 0.00002]", "[0.0034, 0.0007, -0.0021, 0.0002]"))
    rec = read_recording(import_recording("euroc", src, tmp_path / "rec", show_progress=False))
    assert rec.camera.fisheye and rec.camera.dist == [0.0034, 0.0007, -0.0021, 0.0002]
    yml.write_text(yml.read_text().replace("distortion_model: equidistant", "distortion_model: fov"))
    with pytest.raises(UserError, match="'fov' is not supported"):
        import_recording("euroc", src, tmp_path / "rec2", show_progress=False)


def test_euroc_missing_image_and_bad_imu(tmp_path):
    src = make_euroc(tmp_path / "a")
    first = sorted((src / "mav0" / "cam0" / "data").iterdir())[1]
    first.unlink()
    with pytest.raises(UserError, match=r"data.csv: row 3: image .* is missing"):
        import_recording("euroc", src, tmp_path / "r1", show_progress=False)
    src = make_euroc(tmp_path / "b")
    imu = src / "mav0" / "imu0" / "data.csv"
    imu.write_text(imu.read_text() + "1403636580058555392,0.1,0.2\n")  # truncated last line
    with pytest.raises(UserError, match=r"imu0/data.csv: row 62"):
        import_recording("euroc", src, tmp_path / "r2", show_progress=False)
    with pytest.raises(UserError, match="no cam0/ folder"):
        import_recording("euroc", tmp_path, tmp_path / "r3", show_progress=False)


# --------------------------------------------------------------------- KITTI raw
CAM_TO_CAM = """calib_time: 09-Jan-2012 13:57:47
corner_dist: 9.950000e-02
S_00: 1.392000e+03 5.120000e+02
K_00: 9.842439e+02 0.000000e+00 6.900000e+02 0.000000e+00 9.808141e+02 2.331966e+02 0.000000e+00 0.000000e+00 1.000000e+00
D_00: -3.728755e-01 2.037299e-01 2.219027e-03 1.383707e-03 -7.233722e-02
R_00: 1.000000e+00 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00
T_00: 2.573699e-16 -1.059758e-16 1.614870e-16
S_rect_00: 1.242000e+03 3.750000e+02
R_rect_00: 9.999239e-01 9.837760e-03 -7.445048e-03 -9.869795e-03 9.999421e-01 -4.278459e-03 7.402527e-03 4.351614e-03 9.999631e-01
P_rect_00: 7.215377e+02 0.000000e+00 6.095593e+02 0.000000e+00 0.000000e+00 7.215377e+02 1.728540e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00
S_02: 1.392000e+03 5.120000e+02
K_02: 9.597910e+02 0.000000e+00 6.960217e+02 0.000000e+00 9.569251e+02 2.241806e+02 0.000000e+00 0.000000e+00 1.000000e+00
D_02: -3.691481e-01 1.968681e-01 1.353473e-03 5.677587e-04 -6.770705e-02
R_02: 9.999758e-01 -5.267463e-03 -4.552439e-03 5.251945e-03 9.999804e-01 -3.413835e-03 4.570332e-03 3.389843e-03 9.999838e-01
T_02: 5.956621e-02 2.900141e-04 2.577209e-03
S_rect_02: 1.242000e+03 3.750000e+02
R_rect_02: 9.998817e-01 1.511453e-02 -2.841595e-03 -1.511724e-02 9.998853e-01 -9.338510e-04 2.827154e-03 9.766976e-04 9.999955e-01
P_rect_02: 7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+01 0.000000e+00 7.215377e+02 1.728540e+02 2.163791e-01 0.000000e+00 0.000000e+00 1.000000e+00 2.745884e-03
"""
VELO_TO_CAM = """calib_time: 15-Mar-2012 11:37:16
R: 7.533745e-03 -9.999714e-01 -6.166020e-04 1.480249e-02 7.280733e-04 -9.998902e-01 9.998621e-01 7.523790e-03 1.480755e-02
T: -4.069766e-03 -7.631618e-02 -2.717806e-01
delta_f: 0.000000e+00 0.000000e+00
delta_c: 0.000000e+00 0.000000e+00
"""
IMU_TO_VELO = """calib_time: 25-May-2012 16:47:16
R: 9.999976e-01 7.553071e-04 -2.035826e-03 -7.854027e-04 9.998898e-01 -1.482298e-02 2.024406e-03 1.482454e-02 9.998881e-01
T: -8.086759e-01 3.195559e-01 -7.997231e-01
"""


def make_kitti(root: Path, n=5) -> Path:
    day = root / "2011_09_26"
    drive = day / "2011_09_26_drive_0001_sync"
    (drive / "image_02" / "data").mkdir(parents=True)
    (drive / "oxts" / "data").mkdir(parents=True)
    (day / "calib_cam_to_cam.txt").write_text(CAM_TO_CAM)
    (day / "calib_velo_to_cam.txt").write_text(VELO_TO_CAM)
    (day / "calib_imu_to_velo.txt").write_text(IMU_TO_VELO)
    ns = [964389445 + i * 103_000_000 for i in range(n)]
    stamps = [f"2011-09-26 13:02:{25 + v // 10**9:02d}.{v % 10**9:09d}" for v in ns]
    (drive / "image_02" / "timestamps.txt").write_text("\n".join(stamps) + "\n")
    (drive / "oxts" / "timestamps.txt").write_text("\n".join(stamps) + "\n")
    for i in range(n):
        cv2.imwrite(str(drive / "image_02" / "data" / f"{i:010d}.png"), np.full((375, 1242, 3), i, np.uint8))
        # heading east (yaw 0), driving 1 m per packet along +x (east)
        lat, lon = 49.015, 8.43 + i * 1.0 / (111320 * np.cos(np.radians(49.015)))
        vals = [lat, lon, 112.0, 0.0, 0.0, 0.0] + [0.0] * 5 + [0.1, 0.0, 9.81] + [0.0] * 3 + \
               [0.0, 0.0, 0.05] + [0.0] * 3 + [0.3, 0.1, 4, 10, 5, 5, 5]
        (drive / "oxts" / "data" / f"{i:010d}.txt").write_text(" ".join(f"{v:.12g}" for v in vals) + "\n")
    return drive


def test_kitti(tmp_path):
    drive = make_kitti(tmp_path)
    rec = read_recording(import_recording("kitti", drive, tmp_path / "rec", show_progress=False))
    assert rec.n_frames == 5 and rec.camera.width == 1242 and rec.camera.fx == pytest.approx(721.5377)
    np.testing.assert_allclose(np.diff(rec.frames_t), 0.103, atol=1e-6)
    assert rec.imu[0, 3] == pytest.approx(0.05) and rec.imu[0, 6] == pytest.approx(9.81)
    assert rec.gnss_col("heading_deg")[0] == pytest.approx(90.0)
    gt = rec.groundtruth
    # vehicle faces east: the camera looks east, image y points down, camera ~1.65 m above the IMU
    R = quat_to_matrix(gt[0, 4:8])
    assert R[:, 2] @ [1, 0, 0] > 0.99 and R[:, 1] @ [0, 0, -1] > 0.99
    # KITTI rig: camera 1.65 m and OXTS 0.93 m above ground, camera ~1.08 m ahead of the OXTS
    np.testing.assert_allclose(gt[0, 1:4], [1.08, -0.25, 0.73], atol=0.02)
    np.testing.assert_allclose(gt[-1, 1] - gt[0, 1], 4.0, atol=0.01)  # 4 m east over 5 packets


def test_kitti_truncated(tmp_path):
    drive = make_kitti(tmp_path)
    bad = drive / "oxts" / "data" / "0000000002.txt"
    bad.write_text(" ".join(bad.read_text().split()[:12]))
    with pytest.raises(UserError, match=r"0000000002.txt: 12 values, expected 30"):
        import_recording("kitti", drive, tmp_path / "r1", show_progress=False)
    drive2 = make_kitti(tmp_path / "b")
    (drive2 / "image_02" / "data" / "0000000004.png").unlink()
    with pytest.raises(UserError, match="5 timestamps for 4 images"):
        import_recording("kitti", drive2, tmp_path / "r2", show_progress=False)
    (drive2.parent / "calib_velo_to_cam.txt").unlink()
    (drive2 / "image_02" / "timestamps.txt").write_text("2011-09-26 13:02:25.1\nnot a time\n")
    with pytest.raises(UserError):
        import_recording("kitti", drive2, tmp_path / "r3", show_progress=False)
