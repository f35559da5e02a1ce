"""The package's layout holds: no import cycles, experiments/ in layers, every task of the table resolves.

The import graph is read from the sources (every ``import`` and ``from ... import`` statement, inside functions
too: an import that hides a cycle in a function is still a cycle), at the level of files, as
``../shared/checks/import_cycles.py`` does; a package's ``__init__`` and its own submodules are not a cycle.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parent.parent / "src"
PACKAGE = "omnirotor"


def _modules() -> dict[str, Path]:
    out = {}
    for p in (SRC / PACKAGE).rglob("*.py"):
        parts = p.relative_to(SRC).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    return out


def _import_graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports (the longest existing prefix of each imported name)."""
    files = _modules()

    def known(name: str) -> str | None:
        while name and name not in files:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = defaultdict(set)
    for mod, path in files.items():
        is_pkg = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = mod.split(".") if is_pkg else mod.split(".")[:-1]
                    parts = parts[: len(parts) - node.level + 1]
                    base = ".".join([*parts, base] if base else parts)
                names = [base] + [f"{base}.{a.name}" for a in node.names]
            else:
                continue
            for name in names:
                target = known(name)
                if target is None or target == mod or not target.startswith(PACKAGE):
                    continue
                if mod.startswith(target + ".") and files[target].name == "__init__.py":
                    continue  # a module importing its own package
                if is_pkg and target.startswith(mod + "."):
                    continue  # a package importing its own submodules
                graph[mod].add(target)
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (iterative Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in sorted(set(graph) | {t for ts in graph.values() for t in ts}):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.get(root, ()))))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    x = stack.pop()
                    on.discard(x)
                    comp.append(x)
                    if x == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return sorted(out)


def test_the_cycle_finder_finds_a_cycle_hidden_in_a_function():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycles():
    cycles = _cycles(_import_graph())
    assert cycles == [], "import cycles: " + "; ".join(" <-> ".join(c) for c in cycles)


# experiments/: each layer imports only the layers before it (the package docstring's list).
LAYERS = [
    ("omnirotor.experiments.metrics",),
    ("omnirotor.experiments._loop", "omnirotor.experiments.loop", "omnirotor.experiments.figures"),
    ("omnirotor.experiments.faults",),
    ("omnirotor.experiments.tasks",),
    ("omnirotor.experiments.campaigns",),
    ("omnirotor.experiments.paper",),
    ("omnirotor.experiments.calibration",),
]


def _layer(mod: str) -> int | None:
    for i, prefixes in enumerate(LAYERS):
        if any(mod == p or mod.startswith(p + ".") for p in prefixes):
            return i
    return None


def test_experiments_layers_import_only_the_layers_before_them():
    graph = _import_graph()
    wrong = []
    for mod, targets in graph.items():
        lm = _layer(mod)
        for t in targets:
            lt = _layer(t)
            if lm is not None and lt is not None and lt > lm:
                wrong.append(f"{mod} -> {t}")
    assert wrong == []


def test_the_controller_and_the_simulator_never_import_each_other_nor_experiments():
    graph = _import_graph()
    for mod, targets in graph.items():
        for side, other in (("omnirotor.control", "omnirotor.sim"), ("omnirotor.sim", "omnirotor.control")):
            if mod.startswith(side):
                assert not any(t.startswith(other) for t in targets), (mod, targets)
        if mod.startswith(("omnirotor.control", "omnirotor.sim", "omnirotor.so3", "omnirotor.messages")):
            assert not any(t.startswith(("omnirotor.experiments", "omnirotor.cli")) for t in targets), mod
    assert graph.get("omnirotor.so3", set()) == set()


def test_every_task_of_the_table_resolves_to_a_function():
    from omnirotor.experiments.tasks import TASKS, task_function

    assert {"hover", "sliding", "peg-in-hole", "identify-dynamic"} <= set(TASKS)
    for name in TASKS:
        assert callable(task_function(name)), name
    from omnirotor.errors import InputError

    with pytest.raises(InputError, match="unknown task"):
        task_function("no-such-task")


def test_the_ground_floor_imports_nothing_of_the_package():
    """docs/architecture.md's ground floor: the real-time module among them, so that the PX4 bridge and the
    simulator take it without the controller (it lived in fly/node.py, which imports the controller)."""
    graph = _import_graph()
    ground = ("so3", "messages", "_jit", "errors", "limits", "realtime")
    assert {m: sorted(graph.get(f"omnirotor.{m}", ())) for m in ground} == {m: [] for m in ground}
