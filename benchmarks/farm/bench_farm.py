"""Farm benchmark: ledger throughput, scheduling overhead per frame, 1 -> 2 worker speedup.

    .venv/bin/python benchmarks/farm/bench_farm.py [--quick]

1. Ledger: no-op tasks through the SQLite ledger alone (claim, item done, task done), with a
   commit per task (worst case) and per 64 tasks (what the supervisor does under load).
2. Local engine end to end with a no-op processor: frames/s and supervisor overhead per
   frame (wall time minus worker start-up, divided by frames), chunk 1 and chunk 16.
3. Speedup from 1 to 2 local workers with a CPU-bound processor (a real image filter that
   writes its output atomically). The machine's cores are shared: medians of repeats.
Writes benchmarks/results/farm.png and docs/benchmarks/farm.md.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import RESULTS, write_doc  # noqa: E402
# workers import this module as `bench_farm:...`
os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(HERE), os.environ.get("PYTHONPATH"))
                                           if p)

from blendgen import atomic  # noqa: E402
from blendgen.farm import frame_seed, run_tasks  # noqa: E402
from blendgen.farm.ledger import Ledger  # noqa: E402


class NoopProcessor:
    def __init__(self, **_):
        pass

    def is_done(self, item: str) -> bool:
        return False

    def process(self, item: str) -> dict:
        return {}


class FilterProcessor:
    """CPU-bound: repeated separable blur of a seeded 384x384 image, PNG written atomically."""

    def __init__(self, out: str, repeats: int = 120):
        import cv2  # imported once per worker: part of the warm start

        self.out, self.repeats = Path(out), repeats
        cv2.setNumThreads(1)  # one core per worker, so the speedup measures the farm

    def is_done(self, item: str) -> bool:
        return (self.out / f"{item}.png").exists()

    def process(self, item: str) -> dict:
        import cv2
        import numpy as np

        rng = np.random.default_rng(frame_seed(0, item))
        img = rng.random((384, 384), dtype=np.float32)
        for _ in range(self.repeats):
            img = cv2.GaussianBlur(img, (0, 0), 3.0) * 1.5
            img = cv2.normalize(img, None, 0, 1, cv2.NORM_MINMAX)
        atomic.write_image(self.out / f"{item}.png", (img * 255).astype(np.uint8))
        return {"mean": float(img.mean())}


class SleepProcessor:
    """Waits instead of computing (like a render on a remote GPU): isolates the farm's
    parallelism from how busy the shared CPU cores are."""

    def __init__(self, out: str, seconds: float = 0.1):
        self.out, self.seconds = Path(out), seconds

    def is_done(self, item: str) -> bool:
        return (self.out / f"{item}.txt").exists()

    def process(self, item: str) -> dict:
        time.sleep(self.seconds)
        atomic.write_text(self.out / f"{item}.txt", item)
        return {}


def ids(n: int) -> list[str]:
    return [f"{i:06d}" for i in range(n)]


def bench_ledger(n: int, commit_every: int) -> float:
    with tempfile.TemporaryDirectory() as d:
        led = Ledger(d)
        run_id, tasks = led.begin_run("bench", ids(n), 1, "local", 1, set())
        t0 = time.perf_counter()
        for k, tid in enumerate(tasks):
            led.claim(tid, "w0", "log", 60)
            led.item_done("bench", f"{k:06d}", "w0")
            led.task_done(tid)
            if (k + 1) % commit_every == 0:
                led.commit()
        led.commit()
        dt = time.perf_counter() - t0
        led.close()
    return n / dt


def bench_run(processor: str, args: dict, n: int, workers: int, chunk: int,
              per_frame: list | None = None) -> float:
    """Wall time of one run; appends the median per-frame process_s to `per_frame`."""
    with tempfile.TemporaryDirectory() as d:
        a = dict(args)
        if "out" in a:
            a["out"] = d
        t0 = time.perf_counter()
        s = run_tasks(Path(d) / "job", "bench", ids(n), processor, a, workers=workers,
                      chunk=chunk, progress=False)
        dt = time.perf_counter() - t0
        assert s.ok and s.processed == n, s.text()
        if per_frame is not None:
            recs = [json.loads(ln) for ln in open(s.manifest)]
            per_frame.append(statistics.median(r["farm"]["process_s"] for r in recs))
    return dt


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    reps = 3
    n_ledger = 2000 if a.quick else 10000
    n_noop = 300 if a.quick else 2000
    n_cpu = 16 if a.quick else 32
    rows = []

    for every in (1, 64):
        r = statistics.median(bench_ledger(n_ledger, every) for _ in range(reps))
        rows.append(("ledger", f"no-op tasks, commit every {every}", f"{r:,.0f} tasks/s"))
        print(rows[-1], flush=True)
    ledger_rates = [float(r[2].split()[0].replace(",", "")) for r in rows]

    startup = statistics.median(bench_run("bench_farm:NoopProcessor", {}, 1, 1, 1)
                                for _ in range(reps))
    rows.append(("local", "start-up + 1 frame (1 worker)", f"{startup:.2f} s"))
    overheads = {}
    for chunk in (1, 16):
        wall = statistics.median(bench_run("bench_farm:NoopProcessor", {}, n_noop, 1, chunk)
                                 for _ in range(reps))
        per = (wall - startup) / n_noop
        overheads[chunk] = per
        rows.append(("local", f"no-op frames, chunk {chunk}, 1 worker",
                     f"{n_noop / wall:,.0f} frames/s; overhead {per * 1e3:.2f} ms/frame"))
        print(rows[-1], flush=True)

    load = os.getloadavg()[0]
    walls, speedups = {}, {}
    for kind, proc, n in (("CPU-bound filter", "bench_farm:FilterProcessor", n_cpu),
                          ("sleep 0.1 s", "bench_farm:SleepProcessor", n_cpu)):
        for w in (1, 2):
            per: list[float] = []
            walls[kind, w] = statistics.median(
                bench_run(proc, {"out": ""}, n, w, 2, per) for _ in range(reps))
            rows.append(("local", f"{kind}, {n} frames, {w} worker(s)",
                         f"{walls[kind, w]:.2f} s ({n / walls[kind, w]:.2f} frames/s, "
                         f"{statistics.median(per):.3f} s/frame inside the worker)"))
            print(rows[-1], flush=True)
        speedups[kind] = walls[kind, 1] / walls[kind, 2]
        rows.append(("local", f"speedup 1 -> 2 workers ({kind})", f"{speedups[kind]:.2f}x"))
    speedup = speedups["CPU-bound filter"]

    table = ["| part | measurement | result |", "|---|---|---|"]
    table += [f"| {p} | {m} | {r} |" for p, m, r in rows]
    text = "\n".join(table)
    print(text)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(12, 3.6))
    ax[0].bar(["commit/task", "commit/64"], ledger_rates, color=["#888", "#47a"])
    ax[0].axhline(1000, color="r", ls="--", label="target 1000/s")
    ax[0].set_ylabel("no-op tasks/s")
    ax[0].set_yscale("log")
    ax[0].legend()
    ax[0].set_title("ledger throughput")
    ax[1].bar([f"chunk {c}" for c in overheads], [v * 1e3 for v in overheads.values()],
              color="#47a")
    ax[1].set_ylabel("ms per frame")
    ax[1].set_title("scheduling overhead (no-op)")
    kinds = list(speedups)
    ax[2].bar(kinds, [speedups[k] for k in kinds], color=["#47a", "#7a4"])
    ax[2].axhline(2.0, color="r", ls="--", label="ideal 2x")
    ax[2].set_ylabel("speedup 1 -> 2 workers")
    ax[2].legend()
    ax[2].set_title(f"load avg {load:.1f} on {os.cpu_count()} cores")
    fig.tight_layout()
    png = RESULTS / "farm.png"
    with atomic.atomic_path(png) as tmp:
        fig.savefig(tmp, dpi=100)
    cmd = "nice -n 5 .venv/bin/python benchmarks/farm/bench_farm.py" + (" --quick" if a.quick else "")
    md = (f"# Farm benchmark\n\nProduced by `{cmd}` on {os.cpu_count()} shared CPU cores "
          f"(medians of {reps} repeats; 1-minute load average {load:.1f} from other users "
          f"during the run: timings are noisy on shared cores, compare ratios).\n\n"
          f"{text}\n\n![farm](../../benchmarks/results/farm.png)\n")
    write_doc("farm.md", md)
    print(f"wrote {png} and docs/benchmarks/farm.md")


if __name__ == "__main__":
    main()
