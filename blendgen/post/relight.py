"""Re-weight a render's lighting passes toward the estimated illumination.

Cycles splits the object's light into passes: Combined = Dcol*(Ddir + Dind) +
Gcol*(Gdir + Gind) + (transmission, emission, ...). Direct light is the sun, indirect the
sky and bounces. After rendering we change only those terms:
- sun/sky balance: when the estimate says the sun is hidden (overcast, dusk) but the render
  had a sun, the direct term is removed and the indirect term scaled up so the object keeps
  its brightness (soft, shadowless shading instead of hard sun shading);
- colour: per-channel gains bring the chroma of the object's direct light to the estimated
  sun colour and of its indirect light to the estimated sky colour.
Everything else in Combined (emission, transmission) is kept as rendered.
"""

from __future__ import annotations

import numpy as np

from blendgen.post.illumination import Illumination

LUMA_RGB = np.array([0.2126, 0.7152, 0.0722])
MAX_GAIN = 4.0
NEEDED = ("diffuse_direct", "diffuse_indirect", "diffuse_color")


def relight(rgb: np.ndarray, passes: dict, mask: np.ndarray, illumination: Illumination) -> tuple[np.ndarray, dict]:
    """Return the re-weighted linear RGB (HxWx3, RGB order as in the EXR) and what was done.

    ``rgb`` is the render's (premultiplied) Combined colour, ``mask`` the object pixels.
    Passes that are missing or a mask with too few pixels leave ``rgb`` unchanged.
    """
    missing = [k for k in NEEDED if k not in passes]
    if missing:
        return rgb, {"relight": "skipped", "reason": f"missing passes {missing}"}
    if mask.sum() < 4:
        return rgb, {"relight": "skipped", "reason": "fewer than 4 object pixels"}
    # Work on the object's pixel list only.
    dd, di, dc = (_clean(np.asarray(passes[k])[mask]) for k in NEEDED)
    gd, gi, gc = (_clean(np.asarray(passes[k])[mask]) if k in passes else None
                  for k in ("glossy_direct", "glossy_indirect", "glossy_color"))
    D = dd.mean(0).astype(np.float64)
    I = di.mean(0).astype(np.float64)
    lum_d, lum_i = float(D @ LUMA_RGB), float(I @ LUMA_RGB)
    if lum_d + lum_i < 1e-6:
        return rgb, {"relight": "skipped", "reason": "object receives no light in the render"}
    light = illumination.to_lighting()
    rendered_sun_share = lum_d / (lum_d + lum_i)
    w_d, w_i = 1.0, 1.0
    if not light["sun_visible"] and rendered_sun_share > 0.1 and lum_i > 1e-6:
        w_d, w_i = 0.0, min((lum_d + lum_i) / lum_i, 10.0)
    g_d = _gains(D, np.asarray(light["sun_color"])) * w_d
    g_i = _gains(I, np.asarray(light["sky_color"])) * w_i
    delta = dc * ((g_d - 1.0) * dd + (g_i - 1.0) * di)
    if gd is not None and gi is not None and gc is not None:
        delta += gc * ((g_d - 1.0) * gd + (g_i - 1.0) * gi)
    out = rgb.copy()
    out[mask] = np.maximum(rgb[mask] + delta, 0.0)
    return out, {"relight": "applied", "rendered_sun_share": round(rendered_sun_share, 4),
                 "direct_gain_rgb": [round(float(v), 4) for v in g_d],
                 "indirect_gain_rgb": [round(float(v), 4) for v in g_i]}


def _gains(rendered: np.ndarray, target_chroma: np.ndarray) -> np.ndarray:
    """Per-channel gains that give ``rendered`` light the target chroma at equal luminance."""
    r = np.maximum(rendered, 1e-6)
    lr = float(r @ LUMA_RGB)
    t = np.maximum(np.nan_to_num(target_chroma, nan=1.0), 1e-6)
    t = t / float(t @ LUMA_RGB)
    return np.clip(t / (r / lr), 1.0 / MAX_GAIN, MAX_GAIN)


def _clean(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float32)
    a = a[..., :3] if a.ndim == 2 and a.shape[1] >= 3 else np.repeat(a.reshape(-1, 1), 3, axis=1)
    return np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0)
