"""The stages of `blendgen run`'s farm pipeline and what each task waits for (supervisor side).

    hood -> sample, elsewhere -> camera; hood -> cues; camera, cues -> analysis -> motion -> poses
    -> plan -> frames  (ground-plane jobs with analysis; a video adds motion and poses; twin
    jobs: plan -> frames)

Dependencies are ranges of item positions (farm.graph): a frame's analysis waits for the cues
of the frames within +-0.5 s, the ego motion of a recording frame for the analyses of the job
frames nearest to it and the one before, the pose chain for its predecessor, a plan window
for the final analyses (poses) of its frames and, in phase 2, for its two neighbours, and a
frame's render for its window and the one before (whose tracks may spill into it). Everything
here is a few numbers per frame: the supervisor's memory is the ledger's, not the frames'.
"""

from __future__ import annotations

import numpy as np

from blendgen.analysis import split
from blendgen.farm.graph import Stage
from blendgen.scene import windows as W

CUES_CHUNK = 8        # frames per task of the per-frame analysis stages (~1-2 s of work)
MOTION_CHUNK = 16
CHAIN_CHUNK = 64      # the pose chain: microseconds a frame
PRIORITY = {"hood": 9, "camera": 8, "sample": 7, "frames": 6, "plan": 5, "poses": 4, "motion": 3, "analysis": 2,
            "cues": 1}


class PipelineSpec:
    def __init__(self, job, rec, ids: list[str], folder):
        self.job, self.rec, self.ids, self.folder = job, rec, ids, folder
        gp = job.ground_plane
        self.analysed = gp is not None and gp.analysis
        self.index = np.arange(rec.n_frames)[job.frames.start:job.frames.stop:job.frames.step]
        self.times = np.asarray(rec.frames_t, float)[self.index]
        self.seq_cam = split.Settings(rec, gp).seq if self.analysed else False
        self.video = self.analysed and self.seq_cam and len(ids) > 1
        self.dense = split.dense_ids(rec, self.index) if self.video else []
        self.windows = W.plan_windows(self.times, job.inject.sequences)
        self.pos = {f: k for k, f in enumerate(ids)}           # shared by the stages over the job's frames
        self.dpos = {f: k for k, f in enumerate(self.dense)}
        self.analysis_stages = (("hood", "sample", "elsewhere", "camera", "cues", "analysis")
                                + (("motion", "poses") if self.video else ()) + ("poses_file",) if self.analysed else ())

    # -- positions -------------------------------------------------------------------------
    def _job_near(self, d: int) -> int:
        """Job position of the frame nearest to drive frame d."""
        return split.nearest_job(self.index, int(self.index[0]) + d)

    def _dense_of(self, p: int) -> int:
        return int(self.index[p] - self.index[0])

    def needs_analysis(self, p: int):
        lo, hi = split.smoothing_range(self.times, p) if self.seq_cam else (p, p + 1)
        return [("cues", lo, hi), ("camera", 0, 1)]

    def needs_motion(self, d: int):
        a, b = self._job_near(max(d - 1, 0)), self._job_near(d)
        return [("analysis", min(a, b), max(a, b) + 1)] + ([("motion", 0, 1)] if d else [])

    def needs_poses(self, d: int):
        a, b = self._job_near(max(d - 1, 0)), self._job_near(min(d + 1, len(self.dense) - 1))
        return [("poses", d - 1, d), ("motion", d, d + 1), ("analysis", a, b + 1), ("camera", 0, 1)]

    def needs_plan(self, w: int):
        win = self.windows[w]
        out = []
        if self.video:
            out.append(("poses", self._dense_of(win.start), self._dense_of(win.horizon - 1) + 1))
        elif self.analysed:
            out.append(("analysis", win.start, win.horizon))
        out += [("plan", j, j + 1) for j in W.window_needs(self.windows, w)[1]]
        return out

    def needs_frame(self, p: int):
        w = W.window_of(self.windows, p)
        return [("plan", max(w - 1, 0), w + 1)]

    # -- stages ----------------------------------------------------------------------------
    def stages(self, job_dict: dict, *, with_frames: bool = True, redo=(), chunk: int | None = None) -> list[Stage]:
        args = {"job": job_dict, "out_dir": str(self.folder.root)}
        mod = "blendgen.pipeline.analysis_tasks"
        out = []
        if self.analysed:
            # the camera scales its height exactly with a lane width the user gave (camera.CameraSettings)
            an = {**args, "lane_width_given": "lane_width_m" in self.job.ground_plane.model_fields_set}
            sample = split.sample_ids(self.ids)
            spos = {f: k for k, f in enumerate(sample)}
            elsewhere = split.elsewhere_ids(self.rec, self.ids, split.Settings(self.rec, self.job.ground_plane))
            out += [Stage("hood", ["hood"], f"{mod}:HoodTask", an, chunk=1, priority=PRIORITY["hood"], recycle=False),
                    Stage("sample", sample, f"{mod}:CuesTask", an, chunk=2, priority=PRIORITY["sample"],
                          needs=lambda k: [("hood", 0, 1)], recycle=False),
                    Stage("camera", ["camera"], f"{mod}:CameraTask", an, chunk=1, priority=PRIORITY["camera"],
                          needs=lambda k: [("sample", 0, len(sample)), ("elsewhere", 0, len(elsewhere))],
                          recycle=False),
                    Stage("cues", self.ids, f"{mod}:CuesTask", an, chunk=CUES_CHUNK, priority=PRIORITY["cues"],
                          needs=lambda p: [("hood", 0, 1)] + ([("sample", spos[self.ids[p]], spos[self.ids[p]] + 1)]
                                                              if self.ids[p] in spos else []), recycle=False,
                          index=self.pos),
                    Stage("analysis", self.ids, f"{mod}:AnalysisTask", an, chunk=CUES_CHUNK,
                          priority=PRIORITY["analysis"], needs=self.needs_analysis, recycle=False, index=self.pos)]
            out.insert(2, Stage("elsewhere", elsewhere, f"{mod}:ElsewhereTask", an, chunk=2,
                                priority=PRIORITY["sample"], needs=lambda k: [("hood", 0, 1)], recycle=False))
            if self.video:
                out += [Stage("motion", self.dense, f"{mod}:MotionTask", an, chunk=MOTION_CHUNK,
                              priority=PRIORITY["motion"], needs=self.needs_motion, recycle=False, index=self.dpos),
                        Stage("poses", self.dense, f"{mod}:PosesTask", an, chunk=CHAIN_CHUNK,
                              priority=PRIORITY["poses"], needs=self.needs_poses, recycle=False, index=self.dpos)]
        out.append(Stage("plan", [w.name for w in self.windows], "blendgen.pipeline.plan_tasks:PlanWindowTask", args,
                         chunk=1, priority=PRIORITY["plan"], needs=self.needs_plan, recycle=False))
        # the whole-job files, written by a worker once their inputs are in (not the supervisor's work)
        out.append(Stage("plan_file", ["plan.jsonl"], "blendgen.pipeline.plan_tasks:PlanFileTask", args, chunk=1,
                         needs=lambda k: [("plan", 0, len(self.windows))], recycle=False))
        if self.analysed:
            last = ("poses", 0, len(self.dense)) if self.video else ("analysis", 0, len(self.ids))
            out.append(Stage("poses_file", ["poses.csv"], f"{mod}:PosesFileTask", an, chunk=1,
                             needs=lambda k: [last], recycle=False))
        if with_frames:
            out.append(Stage("frames", self.ids, "blendgen.pipeline.frame:FrameProcessor", args,
                             chunk=chunk or self.job.farm.chunk, priority=PRIORITY["frames"], needs=self.needs_frame,
                             redo=redo, index=self.pos))
        return out
