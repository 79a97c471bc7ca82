"""The job output folder (DESIGN.md "Outputs"): paths, the resolved job, stage markers."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import time
from pathlib import Path

import yaml

from blendgen import atomic
from blendgen.errors import UserError
from blendgen.job.schema import Job

FRAME_OUTPUTS = ("composite.png", "instances.png", "labels.json")


class JobFolder:
    def __init__(self, root: Path):
        self.root = Path(root)

    # ---- paths
    @property
    def state(self) -> Path:
        return self.root / ".blendgen"

    @property
    def resolved_job(self) -> Path:
        return self.root / "job.resolved.yaml"

    @property
    def poses_csv(self) -> Path:
        return self.root / "poses.csv"

    @property
    def plan(self) -> Path:
        return self.root / "plan.jsonl"

    @property
    def analysis(self) -> Path:
        return self.root / "analysis"

    @property
    def manifest(self) -> Path:
        return self.root / "manifest.jsonl"

    @property
    def labels(self) -> Path:
        return self.root / "labels"

    @property
    def summary(self) -> Path:
        return self.root / "run_summary.json"

    def frame_dir(self, frame_id: str) -> Path:
        return self.root / "frames" / frame_id

    def frame_done(self, frame_id: str, save_exr: bool) -> bool:
        d = self.frame_dir(frame_id)
        names = FRAME_OUTPUTS + (("render.exr",) if save_exr else ())
        return all((d / n).exists() for n in names)

    # ---- one blendgen process per folder, for every stage (the farm's own lock covers a
    # farm stage only; sync, plan and export write here too)
    @contextlib.contextmanager
    def lock(self):
        self.state.mkdir(parents=True, exist_ok=True)
        with open(self.state / "job.lock", "a+") as f:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                f.seek(0)
                raise UserError(f"another blendgen is running on this folder ({f.read().strip() or 'unknown pid'}); "
                                "wait for it or stop it first", where=str(self.root)) from None
            f.seek(0)
            f.truncate()
            f.write(f"pid {os.getpid()}\n")
            f.flush()
            (self.state / "progress.json").unlink(missing_ok=True)  # a dead run's stage is not this run's
            yield

    # ---- the resolved job: one output folder holds one job
    def claim(self, job: Job) -> None:
        """Write job.resolved.yaml, or check that the folder already holds this same job."""
        resolved = job.resolved()
        digest = job.content_hash()
        if self.resolved_job.exists():
            try:
                old = yaml.safe_load(self.resolved_job.read_text()) or {}
            except yaml.YAMLError:
                old = {}
            if old.get("content_hash") != digest:
                raise UserError(
                    f"holds the outputs of a different job (content hash {old.get('content_hash')} vs "
                    f"{digest}); use another `output` folder, or delete this one to start over",
                    where=str(self.root))
            return
        self.root.mkdir(parents=True, exist_ok=True)
        doc = {"content_hash": digest, **resolved}
        atomic.write_text(self.resolved_job, yaml.safe_dump(doc, sort_keys=False))

    # ---- stage markers (a stage is done when its marker exists; the job is fixed per folder)
    def stage_done(self, stage: str) -> bool:
        return (self.state / f"{stage}.done").exists()

    def mark_stage(self, stage: str, info: dict) -> None:
        atomic.write_json(self.state / f"{stage}.done", info)

    def stage_info(self, stage: str) -> dict:
        p = self.state / f"{stage}.done"
        return json.loads(p.read_text()) if p.exists() else {}

    # ---- progress of the stages that run in this process (farm stages have the ledger)
    def progress(self, stage: str, total: int) -> "StageProgress":
        return StageProgress(self.state / "progress.json", stage, total)

    def progress_line(self) -> str | None:
        """`blendgen status`'s line for an in-process stage that is running or was cut short,
        or None (its file exists only from the stage's start to its end, in one run)."""
        from blendgen.farm.status import fmt_duration, lock_held

        try:
            p = json.loads((self.state / "progress.json").read_text())
            done, total, phase = int(p["done"]), int(p["total"]), p["phase"]
            rate = (done - p["done_at_start"]) / max(p["updated"] - p["started"], 1e-6)
        except (OSError, ValueError, KeyError, TypeError):  # none, or not ours
            return None
        head = f"[{p['stage']}{': ' + phase if phase else ''}] {done}/{total} frames"
        if not lock_held(self.state / "job.lock"):  # its process is gone
            return f"{head}, stopped (pid {p['pid']} on {p['host']} is gone); run again to resume"
        eta = f", ETA {fmt_duration((total - done) / rate)}" if rate > 0 and done < total else ""
        return (f"{head}, running (pid {p['pid']} on {p['host']}), {rate:.2f} frames/s, last update "
                f"{fmt_duration(time.time() - p['updated'])} ago{eta}")


class StageProgress:
    """Call with the number of frames done (and the stage's current phase): written atomically
    at most every EVERY_S seconds, at a new phase and at the last frame, for `blendgen status`
    from another shell. As a context manager, the file goes when the stage ends without error."""

    EVERY_S = 2.0

    def __init__(self, path: Path, stage: str, total: int):
        self.path, self.doc = path, {"stage": stage, "phase": "", "done": 0, "total": int(total),
                                     "pid": os.getpid(), "host": socket.gethostname()}
        self._last = 0.0
        self(0)

    def __call__(self, done: int, phase: str = "", total: int | None = None) -> None:
        """`total`: the phase's own count when it is not the stage's (sync's filter: poses)."""
        now = time.time()
        new_phase = phase != self.doc["phase"] or "started" not in self.doc
        if not new_phase and now - self._last < self.EVERY_S and done < self.doc["total"]:
            return
        if new_phase:  # the rate is per phase
            self.doc.update(phase=phase, started=now, done_at_start=int(done))
        if total is not None:
            self.doc["total"] = int(total)
        self._last = now
        self.doc.update(done=int(done), updated=now)
        atomic.write_json(self.path, self.doc)

    def __enter__(self) -> "StageProgress":
        return self

    def __exit__(self, exc_type, *_) -> None:
        if exc_type is None:
            self.path.unlink(missing_ok=True)
