"""What glass and clear coat mirror: an environment map made from the real frame (bpy-free).

A uniform sky in glossy rays made every rear window one flat dark panel and every car's
paint plastic: real windows mirror the sky, the trees and the street around the car. The
real frame is what the camera saw of that surround, in the units the render lands in
(illumination.py: a render pixel equals the real camera's linear pixel), so the map is the
frame itself, turned into directions:
- in front of the camera each direction looks the frame up through the pinhole;
- what lies behind the camera (which mirrors face when they face the camera: a rear
  window) is the view ahead mirrored about the image plane: the street behind is
  another stretch of the same street;
- beyond the frame's border the nearest border pixel, fading into the mean of its row
  (sideways the street goes on: sky or canopy above, road below; a roof mirroring the
  zenith sees the top row's average, not a smeared row); the ego vehicle's hood is cut
  off first.
The map is in Blender's equirectangular layout for an Environment Texture node in world
axes: column j is the azimuth atan2(y, x) = 2 pi (0.5 - (j + 0.5) / W), row i from the top
the elevation pi / 2 - pi (i + 0.5) / H (measured with bpy 5.0.1: tests/test_render_environment.py).
"""

from __future__ import annotations

import cv2
import numpy as np

from blendgen.geometry import Camera
from blendgen.post.colorspace import srgb_u8_to_linear

MAP_SIZE = (256, 128)  # 1.4 deg a texel: a window of a car 10 m away mirrors a few texels
FADE_DEG = 25.0  # beyond the frame the border pixel fades into its row's mean over this angle
CLIPPED, CLIPPED_GAIN = 250, 3.0  # 8-bit level taken as clipped, and the radiance it stands for
BLUR_DEG = 1.5  # the frame at the map's resolution (a 1280-px frame has ~18 px per texel)


def equirect_directions(width: int, height: int) -> np.ndarray:
    """(height, width, 3) world unit directions of the map's texel centres (Blender's layout)."""
    az = 2 * np.pi * (0.5 - (np.arange(width) + 0.5) / width)
    el = np.pi / 2 - np.pi * (np.arange(height) + 0.5) / height
    ce = np.cos(el)[:, None]
    return np.stack([ce * np.cos(az)[None, :], ce * np.sin(az)[None, :],
                     np.broadcast_to(np.sin(el)[:, None], (height, width))], axis=-1)


def plate_environment(real_bgr: np.ndarray, camera: Camera, T_world_cam, *, hood_top: float | None = None,
                      size: tuple[int, int] = MAP_SIZE) -> np.ndarray:
    """The environment map (size[1], size[0], 3) float32 linear RGB, rows from the top, of an
    8-bit BGR frame seen by `camera` at pose `T_world_cam` (OpenCV axes, camera to world).
    `hood_top`: the image row where the ego vehicle's hood begins (None: no hood)."""
    real = np.asarray(real_bgr)
    if real.ndim != 3 or real.shape[2] != 3 or real.dtype != np.uint8:
        raise ValueError(f"expected an 8-bit BGR frame, got {real.shape} {real.dtype}")
    H, W = real.shape[:2]
    bottom = H if hood_top is None else int(np.clip(hood_top, 1, H))
    lin = srgb_u8_to_linear(real[:bottom, :, ::-1])  # RGB, linear: the render's units
    # A clipped pixel (a daylight sky) is brighter than the 8-bit frame says: real rear windows
    # that mirror it read ~0.3 linear at a Fresnel reflectance of ~0.1 (a sedan's on BDD day).
    lin[real[:bottom].max(axis=2) >= CLIPPED] *= CLIPPED_GAIN
    # Shrink and blur to the map's resolution first: sampling a full-size frame texel by texel
    # aliases. The small frame has two pixels per texel near the optical axis.
    scale = size[0] / (np.pi * camera.fx)
    small = cv2.resize(lin, (max(int(round(W * scale)), 8), max(int(round(bottom * scale)), 2)),
                       interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), np.radians(BLUR_DEG) * camera.fx * scale)
    sh, sw = small.shape[:2]

    R = np.asarray(T_world_cam, dtype=float)[:3, :3]
    d = equirect_directions(*size) @ R  # world direction -> camera axes (x right, y down, z ahead)
    d[..., 2] = np.abs(d[..., 2])  # behind the camera: the view ahead, mirrored
    z = np.maximum(d[..., 2], 1e-3)
    u = (camera.fx * d[..., 0] / z + camera.cx) * scale
    v = (camera.fy * d[..., 1] / z + camera.cy) * scale
    env = cv2.remap(small, np.clip(u, 0, sw - 1).astype(np.float32), np.clip(v, 0, sh - 1).astype(np.float32),
                    cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    # Outside the frame: fade into the mean of the frame's row at the direction's height (sideways
    # the street goes on: sky or canopy above, road below), by the angle beyond the border. Height
    # and azimuth as the camera would see them turned toward the direction (no pinhole blow-up).
    az = np.arctan2(d[..., 0], d[..., 2])
    el_tan = d[..., 1] / np.maximum(np.hypot(d[..., 0], d[..., 2]), 1e-6)
    v_row = np.clip((camera.fy * el_tan + camera.cy) * scale, 0, sh - 1).astype(np.float32)
    rows = small.mean(axis=1)  # (sh, 3)
    row_mean = cv2.remap(rows[:, None, :], np.zeros_like(v_row), v_row, cv2.INTER_LINEAR)
    out_az = np.maximum(az - np.arctan((W - 1 - camera.cx) / camera.fx), np.arctan(-camera.cx / camera.fx) - az)
    el = np.arctan(el_tan)  # downward positive, like image rows
    out_el = np.maximum(el - np.arctan((bottom - 1 - camera.cy) / camera.fy), np.arctan(-camera.cy / camera.fy) - el)
    w = np.clip(np.degrees(np.hypot(np.maximum(out_az, 0), np.maximum(out_el, 0))) / FADE_DEG, 0.0, 1.0)[..., None]
    return ((1 - w) * env + w * row_mean).astype(np.float32)
