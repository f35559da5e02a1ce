"""The criteria of a steady hover window (:mod:`omnirotor.px4.windows`, SPEC §3.1), with no heavy import.

The command line builds its options from :class:`WindowCriteria`'s defaults when it starts, so this module
imports neither NumPy nor pyulog.
"""

from __future__ import annotations

import dataclasses
import math

from omnirotor.errors import InputError

__all__ = ["WindowCriteria", "OPTION_OF"]


@dataclasses.dataclass(frozen=True)
class WindowCriteria:
    """Criteria of a steady hover window (module docstring).

    Attributes:
        accel_max: largest world acceleration, low-passed at ``motion_cutoff_hz`` [m/s²].
        rate_max: largest body rate, low-passed at ``motion_cutoff_hz`` [rad/s].
        speed_max: largest speed [m/s] (inf: unaccelerated flight counts as hover).
        drift_max_deg: largest attitude change within a window [deg].
        spread_frac: largest deviation of a rotor's input ``|omega| omega`` (its thrust, from the speed
            low-passed at ``motion_cutoff_hz``) from its window mean, relative to the rotors' mean ``|u|``.
        spread_min_hz2: floor of that deviation [Hz²].
        spin_fraction: the mean |omega| must exceed this fraction of its 95th percentile over the flight.
        min_duration_s: shortest window [s].
        trim_s: cut from both ends of a window [s]; 0.2 s is about the settling time of the 5 Hz low-pass,
            so a window does not average the filter's smear of the change that ended or began it.
        cutoff_hz: zero-phase low-pass cutoff of the rotor speeds that are averaged [Hz] (SPEC §3.1: 5 Hz,
            4th order).
        motion_cutoff_hz: zero-phase low-pass cutoff of the signals the criteria read [Hz]: the hover's
            bandwidth, far below the rotor-rate vibration (module docstring).
        grid_hz: rate of the grid the criteria are evaluated on [Hz].
    """

    accel_max: float = 0.3
    rate_max: float = 0.1
    speed_max: float = math.inf
    drift_max_deg: float = 3.0
    spread_frac: float = 0.1
    spread_min_hz2: float = 100.0
    spin_fraction: float = 0.5
    min_duration_s: float = 1.0
    trim_s: float = 0.2
    cutoff_hz: float = 5.0
    motion_cutoff_hz: float = 1.0
    grid_hz: float = 50.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if not (v >= 0) or (f.name != "speed_max" and not math.isfinite(v)):
                what = OPTION_OF.get(f.name, f.name)
                raise InputError(f"hover-window criterion {what} must be a finite number >= 0, got {v}")
        if self.grid_hz <= 0 or self.cutoff_hz <= 0 or self.motion_cutoff_hz <= 0:
            raise InputError("hover-window grid_hz, --cutoff and --motion-cutoff must be > 0")


OPTION_OF = {
    "accel_max": "--accel-max",
    "rate_max": "--rate-max",
    "speed_max": "--speed-max",
    "drift_max_deg": "--drift-max",
    "spread_frac": "--spread-max",
    "spread_min_hz2": "--spread-min",
    "spin_fraction": "--spin-fraction",
    "min_duration_s": "--min-duration",
    "trim_s": "--trim",
    "cutoff_hz": "--cutoff",
    "motion_cutoff_hz": "--motion-cutoff",
}
"""The command-line option of each criterion (``hover-windows`` and ``identify`` take them all)."""
