"""The contract every block of the 1 kHz loop follows, controller and simulator alike, and their registry.

A *block* is one box of the paper's diagram (trajectory, admittance, pose controller, allocation, map
scheduler, wrench observer, estimator; on the simulator's side rotors, aerodynamics, sensors, contact,
faults). Each block lives in one module, which owns:

* its **parameters**: a frozen dataclass read from a TOML table (:func:`omnirotor.config.from_mapping`);
* its **state**: one NumPy structured array of shape ``(1,)`` whose dtype the module declares
  (``state_dtype``). Fields carry units and frames in their names (``f_hat_W``, ``u_hz2``); compiled code
  reads them by name (``s["f_hat_W"]``), never by an integer offset. A composer (the controller, the
  simulator) nests its blocks' dtypes as fields of its own dtype, so there is still one array to pass;
* its **compiled step**, beside the Python set-up, written once: Python keeps set-up, validation and
  reporting, and calls the same kernel the compiled composers call;
* the **fields it logs** (names of state fields copied to the run's log each period).

A block registers itself under its kind and a name (:func:`register`), so a composer can be given another
implementation of the same kind (for example a different wrench observer) by name, without editing the
composer: adding a block is one file plus one registration line.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar, Protocol, TypeVar, runtime_checkable

import numpy as np

from omnirotor.errors import InputError

__all__ = ["Block", "BLOCK_KINDS", "register", "block_class", "block_names"]

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
)
"""The kinds of block the composers know, in the order of one period's data flow."""


@runtime_checkable
class Block(Protocol):
    """What a composer may rely on in any block.

    Attributes:
        kind: one of :data:`BLOCK_KINDS`.
        name: the name it is registered under (unique within its kind).
        state_dtype: the structured dtype of its state (named fields, units and frames in the names).
        state: its state, a ``(1,)`` array of ``state_dtype`` (or a view of the composer's nested field).
        log_fields: names of the fields of ``state`` the run's log records each period.
    """

    kind: ClassVar[str]
    name: ClassVar[str]
    state_dtype: ClassVar[np.dtype]
    log_fields: ClassVar[tuple[str, ...]]
    state: np.ndarray

    def reset(self) -> None:
        """Return the state to its initial value (parameters are kept)."""
        ...


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
