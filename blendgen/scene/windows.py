"""Planning a long recording in windows that run in parallel on the farm (bpy-free).

`planner.Planner` plans a drive frame after frame: each spawned object is a track whose whole
trajectory is simulated and checked against every other track, the ego vehicle and the real
frames it will cross. One pass over 15,000 frames is serial (hours), and each spawn simulates to
the end of the recording. Windows cut it into independent pieces without cutting any object
while it is in view:

- The job's frames are cut into windows of time: short ones first (1, 2, 4, 8 s: the first frames
  reach the render early), then 16 s each. A window spawns objects in its own
  frames; their tracks may run on into the next window (its *spill*) but end at the first frame
  there in which they are out of view, and a candidate still in view at the end of the next
  window is rejected. So a window's tracks never reach the window after next.
- Even windows (phase 1) are planned alone, all at once. Odd windows (phase 2) are planned once
  both neighbours are: the neighbours' tracks are fixed obstacles (and count toward the frame's
  objects), so nothing overlaps across a boundary. In the next window's frames a phase-2
  candidate is also rejected where that window already shows `objects_per_frame[1]` objects: an
  even window starts empty and fills its first frame, and a spill on top of that would crowd it.
- A frame's plan is its window's objects plus the previous window's spill into it
  (`frame_plan`). Window w spawns with the seed `frame_seed(job seed, its first frame id)` and
  track ids from its own block of `ID_BLOCK` (ids are unique across any 7 consecutive windows),
  so the plan depends on the job, not on how many workers planned it or in which order. A job
  shorter than the first window is planned exactly as `plan_sequence` plans it.
- Stills (`inject.sequences: false`) plan every frame afresh: all windows are phase 1.
"""

from __future__ import annotations

import bisect
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from blendgen import atomic
from blendgen.plan import SCENERY_ID, FramePlan, PlacedObject
from blendgen.scene.planner import Planner, Track
from blendgen.scene.real_scene import RealFrame, RealScene
from blendgen.scene.riders import split_rider

WINDOW_S = (1.0, 2.0, 4.0, 8.0, 16.0)   # a video's windows: short ones first, then 16 s each
STILL_WINDOWS = (48, 96, 192, 384)  # frames: stills (every frame planned afresh)
ID_BLOCK = 2048
N_BLOCKS = (SCENERY_ID - 1) // ID_BLOCK


@dataclass(frozen=True)
class Window:
    index: int
    start: int     # first own frame (position among the job's frames)
    end: int       # one past the last own frame
    horizon: int   # its tracks are simulated (and may spill) up to here: the next window's end
    phase: int     # 1: planned alone; 2: once both neighbours are planned

    @property
    def name(self) -> str:
        return f"w{self.index:04d}"


def plan_windows(times, sequences: bool, sizes: tuple[int, ...] | None = None) -> list[Window]:
    """The windows of a job whose frames are at `times` (s; or their number). A drive
    (`sequences`) is cut by time, `WINDOW_S` in turn and the last one repeated, so a track's
    room to run on does not depend on the job's frame step; stills by `STILL_WINDOWS` frames.
    `sizes`: frame counts instead (tests)."""
    times = np.arange(times, dtype=float) if np.isscalar(times) else np.asarray(times, float)
    n = len(times)
    bounds = [0]
    if sizes is None and sequences:
        it = iter(WINDOW_S)
        while bounds[-1] < n:
            size = next(it, WINDOW_S[-1])
            bounds.append(max(bounds[-1] + 1, int(np.searchsorted(times, times[bounds[-1]] + size - 1e-9))))
            bounds[-1] = min(bounds[-1], n)
    else:
        sizes = sizes or STILL_WINDOWS
        it = iter(sizes)
        while bounds[-1] < n:
            bounds.append(min(n, bounds[-1] + next(it, sizes[-1])))
    out = []
    for i in range(len(bounds) - 1):
        horizon = bounds[min(i + 2, len(bounds) - 1)] if sequences else bounds[i + 1]
        out.append(Window(i, bounds[i], bounds[i + 1], horizon, 2 if sequences and i % 2 else 1))
    return out


def window_of(windows: list[Window], pos: int) -> int:
    return bisect.bisect_right([w.start for w in windows], pos) - 1


def window_needs(windows: list[Window], i: int) -> tuple[tuple[int, int], list[int]]:
    """What planning window i needs: its frames' range (own + spill) and the windows it waits for."""
    w = windows[i]
    return (w.start, w.horizon), ([j for j in (i - 1, i + 1) if 0 <= j < len(windows)] if w.phase == 2 else [])


# ----------------------------------------------------------------------------- tracks

def track_to_dict(tr: Track, offset: int) -> dict:
    return {"id": tr.id, "cls": tr.cls, "variant": tr.variant, "dims": list(tr.dims), "k0": tr.k0 + offset,
            "xy": tr.xy.tolist(), "z": tr.z.tolist(), "yaw": tr.yaw.tolist(), "scenario": tr.scenario,
            "states": tr.states, "rider_id": tr.rider_id, "pitch": tr.pitch.tolist(), "roll": tr.roll.tolist()}


def track_from_dict(d: dict, lo: int, hi: int) -> Track | None:
    """The track's frames within [lo, hi) (global positions), re-based to lo; None if none."""
    k0 = int(d["k0"])
    a, b = max(k0, lo), min(k0 + len(d["xy"]), hi)
    if a >= b:
        return None
    s = slice(a - k0, b - k0)
    tr = Track(int(d["id"]), d["cls"], d["variant"], tuple(d["dims"]), a - lo, np.asarray(d["xy"], float)[s],
               np.asarray(d["z"], float)[s], np.asarray(d["yaw"], float)[s], d["scenario"],
               d["states"][s] if d["states"] else None, int(d["rider_id"]), pitch=np.asarray(d["pitch"], float)[s],
               roll=np.asarray(d["roll"], float)[s])
    return tr


def placed(tr: Track, k: int, times: np.ndarray) -> list[PlacedObject]:
    """The track's object(s) at its frame k (a ridden two-wheeler and its rider), as Planner.run."""
    i = k - tr.k0
    return split_rider(PlacedObject(
        id=tr.id, cls=tr.cls, position=(float(tr.xy[i, 0]), float(tr.xy[i, 1]), float(tr.z[i])),
        yaw=float(tr.yaw[i]), dims=tuple(float(x) for x in tr.dims), variant=dict(tr.variant),
        velocity=tr.velocity(i, times), state=tr.states[i] if tr.states else None,
        scenario=tr.scenario, pitch=float(tr.pitch[i]), roll=float(tr.roll[i])), tr.rider_id)


# ----------------------------------------------------------------------------- planning

class WindowPlanner(Planner):
    """A Planner over one window's frames [start, horizon) (poses given for all of them) that
    spawns in [start, end) only, with the neighbours' tracks fixed (`fixed`, re-based)."""

    def __init__(self, twin, camera, poses, inject, seed: int, *, window: Window, n_total: int,
                 fixed=(), assets=None, real=None):
        super().__init__(twin, camera, poses, inject, seed, assets=assets, real=real)
        self.window = window
        self.n_plan = window.end - window.start
        self.open_end = window.horizon >= n_total   # nothing is planned after its horizon
        self.id_base = (window.index % N_BLOCKS) * ID_BLOCK
        self.next_id = self.id_base + 1
        self.tracks = list(fixed)
        self.own: list[Track] = []
        self.crowd = inject.objects_per_frame[1]

    def _cut(self, tr: Track) -> int | None:
        """The first frame from the next window on in which the track is out of view."""
        return next((k for k in range(max(self.n_plan, tr.k0), tr.k1) if not self.visible(tr, k)), None)

    def extra_conflict(self, tr: Track) -> str | None:
        if not self.inject.sequences or tr.k1 <= self.n_plan:
            return None
        cut = self._cut(tr)
        if cut is None and tr.k1 >= self.K and not self.open_end:
            return "would still be in view at the end of the next plan window"
        if self.window.phase == 2:
            for k in range(max(self.n_plan, tr.k0), tr.k1 if cut is None else cut):
                n = sum(1 for o in self.tracks if o.k0 <= k < o.k1 and self.visible(o, k))
                if n >= self.crowd:
                    return f"the next plan window already shows {n} objects where it would still be in view"
        return None

    def _bump(self) -> int:
        nid = self.next_id
        self.next_id = nid + 1 if nid < self.id_base + ID_BLOCK else self.id_base + 1
        return nid

    def accept(self, tr: Track) -> Track:
        if self.inject.sequences and tr.k1 > self.n_plan:
            cut = self._cut(tr)
            if cut is not None:
                tr = self._truncate(tr, cut - tr.k0)
        tr.id = self._bump()
        if "rider" in tr.variant:
            tr.rider_id = self._bump()
        self.tracks.append(tr)
        self.own.append(tr)
        return tr

    def spill(self) -> list[dict]:
        """The own tracks' objects in the next window's frames (where they are in view)."""
        out = []
        for k in range(self.n_plan, self.K):
            T = self.ego.T[k]
            objs, notes = [], []
            for tr in sorted(self.own, key=lambda x: x.id):
                if tr.k0 <= k < tr.k1 and self.visible(tr, k):
                    objs += placed(tr, k, self.times)
                    if self.real is not None:
                        cov = self.real.covered(k, T, tr.corners[k - tr.k0], tr.z[k - tr.k0], tr.dims[2])
                        if cov:
                            notes.append({"what": "covers_real", "id": tr.id, "cls": tr.cls, "real": cov})
            out.append({"frame_id": self.poses[k][0], "objects": [asdict(o) for o in objs], "decisions": notes})
        return out


def plan_window(twin, camera, poses, inject, seed: int, *, window: Window, n_total: int, fixed: list[dict] = (),
                assets=None, real=None) -> dict:
    """Plan one window; `poses` are the frames [window.start, window.horizon), `fixed` the
    neighbours' tracks (as stored). Returns the window's record (`write_window`)."""
    tracks = [t for t in (track_from_dict(d, window.start, window.horizon) for d in fixed) if t is not None]
    p = WindowPlanner(twin, camera, poses, inject, seed, window=window, n_total=n_total, fixed=tracks,
                      assets=assets, real=real)
    plans = p.run()
    return {"window": window.index, "start": window.start, "end": window.end, "horizon": window.horizon,
            "phase": window.phase, "seed": seed, "frames": [pl.to_dict() for pl in plans], "spill": p.spill(),
            "tracks": [track_to_dict(tr, window.start) for tr in p.own]}


def plan_in_windows(twin, camera, poses, inject, seed_of, *, assets=None, real_of=None,
                    sizes: tuple[int, ...] | None = None) -> tuple[list[FramePlan], list[dict]]:
    """Every window in this process, phase 1 then phase 2 (what the farm does in parallel):
    the frame plans and the windows' records. `seed_of(frame_id)`: a window's seed from its first
    frame; `real_of(lo, hi)`: the RealScene of frames [lo, hi) or None."""
    wins = plan_windows([t for _, t, _ in poses], inject.sequences, sizes)
    recs: dict[int, dict] = {}
    for phase in (1, 2):
        for w in wins:
            if w.phase != phase:
                continue
            fixed = [d for j in window_needs(wins, w.index)[1] for d in recs[j]["tracks"]]
            recs[w.index] = plan_window(twin, camera, poses[w.start:w.horizon], inject, seed_of(poses[w.start][0]),
                                        window=w, n_total=len(poses), fixed=fixed, assets=assets,
                                        real=None if real_of is None else real_of(w.start, w.horizon))
    plans = [frame_plan(recs[i], recs.get(i - 1), k) for i, w in enumerate(wins) for k in range(w.start, w.end)]
    return plans, [recs[i] for i in range(len(wins))]


def window_path(folder: Path, window: Window | int) -> Path:
    i = window.index if isinstance(window, Window) else int(window)
    return Path(folder) / f"w{i:04d}.json"


def write_window(folder: Path, record: dict) -> None:
    atomic.write_text(window_path(folder, record["window"]), json.dumps(record))


def read_window(folder: Path, index: int) -> dict:
    return json.loads(window_path(folder, index).read_text())


def frame_plan(own: dict, prev: dict | None, pos: int) -> FramePlan:
    """The plan of the frame at position `pos`: its window's objects and the previous window's
    spill into it (an object both list, a fixed neighbour's track, counts once)."""
    plan = FramePlan.from_dict(own["frames"][pos - own["start"]])
    if prev is not None and pos < prev["horizon"]:
        extra = prev["spill"][pos - prev["end"]]
        have = {o.id for o in plan.objects}
        add = [o for o in FramePlan.from_dict({**extra, "t": 0, "T_world_cam": plan.T_world_cam}).objects
               if o.id not in have]
        ids = {o.id for o in add}
        plan.objects = sorted(plan.objects + add, key=lambda o: o.id)
        plan.decisions += [d for d in extra["decisions"] if d.get("id") in ids]
    return plan


# ----------------------------------------------------------------------------- real frames

class LazyRealFrame(RealFrame):
    """A real frame whose road and hood masks are read when the planner first asks for them
    (a window's planner keeps only the frames its tracks cross in memory)."""

    _hoods: dict = {}

    def __init__(self, folder: Path, fa):
        self.fa, self.folder = fa, Path(folder)
        self.footprints = [(o, np.asarray(o.footprint, float)) for o in fa.real_objects if o.footprint]
        self.boxes = [(o, np.asarray(o.box, float)) for o in fa.real_objects]
        self._road = None
        self._road_read = False

    @property
    def road(self):
        if not self._road_read:
            from blendgen.frame_analysis import read_road_mask

            self._road, self._road_read = read_road_mask(self.folder, self.fa), True
        return self._road

    @property
    def hood(self):
        from blendgen.frame_analysis import hood_mask

        if not self.fa.hood:
            return None
        key = (json.dumps(self.fa.hood), self.fa.width, self.fa.height)
        if key not in LazyRealFrame._hoods:  # a video's frames share one hood
            if len(LazyRealFrame._hoods) > 64:
                LazyRealFrame._hoods.clear()
            LazyRealFrame._hoods[key] = hood_mask(self.fa.hood, self.fa.width, self.fa.height)
        return LazyRealFrame._hoods[key]


def lazy_real_scene(analysis_dir: Path, analyses: list, camera) -> RealScene:
    """`analyses`: the frames' FrameAnalysis in plan order (None: no analysis for it)."""
    return RealScene([None if fa is None else LazyRealFrame(analysis_dir, fa) for fa in analyses], camera)
