"""The ego vehicle's hood and dashboard at the bottom of the frame (bpy-free).

Entry point (called by the analysis stage):

    find_hood(rec, frame_ids, *, progress=False) -> {frame_id: polygon | None}

A polygon is [[u, v], ...] in the recording's pixels, closed along the bottom edge; None
means no hood is seen. The hood is a real occluder: nothing is placed on it and virtual
objects behind it are hidden by it.

- Video (frames in temporal order, >= 8 of them): the hood does not change while the road
  does. The still search below runs on the mean of up to 40 frames spread over the
  recording (the moving road blurs away, the hood edge stays sharp) and the region below
  the edge must be static (temporal standard deviation < 6 grey levels on 80 % of it).
  One polygon for all frames.
- Stills of one camera (>= 3): each frame's edge below, then `mount.hood_consensus`: where most
  frames found it at one place, that hood in every frame; found in a minority, none.
- Still: a smooth curve across the whole width in the bottom band (dynamic programming
  over 4-pixel column bins on the vertical gradient, at most one row per bin: slopes up to
  14 deg), accepted when it is a strong edge along most of its length, close to a
  parabola, the region below it differs in colour from the road above it, and no line of the
  scene runs on across it (lane lines and kerbs end at a hood's edge, and cross a shadow's or a
  kerb's on the road: the next edge below is tried).
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

log = logging.getLogger(__name__)

BAND = 0.30          # the hood is searched in the bottom 30 % of the frame
WORK_WIDTH = 320     # detection runs on a frame downscaled to this width
MIN_HEIGHT = 0.025   # a hood lower than this fraction of the frame is ignored
N_VIDEO = 40
BIN = 4              # columns per step of the edge path (at WORK_WIDTH)
CONSENSUS_MIN_FRAMES = 3   # stills: from this many frames on, the camera's hood is their consensus
CROSS_PX = 5         # a scene line crosses an edge when it runs this far (px at WORK_WIDTH) on both sides


def _gray_small(bgr: np.ndarray) -> tuple[np.ndarray, float]:
    gray = bgr if bgr.ndim == 2 else cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    s = WORK_WIDTH / gray.shape[1]
    return cv2.resize(gray, (WORK_WIDTH, max(1, round(gray.shape[0] * s))), interpolation=cv2.INTER_AREA), s


def _best_path(cost: np.ndarray, max_step: int = 1) -> np.ndarray:
    """Row per column of the path that maximises the summed `cost`, moving at most
    max_step rows between neighbouring columns (Viterbi over columns)."""
    h, w = cost.shape
    acc = cost[:, 0].copy()
    back = np.zeros((h, w), dtype=np.int32)
    rows = np.arange(h)
    for x in range(1, w):
        best_prev = np.full(h, -np.inf)
        arg = rows.copy()
        for d in range(-max_step, max_step + 1):
            src = np.clip(rows + d, 0, h - 1)
            cand = acc[src]
            better = cand > best_prev
            best_prev = np.where(better, cand, best_prev)
            arg = np.where(better, src, arg)
        acc = best_prev + cost[:, x]
        back[:, x] = arg
    path = np.empty(w, dtype=np.int32)
    path[-1] = int(acc.argmax())
    for x in range(w - 1, 0, -1):
        path[x - 1] = back[path[x], x]
    return path


def _edge_strength(gray: np.ndarray) -> np.ndarray:
    """Vertical gradient magnitude (a hood edge is mostly horizontal)."""
    g = cv2.GaussianBlur(gray.astype(np.float32), (5, 5), 1.2)
    return np.abs(cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3))


def _polygon(path_rows: np.ndarray, y0: int, s: float, width: int, height: int, n: int = 33) -> list[list[float]]:
    xs = np.linspace(0, len(path_rows) - 1, n)
    vs = np.interp(xs, np.arange(len(path_rows)), path_rows.astype(float)) + y0
    us = (xs + 0.5) / s - 0.5
    vs = np.minimum((vs + 0.5) / s - 0.5, height - 1)
    us[0], us[-1] = 0.0, width - 1.0
    pts = [[float(u), float(v)] for u, v in zip(us, vs)]
    return pts + [[width - 1.0, height - 1.0], [0.0, height - 1.0]]


def _path(eb: np.ndarray, width: int) -> np.ndarray:
    path = np.repeat(_best_path(eb), BIN)
    return np.r_[path, np.full(width - len(path), path[-1])]


def hood_in_still(bgr: np.ndarray, min_strong: float = 0.58) -> tuple[list[list[float]] | None, str]:
    """The hood of one frame, or None, and a sentence saying why. `min_strong`: the fraction
    of the width along which the edge must be strong."""
    H, W = bgr.shape[:2]
    gray, s = _gray_small(bgr)
    h = gray.shape[0]
    y0 = int(h * (1 - BAND))
    e = _edge_strength(gray[y0:])
    e[:2] = e[-2:] = 0
    ref = float(np.median(e)) + 1.0
    eb = e[:, : e.shape[1] // BIN * BIN].reshape(e.shape[0], -1, BIN).mean(axis=2)
    colour = cv2.resize(bgr, (gray.shape[1], h), interpolation=cv2.INTER_AREA).astype(np.float32)
    cols = np.arange(e.shape[1])

    def check(path, min_strong=min_strong, min_contrast=3.5, colour_test=True) -> str | None:
        along = e[path, cols]
        strong = float(np.mean(along > 3 * ref))
        if np.median(h - 1 - (path + y0)) < MIN_HEIGHT * h:
            return "no edge above the bottom rows"
        if strong < min_strong or np.median(along) < min_contrast * ref:
            return (f"no continuous edge across the bottom band ({strong:.0%} of the width strong, "
                    f"need {min_strong:.0%}; median contrast {np.median(along) / ref:.1f}, need {min_contrast})")
        x = np.linspace(-1, 1, len(path))
        rms = float(np.sqrt(np.mean((np.polyval(np.polyfit(x, path, 2), x) - path) ** 2)))
        if rms > 0.025 * h:
            return f"the strongest edge is not a smooth curve ({rms / h:.1%} of the height off a parabola)"
        if not colour_test:
            return None
        # below the edge (hood) must differ from just above it (road)
        above = np.concatenate([colour[np.clip(path + y0 - d, 0, h - 1), cols] for d in (4, 6, 8)])
        below = np.concatenate([colour[np.clip(path + y0 + d, 0, h - 1), cols] for d in (4, 6, 8)])
        diff = float(np.linalg.norm(above.mean(0) - below.mean(0)))
        if diff < 12:
            return f"the edge does not separate two regions (colour difference {diff:.0f} < 12)"
        return None

    segs = _segments(gray, y0)
    rows = np.arange(eb.shape[0])[:, None]
    cost, why = eb.copy(), ""
    for _ in range(3):
        path = _path(cost, e.shape[1])
        why = check(path)
        if why:
            return None, why
        crossing = _crossing(segs, path + y0)
        if not crossing:
            why = ""
            break
        # lines of the scene run on across this edge: it lies on the road (a shadow, a kerb);
        # a hood, if any, is below it
        why = f"the strongest edge is crossed by {crossing} lines of the scene (the road, not a hood)"
        cost[rows <= path[::BIN][: eb.shape[1]][None, :] + 2] = 0
    else:
        return None, why
    # the hood's top is the topmost such edge (reflections on a glossy hood make more below);
    # above a found hood edge a somewhat weaker one is accepted (glare hides parts of it; at
    # night the hood is as dark as the road) unless scene lines cross it
    for _ in range(3):
        upper = eb.copy()
        top = path[::BIN][: eb.shape[1]]
        upper[rows > top[None, :] - 3] = 0
        cand = _path(upper, e.shape[1])
        if check(cand, 0.45, 3.0, colour_test=False) or _crossing(segs, cand + y0):
            break
        path = cand
    return _polygon(path, y0, s, W, H), "hood edge found"


def _segments(gray: np.ndarray, y0: int) -> np.ndarray:
    """LSD segments (x1, y1, x2, y2) of the lower frame (from rows above the search band)."""
    top = max(0, y0 - int(0.15 * gray.shape[0]))
    seg = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD).detect(gray[top:])[0]
    return np.zeros((0, 4)) if seg is None else seg.reshape(-1, 4) + [0, top, 0, top]


def _crossing(segs: np.ndarray, edge_rows: np.ndarray, margin: float = CROSS_PX) -> int:
    """How many scene lines (steeper than 15 deg) run on across the edge: an end more than
    `margin` px above it and the other more than `margin` below. A hood occludes the road: lane
    lines and kerbs end at its edge; a shadow or a kerb on the road is crossed by them."""
    if not len(segs):
        return 0
    x1, y1, x2, y2 = segs.T
    steep = np.abs(y2 - y1) > np.tan(np.radians(15)) * np.abs(x2 - x1)
    cols = np.arange(len(edge_rows))
    d1 = y1 - np.interp(x1, cols, edge_rows)
    d2 = y2 - np.interp(x2, cols, edge_rows)
    return int(np.count_nonzero(steep & (np.minimum(d1, d2) < -margin) & (np.maximum(d1, d2) > margin)))


def hood_in_video(frames: list[np.ndarray]) -> tuple[list[list[float]] | None, str]:
    """The static bottom region of frames spread over a video: the hood edge of the mean
    frame (where the moving road blurs away and the hood stays sharp), accepted when the
    region below it does not change over the video."""
    H, W = frames[0].shape[:2]
    mean = np.mean([f.astype(np.float32) for f in frames], axis=0).astype(np.uint8)
    poly, why = hood_in_still(mean, min_strong=0.75)   # the blurred road leaves only real edges
    if poly is None:
        return None, f"mean frame: {why}"
    stack = np.stack([_gray_small(f)[0].astype(np.float32) for f in frames])
    s = stack.shape[2] / W
    mask = np.zeros(stack.shape[1:], np.uint8)
    cv2.fillPoly(mask, [np.round((np.array(poly) + 0.5) * s - 0.5).astype(np.int32)], 1)
    cv2.erode(mask, np.ones((5, 5), np.uint8), dst=mask)
    std = stack.std(axis=0)
    static = float(np.mean(std[mask > 0] < 6.0)) if mask.any() else 0.0
    if static < 0.8:
        return None, f"the region below the edge changes over the video ({static:.0%} static, need 80 %)"
    return poly, f"static bottom region of the video ({static:.0%} static)"


def find_hood(rec, frame_ids, *, progress: bool = False, shared: bool = True) -> dict[str, list[list[float]] | None]:
    from blendgen.recording.frames import frame_indices, is_sequence, read_frames

    frame_ids = list(frame_ids)
    if is_sequence(rec) and len(frame_ids) >= 8:
        idx = frame_indices(rec, frame_ids)
        pick = sorted({frame_ids[i] for i in np.linspace(0, len(idx) - 1, min(N_VIDEO, len(idx))).astype(int)})
        frames = [im for _, im in read_frames(rec, pick, progress=progress, desc="hood") if im is not None]
        poly, why = hood_in_video(frames)
        log.info("hood: %s", why)
        return {f: poly for f in frame_ids}
    out = {}
    for fid, im in read_frames(rec, frame_ids, progress=progress, desc="hood"):
        out[fid], why = (None, "frame does not decode") if im is None else hood_in_still(im)
        log.info("%s: hood: %s", fid, why)
    if shared and len(out) >= CONSENSUS_MIN_FRAMES:  # stills of one camera: one hood, in most frames or none
        from blendgen.analysis.mount import hood_consensus

        out, why = hood_consensus(out, rec.camera.width, rec.camera.height)
        log.info("hood: %s", why)
    return out
