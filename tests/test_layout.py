"""The layout's rules, checked on the source: no import circles, the engine never imports the app
or viser, and modules stay small (the Numba kernels excepted)."""

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


def test_no_import_circles():
    known = modules()
    graph = {m: imports_of(m, f, known) for m, f in known.items()}
    assert cycles(graph) == []


def test_the_cycle_finder_finds_a_circle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


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
