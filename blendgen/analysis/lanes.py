"""The real lanes in a frame: painted lines along the road and the lanes between them (bpy-free).

The ground-plane twin lays its lanes out from the job's lane width with the ego lane centred
on the camera; a real camera rarely is (the Udacity highway photos: 0.4 m off its lane's
centre) and the real lane's width in the frame's metric is what the camera height and pitch
make of it (2.7 m there for the job's 3.7 m with a pitch that did not fit). A vehicle at the
twin's lane centre then stood on a real lane line. Here the lines themselves are found: the
painted stripes (`road._painted`) on the ground, grouped into straight lines
y = y10 + slope (x - 10) (x ahead, y left of the camera, metres) by a vote over slopes (a
pitch that is off fans the lines out on the ground), a line being a 0.3 m wide band whose
stripes cover LINE_MIN_COVER of its range's 1 m steps. `lane_geometry.ego_lane` and `lane_geometry.lane_centres` turn
them into lanes at a distance ahead: the ego lane between the nearest line on each side when
they are a plausible lane's width apart (the BDD snow street's tyre tracks, 0.3-0.6 covered,
are not), neighbours out to the next line (or one lane width beyond).
"""

from __future__ import annotations

import numpy as np

from blendgen.analysis import road
from blendgen.geometry import Camera
from blendgen.lane_geometry import RANGE_M, X_REF

SLOPES = np.linspace(-0.08, 0.08, 33)   # lateral metres per metre ahead
BIN_M = 0.1
HALF_WIDTH_M = 0.15            # a stripe's pixels lie within this of its line
LINE_MIN_COVER = 0.2           # of the range's 1 m steps (a US freeway's dashes: 0.3-0.6, solid lines 0.9-1)
LINE_MIN_PX = 30
MIN_GAP_M = 0.8                # two lines closer than this at X_REF are one
MAX_LINES = 6


def lane_lines(image: np.ndarray, road_px: np.ndarray | None, camera: Camera, T_world_cam: np.ndarray
               ) -> tuple[list[list[float]], str]:
    """([[y10, slope, cover], ...] from left to right (y10 descending), how it was decided)."""
    if road_px is None or not road_px.any():
        return [], "no road region"
    lab, r, s = road._work_lab(image, road_px)
    _, _, x, y = road._painted(lab, r, camera, T_world_cam, s)
    ok = (x > RANGE_M[0]) & (x < RANGE_M[1]) & (np.abs(y) < 8.0)
    x, y = x[ok], y[ok]
    steps = int(RANGE_M[1] - RANGE_M[0])
    lines = []
    while len(x) >= LINE_MIN_PX and len(lines) < MAX_LINES:
        best = None
        for b in SLOPES:  # the densest offset per slope; its cover decides
            q = y - b * (x - X_REF)
            h, edges = np.histogram(q, bins=np.arange(-8.0 - 0.8, 8.8, BIN_M))
            h = np.convolve(h, np.ones(3), "same")
            for i in np.argsort(h)[-3:]:
                q0 = edges[i] + BIN_M / 2
                on = np.abs(q - q0) < HALF_WIDTH_M
                if on.sum() < LINE_MIN_PX:
                    continue
                cover = len(np.unique(np.floor(x[on] - RANGE_M[0]).astype(int))) / steps
                if best is None or cover > best[0]:
                    best = (cover, b, q0, on)
        if best is None or best[0] < LINE_MIN_COVER:
            break
        cover, b, q0, on = best
        slope, y10 = np.polyfit(x[on] - X_REF, y[on], 1)  # least squares on the stripe's pixels
        if abs(slope) > SLOPES[-1] * 1.5:
            slope, y10 = b, q0
        if all(abs(y10 - l[0]) >= MIN_GAP_M for l in lines):
            lines.append([round(float(y10), 3), round(float(slope), 4), round(cover, 2)])
        keep = np.abs(y - (y10 + slope * (x - X_REF))) > 2 * HALF_WIDTH_M
        x, y = x[keep], y[keep]
    lines.sort(key=lambda l: -l[0])
    if not lines:
        return [], f"no painted line along the road covering {LINE_MIN_COVER:.0%} of {RANGE_M[0]:g}-{RANGE_M[1]:g} m"
    return lines, "painted lines at " + ", ".join(f"{l[0]:+.1f} m ({l[2]:.0%})" for l in lines) + f" ({X_REF:g} m ahead)"
