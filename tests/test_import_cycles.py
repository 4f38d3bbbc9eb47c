"""No import cycles among the modules of grids, matching, graph, backends, io, localization and eval.

Every module under ``src/slam2d`` is parsed with :mod:`ast` (nothing is imported) and every
``import`` / ``from ... import`` in it counts, wherever it is: at the top, inside a function (a lazy
import) or under ``if TYPE_CHECKING:``. Relative imports are resolved. ``from slam2d.x import y``
is a dependency on ``slam2d.x`` and, when ``slam2d.x.y`` is a module, on it too; a package is its
``__init__`` module, and those are kept in the graph (no package re-export makes a cycle through
these folders today). The graph holds every slam2d module, so a cycle that passes through a module
elsewhere (``methods``, ``cli``...) is caught when one of its modules is in these folders.

``KNOWN_EDGES`` are left out of the graph, each with the reason; remove one when it is fixed.
"""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
FOLDERS = ("grids", "matching", "graph", "backends", "io", "localization", "eval")

#: (importer, imported) edges not counted yet (none now).
KNOWN_EDGES: set[tuple[str, str]] = set()


def _modules(src: Path, package: str) -> dict[str, tuple[Path, bool]]:
    """Every module of ``package`` under ``src``: dotted name -> (file, is a package)."""
    modules = {}
    for path in sorted((src / package).rglob("*.py")):
        parts = list(path.relative_to(src).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts = parts[:-1]
        modules[".".join(parts)] = (path, is_package)
    return modules


def _owner(name: str, modules: dict) -> str | None:
    """The module ``name`` is, or the innermost one holding it (``slam2d.x.Thing`` -> ``slam2d.x``)."""
    while name not in modules and "." in name:
        name = name.rpartition(".")[0]
    return name if name in modules else None


def import_graph(src: Path = SRC, package: str = "slam2d") -> dict[str, set[str]]:
    """Module -> the modules of ``package`` it imports anywhere in its file."""
    modules = _modules(src, package)
    graph = {}
    for name, (path, is_package) in modules.items():
        here = name if is_package else name.rpartition(".")[0]
        targets = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if isinstance(node, ast.Import):
                targets.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = here.split(".")[: len(here.split(".")) - (node.level - 1)]
                    source = ".".join(base + ([node.module] if node.module else []))
                else:
                    source = node.module or ""
                targets.add(source)
                targets.update(f"{source}.{a.name}" for a in node.names if f"{source}.{a.name}" in modules)
        deps = {_owner(t, modules) for t in targets if t == package or t.startswith(package + ".")}
        graph[name] = {d for d in deps if d is not None and d != name and (name, d) not in KNOWN_EDGES}
    return graph


def _strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components of more than one module (iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def _a_cycle(graph: dict[str, set[str]], component: list[str]) -> list[str]:
    """A shortest cycle through the component's first module (breadth-first)."""
    inside = set(component)
    start = component[0]
    came_from = {start: None}
    queue = [start]
    for v in queue:
        for w in sorted(graph[v] & inside):
            if w == start:
                path = [v]
                while came_from[path[-1]] is not None:
                    path.append(came_from[path[-1]])
                return [*reversed(path), start]
            if w not in came_from:
                came_from[w] = v
                queue.append(w)
    return component  # not reached: a component of two or more modules has a cycle through each


def _in_folders(module: str) -> bool:
    return any(module == f"slam2d.{f}" or module.startswith(f"slam2d.{f}.") for f in FOLDERS)


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    return [_a_cycle(graph, c) for c in _strongly_connected(graph)]


def test_lazy_type_checking_and_relative_imports_count(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "a.py").write_text("def f():\n    from pkg.b import g\n")
    (pkg / "b.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg.sub import c\n")
    (pkg / "sub" / "c.py").write_text("from .. import a\n")
    (pkg / "d.py").write_text("import pkg.a\n")
    graph = import_graph(tmp_path, "pkg")
    assert graph["pkg.a"] == {"pkg.b"}
    assert graph["pkg.b"] == {"pkg.sub", "pkg.sub.c"}
    assert graph["pkg.sub.c"] == {"pkg", "pkg.a"}
    assert graph["pkg.d"] == {"pkg.a"}
    assert _cycles(graph) == [["pkg.a", "pkg.b", "pkg.sub.c", "pkg.a"]]


def test_no_import_cycles():
    graph = import_graph()
    found = [c for c in _strongly_connected(graph) if any(_in_folders(m) for m in c)]
    report = [" -> ".join(_a_cycle(graph, c)) + (f"  (all of: {', '.join(c)})" if len(c) > 2 else "") for c in found]
    assert not found, "import cycles (one per group of modules that import each other):\n" + "\n".join(report)
