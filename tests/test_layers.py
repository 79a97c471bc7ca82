"""Layers only point down (docs/architecture.md, "Layers").

Every module under blendgen/ is read with `ast` (nothing is imported), function-level
imports included. A module may import its own unit (top-level module or package) and any
unit of a lower layer; the foundation's units may also import each other. The stages are
peers: one stage never imports another, what two stages share lives in the foundation.
No modules import each other in a circle, directly or through others.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "blendgen"

# Lowest first. A unit is blendgen's top-level module or package ("blendgen": its __init__).
LAYERS: list[tuple[str, set[str]]] = [
    ("foundation", {"blendgen", "errors", "atomic", "validation", "geometry", "so3", "farm",
                    "job", "recording", "twin", "plan", "frame_analysis", "frame_labels",
                    "ground", "lane_geometry", "vo", "detection", "dimensions", "geom2d"}),
    ("stages", {"sync", "analysis", "scene", "post", "labels", "train", "eval"}),
    ("render/report", {"render", "report"}),
    ("pipeline", {"pipeline"}),
    ("cli", {"cli"}),
]
LAYER_OF = {unit: i for i, (_, units) in enumerate(LAYERS) for unit in units}


def modules() -> dict[str, Path]:
    out = {}
    for p in sorted(ROOT.rglob("*.py")):
        parts = list(p.relative_to(ROOT.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def imports(name: str, path: Path, known: set[str]) -> set[str]:
    """The blendgen modules `name` imports (a package when the name is not a module)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
                pkg = pkg[:len(pkg) - (node.level - 1)]
                base = ".".join(pkg + ([node.module] if node.module else []))
            for a in node.names:
                sub = f"{base}.{a.name}"
                found.add(sub if sub in known else base)
    return {m for m in found if m == "blendgen" or m.startswith("blendgen.")}


def unit(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "blendgen"


def graph() -> dict[str, set[str]]:
    mods = modules()
    return {m: imports(m, p, set(mods)) for m, p in mods.items()}


def test_every_unit_has_a_layer():
    units = {unit(m) for m in modules()}
    assert not units - set(LAYER_OF), f"units without a layer (add them to LAYERS and docs/architecture.md): " \
                                      f"{sorted(units - set(LAYER_OF))}"


def test_imports_only_point_down():
    bad = []
    for m, targets in sorted(graph().items()):
        u = unit(m)
        for t in sorted(targets):
            v = unit(t)
            lu, lv = LAYER_OF.get(u), LAYER_OF.get(v)
            if u == v or lu is None or lv is None or lv < lu or lu == lv == 0:
                continue
            how = "a peer (sideways)" if lv == lu else "a higher layer"
            bad.append(f"{m} ({LAYERS[lu][0]}) imports {t} ({LAYERS[lv][0]}): {how}")
    assert not bad, "imports that do not point down:\n  " + "\n  ".join(bad)


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index, low, on, stack, out = {}, {}, set(), [], []
    for start in edges:
        if start in index:
            continue
        work = [(start, iter(sorted(edges[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on.add(start)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in edges:
                    continue
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(edges[w]))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def test_no_import_circles():
    found = cycles(graph())
    assert not found, "modules that import each other in a circle:\n  " + "\n  ".join(" <-> ".join(c) for c in found)


def test_the_checks_see_upward_sideways_and_lazy_imports(tmp_path):
    """The reader itself: a relative, a lazy and a plain import are all found."""
    pkg = tmp_path / "blendgen" / "analysis"
    pkg.mkdir(parents=True)
    (pkg / "x.py").write_text("from .y import z\n\ndef f():\n    from blendgen.render import session\n"
                              "    import blendgen.scene.planner\n")
    known = {"blendgen.analysis.y", "blendgen.render.session", "blendgen.scene.planner"}
    assert imports("blendgen.analysis.x", pkg / "x.py", known) == known
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
