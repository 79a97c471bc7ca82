"""run_sync end to end on synthetic recordings with frames (ray-cast, no Blender), the LUT path,
the output files, and the `blendgen sync` command."""

from pathlib import Path

import cv2
import numpy as np
import pymap3d
import pytest

from blendgen import so3
from blendgen.cli import main
from blendgen.geometry import make_pose
from blendgen.job.schema import Sync
from blendgen.recording import folder
from blendgen.sync.lut import write_lut
from blendgen.sync.metrics import gt_poses, trajectory_errors
from blendgen.sync.pipeline import POSES_COLUMNS, read_poses, run_sync
from blendgen.sync.simulate import GEOREF, StreetScene, synthetic_recording


@pytest.fixture(scope="module")
def scene():
    return StreetScene()


@pytest.fixture(scope="module")
def drive(scene):
    return synthetic_recording("drive", 10.0, scene=scene)


def _errors(res, rec):
    return trajectory_errors([p[2] for p in res.poses], gt_poses(rec.groundtruth))


def test_full_fusion_with_frames(tmp_path, drive):
    rec, traj, _ = drive
    calls = []
    res = run_sync(rec, Sync(), tmp_path, georef=GEOREF, progress=False,
                   on_progress=lambda done, phase, total: calls.append((phase, done, total)))
    assert [p[0] for p in res.poses] == [rec.frame_id(i) for i in range(rec.n_frames)]
    # `blendgen status` hears of VO and each filter pass, to their last frame
    assert ("VO", rec.n_frames, rec.n_frames) in calls and ("sync", rec.n_frames, rec.n_frames) in calls
    assert np.allclose(res.times, rec.frames_t)
    err = _errors(res, rec)
    assert err["ate_rmse_m"] < 0.8 and err["rot_median_deg"] < 1.0 and err["rpe_rmse_m"] < 0.1
    assert res.summary["vo_status"].get("ok", 0) >= rec.n_frames - 3
    assert all("vo" in q["flags"] for q in res.quality[1:])
    # files
    lines = (tmp_path / "poses.csv").read_text().splitlines()
    assert lines[0].split(",") == POSES_COLUMNS and len(lines) == rec.n_frames + 1
    tum = (tmp_path / "poses.tum").read_text().splitlines()
    assert len(tum) == rec.n_frames and len(tum[0].split()) == 8
    back = read_poses(tmp_path / "poses.csv", rec)
    assert [b[0] for b in back] == [p[0] for p in res.poses]
    assert np.allclose(back[5][2], res.poses[5][2], atol=1e-5)


def test_vo_improves_rotation_over_imu_gnss(tmp_path, drive):
    rec, _, _ = drive
    with_vo = _errors(run_sync(rec, Sync(), tmp_path / "a", georef=GEOREF, progress=False), rec)
    no_vo = _errors(run_sync(rec, Sync(use_vo=False), tmp_path / "b", georef=GEOREF, progress=False), rec)
    assert with_vo["rot_median_deg"] < no_vo["rot_median_deg"]


def test_dark_frames_are_bridged(tmp_path, scene):
    rec, _, _ = synthetic_recording("drive", 10.0, dark_frames=(15, 35), scene=scene)
    res = run_sync(rec, Sync(), tmp_path, georef=GEOREF, progress=False)
    flags = [q["flags"] for q in res.quality]
    assert sum("vo_failed" in f for f in flags) >= 18
    err = _errors(res, rec)
    assert err["ate_rmse_m"] < 1.0 and err["rot_median_deg"] < 1.5
    assert np.all(np.isfinite(res.cov))


def test_repeated_frames_while_driving(tmp_path, scene):
    """Encoder duplicates: the image repeats but the car moves on (no false standstill)."""
    rec, _, _ = synthetic_recording("drive", 8.0, scene=scene)
    for k in (10, 11, 25):
        rec.extra["images"][k] = rec.extra["images"][k - 1].copy()
    res = run_sync(rec, Sync(), tmp_path, georef=GEOREF, progress=False)
    flags = [q["flags"] for q in res.quality]
    assert ["repeated_frame" in f for f in flags].count(True) == 3
    assert not any("zupt" in f for f in flags)
    err = _errors(res, rec)
    assert err["ate_rmse_m"] < 0.8 and err["rot_median_deg"] < 1.0


def test_vo_only_without_imu_and_gnss(tmp_path, drive):
    rec, _, _ = drive
    res = run_sync(rec, Sync(use_imu=False, use_gnss=False), tmp_path, progress=False)
    assert all("scale_unknown" in q["flags"] for q in res.quality)
    P = res.positions()
    d = P[-1] - P[0]
    assert d[0] > 0.9 * np.linalg.norm(d)  # drives forward (+x of the first camera's heading)
    rel = [np.linalg.norm(so3.log(a[:3, :3].T @ b[:3, :3])) for a, b in
           zip([p[2] for p in res.poses], gt_poses(rec.groundtruth))]
    # rotation relative to the first frame is tracked (the first frame fixes the world)
    G = gt_poses(rec.groundtruth)
    E = [p[2] for p in res.poses]
    drift = [np.degrees(np.linalg.norm(so3.log((G[0][:3, :3].T @ g[:3, :3]).T @ (E[0][:3, :3].T @ e[:3, :3]))))
             for e, g in zip(E, G)]
    assert max(drift) < 3.0 and np.all(np.isfinite(rel))


def test_lut_maps_into_twin_frame(tmp_path, drive):
    """A twin rotated 40 deg and shifted from ENU: poses come out in the twin frame."""
    rec, traj, _ = drive
    a = np.radians(40.0)
    Rz = so3.yaw_rotation(a)
    shift = np.array([500.0, -200.0, 3.0])
    e, n = (g.ravel() for g in np.meshgrid(np.arange(-20.0, 125.0, 5.0), np.arange(-20.0, 25.0, 5.0)))
    lat, lon, alt = pymap3d.enu2geodetic(e, n, np.zeros_like(e), *GEOREF)
    xyz = (Rz @ np.stack([e, n, np.zeros_like(e)])).T + shift
    rows = np.column_stack([lat, lon, alt, np.full_like(e, 90.0), xyz, np.full_like(e, 40.0)])
    write_lut(tmp_path / "lut.csv", rows)
    res = run_sync(rec, Sync(), tmp_path, lut_path=tmp_path / "lut.csv", progress=False)
    T_twin_enu = make_pose(Rz, shift)
    gt = [T_twin_enu @ g for g in gt_poses(rec.groundtruth)]
    err = trajectory_errors([p[2] for p in res.poses], gt)
    assert err["ate_rmse_m"] < 0.8 and err["rot_median_deg"] < 1.0
    assert res.summary["gnss_outside_lut"] == 0


def _write_folder(root: Path, rec) -> Path:
    folder.write_calib(root, rec.camera, rec.T_cam_imu)
    files = []
    for i, img in enumerate(rec.extra["images"]):
        f = f"frames/{i:04d}.png"
        (root / "frames").mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(root / f), img)
        files.append(f)
    folder.write_frames_csv(root, rec.frames_t, files)
    folder.write_imu(root, rec.imu)
    folder.write_gnss(root, rec.gnss)
    return root


def test_command_and_decode_failure(tmp_path, scene, capsys):
    rec, _, _ = synthetic_recording("drive", 4.0, scene=scene)
    root = _write_folder(tmp_path / "rec", rec)
    (root / "frames" / "0007.png").write_bytes(b"broken")
    out = tmp_path / "out"
    code = main(["sync", str(root), "--out", str(out), "--orb-features", "800", "--reanchor-every", "2", "--quiet"])
    assert code == 0
    assert "sync: 20 poses" in capsys.readouterr().out
    rows = (out / "poses.csv").read_text().splitlines()[1:]
    assert "decode_failed" in rows[7] and len(rows) == 20
    # bad input: exit code 2 with a message naming the file
    (tmp_path / "bad.csv").write_text("lat,lon\n1,2\n")
    assert main(["sync", str(root), "--out", str(out), "--lut", str(tmp_path / "bad.csv")]) == 2
    assert "bad.csv" in capsys.readouterr().err
    assert main(["sync", str(root), "--out", str(out), "--orb-features", "3"]) == 2
    assert "--orb-features" in capsys.readouterr().err


def test_imu_gnss_only_outputs_at_pose_rate(tmp_path):
    rec, _, _ = synthetic_recording("drive", 10.0, frames=False)
    res = run_sync(rec, Sync(pose_rate_hz=4.0), tmp_path, georef=GEOREF, progress=False)
    assert len(res.poses) == pytest.approx(11 * 4, abs=3)
    assert np.allclose(np.diff(res.times), 0.25)
    assert res.poses[0][0] == "p000000"


def test_nothing_to_work_with(tmp_path, drive):
    from blendgen.errors import UserError

    rec, _, _ = drive
    with pytest.raises(UserError, match="nothing to work with"):
        run_sync(rec, Sync(use_imu=False, use_gnss=False, use_vo=False), tmp_path, progress=False)
