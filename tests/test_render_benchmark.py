"""The render benchmark as a pytest (excluded by default: -m benchmark)."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.benchmark
@pytest.mark.bpy
def test_bench_render_quick():
    pytest.importorskip("bpy")
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_render.py"), "--quick"],
                       capture_output=True, text=True, timeout=1800, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    md = (ROOT / "docs" / "benchmarks" / "render_quick.md").read_text()
    assert "Speedup over the naive full-frame render" in md and "largest growth after frame 10" in md
