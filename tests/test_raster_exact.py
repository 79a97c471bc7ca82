"""The vectorised rasteriser marks exactly the pixels the per-triangle reference marked."""

import numpy as np
import pytest

from blendgen.render.raster import fill_triangles


def _reference_fill(mask, P, small=8):
    """fill_triangles before issue 17 (large triangles one by one over np.mgrid): the reference."""
    H, W = mask.shape
    P = P[np.all(np.isfinite(P), axis=(1, 2))]
    if len(P) == 0:
        return
    lo, hi = P.min(axis=1), P.max(axis=1)
    x0 = np.clip(np.ceil(lo[:, 0]), 0, W - 1).astype(np.int64)
    x1 = np.clip(np.floor(hi[:, 0]), 0, W - 1).astype(np.int64)
    y0 = np.clip(np.ceil(lo[:, 1]), 0, H - 1).astype(np.int64)
    y1 = np.clip(np.floor(hi[:, 1]), 0, H - 1).astype(np.int64)
    ok = (x1 >= x0) & (y1 >= y0) & (hi[:, 0] >= 0) & (hi[:, 1] >= 0) & (lo[:, 0] <= W - 1) & (lo[:, 1] <= H - 1)
    a, b, c = P[:, 0], P[:, 1], P[:, 2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    ok &= np.abs(area) > 1e-12
    sw, sh = x1 - x0 + 1, y1 - y0 + 1
    is_small = ok & (sw <= small) & (sh <= small)

    def inside(px, py, a, b, c, sgn):
        e0 = (b[..., 0] - a[..., 0]) * (py - a[..., 1]) - (b[..., 1] - a[..., 1]) * (px - a[..., 0])
        e1 = (c[..., 0] - b[..., 0]) * (py - b[..., 1]) - (c[..., 1] - b[..., 1]) * (px - b[..., 0])
        e2 = (a[..., 0] - c[..., 0]) * (py - c[..., 1]) - (a[..., 1] - c[..., 1]) * (px - c[..., 0])
        return (sgn * e0 >= 0) & (sgn * e1 >= 0) & (sgn * e2 >= 0)

    oy, ox = np.divmod(np.arange(small * small), small)
    small_idx = np.nonzero(is_small)[0]
    for k in range(0, len(small_idx), 16384):
        idx = small_idx[k:k + 16384]
        px = x0[idx, None] + ox[None, :]
        py = y0[idx, None] + oy[None, :]
        sel = (px <= x1[idx, None]) & (py <= y1[idx, None])
        sgn = np.sign(area[idx])[:, None]
        sel &= inside(px.astype(float), py.astype(float), a[idx, None], b[idx, None], c[idx, None], sgn)
        mask[py[sel], px[sel]] = 1
    for i in np.nonzero(ok & ~is_small)[0]:
        ys, xs = np.mgrid[y0[i]:y1[i] + 1, x0[i]:x1[i] + 1]
        sel = inside(xs.astype(float), ys.astype(float), a[i], b[i], c[i], np.sign(area[i]))
        mask[ys[sel], xs[sel]] = 1


def _random_triangles(rng, W, H):
    n = 160
    parts = []
    # sizes from sub-pixel to several frames wide, centred on and off screen
    for scale in (0.5, 3, 7.9, 12, 40, 150, 700, 5000):
        c = rng.uniform([-0.3 * W, -0.3 * H], [1.3 * W, 1.3 * H], size=(n // 8, 1, 2))
        parts.append(c + rng.normal(scale=scale, size=(n // 8, 3, 2)))
    # integer vertices: pixel centres exactly on edges and corners (the >= 0 tie rule)
    parts.append(rng.integers(-5, max(W, H) + 5, size=(100, 3, 2)).astype(float))
    # degenerate: collinear, repeated vertices, zero-area slivers, non-finite
    p = rng.uniform(0, W, size=(50, 1, 2))
    d = rng.normal(size=(50, 1, 2))
    parts.append(np.concatenate([p, p + d, p + 2.5 * d], axis=1))
    parts.append(np.repeat(rng.uniform(0, W, size=(20, 1, 2)), 3, axis=1))
    thin = rng.uniform(0, W, size=(50, 3, 2))
    thin[:, 2] = thin[:, 1] + 1e-9
    parts.append(thin)
    bad = rng.uniform(0, W, size=(10, 3, 2))
    bad[:5, 0, 0] = np.nan
    bad[5:, 1, 1] = np.inf
    parts.append(bad)
    # long and thin: wide bounding box, few pixels
    a = rng.uniform([0, 0], [W, H], size=(60, 1, 2))
    parts.append(np.concatenate([a, a + [[W * 0.9, 1.5]], a + [[0.3, 40.0]]], axis=1))
    return parts


def _check_against_reference(sizes, rounds, seed):
    rng = np.random.default_rng(seed)
    for W, H in sizes:
        for _ in range(rounds):
            groups = _random_triangles(rng, W, H)
            partial = 0
            # each kind of triangle on its own (huge ones alone cover the whole frame), then all
            for P in groups + [np.concatenate(groups)]:
                want = np.zeros((H, W), np.uint8)
                _reference_fill(want, P)
                got = np.zeros((H, W), np.uint8)
                fill_triangles(got, P)
                assert np.array_equal(got, want), (W, H, len(P), int((got != want).sum()))
                partial += bool(0 < want.sum() < want.size)
            if W * H > 1000:  # not vacuous: most groups set some pixels and leave others
                assert partial >= 7, partial


def test_fill_triangles_matches_reference_bit_for_bit():
    _check_against_reference(((320, 180), (97, 61), (1, 1), (3, 200)), rounds=2, seed=17)


@pytest.mark.slow
def test_fill_triangles_matches_reference_full_hd():
    _check_against_reference(((1280, 720), (1920, 1080)), rounds=2, seed=18)


def test_fill_triangles_small_batches_same_as_one(monkeypatch):
    """The batch size bounds memory only: tiny batches (one triangle each) give the same mask."""
    import blendgen.render.raster as R

    rng = np.random.default_rng(3)
    groups = _random_triangles(rng, 320, 240)
    P = np.concatenate(groups[:6] + groups[-1:])  # not the frame-covering ones
    want = np.zeros((240, 320), np.uint8)
    fill_triangles(want, P)
    monkeypatch.setattr(R, "BATCH_PX", 1)
    got = np.zeros((240, 320), np.uint8)
    fill_triangles(got, P)
    assert np.array_equal(got, want)
    assert 0 < want.sum() < want.size
