"""The frame analysis as farm tasks (processors of `blendgen run`'s pipeline, bpy-free).

Stages (analysis.split says which part is per frame and which recording-wide):
  hood      one item: a video's hood from 40 frames spread over it -> analysis/hood.json
  sample    the cues (below) of the frames the recording-wide values come from, first
  elsewhere video: frames outside the job spread over the recording, their lane-width height
  camera    one item: the recording-wide values -> analysis/recording.json
  cues      per job frame: hood (stills), road users, vanishing-point camera -> analysis/cues/<id>.json
  analysis  per job frame, once the cues within +-0.5 s are in: camera, road, bands, lanes,
            footprints -> analysis/parts/<id>.json (video) or analysis/<id>.json (stills)
  motion    video, per recording frame from the job's first to its last: VO heading and the
            road's step from the previous frame -> analysis/motion/<id>.json
  poses     video, the same frames in order (a chain): the pose, then each job frame's final
            analysis/<id>.json with its footprints at that pose; analysis/chain/<id>.json
            holds the chain's state after each frame (a task resumes from the one before it)
Every output is written atomically, the file that marks an item done last, so a worker killed
mid-item leaves nothing half-written and the retry redoes that item only.
"""

from __future__ import annotations

import json
import time
from functools import cached_property
from pathlib import Path

import numpy as np

from blendgen import atomic
from blendgen.analysis import split
from blendgen.frame_analysis import FrameAnalysis
from blendgen.job.schema import parse_job
from blendgen.pipeline.outputs import JobFolder
from blendgen.recording.folder import read_recording


def job_index(job, rec) -> np.ndarray:
    """Recording indices of the job's frames (frames.start/stop/step), as sync's poses select them."""
    return np.arange(rec.n_frames)[job.frames.start:job.frames.stop:job.frames.step]


class AnalysisContext:
    """What every analysis task knows: the job, the recording, the job's frames (positions,
    recording indices, times) and, for a video, the recording frames the ego motion runs over."""

    def __init__(self, job: dict, out_dir: str, lane_width_given: bool = False):
        import cv2

        cv2.setNumThreads(1)  # one worker per core: no worker competes with the others for cores
        self.job = parse_job(job, source=str(Path(out_dir) / "job.resolved.yaml"))
        self.folder = JobFolder(Path(out_dir))
        self.dir = self.folder.analysis
        self.rec = read_recording(self.job.recording_dir)
        self.index = job_index(self.job, self.rec)
        self.ids = [self.rec.frame_id(int(i)) for i in self.index]
        self.pos = {f: k for k, f in enumerate(self.ids)}
        self.times = np.asarray(self.rec.frames_t, float)[self.index]
        self.gp = self.job.ground_plane
        self.settings = split.Settings(self.rec, self.gp)
        # the resolved job names every field: whether the user gave the lane width comes from the job file
        self.settings.lane_known = self.settings.lane_w if lane_width_given else None
        self.video = split.video_hood(self.rec, self.ids)
        self.seq = self.settings.seq and len(self.ids) > 1   # ego motion over the video
        self.reader = split.FrameReader(self.rec)

    def frame(self, fid: str):
        return self.reader(split.frame_index(fid))

    def close(self) -> None:
        self.reader.close()

    @cached_property
    def detector(self):
        from blendgen.analysis import objects

        return objects.load_detector(self.job.path(self.gp.detector) if self.gp.detector else None)

    @cached_property
    def calib(self) -> dict:
        return json.loads((self.dir / "recording.json").read_text())

    @cached_property
    def hood(self) -> dict:
        """HoodTask's decision: {"mode": "one" | "none" | "own", "hood": polygon or None}."""
        return json.loads((self.dir / "hood.json").read_text())

    @cached_property
    def recording_camera(self):
        return split.recording_of(self.calib["camera"])

    def cue_path(self, fid: str) -> Path:
        return self.dir / "cues" / f"{fid}.json"

    def part_path(self, fid: str) -> Path:
        return self.dir / "parts" / f"{fid}.json" if self.seq else self.dir / f"{fid}.json"

    @cached_property
    def dense(self) -> list[str]:
        return split.dense_ids(self.rec, self.index) if self.seq else []


# ----------------------------------------------------------------------------- recording-wide

class HoodTask(AnalysisContext):
    """Item "hood": a video's one hood (as hood.find_hood: 40 frames spread over the job), or
    what stills do (the sample's own hoods' consensus: one for all, none, or each its own)."""

    def is_done(self, item: str) -> bool:
        return (self.dir / "hood.json").is_file()

    def process(self, item: str) -> dict:
        from blendgen.analysis.hood import N_VIDEO, hood_in_still, hood_in_video

        t0 = time.process_time()
        if self.video:
            k = np.linspace(0, len(self.ids) - 1, min(N_VIDEO, len(self.ids))).astype(int)
            pick = sorted({self.ids[i] for i in k})
            frames = [im for _, im in split.frames_at(self.rec, pick, self.reader) if im is not None]
            hood, why = hood_in_video(frames)
            doc = {"mode": "one" if hood is not None else "none", "hood": hood, "reason": why}
        else:
            polys = {f: (None if im is None else hood_in_still(im)[0])
                     for f, im in split.frames_at(self.rec, split.sample_ids(self.ids), self.reader)}
            doc = split.stills_hood(polys, self.rec.camera, shared=not self.settings.per_image)
        doc["cpu_s"] = round(time.process_time() - t0, 3)
        atomic.write_json(self.dir / "hood.json", doc)
        return {"mode": doc["mode"], "cpu_s": doc["cpu_s"]}


class ElsewhereTask(AnalysisContext):
    """A recording frame outside the job, spread over the video: its lane cue for the height
    (camera._cues_elsewhere; one camera's height must not depend on the job's frames)."""

    def path(self, fid: str) -> Path:
        return self.dir / "elsewhere" / f"{fid}.json"

    def is_done(self, item: str) -> bool:
        return self.path(item).is_file()

    def process(self, item: str) -> dict:
        t0 = time.process_time()
        cue = split.elsewhere_cue(self.frame(item), self.rec, self.settings, self.hood["hood"])
        atomic.write_json(self.path(item), {"cue": cue})
        return {"lane": cue is not None, "cpu_s": round(time.process_time() - t0, 4)}


class CameraTask(AnalysisContext):
    """Item "camera": the recording-wide values from the sample's cues and the lane cues
    elsewhere (camera.recording_camera) -> analysis/recording.json."""

    def is_done(self, item: str) -> bool:
        return (self.dir / "recording.json").is_file()

    def process(self, item: str) -> dict:
        t0 = time.process_time()
        st = self.settings
        sample = split.sample_ids(self.ids)
        cues = {f: split.cues_of(json.loads(self.cue_path(f).read_text())) for f in sample}
        elsewhere = [c for c in (json.loads((self.dir / "elsewhere" / f"{f}.json").read_text())["cue"]
                                 for f in split.elsewhere_ids(self.rec, self.ids, st)) if c is not None]
        camera = split.recording_doc(cues, self.rec, st, elsewhere)
        doc = {"version": 2, "frames": len(self.ids), "sample": sample, "hood": self.hood, "camera": camera}
        if self.seq:  # the camera's yaw on its mount, from the sample's estimates (all of a short job's)
            rc = split.recording_of(camera)
            ests = {self.pos[f]: split.frame_camera(f, c, camera["angles"][f], rc, self.rec)[0] for f, c in cues.items()}
            doc["mount_yaw"] = split.mount_yaw(self.rec, self.index, ests)
            doc["gnss"] = split.gnss_track(self.rec, float(self.times[0]), float(self.times[-1])) is not None
        doc["cpu_s"] = round(time.process_time() - t0, 3)
        atomic.write_json(self.dir / "recording.json", doc)
        return {"sample": len(sample), "cpu_s": doc["cpu_s"], "height_m": camera["mount"]["height_m"],
                "fx": camera["fx"]}


# ----------------------------------------------------------------------------- cues

class CuesTask(AnalysisContext):
    def is_done(self, item: str) -> bool:
        return self.cue_path(item).is_file()

    def process(self, item: str) -> dict:
        t0 = time.process_time()
        fid, im = item, self.frame(item)
        cue = split.frame_cues(im, fid, float(self.times[self.pos[fid]]), self.rec, self.settings, self.detector,
                               self.hood)
        cue["cpu_s"] = round(time.process_time() - t0, 4)
        atomic.write_json(self.cue_path(fid), cue)
        return {"cpu_s": cue["cpu_s"], "users": len(cue["users"])}


# ----------------------------------------------------------------------------- analysis

class AnalysisTask(AnalysisContext):
    """The frame's camera (from the cues around it) and the rest of its analysis."""

    def __init__(self, job: dict, out_dir: str, **kw):
        super().__init__(job, out_dir, **kw)
        self._cues: dict[str, dict] = {}

    def cue(self, fid: str) -> dict:
        c = self._cues.get(fid)
        if c is None:
            if len(self._cues) > 256:
                self._cues.clear()
            c = self._cues[fid] = json.loads(self.cue_path(fid).read_text())
        return c

    def camera(self, fid: str):
        p = self.pos[fid]
        lo, hi = split.smoothing_range(self.times, p) if self.settings.seq else (p, p + 1)
        window = {x: split.cues_of(self.cue(x)) for x in self.ids[lo:hi]}
        a = split.angles_of(fid, window, self.rec, self.settings)
        return split.frame_camera(fid, window[fid], a, self.recording_camera, self.rec)

    def is_done(self, item: str) -> bool:
        return self.part_path(item).is_file()

    def process(self, item: str) -> dict:
        from blendgen import ground
        from blendgen.analysis import road
        from blendgen.analysis.stage import analyse_frame

        t0 = time.process_time()
        cue = self.cue(item)
        est, horizon = self.camera(item)
        fid, image = item, self.frame(item) if cue["decoded"] else None
        if image is None:
            fa, mask = FrameAnalysis(fid, self.rec.camera.width, self.rec.camera.height, est,
                                     ground.camera_pose(est).tolist(), horizon,
                                     decisions=[{"what": "frame", "value": None, "reason": "does not decode: no road "
                                                 "users, road or hood, the camera estimate only"}]), None
        else:
            camera = self.rec.camera.scaled(image.shape[1], image.shape[0])
            size = (image.shape[1], image.shape[0])
            fa, mask = analyse_frame(image, fid, camera, est, self.detector, horizon=horizon, hood=cue["hood"],
                                     user_road=road.user_mask(self.rec.root, "road", fid, size),
                                     user_walk=road.user_mask(self.rec.root, "sidewalk", fid, size),
                                     users=split.users_of(cue), oncoming=self.settings.oncoming,
                                     lane_width_m=self.settings.lane_width_m)
        cpu = round(time.process_time() - t0 + cue.get("cpu_s", 0.0), 3)
        fa.decisions.append({"what": "cpu_s", "value": cpu, "reason": "analysis CPU seconds of this frame "
                                                                    "(its cues and the rest, on a farm worker)"})
        if mask is not None:
            atomic.write_image(self.dir / f"{fid}_road.png", mask)
        path = self.part_path(fid)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic.write_json(path, fa.to_dict())  # last: marks the frame done
        return {"cpu_s": cpu, "road_users": len(fa.real_objects), "road": fa.road_mask is not None}


# ----------------------------------------------------------------------------- ego motion

class MotionContext(AnalysisContext):
    """Per recording frame of the drive: the camera and hood of the nearest job frame."""

    def __init__(self, job: dict, out_dir: str, **kw):
        super().__init__(job, out_dir, **kw)
        self.dpos = {f: k for k, f in enumerate(self.dense)}
        self._parts: dict[str, FrameAnalysis] = {}

    def part(self, d: int) -> FrameAnalysis:
        """The provisional analysis of the job frame nearest to drive frame d."""
        fid = self.ids[split.nearest_job(self.index, int(self.index[0]) + d)]
        fa = self._parts.get(fid)
        if fa is None:
            if len(self._parts) > 64:
                self._parts.clear()
            fa = self._parts[fid] = FrameAnalysis.from_dict(json.loads(self.part_path(fid).read_text()))
        return fa

    def motion_path(self, fid: str) -> Path:
        return self.dir / "motion" / f"{fid}.json"

    def chain_path(self, fid: str) -> Path:
        return self.dir / "chain" / f"{fid}.json"


class _ByDrive:
    """ests / hoods of the drive's frames for pair_motions, read as it asks."""

    def __init__(self, ctx: "MotionContext", what: str):
        self.ctx, self.what = ctx, what

    def __getitem__(self, fid: str):
        return getattr(self.ctx.part(self.ctx.dpos[fid]), self.what)

    def get(self, fid: str, default=None):
        return self[fid]


class MotionTask(MotionContext):
    """The ego motion's per-pair part. A worker runs on along the drive (VO and the previous
    bird's-eye view carry over); a run that starts elsewhere starts one frame early. Frame 0
    decides the road patch (`near`) for all."""

    def __init__(self, job: dict, out_dir: str, **kw):
        super().__init__(job, out_dir, **kw)
        self._gen, self._next = None, None

    def is_done(self, item: str) -> bool:
        return self.motion_path(item).is_file()

    def _start(self, d: int):
        from blendgen.analysis.egomotion import pair_motions

        near = None if d == 0 else json.loads(self.motion_path(self.dense[0]).read_text())["near"]
        i0 = int(self.index[0])
        run = (self.dense[k] for k in range(max(d - 1, 0), len(self.dense)))
        frames = ((fid, self.frame(fid)) for fid in run)
        times = {f: float(self.rec.frames_t[i0 + k]) for k, f in enumerate(self.dense)}
        gen = pair_motions(self.rec, frames, _ByDrive(self, "camera"), _ByDrive(self, "hood"), near, times=times)
        if d > 0:
            next(gen)  # the frame before: primes VO and the bird's-eye view
        return gen

    def process(self, item: str) -> dict:
        t0 = time.process_time()
        d = self.dpos[item]
        if self._gen is None or self._next != d:
            self._gen = self._start(d)
        fid, m, near = next(self._gen)
        self._next = d + 1
        rec = {**m.to_dict(), "near": near, "cpu_s": round(time.process_time() - t0, 4)}
        atomic.write_json(self.motion_path(item), rec)
        return {"cpu_s": rec["cpu_s"]}


class PosesTask(MotionContext):
    """The chain: each frame's pose from the one before; a job frame's final analysis."""

    def __init__(self, job: dict, out_dir: str, **kw):
        super().__init__(job, out_dir, **kw)
        from blendgen.analysis.split import gnss_track

        self.gnss = gnss_track(self.rec, float(self.times[0]), float(self.times[-1])) if self.seq else None

    def is_done(self, item: str) -> bool:
        return self.chain_path(item).is_file()

    def _raw_yaw(self, d: int):
        if d < 0 or d >= len(self.dense):
            return None
        return split.road_yaw_raw(self.part(d).camera)

    def process(self, item: str) -> dict:
        from blendgen.analysis import objects
        from blendgen.analysis.egomotion import ChainState, PairMotion, chain_pose, chain_step

        t0 = time.process_time()
        d = self.dpos[item]
        state = ChainState() if d == 0 else ChainState.from_dict(
            json.loads(self.chain_path(self.dense[d - 1]).read_text())["state"])
        mrec = json.loads(self.motion_path(item).read_text())
        m = PairMotion(**{k: mrec[k] for k in ("decoded", "yaw", "yaw_src", "ground", "has_prev")})
        yaw = split.despiked([self._raw_yaw(d - 1), self._raw_yaw(d), self._raw_yaw(d + 1)])
        i0 = int(self.index[0])
        gs = None if d == 0 else split.gnss_step(self.gnss, float(self.rec.frames_t[i0 + d - 1]),
                                                 float(self.rec.frames_t[i0 + d]))
        mount = self.calib["mount_yaw"]
        est = self.part(d).camera
        step = chain_step(state, m, yaw, mount, gs)
        T = chain_pose(state, est, mount)
        if item in self.pos:  # a job frame: its final analysis at this pose
            fa = FrameAnalysis.from_dict(json.loads(self.part_path(item).read_text()))
            camera = self.rec.camera.scaled(fa.width, fa.height)
            hood_top = float(np.asarray(fa.hood)[:, 1].min()) if fa.hood else None
            objects.with_footprints(fa.real_objects, camera, T, fa.height, horizon=fa.horizon, hood_top_v=hood_top)
            fa.T_world_cam = T.tolist()
            fa.decisions.append({"what": "pose", "value": [round(float(v), 3) for v in T[:3, 3]],
                                 "reason": f"video ego motion over the ground plane ({step.status})"})
            fa.decisions.append({"what": "cpu_s", "value": round(mrec["cpu_s"] + time.process_time() - t0, 4),
                                 "reason": "ego motion of this frame (its pair and the chain), on a farm worker"})
            atomic.write_json(self.dir / f"{item}.json", fa.to_dict())
        atomic.write_json(self.chain_path(item), {"state": state.to_dict(), "step": dict(step.__dict__)})
        return {"status": step.status, "cpu_s": round(time.process_time() - t0, 4)}


class PosesFileTask(AnalysisContext):
    """Item "poses.csv": OUT/poses.csv/.tum hold what plans and renders use: the job frames'
    analysed camera over the ground plane (ego motion for video), the fixed pose for the others."""

    def is_done(self, item: str) -> bool:
        return (self.dir / "poses.done").is_file()

    def process(self, item: str) -> dict:
        from blendgen.pipeline.plan_tasks import job_twin
        from blendgen.sync.pipeline import SyncResult, write_poses

        t0 = time.process_time()
        T0 = job_twin(self.job).camera_pose(0.0)
        out, quality = [], []
        for i in range(self.rec.n_frames):
            fid = self.rec.frame_id(i)
            T = T0
            if fid in self.pos:
                T = np.asarray(json.loads((self.dir / f"{fid}.json").read_text())["T_world_cam"], float)
            out.append((fid, float(self.rec.frames_t[i]), T))
            quality.append({"vo_status": "none", "vo_inliers": 0, "vo_parallax_px": 0.0,
                            "flags": ["ground_plane"] + (["analysis"] if fid in self.pos else [])})
        write_poses(self.folder.root, SyncResult(out, np.zeros((len(out), 6)), quality))
        cpu = round(time.process_time() - t0, 3)
        atomic.write_json(self.dir / "poses.done", {"frames": len(out), "cpu_s": cpu})
        return {"frames": len(out), "cpu_s": cpu}
