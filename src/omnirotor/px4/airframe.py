"""Vehicles from PX4's control-allocation parameters (SPEC §1.2).

PX4 describes a multirotor's geometry by the parameters ``CA_ROTOR_COUNT``, per rotor ``CA_ROTORn_P{X,Y,Z}``
(position [m], FRD body frame), ``CA_ROTORn_A{X,Y,Z}`` (thrust axis, FRD) and ``CA_ROTORn_KM`` (moment ratio
[m], positive for a counter-clockwise rotor), and the bitmask ``CA_R_REV`` of reversible rotors. They are read
from an airframe file (``param set-default NAME VALUE`` lines, e.g. ``10019_omnicopter``), from a
QGroundControl parameter file (``.params``: tab-separated ``vehicle-id component-id NAME VALUE type`` lines, the
usual way to share a real vehicle's parameters) or from a ULog's parameters. A parameter the source does not set
takes PX4's own default (the control allocator's ``module.yaml``: position 0 m, axis (0, 0, -1), ``KM`` 0.05,
``CA_R_REV`` 0), as PX4 itself does; the defaulted names are said on stderr.

PX4's effectiveness of rotor i is ``f = ct a``, ``m = ct p × a − ct km a``; with our model
``m_i = p_i × f_i + k_i c_tau u_i z_i`` (SPEC §1.2) that gives, in our FLU body (:mod:`~omnirotor.px4.frames`),

    position = D p,  axis = D a,  spin k_i = −sign(km_i),  c_tau = |km| c_f.

PX4 stores no mass, inertia, thrust coefficient in SI or rotor-speed limits (``CA_ROTORn_CT`` is in normalised
units). Those come from a TOML overlay (keys of the vehicle file except ``rotor``), from ``OMR_*`` parameters
(which our own simulated logs add) and otherwise from the defaults :data:`PX4_DEFAULTS`; the inertia defaults to
the mass spread equally over the rotor positions. What was assumed is returned, and the caller says it on stderr.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from omnirotor.config import from_mapping, load_toml
from omnirotor.errors import InputError
from omnirotor.limits import MAX_ROTORS
from omnirotor.px4.frames import vec_from_px4

__all__ = [
    "PX4_DEFAULTS",
    "PX4_ROTOR_DEFAULTS",
    "read_airframe_params",
    "is_airframe_file",
    "vehicle_from_px4_params",
]

PX4_ROTOR_DEFAULTS = {"PX": 0.0, "PY": 0.0, "PZ": 0.0, "AX": 0.0, "AY": 0.0, "AZ": -1.0, "KM": 0.05}
"""PX4's defaults of ``CA_ROTORn_<key>`` (control_allocator/module.yaml)."""

PX4_DEFAULTS: dict[str, Any] = {
    "mass": 1.5,
    "c_f": 1.5e-4,
    "omega_max_hz": 220.0,
    "omega_min_hz_unidirectional": 0.0,
    "propeller_diameter": 0.2032,
}
"""Stated defaults for what PX4 does not store: mass [kg], c_f [N/Hz²] and rotor limit [Hz] of the Omnirotor
(SPEC §1.2, §1.4); bidirectional rotors get ``omega_min_hz = -omega_max_hz``."""

_OVERLAY_KEYS = (
    "name",
    "mass",
    "inertia_diag",
    "gravity",
    "c_f",
    "c_tau",
    "omega_max_hz",
    "omega_min_hz",
    "propeller_diameter",
    "p_E_B",
    "frame_size",
)
_PARAM_LINE = re.compile(r"^\s*param\s+(?:set-default|set)\s+([A-Za-z0-9_]+)\s+(\S+)")
_QGC_LINE = re.compile(r"^\s*\d+\s+\d+\s+([A-Za-z0-9_]+)\s+(\S+)\s+\d+\s*$")
"""A QGroundControl ``.params`` line: vehicle id, component id, name, value, MAVLink type."""


def is_airframe_file(path: Path) -> bool:
    """True when the file is text with a ``param set[-default] CA_...`` line or a QGroundControl ``CA_`` line."""
    try:
        with path.open("rb") as fh:
            head = fh.read(65536)
    except OSError:
        return False
    if b"\0" in head:
        return False
    shell = rb"^\s*param\s+(?:set-default|set)\s+CA_"
    qgc = rb"^\s*\d+\s+\d+\s+CA_[A-Za-z0-9_]*\s+\S+\s+\d+\s*$"
    return re.search(shell, head, re.MULTILINE) is not None or re.search(qgc, head, re.MULTILINE) is not None


def read_airframe_params(path: str | Path) -> dict[str, float]:
    """The parameters of an airframe file or a QGroundControl ``.params`` file; later lines win.

    An airframe sets them by ``param set-default NAME VALUE`` lines, a ``.params`` file lists them as
    ``vehicle-id component-id NAME VALUE type``.
    """
    from omnirotor.safe_io import read_text

    text = read_text(path)
    out: dict[str, float] = {}
    for line in text.splitlines():
        m = _PARAM_LINE.match(line.split("#", 1)[0]) or _QGC_LINE.match(line)
        if m:
            try:
                out[m.group(1)] = float(m.group(2))
            except ValueError:
                continue  # a value PX4 takes from a shell variable: not one of ours
    return out


_RANGES = {"PX": (-100.0, 100.0), "PY": (-100.0, 100.0), "PZ": (-100.0, 100.0), "KM": (-1.0, 1.0)}
_RANGES.update({k: (-100.0, 100.0) for k in ("AX", "AY", "AZ")})
"""The range PX4's parameter definitions give each ``CA_ROTORn_*`` value (NaN and inf fall outside)."""


def _rotor_geometry(
    params: Mapping[str, float], where: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, list[str]]:
    """(n, 3) positions and axes (FRD), (n,) KM, the CA_R_REV bitmask, and what took PX4's defaults."""
    if "CA_ROTOR_COUNT" not in params:
        raise InputError(
            f"{where}: no PX4 rotor geometry (parameter CA_ROTOR_COUNT missing; a log from before PX4's control "
            "allocator): pass --vehicle (a preset, a vehicle TOML, a PX4 airframe or a QGroundControl .params file)"
        )
    count = params["CA_ROTOR_COUNT"]
    if not (isinstance(count, (int, float)) and 1 <= count <= MAX_ROTORS and count == int(count)):
        raise InputError(
            f"{where}: CA_ROTOR_COUNT is {count}; expected a whole number from 1 to {MAX_ROTORS}; pass --vehicle"
        )
    n = int(count)
    pos, axis, km = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n)
    defaulted: dict[str, list[int]] = {}
    for i in range(n):
        vals = {}
        for key, dflt in PX4_ROTOR_DEFAULTS.items():
            name = f"CA_ROTOR{i}_{key}"
            if name not in params:
                defaulted.setdefault(key, []).append(i)
            value = params.get(name, dflt)
            lo, hi = _RANGES[key]
            if not (isinstance(value, (int, float)) and lo <= value <= hi):
                raise InputError(f"{where}: {name} is {value}; PX4 allows {lo:g} to {hi:g}")
            vals[key] = float(value)
        pos[i] = (vals["PX"], vals["PY"], vals["PZ"])
        axis[i] = (vals["AX"], vals["AY"], vals["AZ"])
        km[i] = vals["KM"]
    assumed = [
        f"CA_ROTORn_{key} = {PX4_ROTOR_DEFAULTS[key]:g} (PX4's default) for rotor(s) n = {_ranges(rotors)}"
        for key, rotors in defaulted.items()
    ]
    if "CA_R_REV" not in params:
        assumed.append("CA_R_REV = 0 (PX4's default: no reversible rotor)")
    return pos, axis, km, int(params.get("CA_R_REV", 0)), assumed


def _ranges(idx: list[int]) -> str:
    """'0-3, 5' for [0, 1, 2, 3, 5]."""
    out, start = [], idx[0]
    for a, b in zip(idx, [*idx[1:], None], strict=True):
        if b != a + 1:
            out.append(f"{start}" if start == a else f"{start}-{a}")
            start = b
    return ", ".join(out)


def vehicle_from_px4_params(
    params: Mapping[str, float], name: str, where: str, overlay: Mapping[str, Any] | None = None
):
    """Build a vehicle from PX4 ``CA_*`` parameters plus an overlay of what PX4 does not store.

    Args:
        params: PX4 parameters by name.
        name: vehicle name.
        where: what to name in error messages (the file).
        overlay: values of the vehicle file (``mass``, ``inertia_diag``, ``c_f``, ``c_tau``, ``omega_max_hz``,
            ``omega_min_hz``, ``propeller_diameter``, ``p_E_B``, ``frame_size``, ``gravity``, ``name``).

    Returns:
        ``(vehicle, assumed)``: the :class:`~omnirotor.vehicle.VehicleParams` and a list of ``"key = value"``
        strings for every value taken from a default.

    Raises:
        InputError: missing geometry, an unknown overlay key, mixed reversible and one-way rotors, or a
        non-physical result.
    """
    from omnirotor.vehicle_model import RotorParams, VehicleParams

    overlay = {**_omr_values(params), **dict(overlay or {})}
    unknown = sorted(set(overlay) - set(_OVERLAY_KEYS))
    if unknown:
        raise InputError(f"vehicle overlay: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(_OVERLAY_KEYS)}")
    pos_frd, axis_frd, km, rev, assumed = _rotor_geometry(params, where)
    n = pos_frd.shape[0]
    reversible = [(rev >> i) & 1 == 1 for i in range(n)]
    if any(reversible) and not all(reversible):
        raise InputError(f"{where}: CA_R_REV = {rev} makes only some rotors reversible; the model needs all or none")
    pos = vec_from_px4(pos_frd)
    axis = vec_from_px4(axis_frd)
    if np.any(np.linalg.norm(axis, axis=1) < 1e-9):
        raise InputError(f"{where}: a rotor axis CA_ROTORn_A* is zero")

    def pick(key: str, default: Any) -> Any:
        if key in overlay:
            return overlay[key]
        assumed.append(f"{key} = {default}")
        return default

    mass = pick("mass", PX4_DEFAULTS["mass"])
    c_f = pick("c_f", PX4_DEFAULTS["c_f"])
    omega_max = pick("omega_max_hz", PX4_DEFAULTS["omega_max_hz"])
    try:
        mass_f, c_f_f, omega_max_f = float(mass), float(c_f), float(omega_max)
    except (TypeError, ValueError, OverflowError):
        raise InputError("vehicle overlay: mass, c_f and omega_max_hz must be numbers within a float's range") from None
    for key, value in (("mass", mass_f), ("c_f", c_f_f), ("omega_max_hz", omega_max_f)):
        if not (np.isfinite(value) and value > 0):
            raise InputError(f"vehicle overlay: {key} is {value}; expected a finite number > 0")
    lo = -omega_max_f if all(reversible) else PX4_DEFAULTS["omega_min_hz_unidirectional"]
    omega_min = pick("omega_min_hz", lo)
    if "c_tau" in overlay:
        c_tau = overlay["c_tau"]
    else:
        km_abs = np.abs(km)
        c_tau = float(np.mean(km_abs)) * c_f_f
        if np.ptp(km_abs) > 1e-6 * max(1.0, km_abs.max()):
            assumed.append(f"c_tau = mean |CA_ROTORn_KM| x c_f = {c_tau:.4g} (the rotors' KM differ)")
    if "inertia_diag" in overlay:
        inertia = overlay["inertia_diag"]
    else:
        # the mass spread equally over the rotor positions: J = (m/n) sum(|p|² I − p pᵀ), its diagonal
        J = (mass_f / n) * sum(float(p @ p) * np.eye(3) - np.outer(p, p) for p in pos)
        inertia = [round(float(x), 9) for x in np.diag(J)]
        assumed.append(f"inertia_diag = {inertia} (mass at the rotors)")
    spins = [(-1 if k > 0 else 1) for k in km]
    A_rank = _rank(pos, axis, np.array(spins, dtype=float), float(np.mean(np.abs(km))))
    rotors = tuple(
        RotorParams(position=tuple(map(float, pos[i])), spin=spins[i], axis=tuple(map(float, axis[i])))
        for i in range(n)
    )
    span = float(np.abs(pos).max()) if n else 0.1
    data = {
        "name": overlay.get("name", name),
        "mass": mass,
        "inertia_diag": inertia,
        "c_f": c_f,
        "c_tau": c_tau,
        "omega_max_hz": omega_max,
        "omega_min_hz": omega_min,
        "propeller_diameter": pick("propeller_diameter", PX4_DEFAULTS["propeller_diameter"]),
        "actuated_dof": min(6, max(4, A_rank)),
        "frame_size": overlay.get("frame_size", round(max(2.0 * span, 0.05), 4)),
        "rotors": rotors,
    }
    for key in ("gravity", "p_E_B"):
        if key in overlay:
            data[key] = overlay[key]
    return from_mapping(VehicleParams, data, where), assumed


_OMR = {
    "OMR_MASS": "mass",
    "OMR_CF": "c_f",
    "OMR_CTAU": "c_tau",
    "OMR_WMAX": "omega_max_hz",
    "OMR_WMIN": "omega_min_hz",
    "OMR_G": "gravity",
    "OMR_PROP_D": "propeller_diameter",
}


def _omr_values(params: Mapping[str, float]) -> dict[str, Any]:
    """Vehicle values our own logs store as ``OMR_*`` parameters (:func:`omnirotor.px4.run_export.px4_params_of`)."""
    out: dict[str, Any] = {key: float(params[name]) for name, key in _OMR.items() if name in params}
    if all(f"OMR_J{a}{a}" in params for a in "XYZ"):
        out["inertia_diag"] = [float(params[f"OMR_J{a}{a}"]) for a in "XYZ"]
    if all(f"OMR_EE_{a}" in params for a in "XYZ"):
        out["p_E_B"] = [float(params[f"OMR_EE_{a}"]) for a in "XYZ"]
    return out


def _rank(pos: np.ndarray, axis: np.ndarray, spins: np.ndarray, km: float) -> int:
    from omnirotor.vehicle_model import wrench_map

    a = axis / np.linalg.norm(axis, axis=1, keepdims=True)
    A = wrench_map(pos, a, spins, 1.0, km)
    return int(np.linalg.matrix_rank(A, tol=1e-9 * np.abs(A).max()))


def load_overlay(path: str | Path | None) -> dict[str, Any]:
    """The TOML overlay of a PX4 vehicle ({} for None)."""
    if path is None:
        return {}
    data = load_toml(path)
    if "rotor" in data:
        raise InputError(f"{path}: an overlay cannot define rotors (they come from the PX4 parameters)")
    return data
