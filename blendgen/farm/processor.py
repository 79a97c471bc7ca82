"""What runs inside a farm worker: load the processor once, then run items through it.

A processor is any class named as `"module:Class"`, built once per worker process with
`**processor_args` (a warm Blender session lives inside it) and offering
`is_done(item) -> bool`, `process(item) -> dict` and optionally `close()`. This module is
shared by the local worker process and the Ray task and never imports bpy itself.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import re
import sys
import time
import traceback
from pathlib import Path
from typing import Any, Callable, Iterator

from ..errors import UserError

_SPEC = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")


def check_processor_spec(processor: str) -> tuple[str, str]:
    if not isinstance(processor, str) or not _SPEC.match(processor):
        raise UserError(f"expected 'package.module:ClassName', got {processor!r}",
                        where="farm processor")
    module, cls = processor.split(":")
    return module, cls


def load_processor(processor: str, processor_args: dict) -> Any:
    module, cls = check_processor_spec(processor)
    obj = getattr(importlib.import_module(module), cls)(**processor_args)
    for method in ("is_done", "process"):
        if not callable(getattr(obj, method, None)):
            raise TypeError(f"processor {processor} has no method {method}(item)")
    return obj


def close_processor(proc: Any) -> None:
    close = getattr(proc, "close", None)
    if callable(close):
        close()


def rss_mb() -> float:
    """Resident set size of this process (Linux /proc; 0 where unavailable)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


@contextlib.contextmanager
def redirect_output(log_path: str | os.PathLike) -> Iterator[None]:
    """Send this process's stdout/stderr (file descriptors 1 and 2, so that Blender's C-level
    prints are caught too) to `log_path` for the duration of the block."""
    Path(log_path).parent.mkdir(parents=True, exist_ok=True)
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    try:
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for f in (fd, *saved):
            os.close(f)


def run_items(proc: Any, items: list[str], emit: Callable[[dict], None]) -> bool:
    """Run `items` in order through `proc`, emitting one event per item.

    Events: {"ev": "item", "item", "skipped", "record", "is_done_s", "process_s"};
    {"ev": "item_failed", "item", "error"} when an item raises UserError (bad input of that
    item alone, e.g. a corrupt frame: retrying cannot help and the worker is healthy, so the
    task goes on with the next item); and, on the first other exception,
    {"ev": "error", "item", "error"} (the traceback goes to stderr, i.e. the task's log)
    after which the rest of the task is abandoned. Returns True when no item raised anything
    but UserError.
    """
    for item in items:
        t0 = time.perf_counter()
        try:
            skipped = bool(proc.is_done(item))
            t1 = time.perf_counter()
            record = None
            if not skipped:
                print(f"[blendgen.farm] {time.strftime('%H:%M:%S')} item {item}", flush=True)
                record = proc.process(item)
                if record is None:
                    record = {}
                if not isinstance(record, dict):
                    raise TypeError(f"process({item!r}) returned {type(record).__name__}, "
                                    "expected a dict (the manifest record)")
                json.dumps(record)  # fail here, on the worker, if it is not JSON-able
        except UserError as e:
            print(f"[blendgen.farm] item {item} failed: {e}", file=sys.stderr, flush=True)
            emit({"ev": "item_failed", "item": item, "error": str(e)[:2000]})
            continue
        except Exception as e:  # the supervisor decides about retries; keep the evidence
            traceback.print_exc()
            sys.stderr.flush()
            emit({"ev": "error", "item": item, "error": f"{type(e).__name__}: {e}"[:2000]})
            return False
        t2 = time.perf_counter()
        emit({"ev": "item", "item": item, "skipped": skipped, "record": record,
              "is_done_s": t1 - t0, "process_s": t2 - t1})
    return True


def clean_stale_temps(folder: str | os.PathLike, stem: str = "*") -> int:
    """Remove temp files that `blendgen.atomic` left in `folder` when a worker was killed
    mid-write (`.<stem>.<random>.tmp<ext>`). Processors call this before writing an item,
    for that item's own folder or file stem only: other workers may be writing beside it."""
    n = 0
    folder = Path(folder)
    if folder.is_dir():
        for p in folder.glob(f".{stem}.*tmp*"):
            with contextlib.suppress(FileNotFoundError):
                p.unlink()
                n += 1
    return n
