"""The import graph points one way: onboard core <- simulator <- offline analysis (issue 24).

Layers (a module may import its own layer and those below it, never above):

0. **core**, what runs on a robot: ``terrain_estimation`` filters, models,
   estimators, ROS nodes and adapters, bag I/O, parameters, the consistency
   statistics, and ``terrain-estimate`` (the offline runner of the nodes).
1. **simulator**: ``vehicle_sim`` (plants, terrain, effects, simulator nodes
   and tools). It may use the core's shared geometry and kinematics, its
   parameter specs and its node framework.
2. **offline analysis**, the package ``terrain_analysis`` (beside the core in
   ``src/terrain_estimation``): sim-to-real diagnosis, fleet batch runs,
   reproductions, benchmarks, validation, the demo, the config generator (it
   writes the simulator's sections too) and the information bounds (they
   simulate the truth).

Every import counts, at module level or inside a function (a lazy import is
still a dependency). The graph is read from the source with :mod:`ast`, so
the check needs neither package importable.

Three checks: no back edge between layers, no cycle between modules, no cycle
between packages (a package is a directory: ``terrain_estimation.ros``,
``vehicle_sim.plants``; a top-level module such as ``terrain_estimation.bag``
is its own package). What the tree held when the check was written is listed
in the ``KNOWN_*`` sets: the lists may only shrink (an entry that no longer
holds fails too, so that it is removed), and anything new fails.

Run ``python test/test_import_graph.py`` to print the package graph.
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCES = (ROOT / "src" / "terrain_estimation", ROOT / "src" / "vehicle_sim")
TOP_LEVEL = ("terrain_estimation", "terrain_analysis", "vehicle_sim")

#: Back edges present when the check was written (issue 24 removes them).
KNOWN_BACK_EDGES: frozenset[tuple[str, str]] = frozenset()
#: Module cycles present when the check was written (each as a sorted tuple).
KNOWN_MODULE_CYCLES: frozenset[tuple[str, ...]] = frozenset()
#: Package cycles present when the check was written (each as a sorted tuple).
KNOWN_PACKAGE_CYCLES: frozenset[tuple[str, ...]] = frozenset()


def modules() -> dict[str, Path]:
    """Every module of the two packages: dotted name -> file."""
    out: dict[str, Path] = {}
    for root in SOURCES:
        for path in root.rglob("*.py"):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            if parts and parts[0] in TOP_LEVEL:
                out[".".join(parts)] = path
    return out


def _resolve(name: str, known: Mapping[str, Path]) -> str | None:
    """The module of ours that ``import name`` loads (the longest known prefix), or None."""
    while name and name not in known:
        name = name.rpartition(".")[0]
    return name or None


def imports(known: Mapping[str, Path]) -> dict[str, set[str]]:
    """module -> the modules of ours it imports (anywhere in its source)."""
    graph: dict[str, set[str]] = {}
    for module, path in known.items():
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    base = ".".join([*anchor, base] if base else anchor)
                # ``from pkg import mod`` imports pkg.mod; ``from mod import name`` imports mod
                names = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
            else:
                continue
            for name in names:
                target = _resolve(name, known)
                if target is not None and target != module:
                    found.add(target)
        graph[module] = found
    return graph


def layer(module: str) -> int:
    """0 core, 1 simulator, 2 offline analysis."""
    if module.startswith("terrain_analysis"):
        return 2
    if module.startswith("vehicle_sim"):
        return 1
    return 0


def package_of(module: str, known: Mapping[str, Path]) -> str:
    """The directory a module lives in (a package's ``__init__`` belongs to the package itself)."""
    if known[module].name == "__init__.py" or module.count(".") < 1:
        return module
    parent = module.rpartition(".")[0]
    return module if parent in TOP_LEVEL else parent


def strongly_connected(graph: Mapping[str, Iterable[str]]) -> list[tuple[str, ...]]:
    """Tarjan's strongly connected components of more than one node, each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[tuple[str, ...]] = []
    counter = 0
    nodes = sorted(set(graph) | {w for ws in graph.values() for w in ws})

    def visit(v: str) -> None:
        nonlocal counter
        index[v] = low[v] = counter
        counter += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(tuple(sorted(component)))

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(nodes) + 100))
    try:
        for v in nodes:
            if v not in index:
                visit(v)
    finally:
        sys.setrecursionlimit(limit)
    return out


def package_graph(graph: Mapping[str, set[str]], known: Mapping[str, Path]) -> dict[str, set[str]]:
    """package -> the packages it imports."""
    out: dict[str, set[str]] = {}
    for module, targets in graph.items():
        a = package_of(module, known)
        for target in targets:
            b = package_of(target, known)
            if a != b:
                out.setdefault(a, set()).add(b)
    return out


def render(packages: Mapping[str, set[str]]) -> str:
    """The package graph as text, one package a line, with its layer."""
    return "\n".join(f"[{layer(p)}] {p} -> {', '.join(sorted(packages[p]))}" for p in sorted(packages))


def _check_known(found: set[tuple[str, ...]] | set[tuple[str, str]], known: frozenset, what: str, graph: str) -> None:
    new = sorted(found - known)
    gone = sorted(known - found)
    assert not new, f"new {what} (the graph must point one way: core <- simulator <- analysis): {new}\n{graph}"
    assert not gone, f"{what} listed as known no longer exist: remove them from the test's list: {gone}"


def test_no_back_edge_between_layers() -> None:
    known = modules()
    graph = imports(known)
    back = {(m, t) for m, targets in graph.items() for t in targets if layer(t) > layer(m)}
    _check_known(back, KNOWN_BACK_EDGES, "back edges", render(package_graph(graph, known)))


def test_no_cycle_between_modules() -> None:
    known = modules()
    graph = imports(known)
    _check_known(set(strongly_connected(graph)), KNOWN_MODULE_CYCLES, "module cycles", "")


def test_no_cycle_between_packages() -> None:
    known = modules()
    packages = package_graph(imports(known), known)
    _check_known(set(strongly_connected(packages)), KNOWN_PACKAGE_CYCLES, "package cycles", render(packages))


_BLOCKER = """
import importlib, importlib.abc, sys
BLOCKED = {blocked!r}
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if any(name == b or name.startswith(b + ".") for b in BLOCKED):
            raise ImportError(f"{{name}} is not installed (core-only check)")
        return None
sys.meta_path.insert(0, Block())
for module in {modules!r}:
    importlib.import_module(module)
print("imported", len({modules!r}), "core modules")
"""


def test_the_core_imports_without_the_simulator_and_the_analysis() -> None:
    """Every core module imports with ``vehicle_sim`` and the analysis modules made unimportable."""
    import subprocess

    known = modules()
    leaning = {source for source, _ in KNOWN_BACK_EDGES}
    core = sorted(m for m in known if layer(m) == 0 and m not in leaning)
    blocked = sorted({"vehicle_sim", *(m for m in known if layer(m) == 2)})
    script = _BLOCKER.format(blocked=blocked, modules=core)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    assert f"imported {len(core)} core modules" in done.stdout


def test_the_checker_sees_a_back_edge_and_a_cycle(tmp_path: Path) -> None:
    """The graph reader finds absolute, relative and lazy imports, and a cycle."""
    pkg = tmp_path / "terrain_estimation"
    (pkg / "filters").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "filters" / "__init__.py").write_text("from . import ukf\n")
    (pkg / "filters" / "ukf.py").write_text("def f():\n    from terrain_analysis.tools.bench import x\n")
    ana = tmp_path / "terrain_analysis"
    (ana / "tools").mkdir(parents=True)
    (ana / "__init__.py").write_text("")
    (ana / "tools" / "__init__.py").write_text("")
    (ana / "tools" / "bench.py").write_text(
        "from terrain_estimation.filters.ukf import f\nfrom . import __name__ as n\nx = 1\n"
    )
    known = {
        "terrain_estimation": pkg / "__init__.py",
        "terrain_estimation.filters": pkg / "filters" / "__init__.py",
        "terrain_estimation.filters.ukf": pkg / "filters" / "ukf.py",
        "terrain_analysis": ana / "__init__.py",
        "terrain_analysis.tools": ana / "tools" / "__init__.py",
        "terrain_analysis.tools.bench": ana / "tools" / "bench.py",
    }
    graph = imports(known)
    assert graph["terrain_estimation.filters"] == {"terrain_estimation.filters.ukf"}
    assert graph["terrain_estimation.filters.ukf"] == {"terrain_analysis.tools.bench"}
    assert graph["terrain_analysis.tools.bench"] == {"terrain_estimation.filters.ukf", "terrain_analysis.tools"}
    assert layer("terrain_analysis.tools.bench") > layer("vehicle_sim.plants") > layer("terrain_estimation.filters.ukf")
    assert strongly_connected(graph) == [("terrain_analysis.tools.bench", "terrain_estimation.filters.ukf")]


if __name__ == "__main__":
    _known = modules()
    print(render(package_graph(imports(_known), _known)))
