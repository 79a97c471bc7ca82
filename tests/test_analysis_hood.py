"""Ego hood / dashboard (blendgen.analysis.hood) on real dashcam photos and a video."""

import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from blendgen.analysis.hood import hood_in_still, hood_in_video

# ../shared/data from the project root; BLENDGEN_SHARED_DATA points elsewhere (e.g. from a worktree)
REAL = Path(os.environ.get("BLENDGEN_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")) / "real"
pytestmark = pytest.mark.data


def need(rel: str) -> Path:
    p = REAL / rel
    if not p.exists():
        pytest.skip(f"needs ../shared/data/real/{rel}")
    return p


def top_at(poly, u):
    edge = np.array(poly[:-2])
    return float(np.interp(u, edge[:, 0], edge[:, 1]))


# hood top edge at the centre column, read off the photos by eye (+- 30 px)
@pytest.mark.parametrize("name,top", [("0ace96c3-48481887.jpg", 578), ("7dd9ef45-f197db95.jpg", 605),
                                      ("9aa94005-ff1d4c9a.jpg", 640)])
def test_bdd_hood_found(name, top):
    im = cv2.imread(str(need(f"bdd_street_photos/{name}")))
    poly, why = hood_in_still(im)
    assert poly is not None, why
    assert abs(top_at(poly, 640) - top) <= 30, top_at(poly, 640)
    assert poly[-1] == [0.0, 719.0] and poly[-2] == [1279.0, 719.0]


def test_udacity_hood_found_and_highway_has_none():
    for n in ("straight_lines1.jpg", "straight_lines2.jpg"):
        poly, why = hood_in_still(cv2.imread(str(need(f"udacity_lane_camera/{n}"))))
        assert poly is not None and 640 <= top_at(poly, 640) <= 680, why
    for p in sorted(need("udacity_highway_images").glob("*.jpg")):
        poly, why = hood_in_still(cv2.imread(str(p)))
        assert poly is None, (p.name, why)


def test_video_static_bottom_is_the_hood():
    cap = cv2.VideoCapture(str(need("udacity_solidWhiteRight.mp4")))
    frames = []
    while len(frames) < 200:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(f)
    frames = frames[::8]
    poly, why = hood_in_video(frames)
    assert poly is None, why                      # the road moves: no hood
    # the same drive seen over a dark, glossy hood whose edge bulges up in the middle
    h, w = frames[0].shape[:2]
    u = np.arange(w)
    edge = (h - 70 + 25 * ((u - w / 2) / (w / 2)) ** 2).astype(int)
    rows = np.arange(h)[:, None]
    hood = rows >= edge[None, :]
    shade = np.clip(40 + 0.3 * (rows - edge[None, :]), 0, 255)
    with_hood = [np.where(hood[..., None], shade[..., None].astype(np.uint8), f) for f in frames]
    poly, why = hood_in_video(with_hood)
    assert poly is not None, why
    for x in (100, w // 2, w - 100):
        assert abs(top_at(poly, x) - edge[x]) <= 6, (x, top_at(poly, x), edge[x])
