"""Faults and plant-only perturbations for robustness studies (issue "Robustness"; SPEC §1.4, §4.5, §7).

Two things make a simulated run differ from what the controller and the reference believe:

* :class:`PlantPerturbation`: the plant is not the model. The simulator flies a vehicle whose mass and
  inertia differ from the controller's (``mass_scale``, ``inertia_scale``), in a scene moved by
  ``scene_offset_W`` from where the reference trajectory was planned, with simulator overrides (truth
  aerodynamics, sensors, friction, ...) that only the plant sees, and a schedule of faults.
* Faults, timed events the simulator's step applies at the plant boundary (:mod:`omnirotor.sim.faults`, its
  fault schedule, filled by :func:`install_faults`): they edit the command the rotors get, the external
  wrench, and the frame the controller reads, inside the compiled step, so a run with faults takes the same
  compiled loop as one without.

Faults (times in simulator seconds, windows ``[t_start_s, t_start_s + duration_s)``):

* :class:`MocapDropout`: no motion-capture sample is delivered in the window (nor any taken in it). The
  UKF flies on the IMU, flags the estimate ``ESTIMATE_DEGRADED`` after its ``mocap_timeout_s`` and clears
  the flag at the next accepted sample. The bypass estimator reads ``SensorFrame.state``, which stands for
  a working estimator, so a dropout does not touch it unless ``drop_state`` is set (the state is then
  missing, and the bypass estimator holds its last state flagged degraded).
* :class:`RotorFailure`: from ``t_start_s`` on, the command of one rotor is forced to 0 Hz at the plant
  boundary (the motor stops; its speed decays through the rotor lag, SPEC §1.4). With ``tell_controller``
  the controller is told after ``detect_delay_s`` through
  :meth:`~omnirotor.control.controller.InteractionController.set_failed_rotors`, and its allocation then
  excludes the rotor. Told, the seven others hold the hover as before (within a few millimetres of the
  undisturbed hover in ``tests/test_faults.py``); not told, the allocation keeps asking the dead rotor for
  thrust, the others saturate and the vehicle sags ~15 cm to a new equilibrium (the pose loop has no
  integrator), every command still within the limits.
* :class:`SensorCorruption`: NaN, inf, an added spike or a set value in one signal of the frame
  (accelerometer, gyroscope, rotor speeds, motion-capture position or quaternion, bypass position, velocity
  or attitude, the frame's time stamp) over a window; or, sustained, the signal frozen on its first value,
  a ramp (a growing bias, a drifting position) or a geometric growth. The controller's frame supervision
  (:mod:`omnirotor.control.supervisor`) rejects them, flagged ``FRAME_REJECTED`` with the cause logged.
* :class:`WindGust`: an external force (and moment) at the CoM, world frame, with a "1-cos" or "step"
  profile, applied as the simulator's external wrench (the gust owns the external wrench while it blows and
  clears it after).

The schedule also checks every command the controller sends (``sim.faults.commands_nonfinite``,
``commands_out_of_limits``): the project's rule is that nothing non-finite, nor beyond the rotor limits,
reaches the motors. :func:`safety_stats` gives the same verdict, and the count of each status flag, from
a controller log.

Unreachable references (a waypoint 5 m away in 0.5 s, a 180° flip in 0.2 s) need no injector: they are
trajectories (:func:`unreachable_reference`), and the allocation saturates them safely (``SATURATED``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from omnirotor.config import apply_overrides, apply_values, check_finite, check_positive
from omnirotor.control.trajectory import PoseTrajectory, Waypoint
from omnirotor.errors import InputError
from omnirotor.messages import ControlStatus
from omnirotor.sim import SimParams, Simulator
from omnirotor.sim.faults import CORRUPTIONS, PROFILES, SIGNALS
from omnirotor.so3 import rot_x
from omnirotor.vehicle import VehicleParams

__all__ = [
    "MocapDropout",
    "RotorFailure",
    "SensorCorruption",
    "WindGust",
    "Fault",
    "PlantPerturbation",
    "install_faults",
    "plant_simulator",
    "safety_stats",
    "unreachable_reference",
    "CORRUPTIBLE_SIGNALS",
    "CORRUPTION_KINDS",
    "GUST_PROFILES",
    "FRAME_GLITCHES",
    "glitch_fault",
    "random_mix",
]

CORRUPTIBLE_SIGNALS = SIGNALS
"""Signals of a :class:`~omnirotor.messages.SensorFrame` a :class:`SensorCorruption` can hit."""
CORRUPTION_KINDS = CORRUPTIONS
GUST_PROFILES = PROFILES
_SCENE_POINTS = ("wall_point", "tilted_wall_point", "pipe_centre", "hole_entrance", "free_start")
"""The scene anchors moved by :attr:`PlantPerturbation.scene_offset_W`."""


def _check_window(name: str, t_start_s: float, duration_s: float | None) -> None:
    check_finite(f"{name}.t_start_s", t_start_s)
    if t_start_s < 0:
        raise InputError(f"{name}.t_start_s must be >= 0, got {t_start_s}")
    if duration_s is not None:
        check_positive(f"{name}.duration_s", duration_s)


@dataclasses.dataclass(frozen=True)
class MocapDropout:
    """Motion capture lost for a while (module docstring).

    Attributes:
        t_start_s: start of the dropout [s].
        duration_s: its length [s].
        drop_state: also remove ``SensorFrame.state`` (what the bypass estimator reads) in the window.
    """

    t_start_s: float
    duration_s: float
    drop_state: bool = False

    def __post_init__(self) -> None:
        _check_window("mocap_dropout", self.t_start_s, self.duration_s)


@dataclasses.dataclass(frozen=True)
class RotorFailure:
    """One motor stops for good (module docstring).

    Attributes:
        rotor: the failed rotor, numbered from 1 as in the logs.
        t_start_s: when it stops [s].
        tell_controller: tell the controller (``set_failed_rotors``) after ``detect_delay_s``.
        detect_delay_s: time from the failure to the controller being told [s].
    """

    rotor: int
    t_start_s: float
    tell_controller: bool = True
    detect_delay_s: float = 0.0

    def __post_init__(self) -> None:
        if isinstance(self.rotor, bool) or not isinstance(self.rotor, (int, np.integer)) or self.rotor < 1:
            raise InputError(f"rotor_failure.rotor must be an integer >= 1, got {self.rotor!r}")
        _check_window("rotor_failure", self.t_start_s, None)
        check_finite("rotor_failure.detect_delay_s", self.detect_delay_s)
        if self.detect_delay_s < 0:
            raise InputError(f"rotor_failure.detect_delay_s must be >= 0, got {self.detect_delay_s}")


@dataclasses.dataclass(frozen=True)
class SensorCorruption:
    """Bad values in one sensor signal over a window (module docstring).

    Attributes:
        signal: one of :data:`CORRUPTIBLE_SIGNALS`.
        t_start_s: start [s].
        duration_s: length [s] (one control period for a single bad sample).
        kind: "nan", "inf", "spike" (``magnitude`` added to every component), "set" (``magnitude`` replaces
            it), "freeze" (the signal's first value in the window is repeated: a motion capture frozen on one
            pose with fresh time stamps), "ramp" (``magnitude`` times the fraction of ``rise_s`` elapsed, at most
            1, added: a growing bias, a drifting position) or "grow" (``|magnitude|`` to the power of that
            fraction, with its sign, added: a value running away geometrically).
        magnitude: the spike, value or final ramp, in the signal's unit (m/s², rad/s, Hz, m, s; for "state": m
            on the position; "state_v": m/s; "state_R" and "mocap_q": none).
        component: only this component (0-based) of the signal; None for all of them.
        rise_s: the time a ramp or growth takes to reach ``magnitude`` [s] (None: ``duration_s``).
        random: ``(probability, seed, group, member, members)``: each frame of the window is bad with the
            probability and is then hit by one fault of the group (``members`` corruptions sharing ``group``
            and ``seed``, this one the ``member``-th), drawn from the seed and the frame's step; None: every
            frame. :func:`random_mix` builds such a group.
    """

    signal: str
    t_start_s: float
    duration_s: float
    kind: str = "nan"
    magnitude: float = 0.0
    component: int | None = None
    rise_s: float | None = None
    random: tuple[float, int, int, int, int] | None = None

    def __post_init__(self) -> None:
        if self.signal not in CORRUPTIBLE_SIGNALS:
            raise InputError(f"sensor_corruption.signal must be one of {', '.join(CORRUPTIBLE_SIGNALS)}")
        if self.kind not in CORRUPTION_KINDS:
            raise InputError(f"sensor_corruption.kind must be one of {', '.join(CORRUPTION_KINDS)}")
        _check_window("sensor_corruption", self.t_start_s, self.duration_s)
        check_finite("sensor_corruption.magnitude", self.magnitude)
        if self.component is not None and (
            isinstance(self.component, bool) or not isinstance(self.component, int) or self.component < 0
        ):
            raise InputError(f"sensor_corruption.component must be an integer >= 0, got {self.component!r}")
        if self.rise_s is not None:
            check_positive("sensor_corruption.rise_s", self.rise_s)
        if self.random is not None:
            if len(self.random) != 5:
                raise InputError("sensor_corruption.random must be (probability, seed, group, member, members)")
            p, *ints = self.random
            check_finite("sensor_corruption.random probability", p)
            if not 0.0 < p <= 1.0:
                raise InputError(f"sensor_corruption.random probability must be in (0, 1], got {p}")
            if any(isinstance(i, bool) or not isinstance(i, (int, np.integer)) or i < 0 for i in ints):
                raise InputError("sensor_corruption.random seed, group, member and members must be integers >= 0")
            if not ints[2] < ints[3]:
                raise InputError("sensor_corruption.random member must be below members")
        if self.signal == "time" and self.kind in ("freeze", "ramp", "grow"):
            raise InputError(
                f"sensor_corruption.kind {self.kind!r} does not apply to the time (a clock step is a spike)"
            )


@dataclasses.dataclass(frozen=True)
class WindGust:
    """An external wrench at the CoM, world frame, over a window (module docstring).

    Attributes:
        t_start_s: start [s].
        duration_s: length [s].
        force_W: (3,) peak force [N].
        moment_W: (3,) peak moment [N·m].
        profile: "1-cos" (``0.5 (1 - cos(2 pi tau))`` of the peak, ``tau`` the fraction of the window) or
            "step" (the peak throughout).
    """

    t_start_s: float
    duration_s: float
    force_W: tuple[float, float, float]
    moment_W: tuple[float, float, float] = (0.0, 0.0, 0.0)
    profile: str = "1-cos"

    def __post_init__(self) -> None:
        _check_window("wind_gust", self.t_start_s, self.duration_s)
        if len(self.force_W) != 3 or len(self.moment_W) != 3:
            raise InputError("wind_gust.force_W and moment_W must have 3 components")
        check_finite("wind_gust.force_W", *self.force_W)
        check_finite("wind_gust.moment_W", *self.moment_W)
        if self.profile not in GUST_PROFILES:
            raise InputError(f"wind_gust.profile must be one of {', '.join(GUST_PROFILES)}")


Fault = MocapDropout | RotorFailure | SensorCorruption | WindGust
_FAULT_TYPES = (MocapDropout, RotorFailure, SensorCorruption, WindGust)


@dataclasses.dataclass(frozen=True)
class PlantPerturbation:
    """How the plant differs from what the controller and the reference believe (module docstring).

    Attributes:
        mass_scale: true mass over the believed one.
        inertia_scale: (3,) true principal inertia over the believed one, per axis.
        scene_offset_W: (3,) the true scene's displacement from the planned one [m] (walls, pipe, hole).
        sim_overrides: dotted ``key=value`` overrides of the simulator parameters seen by the plant only.
        sim_values: ``(dotted key, value)`` pairs set on those parameters after ``sim_overrides``, typed (a
            campaign's drawn values: :func:`omnirotor.config.apply_values`).
        faults: the fault schedule.
    """

    mass_scale: float = 1.0
    inertia_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    scene_offset_W: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sim_overrides: tuple[str, ...] = ()
    sim_values: tuple[tuple[str, Any], ...] = ()
    faults: tuple[Fault, ...] = ()

    def __post_init__(self) -> None:
        check_positive("plant.mass_scale", self.mass_scale)
        if len(self.inertia_scale) != 3 or len(self.scene_offset_W) != 3:
            raise InputError("plant.inertia_scale and plant.scene_offset_W must have 3 components")
        for s in self.inertia_scale:
            check_positive("plant.inertia_scale", s)
        check_finite("plant.scene_offset_W", *self.scene_offset_W)
        for f in self.faults:
            if not isinstance(f, _FAULT_TYPES):
                raise InputError(f"plant.faults: not a fault: {f!r}")

    @property
    def is_identity(self) -> bool:
        """True when the plant is exactly the believed model and nothing is injected."""
        return self == PlantPerturbation()

    def vehicle(self, believed: VehicleParams) -> VehicleParams:
        """The true vehicle: the believed one with the mass and inertia scaled.

        Raises:
            InputError: the scaled inertia is not physical.
        """
        if self.mass_scale == 1.0 and tuple(self.inertia_scale) == (1.0, 1.0, 1.0):
            return believed
        J = tuple(float(j * s) for j, s in zip(believed.inertia_diag, self.inertia_scale, strict=True))
        return dataclasses.replace(believed, mass=believed.mass * self.mass_scale, inertia_diag=J)

    def sim_params(self, believed: SimParams) -> SimParams:
        """The true simulator parameters: the scene moved by ``scene_offset_W``, then the overrides and values."""
        params = believed
        if any(self.scene_offset_W):
            d = self.scene_offset_W
            moved = {
                name: tuple(float(a + b) for a, b in zip(getattr(params.scene, name), d, strict=True))
                for name in _SCENE_POINTS
            }
            params = dataclasses.replace(params, scene=dataclasses.replace(params.scene, **moved))
        return apply_values(apply_overrides(params, list(self.sim_overrides)), self.sim_values)


def install_faults(sim: Simulator, faults: Sequence[Fault] = (), controller=None) -> Simulator:
    """Load a fault schedule into ``sim`` (its step applies it; module docstring); returns ``sim``.

    Args:
        sim: the simulator (the plant); its schedule (``sim.faults``) must be empty.
        faults: the schedule.
        controller: the controller to tell about rotor failures (anything with ``set_failed_rotors``);
            None: nobody is told.

    Raises:
        InputError: not a fault, a fault naming a rotor the vehicle does not have, a controller needed but
            without ``set_failed_rotors``, or a simulator with a schedule already.
    """
    schedule = sim.faults
    if schedule.state[0]["n_faults"]:
        raise InputError("install_faults: the simulator has a fault schedule already")
    n = sim.vehicle.n_rotors
    for f in faults:
        if not isinstance(f, _FAULT_TYPES):
            raise InputError(f"not a fault: {f!r}")
        if isinstance(f, RotorFailure):
            if f.rotor > n:
                raise InputError(f"rotor_failure.rotor {f.rotor}: the vehicle has {n} rotors")
            if f.tell_controller and controller is not None and not hasattr(controller, "set_failed_rotors"):
                raise InputError("rotor_failure.tell_controller needs a controller with set_failed_rotors")
    for f in faults:
        if isinstance(f, RotorFailure):
            tell = f.detect_delay_s if f.tell_controller and controller is not None else None
            schedule.add_rotor_failure(f.rotor - 1, f.t_start_s, tell)
        elif isinstance(f, MocapDropout):
            schedule.add_mocap_dropout(f.t_start_s, f.duration_s, f.drop_state)
        elif isinstance(f, SensorCorruption):
            schedule.add_corruption(
                f.signal, f.kind, f.t_start_s, f.duration_s, f.magnitude, f.component, f.rise_s, f.random
            )
        else:
            schedule.add_gust(f.t_start_s, f.duration_s, f.force_W, f.moment_W, f.profile)
    if controller is not None and any(isinstance(f, RotorFailure) and f.tell_controller for f in faults):
        schedule.notify = controller.set_failed_rotors
    return sim


def plant_simulator(
    believed_vehicle: VehicleParams,
    scene: str,
    believed_params: SimParams,
    seed: int,
    plant: PlantPerturbation | None,
    controller=None,
    reset: bool = True,
) -> Simulator:
    """The simulator of the true plant: the believed one perturbed by ``plant``, its faults scheduled.

    Args:
        believed_vehicle: the vehicle the controller flies with.
        scene: scene name.
        believed_params: the simulator parameters the reference was planned with.
        seed: simulator noise seed.
        plant: the perturbation (None: the believed plant, no faults).
        controller: told about rotor failures.
        reset: reset the simulator at the scene's start; False leaves it to the caller, before anything else
            (see :class:`~omnirotor.sim.Simulator`).

    Returns:
        A :class:`~omnirotor.sim.Simulator` (with the fault schedule of ``plant``, :func:`install_faults`).
    """
    if plant is None:
        return Simulator(believed_vehicle, scene=scene, params=believed_params, seed=seed, reset=reset)
    sim_params = plant.sim_params(believed_params)
    sim = Simulator(plant.vehicle(believed_vehicle), scene=scene, params=sim_params, seed=seed, reset=reset)
    return install_faults(sim, plant.faults, controller) if plant.faults else sim


def safety_stats(omega_cmd_hz: np.ndarray, status: np.ndarray, vehicle: VehicleParams) -> dict:
    """Were all commands finite and within the limits, and how often was each status flag raised?

    Args:
        omega_cmd_hz: (k, n) the commands of a run [Hz] (the controller log's ``omega_cmd_hz``).
        status: (k,) the :class:`~omnirotor.messages.ControlStatus` bits of each step.
        vehicle: the vehicle whose limits apply.

    Returns:
        ``{"commands_finite", "commands_within_limits", "steps", "flags": {name: steps}}``.
    """
    w = np.ascontiguousarray(omega_cmd_hz, dtype=float)  # a log's strided view: gathered once
    bits = np.asarray(status).astype(np.int64)
    finite = bool(np.all(np.isfinite(w)))
    within = finite and bool(np.all((w >= vehicle.omega_min_hz) & (w <= vehicle.omega_max_hz)))
    flags = {
        f.name.lower(): int(np.count_nonzero(bits & int(f))) for f in ControlStatus if f != ControlStatus.OK and f.name
    }
    return {"commands_finite": finite, "commands_within_limits": within, "steps": int(bits.size), "flags": flags}


def unreachable_reference(
    p_E_W: np.ndarray, R_WB: np.ndarray, kind: str, t_start_s: float = 1.0, hold_s: float = 4.0
) -> PoseTrajectory:
    """An EE reference the vehicle cannot follow: "jump" (5 m sideways in 0.5 s) or "flip" (180° in 0.2 s).

    The reference rests at ``(p_E_W, R_WB)`` until ``t_start_s``, makes the impossible move, and holds the
    new pose for ``hold_s`` [s], long enough to see the vehicle recover.

    Raises:
        InputError: unknown kind.
    """
    p0 = np.asarray(p_E_W, dtype=float)
    R0 = np.asarray(R_WB, dtype=float)
    if kind == "jump":
        move_s, p1, R1 = 0.5, p0 + np.array([5.0, 0.0, 0.0]), R0
    elif kind == "flip":
        move_s, p1, R1 = 0.2, p0, R0 @ rot_x(math.pi)
    else:
        raise InputError(f"unreachable reference kind must be 'jump' or 'flip', got {kind!r}")
    t1 = t_start_s + move_s
    return PoseTrajectory(
        [Waypoint(0.0, p0, R0), Waypoint(t_start_s, p0, R0), Waypoint(t1, p1, R1), Waypoint(t1 + hold_s, p1, R1)]
    )


# -- sensor glitches: the catalogue the frame supervision is tried on ------------------------------------------

FrameGlitch = tuple[str, str, str, float, "int | None", int, str | None, str | None]
"""``(label, signal, kind, magnitude, component, frames, cause with the UKF, cause with the bypass)``: a
:class:`SensorCorruption` of ``frames`` control periods and the supervision cause (a name of
:data:`omnirotor.control.supervisor.CAUSES`) each estimator must report (None: it does not read that signal)."""

FRAME_GLITCHES: tuple[FrameGlitch, ...] = (
    ("accelerometer NaN", "imu_acc", "nan", 0.0, None, 1, "imu", "imu"),
    ("gyroscope inf (one axis)", "imu_gyro", "inf", 0.0, 1, 1, "imu", "imu"),
    ("accelerometer 1e4 m/s² (beyond range)", "imu_acc", "spike", 1e4, None, 1, "imu", "imu"),
    ("rotor speed NaN (one rotor)", "rotor_hz", "nan", 0.0, 2, 1, "rotor", "rotor"),
    ("rotor speeds 5000 Hz", "rotor_hz", "set", 5000.0, None, 1, "rotor", "rotor"),
    ("rotor speed -5000 Hz (one rotor)", "rotor_hz", "set", -5000.0, 5, 1, "rotor", "rotor"),
    ("time +1000 s", "time", "spike", 1000.0, None, 1, "time", "time"),
    ("time -0.5 s", "time", "spike", -0.5, None, 1, "time", "time"),
    ("time repeated", "time", "spike", -1e-3, None, 1, "time", "time"),
    ("time NaN", "time", "nan", 0.0, None, 1, "time", "time"),
    ("motion capture NaN", "mocap", "nan", 0.0, None, 11, "mocap", "mocap"),
    ("motion capture 1 km away", "mocap", "spike", 1000.0, None, 11, "mocap_jump", None),
    ("motion-capture quaternion zero", "mocap_q", "set", 0.0, None, 11, "mocap", "mocap"),
    ("motion-capture quaternion not unit", "mocap_q", "spike", 0.5, 0, 11, "mocap", "mocap"),
    ("state position 1 km away", "state", "spike", 1000.0, None, 1, None, "state_jump"),
    ("state NaN", "state", "nan", 0.0, None, 1, None, "state"),
    ("state velocity jump 3 m/s", "state_v", "spike", 3.0, 0, 1, None, "state_jump"),
    ("state attitude zeros", "state_R", "set", 0.0, None, 1, None, "state"),
    ("state attitude NaN (one entry)", "state_R", "nan", 0.0, 4, 1, None, "state"),
    ("state attitude not orthogonal", "state_R", "spike", 0.3, 1, 1, None, "state"),
)
"""Single bad frames (a motion-capture glitch spans one 100 Hz sample: 11 periods) a real robot sees."""


def glitch_fault(glitch: FrameGlitch, t_start_s: float, dt: float = 1e-3) -> SensorCorruption:
    """The :class:`SensorCorruption` of a glitch (a row of :data:`FRAME_GLITCHES`) from ``t_start_s``; period ``dt``."""
    _, signal, kind, magnitude, component, frames, *_ = glitch
    return SensorCorruption(signal, t_start_s, frames * dt, kind, magnitude, component)


def random_mix(
    glitches: Sequence[FrameGlitch], p: float, t_start_s: float, duration_s: float, seed: int, group: int = 0
) -> tuple[SensorCorruption, ...]:
    """Random bad frames: one :class:`SensorCorruption` per glitch, sharing their draws.

    In ``[t_start_s, t_start_s + duration_s)`` each frame is bad with probability ``p``, hit then by one of
    ``glitches`` (rows of :data:`FRAME_GLITCHES`, each drawn equally often), the draws from ``seed``. At most
    :data:`~omnirotor.sim.faults.MAX_FAULTS` glitches in all of a schedule.
    """
    m = len(glitches)
    return tuple(
        SensorCorruption(signal, t_start_s, duration_s, kind, magnitude, component, None, (p, seed, group, j, m))
        for j, (_, signal, kind, magnitude, component, *_) in enumerate(glitches)
    )
