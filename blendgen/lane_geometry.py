"""The lanes that painted lines bound (bpy-free): lines as the frame analysis stores them
(`FrameAnalysis.lane_lines`, found by `analysis.lanes`): [y10, slope, cover], the line
y = y10 + slope (x - X_REF) on the ground (x ahead, y left of the camera, metres) and the share
of its range's 1 m steps that is painted. The analysis reads the ego lane from them, the
planner puts vehicles in the lanes between them.
"""

from __future__ import annotations

RANGE_M = (5.0, 30.0)          # ahead of the camera: resolved, past the hood
X_REF = 10.0                   # lines are given by their offset here
LANE_SPAN = (0.7, 1.35)        # a lane between two lines, as a share of the job's lane width


def kept_lines(lines: list[list[float]], lane_width_m: float) -> list[list[float]]:
    """The lines `ego_lane` reads: strongest first; a weaker line within a lane's width of a kept
    one is a track or crack."""
    kept = []
    for l in sorted(lines, key=lambda l: -l[2]):
        if all(abs(l[0] - k[0]) >= LANE_SPAN[0] * lane_width_m for k in kept):
            kept.append(l)
    return kept


def ego_lane(lines: list[list[float]], x: float, lane_width_m: float, kept: list | None = None
             ) -> tuple[float, float, list[float]] | None:
    """(right edge, left edge, every kept line's offset) of the camera's lane `x` metres ahead,
    or None when the lines bound none: no line within a lane's width on either side, or the
    nearest two a lane's width apart beyond LANE_SPAN. One line alone bounds the lane on its side.
    `kept`: `kept_lines(lines, lane_width_m)` when the caller has it (the planner asks per frame
    many times)."""
    w = lane_width_m
    kept = kept_lines(lines, w) if kept is None else kept
    xc = min(max(float(x), RANGE_M[0]), RANGE_M[1]) - X_REF
    ys = [l[0] + l[1] * xc for l in kept]   # plain floats: a handful, asked for many times
    left, right = sorted(v for v in ys if v > 0), sorted((v for v in ys if v <= 0), reverse=True)
    near_l = left[0] if len(left) and left[0] < LANE_SPAN[1] * w else None
    near_r = right[0] if len(right) and -right[0] < LANE_SPAN[1] * w else None
    if near_l is not None and near_r is not None:
        if not LANE_SPAN[0] * w <= near_l - near_r <= LANE_SPAN[1] * w:
            return None
        return near_r, near_l, ys
    if near_l is not None and near_l >= 0.3 * w:
        return near_l - w, near_l, ys
    if near_r is not None and -near_r >= 0.3 * w:
        return near_r, near_r + w, ys
    return None


def lane_centres(lines: list[list[float]], x: float, lane_width_m: float, n_max: int = 3, kept: list | None = None
                 ) -> dict[int, float] | None:
    """Lateral offsets (left > 0) of the lane centres `x` metres ahead, by lane: 0 the ego lane
    (`ego_lane`), +1 the next on the left, -1 on the right, ... up to n_max; a neighbour reaches
    to the next line about a lane's width out, or is as wide as the ego lane. None without an
    ego lane."""
    ego = ego_lane(lines, x, lane_width_m, kept)
    if ego is None:
        return None
    lo, hi, ys = ego
    we = hi - lo
    out = {0: (lo + hi) / 2}
    for side, edge in ((1, hi), (-1, lo)):
        for n in range(1, n_max + 1):
            nxt = [v for v in ys if LANE_SPAN[0] * we <= side * (v - edge) <= LANE_SPAN[1] * we]
            far = min(nxt, key=lambda v: side * v) if nxt else edge + side * we
            out[side * n] = (edge + far) / 2
            edge = far
    return out
