"""`-m benchmark` wrapper: the sync benchmark in its quick form (about 3 minutes)."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.benchmark
def test_bench_sync_quick():
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "sync" / "bench_sync.py"), "--quick"], cwd=ROOT,
                         capture_output=True, text=True, timeout=1800)
    assert out.returncode == 0, out.stderr[-2000:]
    md = (ROOT / "docs" / "benchmarks" / "sync_quick.md").read_text()
    assert "(default" in md and "VO throughput" in md and "Easy vs hard synthetic drive" in md
