"""Closed loop of the interaction controller and the simulator at 1 kHz, its metrics, and a task's options.

:func:`run_closed_loop` alternates ``sim.step(command)`` and ``controller.step(frame)`` (the first period
flies the controller's hold command, as :meth:`~omnirotor.control.controller.InteractionController.reset`
consumes the initial frame) and records the simulator's ground truth in a second preallocated
:class:`~omnirotor.recorder.Recorder` whose row ``k`` is the instant of the controller log's row ``k`` (the
truth at the frame the controller saw), ``t = (k + 1) dt``.

When both sides have compiled steps (a :class:`~omnirotor.sim.Simulator` with its own rotor and truth models,
the compiled QP solver) and nothing needs Python every step (no ``on_step``, no video), the loop itself runs
compiled (:mod:`omnirotor.experiments._loop`), in chunks of up to a noise block between progress reports:
the same kernels in the same order, so the logs are identical to the Python loop's (tested), about five times
faster.

Metrics follow SPEC §6 (Table 1), computed by :mod:`omnirotor.experiments.metrics` on the
:func:`run_log` of the two recorders: errors of the EE pose the controller believed (the paper's) and of the
true one against the compliant EE reference.

A task (:mod:`omnirotor.experiments.tasks`, an explicit table) is a function ``(TaskOptions, progress) ->
TaskResult`` built on :func:`run_closed_loop`.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import functools
import math
import time
from collections.abc import Callable, Iterator
from typing import Protocol

import numpy as np

from omnirotor.config import apply_overrides
from omnirotor.control.admittance import AdmittanceParams
from omnirotor.control.controller import ControllerParams, InteractionController, load_controller_params
from omnirotor.control.trajectory import PoseTrajectory
from omnirotor.errors import InputError
from omnirotor.experiments.metrics import RunLog, table1_errors
from omnirotor.limits import MAX_DURATION_S, MAX_SEED, MIN_DURATION_S
from omnirotor.recorder import Recorder
from omnirotor.sim import SimParams, Simulator
from omnirotor.sim.params import AeroParams
from omnirotor.vehicle import VehicleParams

__all__ = [
    "run_closed_loop",
    "TRUTH_GROUPS",
    "run_log",
    "TaskOptions",
    "TaskResult",
    "FrameSink",
    "video_sink",
    "TRUTH_MODELS",
    "ESTIMATORS",
    "loop_override",
]

_XYZ = ("x", "y", "z")
_RMAT = ("xx", "xy", "xz", "yx", "yy", "yz", "zx", "zy", "zz")
_PROGRESS_UPDATES = 100
TRUTH_MODELS = ("wake", "spec7", "interference", "nominal")
ESTIMATORS = ("ukf", "bypass")


def TRUTH_GROUPS(n_rotors: int) -> list[tuple[str, tuple[str, ...] | int]]:  # noqa: N802 (a table, by name)
    """Column groups of the ground-truth log: the true state, EE tip, contact wrench and loop timing.

    ``plant_step_us`` and ``controller_step_us`` are the wall-clock times of the simulator's step that produced
    the row's frame and of the controller's step on it [µs].
    """
    return [
        ("t", 1),
        ("p_W", _XYZ),
        ("v_W", _XYZ),
        ("R_WB", _RMAT),
        ("omega_B", _XYZ),
        ("p_E_W", _XYZ),
        ("contact_force_W", _XYZ),
        ("contact_moment_W", _XYZ),
        ("in_contact", 1),
        ("rotor_hz", tuple(str(i + 1) for i in range(n_rotors))),
        ("plant_step_us", 1),
        ("controller_step_us", 1),
    ]


class FrameSink(Protocol):
    """Anything that wants to see the simulator every step (e.g. a video recorder)."""

    def capture(self, sim: Simulator) -> None:
        """Called after every simulator step; decides itself whether to render a frame."""


def start_pose_of(trajectory: PoseTrajectory, vehicle: VehicleParams) -> tuple[np.ndarray, np.ndarray]:
    """Body pose ``(p_W [m], R_WB)`` that puts the EE tip on the trajectory's first waypoint."""
    w = trajectory.waypoints[0]
    return w.p_W - w.R_WB @ vehicle.p_E_B_array, w.R_WB.copy()


_LOOP_OVERRIDE: contextvars.ContextVar[Callable | None] = contextvars.ContextVar("loop_override", default=None)


@contextlib.contextmanager
def loop_override(loop: Callable) -> Iterator[None]:
    """Within the block, :func:`run_closed_loop` calls ``loop`` with its arguments instead of flying in process.

    The software-in-the-loop simulator (:mod:`omnirotor.sitl`) runs a task of ``omnirotor run`` unchanged — its
    plant, protocol and metrics — with the controller in another process: ``loop`` has the signature of
    :func:`run_closed_loop` and returns its two logs.
    """
    token = _LOOP_OVERRIDE.set(loop)
    try:
        yield
    finally:
        _LOOP_OVERRIDE.reset(token)


def run_closed_loop(
    sim: Simulator,
    controller: InteractionController,
    trajectory: PoseTrajectory,
    duration_s: float,
    progress: Callable[[float], None] | None = None,
    video: FrameSink | None = None,
    on_step: Callable[[Simulator, float], None] | None = None,
) -> tuple[Recorder, Recorder]:
    """Fly ``trajectory`` in ``sim`` for ``duration_s``, starting at rest on the trajectory's first pose.

    Args:
        sim: the simulator (reset here to the trajectory's start; any external wrench set before is cleared).
        controller: the controller (reset here on the first frame).
        trajectory: desired EE trajectory (time 0 = start of the run).
        duration_s: simulated time [s].
        progress: called with the completed fraction in [0, 1] about every 1 %.
        video: optional :class:`FrameSink` given the simulator after every step.
        on_step: optional ``(sim, t)`` callback before each simulator step from ``t`` [s], e.g. to switch an
            external wrench on at some time with ``sim.set_external_wrench``.

    Returns:
        ``(controller log, truth log)``: the controller's own recorder (see
        :data:`omnirotor.control.controller.LOG_GROUPS`) and a new one with :func:`TRUTH_GROUPS`.

    Raises:
        InputError: non-positive duration, or simulator and controller periods that differ.
    """
    override = _LOOP_OVERRIDE.get()
    if override is not None:
        return override(sim, controller, trajectory, duration_s, progress=progress, video=video, on_step=on_step)
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise InputError(f"duration must be a finite number of seconds > 0, got {duration_s}")
    dt = controller.params.dt
    if abs(sim.dt - dt) > 1e-12:
        raise InputError(f"simulator period {sim.dt} s differs from the controller period {dt} s")
    n_steps = int(round(duration_s / dt))
    p0, R0 = start_pose_of(trajectory, controller.vehicle)
    frame = sim.reset(p_W=p0, R_WB=R0)
    controller.log.ensure_capacity(n_steps)
    controller.reset(frame, trajectory)
    truth_log = Recorder(n_steps, TRUTH_GROUPS(controller.vehicle.n_rotors))
    every = max(1, n_steps // _PROGRESS_UPDATES)
    if video is None and on_step is None and isinstance(sim, Simulator):
        sim_args, ctl_state = sim.kernel_state, controller.kernel_state
        if sim_args is not None and ctl_state is not None:
            _run_compiled(sim, controller, sim_args, ctl_state, truth_log, n_steps, every, progress)
            return controller.log, truth_log
    clock = time.perf_counter
    cmd = controller.hold_command()  # the reset frame is consumed by reset(); hold its speeds for one period
    for k in range(n_steps):
        if on_step is not None:
            on_step(sim, sim.t)
        tic0 = clock()
        frame = sim.step(cmd)
        tic = clock()
        if video is not None:
            video.capture(sim)
            tic = clock()
        cmd = controller.step(frame)
        toc = clock()
        row = truth_log.next_row()  # the TRUTH_GROUPS in order: the simulator's truth row, then the timings
        if row is not None:
            sim.truth_row(row)
            row[-2] = (tic - tic0) * 1e6
            row[-1] = (toc - tic) * 1e6
        if progress is not None and (k + 1) % every == 0:
            progress((k + 1) / n_steps)
    if progress is not None:
        progress(1.0)
    return controller.log, truth_log


def _run_compiled(
    sim: Simulator,
    controller: InteractionController,
    sim_args: np.ndarray,
    ctl_state: np.ndarray,
    truth_log: Recorder,
    n_steps: int,
    every: int,
    progress: Callable[[float], None] | None,
) -> None:
    """The loop of :func:`run_closed_loop` in compiled chunks (module docstring); the logs are filled in place."""
    from omnirotor.experiments._loop import run_steps  # compiles on first use

    log = controller.log
    records = log.data.view(controller.log_dtype).reshape(-1)  # the log's rows as its records (the same memory)
    cmd = controller.kernel_command  # the command array the compiled step writes and the simulator reads
    frame = sim.frame_record
    ts = np.zeros(2, dtype=np.int64)  # the compiled clock's scratch
    k0_sim = sim.step_index
    k = 0
    notices = [j - k0_sim for j in sim.faults.notice_steps(sim.dt) if j >= k0_sim]  # the controller is told there
    try:
        while k < n_steps:
            for stream in sim.noise_streams:
                if stream.exhausted:
                    stream.refill()
            sim.faults.tell_due(k0_sim + k, sim.dt)
            stop = n_steps if progress is None else min(n_steps, (k // every + 1) * every)
            stop = min([stop] + [j for j in notices if j > k])
            k = run_steps(sim_args, ctl_state, cmd, frame, k, stop, k0_sim, sim.dt, truth_log.data, records, ts)
            if progress is not None and k % every == 0:
                progress(k / n_steps)
    finally:  # what was run is logged and the Python side of both reflects it
        sim.step_index = k0_sim + k
        truth_log.n = k
        log.n = k
        controller.sync()
    if progress is not None:
        progress(1.0)


def run_log(controller_log: Recorder, truth_log: Recorder) -> RunLog:
    """The signals of a run for :mod:`omnirotor.experiments.metrics`: true and believed EE pose, references, estimates.

    Rows are paired by index (row ``k`` of both logs is the same instant); the shorter log sets the length. The
    signals are views of the two logs' storage (no copies; ``in_contact``, ``region`` and ``status`` are converted):
    they show what the logs hold, so a log cleared and written again (a reused controller) changes them.
    """
    n = min(controller_log.n, truth_log.n)
    c, tr = controller_log, truth_log
    return RunLog(
        t=c.group("t")[:n],
        p_E_W=tr.group("p_E_W")[:n],
        R_WE=tr.group("R_WB")[:n].reshape(n, 3, 3),  # R_E^B = I (SPEC §1.5)
        p_E_est_W=c.group("p_E_W")[:n],
        R_WE_est=c.group("R_WB")[:n].reshape(n, 3, 3),
        p_Er_W=c.group("p_E_ref_W")[:n],
        R_WEr=c.group("R_E_ref")[:n].reshape(n, 3, 3),
        p_Ed_W=c.group("p_E_des_W")[:n],
        f_ext_hat_W=c.group("f_ext_W")[:n],
        m_ext_hat_B=c.group("m_ext_B")[:n],
        f_contact_W=tr.group("contact_force_W")[:n],
        in_contact=tr.group("in_contact")[:n] > 0.5,
        region=c.group("region")[:n].astype(int),
        omega_hz=c.group("omega_cmd_hz")[:n],
        status=c.group("status")[:n].astype(int),
    )


# -- tasks ----------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class TaskOptions:
    """Options common to every task of ``omnirotor run``.

    Attributes:
        solver: allocation QP backend, "active-set" (default), "daqp" or "proxsuite".
        estimator: "ukf" or "bypass" (ground truth plus noise).
        duration_s: simulated time [s]; None for the task's default.
        seed: simulator noise seed.
        truth: truth aerodynamics of the simulator: "wake" (the calibrated rotor-wake model, default),
            "spec7" or "interference" (SPEC §7), or "nominal" (= A_nom u).
        vehicle: vehicle preset or TOML file.
        controller_config: controller TOML file (see ``load_controller_params``), or None.
        overrides: dotted ``key=value`` overrides of the controller parameters.
        video: MP4 file to film the run into (30 fps, offscreen MuJoCo rendering), or None.
        disturbances: fly the simulator's disturbances (thrust fluctuation, recirculation force, IMU vibration,
            motion-capture jitter; docs/fidelity.md); False: :meth:`SimParams.undisturbed`.
    """

    solver: str = "active-set"
    estimator: str = "ukf"
    duration_s: float | None = None
    seed: int = 0
    truth: str = "wake"
    vehicle: str = "omnirotor"
    controller_config: str | None = None
    overrides: tuple[str, ...] = ()
    video: str | None = None
    disturbances: bool = True

    def __post_init__(self) -> None:
        if self.estimator not in ESTIMATORS:
            raise InputError(f"estimator must be one of {', '.join(ESTIMATORS)}, got {self.estimator!r}")
        if self.truth not in TRUTH_MODELS:
            raise InputError(f"truth must be one of {', '.join(TRUTH_MODELS)}, got {self.truth!r}")
        if self.duration_s is not None and not (MIN_DURATION_S <= self.duration_s <= MAX_DURATION_S):
            raise InputError(
                f"duration must be in [{MIN_DURATION_S:g}, {MAX_DURATION_S:g}] s (omnirotor.limits), "
                f"got {self.duration_s:g}"
            )
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed <= MAX_SEED:
            raise InputError(f"seed must be an integer in [0, 2^63 - 1], got {_short_int(self.seed)}")

    def controller_params(self, admittance: AdmittanceParams | None = None) -> ControllerParams:
        """Controller parameters: file and overrides, then these options' solver and estimator.

        Args:
            admittance: the task's admittance set, applied before the file and overrides.
        """
        choices = (self.solver, self.estimator, tuple(self.overrides))
        if self.controller_config is None:  # the defaults: built once per process (a campaign asks every run)
            return _default_controller_params(admittance, *choices)
        return _controller_params(load_controller_params(self.controller_config), None, *choices)

    def sim_params(self) -> SimParams:
        """Simulator parameters with the chosen truth aerodynamics (and without the disturbances if so chosen)."""
        return task_sim_params(self.truth, self.disturbances)


def _controller_params(
    params: ControllerParams,
    admittance: AdmittanceParams | None,
    solver: str,
    estimator: str,
    overrides: tuple[str, ...],
) -> ControllerParams:
    """:meth:`TaskOptions.controller_params` from the file's (or the default) parameters."""
    if admittance is not None:
        params = dataclasses.replace(params, admittance=admittance)
    params = dataclasses.replace(
        params,
        allocation=dataclasses.replace(params.allocation, solver=solver),
        estimator=dataclasses.replace(params.estimator, kind=estimator),
    )
    return apply_overrides(params, list(overrides))


@functools.lru_cache(maxsize=64)
def _default_controller_params(
    admittance: AdmittanceParams | None, solver: str, estimator: str, overrides: tuple[str, ...]
) -> ControllerParams:
    """:meth:`TaskOptions.controller_params` without a file, once per combination (the result is frozen, shared)."""
    return _controller_params(ControllerParams(), admittance, solver, estimator, overrides)


@functools.lru_cache(maxsize=64)
def task_sim_params(truth: str, disturbances: bool, overrides: tuple[str, ...] = ()) -> SimParams:
    """Simulator parameters of a task: the truth aerodynamics, the disturbances or not, then dotted overrides.

    Built once per combination and process (a campaign's runs ask for them several times each); the result is
    frozen, so its callers share it.
    """
    params = SimParams(aero=AeroParams(model=truth))
    params = params if disturbances else params.undisturbed()
    return apply_overrides(params, list(overrides)) if overrides else params


@contextlib.contextmanager
def video_sink(sim: Simulator, path: str | None) -> Iterator[FrameSink | None]:
    """A :class:`~omnirotor.sim.VideoRecorder` of ``sim`` writing ``path`` (None: no video).

    The file is written when the block exits normally and discarded on an exception.
    """
    if path is None:
        yield None
        return
    from omnirotor.sim import VideoRecorder

    with VideoRecorder(sim, path) as rec:
        yield rec


@dataclasses.dataclass
class TaskResult:
    """What a task run produced.

    Attributes:
        task: task name.
        options: the options it ran with.
        duration_s: simulated time [s].
        controller_log: the controller's log.
        truth_log: the ground-truth log.
        metrics_from_s: time [s] from which the error metrics are taken (settling excluded).
    """

    task: str
    options: TaskOptions
    duration_s: float
    controller_log: Recorder
    truth_log: Recorder
    metrics_from_s: float = 0.0

    def summary(self) -> dict:
        """The JSON of ``omnirotor run``: EE errors (SPEC §6), options and the controller step time."""
        log = run_log(self.controller_log, self.truth_log)
        return self.summary_of(log, table1_errors(log, log.t >= self.metrics_from_s))

    def summary_of(self, log: RunLog, errors: dict[str, dict]) -> dict:
        """:meth:`summary` from the run's :func:`run_log` and its EE errors, computed once by the caller.

        Args:
            log: the run's signals (:func:`run_log`).
            errors: ``table1_errors`` of ``log`` from ``metrics_from_s`` (the RMS and max EE errors, believed and
                true pose).
        """
        out = {
            "task": self.task,
            "solver": self.options.solver,
            "estimator": self.options.estimator,
            "truth": self.options.truth,
            "seed": self.options.seed,
            "duration_s": self.duration_s,
        }
        out.update(errors)
        keep = log.t >= self.metrics_from_s
        out["f_ext_hat_W_mean_N"] = log.f_ext_hat_W[keep].mean(axis=0).tolist()
        out["m_ext_hat_B_mean_Nm"] = log.m_ext_hat_B[keep].mean(axis=0).tolist()
        out["xi_p_W_final_cm"] = (100.0 * self.controller_log.group("xi_p_W")[-1]).tolist()
        step_us = self.truth_log.group("controller_step_us")
        out["controller_step_us_median"] = float(np.median(step_us))
        status = self.controller_log.group("status").astype(int)
        out["steps"] = int(status.shape[0])
        out["steps_flagged"] = int(np.count_nonzero(status))
        return out


TaskFn = Callable[[TaskOptions, Callable[[float], None] | None], TaskResult]


def _short_int(v: object) -> str:
    return f"an integer of {v.bit_length()} bits" if isinstance(v, int) and v.bit_length() > 64 else repr(v)


HOVER_DURATION_S = 5.0
"""Default length of the ``hover`` task (:func:`omnirotor.experiments.tasks.common.hover`) [s]."""
