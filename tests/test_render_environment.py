"""What glass and clear coat mirror: the environment map made from the real frame (bpy-free)."""

import numpy as np
import pytest

from blendgen.geometry import Camera, R_world_cam_from_ypr, make_pose
from blendgen.post.colorspace import srgb_u8_to_linear
from blendgen.render.environment import CLIPPED_GAIN, equirect_directions, plate_environment

CAM = Camera.from_hfov(320, 180, 70)
T = make_pose(R_world_cam_from_ypr(0.0), [0.0, 0.0, 1.5])  # looking along +x, level


def _texel(env, direction):
    """The map's texel nearest a world direction."""
    d = equirect_directions(env.shape[1], env.shape[0])
    return env[np.unravel_index(np.argmax(d @ np.asarray(direction, float)), env.shape[:2])]


def _frame():
    """Sky-blue top rows, a red left and a green right half in the middle, grey road below."""
    f = np.zeros((180, 320, 3), np.uint8)
    f[:60] = (200, 150, 90)
    f[60:120, :160] = (40, 40, 200)
    f[60:120, 160:] = (40, 200, 40)
    f[120:] = (90, 90, 90)
    return f


def test_directions_follow_blenders_equirectangular_layout():
    d = equirect_directions(8, 4)
    assert d.shape == (4, 8, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0)
    # column 0 is -x (azimuth pi), the middle column +x, a quarter of the way +y; the top row up
    assert d[1, 0, 0] < -0.9 * np.cos(np.pi / 8) and d[1, 4, 0] > 0 and d[1, 2, 1] > 0.9 * np.cos(np.pi / 8)
    assert (d[0, :, 2] > 0.9).all() and (d[-1, :, 2] < -0.9).all()


def test_ahead_behind_above_and_below():
    f = _frame()
    env = plate_environment(f, CAM, T)
    assert env.shape == (128, 256, 3) and env.dtype == np.float32 and np.isfinite(env).all()
    red, green = srgb_u8_to_linear(np.uint8([200, 40, 40])), srgb_u8_to_linear(np.uint8([40, 200, 40]))
    left, right = [1.0, 0.3, 0.0], [1.0, -0.3, 0.0]  # world +y is the camera's left
    np.testing.assert_allclose(_texel(env, left), red, atol=0.02)
    np.testing.assert_allclose(_texel(env, right), green, atol=0.02)
    # behind the camera: the view ahead mirrored about the image plane (left stays left)
    np.testing.assert_allclose(_texel(env, [-1.0, 0.3, 0.0]), red, atol=0.02)
    np.testing.assert_allclose(_texel(env, [-1.0, -0.3, 0.0]), green, atol=0.02)
    # the zenith is the top rows' mean (the sky), the nadir the bottom rows' (the road)
    np.testing.assert_allclose(_texel(env, [0, 0, 1]), srgb_u8_to_linear(np.uint8([90, 150, 200])), atol=0.01)
    np.testing.assert_allclose(_texel(env, [0, 0, -1]), srgb_u8_to_linear(np.uint8([90, 90, 90])), atol=0.01)
    # straight sideways, beyond the frame: the mean of the row at that height (red and green)
    np.testing.assert_allclose(_texel(env, [0, 1, 0]), (red + green) / 2, atol=0.02)


def test_the_hood_is_cut_off_and_a_clipped_sky_is_brighter():
    f = _frame()
    f[150:] = (0, 0, 255)  # our own red hood
    env = plate_environment(f, CAM, T, hood_top=150)
    assert env[..., 0].max() < 0.6 * srgb_u8_to_linear(np.uint8([255]))[0]  # no hood red anywhere
    f = _frame()
    f[:60] = 255
    env = plate_environment(f, CAM, T)
    np.testing.assert_allclose(_texel(env, [0, 0, 1]), CLIPPED_GAIN, rtol=0.01)


def test_pitched_camera_and_dark_or_one_pixel_frames():
    tilted = make_pose(R_world_cam_from_ypr(0.0, np.radians(-20.0)), [0.0, 0.0, 1.5])  # looking down
    env = plate_environment(_frame(), CAM, tilted)
    # looking 20 deg down, the horizon ahead is the frame's top third: sky-blue
    assert _texel(env, [1, 0, 0])[2] > _texel(env, [1, 0, 0])[0]
    assert not plate_environment(np.zeros((180, 320, 3), np.uint8), CAM, T).any()
    tiny = plate_environment(np.full((1, 1, 3), 128, np.uint8), Camera.from_hfov(1, 1, 60), T)
    np.testing.assert_allclose(tiny, srgb_u8_to_linear(np.uint8([128]))[0], atol=1e-6)


def test_bad_frame():
    with pytest.raises(ValueError, match="8-bit BGR"):
        plate_environment(np.zeros((10, 10), np.uint8), CAM, T)
