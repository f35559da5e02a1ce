"""Fault injection inside the simulator's step: a schedule of rotor failures, gusts, dropouts and corruptions.

The faults themselves (what they mean, their parameters, their validation) are described in
:mod:`omnirotor.experiments.faults`; this block applies them at the plant boundary, in the compiled step,
so a run with faults takes the same compiled loop as one without. Per control period from ``t = k dt``:

1. :func:`faults_command`: the command is checked (non-finite, beyond the rotor limits: counted), and the
   command of every failed rotor (``t + 1e-12 >= t_start``) is forced to 0 Hz;
2. :func:`faults_wrench`: the gusts blowing at ``t`` set the external wrench at the CoM (``0.5 (1 - cos(2 pi
   tau))`` or a step of the peak), and clear it when they stop;
3. after the step, :func:`faults_frame` edits the new frame (its time ``t'``): a motion-capture dropout
   ``[t_start, t_end)`` removes the sample delivered in it and any sample taken in it (and the bypass state
   with ``drop_state``); a corruption puts NaN, inf, an added spike or a set value into one signal (all
   components, or one), in the order of the schedule. Sustained faults (issue 26) have three more kinds:
   *freeze* repeats the signal's first value in the window (a motion capture frozen on one pose whose samples
   keep fresh time stamps), *ramp* adds ``magnitude * min(1, tau / rise_s)`` (``tau`` the time since the
   window's start: a bias growing over ``rise_s`` then held, a position drifting) and *grow* adds
   ``|magnitude| ** min(1, tau / rise_s)`` with the magnitude's sign (a value growing geometrically from 1 to
   the magnitude, e.g. an accelerometer running away to 1e300). A clock reset is a *spike* of ``-t_start`` on
   "time" over the rest of the run (the clock restarts from 0 and runs on).

Telling the controller that a rotor failed is not the plant's business: the schedule gives the steps at
which it is due (:meth:`FaultSchedule.notice_steps`) and calls :attr:`FaultSchedule.notify` at them from the
simulator's :meth:`~omnirotor.sim.simulator.Simulator.step`; a compiled loop stops there and calls it too.
Every onset and end is logged (:meth:`FaultSchedule.events`).

The block (:class:`FaultSchedule`, registered as ``("faults", "schedule")``) owns its record
(:data:`STATE_DTYPE`: the schedule, the failed rotors, the counters, the event log).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from omnirotor._jit import jit, jit_inline
from omnirotor.blocks import register
from omnirotor.errors import InputError
from omnirotor.frame_kernels import clear_mocap, clear_state
from omnirotor.sim.rotors import MAX_ROTORS

__all__ = [
    "FaultSchedule",
    "faults_command",
    "faults_wrench",
    "faults_frame",
    "STATE_DTYPE",
    "MAX_FAULTS",
    "SIGNALS",
    "CORRUPTIONS",
    "PROFILES",
]

MAX_FAULTS = 32
"""Faults a schedule has room for."""
MAX_EVENTS = 4 * MAX_FAULTS + 64
"""Onsets and ends the event log has room for (gusts may start and stop several times)."""
ROTOR_FAILURE, MOCAP_DROPOUT, CORRUPTION, GUST = 1, 2, 3, 4
SIGNALS = ("imu_acc", "imu_gyro", "rotor_hz", "mocap", "state", "time", "mocap_q", "state_v", "state_R")
"""Signals of the frame a corruption can hit (their codes are their indices): "mocap" is the position (and the
quaternion for nan/inf), "state" the bypass state's position, "time" the frame's time stamp, "mocap_q" the
quaternion, "state_v" the bypass velocity and "state_R" its attitude matrix (row-major)."""
CORRUPTIONS = ("nan", "inf", "spike", "set", "freeze", "ramp", "grow")
PROFILES = ("1-cos", "step")
_SIG_ACC, _SIG_GYRO, _SIG_ROTOR, _SIG_MOCAP, _SIG_STATE, _SIG_TIME, _SIG_MOCAP_Q, _SIG_STATE_V, _SIG_STATE_R = range(9)
_NAN, _INF, _SPIKE, _SET, _FREEZE, _RAMP, _GROW = range(7)
N_HELD = 9
"""Values a frozen signal keeps (the largest signal: the bypass attitude matrix)."""
_STEP_PROFILE = 1
_TIME_TOL_S = 1e-12
"""A fault due at ``t_start`` starts at the first period whose time is within this of it."""
# Event codes of the log.
EV_FAIL, EV_TOLD, EV_DROP_ON, EV_DROP_OFF, EV_CORR_ON, EV_CORR_OFF, EV_GUST_ON, EV_GUST_OFF = range(8)

FAULT_DTYPE = np.dtype(
    [
        ("kind", np.int64),  # ROTOR_FAILURE, MOCAP_DROPOUT, CORRUPTION, GUST
        ("t_start_s", np.float64),
        ("t_end_s", np.float64),  # end of the window (a failure lasts)
        ("duration_s", np.float64),
        ("rotor", np.int64),  # failure: 0-based rotor
        ("drop_state", np.bool_),  # dropout: also remove the bypass state
        ("signal", np.int64),  # corruption: index in SIGNALS
        ("corruption", np.int64),  # index in CORRUPTIONS
        ("magnitude", np.float64),  # spike
        ("component", np.int64),  # -1: all components
        ("rise_s", np.float64),  # ramp and grow: time to reach the magnitude [s]
        ("held", np.float64, (N_HELD,)),  # freeze: the values held (the signal's first in the window)
        ("n_held", np.int64),  # freeze: values held so far (0: none yet)
        ("probability", np.float64),  # random: the chance of a bad frame in the window (0: every frame)
        ("group", np.int64),  # random: faults of one group share the draw, one of them hits a bad frame
        ("member", np.int64),  # its index in the group ...
        ("members", np.int64),  # ... of this many
        ("seed", np.int64),  # random: the draws' seed
        ("force_W", np.float64, (3,)),  # gust peak [N]
        ("moment_W", np.float64, (3,)),  # gust peak [N·m]
        ("profile", np.int64),  # index in PROFILES
        ("on", np.bool_),  # state: active at the last check
    ]
)
"""One scheduled fault (fields of the kinds that do not use them stay 0)."""

STATE_DTYPE = np.dtype(
    [
        ("n_faults", np.int64),
        ("faults", FAULT_DTYPE, (MAX_FAULTS,)),
        ("n_rotors", np.int64),
        ("omega_min_hz", np.float64),
        ("omega_max_hz", np.float64),
        ("failed", np.int8, (MAX_ROTORS,)),  # 1: failed (numba has no nested bool arrays)
        ("any_failed", np.bool_),
        ("gust_on", np.bool_),
        ("has_gusts", np.bool_),
        ("has_frame_faults", np.bool_),
        ("cmd_hz", np.float64, (MAX_ROTORS,)),  # the command the rotors get
        ("commands_checked", np.int64),
        ("commands_nonfinite", np.int64),
        ("commands_out_of_limits", np.int64),
        ("n_events", np.int64),
        ("event_t", np.float64, (MAX_EVENTS,)),
        ("event_code", np.int64, (MAX_EVENTS,)),
        ("event_fault", np.int64, (MAX_EVENTS,)),
    ]
)
"""The schedule and what it has done."""


@jit_inline
def _log(st, t: float, code: int, i: int) -> None:
    """Log event ``code`` of fault ``i`` at ``t`` (inlined: callers pass constants, one version each otherwise)."""
    j = st["n_events"]
    if j < st["event_t"].shape[0]:
        st["event_t"][j] = t
        st["event_code"][j] = code
        st["event_fault"][j] = i
        st["n_events"] = j + 1


@jit
def faults_command(st, t: float, cmd_hz):
    """Check the command and force failed rotors to 0 Hz (module docstring); returns the rotors' command.

    Args:
        st: the :data:`STATE_DTYPE` record, updated.
        t: time of the period's start [s].
        cmd_hz: (n,) the controller's command [Hz] (not modified).

    Returns:
        (n,) the command for the rotors (a view of ``st.cmd_hz``).
    """
    n = st["n_rotors"]
    out = st["cmd_hz"][:n]
    st["commands_checked"] += 1
    finite, within = True, True
    for i in range(n):
        c = cmd_hz[i]
        out[i] = c
        if not math.isfinite(c):
            finite = False
        elif not (st["omega_min_hz"] <= c <= st["omega_max_hz"]):
            within = False
    if not finite:
        st["commands_nonfinite"] += 1
    elif not within:
        st["commands_out_of_limits"] += 1
    for i in range(st["n_faults"]):
        f = st["faults"][i]
        if f["kind"] == ROTOR_FAILURE and not f["on"] and t + _TIME_TOL_S >= f["t_start_s"]:
            f["on"] = True
            st["failed"][f["rotor"]] = 1
            st["any_failed"] = True
            _log(st, t, EV_FAIL, i)
    if st["any_failed"]:
        for i in range(n):
            if st["failed"][i]:
                out[i] = 0.0
    return out


@jit
def faults_wrench(st, t: float, ext) -> None:
    """The gusts blowing at ``t`` into the external wrench record ``ext`` (at the CoM; cleared after them)."""
    if not st["has_gusts"]:
        return
    fx, fy, fz, mx, my, mz = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    on = False
    for i in range(st["n_faults"]):
        g = st["faults"][i]
        if g["kind"] != GUST:
            continue
        tau = (t - g["t_start_s"]) / g["duration_s"]
        if not 0.0 <= tau < 1.0:
            continue
        s = 1.0 if g["profile"] == _STEP_PROFILE else 0.5 * (1.0 - math.cos(2.0 * math.pi * tau))
        if s > 0.0:
            on = True
            fx += s * g["force_W"][0]
            fy += s * g["force_W"][1]
            fz += s * g["force_W"][2]
            mx += s * g["moment_W"][0]
            my += s * g["moment_W"][1]
            mz += s * g["moment_W"][2]
    if on or st["gust_on"]:
        f, m = ext["f_W"], ext["m_W"]
        f[0], f[1], f[2], m[0], m[1], m[2] = fx, fy, fz, mx, my, mz
        ext["at_ee"] = False
        ext["active"] = fx != 0.0 or fy != 0.0 or fz != 0.0 or mx != 0.0 or my != 0.0 or mz != 0.0
    if on != st["gust_on"]:
        _log(st, t, EV_GUST_ON if on else EV_GUST_OFF, -1)
    st["gust_on"] = on


@jit
def _corrupted(x: float, f, t: float) -> float:
    """The value ``x`` corrupted by fault ``f`` at time ``t`` (freeze: handled by :func:`_bad`)."""
    kind = f["corruption"]
    if kind == _NAN:
        return math.nan
    if kind == _INF:
        return math.inf
    if kind == _SET:
        return f["magnitude"]
    if kind == _RAMP or kind == _GROW:
        frac = min(1.0, max(0.0, (t - f["t_start_s"]) / f["rise_s"]))
        if kind == _RAMP:
            return x + f["magnitude"] * frac
        return x + math.copysign(abs(f["magnitude"]) ** frac, f["magnitude"])
    return x + f["magnitude"]


@jit
def _bad(values, f, t: float, first: int = 0) -> None:
    """Corrupt ``values`` (a signal of the frame: a 1-D array, or a matrix's ``.flat``) by fault ``f`` at ``t``.

    One component or all.

    An absent component: nothing. A freeze holds the values from ``f.held[first]`` on (taken the first time it
    sees the signal).
    """
    size = len(values)
    lo, hi = 0, size
    if f["component"] >= 0:
        if f["component"] >= size:
            return
        lo, hi = f["component"], f["component"] + 1
    if f["corruption"] == _FREEZE:
        held = f["held"]
        if f["n_held"] <= first:
            for j in range(lo, hi):
                held[first + j] = values[j]
            f["n_held"] = first + size
        for j in range(lo, hi):
            values[j] = held[first + j]
        return
    for j in range(lo, hi):
        values[j] = _corrupted(values[j], f, t)


@jit
def _draw(seed: int, k: int) -> float:
    """A uniform number in [0, 1) from ``seed`` and the step ``k`` (splitmix64: no generator state to keep)."""
    z = np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(k) + np.uint64(0x632BE59BD9B4E019)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@jit
def _hits(c, t: float) -> bool:
    """Whether a random corruption hits the frame of time ``t``: its group's draw falls in its share."""
    if c["probability"] <= 0.0:
        return True
    u = _draw(c["seed"] * 1000 + c["group"], int(round(t * 1e6)))
    if u >= c["probability"]:
        return False
    return int(u / c["probability"] * c["members"]) == c["member"]


@jit
def faults_frame(st, frame) -> None:
    """Dropouts and corruptions of the frame record due at its time (module docstring), in place."""
    if not st["has_frame_faults"]:
        return
    t = frame.t
    mocap, state = frame.mocap, frame.state
    mocap_new = mocap.new != 0.0
    mocap_t = mocap.t
    for i in range(st["n_faults"]):
        d = st["faults"][i]
        if d["kind"] != MOCAP_DROPOUT:
            continue
        active = d["t_start_s"] <= t < d["t_end_s"]
        if active != d["on"]:
            d["on"] = active
            _log(st, t, EV_DROP_ON if active else EV_DROP_OFF, i)
        if active or (mocap_new and d["t_start_s"] <= mocap_t < d["t_end_s"]):
            clear_mocap(mocap)
            if d["drop_state"] and active:
                clear_state(state)
    for i in range(st["n_faults"]):
        c = st["faults"][i]
        if c["kind"] != CORRUPTION:
            continue
        active = c["t_start_s"] <= t < c["t_end_s"]
        if active != c["on"]:
            c["on"] = active
            c["n_held"] = 0
            _log(st, t, EV_CORR_ON if active else EV_CORR_OFF, i)
        if not active or not _hits(c, t):
            continue
        # Every 1-D signal as an array ([:]) and the offset as an int64 (not a literal), so that _bad compiles
        # once for them all (and once for the attitude matrix's entries), not once per field shape and offset.
        zero = np.int64(0)
        sig = c["signal"]
        if sig == _SIG_ACC:
            _bad(frame.imu.acc_B[:], c, t, zero)
        elif sig == _SIG_GYRO:
            _bad(frame.imu.gyro_B[:], c, t, zero)
        elif sig == _SIG_ROTOR:
            _bad(frame.rotor_hz[:], c, t, zero)
        elif sig == _SIG_MOCAP:
            if mocap.new != 0.0 and mocap_new:
                _bad(mocap.p_W[:], c, t, zero)
                kind = c["corruption"]
                if kind == _NAN or kind == _INF or kind == _FREEZE:  # a frozen sample: its pose, fresh stamps
                    _bad(mocap.q_WB[:], c, t, np.int64(3))
        elif sig == _SIG_MOCAP_Q:
            if mocap.new != 0.0 and mocap_new:
                _bad(mocap.q_WB[:], c, t, zero)
        elif sig == _SIG_TIME:  # a clock step (spike) moves the motion-capture stamp of the same clock too
            if c["component"] <= 0:
                frame.t = _corrupted(frame.t, c, t)
            if c["corruption"] == _SPIKE and mocap.new != 0.0:
                mocap.t += c["magnitude"]
        elif state.valid != 0.0:  # the bypass state's position, velocity or attitude
            if sig == _SIG_STATE_V:
                _bad(state.v_W[:], c, t, zero)
            elif sig == _SIG_STATE_R:
                _bad(state.R_WB.flat, c, t, zero)  # its row-major entries (a reshape compiles numba's error text)
            else:
                _bad(state.p_W[:], c, t, zero)


@register("faults", "schedule")
class FaultSchedule:
    """A schedule of faults applied by the simulator's step (module docstring).

    Args:
        n_rotors: the vehicle's rotors.
        omega_min_hz: the rotors' lower speed limit [Hz] (for the command check).
        omega_max_hz: the upper limit [Hz].
        state: (1,) :data:`STATE_DTYPE` record to live in, e.g. a field of the simulator's (default: its own).

    Attributes:
        notify: called with the (n,) bool mask of failed rotors when the controller is to be told (and with
            None at :meth:`reset` when any failure is to be told), or None.
    """

    state_dtype = STATE_DTYPE
    log_fields = ("failed", "commands_nonfinite", "commands_out_of_limits")

    def __init__(self, n_rotors: int, omega_min_hz: float, omega_max_hz: float, state: np.ndarray | None = None):
        self.state = np.zeros(1, STATE_DTYPE) if state is None else state
        s = self.state[0]
        s["n_rotors"], s["omega_min_hz"], s["omega_max_hz"] = n_rotors, omega_min_hz, omega_max_hz
        self.n_rotors = n_rotors
        self.notify: Callable[[np.ndarray | None], None] | None = None
        self._notices: list[tuple[float, int]] = []  # (time the controller is told [s], failure index)
        self._rotor_of: dict[int, int] = {}
        self._labels: list[str] = []
        self._told: set[int] = set()
        self._told_log: list[tuple[float, int]] = []

    # -- building the schedule ----------------------------------------------------------------------------------
    def _add(self, kind: int, label: str, t_start_s: float, t_end_s: float, **fields) -> np.void:
        s = self.state[0]
        i = int(s["n_faults"])
        if i >= MAX_FAULTS:
            raise InputError(f"at most {MAX_FAULTS} faults per run")
        f = s["faults"][i]
        f["kind"], f["t_start_s"], f["t_end_s"] = kind, t_start_s, t_end_s
        for k, v in fields.items():
            f[k] = v
        s["n_faults"] = i + 1
        self._labels.append(label)
        return f

    def add_rotor_failure(self, rotor: int, t_start_s: float, tell_after_s: float | None) -> None:
        """Rotor ``rotor`` (0-based) stops at ``t_start_s``; the controller is told ``tell_after_s`` later.

        ``tell_after_s`` None: never told.
        """
        if not 0 <= rotor < self.n_rotors:
            raise InputError(f"rotor_failure.rotor {rotor + 1}: the vehicle has {self.n_rotors} rotors")
        i = int(self.state[0]["n_faults"])
        self._add(ROTOR_FAILURE, f"rotor {rotor + 1}", t_start_s, math.inf, rotor=rotor)
        self._rotor_of[i] = rotor
        if tell_after_s is not None:
            self._notices.append((t_start_s + tell_after_s, i))

    def add_mocap_dropout(self, t_start_s: float, duration_s: float, drop_state: bool) -> None:
        """No motion-capture sample delivered, nor taken, in ``[t_start_s, t_start_s + duration_s)``."""
        self._add(MOCAP_DROPOUT, "motion-capture dropout", t_start_s, t_start_s + duration_s, drop_state=drop_state)
        self.state[0]["has_frame_faults"] = True

    def add_corruption(
        self,
        signal: str,
        kind: str,
        t_start_s: float,
        duration_s: float,
        magnitude: float,
        component: int | None,
        rise_s: float | None = None,
        random: tuple[float, int, int, int, int] | None = None,
    ) -> None:
        """``kind`` (:data:`CORRUPTIONS`, of ``magnitude``) in ``signal`` (:data:`SIGNALS`) over the window.

        ``rise_s``: the time a ramp or a growth takes to reach its magnitude [s] (None: the window's length).
        ``random``: ``(probability, seed, group, member, members)``: each frame of the window is bad with the
        probability, and then hit by one of the group's ``members`` faults, drawn (None: every frame).
        """
        p, seed, group, member, members = (0.0, 0, 0, 0, 1) if random is None else random
        self._add(
            CORRUPTION, f"{kind} on {signal}", t_start_s, t_start_s + duration_s, signal=SIGNALS.index(signal),
            corruption=CORRUPTIONS.index(kind), magnitude=magnitude, component=-1 if component is None else component,
            rise_s=duration_s if rise_s is None else rise_s, probability=p, seed=seed, group=group, member=member,
            members=members,
        )  # fmt: skip
        self.state[0]["has_frame_faults"] = True

    def add_gust(self, t_start_s: float, duration_s: float, force_W, moment_W, profile: str) -> None:
        """An external wrench at the CoM over the window, ``profile`` "1-cos" or "step" of the peak."""
        self._add(
            GUST, "wind gust", t_start_s, t_start_s + duration_s, duration_s=duration_s, force_W=force_W,
            moment_W=moment_W, profile=PROFILES.index(profile),
        )  # fmt: skip
        self.state[0]["has_gusts"] = True

    # -- running ----------------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the start of the run: nothing failed, nothing active, counters and log cleared."""
        s = self.state[0]
        s["faults"]["on"] = False
        s["faults"]["n_held"] = 0
        s["failed"], s["any_failed"], s["gust_on"] = 0, False, False
        s["commands_checked"] = s["commands_nonfinite"] = s["commands_out_of_limits"] = 0
        s["n_events"] = 0
        s["cmd_hz"], s["event_t"], s["event_code"], s["event_fault"] = 0.0, 0.0, 0, 0
        self._told = set()
        self._told_log: list[tuple[float, int]] = []
        if self.notify is not None and self._notices:
            self.notify(None)

    def notice_steps(self, dt: float) -> list[int]:
        """Step indices ``k`` at whose start (``t = k dt``) the controller is told about a failure, sorted."""
        steps = []
        for t_tell, _ in self._notices:
            k = max(0, int(math.floor(t_tell / dt)) - 1)
            while k * dt + _TIME_TOL_S < t_tell:
                k += 1
            steps.append(k)
        return sorted(set(steps))

    def tell_due(self, k: int, dt: float) -> None:
        """Tell the controller (:attr:`notify`) the failures due at the start of step ``k``."""
        t = k * dt
        due = [i for t_tell, i in self._notices if i not in self._told and t + _TIME_TOL_S >= t_tell]
        if not due:
            return
        self._told.update(due)
        failed = self.state[0]["failed"][: self.n_rotors].astype(bool)
        for i in due:
            failed[self._rotor_of[i]] = True  # failed at this step's start at the latest
        for i in due:
            self._told_log.append((t, i))
        if self.notify is not None:
            self.notify(failed)

    @property
    def commands_checked(self) -> int:
        """Commands received since the last reset."""
        return int(self.state[0]["commands_checked"])

    @property
    def commands_nonfinite(self) -> int:
        """Of those, commands with a non-finite speed."""
        return int(self.state[0]["commands_nonfinite"])

    @property
    def commands_out_of_limits(self) -> int:
        """Of those, commands with a speed beyond the vehicle's limits."""
        return int(self.state[0]["commands_out_of_limits"])

    @property
    def events(self) -> list[tuple[float, str]]:
        """``(t [s], description)`` of each fault's onset and end, in order (for reports)."""
        s = self.state[0]
        rows = []  # (t, rank, order, description): at one time, frame edits, failures, notices, gusts
        for j in range(int(s["n_events"])):
            t, code, i = float(s["event_t"][j]), int(s["event_code"][j]), int(s["event_fault"][j])
            if code == EV_FAIL:
                rows.append((t, 1, j, f"{self._labels[i]} fails"))
            elif code in (EV_DROP_ON, EV_CORR_ON):
                rows.append((t, 0, j, f"{self._labels[i]} starts"))
            elif code in (EV_DROP_OFF, EV_CORR_OFF):
                rows.append((t, 0, j, f"{self._labels[i]} ends"))
            else:
                rows.append((t, 3, j, "wind gust starts" if code == EV_GUST_ON else "wind gust ends"))
        if self.notify is not None:
            rows += [(t, 2, j, f"controller told {self._labels[i]} failed") for j, (t, i) in enumerate(self._told_log)]
        return [(t, text) for t, _, _, text in sorted(rows)]
