"""What every benchmark script shares: where the checkout, its results and the shared data are,
running the blendgen CLI in a subprocess, a percentile interval, and writing a table into docs.

A script in benchmarks/<stage>/ puts the checkout first on sys.path (so this checkout's blendgen
is the one measured, whatever the venv has installed) and imports from here:

    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    from benchmarks.common import ROOT, REAL  # noqa: E402
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from blendgen import atomic  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"  # plots and JSON (docs link them)
TMP = RESULTS / "tmp"  # git-ignored: caches, renders, overlays of non-commercial footage
DOCS = ROOT / "docs" / "benchmarks"  # each benchmark's current table
# ../shared/data beside the checkout, unless BLENDGEN_SHARED_DATA points elsewhere
SHARED_DATA = Path(os.environ.get("BLENDGEN_SHARED_DATA", ROOT.parent / "shared" / "data"))
REAL = SHARED_DATA / "real"
DETECTOR = SHARED_DATA / "models" / "yolox_nano.onnx"


def blendgen_cmd(*args) -> list[str]:
    """`blendgen ARGS` as a subprocess command line, with this interpreter."""
    return [sys.executable, "-m", "blendgen.cli", *map(str, args)]


def checkout_env(**extra: str) -> dict[str, str]:
    """The environment with this checkout first on PYTHONPATH (subprocesses import its blendgen)."""
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)
    return {**os.environ, "PYTHONPATH": path, **extra}


def sh(cmd: list, env=None, cwd: Path = ROOT) -> str:
    """Run cmd from the checkout; its stdout, or RuntimeError with the tail of both streams."""
    cmd = [str(c) for c in cmd]
    r = subprocess.run(cmd, cwd=cwd, env=env or checkout_env(), capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    return r.stdout


def ci95(samples) -> tuple[float, float]:
    """The 2.5 and 97.5 percentiles of bootstrap samples (NaNs ignored): a 95 % interval."""
    lo, hi = np.nanpercentile(np.asarray(samples, float), [2.5, 97.5])
    return float(lo), float(hi)


def write_doc(name: str, text: str) -> Path:
    """Replace docs/benchmarks/NAME atomically (a killed run leaves the last table whole)."""
    path = DOCS / name
    atomic.write_text(path, text)
    return path
