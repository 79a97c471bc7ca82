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
from scipy import ndimage

from blendgen.errors import UserError
from blendgen.job.schema import Post
from blendgen.post import sensor
from blendgen.post.color_transfer import transfer_pixels
from blendgen.post.colorspace import (finite, linear_to_srgb, linear_to_srgb_u8, srgb_to_linear,
                                      srgb_u8_to_linear)
from blendgen.post.illumination import Illumination
from blendgen.post.relight import local_light_gain, relight

# Full-strength transfer makes an object take the background's colours (a red car on grey
# asphalt turns grey). Default strengths (Post.color_strength = None), measured in
# benchmarks/post/bench_post.py (docs/post.md): a little after environment-light matching, which
# already gets the light right, more when the render used a default light.
STRENGTH_AFTER_ENV_LIGHT = 0.1
STRENGTH_WITHOUT_ENV_LIGHT = 0.3
RING_PX = 0.35  # background ring width, as a fraction of the object's box size
MIN_RING_PX = 6
# a patch's border keeps 0.77-0.9 of a soft sky shadow on the real photos; darker there is a
# shadow its patch cuts off, which is not divided out
FLOOR_MIN = 0.75
SHADOW_EPS = 0.03  # (smoothed) shadow-catcher values below 1 - eps darken the background
HDR_MAX = 1e4  # clamp for +inf / absurd values in the EXR
WINDOW_PAD = 16  # px around objects and catcher patches: > every neighbourhood a step reads
WINDOW_GRID = 16  # window origin on this grid (a multiple of the 8x8 JPEG and 4-px sample grids)
ONE_F32_BITS = np.uint32(0x3F800000)  # 1.0f: the shadow catcher's value where nothing is caught
SENSOR_MARGIN = 16  # px around an object: the widest sensor blur (sigma 2.2) reads 9
LIGHT_PASSES = ("diffuse_direct", "diffuse_indirect", "diffuse_color", "glossy_direct", "glossy_indirect",
                "glossy_color")


def composite_frame(real_bgr: np.ndarray, passes: dict, *, settings: Post | None = None,
                    illumination: Illumination | None = None, seed: int = 0,
                    crop: bool = True, sensor_profile: sensor.SensorProfile | None = None) -> tuple[np.ndarray, dict]:
    """Composite the render's objects into ``real_bgr`` (uint8 HxWx3). Returns (image, info).

    All per-pixel work runs on one window: the union of the object pixels and the shadow
    catcher's patches, padded by WINDOW_PAD and aligned to a WINDOW_GRID-px grid; the rest of
    the frame is the real frame, copied. ``crop=False`` makes the window the whole frame (the
    reference the crop is tested against: the results agree to < 0.5 level). ``sensor_profile``:
    the camera's (sensor.SensorCache in a recording); None measures this frame."""
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
    catcher = _pass(passes, "shadow_catcher", (H, W), None) if settings.shadows else None
    win = _work_window(idx, catcher, H, W) if crop else (0, 0, W, H)
    if win is None:
        return _unchanged(real_bgr, info, t0)
    wx0, wy0, wx1, wy1 = win
    R = (slice(wy0, wy1), slice(wx0, wx1))
    info["window_xywh"] = [int(wx0), int(wy0), int(wx1 - wx0), int(wy1 - wy0)]
    shadowed, shadow, grey, baseline = _shadow_mask(catcher, win) if catcher is not None else (None,) * 3 + (1.0,)
    obj_any = idx[R] > 0
    has_shadow = shadowed is not None and shadowed.any()
    if not obj_any.any() and not has_shadow:
        return _unchanged(real_bgr, info, t0)
    out = real_bgr.copy()  # pixels neither object nor shadow stay bit-identical

    # ---- shadows: the real image (linear) times the catcher, on the shadow's pixels only
    t1 = time.perf_counter()
    if has_shadow:
        sb = _bbox(shadowed, 2, wy1 - wy0, wx1 - wx0)  # within the window
        m = shadowed[sb]
        sc = cv2.blur(grey[sb], (3, 3))
        # A shadow is the road's own colour darkened: the catcher's grey level (its colour is
        # the render's sky light, bluish under a clear sky, where a real photo's shadows are
        # greyer), in the tint of the frame's own sun shadows when the estimate measured one.
        # Shadows only darken: the catcher's >1 values (bounce light, noise) are not added.
        mult = _rep3(sc[m])
        tint = getattr(illumination, "shadow_tint_rgb", None) if illumination is not None else None
        if tint is not None:
            mult = _shade_tint(mult, np.asarray(tint, np.float32)[::-1])
        mult /= baseline
        np.clip(mult, 0.0, 1.0, out=mult)
        # the sky shadow under an object still blocks light at the catcher patch's edge:
        # divided by the patch's value there, it ends at 1, or the patch's outline shows on
        # the road (sun shadows end a margin inside their patch, their floor is ~1). The
        # window holds whole patches, so the floor is the same as on the full frame.
        my, mx = np.nonzero(m)
        my, mx = my + sb[0].start, mx + sb[1].start  # window coordinates
        floor = np.maximum(_patch_floor(shadow, grey, idx[R], (my, mx)) / baseline, FLOOR_MIN)
        mult = np.clip(mult / _rep3(floor), 0.0, 1.0)
        flat = (my + wy0) * W + (mx + wx0)  # flat frame indices: gathers ~5x faster than masks
        out2 = out.reshape(-1, 3)
        _put(out2, flat, linear_to_srgb_u8(srgb_u8_to_linear(np.take(out2, flat, axis=0)) * mult))
        info.update(shadows=True, shadow_px=int(m.sum()), shadow_baseline=round(baseline, 4))

    # ---- objects: crop to them and their background rings (origin on the 8x8 JPEG grid)
    t2 = time.perf_counter()
    timings = {}
    if obj_any.any():
        timings = _composite_objects(out, real_bgr, passes, rgba, idx, win, obj_any, shadowed, settings,
                                     illumination, seed, info, sensor_profile)
    t3 = time.perf_counter()
    info["timings_ms"] = {k: round(1e3 * v, 3) for k, v in {
        "prepare": t1 - t0, "shadows": t2 - t1, **timings, "objects": t3 - t2, "total": t3 - t0}.items()}
    return out, info


def _shade_tint(mult: np.ndarray, tint_bgr: np.ndarray) -> np.ndarray:
    """Grey shadow factors (n, 3) in the tint of the frame's real shadows: full tint where
    the shadow is deep (factor <= 1 / ratio of a sun shadow), none where it fades to 1."""
    depth = np.clip((1.0 - mult) / 0.5, 0.0, 1.0)  # 0 at no shadow, 1 from a factor of 0.5 down
    return mult * (1.0 + depth * (tint_bgr[None, :] - 1.0))


def _unchanged(real_bgr, info, t0):
    info["timings_ms"] = {"total": round(1e3 * (time.perf_counter() - t0), 3)}
    info["notes"].append("no object or shadow pixels: frame unchanged")
    return real_bgr.copy(), info


def _work_window(idx: np.ndarray, catcher: np.ndarray | None, H: int, W: int):
    """(x0, y0, x1, y1) around every object pixel (+1 px of anti-aliased rim) and every
    catcher pixel that is not exactly 1 (outside the rendered region the catcher is 1), padded
    and aligned to the WINDOW_GRID; None when there is neither."""
    boxes = []
    nz = cv2.compare(idx, 0, cv2.CMP_NE) if idx.dtype == np.int32 else (idx != 0).view(np.uint8)
    x, y, w, h = cv2.boundingRect(nz)
    if w > 0:
        boxes.append((x - 1, y - 1, x + w + 1, y + h + 1))
    if catcher is not None:
        # "!= 1.0" on the float bits of all channels at once: one pass, no float temporaries.
        c = np.ascontiguousarray(catcher, dtype=np.float32)
        nc = c.shape[2] if c.ndim == 3 else 1
        x, y, w, h = cv2.boundingRect((c.view(np.uint32) != ONE_F32_BITS).view(np.uint8).reshape(H, W * nc))
        if w > 0:
            boxes.append((x // nc, y, (x + w - 1) // nc + 1, y + h))
    if not boxes:
        return None
    b = np.array(boxes)
    g = WINDOW_GRID
    x0, y0 = (max(0, v - WINDOW_PAD) // g * g for v in b[:, :2].min(axis=0))
    x1, y1 = (min(lim, -(-(v + WINDOW_PAD) // g) * g) for v, lim in zip(b[:, 2:].max(axis=0), (W, H)))
    return int(x0), int(y0), int(x1), int(y1)


def _composite_objects(out, real_bgr, passes, rgba, idx, win, obj_any, shadowed, settings, illumination, seed,
                       info, sensor_profile) -> dict:
    """Relight, colour-transfer, sensor-match and alpha-blend each object into ``out`` (in
    place), each on its own crop (box + background ring), so the cost follows object size.
    ``obj_any`` and ``shadowed`` are the window's; outside it there is neither."""
    H, W = real_bgr.shape[:2]
    t0 = time.perf_counter()
    wx0, wy0, wx1, wy1 = win
    ids_w = idx[wy0:wy1, wx0:wx1]
    lo, hi = cv2.minMaxLoc(ids_w)[:2] if ids_w.dtype == np.int32 else (ids_w.min(), ids_w.max())
    # ids already in 0..65535 (always, in practice): one conversion pass instead of clip + convert
    ids_u16 = ids_w.astype(np.uint16) if 0 <= lo and hi <= 65535 else np.clip(ids_w, 0, 65535).astype(np.uint16)
    # Anti-aliased rims (alpha > 0 next to an object) belong to the neighbouring object.
    owner = cv2.dilate(ids_u16, np.ones((3, 3), np.uint8))
    cv2.copyTo(ids_u16, cv2.compare(ids_u16, 0, cv2.CMP_GT), owner)  # an object's own pixels keep their id
    boxes = ndimage.find_objects(owner)  # each id's box in one pass
    env_lit = illumination is not None and settings.illumination != "off"
    strength = 0.0 if settings.color_transfer == "none" else settings.color_strength \
        if settings.color_strength is not None else \
        STRENGTH_AFTER_ENV_LIGHT if env_lit else STRENGTH_WITHOUT_ENV_LIGHT
    profile = None if not settings.sensor_match else \
        sensor_profile if sensor_profile is not None else sensor.measure_frame(real_bgr)
    if profile is not None:
        info["sensor"] = {"measured": {k: (round(v, 4) if isinstance(v, float) else v)
                                       for k, v in profile.to_dict().items()}, "applied": {}}
    not_road = obj_any if shadowed is None else obj_any | shadowed
    tm = dict.fromkeys(("relight", "color_transfer", "sensor", "blend"), 0.0)
    tm["objects_prepare"] = time.perf_counter() - t0
    for oid, box in enumerate(boxes, start=1):
        if box is None:
            continue
        by0, by1, bx0, bx1 = box[0].start + wy0, box[0].stop + wy0, box[1].start + wx0, box[1].stop + wx0
        ring_px = int(max(MIN_RING_PX, RING_PX * max(by1 - by0, bx1 - bx0)))
        # Crop = the object's box + its ring (colour transfer reads it) or + SENSOR_MARGIN (the
        # widest sensor blur's reach), origin on the 8x8 JPEG grid of the frame.
        pad = ring_px if strength > 0 else SENSOR_MARGIN
        y0, x0 = max(0, (by0 - pad) // 8 * 8), max(0, (bx0 - pad) // 8 * 8)
        y1, x1 = min(H, by1 + pad), min(W, bx1 + pad)
        crop = (slice(y0, y1), slice(x0, x1))
        o_c = idx[crop] == oid
        own_c = _in_window(owner, win, crop, 0) == oid
        alpha = np.clip(finite(rgba[crop][..., 3].astype(np.float32)), 0.0, 1.0)
        alpha[~own_c] = 0.0  # elsewhere alpha is another object's or the shadow catcher's
        alpha[o_c & (alpha < 1e-3)] = 1.0  # index says object but alpha is empty (e.g. NaN): trust index
        cov = alpha > 0
        cy, cx = np.nonzero(cov)
        a_px = alpha[cy, cx]
        a3 = _rep3(a_px)  # (n, 3): same-shape products are ~5x faster than (n, 1) broadcasts
        flat = (cy + y0) * W + (cx + x0)  # np.take on flat indices: ~5x faster than a masked view
        rgb_px = np.clip(finite(_rows3(_take(rgba, flat), cv2.COLOR_BGRA2BGR), 0.0, HDR_MAX), 0.0, HDR_MAX)
        rec = {"id": int(oid), "pixels": int(o_c.sum()), "crop_xywh": [int(x0), int(y0), int(x1 - x0), int(y1 - y0)]}

        # ---- relight (re-weight the lighting passes toward the estimate)
        t1 = time.perf_counter()
        if settings.relight and env_lit:
            sel = np.flatnonzero((a_px > 0.5) & o_c[cy, cx])  # the object's own, solid pixels
            sub = {k: _take(passes[k], flat[sel]) for k in LIGHT_PASSES
                   if k in passes and np.shape(passes[k])[:2] == (H, W)}
            local = None
            if illumination.condition != "day":  # night light pools: the light where it stands
                local = local_light_gain(real_bgr, (bx0, by0, bx1, by1), illumination,
                                         exclude=lambda band: _in_window(not_road, win, band, False))
            lit, rec["relight"] = relight(np.take(rgb_px, sel, axis=0), sub, None, illumination, local_gain=local)
            _put(rgb_px, sel, lit)
        # Un-premultiply, then display-encode (HDR clips here, like the real camera's sensor).
        obj = np.zeros(alpha.shape + (3,), np.float32)
        lflat = cy * alpha.shape[1] + cx  # crop-flat indices of the covered pixels
        srgb = linear_to_srgb(rgb_px / a3)
        _put(obj.reshape(-1, 3), lflat, _rows3(srgb, cv2.COLOR_RGB2BGR))  # BGR, [0, 1]

        # ---- colour transfer against the real background around the object
        t2 = time.perf_counter()
        om = o_c & (alpha > 0.5)
        if strength > 0 and om.any():
            # Ring = background within ring_px of the object (distance transform: O(N) for any r).
            dist = cv2.distanceTransform((~om).astype(np.uint8), cv2.DIST_L2, 3)
            ring = (dist <= ring_px) & (idx[crop] == 0) & (alpha == 0)
            if shadowed is not None:
                ring &= ~_in_window(shadowed, win, crop, False)
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
        out2 = out.reshape(-1, 3)
        # a * I_V + (1 - a) * I_R, in place on the two temporaries (the same products, bit for bit)
        fg = srgb_to_linear(_take(obj, lflat))
        fg *= a3
        bg = srgb_u8_to_linear(np.take(out2, flat, axis=0))
        bg *= 1.0 - a3
        fg += bg
        _put(out2, flat, linear_to_srgb_u8(fg))
        t5 = time.perf_counter()
        for k, v in (("relight", t2 - t1), ("color_transfer", t3 - t2), ("sensor", t4 - t3), ("blend", t5 - t4)):
            tm[k] += v
        info["objects"].append(rec)
    if len(info["objects"]) == 1:  # keep the simple one-object view at the top level
        info["relight"] = info["objects"][0].get("relight")
    elif info["objects"]:
        info["relight"] = {"relight": "per object", "objects": [o.get("relight") for o in info["objects"]]}
    return tm


def _in_window(a: np.ndarray, win, crop: tuple[slice, slice], fill) -> np.ndarray:
    """The frame-coordinate ``crop`` of ``a``, an array that covers only the window ``win``:
    ``fill`` outside the window."""
    wx0, wy0, wx1, wy1 = win
    ys, xs = crop
    y0, y1, x0, x1 = ys.start, ys.stop, xs.start, xs.stop
    iy0, iy1, ix0, ix1 = max(y0, wy0), min(y1, wy1), max(x0, wx0), min(x1, wx1)
    if (iy0, iy1, ix0, ix1) == (y0, y1, x0, x1):
        return a[y0 - wy0:y1 - wy0, x0 - wx0:x1 - wx0]
    res = np.full((y1 - y0, x1 - x0) + a.shape[2:], fill, a.dtype)
    if iy1 > iy0 and ix1 > ix0:
        res[iy0 - y0:iy1 - y0, ix0 - x0:ix1 - x0] = a[iy0 - wy0:iy1 - wy0, ix0 - wx0:ix1 - wx0]
    return res


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


def _rows3(rows: np.ndarray, code: int) -> np.ndarray:
    """(n, 3) float32 rows of (n, 4) or (n, 3) ``rows`` through cvtColor ``code`` (drop alpha,
    swap R and B): numpy's [:, :3] and [:, ::-1] copies run 3-element inner loops."""
    rows = np.ascontiguousarray(rows, dtype=np.float32)
    if rows.shape[1] != (4 if code == cv2.COLOR_BGRA2BGR else 3) or not len(rows):
        return np.ascontiguousarray(rows[:, :3] if code == cv2.COLOR_BGRA2BGR else rows[:, ::-1])
    return cv2.cvtColor(rows.reshape(-1, 1, rows.shape[1]), code).reshape(-1, 3)


def _rep3(v: np.ndarray) -> np.ndarray:
    """(n,) float32 -> (n, 3), the value in each channel (numpy's (n, 1) broadcast against
    (n, 3) runs an inner loop of 3 elements per row)."""
    v = np.ascontiguousarray(v, dtype=np.float32).reshape(-1)
    return cv2.merge((v, v, v)).reshape(-1, 3) if v.size else np.zeros((0, 3), np.float32)


def _put(dst: np.ndarray, flat: np.ndarray, rows: np.ndarray) -> None:
    """dst[flat] = rows for a C-contiguous (N, C) ``dst``: each row moved as one opaque item
    (np.put on a void view: ~3x faster than fancy-index assignment of (n, C) rows)."""
    c = dst.shape[1]
    item = np.dtype((np.void, c * dst.itemsize))
    src = np.ascontiguousarray(rows, dtype=dst.dtype).reshape(-1, c)
    np.put(dst.view(item).reshape(-1), flat, src.view(item).reshape(-1), mode="clip")


def _shadow_mask(catcher: np.ndarray, win):
    """(shadowed, catcher (float32, finite, 3-D), its grey level, baseline) on the window ``win``."""
    x0, y0, x1, y1 = win
    sc = catcher[y0:y1, x0:x1]
    if sc.ndim == 3 and sc.shape[2] == 3 and sc.dtype == np.float32:
        shadow = finite(sc, 1.0)  # the window as a view (OpenCV reads strided rows): no copy
    else:
        shadow = finite(np.ascontiguousarray(sc[..., :3] if sc.ndim == 3 else sc[..., None], dtype=np.float32), 1.0)
    # Grey level via cvtColor (~10x faster than a min over channels).
    grey = cv2.cvtColor(shadow, cv2.COLOR_BGR2GRAY) if shadow.shape[2] == 3 else shadow[..., 0]
    # The catcher carries a small global bias (objects block a little sky everywhere, denoiser
    # bias): measured as the median of the open ground, it is divided out so that only real
    # shadows remain. Exact 1.0 is sky / no catcher and does not count. Sampled on the frame's
    # 4-px grid; outside the window the catcher is 1 and would not count.
    sample = grey[(-y0) % 4::4, (-x0) % 4::4]
    sample = sample[(sample > 0.85) & (sample < 0.9995)]
    baseline = float(np.median(sample)) if sample.size > 64 else 1.0
    baseline = baseline if 0.9 <= baseline < 1.0 else 1.0
    # The pass is a ratio of two noisy estimates; shadows are smooth, so a small blur before
    # the threshold keeps real shadows and drops the noise.
    return cv2.blur(grey, (3, 3)) < baseline * (1.0 - SHADOW_EPS), shadow, grey, baseline


def _patch_floor(catcher: np.ndarray, grey: np.ndarray, idx: np.ndarray, at: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """At the pixels ``at`` (rows, cols): the catcher's grey level on its patches' ground border,
    spread inward (the border values' local mean, 33 px, else 129 px, else all of them). A soft
    sky shadow has not ended where its patch does; dividing this floor out makes every shadow
    end at 1 on the border, so the patch's outline never shows, while the contact shadow under
    a vehicle keeps its depth. (A fade toward the border over 30 % of the covered area's
    inradius, the whole render region with its objects, had a catcher of 0.05 under a van's
    bumper composite as 0.75 of the road's light.)"""
    c = np.asarray(catcher, dtype=np.float32)  # (h, w, 3) or (h, w, 1), as _shadow_mask gives it
    if c.shape[2] == 3:
        # 255 where a channel's float bits are not 1.0f (int32 compare), ORed by cvtColor
        ne = cv2.compare(c.view(np.int32).reshape(c.shape[0], -1), int(ONE_F32_BITS), cv2.CMP_NE)
        covered = cv2.cvtColor(ne.reshape(c.shape), cv2.COLOR_BGR2GRAY)
    else:
        covered = (c[..., 0].view(np.uint32) != ONE_F32_BITS).astype(np.uint8) * np.uint8(255)
    ground = idx <= 0
    covered[~ground] = 255  # an object stands inside its patch
    # Only the patches' box (+1 px, so that a border on the box's edge is found).
    x, y, w, h = cv2.boundingRect(covered)
    H, W = covered.shape
    y0, x0, y1, x1 = max(0, y - 1), max(0, x - 1), min(H, y + h + 1), min(W, x + w + 1)
    box = (slice(y0, y1), slice(x0, x1))
    covered = covered[box]
    # covered ground next to uncovered pixels (the frame's edge is no border: erode treats
    # outside the image as covered)
    border = ((covered > 0) & (cv2.erode(covered, np.ones((3, 3), np.uint8)) == 0) & ground[box]).astype(np.float32)
    if not border.any():
        return np.ones(len(at[0]), np.float32)
    value = np.clip(grey[box], 0.0, 1.0) * border
    rows, cols = at[0] - y0, at[1] - x0
    floor = np.full(len(rows), float(np.median(value[border > 0])), np.float32)
    todo = np.ones(len(rows), bool)
    for k in (33, 129):
        if not todo.any():
            break
        wsum = cv2.blur(border, (k, k))[rows, cols]
        ok = todo & (wsum > 1e-4)
        floor[ok] = cv2.blur(value, (k, k))[rows, cols][ok] / wsum[ok]
        todo &= ~ok
    return floor


def _bbox(mask: np.ndarray, pad: int, H: int, W: int) -> tuple[slice, slice]:
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return (slice(max(0, rows[0] - pad), min(H, rows[-1] + 1 + pad)),
            slice(max(0, cols[0] - pad), min(W, cols[-1] + 1 + pad)))


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
