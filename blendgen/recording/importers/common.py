"""Helpers shared by the importers: output folder, file placement, text tables, defaults."""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import numpy as np

from blendgen import atomic
from blendgen.errors import UserError
from blendgen.geometry import Camera

TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}


def prepare_output(dst: str | Path, force: bool = False) -> Path:
    """The destination folder, created; refuses a non-empty one unless `force`."""
    dst = Path(dst)
    if dst.exists() and not dst.is_dir():
        raise UserError("destination exists and is not a folder", where=str(dst))
    if dst.is_dir() and any(dst.iterdir()) and not force:
        raise UserError("destination folder is not empty (pass --force to write into it)", where=str(dst))
    dst.mkdir(parents=True, exist_ok=True)
    return dst


def place_file(src: Path, dst: Path) -> None:
    """Put a copy of src at dst atomically: a hard link when possible (no extra space), else a copy.

    Never re-encodes: images and videos keep their bytes.
    """
    with atomic.atomic_path(dst) as tmp:
        tmp.unlink()
        try:
            # resolve first: Linux link() hard-links a symlink itself, and a recording's frames
            # may not be symlinks out of its folder
            os.link(Path(src).resolve(), tmp)
        except OSError:
            shutil.copyfile(src, tmp)


def progress(iterable, *, total: int | None = None, desc: str = "", enabled: bool = True):
    """tqdm progress on stderr for long conversions (silent when disabled or not a terminal)."""
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc, unit="it", leave=False,
                disable=not enabled or not sys.stderr.isatty(), file=sys.stderr)


def first_frame_size(video: Path, what: str = "the first video frame") -> tuple[int, int]:
    """(width, height) of a video, from its first decoded frame; UserError if it does not decode."""
    import cv2

    cap = cv2.VideoCapture(str(video))
    ok, first = cap.read()
    cap.release()
    if not ok:
        raise UserError(f"{what} does not decode", where=str(video))
    return first.shape[1], first.shape[0]


def default_camera(width: int, height: int, hfov_deg: float) -> Camera:
    return Camera.from_hfov(int(width), int(height), float(hfov_deg))


def import_meta(fmt: str, src: Path, *, camera: str, T_cam_imu: str, notes: list[str] | None = None,
                **extra) -> dict:
    """The `import:` section of calib.yaml: provenance and what was assumed rather than read.

    `camera` / `T_cam_imu` start with "assumed" when the importer had to guess; the check
    (`blendgen import --check`) reports those.
    """
    meta = {"format": fmt, "source": str(src), "camera_calibration": camera, "T_cam_imu": T_cam_imu,
            "notes": list(notes or [])}
    meta.update(extra)
    return meta


def read_table(path: Path, aliases: dict[str, list[str]], *, required: list[str],
               what: str) -> dict[str, np.ndarray]:
    """A CSV (comma or whitespace separated, one header line, '#' allowed before it) as columns.

    `aliases` maps our column name to accepted header names (case-insensitive, units in
    brackets ignored, e.g. "w_RS_S_x [rad s^-1]").
    """
    if not path.exists():
        raise UserError(f"{what} file not found", where=str(path))
    text = path.read_text(errors="replace").splitlines()
    lines = [ln for ln in text if ln.strip()]
    if not lines:
        raise UserError(f"{what} file is empty", where=str(path))
    sep = "," if "," in lines[0] else None
    header = [_norm(h) for h in (lines[0].split(sep))]
    idx = {}
    for name, names in aliases.items():
        for cand in [name] + names:
            if _norm(cand) in header:
                idx[name] = header.index(_norm(cand))
                break
    missing = [c for c in required if c not in idx]
    if missing:
        raise UserError(f"{what}: missing column(s) {missing}; header is {lines[0].strip()!r}; "
                        f"accepted names: { {c: [c] + aliases[c] for c in missing} }", where=str(path))
    out = {c: np.empty(len(lines) - 1) for c in idx}
    for r, ln in enumerate(lines[1:]):
        fields = [f.strip() for f in ln.split(sep)]
        for c, j in idx.items():
            if j >= len(fields):
                raise UserError(f"row {r + 2}: {len(fields)} fields, column {c!r} is field {j + 1} "
                                "(truncated line?)", where=str(path))
            try:
                out[c][r] = float(fields[j]) if fields[j] != "" else np.nan
            except ValueError:
                raise UserError(f"row {r + 2}: column {c!r} is {fields[j]!r}, not a number", where=str(path)) from None
    return out


def _norm(h: str) -> str:
    h = h.strip().lstrip("#").strip().lower()
    return h.split("[")[0].split("(")[0].strip()


def require_increasing(t: np.ndarray, path: Path | str, what: str) -> None:
    d = np.diff(t)
    bad = np.flatnonzero(~(d > 0))
    if bad.size:
        raise UserError(f"{what}: timestamp {t[bad[0] + 1]!r} (sample {bad[0] + 1}) does not increase after "
                        f"{t[bad[0]]!r}", where=str(path))


def dedupe_sorted(t: np.ndarray, *arrays: np.ndarray) -> tuple:
    """Sort by time and drop repeated timestamps (logs often repeat the last message)."""
    order = np.argsort(t, kind="stable")
    t = t[order]
    keep = np.concatenate([[True], np.diff(t) > 0]) if len(t) else np.zeros(0, bool)
    return (t[keep],) + tuple(a[order][keep] for a in arrays)
