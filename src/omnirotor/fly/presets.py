"""Flight parameters (:class:`FlyParams`, TOML) and the named admittance presets a flight can switch to.

The admittance presets are the sets of the paper's Table 2 (SPEC §5.1: "PC" point contact, "SD" sliding,
"PiH" peg-in-hole) and the free-flight set, as :data:`omnirotor.control.admittance.ADMITTANCE_PRESETS`
defines them (written once, there); a flight file may add its own under ``[admittance_presets.NAME]`` with
the keys of :class:`~omnirotor.control.admittance.AdmittanceParams`.

The default flight file is ``presets/fly/default.toml``; :func:`load_fly_params` reads it or another one and
applies dotted ``key=value`` overrides, rejecting unknown keys.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from types import MappingProxyType

from omnirotor.config import apply_overrides, check_finite, check_positive, from_mapping, load_toml
from omnirotor.control.admittance import ADMITTANCE_PRESETS, AdmittanceParams
from omnirotor.errors import InputError

__all__ = ["FlyParams", "load_fly_params", "DEFAULT_FLY_FILE", "admittance_presets"]

DEFAULT_FLY_FILE = Path(__file__).resolve().parent.parent / "presets" / "fly" / "default.toml"
"""The flight parameters the node uses unless told otherwise."""

Vec3 = tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class FlyParams:
    """What the flight logic may do and when it must give up (every limit of a setpoint is here).

    Positions are of the end-effector (EE) tip unless the name says ``body``; the workspace box bounds both
    the body (CoM) and the EE, world frame.

    Attributes:
        takeoff_height_m: default height of the take-off above the pose where the vehicle was armed [m].
        max_takeoff_height_m: largest take-off height a request may ask for [m].
        climb_speed_mps: largest vertical speed of the take-off reference [m/s].
        land_speed_mps: largest descent speed of the landing reference [m/s].
        max_speed_mps: largest speed of a goto reference [m/s].
        max_acc_mps2: largest acceleration of any reference segment [m/s²].
        max_rate_dps: largest angular rate of a reference segment [deg/s].
        min_segment_s: shortest reference segment [s].
        workspace_min_m: (3,) lower corner of the flight volume [m], world frame.
        workspace_max_m: (3,) upper corner [m].
        max_depth_m: largest penetration depth a push may ask for [m] (SPEC §5: force ≈ K_E · depth).
        depth_speed_mps: largest speed of the reference along the contact normal while the depth changes [m/s].
        contact_preset: admittance preset entered with contact (a push from hover), e.g. "PC" (Table 2).
        free_preset: admittance preset of free flight (take-off, goto, leaving contact).
        imu_stale_s: IMU older than this degrades the flight [s] (the failsafe, :mod:`omnirotor.fly.failsafe`).
        mocap_stale_s: motion capture older than this degrades the flight [s].
        hold_after_s: a link stale this long past its limit makes the vehicle hold [s].
        land_after_s: a link stale this long past its limit makes the vehicle land [s] (> hold_after_s).
        touchdown_height_m: within this height of the take-off height the vehicle may be on the ground [m].
        touchdown_speed_mps: and moving less than this (vertically) [m/s] ...
        touchdown_dwell_s: ... for this long [s]: touchdown, the vehicle disarms.
        land_timeout_s: the vehicle disarms this long after the landing reference reached the ground even
            without touchdown detected [s] (a bounded landing).
        idle_hz: rotor speed while armed on the ground [Hz] (0 for reversible propellers: no thrust).
        geofence_margin_m: motion capture puts the body further than this outside the workspace box in flight:
            the flight is terminated (rotors stopped, disarmed) [m]. Every reference stays inside the box, so a
            vehicle this far outside it is not under control (:mod:`omnirotor.fly.failsafe`).
        divergence_m: the controller's position estimate and motion capture disagree by more than this ...
        divergence_s: ... for this long in flight: the flight is terminated [s] (a controller flying on an estimate
            that left the vehicle would fly it away while believing it is on its reference).
        admittance_presets: presets added by the flight file (name, parameters); the built-in ones
            (:func:`admittance_presets`) cannot be redefined.
    """

    takeoff_height_m: float = 0.5
    max_takeoff_height_m: float = 2.0
    climb_speed_mps: float = 0.3
    land_speed_mps: float = 0.2
    max_speed_mps: float = 0.5
    max_acc_mps2: float = 1.0
    max_rate_dps: float = 30.0
    min_segment_s: float = 1.0
    workspace_min_m: Vec3 = (-2.0, -2.0, 0.0)
    workspace_max_m: Vec3 = (2.0, 2.0, 2.5)
    max_depth_m: float = 0.15
    depth_speed_mps: float = 0.05
    contact_preset: str = "PC"
    free_preset: str = "free"
    imu_stale_s: float = 0.020
    mocap_stale_s: float = 0.200
    hold_after_s: float = 0.5
    land_after_s: float = 2.0
    touchdown_height_m: float = 0.05
    touchdown_speed_mps: float = 0.05
    touchdown_dwell_s: float = 1.0
    land_timeout_s: float = 10.0
    idle_hz: float = 0.0
    geofence_margin_m: float = 0.5
    divergence_m: float = 0.3
    divergence_s: float = 0.1
    admittance_presets: tuple[tuple[str, AdmittanceParams], ...] = ()

    def __post_init__(self) -> None:
        for name in (
            "takeoff_height_m", "max_takeoff_height_m", "climb_speed_mps", "land_speed_mps", "max_speed_mps",
            "max_acc_mps2", "max_rate_dps", "min_segment_s", "max_depth_m", "depth_speed_mps", "imu_stale_s",
            "mocap_stale_s", "hold_after_s", "land_after_s", "touchdown_height_m", "touchdown_speed_mps",
            "touchdown_dwell_s", "land_timeout_s", "geofence_margin_m", "divergence_m", "divergence_s",
        ):  # fmt: skip
            check_positive(f"fly {name}", getattr(self, name))
        check_finite("fly idle_hz", self.idle_hz)
        for name in ("workspace_min_m", "workspace_max_m"):
            value = getattr(self, name)
            if len(value) != 3:
                raise InputError(f"fly {name} must have 3 values, got {len(value)}")
            check_finite(f"fly {name}", *value)
        if not all(lo < hi for lo, hi in zip(self.workspace_min_m, self.workspace_max_m, strict=True)):
            raise InputError(f"fly workspace_min_m {self.workspace_min_m} must be below workspace_max_m")
        if self.takeoff_height_m > self.max_takeoff_height_m:
            raise InputError("fly takeoff_height_m must be <= max_takeoff_height_m")
        if not self.land_after_s > self.hold_after_s:
            raise InputError("fly land_after_s must be > hold_after_s (a stale link first holds, then lands)")
        names = [name for name, _ in self.admittance_presets]
        clash = sorted(set(names) & set(ADMITTANCE_PRESETS))
        if clash:
            raise InputError(f"fly admittance preset(s) {', '.join(clash)} redefine a built-in preset")
        if len(set(names)) != len(names):
            raise InputError("fly admittance presets: a name is given twice")
        known = set(names) | set(ADMITTANCE_PRESETS)
        for name in ("contact_preset", "free_preset"):
            if getattr(self, name) not in known:
                raise InputError(
                    f"fly {name} {getattr(self, name)!r} is not a preset; presets: {', '.join(sorted(known))}"
                )
        if not math.isfinite(self.max_rate_dps):  # pragma: no cover (check_positive covers it)
            raise InputError("fly max_rate_dps must be finite")

    def in_workspace(self, p_W) -> bool:
        """True if the point ``p_W`` (3,) [m] lies in the flight volume (closed box)."""
        return all(
            lo <= float(x) <= hi for lo, x, hi in zip(self.workspace_min_m, p_W, self.workspace_max_m, strict=True)
        )


def admittance_presets(params: FlyParams | None = None) -> MappingProxyType:
    """The admittance presets by name: Table 2's and the free-flight set, then the flight file's own."""
    presets = dict(ADMITTANCE_PRESETS)
    if params is not None:
        presets.update(params.admittance_presets)
    return MappingProxyType(presets)


def load_fly_params(
    path: str | Path | None = DEFAULT_FLY_FILE, overrides: list[str] | tuple[str, ...] = ()
) -> FlyParams:
    """Flight parameters from a TOML file (default ``presets/fly/default.toml``) and dotted overrides.

    The file's top-level keys are the fields of :class:`FlyParams`; ``[admittance_presets.NAME]`` tables add
    presets with the keys of :class:`~omnirotor.control.admittance.AdmittanceParams`. Unknown keys are errors.

    Args:
        path: the file, or None for the dataclass defaults.
        overrides: ``key=value`` items applied after the file (e.g. ``"max_speed_mps=0.3"``).

    Raises:
        InputError: unreadable file, unknown key, bad value.
    """
    if path is None:
        return apply_overrides(FlyParams(), list(overrides))
    data = dict(load_toml(path))
    tables = data.pop("admittance_presets", {})
    if not isinstance(tables, dict):
        raise InputError(f"{path}: admittance_presets must be a table of tables")
    extra = tuple(
        (str(name), from_mapping(AdmittanceParams, table, f"{path}: admittance_presets.{name}"))
        for name, table in tables.items()
    )
    data["admittance_presets"] = extra
    params = from_mapping(FlyParams, data, str(path))
    return apply_overrides(params, list(overrides))
