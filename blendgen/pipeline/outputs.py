"""The job output folder (DESIGN.md "Outputs"): paths, the resolved job, stage markers."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
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

