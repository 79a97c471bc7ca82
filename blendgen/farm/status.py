"""`blendgen status OUT`: what the ledger says about each stage, readable while a job runs."""

from __future__ import annotations

import fcntl
import json
import os
import time
from pathlib import Path

from .ledger import LEDGER_DIR, connect, ledger_path


def lock_held(path: Path) -> bool | None:
    """Whether a process holds the flock on `path` (same host), None when it cannot tell."""
    if not path.exists():
        return None
    try:
        with open(path) as f:
            try:
                fcntl.flock(f, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
            fcntl.flock(f, fcntl.LOCK_UN)
            return False
    except OSError:
        return None


def fmt_duration(s: float) -> str:
    s = max(0, int(round(s)))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


def status_report(out_dir: Path) -> str:
    """Per stage (its latest run): done/running/failed/left, rate, ETA, and the last error
    and log of each failed task. Raises UserError when OUT has no ledger."""
    out_dir = Path(out_dir)
    conn = connect(ledger_path(out_dir), readonly=True)
    try:
        runs = conn.execute("SELECT * FROM runs WHERE run_id IN "
                            "(SELECT max(run_id) FROM runs GROUP BY stage) ORDER BY run_id"
                            ).fetchall()
        alive = lock_held(out_dir / LEDGER_DIR / "supervisor.lock")
        lines = [f"{out_dir}: {len(runs)} stage(s) in the ledger"]
        now = time.time()
        for run in runs:
            lines += _stage_lines(conn, run, alive, now)
        return "\n".join(lines)
    finally:
        conn.close()


def _stage_lines(conn, run, alive: bool | None, now: float) -> list[str]:
    rid, stage = run["run_id"], run["stage"]
    counts = {r["state"]: r["n"] for r in conn.execute(
        "SELECT state, count(*) AS n FROM items WHERE stage=? AND run_id=? GROUP BY state",
        (stage, rid))}
    total = sum(counts.values())
    done, failed = counts.get("done", 0), counts.get("failed", 0)
    running = counts.get("running", 0)
    left = total - done - failed - running
    if run["state"] == "running":
        stale = alive is False or (alive is None and now - (run["heartbeat"] or 0) > 30)
        where = f"pid {run['pid']} on {run['host']}"
        state = (f"NOT RESPONDING: supervisor ({where}) is gone, last heartbeat "
                 f"{fmt_duration(now - (run['heartbeat'] or now))} ago; run again to resume"
                 if stale else f"running ({where})")
    else:
        state = f"finished: {run['state']}"
    lines = [f"[{stage}] run {rid} on {run['engine']} x{run['workers']}: {state}",
             f"  done {done}/{total}, running {running}, failed {failed}, left {left}"]
    new = conn.execute("SELECT count(*) AS n, min(finished) AS t0, max(finished) AS t1 FROM "
                       "items WHERE stage=? AND run_id=? AND state='done' AND finished>=?",
                       (stage, rid, run["started"])).fetchone()
    end = now if run["state"] == "running" and state.startswith("running") else (
        new["t1"] or run["finished"] or now)
    elapsed = end - run["started"]
    if new["n"] and elapsed > 0:
        rate = new["n"] / elapsed
        todo = total - done - failed
        eta = f", ETA {fmt_duration(todo / rate)}" if todo and state.startswith("running") else ""
        lines.append(f"  rate {rate:.2f} frames/s over {fmt_duration(elapsed)}{eta}")
    for t in conn.execute("SELECT task_id, items, attempts, error, log_path FROM tasks WHERE "
                          "run_id=? AND state='failed' ORDER BY task_id", (rid,)):
        its = json.loads(t["items"])
        head = ", ".join(its[:4]) + (" ..." if len(its) > 4 else "")
        lines.append(f"  FAILED task {t['task_id']} [{head}] after {t['attempts']} "
                     f"attempt(s): {t['error']}")
        if t["log_path"] and os.path.exists(t["log_path"]):
            lines.append(f"    log: {t['log_path']}")
    if "error" in {r[1] for r in conn.execute("PRAGMA table_info(items)")}:
        for r in conn.execute("SELECT item, error FROM items WHERE stage=? AND run_id=? AND "
                              "state='failed' AND error IS NOT NULL ORDER BY item", (stage, rid)):
            lines.append(f"  FAILED frame {r['item']}: {r['error']}")
    return lines
