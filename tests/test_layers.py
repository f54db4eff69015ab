"""Layers import downwards only: no import cycle between teamslam's packages.

Every ``import``/``from … import`` of every module (module level and inside functions, since a
deferred import is still a dependency) is mapped to the package it names; the graph of packages
must be acyclic, and the lower layers must not reach the ones above them.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import teamslam

ROOT = Path(teamslam.__file__).parent

# each package and the packages it must never import (the layers above it)
FORBIDDEN = {
    "geometry": {"gaussian", "graph", "dvi", "msckf", "ekf2d", "runtime", "eval", "cli"},
    "gaussian": {"graph", "dvi", "msckf", "ekf2d", "runtime", "eval", "cli"},
    "graph": {"dvi", "msckf", "ekf2d", "runtime", "eval", "cli"},
    "msckf": {"runtime", "eval", "cli", "ros2"},
    "datasets": {"msckf", "runtime", "eval", "cli"},
    "runtime": {"cli"},
    "eval": {"cli"},
}


def _package(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "teamslam" or len(parts) < 2:
        return None
    return parts[1]


def _own_package(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    return rel.parts[0]


def package_graph() -> dict[str, set[str]]:
    """``{package: {packages it imports}}`` over every module of teamslam."""
    graph: dict[str, set[str]] = defaultdict(set)
    for path in ROOT.rglob("*.py"):
        own = _own_package(path)
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            for name in names:
                target = _package(name)
                if not target or target == own:
                    continue
                if (ROOT / target).is_dir() or (ROOT / f"{target}.py").exists():
                    graph[own].add(target)
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return [*stack[stack.index(nxt) :], nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_no_import_cycle_between_packages():
    graph = package_graph()
    assert graph["runtime"] >= {"msckf"}  # the graph is really built
    cycle = _cycle(graph)
    assert cycle is None, " → ".join(cycle)


def test_the_cycle_finder_finds_cycles():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": {"c"}}) is None


def test_lower_layers_do_not_import_upper_ones():
    graph = package_graph()
    wrong = {p: graph.get(p, set()) & above for p, above in FORBIDDEN.items()}
    assert not any(wrong.values()), {p: sorted(w) for p, w in wrong.items() if w}


def test_each_layer_imports_on_its_own_in_a_fresh_interpreter():
    modules = [
        "teamslam.msckf.consensus",
        "teamslam.msckf.protocol",
        "teamslam.runtime",
        "teamslam.runtime.wire",
        "teamslam.cli",
    ]
    code = "import importlib, sys\nfor m in sys.argv[1:]:\n    importlib.import_module(m)\n"
    for module in modules:
        done = subprocess.run(
            [sys.executable, "-c", code, module], capture_output=True, text=True, timeout=120
        )
        assert done.returncode == 0, done.stderr
