"""The layout's rules, checked on the source: no import circles (between modules, and between the
engine's subpackages and its root modules), the engine never imports the app or viser, the product
never imports a benchmark or test harness, and modules stay small (the Numba kernels excepted)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("splat_core", "app")
# Numba kernels: one file per kernel family, long by nature (docs/design.md).
LONG_ALLOWED = {"splat_core/render/cpu.py", "splat_core/render/project_cpu.py"}
MAX_LINES = 360


def modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for f in (ROOT / pkg).rglob("*.py"):
            parts = list(f.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = f
    return out


def imports_of(name: str, path: Path, known: dict) -> set[str]:
    """Modules of ours that `name` imports anywhere in its file (function-level imports too)."""
    base = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            candidates = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            prefix = ".".join(base[:len(base) - node.level + 1] + ([node.module] if node.module else [])) \
                if node.level else node.module
            names = [f"{prefix}.{a.name}" for a in node.names]
            # `from . import a, b` of submodules imports the modules, not something of the package
            candidates = names + ([] if all(n in known for n in names) else [prefix])
        else:
            continue
        found.update(c for c in candidates if c in known and c != name)
    return found


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))
    for v in graph:
        if v not in index:
            visit(v)
    return out


def unit(name: str, known: dict) -> str:
    """An engine module's place in the package view: its subpackage (splat_core.loop.verify ->
    splat_core.loop), or the module itself at the root (splat_core.slam)."""
    parts = name.split(".")
    is_package = name in known and known[name].name == "__init__.py"
    return ".".join(parts[:2]) if len(parts) > 2 or (len(parts) == 2 and is_package) else name


def package_graph(graph: dict[str, set[str]], known: dict) -> dict[str, set[str]]:
    """The engine's import graph with each subpackage collapsed to one node."""
    out: dict[str, set[str]] = {}
    for name, imported in graph.items():
        if name.startswith("splat_core."):
            here = unit(name, known)
            out.setdefault(here, set()).update(unit(i, known) for i in imported
                                               if i.startswith("splat_core.") and unit(i, known) != here)
    for targets in list(out.values()):
        for t in targets:
            out.setdefault(t, set())
    return out


def test_no_import_circles():
    known = modules()
    graph = {m: imports_of(m, f, known) for m, f in known.items()}
    assert cycles(graph) == []


def test_the_cycle_finder_finds_a_circle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_circles_between_the_engines_packages():
    """Nothing imports up the graph: a subpackage that a root module uses (render/, loop/, align/)
    never imports that root module back, not even from a module the root one never loads."""
    known = modules()
    graph = {m: imports_of(m, f, known) for m, f in known.items()}
    assert cycles(package_graph(graph, known)) == []


def test_the_package_view_finds_an_upward_import():
    # loop/evaluate.py (a harness then in the product) imported slam.py, which imports loop/: no
    # circle between modules, one between slam and its loop package.
    graph = {"splat_core.slam": {"splat_core.loop.closer"}, "splat_core.loop.closer": set(),
             "splat_core.loop.evaluate": {"splat_core.slam"}}
    known = {name: Path(name.replace(".", "/") + ".py") for name in graph}
    assert cycles(graph) == []
    assert cycles(package_graph(graph, known)) == [["splat_core.loop", "splat_core.slam"]]


def test_the_product_imports_no_harness():
    """Benchmark and test helpers (benchmarks/*.py, tests/helpers/) stay out of splat_core and app."""
    harnesses = {f.stem for f in (ROOT / "benchmarks").glob("*.py")} | {"benchmarks", "tests", "helpers", "conftest"}
    for name, path in modules().items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                tops = {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                tops = {node.module.split(".")[0]}
            else:
                continue
            assert not tops & harnesses, (name, tops & harnesses)


def test_the_engine_imports_neither_the_app_nor_viser():
    known = modules()
    for name, path in known.items():
        if not name.startswith("splat_core"):
            continue
        text = path.read_text()
        assert not any(m.startswith("app") for m in imports_of(name, path, known)), name
        assert "import viser" not in text and "from viser" not in text, name


def test_modules_stay_small():
    long = {str(f.relative_to(ROOT)): len(f.read_text().splitlines()) for f in modules().values()}
    assert {f: n for f, n in long.items() if n > MAX_LINES and f not in LONG_ALLOWED} == {}
