"""Planning as farm tasks: one item per plan window (scene.windows), bpy-free.

A window's task reads its frames' poses (the final frame analyses of a ground-plane job,
poses.csv otherwise), the real frames' constraints (lazily: only the road masks its tracks
cross are read), the neighbours' tracks when it is a phase-2 window, and writes
OUT/plan/w<index>.json. `frame_plan_reader` gives the renderers a frame's plan from those
files; `write_plan_jsonl` streams them into OUT/plan.jsonl when the pipeline ends.
"""

from __future__ import annotations

import json
import time
from functools import cached_property
from pathlib import Path

import numpy as np

from blendgen.farm.seeds import frame_seed
from blendgen.job.schema import parse_job
from blendgen.pipeline.outputs import JobFolder
from blendgen.recording.folder import read_recording
from blendgen.scene import windows as W


def plan_dir(out_dir: Path) -> Path:
    return Path(out_dir) / "plan"


def job_twin(job):
    if job.twin_path is not None:
        from blendgen.twin.model import load_twin

        return load_twin(job.twin_path)
    from blendgen.scene.ground_plane import GroundPlaneTwin

    return GroundPlaneTwin.from_job(job.ground_plane)


def analysed(job) -> bool:
    return job.ground_plane is not None and job.ground_plane.analysis


class PlanWindowTask:
    def __init__(self, job: dict, out_dir: str):
        self.job = parse_job(job, source=str(Path(out_dir) / "job.resolved.yaml"))
        self.folder = JobFolder(Path(out_dir))
        self.rec = read_recording(self.job.recording_dir)
        index = np.arange(self.rec.n_frames)[self.job.frames.start:self.job.frames.stop:self.job.frames.step]
        self.ids = [self.rec.frame_id(int(i)) for i in index]
        self.times = np.asarray(self.rec.frames_t, float)[index]
        self.windows = W.plan_windows(self.times, self.job.inject.sequences)
        w, h = self.job.render.resolution or (self.rec.camera.width, self.rec.camera.height)
        self.camera = self.rec.camera.scaled(w, h)
        self.dir = plan_dir(out_dir)

    @cached_property
    def twin(self):
        return job_twin(self.job)

    @cached_property
    def assets(self):
        from blendgen.job.assets import CATALOG_NAME, AssetSampler

        if not self.job.inject.assets:
            return None
        doc = json.loads((self.folder.root / CATALOG_NAME).read_text())
        return AssetSampler(doc["assets"], self.job.inject.asset_share)

    @cached_property
    def sync_poses(self) -> dict:
        from blendgen.sync.pipeline import read_poses

        return {fid: T for fid, _, T in read_poses(self.folder.poses_csv, self.rec)}

    def is_done(self, item: str) -> bool:
        return W.window_path(self.dir, int(item[1:])).is_file()

    def process(self, item: str) -> dict:
        from blendgen.frame_analysis import read_analysis

        t0 = time.process_time()
        win = self.windows[int(item[1:])]
        ids = self.ids[win.start:win.horizon]
        real = None
        if analysed(self.job):
            fas = [read_analysis(self.folder.analysis, f) for f in ids]
            poses = [(f, float(t), np.asarray(fa.T_world_cam, float)) for f, t, fa in
                     zip(ids, self.times[win.start:win.horizon], fas)]
            real = W.lazy_real_scene(self.folder.analysis, fas, self.camera)
        else:
            poses = [(f, float(t), self.sync_poses[f]) for f, t in zip(ids, self.times[win.start:win.horizon])]
        fixed = [d for j in W.window_needs(self.windows, win.index)[1] for d in W.read_window(self.dir, j)["tracks"]]
        # the layout's stream starts from (seed, the window's first frame id): as plan_sequence's
        # from the job's first frame, so a job within one window is planned as before
        seed = frame_seed(self.job.seed, ids[0])
        rec = W.plan_window(self.twin, self.camera, poses, self.job.inject, seed, window=win, n_total=len(self.ids),
                            fixed=fixed, assets=self.assets, real=real)
        rec["cpu_s"] = round(time.process_time() - t0, 3)
        W.write_window(self.dir, rec)
        return {"window": win.index, "phase": win.phase, "frames": win.end - win.start, "tracks": len(rec["tracks"]),
                "cpu_s": rec["cpu_s"]}


class FramePlans:
    """A frame's plan from the window files (the last few kept): for the renderers."""

    def __init__(self, out_dir: Path, times, sequences: bool, ids: list[str]):
        self.dir = plan_dir(out_dir)
        self.windows = W.plan_windows(times, sequences)
        self.pos = {f: k for k, f in enumerate(ids)}
        self._cache: dict[int, dict] = {}

    def _window(self, i: int) -> dict:
        if i not in self._cache:
            if len(self._cache) >= 3:
                self._cache.pop(next(iter(self._cache)))
            self._cache[i] = W.read_window(self.dir, i)
        return self._cache[i]

    def __getitem__(self, frame_id: str):
        p = self.pos[frame_id]
        i = W.window_of(self.windows, p)
        return W.frame_plan(self._window(i), self._window(i - 1) if i > 0 else None, p)


def write_plan_jsonl(out_dir: Path, times, sequences: bool, ids: list[str], path: Path) -> dict:
    """OUT/plan.jsonl from the window files, one window in memory at a time; returns what
    `unplaced_warnings` needs (objects per class, rejections per class and reason)."""
    from blendgen import atomic

    plans = FramePlans(out_dir, times, sequences, ids)
    placed: dict[str, int] = {}
    rejected: dict[str, dict[str, int]] = {}
    n_obj = 0
    with atomic.atomic_path(path) as tmp, open(tmp, "w") as f:
        for fid in ids:
            p = plans[fid]
            n_obj += len(p.objects)
            for o in p.objects:
                placed[o.cls] = placed.get(o.cls, 0) + 1
            for d in p.decisions:
                if d.get("what") == "rejected":
                    r = rejected.setdefault(d["cls"], {})
                    r[d["reason"]] = r.get(d["reason"], 0) + d["count"]
            f.write(json.dumps(p.to_dict()) + "\n")
    return {"objects": n_obj, "placed": placed, "rejected": rejected}


class PlanFileTask(PlanWindowTask):
    """Item "plan.jsonl": OUT/plan.jsonl from the windows, and OUT/plan/stats.json (what the
    supervisor warns about), once every window is planned."""

    def is_done(self, item: str) -> bool:
        return (self.dir / "stats.json").is_file() and self.folder.plan.is_file()

    def process(self, item: str) -> dict:
        from blendgen import atomic

        t0 = time.process_time()
        stats = write_plan_jsonl(self.folder.root, self.times, self.job.inject.sequences, self.ids, self.folder.plan)
        stats["cpu_s"] = round(time.process_time() - t0, 3)
        atomic.write_json(self.dir / "stats.json", stats)
        return {"objects": stats["objects"], "cpu_s": stats["cpu_s"]}


def unplaced_warnings(stats: dict, inject, n_frames: int) -> list[str]:
    """planner.unplaced_warnings from `write_plan_jsonl`'s counts."""
    out = []
    for cls, w in inject.classes.items():
        if w <= 0 or cls in stats["placed"]:
            continue
        reasons = stats["rejected"].get(cls, {})
        why = max(reasons, key=reasons.get) if reasons else "never drawn (its weight is small)"
        out.append(f"class {cls!r} (weight {w:g}) was placed in none of {n_frames} frames: {why}")
    return out
