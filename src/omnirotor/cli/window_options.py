"""The hover-window criteria as command-line options, shared by ``hover-windows`` and ``identify``.

Each option's default is :class:`~omnirotor.px4.criteria.WindowCriteria`'s; a command declares the options with
these types and passes its values to :func:`criteria`.
"""

from __future__ import annotations

from typing import Annotated

import typer

from omnirotor.cli import number_option
from omnirotor.px4.criteria import WindowCriteria

DEFAULT = WindowCriteria()
"""The default criteria (every option's default)."""


def _number(text: str | float) -> float:
    """An option's number (typer passes the default through the parser too)."""
    return float(text) if isinstance(text, float) else number_option(text)


def _opt(help_text: str):
    return typer.Option(help=help_text, parser=_number)


MinDuration = Annotated[float, _opt("Shortest hover window, after trimming [s].")]
AccelMax = Annotated[
    float, _opt("Largest acceleration in a window [m/s²] (derivative of the velocity low-passed at --motion-cutoff).")
]
RateMax = Annotated[float, _opt("Largest body rate in a window [rad/s] (low-passed at --motion-cutoff).")]
SpeedMax = Annotated[float, _opt("Largest speed in a window [m/s] (inf: steady climbs and descents count).")]
DriftMax = Annotated[float, _opt("Largest attitude change within a window [deg].")]
SpreadMax = Annotated[
    float, _opt("Largest change of a rotor's thrust (|ω|ω) within a window, as a fraction of the rotors' mean.")
]
SpreadMin = Annotated[float, _opt("Floor of that change [Hz²].")]
SpinFraction = Annotated[
    float, _opt("Flying: mean |ω| above this fraction of its 95th percentile over the flight (not on the ground).")
]
Trim = Annotated[float, _opt("Cut from both ends of each window [s].")]
Cutoff = Annotated[float, _opt("Low-pass cutoff of the rotor speeds that are averaged [Hz] (SPEC §3.1).")]
MotionCutoff = Annotated[
    float, _opt("Low-pass cutoff of the signals the criteria read [Hz]: the hover's bandwidth, below vibration.")
]


def criteria(
    min_duration: float,
    accel_max: float,
    rate_max: float,
    speed_max: float,
    drift_max: float,
    spread_max: float,
    spread_min: float,
    spin_fraction: float,
    trim: float,
    cutoff: float,
    motion_cutoff: float,
) -> WindowCriteria:
    """The criteria of the options' values (an invalid one raises :class:`~omnirotor.errors.InputError`)."""
    return WindowCriteria(
        accel_max=accel_max,
        rate_max=rate_max,
        speed_max=speed_max,
        drift_max_deg=drift_max,
        spread_frac=spread_max,
        spread_min_hz2=spread_min,
        spin_fraction=spin_fraction,
        min_duration_s=min_duration,
        trim_s=trim,
        cutoff_hz=cutoff,
        motion_cutoff_hz=motion_cutoff,
    )
