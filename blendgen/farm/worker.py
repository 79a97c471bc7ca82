"""A local farm worker: `python -m blendgen.farm.worker --rfd R --wfd W --ppid P`.

Started by the supervisor as a fresh interpreter (never forked from a process that may have
imported bpy), it builds the processor once and then runs the tasks it is sent over a pipe,
one JSON line per message. It dies with its supervisor: PR_SET_PDEATHSIG on Linux, a
parent-pid watchdog elsewhere, and EOF on the command pipe between tasks.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import signal
import socket
import sys
import threading
import time
import traceback

from .processor import close_processor, load_processor, redirect_output, rss_mb, run_items

PR_SET_PDEATHSIG = 1


def _die_with_parent(ppid: int) -> None:
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
        except (OSError, AttributeError):
            pass
    if os.getppid() != ppid:  # the parent died before prctl took effect
        os._exit(70)

    def watchdog() -> None:
        while True:
            time.sleep(1.0)
            if os.getppid() != ppid:
                os._exit(70)

    threading.Thread(target=watchdog, name="parent-watchdog", daemon=True).start()


class _Channel:
    def __init__(self, rfd: int, wfd: int):
        self.r = os.fdopen(rfd, "rb", buffering=0)
        self.rbuf = b""
        self.wfd = wfd

    def send(self, msg: dict) -> None:
        data = (json.dumps(msg) + "\n").encode("utf-8")
        while data:
            try:
                n = os.write(self.wfd, data)
            except BrokenPipeError:
                os._exit(71)  # supervisor gone: nobody will record our work
            data = data[n:]

    def recv(self) -> dict | None:
        while b"\n" not in self.rbuf:
            chunk = self.r.read(65536)
            if not chunk:
                return None
            self.rbuf += chunk
        line, self.rbuf = self.rbuf.split(b"\n", 1)
        return json.loads(line)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="blendgen.farm.worker")
    ap.add_argument("--rfd", type=int, required=True)
    ap.add_argument("--wfd", type=int, required=True)
    ap.add_argument("--ppid", type=int, required=True)
    a = ap.parse_args(argv)
    _die_with_parent(a.ppid)
    # Ctrl-C reaches the whole process group; the supervisor decides how workers stop.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    ch = _Channel(a.rfd, a.wfd)
    init = ch.recv()
    if init is None:
        return 0
    with redirect_output(init["log"]):
        t0 = time.perf_counter()
        procs = {}
        try:
            # one per stage of the run (a pipeline's stages share the workers), built once
            for stage, spec in init["processors"].items():
                procs[stage] = load_processor(spec["processor"], spec["processor_args"])
        except Exception as e:
            traceback.print_exc()
            ch.send({"ev": "init_error", "error": f"{type(e).__name__}: {e}"[:2000]})
            return 3
        ch.send({"ev": "ready", "pid": os.getpid(), "host": socket.gethostname(),
                 "init_s": time.perf_counter() - t0, "rss_mb": rss_mb()})
        while True:
            msg = ch.recv()
            if msg is None or msg.get("op") == "stop":
                break
            task = msg["task"]

            def emit(ev: dict, task=task) -> None:
                ev["task"] = task
                ch.send(ev)

            with redirect_output(msg["log"]):
                print(f"[blendgen.farm] task {task} ({msg['stage']}) attempt {msg.get('attempt')} on pid "
                      f"{os.getpid()}: {len(msg['items'])} items", flush=True)
                ok = run_items(procs[msg["stage"]], msg["items"], emit)
            ch.send({"ev": "task_end", "task": task, "ok": ok, "rss_mb": rss_mb()})
        for proc in procs.values():
            try:
                close_processor(proc)
            except Exception:
                traceback.print_exc()
    return 0


if __name__ == "__main__":
    sys.exit(main())
