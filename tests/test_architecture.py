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


# -- compiled state as named records (issue 11, STYLE rule 13) ----------------------------------------------------

_PACKED_LAYOUTS = {"omnirotor.sim.step": "TRUTH_ROW_"}
"""Flat layouts that stay flat, each owned by one module: the simulator's truth log row. Its constants may index
arrays; no other constant may (the sensor frame and the estimate are records: :mod:`omnirotor.messages`)."""


def _int_constants(tree: ast.Module) -> set[str]:
    """Upper-case module-level names bound to an integer expression (literals and such names)."""
    out = set()
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            name = node.targets[0].id
            if name.lstrip("_").isupper():
                parts = list(ast.walk(node.value))
                allowed = (ast.BinOp, ast.UnaryOp, ast.Name, ast.Constant, ast.operator, ast.unaryop, ast.Load)
                if all(isinstance(n, allowed) for n in parts) and all(
                    type(n.value) is int for n in parts if isinstance(n, ast.Constant)
                ):
                    out.add(name)
    return out


def _constants_indexing(path: Path, package: str) -> set[str]:
    """Integer constants (the module's own or imported ones) used inside a subscript's index in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    own = {name: package for name in _int_constants(tree)}
    imported = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            for alias in node.names:
                if alias.name.lstrip("_").isupper():
                    imported[alias.asname or alias.name] = node.module
    known = {**imported, **own}
    hits = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Subscript):
            for n in ast.walk(node.slice):
                if isinstance(n, ast.Name) and n.id in known:
                    hits.add(f"{known[n.id]}.{n.id}")
                elif isinstance(n, ast.Attribute) and n.attr.lstrip("_").isupper():  # module.CONSTANT
                    hits.add(f"?.{n.attr}")
    return hits


def test_no_integer_offset_indexes_compiled_state():
    """Blocks of the controller and the simulator read their state by field name, never ``x[UKF_S + 6]``."""
    bad = []
    for sub in ("control", "sim"):
        for path in _modules(sub):
            package = ".".join(path.relative_to(SRC.parent).with_suffix("").parts)
            for hit in _constants_indexing(path, package):
                owner, name = hit.rsplit(".", 1)
                if not any(owner == mod and name.startswith(prefix) for mod, prefix in _PACKED_LAYOUTS.items()):
                    bad.append(f"{path.relative_to(SRC.parent)}: {hit}")
    assert not bad, bad


def test_offset_check_finds_an_offset(tmp_path):
    """The check above is not vacuous: it finds a constant used as an offset, imported or the module's own."""
    f = tmp_path / "m.py"
    f.write_text(
        "from omnirotor.x import Y_Z\nUKF_S = 0\nUKF_F = UKF_S + 16\n\ndef k(x):\n    return x[UKF_F + 6] + x[Y_Z]\n"
    )
    assert _constants_indexing(f, "pkg.m") == {"pkg.m.UKF_F", "omnirotor.x.Y_Z"}


def test_estimator_and_scheduler_state_are_named_records():
    """The UKF and the map scheduler keep their state in structured records that their kernels read by name."""
    from omnirotor.control import _estimator_kernels as ek
    from omnirotor.control import _map_kernels as mk
    from omnirotor.control.composer import ControllerSizes, controller_dtype
    from omnirotor.control.estimator import UKFEstimator
    from omnirotor.control.maps import MapScheduler
    from omnirotor.control.observer import STATE_DTYPE as OBSERVER_DTYPE

    assert UKFEstimator.state_dtype is ek.UKF_DTYPE and MapScheduler.state_dtype is mk.STATE_DTYPE
    assert "n_nonfinite" in ek.UKF_DTYPE.names and "n_nonfinite" in mk.STATE_DTYPE.names
    # The flat layouts are gone: no offset constants, no layout functions.
    assert not any(hasattr(ek, name) for name in ("UKF_S", "UKF_SIZE", "WP_L", "WF_R", "CNT_SIZE", "memory_layout"))
    assert not any(hasattr(mk, name) for name in ("SCH_HEADER", "REG_EL_LO", "STATE_REGION", "region_stride"))
    # Nested into the controller's state under the registered names.
    ctl = controller_dtype(OBSERVER_DTYPE, ControllerSizes(8, 40, 10, 3, 600))
    assert ctl["ukf"] == ek.UKF_DTYPE and ctl["maps"] == mk.STATE_DTYPE
    # Their sized arrays are subarray fields of the same record (no addresses, no arrays beside it).
    assert ctl["ukf_memory"]["imu_buf"].shape == (40,) and ctl["maps_arrays"]["az_lo_rad"].shape == (10, 3)
    assert ctl["allocation_arrays"]["H"].shape == (8, 8) and ctl["trajectory_data"].shape == (600,)
    assert "arrays" not in ctl.names
    # The kernels' sources read fields as attributes of their records (u.x_out, st.region), never by offset.
    for module, fields in ((ek, ("u.x_out", "u.P", "w.sigma_R_WB", "u.k_fused")), (mk, ("st.region", "r.n_az"))):
        text = Path(module.__file__).read_text(encoding="utf-8")
        assert all(f in text for f in fields)


# -- no literal slices of a record's arrays in compiled code (issue 23 item 2) ---------------------------------------

_JIT_DECORATORS = {"jit", "jit_inline", "jit_entry", "njit"}


def _compiled_functions(tree: ast.Module):
    """The functions of a module compiled by numba (decorated ``@jit``, ``@jit_inline``, ``@jit_entry``, ``@njit``)."""
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef):
            for deco in node.decorator_list:
                d = deco.func if isinstance(deco, ast.Call) else deco
                name = d.attr if isinstance(d, ast.Attribute) else getattr(d, "id", "")
                if name in _JIT_DECORATORS:
                    yield node
                    break


def _record_slices(path: Path, root: Path = SRC.parent) -> list[str]:
    """Literal slices (``x.f[0:3]``, ``r["f"][3:6]``) of a record's field inside the compiled functions of ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    hits = []
    for fn in _compiled_functions(tree):
        for node in ast.walk(fn):
            if not (isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Slice)):
                continue
            sl = node.slice
            literal = any(isinstance(b, ast.Constant) and type(b.value) is int for b in (sl.lower, sl.upper))
            v = node.value
            field = isinstance(v, ast.Attribute) or (
                isinstance(v, ast.Subscript) and isinstance(v.slice, ast.Constant) and isinstance(v.slice.value, str)
            )
            if literal and field:
                hits.append(f"{path.relative_to(root)}:{node.lineno}: {ast.unparse(node)}")
    return hits


def test_no_literal_slice_of_a_record_field_in_compiled_code():
    """Mixed vectors between blocks travel as named fields (``f_ext_W``, ``m_ext_B``), never ``output[0:3]``."""
    bad = [hit for sub in ("control", "sim") for path in _modules(sub) for hit in _record_slices(path)]
    assert not bad, "\n".join(bad)


def test_record_slice_check_finds_a_slice(tmp_path):
    """The check above is not vacuous: it finds an attribute's and a string key's literal slice in a kernel."""
    f = tmp_path / "m.py"
    f.write_text(
        "@jit\ndef k(r, x):\n    a = r.output[0:3]\n    b = r['w'][3:6]\n    c = x[0:3]\n    return a, b, c\n\n"
        "def py(r):\n    return r.output[0:3]\n"
    )
    hits = [h.split(": ", 1)[1] for h in _record_slices(f, tmp_path)]
    assert hits == ["r.output[0:3]", "r['w'][3:6]"]


# -- one record, one entry point (issue 23 item 1) ------------------------------------------------------------------

_ADDRESS_MACHINERY = (
    *("numba.carray", "carray(", "void_pointer", "address_table", "records_at"),
    *("NamedTuple", "_by_table", "_by_state"),
)


def test_the_controller_passes_one_record_and_no_addresses():
    """No module of control/ stores or rebuilds arrays by address, nor groups arrays in NamedTuples; the
    controller's step is one compiled function of (state, frame, row)."""
    import inspect

    from omnirotor.control import composer

    for path in sorted((SRC / "control").glob("*.py")):
        text = path.read_text(encoding="utf-8")
        found = [word for word in _ADDRESS_MACHINERY if word in text]
        assert not found, f"{path.name} uses {found}"
    assert list(inspect.signature(composer.controller_step.py_func).parameters) == ["state", "frame", "row"]
    entries = [name for name in composer.__all__ if name.startswith("controller_step")]
    assert entries == ["controller_step"]
