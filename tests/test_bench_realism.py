"""benchmarks/realism/bench_realism.py's tables: objects of the library set pair with the procedural
set's by frame, slot, class and place, and the default per class follows the paired difference."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("bench_realism", ROOT / "benchmarks" / "realism" / "bench_realism.py")
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)


def row(frame, oid, cls, found, pos=(10.0, 1.0, 0.0), asset=None, h=100, source="a"):
    return {"frame": frame, "id": oid, "cls": cls, "h": h, "position": list(pos), "yaw": 0.0, "asset": asset,
            "source": source, "scores": {bench.DEFAULT_VARIANT: 0.8 if found else 0.0}}


def test_library_objects_pair_with_the_procedural_ones_planned_alike():
    proc = [row("u/f1", 1, "car", True), row("u/f1", 2, "bus", True), row("u/f2", 1, "bus", True)]
    lib = [row("u/f1", 1, "car", False, asset="prius.obj"), row("u/f1", 2, "bus", False, pos=(30, 1, 0), asset="bus.obj"),
           row("u/f2", 1, "truck", True)]
    pr = bench.pairs(proc, lib)
    assert [(a["id"], b["asset"]) for a, b in pr] == [(1, "prius.obj")]  # the bus moved, the truck is another class


def test_default_per_class_is_the_library_only_where_it_is_measurably_better():
    def sets(n):
        proc, lib = [], []
        for k in range(n):
            proc += [row(f"u/f{k}", 1, "car", k < n // 2), row(f"u/f{k}", 2, "bus", True),
                     row(f"u/f{k}", 3, "person", True)]
            lib += [row(f"u/f{k}", 1, "car", k < n - 2, asset="prius.obj"), row(f"u/f{k}", 2, "bus", k < 3, asset="bus.obj"),
                    row(f"u/f{k}", 3, "person", True)]  # no library person: stays procedural
        return proc, lib

    proc, lib = sets(30)
    d = bench.choose_defaults(proc, lib, bench.DEFAULT_VARIANT)
    assert d["car"] == "library" and d["bus"] == "procedural" and d["person"] == "procedural"
    m, lo, hi = bench.paired_diff([(a, b) for a, b in bench.pairs(proc, lib) if a["cls"] == "car"], bench.DEFAULT_VARIANT)
    assert abs(m - 13 / 30) < 1e-9 and 0 < lo <= m <= hi
    # the same lead on fewer paired objects than MIN_PAIRS decides nothing
    assert bench.choose_defaults(*sets(bench.MIN_PAIRS - 2), bench.DEFAULT_VARIANT)["car"] == "procedural"
