"""Re-anchoring: a drifted trajectory is pulled onto the fixes, with no jumps and no creeping."""

import numpy as np

from blendgen.geometry import make_pose
from blendgen.sync.pipeline import SyncResult
from blendgen.sync.reanchor import reanchor


def _result(t, P):
    poses = [(f"f{i:06d}", float(ti), make_pose(np.eye(3), p)) for i, (ti, p) in enumerate(zip(t, P))]
    return SyncResult(poses, np.ones((len(t), 6)), [{"flags": []} for _ in t])


def test_drift_is_removed_smoothly_and_parking_stays_put():
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 40.0, 0.2)
    speed = np.where((t > 15) & (t < 25), 0.0, 8.0)  # 10 s parked in the middle
    x = np.concatenate([[0.0], np.cumsum(speed[1:] * 0.2)])
    truth = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    # odometry drift grows with distance (0.8 % along, 0.5 % across): ~2.0 m / 1.2 m at the end
    drift = np.column_stack([0.008 * x, 0.005 * x, np.zeros_like(x)])
    res = _result(t, truth + drift)
    ft = np.arange(0.05, 40.0, 0.1)
    fx = np.column_stack([np.interp(ft, t, truth[:, k]) for k in range(3)]) + rng.normal(0, 0.5, (len(ft), 3))
    n = reanchor(res, ft, fx, np.ones(len(ft), bool), np.full(len(ft), 0.5), 5.0, np.eye(4))
    assert n == 8
    P = res.positions()
    err = np.linalg.norm(P[:, :2] - truth[:, :2], axis=1)
    before = np.linalg.norm(drift[:, :2], axis=1)
    assert np.median(err) < 0.35 * np.median(before)
    steps = np.linalg.norm(np.diff(P, axis=0), axis=1)
    assert steps.max() < 1.6 + 0.1  # 8 m/s * 0.2 s plus a small share of the correction
    parked = (t > 15.5) & (t < 24.5)
    assert np.ptp(P[parked, 0]) < 0.02 and np.ptp(P[parked, 1]) < 0.02
    assert all("reanchored" in q["flags"] for q in res.quality)


def test_agreeing_trajectory_is_left_alone():
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 20.0, 0.2)
    truth = np.column_stack([8 * t, np.zeros_like(t), np.zeros_like(t)])
    res = _result(t, truth.copy())
    ft = np.arange(0.05, 20.0, 0.1)
    fx = np.column_stack([8 * ft, np.zeros_like(ft), np.zeros_like(ft)]) + rng.normal(0, 1.0, (len(ft), 3))
    reanchor(res, ft, fx, np.ones(len(ft), bool), np.full(len(ft), 1.0), 5.0, np.eye(4))
    assert np.abs(res.positions() - truth).max() < 0.15  # the fix noise is not copied in
