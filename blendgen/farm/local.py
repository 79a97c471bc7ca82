"""The local engine: this process supervises N worker subprocesses on this machine.

Workers are fresh `python -m blendgen.farm.worker` interpreters (never forks of this
process), so bpy's sys.path pollution cannot reach them. One event loop over the workers'
pipes: dispatch a task to each idle worker, record items as they finish, re-queue at once
the task of a worker that failed or died, recycle workers after `recycle_after` items or
above `max_rss_mb`, kill a worker that finishes no item for `item_timeout_s` (a hang: its
task is retried like a crash's), retire a worker slot that keeps failing.
"""

from __future__ import annotations

import collections
import contextlib
import json
import os
import selectors
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import blendgen

from ..errors import StageError
from .books import Books

SLOT_MAX_FAILURES_IN_ROW = 3  # a slot failing this many times in a row gets no more tasks
STOP_GRACE_S = 10.0           # time a stopping worker gets to close() its processor
# item_timeout_s "auto": a worker that finishes no item for 30 min, or for 10x the slowest item
# of this run when that is longer, is taken for hung
AUTO_TIMEOUT_FLOOR_S = 1800.0
AUTO_TIMEOUT_FACTOR = 10.0


def worker_env(tmp_dir: str | os.PathLike | None = None) -> dict[str, str]:
    """Environment for a worker: blendgen importable, no bpy-internal module paths, and
    temp files in `tmp_dir` (which the supervisor removes when the stage ends)."""
    env = os.environ.copy()
    if tmp_dir is not None:
        env["TMPDIR"] = str(tmp_dir)
    root = str(Path(blendgen.__file__).resolve().parents[1])
    parts = [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p and not _bpy_path(p)]
    env["PYTHONPATH"] = os.pathsep.join([root] + [p for p in parts if p != root])
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def _bpy_path(p: str) -> bool:
    # bpy's own scripts/modules folder holds a pure-Python `bpy` package that shadows the
    # real module in a child interpreter (`No module named '_bpy'`).
    norm = p.replace("\\", "/")
    return "/bpy/" in norm and "/scripts/" in norm


def describe_exit(rc: int | None) -> str:
    if rc is None:
        return "still running"
    if rc < 0:
        try:
            return f"killed by {signal.Signals(-rc).name}"
        except ValueError:
            return f"killed by signal {-rc}"
    return f"exit code {rc}"


@dataclass
class _Worker:
    slot: int
    name: str
    proc: subprocess.Popen
    rfd: int
    wfd: int
    log: str
    state: str = "starting"  # starting, idle, busy, stopping
    task: int | None = None
    attempt: int = 0
    items_left: list[str] = field(default_factory=list)
    error: str | None = None
    processed: int = 0
    rss_mb: float = 0.0
    buf: bytes = b""
    eof: bool = False
    since: float = 0.0         # monotonic time of its start, its task's start or last item, its stop
    hung: str | None = None    # why the supervisor killed it
    killed_at: float = 0.0


class LocalEngine:
    def __init__(self, books: Books, *, workers: int, recycle_after: int, max_rss_mb: int,
                 item_timeout_s: float | str | None = "auto"):
        self.books = books
        self.graph = books.graph
        self.item_timeout_s = item_timeout_s
        self.slowest_item_s = 0.0
        self.last_check = time.monotonic()
        self.abandoned: list[subprocess.Popen] = []  # killed workers that did not exit
        self.processor = " + ".join(sorted({s.processor for s in books.stages.values()}))
        self.n_slots = workers
        self.recycle_after, self.max_rss_mb = recycle_after, max_rss_mb
        self.sel = selectors.DefaultSelector()
        self.workers: dict[int, _Worker] = {}  # slot -> live worker
        self.generation = collections.Counter()
        self.fails_in_row = collections.Counter()
        self.retired: set[int] = set()
        self.queue: collections.deque[int] = collections.deque()  # retries: before any ready task
        self.ever_ready = False
        self.init_failures = 0
        self.last_init_error: tuple[str, str] | None = None

    # -- lifecycle -------------------------------------------------------------------------
    def run(self) -> None:
        try:
            while True:
                self.books.fail_blocked()
                busy = any(w.state == "busy" for w in self.workers.values())
                if not (self.queue or self.graph.n_ready or busy):
                    if self.graph.waiting:
                        raise StageError(f"farm: {self.graph.waiting} task(s) wait for items no task will "
                                         "finish (a pipeline's dependencies are wrong)")
                    break
                self._top_up()
                if not self.workers:
                    self._give_up()
                    break
                self._dispatch()
                self._poll(timeout=1.0)
                self.books.flush(force=False)
        except BaseException:
            self._abort()
            raise
        self._shutdown()

    def _top_up(self) -> None:
        """Keep min(slots, outstanding tasks) workers alive (a pipeline's waiting tasks count:
        their inputs are on the way)."""
        busy = sum(w.state == "busy" for w in self.workers.values())
        want = min(self.n_slots, len(self.queue) + self.graph.n_ready + busy + self.graph.waiting)
        for slot in range(self.n_slots):
            if len(self.workers) >= want:
                break
            if slot not in self.workers and slot not in self.retired:
                self._spawn(slot)

    def _spawn(self, slot: int) -> None:
        self.generation[slot] += 1
        name = f"{os.uname().nodename}/w{slot}.{self.generation[slot]}"
        log = self.books.worker_log(f"w{slot}.{self.generation[slot]}")
        to_r, to_w = os.pipe()
        from_r, from_w = os.pipe()
        with open(log, "ab") as logf:
            proc = subprocess.Popen(
                [sys.executable, "-m", "blendgen.farm.worker", "--rfd", str(to_r), "--wfd",
                 str(from_w), "--ppid", str(os.getpid())],
                pass_fds=(to_r, from_w), stdin=subprocess.DEVNULL, stdout=logf,
                stderr=subprocess.STDOUT, env=worker_env(self.books.tmp_dir), close_fds=True)
        os.close(to_r)
        os.close(from_w)
        os.set_blocking(from_r, False)
        w = _Worker(slot=slot, name=name, proc=proc, rfd=from_r, wfd=to_w, log=log, since=time.monotonic())
        self.workers[slot] = w
        self.sel.register(from_r, selectors.EVENT_READ, w)
        self.books.ledger.worker_started(self.books.run_id, name, os.uname().nodename,
                                         proc.pid, log)
        self.books.stats.workers_started += 1
        self._send(w, {"op": "init", "processors": self.books.processors(), "log": log})

    def _send(self, w: _Worker, msg: dict) -> bool:
        try:
            os.write(w.wfd, (json.dumps(msg) + "\n").encode("utf-8"))
            return True
        except (BrokenPipeError, OSError):
            return False  # it died; its EOF is handled by _poll

    # -- scheduling ------------------------------------------------------------------------
    def _dispatch(self) -> None:
        for w in list(self.workers.values()):
            if w.state != "idle" or not (self.queue or self.graph.n_ready):
                continue
            tid = self._pick(w)
            if tid is None:
                continue
            attempt, items, log = self.books.claim(tid, w.name)
            if not items:  # every item finished meanwhile (e.g. done just before a crash)
                self.books.on_task_done(tid)
                continue
            w.state, w.task, w.attempt, w.items_left, w.error = "busy", tid, attempt, items, None
            w.since = time.monotonic()
            # a failed send means it just died: _poll sees the exit and re-queues the task
            self._send(w, {"op": "task", "task": tid, "stage": self.books.stage_of(tid), "attempt": attempt,
                           "items": items, "log": log})

    def _pick(self, w: _Worker) -> int | None:
        """First retried, else first ready task (by the pipeline's priority) this worker did not
        already fail; a task every live worker has failed may go back to one of them (retry
        elsewhere when there is an elsewhere). Ready tasks were never tried: any worker takes them."""
        live = {x.name for x in self.workers.values()}
        for tid in self.queue:
            avoid = set(self.books.ledger.avoid(tid))
            if w.name not in avoid or live <= avoid:
                self.queue.remove(tid)
                return tid
        return self.graph.pop()

    # -- events ----------------------------------------------------------------------------
    def _item_limit_s(self) -> float | None:
        if self.item_timeout_s != "auto":
            return self.item_timeout_s
        return max(AUTO_TIMEOUT_FLOOR_S, AUTO_TIMEOUT_FACTOR * self.slowest_item_s)

    def _poll(self, timeout: float) -> None:
        for key, _ in self.sel.select(timeout):
            self._read(key.data)
        self._kill_hung()
        for w in list(self.workers.values()):
            if w.eof or w.proc.poll() is not None:
                self._read(w, drain=True)  # events sent just before it died still count
                self._on_exit(w)

    def _kill_hung(self) -> None:
        """Kill busy workers that finished no item for the limit, and workers that took longer
        to start (the processor's constructor) or STOP_GRACE_S to stop (its close()); give up
        on a busy one that SIGKILL does not end within STOP_GRACE_S (stuck in the kernel, e.g.
        in a GPU driver): its task goes back to the queue and the slot to a new worker."""
        now = time.monotonic()
        if now - self.last_check > 60.0:  # this supervisor was stopped (Ctrl-Z): that time is no one's
            for w in self.workers.values():
                w.since += now - self.last_check
        self.last_check = now
        limit = self._item_limit_s()
        for w in list(self.workers.values()):
            wait, verb = {"starting": (limit, "start"), "stopping": (STOP_GRACE_S, "stop")}.get(w.state, (None, ""))
            if w.hung is None and wait is not None and now - w.since > wait:
                w.hung = f"worker {w.name} took over {wait:.0f} s to {verb} and was killed; worker log: {w.log}"
                if w.state == "starting":
                    self.last_init_error = (w.hung, w.log)  # what no worker starting says
                with contextlib.suppress(ProcessLookupError):
                    w.proc.kill()
                continue
            if w.state != "busy" or limit is None:
                continue
            if w.hung is None and now - w.since > limit:
                self._read(w, drain=True)  # an item that finished just now counts
                if now - w.since <= limit or w.state != "busy":
                    continue
                item = w.items_left[0] if w.items_left else "?"
                w.hung = (f"worker {w.name} finished no item in {now - w.since:.0f} s (farm.item_timeout_s: "
                          f"{limit:.0f} s) and was killed during item {item}; worker log: {w.log}")
                w.killed_at = now
                with contextlib.suppress(ProcessLookupError):
                    w.proc.kill()
            elif w.hung is not None and now - w.killed_at > STOP_GRACE_S and w.proc.poll() is None:
                self.sel.unregister(w.rfd)
                for fd in (w.rfd, w.wfd):
                    with contextlib.suppress(OSError):
                        os.close(fd)
                del self.workers[w.slot]
                self.abandoned.append(w.proc)  # not waited for: it may never exit
                self.books.stats.worker_deaths += 1
                self.books.ledger.worker_update(self.books.run_id, w.name, state="exited", exit="killed, did not exit")
                self._task_failed(w.task, w, w.hung + f"; it did not exit {STOP_GRACE_S:.0f} s after SIGKILL (left "
                                                      f"behind, pid {w.proc.pid})")

    def _read(self, w: _Worker, drain: bool = False) -> None:
        while not w.eof:
            try:
                chunk = os.read(w.rfd, 1 << 16)
            except BlockingIOError:
                break
            if not chunk:
                w.eof = True
            w.buf += chunk
            while b"\n" in w.buf:
                line, w.buf = w.buf.split(b"\n", 1)
                self._on_message(w, json.loads(line))
            if not drain:
                break

    def _on_message(self, w: _Worker, ev: dict) -> None:
        kind = ev["ev"]
        if kind in ("item", "item_failed") and ev.get("task") == w.task:  # progress: not hung
            w.since = time.monotonic()
            self.slowest_item_s = max(self.slowest_item_s, ev.get("process_s", 0.0))
        if kind == "ready":
            w.rss_mb = ev.get("rss_mb", 0.0)
            if w.state == "starting":  # not if it was told to stop while starting
                w.state = "idle"
            self.ever_ready = True
            self.books.ledger.worker_update(self.books.run_id, w.name, state="idle")
        elif kind == "init_error":
            w.error = ev["error"]
            self.last_init_error = (ev["error"], w.log)
            self.init_failures += 1
            if not self.ever_ready and self.init_failures >= SLOT_MAX_FAILURES_IN_ROW:
                # the processor never started anywhere: a setup error, not a flaky worker
                self.retired = set(range(self.n_slots))
        elif kind == "item" and ev.get("task") == w.task:
            self.books.on_item(w.task, w.attempt, w.name, ev)
            with contextlib.suppress(ValueError):
                w.items_left.remove(ev["item"])
            if not ev.get("skipped") and self.books.stages[self.books.stage_of(w.task)].recycle:
                w.processed += 1
        elif kind == "item_failed" and ev.get("task") == w.task:
            self.books.on_item_failed(w.task, w.name, ev)
            with contextlib.suppress(ValueError):
                w.items_left.remove(ev["item"])
        elif kind == "error" and ev.get("task") == w.task:
            w.error = f"item {ev['item']}: {ev['error']}"
        elif kind == "task_end" and ev.get("task") == w.task:
            w.rss_mb = ev.get("rss_mb", 0.0)
            tid, w.task, w.state = w.task, None, "idle"
            if ev["ok"]:
                self.books.on_task_done(tid)
                self.fails_in_row[w.slot] = 0
                self.books.ledger.worker_update(self.books.run_id, w.name, items=0)
            else:
                self._task_failed(tid, w, w.error or "unknown error")
            if (self.queue or self.graph.n_ready or self.graph.waiting) and (
                    w.processed >= self.recycle_after or w.rss_mb > self.max_rss_mb):
                why = (f"{w.processed} items" if w.processed >= self.recycle_after
                       else f"RSS {w.rss_mb:.0f} MB > {self.max_rss_mb} MB")
                self._stop(w, f"recycled after {why}")
                self.books.stats.recycled += 1

    def _task_failed(self, tid: int, w: _Worker, error: str) -> None:
        final = self.books.on_task_failed(tid, w.name, error)
        if not final:
            self.queue.appendleft(tid)  # re-queued at once, at the front
        self.fails_in_row[w.slot] += 1
        self.books.ledger.worker_update(self.books.run_id, w.name, failed=True)
        if self.fails_in_row[w.slot] >= SLOT_MAX_FAILURES_IN_ROW and w.slot not in self.retired:
            self.retired.add(w.slot)
            self.books.stats.retired.append(f"slot w{w.slot} (last: {w.name})")
            if w.state == "idle":
                self._stop(w, "retired: failed repeatedly")

    def _stop(self, w: _Worker, why: str) -> None:
        w.state, w.since = "stopping", time.monotonic()
        self.books.ledger.worker_update(self.books.run_id, w.name, state="stopping", exit=why)
        self._send(w, {"op": "stop"})

    def _on_exit(self, w: _Worker) -> None:
        try:
            rc = w.proc.wait(timeout=STOP_GRACE_S if w.state == "stopping" else 5.0)
        except subprocess.TimeoutExpired:
            if not w.eof:
                return  # alive; pipe still open
            w.proc.kill()
            rc = w.proc.wait()
        self.sel.unregister(w.rfd)
        os.close(w.rfd)
        os.close(w.wfd)
        del self.workers[w.slot]
        how = describe_exit(rc)
        planned = w.state == "stopping" and rc == 0
        self.books.ledger.worker_update(self.books.run_id, w.name, state="exited",
                                        exit=None if planned else w.hung or how)
        if planned:
            return
        self.books.stats.worker_deaths += 1
        if w.task is not None:
            where = f" during item {w.items_left[0]}" if w.items_left else ""
            self._task_failed(w.task, w, w.hung or f"worker {w.name} died ({how}){where}; "
                                                   f"worker log: {w.log}")
        else:
            # died while starting or idle: counts against the slot, not against a task
            self.fails_in_row[w.slot] += 1
            if self.fails_in_row[w.slot] >= SLOT_MAX_FAILURES_IN_ROW:
                self.retired.add(w.slot)
                self.books.stats.retired.append(f"slot w{w.slot} (last: {w.name}, {how})")

    def _give_up(self) -> None:
        """No worker can run: fail what is left, or say why workers cannot start."""
        if not self.ever_ready and self.last_init_error:
            err, log = self.last_init_error
            raise StageError(f"farm stage {self.books.stage}: processor {self.processor} "
                             f"failed to start on every worker: {err} (log: {log})")
        if not self.ever_ready:
            raise StageError(f"farm stage {self.books.stage}: workers died before starting; "
                             f"see {self.books.log_dir}")
        left = list(self.queue) + [t for t in iter(self.graph.pop, None)]
        self.queue.clear()
        for tid in left:
            self.books.graph_fail(tid, "no healthy worker left")
        for tid in self.graph.waiting_tasks():
            self.books.graph_fail(tid, "no healthy worker left")

    def _shutdown(self) -> None:
        for w in list(self.workers.values()):
            if w.state != "stopping":
                self._stop(w, "job finished")
        deadline = time.monotonic() + STOP_GRACE_S
        while self.workers and time.monotonic() < deadline:
            self._poll(timeout=0.2)
        self._kill_all()

    def _abort(self) -> None:
        """Ctrl-C or an internal error: kill workers (outputs are atomic, so nothing partial
        stays under a final name), give their tasks back uncounted, keep the ledger sane."""
        self._kill_all()
        for w in list(self.workers.values()):
            if w.task is not None:
                self.books.release(w.task)
        with contextlib.suppress(Exception):
            self.books.flush()

    def _kill_all(self) -> None:
        for w in self.workers.values():
            with contextlib.suppress(ProcessLookupError):
                w.proc.kill()
        for w in self.workers.values():
            with contextlib.suppress(Exception):
                w.proc.wait(timeout=5)
            with contextlib.suppress(Exception):
                self.sel.unregister(w.rfd)
            for fd in (w.rfd, w.wfd):
                with contextlib.suppress(OSError):
                    os.close(fd)
