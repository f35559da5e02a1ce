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
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from omnirotor.errors import InputError
from omnirotor.regions import Partition, load_partition, partition_from_dict

__all__ = ["MapEntry", "WrenchMapSet", "load_wrench_maps", "SCHEMA", "SCHEMA_VERSION", "write_json_atomic"]

SCHEMA = "omnirotor/wrench-maps"
SCHEMA_VERSION = 1


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


def write_json_atomic(path: str | Path, obj: Any) -> None:
    """Write ``obj`` as JSON to ``path`` through a temporary file and a rename."""
    p = Path(path)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=p.parent, prefix=f".{p.name}.", suffix=".tmp")
    except OSError as exc:
        raise InputError(f"{p}: cannot write ({exc.strerror})") from None
    try:
        with os.fdopen(fd, "w") as fh:
            json.dump(obj, fh, indent=1)
            fh.write("\n")
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


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


def _entry(value: Any, shape: tuple[int, int], where: str) -> MapEntry:
    if not isinstance(value, dict) or "A" not in value:
        raise InputError(f"{where}: expected an object with key 'A'")

    def num(key: str) -> float | None:
        v = value.get(key)
        if v is None:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise InputError(f"{where}.{key}: expected a finite number, got {v!r}")
        return float(v)

    points = value.get("points", 0)
    if isinstance(points, bool) or not isinstance(points, int) or points < 0:
        raise InputError(f"{where}.points: expected a count, got {points!r}")
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
    try:
        data = json.loads(p.read_text())
    except FileNotFoundError:
        raise InputError(f"{p}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: cannot read ({exc})") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{p}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise InputError(f"{p}: not a wrench-map file (schema must be {SCHEMA!r})")
    if data.get("version") != SCHEMA_VERSION:
        raise InputError(f"{p}: schema version {data.get('version')!r} unsupported (this build reads {SCHEMA_VERSION})")
    n = data.get("n_rotors")
    if isinstance(n, bool) or not isinstance(n, int) or n < 4:
        raise InputError(f"{p}: n_rotors must be an integer >= 4")
    if n_rotors is not None and n != n_rotors:
        raise InputError(f"{p}: maps are for {n} rotors, the vehicle has {n_rotors}")
    shape = (6, n)
    nominal = _matrix(data.get("nominal"), shape, f"{p}: nominal")
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
    delta = data.get("delta")
    weights = data.get("weights") or ()
    if not isinstance(weights, list) or not all(
        isinstance(w, (int, float)) and not isinstance(w, bool) and math.isfinite(w) for w in weights
    ):
        raise InputError(f"{p}: weights must be an array of finite numbers")
    return WrenchMapSet(
        vehicle=str(data.get("vehicle", "")),
        nominal=nominal,
        partition=partition,
        regions=regions,
        global_=_entry(g, shape, f"{p}: global") if g is not None else None,
        delta=float(delta) if isinstance(delta, (int, float)) and not isinstance(delta, bool) else None,
        weights=tuple(float(w) for w in weights),
        rho=data.get("rho"),
    )
