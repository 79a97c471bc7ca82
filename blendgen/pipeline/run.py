"""`blendgen run`: record (synthetic only) -> sync -> plan -> frames -> export -> report.

This process is the supervisor: it never imports bpy. Blender work (the synthetic
recording's frames, the per-frame renders) runs in farm workers. Every stage leaves its
outputs atomically and a marker; running the same job again skips what is finished.
"""

from __future__ import annotations

import functools
import hashlib
import json
import time
from collections import Counter
from pathlib import Path

import numpy as np

from blendgen import atomic
from blendgen.errors import StageError, UserError
from blendgen.job.schema import Job
from blendgen.pipeline.outputs import JobFolder
from blendgen.recording.folder import read_recording

STAGES = ("record", "sync", "analysis", "plan", "frames", "export", "report")


class Runner:
    def __init__(self, job: Job, *, engine: str | None = None, workers: int | None = None,
                 chunk: int | None = None, address: str | None = None, progress: bool = True,
                 until: str | None = None):
        self.job = job
        self.folder = JobFolder(job.out_dir)
        farm = job.farm
        self.farm = dict(engine=engine or farm.engine, workers=workers or farm.workers, chunk=chunk or farm.chunk,
                         max_attempts=farm.max_attempts, recycle_after=farm.recycle_after_frames,
                         max_rss_mb=farm.max_rss_mb, item_timeout_s=farm.item_timeout_s,
                         address=address or farm.address)
        self.progress = progress
        self.until = until  # "plan": stop when every frame is planned (benchmarks)
        self.pipeline_summaries: dict = {}
        self.times: dict[str, float] = {}
        self.skipped: list[str] = []
        self.warnings: list[str] = []

    def _say(self, stage: str, what: str) -> None:
        if self.progress:
            print(f"[{STAGES.index(stage) + 1}/{len(STAGES)}] {stage}: {what}", flush=True)

    @functools.cached_property
    def twin(self):
        if self.job.twin_path is not None:
            from blendgen.twin.model import load_twin

            return load_twin(self.job.twin_path)
        from blendgen.scene.ground_plane import GroundPlaneTwin

        return GroundPlaneTwin.from_job(self.job.ground_plane)

    # ------------------------------------------------------------------ stages
    def record(self) -> None:
        job = self.job
        if job.synthetic is None:
            self.skipped.append("record")
            self._say("record", f"using recording {job.recording_dir}")
            return
        root = job.recording_dir
        if (root / "frames.csv").exists():
            self.skipped.append("record")
            self._say("record", f"synthetic recording already made ({root})")
            return
        from blendgen.pipeline.synthetic import clear_sky_lighting, write_sensor_data
        from blendgen.recording.folder import write_frames_csv

        twin = self.twin
        s = job.synthetic
        self._say("record", f"synthetic drive {s.duration_s:g} s at {s.fps:g} fps, "
                               f"{s.resolution[0]}x{s.resolution[1]}, Cycles {s.samples} spp -> {root}")
        frame_t = write_sensor_data(root, twin, s, job.seed)
        rec = read_recording(root)
        lighting = clear_sky_lighting(twin.georef, rec.utc(0.0))
        ids = [rec.frame_id(i) for i in range(len(frame_t))]
        render = job.render.model_dump()
        render["resolution"] = None
        summary = self._farm("record", ids, "blendgen.pipeline.synthetic:BackgroundRenderer",
                             {"recording_dir": str(root), "twin_path": str(job.twin_path), "render": render,
                              "samples": s.samples, "lighting": lighting})
        if summary.failed or summary.failed_items:
            raise StageError(f"record: {len(summary.failed) + len(summary.failed_items)} background task(s)/"
                             f"frame(s) failed; see `blendgen status "
                             f"{self.folder.root}`")
        write_frames_csv(root, frame_t, [f"frames/{i}.png" for i in ids])

    def sync(self, rec) -> list[tuple[str, float, np.ndarray]]:
        from blendgen.sync.pipeline import read_poses, run_sync

        job = self.job
        if self.folder.stage_done("sync"):
            self.skipped.append("sync")
            self._say("sync", f"poses exist ({self.folder.poses_csv})")
            return read_poses(self.folder.poses_csv, rec)
        if job.ground_plane is not None:
            return self._ground_plane_poses(rec)
        lut = job.path(job.sync.lut) if job.sync.lut else self._default_lut()
        self._say("sync", f"{rec.n_frames} frames, {len(rec.imu)} IMU, {len(rec.gnss)} GNSS samples"
                             f"{', LUT ' + str(lut) if lut else ''}")
        with self.folder.progress("sync", rec.n_frames) as p:
            result = run_sync(rec, job.sync, self.folder.root, lut_path=lut, georef=self.twin.georef,
                              progress=self.progress, road_surface=self.twin.ground_heights, on_progress=p)
        self.folder.mark_stage("sync", {"frames": len(result.poses)})
        return result.poses

    def _ground_plane_poses(self, rec):
        """Footage without a map: the ground-plane twin is the road under the camera, so
        every frame's pose is the dashcam's fixed pose above it (no sync to estimate)."""
        from blendgen.sync.pipeline import SyncResult, write_poses

        T = self.twin.camera_pose(0.0)
        poses = [(rec.frame_id(i), float(t), T) for i, t in enumerate(rec.frames_t)]
        quality = [{"vo_status": "none", "vo_inliers": 0, "vo_parallax_px": 0.0, "flags": ["ground_plane"]}
                   for _ in poses]
        write_poses(self.folder.root, SyncResult(poses, np.zeros((len(poses), 6)), quality))
        self._say("sync", f"ground-plane twin: fixed camera pose for {len(poses)} frames"
                             + (" (the analysis stage estimates each frame's)" if self.job.ground_plane.analysis else ""))
        self.folder.mark_stage("sync", {"frames": len(poses), "ground_plane": True})
        return poses

    def _default_lut(self) -> Path | None:
        tp = self.job.twin_path
        if tp is None:
            return None
        lut = tp.with_name(f"{tp.stem}_lut.csv")
        if lut.exists():
            return lut
        lut = self.folder.state / "lut.csv"
        if not lut.exists():
            self.twin.export_lut(lut, 5.0)
        return lut

    def _selected(self, poses):
        job = self.job
        sel = poses[job.frames.start:job.frames.stop:job.frames.step]
        if not sel:
            raise UserError(f"frames: start {job.frames.start}, stop {job.frames.stop} select no frame of the "
                            f"recording's {len(poses)}", where="job")
        return sel

    # ------------------------------------------------------------------ the farm pipeline
    def pipeline(self, rec, poses) -> list[str]:
        """Frame analysis (ground-plane jobs), planning and rendering as one pipeline of farm
        tasks (pipeline.stages): each task starts as soon as what it needs is done, so the first
        frames are rendered while the rest of the recording is still analysed. Returns the job's
        frame ids."""
        from blendgen.farm import run_pipeline
        from blendgen.pipeline.stages import PipelineSpec

        job = self.job
        ids = [fid for fid, _, _ in self._selected(poses)]
        spec = PipelineSpec(job, rec, ids, self.folder)
        gp = job.ground_plane
        if spec.analysed:
            self._say("analysis", f"{len(ids)} frames on the farm: {', '.join(spec.analysis_stages)} -> "
                                  f"{self.folder.analysis}")
        else:
            self._say("analysis", "not needed (twin job)" if gp is None else "off (ground_plane.analysis: false)")
            self.skipped.append("analysis")
        assets = self.assets()  # before the workers start: planning draws from OUT/assets.json
        self._say("plan", f"{len(spec.windows)} plan window(s) on the farm -> {self.folder.root / 'plan'}")
        left = [] if self.until == "plan" else [i for i in ids if not self.folder.frame_done(i, job.export.save_exr)]
        if self.until != "plan":
            self._say("frames", f"{len(ids) - len(left)} of {len(ids)} done; rendering {len(left)} on "
                                f"{self.farm['workers']} {self.farm['engine']} worker(s) as their plans are made")
        stages = spec.stages(self.job.resolved(), with_frames=self.until != "plan", redo=left, chunk=self.farm["chunk"])
        del assets
        f = self.farm
        t0 = time.perf_counter()
        self.pipeline_summaries = run_pipeline(
            self.folder.root, stages, engine=f["engine"], workers=f["workers"], max_attempts=f["max_attempts"],
            recycle_after=f["recycle_after"], max_rss_mb=f["max_rss_mb"], item_timeout_s=f["item_timeout_s"],
            address=f["address"], progress=self.progress, seed=job.seed, name="pipeline")
        self.times["pipeline"] = round(time.perf_counter() - t0, 3)
        sums = self.pipeline_summaries
        for name, group in (("analysis", spec.analysis_stages), ("plan", ("plan", "plan_file")), ("frames", ("frames",))):
            group = [g for g in group if g in sums]
            if not group:
                continue
            if all(sums[g].already_done == sums[g].total for g in group):
                self.skipped.append(name)
            spans = [sums[g] for g in group if sums[g].first_start_s is not None]
            if spans:  # the stages overlap: each one's span from its first task to its last item
                self.times[f"{name}_span"] = round(max(x.last_done_s or 0 for x in spans)
                                                   - min(x.first_start_s for x in spans), 3)
        bad = [x for g, x in sums.items() if g != "frames" and not x.ok]
        if bad:
            raise StageError("; ".join(x.text() for x in bad) + f"\nsee `blendgen status {self.folder.root}`")
        if spec.analysed:  # poses.csv: the analysed poses (the pipeline's poses_file task wrote them)
            self.folder.mark_stage("analysis", {"frames": len(ids)})
        from blendgen.pipeline.plan_tasks import plan_dir, unplaced_warnings

        stats = json.loads((plan_dir(self.folder.root) / "stats.json").read_text())
        self.warnings = unplaced_warnings(stats, job.inject, len(ids))
        if not self.folder.stage_done("plan"):
            self.folder.mark_stage("plan", {"frames": len(ids), "objects": stats["objects"], "warnings": self.warnings})
        for w in self.warnings:
            print(f"  WARNING: {w}", flush=True)
        return ids

    def assets(self):
        """Import and measure every library asset once in a farm worker (resumable), write
        OUT/assets.json, and stop with every bad asset named before anything is planned."""
        from blendgen.job.assets import CATALOG_NAME, AssetSampler, discover, result_path

        if not self.job.inject.assets:
            return None
        refs = {result_path(self.folder.state, r).stem: r for r in discover(self.job.asset_sources)}
        self._say("plan", f"inspecting {len(refs)} library asset(s) in Blender")
        summary = self._farm("assets", list(refs), "blendgen.render.assets:AssetInspector",
                             {"refs": [r.to_dict() for r in refs.values()], "out_dir": str(self.folder.state)})
        if summary.failed:
            raise StageError(f"assets: {len(summary.failed)} inspection task(s) failed: "
                             f"{summary.failed[0].get('error', '')[:500]}")
        results = [json.loads(result_path(self.folder.state, r).read_text()) for r in refs.values()]
        bad = [f"{r['key']}: {r['error']}" for r in results if r.get("error")]
        if bad:
            raise UserError(f"{len(bad)} bad library asset(s); nothing was rendered:\n  " + "\n  ".join(bad),
                            where="inject.assets")
        atomic.write_json(self.folder.root / CATALOG_NAME, {"version": 1, "assets": results}, indent=1)
        return AssetSampler(results, self.job.inject.asset_share)

    def export(self, ids: list[str]) -> dict:
        from blendgen.labels.export import export_labels

        done = [self.folder.frame_dir(i) / "labels.json" for i in ids
                if self.folder.frame_done(i, self.job.export.save_exr)]
        ex = self.job.export
        # a frame done again (its files deleted) changes its labels.json: the export is redone
        stamp = hashlib.sha256("".join(f"{p.parent.name}:{p.stat().st_mtime_ns}:{p.stat().st_size};"
                                       for p in done).encode()).hexdigest()[:16]
        key = {"frames": [p.parent.name for p in done], "formats": ex.formats, "kitti_types": ex.kitti_types,
               "yolo_val_fraction": ex.yolo_val_fraction, "labels_stamp": stamp}
        if self.folder.stage_done("export") and self.folder.stage_info("export").get("key") == key:
            self.skipped.append("export")
            self._say("export", f"labels up to date ({self.folder.labels})")
            return self.folder.stage_info("export").get("result", {})
        self._say("export", f"{len(done)} frames -> {', '.join(self.job.export.formats)}")
        result = export_labels(self.folder.root, done, ex.formats, kitti_types=ex.kitti_types,
                               yolo_val_fraction=ex.yolo_val_fraction, seed=self.job.seed)
        self.folder.mark_stage("export", {"key": key, "result": result})
        return result

    def report(self) -> Path:
        from blendgen.report import build_report

        marker = self.folder.root / "report" / "index.md"
        if "export" in self.skipped and marker.exists():
            self.skipped.append("report")
            self._say("report", f"up to date ({marker})")
            return marker
        self._say("report", f"-> {self.folder.root / 'report'}")
        return build_report(self.folder.root)

    def _farm(self, stage: str, items: list[str], processor: str, args: dict, redo=()):
        from blendgen.farm import run_tasks

        return run_tasks(self.folder.root, stage, items, processor, args, progress=self.progress,
                         seed=self.job.seed, redo=redo, **self.farm)

    # ------------------------------------------------------------------ run
    def run(self) -> dict:
        self._check_frames()  # before anything is written: a corrected job must still fit
        with self.folder.lock():
            return self._run()

    def _check_frames(self) -> None:
        job = self.job
        if job.synthetic is not None:
            n = int(np.floor(job.synthetic.duration_s * job.synthetic.fps + 1e-9)) + 1  # as `record` makes it
        else:
            self._rec = read_recording(job.recording_dir, require_frames=True)  # read once: _run uses it
            n = self._rec.n_frames
            if job.labels.real in ("auto", "user", "ignore"):  # the frame workers use them: checked here, once
                from blendgen.recording.labels import read_recording_labels

                read_recording_labels(self._rec)
        if job.frames.start >= n:
            raise UserError(f"frames.start is {job.frames.start}, but the recording {job.recording_dir} has {n} "
                            f"frames (0..{n - 1}); nothing was written", where="job")

    def _run(self) -> dict:
        from blendgen.farm import clean_stale_temps

        dirs = [self.folder.root, self.folder.labels, self.folder.root / "report", self.folder.state]
        if self.job.synthetic is not None:  # the recording blendgen makes is ours to clean too
            dirs += [self.job.recording_dir, self.job.recording_dir / "frames"]
        for d in dirs:
            clean_stale_temps(d)  # what a killed earlier run left (we hold the folder's lock)
        self.folder.claim(self.job)
        t_all = time.perf_counter()

        def timed(name, fn, *a):
            t = time.perf_counter()
            out = fn(*a)
            self.times[name] = round(time.perf_counter() - t, 3)
            return out

        timed("record", self.record)
        rec = getattr(self, "_rec", None) or read_recording(self.job.recording_dir, require_frames=True)
        poses = timed("sync", self.sync, rec)
        ids = self.pipeline(rec, poses)
        if self.until == "plan":
            self.times["total"] = round(time.perf_counter() - t_all, 3)
            return {"job": self.job.name, "frames": {"total": len(ids)}, "seconds_per_stage": self.times,
                    "skipped_stages": self.skipped, "pipeline": self._stage_report()}
        farm_summary = self.pipeline_summaries["frames"]
        if farm_summary.already_done == farm_summary.total:
            farm_summary = None
        export = timed("export", self.export, ids)
        self.times["total"] = round(time.perf_counter() - t_all, 3)
        summary = self._summary(ids, farm_summary, export)  # written first: the report shows it
        timed("report", self.report)
        return summary

    def _summary(self, ids, farm_summary, export) -> dict:
        from blendgen.frame_labels import all_instances, read_frame_labels
        from blendgen.labels.export import source_counts

        done = [i for i in ids if self.folder.frame_done(i, self.job.export.save_exr)]
        per_class: Counter = Counter()
        insts = []
        for i in done:
            insts += all_instances(read_frame_labels(self.folder.frame_dir(i) / "labels.json"))
        for inst in insts:
            if not inst.get("ignore"):
                per_class[inst["cls"]] += 1
        # every frame not done is listed once, with the reason it failed
        reasons = {f["item"]: f["error"] for f in getattr(farm_summary, "failed_items", [])}
        for task in getattr(farm_summary, "failed", []) or []:
            reasons.update({i: f"task {task['task']} failed: {task['error']}" for i in task["items"]})
        done_set = set(done)
        failed = [{"frame": i, "reason": reasons[i]} for i in ids if i in reasons and i not in done_set]
        summary = {
            "job": self.job.name, "output": str(self.folder.root),
            "frames": {"total": len(ids), "done": len(done), "failed": len(failed)},
            "failed_frames": failed,
            "labels_per_class": dict(sorted(per_class.items())),
            # labels and ignore regions by where they came from: injected, user, detector (labels.real)
            "labels_per_source": source_counts(insts),
            "seconds_per_stage": self.times, "skipped_stages": self.skipped, "warnings": self.warnings,
            "throughput": self._throughput(farm_summary),
            "pipeline": self._stage_report(),
            "outputs": {"labels": str(self.folder.labels), "report": str(self.folder.root / "report" / "index.md"),
                        "manifest": str(self.folder.manifest), "frames": str(self.folder.root / "frames")},
            "export": export,
        }
        atomic.write_json(self.folder.summary, summary, indent=2)
        return summary

    def _stage_report(self) -> dict:
        """Per farm stage of the pipeline: items, how many this run did, when its first task
        started and its last item finished (seconds after the pipeline started)."""
        return {n: {"total": x.total, "processed": x.processed, "already_done": x.already_done,
                    "first_start_s": x.first_start_s, "first_done_s": x.first_done_s, "last_done_s": x.last_done_s}
                for n, x in self.pipeline_summaries.items()}

    def _throughput(self, farm_summary) -> dict:
        """Frames/min of the frame work alone (sync, analysis, plan, frames, export): what a real
        recording costs. The synthetic `record` stage is the demo's own recording, not work
        done per augmented frame, so it is left out."""
        from blendgen.report.build import FRAME_WORK

        frames = getattr(farm_summary, "processed", 0)
        work_s = sum(self.times.get(k, 0.0) for k in FRAME_WORK)
        return {"frames": frames, "frame_work_s": round(work_s, 3),
                "frames_per_min": round(60 * frames / work_s, 2) if frames and work_s > 0 else None}


def print_summary(s: dict) -> None:
    f = s["frames"]
    print()
    print(f"blendgen: job {s['job']!r} — {f['done']}/{f['total']} frames done"
          + (f", {f['failed']} FAILED" if f["failed"] else ""))
    for f in s.get("failed_frames", []):
        print(f"  FAILED {f['frame']}: {f['reason']}")
    if s["labels_per_class"]:
        print("  labels:  " + ", ".join(f"{k} {v}" for k, v in s["labels_per_class"].items()))
    else:
        print("  labels:  none")
    src = s.get("labels_per_source") or {}
    if src.get("per_source") or src.get("ignored_per_source"):
        ign = src.get("ignored_per_source") or {}
        print("  sources: " + ", ".join(f"{k} {v}" for k, v in src["per_source"].items())
              + (f"; ignore regions: {', '.join(f'{k} {v}' for k, v in ign.items())}" if ign else ""))
    times = s["seconds_per_stage"]
    print("  time:    " + ", ".join(f"{k} {v:.1f}s" for k, v in times.items())
          + (f"  (skipped, already done: {', '.join(s['skipped_stages'])})" if s["skipped_stages"] else ""))
    tp = s.get("throughput") or {}
    if tp.get("frames_per_min"):
        print(f"  speed:   {tp['frames_per_min']:.1f} frames/min of frame work ({tp['frames']} frames in "
              f"{tp['frame_work_s']:.1f} s of sync+analysis+plan+frames+export; recording synthesis not counted)")
    for w in s.get("warnings", []):
        print(f"  WARNING: {w}")
    o = s["outputs"]
    print(f"  outputs: {o['frames']}/<frame>/composite.png, {o['labels']}/, {o['report']}")
