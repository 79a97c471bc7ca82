"""Composite rendered objects (EXR passes) into a real frame.

Per frame, on the crop that holds the objects and their shadows (the rest of the frame is
never touched):
1. relight: re-weight the lighting passes toward the illumination estimate (relight.py);
2. colour transfer: each object's region toward the real background around it;
3. shadows: the real image (linear) times the shadow-catcher pass;
4. sensor matching: blur, vignetting, noise, JPEG measured in the real frame (sensor.py);
5. I = a * I_V + (1 - a) * I_R in linear light, with a the render's alpha (anti-aliased
   edges) restricted to the object pixels of the index pass, so that shadow-catcher alpha
   never counts as object. Labels come from the index pass alone: shadows never enter them.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from blendgen.errors import UserError
from blendgen.job.schema import Post
from blendgen.post import sensor
from blendgen.post.color_transfer import transfer_pixels
from blendgen.post.colorspace import linear_to_srgb, srgb_to_linear, srgb_u8_to_linear, to_u8
from blendgen.post.illumination import Illumination
from blendgen.post.relight import relight

# Full-strength transfer makes an object take the background's colours (a red car on grey
# asphalt turns grey); half strength moves it toward the scene's light and keeps its albedo.
# Measured in benchmarks/bench_post.py (see docs/post.md).
TRANSFER_STRENGTH = {"reinhard": 0.5, "mkl": 0.5, "histogram": 0.5, "none": 0.0}
RING_PX = 0.35  # background ring width, as a fraction of the object's box size
MIN_RING_PX = 6
SHADOW_EPS = 0.03  # (smoothed) shadow-catcher values below 1 - eps darken the background
SHADOW_SMOOTH_PX = 1.0
HDR_MAX = 1e4  # clamp for +inf / absurd values in the EXR


def composite_frame(real_bgr: np.ndarray, passes: dict, *, settings: Post | None = None,
                    illumination: Illumination | None = None, seed: int = 0) -> tuple[np.ndarray, dict]:
    """Composite the render's objects into ``real_bgr`` (uint8 HxWx3). Returns (image, info)."""
    t0 = time.perf_counter()
    settings = settings or Post()
    _check_frame(real_bgr)
    H, W = real_bgr.shape[:2]
    rgba = _pass(passes, "rgba", (H, W), 4, required=True)
    if "index" in passes:
        idx = _pass(passes, "index", (H, W), None)
        idx = np.rint(np.nan_to_num(idx.astype(np.float64), nan=0.0)).astype(np.int32) if idx.dtype.kind == "f" else idx.astype(np.int32)
        if idx.ndim == 3:
            idx = idx[..., 0]
    else:
        idx = (np.nan_to_num(rgba[..., 3], nan=0.0) > 0.5).astype(np.int32)
    info: dict = {"objects": [], "color_transfer": settings.color_transfer, "shadows": False,
                  "relight": None, "sensor": None, "notes": []}
    if "index" not in passes:
        info["notes"].append("no index pass: object mask from alpha > 0.5, one object id 1")

    shadow = None
    if settings.shadows and "shadow_catcher" in passes:
        sc = _pass(passes, "shadow_catcher", (H, W), None)
        shadow = sc[..., :3] if sc.ndim == 3 else sc[..., None]
    obj_any = idx > 0
    # Shadow pixels from the catcher's grey level (cvtColor: ~10x faster than a min over
    # channels); NaN compares False, so a NaN catcher pixel is "no shadow".
    if shadow is not None:
        grey = cv2.cvtColor(np.ascontiguousarray(shadow, dtype=np.float32), cv2.COLOR_BGR2GRAY) \
            if shadow.shape[2] == 3 else shadow[..., 0].astype(np.float32)
        # The catcher pass is a ratio of two noisy estimates: at low sample counts the whole
        # ground flickers around 1. Shadows are smooth, so a small blur before the threshold
        # keeps real shadows and drops the noise.
        grey = cv2.GaussianBlur(np.nan_to_num(grey, nan=1.0), (0, 0), SHADOW_SMOOTH_PX)
        shadowed = grey < 1.0 - SHADOW_EPS
    else:
        shadowed = np.zeros((H, W), bool)
    if not obj_any.any() and not shadowed.any():
        info["timings_ms"] = {"total": round(1e3 * (time.perf_counter() - t0), 3)}
        info["notes"].append("no object or shadow pixels: frame unchanged")
        return real_bgr.copy(), info

    # ---- crop to the objects, their background rings and shadows (origin on the 8x8 grid)
    anyp = obj_any | shadowed
    ys, xs = np.flatnonzero(anyp.any(axis=1)), np.flatnonzero(anyp.any(axis=0))
    y0, y1, x0, x1 = ys[0], ys[-1] + 1, xs[0], xs[-1] + 1
    m = int(max(MIN_RING_PX, RING_PX * max(y1 - y0, x1 - x0))) + 2
    y0, x0 = max(0, (y0 - m) // 8 * 8), max(0, (x0 - m) // 8 * 8)
    y1, x1 = min(H, y1 + m), min(W, x1 + m)
    crop = (slice(y0, y1), slice(x0, x1))
    real_c = real_bgr[crop]
    idx_c, obj_c = idx[crop], obj_any[crop]
    rgba_c = rgba[crop].astype(np.float32)  # a copy: cleaned in place
    np.nan_to_num(rgba_c, copy=False, nan=0.0, posinf=HDR_MAX, neginf=0.0)
    np.clip(rgba_c, 0.0, HDR_MAX, out=rgba_c)
    # Object alpha: the render's coverage on and right next to object pixels (anti-aliased
    # rims); elsewhere alpha belongs to the shadow catcher and is handled as a shadow.
    near = cv2.dilate(obj_c.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    alpha = np.where(near, np.clip(rgba_c[..., 3], 0.0, 1.0), 0.0).astype(np.float32)
    alpha[obj_c & (alpha < 1e-3)] = 1.0  # index says object but alpha is empty (e.g. NaN): trust index
    rgb = rgba_c[..., :3]  # RGB order, premultiplied, linear

    # ---- 1. relight
    t1 = time.perf_counter()
    if settings.relight and illumination is not None and settings.illumination != "off":
        sub = {k: v[crop] for k, v in passes.items() if k in ("diffuse_direct", "diffuse_indirect", "diffuse_color",
                                                              "glossy_direct", "glossy_indirect", "glossy_color")}
        rgb, info["relight"] = relight(rgb, sub, obj_c & (alpha > 0.5), illumination)
    # Un-premultiply, then display-encode (HDR clips here, like the real camera's sensor).
    obj_srgb = np.zeros(rgb.shape, np.float32)
    cov = alpha > 0
    obj_srgb[cov] = linear_to_srgb(rgb[cov][:, ::-1] / alpha[cov][:, None])  # BGR, [0, 1]

    # ---- 2. colour transfer, per object against the real background around it
    t2 = time.perf_counter()
    real_f = real_c.astype(np.float32) / 255.0
    strength = TRANSFER_STRENGTH[settings.color_transfer]
    for oid in np.unique(idx_c[obj_c]):
        om = (idx_c == oid) & (alpha > 0.5)
        rec = {"id": int(oid), "pixels": int(om.sum())}
        if strength > 0 and om.any():
            oy, ox = np.nonzero(om)
            r = int(max(MIN_RING_PX, RING_PX * max(oy.ptp() + 1, ox.ptp() + 1)))
            # Ring = background within r px of the object (distance transform: O(N) for any r).
            dist = cv2.distanceTransform((~om).astype(np.uint8), cv2.DIST_L2, 3)
            ring = (dist <= r) & ~near & ~shadowed[crop]
            if ring.sum() >= 4:
                s_pix = obj_srgb[om]
                mapped = transfer_pixels(s_pix, real_f[ring], settings.color_transfer)
                obj_srgb[om] = np.clip(s_pix + strength * (mapped - s_pix), 0.0, 1.0)
                rec["transfer"] = {"method": settings.color_transfer, "strength": strength, "ring_px": int(ring.sum()),
                                   "mean_shift_bgr": [round(float(v), 4) for v in (obj_srgb[om] - s_pix).mean(0)]}
            else:
                rec["transfer"] = {"method": "none", "reason": "no visible background around the object"}
        info["objects"].append(rec)

    # ---- 3. shadows on the real image, in linear light
    t3 = time.perf_counter()
    sh_c = shadowed[crop]
    touched = (alpha > 0) | sh_c
    bg_lin = srgb_u8_to_linear(real_c[touched])  # pixel list: only touched pixels change
    if shadow is not None and sh_c.any():
        sc_c = np.nan_to_num(shadow[crop].astype(np.float32), nan=1.0, posinf=1.0, neginf=1.0)
        sc_c = cv2.GaussianBlur(sc_c, (0, 0), SHADOW_SMOOTH_PX).reshape(sc_c.shape)
        # Shadows only darken: the catcher's >1 values (bounce light, noise) are not added.
        mult = np.clip(sc_c[touched][:, ::-1], 0.0, 1.0)
        bg_lin = bg_lin * mult
        info["shadows"] = True
        info["shadow_px"] = int(shadowed.sum())

    # ---- 4. sensor matching on the object pixels
    t4 = time.perf_counter()
    if settings.sensor_match and obj_c.any():
        profile = sensor.measure(_centre_crop(real_bgr))
        obj_srgb, applied = sensor.apply(obj_srgb, alpha, profile, origin=(x0, y0), frame_size=(W, H), seed=seed)
        info["sensor"] = {"measured": {k: (round(v, 4) if isinstance(v, float) else v)
                                       for k, v in profile.to_dict().items()}, "applied": applied}

    # ---- 5. alpha composite in linear light
    t5 = time.perf_counter()
    a = alpha[touched][:, None]
    out_lin = a * srgb_to_linear(obj_srgb[touched]) + (1.0 - a) * bg_lin
    out = real_bgr.copy()  # untouched pixels stay bit-identical
    out_c = out[crop]
    out_c[touched] = to_u8(linear_to_srgb(out_lin))
    t6 = time.perf_counter()
    info["crop_xywh"] = [int(x0), int(y0), int(x1 - x0), int(y1 - y0)]
    info["timings_ms"] = {k: round(1e3 * v, 3) for k, v in {
        "prepare": t1 - t0, "relight": t2 - t1, "color_transfer": t3 - t2, "shadows": t4 - t3,
        "sensor": t5 - t4, "blend": t6 - t5, "total": t6 - t0}.items()}
    return out, info


def _centre_crop(img: np.ndarray, size: int = 512) -> np.ndarray:
    """A central crop on the 8x8 grid: sensor statistics are global, this keeps them fast."""
    h, w = img.shape[:2]
    ch, cw = min(h, size) // 8 * 8 or h, min(w, size) // 8 * 8 or w
    y0, x0 = (h - ch) // 2 // 8 * 8, (w - cw) // 2 // 8 * 8
    return img[y0:y0 + ch, x0:x0 + cw]


def _check_frame(real_bgr) -> None:
    if not isinstance(real_bgr, np.ndarray) or real_bgr.dtype != np.uint8 or real_bgr.ndim != 3 \
            or real_bgr.shape[2] != 3:
        raise UserError(f"expected the real frame as HxWx3 uint8 BGR, got {getattr(real_bgr, 'dtype', None)} "
                        f"{getattr(real_bgr, 'shape', None)}", where="composite_frame real_bgr")


def _pass(passes: dict, name: str, hw: tuple[int, int], channels: int | None, required: bool = False) -> np.ndarray:
    if name not in passes:
        if required:
            raise UserError(f"render pass {name!r} is missing (got {sorted(passes)})", where="composite_frame passes")
        return None
    a = np.asarray(passes[name])
    if a.shape[:2] != hw or (channels is not None and (a.ndim != 3 or a.shape[2] < channels)):
        want = f"{hw[0]}x{hw[1]}" + (f"x{channels}" if channels else "")
        raise UserError(f"render pass {name!r} has shape {a.shape}, expected {want} (the real frame's size)",
                        where="composite_frame passes")
    return a
