"""Composite rendered objects (EXR passes) into a real frame.

Per frame (pixels that are neither object nor shadow are never touched, bit for bit):
1. shadows: the real image (linear) times the shadow-catcher pass, on the shadow's pixels;
then on the crop around the objects and their background rings:
2. relight: re-weight the lighting passes toward the illumination estimate (relight.py);
3. colour transfer: each object's region toward the real background around it;
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
from blendgen.post.colorspace import (LUMA_BGR, finite, linear_to_srgb, linear_to_srgb_u8, srgb_to_linear,
                                      srgb_u8_to_linear)
from blendgen.post.illumination import Illumination
from blendgen.post.relight import local_light_gain, relight

# Full-strength transfer makes an object take the background's colours (a red car on grey
# asphalt turns grey). Default strengths (Post.color_strength = None), measured in
# benchmarks/bench_post.py (docs/post.md): a little after environment-light matching, which
# already gets the light right, more when the render used a default light.
STRENGTH_AFTER_ENV_LIGHT = 0.1
STRENGTH_WITHOUT_ENV_LIGHT = 0.3
RING_PX = 0.35  # background ring width, as a fraction of the object's box size
MIN_RING_PX = 6
SHADOW_EPS = 0.03  # (smoothed) shadow-catcher values below 1 - eps darken the background
CONTACT_FADE = 0.3  # soft shadows reach full strength this far into the patch (of its inradius)
HDR_MAX = 1e4  # clamp for +inf / absurd values in the EXR
LIGHT_PASSES = ("diffuse_direct", "diffuse_indirect", "diffuse_color", "glossy_direct", "glossy_indirect",
                "glossy_color")


def composite_frame(real_bgr: np.ndarray, passes: dict, *, settings: Post | None = None,
                    illumination: Illumination | None = None, seed: int = 0) -> tuple[np.ndarray, dict]:
    """Composite the render's objects into ``real_bgr`` (uint8 HxWx3). Returns (image, info)."""
    t0 = time.perf_counter()
    settings = settings or Post()
    _check_frame(real_bgr)
    H, W = real_bgr.shape[:2]
    rgba = _pass(passes, "rgba", (H, W), 4, required=True)
    info: dict = {"objects": [], "color_transfer": settings.color_transfer, "shadows": False,
                  "relight": None, "sensor": None, "notes": []}
    if "index" in passes:
        idx = _pass(passes, "index", (H, W), None)
        if idx.ndim == 3:
            idx = idx[..., 0]
        idx = np.rint(finite(idx.astype(np.float32))).astype(np.int32) if idx.dtype.kind == "f" else idx
    else:
        idx = (finite(rgba[..., 3]) > 0.5).astype(np.int32)
        info["notes"].append("no index pass: object mask from alpha > 0.5, one object id 1")
    obj_any = idx > 0
    shadowed, shadow, baseline = _shadow_mask(passes, (H, W)) if settings.shadows else (None, None, 1.0)
    has_shadow = shadowed is not None and shadowed.any()
    if not obj_any.any() and not has_shadow:
        info["timings_ms"] = {"total": round(1e3 * (time.perf_counter() - t0), 3)}
        info["notes"].append("no object or shadow pixels: frame unchanged")
        return real_bgr.copy(), info
    out = real_bgr.copy()  # pixels neither object nor shadow stay bit-identical

    # ---- shadows: the real image (linear) times the catcher, on the shadow's pixels only
    t1 = time.perf_counter()
    if has_shadow:
        sb = _bbox(shadowed, 2, H, W)
        m = shadowed[sb]
        sc = cv2.blur(finite(shadow[sb].astype(np.float32), 1.0), (3, 3))
        sc = sc.reshape(m.shape + (-1,))
        # Shadows only darken: the catcher's >1 values (bounce light, noise) are not added.
        mult = np.clip(sc[m][:, ::-1] / baseline, 0.0, 1.0)
        # the sky shadow under an object still blocks light at the catcher patch's edge: fade
        # it out toward the edge, or the patch's outline shows on the road (sun shadows end
        # a margin inside their patch, so the fade leaves them whole)
        mult = 1.0 - _edge_fade(finite(shadow[sb].astype(np.float32), 1.0))[m][:, None] * (1.0 - mult)
        region = out[sb]
        region[m] = linear_to_srgb_u8(srgb_u8_to_linear(region[m]) * mult)
        info.update(shadows=True, shadow_px=int(m.sum()), shadow_baseline=round(baseline, 4))

    # ---- objects: crop to them and their background rings (origin on the 8x8 JPEG grid)
    t2 = time.perf_counter()
    timings = {}
    if obj_any.any():
        timings = _composite_objects(out, real_bgr, passes, rgba, idx, obj_any, shadowed, settings, illumination,
                                     seed, info)
    t3 = time.perf_counter()
    info["timings_ms"] = {k: round(1e3 * v, 3) for k, v in {
        "prepare": t1 - t0, "shadows": t2 - t1, **timings, "objects": t3 - t2, "total": t3 - t0}.items()}
    return out, info


def _composite_objects(out, real_bgr, passes, rgba, idx, obj_any, shadowed, settings, illumination, seed,
                       info) -> dict:
    """Relight, colour-transfer, sensor-match and alpha-blend each object into ``out`` (in
    place), each on its own crop (box + background ring), so the cost follows object size."""
    H, W = real_bgr.shape[:2]
    t0 = time.perf_counter()
    ob = _bbox(obj_any, 1, H, W)
    ids_u16 = np.clip(idx[ob], 0, 65535).astype(np.uint16)
    # Anti-aliased rims (alpha > 0 next to an object) belong to the neighbouring object.
    owner = np.where(ids_u16 > 0, ids_u16, cv2.dilate(ids_u16, np.ones((3, 3), np.uint8)))
    env_lit = illumination is not None and settings.illumination != "off"
    strength = 0.0 if settings.color_transfer == "none" else settings.color_strength \
        if settings.color_strength is not None else \
        STRENGTH_AFTER_ENV_LIGHT if env_lit else STRENGTH_WITHOUT_ENV_LIGHT
    profile = sensor.measure(_centre_crop(real_bgr)) if settings.sensor_match else None
    if profile is not None:
        info["sensor"] = {"measured": {k: (round(v, 4) if isinstance(v, float) else v)
                                       for k, v in profile.to_dict().items()}, "applied": {}}
    real_y = None  # the real frame's linear luminance, for night local light (computed once)
    not_road = obj_any if shadowed is None else obj_any | shadowed
    tm = dict.fromkeys(("relight", "color_transfer", "sensor", "blend"), 0.0)
    tm["objects_prepare"] = time.perf_counter() - t0
    for oid in np.flatnonzero(np.bincount(ids_u16.ravel(), minlength=1)[1:]) + 1:  # ids present, O(N)
        own = owner == oid
        rows, cols = np.flatnonzero(own.any(axis=1)), np.flatnonzero(own.any(axis=0))
        ring_px = int(max(MIN_RING_PX, RING_PX * max(rows[-1] - rows[0] + 1, cols[-1] - cols[0] + 1)))
        # Crop = the object's box + its ring, origin on the 8x8 JPEG grid of the frame.
        y0 = max(0, (ob[0].start + rows[0] - ring_px) // 8 * 8)
        x0 = max(0, (ob[1].start + cols[0] - ring_px) // 8 * 8)
        y1 = min(H, ob[0].start + rows[-1] + 1 + ring_px)
        x1 = min(W, ob[1].start + cols[-1] + 1 + ring_px)
        crop = (slice(y0, y1), slice(x0, x1))
        o_c = idx[crop] == oid
        own_c = np.zeros(o_c.shape, bool)
        oy, ox = ob[0].start - y0, ob[1].start - x0  # owner (box ob) -> crop offset
        ys, xs = slice(max(0, oy), min(y1 - y0, oy + own.shape[0])), slice(max(0, ox), min(x1 - x0, ox + own.shape[1]))
        own_c[ys, xs] = own[ys.start - oy:ys.stop - oy, xs.start - ox:xs.stop - ox]
        alpha = np.clip(finite(rgba[crop][..., 3].astype(np.float32)), 0.0, 1.0)
        alpha[~own_c] = 0.0  # elsewhere alpha is another object's or the shadow catcher's
        alpha[o_c & (alpha < 1e-3)] = 1.0  # index says object but alpha is empty (e.g. NaN): trust index
        cov = alpha > 0
        cy, cx = np.nonzero(cov)
        flat = (cy + y0) * W + (cx + x0)  # np.take on flat indices: ~5x faster than a masked view
        rgb_px = np.clip(finite(_take(rgba, flat)[:, :3].astype(np.float32), 0.0, HDR_MAX), 0.0, HDR_MAX)
        rec = {"id": int(oid), "pixels": int(o_c.sum()), "crop_xywh": [int(x0), int(y0), int(x1 - x0), int(y1 - y0)]}

        # ---- relight (re-weight the lighting passes toward the estimate)
        t1 = time.perf_counter()
        if settings.relight and env_lit:
            sub = {k: _take(passes[k], flat) for k in LIGHT_PASSES
                   if k in passes and np.shape(passes[k])[:2] == (H, W)}
            local = None
            if illumination.condition != "day":  # night light pools: the light where it stands
                if real_y is None:
                    real_y = srgb_u8_to_linear(real_bgr) @ LUMA_BGR
                bx, by = ob[1].start, ob[0].start  # own's box, in frame pixels
                local = local_light_gain(real_y, (bx + int(cols[0]), by + int(rows[0]), bx + int(cols[-1]) + 1,
                                                  by + int(rows[-1]) + 1), illumination, exclude=not_road)
            rgb_px, rec["relight"] = relight(rgb_px, sub, (alpha[cov] > 0.5) & o_c[cov], illumination,
                                             local_gain=local)
        # Un-premultiply, then display-encode (HDR clips here, like the real camera's sensor).
        obj = np.zeros(alpha.shape + (3,), np.float32)
        obj[cov] = linear_to_srgb(rgb_px[:, ::-1] / alpha[cov][:, None])  # BGR, [0, 1]

        # ---- colour transfer against the real background around the object
        t2 = time.perf_counter()
        om = o_c & (alpha > 0.5)
        if strength > 0 and om.any():
            # Ring = background within ring_px of the object (distance transform: O(N) for any r).
            dist = cv2.distanceTransform((~om).astype(np.uint8), cv2.DIST_L2, 3)
            ring = (dist <= ring_px) & (idx[crop] == 0) & (alpha == 0)
            if shadowed is not None:
                ring &= ~shadowed[crop]
            if ring.sum() >= 4:
                s_pix = obj[om]
                mapped = transfer_pixels(s_pix, real_bgr[crop][ring].astype(np.float32) / 255.0,
                                         settings.color_transfer)
                obj[om] = np.clip(s_pix + strength * (mapped - s_pix), 0.0, 1.0)
                rec["transfer"] = {"method": settings.color_transfer, "strength": strength, "ring_px": int(ring.sum()),
                                   "mean_shift_bgr": [round(float(v), 4) for v in (obj[om] - s_pix).mean(0)]}
            else:
                rec["transfer"] = {"method": "none", "reason": "no visible background around the object"}

        # ---- sensor matching on the object pixels
        t3 = time.perf_counter()
        if profile is not None:
            obj, applied = sensor.apply(obj, alpha, profile, origin=(x0, y0), frame_size=(W, H),
                                        seed=seed * 65536 + int(oid))
            rec["sensor"] = applied
            info["sensor"]["applied"].update(applied)

        # ---- alpha blend in linear light over the (already shadowed) background
        t4 = time.perf_counter()
        out_c = out[crop]
        a = alpha[cov][:, None]
        out_c[cov] = linear_to_srgb_u8(a * srgb_to_linear(obj[cov]) + (1.0 - a) * srgb_u8_to_linear(out_c[cov]))
        t5 = time.perf_counter()
        for k, v in (("relight", t2 - t1), ("color_transfer", t3 - t2), ("sensor", t4 - t3), ("blend", t5 - t4)):
            tm[k] += v
        info["objects"].append(rec)
    if len(info["objects"]) == 1:  # keep the simple one-object view at the top level
        info["relight"] = info["objects"][0].get("relight")
    elif info["objects"]:
        info["relight"] = {"relight": "per object", "objects": [o.get("relight") for o in info["objects"]]}
    return tm


def apply_occluder(passes: dict, mask: np.ndarray) -> dict:
    """The passes with a real occluder in front of every virtual object (the ego hood):
    under `mask` (HxW bool) no object, no alpha and no shadow, so neither the composite
    nor the labels see what the occluder hides."""
    out = dict(passes)
    for name, empty in (("rgba", 0.0), ("index", 0), ("shadow_catcher", 1.0)):
        if name in out and np.shape(out[name])[:2] == mask.shape:
            a = np.array(out[name], copy=True)
            a[mask] = empty
            out[name] = a
    return out


def _take(a: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """Rows ``flat`` of an HxW(xC) image viewed as (H*W, C)."""
    a = np.asarray(a)
    return np.take(a.reshape(a.shape[0] * a.shape[1], -1), flat, axis=0)


def _shadow_mask(passes: dict, hw: tuple[int, int]):
    """(shadowed HxW bool, catcher HxWxC, baseline) or (None, None, 1.0) without the pass."""
    if "shadow_catcher" not in passes:
        return None, None, 1.0
    sc = _pass(passes, "shadow_catcher", hw, None)
    shadow = sc[..., :3] if sc.ndim == 3 else sc[..., None]
    # Grey level via cvtColor (~10x faster than a min over channels).
    grey = cv2.cvtColor(np.ascontiguousarray(shadow, dtype=np.float32), cv2.COLOR_BGR2GRAY) \
        if shadow.shape[2] == 3 else shadow[..., 0].astype(np.float32)
    grey = finite(grey, 1.0)
    # The catcher carries a small global bias (objects block a little sky everywhere, denoiser
    # bias): measured as the median of the open ground, it is divided out so that only real
    # shadows remain. Exact 1.0 is sky / no catcher and does not count.
    sample = grey[::4, ::4]
    sample = sample[(sample > 0.85) & (sample < 0.9995)]
    baseline = float(np.median(sample)) if sample.size > 64 else 1.0
    baseline = baseline if 0.9 <= baseline < 1.0 else 1.0
    # The pass is a ratio of two noisy estimates; shadows are smooth, so a small blur before
    # the threshold keeps real shadows and drops the noise.
    grey = cv2.blur(grey, (3, 3))
    return grey < baseline * (1.0 - SHADOW_EPS), shadow, baseline


def _edge_fade(catcher: np.ndarray) -> np.ndarray:
    """0 at the edge of each catcher patch (pixels != 1.0) rising to 1 at CONTACT_FADE of its
    inradius: a contact shadow's weight, so it fades into the road instead of stopping."""
    from scipy import ndimage

    covered = (catcher.reshape(catcher.shape[:2] + (-1,)) != 1.0).any(axis=2).astype(np.uint8)
    dist = cv2.distanceTransform(covered, cv2.DIST_L2, 3)
    n, labels = cv2.connectedComponents(covered, connectivity=8)
    inradius = np.zeros(n, np.float32)
    if n > 1:
        inradius[1:] = ndimage.maximum(dist, labels, np.arange(1, n))
    return np.clip(dist / np.maximum(CONTACT_FADE * inradius[labels], 1.0), 0.0, 1.0)


def _bbox(mask: np.ndarray, pad: int, H: int, W: int) -> tuple[slice, slice]:
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return (slice(max(0, rows[0] - pad), min(H, rows[-1] + 1 + pad)),
            slice(max(0, cols[0] - pad), min(W, cols[-1] + 1 + pad)))


def _centre_crop(img: np.ndarray, size: int = 384) -> np.ndarray:
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
