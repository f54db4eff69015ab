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

# every package and top-level module of teamslam, by layer: each may import only from layers
# below its own (the same layer: only itself)
LAYERS: list[set[str]] = [
    {"errors", "_lazy", "_version", "textio", "linalg", "staging", "_gaussian_kernels"},
    {"_optional"},
    {"parallel"},
    {"geometry"},
    {"gaussian", "graph", "testing"},
    {"association", "frontend", "dvi"},
    {"datasets"},
    {"sim", "ekf2d"},
    {"msckf"},
    {"runtime"},
    {"eval"},
    {"ros2"},
    {"viz"},
    {"live"},
    {"api"},
    {"paper"},
    {"cli", "__init__"},
    {"__main__"},
]
RANK = {name: rank for rank, layer in enumerate(LAYERS) for name in layer}

# msckf's rooms, lowest first; its top-level modules (agent, team, …) are the last room
MSCKF_ROOMS = ["settings", "filter", "objects", "consensus", "top"]


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


def test_every_package_has_a_layer():
    names = {p.stem if p.is_file() else p.name for p in ROOT.iterdir()}
    names = {n for n in names if not n.startswith((".", "__pycache__")) and n != "py"}
    modules = {n for n in names if (ROOT / n).is_dir() or (ROOT / f"{n}.py").exists()}
    assert modules <= set(RANK), sorted(modules - set(RANK))


def test_lower_layers_do_not_import_upper_ones():
    graph = package_graph()
    wrong = {
        (p, t)
        for p, targets in graph.items()
        for t in targets
        if RANK.get(t, -1) >= RANK[p] and t != p
    }
    assert not wrong, sorted(wrong)


def _msckf_room(module: str) -> str | None:
    parts = module.split(".")
    if parts[:2] != ["teamslam", "msckf"] or len(parts) < 3:
        return None
    return parts[2] if parts[2] in MSCKF_ROOMS else "top"


def test_msckf_rooms_import_downwards():
    """settings < filter < objects < consensus < the drivers (agent, team, centralised, …)."""
    rank = {room: k for k, room in enumerate(MSCKF_ROOMS)}
    wrong = []
    for path in (ROOT / "msckf").rglob("*.py"):
        parts = path.relative_to(ROOT / "msckf").parts
        own = parts[0] if len(parts) > 1 else "top"
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            for name in names:
                room = _msckf_room(name)
                if room is not None and rank[room] > rank[own]:
                    wrong.append(f"{path.relative_to(ROOT)} imports {name}")
    assert not wrong, wrong


def test_each_layer_imports_on_its_own_in_a_fresh_interpreter():
    modules = [
        "teamslam.msckf.consensus",
        "teamslam.msckf.consensus.protocol",
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
