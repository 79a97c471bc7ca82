"""Farm pipelines (`run_pipeline`): stages that share the workers, each task starting as soon as
the items it needs are done; the processors here are imported by the worker subprocesses as
`test_farm_pipeline:<Class>` (tests/ on PYTHONPATH)."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from blendgen import atomic
from blendgen.errors import StageError
from blendgen.farm import run_pipeline
from blendgen.farm.graph import Stage, TaskGraph

TESTS = Path(__file__).resolve().parent
N = 24


class Step:
    """Stage processors of a three-stage toy pipeline over N items (ids 000000..):
    `a`: writes a/<k> = k^2; `b`: needs a[k-1..k+1], writes b/<k> = their sum; `c`: a chain,
    needs c[k-1] and b[k], writes c/<k> = c[k-1] + b[k] (a prefix sum). Each reads its inputs
    and raises when one is missing, so a task run too early fails the test. Knobs: `fail`
    (an `a` item that always raises), `kill_at` (the worker SIGKILLs itself once, mid-item,
    at this `a` item), `slow_s` (each item sleeps)."""

    def __init__(self, out: str, stage: str, fail: str = "", kill_at: str = "", slow_s: float = 0.0):
        self.out, self.stage = Path(out), stage
        self.fail, self.kill_at, self.slow_s = fail, kill_at, slow_s

    def _read(self, stage: str, k: int) -> int:
        p = self.out / stage / f"{k:06d}"
        if not p.exists():
            raise RuntimeError(f"{self.stage} ran before its input {p} existed")
        return int(p.read_text())

    def is_done(self, item: str) -> bool:
        return (self.out / self.stage / item).exists()

    def process(self, item: str) -> dict:
        k = int(item)
        time.sleep(self.slow_s)
        if self.stage == "a":
            if item == self.fail:
                raise RuntimeError(f"item {item} is broken (on purpose)")
            marker = self.out / "killed"
            if item == self.kill_at and not marker.exists():
                marker.touch()
                os.kill(os.getpid(), signal.SIGKILL)
            v = k * k
        elif self.stage == "b":
            v = sum(self._read("a", j) for j in range(max(0, k - 1), min(N, k + 2)))
        else:
            v = (self._read("c", k - 1) if k else 0) + self._read("b", k)
        atomic.write_text(self.out / self.stage / item, str(v))
        with open(self.out / "order.log", "a") as f:
            f.write(f"{self.stage} {item}\n")
        return {"value": v}


@pytest.fixture(autouse=True)
def _tests_on_pythonpath(monkeypatch):
    old = os.environ.get("PYTHONPATH", "")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(p for p in (str(TESTS), old) if p))


def ids() -> list[str]:
    return [f"{i:06d}" for i in range(N)]


def stages(out: Path, **knobs) -> list[Stage]:
    def args(stage):
        return {"out": str(out), "stage": stage, **knobs}

    return [Stage("a", ids(), "test_farm_pipeline:Step", args("a"), chunk=3, priority=0),
            Stage("b", ids(), "test_farm_pipeline:Step", args("b"), chunk=4, priority=1,
                  needs=lambda k: [("a", k - 1, k + 2)]),
            Stage("c", ids(), "test_farm_pipeline:Step", args("c"), chunk=5, priority=2,
                  needs=lambda k: [("c", k - 1, k), ("b", k, k + 1)])]


def expected(k: int) -> int:
    b = [sum(j * j for j in range(max(0, i - 1), min(N, i + 2))) for i in range(N)]
    return sum(b[:k + 1])


def assert_complete(out: Path) -> None:
    for k, it in enumerate(ids()):
        assert int((out / "c" / it).read_text()) == expected(k), it


def test_graph_readiness_and_chains():
    st = [Stage("a", ids(), "m:C", {}, chunk=4), Stage("c", ids(), "m:C", {}, needs=lambda k: [("c", k - 1, k),
                                                                                              ("a", k, k + 1)])]
    g = TaskGraph(st)
    g.add_task(1, "a", ids()[:4])
    g.add_task(2, "c", ids()[:2])     # needs a 0, 1 (c 0 -> c 1 inside the task)
    g.add_task(3, "c", ids()[2:4])    # needs c 1 and a 2, 3
    assert g.pop() == 1 and g.pop() is None and g.waiting == 2
    for it in ids()[:3]:
        g.done("a", it)
    assert g.pop() == 2 and g.pop() is None
    g.done("c", ids()[0])
    g.done("c", ids()[1])
    assert g.pop() is None            # still needs a 3
    g.done("a", ids()[3])
    assert g.pop() == 3 and g.waiting == 0
    # an input that fails for good blocks what needs it
    g2 = TaskGraph(st)
    g2.add_task(1, "a", ids()[:4])
    g2.add_task(2, "c", ids()[:2])
    assert g2.failed("a", ids()[1]) == [(2, "needs a 000001, which failed")] and g2.waiting == 0


def test_pipeline_runs_each_task_after_its_inputs(tmp_path):
    out = tmp_path / "job"
    s = run_pipeline(out, stages(out), workers=2, progress=False, seed=1)
    assert all(x.ok for x in s.values()), {k: v.text() for k, v in s.items()}
    assert_complete(out)
    order = (out / "order.log").read_text().split("\n")
    # the chain's first items ran before the last `a` items: the stages overlapped
    assert order.index(f"c {ids()[0]}") < order.index(f"a {ids()[-1]}")
    manifest = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    assert sorted((m["stage"], m["item"]) for m in manifest) == sorted((s_, i) for s_ in "abc" for i in ids())
    # a second run dispatches nothing
    s2 = run_pipeline(out, stages(out), workers=2, progress=False, seed=1)
    assert all(x.processed == 0 and x.already_done == N for x in s2.values())


def test_a_killed_worker_loses_nothing_and_a_failed_input_fails_what_needs_it(tmp_path):
    out = tmp_path / "job"
    s = run_pipeline(out, stages(out, kill_at=ids()[7], fail=ids()[20]), workers=2, max_attempts=2,
                     progress=False)
    assert s["a"].worker_deaths == 1
    assert not s["a"].ok and s["a"].done == N - 1 and ids()[20] in s["a"].failed[0]["items"]
    # b 19..21 need a 20, so their tasks (b in fours: 16..23) fail; c is a chain in fives: the
    # task of c 15..19 needs b 16, and every later one its predecessor
    failed_b = sorted(i for f in s["b"].failed for i in f["items"])
    assert failed_b == ids()[16:24] and s["b"].done == 16
    assert s["c"].done == 15 and all("which failed" in f["error"] for f in s["b"].failed + s["c"].failed)
    for k in range(15):
        assert int((out / "c" / ids()[k]).read_text()) == expected(k)
    with sqlite3.connect(out / ".blendgen" / "ledger.sqlite") as db:
        errs = [r[0] for r in db.execute("SELECT error FROM attempts WHERE error IS NOT NULL")]
    assert any("SIGKILL" in e and ids()[7] in e for e in errs), errs
    # fixed: the next run does the rest and nothing else
    s2 = run_pipeline(out, stages(out), workers=2, progress=False)
    assert all(x.ok for x in s2.values())
    assert s2["a"].processed == 1 and s2["c"].processed == N - 15
    assert_complete(out)


def test_supervisor_killed_mid_pipeline_then_resumed(tmp_path):
    out = tmp_path / "job"
    code = ("import sys; sys.path.insert(0, %r)\n"
            "from pathlib import Path\nfrom test_farm_pipeline import stages\n"
            "from blendgen.farm import run_pipeline\n"
            "out = Path(%r)\nrun_pipeline(out, stages(out, slow_s=0.15), workers=2, progress=False)\n"
            ) % (str(TESTS), str(out))
    p = subprocess.Popen([sys.executable, "-c", code], env={**os.environ})
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (out / "c" / ids()[2]).exists():
        time.sleep(0.1)
    p.send_signal(signal.SIGKILL)
    p.wait()
    assert not (out / "c" / ids()[-1]).exists()
    s = run_pipeline(out, stages(out), workers=2, progress=False)
    assert all(x.ok for x in s.values())
    assert_complete(out)
    order = (out / "order.log").read_text().split("\n")
    assert len([x for x in order if x.startswith("c ")]) == N  # no chain item twice


def test_dependencies_no_task_can_meet_are_an_error(tmp_path):
    out = tmp_path / "job"
    bad = stages(out)
    bad[0] = Stage("a", ids(), "test_farm_pipeline:Step", {"out": str(out), "stage": "a"}, chunk=3,
                   needs=lambda k: [("c", k, k + 1)])  # a cycle a -> c -> b -> a
    with pytest.raises(StageError, match="wait for items"):
        run_pipeline(out, bad, workers=1, progress=False)


@pytest.mark.ray
@pytest.mark.timeout(600)
def test_ray_runs_the_same_pipeline(tmp_path):
    pytest.importorskip("ray")
    out = tmp_path / "job"
    s = run_pipeline(out, stages(out), engine="ray", workers=2, progress=False)
    assert all(x.ok for x in s.values()), {k: v.text() for k, v in s.items()}
    assert_complete(out)
