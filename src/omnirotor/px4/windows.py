"""Steady hover windows found automatically in a flight, and their hover points (SPEC §3.1).

The authors picked hover windows by hand. Here a window is a stretch in which the vehicle is in force and
moment balance, so that the rotors' force equals ``R_WBᵀ m g e3`` (SPEC §3.1). Unaccelerated flight (a steady
climb or descent) balances the weight as hover does, up to drag, so the criteria are on acceleration, not on
speed. On a uniform time grid (``grid_hz``), a sample is *steady* when

* the world acceleration ``|a_W|`` < ``accel_max`` (from ``vehicle_local_position`` a*, else differentiated
  velocity; the check is skipped when the log has neither);
* the body rate ``|omega_B|`` < ``rate_max`` (skipped without rate data);
* the mean rotor speed ``mean_i |omega_i|`` > ``spin_fraction`` × its 95th percentile over the flight (the
  vehicle is flying, not idling on the ground), and the log's land detector (if any) says airborne;
* optionally the speed ``|v_W|`` < ``speed_max`` (off by default).

Each run of steady samples is cut greedily into windows in which the attitude stays within ``drift_max_deg``
of the window's first attitude and every rotor speed within ``spread_frac`` × (mean |omega|) (at least
``spread_min_hz``) of its running window mean. ``trim_s`` is cut from both ends of each window, and windows
shorter than ``min_duration_s`` are dropped.

Rotor speeds are first smoothed by a zero-phase 4th-order Butterworth at ``cutoff_hz`` = 5 Hz (SPEC §3.1);
rates and accelerations likewise. A signal sampled too slowly for the filter (below 2.5 × cutoff) is used
unfiltered, and that is reported. A window's hover point is the projected mean attitude and the mean signed
input ``u = mean(|omega| omega)`` over the window's samples; the CSV stores ``omega = sign(u) sqrt(|u|)``,
which :func:`omnirotor.identification.load_csv` turns back into the same ``u``. (SPEC §3.1 squares the mean
speed instead: the two differ by the speed's variance over the window, ≤ 0.01 % in steady windows.)
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from omnirotor.errors import InputError
from omnirotor.px4.flight import Flight, Series, read_flight
from omnirotor.so3 import project_to_SO3

__all__ = [
    "WindowCriteria",
    "HoverWindow",
    "find_hover_windows",
    "HoverPoints",
    "hover_points",
    "plot_windows",
    "load_ulog",
    "on_grid",
]


ACTUATOR_MOTORS_NOTE = (
    "no esc_rpm in the log: rotor speeds mapped from actuator_motors as sign(c) sqrt(|c|) x {omega_max:g} Hz"
)
"""What is said on stderr when rotor speeds come from ``actuator_motors`` (:mod:`omnirotor.px4.flight`)."""


@dataclasses.dataclass(frozen=True)
class WindowCriteria:
    """Criteria of a steady hover window (module docstring).

    Attributes:
        accel_max: largest world acceleration [m/s²].
        rate_max: largest body rate [rad/s].
        speed_max: largest speed [m/s] (inf: unaccelerated flight counts as hover).
        drift_max_deg: largest attitude change within a window [deg].
        spread_frac: largest deviation of a rotor speed from its window mean, relative to the mean |omega|.
        spread_min_hz: floor of that deviation [Hz].
        spin_fraction: the mean |omega| must exceed this fraction of its 95th percentile over the flight.
        min_duration_s: shortest window [s].
        trim_s: cut from both ends of a window [s]; 0.2 s is about the settling time of the 5 Hz low-pass,
            so a window does not average the filter's smear of the change that ended or began it.
        cutoff_hz: zero-phase low-pass cutoff [Hz] (SPEC §3.1: 5 Hz, 4th order).
        grid_hz: rate of the grid the criteria are evaluated on [Hz].
    """

    accel_max: float = 0.3
    rate_max: float = 0.1
    speed_max: float = math.inf
    drift_max_deg: float = 3.0
    spread_frac: float = 0.05
    spread_min_hz: float = 1.0
    spin_fraction: float = 0.5
    min_duration_s: float = 1.0
    trim_s: float = 0.2
    cutoff_hz: float = 5.0
    grid_hz: float = 50.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if not (v >= 0) or (f.name != "speed_max" and not math.isfinite(v)):
                raise InputError(f"hover-window criterion {f.name} must be a finite number >= 0, got {v}")
        if self.grid_hz <= 0 or self.cutoff_hz <= 0:
            raise InputError("hover-window grid_hz and cutoff_hz must be > 0")


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
    """

    windows: tuple[HoverWindow, ...]
    R_WB: np.ndarray
    u_hz2: np.ndarray
    notes: tuple[str, ...]

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


def _steady_mask(flight: Flight, t: np.ndarray, c: WindowCriteria, omega: np.ndarray, notes: list[str]) -> np.ndarray:
    ok = np.ones(t.size, dtype=bool)
    if flight.a_W is not None:
        a = _lowpass(flight.a_W, c.cutoff_hz, "acceleration", notes)
        ok &= np.linalg.norm(on_grid(t, flight.a_W.t, a), axis=1) < c.accel_max
    elif flight.v_W is not None and flight.v_W.t.size > 2:
        a = np.gradient(_lowpass(flight.v_W, c.cutoff_hz, "velocity", notes), flight.v_W.t, axis=0)
        ok &= np.linalg.norm(on_grid(t, flight.v_W.t, a), axis=1) < c.accel_max
    else:
        notes.append("no local position in the log: the acceleration criterion was skipped")
    if math.isfinite(c.speed_max):
        if flight.v_W is None:
            raise InputError(f"{flight.name}: a speed limit needs velocity (topic vehicle_local_position missing)")
        ok &= np.linalg.norm(on_grid(t, flight.v_W.t, flight.v_W.x), axis=1) < c.speed_max
    if flight.omega_B is not None:
        w = _lowpass(flight.omega_B, c.cutoff_hz, "angular rate", notes)
        ok &= np.linalg.norm(on_grid(t, flight.omega_B.t, w), axis=1) < c.rate_max
    else:
        notes.append("no angular rate in the log: the rate criterion was skipped")
    spin = np.mean(np.abs(omega), axis=1)
    ok &= spin > c.spin_fraction * np.percentile(spin, 95) if spin.size else ok
    if flight.landed is not None:
        idx = np.clip(np.searchsorted(flight.landed.t, t, side="right") - 1, 0, flight.landed.t.size - 1)
        ok &= flight.landed.x[idx] < 0.5
    return ok


def find_hover_windows(flight: Flight, criteria: WindowCriteria | None = None) -> tuple[list[HoverWindow], list[str]]:
    """The steady hover windows of a flight (module docstring); returns them and notes for stderr."""
    c = criteria or WindowCriteria()
    notes: list[str] = []
    t_start = max(flight.R_WB.t[0], flight.omega_hz.t[0])
    t_end = min(flight.R_WB.t[-1], flight.omega_hz.t[-1])
    if t_end - t_start < c.min_duration_s:
        return [], notes
    t = np.arange(t_start, t_end, 1.0 / c.grid_hz)
    omega_f = _lowpass(flight.omega_hz, c.cutoff_hz, "rotor speeds", notes)
    omega = on_grid(t, flight.omega_hz.t, omega_f)
    R = on_grid(t, flight.R_WB.t, flight.R_WB.x)
    ok = _steady_mask(flight, t, c, omega, notes)
    windows: list[HoverWindow] = []

    def close(i0: int, i1: int) -> None:  # samples i0..i1-1
        t0, t1 = t[i0] + c.trim_s, t[i1 - 1] - c.trim_s
        if t1 - t0 >= c.min_duration_s:
            windows.append(HoverWindow(float(t0), float(t1)))

    i0 = None
    total = np.zeros(omega.shape[1])
    for k in range(t.size):
        if not ok[k]:
            if i0 is not None:
                close(i0, k)
                i0 = None
            continue
        if i0 is not None:
            mean = total / (k - i0)
            band = max(c.spread_frac * float(np.mean(np.abs(mean))), c.spread_min_hz)
            if _angle_deg(R[i0], R[k]) > c.drift_max_deg or np.max(np.abs(omega[k] - mean)) > band:
                close(i0, k)
                i0 = None
        if i0 is None:
            i0, total = k, np.zeros(omega.shape[1])
        total += omega[k]
    if i0 is not None:
        close(i0, t.size)
    return windows, notes


def hover_points(flight: Flight, criteria: WindowCriteria | None = None) -> HoverPoints:
    """Find the windows and average each into a hover point (mean attitude, mean signed input)."""
    c = criteria or WindowCriteria()
    windows, notes = find_hover_windows(flight, c)
    omega_f = _lowpass(flight.omega_hz, c.cutoff_hz, "rotor speeds", [])
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
    return HoverPoints(tuple(kept), R_arr, np.array(us).reshape(-1, n), tuple(dict.fromkeys(notes)))


def plot_windows(flight: Flight, points: HoverPoints, path: str | Path) -> None:
    """Figure of the flight over time: rotor speeds, attitude, acceleration and rate, windows shaded."""
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
    if flight.a_W is not None:
        ax.plot(flight.a_W.t, np.linalg.norm(flight.a_W.x, axis=1), lw=0.8, label="|a_W| [m/s²]")
    if flight.v_W is not None:
        ax.plot(flight.v_W.t, np.linalg.norm(flight.v_W.x, axis=1), lw=0.8, label="|v_W| [m/s]")
    if flight.omega_B is not None:
        ax.plot(flight.omega_B.t, np.linalg.norm(flight.omega_B.x, axis=1), lw=0.6, label="|omega_B| [rad/s]")
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


def load_ulog(path: str | Path, vehicle, criteria: WindowCriteria | None = None):
    """Hover data of a ULog for identification: its automatic hover windows, one point each.

    Says on stderr how many windows were found and what was assumed (unfiltered signals, rotor speeds mapped
    from ``actuator_motors``).

    Raises:
        InputError: not a ULog, no attitude, no rotor speeds, or no hover window at all.
    """
    import sys

    from omnirotor.identification import HoverData

    p = Path(path)
    flight = read_flight(p, vehicle.n_rotors, vehicle.omega_max_hz)
    pts = hover_points(flight, criteria)
    notes = list(pts.notes)
    if flight.speed_source == "actuator_motors":
        notes.insert(0, ACTUATOR_MOTORS_NOTE.format(omega_max=vehicle.omega_max_hz))
    if not pts.windows:
        raise InputError(f"{p}: no steady hover window found (criteria: {criteria or WindowCriteria()})")
    spans = ", ".join(f"{w.t0_s:.1f}-{w.t1_s:.1f}" for w in pts.windows[:8]) + (" ..." if len(pts.windows) > 8 else "")
    print(f"omnirotor: {p.name}: {len(pts.windows)} hover window(s) at t = {spans} s", file=sys.stderr)
    for note in notes:
        print(f"omnirotor: {p.name}: {note}", file=sys.stderr)
    N = len(pts.windows)
    up = np.array([0.0, 0.0, vehicle.weight])
    w_B = np.array([np.concatenate([R.T @ up, np.zeros(3)]) for R in pts.R_WB])
    return HoverData(pts.u_hz2, w_B, ("",) * N, (p.name,) * N)
