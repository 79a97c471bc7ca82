"""Plan windows (scene.windows): a long drive planned in windows that can run in parallel gives
the same plan in any order, keeps objects apart across window boundaries, and cuts no object
while it is in view; a job shorter than the first window is planned exactly as before."""

from __future__ import annotations

import math

import numpy as np
import pytest

from blendgen.geom2d import convex_overlap
from blendgen.geometry import Camera, R_world_cam_from_ypr, make_pose
from blendgen.job.schema import SCENARIOS, Inject
from blendgen.scene.ground_plane import GroundPlaneTwin
from blendgen.scene.planner import Planner, footprints, plan_sequence
from blendgen.scene.windows import (frame_plan, plan_in_windows, plan_window, plan_windows, track_from_dict,
                                    window_needs)

CAM = Camera.from_hfov(640, 360, 70.0)
CLASSES = {"car": 3, "person": 2, "bicycle": 1, "motorcycle": 1, "bus": 1, "truck": 1, "traffic light": 1}
SIZES = (20, 30, 40)


def drive(n: int, fps: float = 10.0, speed: float = 9.0):
    out = []
    for i in range(n):
        x = speed * i / fps
        yaw = 0.03 * math.sin(i / 25.0)
        out.append((f"f{i:06d}", i / fps, make_pose(R_world_cam_from_ypr(yaw, -0.02), [x, 0.4 * math.sin(i / 40), 1.4])))
    return out


def seed_of(fid: str) -> int:
    return int(fid[1:]) * 7 + 3


def inject(**kw) -> Inject:
    return Inject(**{"objects_per_frame": (3, 5), "classes": CLASSES, "scenarios": list(SCENARIOS),
                     "distance_m": (4.0, 40.0), **kw})


TWIN = GroundPlaneTwin(1.4, -2.0, 3.6)


def test_a_job_shorter_than_the_first_window_is_planned_as_plan_sequence():
    poses = drive(19)
    plans, recs = plan_in_windows(TWIN, CAM, poses, inject(), seed_of, sizes=SIZES)
    assert len(recs) == 1
    ref = plan_sequence(TWIN, CAM, poses, inject(), seed_of(poses[0][0]))
    assert [p.to_dict() for p in plans] == [p.to_dict() for p in ref]


@pytest.fixture(scope="module")
def long_drive():
    poses = drive(150)
    return (poses, *plan_in_windows(TWIN, CAM, poses, inject(), seed_of, sizes=SIZES))


def test_windows_give_one_plan_whatever_the_order_and_keep_objects_apart(long_drive):
    poses, plans, recs = long_drive
    wins = plan_windows(len(poses), True, SIZES)
    assert [w.phase for w in wins] == [1, 2, 1, 2, 1] and len(plans) == 150
    # any order the farm may run them in: phase 2 needs its neighbours only
    again = {}
    for w in reversed(wins):
        if w.phase == 1:
            again[w.index] = plan_window(TWIN, CAM, poses[w.start:w.horizon], inject(), seed_of(poses[w.start][0]),
                                         window=w, n_total=150)
    for w in wins:
        if w.phase == 2:
            fixed = [d for j in window_needs(wins, w.index)[1] for d in again[j]["tracks"]]
            again[w.index] = plan_window(TWIN, CAM, poses[w.start:w.horizon], inject(), seed_of(poses[w.start][0]),
                                         window=w, n_total=150, fixed=fixed)
    assert [again[i] for i in range(len(wins))] == recs
    n = np.array([len({o.id for o in p.objects}) for p in plans])
    assert n.mean() >= 3 and n.max() <= 12, n
    for p in plans:  # no two objects overlap, whichever window placed them
        fps = [(o.id, footprints(np.array([o.position[:2]]), np.array([o.yaw]), o.dims[0], o.dims[1])[0])
               for o in p.objects if o.cls != "traffic light" and "rides" not in o.variant]
        for a in range(len(fps)):
            for b in range(a + 1, len(fps)):
                if fps[a][0] != fps[b][0]:
                    assert not convex_overlap(fps[a][1], fps[b][1], 0.0), (p.frame_id, fps[a][0], fps[b][0])


def test_no_object_is_cut_while_in_view_at_a_window_boundary(long_drive):
    poses, plans, recs = long_drive
    whole = Planner(TWIN, CAM, poses, inject(), 0)  # visibility over the whole drive
    ids = [{o.id for o in p.objects} for p in plans]
    checked = 0
    for rec in recs:
        for d in rec["tracks"]:
            tr = track_from_dict(d, 0, len(poses))
            for k in range(max(tr.k0, rec["end"] - 1), min(tr.k1, len(poses))):
                assert (tr.id in ids[k]) == whole.visible(tr, k), (rec["window"], tr.id, k)
                checked += 1
            k1 = tr.k1
            if rec["end"] <= k1 < len(poses) and k1 in range(rec["end"], rec["horizon"]):
                # ended in the next window: it was cut there, out of view (or its lane ended)
                assert tr.id not in ids[k1] or tr.id in {t["id"] for r in recs for t in r["tracks"] if r is not rec}
    assert checked > 0


def test_stills_plan_every_window_alone():
    poses = drive(60)
    plans, recs = plan_in_windows(TWIN, CAM, poses, inject(sequences=False), seed_of, sizes=SIZES)
    assert all(r["phase"] == 1 and r["horizon"] == r["end"] for r in recs)
    assert all(len(p.objects) >= 3 for p in plans)


@pytest.mark.parametrize("n", [1, 20, 21, 150])
def test_window_layout_covers_every_frame_once(n):
    wins = plan_windows(n, True, SIZES)
    assert wins[0].start == 0 and wins[-1].end == n
    assert all(a.end == b.start for a, b in zip(wins, wins[1:]))
    assert all(w.horizon == (wins[w.index + 1].end if w.index + 1 < len(wins) else n) for w in wins)
    assert frame_plan is not None


def test_a_drive_is_cut_by_time_whatever_the_frame_step():
    for fps in (25.0, 5.0):
        times = np.arange(int(40 * fps)) / fps
        wins = plan_windows(times, True)
        starts = [times[w.start] for w in wins]
        assert np.allclose(starts, [0, 1, 3, 7, 15, 31]), (fps, starts)
        assert wins[-1].end == len(times) and [w.phase for w in wins] == [1, 2, 1, 2, 1, 2]
    assert [w.end - w.start for w in plan_windows(100, False)] == [48, 52]
