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


def test_sea_horizon_and_its_elevation_under_a_known_camera():
    """A rendered horizon: bright sky over a darker, noisy sea with a foam streak below, seen by a
    camera pitched 2 deg down and rolled 1 deg. The line is found to a fraction of a pixel, and
    the true pose puts it on its horizontal plane; a pose 1 deg off in pitch reads 1 deg."""
    from blendgen import so3
    from blendgen.geometry import Camera
    from blendgen.sync.metrics import horizon_errors, sea_horizon

    cam = Camera.from_hfov(854, 480, 94.0)
    R_level = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # camera looks along +x
    R_wc = R_level @ so3.exp(np.radians([2.0, 0.0, 0.0])) @ so3.exp(np.radians([0.0, 0.0, 1.0]))
    up = R_wc.T @ np.array([0.0, 0.0, 1.0])
    v, u = np.mgrid[0:480, 0:854]
    rays = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u, float)], axis=-1)
    sky = rays @ up > 0
    rng = np.random.default_rng(0)
    img = np.where(sky, 180.0, 110.0) + rng.normal(0, 3, sky.shape)
    img[300:304, 60:120] = 200.0  # a foam streak below the horizon, brighter than the sky
    img = np.clip(img, 0, 255).astype(np.uint8)

    def pose(R):
        return np.block([[R, np.zeros((3, 1))], [np.zeros((1, 3)), 1.0]])

    h = sea_horizon(img, (10, 240), (150, 330))
    assert h is not None
    # the detected points lie on the true horizon: their rays are horizontal within 0.1 deg
    e = horizon_errors({0: h}, {0: pose(R_wc)}, cam)
    assert np.all(np.abs(e) < 0.1)
    # heading does not move the horizon; a 1 deg pitch error moves it by 1 deg near the centre
    turned = so3.exp(np.radians([0.0, 0.0, 30.0])) @ R_wc
    assert np.allclose(horizon_errors({0: h}, {0: pose(turned)}, cam), e, atol=1e-9)
    hc = sea_horizon(img, (377, 477), (150, 330))
    e0 = horizon_errors({0: hc}, {0: pose(R_wc)}, cam, half_span_px=40.0)
    e1 = horizon_errors({0: hc}, {0: pose(R_wc @ so3.exp(np.radians([1.0, 0.0, 0.0])))}, cam, half_span_px=40.0)
    assert np.all(np.abs(e0) < 0.1) and np.allclose(np.abs(e1 - e0), 1.0, atol=0.02)
    assert sea_horizon(np.full((480, 854), 128, np.uint8), (10, 240), (150, 330)) is None  # no horizon
