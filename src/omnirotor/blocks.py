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
* the **fields it logs** (names of state fields copied to the run's log each period);
* for the controller's blocks (:data:`CONTROLLER_KINDS`, which read measurements that may be corrupt), a count
  of the steps whose inputs were not finite (field ``n_nonfinite``): such a step leaves the rest of the state as
  it was. The simulator's blocks are fed by the simulator's own state; their conformance suite checks instead
  that a non-finite command is held or propagated as their docstrings say.

Compiled code reaches the step of whichever block of a kind it was given through :func:`compiled_step`:
``compiled_step("observer")(state, ...)`` compiles to the ``kernel`` of the class registered under that kind
whose ``state_dtype`` is the record type of ``state``, so a composer is written once for every implementation
and is compiled (and cached) per combination of its blocks' state types.

A block registers itself under its kind and a name (:func:`register`), so a composer can be given another
implementation of the same kind (for example a different wrench observer) by name, without editing the
composer: adding a block is one file plus one registration line.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar, Protocol, TypeVar, runtime_checkable

import numba
import numpy as np
from numba import types
from numba.extending import overload

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
]

BLOCK_KINDS = (
    "trajectory",
    "admittance",
    "pose",
    "allocation",
    "maps",
    "observer",
    "estimator",
    "rotors",
    "aero",
    "sensors",
    "contact",
    "faults",
    "airflow",
)
"""The kinds of block the composers know, in the order of one period's data flow."""

CONTROLLER_KINDS = BLOCK_KINDS[:7]
"""The controller's kinds (the rest are the simulator's)."""


@runtime_checkable
class Block(Protocol):
    """What a composer may rely on in any block.

    Attributes:
        kind: one of :data:`BLOCK_KINDS`.
        name: the name it is registered under (unique within its kind).
        state_dtype: the structured dtype of its state (named fields, units and frames in the names).
        state: its state, a ``(1,)`` array of ``state_dtype`` (or a view of the composer's nested field).
        log_fields: names of the fields of ``state`` the run's log records each period.
        kernel: its compiled step, ``kernel(record, *inputs)`` (``record`` is ``state[0]``), for the kinds a
            composer reaches through :func:`compiled_step`.
    """

    kind: ClassVar[str]
    name: ClassVar[str]
    state_dtype: ClassVar[np.dtype]
    log_fields: ClassVar[tuple[str, ...]]
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
        cls.kind = kind  # type: ignore[attr-defined]
        cls.name = name  # type: ignore[attr-defined]
        return cls

    return deco


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


_STEPS: dict[str, Callable[..., Any]] = {}


def compiled_step(kind: str) -> Callable[..., Any]:
    """The step of blocks of ``kind`` for compiled code, chosen by the record type of its first argument.

    ``compiled_step(kind)(record, *inputs)`` inside a compiled function compiles to ``cls.kernel(record,
    *inputs)`` of the registered class of that kind whose ``state_dtype`` is the record's type; called from
    Python it does the same lookup. A block registered later (another module, a test) is found too.
    """
    if kind not in _REGISTRY:
        raise InputError(f"unknown block kind {kind!r}; known: {', '.join(BLOCK_KINDS)}")
    if kind in _STEPS:
        return _STEPS[kind]

    def _class_of_record(record_type) -> type | None:
        for cls in _REGISTRY[kind].values():
            dtype = getattr(cls, "state_dtype", None)
            if dtype is not None and numba.from_dtype(dtype) == record_type:
                return cls
        return None

    def step(record, *inputs):
        dtype = getattr(record, "dtype", None)
        for cls in _REGISTRY[kind].values():
            if dtype is not None and getattr(cls, "state_dtype", None) == dtype:
                return cls.kernel(record, *inputs)
        raise InputError(f"no {kind} block has the state type of this record")

    step.__name__ = step.__qualname__ = f"{kind}_step"

    @overload(step)
    def _step_overload(record, *inputs):
        if not isinstance(record, types.Record):
            return None
        cls = _class_of_record(record)
        if cls is None:
            return None
        kernel = cls.kernel

        def impl(record, *inputs):
            return kernel(record, *inputs)

        return impl

    _STEPS[kind] = step
    return step
