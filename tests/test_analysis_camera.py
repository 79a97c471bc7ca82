"""Camera from the frames (blendgen.analysis.camera): pitch, roll, height, fallbacks."""

import logging
import math
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from blendgen.analysis.camera import estimate_cameras, estimate_frame, road_axes
from blendgen.geometry import Camera, R_world_cam_from_ypr, make_pose
from blendgen.recording import folder

CAM = Camera.from_hfov(640, 360, 70)
# ../shared/data from the project root; BLENDGEN_SHARED_DATA points elsewhere (e.g. from a worktree)
REAL = Path(os.environ.get("BLENDGEN_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")) / "real"


def line_scene(pitch, roll, yaw=0.0, height=1.5, lane=3.3, seed=0):
    """A street drawn from its 3-D lines: lane markings (dashed), kerbs and poles."""
    rng = np.random.default_rng(seed)
    img = np.clip(rng.normal(90, 6, (CAM.height, CAM.width)), 0, 255).astype(np.uint8)
    T = make_pose(R_world_cam_from_ypr(math.radians(yaw), math.radians(pitch), math.radians(roll)), [0, 0, height])
    lines = []
    for y in (-1.5 * lane, -0.5 * lane, 0.5 * lane, 1.5 * lane):
        lines += [((x, y, 0), (x + 3, y, 0)) for x in np.arange(3, 80, 6)]
    for y in (-2 * lane - 1, 2 * lane + 1):
        lines.append(((3, y, 0.0), (120, y, 0.0)))
    for x in np.arange(8, 70, 7):
        for y in (-2 * lane - 2, 2 * lane + 2):
            lines.append(((x, y, 0), (x, y, 5)))
    for a, b in lines:
        uv, ok = CAM.project_world(T, [a, b])
        if ok.all():
            cv2.line(img, tuple(np.round(uv[0] * 16).astype(int)), tuple(np.round(uv[1] * 16).astype(int)),
                     230, 3, cv2.LINE_AA, shift=4)
    return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)


@pytest.mark.parametrize("pitch,roll,yaw", [(3, -2, 0), (0, 0, 2), (-2, 1.5, -3), (5, 3, 1)])
def test_pitch_roll_height_from_lines(pitch, roll, yaw):
    r = estimate_frame(line_scene(pitch, roll, yaw), CAM, lane_width_m=3.3)
    assert abs(r.pitch - pitch) < 0.3 and abs(r.roll - roll) < 0.3, (r.pitch, r.roll, r.support)
    assert abs(r.yaw - yaw) < 1.0
    assert r.confidence > 0.5 and not r.reasons
    assert r.height_lanes == pytest.approx(1.5, rel=0.1)


def write_images_recording(root, frames, fmt="images"):
    root.mkdir(parents=True, exist_ok=True)
    names = []
    for i, im in enumerate(frames):
        names.append(f"{i:03d}.png")
        cv2.imwrite(str(root / names[-1]), im)
    folder.write_frames_csv(root, np.arange(len(frames), dtype=float), names)
    folder.write_calib(root, CAM, None, None, extra={"import": {"format": fmt, "camera_calibration": "from test"}})
    return folder.read_recording(root)


def test_no_structure_falls_back_with_a_reason(tmp_path, caplog):
    rng = np.random.default_rng(1)
    frames = [np.zeros((360, 640, 3), np.uint8), np.full((360, 640, 3), 128, np.uint8),
              rng.integers(0, 256, (360, 640, 3), dtype=np.uint8)]
    for im, why in zip(frames, ["dark", "uniform", "no straight edges"]):
        r = estimate_frame(im, CAM)
        assert r.pitch is None and why in r.reasons[0], r.reasons
    rec = write_images_recording(tmp_path / "rec", frames)
    with caplog.at_level(logging.INFO, logger="blendgen.analysis.camera"):
        out = estimate_cameras(rec, [rec.frame_id(i) for i in range(3)])
    for fid, (est, horizon) in out.items():
        assert est.source["pitch"] == "default" and est.source["height"] == "default"
        assert est.confidence == 0.0 and est.height_m == 1.5
        assert horizon[0][1] == pytest.approx(CAM.cy)       # level camera: horizon through the centre
        assert any(fid in m and "line segments" in m for m in caplog.messages)


def test_user_values_are_kept_and_stills_share_one_mount(tmp_path):
    """Stills of one camera: one mount (pitch 3, roll -2 in five of them). A sixth whose car
    pitches 0.8 deg more moves towards its own lines at most that far (a wrong vanishing point
    among right ones: test_analysis_mount)."""
    from blendgen.job.schema import GroundPlane

    frames = [line_scene(3, -2, seed=i) for i in range(5)] + [line_scene(3.8, -2)]
    rec = write_images_recording(tmp_path / "rec", frames)
    ids = [rec.frame_id(i) for i in range(6)]
    out = estimate_cameras(rec, ids, user=GroundPlane(camera_height_m="auto", pitch_deg="auto", roll_deg="auto",
                                                      lane_width_m=3.3))
    for f in ids:
        e = out[f][0]
        assert e.source == {"pitch": "mount", "roll": "mount", "height": "lanes"}
        assert e.height_m == out[ids[0]][0].height_m == pytest.approx(1.5, rel=0.05)   # one height for the camera
        if f in ids[:5]:
            assert abs(e.pitch_deg - 3) < 0.3 and abs(e.roll_deg + 2) < 0.3, e
    assert 2.95 < out[ids[5]][0].pitch_deg < 3.85
    e0 = out[ids[0]][0]
    # horizon: through the road's vanishing point, tilted by the roll
    (u0, v0), (u1, v1) = out[ids[0]][1]
    assert math.degrees(math.atan2(v1 - v0, u1 - u0)) == pytest.approx(2.0, abs=0.3)
    gp = GroundPlane(camera_height_m=1.5, pitch_deg="auto", roll_deg=0.5)
    e = estimate_cameras(rec, ids[:1], user=gp)[ids[0]][0]
    assert e.height_m == 1.5 and e.roll_deg == 0.5 and e.source["height"] == "user" and e.source["roll"] == "user"
    assert abs(e.pitch_deg - 3) < 0.4


@pytest.mark.bpy
def test_demo_town_frames_recovered(request):
    """Frames rendered from the demo town at known poses (cached between runs)."""
    pytest.importorskip("bpy")
    from blendgen.render.posed_frames import render_posed_frames

    specs = [dict(name="p3_r-2", seed=0, s=0, height_m=1.5, pitch_deg=3.0, roll_deg=-2.0, yaw_deg=0.0),
             dict(name="p-2_r1.5", seed=2, s=5, height_m=1.7, pitch_deg=-2.0, roll_deg=1.5, yaw_deg=-3.0)]
    out_dir = request.config.cache.mkdir("blendgen_camera_frames")
    poses = render_posed_frames(out_dir, specs, CAM, samples=4)
    for name, p in poses.items():
        r = estimate_frame(cv2.imread(str(out_dir / f"{name}.png")), CAM, lane_width_m=3.3)
        assert abs(r.pitch - p["pitch_deg"]) < 0.5 and abs(r.roll - p["roll_deg"]) < 0.5, (name, r.pitch, r.roll)
        assert r.height_lanes == pytest.approx(p["height_m"], rel=0.1)


def lane_lines_vanishing_point(img, K, D, corridors):
    """Ground truth: the two ego-lane lines' intersection in the undistorted image, each line
    fitted (Huber) to the paint pixels (yellow or white) in a hand-drawn corridor around it."""
    und = cv2.undistort(img, K, D)
    hsv = cv2.cvtColor(und, cv2.COLOR_BGR2HSV).astype(int)
    yy, xx = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    paint = (((hsv[..., 0] > 15) & (hsv[..., 0] < 35) & (hsv[..., 1] > 90) & (hsv[..., 2] > 140)) |
             ((hsv[..., 1] < 50) & (hsv[..., 2] > 190))) & (yy > 470) & (yy < 670)
    lines = []
    for (x0, y0), (x1, y1) in corridors:
        near = np.abs((x1 - x0) * (yy - y0) - (y1 - y0) * (xx - x0)) / math.hypot(x1 - x0, y1 - y0) < 30
        pts = np.c_[xx[paint & near], yy[paint & near]].astype(np.float32)
        vx, vy, cx, cy = cv2.fitLine(pts, cv2.DIST_HUBER, 0, 0.01, 0.01).ravel()
        lines.append(np.cross([cx, cy, 1.0], [cx + vx, cy + vy, 1.0]))
    vp = np.cross(*lines)
    return vp[:2] / vp[2]


@pytest.mark.data
def test_udacity_dashcam_horizon_is_the_lane_vanishing_point():
    """Calibrate the real dashcam from its chessboards, then the horizon estimated on a straight,
    flat highway must pass through the lane lines' vanishing point."""
    from blendgen.analysis.hood import hood_in_still
    from blendgen.analysis.lane_direction import lane_direction

    root = REAL / "udacity_lane_camera"
    if not (root / "camera_cal").is_dir():
        pytest.skip("needs ../shared/data/real/udacity_lane_camera/camera_cal")
    board = np.zeros((54, 3), np.float32)
    board[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2)
    obj, img_pts = [], []
    for p in sorted((root / "camera_cal").glob("*.jpg")):
        g = cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2GRAY)
        ok, c = cv2.findChessboardCorners(g, (9, 6), flags=cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_FAST_CHECK)
        if ok:
            obj.append(board)
            img_pts.append(cv2.cornerSubPix(g, c, (11, 11), (-1, -1),
                                            (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)))
    assert len(obj) >= 15
    rms, K, D, _, _ = cv2.calibrateCamera(obj, img_pts, (1280, 720), None, None)
    assert rms < 1.5
    cam = Camera(1280, 720, K[0, 0], K[1, 1], K[0, 2], K[1, 2], D.ravel().tolist())
    corridors = {"straight_lines1.jpg": (((220, 700), (620, 432)), ((1045, 690), (665, 432))),
                 "straight_lines2.jpg": (((250, 695), (620, 432)), ((1070, 690), (660, 432)))}
    for name, cor in corridors.items():
        img = cv2.imread(str(root / name))
        vp = lane_lines_vanishing_point(img, K, D, cor)
        r = estimate_frame(img, cam, hood=hood_in_still(img)[0])
        # horizon row at the vanishing point's column (undistorted pinhole image)
        U = road_axes(math.radians(r.pitch), math.radians(r.roll), 0.0)[2]
        lh = np.linalg.inv(cam.K).T @ U
        v = -(lh[0] * vp[0] + lh[2]) / lh[1]
        assert abs(math.degrees(math.atan((v - vp[1]) / cam.fy))) < 0.5, (name, v, vp)
        # the lane markings' vanishing point found without the corridors (analysis.lane_direction)
        ld = lane_direction(img, cam, hood=hood_in_still(img)[0])
        assert ld.vp is not None and np.hypot(*(np.array(ld.vp) - vp)) < 2.0, (name, ld.summary(), vp)


def test_imu_gravity_gives_pitch_and_roll_without_lines(tmp_path):
    """A dark video (no lines) with an IMU: pitch and roll come from gravity."""
    from scipy.spatial.transform import Rotation

    rec = write_images_recording(tmp_path / "rec", [np.zeros((360, 640, 3), np.uint8)] * 3, fmt="video")
    R_cam_imu = Rotation.from_euler("xyz", [80, 5, -90], degrees=True).as_matrix()
    rec.T_cam_imu = make_pose(R_cam_imu, [0.1, 0.0, 0.0])
    R_world_imu = R_world_cam_from_ypr(0.3, math.radians(3.0), math.radians(-2.0)) @ R_cam_imu
    t = np.arange(0, 3, 0.01)
    rng = np.random.default_rng(0)
    acc = (R_world_imu.T @ [0, 0, 9.81])[None, :] + rng.normal(0, 0.05, (len(t), 3))
    rec.imu = np.c_[t, np.zeros((len(t), 3)), acc]
    out = estimate_cameras(rec, [rec.frame_id(i) for i in range(3)])
    for est, _ in out.values():
        assert est.source["pitch"] == "imu" and est.source["roll"] == "imu"
        assert abs(est.pitch_deg - 3.0) < 0.2 and abs(est.roll_deg + 2.0) < 0.2 and est.confidence > 0.2


def test_video_is_smoothed_and_a_dark_frame_takes_its_neighbours(tmp_path):
    frames = [line_scene(2.0, -1.0, seed=i) for i in range(5)]
    frames[2] = np.zeros_like(frames[0])
    rec = write_images_recording(tmp_path / "rec", frames, fmt="video")
    rec.frames_t = np.arange(5) * 0.1
    out = estimate_cameras(rec, [rec.frame_id(i) for i in range(5)])
    for fid, (est, _) in out.items():
        assert est.source["pitch"] == "smoothed" and abs(est.pitch_deg - 2.0) < 0.3 and abs(est.roll_deg + 1) < 0.3
        assert est.source["height"] == "lanes"     # one height for the whole video
    assert "line segments" in out["f000002"][0].reasons[0]


def test_focal_length_from_two_vanishing_points_when_the_fov_was_guessed():
    guess = Camera.from_hfov(640, 360, 60)            # the real camera has 70 deg
    r = estimate_frame(line_scene(5, 3), guess, fit_focal=True)
    assert r.fx == pytest.approx(CAM.fx, rel=0.03) and abs(r.pitch - 5) < 0.2 and abs(r.roll - 3) < 0.2
    # nearly level: the vertical vanishing point is too far to fix f, the guess is kept and the
    # angles agree with it, so the horizon still lands on the right image row
    r = estimate_frame(line_scene(3, -2), guess, fit_focal=True)
    assert r.fx is None
    v_true = CAM.cy + CAM.fy * math.tan(math.radians(3))
    assert guess.cy + guess.fy * math.tan(math.radians(r.pitch)) == pytest.approx(v_true, abs=2)


@pytest.mark.parametrize("cam", [CAM, Camera(640, 360, CAM.fx, CAM.fy, CAM.cx, CAM.cy, [-0.25, 0.08, 0.0, 0.0, 0.0]),
                                 Camera(640, 360, 260.0, 260.0, 319.5, 179.5, [0.043, 0.036, -0.034, 0.012],
                                        "equidistant")], ids=["pinhole", "barrel", "fisheye"])
def test_height_from_real_cars_boxes(cam):
    """Boxes of cars around the camera give its height within 2 %, through lens distortion too
    (the box is undistorted first: k1 = -0.25 read as a pinhole was up to 6.5 % off)."""
    from blendgen.analysis.camera import height_from_cars

    T = make_pose(R_world_cam_from_ypr(0.0, math.radians(2.0), 0.0), [0, 0, 1.5])
    R = road_axes(math.radians(2.0), 0.0, 0.0)
    boxes = []
    for x, y in ((12, -3.5), (25, 0.0), (18, 3.5), (40, -3.5), (8, 3.5), (10, -1.0)):   # ahead, beside, straddling
        corners = [[x + dx, y + dy, dz] for dx in (0, 4.5) for dy in (-0.9, 0.9) for dz in (0, 1.5)]
        uv, _ = cam.project_world(T, corners)
        (u0, v0), (u1, v1) = uv.min(0), uv.max(0)
        boxes.append([u0, v0, u1 - u0, v1 - v0])
        assert height_from_cars(boxes[-1:], cam, R) == pytest.approx(1.5, rel=0.02), (x, y)
    assert height_from_cars(boxes, cam, R) == pytest.approx(1.5, rel=0.02)


def test_video_camera_height_does_not_depend_on_the_jobs_frames(tmp_path):
    """The freeway video's camera height came out 1.56 m (the real cars' boxes) for frames 0-56
    and 1.28 m (one frame's lanes) for every 30th frame; lanes from frames spread over the
    whole recording now set it for both (the lane dashes' 14.6 m period says about 1.22 m)."""
    p = Path(os.environ.get("BLENDGEN_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")) \
        / "real" / "udacity_solidWhiteRight.mp4"
    if not p.is_file():
        pytest.skip(f"needs {p}")
    from blendgen.analysis.objects import load_detector, road_users
    from blendgen.recording.folder import read_recording
    from blendgen.recording.frames import read_frames
    from blendgen.recording.importers.video import import_video

    rec = read_recording(import_video(p, tmp_path / "rec", show_progress=False, hfov_deg=55.0))
    det = load_detector()
    heights = {}
    for name, idx in (("0-56", range(0, 57, 4)), ("every 30th", range(0, 221, 30))):
        ids = [rec.frame_id(i) for i in idx]
        cars = {f: [o.box for o in road_users(im, det) if o.cls == "car"] for f, im in read_frames(rec, ids)}
        est = estimate_cameras(rec, ids, car_boxes=cars)
        heights[name] = est[ids[0]][0].height_m
        assert "lanes" in est[ids[0]][0].source["height"], est[ids[0]][0].reasons
    assert abs(heights["0-56"] / heights["every 30th"] - 1) < 0.08 and 1.05 < heights["0-56"] < 1.4, heights



def test_stills_of_different_cameras_each_get_their_own_mount(tmp_path):
    """`ground_plane.stills: per_image` (photos of different cars: pitch 3 / -2, heights 1.2 / 1.7):
    each photo gets the camera it gets imported alone; `shared` gives them one mount."""
    from blendgen.job.schema import GroundPlane

    frames = [line_scene(3, -2, height=1.2, seed=0), line_scene(-2, 1, height=1.7, seed=1),
              line_scene(3, -2, height=1.2, seed=2), line_scene(-2, 1, height=1.7, seed=3)]
    rec = write_images_recording(tmp_path / "rec", frames)
    ids = [rec.frame_id(i) for i in range(4)]
    kw = dict(camera_height_m="auto", pitch_deg="auto", roll_deg="auto", lane_width_m=3.3)
    own = estimate_cameras(rec, ids, user=GroundPlane(**kw, stills="per_image"))
    for i, f in enumerate(ids):
        alone = write_images_recording(tmp_path / f"alone{i}", [frames[i]])
        a = estimate_cameras(alone, [alone.frame_id(0)], user=GroundPlane(**kw))[alone.frame_id(0)][0]
        e = own[f][0]
        assert (e.height_m, e.pitch_deg, e.roll_deg) == pytest.approx((a.height_m, a.pitch_deg, a.roll_deg), abs=1e-6)
        pitch, roll = (3, -2) if i % 2 == 0 else (-2, 1)
        assert abs(e.pitch_deg - pitch) < 1.2 and abs(e.roll_deg - roll) < 0.4, e   # one frame's fit
    assert own[ids[1]][0].height_m > own[ids[0]][0].height_m + 0.1   # 1.7 against 1.2 (one frame: towards the prior)
    shared = estimate_cameras(rec, ids, user=GroundPlane(**kw))
    assert len({round(shared[f][0].height_m, 6) for f in ids}) == 1   # one camera: one height for all
