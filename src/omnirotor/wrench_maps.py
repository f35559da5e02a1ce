"""Wrench-map files: the nominal, global and per-region maps of a vehicle (schema ``omnirotor/wrench-maps`` v1).

A wrench map ``A`` (6 x n) sends rotor inputs ``u`` [Hz²] to the body wrench at the CoM (rows fx fy fz
[N/Hz²] and mx my mz [N·m/Hz²], columns rotors 1..n), SPEC §1.2. The file is JSON::

    {
      "schema": "omnirotor/wrench-maps", "version": 1,
      "vehicle": "omnirotor", "n_rotors": 8,
      "delta": 3e-05, "weights": [10, 10, 10, 1e-12, 1e-12, 1e-12], "rho": 1e-08,
      "partition": {"name": "paper", "region": [...]},          # the regions, as in presets/regions/*.toml
      "nominal": [[...8], ...6],
      "global":  {"A": [[...]], "points": 39, "force_residual_rms_N": 0.52,
                  "nominal_force_residual_rms_N": 2.2, "identified": true},
      "regions": {"R1": {same keys as global}, ..., "R10": {...}}
    }

A region without data keeps the nominal map (``identified: false``, ``points: 0``, residuals ``null``),
as on the paper's vehicle where only R1, R3 and R4 were flown (SPEC §3.3).

Loading refuses unknown keys, non-finite entries, and degenerate maps (issue 14): a map whose rank is below
the nominal map's, or any entry farther from nominal than :data:`MAX_RELATIVE_CHANGE` times the largest
nominal entry (an identified map moves each entry by at most Δ, a few per cent).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np

from omnirotor.errors import InputError
from omnirotor.regions import Partition, load_partition, partition_from_dict
from omnirotor.safe_io import load_json, write_json_atomic

__all__ = ["MapEntry", "WrenchMapSet", "load_wrench_maps", "SCHEMA", "SCHEMA_VERSION", "write_json_atomic"]

SCHEMA = "omnirotor/wrench-maps"
SCHEMA_VERSION = 1
MAX_RELATIVE_CHANGE = 1.0
"""Largest ``max |A - A_nom|`` of a loaded map, relative to ``max |A_nom|``."""
_TOP_KEYS = {"schema", "version", "vehicle", "n_rotors", "delta", "weights", "rho", "partition", "nominal"}
_TOP_KEYS |= {"global", "regions"}
_ENTRY_KEYS = {"A", "points", "force_residual_rms_N", "nominal_force_residual_rms_N", "identified"}


@dataclasses.dataclass(frozen=True)
class MapEntry:
    """One identified map and how well it fits its data.

    Attributes:
        A: (6, n) the map.
        points: number of hover points it was fitted on.
        force_residual_rms_N: RMS over points of the force-residual norm ``|f_j - A_1 u_j|`` [N].
        nominal_force_residual_rms_N: the same for the nominal map on the same points [N].
        identified: False when the region had no data and keeps the nominal map.
    """

    A: np.ndarray
    points: int = 0
    force_residual_rms_N: float | None = None
    nominal_force_residual_rms_N: float | None = None
    identified: bool = False

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {
            "A": self.A.tolist(),
            "points": self.points,
            "force_residual_rms_N": self.force_residual_rms_N,
            "nominal_force_residual_rms_N": self.nominal_force_residual_rms_N,
            "identified": self.identified,
        }


@dataclasses.dataclass(frozen=True)
class WrenchMapSet:
    """Nominal, global and per-region wrench maps of one vehicle."""

    vehicle: str
    nominal: np.ndarray
    partition: Partition
    regions: dict[str, MapEntry]
    global_: MapEntry | None = None
    delta: float | None = None
    weights: tuple[float, ...] = ()
    rho: float | None = None

    def region_maps(self) -> list[np.ndarray]:
        """The map of each region in partition order (nominal where a region has none)."""
        return [self.regions[n].A if n in self.regions else self.nominal for n in self.partition.names]

    def to_dict(self) -> dict[str, Any]:
        """JSON form (schema v1)."""
        return {
            "schema": SCHEMA,
            "version": SCHEMA_VERSION,
            "vehicle": self.vehicle,
            "n_rotors": int(self.nominal.shape[1]),
            "delta": self.delta,
            "weights": list(self.weights),
            "rho": self.rho,
            "partition": self.partition.to_dict(),
            "nominal": self.nominal.tolist(),
            "global": self.global_.to_dict() if self.global_ is not None else None,
            "regions": {n: self.regions[n].to_dict() for n in self.partition.names if n in self.regions},
        }

    def save(self, path: str | Path) -> None:
        """Write the JSON file atomically (nothing half-written on failure)."""
        write_json_atomic(path, self.to_dict())


def _matrix(value: Any, shape: tuple[int, int], where: str) -> np.ndarray:
    try:
        A = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{where}: not a numeric matrix") from None
    if A.shape != shape:
        raise InputError(f"{where}: shape {A.shape}, expected {shape}")
    if not np.all(np.isfinite(A)):
        raise InputError(f"{where}: contains NaN or inf")
    return A


def _finite(v: Any) -> bool:
    """A JSON number that is a finite float (not a bool, not an integer too big for a float)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    try:
        return math.isfinite(float(v))
    except OverflowError:
        return False


def _rank(A: np.ndarray) -> int:
    scale = float(np.abs(A).max())
    return 0 if scale == 0.0 else int(np.linalg.matrix_rank(A, tol=1e-9 * scale))


def _check_map(A: np.ndarray, nominal: np.ndarray, where: str) -> None:
    """Refuse a degenerate map: rank below the nominal's, or entries implausibly far from nominal."""
    scale = float(np.abs(nominal).max())
    change = float(np.abs(A - nominal).max())
    if change > MAX_RELATIVE_CHANGE * scale:
        raise InputError(
            f"{where}: an entry differs from nominal by {change:.3g}, more than {MAX_RELATIVE_CHANGE:g} x the "
            f"largest nominal entry ({scale:.3g}); not a map of this vehicle"
        )
    rank, rank_nom = _rank(A), _rank(nominal)
    if rank < rank_nom:
        raise InputError(f"{where}: degenerate map of rank {rank} (the nominal map has rank {rank_nom})")


def _entry(value: Any, shape: tuple[int, int], where: str) -> MapEntry:
    if not isinstance(value, dict) or "A" not in value:
        raise InputError(f"{where}: expected an object with key 'A'")
    unknown = sorted(set(value) - _ENTRY_KEYS)
    if unknown:
        raise InputError(f"{where}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(_ENTRY_KEYS))}")

    def num(key: str) -> float | None:
        v = value.get(key)
        if v is None:
            return None
        if not _finite(v):
            raise InputError(f"{where}.{key}: expected a finite number")
        return float(v)

    points = value.get("points", 0)
    if isinstance(points, bool) or not isinstance(points, int) or not 0 <= points <= 10**9:
        raise InputError(f"{where}.points: expected a count of hover points (0 to 10^9)")
    return MapEntry(
        A=_matrix(value["A"], shape, f"{where}.A"),
        points=points,
        force_residual_rms_N=num("force_residual_rms_N"),
        nominal_force_residual_rms_N=num("nominal_force_residual_rms_N"),
        identified=bool(value.get("identified", points > 0)),
    )


def load_wrench_maps(path: str | Path, n_rotors: int | None = None) -> WrenchMapSet:
    """Read and validate a wrench-map JSON file.

    Args:
        path: the file.
        n_rotors: when given, the maps must have this many columns.

    Raises:
        InputError: missing or corrupt file, wrong schema or version, wrong shapes, NaN or inf.
    """
    p = Path(path)
    data = load_json(p)
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise InputError(f"{p}: not a wrench-map file (schema must be {SCHEMA!r})")
    unknown = sorted(str(k) for k in set(data) - _TOP_KEYS)
    if unknown:
        raise InputError(f"{p}: unknown key(s) {', '.join(unknown)[:200]}; allowed: {', '.join(sorted(_TOP_KEYS))}")
    if data.get("version") != SCHEMA_VERSION:
        raise InputError(f"{p}: schema version {data.get('version')!r} unsupported (this build reads {SCHEMA_VERSION})")
    n = data.get("n_rotors")
    if isinstance(n, bool) or not isinstance(n, int) or n < 4:
        raise InputError(f"{p}: n_rotors must be an integer >= 4")
    if n_rotors is not None and n != n_rotors:
        raise InputError(f"{p}: maps are for {n} rotors, the vehicle has {n_rotors}")
    shape = (6, n)
    nominal = _matrix(data.get("nominal"), shape, f"{p}: nominal")
    if _rank(nominal) < 4:
        raise InputError(f"{p}: nominal map of rank {_rank(nominal)}; a vehicle's map has rank 4 to 6")
    part_raw = data.get("partition")
    partition = partition_from_dict(part_raw, f"{p}: partition") if part_raw else load_partition("paper")
    regions_raw = data.get("regions") or {}
    if not isinstance(regions_raw, dict):
        raise InputError(f"{p}: regions must be an object")
    regions = {}
    for name, value in regions_raw.items():
        partition.region(name)  # unknown names are an error
        regions[name] = _entry(value, shape, f"{p}: regions.{name}")
    g = data.get("global")
    global_ = _entry(g, shape, f"{p}: global") if g is not None else None
    for name, e in [*regions.items(), *([("global", global_)] if global_ is not None else [])]:
        _check_map(e.A, nominal, f"{p}: {'regions.' if name != 'global' else ''}{name}.A")
    delta = data.get("delta")
    if delta is not None and not (_finite(delta) and delta > 0):
        raise InputError(f"{p}: delta must be a finite number > 0, or null")
    rho = data.get("rho")
    if rho is not None and not _finite(rho):
        raise InputError(f"{p}: rho must be a finite number, or null")
    weights = data.get("weights") or ()
    if not isinstance(weights, list) or not all(_finite(w) for w in weights):
        raise InputError(f"{p}: weights must be an array of finite numbers")
    return WrenchMapSet(
        vehicle=str(data.get("vehicle", "")),
        nominal=nominal,
        partition=partition,
        regions=regions,
        global_=global_,
        delta=float(delta) if delta is not None else None,
        weights=tuple(float(w) for w in weights),
        rho=float(rho) if rho is not None else None,
    )
