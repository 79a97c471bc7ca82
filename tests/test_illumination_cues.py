"""Illumination cues: sun azimuth from real road users' shadows, snow is not sun, exposure bounded
by the road's albedo range, night catches contact shadows and casts no sun shadow."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from blendgen.frame_analysis import CameraEstimate, RealObject
from blendgen.geometry import Camera
from blendgen.ground import camera_pose
from blendgen.post.illumination import enu_from_az_el, estimate_illumination
from blendgen.post.shadow_direction import sun_azimuth_from_shadows

CAM = Camera.from_hfov(640, 360, 60)
T = camera_pose(CameraEstimate(height_m=1.4, pitch_deg=-3.0, roll_deg=0.0))  # looks along +x: east
REAL = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"


def _uv(pts):
    uv, ok = CAM.project_world(T, np.asarray(pts, float))
    assert ok.all()
    return uv


def _street(cars, sun_az, sun_el=35.0):
    """A drawn sunny street: blue sky, textured asphalt, boxy cars with the shadows that a
    sun at (sun_az, sun_el) casts from them; returns the frame and the cars as RealObjects."""
    rng = np.random.default_rng(0)
    img = np.zeros((CAM.height, CAM.width, 3), np.uint8)
    hz = int(_uv([[1e4, 0, 0]])[0, 1])
    img[:hz] = (215, 160, 110)
    img[hz:] = (118, 120, 122)
    img[hz:] += rng.integers(0, 10, size=(CAM.height - hz, CAM.width, 1), dtype=np.uint8)
    s = enu_from_az_el(sun_az, sun_el)
    objs = []
    for cx, cy in cars:
        L, W, H = 4.5, 1.8, 1.5
        foot = np.array([[cx - L / 2, cy - W / 2], [cx + L / 2, cy - W / 2], [cx + L / 2, cy + W / 2],
                         [cx - L / 2, cy + W / 2]])
        base = np.c_[foot, np.zeros(4)]
        top = np.c_[foot, np.full(4, H)]
        cast = np.c_[foot - H * s[:2] / s[2], np.zeros(4)]  # the roof's shadow on the ground
        hull = cv2.convexHull(_uv(np.r_[base, cast]).astype(np.float32)).astype(np.int32)
        cv2.fillConvexPoly(img, hull, (38, 39, 41))
        body = _uv(np.r_[base, top])
        cv2.fillConvexPoly(img, cv2.convexHull(body.astype(np.float32)).astype(np.int32), (60, 50, 150))
        x0, y0 = body.min(axis=0)
        x1, y1 = body.max(axis=0)
        objs.append(RealObject("car", 0.9, [float(x0), float(y0), float(x1 - x0), float(y1 - y0)],
                               footprint=foot.tolist()))
    return img, objs


def _ang(a, b):
    return abs((a - b + 180) % 360 - 180)


@pytest.mark.parametrize("sun_az", [0.0, 60.0, 130.0, 180.0])  # left, front-left, front-right, right
def test_sun_azimuth_from_drawn_car_shadows(sun_az):
    img, objs = _street([(14.0, 3.5), (20.0, -3.0), (11.0, -2.5)], sun_az)
    az, why, details = sun_azimuth_from_shadows(img, objs, CAM, T)
    assert az is not None, why
    assert _ang(az, sun_az) < 25, (az, sun_az, details)
    est = estimate_illumination(img, T_world_cam=T, real_objects=objs, camera=CAM)
    assert est.sun_visible and est.sun_direction_source == "shadows"
    assert _ang(est.sun_azimuth_deg, sun_az) < 25 and any("shadows of" in n for n in est.notes)


def test_sun_behind_camera_falls_back_with_reason():
    img, objs = _street([(14.0, 0.3), (22.0, -0.4)], 270.0)  # behind the camera: shadows hidden
    az, why, _ = sun_azimuth_from_shadows(img, objs, CAM, T)
    assert az is None and "sun behind the camera" in why
    est = estimate_illumination(img, T_world_cam=T, real_objects=objs, camera=CAM)
    assert est.sun_visible and est.sun_direction_source == "default"
    assert any(n.startswith("sun azimuth stays the default: none of 2 real road users") for n in est.notes)
    est = estimate_illumination(img, T_world_cam=T)  # no analysis at all
    assert any("no real road users" in n for n in est.notes)


def test_golden_hour_sun_stays_the_key():
    """Sun 4 deg up (dusk by the ephemeris): seen (shadows across the road, or a clear sky) it
    lights the scene (lamps on, no street-light key); behind cloud it is dusk as before."""
    img, _ = _street([(14.0, -3.5), (20.0, -6.0), (11.0, -2.5)], 180.0, sun_el=4.0)  # shadows across the road
    est = estimate_illumination(img, sun_az_el=(180.0, 4.0))
    light = est.to_lighting()
    assert est.condition == "dusk" and est.sun_visible and est.visibility_cue == "shadows", est.notes
    assert light["lights_on"] and light["sun_strength"] > 0 and light["street_light"] is None
    plain, _ = _street([], 180.0)
    est = estimate_illumination(plain, sun_az_el=(180.0, 4.0))
    assert est.condition == "dusk" and est.visibility_cue == "clear_sky" and 0.2 < est.sun_fraction < 0.3
    plain[:150] = (200, 198, 196)  # grey cloud
    est = estimate_illumination(plain, sun_az_el=(180.0, 4.0))
    assert est.condition == "dusk" and not est.sun_visible and est.to_lighting()["street_light"] is not None
    # a frame darker than its high sun (a tunnel's mouth, a lamp-lit underpass) is dusk without it
    dark = (img * 0.52).astype(np.uint8)
    est = estimate_illumination(dark, sun_az_el=(180.0, 40.0))
    assert est.condition == "dusk" and not est.sun_visible and est.to_lighting()["street_light"] is not None


def test_grey_sky_two_tone_road_is_not_sun():
    img, _ = _street([], 0.0)
    img[:150] = (222, 218, 214)  # grey-white cloud
    img[200:, :200] = (235, 236, 236)  # snow banks beside a grey road: a two-tone road
    img[200:, 450:] = (232, 234, 235)
    est = estimate_illumination(img)
    assert est.shadow_ratio >= 1.8  # the road is two-tone ...
    assert not est.sun_visible and est.visibility_cue == "overcast_sky"  # ... but that is not sun
    assert est.to_lighting()["sun_strength"] == 0.0


@pytest.mark.data
def test_real_snow_street_is_not_sun_visible():
    p = REAL / "bdd_street_photos" / "7dd9ef45-f197db95.jpg"
    if not p.is_file():
        pytest.skip(f"needs {p}")
    est = estimate_illumination(cv2.imread(str(p)))
    assert est.condition == "day" and not est.sun_visible and est.visibility_cue != "shadows"


@pytest.mark.data
def test_real_night_street_catches_contact_shadows_not_sun():
    from blendgen.render import effects as fx

    p = REAL / "bdd_street_photos" / "9aa94005-ff1d4c9a.jpg"
    if not p.is_file():
        pytest.skip(f"needs {p}")
    light = estimate_illumination(cv2.imread(str(p))).to_lighting()
    out = {"rgba", "shadow_catcher"}
    assert fx.sun_direction(light) is None and light["sun_strength"] == 0.0  # no sun, no sun shadow
    d = fx.decide_shadow_catcher(light, out)
    assert d.value is True and "street-light" in d.reason
    key = fx.shadow_light_direction(light)
    assert key[2] > np.sin(np.radians(60))  # overhead: a short contact shadow, never a long one


def test_exposure_held_to_the_road_albedo_range():
    img, _ = _street([], 0.0)
    img[150:200] = (12, 14, 12)  # dark foliage and walls around a lit road: the scene meter reads low
    img[:150, :400] = (20, 30, 20)
    est = estimate_illumination(img)
    assert est.exposure_source == "road_albedo_max"
    assert est.light_level == pytest.approx(est.ground_luminance / 0.40)
    assert est.light_level > est.log_average_luminance / 0.14  # raised over the scene meter
    assert any("outside 0.05-0.4" in n for n in est.notes)
    plain = estimate_illumination(_street([], 0.0)[0])
    assert plain.exposure_source == "scene" and any(n.startswith("exposure: scene log-average") for n in plain.notes)


def _night_pool_frame():
    """A dark street (night by its light) with one lamp pool on the road at the right."""
    img = np.full((240, 320, 3), 5, np.uint8)
    img[120:] = (16, 17, 19)
    img[150:240, 200:320] = (80, 100, 120)  # warm pool of lamp light on the road
    return img


def _grey_object(x, y=100, w=30, h=60):
    """Passes of one grey diffuse box object (id 1): lit by a uniform render light."""
    H, W = 240, 320
    p = {k: np.zeros((H, W, 3), np.float32) for k in ("diffuse_direct", "diffuse_indirect", "diffuse_color")}
    rgba = np.zeros((H, W, 4), np.float32)
    idx = np.zeros((H, W), np.int32)
    sl = (slice(y, y + h), slice(x, x + w))
    p["diffuse_color"][sl] = 0.5
    p["diffuse_direct"][sl] = 0.1
    rgba[sl] = (0.05, 0.05, 0.05, 1.0)
    idx[sl] = 1
    return {**p, "rgba": rgba, "index": idx}


def test_night_objects_take_the_light_where_they_stand():
    from blendgen.job.schema import Post
    from blendgen.post.colorspace import LUMA_BGR, srgb_u8_to_linear
    from blendgen.post.composite import composite_frame
    from blendgen.post.relight import local_light_gain

    real = _night_pool_frame()
    est = estimate_illumination(real)
    assert est.condition == "night"
    Y = srgb_u8_to_linear(real) @ LUMA_BGR
    in_pool, in_dark = local_light_gain(Y, (240, 100, 270, 160), est), local_light_gain(Y, (40, 100, 70, 160), est)
    assert in_dark == pytest.approx(1.0, abs=0.1) and in_pool > 1.5  # the road median is the unlit road
    day = estimate_illumination(_street([], 0.0)[0])
    assert local_light_gain(srgb_u8_to_linear(_street([], 0.0)[0]) @ LUMA_BGR, (40, 100, 70, 160), day) is None

    post = Post(color_transfer="none", sensor_match=False)
    lit = {}
    for name, x in (("pool", 240), ("dark", 40)):
        comp, info = composite_frame(real, _grey_object(x), settings=post, illumination=est)
        lit[name] = float(comp[110:150, x + 5:x + 25].mean())
        assert info["relight"]["local_light_gain"] == pytest.approx(in_pool if name == "pool" else in_dark, rel=0.05)
    assert lit["pool"] > 1.3 * lit["dark"]  # same object, same render: brighter in the lamp's pool
