"""Stages of a farm pipeline and the dependencies between their tasks (supervisor side).

A pipeline runs several stages at once on the same workers: a task of one stage becomes
ready when the items it needs from other stages (or earlier items of its own) are done, so
frame analysis, planning and rendering overlap and the first frames are rendered long before
the last ones are analysed. Dependencies are ranges of item positions, given per item by the
stage's `needs(position)`; the graph keeps one byte of state per item and, per waiting
task, its unmet count, so the supervisor's cost per finished item does not grow with the
recording's length.
"""

from __future__ import annotations

import heapq
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Callable, Iterable

BUCKET = 32          # items per watcher bucket
PENDING, DONE, FAILED = 0, 1, 2


@dataclass
class Stage:
    """One stage of a pipeline. `needs(position)` lists the (stage, lo, hi) position ranges an
    item waits for (its own stage's earlier items included: a chain); `priority`: among ready
    tasks, a higher one goes first (later stages first gets frames out early), then the
    earlier position; `recycle`: its items count toward `recycle_after` (Blender's memory)."""

    name: str
    items: list[str]
    processor: str
    processor_args: dict
    chunk: int = 4
    needs: Callable[[int], Iterable[tuple[str, int, int]]] | None = None
    priority: int = 0
    recycle: bool = True
    redo: Iterable[str] = ()
    index: dict[str, int] = field(default_factory=dict, repr=False)

    def __post_init__(self):
        if not self.index:
            self.index = {it: k for k, it in enumerate(self.items)}


@dataclass
class _Task:
    tid: int
    stage: str
    first: int
    ranges: list[tuple[str, int, int]]
    own: frozenset[int]
    unmet: int = 0


class TaskGraph:
    """Readiness of the pipeline's tasks. `done(stage, item)` / `failed(stage, item)` as items
    finish; `pop()` gives the next ready task id; tasks whose inputs failed for good come back
    from `failed()` so the engine can fail them too, with the reason."""

    def __init__(self, stages: list[Stage]):
        self.stages = {s.name: s for s in stages}
        self.state = {s.name: bytearray(len(s.items)) for s in stages}
        self.tasks: dict[int, _Task] = {}
        self.watch: dict[tuple[str, int], list[int]] = defaultdict(list)
        self.heap: list[tuple[int, int, int]] = []
        self.blocked: dict[int, str] = {}   # task id -> why it cannot run (an input failed)
        self.new_blocked: list[tuple[int, str]] = []   # blocked when added: for the engine to fail
        self.waiting = 0

    # -- set-up ----------------------------------------------------------------------------
    def mark_done(self, stage: str, items: Iterable[str]) -> None:
        """Items finished before this run (the ledger's)."""
        st, idx = self.state[stage], self.stages[stage].index
        for it in items:
            k = idx.get(it)
            if k is not None:
                st[k] = DONE

    def add_task(self, tid: int, stage: str, items: list[str]) -> None:
        spec = self.stages[stage]
        pos = sorted(spec.index[it] for it in items)
        own = frozenset(pos)
        ranges: dict[str, list[list[int]]] = defaultdict(list)
        if spec.needs is not None:
            for p in pos:
                for s, lo, hi in spec.needs(p):
                    if s not in self.state:
                        raise ValueError(f"stage {stage} needs unknown stage {s!r}")
                    lo, hi = max(0, lo), min(hi, len(self.state[s]))
                    if lo < hi:
                        ranges[s].append([lo, hi])
        merged = []
        for s, rs in ranges.items():
            rs.sort()
            cur = rs[0]
            for r in rs[1:]:
                if r[0] <= cur[1]:
                    cur[1] = max(cur[1], r[1])
                else:
                    merged.append((s, cur[0], cur[1]))
                    cur = r
            merged.append((s, cur[0], cur[1]))
        t = _Task(tid, stage, pos[0] if pos else 0, merged, own)
        self.tasks[tid] = t
        buckets: set[tuple[str, int]] = set()
        for s, lo, hi in merged:
            st = self.state[s]
            for p in range(lo, hi):
                if s == stage and p in own:
                    continue  # its own earlier items: done in order within the task
                if st[p] == FAILED and tid not in self.blocked:
                    self.blocked[tid] = f"needs {s} {self.stages[s].items[p]}, which failed"
                    self.new_blocked.append((tid, self.blocked[tid]))
                elif st[p] != DONE:
                    t.unmet += 1
                    buckets.add((s, p // BUCKET))
        for b in buckets:
            self.watch[b].append(tid)
        if tid in self.blocked:
            return
        if t.unmet == 0:
            self._push(t)
        else:
            self.waiting += 1

    def _push(self, t: _Task) -> None:
        heapq.heappush(self.heap, (-self.stages[t.stage].priority, t.first, t.tid))

    # -- events ----------------------------------------------------------------------------
    def done(self, stage: str, item: str) -> None:
        k = self.stages[stage].index.get(item)
        if k is None or self.state[stage][k] == DONE:
            return
        self.state[stage][k] = DONE
        for tid in self.watch.get((stage, k // BUCKET), ()):
            t = self.tasks.get(tid)
            if t is None or t.unmet == 0 or (t.stage == stage and k in t.own) or tid in self.blocked:
                continue
            if any(s == stage and lo <= k < hi for s, lo, hi in t.ranges):
                t.unmet -= 1
                if t.unmet == 0:
                    self.waiting -= 1
                    self._push(t)

    def failed(self, stage: str, item: str) -> list[tuple[int, str]]:
        """The item failed for good: the waiting tasks that need it, with the reason (the
        engine fails them, which fails their items, and so on down the pipeline)."""
        k = self.stages[stage].index.get(item)
        if k is None:
            return []
        self.state[stage][k] = FAILED
        out = []
        for tid in self.watch.get((stage, k // BUCKET), ()):
            t = self.tasks.get(tid)
            if t is None or tid in self.blocked or t.unmet == 0 or (t.stage == stage and k in t.own):
                continue
            if any(s == stage and lo <= k < hi for s, lo, hi in t.ranges):
                why = f"needs {stage} {item}, which failed"
                self.block(tid, why)
                out.append((tid, why))
        return out

    def block(self, tid: int, why: str) -> None:
        """The task will not run (an input failed, or no worker is left)."""
        if tid in self.blocked:
            return
        self.blocked[tid] = why
        if self.tasks[tid].unmet > 0:
            self.waiting -= 1

    def pop(self) -> int | None:
        return heapq.heappop(self.heap)[2] if self.heap else None

    def peek_ready(self) -> list[int]:
        """Ready task ids in dispatch order (for engines that skip some for a worker)."""
        return [tid for _, _, tid in sorted(self.heap)]

    def remove(self, tid: int) -> None:
        self.heap = [e for e in self.heap if e[2] != tid]
        heapq.heapify(self.heap)

    def push_front(self, tid: int) -> None:
        """A retried task: before every other ready one."""
        heapq.heappush(self.heap, (-(1 << 30), -1, tid))

    def waiting_tasks(self) -> list[int]:
        return [t.tid for t in self.tasks.values() if t.unmet > 0 and t.tid not in self.blocked]

    @property
    def n_ready(self) -> int:
        return len(self.heap)

    def stage_of(self, tid: int) -> str:
        return self.tasks[tid].stage
