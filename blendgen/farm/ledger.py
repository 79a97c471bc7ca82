"""The SQLite task ledger (`OUT/.blendgen/ledger.sqlite`): the one source of truth for
task state, attempts, leases, errors and log paths, on every engine.

Only the supervisor writes it (one connection, batched commits); `blendgen status` and other
readers open it concurrently thanks to WAL mode. Items (frames) carry their own state, so a
task that dies half-way keeps the items it finished, and its retry covers only the rest.
"""

from __future__ import annotations

import json
import os
import socket
import sqlite3
import time
from pathlib import Path

from ..errors import UserError

LEDGER_DIR = ".blendgen"
LEDGER_NAME = "ledger.sqlite"
SCHEMA_VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta(key TEXT PRIMARY KEY, value TEXT);
CREATE TABLE IF NOT EXISTS runs(
    run_id INTEGER PRIMARY KEY AUTOINCREMENT, stage TEXT NOT NULL, engine TEXT, workers INT,
    host TEXT, pid INT, started REAL, heartbeat REAL, finished REAL, state TEXT,
    n_items INT, n_done_at_start INT);
CREATE TABLE IF NOT EXISTS items(
    stage TEXT NOT NULL, item TEXT NOT NULL, state TEXT NOT NULL, task_id INT,
    run_id INT, worker TEXT, finished REAL, in_manifest INT NOT NULL DEFAULT 0, error TEXT,
    PRIMARY KEY(stage, item));
CREATE TABLE IF NOT EXISTS tasks(
    task_id INTEGER PRIMARY KEY AUTOINCREMENT, stage TEXT NOT NULL, run_id INT NOT NULL,
    items TEXT NOT NULL, state TEXT NOT NULL, attempts INT NOT NULL DEFAULT 0, worker TEXT,
    lease_until REAL, error TEXT, log_path TEXT, avoid TEXT NOT NULL DEFAULT '[]',
    created REAL, started REAL, finished REAL);
CREATE TABLE IF NOT EXISTS attempts(
    task_id INT NOT NULL, attempt INT NOT NULL, worker TEXT, started REAL, finished REAL,
    outcome TEXT, error TEXT, log_path TEXT, PRIMARY KEY(task_id, attempt));
CREATE TABLE IF NOT EXISTS workers(
    run_id INT NOT NULL, worker TEXT NOT NULL, host TEXT, pid INT, started REAL,
    last_seen REAL, items_done INT NOT NULL DEFAULT 0, failures INT NOT NULL DEFAULT 0,
    state TEXT, exit TEXT, log_path TEXT, PRIMARY KEY(run_id, worker));
CREATE INDEX IF NOT EXISTS tasks_by_run ON tasks(run_id, state);
CREATE INDEX IF NOT EXISTS items_by_run ON items(stage, run_id, state);
CREATE INDEX IF NOT EXISTS items_by_task ON items(stage, task_id);
"""


def ledger_path(out_dir: str | os.PathLike) -> Path:
    return Path(out_dir) / LEDGER_DIR / LEDGER_NAME


def connect(path: Path, *, readonly: bool = False) -> sqlite3.Connection:
    if readonly:
        if not path.exists():
            raise UserError("no ledger here (has a job run in this folder?)", where=str(path))
        conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=10)
    else:
        path.parent.mkdir(parents=True, exist_ok=True)
        conn = sqlite3.connect(str(path), timeout=30)
        # WAL: readers (status) never block the writer; NORMAL sync is durable at checkpoints
        # and cannot corrupt the database on a crash, which is what resuming needs.
        conn.execute("PRAGMA journal_mode=WAL")
        conn.execute("PRAGMA synchronous=NORMAL")
    conn.row_factory = sqlite3.Row
    return conn


class Ledger:
    """Writer side of the ledger. Methods do not commit; the supervisor calls `commit()` once
    per event-loop turn so that a burst of finished items costs one transaction."""

    def __init__(self, out_dir: str | os.PathLike):
        self.path = ledger_path(out_dir)
        try:
            self.conn = connect(self.path)
            self.conn.executescript(_SCHEMA)
            cols = {r[1] for r in self.conn.execute("PRAGMA table_info(items)")}
            if "error" not in cols:  # ledgers written before per-item failures
                self.conn.execute("ALTER TABLE items ADD COLUMN error TEXT")
            row = self.conn.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
        except sqlite3.DatabaseError as e:
            raise UserError(f"the ledger is not a readable SQLite database ({e})",
                            where=str(self.path)) from e
        if row is None:
            self.conn.execute("INSERT INTO meta VALUES('schema', ?)", (str(SCHEMA_VERSION),))
        elif int(row["value"]) != SCHEMA_VERSION:
            raise UserError(f"ledger schema {row['value']} is not the supported "
                            f"{SCHEMA_VERSION}; remove it to start the stage afresh",
                            where=str(self.path))
        self.conn.commit()

    # -- runs ------------------------------------------------------------------------------
    def begin_run(self, stage: str, items: list[str], chunk: int, engine: str,
                  workers: int, manifest_items: set[str], redo: set[str] = frozenset()) -> tuple[int, list[int]]:
        """Register a run of `stage` over `items` and chunk the unfinished ones into tasks.

        Tasks left running or pending by an earlier (crashed or interrupted) run become
        `stale`; their unfinished items are chunked again. Items whose record reached the
        manifest are done even if the ledger commit after it was lost in a crash; items in
        `redo` (done, but their outputs were deleted) are done again.
        """
        now = time.time()
        c = self.conn
        c.execute("UPDATE runs SET state='interrupted', finished=? "
                  "WHERE stage=? AND state='running'", (now, stage))
        c.execute("UPDATE tasks SET state='stale' WHERE stage=? AND state IN "
                  "('pending','running')", (stage,))
        c.executemany("INSERT OR IGNORE INTO items(stage, item, state) VALUES(?, ?, 'pending')",
                      ((stage, it) for it in items))
        if manifest_items:
            c.executemany("UPDATE items SET state='done', in_manifest=1 WHERE stage=? AND "
                          "item=? AND state!='done'", ((stage, it) for it in manifest_items))
        if redo:
            c.executemany("UPDATE items SET state='pending', in_manifest=0 WHERE stage=? AND item=?",
                          ((stage, it) for it in redo))
        cur = c.execute("INSERT INTO runs(stage, engine, workers, host, pid, started, heartbeat,"
                        " state, n_items) VALUES(?,?,?,?,?,?,?,'running',?)",
                        (stage, engine, workers, socket.gethostname(), os.getpid(), now, now,
                         len(items)))
        run_id = int(cur.lastrowid)
        c.executemany("UPDATE items SET run_id=? WHERE stage=? AND item=?",
                      ((run_id, stage, it) for it in items))
        done = {r["item"] for r in c.execute(
            "SELECT item FROM items WHERE stage=? AND run_id=? AND state='done'", (stage, run_id))}
        # frames that failed on their own input get another chance (the user may have fixed it)
        c.execute("UPDATE items SET state='pending', task_id=NULL, worker=NULL, error=NULL "
                  "WHERE stage=? AND run_id=? AND state!='done'", (stage, run_id))
        c.execute("UPDATE runs SET n_done_at_start=? WHERE run_id=?", (len(done), run_id))
        todo = [it for it in items if it not in done]
        task_ids = []
        for k in range(0, len(todo), chunk):
            part = todo[k:k + chunk]
            cur = c.execute("INSERT INTO tasks(stage, run_id, items, state, created) "
                            "VALUES(?,?,?,'pending',?)", (stage, run_id, json.dumps(part), now))
            tid = int(cur.lastrowid)
            task_ids.append(tid)
            c.executemany("UPDATE items SET task_id=? WHERE stage=? AND item=?",
                          ((tid, stage, it) for it in part))
        self.commit()
        return run_id, task_ids

    def heartbeat(self, run_id: int, lease_s: float) -> None:
        now = time.time()
        self.conn.execute("UPDATE runs SET heartbeat=? WHERE run_id=?", (now, run_id))
        self.conn.execute("UPDATE tasks SET lease_until=? WHERE run_id=? AND state='running'",
                          (now + lease_s, run_id))

    def end_run(self, run_id: int, state: str) -> None:
        self.conn.execute("UPDATE runs SET state=?, finished=?, heartbeat=? WHERE run_id=?",
                          (state, time.time(), time.time(), run_id))
        self.commit()

    # -- tasks -----------------------------------------------------------------------------
    def task(self, task_id: int) -> sqlite3.Row:
        return self.conn.execute("SELECT * FROM tasks WHERE task_id=?", (task_id,)).fetchone()

    def remaining_items(self, task_id: int) -> list[str]:
        row = self.task(task_id)
        pending = {r["item"] for r in self.conn.execute(
            "SELECT item FROM items WHERE stage=? AND task_id=? AND state NOT IN "
            "('done', 'failed')",
            (row["stage"], task_id))}
        return [it for it in json.loads(row["items"]) if it in pending]

    def avoid(self, task_id: int) -> list[str]:
        return json.loads(self.task(task_id)["avoid"])

    def claim(self, task_id: int, worker: str, log_path: str, lease_s: float) -> int:
        """Lease a task to a worker; returns the attempt number (1-based)."""
        now = time.time()
        c = self.conn
        c.execute("UPDATE tasks SET state='running', attempts=attempts+1, worker=?, started=?, "
                  "lease_until=?, log_path=? WHERE task_id=?",
                  (worker, now, now + lease_s, log_path, task_id))
        row = self.task(task_id)
        c.execute("UPDATE items SET state='running', worker=? WHERE stage=? AND task_id=? AND "
                  "state NOT IN ('done', 'failed')", (worker, row["stage"], task_id))
        c.execute("INSERT OR REPLACE INTO attempts(task_id, attempt, worker, started, log_path) "
                  "VALUES(?,?,?,?,?)", (task_id, row["attempts"], worker, now, log_path))
        return int(row["attempts"])

    def set_attempt_worker(self, task_id: int, attempt: int, worker: str) -> None:
        """Ray places tasks itself: the worker is known only when the result comes back."""
        self.conn.execute("UPDATE tasks SET worker=? WHERE task_id=?", (worker, task_id))
        self.conn.execute("UPDATE attempts SET worker=? WHERE task_id=? AND attempt=?",
                          (worker, task_id, attempt))

    def item_done(self, stage: str, item: str, worker: str, in_manifest: bool = True) -> None:
        self.conn.execute("UPDATE items SET state='done', worker=?, finished=?, in_manifest=? "
                          "WHERE stage=? AND item=?",
                          (worker, time.time(), int(in_manifest), stage, item))

    def item_failed(self, stage: str, item: str, worker: str, error: str) -> None:
        """The item's own input is bad (UserError): it fails alone, with no retry."""
        self.conn.execute("UPDATE items SET state='failed', worker=?, finished=?, error=? "
                          "WHERE stage=? AND item=?", (worker, time.time(), error, stage, item))

    def task_done(self, task_id: int) -> None:
        now = time.time()
        row = self.task(task_id)
        self.conn.execute("UPDATE tasks SET state='done', finished=?, lease_until=NULL, "
                          "error=NULL WHERE task_id=?", (now, task_id))
        self.conn.execute("UPDATE attempts SET finished=?, outcome='done' WHERE task_id=? AND "
                          "attempt=?", (now, task_id, row["attempts"]))

    def task_failed(self, task_id: int, worker: str, error: str, max_attempts: int) -> bool:
        """Record a failed attempt. Returns True when the task is now failed for good
        (its items become `failed`), False when it went back to the queue."""
        now = time.time()
        row = self.task(task_id)
        avoid = json.loads(row["avoid"])
        if worker not in avoid:
            avoid.append(worker)
        final = row["attempts"] >= max_attempts
        state = "failed" if final else "pending"
        self.conn.execute("UPDATE tasks SET state=?, error=?, avoid=?, finished=?, "
                          "lease_until=NULL WHERE task_id=?",
                          (state, error, json.dumps(avoid), now, task_id))
        self.conn.execute("UPDATE attempts SET finished=?, outcome='failed', error=? "
                          "WHERE task_id=? AND attempt=?", (now, error, task_id, row["attempts"]))
        self.conn.execute("UPDATE items SET state=? WHERE stage=? AND task_id=? AND "
                          "state NOT IN ('done', 'failed')", (state, row["stage"], task_id))
        return final

    def release(self, task_id: int) -> None:
        """Give a leased task back without counting the attempt (Ctrl-C, shutdown)."""
        row = self.task(task_id)
        self.conn.execute("UPDATE tasks SET state='pending', attempts=max(attempts-1, 0), "
                          "worker=NULL, lease_until=NULL WHERE task_id=?", (task_id,))
        self.conn.execute("DELETE FROM attempts WHERE task_id=? AND attempt=?",
                          (task_id, row["attempts"]))
        self.conn.execute("UPDATE items SET state='pending', worker=NULL WHERE stage=? AND "
                          "task_id=? AND state NOT IN ('done', 'failed')", (row["stage"], task_id))

    # -- workers ---------------------------------------------------------------------------
    def worker_started(self, run_id: int, worker: str, host: str, pid: int,
                       log_path: str) -> None:
        now = time.time()
        self.conn.execute("INSERT OR REPLACE INTO workers(run_id, worker, host, pid, started, "
                          "last_seen, state, log_path) VALUES(?,?,?,?,?,?,'starting',?)",
                          (run_id, worker, host, pid, now, now, log_path))

    def worker_update(self, run_id: int, worker: str, *, state: str | None = None,
                      items: int = 0, failed: bool = False, exit: str | None = None) -> None:
        self.conn.execute(
            "UPDATE workers SET last_seen=?, items_done=items_done+?, failures=failures+?, "
            "state=coalesce(?, state), exit=coalesce(?, exit) WHERE run_id=? AND worker=?",
            (time.time(), items, int(failed), state, exit, run_id, worker))

    # -- queries ---------------------------------------------------------------------------
    def failed_tasks(self, run_id: int) -> list[dict]:
        rows = self.conn.execute("SELECT task_id, items, attempts, error, log_path FROM tasks "
                                 "WHERE run_id=? AND state='failed' ORDER BY task_id", (run_id,))
        return [{"task": r["task_id"], "items": json.loads(r["items"]), "attempts": r["attempts"],
                 "error": r["error"], "log": r["log_path"]} for r in rows]

    def failed_items(self, stage: str, run_id: int) -> list[dict]:
        """Items that failed on their own input (not with a failed task)."""
        rows = self.conn.execute("SELECT item, error FROM items WHERE stage=? AND run_id=? AND "
                                 "state='failed' AND error IS NOT NULL ORDER BY item",
                                 (stage, run_id))
        return [{"item": r["item"], "error": r["error"]} for r in rows]

    def done_items(self, stage: str, run_id: int) -> list[str]:
        return [r["item"] for r in self.conn.execute(
            "SELECT item FROM items WHERE stage=? AND run_id=? AND state='done'", (stage, run_id))]

    def task_items(self, task_ids: list[int]) -> list[tuple[int, list[str]]]:
        if not task_ids:
            return []
        rows = self.conn.execute("SELECT task_id, items FROM tasks WHERE task_id BETWEEN ? AND ? ORDER BY task_id",
                                 (min(task_ids), max(task_ids)))
        want = set(task_ids)
        return [(r["task_id"], json.loads(r["items"])) for r in rows if r["task_id"] in want]

    def count_items(self, stage: str, run_id: int) -> dict[str, int]:
        rows = self.conn.execute("SELECT state, count(*) AS n FROM items WHERE stage=? AND "
                                 "run_id=? GROUP BY state", (stage, run_id))
        return {r["state"]: r["n"] for r in rows}

    def commit(self) -> None:
        self.conn.commit()

    def close(self) -> None:
        try:
            self.conn.commit()
        finally:
            self.conn.close()

