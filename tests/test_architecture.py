"""Layering rules: the controller talks to a plant only through omnirotor.messages (STYLE rule 2).

* no module of ``omnirotor.control`` imports ``mujoco``, ``omnirotor.sim`` or ``omnirotor.experiments``;
* no module of ``omnirotor.sim`` imports ``omnirotor.control``.

Imports are read with :mod:`ast` (also those inside functions), including relative ones.
"""

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "omnirotor"


def _imported_modules(path: Path, package: str) -> set[str]:
    """Absolute names of every module imported anywhere in ``path`` (package = the file's package)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                prefix = ".".join(base)
                mod = f"{prefix}.{node.module}" if node.module else prefix
            else:
                mod = node.module or ""
            names.add(mod)
            names.update(f"{mod}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Call):
            # importlib.import_module("...") / __import__("...") with a literal name
            func = node.func
            fname = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if fname in ("import_module", "__import__") and node.args and isinstance(node.args[0], ast.Constant):
                names.add(str(node.args[0].value))
    return names


def _modules(subpackage: str) -> list[Path]:
    root = SRC / subpackage
    return sorted(root.rglob("*.py")) if root.is_dir() else []


def _violations(subpackage: str, forbidden: tuple[str, ...]) -> list[str]:
    bad = []
    for path in _modules(subpackage):
        rel = path.relative_to(SRC.parent).with_suffix("")
        package = ".".join(rel.parts[:-1])  # a module's package; for __init__.py, the package itself
        for name in _imported_modules(path, package):
            if any(name == f or name.startswith(f + ".") for f in forbidden):
                bad.append(f"{path.relative_to(SRC.parent)} imports {name}")
    return sorted(set(bad))


def test_helper_resolves_relative_imports(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("from ..sim import scenes\nfrom . import x\nimport mujoco.viewer\n")
    names = _imported_modules(f, "omnirotor.control")
    assert "omnirotor.sim" in names and "omnirotor.sim.scenes" in names
    assert "omnirotor.control.x" in names and "mujoco.viewer" in names


def test_control_package_exists():
    assert _modules("control"), "src/omnirotor/control has no modules"


def test_control_never_imports_the_simulator():
    bad = _violations("control", ("mujoco", "omnirotor.sim", "omnirotor.experiments"))
    assert not bad, "\n".join(bad)


def test_simulator_never_imports_the_controller():
    if not _modules("sim"):
        pytest.skip("omnirotor.sim not present")
    bad = _violations("sim", ("omnirotor.control",))
    assert not bad, "\n".join(bad)
