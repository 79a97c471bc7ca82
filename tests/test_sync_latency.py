"""GNSS receiver latency by profile likelihood (blendgen.sync.latency, calib.yaml gnss.latency_s: auto)."""

import numpy as np
import pytest

from blendgen.errors import UserError
from blendgen.geometry import invert_pose
from blendgen.job.schema import Sync
from blendgen.recording.model import Recording
from blendgen.sync.calibration import describe, read_priors
from blendgen.sync.latency import profile_latency
from blendgen.sync.pipeline import run_sync
from blendgen.sync.simulate import GEOREF, synthetic_recording


def test_profile_finds_the_minimum_and_its_curvature():
    calls = []

    def cost(t):  # a likelihood that is not quite a parabola (steeper above, as on comma2k19)
        calls.append(t)
        d = t - 0.137
        return 100.0 + 0.5 * (d / 0.02) ** 2 + 300.0 * d**3

    p = profile_latency(cost, 0.0, 0.4)
    assert p.tau_s == pytest.approx(0.137, abs=0.003)
    assert p.std_s == pytest.approx(0.02, rel=0.15)
    assert not p.at_limit
    assert len(calls) <= 9  # the forward passes it costs
    assert min(p.costs) == 0.0 and len(p.taus) == len(calls)


def test_profile_prior_and_search_limit():
    flat = profile_latency(lambda t: 0.0 * t, -0.3, 0.3, step=0.05, prior=(0.1, 0.1))
    assert flat.tau_s == pytest.approx(0.1, abs=1e-6)  # a flat likelihood leaves the prior
    assert flat.std_s == pytest.approx(0.1, rel=0.05)
    edge = profile_latency(lambda t: 10.0 * t, 0.0, 0.4)  # decreasing towards 0: at the limit
    assert edge.tau_s == 0.0 and edge.at_limit


def _rec(gnss: dict) -> Recording:
    rec = Recording(root=None, camera=None)
    rec.extra["gnss"] = gnss
    return rec


def test_calib_yaml_latency_auto_and_bad_values():
    pri = read_priors(_rec({"latency_s": "auto", "latency_max_s": 0.3}))
    assert pri.latency_auto and pri.latency_s == 0.0 and pri.latency_max_s == 0.3
    assert not read_priors(_rec({"latency_s": 0.05})).latency_auto
    with pytest.raises(UserError, match="latency_s"):
        read_priors(_rec({"latency_s": "soon"}))
    with pytest.raises(UserError, match="latency_max_s"):
        read_priors(_rec({"latency_s": "auto", "latency_max_s": 0.0}))


def test_calib_yaml_road_vehicle():
    from blendgen.sync.calibration import road_vehicle

    rec = _rec({})
    assert road_vehicle(rec)
    rec.extra["vehicle"] = {"road_vehicle": False}
    assert not road_vehicle(rec)
    rec.extra["vehicle"] = {"road_vehicle": "no"}
    with pytest.raises(UserError, match="road_vehicle: expected true or false"):
        road_vehicle(rec)


def _drive_error(out, latency_true: float, mode, seed: int = 0):
    rec, traj, T_cam_imu = synthetic_recording("drive", 60, frames=False, seed=seed,
                                               gnss_errors={"latency_s": latency_true})
    if mode is not None:
        rec.extra["gnss"] = {"latency_s": mode}
    res = run_sync(rec, Sync(), out, georef=GEOREF, progress=False)
    T_bc = invert_pose(T_cam_imu)
    G = np.array([(traj.pose(t) @ T_bc)[:3, 3] for t in res.times])
    err = np.linalg.norm(res.positions()[:, :2] - G[:, :2], axis=1)
    return res, float(np.sqrt(np.mean(err**2)))


@pytest.mark.slow
def test_synthetic_latency_is_recovered(tmp_path):
    """A receiver 0.08 s late on the 60 s synthetic drive (8 m/s +-15 %, S-curves, 1 m white
    GNSS noise): the profile finds it within 0.05 s (measured: 0.104 +- 0.042 and 0.064 +- 0.042
    s with seeds 0 and 1) and the horizontal error drops (0.65 -> 0.21 m); without a latency the
    estimate stays near 0 (0.028 and 0.000)."""
    res, err = _drive_error(tmp_path / "a", 0.08, "auto")
    lat = res.summary["gnss_latency"]
    assert abs(lat["latency_s"] - 0.08) < 0.05
    assert abs(lat["latency_s"] - 0.08) < 2.5 * lat["latency_std_s"]
    assert 0.01 < lat["latency_std_s"] < 0.1 and not lat["at_search_limit"]
    assert "profile likelihood" in describe(res.summary["calibration"])
    _, err_ignored = _drive_error(tmp_path / "b", 0.08, None)
    assert err < 0.5 * err_ignored  # 0.21 vs 0.65 m
    res0, _ = _drive_error(tmp_path / "c", 0.0, "auto")
    assert res0.summary["gnss_latency"]["latency_s"] < 0.06


def test_gnss_noise_scale_from_the_innovations(tmp_path):
    """gnss.h_std_scale: auto. The synthetic fixes have 1 m white noise and no h_std_m column
    (stated 1.5 m): the innovations say 1.0 / 1.5 = 0.67 (measured 0.667 over 60 s)."""
    rec, _, _ = synthetic_recording("drive", 30, frames=False, seed=3)
    rec.extra["gnss"] = {"h_std_scale": "auto"}
    res = run_sync(rec, Sync(), tmp_path, georef=GEOREF, progress=False)
    cal = res.summary["calibration"]
    assert cal["gnss_h_std_scale"] == pytest.approx(1.0 / 1.5, rel=0.15)
    assert cal["gnss_h_std_scale"] == cal["gnss_h_std_scale_measured"]
    assert "gnss_latency" not in res.summary  # the latency stays as given
    with pytest.raises(UserError, match="h_std_scale"):
        read_priors(_rec({"h_std_scale": "often"}))
    with pytest.raises(UserError, match="h_std_scale"):
        read_priors(_rec({"h_std_scale": 0.0}))


def test_describe_says_how_the_latency_was_found():
    cal = {"camera_mount_rpy_deg": [0.9, 3.7, 0.0], "mount_std_deg": [0.5, 0.2, 0.3], "gnss_latency_s": 0.068,
           "gnss_latency_std_s": 0.014, "gnss_latency_method": "profile likelihood", "lever_arm_m": [0, 0, 0],
           "lever_arm_std_m": [0, 0, 0], "gnss_h_std_scale": 0.084, "gnss_h_std_scale_measured": 0.084}
    line = describe(cal)
    assert "GNSS latency +0.068 +- 0.014 s (profile likelihood)" in line and "fix noise x0.084" in line
    assert "undetermined" in describe({**cal, "gnss_latency_std_s": None})
    plain = describe({**cal, "gnss_latency_s": 0.0, "gnss_latency_std_s": 0.0, "gnss_latency_method": None,
                      "gnss_h_std_scale": 1.0, "gnss_h_std_scale_measured": None})
    assert "as given" in plain
