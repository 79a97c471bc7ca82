"""Re-weight a render's lighting passes toward the estimated illumination.

Cycles splits the object's light into passes: Combined = Dcol*(Ddir + Dind) +
Gcol*(Gdir + Gind) + (transmission, emission, ...), where "direct" is light from lamps *and
the world* after one bounce and "indirect" the rest. Direct/indirect therefore do not
separate sun from sky (that needs light groups); the sun/sky balance is set before
rendering, from the same estimate, through the lighting dict. After rendering we correct
what the render cannot know exactly: per-channel gains bring the chroma of the object's
light (direct + indirect, diffuse and glossy) to the illuminant measured in the real frame
(shades of grey), at unchanged luminance. Emission and transmission stay as rendered.

At night and dusk the light is local: street lamps and headlights make pools, and an object
on an unlit pavement is dark while one in a lamp's pool is bright. A uniform key lights every
object alike. `local_light_gain` reads the light where the object stands off the real road at
its foot (median luminance of a band under its contact line) against the frame's road median,
and `relight` scales the object's reflected light (not its lamps' emission) by it.
"""

from __future__ import annotations

import cv2
import numpy as np

from blendgen.post.colorspace import LUMA_BGR, finite, srgb_u8_to_linear
from blendgen.post.illumination import Illumination

LUMA_RGB = np.array([0.2126, 0.7152, 0.0722])
MAX_GAIN = 4.0
LOCAL_GAIN_RANGE = (0.35, 2.5)  # night light pools: the road under a lamp vs unlit pavement
LOCAL_GAIN_POWER = 0.5  # the road is lit from above, an object's sides less: half the road's contrast
NEEDED = ("diffuse_direct", "diffuse_indirect", "diffuse_color")


def local_light_gain(real_lin_y: np.ndarray, box: tuple[int, int, int, int], illumination: Illumination,
                     exclude=None) -> float | None:
    """Night/dusk: light at the object's foot relative to the frame's road, or None (daylight,
    a visible sun, or no road visible under the object). ``real_lin_y``: the real frame's
    linear luminance (HxW), or the frame itself (HxWx3 uint8 BGR: only the band is converted); ``box`` =
    (x0, y0, x1, y1) of the object's pixels; ``exclude``: pixels that are not road (objects,
    shadows), an HxW bool array or a function of the band's (rows, cols) slices."""
    if illumination.condition == "day" or illumination.sun_visible or illumination.ground_luminance <= 1e-5:
        return None  # by day, and under a low sun at dusk, the road's light and shade are the sun's
    H, W = real_lin_y.shape[:2]
    x0, y0, x1, y1 = box
    w, h = x1 - x0, y1 - y0
    band = (slice(max(0, y1), min(H, y1 + max(4, int(0.15 * h)))),
            slice(max(0, int(x0 - 0.5 * w)), min(W, int(x1 + 0.5 * w))))
    y = real_lin_y[band]
    if y.ndim == 3:
        y = srgb_u8_to_linear(y) @ LUMA_BGR
    if exclude is not None:
        y = y[~(exclude(band) if callable(exclude) else exclude[band])]
    if y.size < 16:
        return None
    g = (float(np.median(y)) / illumination.ground_luminance) ** LOCAL_GAIN_POWER
    return float(np.clip(g, *LOCAL_GAIN_RANGE))


def relight(rgb: np.ndarray, passes: dict, mask: np.ndarray, illumination: Illumination,
            local_gain: float | None = None) -> tuple[np.ndarray, dict]:
    """Return the re-weighted linear RGB (HxWx3, RGB order as in the EXR) and what was done.

    ``rgb`` is the render's (premultiplied) Combined colour, ``mask`` the object pixels
    (None: ``rgb`` and the passes are Nx3 lists of the object's pixels only).
    Passes that are missing or a mask with too few pixels leave ``rgb`` unchanged.
    """
    missing = [k for k in NEEDED if k not in passes]
    if missing:
        return rgb, {"relight": "skipped", "reason": f"missing passes {missing}"}
    if (len(rgb) if mask is None else mask.sum()) < 4:
        return rgb, {"relight": "skipped", "reason": "fewer than 4 object pixels"}
    # Work on the object's pixel list only.
    pick = (lambda a: np.asarray(a)) if mask is None else (lambda a: np.asarray(a)[mask])
    dd, di, dc = (_clean(pick(passes[k])) for k in NEEDED)
    gd, gi, gc = (_clean(pick(passes[k])) if k in passes else None
                  for k in ("glossy_direct", "glossy_indirect", "glossy_color"))
    # Column means with cv2.mean (double accumulators, one thread): a BLAS call here waits for
    # its worker threads on a loaded machine, numpy's strided column sums are slower still.
    D = np.array(cv2.mean(dd.reshape(-1, 1, 3))[:3])
    I = np.array(cv2.mean(di.reshape(-1, 1, 3))[:3])
    if float((D + I) @ LUMA_RGB) < 1e-6:
        return rgb, {"relight": "skipped", "reason": "object receives no light in the render"}
    target = np.asarray(illumination.illuminant_rgb, dtype=float)
    g = _gains(D + I, target).astype(np.float32)  # float32: a float64 gain would promote every pixel
    if local_gain is not None:
        g = g * np.float32(local_gain)
    gm1 = g - np.float32(1.0)
    # in place (the same products as dc * (gm1 * (dd + di)), bit for bit, fewer temporaries)
    delta = _scale_channels(np.add(dd, di), gm1)
    delta *= dc
    if gd is not None and gi is not None and gc is not None:
        gl = _scale_channels(np.add(gd, gi), gm1)
        gl *= gc
        delta += gl
    if mask is None:
        out = np.add(rgb, delta, dtype=np.float32) if rgb.dtype == np.float32 else rgb + delta
        out = np.maximum(out, 0.0, out=out)
    else:
        out = rgb.copy()
        out[mask] = np.maximum(rgb[mask] + delta, 0.0)
    rec = {"relight": "applied", "light_gain_rgb": [round(float(v), 4) for v in g]}
    if local_gain is not None:
        rec["local_light_gain"] = round(float(local_gain), 4)
    return out, rec


def _gains(rendered: np.ndarray, target_chroma: np.ndarray) -> np.ndarray:
    """Per-channel gains that give ``rendered`` light the target chroma at equal luminance."""
    r = np.maximum(rendered, 1e-6)
    lr = float(r @ LUMA_RGB)
    t = np.maximum(np.nan_to_num(target_chroma, nan=1.0), 1e-6)
    t = t / float(t @ LUMA_RGB)
    return np.clip(t / (r / lr), 1.0 / MAX_GAIN, MAX_GAIN)


def _scale_channels(x: np.ndarray, g: np.ndarray) -> np.ndarray:
    """x * g for (n, 3) float32 x and 3 gains, in place; OpenCV's per-channel scalar product
    (the same float32 products) is ~2x faster than numpy's 3-element broadcast."""
    if x.dtype != np.float32 or x.ndim != 2 or x.shape[1] != 3 or not x.flags.c_contiguous or len(x) == 0:
        x *= g
        return x
    v = x.reshape(-1, 1, 3)
    cv2.multiply(v, (float(g[0]), float(g[1]), float(g[2]), 0.0), dst=v)
    return x


def _clean(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float32)
    a = a[..., :3] if a.ndim == 2 and a.shape[1] >= 3 else np.repeat(a.reshape(-1, 1), 3, axis=1)
    return finite(a)
