"""Evaluation metrics of the sync (bpy-free)."""

import numpy as np
import pytest

from blendgen.sync.metrics import fix_offset


def _straight_drive(latency, along, across, heading_deg=87.5, seed=0):
    """A straight 60 s drive (speed 12 -> 19 -> 15 m/s) and 10 Hz fixes stamped `latency` late,
    offset `along` / `across` (left +) from the track, with 0.2 m noise."""
    t = np.arange(0.0, 60.0, 0.01)
    speed = 15.5 + 3.5 * np.sin(2 * np.pi * t / 60.0)
    s = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t))])
    h = np.radians(heading_deg)
    fwd, left = np.array([np.cos(h), np.sin(h)]), np.array([-np.sin(h), np.cos(h)])
    gt = np.zeros((len(t), 8))
    gt[:, 0], gt[:, 1:3], gt[:, 4] = t, s[:, None] * fwd, 1.0
    tf = np.arange(1.0, 59.0, 0.1)
    xy = np.column_stack([np.interp(tf - latency, t, gt[:, j]) for j in (1, 2)]) + along * fwd + across * left
    xy += np.random.default_rng(seed).normal(0.0, 0.2, xy.shape)
    return tf, xy, gt


def test_fix_offset_splits_a_constant_offset_from_a_latency():
    tf, xy, gt = _straight_drive(0.07, -0.35, 0.39)
    at_true = fix_offset(tf, xy, gt, 0.07)
    assert at_true["along_m"] == pytest.approx(-0.35, abs=0.03)
    assert at_true["across_m"] == pytest.approx(0.39, abs=0.03)
    assert at_true["floor_m"] == pytest.approx(np.hypot(0.35, 0.39), abs=0.03)
    assert at_true["heading_span_deg"] < 0.1
    # taken at their stamps: the along-track error grows with speed, the regression finds both
    stamped = fix_offset(tf, xy, gt, 0.0)
    assert stamped["regressed_latency_s"] == pytest.approx(0.07, abs=0.01)
    assert stamped["regressed_along_offset_m"] == pytest.approx(-0.35, abs=0.1)
    assert stamped["across_m"] == pytest.approx(0.39, abs=0.03)  # across the track latency does nothing
    assert stamped["floor_m"] > 1.0
