"""Steady hover windows found automatically in a flight, and their hover points (SPEC §3.1).

The authors picked hover windows by hand. Here a window is a stretch in which the vehicle is in force and
moment balance, so that the rotors' force equals ``R_WBᵀ m g e3`` (SPEC §3.1). Unaccelerated flight (a steady
climb or descent) balances the weight as hover does, up to drag, so the criteria are on acceleration, not on
speed.

**Filtered signals.** A hover point is an average over a second or more, so what matters is the vehicle's
motion in the hover's bandwidth, not what an IMU reads instant by instant: a real accelerometer (and the
simulator's, calibrated on the paper's robot) carries rotor-rate vibration (the rotors turn at 50-200 Hz) and
broadband noise of 0.5-3 m/s², and the rotor speeds jitter by a few Hz while the attitude loop fights it.
The motion criteria therefore read signals low-passed at ``motion_cutoff_hz`` = 1 Hz (zero-phase 4th-order
Butterworth): about the position loop's bandwidth, two decades below the rotor rates, and fast enough to see
any transition between holds (a minimum-jerk move of a second or more). The acceleration is the derivative
of the low-passed velocity (fused with motion capture or GPS, so free of the accelerometer's bias); only a
log without velocity uses the low-passed acceleration ``a_W`` instead.

On a uniform time grid (``grid_hz``), a sample is *steady* when

* the world acceleration ``|a_W|`` < ``accel_max`` (skipped when the log has neither velocity nor
  acceleration);
* the body rate ``|omega_B|`` < ``rate_max`` (skipped without rate data);
* the mean rotor speed ``mean_i |omega_i|`` > ``spin_fraction`` × its 95th percentile over the flight (the
  vehicle is flying, not idling on the ground), and the log's land detector (if any) says airborne;
* optionally the speed ``|v_W|`` < ``speed_max`` (off by default).

Each run of steady samples is cut greedily into windows in which the attitude stays within ``drift_max_deg``
of the window's first attitude and every rotor speed (low-passed at ``motion_cutoff_hz``) within
``spread_frac`` × (mean |omega|) (at least ``spread_min_hz``) of its running window mean. ``trim_s`` is cut
from both ends of each window, and windows shorter than ``min_duration_s`` are dropped. How much of the flight
each criterion rejected is kept (:attr:`HoverPoints.rejections`) and said when few or no windows are found.

A window's hover point is the projected mean attitude and the mean signed input ``u = mean(|omega| omega)``
over the window's samples of the rotor speeds low-passed at ``cutoff_hz`` = 5 Hz (SPEC §3.1). A signal sampled
too slowly for a filter (below 2.5 × its cutoff) is used unfiltered, and that is reported. The CSV stores
``omega = sign(u) sqrt(|u|)``, which :func:`omnirotor.identification.load_csv` turns back into the same ``u``.
(SPEC §3.1 squares the mean speed instead: the two differ by the speed's variance over the window, ≤ 0.01 % in
steady windows.)
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from omnirotor.errors import InputError
from omnirotor.px4.criteria import OPTION_OF, WindowCriteria
from omnirotor.px4.flight import Flight, Series, read_flight
from omnirotor.so3 import project_to_SO3

__all__ = [
    "WindowCriteria",
    "HoverWindow",
    "find_hover_windows",
    "HoverPoints",
    "hover_points",
    "plot_windows",
    "motion_signals",
    "flight_hover_points",
    "read_flight_log",
    "say_windows",
    "on_grid",
]


@dataclasses.dataclass(frozen=True)
class HoverWindow:
    """One steady window: ``[t0_s, t1_s]`` since the log's start [s]."""

    t0_s: float
    t1_s: float


@dataclasses.dataclass(frozen=True)
class HoverPoints:
    """The hover points of a flight.

    Attributes:
        windows: the windows.
        R_WB: (k, 3, 3) mean attitude of each window.
        u_hz2: (k, n) mean signed inputs ``|omega| omega`` [Hz²].
        notes: what was assumed or skipped (for stderr).
        rejections: one line per criterion: how much of the flight it rejected (for stderr when few windows).
    """

    windows: tuple[HoverWindow, ...]
    R_WB: np.ndarray
    u_hz2: np.ndarray
    notes: tuple[str, ...]
    rejections: tuple[str, ...] = ()

    @property
    def omega_hz(self) -> np.ndarray:
        """(k, n) the speeds whose ``|omega| omega`` is ``u_hz2`` [Hz] (the CSV's columns)."""
        return np.sign(self.u_hz2) * np.sqrt(np.abs(self.u_hz2))


def _lowpass(s: Series, cutoff_hz: float, what: str, notes: list[str]) -> np.ndarray:
    """Zero-phase 4th-order Butterworth of a series (SPEC §3.1), or the raw values when sampled too slowly."""
    from scipy.signal import butter, sosfiltfilt

    if s.t.size < 16:
        notes.append(f"{what}: too few samples to filter, used unfiltered")
        return s.x
    fs = 1.0 / float(np.median(np.diff(s.t)))
    if fs < 2.5 * cutoff_hz:
        notes.append(f"{what} sampled at {fs:.1f} Hz, too slow for the {cutoff_hz:g} Hz low-pass: used unfiltered")
        return s.x
    sos = butter(4, cutoff_hz, fs=fs, output="sos")
    return sosfiltfilt(sos, s.x, axis=0, padlen=min(s.t.size - 1, 3 * (2 * sos.shape[0] + 1)))


def on_grid(t: np.ndarray, s_t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The samples ``x`` (taken at times ``s_t``, along axis 0) linearly interpolated at the times ``t``."""
    x2 = x.reshape(x.shape[0], -1)
    out = np.column_stack([np.interp(t, s_t, x2[:, j]) for j in range(x2.shape[1])])
    return out.reshape((t.size, *x.shape[1:]))


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def motion_signals(
    flight: Flight, t: np.ndarray, c: WindowCriteria, notes: list[str] | None = None
) -> dict[str, tuple[str, np.ndarray, float]]:
    """The low-passed motion the acceleration and rate criteria read, on the grid ``t`` (module docstring).

    Returns:
        criterion name -> (the signal's label, its values, the criterion's limit).
    """
    notes = [] if notes is None else notes
    out: dict[str, tuple[str, np.ndarray, float]] = {}
    fc = c.motion_cutoff_hz
    if flight.v_W is not None and flight.v_W.t.size > 2:
        a = np.gradient(_lowpass(flight.v_W, fc, "velocity", notes), flight.v_W.t, axis=0)
        out["accel_max"] = ("|dv/dt|", np.linalg.norm(on_grid(t, flight.v_W.t, a), axis=1), c.accel_max)
    elif flight.a_W is not None:
        a = _lowpass(flight.a_W, fc, "acceleration", notes)
        out["accel_max"] = ("|a_W|", np.linalg.norm(on_grid(t, flight.a_W.t, a), axis=1), c.accel_max)
    else:
        notes.append("no local position in the log: the acceleration criterion was skipped")
    if flight.omega_B is not None:
        w = _lowpass(flight.omega_B, fc, "angular rate", notes)
        out["rate_max"] = ("|omega_B|", np.linalg.norm(on_grid(t, flight.omega_B.t, w), axis=1), c.rate_max)
    else:
        notes.append("no angular rate in the log: the rate criterion was skipped")
    return out


def _sample_tests(
    flight: Flight, t: np.ndarray, c: WindowCriteria, omega: np.ndarray, notes: list[str]
) -> dict[str, tuple[str, np.ndarray]]:
    """Each per-sample criterion's verdict on the grid: name -> (what it demands, True where it passes)."""
    tests: dict[str, tuple[str, np.ndarray]] = {}
    units = {"accel_max": "m/s²", "rate_max": "rad/s"}
    for key, (label, value, limit) in motion_signals(flight, t, c, notes).items():
        tests[key] = (f"{label} < {limit:g} {units[key]}", value < limit)
    if math.isfinite(c.speed_max):
        if flight.v_W is None:
            raise InputError(f"{flight.name}: a speed limit needs velocity (topic vehicle_local_position missing)")
        speed = np.linalg.norm(on_grid(t, flight.v_W.t, flight.v_W.x), axis=1)
        tests["speed_max"] = (f"|v_W| < {c.speed_max:g} m/s", speed < c.speed_max)
    spin = np.mean(np.abs(omega), axis=1)
    floor = c.spin_fraction * np.percentile(spin, 95) if spin.size else 0.0
    demand = f"mean |omega| > {c.spin_fraction:g} x its 95th percentile ({floor:.0f} Hz)"
    tests["spin_fraction"] = (demand, spin > floor)
    if flight.landed is not None:
        idx = np.clip(np.searchsorted(flight.landed.t, t, side="right") - 1, 0, flight.landed.t.size - 1)
        tests["landed"] = ("airborne (vehicle_land_detected)", flight.landed.x[idx] < 0.5)
    return tests


def _percent(x: float) -> str:
    return f"{100.0 * x:.0f} %" if x >= 0.01 or x == 0 else f"{100.0 * x:.1g} %"


def find_hover_windows(
    flight: Flight, criteria: WindowCriteria | None = None, rejections: list[str] | None = None
) -> tuple[list[HoverWindow], list[str]]:
    """The steady hover windows of a flight (module docstring); returns them and notes for stderr.

    ``rejections``, if given, receives one line per criterion saying how much of the flight it rejected.
    """
    c = criteria or WindowCriteria()
    notes: list[str] = []
    t_start = max(flight.R_WB.t[0], flight.omega_hz.t[0])
    t_end = min(flight.R_WB.t[-1], flight.omega_hz.t[-1])
    if t_end - t_start < c.min_duration_s:
        if rejections is not None:
            rejections.append(f"the log's attitude and rotor speeds overlap for {max(t_end - t_start, 0):.2f} s only")
        return [], notes
    t = np.arange(t_start, t_end, 1.0 / c.grid_hz)
    omega = on_grid(t, flight.omega_hz.t, _lowpass(flight.omega_hz, c.motion_cutoff_hz, "rotor speeds", notes))
    u = np.abs(omega) * omega  # signed inputs, proportional to the rotors' thrusts
    R = on_grid(t, flight.R_WB.t, flight.R_WB.x)
    tests = _sample_tests(flight, t, c, omega, notes)
    ok = np.ones(t.size, dtype=bool)
    for _, passed in tests.values():
        ok &= passed
    windows: list[HoverWindow] = []
    cuts = {"drift_max_deg": 0, "spread_frac": 0}
    dropped_s = [0.0]
    dt = 1.0 / c.grid_hz

    def close(i0: int, i1: int) -> None:  # samples i0..i1-1
        t0, t1 = t[i0] + c.trim_s, t[i1 - 1] - c.trim_s
        if t1 - t0 >= c.min_duration_s:
            windows.append(HoverWindow(float(t0), float(t1)))
        else:
            dropped_s[0] += (i1 - i0) * dt

    i0 = None
    total = np.zeros(u.shape[1])
    for k in range(t.size):
        if not ok[k]:
            if i0 is not None:
                close(i0, k)
                i0 = None
            continue
        if i0 is not None:
            mean = total / (k - i0)
            band = max(c.spread_frac * float(np.mean(np.abs(mean))), c.spread_min_hz2)
            drift = _angle_deg(R[i0], R[k]) > c.drift_max_deg
            if drift or np.max(np.abs(u[k] - mean)) > band:
                cuts["drift_max_deg" if drift else "spread_frac"] += 1
                close(i0, k)
                i0 = None
        if i0 is None:
            i0, total = k, np.zeros(u.shape[1])
        total += u[k]
    if i0 is not None:
        close(i0, t.size)
    if rejections is not None:
        span = t.size * dt
        for key, (demand, passed) in tests.items():
            rejections.append(
                f"{OPTION_OF.get(key, key)}: {demand} rejected {_percent(1.0 - passed.mean())} of the flight "
                f"({(~passed).sum() * dt:.1f} of {span:.1f} s)"
            )
        rejections.append(f"all of these together leave {ok.sum() * dt:.1f} s steady")
        rejections.append(
            f"{OPTION_OF['drift_max_deg']} ({c.drift_max_deg:g} deg) cut it {cuts['drift_max_deg']} time(s), "
            f"{OPTION_OF['spread_frac']} ({c.spread_frac:g} of the mean rotor thrust, "
            f"at least {c.spread_min_hz2:g} Hz²) "
            f"{cuts['spread_frac']} time(s)"
        )
        rejections.append(
            f"{OPTION_OF['min_duration_s']} ({c.min_duration_s:g} s after {OPTION_OF['trim_s']} {c.trim_s:g} s at "
            f"each end) dropped {dropped_s[0]:.1f} s of steady flight in pieces too short"
        )
    return windows, notes


def hover_points(flight: Flight, criteria: WindowCriteria | None = None) -> HoverPoints:
    """Find the windows and average each into a hover point (mean attitude, mean signed input)."""
    c = criteria or WindowCriteria()
    rejections: list[str] = []
    windows, notes = find_hover_windows(flight, c, rejections)
    omega_f = _lowpass(flight.omega_hz, c.cutoff_hz, "rotor speeds", notes)
    u_all = np.abs(omega_f) * omega_f
    Rs, us, kept = [], [], []
    for w in windows:
        m_att = (flight.R_WB.t >= w.t0_s) & (flight.R_WB.t <= w.t1_s)
        m_rot = (flight.omega_hz.t >= w.t0_s) & (flight.omega_hz.t <= w.t1_s)
        if not m_att.any() or not m_rot.any():
            continue
        Rs.append(project_to_SO3(flight.R_WB.x[m_att].mean(axis=0)))
        us.append(u_all[m_rot].mean(axis=0))
        kept.append(w)
    n = flight.omega_hz.x.shape[1]
    R_arr = np.array(Rs).reshape(-1, 3, 3)
    return HoverPoints(tuple(kept), R_arr, np.array(us).reshape(-1, n), tuple(dict.fromkeys(notes)), tuple(rejections))


def plot_windows(flight: Flight, points: HoverPoints, path: str | Path, criteria: WindowCriteria | None = None) -> None:
    """Figure of the flight over time: rotor speeds, attitude, the motion criteria against their limits, windows.

    The raw acceleration is drawn faint behind the criteria: what a real IMU reads in a hover.
    """
    criteria = criteria or WindowCriteria()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from omnirotor.so3 import rpy_from_R

    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    ax = axes[0]
    for i in range(flight.omega_hz.x.shape[1]):
        ax.plot(flight.omega_hz.t, flight.omega_hz.x[:, i], lw=0.8, label=f"rotor {i + 1}")
    ax.set_ylabel(f"rotor speed [Hz]\n({flight.speed_source})")
    ax.legend(ncol=min(8, flight.omega_hz.x.shape[1]), fontsize=7, loc="upper left")
    ax = axes[1]
    rpy = np.degrees(np.array([rpy_from_R(R) for R in flight.R_WB.x]))
    for j, lab in enumerate(("roll", "pitch", "yaw")):
        ax.plot(flight.R_WB.t, rpy[:, j], lw=0.8, label=lab)
    ax.set_ylabel("attitude ZYX [deg]")
    ax.legend(fontsize=7, loc="upper left")
    ax = axes[2]
    if flight.a_W is not None:  # what the accelerometer reads: vibration, not motion
        ax.plot(flight.a_W.t, np.linalg.norm(flight.a_W.x, axis=1), lw=0.5, color="0.75", label="|a_W| raw [m/s²]")
    grid = np.arange(flight.R_WB.t[0], flight.R_WB.t[-1], 1.0 / criteria.grid_hz)
    for (label, value, limit), color, unit in zip(
        motion_signals(flight, grid, criteria).values(), ("tab:blue", "tab:green"), ("m/s²", "rad/s"), strict=False
    ):
        ax.plot(grid, value, lw=1.0, color=color, label=f"{label} [{unit}], {criteria.motion_cutoff_hz:g} Hz low-pass")
        ax.axhline(limit, color=color, lw=0.8, ls="--", label=f"limit {limit:g} {unit}")
    ax.set_ylim(0, 3.0 * max(criteria.accel_max, criteria.rate_max))
    ax.set_ylabel("motion")
    ax.set_xlabel("time since log start [s]")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, loc="upper left")
    for a in axes:
        for w in points.windows:
            a.axvspan(w.t0_s, w.t1_s, color="tab:green", alpha=0.2, lw=0)
        a.grid(alpha=0.3)
    axes[0].set_title(f"{flight.name}: {len(points.windows)} hover window(s) (shaded)")
    fig.tight_layout()
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_name(f".{p.name}.tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(p)


FEW_WINDOWS = 3
"""Below this many windows the rejections of every criterion are said on stderr."""


def say_windows(flight: Flight, pts: HoverPoints, vehicle) -> None:
    """Say on stderr what was assumed (mapped rotor speeds, unfiltered signals) and what each criterion rejected.

    The rejections are said when fewer than :data:`FEW_WINDOWS` or fewer than the vehicle's ``n - 3`` windows
    were found.
    """
    import sys

    lines = list(flight.notes) + list(pts.notes)
    if len(pts.windows) < max(FEW_WINDOWS, vehicle.n_rotors - 3):
        lines.append(f"{len(pts.windows)} hover window(s); what each criterion rejected:")
        lines.extend(f"  {r}" for r in pts.rejections)
    for line in lines:
        print(f"omnirotor: {flight.name}: {line}", file=sys.stderr)


def read_flight_log(path: str | Path, n_rotors: int | None = None, omega_max_hz: float | None = None) -> Flight:
    """A flight from a PX4 ULog or a ROS 2 bag folder (:mod:`omnirotor.px4.rosbag_io`)."""
    from omnirotor.px4.rosbag_io import is_rosbag, read_bag_flight

    if is_rosbag(path):
        return read_bag_flight(path, n_rotors, omega_max_hz)
    return read_flight(path, n_rotors, omega_max_hz)


def flight_hover_points(path: str | Path, vehicle, criteria: WindowCriteria | None = None) -> HoverPoints:
    """The hover points of a ULog or ROS 2 bag for identification: its automatic hover windows, one point each.

    Says on stderr how many windows were found and what was assumed (:func:`say_windows`);
    :func:`omnirotor.identification.load_hover_data` turns them into hover data.

    Raises:
        InputError: not a ULog, no attitude, no rotor speeds, or no hover window at all.
    """
    import sys

    p = Path(path)
    flight = read_flight_log(p, vehicle.n_rotors, vehicle.omega_max_hz)
    pts = hover_points(flight, criteria)
    say_windows(flight, pts, vehicle)
    if not pts.windows:
        raise InputError(f"{p}: no steady hover window found (stderr above says what each criterion rejected)")
    spans = ", ".join(f"{w.t0_s:.1f}-{w.t1_s:.1f}" for w in pts.windows[:8]) + (" ..." if len(pts.windows) > 8 else "")
    print(f"omnirotor: {p.name}: {len(pts.windows)} hover window(s) at t = {spans} s", file=sys.stderr)
    return pts
