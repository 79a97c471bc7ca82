"""From an OpenCV camera to what Blender can render, bpy-free.

Blender renders ideal pinhole images only. For a camera with lens distortion we render a
slightly wider pinhole "canvas" and remap it to the distorted image with OpenCV; the
render, its masks and every pass go through the same maps, so labels stay exact.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from blendgen.geometry import Camera, CV_TO_BLENDER

SENSOR_WIDTH_MM = 36.0


def blender_intrinsics(cam: Camera) -> dict:
    """Pinhole fx, fy, cx, cy (pixel centres at integers) -> Blender camera/render settings.

    Horizontal sensor fit: fx = lens / sensor_width * W. Shift is in units of the larger
    image side; Blender's principal point with zero shift is the image centre, which is
    pixel coordinate (W-1)/2. fy != fx is expressed through the pixel aspect ratio.
    """
    W, H = int(cam.width), int(cam.height)
    big = float(max(W, H))
    # Blender scales the vertical axis by aspect_y / aspect_x: fy = fx * aspect_x / aspect_y.
    aspect_x, aspect_y = (1.0, cam.fx / cam.fy) if cam.fx >= cam.fy else (cam.fy / cam.fx, 1.0)
    # With non-square pixels Blender fits the sensor to the larger *displayed* side.
    disp_w, disp_h = W * aspect_x, H * aspect_y
    if disp_w >= disp_h:
        fit, lens = "HORIZONTAL", cam.fx * SENSOR_WIDTH_MM / W
        shift_x = ((W - 1) / 2 - cam.cx) / W
        shift_y = (cam.cy - (H - 1) / 2) / W * (aspect_y / aspect_x)
    else:
        fit, lens = "VERTICAL", cam.fy * SENSOR_WIDTH_MM / H
        shift_x = ((W - 1) / 2 - cam.cx) / H * (aspect_x / aspect_y)
        shift_y = (cam.cy - (H - 1) / 2) / H
    del big
    return {"resolution": (W, H), "sensor_fit": fit, "sensor_width": SENSOR_WIDTH_MM,
            "sensor_height": SENSOR_WIDTH_MM, "lens": float(lens), "shift_x": float(shift_x),
            "shift_y": float(shift_y), "pixel_aspect": (float(aspect_x), float(aspect_y))}


def blender_matrix_world(T_world_cam) -> np.ndarray:
    """OpenCV pose (x right, y down, z forward) -> Blender camera matrix_world (looks down -z)."""
    T = np.array(T_world_cam, dtype=float)
    M = np.eye(4)
    M[:3, :3] = T[:3, :3] @ CV_TO_BLENDER
    M[:3, 3] = T[:3, 3]
    return M


@dataclass
class Canvas:
    """The pinhole image Blender renders, and how it maps onto the output camera's pixels."""

    output: Camera
    pinhole: Camera
    map_x: np.ndarray | None = field(default=None, repr=False)  # output pixel -> canvas x (float32)
    map_y: np.ndarray | None = field(default=None, repr=False)
    _fixed: dict = field(default_factory=dict, repr=False, compare=False)  # see _box_maps

    @property
    def remapped(self) -> bool:
        return self.map_x is not None

    def to_output(self, img: np.ndarray, *, nearest: bool = False, border: float = 0.0,
                  out_box=None, src_box=None) -> np.ndarray:
        """Canvas image -> output image (identity for an undistorted camera).

        `out_box` (x0, y0, x1, y1): compute only that box of the output (remap is per
        pixel: the same values as cropping the full result). `src_box`: `img` is only that
        box of the canvas and the canvas is `border` everywhere else; the result is the
        same as remapping the whole canvas (cv2.remap's fixed-point maps, shifted exactly).
        Both ignored without a remap.
        """
        if not self.remapped:
            return img
        import cv2

        interp = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
        if img.ndim == 3 and img.shape[2] > 4:  # cv2.remap handles at most 4 channels at once
            return np.stack([self.to_output(img[..., c], nearest=nearest, border=border, out_box=out_box,
                                            src_box=src_box) for c in range(img.shape[2])], axis=2)
        # One value per channel: a plain float would be (border, 0, 0, 0) for a colour image.
        bv = (float(border),) * 4
        if src_box is not None:
            m1, m2 = self._box_maps(nearest, tuple(src_box), out_box)
            return cv2.remap(img, m1, m2, interp, borderMode=cv2.BORDER_CONSTANT, borderValue=bv)
        mx, my = self.map_x, self.map_y
        if out_box is not None:
            x0, y0, x1, y1 = out_box
            mx, my = mx[y0:y1, x0:x1], my[y0:y1, x0:x1]
        return cv2.remap(img, mx, my, interp, borderMode=cv2.BORDER_CONSTANT, borderValue=bv)

    def _box_maps(self, nearest: bool, src_box, out_box):
        """The maps in cv2's own fixed-point form (CV_16SC2 source pixel + 1/32 px fraction
        index: what cv2.remap converts float maps to on every call, so it interpolates the
        same), restricted to `out_box` and shifted to `src_box`'s origin. Integer shifts are
        exact, which float maps minus an offset are not. Cached for the last boxes."""
        import cv2

        key = (nearest, src_box, None if out_box is None else tuple(out_box))
        if key in self._fixed:
            return self._fixed[key]
        base = self._fixed.get(nearest)
        if base is None:
            base = self._fixed[nearest] = cv2.convertMaps(self.map_x, self.map_y, cv2.CV_16SC2,
                                                          nninterpolation=nearest)
        xy, frac = base
        if out_box is not None:
            x0, y0, x1, y1 = out_box
            xy = xy[y0:y1, x0:x1]
            frac = None if nearest else frac[y0:y1, x0:x1]
        # int16 saturates far outside the canvas; clipping keeps those outside any box
        xy = np.clip(xy.astype(np.int32) - np.array(src_box[:2], np.int32), -32768, 32767).astype(np.int16)
        maps = (xy, None if nearest else np.ascontiguousarray(frac))
        for k in [k for k in self._fixed if isinstance(k, tuple) and k[0] == nearest]:
            del self._fixed[k]  # one frame's boxes at a time
        self._fixed[key] = maps
        return maps

    def region_to_output(self, region):
        """A canvas pixel box (x0, y0, x1, y1) -> the output box that samples from it."""
        if region is None or not self.remapped:
            return region
        x0, y0, x1, y1 = region
        inside = (self.map_x >= x0 - 1) & (self.map_x <= x1) & (self.map_y >= y0 - 1) & (self.map_y <= y1)
        ys, xs = np.nonzero(inside)
        if len(xs) == 0:
            return None
        return (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)


def make_canvas(cam: Camera, *, pad_px: int = 2, max_growth: float = 1.6) -> Canvas:
    """The canvas for `cam`: itself for an undistorted square-pixel camera, else a square-pixel
    pinhole covering its view (Blender 5 cannot write multilayer EXRs with a pixel aspect
    other than 1, so fx != fy is resampled like distortion).

    The canvas keeps the output's larger focal length (same detail at the centre) unless
    covering the distorted field of view would need more than `max_growth` times the output
    size per side; then the focal length shrinks to fit.
    """
    square = abs(cam.fx - cam.fy) <= 1e-9 * max(cam.fx, cam.fy)
    if not cam.distorted and square:
        return Canvas(cam, Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy))
    W, H = int(cam.width), int(cam.height)
    us, vs = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    if cam.distorted:
        xn = cam.normalized(np.stack([us.ravel(), vs.ravel()], axis=1), iterations=40).reshape(H, W, 2)
    else:
        xn = np.stack([(us - cam.cx) / cam.fx, (vs - cam.cy) / cam.fy], axis=2)
    # Extent of the view from the image border (the interior lies inside for sane lenses).
    border = np.concatenate([xn[0], xn[-1], xn[:, 0], xn[:, -1]])
    xmin, ymin = border.min(axis=0)
    xmax, ymax = border.max(axis=0)
    f = max(cam.fx, cam.fy)
    f *= min(1.0, max_growth * W / (f * (xmax - xmin)), max_growth * H / (f * (ymax - ymin)))
    cw = int(np.ceil(f * (xmax - xmin))) + 2 * pad_px + 1
    ch = int(np.ceil(f * (ymax - ymin))) + 2 * pad_px + 1
    cx, cy = pad_px - f * xmin, pad_px - f * ymin
    pin = Camera(cw, ch, f, f, cx, cy)
    map_x = (f * xn[..., 0] + cx).astype(np.float32)
    map_y = (f * xn[..., 1] + cy).astype(np.float32)
    return Canvas(cam, pin, map_x, map_y)
