"""Post stage: colour transfer, illumination estimate, sensor measures, compositing."""

from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np
import pytest

from blendgen.errors import UserError
from blendgen.job.schema import Post
from blendgen.post.color_transfer import METHODS, transfer
from blendgen.post.composite import composite_frame
from blendgen.post.illumination import enu_from_az_el, estimate_illumination, sun_position
from blendgen.post import sensor

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
REAL = DATA / "real" / "udacity_highway_images" / "solidWhiteRight.jpg"
TRANSFER = [m for m in METHODS if m != "none"]


def _scene(h=120, w=160, seed=0):
    """A synthetic road frame: blue sky on top, grey road below, some texture."""
    rng = np.random.default_rng(seed)
    img = np.zeros((h, w, 3), np.uint8)
    img[: h // 2] = (220, 170, 120)  # BGR: blue sky
    img[h // 2:] = (90, 92, 95)
    img[h // 2:] += rng.integers(0, 12, size=(h - h // 2, w, 1), dtype=np.uint8)
    return img


def _passes(h, w, box=(40, 60, 30, 40), oid=3, colour=(0.6, 0.1, 0.1), alpha_edge=True):
    """rgba (linear RGB premultiplied) + index for one box object."""
    y, x, bh, bw = box
    rgba = np.zeros((h, w, 4), np.float32)
    idx = np.zeros((h, w), np.int32)
    rgba[y:y + bh, x:x + bw, :3] = colour
    rgba[y:y + bh, x:x + bw, 3] = 1.0
    idx[y:y + bh, x:x + bw] = oid
    if alpha_edge:  # a half-covered rim column
        rgba[y:y + bh, x + bw, :3] = np.array(colour) * 0.5
        rgba[y:y + bh, x + bw, 3] = 0.5
    return {"rgba": rgba, "index": idx}


# ---------------- colour transfer

@pytest.mark.parametrize("method", TRANSFER)
def test_transfer_onto_itself_is_identity(method):
    img = _scene()
    mask = np.zeros(img.shape[:2], bool)
    mask[20:100, 30:120] = True
    out = transfer(img, mask, img, mask, method)
    assert np.array_equal(out, img)
    f = img.astype(np.float32) / 255
    assert np.allclose(transfer(f, mask, f, mask, method), f, atol=1e-6)


@pytest.mark.parametrize("method", TRANSFER)
def test_transfer_moves_statistics_toward_reference(method):
    rng = np.random.default_rng(1)
    src = np.clip(rng.normal(0.3, 0.05, (64, 64, 3)), 0, 1).astype(np.float32)
    ref = np.clip(rng.normal([0.7, 0.5, 0.2], 0.1, (64, 64, 3)), 0, 1).astype(np.float32)
    out = transfer(src, None, ref, None, method)
    assert np.isfinite(out).all()
    # mean colour lands within 0.03 of the reference's, from 0.2-0.4 away
    assert np.abs(out.reshape(-1, 3).mean(0) - ref.reshape(-1, 3).mean(0)).max() < 0.03


@pytest.mark.parametrize("method", TRANSFER)
@pytest.mark.parametrize("case", ["flat_src", "flat_ref", "one_pixel_ref", "one_pixel_src", "black_ref",
                                  "saturated_ref", "hdr", "nan"])
def test_transfer_is_stable_on_degenerate_input(method, case):
    rng = np.random.default_rng(2)
    src = rng.random((32, 32, 3)).astype(np.float32)
    ref = rng.random((32, 32, 3)).astype(np.float32)
    sm = np.ones((32, 32), bool)
    rm = np.ones((32, 32), bool)
    if case == "flat_src":
        src[:] = 0.4
    elif case == "flat_ref":
        ref[:] = 0.4
    elif case == "one_pixel_ref":
        rm[:] = False
        rm[5, 5] = True
    elif case == "one_pixel_src":
        sm[:] = False
        sm[7, 9] = True
    elif case == "black_ref":
        ref[:] = 0.0
    elif case == "saturated_ref":
        ref[:] = 1.0
    elif case == "hdr":
        src *= 50.0
        ref *= 20.0
    elif case == "nan":
        src[3:6, 3:6] = np.nan
        ref[10:12] = np.inf
    out = transfer(src, sm, ref, rm, method)
    assert out.shape == src.shape and np.isfinite(out[sm]).all()
    assert (out[sm] >= 0).all()
    if case in ("flat_src", "one_pixel_src"):  # a flat source only shifts to the reference mean
        ref_mean = ref[rm].mean(0)  # (Lab methods match the Lab mean: a looser bound in BGR)
        assert np.abs(out[sm].mean(0) - ref_mean).max() < (0.05 if method == "mkl" else 0.12)
    if case in ("black_ref", "saturated_ref"):
        assert np.abs(out[sm].mean() - ref.mean()) < 0.1


def test_transfer_empty_mask_returns_source_bit_for_bit():
    img = _scene()
    ref = _scene(seed=5)[::-1].copy()
    empty = np.zeros(img.shape[:2], bool)
    for m in METHODS:
        assert np.array_equal(transfer(img, empty, ref, None, m), img)
        assert np.array_equal(transfer(img, None, ref, empty, m), img)


def test_transfer_rejects_bad_input():
    img = _scene()
    with pytest.raises(UserError, match="unknown colour transfer method"):
        transfer(img, None, img, None, "poisson")
    with pytest.raises(UserError, match="mask shape"):
        transfer(img, np.ones((3, 3), bool), img, None, "reinhard")


# ---------------- illumination

def test_sun_position_matches_known_noon_and_enu():
    # Greenwich, equinox 2026-03-20 ~12:07 UTC: sun due south at ~38.5 deg elevation (90 - 51.48 + ~0).
    el, az = sun_position(datetime(2026, 3, 20, 12, 7, tzinfo=timezone.utc), 51.4769, 0.0)
    assert abs(az - 180) < 2.5 and abs(el - 38.5) < 1.0
    d = enu_from_az_el(az, el)
    assert abs(np.linalg.norm(d) - 1) < 1e-9 and d[1] < -0.7 and abs(d[0]) < 0.05  # south, up
    night_el, _ = sun_position(datetime(2026, 3, 20, 0, 0, tzinfo=timezone.utc), 51.4769, 0.0)
    assert night_el < 0


def test_illumination_estimates_colour_cast_and_overcast():
    img = _scene()
    base = estimate_illumination(img)
    warm = img.astype(np.float32) * np.array([0.7, 0.9, 1.15])  # BGR: warmer light
    warm_est = estimate_illumination(np.clip(warm, 0, 255).astype(np.uint8))
    r0, _, b0 = base.illuminant_rgb
    r1, _, b1 = warm_est.illuminant_rgb
    assert r1 / b1 > 1.3 * (r0 / b0)
    grey = img.copy()
    grey[: img.shape[0] // 2] = (200, 200, 200)  # overcast: grey sky, no shadows
    ov = estimate_illumination(grey)
    assert not ov.sun_visible and ov.to_lighting()["sun_strength"] == 0.0
    light = ov.to_lighting()
    assert set(light) == {"sun_direction", "sun_strength", "sun_color", "sun_angle_deg", "sky_color",
                          "sky_strength", "sun_visible", "condition", "lights_on", "street_light",
                          "reflected_strength"}
    assert light["condition"] == "day" and not light["lights_on"] and light["street_light"] is None
    assert light["reflected_strength"] is None  # by day glossy rays see the sky that lights the objects
    assert all(np.isfinite(np.asarray(v, float)).all() for k, v in light.items()
               if k not in ("condition", "street_light", "reflected_strength"))


def test_illumination_detects_sun_from_road_shadows():
    img = _scene(240, 320)
    img[: 120] = (255, 255, 255)  # sky clipped white (a grey-white one is cloud): only the shadows can tell
    img[150:200, 40:200] = (35, 36, 38)  # a large cast shadow on the road, 1/3 brightness
    est = estimate_illumination(img)
    assert est.sun_visible and est.visibility_cue == "shadows"
    assert 0.4 < est.sun_fraction < 0.9
    light = est.to_lighting()
    assert light["sun_strength"] > 0 and light["sky_strength"] > 0


def test_illumination_stable_on_black_and_white_frames():
    for v in (0, 255):
        est = estimate_illumination(np.full((40, 60, 3), v, np.uint8))
        light = est.to_lighting()
        numbers = [light[k] for k in ("sun_direction", "sun_strength", "sun_color", "sky_color", "sky_strength")]
        assert all(np.isfinite(np.asarray(x, float)).all() for x in numbers)
    with pytest.raises(UserError, match="real_bgr"):
        estimate_illumination(np.zeros((10, 10), np.uint8))


def test_illumination_sun_direction_from_time_and_position():
    est = estimate_illumination(_scene(), when_utc=datetime(2026, 6, 21, 20, 0, tzinfo=timezone.utc),
                                latlon=(37.4, -122.1))  # ~13:00 PDT in California: high sun
    assert est.sun_direction_source == "ephemeris" and est.sun_elevation_deg > 60
    assert est.sun_direction[2] > 0.85


def _night_street(h=240, w=320, seed=1):
    """A dark street: black sky, dim road, a bright headlight pool on the road (bimodal road,
    the trap that used to read as sun shadows)."""
    rng = np.random.default_rng(seed)
    img = np.full((h, w, 3), 6, np.uint8)
    img[h // 2:] = (14, 15, 17)
    img[h // 2:] += rng.integers(0, 4, size=(h - h // 2, w, 1), dtype=np.uint8)
    img[170:230, 120:230] = (70, 90, 110)  # warm pool of light from a lamp
    cv2.circle(img, (260, 40), 6, (180, 230, 255), -1)  # the lamp itself
    return img


def test_dark_frame_is_night_without_sun_shadow():
    from blendgen.render.effects import decide_shadow_catcher, sun_direction

    est = estimate_illumination(_night_street())
    light = est.to_lighting()
    assert est.condition == "night" and not est.sun_visible and est.visibility_cue == "night"
    assert light["lights_on"] and light["sun_strength"] == 0.0 and not light["sun_visible"]
    # no sun shadow: the ground catches only the soft contact shadows of the street light and sky
    catcher = decide_shadow_catcher(light, {"rgba", "shadow_catcher"})
    assert catcher.value is True and "street-light" in catcher.reason and "no sun shadow" in catcher.reason
    assert sun_direction(light) is None
    street = light["street_light"]
    assert street["strength"] > 0 and street["direction"][2] > 0.9  # overhead key replaces the sun
    r, g, b = street["color"]
    assert r > b  # the lamps' warm colour, not daylight
    # Exposure follows the frame: the night key + ambient are far below a daylight frame's.
    day = estimate_illumination(_scene(240, 320)).to_lighting()
    assert street["strength"] + light["sky_strength"] < 0.2 * (day["sun_strength"] + day["sky_strength"])
    # mirrors show the dark scene, not the ambient that lights the objects
    assert light["reflected_strength"] == est.log_average_luminance < 0.5 * light["sky_strength"]


def test_dusk_from_sun_elevation():
    est = estimate_illumination(_scene(), sun_az_el=(250.0, 2.0))  # bright frame, sun 2 deg up
    assert est.condition == "dusk" and est.to_lighting()["lights_on"]
    # a clear sky: the sun is out, but 2 deg up it gives little of the light
    assert est.visibility_cue == "clear_sky" and est.sun_fraction < 0.2
    est = estimate_illumination(_scene(), sun_az_el=(250.0, -3.0))  # set
    assert est.condition == "dusk" and not est.sun_visible and est.to_lighting()["street_light"] is not None


def test_light_concrete_road_does_not_wash_objects_out():
    def frame(road_bgr):
        img = _scene(240, 320)
        img[120:160] = (60, 75, 70)  # verges, kerbs and walls between the sky and the road
        img[160:] = road_bgr
        return img

    asphalt = estimate_illumination(frame((80, 82, 85)))
    concrete = estimate_illumination(frame((185, 188, 192)))
    road_ratio = concrete.ground_luminance / asphalt.ground_luminance
    assert road_ratio > 4
    la, lc = asphalt.to_lighting(), concrete.to_lighting()
    light_ratio = (lc["sun_strength"] * 0.7 + lc["sky_strength"]) / (la["sun_strength"] * 0.7 + la["sky_strength"])
    # The scene's light rises by its log-average only, not by the road's albedo ratio.
    assert light_ratio < 0.5 * road_ratio
    assert concrete.road_albedo > 1.5 * asphalt.road_albedo


BDD_NIGHT = DATA / "real" / "bdd_street_photos" / "9aa94005-ff1d4c9a.jpg"


@pytest.mark.data
def test_illumination_on_real_night_street():
    if not BDD_NIGHT.is_file():
        pytest.skip(f"needs {BDD_NIGHT}")
    est = estimate_illumination(cv2.imread(str(BDD_NIGHT)))
    light = est.to_lighting()
    assert est.condition == "night" and not est.sun_visible
    assert light["lights_on"] and light["sun_strength"] == 0.0 and light["street_light"] is not None


@pytest.mark.data
def test_illumination_on_real_sunny_highway():
    if not REAL.is_file():
        pytest.skip(f"needs {REAL}")
    est = estimate_illumination(cv2.imread(str(REAL)))
    assert est.sun_visible and est.sky_fraction > 0.2
    assert 150 < est.horizon_row < 320  # 540 px high frame, horizon near the middle


# ---------------- sensor measures

def test_sensor_measures_noise_blur_jpeg_vignette():
    rng = np.random.default_rng(3)
    base = cv2.GaussianBlur((rng.random((256, 256)) * 255).astype(np.uint8), (0, 0), 3)
    base = cv2.normalize(base, None, 30, 220, cv2.NORM_MINMAX)
    noisy = np.clip(base + rng.normal(0, 6, base.shape), 0, 255).astype(np.uint8)
    assert sensor.noise_sigma(base) < sensor.NOISE_MIN_SIGMA
    assert 4.0 < sensor.noise_sigma(noisy) < 8.0
    sharp = (rng.random((128, 128)) > 0.5).astype(np.uint8) * 200
    assert sensor.blur_metric(cv2.GaussianBlur(sharp, (0, 0), 2)) > sensor.blur_metric(sharp) + 0.2
    ok, enc = cv2.imencode(".jpg", base, [cv2.IMWRITE_JPEG_QUALITY, 30])
    jpg = cv2.imdecode(enc, cv2.IMREAD_GRAYSCALE)
    prof = sensor.measure(cv2.cvtColor(jpg, cv2.COLOR_GRAY2BGR))
    assert prof.blockiness > sensor.BLOCKINESS_MIN and prof.jpeg_quality is not None and prof.jpeg_quality <= 50
    flat = np.full((180, 320), 160, np.float32)
    ys, xs = np.mgrid[0:180, 0:320]
    r2 = ((xs - 159.5) ** 2 + (ys - 89.5) ** 2) / (159.5 ** 2 + 89.5 ** 2)
    assert 0.25 < sensor.vignette_k((flat * (1 - 0.3 * r2)).astype(np.uint8)) < 0.35
    assert sensor.vignette_k(flat.astype(np.uint8)) < 0.02


def test_sensor_cache_measures_once_per_block_whatever_the_order():
    rng = np.random.default_rng(6)
    clean = _scene(240, 320)
    noisy = [np.clip(clean + rng.normal(0, 5, clean.shape), 0, 255).astype(np.uint8) for _ in range(12)]
    frames = {i: noisy[i] for i in range(12)}
    frames[7] = (clean // 2).astype(np.uint8)  # exposure change: half as bright, no noise
    frames[3] = cv2.GaussianBlur(frames[3], (0, 0), 2)  # motion blur on one frame
    reads = []

    def read(i):
        reads.append(i)
        return frames[i]

    a, b = sensor.SensorCache(read, block=5), sensor.SensorCache(read, block=5)
    forward = {i: a.profile(i, frames[i]) for i in range(12)}
    assert a.measured == 4 and reads == []  # frames 0, 5, 10 and the darker frame 7
    backward = {i: b.profile(i, frames[i]) for i in reversed(range(12))}
    assert forward == backward and sorted(reads) == [0, 5, 10]  # mid-block: it reads the first frame
    assert forward[4][1] == {"frame": 0, "blur_frame": 4} and forward[7][1]["frame"] == 7
    own, first = sensor.measure_frame(frames[4]), sensor.measure_frame(frames[0])
    assert forward[4][0].noise_sigma == first.noise_sigma > sensor.NOISE_MIN_SIGMA
    assert forward[4][0].blur_metric == own.blur_metric  # blur follows the motion: every frame's own
    assert forward[3][0].blur_metric == sensor.measure_frame(frames[3]).blur_metric > first.blur_metric + 0.1
    assert forward[7][0].noise_sigma < sensor.NOISE_MIN_SIGMA  # measured on itself, not on frame 5
    with pytest.raises(ValueError):
        sensor.SensorCache(read, block=0)

    def broken(i):
        raise UserError(f"frame {i} is truncated", where="frames/")

    c = sensor.SensorCache(broken, block=5)  # a bad first frame: the block's good frames measure themselves
    prof, src = c.profile(3, frames[3])
    assert prof == sensor.measure_frame(frames[3]) and src["frame"] == 3 and "unreadable" in src["reason"]


# ---------------- compositing

def test_composite_empty_mask_returns_background_bit_for_bit():
    real = _scene()
    h, w = real.shape[:2]
    passes = {"rgba": np.zeros((h, w, 4), np.float32), "index": np.zeros((h, w), np.int32),
              "shadow_catcher": np.ones((h, w, 3), np.float32)}
    for method in METHODS:
        out, info = composite_frame(real, passes, settings=Post(color_transfer=method), illumination=None, seed=0)
        assert np.array_equal(out, real)


def test_soft_contact_shadow_keeps_its_depth_and_its_patch_leaves_no_outline():
    """Without a sun, a vehicle's contact shadow lies right under it in a foreshortened catcher
    patch, which its render region cuts where the sky it hides is still ~0.85. Under the BDD day
    photo's van (catcher 0.05-0.08) the composite was only 15-25 % darker: a fade toward the
    region's edge over 30 % of the (object-merged) patch's inradius halved it. Now the border's
    value is divided out: the shadow keeps its depth and ends at 1 on the border."""
    h, w = 320, 320
    real = np.full((h, w, 3), 150, np.uint8)
    p = _passes(h, w, box=(40, 60, 230, 200), alpha_edge=False)  # a van close ahead
    sc = np.ones((h, w, 3), np.float32)
    sc[:300] = 1.0004  # the render region: the catcher's noise, never exactly 1
    sc[270:300] = 0.85  # the patch under the van, cut by the region's bottom edge
    sc[270:278, 70:250] = 0.07  # the contact shadow under the bumper
    p["shadow_catcher"] = sc
    s = Post(color_transfer="none", sensor_match=False, relight=False)
    out, _ = composite_frame(real, p, settings=s, illumination=None, seed=0)
    lin = (out[..., 0].astype(float) / 255) ** 2.2 / (150 / 255) ** 2.2
    assert lin[271:277, 100:220].max() < 0.12  # 0.07 / 0.85 = 0.08 of the road's light
    assert np.abs(out[290:300].astype(int) - 150).max() <= 2  # no step at the region's edge
    assert np.array_equal(out[301:], real[301:])


def test_sun_shadow_is_the_roads_own_colour_darkened():
    """The catcher under a clear blue sky is bluish (the render's sky light fills the shade):
    the composite darkens the road by its grey level, keeping the road's own colour, unless the
    frame's real shadows have a tint of their own, which then colours the deep shadow."""
    h, w = 200, 200
    real = np.full((h, w, 3), (96, 112, 128), np.uint8)  # a warm grey road (BGR)
    p = _passes(h, w, box=(20, 20, 60, 60), alpha_edge=False)
    sc = np.ones((h, w, 3), np.float32)
    sc[120:160, 40:160] = (0.20, 0.27, 0.33)  # RGB: sky-blue shade, as Cycles gives it
    p["shadow_catcher"] = sc
    s = Post(color_transfer="none", sensor_match=False, relight=False)
    out, _ = composite_frame(real, p, settings=s, illumination=None, seed=0)
    lin = lambda a: (a.astype(float) / 255) ** 2.2  # noqa: E731
    inner = (slice(125, 155), slice(50, 150))
    ratio = lin(out[inner]).reshape(-1, 3).mean(0) / lin(real[inner]).reshape(-1, 3).mean(0)
    assert ratio.max() < 0.4 and ratio.max() / ratio.min() < 1.05  # darker, same colour
    ill = estimate_illumination(_scene())
    ill.shadow_tint_rgb = (0.9, 1.0, 1.1)  # this frame's real shadows are a little blue
    out2, _ = composite_frame(real, p, settings=s, illumination=ill, seed=0)
    r2 = lin(out2[inner]).reshape(-1, 3).mean(0) / lin(real[inner]).reshape(-1, 3).mean(0)
    assert r2[0] / r2[2] == pytest.approx(1.1 / 0.9, rel=0.05)  # BGR: blue over red


def test_illumination_measures_the_tint_of_real_sun_shadows():
    img = _scene(240, 320)
    img[: 120] = (255, 255, 255)
    img[150:200, 40:200] = (40, 36, 34)  # a cast shadow, a little bluer than the road (BGR)
    est = estimate_illumination(img)
    assert est.sun_visible and est.shadow_tint_rgb is not None
    r, g, b = est.shadow_tint_rgb
    assert b > 1.02 and r < 0.98
    assert estimate_illumination(_scene()).shadow_tint_rgb is None  # no shadow: neutral


def test_composite_paste_touches_only_object_and_shadow():
    real = _scene()
    h, w = real.shape[:2]
    p = _passes(h, w)
    sc = np.ones((h, w, 3), np.float32)
    sc[72:80, 50:110] = 0.4  # a shadow under the object
    p["shadow_catcher"] = sc
    s = Post(color_transfer="none", sensor_match=False, relight=False)
    out, info = composite_frame(real, p, settings=s, illumination=None, seed=0)
    obj = p["index"] > 0
    rim = (p["rgba"][..., 3] > 0) & ~obj
    shadow_only = np.zeros_like(obj)
    shadow_only[74:78, 53:107] = True  # the shadow's interior (its edge is smoothed)
    shadow_only &= ~cv2.dilate((obj | rim).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    near = cv2.dilate(((sc[..., 0] < 1) | obj | rim).astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    untouched = ~near
    assert np.array_equal(out[untouched], real[untouched])
    # the object is the render's colour (linear 0.6, 0.1, 0.1 -> sRGB 203, 89, 89; BGR order)
    assert np.abs(out[obj].astype(int).mean(0) - [89, 89, 203]).max() <= 1
    assert (out[shadow_only].astype(int).sum(1) < real[shadow_only].astype(int).sum(1)).all()
    # anti-aliased rim lies between object and background
    assert (out[rim][:, 2].astype(int) > real[rim][:, 2].astype(int)).all()
    assert info["shadows"] and info["objects"][0]["id"] == 3
    s2 = Post(color_transfer="none", sensor_match=False, relight=False, shadows=False)
    out2, _ = composite_frame(real, p, settings=s2, illumination=None, seed=0)
    assert np.array_equal(out2[shadow_only], real[shadow_only])


@pytest.mark.parametrize("method", TRANSFER)
def test_composite_colour_transfer_pulls_toward_background(method):
    real = _scene()
    h, w = real.shape[:2]
    p = _passes(h, w, colour=(0.9, 0.9, 0.9), alpha_edge=False)  # a white object on grey road
    base, _ = composite_frame(real, p, settings=Post(color_transfer="none", sensor_match=False), illumination=None, seed=0)
    out, info = composite_frame(real, p, settings=Post(color_transfer=method, sensor_match=False),
                                illumination=None, seed=0)
    obj = p["index"] > 0
    assert out[obj].mean() < base[obj].mean() - 10
    assert info["objects"][0]["transfer"]["method"] == method


@pytest.mark.parametrize("case", ["nan", "hdr", "one_pixel", "black_bg", "saturated_bg", "no_index", "no_lighting"])
def test_composite_is_stable_on_hard_cases(case):
    real = _scene()
    h, w = real.shape[:2]
    p = _passes(h, w)
    il = estimate_illumination(real)
    if case == "nan":
        p["rgba"][45:50, 65:70] = np.nan
        p["shadow_catcher"] = np.full((h, w, 3), np.nan, np.float32)
    elif case == "hdr":
        p["rgba"][..., :3] *= 40.0
        p["rgba"][41, 61, :3] = np.inf
    elif case == "one_pixel":
        p = _passes(h, w, box=(50, 50, 1, 1), alpha_edge=False)
    elif case == "black_bg":
        real = np.zeros_like(real)
    elif case == "saturated_bg":
        real = np.full_like(real, 255)
    elif case == "no_index":
        del p["index"]
    if case != "no_lighting":
        ones = np.ones((h, w, 3), np.float32)
        p.update(diffuse_direct=ones * 0.8, diffuse_indirect=ones * 0.2, diffuse_color=ones * 0.5)
    for method in METHODS:
        out, info = composite_frame(real, p, settings=Post(color_transfer=method), illumination=il, seed=1)
        assert out.dtype == np.uint8 and out.shape == real.shape
        assert info["timings_ms"]["total"] >= 0


def test_composite_relight_matches_light_colour_to_estimate():
    real = _scene()
    warm = np.clip(real.astype(np.float32) * np.array([0.6, 0.9, 1.2]), 0, 255).astype(np.uint8)
    il = estimate_illumination(warm)  # a warm scene illuminant
    h, w = real.shape[:2]
    p = _passes(h, w, colour=(0.4, 0.4, 0.4), alpha_edge=False)
    obj = p["index"] > 0
    dd = np.zeros((h, w, 3), np.float32)
    dd[..., :] = (0.6, 0.8, 1.2)  # the render's light is bluish (RGB)
    di = np.full((h, w, 3), 0.2, np.float32)
    dc = np.full((h, w, 3), 0.5, np.float32)
    p["rgba"][obj, :3] = (dc * (dd + di))[obj]
    p.update(diffuse_direct=dd, diffuse_indirect=di, diffuse_color=dc)
    s = Post(color_transfer="none", sensor_match=False)
    before, _ = composite_frame(warm, p, settings=Post(color_transfer="none", sensor_match=False, relight=False),
                               illumination=il, seed=0)
    out, info = composite_frame(warm, p, settings=s, illumination=il, seed=0)
    assert info["relight"]["relight"] == "applied"
    r0, b0 = before[obj][:, 2].mean(), before[obj][:, 0].mean()
    r1, b1 = out[obj][:, 2].mean(), out[obj][:, 0].mean()
    assert b0 > r0 and r1 > b1  # bluish -> warm like the scene
    lum = lambda im: (im[obj].astype(float) @ [0.0722, 0.7152, 0.2126]).mean()
    assert abs(lum(out) - lum(before)) < 12  # colour changes, brightness about kept


def test_composite_rejects_mismatched_passes():
    real = _scene()
    with pytest.raises(UserError, match="'rgba' has shape"):
        composite_frame(real, {"rgba": np.zeros((10, 10, 4), np.float32)}, settings=Post(), illumination=None, seed=0)
    with pytest.raises(UserError, match="missing"):
        composite_frame(real, {}, settings=Post(), illumination=None, seed=0)


def test_composite_sensor_matching_adds_measured_noise_only_when_present():
    rng = np.random.default_rng(4)
    clean = _scene(240, 320)
    noisy = np.clip(clean.astype(float) + rng.normal(0, 5, clean.shape), 0, 255).astype(np.uint8)
    h, w = clean.shape[:2]
    p = _passes(h, w, box=(120, 100, 60, 80), colour=(0.3, 0.3, 0.3), alpha_edge=False)
    s = Post(color_transfer="none", relight=False)
    _, info_clean = composite_frame(clean, p, settings=s, illumination=None, seed=0)
    out, info_noisy = composite_frame(noisy, p, settings=s, illumination=None, seed=0)
    assert "noise_sigma" not in info_clean["sensor"]["applied"]
    assert "noise_sigma" in info_noisy["sensor"]["applied"]
    assert out[125:175, 105:175].astype(float).std() > 2.5
    # a cached profile (the frame processor's) gives the same composite as measuring the frame
    cached, info = composite_frame(noisy, p, settings=s, illumination=None, seed=0,
                                   sensor_profile=sensor.measure_frame(noisy))
    assert np.array_equal(cached, out) and info["sensor"] == info_noisy["sensor"]
    # and the profile given is the one applied: the clean frame gets the noisy camera's noise
    _, info_given = composite_frame(clean, p, settings=s, illumination=None, seed=0,
                                    sensor_profile=sensor.measure_frame(noisy))
    assert "noise_sigma" in info_given["sensor"]["applied"]


def test_composite_at_720p_is_finite_and_repeatable():
    rng = np.random.default_rng(5)
    real = cv2.GaussianBlur(rng.integers(0, 255, (720, 1280, 3), dtype=np.uint8), (0, 0), 2)
    p = _passes(720, 1280, box=(300, 500, 200, 300))
    ones = np.ones((720, 1280, 3), np.float32)
    p.update(diffuse_direct=ones * 0.8, diffuse_indirect=ones * 0.2, diffuse_color=ones * 0.5,
             shadow_catcher=ones.copy())
    p["shadow_catcher"][500:540, 480:820] = 0.5
    il = estimate_illumination(real)
    # its time per frame is measured by benchmarks/post/bench_post.py --timing
    a, _ = composite_frame(real, p, settings=Post(color_transfer="mkl"), illumination=il, seed=0)
    b, _ = composite_frame(real, p, settings=Post(color_transfer="mkl"), illumination=il, seed=0)
    assert a.shape == real.shape and np.array_equal(a, b)


def test_composite_color_strength_scales_the_transfer():
    real = _scene()
    h, w = real.shape[:2]
    p = _passes(h, w, colour=(0.9, 0.9, 0.9), alpha_edge=False)
    obj = p["index"] > 0
    base = dict(sensor_match=False, relight=False)
    none, _ = composite_frame(real, p, settings=Post(color_transfer="none", **base), illumination=None, seed=0)
    zero, _ = composite_frame(real, p, settings=Post(color_transfer="reinhard", color_strength=0.0, **base),
                              illumination=None, seed=0)
    auto, _ = composite_frame(real, p, settings=Post(color_transfer="reinhard", **base), illumination=None, seed=0)
    full, _ = composite_frame(real, p, settings=Post(color_transfer="reinhard", color_strength=1.0, **base),
                              illumination=None, seed=0)
    assert np.array_equal(zero, none)
    assert none[obj].mean() > auto[obj].mean() > full[obj].mean()
