"""The contract every block of the 1 kHz loop follows, controller and simulator alike, and their registry.

A *block* is one box of the paper's diagram (trajectory, admittance, pose controller, allocation, map
scheduler, wrench observer, estimator; on the simulator's side rotors, aerodynamics, sensors, contact,
faults, airflow). Each block lives in one module, which owns:

* its **parameters**: a frozen dataclass read from a TOML table (:func:`omnirotor.config.from_mapping`);
* its **state**: one NumPy structured array of shape ``(1,)`` whose dtype the module declares
  (``state_dtype``). Fields carry units and frames in their names (``f_hat_W``, ``u_hz2``); compiled code
  reads them by name (``s["f_hat_W"]``), never by an integer offset. A composer (the controller, the
  simulator) nests its blocks' dtypes as fields of its own dtype, so there is still one array to pass;
* its **compiled step**, beside the Python set-up, written once: Python keeps set-up, validation and
  reporting, and calls the same kernel the compiled composers call;
* the **fields it logs** (``log_fields``: the fields of its state the run's log records each period, each
  under its own name or ``(group, (field, ...))`` under another name, consecutive fields in one group;
  ``log_labels`` may name a group's columns). A composer's log is one record whose fields are these groups
  (:func:`log_groups`), filled by one generic compiled copy (:func:`log_writer`): a signal logged is one
  declaration in its block;
* for the controller's blocks (:data:`CONTROLLER_KINDS`, which read measurements that may be corrupt), a count
  of the steps whose inputs were not finite (field ``n_nonfinite``): such a step leaves the rest of the state as
  it was. The simulator's blocks are fed by the simulator's own state; their conformance suite checks instead
  that a non-finite command is held or propagated as their docstrings say.

Compiled code reaches the step of whichever block of a kind it was given through :func:`compiled_step`:
``compiled_step("observer")(state, ...)`` compiles to the ``kernel`` of the class registered under that kind
whose ``state_dtype`` is the record type of ``state``, so a composer is written once for every implementation
and is compiled (and cached) per combination of its blocks' state types. Every controller kind is reached so
(:data:`KIND_STEPS` gives each kind's typed step; the controller's composer calls no block directly).

A block registers itself under its kind and a name (:func:`register`), so a composer can be given another
implementation of the same kind (for example a different wrench observer) by name, without editing the
composer: adding a block is one file plus one registration line.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
from collections.abc import Callable
from typing import Any, ClassVar, Protocol, TypeVar, runtime_checkable

import numba
import numpy as np
from numba import types
from numba.extending import lower_builtin, overload, type_callable

from omnirotor._jit import record_sources
from omnirotor.errors import InputError

__all__ = [
    "Block",
    "BLOCK_KINDS",
    "register",
    "block_class",
    "block_names",
    "compiled_step",
    "state_array",
    "new_state",
    "new_records",
    "record_view",
    "LogGroup",
    "log_groups",
    "log_dtype",
    "log_writer",
    "class_of_record",
]

BLOCK_KINDS = (
    "supervisor",
    "estimator",
    "maps",
    "observer",
    "trajectory",
    "admittance",
    "pose",
    "allocation",
    "rotors",
    "aero",
    "sensors",
    "contact",
    "faults",
    "airflow",
)
"""The kinds of block the composers know, in the order of one period's data flow."""

CONTROLLER_KINDS = BLOCK_KINDS[:8]
"""The controller's kinds (the rest are the simulator's)."""

KIND_STEPS = {
    "supervisor": "kernel(r, frame, estimate) -> act: checks the frame record against the last period's estimate "
    "record; writes r.clean (the checked frame head, FRAME_HEAD_DTYPE), r.cause (CAUSE_* bits), r.counts, "
    "r.dt_s (the interval the frame closes [s]), r.coasting, r.blind, r.reinit_v_W, r.fs_mode; act: the cause "
    "bits plus ACT_REINIT. Entry reference(r, estimate, p_E_B, dt, ref): the failsafe's EE reference record, "
    "called while r.fs_mode is on (optional)",
    "estimator": "kernel(r, memory, frame, estimate) -> code: the estimate record from the checked frame head "
    "(FRAME_HEAD_DTYPE); memory: the controller's sized estimator memory (ukf_memory); code: STEP_* bits, or -1 "
    "when there is no estimate yet",
    "maps": "kernel(r, arrays, R_WB) -> region: the (6, n) wrench map of the attitude R_WB into arrays.out "
    "(arrays: the controller's maps_arrays record), r.region the region index (-1: none)",
    "observer": "kernel(r, A, u_hz2, a_W, R_WB, omega_B, dt): r.f_ext_W, r.m_ext_B (interaction), r.f_filt_W, "
    "r.m_filt_B (compensated) from the (6, n) map A, the rotor inputs u_hz2 [Hz²] and the estimate",
    "trajectory": "kernel(r, data, t, ref): the desired EE reference record ref at trajectory time t [s]; data: the "
    "controller's trajectory field (floats the block's load() packed)",
    "admittance": "kernel(r, f_E_W, m_E_W, desired, compliant, dt): the compliant EE reference record from the "
    "desired one under the EE wrench [N, N·m, world]; r.xi_p_W is the position offset",
    "pose": "kernel(r, body_ref, p_W, v_W, R_WB, omega_B, f_filt_W, m_filt_B, dt): r.f_ref_W [N, world], "
    "r.m_ref_B [N·m, body] from the body reference record and the estimate, compensating the filtered wrench",
    "allocation": "kernel(r, arrays, f_ref_W, m_ref_B, R_WB, A) -> code: the rotor inputs of the wrench reference "
    "(arrays: the block's arrays_dtype(n) record, the controller's allocation_arrays): ALLOC_DONE (arrays.u_hz2 "
    "holds them), BEGIN_HELD (an input was not finite: the last safe inputs held), or BEGIN_SOLVE / "
    "BEGIN_SOLVE_NEW_MAP (a QP is prepared: entries qp(r, arrays) -> solved, then finish(r, arrays, solved) "
    "write arrays.u_hz2; optional); r.status (1.0: a fallback), r.saturated",
}
"""The typed step of each controller kind, reached by the composer through the registry (:func:`compiled_step`).

A block of that kind registers a ``kernel`` of this signature (and the further entries named there, which a
block may leave out when it never asks for them). Its record holds the output fields named. Constructors, by
kind, with the parameters of the kind (``omnirotor.control``'s ``*Params``):

* supervisor ``(vehicle, params, *, state=None)``, ``reset(frame_record, *, dt, acc_range, gyro_range,
  check_state, check_mocap)``;
* estimator ``(vehicle, params, *, state=None, memory=None)``, ``reset(frame)`` (``EstimatorParams.kind``: the
  UKF or the bypass, whose two fields the record holds);
* maps ``(vehicle, maps, params, *, state=None, arrays=None)``, ``follows_attitude`` (its kernel runs each
  period), ``sync()``;
* observer, pose ``(vehicle, params, *, state=None)``; admittance ``(params, *, state=None)``;
* trajectory ``(capacity_waypoints, *, state=None, data=None)``, ``load(trajectory)`` (an ``InputError``
  beyond its capacity), ``data_size(capacity_waypoints)`` (a class method: floats of ``data``);
* allocation ``(vehicle, params, *, state=None, arrays=None)``, ``arrays_dtype(n)`` (a static method),
  ``solves_compiled`` (False: ``solve_qp(code)`` is called from Python between the composer's two halves).

The controller chooses each by name: ``ControllerParams.<kind>_kind`` (the estimator by ``EstimatorParams.kind``).
"""


@runtime_checkable
class Block(Protocol):
    """What a composer may rely on in any block.

    Attributes:
        kind: one of :data:`BLOCK_KINDS`.
        name: the name it is registered under (unique within its kind).
        state_dtype: the structured dtype of its state (named fields, units and frames in the names).
        state: its state, a ``(1,)`` array of ``state_dtype`` (or a view of the composer's nested field).
        log_fields: the fields of ``state`` the run's log records each period: a field's name (logged under
            it), or ``(group, (field, ...))`` (consecutive fields logged as one group named ``group``).
            Optional ``log_labels``: ``{group: column labels}`` (default: x, y, z for 3 values, the row-major
            entries of a 3 x 3 matrix, else 1, 2, ...).
        kernel: its compiled step, ``kernel(record, *inputs)`` (``record`` is ``state[0]``), for the kinds a
            composer reaches through :func:`compiled_step`.
    """

    kind: ClassVar[str]
    name: ClassVar[str]
    state_dtype: ClassVar[np.dtype]
    log_fields: ClassVar[tuple[str | tuple[str, tuple[str, ...]], ...]]
    state: np.ndarray

    def reset(self) -> None:
        """Return the state to its initial value (parameters are kept)."""


T = TypeVar("T")

_REGISTRY: dict[str, dict[str, type]] = {kind: {} for kind in BLOCK_KINDS}


def register(kind: str, name: str) -> Callable[[type[T]], type[T]]:
    """Class decorator: make a block class available to the composers as ``(kind, name)``.

    Args:
        kind: one of :data:`BLOCK_KINDS`.
        name: its name within the kind.

    Raises:
        InputError: unknown kind, or the name is taken by another class.
    """
    if kind not in _REGISTRY:
        raise InputError(f"unknown block kind {kind!r}; known: {', '.join(BLOCK_KINDS)}")

    def deco(cls: type[T]) -> type[T]:
        taken = _REGISTRY[kind].get(name)
        if taken is not None and taken is not cls:
            raise InputError(f"a {kind} block named {name!r} is registered already ({taken.__qualname__})")
        dtype = getattr(cls, "state_dtype", None)
        if dtype is not None:
            if dtype.names is None:
                raise InputError(f"{cls.__qualname__}.state_dtype must be a structured dtype (named fields)")
            if kind in CONTROLLER_KINDS and "n_nonfinite" not in dtype.names:
                raise InputError(f"{cls.__qualname__}.state_dtype must be structured with a field 'n_nonfinite'")
            for other_name, other in _REGISTRY[kind].items():
                if other is not cls and getattr(other, "state_dtype", None) == dtype:
                    raise InputError(f"{kind} blocks {other_name!r} and {name!r} have the same state_dtype")
        _REGISTRY[kind][name] = cls
        if dtype is not None:  # compiled callers reach its code through its record type, not an import
            record_sources(dtype, _source_files(cls))
        cls.kind = kind  # type: ignore[attr-defined]
        cls.name = name  # type: ignore[attr-defined]
        return cls

    return deco


def _source_files(cls: type) -> set[str | None]:
    """The files of a block class and of the compiled functions it holds (``None``: one has no file, a prompt's)."""

    def file_of(obj) -> str | None:
        try:
            return inspect.getsourcefile(obj)
        except (TypeError, OSError):  # a built-in, or code from a string or a prompt
            return None

    files = {file_of(cls)}
    for attr in dir(cls):
        py_func = getattr(inspect.getattr_static(cls, attr, None), "py_func", None)
        if py_func is not None:
            files.add(file_of(py_func))
    return files


def block_class(kind: str, name: str) -> type[Any]:
    """The class registered as ``(kind, name)``.

    Raises:
        InputError: nothing registered under that kind and name (the message lists what is).
    """
    if kind not in _REGISTRY:
        raise InputError(f"unknown block kind {kind!r}; known: {', '.join(BLOCK_KINDS)}")
    try:
        return _REGISTRY[kind][name]
    except KeyError:
        known = ", ".join(sorted(_REGISTRY[kind])) or "none"
        raise InputError(f"no {kind} block named {name!r}; registered: {known}") from None


def block_names(kind: str) -> tuple[str, ...]:
    """Names registered under ``kind``, sorted."""
    if kind not in _REGISTRY:
        raise InputError(f"unknown block kind {kind!r}; known: {', '.join(BLOCK_KINDS)}")
    return tuple(sorted(_REGISTRY[kind]))


_PURE_PYTHON = bool(numba.config.DISABLE_JIT)


def new_records(dtype: np.dtype, n: int = 1) -> np.ndarray:
    """``n`` zeroed records of ``dtype``, a ``(n,)`` array.

    With ``NUMBA_DISABLE_JIT=1`` (kernels run as Python) it is a ``numpy.recarray``, whose records read their
    fields as attributes (``r.output``) as compiled code does; compiled, a plain array.
    """
    records = np.zeros(n, dtype=dtype)
    return records.view(np.recarray) if _PURE_PYTHON else records


def new_state(dtype: np.dtype) -> np.ndarray:
    """A zeroed ``(1,)`` state of ``dtype`` (:func:`new_records`)."""
    return new_records(dtype)


def state_array(dtype: np.dtype, state: np.ndarray | None, owner: str) -> np.ndarray:
    """A block's state: ``state`` (zeroed) when given (e.g. a field of its composer's state), else a new one.

    Raises:
        InputError: ``state`` is not a writeable ``(1,)`` array of ``dtype``.
    """
    if state is None:
        return new_state(dtype)
    if not (isinstance(state, np.ndarray) and state.dtype == dtype and state.shape == (1,) and state.flags.writeable):
        raise InputError(f"{owner} state must be a writeable (1,) array of its state_dtype")
    state[...] = np.zeros(1, dtype=dtype)
    return state


def record_view(records: np.ndarray) -> np.record:
    """The first record of ``records`` (a ``(1,)`` structured array) with its fields as attributes, a view.

    ``record_view(a).x`` is the field ``x`` of ``a[0]`` (an array view for a subarray field), so Python set-up
    reads a block's sized arrays by the names compiled code uses; compiled kernels take the record itself.
    """
    return records.view(np.recarray)[0]


# -- the log: one record of the blocks' logged fields ------------------------------------------------------------

_XYZ = ("x", "y", "z")
_RMAT = ("xx", "xy", "xz", "yx", "yy", "yz", "zx", "zy", "zz")  # row-major entries of a rotation matrix


@dataclasses.dataclass(frozen=True)
class LogGroup:
    """One group of a log record.

    Attributes:
        name: the group's name (a field of the log record, a column group of the recorder).
        paths: the dotted paths of the fields of the composer's record whose values it holds, in order
            (``("pose.f_ref_W", "pose.m_ref_B")``).
        shape: its shape in the log record (``()`` a scalar; one field keeps its shape, several are joined
            into a vector).
        labels: its column labels.
    """

    name: str
    paths: tuple[str, ...]
    shape: tuple[int, ...]
    labels: tuple[str, ...]


_LOGGABLE = (np.dtype(np.float64), np.dtype(np.int64))


def _default_labels(shape: tuple[int, ...]) -> tuple[str, ...]:
    size = int(np.prod(shape, dtype=int))
    if shape == (3,):
        return _XYZ
    if shape == (3, 3):
        return _RMAT
    return ("0",) if size == 1 else tuple(str(i + 1) for i in range(size))


def _field_dtype(dtype: np.dtype, path: str) -> np.dtype:
    d = dtype
    for part in path.split("."):
        if d.names is None or part not in d.names:
            raise InputError(f"log: no field {path!r} in the composer's record")
        d = d.fields[part][0]
    return d


def log_groups(state_dtype: np.dtype, sources) -> tuple[LogGroup, ...]:
    """The groups of a composer's log record, in order.

    Args:
        state_dtype: the composer's record type (every path below is a field of it).
        sources: ``(prefix, log_fields, log_labels)`` in log order: a record of the composer (``"pose"``, or
            ``""`` for the record itself), the fields it logs (:class:`Block`'s ``log_fields`` form) and their
            labels (a dict, may be empty).

    Raises:
        InputError: a field that does not exist, or two groups of the same name.
    """
    groups: list[LogGroup] = []
    for prefix, fields, labels in sources:
        for entry in fields:
            name, names = (entry, (entry,)) if isinstance(entry, str) else (entry[0], tuple(entry[1]))
            paths = tuple(f"{prefix}.{f}" if prefix else f for f in names)
            dtypes = [_field_dtype(state_dtype, p) for p in paths]
            if any((d.base if d.subdtype is not None else d) not in _LOGGABLE for d in dtypes):
                raise InputError(f"log group {name!r}: only float64 and int64 fields are logged (as float64)")
            shapes = [d.shape for d in dtypes]
            shape = shapes[0] if len(shapes) == 1 else (sum(int(np.prod(s, dtype=int)) for s in shapes),)
            lab = tuple(labels.get(name, _default_labels(shape)))
            if len(lab) != int(np.prod(shape, dtype=int)):
                raise InputError(f"log group {name!r}: {len(lab)} labels for {int(np.prod(shape, dtype=int))} values")
            groups.append(LogGroup(name, paths, shape, lab))
    names = [g.name for g in groups]
    if len(set(names)) != len(names):
        raise InputError(f"log: duplicate groups in {names}")
    return tuple(groups)


@functools.cache
def log_dtype(groups: tuple[LogGroup, ...]) -> np.dtype:
    """The log record of ``groups``: one float64 field per group, packed.

    A row of floats (the recorder's) viewed as this dtype is the record, field by field in group order.
    """
    return np.dtype([(g.name, np.float64, g.shape) if g.shape else (g.name, np.float64) for g in groups])


def class_of_record(kind: str, record_type) -> type | None:
    """The class registered under ``kind`` whose ``state_dtype`` is numba's ``record_type`` (None: none)."""
    for cls in _REGISTRY[kind].values():
        dtype = getattr(cls, "state_dtype", None)
        if dtype is not None and numba.from_dtype(dtype) == record_type:
            return cls
    return None


def _writer_source(groups: tuple[LogGroup, ...]) -> str:
    """Straight-line code copying each group's fields from ``src`` into ``dst`` (the log record), by name."""
    lines = ["def impl(dst, src):"]
    for g in groups:
        if len(g.paths) == 1 and not g.shape:
            lines.append(f"    dst.{g.name} = src.{g.paths[0]}")
        elif len(g.paths) == 1:  # element by element: an array assigned to a slice compiles numba's error text
            index = ", ".join(f"_i{d}" for d in range(len(g.shape)))
            for d, size in enumerate(g.shape):
                lines.append(f"    {'    ' * d}for _i{d} in range({size}):")
            lines.append(f"    {'    ' * len(g.shape)}dst.{g.name}[{index}] = src.{g.paths[0]}[{index}]")
        else:
            lines.append("    _k = 0")
            for path in g.paths:
                lines.append(f"    for _v in src.{path}.flat:")  # its entries, row-major
                lines.append(f"        dst.{g.name}[_k] = _v")
                lines.append("        _k += 1")
    lines.append("    return None")
    return "\n".join(lines)


def log_writer(name: str, groups_of: Callable[[Any, Any], tuple[LogGroup, ...] | None]) -> Callable[..., Any]:
    """A compiled ``write(dst, src)``: every group of the log record ``dst`` from its fields of ``src``.

    Compiled per pair of record types, from ``groups_of(dst_type, src_type)`` (numba's types; None: not
    this writer's pair): straight-line copies by field name, generated from the groups, so that no copy is
    written by hand beside the declarations. From Python it does the same with NumPy.
    """

    def write(dst, src):
        groups = groups_of(numba.from_dtype(dst.dtype), numba.from_dtype(src.dtype))
        for g in groups:
            values = [np.ravel(_get_path(src, p)) for p in g.paths]
            dst[g.name] = np.concatenate(values).reshape(g.shape) if g.shape else values[0][0]

    write.__name__ = write.__qualname__ = name

    @overload(write)
    def _write_overload(dst, src):
        if not (isinstance(dst, types.Record) and isinstance(src, types.Record)):
            return None
        groups = groups_of(dst, src)
        if groups is None:
            return None
        namespace: dict[str, Any] = {}
        exec(_writer_source(groups), namespace)  # noqa: S102 (code generated from the declared field names)
        return namespace["impl"]

    return write


def _get_path(record, path: str):
    for part in path.split("."):
        record = record[part]
    return record


_STEPS: dict[tuple[str, str], Callable[..., Any]] = {}


def _entry_params(kind: str, entry: str) -> tuple[str, ...]:
    """The parameter names of a kind's entry, as :data:`KIND_STEPS` writes them (``r``, ...)."""
    text = KIND_STEPS.get(kind, "")
    start = 0 if entry == "kernel" else text.find(f"{entry}(")
    if not text or start < 0:
        raise InputError(f"the {kind} kind has no entry {entry!r} (KIND_STEPS)")
    inner = text[text.index("(", start) + 1 : text.index(")", start)]
    return tuple(a.strip() for a in inner.split(","))


def compiled_step(kind: str, entry: str = "kernel", default: Callable[..., Any] | None = None) -> Callable[..., Any]:
    """The step of blocks of ``kind`` for compiled code, chosen by the record type of its first argument.

    ``compiled_step(kind)(record, *inputs)`` inside a compiled function compiles to ``cls.kernel(record,
    *inputs)`` of the registered class of that kind whose ``state_dtype`` is the record's type; called from
    Python it does the same lookup. A block registered later (another module, a test) is found too. The
    choice is made when the caller compiles: nothing is looked up per call.

    Args:
        kind: one of :data:`BLOCK_KINDS`.
        entry: the class attribute to call (``"kernel"``, or a further entry of the kind, :data:`KIND_STEPS`).
        default: a compiled function called instead when the class has no such entry (an optional entry);
            None: the entry is required.
    """
    if kind not in _REGISTRY:
        raise InputError(f"unknown block kind {kind!r}; known: {', '.join(BLOCK_KINDS)}")
    key = (kind, entry)
    if key in _STEPS:
        return _STEPS[key]

    names = _entry_params(kind, entry)
    args = ", ".join(names)

    def lookup(record):
        dtype = getattr(record, "dtype", None)
        for cls in _REGISTRY[kind].values():
            if dtype is not None and getattr(cls, "state_dtype", None) == dtype:
                fn = getattr(cls, entry, default)
                if fn is None:
                    raise InputError(f"{kind} block {cls.name!r} has no {entry!r}")
                return fn
        raise InputError(f"no {kind} block has the state type of this record")

    def kernel_of(record):
        """The compiled function a call with this record type compiles to (None: not a block of the kind)."""
        if not isinstance(record, types.Record):
            return None
        cls = class_of_record(kind, record)
        return None if cls is None else getattr(cls, entry, default)

    def resolve(context, arg_types):
        """The signature of the block's kernel for these argument types (compiling it), or None."""
        fn = kernel_of(arg_types[0])
        if fn is None:
            return None
        return context.resolve_function_type(context.resolve_value_type(fn), arg_types, {})

    # The step and its typer take the kind's parameters by name (keyword arguments are folded by them).
    namespace = {"lookup": lookup, "resolve": resolve}
    exec(  # noqa: S102 (generated from KIND_STEPS' parameter names)
        f"def step({args}):\n    return lookup({names[0]})({args})\n"
        f"def typer_of(context):\n"
        f"    def typer({args}):\n        return resolve(context, ({args},))\n"
        f"    return typer\n",
        namespace,
    )
    step = namespace["step"]
    step.__name__ = step.__qualname__ = f"{kind}_{entry}"
    # In compiled code the call is the block's kernel itself, typed and lowered as a direct call of it (numba's
    # low-level extension API), with no function of its own in between: a wrapper (an ``overload``'s
    # implementation) would be one more compiled function, and one more module that links the block's
    # machine code and optimises it again (13 wrappers: about 7 s of a first run's compilation).
    type_callable(step)(namespace["typer_of"])

    @lower_builtin(step, types.VarArg(types.Any))
    def _lower(context, builder, sig, args):
        fnty = context.typing_context.resolve_value_type(kernel_of(sig.args[0]))
        return context.get_function(fnty, sig)(builder, args)

    _STEPS[key] = step
    return step
