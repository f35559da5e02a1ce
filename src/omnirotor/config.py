"""Parameters as frozen dataclasses loaded from TOML.

Every block of the project has one frozen dataclass of parameters. :func:`from_mapping` builds one from a
TOML table and rejects unknown keys (an ignored key is a silent bug), and :func:`apply_overrides` applies
dotted ``key=value`` overrides given on the command line. Validation lives in each dataclass's
``__post_init__`` and raises :class:`~omnirotor.errors.InputError`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
import tomllib
import types
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, TypeVar

from omnirotor.errors import InputError

__all__ = [
    "load_toml",
    "from_mapping",
    "apply_overrides",
    "apply_values",
    "check_finite",
    "check_positive",
    "parse_float",
]

T = TypeVar("T")


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file, turning every I/O or syntax problem into an :class:`InputError`."""
    from omnirotor.safe_io import read_text

    p = Path(path)
    text = read_text(p)  # a regular file of bounded size (a FIFO or a device is refused, never read)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{p}: not valid TOML ({exc})") from None
    except RecursionError:
        raise InputError(f"{p}: not usable TOML (nested too deeply)") from None


def _short(value: Any) -> str:
    """``repr`` of a value cut to 40 characters (a 5000-digit integer makes no readable message)."""
    if isinstance(value, int) and value.bit_length() > 100:
        return f"an integer of {value.bit_length()} bits"
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _convert(value: Any, tp: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, Mapping):
            raise InputError(f"{where}: expected a table, got {type(value).__name__}")
        return from_mapping(tp, value, where)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(f"{where}: expected a number, got {_short(value)}")
        try:
            return float(value)
        except OverflowError:  # an integer too big for a float
            raise InputError(f"{where}: {_short(value)} is too large for a number") from None
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(f"{where}: expected an integer, got {_short(value)}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise InputError(f"{where}: expected true or false, got {_short(value)}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise InputError(f"{where}: expected a string, got {_short(value)}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise InputError(f"{where}: expected an array, got {_short(value)}")
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if len(args) != len(value):
            raise InputError(f"{where}: expected {len(args)} values, got {len(value)}")
        return tuple(_convert(v, a, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value, strict=True)))
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            return None
        return _convert(value, args[0], where)
    return value


@functools.cache
def _field_names(cls: type) -> frozenset[str]:
    """The field names of a dataclass type."""
    return frozenset(f.name for f in dataclasses.fields(cls))


@functools.cache
def _type_hints(cls: type) -> dict[str, Any]:
    """``typing.get_type_hints`` of a dataclass, evaluated once per class (a campaign run builds hundreds)."""
    return typing.get_type_hints(cls)


def from_mapping(cls: type[T], data: Mapping[str, Any], where: str = "") -> T:
    """Build the frozen dataclass ``cls`` from a mapping, rejecting unknown keys.

    Args:
        cls: a dataclass type whose fields carry plain annotations (float, int, bool, str, tuples,
            nested dataclasses).
        data: the TOML table.
        where: a location prefix for error messages, e.g. the file name.

    Returns:
        The dataclass instance; its ``__post_init__`` has validated it.
    """
    hints = _type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    prefix = f"{where}: " if where else ""
    if not isinstance(data, Mapping):
        raise InputError(f"{prefix}expected a table, got {type(data).__name__}")
    unknown = sorted(set(data) - names)
    if unknown:
        raise InputError(f"{prefix}unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(names))}")
    kwargs = {k: _convert(v, hints[k], f"{where}.{k}" if where else k) for k, v in data.items()}
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise InputError(f"{prefix}{exc}") from None


_TOML_DECIMAL = re.compile(r"[+-]?(?:0|[1-9][0-9]*)(?P<float>(?:\.[0-9]+)?(?:[eE][+-]?[0-9]+)?)")
"""A TOML integer or float in decimal notation without underscores: the values a campaign writes."""


def _parse_scalar(text: str) -> Any:
    m = _TOML_DECIMAL.fullmatch(text)
    if m is not None:  # what tomllib makes of it, without parsing a document
        return float(text) if m.group("float") else int(text)
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except (tomllib.TOMLDecodeError, RecursionError):
        return text


def apply_overrides(obj: T, overrides: list[str]) -> T:
    """Return a copy of a (nested) frozen dataclass with dotted ``key=value`` overrides applied.

    Values are parsed as TOML (``0.3``, ``[1, 2, 3]``, ``true``); anything else is taken as a string. Then as
    :func:`apply_values`.
    """
    values = []
    for item in overrides:
        if "=" not in item:
            raise InputError(f"override {item!r}: expected key=value")
        key, text = item.split("=", 1)
        values.append((key.strip(), _parse_scalar(text.strip())))
    return apply_values(obj, values)


def apply_values(obj: T, values: Iterable[tuple[str, Any]]) -> T:
    """Return a copy of a (nested) frozen dataclass with the fields at dotted keys set to typed values.

    What code that holds the values already uses (a campaign's drawn parameters): nothing is written as text and
    parsed back. Each key and value is checked in order (unknown key, not a parameter group, wrong type: the
    first bad one is the error); then each dataclass is replaced once with all its new values, a later value of
    the same key winning, so that ``__post_init__`` validates the result, not every step to it (a campaign run's
    plant has about twenty of them, and each replace of the simulator parameters validated all of them).
    """
    items = []
    for key, value in values:
        path = key.split(".")
        items.append((path, _checked_value(obj, path, value, key)))
    return _set_paths(obj, items) if items else obj


def _checked_value(obj: Any, path: list[str], value: Any, full: str) -> Any:
    """``value`` converted to the type of the field at ``path`` in ``obj`` (which must exist)."""
    for i, name in enumerate(path):
        if not dataclasses.is_dataclass(obj):
            raise InputError(f"override {full}: {name!r} is not a parameter group")
        names = _field_names(type(obj))
        if name not in names:
            raise InputError(f"override {full}: unknown key {name!r}; allowed: {', '.join(sorted(names))}")
        if i == len(path) - 1:
            return _convert(value, _type_hints(type(obj))[name], full)
        obj = getattr(obj, name)
    raise AssertionError("unreachable")  # pragma: no cover


def _set_paths(obj: Any, items: list[tuple[list[str], Any]]) -> Any:
    """``obj`` with the checked ``(path, value)`` items set in order: one ``dataclasses.replace`` per dataclass."""
    changes: dict[str, Any] = {}
    inner: dict[str, list[tuple[list[str], Any]]] = {}
    for path, value in items:
        name = path[0]
        if len(path) == 1:
            changes[name] = value
            inner.pop(name, None)  # a whole group given replaces what earlier items set inside it
        else:
            inner.setdefault(name, []).append((path[1:], value))
    for name, sub in inner.items():
        changes[name] = _set_paths(changes.get(name, getattr(obj, name)), sub)
    return dataclasses.replace(obj, **changes)


def parse_float(text: str, where: str) -> float:
    """A number written by a user (option, CSV cell): Python's ``float`` without its surprises.

    ``float("1_6_0")`` is 160 and ``float(" 1 ")`` is 1; a user who wrote ``1_6_0`` meant something else, so
    underscores are refused. Non-finite results (``nan``, ``1e400``) are returned for the caller to judge.

    Raises:
        InputError: not a number.
    """
    t = text.strip()
    if "_" in t or not t:
        raise InputError(f"{where}: not a number: {t[:40]!r}")
    try:
        return float(t)
    except ValueError:
        raise InputError(f"{where}: not a number: {t[:40]!r}") from None


def check_finite(name: str, *values: float) -> None:
    """Raise :class:`InputError` if any value is NaN or infinite."""
    for v in values:
        if not math.isfinite(v):
            raise InputError(f"{name} must be finite, got {v}")


def check_positive(name: str, value: float) -> None:
    """Raise :class:`InputError` unless ``value`` is finite and > 0."""
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"{name} must be a finite number > 0, got {value}")
