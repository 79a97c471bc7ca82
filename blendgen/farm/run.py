"""`run_tasks`: the farm's entry point, called by every stage that needs workers."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from ..errors import UserError
from .books import Books, FarmSummary
from .graph import Stage
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
    stage_spec = Stage(stage, list(items), processor, processor_args, chunk=chunk, redo=redo)
    return run_pipeline(out_dir, [stage_spec], engine=engine, workers=workers, max_attempts=max_attempts,
                        recycle_after=recycle_after, max_rss_mb=max_rss_mb, item_timeout_s=item_timeout_s,
                        address=address, progress=progress, seed=seed)[stage]


def run_pipeline(out_dir: Path, stages: list[Stage], *, engine: str = "local", workers: int = 1,
                 max_attempts: int = 3, recycle_after: int = 200, max_rss_mb: int = 6000,
                 item_timeout_s: float | str | None = "auto", address: str | None = None,
                 progress: bool = True, seed: int = 0, name: str | None = None) -> dict[str, FarmSummary]:
    """Run several stages on the same workers, each task as soon as what it needs is done
    (`Stage.needs`), the ready ones by priority; returns each stage's `FarmSummary`. Resumes
    from the ledger like `run_tasks` (one ledger run per stage); a task whose input failed for
    good fails too, naming it. Every worker builds every stage's processor once."""
    if engine not in ENGINES:
        raise UserError(f"expected one of {', '.join(ENGINES)}, got {engine!r}",
                        where="farm.engine")
    for name_, value, low in (("workers", workers, 1), ("max_attempts", max_attempts, 1),
                              ("recycle_after_frames", recycle_after, 1), ("max_rss_mb", max_rss_mb, 1)):
        if not isinstance(value, int) or value < low:
            raise UserError(f"expected an integer >= {low}, got {value!r}", where=f"farm.{name_}")
    for st in stages:
        check_processor_spec(st.processor)
        if not isinstance(st.chunk, int) or st.chunk < 1:
            raise UserError(f"expected an integer >= 1, got {st.chunk!r}", where="farm.chunk")
        try:
            json.dumps(st.processor_args)
        except TypeError as e:
            raise UserError(f"processor_args must be JSON-able ({e})", where="farm") from e
    if item_timeout_s not in ("auto", None) and not (isinstance(item_timeout_s, (int, float))
                                                     and item_timeout_s > 0):
        raise UserError(f"expected seconds > 0, 'auto' or null, got {item_timeout_s!r}",
                        where="farm.item_timeout_s")
    books = Books(Path(out_dir), stages, engine=engine, workers=workers, seed=seed,
                  max_attempts=max_attempts, progress=progress, name=name)
    # Workers' temp files (Blender's, the render session's) go under OUT, not /tmp, so that
    # what a killed worker leaves is removed here: before (a killed earlier run) and after.
    tmp = books.tmp_dir
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        if engine == "local":
            from .local import LocalEngine

            LocalEngine(books, workers=workers, recycle_after=recycle_after, max_rss_mb=max_rss_mb,
                        item_timeout_s=item_timeout_s).run()
        else:
            from .ray_engine import RayEngine

            RayEngine(books, workers=workers, recycle_after=recycle_after, address=address,
                      item_timeout_s=item_timeout_s).run()
    except BaseException as e:
        books.finish("interrupted" if isinstance(e, KeyboardInterrupt) else "failed")
        raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return books.finish()
