"""The supervisor's bookkeeping, shared by every engine: the ledger, the manifest, the
progress bar, per-attempt log paths and the final summary. Single writer by construction:
a lock file keeps a second supervisor off the same output folder."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

from .. import atomic
from ..errors import UserError
from .graph import Stage, TaskGraph
from .ledger import LEDGER_DIR, Ledger
from .seeds import frame_seed

MANIFEST = "manifest.jsonl"
LEASE_S = 60.0  # a running task's lease; renewed by every supervisor heartbeat
FLUSH_EVERY_S = 0.2  # manifest fsync + ledger commit at most this often (and at the end)
FLUSH_LINES = 512
PROGRESS_EVERY_S = 10.0  # a pipeline prints one line of its stages' counts this often


def fmt_s(s: float) -> str:
    s = int(s)
    return f"{s // 60}m{s % 60:02d}s"
_STAGE = re.compile(r"^[A-Za-z0-9_-]+$")


@dataclass
class FarmSummary:
    """What `run_tasks` returns. `ok` is False when any task failed for good."""

    stage: str
    engine: str
    run_id: int
    total: int                 # items asked for
    done: int                  # items done after this run (including earlier runs)
    already_done: int          # items done before this run started (not dispatched)
    processed: int             # items this run processed
    skipped: int               # items a worker found already complete (is_done)
    failed: list[dict] = field(default_factory=list)  # {task, items, attempts, error, log}
    failed_items: list[dict] = field(default_factory=list)  # {item, error}: bad input, no retry
    elapsed_s: float = 0.0
    workers_started: int = 0
    worker_deaths: int = 0     # unexpected worker exits (crash, kill, OOM)
    recycled: int = 0          # planned restarts (recycle_after / max_rss_mb)
    retired: list[str] = field(default_factory=list)  # workers/nodes that kept failing
    ledger: str = ""
    manifest: str = ""
    # seconds after the run started: its first task's start, its first and last item done (None: none)
    first_start_s: float | None = None
    first_done_s: float | None = None
    last_done_s: float | None = None

    @property
    def ok(self) -> bool:
        return not self.failed and not self.failed_items and self.done == self.total

    @property
    def rate(self) -> float:
        return (self.processed + self.skipped) / self.elapsed_s if self.elapsed_s > 0 else 0.0

    def text(self) -> str:
        lines = [f"{self.stage}: {self.done}/{self.total} done ({self.already_done} before this "
                 f"run, {self.processed} processed, {self.skipped} found complete) in "
                 f"{self.elapsed_s:.1f} s on {self.engine}; {self.workers_started} worker "
                 f"start(s), {self.worker_deaths} death(s), {self.recycled} recycle(s)"]
        if self.retired:
            lines.append(f"  retired for repeated failures: {', '.join(self.retired)}")
        for f in self.failed:
            items = ", ".join(f["items"][:5]) + (" ..." if len(f["items"]) > 5 else "")
            lines.append(f"  FAILED task {f['task']} [{items}] after {f['attempts']} attempt(s):"
                         f" {f['error']}\n    log: {f['log']}")
        for f in self.failed_items:
            lines.append(f"  FAILED frame {f['item']}: {f['error']}")
        return "\n".join(lines)


def read_manifest_items(path: Path, stage: str) -> set[str]:
    """Items of `stage` with a record in the manifest (a torn last line is skipped)."""
    done: set[str] = set()
    if not path.exists():
        return done
    with open(path, encoding="utf-8") as f:
        for line in f:
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(rec, dict) and rec.get("stage") == stage and "item" in rec:
                done.add(str(rec["item"]))
    return done


@dataclass
class EngineStats:
    """What the engine counts across all stages of a run."""

    workers_started: int = 0
    worker_deaths: int = 0
    recycled: int = 0
    retired: list[str] = field(default_factory=list)


def _check_items(stage: str, items: list[str]) -> None:
    if not isinstance(stage, str) or not _STAGE.match(stage):
        raise UserError(f"stage must match [A-Za-z0-9_-]+, got {stage!r}", where="farm")
    seen: set[str] = set()
    for it in items:
        if not isinstance(it, str) or not it:
            raise UserError(f"items must be non-empty strings (frame ids), got {it!r}",
                            where=f"farm stage {stage}")
        if it in seen:
            raise UserError(f"frame id {it!r} appears twice", where=f"farm stage {stage}")
        seen.add(it)


class Books:
    """The bookkeeping of one farm run: one stage (`Books(out, "frames", items, chunk=...)`) or
    a pipeline of stages (`Books(out, [Stage, ...])`) sharing the workers, the lock, the ledger
    and the manifest. Engines address everything by task id."""

    def __init__(self, out_dir: Path, stages, items: list[str] | None = None, *, chunk: int = 4,
                 engine: str, workers: int, seed: int, max_attempts: int, progress: bool, redo=(),
                 name: str | None = None):
        if isinstance(stages, str):
            stages = [Stage(stages, list(items or []), "-:-", {}, chunk=chunk, redo=redo)]
        for st in stages:
            _check_items(st.name, st.items)
        self.out_dir = Path(out_dir)
        self.stages = {st.name: st for st in stages}
        self.name = name or stages[0].name
        self.seed, self.max_attempts = seed, max_attempts
        self.meta_dir = self.out_dir / LEDGER_DIR
        self.tmp_dir = self.meta_dir / "tmp" / self.name  # workers' TMPDIR (run_tasks empties it)
        self.log_root = self.meta_dir / "logs"
        self.log_dir = self.log_root / self.name
        for st in stages:
            (self.log_root / st.name).mkdir(parents=True, exist_ok=True)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.stage = self.name
        self._lock = self._take_lock()
        self.manifest = self.out_dir / MANIFEST
        self.graph = TaskGraph(stages)
        self.stats = EngineStats()
        self.summaries: dict[str, FarmSummary] = {}
        self.run_ids: dict[str, int] = {}
        self.in_manifest: dict[str, set[str]] = {}
        self._new_blocked: list[tuple[int, str]] = []
        self._failed_tids: set[int] = set()
        try:
            self.ledger = Ledger(self.out_dir)
            for st in stages:
                self._begin(st, engine, workers)
        except BaseException:
            self._lock.close()  # let the next attempt in (same process included)
            raise
        self.run_id = self.run_ids[stages[0].name]   # the workers table's run
        self.task_ids = [tid for st in stages for tid in self._tids[st.name]]
        self._lines: list[str] = []
        self._t0 = time.perf_counter()
        self._last_beat = 0.0
        self._last_flush = 0.0
        self._last_line = time.monotonic()
        self.bar = None
        self.progress = progress
        if progress and len(stages) == 1 and stages[0].items:
            from tqdm import tqdm

            s = self.summaries[stages[0].name]
            self.bar = tqdm(total=s.total, initial=s.done, unit="frame",
                            desc=stages[0].name, dynamic_ncols=True, smoothing=0.1)

    @property
    def summary(self) -> FarmSummary:
        """The first stage's summary (a one-stage run's)."""
        return self.summaries[next(iter(self.stages))]

    def _begin(self, st: Stage, engine: str, workers: int) -> None:
        in_manifest = read_manifest_items(self.manifest, st.name)
        redo = set(st.redo)
        run_id, tids = self.ledger.begin_run(st.name, st.items, st.chunk, engine, workers,
                                             (in_manifest & set(st.items)) - redo, redo=redo)
        self.run_ids[st.name] = run_id
        self.in_manifest[st.name] = in_manifest
        counts = self.ledger.count_items(st.name, run_id)
        self.summaries[st.name] = FarmSummary(stage=st.name, engine=engine, run_id=run_id, total=len(st.items),
                                              done=counts.get("done", 0), already_done=counts.get("done", 0),
                                              processed=0, skipped=0, ledger=str(self.ledger.path),
                                              manifest=str(self.manifest))
        self.graph.mark_done(st.name, self.ledger.done_items(st.name, run_id))
        if not hasattr(self, "_tids"):
            self._tids = {}
        self._tids[st.name] = tids
        for tid, items in self.ledger.task_items(tids):
            self.graph.add_task(tid, st.name, items)

    def _take_lock(self):
        path = self.meta_dir / "supervisor.lock"
        f = open(path, "a+")
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            f.seek(0)
            holder = f.read().strip()
            f.close()
            raise UserError(f"another blendgen supervisor is running on this folder "
                            f"({holder or 'unknown pid'}); wait for it or stop it first",
                            where=str(self.out_dir)) from None
        f.seek(0)
        f.truncate()
        f.write(f"pid {os.getpid()} stage {self.name}\n")
        f.flush()
        return f

    # -- scheduling ------------------------------------------------------------------------
    def stage_of(self, task_id: int) -> str:
        return self.graph.stage_of(task_id)

    def processors(self) -> dict[str, dict]:
        """What a worker builds: per stage, its processor and arguments."""
        return {n: {"processor": s.processor, "processor_args": s.processor_args} for n, s in self.stages.items()}

    def fail_blocked(self) -> None:
        """Fail for good the tasks whose inputs failed (and, in turn, what needs theirs)."""
        todo = self._new_blocked + self.graph.new_blocked
        self._new_blocked, self.graph.new_blocked = [], []
        while todo:
            tid, why = todo.pop()
            if tid in self._failed_tids:
                continue
            self._failed_tids.add(tid)
            stage = self.stage_of(tid)
            left = self.ledger.remaining_items(tid)
            self.ledger.claim(tid, "-", "", 0)
            self.ledger.task_failed(tid, "-", why, 0)
            for it in left:
                todo += self.graph.failed(stage, it)

    def graph_fail(self, task_id: int, why: str) -> None:
        """Fail a task for good without running it (its items fail, and what needs them)."""
        self.graph.block(task_id, why)
        self._new_blocked.append((task_id, why))
        self.fail_blocked()

    # -- per attempt -----------------------------------------------------------------------
    def log_path(self, task_id: int, attempt: int) -> str:
        return str(self.log_root / self.stage_of(task_id) / f"task-{task_id:06d}-a{attempt}.log")

    def worker_log(self, name: str) -> str:
        return str(self.log_dir / f"worker-{name}.log")

    def claim(self, task_id: int, worker: str) -> tuple[int, list[str], str]:
        items = self.ledger.remaining_items(task_id)
        attempt = self.ledger.task(task_id)["attempts"] + 1
        log = self.log_path(task_id, attempt)
        self.ledger.claim(task_id, worker, log, LEASE_S)
        summary = self.summaries[self.stage_of(task_id)]
        if summary.first_start_s is None:
            summary.first_start_s = round(time.perf_counter() - self._t0, 3)
        return attempt, items, log

    def on_item(self, task_id: int, attempt: int, worker: str, ev: dict) -> None:
        item = ev["item"]
        stage = self.stage_of(task_id)
        summary, in_manifest = self.summaries[stage], self.in_manifest[stage]
        farm = {"task": task_id, "attempt": attempt, "worker": worker,
                "is_done_s": round(ev.get("is_done_s", 0.0), 6),
                "process_s": round(ev.get("process_s", 0.0), 6),
                "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        if ev.get("skipped"):
            summary.skipped += 1
            if item not in in_manifest:
                # Outputs exist but the record was lost (supervisor died between the worker
                # finishing and the manifest append): note it so every frame has a line.
                rec = {"stage": stage, "item": item, "seed": frame_seed(self.seed, item),
                       "skipped": "outputs already complete", "farm": farm}
                self._lines.append(json.dumps(rec, default=atomic._json_default))
        else:
            summary.processed += 1
            rec = dict(ev.get("record") or {})
            rec.setdefault("stage", stage)
            rec.setdefault("item", item)
            rec.setdefault("seed", frame_seed(self.seed, item))
            rec["farm"] = farm
            self._lines.append(json.dumps(rec, default=atomic._json_default))
        in_manifest.add(item)
        self.ledger.item_done(stage, item, worker)
        self.graph.done(stage, item)
        summary.done += 1
        summary.last_done_s = round(time.perf_counter() - self._t0, 3)
        if summary.first_done_s is None:
            summary.first_done_s = summary.last_done_s
        if self.bar is not None:
            self.bar.update(1)

    def on_item_failed(self, task_id: int, worker: str, ev: dict) -> None:
        """An item raised UserError: it alone fails, at once (no retry, worker not blamed)."""
        stage = self.stage_of(task_id)
        self.ledger.item_failed(stage, ev["item"], worker, ev["error"])
        self._new_blocked += self.graph.failed(stage, ev["item"])
        with contextlib.suppress(OSError), open(self.ledger.task(task_id)["log_path"], "a",
                                                encoding="utf-8") as f:
            f.write(f"[blendgen.farm supervisor] frame {ev['item']} failed: {ev['error']}\n")
        if self.bar is not None:
            self.bar.update(1)

    def on_task_done(self, task_id: int) -> None:
        self.ledger.task_done(task_id)

    def on_task_failed(self, task_id: int, worker: str, error: str) -> bool:
        left = self.ledger.remaining_items(task_id)
        final = self.ledger.task_failed(task_id, worker, error, self.max_attempts)
        log = self.ledger.task(task_id)["log_path"]
        if log:
            with contextlib.suppress(OSError), open(log, "a", encoding="utf-8") as f:
                f.write(f"\n[blendgen.farm supervisor] attempt failed on {worker}: {error}"
                        f"{' (giving up)' if final else ' (re-queued)'}\n")
        if final:
            stage = self.stage_of(task_id)
            for it in left:
                self._new_blocked += self.graph.failed(stage, it)
            if self.bar is not None:
                self.bar.set_postfix_str(f"failed tasks: {len(self.ledger.failed_tasks(self.run_ids[stage]))}")
        return final

    def release(self, task_id: int) -> None:
        self.ledger.release(task_id)

    # -- commits ---------------------------------------------------------------------------
    def flush(self, force: bool = True) -> None:
        """Manifest first, then the ledger: if we die in between, the next run finds the
        record in the manifest and marks the item done without redoing it. Unforced calls
        batch (an item finished but not yet flushed when we die is found complete by
        `is_done` on the next run: skipped, not redone)."""
        now = time.monotonic()
        if not force and len(self._lines) < FLUSH_LINES and now - self._last_flush < FLUSH_EVERY_S:
            return
        self._last_flush = now
        if self._lines:
            atomic.append_line(self.manifest, "\n".join(self._lines))
            self._lines.clear()
        if now - self._last_beat > 2.0:
            for rid in self.run_ids.values():
                self.ledger.heartbeat(rid, LEASE_S)
            self._last_beat = now
        self.ledger.commit()
        if self.progress and self.bar is None and now - self._last_line > PROGRESS_EVERY_S:
            self._last_line = now
            print(self.progress_line(), flush=True)

    def progress_line(self) -> str:
        """One line for a pipeline: each stage's done/total."""
        return "  farm: " + ", ".join(f"{n} {s.done}/{s.total}" for n, s in self.summaries.items()) + \
            f" ({fmt_s(time.perf_counter() - self._t0)})"

    def finish(self, state: str | None = None) -> dict[str, FarmSummary]:
        """End every stage's run; returns the summaries by stage (`.summary`: the first)."""
        self.flush()
        elapsed = time.perf_counter() - self._t0
        for name, summary in self.summaries.items():
            rid = self.run_ids[name]
            summary.failed = self.ledger.failed_tasks(rid)
            summary.failed_items = self.ledger.failed_items(name, rid)
            summary.elapsed_s = elapsed
            summary.workers_started, summary.worker_deaths = self.stats.workers_started, self.stats.worker_deaths
            summary.recycled, summary.retired = self.stats.recycled, list(self.stats.retired)
            self.ledger.end_run(rid, state or ("done" if summary.ok else "failed"))
        self.close()
        return self.summaries

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
        with contextlib.suppress(Exception):
            self.ledger.close()
        if self._lock is not None:
            self._lock.close()  # closing the file releases the flock
            self._lock = None
