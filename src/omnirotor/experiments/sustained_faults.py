"""Sustained sensor faults flown in hover, each with the bound it must meet (issue 26 item 1; SPEC §4.5).

:data:`SCENARIOS` is the table: every sustained fault the issue lists (a motion capture frozen or offset, a
marker swap, IMU losses, blackouts of every input, runaway and non-finite IMU signals, clock resets, bias
ramps, a drifting bypass state, random mixes of bad frames), each a schedule of
:mod:`omnirotor.experiments.faults` from :data:`T_FAULT_S` into the free scene's hover, flown by the compiled
closed loop (:func:`~omnirotor.experiments.tasks.fault_hovers.glitch_hover`) with the UKF (the default) or the
bypass estimator, and its *bound*, the promise it is checked against (:func:`verdict`):

* ``recover``: flagged (some frame-supervision cause or status flag during the fault), the body never farther
  than ``peak_m`` from its hover reference, and back within :data:`BACK_M` (5 cm) no later than
  :data:`BACK_S` (2 s) after the fault ends, staying there;
* ``track``: within :data:`BACK_M` of the reference all along (a slow bias within the estimator's range);
* ``flag``: flagged (the cause named by the scenario) and never farther than ``peak_m`` (1 m: does not fly
  away) — a fault beyond what the estimator can follow;
* ``land``: the controller's failsafe (:mod:`omnirotor.control.supervisor`, ``CAUSE_FAILSAFE``) takes over:
  flagged, it holds and then descends; the body ends below its start height by at least half of it (on the
  ground: the hover is at 1.5 m), within :data:`LAND_RADIUS_M` (1 m) of where the fault began horizontally,
  and never farther than that from it on the way (it never flies away).

Every run's commands are also checked: finite and within the rotor limits (``safe``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from omnirotor.control import supervisor as sup
from omnirotor.experiments.faults import FRAME_GLITCHES, Fault, SensorCorruption, random_mix, safety_stats
from omnirotor.messages import ControlStatus
from omnirotor.vehicle import VehicleParams

__all__ = ["Scenario", "SCENARIOS", "T_FAULT_S", "BACK_M", "BACK_S", "run_scenario", "verdict", "MIX_GLITCHES"]

T_FAULT_S = 2.0
"""When every fault starts [s] (the hover has settled)."""
BACK_M = 0.05
"""The issue's bound: back within 5 cm of the reference ..."""
BACK_S = 2.0
"""... within 2 s of the fault's end."""
LAND_RADIUS_M = 1.0
"""A landing ends within this of where the fault began, horizontally [m]."""


@dataclasses.dataclass(frozen=True)
class Scenario:
    """One sustained fault and its bound (module docstring).

    Attributes:
        name: what happens, e.g. "mocap frozen 2 s".
        family: the group it is plotted and tabled with.
        estimator: "ukf" or "bypass".
        faults: the schedule, from :data:`T_FAULT_S`.
        fault_s: how long the fault lasts [s] (a ramp that stays: until the end of the run).
        bound: "recover", "track", "flag" or "land".
        peak_m: the largest distance from the reference allowed (recover, flag) [m].
        cause: the supervision cause (a name of :data:`omnirotor.control.supervisor.CAUSES`) or status flag
            (a :class:`~omnirotor.messages.ControlStatus` name, lower case) that must be raised; None: any.
        after_s: how long the run goes on after the fault [s].
    """

    name: str
    family: str
    estimator: str
    faults: tuple[Fault, ...]
    fault_s: float
    bound: str
    peak_m: float = 1.0
    cause: str | None = None
    after_s: float = 3.0

    @property
    def duration_s(self) -> float:
        """The run's length [s]."""
        return T_FAULT_S + self.fault_s + self.after_s


def _c(signal: str, duration_s: float, kind: str = "nan", magnitude: float = 0.0, **kw) -> SensorCorruption:
    return SensorCorruption(signal, T_FAULT_S, duration_s, kind, magnitude, **kw)


def _blackout(duration_s: float) -> tuple[Fault, ...]:
    """Every input non-finite: IMU, motion capture, rotor speeds and the frame's time."""
    return tuple(_c(s, duration_s) for s in ("imu_acc", "imu_gyro", "mocap", "rotor_hz", "time"))


def _imu(duration_s: float) -> tuple[Fault, ...]:
    return (_c("imu_acc", duration_s), _c("imu_gyro", duration_s))


MIX_GLITCHES = tuple(g for g in FRAME_GLITCHES if g[6] is not None)
"""The single bad frames a random mix draws from (those the UKF reads)."""
MIX_SEEDS = (0, 1, 2, 3)
_REST_S = 100.0
"""A clock step lasts for the rest of the run."""


def _scenarios() -> tuple[Scenario, ...]:
    s: list[Scenario] = [
        Scenario("mocap frozen 2 s", "motion capture", "ukf", (_c("mocap", 2.0, "freeze"),), 2.0, "recover", 0.1),
        Scenario(
            "marker offset 0.2 m for 3 s", "motion capture", "ukf",
            (_c("mocap", 3.0, "spike", 0.2, component=0),), 3.0, "recover", 0.1,
        ),
        Scenario(
            "marker swap (0.5 m for 2 s)", "motion capture", "ukf",
            (_c("mocap", 2.0, "spike", 0.5, component=1),), 2.0, "recover", 0.1,
        ),
    ]  # fmt: skip
    for ms in (50, 75, 100):
        s.append(Scenario(f"IMU NaN {ms} ms", "IMU loss", "ukf", _imu(ms / 1e3), ms / 1e3, "recover", 0.1))
    for ms in (100, 200, 300):
        s.append(Scenario(f"blackout {ms} ms", "blackout", "ukf", _blackout(ms / 1e3), ms / 1e3, "recover", 0.1))
    for sec, after in ((0.5, 8.0), (2.0, 20.0)):
        name = f"blackout {sec:g} s"
        s.append(Scenario(name, "blackout", "ukf", _blackout(sec), sec, "land", cause="failsafe", after_s=after))
    s += [
        Scenario("gyro inf 300 frames", "IMU loss", "ukf", (_c("imu_gyro", 0.3, "inf"),), 0.3, "recover", 0.1),
        Scenario("gyro NaN 100 frames", "IMU loss", "ukf", (_c("imu_gyro", 0.1),), 0.1, "recover", 0.1),
        Scenario("accelerometer NaN 200 frames", "IMU loss", "ukf", (_c("imu_acc", 0.2),), 0.2, "recover", 0.1),
        Scenario(
            "accelerometer growing to 1e300", "IMU loss", "ukf", (_c("imu_acc", 1.0, "grow", 1e300, component=2),),
            1.0, "land", cause="failsafe", after_s=8.0,
        ),
        Scenario(
            "clock reset to 0", "clock", "ukf", (_c("time", _REST_S, "spike", -T_FAULT_S),), 0.0, "recover", 0.1,
            "clock_reset",
        ),
        Scenario(
            "clock jump back 0.5 s", "clock", "ukf", (_c("time", _REST_S, "spike", -0.5),), 0.0, "recover", 0.1,
            "clock_reset",
        ),
        Scenario(
            "accelerometer bias ramp 3 m/s² over 3 s", "bias ramp", "ukf",
            (_c("imu_acc", _REST_S, "ramp", 3.0, component=0, rise_s=3.0),), 3.0, "track",
        ),
        Scenario(
            "gyro bias ramp 0.5 rad/s over 3 s", "bias ramp", "ukf",
            (_c("imu_gyro", _REST_S, "ramp", 0.5, component=2, rise_s=3.0),), 3.0, "track",
        ),
        Scenario(
            "accelerometer bias ramp 10 m/s² over 3 s (beyond range)", "bias ramp", "ukf",
            (_c("imu_acc", _REST_S, "ramp", 10.0, component=0, rise_s=3.0),), 3.0, "flag", 1.0, "bias_beyond_range",
        ),
        Scenario(
            "gyro bias ramp 2 rad/s over 3 s (beyond range)", "bias ramp", "ukf",
            (_c("imu_gyro", _REST_S, "ramp", 2.0, component=2, rise_s=3.0),), 3.0, "flag", 1.0, "bias_beyond_range",
        ),
        Scenario(
            "bypass position drifting 1 mm/frame for 1 s", "bypass", "bypass",
            (_c("state", 1.0, "ramp", 1.0, component=0),), 1.0, "recover", 0.1, "state_drift",
        ),
    ]  # fmt: skip
    for seed in MIX_SEEDS:
        s.append(
            Scenario(
                f"random mix p = 0.3 for 2 s (seed {seed})", "random mix", "ukf",
                random_mix(MIX_GLITCHES, 0.3, T_FAULT_S, 2.0, seed), 2.0, "track",
            )
        )  # fmt: skip
    return tuple(s)


SCENARIOS: tuple[Scenario, ...] = _scenarios()
"""Every sustained fault of issue 26 item 1, with its bound (module docstring)."""


def run_scenario(vehicle: VehicleParams, scenario: Scenario, seed: int = 1) -> dict:
    """Fly ``scenario`` (compiled closed loop, clean plant); the logs of :func:`glitch_hover` plus ``safe``."""
    from omnirotor.experiments.tasks.fault_hovers import glitch_hover

    run = glitch_hover(vehicle, scenario.estimator, scenario.faults, scenario.duration_s, seed=seed)
    safety = safety_stats(run["omega"], run["status"], vehicle)
    s = run["sim"].faults
    run["safe"] = bool(
        safety["commands_finite"]
        and safety["commands_within_limits"]
        and s.commands_nonfinite == 0
        and s.commands_out_of_limits == 0
    )
    return run


def _raised(run: dict, name: str | None, window: np.ndarray) -> bool:
    """Whether the cause or status flag ``name`` (None: any rejection or degradation) was raised in ``window``."""
    cause, status = run["cause"][window], run["status"][window]
    if name is None:
        bits = int(ControlStatus.FRAME_REJECTED | ControlStatus.ESTIMATE_DEGRADED | ControlStatus.NONFINITE_INPUT)
        return bool(np.any(cause != 0) or np.any(status & bits))
    names = dict(sup.CAUSES)
    if name in names:
        return bool(np.any(cause & names[name]))
    return bool(np.any(status & int(ControlStatus[name.upper()])))


def verdict(scenario: Scenario, run: dict) -> dict:
    """Whether ``run`` met the scenario's bound, and the figures it is judged on.

    Returns:
        ``ok``, ``flagged``, ``safe``, ``peak_m`` (largest distance from the reference from the fault on),
        ``end_m`` (at the end), ``back_s`` (time from the fault's end until it stays within :data:`BACK_M`; inf
        if it never does), and for a landing ``drop_m`` (height lost), ``land_offset_m`` (horizontal distance
        from where the fault began, at the end) and ``away_m`` (its largest value from the fault on).
    """
    t, err = run["t"], run["err"]
    k = min(len(t), len(run["cause"]))
    t, err = t[:k], err[:k]
    t0, t1 = T_FAULT_S, T_FAULT_S + scenario.fault_s
    during = t >= t0
    flagged = _raised(run, scenario.cause, np.flatnonzero(during))
    peak = float(np.max(err[during]))
    out_idx = np.flatnonzero(err > BACK_M)
    last_out = float(t[out_idx[-1]]) if out_idx.size else -np.inf
    back_s = max(0.0, last_out - t1) if last_out < t[-1] else np.inf
    res = {"flagged": flagged, "safe": run["safe"], "peak_m": peak, "end_m": float(err[-1]), "back_s": back_s}
    b = scenario.bound
    if b == "recover":
        ok = flagged and peak <= scenario.peak_m and back_s <= BACK_S
    elif b == "track":
        ok = peak <= BACK_M
    elif b == "flag":
        ok = flagged and peak <= scenario.peak_m
    else:  # land
        p = run["p_W"][:k]
        start = p[np.searchsorted(t, t0)]
        horiz = np.linalg.norm(p[:, :2] - start[:2], axis=1)
        res["drop_m"] = float(start[2] - p[-1, 2])
        res["land_offset_m"] = float(horiz[-1])
        res["away_m"] = float(np.max(horiz[during]))
        ok = (
            flagged
            and res["drop_m"] >= 0.5 * start[2]
            and res["away_m"] <= LAND_RADIUS_M
            and res["land_offset_m"] <= LAND_RADIUS_M
        )
    res["ok"] = bool(ok and run["safe"])
    return res


Progress = Callable[[str], None]


def run_all(vehicle: VehicleParams, progress: Progress | None = None) -> list[tuple[Scenario, dict, dict]]:
    """Every scenario of :data:`SCENARIOS` flown and judged: ``(scenario, run, verdict)`` in order."""
    out = []
    for i, sc in enumerate(SCENARIOS):
        if progress is not None:
            progress(f"sustained fault {i + 1}/{len(SCENARIOS)}: {sc.name}")
        run = run_scenario(vehicle, sc)
        out.append((sc, run, verdict(sc, run)))
    return out
