"""Hand-written pieces we keep (docs/design_decisions.md) agree with their libraries."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from blendgen import so3
from blendgen.sync.metrics import trajectory_errors


def test_so3_matches_scipy():
    rng = np.random.default_rng(0)
    ws = np.concatenate([rng.normal(0, 1, (200, 3)), rng.normal(0, 1e-9, (20, 3))])
    for w in ws:
        R = so3.exp(w)
        assert np.allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
        assert np.allclose(so3.log(R), Rotation.from_matrix(R).as_rotvec(), atol=1e-9)


def test_ate_rpe_match_evo(monkeypatch):
    pytest.importorskip("evo.core.metrics")
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1]))
    from benchmarks.realism.bench_own_vs_library import evo_ate_rpe  # the benchmark's evo reference

    rng = np.random.default_rng(1)
    n = 60
    t = np.arange(n) * 0.1
    R = Rotation.from_euler("zyx", np.column_stack([t / 3, 0.05 * np.sin(t), 0.02 * t])).as_matrix()
    pos = np.column_stack([5 * t, 2 * np.sin(t), 0.3 * np.cos(t)])
    gt = [np.block([[r, p[:, None]], [np.zeros((1, 3)), 1.0]]) for r, p in zip(R, pos)]
    Ra = Rotation.from_euler("z", 0.3).as_matrix()
    est = [np.block([[Ra @ g[:3, :3], (Ra @ g[:3, 3] + rng.normal(0, 0.2, 3) + [3, 1, 0])[:, None]],
                     [np.zeros((1, 3)), 1.0]]) for g in gt]
    ours = trajectory_errors(est, gt, align="se3")
    ate, rpe = evo_ate_rpe(est, gt, t)
    assert ours["ate_rmse_m"] == pytest.approx(ate, abs=1e-9)
    assert ours["rpe_rmse_m"] == pytest.approx(rpe, abs=1e-9)
