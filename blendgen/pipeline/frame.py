"""Per-frame work inside a farm worker: illumination -> render -> post -> labels.

`FrameProcessor` is instantiated once per worker process (it holds the warm Blender
session) and then processes many frames. It is the only pipeline code that reaches bpy,
and only through `blendgen.render.session`, imported lazily.
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import cv2
import numpy as np

from blendgen import __version__, atomic
from blendgen.farm.processor import clean_stale_temps
from blendgen.farm.seeds import frame_seed
from blendgen.job.schema import parse_job
from blendgen.pipeline.outputs import JobFolder
from blendgen.plan import SCENERY_ID, FramePlan
from blendgen.recording.folder import read_frame, read_recording


def render_outputs(job) -> set[str]:
    """The passes the job's outputs need (simulate only what is needed)."""
    outputs = {"rgba", "index"}
    if job.post.shadows:
        outputs.add("shadow_catcher")
    if job.post.relight and job.post.illumination == "auto":
        outputs.add("lighting")
    return outputs


def load_plans(path: Path) -> dict[str, FramePlan]:
    plans = {}
    with open(path) as f:
        for line in f:
            if line.strip():
                p = FramePlan.from_dict(json.loads(line))
                plans[p.frame_id] = p
    return plans


class FrameProcessor:
    def __init__(self, job: dict, out_dir: str):
        self.job = parse_job(job, source=str(Path(out_dir) / "job.resolved.yaml"))
        self.folder = JobFolder(Path(out_dir))
        self.rec = read_recording(self.job.recording_dir)
        self._plans = None  # read at the first frame: in a pipeline the plan is made after the workers start
        self.georef = self._georef()
        w, h = self.job.render.resolution or (self.rec.camera.width, self.rec.camera.height)
        self.camera = self.rec.camera.scaled(w, h)
        self.session = None
        self.sensor = None  # the camera's sensor profile, measured once per block of frames
        self.real_mode, self.rec_labels = real_label_mode(self.job, self.rec)
        self.detector = None  # twin jobs with detector labels: loaded on first use

    def _real(self, i: int) -> np.ndarray:
        """Recording frame i at the render resolution."""
        real = read_frame(self.rec, i)
        if real.shape[:2] != (self.camera.height, self.camera.width):
            real = cv2.resize(real, (self.camera.width, self.camera.height), interpolation=cv2.INTER_AREA)
        return real

    @property
    def plans(self):
        """frame id -> FramePlan: from the plan windows (OUT/plan/, one window file at a time), or
        from OUT/plan.jsonl."""
        if self._plans is None:
            from blendgen.pipeline.plan_tasks import FramePlans, plan_dir

            if plan_dir(self.folder.root).is_dir():
                fr = self.job.frames
                index = np.arange(self.rec.n_frames)[fr.start:fr.stop:fr.step]
                self._plans = FramePlans(self.folder.root, np.asarray(self.rec.frames_t, float)[index],
                                         self.job.inject.sequences, [self.rec.frame_id(int(i)) for i in index])
            else:
                self._plans = load_plans(self.folder.plan)
        return self._plans

    def _georef(self):
        if self.job.twin_path is None:
            return None
        from blendgen.twin.model import load_twin

        return load_twin(self.job.twin_path).georef

    def is_done(self, frame_id: str) -> bool:
        return self.folder.frame_done(frame_id, self.job.export.save_exr)

    def process(self, frame_id: str) -> dict:
        from blendgen.frame_labels import write_frame_labels
        from blendgen.labels.instances import extract_instances
        from blendgen.post.composite import composite_frame
        from blendgen.post.illumination import estimate_illumination
        from blendgen.render.exr import read_passes

        job, plan = self.job, self.plans[frame_id]
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        i = int(frame_id.lstrip("f"))
        real = self._real(i)
        seed = frame_seed(job.seed, frame_id)

        fa, real_boxes = self._analysis(frame_id)
        illum = None
        if job.post.illumination == "auto":
            from blendgen.frame_analysis import RealObject

            # the real road users' shadows give the sun's azimuth when time/position do not
            users = [RealObject(b["cls"], 0.0, b["box"], o.footprint)
                     for b, o in zip(real_boxes or [], fa.real_objects if fa else [])]
            illum = estimate_illumination(real, T_world_cam=np.asarray(plan.T_world_cam),
                                          when_utc=self.rec.utc(plan.t),
                                          latlon=self.georef[:2] if self.georef else None,
                                          real_objects=users, camera=self.camera)
            plan.lighting = illum.to_lighting()
        timings["illumination"] = time.perf_counter() - t0

        t1 = time.perf_counter()
        if self.session is None:
            from blendgen.render.session import RenderSession

            self.session = RenderSession(job.twin_path, job.ground_plane, job.render, self.camera)
        fdir = self.folder.frame_dir(frame_id)
        fdir.mkdir(parents=True, exist_ok=True)
        clean_stale_temps(fdir)  # what a killed attempt left (only this worker writes here)
        exr = fdir / "render.exr"
        # An EXR deleted after the frame (export.save_exr: false) is written uncompressed:
        # ~0.15 CPU-s less to write and read (docs/render.md).
        info = self.session.render_frame(plan, exr, render_outputs(job),
                                         compression="zip" if job.export.save_exr else "none",
                                         environment=lambda: self._environment(real, plan, fa), seed=seed)
        passes = read_passes(exr)
        timings["render"] = time.perf_counter() - t1

        t2 = time.perf_counter()
        if fa is not None and fa.hood:  # the real hood hides whatever is behind it
            from blendgen.frame_analysis import hood_mask
            from blendgen.post.composite import apply_occluder

            sx, sy = self.camera.width / fa.width, self.camera.height / fa.height
            passes = apply_occluder(passes, hood_mask(np.asarray(fa.hood) * [sx, sy], self.camera.width,
                                                      self.camera.height))
        profile = None
        if job.post.sensor_match:
            from blendgen.post.sensor import SensorCache

            if self.sensor is None:
                self.sensor = SensorCache(self._real)
            profile, profile_src = self.sensor.profile(i, real)
        composite, post_info = composite_frame(real, passes, settings=job.post, illumination=illum, seed=seed,
                                               sensor_profile=profile)
        if profile is not None and post_info.get("sensor") is not None:
            post_info["sensor"]["measured_on"] = profile_src
        timings["post"] = time.perf_counter() - t2

        t3 = time.perf_counter()
        from blendgen.labels.real_objects import real_instances

        index = passes["index"]
        real_boxes_out = self._real_labels(frame_id, real, fa)
        if real_boxes_out is not None:
            real_boxes = [{"cls": r["cls"], "box": r["box"]} for r in real_boxes_out]
        instances = extract_instances(index, plan, self.camera, amodal_px=info.get("amodal_px"),
                                      min_visible_px=job.export.min_visible_px, small_objects=job.export.small_objects,
                                      real_boxes=real_boxes)
        # every rendered pixel (objects, their scenery) is in front of the real frame's road users
        real_insts = None if real_boxes_out is None else real_instances(
            real_boxes_out, index > 0, min_visible_px=job.export.min_visible_px,
            small_objects=job.export.small_objects)
        # the instance image holds labelled objects only (scenery such as a signal pole is not one)
        atomic.write_image(fdir / "instances.png", np.where(index >= SCENERY_ID, 0, np.clip(index, 0, None))
                           .astype(np.uint16))
        atomic.write_image(fdir / "composite.png", composite)
        # labels.json last: its presence (with the others) marks the frame finished.
        write_frame_labels(fdir / "labels.json", frame_id, f"frames/{frame_id}/composite.png",
                           self.camera.width, self.camera.height, instances, camera=self.camera, real=real_insts)
        if not job.export.save_exr:
            exr.unlink(missing_ok=True)
        timings["labels"] = time.perf_counter() - t3
        timings["total"] = time.perf_counter() - t0

        return {
            "stage": "frames", "frame_id": frame_id, "t": plan.t, "seed": seed,
            "versions": {"blendgen": __version__},
            "objects": {o.cls: sum(1 for q in plan.objects if q.cls == o.cls) for o in plan.objects},
            "labels": len([x for x in instances if not x.get("ignore")]),
            "real_labels": None if real_insts is None else {  # labels.real's mode and what it gave
                "mode": self.real_mode, "sources": sorted({x["source"] for x in real_insts}),
                "labels": sum(not x["ignore"] for x in real_insts), "ignored": sum(x["ignore"] for x in real_insts),
                "dropped": len(real_boxes_out) - len(real_insts)},  # wholly covered, or too small
            "hashes": {n: _sha(fdir / n) for n in ("composite.png", "instances.png", "labels.json")},
            "timings": {k: round(v, 4) for k, v in timings.items()},
            "render": {k: v for k, v in info.items() if k != "amodal_px"},
            "post": post_info,
            "analysis": None if fa is None else {
                "camera": fa.camera.__dict__, "road_direction_deg": fa.road_direction_deg,
                "real_objects": len(fa.real_objects), "hood": fa.hood is not None, "decisions": fa.decisions},
            "plan_decisions": plan.decisions,
            "illumination": None if illum is None else {  # what the light was read from, and fallbacks
                k: getattr(illum, k) for k in ("condition", "visibility_cue", "sun_visible", "sun_azimuth_deg",
                                               "sun_direction_source", "road_albedo", "notes")},
        }

    def _environment(self, real: np.ndarray, plan: FramePlan, fa) -> np.ndarray | None:
        """What glass and clear coat mirror by day: the real frame around the camera, its hood cut
        off. At dusk and night the lighting's dim uniform world and the lamp's glint (a frame's
        lamps and glare, spread around the car, turned black paint grey on the BDD night street)."""
        if self.job.render.reflections != "frame" or (plan.lighting or {}).get("condition", "day") != "day":
            return None
        from blendgen.render.environment import plate_environment

        hood_top = None
        if fa is not None and fa.hood:
            hood_top = min(p[1] for p in fa.hood) * self.camera.height / fa.height
        return plate_environment(real, self.camera, plan.T_world_cam, hood_top=hood_top)

    def _analysis(self, frame_id: str):
        """The frame's analysis (ground-plane jobs) and its real boxes at the render resolution."""
        from blendgen.frame_analysis import read_analysis

        fa = read_analysis(self.folder.analysis, frame_id)
        if fa is None:
            return None, None
        sx, sy = self.camera.width / fa.width, self.camera.height / fa.height
        return fa, [{"cls": o.cls, "box": [o.box[0] * sx, o.box[1] * sy, o.box[2] * sx, o.box[3] * sy]}
                    for o in fa.real_objects]

    def _real_labels(self, frame_id: str, real_frame: np.ndarray, fa) -> list[dict] | None:
        """The real road users of this frame as labels.real says (render resolution), or None."""
        from blendgen.labels.real_objects import DETECTOR_LABEL_SCORE, detector_boxes, user_boxes

        mode = self.real_mode
        if mode == "none":
            return None
        if mode in ("user", "ignore") and self.rec_labels is not None and frame_id in self.rec_labels:
            W, H = self.rec.camera.width, self.rec.camera.height
            boxes = user_boxes(self.rec_labels[frame_id], self.camera.width / W, self.camera.height / H)
        else:  # detector, or a frame the user's labels do not cover
            if fa is not None:  # the analysis' detections: the ego vehicle's own hood already left out
                sx, sy = self.camera.width / fa.width, self.camera.height / fa.height
                dets = [{"cls": o.cls, "score": o.score, "distance_m": o.distance_m,
                         "box": [o.box[0] * sx, o.box[1] * sy, o.box[2] * sx, o.box[3] * sy]}
                        for o in fa.real_objects]
            else:
                from blendgen.analysis.objects import load_detector, road_users

                if self.detector is None:
                    gp = self.job.ground_plane
                    self.detector = load_detector(self.job.path(gp.detector) if gp and gp.detector else None)
                from blendgen.analysis.stage import not_ego

                H, W = real_frame.shape[:2]  # no hood known: a very wide box at the bottom is our own car
                users, _ = not_ego(road_users(real_frame, self.detector), None, W, H)
                dets = [{"cls": o.cls, "score": o.score, "box": o.box} for o in users]
            boxes = detector_boxes(dets, self.job.labels.detector_score or DETECTOR_LABEL_SCORE)
        if mode == "ignore":
            for b in boxes:
                b["ignore"] = True
        return boxes

    def close(self):
        if self.session is not None:
            self.session.close()


def real_label_mode(job, rec) -> tuple[str, dict | None]:
    """(labels.real with `auto` resolved, the recording's own labels or None)."""
    from blendgen.recording.labels import read_recording_labels

    labels = read_recording_labels(rec) if job.synthetic is None else None
    mode = job.labels.real
    if mode == "auto":
        mode = "none" if job.synthetic is not None else "user" if labels is not None else "detector"
    return mode, labels


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]
