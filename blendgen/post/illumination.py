"""Illumination estimation from one real frame (bpy-free).

What is measured, and how:
- illuminant colour: shades-of-grey (Finlayson & Trezzi 2004, Minkowski p=6) on linear,
  non-sky, unsaturated pixels;
- exposure: median and log-average linear luminance of the non-sky pixels;
- sky colour and brightness: the bright, smooth region connected to the top border;
- sun direction: solar azimuth/elevation (pvlib's SPA) from position + UTC time, turned
  into the world ENU frame (x east, y north, z up); without them, in sunlight, the azimuth
  from the shadows that the real road users cast (shadow_direction.py), else a default;
- sun visibility: lit vs shadowed road (two-class Otsu split of the road's log luminance,
  lane markings removed by a top-hat), with a clear-blue-sky cue when the road shows no
  shadow; never under a grey-white sky (snow banks make two-tone roads), at night, or at dusk
  unless the sun is known to be up (street lights and headlights make bimodal roads too);
- condition day / dusk / night: the sun's elevation when the ephemeris gives it (civil
  twilight, -6..6 deg, is dusk), else the frame's log-average luminance and sky brightness.
  At night and dusk vehicle lights are on and an overhead street-light key replaces the sun,
  except at a dusk whose sun is known to be up (0..6 deg) and is seen (road shadows, clear sky).

`Illumination.to_lighting()` turns the estimate into the lighting dict of
docs/architecture.md, in units that make a Cycles render (Standard view transform, film
exposure 0) land at the real camera's exposure. The light is read off the whole non-sky
scene (log-average luminance = SCENE_ALBEDO x irradiance/pi, as a camera's auto-exposure
meters it), not off the road alone: a light concrete road would otherwise brighten objects
by its albedo ratio (1.4-1.7x measured). The road's albedo that this implies must lie in the
range of real roads (fresh asphalt 0.05 .. light concrete 0.40); outside it the road at that
bound sets the light (`exposure_source`, and a note says which and why).
(Cycles: a uniform world of strength L gives a white diffuse surface radiance L; a sun of
strength S gives S*cos/pi.)
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone

import cv2
import numpy as np

from blendgen.errors import UserError
from blendgen.post.colorspace import LUMA_BGR, srgb_u8_to_linear

# Mean albedo of the non-sky scene. Calibrated on the Udacity asphalt highway photos, where the
# road's albedo is the asphalt prior 0.12 (aged asphalt 0.10-0.15): there the scene's
# log-average is 1.17x the road's median, so 0.12 x 1.17 = 0.14.
SCENE_ALBEDO = 0.14
ROAD_ALBEDO_RANGE = (0.05, 0.40)  # new asphalt .. light concrete: bounds the implied road albedo
# Condition from the image when the sun's elevation is unknown: non-sky log-average luminance
# (linear) of the BDD night street 0.017, of day photos 0.05-0.18 (a tree-shaded street 0.053).
NIGHT_LOG_AVG = 0.03
DUSK_LOG_AVG = 0.045
DARK_SKY = 0.1  # a sky region brighter than this is daylight whatever the scene's exposure
TWILIGHT_DEG = (-6.0, 6.0)  # civil twilight and the sun's last 6 deg: dusk
STREET_LIGHT_SHARE = {"night": 0.7, "dusk": 0.4}  # overhead key's share of the irradiance
STREET_LIGHT_ELEVATION_DEG = 70.0  # lamps stand high beside the road: light mostly from above
SHADES_OF_GREY_P = 6.0
CLEAR_SKY_SUN_FRACTION = 0.8  # asymptotic sun share of the ground irradiance under a clear sky
OVERCAST_SKY_BR = 1.2  # blue/red of a sky below which it is cloud, not clear
MIN_SHADOW_RATIO = 1.8  # lit/shadow road luminance ratio above which the sun is called visible
DEFAULT_SUN_ELEVATION_DEG = 45.0
WORK_WIDTH = 192  # statistics run on a downsampled copy: they are global, this keeps them ~2 ms


@dataclass
class Illumination:
    """An estimate of the light in one real frame. Colours are linear Rec.709 RGB."""

    illuminant_rgb: tuple[float, float, float]  # chroma, luminance 1
    exposure: float  # median linear luminance of non-sky pixels
    log_average_luminance: float
    ground_luminance: float  # median linear luminance of the road region
    sky_rgb: tuple[float, float, float] | None  # mean linear sky colour (None: no sky found)
    sky_luminance: float
    sky_fraction: float
    sky_saturated: float  # share of sky pixels clipped in the 8-bit frame
    sun_direction: tuple[float, float, float]  # world frame, toward the sun
    sun_elevation_deg: float
    sun_azimuth_deg: float  # clockwise from north
    sun_direction_source: str  # "ephemeris" | "given" | "shadows" | "default"
    sun_visible: bool
    sun_fraction: float  # share of the ground irradiance that comes from the sun
    shadow_ratio: float  # lit / shadowed road luminance (1: no shadow measured)
    visibility_cue: str  # "shadows" | "clear_sky" | "overcast" | "overcast_sky" | "below_horizon" | "night" | "dusk"
    horizon_row: float  # sky line (bottom of the sky region, or from the pitch), in input pixels
    condition: str = "day"  # "day" | "dusk" | "night"
    road_albedo: float = 0.12  # implied by the road's median against the scene's log-average
    notes: list[str] = field(default_factory=list)
    light_level: float | None = None  # irradiance / pi in pixel units (None: scene meter alone)
    exposure_source: str = "scene"  # "scene" | "road_albedo_max" | "road_albedo_min": what metered it
    # the real road's sun shadows against its lit road, per channel at equal luminance (linear
    # RGB, luminance 1): a composited shadow darkens the road by the render's ratio in this
    # tint; None (no sun shadow measured): neutral, the road's own colour darkened
    shadow_tint_rgb: tuple[float, float, float] | None = None

    def to_dict(self) -> dict:
        return asdict(self)

    def to_lighting(self) -> dict:
        """The lighting dict (architecture.md) for the render driver."""
        total = self.light_level or max(self.log_average_luminance, 1e-4) / SCENE_ALBEDO  # irradiance / pi
        f = self.sun_fraction if self.sun_visible else 0.0
        ill = np.asarray(self.illuminant_rgb, dtype=float)
        sky_c = _unit_luma(np.asarray(self.sky_rgb, float)) if self.sky_rgb is not None else ill
        if f > 0.05:
            sun_c = (ill - (1 - f) * sky_c) / f  # total light = f * sun + (1 - f) * sky
            sun_c = _unit_luma(np.clip(sun_c, 0.05 * ill.max(), None))
        else:
            sun_c = ill
        sin_el = max(math.sin(math.radians(self.sun_elevation_deg)), 0.08)
        sun_strength = math.pi * f * total / sin_el if f > 0 else 0.0
        return {
            "sun_direction": [float(v) for v in self.sun_direction],
            "sun_strength": float(sun_strength),
            "sun_color": [float(v) for v in sun_c],
            "sun_angle_deg": 0.53 if self.shadow_ratio >= 3.0 or self.visibility_cue == "clear_sky" else 2.0,
            "sky_color": [float(v) for v in sky_c],
            "sky_strength": float((1.0 - f) * total),
            "sun_visible": bool(self.sun_visible and f > 0),
            "condition": self.condition,
            "lights_on": self.condition != "day",
            "street_light": self._street_light(total),
            # what glass and clear coats mirror at dusk and night: the scene's mean radiance, not
            # the ambient that lights the objects (7x brighter on the BDD night street, where car
            # windows then read lighter than their bodies); by day the sky is that bright
            "reflected_strength": None if self.condition == "day" else float(self.log_average_luminance),
        }

    def _street_light(self, total: float) -> dict | None:
        """Night/dusk: an overhead key from the lamps' colour (shades of grey weighs the bright
        lamps most), soft, from high up beside the road; no sun shadow is caught from it."""
        share = STREET_LIGHT_SHARE.get(self.condition)
        if share is None or self.sun_visible:
            return None
        direction = enu_from_az_el(self.sun_azimuth_deg, STREET_LIGHT_ELEVATION_DEG)
        sin_el = math.sin(math.radians(STREET_LIGHT_ELEVATION_DEG))
        return {"direction": [float(v) for v in direction], "strength": float(math.pi * share * total / sin_el),
                "color": [float(v) for v in self.illuminant_rgb], "angle_deg": 30.0, "share": share}


def estimate_illumination(real_bgr: np.ndarray, *, T_world_cam=None, when_utc: datetime | None = None,
                          latlon: tuple[float, float] | None = None,
                          sun_az_el: tuple[float, float] | None = None, real_objects=None,
                          camera=None) -> Illumination:
    """Estimate the light of a real 8-bit BGR frame (see the module docstring).

    The sun's position comes from ``when_utc`` + ``latlon`` (pvlib), or directly from
    ``sun_az_el`` = (azimuth clockwise from north, elevation), degrees, when it is known
    otherwise (a synthetic scene); without either, in sunlight, the azimuth is read off the
    shadows of ``real_objects`` (the frame analysis's road users, boxes in ``real_bgr`` pixels)
    through ``camera`` and ``T_world_cam`` (blendgen/post/shadow_direction.py), else a default
    (the note says why).
    """
    if not isinstance(real_bgr, np.ndarray) or real_bgr.ndim != 3 or real_bgr.shape[2] != 3 \
            or real_bgr.dtype != np.uint8 or min(real_bgr.shape[:2]) < 2:
        raise UserError(f"expected an HxWx3 uint8 BGR frame, got {getattr(real_bgr, 'dtype', None)} "
                        f"{getattr(real_bgr, 'shape', None)}", where="estimate_illumination real_bgr")
    H, W = real_bgr.shape[:2]
    scale = min(1.0, WORK_WIDTH / W)
    small = cv2.resize(real_bgr, (max(2, round(W * scale)), max(2, round(H * scale))),
                       interpolation=cv2.INTER_AREA) if scale < 1 else real_bgr
    h, w = small.shape[:2]
    lin = srgb_u8_to_linear(small)
    Y = lin @ LUMA_BGR
    notes: list[str] = []

    pitch = _camera_pitch(T_world_cam)
    sky = _sky_mask(small)
    sky_frac = float(sky.mean())
    if sky_frac > 0.01:
        rows = np.where(sky.any(axis=1))[0]
        # lowest sky row of each column (-1: none), as one argmax over the flipped rows
        col_bottom = np.where(sky.any(axis=0), h - 1 - np.argmax(sky[::-1], axis=0), -1)
        horizon = float(np.median(col_bottom[col_bottom >= 0])) if rows.size else 0.45 * h
    elif pitch is not None:
        # No sky seen: place the horizon from the camera pitch (assumed 60 deg horizontal FOV).
        f_px = 0.5 * w / math.tan(math.radians(30))
        horizon = float(np.clip(0.5 * h - f_px * math.tan(pitch), 0, h - 1))
        notes.append("no sky region found: horizon from the camera pitch")
    else:
        horizon = 0.45 * h
        notes.append("no sky region found: horizon assumed at 45% of the height")

    # channel max with OpenCV (numpy's max over the 3-channel axis is ~10x slower)
    cmax = cv2.max(cv2.max(small[..., 0], small[..., 1]), small[..., 2])
    valid = (cmax < 250) & (cmax > 5)  # unsaturated, not black
    scene = valid & ~sky
    if scene.sum() < 16:
        scene = ~sky if (~sky).sum() >= 16 else np.ones_like(sky)
        notes.append("few unsaturated pixels: statistics include clipped ones")

    # Shades of grey on linear values (BGR); normalised to unit luminance.
    pix = lin[scene].astype(np.float64)
    e = np.power(np.mean(np.power(pix, SHADES_OF_GREY_P), axis=0), 1.0 / SHADES_OF_GREY_P)
    ill_bgr = _unit_luma_bgr(e)
    Ys = Y[scene]
    exposure = float(np.median(Ys))
    log_avg = float(np.exp(np.mean(np.log(Ys + 1e-4))))

    # Sky colour and brightness.
    if sky_frac > 0.01:
        sky_bgr = lin[sky].mean(axis=0)
        sky_rgb = tuple(float(v) for v in sky_bgr[::-1])
        sky_lum = float(sky_bgr @ LUMA_BGR)
        sky_sat = float((cmax[sky] >= 250).mean())
    else:
        sky_bgr, sky_rgb, sky_lum, sky_sat = None, None, 0.0, 0.0

    # Road: below the horizon, greyish, not sky.
    ground = np.zeros((h, w), bool)
    g0 = int(min(h - 1, max(0, horizon + 0.12 * h)))
    ground[g0:] = True
    hsv = cv2.cvtColor(small, cv2.COLOR_BGR2HSV)
    ground &= (hsv[..., 1] < 50) & ~sky  # asphalt/concrete are grey; verges and grass are not
    if ground.sum() < 16:
        ground[g0:] = True
        notes.append("no grey road region: ground statistics over the lower frame")
    ground_lum = float(np.median(Y[ground])) if ground.any() else exposure

    ratio, shadow_share, tint_bgr = _shadow_ratio(small, Y, ground, lin)
    # The light: metered on the whole scene, then held to what the road can be. A road that the
    # scene meter makes brighter than light concrete (a dark, shaded or foliage-framed scene
    # around a lit road) or darker than fresh asphalt (snow, white walls) means the scene's
    # mean albedo is not SCENE_ALBEDO; the road's albedo range then sets the light.
    light = max(log_avg, 1e-4) / SCENE_ALBEDO
    implied = ground_lum / light
    lo_a, hi_a = ROAD_ALBEDO_RANGE
    exposure_source = "scene"
    if implied > hi_a or implied < lo_a:
        bound = hi_a if implied > hi_a else lo_a
        exposure_source = "road_albedo_max" if implied > hi_a else "road_albedo_min"
        notes.append(f"exposure: the scene meter would make the road's albedo {implied:.2f}, outside "
                     f"{lo_a}-{hi_a}: light set from the road at albedo {bound} ({light:.3f} -> "
                     f"{ground_lum / bound:.3f})")
        light = ground_lum / bound
    else:
        notes.append(f"exposure: scene log-average {log_avg:.3f} at mean albedo {SCENE_ALBEDO} "
                     f"(road albedo {implied:.2f}, within {lo_a}-{hi_a})")
    road_albedo = float(np.clip(implied, *ROAD_ALBEDO_RANGE))

    # Sun direction.
    if sun_az_el is not None:
        az, el = float(sun_az_el[0]), float(sun_az_el[1])
        source = "given"
    elif when_utc is not None and latlon is not None:
        el, az = sun_position(when_utc, latlon[0], latlon[1])
        source = "ephemeris"
    else:
        el, az = DEFAULT_SUN_ELEVATION_DEG, _default_azimuth(T_world_cam)
        source = "default"
        notes.append("no time/position: sun direction is a default (behind the camera, 40 deg to its right)")
    sun_dir = enu_from_az_el(az, el)

    condition = _condition(el if source != "default" else None, log_avg, sky_lum if sky_bgr is not None else None)

    # Sun visibility.
    shadow_tint = None
    if el <= 0:
        visible, f, cue = False, 0.0, "below_horizon"
    elif condition == "night" or (condition == "dusk" and (source == "default" or el >= TWILIGHT_DEG[1])):
        # a dusk that the sun's own elevation calls (0-6 deg up) is judged as by day (shadows,
        # clear sky): golden hour, not street lamps (taken as set, its long shadows and warm key
        # were lost); a frame darker than its high sun (a tunnel, a lamp-lit underpass) is not
        visible, f, cue = False, 0.0, condition
    elif sky_bgr is not None and _overcast_sky(sky_bgr, sky_sat):
        # A grey-white sky is cloud: a two-tone road under it is snow banks, wet or white
        # patches (the BDD snow street: ratio 4.5), not sun shadows.
        visible, f, cue = False, 0.0, "overcast_sky"
        if ratio >= MIN_SHADOW_RATIO:
            notes.append(f"two-tone road (ratio {ratio:.1f}) under a grey-white sky: read as snow or "
                         "light surfaces, not sun shadows")
    elif ratio >= MIN_SHADOW_RATIO:
        visible, f, cue = True, float(np.clip(1.0 - 1.0 / ratio, 0.0, 0.95)), "shadows"
        if tint_bgr is not None:
            shadow_tint = tuple(float(v) for v in tint_bgr[::-1])
    elif sky_bgr is not None and _clear_blue(sky_bgr, sky_lum, ground_lum):
        visible, f, cue = True, clear_sky_sun_fraction(el), "clear_sky"
    else:
        visible, f, cue = False, 0.0, "overcast"

    if condition != "day":
        notes.append(f"{condition}: vehicle lights on, " + ("the low sun stays the key" if visible
                                                            else "street-light key instead of the sun"))

    if visible and source == "default":
        # The sun's azimuth from the shadows of the real road users, when they show them.
        shadow_az, why = None, "no real road users or camera given"
        if real_objects and camera is not None and T_world_cam is not None:
            from blendgen.post.shadow_direction import sun_azimuth_from_shadows

            shadow_az, why, _ = sun_azimuth_from_shadows(real_bgr, real_objects, camera, T_world_cam)
        if shadow_az is not None:
            az, source = shadow_az, "shadows"
            sun_dir = enu_from_az_el(az, el)
            notes.append(f"sun azimuth {az:.0f} deg from the {why}; elevation a default {el:.0f} deg")
        else:
            notes.append(f"sun azimuth stays the default: {why}")

    return Illumination(
        illuminant_rgb=tuple(float(v) for v in ill_bgr[::-1]),
        exposure=exposure, log_average_luminance=log_avg, ground_luminance=ground_lum,
        sky_rgb=sky_rgb, sky_luminance=sky_lum, sky_fraction=sky_frac, sky_saturated=sky_sat,
        sun_direction=tuple(float(v) for v in sun_dir), sun_elevation_deg=float(el), sun_azimuth_deg=float(az),
        sun_direction_source=source, sun_visible=visible, sun_fraction=f, shadow_ratio=float(ratio),
        visibility_cue=cue, horizon_row=float(horizon / scale if scale < 1 else horizon), notes=notes,
        condition=condition, road_albedo=road_albedo, light_level=float(light), exposure_source=exposure_source,
        shadow_tint_rgb=shadow_tint)


def _condition(sun_el: float | None, log_avg: float, sky_lum: float | None) -> str:
    """day / dusk / night: from the sun's elevation when known, else from the frame's light.
    A frame darker than the ephemeris says (a tunnel, heavy overcast at dusk) takes the darker."""
    if sky_lum is not None and sky_lum > DARK_SKY:
        by_image = "day"
    else:
        by_image = "night" if log_avg < NIGHT_LOG_AVG else "dusk" if log_avg < DUSK_LOG_AVG else "day"
    if sun_el is None:
        return by_image
    by_sun = "night" if sun_el < TWILIGHT_DEG[0] else "dusk" if sun_el < TWILIGHT_DEG[1] else "day"
    order = ("day", "dusk", "night")
    return max(by_sun, by_image, key=order.index)


# ---- sun position

def sun_position(when_utc: datetime, lat: float, lon: float) -> tuple[float, float]:
    """(apparent elevation, azimuth clockwise from north), degrees, from pvlib's SPA."""
    import pandas as pd
    import pvlib

    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        raise UserError(f"latitude/longitude ({lat}, {lon}) out of range", where="estimate_illumination latlon")
    if when_utc.tzinfo is None:
        when_utc = when_utc.replace(tzinfo=timezone.utc)
    sp = pvlib.solarposition.get_solarposition(pd.DatetimeIndex([when_utc]), lat, lon)
    return float(sp["apparent_elevation"].iloc[0]), float(sp["azimuth"].iloc[0])


def enu_from_az_el(az_deg: float, el_deg: float) -> np.ndarray:
    """Unit vector toward the sun in ENU (x east, y north, z up)."""
    az, el = math.radians(az_deg), math.radians(el_deg)
    return np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])


def _default_azimuth(T_world_cam) -> float:
    """Azimuth behind the camera, 40 deg to its right (objects front-lit), or south-east without a pose."""
    if T_world_cam is None:
        return 135.0
    z = np.asarray(T_world_cam, float)[:3, 2]  # optical axis in the world
    heading = math.degrees(math.atan2(z[0], z[1]))  # clockwise from north (+y)
    return (heading + 180.0 - 40.0) % 360.0


def _camera_pitch(T_world_cam) -> float | None:
    if T_world_cam is None:
        return None
    T = np.asarray(T_world_cam, float)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise UserError(f"T_world_cam must be a finite 4x4 matrix, got shape {T.shape}",
                        where="estimate_illumination T_world_cam")
    z = T[:3, 2]
    return math.asin(float(np.clip(z[2] / max(np.linalg.norm(z), 1e-9), -1, 1)))


# ---- image measurements

def _sky_mask(small: np.ndarray) -> np.ndarray:
    """Bright, smooth pixels in the upper 60% connected to the top border."""
    h, w = small.shape[:2]
    gray = cv2.cvtColor(small, cv2.COLOR_BGR2GRAY).astype(np.float32)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    grad = cv2.blur(np.sqrt(gx * gx + gy * gy), (3, 3))
    b, r = small[..., 0].astype(np.int16), small[..., 2].astype(np.int16)
    # Sky: smooth and either bluish or bright and neutral (overcast); not brightness alone,
    # since sunlit dry grass or concrete is often brighter than a blue sky.
    skyish = (gray > 60) & ((b >= r + 8) | ((gray > 170) & (np.abs(b - r) < 25)))
    cand = skyish & (grad < 30)
    cand[int(0.6 * h):] = False
    n, labels = cv2.connectedComponents(cand.astype(np.uint8), connectivity=4)
    top = np.unique(labels[0][cand[0]])
    top = top[top > 0]
    if top.size == 0:
        return np.zeros((h, w), bool)
    return np.isin(labels, top)


SHADOW_TINT_RANGE = (0.8, 1.25)  # per channel: a shade's tint, never a colour of its own


def _shadow_ratio(small: np.ndarray, Y: np.ndarray, ground: np.ndarray, lin: np.ndarray | None = None):
    """(lit/shadow luminance ratio of the road, 1.0 when the road is not bimodal; the shadow
    class's share; the shadows' tint: per-channel median ratio shadow/lit (linear BGR) divided by
    the luminance ratio, or None)."""
    gray = cv2.cvtColor(small, cv2.COLOR_BGR2GRAY)
    # Lane markings are thin bright lines, not sunlit road: remove them with a white top-hat.
    k = max(3, (small.shape[1] // 40) | 1)
    tophat = cv2.morphologyEx(gray, cv2.MORPH_TOPHAT, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)))
    road = ground & (tophat < 25)
    y = Y[road]
    if y.size < 64:
        return 1.0, 0.0, None
    ly = np.log(y + 1e-4)
    lo, hi = np.percentile(ly, [1, 99])
    if hi - lo < 1e-3:
        return 1.0, 0.0, None
    q = np.clip((ly - lo) / (hi - lo) * 255, 0, 255).astype(np.uint8)
    t, _ = cv2.threshold(q.reshape(-1, 1), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    dark, bright = y[q <= t], y[q > t]
    share = dark.size / y.size
    if dark.size < 16 or bright.size < 16 or not 0.03 <= share <= 0.85:
        return 1.0, share, None
    # Bimodality: the two classes must explain most of the variance (not a smooth gradient).
    between = share * (1 - share) * (ly[q > t].mean() - ly[q <= t].mean()) ** 2
    if between / max(ly.var(), 1e-12) < 0.6:
        return 1.0, share, None
    ratio = float(np.median(bright) / max(np.median(dark), 1e-4))
    tint = None
    if lin is not None:
        px = lin[road].astype(np.float64)
        qd = (q <= t).ravel()
        d_bgr, b_bgr = np.median(px[qd], axis=0), np.median(px[~qd], axis=0)
        tint = (d_bgr / np.maximum(b_bgr, 1e-5)) * ratio
        tint = np.clip(_unit_luma_bgr(tint), *SHADOW_TINT_RANGE)
    return ratio, share, tint


def clear_sky_sun_fraction(el_deg: float) -> float:
    """Direct share of the horizontal irradiance under a clear sky: ~0.7 at high sun, ~0.5 at
    15 deg, ~0.25 at 4 deg (the sun's horizontal irradiance falls with sin(el), the sky's much less)."""
    s = max(math.sin(math.radians(el_deg)), 0.0)
    return CLEAR_SKY_SUN_FRACTION * s / (s + 0.15)


def _clear_blue(sky_bgr: np.ndarray, sky_lum: float, ground_lum: float) -> bool:
    """A blue sky that is not darker than the road: a clear sky, so the sun is out."""
    b, g, r = (float(v) for v in sky_bgr)
    return b > 1.15 * r and sky_lum > 0.8 * max(ground_lum, 1e-4)


def _overcast_sky(sky_bgr: np.ndarray, sky_saturated: float) -> bool:
    """A grey-white sky (cloud), seen and mostly unclipped: a clear sky is blue (b/r 2.2-3.2 on
    the Udacity photos, the BDD snow street's grey sky 1.05); a sky clipped white says nothing."""
    b, _, r = (float(v) for v in sky_bgr)
    return b < OVERCAST_SKY_BR * r and sky_saturated < 0.6


def _unit_luma_bgr(c_bgr: np.ndarray) -> np.ndarray:
    c = np.maximum(np.nan_to_num(np.asarray(c_bgr, float)), 1e-6)
    return c / max(float(c @ LUMA_BGR), 1e-6)


def _unit_luma(c_rgb: np.ndarray) -> np.ndarray:
    return _unit_luma_bgr(np.asarray(c_rgb, float)[::-1])[::-1]
