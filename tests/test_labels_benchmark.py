"""`-m benchmark` wrapper: the labels benchmark runs end to end in quick mode."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.benchmark
def test_bench_labels_quick(tmp_path):
    # Outputs to tmp_path: the committed results come from a full run.
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "labels" / "bench_labels.py"), "--quick",
                        "--outputs", str(tmp_path)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "export coco" in r.stdout and (tmp_path / "labels.png").exists() and (tmp_path / "labels.md").exists()
