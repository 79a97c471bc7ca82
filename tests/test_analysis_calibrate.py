"""`blendgen calibrate` and the job's `ground_plane: auto`."""

import numpy as np
import pytest
import yaml

from blendgen.cli import main
from blendgen.errors import UserError
from blendgen.job.schema import parse_job
from test_analysis_camera import line_scene, write_images_recording
from test_analysis_egomotion import drive, write_drive
from test_analysis_lane_direction import CAM as LANE_CAM
from test_analysis_lane_direction import road_frame


def test_calibrate_stills_writes_the_estimate(tmp_path, capsys):
    rec = write_images_recording(tmp_path / "rec", [line_scene(3, -2), line_scene(3, -2, seed=1)])
    assert main(["calibrate", str(rec.root), "--quiet", "--lane-width", "3.3"]) == 0
    out = capsys.readouterr().out
    assert "2 frames (stills)" in out and "ground_plane.yaml" in out
    doc = yaml.safe_load((rec.root / "ground_plane.yaml").read_text())
    f0 = doc["frames"][0]
    assert f0["id"] == "f000000" and abs(f0["pitch_deg"] - 3) < 0.3 and abs(f0["roll_deg"] + 2) < 0.3
    assert f0["source"]["height"] == "lanes" and f0["height_m"] == pytest.approx(1.5, rel=0.1)
    assert doc["summary"]["frames"] == 2 and "position_m" not in f0
    # a fixed value is kept, another output path is honoured
    assert main(["calibrate", str(rec.root), "--quiet", "--height", "1.3", "--out", str(tmp_path / "g.yaml")]) == 0
    doc = yaml.safe_load((tmp_path / "g.yaml").read_text())
    assert doc["summary"]["height_m"] == 1.3 and doc["frames"][1]["source"]["height"] == "user"


def test_calibrate_video_moves_over_the_ground(tmp_path, capsys):
    rec = write_drive(tmp_path / "drive", drive(n=8, yaw_rate_deg=0.0))
    assert main(["calibrate", str(rec.root), "--quiet", "--height", "1.4", "--pitch", "2", "--roll", "-1"]) == 0
    doc = yaml.safe_load((rec.root / "ground_plane.yaml").read_text())
    xs = [f["position_m"][0] for f in doc["frames"]]
    assert np.allclose(np.diff(xs), 1.0, atol=0.05), xs
    assert "travelled" in capsys.readouterr().out


def test_calibrate_gives_the_camera_yaw_from_lane_markings(tmp_path, capsys):
    """Road photos taken with the camera 1.2 deg left of the lane (pitch 2.5 deg): the lane
    markings' yaw per frame and over the recording, for calib.yaml vehicle.camera_yaw_deg."""
    import cv2

    from blendgen.recording import folder

    root = tmp_path / "rec"
    root.mkdir()
    names = []
    for i in range(3):
        names.append(f"{i:03d}.png")
        cv2.imwrite(str(root / names[-1]), road_frame(1.2, 2.5, seed=i))
    cv2.imwrite(str(root / "003.png"), np.full((LANE_CAM.height, LANE_CAM.width, 3), 90, np.uint8))
    folder.write_frames_csv(root, np.arange(4, dtype=float), names + ["003.png"])
    folder.write_calib(root, LANE_CAM, None, None, extra={"import": {"format": "images"}})
    assert main(["calibrate", str(root), "--quiet"]) == 0
    assert "lane markings in 3 frames: camera yaw in the car +1.2" in capsys.readouterr().out
    doc = yaml.safe_load((root / "ground_plane.yaml").read_text())
    assert doc["summary"]["lane_yaw_deg"] == pytest.approx(1.2, abs=0.05) and doc["summary"]["lane_yaw_frames"] == 3
    assert doc["frames"][0]["lane_direction"]["yaw_deg"] == pytest.approx(1.2, abs=0.05)
    assert "lane marking" in doc["frames"][3]["lane_direction"]["reason"]


@pytest.mark.parametrize("args,msg", [(["--step", "0"], "--step"), (["--pitch", "99"], "--pitch"),
                                      (["--lane-width", "9"], "--lane-width")])
def test_calibrate_bad_input_exits_2(tmp_path, capsys, args, msg):
    rec = write_images_recording(tmp_path / "rec", [line_scene(0, 0)])
    assert main(["calibrate", str(rec.root), "--quiet", *args]) == 2
    err = capsys.readouterr().err
    assert msg in err and "Traceback" not in err
    assert not (rec.root / "ground_plane.yaml").exists()


def test_calibrate_missing_recording_exits_2(tmp_path, capsys):
    assert main(["calibrate", str(tmp_path / "nope")]) == 2
    assert "recording folder not found" in capsys.readouterr().err


def test_job_ground_plane_auto(tmp_path):
    base = {"name": "j", "recording": str(tmp_path), "output": "out"}
    gp = parse_job({**base, "ground_plane": "auto"}, source="job.yaml", job_dir=tmp_path).ground_plane
    assert gp.auto == ["camera_height_m", "pitch_deg", "roll_deg"]
    gp = parse_job({**base, "ground_plane": {"pitch_deg": "auto", "roll_deg": 1.5}}, source="job.yaml",
                   job_dir=tmp_path).ground_plane
    assert gp.auto == ["pitch_deg"] and gp.roll_deg == 1.5 and gp.camera_height_m == 1.5
    for bad, field in (({"pitch_deg": "autom"}, "ground_plane.pitch_deg"), ("yes", "ground_plane"),
                       ({"camera_height_m": 7}, "ground_plane.camera_height_m"), ({"roll_deg": True}, "roll_deg")):
        with pytest.raises(UserError, match=field) as e:
            parse_job({**base, "ground_plane": bad}, source="job.yaml", job_dir=tmp_path)
        assert "auto" in str(e.value)
