"""Atomic file output: every file is written to a temporary name in the same folder,
flushed, and renamed, so a crash never leaves a half-written file behind."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Iterator


def _file_mode() -> int:
    """Mode a plain open() would give a new file: 0o666 less the umask (mkstemp gives 0o600,
    which would make a dataset written for a team unreadable to it)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


FILE_MODE = _file_mode()  # read once: os.umask is process-wide and not thread-safe to probe


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside `path`; rename it onto `path` if the block succeeds.

    The temp name keeps the real extension (or `suffix`) so writers that pick a format by
    extension (cv2.imwrite, Blender, OpenEXR) still work.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ext = suffix if suffix is not None else "".join(path.suffixes)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{ext}", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        if not tmp_path.exists() or tmp_path.stat().st_size == 0 and not _allow_empty(path):
            raise OSError(f"writer produced no data for {path}")
        os.chmod(tmp_path, FILE_MODE)
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def _allow_empty(path: Path) -> bool:
    return path.suffix in {".txt", ".csv", ".jsonl", ".json", ".yaml", ".tum"}


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())


def write_text(path: str | os.PathLike, text: str) -> None:
    write_bytes(path, text.encode("utf-8"))


def write_json(path: str | os.PathLike, obj: Any, indent: int | None = None) -> None:
    write_text(path, json.dumps(obj, indent=indent, default=_json_default) + "\n")


def write_image(path: str | os.PathLike, image, params: list[int] | None = None) -> None:
    """cv2.imwrite through a temp file; raises instead of returning False."""
    import cv2

    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), image, params or []):
            raise OSError(f"cv2.imwrite could not write {path}")


def append_line(path: str | os.PathLike, line: str) -> None:
    """Append one line with a single write + fsync (a torn last line is skipped on read)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a", encoding="utf-8") as f:
        f.write(line.rstrip("\n") + "\n")
        f.flush()
        os.fsync(f.fileno())


def _json_default(o: Any):
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
