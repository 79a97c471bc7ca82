"""`run_tasks`: the farm's entry point, called by every stage that needs workers."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from ..errors import UserError
from .books import Books, FarmSummary
from .processor import check_processor_spec

ENGINES = ("local", "ray")


def run_tasks(out_dir: Path, stage: str, items: list[str], processor: str,
              processor_args: dict, *, engine: str = "local", workers: int = 1, chunk: int = 4,
              max_attempts: int = 3, recycle_after: int = 200, max_rss_mb: int = 6000,
              item_timeout_s: float | str | None = "auto", address: str | None = None,
              progress: bool = True, seed: int = 0, redo=()) -> FarmSummary:
    """Run `processor` over `items` (frame ids) in chunks of `chunk`, resuming from the ledger.

    Items already done in `OUT/.blendgen/ledger.sqlite` (or recorded in `OUT/manifest.jsonl`)
    are not dispatched, except those in `redo` (their outputs are gone); workers also skip
    items whose `is_done(item)` is true. Returns a
    `FarmSummary`; failed tasks (after `max_attempts`) are listed in `summary.failed` with
    their error and log, and `summary.ok` is False. A worker that finishes no item for
    `item_timeout_s` ("auto": 30 min or 10x the slowest item so far; None: never) is killed
    (Ray: ends itself) and its task retried. Ctrl-C kills the workers, gives their
    tasks back, and re-raises KeyboardInterrupt: running again resumes.
    """
    check_processor_spec(processor)
    if engine not in ENGINES:
        raise UserError(f"expected one of {', '.join(ENGINES)}, got {engine!r}",
                        where="farm.engine")
    for name, value, low in (("workers", workers, 1), ("chunk", chunk, 1),
                             ("max_attempts", max_attempts, 1),
                             ("recycle_after_frames", recycle_after, 1),
                             ("max_rss_mb", max_rss_mb, 1)):
        if not isinstance(value, int) or value < low:
            raise UserError(f"expected an integer >= {low}, got {value!r}", where=f"farm.{name}")
    if item_timeout_s not in ("auto", None) and not (isinstance(item_timeout_s, (int, float))
                                                     and item_timeout_s > 0):
        raise UserError(f"expected seconds > 0, 'auto' or null, got {item_timeout_s!r}",
                        where="farm.item_timeout_s")
    try:
        json.dumps(processor_args)
    except TypeError as e:
        raise UserError(f"processor_args must be JSON-able ({e})", where="farm") from e
    books = Books(Path(out_dir), stage, list(items), chunk=chunk, engine=engine,
                  workers=workers, seed=seed, max_attempts=max_attempts, progress=progress, redo=redo)
    # Workers' temp files (Blender's, the render session's) go under OUT, not /tmp, so that
    # what a killed worker leaves is removed here: before (a killed earlier run) and after.
    tmp = books.tmp_dir
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        if engine == "local":
            from .local import LocalEngine

            LocalEngine(books, processor, processor_args, workers=workers,
                        recycle_after=recycle_after, max_rss_mb=max_rss_mb,
                        item_timeout_s=item_timeout_s).run(books.task_ids)
        else:
            from .ray_engine import RayEngine

            RayEngine(books, processor, processor_args, workers=workers, chunk=chunk,
                      recycle_after=recycle_after, address=address,
                      item_timeout_s=item_timeout_s).run(books.task_ids)
    except BaseException as e:
        books.finish("interrupted" if isinstance(e, KeyboardInterrupt) else "failed")
        raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return books.finish()
