"""The post stage's crop window (issue 17): working on the window around the objects and
the catcher patches gives the same composite as working on the whole frame."""

import cv2
import numpy as np
import pytest

from blendgen.job.schema import Post
from blendgen.post.colorspace import linear_to_srgb, linear_to_srgb_exact, srgb_to_linear, srgb_to_linear_exact
from blendgen.post.composite import WINDOW_GRID, composite_frame
from blendgen.post.illumination import estimate_illumination

H, W = 240, 320


def _real(seed=0, dark=False):
    """A textured, noisy, JPEG-compressed road frame (so sensor matching applies noise/JPEG)."""
    rng = np.random.default_rng(seed)
    img = np.zeros((H, W, 3), np.float32)
    img[: H // 2] = (220, 170, 120)
    img[H // 2:] = (90, 92, 95)
    img += rng.normal(0, 6, img.shape)
    img += 25 * np.sin(np.arange(W) / 7.0)[None, :, None]
    if dark:
        img *= 0.12
    u8 = np.clip(img, 0, 255).astype(np.uint8)
    return cv2.imdecode(cv2.imencode(".jpg", u8, [cv2.IMWRITE_JPEG_QUALITY, 55])[1], cv2.IMREAD_COLOR)


def _passes(objects, patches):
    """rgba/index/lighting/catcher passes: `objects` (id, y, x, h, w, rgb) boxes with a half
    alpha rim; `patches` (y, x, h, w, darkness) catcher patches with a darker core."""
    rgba = np.zeros((H, W, 4), np.float32)
    idx = np.zeros((H, W), np.int32)
    dd = np.zeros((H, W, 3), np.float32)
    for oid, y, x, h, w, rgb in objects:
        rgba[y:y + h, x:x + w, :3] = rgb
        rgba[y:y + h, x:x + w, 3] = 1.0
        idx[y:y + h, x:x + w] = oid
        dd[y:y + h, x:x + w] = (0.9, 0.8, 0.7)
        if x + w < W:  # anti-aliased rim
            rgba[y:y + h, x + w, :3] = np.array(rgb) * 0.5
            rgba[y:y + h, x + w, 3] = 0.5
    sc = np.ones((H, W, 3), np.float32)
    for y, x, h, w, dark in patches:
        sc[y:y + h, x:x + w] = 0.985  # the catcher's small global bias
        sc[y + h // 4:y + 3 * h // 4, x + w // 4:x + 3 * w // 4] = dark
    return {"rgba": rgba, "index": idx, "shadow_catcher": sc, "diffuse_direct": dd,
            "diffuse_indirect": dd * 0.2, "diffuse_color": np.full((H, W, 3), 0.5, np.float32)}


CASES = {
    "edges": ([(1, 0, 0, 30, 40, (0.6, 0.1, 0.1)), (2, 100, W - 25, 60, 25, (0.1, 0.2, 0.5)),
               (3, H - 20, 130, 20, 50, (0.4, 0.4, 0.1))],
              [(H - 40, W - 60, 40, 60, 0.4), (0, 0, 50, 70, 0.5)]),
    "one pixel": ([(5, 120, 160, 1, 1, (0.9, 0.9, 0.9)), (6, 0, W - 1, 1, 1, (0.2, 0.9, 0.2))], []),
    "shadow only": ([], [(150, 100, 40, 80, 0.3)]),
    "middle": ([(7, 110, 140, 50, 40, (0.3, 0.3, 0.35)), (9, 130, 200, 30, 30, (0.5, 0.1, 0.1))],
               [(150, 120, 30, 120, 0.35)]),
}


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("setting", ["default", "reinhard", "night"])
def test_window_equals_full_frame(case, setting):
    real = _real(dark=setting == "night")
    passes = _passes(*CASES[case])
    est = estimate_illumination(real)
    if setting == "night":
        assert est.condition != "day"  # the local-light path (band under the object) runs
    post = Post(color_transfer="reinhard") if setting == "reinhard" else Post()
    crop, info = composite_frame(real, passes, settings=post, illumination=est, seed=3)
    full, _ = composite_frame(real, passes, settings=post, illumination=est, seed=3, crop=False)
    diff = np.abs(crop.astype(np.int16) - full)
    mse = float((diff.astype(np.float64) ** 2).mean())
    assert diff.max() <= 1 and (mse == 0 or 10 * np.log10(255 ** 2 / mse) >= 54)
    x, y, w, h = info["window_xywh"]
    assert x % WINDOW_GRID == 0 and y % WINDOW_GRID == 0
    changed = np.any(crop != real, axis=2)
    assert changed.any()
    inside = np.zeros((H, W), bool)
    inside[y:y + h, x:x + w] = True
    assert not (changed & ~inside).any()  # nothing outside the window is touched


def test_empty_passes_return_the_frame():
    real = _real()
    passes = _passes([], [])
    out, info = composite_frame(real, passes, settings=Post(), illumination=estimate_illumination(real), seed=0)
    assert np.array_equal(out, real) and "window_xywh" not in info


def test_lookup_tables_are_exact_enough():
    x = np.random.default_rng(0).random(200000).astype(np.float32)
    x[:3] = (0.0, 1.0, 0.0031308)
    assert np.abs(srgb_to_linear(x) - srgb_to_linear_exact(x)).max() < 1e-4
    assert np.abs(linear_to_srgb(x) - linear_to_srgb_exact(x)).max() < 1e-4
    assert linear_to_srgb(np.array([np.nan, np.inf, 2.0, -1.0], np.float32)).tolist() == [0.0, 1.0, 1.0, 0.0]
