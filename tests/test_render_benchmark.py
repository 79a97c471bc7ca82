"""The render benchmark: its sample search (fast), and the whole quick run as a pytest
(excluded by default: -m benchmark)."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_render", ROOT / "benchmarks" / "render" / "bench_render.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_sample_search_finds_the_lowest_count_reaching_the_target():
    search = _bench().search_samples
    calls = []

    def measure(n):  # PSNR rising with samples: 12 gives 34.8 dB, 13 gives 35.2 dB
        calls.append(n)
        return {"samples": n, "psnr_db": 30.0 + 0.4 * n}

    row, tried = search(measure, 35.0, 1, 256)
    assert row["samples"] == 13
    assert len(calls) == len(set(calls)) <= 8  # doubling to 16, then bisection: no repeats
    assert [r["samples"] for r in tried] == sorted(calls)
    # Noisy PSNR (a dip at 14): the answer is a hit with a miss one sample below it.
    row, tried = search(lambda n: {"samples": n, "psnr_db": {14: 34.9}.get(n, 30.0 + 0.4 * n)}, 35.0, 1, 256)
    by_n = {r["samples"]: r["psnr_db"] for r in tried}
    assert row["psnr_db"] >= 35.0 and by_n[row["samples"] - 1] < 35.0
    row, _ = search(lambda n: {"samples": n, "psnr_db": 20.0}, 35.0, 1, 64)
    assert row is None

    # a memo shared between two targets: the second search reuses the first one's renders
    memo, calls = {}, []
    for target in (35.0, 36.0):
        search(lambda n: calls.append(n) or {"samples": n, "psnr_db": 30.0 + 0.4 * n}, target, 1, 256, memo)
    assert len(calls) == len(set(calls))


def test_naive_cost_from_a_line_fit_at_the_interpolated_count():
    fit = _bench().fitted_naive_cpu
    # CPU = 20 + 2 n with one noisy render at 13 (+5 s); PSNR 36.9 at 12, 37.4 at 13
    rows = [{"samples": n, "cpu_s": 20 + 2 * n + (5 if n == 13 else 0), "psnr_db": 32.1 + 0.4 * n + (0.1 if n >= 13 else 0)}
            for n in (1, 2, 4, 8, 12, 13, 16)]
    n, cpu, a, b = fit(rows, 37.0)
    assert n == pytest.approx(12.2)
    assert cpu == pytest.approx(a + b * n) and abs(b - 2) < 0.3  # the noisy render barely moves the line
    assert fit(rows, 99.0) is None  # not bracketed


@pytest.mark.benchmark
@pytest.mark.bpy
def test_bench_render_quick():
    pytest.importorskip("bpy")
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "render" / "bench_render.py"), "--quick",
                        "--repeats", "1"], capture_output=True, text=True, timeout=1800, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    md = (ROOT / "docs" / "benchmarks" / "render_fair_quick.md").read_text()
    assert "cheaper in CPU seconds" in md and "opposite edges, clustered" in md and "Interleaved pairs" in md


@pytest.mark.bpy
def test_gpu_bench_without_a_gpu_says_so_and_writes_nothing(tmp_path):
    pytest.importorskip("bpy")
    out = [ROOT / "docs" / "benchmarks" / "render_gpu.md", ROOT / "benchmarks" / "results" / "render_gpu.json"]
    before = [p.stat().st_mtime if p.exists() else None for p in out]
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "render" / "bench_render_gpu.py"), "--quick"],
                       capture_output=True, text=True, timeout=600, cwd=ROOT)
    if r.returncode == 0:
        pytest.skip("this machine has a GPU that Cycles can use")
    assert "found no GPU" in r.stderr and "Traceback" not in r.stderr
    assert [p.stat().st_mtime if p.exists() else None for p in out] == before


@pytest.mark.benchmark
@pytest.mark.bpy
def test_bench_render_gpu_script_on_the_cpu():
    pytest.importorskip("bpy")
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "render" / "bench_render_gpu.py"), "--device", "CPU", "--quick",
                        "--repeats", "1", "--pairs", "1", "--ref-samples", "32", "--max-samples", "64"],
                       capture_output=True, text=True, timeout=1800, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    md = (ROOT / "docs" / "benchmarks" / "render_gpu_cpu_quick.md").read_text()
    assert "cheaper in CPU wall seconds" in md and "opposite edges, clustered" in md
