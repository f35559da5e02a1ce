"""Vehicles from files: presets, TOML files, PX4 airframe files and ULogs (SPEC §1).

The model (:class:`VehicleParams`, its nominal wrench map, force envelope; SPEC §1, §2) is
:mod:`omnirotor.vehicle_model`, whose names this module re-exports. Vehicle files are TOML (see
``presets/*.toml``): a rotor gives its ``axis`` directly or, as the Omnirotor's do, a tilt ``tilt_deg`` about
body ``tilt_about`` = "x" or "y" applied to e3 (SPEC §1.2 table). PX4 sources go through :mod:`omnirotor.px4`,
which builds the model's types without importing this module.
"""

from __future__ import annotations

import functools
import os
from importlib import resources
from pathlib import Path

from omnirotor.config import from_mapping, load_toml
from omnirotor.errors import InputError
from omnirotor.vehicle_model import (
    ForceEnvelope,
    RotorParams,
    VehicleParams,
    fibonacci_sphere,
    force_envelope,
    max_zero_torque_force,
    wrench_map,
    zero_moment_force_basis,
)

__all__ = [
    "RotorParams",
    "VehicleParams",
    "wrench_map",
    "load_vehicle",
    "vehicle_spec",
    "preset_names",
    "ForceEnvelope",
    "force_envelope",
    "zero_moment_force_basis",
    "max_zero_torque_force",
    "fibonacci_sphere",
]


def preset_names() -> list[str]:
    """Names of the vehicle presets shipped with the package."""
    return list(_preset_names())


@functools.cache
def _preset_names() -> tuple[str, ...]:
    """:func:`preset_names`, listed once per process (:func:`load_vehicle` asks on every call)."""
    files = resources.files("omnirotor") / "presets" / "vehicles"
    return tuple(sorted(p.name[: -len(".toml")] for p in files.iterdir() if p.name.endswith(".toml")))


OVERLAY_SEP = "::"
"""Separates a PX4 vehicle source from its TOML overlay in one vehicle spec string (see :func:`vehicle_spec`)."""


def vehicle_spec(vehicle: str, overlay: str | Path | None = None) -> str:
    """One spec string for ``vehicle`` with an optional overlay (``--vehicle V --vehicle-overlay F``)."""
    return str(vehicle) if overlay is None else f"{vehicle}{OVERLAY_SEP}{overlay}"


def load_vehicle(spec: str | Path = "omnirotor", overlay: str | Path | None = None) -> VehicleParams:
    """Load a vehicle from a preset name, a TOML file, a PX4 airframe file or a PX4 ULog.

    A PX4 source (an airframe file with ``param set-default CA_...`` lines, or a ``.ulg`` log with its ``CA_*``
    parameters) gives the rotor geometry; mass, inertia, c_f, c_tau and the speed limits come from ``overlay``
    (a TOML file of vehicle keys without rotors) and otherwise from stated defaults, which are said on stderr
    once per process (:mod:`omnirotor.px4.airframe`). ``spec`` may carry the overlay itself as
    ``"SOURCE::OVERLAY"`` (:func:`vehicle_spec`), so that one string passes through run options.

    Raises:
        InputError: unknown preset, unreadable file, unknown key or non-physical value.
    """
    text = str(spec)
    if OVERLAY_SEP in text:
        if overlay is not None:
            raise InputError(f"vehicle {text!r}: an overlay is given twice")
        text, overlay = text.split(OVERLAY_SEP, 1)
    if text in _preset_names():
        if overlay is not None:
            raise InputError("--vehicle-overlay applies to PX4 airframe files and ULogs only")
        path = resources.files("omnirotor") / "presets" / "vehicles" / f"{text}.toml"
        return _load_toml_vehicle(text, str(path), f"preset {text}", 0)
    else:
        p = Path(text)
        if not p.suffix and not os.path.exists(p):
            raise InputError(f"unknown vehicle preset {text!r}; presets: {', '.join(preset_names())}")
        if _is_px4_source(p):
            return _load_px4_vehicle(str(p), None if overlay is None else str(overlay), _stamp(p), _stamp(overlay))
        if overlay is not None:
            raise InputError("--vehicle-overlay applies to PX4 airframe files and ULogs only")
        return _load_toml_vehicle(text, str(p), str(p), _stamp(p))


@functools.lru_cache(maxsize=16)
def _load_toml_vehicle(text: str, path: str, where: str, _mtime: int) -> VehicleParams:
    """A vehicle from a TOML file, parsed once per file version (a campaign worker loads it for every run).

    The vehicle is a frozen dataclass; its cached arrays are shared by the callers, which only read them.
    """
    data = load_toml(Path(path))
    rotors = data.pop("rotor", None)
    if not isinstance(rotors, list) or not rotors:
        raise InputError(f"{where}: needs [[rotor]] tables")
    parsed = tuple(from_mapping(RotorParams, r, f"{where} rotor {i + 1}") for i, r in enumerate(rotors))
    data.setdefault("name", Path(text).stem)
    return from_mapping(VehicleParams, {**data, "rotors": parsed}, where)


def _is_px4_source(p: Path) -> bool:
    if p.suffix.lower() == ".ulg":
        return True
    if p.suffix.lower() == ".toml" or not p.is_file():
        return False
    from omnirotor.px4.airframe import is_airframe_file

    return is_airframe_file(p)


def _stamp(path: str | Path | None) -> int:
    """Modification time [ns] of a file (0 when absent): part of the cache key of :func:`_load_px4_vehicle`."""
    try:
        return Path(path).stat().st_mtime_ns if path is not None else 0
    except OSError:
        return 0


@functools.lru_cache(maxsize=16)
def _load_px4_vehicle(path: str, overlay: str | None, _mtime: int, _overlay_mtime: int) -> VehicleParams:
    """A vehicle from a PX4 airframe file or ULog; says the assumed values on stderr (once per file version)."""
    import sys

    from omnirotor.px4.airframe import load_overlay, read_airframe_params, vehicle_from_px4_params

    p = Path(path)
    if p.suffix.lower() == ".ulg":
        from omnirotor.px4.flight import read_ulog_params

        params = read_ulog_params(p)
    else:
        params = read_airframe_params(p)
    vehicle, assumed = vehicle_from_px4_params(params, p.name, str(p), load_overlay(overlay))
    if assumed:
        print(f"omnirotor: vehicle {p.name}: not in the file, assumed: {'; '.join(assumed)}", file=sys.stderr)
    return vehicle
