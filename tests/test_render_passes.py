"""Frame EXR assembly restricted to the regions' box: the same file contents as before."""

import numpy as np
import pytest

from blendgen.geometry import Camera
from blendgen.render.exr import empty_passes, read_passes, write_passes
from blendgen.render.passes import write_frame
from blendgen.render.projection import make_canvas

KEYS = ["rgba", "index", "depth", "shadow_catcher", "diffuse_direct", "diffuse_indirect", "diffuse_color",
        "glossy_direct", "glossy_indirect", "glossy_color"]


def _old_to_output(canvas, img, nearest=False, border=0.0):
    """Canvas.to_output before issue 17: float maps over the whole canvas."""
    if not canvas.remapped:
        return img
    import cv2

    if img.ndim == 3 and img.shape[2] > 4:
        return np.stack([_old_to_output(canvas, img[..., c], nearest, border) for c in range(img.shape[2])], axis=2)
    return cv2.remap(img, canvas.map_x, canvas.map_y, cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=border)


def _reference_write(path, raws, keys, regions, canvas, union, out_region):
    """RenderSession._uncrop / _finish_passes / write_passes before issue 17 (full frame)."""
    pin = canvas.pinhole
    if regions is None:
        raw = raws[0]
    else:
        raw = {}
        for r, (x0, y0, x1, y1) in zip(raws, regions):
            for k, a in r.items():
                if k not in raw:
                    raw[k] = np.full((pin.height, pin.width) + a.shape[2:], 1.0 if k == "shadow_catcher" else 0,
                                     dtype=a.dtype)
                raw[k][y0:y1, x0:x1] = a
    out = {}
    for k in keys:
        if k not in raw:
            out[k] = empty_passes(pin.width, pin.height, [k])[k]
            continue
        a = raw[k]
        if k == "shadow_catcher":
            valid = np.zeros(a.shape[:2], bool)
            if regions is None:
                valid[:] = True
            for x0, y0, x1, y1 in regions or []:
                valid[y0:y1, x0:x1] = True
            a = np.where(valid[..., None] & (a.sum(axis=2, keepdims=True) > 0), a, 1.0).astype(np.float32)
        if k == "index":
            a = _old_to_output(canvas, a.astype(np.float32), nearest=True)
        elif k == "shadow_catcher":
            a = _old_to_output(canvas, a, border=1.0)
        else:
            a = _old_to_output(canvas, a)
        out[k] = np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0)
    write_passes(path, out, window=out_region)


def _region_raws(rng, regions, keys):
    """What read_passes gives for Blender's cropped renders: noise, NaN/inf, empty catcher pixels."""
    raws = []
    for x0, y0, x1, y1 in regions:
        h, w = y1 - y0, x1 - x0
        r = {}
        for k in keys:
            if k == "index":
                r[k] = rng.integers(0, 6, size=(h, w)).astype(np.int32)
            elif k == "depth":
                r[k] = np.where(rng.random((h, w)) < 0.3, 0.0, rng.uniform(1, 80, (h, w))).astype(np.float32)
            else:
                a = rng.normal(0.4, 0.5, size=(h, w, 4 if k == "rgba" else 3)).astype(np.float32)
                if k == "shadow_catcher":
                    a[rng.random((h, w)) < 0.3] = 0.0  # no catcher hit: must become 1
                bad = rng.random(a.shape) < 0.01
                a[bad] = rng.choice(np.array([np.nan, np.inf, -np.inf], np.float32), size=int(bad.sum()))
                r[k] = a
        raws.append(r)
    return raws


def _union(regions):
    r = np.array(regions)
    return (int(r[:, 0].min()), int(r[:, 1].min()), int(r[:, 2].max()), int(r[:, 3].max()))


CAMS = {"pinhole": Camera(160, 90, 120.0, 120.0, 79.3, 45.1),
        "distorted": Camera(160, 90, 100.0, 100.0, 80.5, 44.0, [-0.25, 0.08, 0.001, -0.0005, 0.0])}


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")  # inf - inf in the catcher sum, as before
@pytest.mark.parametrize("cam", sorted(CAMS))
def test_write_frame_same_exr_contents_as_full_frame(tmp_path, cam):
    canvas = make_canvas(CAMS[cam])
    pin = canvas.pinhole
    rng = np.random.default_rng(0)
    W, H = pin.width, pin.height
    cases = [
        [(10, 12, 60, 40)],                                      # one region
        [(3, 20, 40, 70), (100, 5, W - 1, 30)],                  # opposite sides
        [(20, 20, 70, 60), (50, 40, 110, H)],                    # overlapping, touching the bottom
        [(0, 0, 30, 25), (W - 30, H - 20, W, H)],                # canvas corners
        None,                                                    # full frame
    ]
    for regions in cases:
        for keys in (KEYS, ["rgba", "index", "shadow_catcher"], ["rgba", "depth"]):
            raw_keys = [k for k in keys if k != "shadow_catcher" or regions is None or len(keys) > 3]
            rs = regions or [(0, 0, W, H)]
            raws = _region_raws(rng, rs, raw_keys)
            union = _union(regions) if regions else None
            out_region = canvas.region_to_output(union) if union else None
            want, got = tmp_path / "want.exr", tmp_path / "got.exr"
            _reference_write(want, [{k: v.copy() for k, v in r.items()} for r in raws], keys, regions, canvas,
                             union, out_region)
            write_frame(got, raws, keys, regions, canvas, union)
            a, b = read_passes(want), read_passes(got)
            assert sorted(a) == sorted(b) == sorted(keys)
            for k in keys:
                assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, k
                # bit for bit, NaN-free, -0.0 kept
                assert a[k].tobytes() == b[k].tobytes(), (cam, regions, k)
            if "shadow_catcher" in keys and regions:
                assert (b["shadow_catcher"] == 1).mean() > 0.3  # outside and no-hit pixels read "unshadowed"


def test_write_passes_window_arrays_checked(tmp_path):
    p = {"rgba": np.zeros((5, 6, 4), np.float32)}
    write_passes(tmp_path / "ok.exr", p, window=(2, 3, 8, 8), frame_size=(10, 9))
    assert read_passes(tmp_path / "ok.exr")["rgba"].shape == (9, 10, 4)
    with pytest.raises(ValueError, match="window"):
        write_passes(tmp_path / "bad.exr", p, window=(2, 3, 9, 8), frame_size=(10, 9))
    with pytest.raises(ValueError, match="inside"):
        write_passes(tmp_path / "bad.exr", p, window=(6, 3, 12, 8), frame_size=(10, 9))


def test_write_passes_codecs_lossless(tmp_path):
    from blendgen.render.exr import COMPRESSIONS

    rng = np.random.default_rng(5)
    p = {"rgba": rng.normal(size=(30, 40, 4)).astype(np.float32), "index": rng.integers(0, 9, (30, 40)),
         "shadow_catcher": rng.random((30, 40, 3)).astype(np.float32)}
    p["rgba"][:10] = 0.0  # runs for RLE
    want = None
    for codec in COMPRESSIONS:
        write_passes(tmp_path / f"{codec}.exr", p, window=(3, 2, 37, 29), compression=codec)
        got = read_passes(tmp_path / f"{codec}.exr")
        if want is None:
            want = got
        for k in p:
            assert got[k].tobytes() == want[k].tobytes(), (codec, k)
    assert (tmp_path / "none.exr").stat().st_size > (tmp_path / "zip.exr").stat().st_size
    with pytest.raises(ValueError, match="compression"):
        write_passes(tmp_path / "x.exr", p, compression="dwaa")  # lossy: not offered
