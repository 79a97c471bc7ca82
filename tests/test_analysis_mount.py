"""The recording-wide reduction (blendgen.analysis.mount): one hood and one camera mount from
the per-frame cues of stills of one camera, and how far objects may stand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from blendgen.analysis.mount import FrameCues, estimate_mount, hood_consensus, placement_limit
from blendgen.geometry import Camera, R_world_cam_from_ypr, make_pose

CAM = Camera.from_hfov(1280, 720, 70)


def hood_edge(top: float, W: int = 1280, H: int = 720) -> list[list[float]]:
    u = np.linspace(0, W - 1, 33)
    v = top + 40 * (2 * u / (W - 1) - 1) ** 2          # a hood's edge, lower at the sides
    return [[float(a), float(b)] for a, b in zip(u, v)] + [[W - 1.0, H - 1.0], [0.0, H - 1.0]]


def test_hood_consensus_takes_the_majority_and_drops_a_minority():
    polys = {f"f{i}": hood_edge(610 + (i % 3)) for i in range(7)}
    polys["f7"] = hood_edge(480)          # a shadow edge on the road in one frame
    polys["f8"] = None                    # glare: no edge found
    out, why = hood_consensus(polys, 1280, 720)
    assert "7 of 9" in why and all(p == out["f0"] for p in out.values())   # f7 and f8 too
    assert abs(np.interp(640, *np.asarray(out["f0"][:-2]).T) - 611) < 3
    # a roof camera: edges of the road in 3 of 9 frames, each somewhere else
    polys = {f"f{i}": (hood_edge(450 + 40 * i) if i < 3 else None) for i in range(9)}
    out, why = hood_consensus(polys, 1280, 720)
    assert all(p is None for p in out.values()) and "3 of 9" in why
    # stills of three cars imported together (the BDD photos): each keeps its own
    polys = {f"f{i}": hood_edge(t) for i, t in enumerate((578, 605, 640))}
    out, why = hood_consensus(polys, 1280, 720)
    assert out == polys and "its own" in why


def person_cue(T, xy, cam=CAM):
    """A 1.7 m person standing at ground point xy, as the per-frame part leaves its box."""
    (ub, vb), (ut, vt) = cam.project_world(T, [[xy[0], xy[1], 0.0], [xy[0], xy[1], 1.7]])[0]
    return ("person", [[ub, vb], [ub - 12, vb], [ub + 12, vb], [ut, vt]])


def lane_cue(T, width, cam=CAM):
    """The ego lane's two lines (width apart, camera 0.3 m right of centre) as two pixels each."""
    out = []
    for y in (-width / 2 - 0.3, width / 2 - 0.3):
        uv, _ = cam.project_world(T, [[6.0, y, 0.0], [20.0, y, 0.0]])
        out.append(uv.tolist())
    return out


def pose(h, pitch, roll):
    return make_pose(R_world_cam_from_ypr(0.0, math.radians(pitch), math.radians(roll)), [0, 0, h])


@pytest.mark.parametrize("h", [1.2, 1.65])
def test_mount_height_from_people_and_lanes_with_an_outlier(h):
    """Stills of one camera (pitch -2, roll 0.5): people at 8-30 m and a 3.4 m lane give the
    height; a child (or a sitting person) among the people and a frame whose vanishing point is
    6 deg off (car rears taken for the road's lines) move nothing."""
    T = pose(h, -2.0, 0.5)
    rng = np.random.default_rng(1)
    frames = {}
    for i in range(6):
        objs = [person_cue(T, (rng.uniform(8, 30), rng.uniform(-4, 4))) for _ in range(3)]
        if i == 0:  # a 1.1 m child
            (ub, vb), _, _, (ut, vt) = objs[0][1]
            objs[0] = ("person", [[ub, vb], [ub - 8, vb], [ub + 8, vb], [ut, vb - (vb - vt) * 1.1 / 1.7]])
        frames[f"f{i}"] = FrameCues(pitch=(-8.0 if i == 1 else -2.0) + rng.normal(0, 0.1), roll=0.5 + rng.normal(0, 0.1), pitch_std=0.1,
                                    roll_std=0.1, objects=objs, lane=lane_cue(T, 3.4) if i % 2 else None)
    m = estimate_mount(frames, CAM.K, size_scale=1.0)
    assert m.height_m == pytest.approx(h, rel=0.03), m
    assert abs(m.pitch_deg + 2.0) < 0.15 and abs(m.roll_deg - 0.5) < 0.15
    assert abs(m.frame_pitch["f1"] + 2.0) < 0.5
    assert m.source["height"] == "lanes+people" and m.cues["person"] == 18 and m.cues["lane"] == 3
    assert m.height_std_log < 0.08


def test_people_pin_the_horizon_without_lines():
    """No vanishing point in any frame: people at different distances give pitch and height
    (near and far ones agree only at the right horizon)."""
    T = pose(1.5, 1.5, 0.0)
    frames = {f"f{i}": FrameCues(objects=[person_cue(T, (d, 2.0 * (-1) ** k)) for k, d in enumerate((7, 12, 20, 35))])
              for i in range(3)}
    m = estimate_mount(frames, CAM.K, size_scale=1.0)
    assert abs(m.pitch_deg - 1.5) < 0.3 and m.height_m == pytest.approx(1.5, rel=0.05), m


def test_no_cue_falls_back_to_the_prior_and_says_so():
    frames = {f"f{i}": FrameCues(pitch=1.0, roll=0.0, pitch_std=0.2, roll_std=0.2) for i in range(3)}
    m = estimate_mount(frames, CAM.K)
    assert m.height_m == pytest.approx(1.5) and m.source["height"] == "default"
    assert m.height_std_log == pytest.approx(0.25, rel=0.05) and "prior" in m.reasons[0]
    # the user's values are kept
    m = estimate_mount(frames, CAM.K, fixed={"camera_height_m": 1.3, "pitch_deg": 0.5})
    assert m.height_m == 1.3 and all(v == 0.5 for v in m.frame_pitch.values()) and m.source["pitch"] == "user"


def test_placement_limit():
    lim, why = placement_limit(0.5, 0.0, 0.05, 70)
    assert lim == pytest.approx(0.3 / math.tan(math.radians(0.5)), rel=1e-6) and "pitch +-0.50" in why
    assert placement_limit(0.5, 0.5, 0.05, 70)[0] < lim        # roll tilts objects beside the road
    assert placement_limit(0.0, 0.0, 0.0, 70)[0] is None
    assert placement_limit(3.0, 3.0, 0.05, 70)[0] < 4              # nothing known: nothing but the nearest
    lim, why = placement_limit(0.1, 0.1, 0.3, 70)
    assert lim == 0.0 and "unknown scale" in why
