"""The package's import graph: no cycles, and ``import surfnorm`` stays cheap.

The graph is read from the source (every ``import`` and ``from ... import`` statement, at module
level or inside a function, since a lazy import still ties two modules together, and the module
that a registry entry's ``kernel="surfnorm.kernels.<module>.<function>"`` names, which its run
imports), so a cycle is found whether or not any test happens to execute the import.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted((SRC / "surfnorm").rglob("*.py"))}


def _resolve(current: str, is_package: bool, level: int, target: str | None) -> str:
    if level == 0:
        return target or ""
    base = current.split(".") if is_package else current.split(".")[:-1]
    base = base[: len(base) - (level - 1)]
    return ".".join(base + ([target] if target else []))


def import_graph() -> dict[str, set[str]]:
    """surfnorm module -> the surfnorm modules it imports (a name imported from a package counts as its
    submodule when there is one)."""
    modules = _modules()
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        is_package = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.keyword) and node.arg == "kernel" and isinstance(node.value, ast.Constant):
                # a registry entry's kernel="surfnorm.kernels.<module>.<function>": its run imports that module
                targets = [str(node.value.value).rpartition(".")[0]]
            elif isinstance(node, ast.ImportFrom):
                base = _resolve(name, is_package, node.level, node.module)
                subs = [f"{base}.{alias.name}" for alias in node.names if f"{base}.{alias.name}" in modules]
                targets = subs or [base]
                if subs and len(subs) < len(node.names):
                    targets.append(base)
            for target in targets:
                if target in modules and target != name:
                    graph[name].add(target)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of the graph as a list of modules (first == last), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node):
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt) :] + [nxt]
            if nxt not in state:
                found = visit(nxt)
                if found:
                    return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return None


def test_no_import_cycle_in_src():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_cycle_finder_finds_a_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}
    assert find_cycle(graph) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


@pytest.mark.slow
def test_graph_sees_lazy_and_relative_imports():
    graph = import_graph()
    # methods.py imports each kernel when it first runs it (the module its entry's kernel= names)
    assert "surfnorm.kernels.translate" in graph["surfnorm.methods"]
    assert "surfnorm.kernels.sda" in graph["surfnorm.methods"]
    # the kernels import their shared settings from the level above
    assert "surfnorm._config" in graph["surfnorm.kernels.translate"]


@pytest.mark.slow
def test_kernels_never_import_the_registry_or_the_front_door():
    graph = import_graph()
    for name, targets in graph.items():
        if name.startswith("surfnorm.kernels"):
            bad = {t for t in targets if t in ("surfnorm", "surfnorm.methods", "surfnorm._api", "surfnorm.cli")}
            assert not bad, f"{name} imports {sorted(bad)}"


@pytest.mark.slow
@pytest.mark.parametrize("heavy", ["numba", "torch", "dask", "distributed", "cv2", "open3d"])
def test_import_surfnorm_loads_no_heavy_dependency(heavy):
    code = f"import sys, surfnorm; surfnorm.methods(); assert {heavy!r} not in sys.modules, 'imported'"
    subprocess.run([sys.executable, "-c", code], check=True, env={"PYTHONPATH": str(SRC)})
