"""Farm tests: ledger, local worker pool under failures, supervisor crash + resume, status.

The processors below are real (they write files atomically and log every completion) and are
imported by the worker subprocesses as `test_farm:FileProcessor` (tests/ on PYTHONPATH).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import signal
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

from blendgen import atomic
from blendgen.errors import StageError, UserError
from blendgen.farm import clean_stale_temps, frame_seed, run_tasks
from blendgen.farm.status import status_report

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent


def expected_bytes(item: str) -> bytes:
    # 64 KiB per item, derived from the item's seed: a partial file is detectable
    block = hashlib.sha256(f"{frame_seed(7, item)}".encode()).digest()
    return block * 2048


HANG_S = 3600  # a hang: far longer than any bound below, which are >= 10x a normal run


class FileProcessor:
    """Writes OUT/items/<item>.bin atomically. Knobs (marker files make them one-shot):
    `raise_once`: items that raise on their first attempt; `hang_once`: an item that writes
    half its temp file, drops `hang.pid` and sleeps (the test SIGKILLs it there);
    `always_fail`: items that always raise; `bad_input`: items whose input is bad (UserError);
    `delay`: seconds per item; `hang_init_once`: the first constructor sleeps; `hang_close`:
    close() sleeps."""

    def __init__(self, out: str, delay: float = 0.0, raise_once=(), hang_once=None,
                 always_fail=(), bad_input=(), hang_init_once=False, hang_close=False):
        self.out = Path(out)
        self.hang_close = hang_close
        if hang_init_once and not (self.out / "init_hung").exists():
            self.out.mkdir(parents=True, exist_ok=True)
            (self.out / "init_hung").touch()
            time.sleep(HANG_S)
        self.dir = self.out / "items"
        self.dir.mkdir(parents=True, exist_ok=True)
        self.delay, self.raise_once, self.hang_once = delay, set(raise_once), hang_once
        self.always_fail, self.bad_input = set(always_fail), set(bad_input)
        self.closed_marker = self.out / "closed.log"
        # like the render session: a private temp folder, which a killed worker cannot remove
        atomic.append_line(self.out / "tmpdirs.log", tempfile.mkdtemp(prefix="blendgen_render_"))

    def path(self, item: str) -> Path:
        return self.dir / f"{item}.bin"

    def is_done(self, item: str) -> bool:
        return self.path(item).exists()

    def process(self, item: str) -> dict:
        clean_stale_temps(self.dir, item)  # only this item's leftovers
        if item in self.bad_input:
            atomic.append_line(self.out / "bad_input.log", item)
            raise UserError(f"frame {item} does not decode as an image", where=f"frames/{item}.png")
        if item in self.always_fail:
            raise ValueError(f"item {item} is broken on purpose")
        marker = self.out / f"raised-{item}"
        if item in self.raise_once and not marker.exists():
            marker.touch()
            raise RuntimeError(f"transient failure on {item}")
        data = expected_bytes(item)
        with atomic.atomic_path(self.path(item)) as tmp:
            with open(tmp, "wb") as f:
                f.write(data[: len(data) // 2])
                f.flush()
                if item == self.hang_once and not (self.out / "hang.pid").exists():
                    atomic.write_text(self.out / "hang.pid", str(os.getpid()))
                    time.sleep(HANG_S)  # killed here, temp file half written
                f.write(data[len(data) // 2:])
            time.sleep(self.delay)
        atomic.append_line(self.out / "completions.log", f"{item} {os.getpid()}")
        return {"bytes": len(data), "pid": os.getpid()}

    def close(self) -> None:
        atomic.append_line(self.closed_marker, str(os.getpid()))
        if self.hang_close:
            time.sleep(HANG_S)


class BpyProcessor:
    """A warm Blender session per worker: proves workers import bpy even when the
    supervisor's own process imported bpy first (the `No module named '_bpy'` trap)."""

    def __init__(self, out: str):
        import bpy

        self.bpy, self.out = bpy, Path(out)

    def is_done(self, item: str) -> bool:
        return (self.out / f"{item}.txt").exists()

    def process(self, item: str) -> dict:
        self.bpy.ops.mesh.primitive_cube_add(size=float(len(item)))
        n = len(self.bpy.data.objects)
        atomic.write_text(self.out / f"{item}.txt", f"{self.bpy.app.version_string} {n}")
        return {"objects": n}


class BrokenInit:
    def __init__(self, **kw):
        raise RuntimeError("cannot open the twin (on purpose)")


@pytest.fixture(autouse=True)
def _tests_on_pythonpath(monkeypatch):
    old = os.environ.get("PYTHONPATH", "")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(p for p in (str(TESTS), old) if p))


def items(n: int) -> list[str]:
    return [f"{i:06d}" for i in range(n)]


def completions(out: Path) -> list[str]:
    p = out / "completions.log"
    return [ln.split()[0] for ln in p.read_text().splitlines()] if p.exists() else []


def manifest(out: Path) -> list[dict]:
    return [json.loads(ln) for ln in (out / "manifest.jsonl").read_text().splitlines()]


def assert_outputs_complete(out: Path, ids: list[str]) -> None:
    for it in ids:
        assert (out / "items" / f"{it}.bin").read_bytes() == expected_bytes(it), it
    leftovers = [p.name for p in (out / "items").iterdir() if p.name.startswith(".")]
    assert leftovers == [], f"partial temp files left: {leftovers}"


# -- pure functions --------------------------------------------------------------------------
def test_frame_seed_is_deterministic_and_spread():
    seeds = [frame_seed(7, f"{i:06d}") for i in range(2000)]
    assert seeds == [frame_seed(7, f"{i:06d}") for i in range(2000)]
    assert len(set(seeds)) == 2000
    assert all(0 <= s < 2**31 for s in seeds)
    assert frame_seed(8, "000001") != frame_seed(7, "000001")


def test_bad_arguments_are_user_errors(tmp_path):
    with pytest.raises(UserError, match="module:ClassName"):
        run_tasks(tmp_path, "frames", ["a"], "not a spec", {}, progress=False)
    with pytest.raises(UserError, match="farm.engine"):
        run_tasks(tmp_path, "frames", ["a"], "m:C", {}, engine="slurm", progress=False)
    with pytest.raises(UserError, match="appears twice"):
        run_tasks(tmp_path, "frames", ["a", "a"], "m:C", {}, progress=False)
    with pytest.raises(UserError, match="farm.workers"):
        run_tasks(tmp_path, "frames", ["a"], "m:C", {}, workers=0, progress=False)


def test_ledger_garbage_is_a_user_error(tmp_path):
    led = tmp_path / ".blendgen" / "ledger.sqlite"
    led.parent.mkdir(parents=True)
    led.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(UserError, match="ledger.sqlite"):
        run_tasks(tmp_path, "frames", ["a"], "test_farm:FileProcessor", {"out": str(tmp_path)},
                  progress=False)
    led.unlink()  # the lock was released: a second try in this process proceeds
    s = run_tasks(tmp_path, "frames", ["a"], "test_farm:FileProcessor", {"out": str(tmp_path)},
                  progress=False)
    assert s.ok


def test_second_supervisor_on_the_same_folder_is_refused(tmp_path):
    from blendgen.farm.books import Books

    b = Books(tmp_path, "frames", ["a"], chunk=1, engine="local", workers=1, seed=0,
              max_attempts=1, progress=False)
    try:
        with pytest.raises(UserError, match="another blendgen supervisor"):
            run_tasks(tmp_path, "frames", ["a"], "test_farm:FileProcessor",
                      {"out": str(tmp_path)}, progress=False)
    finally:
        b.close()


# -- local engine ----------------------------------------------------------------------------
def test_local_failures_raise_once_and_sigkilled_worker(tmp_path):
    """Issue 7: 20 tasks on 2 workers, one task raises once, one worker SIGKILLed mid-task."""
    out = tmp_path / "job"
    ids = items(40)  # chunk 2 -> 20 tasks
    killed = []

    def killer():
        pidf = out / "hang.pid"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not pidf.exists():
            time.sleep(0.05)
        pid = int(pidf.read_text())
        os.kill(pid, signal.SIGKILL)
        killed.append(pid)

    t = threading.Thread(target=killer, daemon=True)
    t.start()
    s = run_tasks(out, "frames", ids, "test_farm:FileProcessor",
                  {"out": str(out), "delay": 0.02, "raise_once": ["000013"],
                   "hang_once": "000027"},
                  workers=2, chunk=2, max_attempts=3, progress=False, seed=7)
    t.join(5)
    assert killed, "the hanging worker was never seen"
    assert s.ok, s.text()
    assert (s.total, s.done, s.already_done) == (40, 40, 0)
    assert s.worker_deaths == 1 and s.workers_started >= 3
    done = completions(out)
    assert sorted(done) == ids, "every item completed exactly once"
    assert_outputs_complete(out, ids)
    recs = manifest(out)
    assert sorted(r["item"] for r in recs) == ids
    by_item = {r["item"]: r for r in recs}
    assert by_item["000013"]["farm"]["attempt"] == 2
    assert by_item["000027"]["farm"]["attempt"] == 2
    assert by_item["000027"]["pid"] != killed[0]
    assert all(r["seed"] == frame_seed(7, r["item"]) for r in recs)
    con = sqlite3.connect(out / ".blendgen" / "ledger.sqlite")
    states = dict(con.execute("SELECT state, count(*) FROM tasks GROUP BY state").fetchall())
    assert states == {"done": 20}
    failed_attempts = con.execute("SELECT task_id, error, log_path FROM attempts "
                                  "WHERE outcome='failed'").fetchall()
    assert len(failed_attempts) == 2
    errors = " | ".join(e for _, e, _ in failed_attempts)
    assert "transient failure on 000013" in errors and "SIGKILL" in errors
    for _, _, log in failed_attempts:
        assert Path(log).exists()
    # Issue 16: workers' temp folders (the SIGKILLed one's too) live under OUT and are gone
    tmpdirs = (out / "tmpdirs.log").read_text().split()
    assert len(tmpdirs) >= 3 and all(d.startswith(str(out / ".blendgen" / "tmp")) for d in tmpdirs)
    assert [d for d in tmpdirs if Path(d).exists()] == []
    # workers closed their processors on the way out (warm sessions are shut down cleanly)
    assert len((out / "closed.log").read_text().split()) >= 2
    # running again: nothing is dispatched, nothing is redone
    s2 = run_tasks(out, "frames", ids, "test_farm:FileProcessor", {"out": str(out)},
                   workers=2, chunk=2, progress=False, seed=7)
    assert (s2.already_done, s2.processed, s2.workers_started) == (40, 0, 0)
    assert sorted(completions(out)) == ids


def test_permanent_failure_keeps_log_and_summary(tmp_path):
    out = tmp_path / "job"
    ids = items(6)
    s = run_tasks(out, "frames", ids, "test_farm:FileProcessor",
                  {"out": str(out), "always_fail": ["000004"]},
                  workers=2, chunk=2, max_attempts=2, progress=False)
    assert not s.ok and s.done == 4
    assert len(s.failed) == 1
    f = s.failed[0]
    assert f["items"] == ["000004", "000005"] and f["attempts"] == 2
    assert "broken on purpose" in f["error"]
    log = Path(f["log"]).read_text()
    assert "ValueError: item 000004 is broken on purpose" in log  # the traceback is kept
    assert "FAILED task" in s.text() and f["log"] in s.text()
    report = status_report(out)
    assert "failed 2" in report and "broken on purpose" in report
    # 000005 was never reached; a later run retries the failed task afresh
    s2 = run_tasks(out, "frames", ids, "test_farm:FileProcessor", {"out": str(out)},
                   workers=1, chunk=2, progress=False)
    assert s2.ok and s2.processed == 2 and s2.already_done == 4


def test_hung_worker_is_killed_and_its_task_retried(tmp_path):
    """A worker that finishes no item for farm.item_timeout_s is taken for hung (not dead)."""
    out = tmp_path / "job"
    ids = items(4)
    t0 = time.monotonic()
    s = run_tasks(out, "frames", ids, "test_farm:FileProcessor", {"out": str(out), "hang_once": "000002"},
                  workers=1, chunk=2, item_timeout_s=3, progress=False)
    assert time.monotonic() - t0 < 120  # ~5 s normally; a hang sleeps an hour
    assert s.ok and s.done == 4 and s.worker_deaths == 1
    assert_outputs_complete(out, ids)
    with sqlite3.connect(out / ".blendgen" / "ledger.sqlite") as db:
        errors = [r[0] for r in db.execute("SELECT error FROM attempts WHERE error IS NOT NULL")]
    assert len(errors) == 1 and "finished no item in" in errors[0] and "item 000002" in errors[0]
    with pytest.raises(UserError, match="item_timeout_s"):
        run_tasks(out, "frames", ids, "test_farm:FileProcessor", {"out": str(out)}, item_timeout_s=0)


def test_workers_that_hang_while_starting_or_stopping_are_killed(tmp_path, monkeypatch):
    """A constructor that never returns, a close() that never returns: neither holds the slot."""
    import blendgen.farm.local as local

    monkeypatch.setattr(local, "STOP_GRACE_S", 2.0)
    out = tmp_path / "job"
    t0 = time.monotonic()
    s = run_tasks(out, "frames", items(3), "test_farm:FileProcessor", {"out": str(out), "hang_init_once": True},
                  workers=1, chunk=1, item_timeout_s=3, progress=False)
    assert s.ok and s.done == 3 and time.monotonic() - t0 < 120, s.text()
    with sqlite3.connect(out / ".blendgen" / "ledger.sqlite") as db:
        exits = [r[0] for r in db.execute("SELECT exit FROM workers WHERE exit IS NOT NULL")]
    assert any("took over 3 s to start" in e for e in exits), exits
    out2 = tmp_path / "job2"
    t0 = time.monotonic()
    s = run_tasks(out2, "frames", items(3), "test_farm:FileProcessor", {"out": str(out2), "hang_close": True},
                  workers=1, chunk=1, recycle_after=1, progress=False)
    assert s.ok and s.done == 3 and time.monotonic() - t0 < 120, s.text()  # not 3 hangs
    assert_outputs_complete(out2, items(3))


def test_hung_worker_that_survives_sigkill_is_left_behind(tmp_path, monkeypatch):
    """A worker stuck in the kernel ignores SIGKILL: the job must not wait for it forever."""
    import blendgen.farm.local as local

    monkeypatch.setattr(local, "STOP_GRACE_S", 2.0)
    monkeypatch.setattr(subprocess.Popen, "kill", lambda self: None)  # the kill does not take
    out = tmp_path / "job"
    ids = items(4)
    try:
        s = run_tasks(out, "frames", ids, "test_farm:FileProcessor", {"out": str(out), "hang_once": "000002"},
                      workers=1, chunk=2, item_timeout_s=2, progress=False)
        assert s.ok and s.done == 4
        assert_outputs_complete(out, ids)
        with sqlite3.connect(out / ".blendgen" / "ledger.sqlite") as db:
            errors = [r[0] for r in db.execute("SELECT error FROM attempts WHERE error IS NOT NULL")]
        assert len(errors) == 1 and "did not exit 2 s after SIGKILL" in errors[0], errors
    finally:
        with contextlib.suppress(Exception):
            os.kill(int((out / "hang.pid").read_text()), signal.SIGKILL)


def test_bad_input_fails_that_item_alone(tmp_path):
    """Issue 16: a UserError in one item (a corrupt frame) fails that item at once, with its
    reason; its task neighbours are produced, nothing is retried, no worker is retired."""
    out = tmp_path / "job"
    ids = items(6)
    bad = ["000002", "000003"]
    s = run_tasks(out, "frames", ids, "test_farm:FileProcessor",
                  {"out": str(out), "bad_input": bad}, workers=1, chunk=4, max_attempts=3,
                  progress=False)
    assert not s.ok and s.done == 4 and s.failed == [] and s.retired == []
    assert sorted(completions(out)) == [i for i in ids if i not in bad]
    assert (out / "bad_input.log").read_text().split() == bad  # each tried exactly once
    assert s.workers_started == 1 and s.worker_deaths == 0
    assert [f["item"] for f in s.failed_items] == bad
    assert all("does not decode" in f["error"] for f in s.failed_items)
    assert s.text().count("FAILED frame") == 2
    report = status_report(out)
    assert "failed 2" in report
    assert report.count("FAILED frame 000002: frames/000002.png: frame 000002 does not decode") == 1
    assert "FAILED task" not in report
    # fixed input: a second run retries only the failed items
    s2 = run_tasks(out, "frames", ids, "test_farm:FileProcessor", {"out": str(out)},
                   workers=1, chunk=4, progress=False)
    assert s2.ok and s2.processed == 2 and s2.already_done == 4 and s2.failed_items == []


def test_processor_that_cannot_start_is_a_stage_error(tmp_path):
    with pytest.raises(StageError, match="cannot open the twin"):
        run_tasks(tmp_path, "frames", items(6), "test_farm:BrokenInit", {}, workers=2,
                  chunk=1, progress=False)
    con = sqlite3.connect(tmp_path / ".blendgen" / "ledger.sqlite")
    assert con.execute("SELECT count(*) FROM workers").fetchone()[0] <= 4  # gave up early
    assert "finished: failed" in status_report(tmp_path)


def test_recycling_after_n_items(tmp_path):
    out = tmp_path / "job"
    ids = items(9)
    s = run_tasks(out, "frames", ids, "test_farm:FileProcessor", {"out": str(out)},
                  workers=1, chunk=1, recycle_after=4, progress=False)
    assert s.ok and s.recycled == 2 and s.workers_started == 3 and s.worker_deaths == 0
    pids = {r["pid"] for r in manifest(out)}
    assert len(pids) == 3


def test_recycling_above_rss_limit(tmp_path):
    out = tmp_path / "job"
    s = run_tasks(out, "frames", items(6), "test_farm:FileProcessor", {"out": str(out)},
                  workers=1, chunk=2, max_rss_mb=1, progress=False)
    # every worker is above 1 MB after its task: recycled before each remaining task
    assert s.ok and s.recycled == 2 and s.workers_started == 3
    con = sqlite3.connect(out / ".blendgen" / "ledger.sqlite")
    exits = [e for (e,) in con.execute("SELECT exit FROM workers ORDER BY started")]
    assert all("RSS" in e and "> 1 MB" in e for e in exits[:2]), exits


# SIGINT raises KeyboardInterrupt in the supervisor even when the test run inherited it ignored
# (a background job of a non-interactive shell: the ctrl-c test then saw exit 0)
_SUPERVISOR = """
import signal
import sys
signal.signal(signal.SIGINT, signal.default_int_handler)
from blendgen.farm import run_tasks
out = sys.argv[1]
run_tasks(out, "frames", [f"{i:06d}" for i in range(30)], "test_farm:FileProcessor",
          {"out": out, "delay": 0.15}, workers=2, chunk=3, progress=False)
"""


def test_supervisor_sigkill_then_resume(tmp_path):
    """Issue 7: SIGKILL the supervisor mid-job, run again: nothing finished is redone."""
    out = tmp_path / "job"
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), str(TESTS), env.get("PYTHONPATH", "")])
    sup = subprocess.Popen([sys.executable, "-c", _SUPERVISOR, str(out)], env=env, cwd=ROOT)
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline and len(completions(out)) < 8:
        time.sleep(0.05)
    assert len(completions(out)) >= 8, "the supervisor made no progress"
    con = sqlite3.connect(out / ".blendgen" / "ledger.sqlite")
    worker_pids = [p for (p,) in con.execute("SELECT pid FROM workers")]
    con.close()
    sup.kill()
    sup.wait()
    # workers die with their supervisor (PR_SET_PDEATHSIG)
    deadline = time.monotonic() + 10
    alive = worker_pids
    while alive and time.monotonic() < deadline:
        time.sleep(0.1)
        alive = [p for p in worker_pids if _alive(p)]
    assert not alive, f"workers outlived their supervisor: {alive}"
    before = completions(out)
    report = status_report(out)
    assert "frames" in report and "NOT RESPONDING" in report
    s = run_tasks(out, "frames", items(30), "test_farm:FileProcessor", {"out": str(out)},
                  workers=2, chunk=3, progress=False)
    assert s.ok
    after = completions(out)
    assert sorted(after) == items(30), "an item finished before the kill was redone"
    assert s.processed == 30 - len(before)
    assert_outputs_complete(out, items(30))
    assert sorted(r["item"] for r in manifest(out)) == items(30)


def test_ctrl_c_leaves_a_resumable_ledger(tmp_path):
    out = tmp_path / "job"
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), str(TESTS), env.get("PYTHONPATH", "")])
    sup = subprocess.Popen([sys.executable, "-c", _SUPERVISOR, str(out)], env=env, cwd=ROOT,
                           stderr=subprocess.PIPE)
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline and len(completions(out)) < 5:
        time.sleep(0.05)
    sup.send_signal(signal.SIGINT)
    _, err = sup.communicate(timeout=30)
    assert sup.returncode != 0 and b"KeyboardInterrupt" in err
    con = sqlite3.connect(out / ".blendgen" / "ledger.sqlite")
    assert con.execute("SELECT state FROM runs").fetchone()[0] == "interrupted"
    assert con.execute("SELECT count(*) FROM tasks WHERE state='running'").fetchone()[0] == 0
    assert con.execute("SELECT count(*) FROM items WHERE state='running'").fetchone()[0] == 0
    pids = [p for (p,) in con.execute("SELECT pid FROM workers")]
    con.close()
    assert not [p for p in pids if _alive(p)]
    assert "finished: interrupted" in status_report(out)
    s = run_tasks(out, "frames", items(30), "test_farm:FileProcessor", {"out": str(out)},
                  workers=2, chunk=3, progress=False)
    assert s.ok and sorted(completions(out)) == items(30)
    assert_outputs_complete(out, items(30))


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_supervisor_imports_no_bpy():
    code = ("import sys, blendgen.farm, blendgen.farm.local, blendgen.farm.status, "
            "blendgen.farm.ray_engine; print('bpy' in sys.modules)")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert res.stdout.strip() == "False", res.stderr


def test_worker_env_drops_bpy_module_paths(monkeypatch):
    from blendgen.farm.local import worker_env

    polluted = "/venv/lib/python3.11/site-packages/bpy/5.0/scripts/modules"
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([polluted, "/my/procs"]))
    parts = worker_env()["PYTHONPATH"].split(os.pathsep)
    assert parts == [str(ROOT), "/my/procs"]


@pytest.mark.bpy
def test_workers_import_bpy_under_a_supervisor_that_imported_bpy(tmp_path):
    pytest.importorskip("bpy")
    out = tmp_path / "job"
    code = ("import sys, bpy\n"
            "from blendgen.farm import run_tasks\n"
            f"s = run_tasks({str(out)!r}, 'frames', ['a', 'bb', 'ccc'], 'test_farm:BpyProcessor',"
            f" {{'out': {str(out)!r}}}, workers=1, chunk=3, progress=False)\n"
            "print(s.text()); sys.exit(0 if s.ok else 1)\n")
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), str(TESTS), env.get("PYTHONPATH", "")])
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, env=env, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    texts = [(out / f"{i}.txt").read_text().split() for i in ("a", "bb", "ccc")]
    assert [int(t[1]) for t in texts] == [4, 5, 6]  # one warm session: the scene kept growing


def test_status_report_counts(tmp_path):
    out = tmp_path / "job"
    run_tasks(out, "record", items(4), "test_farm:FileProcessor", {"out": str(out)},
              workers=1, chunk=4, progress=False)
    rep = status_report(out)
    assert "record" in rep and "done 4/4" in rep
    with pytest.raises(UserError, match="ledger"):
        status_report(tmp_path / "nowhere")


# -- Ray engine ------------------------------------------------------------------------------
LOOPBACK_IPS = ("127.0.0.1", "::1", "::ffff:127.0.0.1")


@pytest.mark.ray
@pytest.mark.timeout(300)
def test_local_ray_listens_on_loopback_only(tmp_path):
    """Issue 16: during a local Ray run no Ray or blendgen port listens beyond loopback."""
    pytest.importorskip("ray")
    psutil = pytest.importorskip("psutil")
    out = tmp_path / "job"
    seen: dict = {}
    stop = threading.Event()

    def watch():
        me = psutil.Process()
        while not stop.is_set():
            procs = [me] + me.children(recursive=True)
            for proc in procs:
                with contextlib.suppress(psutil.Error):
                    for c in proc.net_connections(kind="inet"):
                        if c.status == psutil.CONN_LISTEN:
                            seen[(proc.pid, c.laddr.ip, c.laddr.port)] = proc.name()
            time.sleep(0.2)

    t = threading.Thread(target=watch, daemon=True)
    t.start()
    try:
        s = run_tasks(out, "frames", items(4), "test_farm:FileProcessor",
                      {"out": str(out), "delay": 0.5}, engine="ray", workers=1, chunk=2,
                      progress=False)
    finally:
        stop.set()
        t.join(5)
    assert s.ok, s.text()
    assert len(seen) >= 3, f"saw too few listening sockets to judge: {seen}"
    exposed = {k: v for k, v in seen.items() if k[1] not in LOOPBACK_IPS}
    assert exposed == {}, f"listening beyond loopback: {exposed}"
    tmpdirs = (out / "tmpdirs.log").read_text().split()  # Ray workers' temp folders: gone too
    assert tmpdirs and [d for d in tmpdirs if Path(d).exists()] == []


@pytest.mark.ray
@pytest.mark.timeout(900)
def test_ray_worker_that_hangs_ends_itself_and_the_task_is_retried(tmp_path):
    """farm.item_timeout_s on Ray: the worker process ends itself (SIGALRM) when an item runs
    past the limit, and Ray retries the task."""
    pytest.importorskip("ray")
    out = tmp_path / "job"
    ids = items(4)
    t0 = time.monotonic()
    s = run_tasks(out, "frames", ids, "test_farm:FileProcessor", {"out": str(out), "hang_once": "000002"},
                  engine="ray", workers=1, chunk=2, item_timeout_s=3, progress=False)
    assert s.ok and s.done == 4, s.text()
    assert time.monotonic() - t0 < 300  # ~20 s normally; a hang sleeps an hour
    assert_outputs_complete(out, ids)
    logs = "".join(p.read_text() for p in (out / ".blendgen" / "logs").rglob("*.log"))
    assert "farm.item_timeout_s 3: this process ends (SIGALRM)" in logs


def test_ray_cluster_run_needs_a_token(tmp_path, monkeypatch):
    pytest.importorskip("ray")
    for k in ("RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH"):
        monkeypatch.delenv(k, raising=False)
    with pytest.raises(UserError, match="RAY_AUTH_TOKEN"):
        run_tasks(tmp_path, "frames", items(2), "test_farm:FileProcessor", {"out": str(tmp_path)},
                  engine="ray", address="127.0.0.1:6379", progress=False)


@pytest.mark.ray
@pytest.mark.timeout(300)
def test_ray_cluster_survives_node_removal(tmp_path, monkeypatch):
    """Issue 7: a local Ray cluster on 127.0.0.1 (head + 2 worker nodes); one worker node is
    removed mid-run; the job still completes, each item exactly once, nothing partial."""
    ray = pytest.importorskip("ray")
    from ray._private import ray_constants
    from ray.cluster_utils import Cluster

    # Ray rewrites 127.0.0.1 to the machine's network IP when a driver connects, unless
    # told this is not a multi-host cluster (see docs/farm.md, "loopback-only cluster").
    monkeypatch.setenv("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
    monkeypatch.setattr(ray_constants, "ENABLE_RAY_CLUSTER", False)
    # a cluster run needs the cluster's token; this one uses Ray's default token file
    monkeypatch.setenv("RAY_AUTH_TOKEN_PATH", str(Path.home() / ".ray" / "auth_token"))
    out = tmp_path / "job"
    ids = items(24)
    small = {"object_store_memory": 80 * 2**20, "node_ip_address": "127.0.0.1"}
    cluster = Cluster(initialize_head=True,
                      head_node_args={"num_cpus": 0, "include_dashboard": False, **small})
    try:
        keep = cluster.add_node(num_cpus=1, **small)
        doomed = cluster.add_node(num_cpus=1, **small)
        cluster.wait_for_nodes()
        removed = []

        def remover():
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline and len(completions(out)) < 6:
                time.sleep(0.05)
            cluster.remove_node(doomed, allow_graceful=False)
            removed.append(time.monotonic())

        t = threading.Thread(target=remover, daemon=True)
        t.start()
        s = run_tasks(out, "frames", ids, "test_farm:FileProcessor",
                      {"out": str(out), "delay": 0.25, "raise_once": ["000003"]},
                      engine="ray", address=cluster.address, workers=2, chunk=2,
                      max_attempts=3, progress=False, seed=7)
        finished = time.monotonic()
        t.join(5)
        assert removed and removed[0] < finished, "the node was not removed mid-run"
        assert s.ok, s.text()
        assert sorted(completions(out)) == ids
        assert_outputs_complete(out, ids)
        assert sorted(r["item"] for r in manifest(out)) == ids
        assert keep in cluster.list_all_nodes() and doomed not in cluster.list_all_nodes()
        runs_on = {r["farm"]["worker"] for r in manifest(out)}
        assert len(runs_on) >= 2, "both worker nodes should have taken tasks"
    finally:
        ray.shutdown()
        cluster.shutdown()


# -- benchmark wrapper (excluded by default: -m benchmark) ------------------------------------
@pytest.mark.benchmark
def test_bench_ledger_throughput_and_overhead(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks" / "farm"))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT / "benchmarks" / "farm"), str(TESTS)]))
    import bench_farm

    assert bench_farm.bench_ledger(2000, commit_every=1) >= 1000  # issue 7 target
    startup = bench_farm.bench_run("bench_farm:NoopProcessor", {}, 1, 1, 1)
    wall = bench_farm.bench_run("bench_farm:NoopProcessor", {}, 300, 1, 16)
    assert (wall - startup) / 300 < 0.02  # scheduling overhead per frame well under a render


def test_deleted_outputs_are_done_again(tmp_path):
    """The ledger says done, but the user deleted two outputs: those two run again, only those."""
    out = tmp_path / "job"
    ids = items(5)
    s = run_tasks(out, "frames", ids, "test_farm:FileProcessor", {"out": str(out)}, progress=False)
    assert s.ok and s.processed == 5
    gone = [ids[1], ids[3]]
    for it in gone:
        (out / "items" / f"{it}.bin").unlink()
    s2 = run_tasks(out, "frames", ids, "test_farm:FileProcessor", {"out": str(out)}, progress=False,
                   redo=gone)
    assert s2.ok and s2.processed == 2 and s2.already_done == 3
    for it in ids:
        assert (out / "items" / f"{it}.bin").read_bytes() == expected_bytes(it)
