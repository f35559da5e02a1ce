"""The 1 kHz sensorless interaction controller: every block of the paper's Figure 4 wired together.

One :meth:`InteractionController.step` turns a :class:`~omnirotor.messages.SensorFrame` into a
:class:`~omnirotor.messages.RotorCommand`:

1. state estimate (UKF or bypass, :mod:`omnirotor.control.estimator`);
2. wrench map of the current attitude (:mod:`omnirotor.control.maps`, SPEC §3.3);
3. external wrench observer with that map and the rotor inputs acting on the vehicle (SPEC §4.3); its
   interaction estimate (after bias and zeroing) drives the admittance, its full estimate (before them)
   is compensated by the pose controller (see :mod:`omnirotor.control.observer`);
4. the wrench moved to the end-effector (EE) tip, admittance filter, compliant EE reference (SPEC §4.4);
5. body reference from the EE reference (SPEC §4.4);
6. pose controller -> wrench reference ``[f_ref_W; m_ref_B]`` (SPEC §4.1);
7. allocation QP -> inputs u [Hz²] (SPEC §4.2), then ``omega = sign(u) sqrt(|u|)`` clipped to the limits.

Safety: the estimators replace a non-finite or out-of-range sensor sample by the last good one and say so;
the step is then flagged ``NONFINITE_INPUT`` and runs on. Should a non-finite state estimate (or measured
rotor speed) still arrive, no stateful block is updated and the last safe command is held, flagged
``NONFINITE_INPUT``. Nothing non-finite ever leaves :meth:`step`.

The observer's input ``u`` is by default the *measured* rotor speeds of the frame (``u = |omega| omega``,
as on the robot, where the motor controllers report them; it accounts for the rotor lag), or with
``observer_input = "commanded"`` the previous command.

Trajectory time is ``frame.t - t0`` with ``t0`` the time of the frame given to :meth:`reset`. :meth:`reset`
consumes that frame (the estimator starts from it); the command for the first period is
:meth:`InteractionController.hold_command`, and :meth:`step` takes the frames that follow.

Every step is logged in :attr:`InteractionController.log` (a :class:`~omnirotor.recorder.Recorder`, groups
in :data:`LOG_GROUPS`): time, estimate, actual EE position, desired and compliant EE poses, admittance
offset, estimated wrench, wrench reference, pose errors, u, omega command, region index and status.

Cost. Every block keeps its state, and its sized arrays, in a field of the controller's one structured record
(:attr:`state`, see :mod:`omnirotor.control.composer`). With the default QP solver ("active-set", compiled)
:meth:`step` is **one** compiled call, :func:`~omnirotor.control.composer.controller_step` ``(state, frame,
row)``, on the frame's record (:mod:`omnirotor.messages`): a frame made by the simulator carries it, another one
is written into one first. The call skips numba's typing of its three records (the specialisation for this
controller's own arrays, found once by the first step: :func:`omnirotor._jit.typed_entry`), after a cheap check
that the arrays are of those types; others go through numba's dispatch. A compiled closed loop calls the same
function with :attr:`InteractionController.kernel_state`. With the "daqp" or "proxsuite" solvers (called from
Python) the composer's two halves run as two compiled calls around that solver; with an estimator that is not compiled
(e.g. a stand-in) its estimate is given to the same composer. There is one implementation of every block's
step.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from omnirotor._jit import typed_entry
from omnirotor.blocks import block_class, block_names, log_dtype, new_records, new_state, record_view
from omnirotor.config import apply_overrides, check_positive, from_mapping, load_toml
from omnirotor.control import _estimator_kernels as _ek
from omnirotor.control import composer as _c
from omnirotor.control.admittance import AdmittanceParams, body_reference_from_ee
from omnirotor.control.allocation import BEGIN_SOLVE, BEGIN_SOLVE_NEW_MAP, AllocationParams
from omnirotor.control.estimator import BypassEstimator, EstimatorParams, UKFEstimator, make_estimator, ukf_capacity
from omnirotor.control.maps import MAP_MODES, MapParams, schedule_sizes
from omnirotor.control.observer import ObserverParams
from omnirotor.control.pose import PoseControlParams
from omnirotor.control.supervisor import CAUSES, SupervisorParams
from omnirotor.control.trajectory import (
    MIN_CAPACITY_WAYPOINTS,
    SEGMENT_DTYPE,
    PoseTrajectory,
    ReferenceSample,
    start_segment,
)
from omnirotor.errors import InputError
from omnirotor.messages import ControlStatus, RotorCommand, SensorFrame, frame_dtype
from omnirotor.recorder import Recorder
from omnirotor.vehicle import VehicleParams
from omnirotor.wrench_maps import WrenchMapSet

__all__ = [
    "ControllerParams",
    "InteractionController",
    "load_controller_params",
    "LOG_GROUPS",
    "OBSERVER_INPUTS",
]

OBSERVER_INPUTS = ("measured", "commanded")


def LOG_GROUPS(n_rotors: int, params: ControllerParams | None = None) -> list[tuple[str, tuple[str, ...]]]:  # noqa: N802
    """Column groups of the controller log for ``n_rotors`` rotors: ``(name, column labels)`` in row order.

    Derived from the log record (:func:`omnirotor.control.composer.log_sources`: every block's own
    ``log_fields``), the flat row being that record's floats in order. ``t`` [s] trajectory time; ``region``
    map region index (-1 in nominal/global mode); ``status`` the :class:`ControlStatus` bits; ``p_W, v_W, a_W,
    R_WB, omega_B`` the state estimate (``R_WB`` row-major); ``p_E_W`` the estimated EE tip; ``*_E_ref*`` the
    compliant EE reference and ``*_E_des*`` the desired EE reference (pose, velocity, acceleration, world-frame
    angular velocity and acceleration); ``xi_p_W`` the admittance position offset; ``f_ext_W, m_ext_B`` the
    observer's interaction estimate (with another observer: its ``log_fields``); ``w_ref`` the pose
    controller's ``[f_ref_W; m_ref_B]``; ``pose_err`` ``[e_p, e_v, e_R, e_omega]`` of the body; ``u_hz2`` the
    allocated inputs; ``omega_cmd_hz`` the command; ``frame_reject`` the frame supervision's cause bits
    (:data:`omnirotor.control.supervisor.CAUSES`, 0 for a clean frame).
    """
    classes = _block_classes(params if params is not None else ControllerParams())
    state_dtype = _controller_dtype(classes, _c.ControllerSizes(n_rotors, 1, 0, 0, 1))
    return [(g.name, g.labels) for g in _c.controller_log_groups(state_dtype, classes)]


_CHOSEN_KINDS = ("supervisor", "maps", "observer", "trajectory", "admittance", "pose", "allocation")
"""The kinds :class:`ControllerParams` chooses by name (``<kind>_kind``; the estimator by ``estimator.kind``)."""


def _block_classes(params: ControllerParams) -> dict[str, type]:
    """The class of each kind ``params`` name (every one is reached through the registry)."""
    return {kind: block_class(kind, getattr(params, f"{kind}_kind")) for kind in _CHOSEN_KINDS}


def _controller_dtype(classes: dict[str, type], sizes: _c.ControllerSizes) -> np.dtype:
    """The controller's record for blocks of these classes and these sizes (:func:`composer.controller_dtype`)."""
    d = {kind: cls.state_dtype for kind, cls in classes.items()}
    return _c.controller_dtype(
        d["observer"], sizes, d["admittance"], d["pose"], d["supervisor"], d["maps"], d["trajectory"],
        d["allocation"], classes["allocation"].arrays_dtype(sizes.n_rotors),
    )  # fmt: skip


@dataclasses.dataclass(frozen=True)
class ControllerParams:
    """Parameters of the whole controller; one TOML section per block (see :func:`load_controller_params`).

    Attributes:
        pose: pose controller (SPEC §4.1).
        allocation: allocation QP (SPEC §4.2).
        maps: wrench-map scheduling (SPEC §3.3).
        observer: wrench observer (SPEC §4.3).
        admittance: admittance filter (SPEC §4.4, §5.1); default the free-flight set.
        estimator: state estimator (SPEC §4.5).
        supervisor: the sensor-frame supervision (:mod:`omnirotor.control.supervisor`).
        dt: control period [s] (1 kHz, SPEC §4).
        log_capacity: rows preallocated for the log [steps]; a full log grows by as many rows again (no cap;
            :class:`~omnirotor.recorder.Recorder`). 0: no log.
        observer_input: "measured" rotor speeds (default) or the "commanded" ones feed the observer.
        observer_kind: the registered name of the observer block (:mod:`omnirotor.blocks`; default
            "momentum", :class:`~omnirotor.control.observer.WrenchObserver`); it is built from ``observer``.
        admittance_kind: the registered name of the admittance block (default "mass-spring-damper",
            :class:`~omnirotor.control.admittance.AdmittanceFilter`), built from ``admittance``.
        pose_kind: the registered name of the pose controller (default "geometric-pid",
            :class:`~omnirotor.control.pose.PoseController`), built from ``pose``.
        supervisor_kind: the registered name of the frame supervision (default "frame-checks",
            :class:`~omnirotor.control.supervisor.FrameSupervisor`), built from ``supervisor``.
        maps_kind: the registered name of the map scheduler (default "regions",
            :class:`~omnirotor.control.maps.MapScheduler`), built from ``maps``.
        allocation_kind: the registered name of the allocation (default "box-qp",
            :class:`~omnirotor.control.allocation.Allocator`), built from ``allocation``.
        trajectory_kind: the registered name of the trajectory block (default "min-jerk",
            :class:`~omnirotor.control.trajectory.WaypointTrajectory`).
        trajectory_waypoints: the most waypoints a trajectory given to :meth:`InteractionController.reset` may
            have (the record's capacity, fixed when the controller is built: a longer one is refused with an
            ``InputError``, never compiled for); at least 2 (the flight node's moves have two).
    """

    pose: PoseControlParams = dataclasses.field(default_factory=PoseControlParams)
    allocation: AllocationParams = dataclasses.field(default_factory=AllocationParams)
    maps: MapParams = dataclasses.field(default_factory=MapParams)
    observer: ObserverParams = dataclasses.field(default_factory=ObserverParams)
    admittance: AdmittanceParams = dataclasses.field(default_factory=AdmittanceParams)
    estimator: EstimatorParams = dataclasses.field(default_factory=EstimatorParams)
    supervisor: SupervisorParams = dataclasses.field(default_factory=SupervisorParams)
    dt: float = 1e-3
    log_capacity: int = 120_000
    observer_input: str = "measured"
    observer_kind: str = "momentum"
    admittance_kind: str = "mass-spring-damper"
    pose_kind: str = "geometric-pid"
    supervisor_kind: str = "frame-checks"
    maps_kind: str = "regions"
    allocation_kind: str = "box-qp"
    trajectory_kind: str = "min-jerk"
    trajectory_waypoints: int = MIN_CAPACITY_WAYPOINTS

    def __post_init__(self) -> None:
        check_positive("controller dt", self.dt)
        if isinstance(self.log_capacity, bool) or not isinstance(self.log_capacity, int) or self.log_capacity < 0:
            raise InputError(f"controller log_capacity must be an integer >= 0, got {self.log_capacity!r}")
        if self.observer_input not in OBSERVER_INPUTS:
            raise InputError(f"observer_input must be one of {OBSERVER_INPUTS}, got {self.observer_input!r}")
        n = self.trajectory_waypoints
        if isinstance(n, bool) or not isinstance(n, int) or n < 2:  # a move (retarget, take-off) has two
            raise InputError(f"controller trajectory_waypoints must be an integer >= 2, got {n!r}")
        for kind in _CHOSEN_KINDS:
            name = getattr(self, f"{kind}_kind")
            if not isinstance(name, str) or name not in block_names(kind):
                block_class(kind, str(name))  # raises, listing the registered blocks of that kind


def load_controller_params(
    path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()
) -> ControllerParams:
    """Controller parameters from a TOML file and/or dotted ``key=value`` overrides.

    The file has top-level ``dt``, ``log_capacity``, ``observer_input``, the ``*_kind`` block names and sections
    ``[pose]``, ``[allocation]``, ``[maps]``, ``[observer]``, ``[admittance]``, ``[estimator]``, ``[supervisor]``
    whose keys are the fields of the blocks' parameter classes; unknown keys are errors. Overrides look like
    ``"observer.cutoff_hz=5"`` or ``"admittance.stiffness_pos=[30, 30, 30]"``.

    Args:
        path: TOML file, or None for the defaults.
        overrides: dotted overrides applied after the file.

    Raises:
        InputError: unreadable file, unknown key, bad value.
    """
    params = ControllerParams()
    if path is not None:
        params = from_mapping(ControllerParams, load_toml(path), str(path))
    return apply_overrides(params, list(overrides))


# ControlStatus values by bit pattern, so that step() never builds an enum by OR-ing flags.
_STATUS_BY_BITS = tuple(ControlStatus(i) for i in range(1024))


class InteractionController:
    """The composed interaction controller (module docstring).

    Args:
        vehicle: the vehicle model.
        params: controller parameters.
        maps: identified wrench maps; required by ``maps.mode`` "global" and "piecewise".

    Attributes:
        estimator, scheduler, observer, admittance, pose, allocator: the blocks.
        log: the step log (:data:`LOG_GROUPS`); cleared by :meth:`reset`. Each row's floats are one record
            of :attr:`log_dtype`, whose fields are :attr:`log_groups` (every block's ``log_fields``).
        desired_ee, compliant_ee, body_ref: the references of the last step.
    """

    def __init__(
        self, vehicle: VehicleParams, params: ControllerParams | None = None, maps: WrenchMapSet | None = None
    ) -> None:
        self.vehicle = vehicle
        self.params = params if params is not None else ControllerParams()
        p = self.params
        n = vehicle.n_rotors
        self._wrench_maps = maps
        self._dt = p.dt
        self._measured_input = p.observer_input == "measured"
        self._p_E_B = vehicle.p_E_B_array
        self._omega_lo = float(vehicle.omega_min_hz)
        self._omega_hi = float(vehicle.omega_max_hz)
        self._n = n
        self._rotor_shape = (n,)
        self._failed_mask: np.ndarray | None = None
        self._trajectory: PoseTrajectory | None = None
        self._t0 = 0.0
        self._frame_buf = new_records(frame_dtype(n))
        self._frame_dtype = frame_dtype(n)
        self._kernel_estimator = None  # the estimator the compiled step runs on its field (set by reset)
        self._fast = False  # step() is one compiled call (set by reset)
        self.estimator = None
        self._assemble()
        self.log_groups = _c.controller_log_groups(self.state.dtype, _block_classes(p))
        self.log_dtype = log_dtype(self.log_groups)
        self.log = Recorder(
            p.log_capacity,
            [(g.name, g.labels) for g in self.log_groups],
            grow_rows=p.log_capacity,
            record_dtype=self.log_dtype,  # the step writes the log's row itself, as a record (no copy)
        )
        self._no_row = np.zeros(0, self.log_dtype)
        # The compiled step for the types of this controller's own arrays, called without numba's typing of the
        # three records per call (found by the first step from Python: _typed_arrays); the arrays it was found
        # for, and the log memory whose rows were checked.
        self._typed_step = None
        self._typed_state: np.ndarray | None = None
        self._typed_row_base: np.ndarray | None = None

    def _assemble(self) -> None:
        """Build the controller's record and every block of the kinds :attr:`params` names on its field.

        The record's sizes (rotors, UKF ring, map partition, trajectory capacity) are fixed here, so its type,
        and the compiled step, never change afterwards.
        """
        p, vehicle, n = self.params, self.vehicle, self._n
        classes = _block_classes(p)
        n_regions, n_intervals = schedule_sizes(self._wrench_maps)
        traj_size = classes["trajectory"].data_size(p.trajectory_waypoints)
        self.sizes = _c.ControllerSizes(n, ukf_capacity(p.estimator), n_regions, n_intervals, traj_size)
        self.state = state = new_state(_controller_dtype(classes, self.sizes))
        self._own = own = state[0]["own"]
        self.estimator = make_estimator(vehicle, p.estimator, state=state[p.estimator.kind], memory=state["ukf_memory"])
        self.supervisor = classes["supervisor"](vehicle, p.supervisor, state=state["supervisor"])
        self.scheduler = classes["maps"](
            vehicle, self._wrench_maps, p.maps, state=state["maps"], arrays=state["maps_arrays"]
        )
        self._piecewise = bool(self.scheduler.follows_attitude)  # the map depends on the attitude
        self.observer = classes["observer"](vehicle, p.observer, state=state["observer"])
        self.trajectory_block = classes["trajectory"](
            p.trajectory_waypoints, state=state["trajectory"], data=state["trajectory_data"][0]
        )
        self.admittance = classes["admittance"](p.admittance, state=state["admittance"])
        self.pose = classes["pose"](vehicle, p.pose, state=state["pose"])
        self.allocator = classes["allocation"](
            vehicle, p.allocation, state=state["allocation"], arrays=state["allocation_arrays"]
        )
        self.desired_ee = ReferenceSample(state["desired_ee"])
        self.compliant_ee = ReferenceSample(state["compliant_ee"])
        self.body_ref = ReferenceSample(state["body_ref"])
        own["p_E_B"] = vehicle.p_E_B
        own["omega_min_hz"] = self._omega_lo
        own["omega_max_hz"] = self._omega_hi
        own["dt"] = self._dt
        own["measured"] = 1 if self._measured_input else 0
        own["piecewise"] = 1 if self._piecewise else 0
        own["excluded"] = 0
        rot = record_view(state["rotors"])
        self._u_obs, self._u_cmd, self._omega_cmd, self._omega_safe = (
            rot.u_obs_hz2, rot.u_cmd_hz2, rot.omega_cmd_hz, rot.omega_safe_hz
        )  # fmt: skip
        self._estimate = state["own"]["estimate"]  # (1,) view: the estimate of the last period

    # -- set-up -------------------------------------------------------------------------------------------

    @property
    def trajectory(self) -> PoseTrajectory | None:
        """The desired EE trajectory given to :meth:`reset`."""
        return self._trajectory

    def set_failed_rotors(self, mask: np.ndarray | None) -> None:
        """Exclude rotors from the allocation (see :meth:`Allocator.set_failed_rotors`)."""
        self.allocator.set_failed_rotors(mask)
        self._failed_mask = self.allocator.failed_rotors.copy()
        self._own["excluded"] = 1 if self._excluded else 0

    @property
    def _excluded(self) -> bool:
        return self._failed_mask is not None and bool(np.any(self._failed_mask))

    @property
    def kernel_state(self) -> np.ndarray | None:
        """The controller's record, for a compiled loop's call of :func:`omnirotor.control.composer.controller_step`.

        None before :meth:`reset`, with a QP solver called from Python ("daqp", "proxsuite"), or while the
        estimator is not one the compiled step runs (not initialised, or replaced after :meth:`reset`).
        Its type is fixed when the controller is built (:attr:`sizes`).
        """
        if self._trajectory is None or not self.allocator.solves_compiled or not self._estimator_compiled():
            return None
        return self.state

    def _estimator_compiled(self) -> bool:
        est = self.estimator
        return est is self._kernel_estimator and bool(getattr(est, "initialised", False))

    @property
    def frame_causes(self) -> dict[str, int]:
        """Frames since :meth:`reset` with each cause of the frame supervision (:mod:`omnirotor.control.supervisor`)."""
        counts = self.state[0]["supervisor"]["counts"]
        return {name: int(counts[i]) for i, (name, _) in enumerate(CAUSES)}

    @property
    def kernel_command(self) -> np.ndarray:
        """(n,) the array the compiled step writes its command into [Hz] (a compiled loop's plant input).

        Read it, never write it: it is the controller's own state (the last command). Valid until the next
        :meth:`reset`.
        """
        return self._omega_cmd

    def sync(self) -> None:
        """Bring the Python-side attributes up to date after compiled steps made elsewhere (a compiled loop).

        Every block keeps its state in arrays the compiled step updates; only the map scheduler's region name
        and index are Python attributes.
        """
        self.scheduler.sync()

    def _prepare_step(self) -> None:
        """Say in the record which estimator the compiled step runs, and whether :meth:`step` is one call."""
        est = self.estimator
        own = self._own
        own["t0"] = self._t0
        own["excluded"] = 1 if self._excluded else 0
        # The compiled step runs the UKF or the bypass kept in the state's field of its name; another estimator
        # (or one kept elsewhere) runs from Python and gives its estimate.
        own["estimator"] = _c.EST_GIVEN
        if isinstance(est, UKFEstimator) and np.shares_memory(est.state, self.state["ukf"]):
            own["estimator"] = _c.EST_UKF
        elif isinstance(est, BypassEstimator) and np.shares_memory(est.state, self.state["bypass"]):
            own["estimator"] = _c.EST_BYPASS
        self._kernel_estimator = est
        self._own_estimator_kind = int(own["estimator"])
        # One compiled call when nothing runs from Python (after reset the estimator is initialised: its reset
        # raises otherwise).
        compiled = self.allocator.solves_compiled and self._own_estimator_kind != _c.EST_GIVEN
        self._fast = compiled and self._estimator_compiled()

    def reset(self, frame: SensorFrame, trajectory: PoseTrajectory) -> None:
        """Start a run: reset every block on the first frame and fly ``trajectory`` from ``frame.t``.

        The held "last safe" command starts as the frame's measured rotor speeds (clipped), or the upright
        hover speeds if those are not finite. The log is cleared. The trajectory is loaded into the trajectory
        block (the record's fields ``trajectory`` and ``trajectory_data``), whose capacity was fixed when the
        controller was built (``ControllerParams.trajectory_waypoints``): the record, and so the compiled step,
        stay the same.

        Raises:
            InputError: not a :class:`PoseTrajectory`, one with more waypoints than the capacity, or a frame
                whose rotor count is not the vehicle's.
        """
        if not isinstance(trajectory, PoseTrajectory):
            raise InputError(f"expected a PoseTrajectory, got {type(trajectory).__name__}")
        hz = np.asarray(frame.rotor_hz, dtype=float)
        if hz.shape != (self._n,):
            raise InputError(f"frame.rotor_hz has shape {hz.shape}; the vehicle has {self._n} rotors")
        record = self._record(frame)
        self.trajectory_block.load(trajectory)  # refuses a trajectory beyond the capacity, before anything changes
        self.trajectory_block.reset()
        self._trajectory = trajectory
        self._t0 = float(frame.t)
        self.estimator.reset(frame)
        # The estimate the first frame's supervision checks motion capture against: the start's.
        if isinstance(self.estimator, UKFEstimator):
            self.estimator.write_estimate(self._estimate)
        elif isinstance(self.estimator, BypassEstimator):
            self._estimate[0] = self.estimator.state["last"][0]
        self.observer.reset()
        self.admittance.reset()
        self.pose.reset()
        self.allocator.reset()
        if not np.all(np.isfinite(hz)):
            u = self.vehicle.hover_input()
            hz = np.sign(u) * np.sqrt(np.abs(u))
        np.clip(hz, self._omega_lo, self._omega_hi, out=self._omega_safe)
        self._omega_cmd[:] = self._omega_safe
        np.multiply(np.abs(self._omega_safe), self._omega_safe, out=self._u_cmd)
        self._u_obs[:] = self._u_cmd
        trajectory.sample(0.0, self.desired_ee)
        self.compliant_ee.copy_from(self.desired_ee)
        body_reference_from_ee(self.compliant_ee, self._p_E_B, self.body_ref)
        self.log.clear()
        self.state["segment"] = np.zeros(1, SEGMENT_DTYPE)  # the trajectory given here flies
        self._prepare_step()
        kind = int(self._own["estimator"])
        self.supervisor.reset(
            record, dt=self._dt, acc_range=self.params.estimator.acc_range,
            gyro_range=self.params.estimator.gyro_range, check_state=kind == _c.EST_BYPASS,
            check_mocap=kind == _c.EST_UKF,
        )  # fmt: skip

    def hold_command(self, t: float | None = None) -> RotorCommand:
        """The last safe command (after :meth:`reset`: the initial frame's speeds), e.g. for the first period.

        :meth:`reset` consumes its frame; the command that flies the period until the next frame is this
        one, and :meth:`step` then takes the frames that follow.

        Args:
            t: time stamp [s] of the command; default the reset frame's time.
        """
        return RotorCommand(t=self._t0 if t is None else t, omega_hz=self._omega_safe.copy())

    # -- set-points in flight (between steps; the flight node's commands) -----------------------------------

    @property
    def time(self) -> float:
        """The controller's (trajectory) time of the last step [s]: the frame's time minus the reset frame's."""
        return float(self._own["t"])

    def retarget(self, p_E_W: np.ndarray, R_WE: np.ndarray | None = None, duration_s: float = 2.0) -> None:
        """Replace the trajectory, from the next step on, by a minimum-jerk segment to an EE pose at rest.

        The segment starts at the controller's time (:attr:`time`, which runs on continuously) from the desired
        EE reference of the last step: its position, velocity and acceleration are continuous there (the
        attitude moves along the geodesic from the last desired attitude, its angular velocity starting at 0;
        :func:`~omnirotor.control.trajectory.segment_sample`). After ``duration_s`` the pose is held. A later
        call starts a new segment from wherever the reference then is; :meth:`reset` returns to a trajectory.

        Args:
            p_E_W: (3,) target EE position [m], world frame.
            R_WE: (3, 3) target EE attitude (EE to world); default the last desired attitude.
            duration_s: duration of the segment [s].

        Raises:
            InputError: before :meth:`reset`, or a target or duration that is not valid.
        """
        if self._trajectory is None:
            raise InputError("InteractionController.retarget before reset(frame, trajectory)")
        R = self.desired_ee.R_WB if R_WE is None else R_WE
        start_segment(self.state["segment"], self.desired_ee, self.time, p_E_W, R, duration_s)

    def set_admittance(self, params: AdmittanceParams | str) -> None:
        """Change the admittance parameters in flight: an :class:`AdmittanceParams` or a preset's name.

        Only the parameters change; the filter's offsets (``xi``) and their rates are its state and carry on,
        so the compliant reference does not jump (it moves on under the new mass, damping and stiffness).
        Presets: :data:`~omnirotor.control.admittance.ADMITTANCE_PRESETS` (the paper's Table 2 sets).

        Raises:
            InputError: an unknown preset name.
        """
        p = AdmittanceParams.preset(params) if isinstance(params, str) else params
        if not isinstance(p, AdmittanceParams):
            raise InputError(f"expected AdmittanceParams or a preset name, got {type(params).__name__}")
        self.admittance.set_params(p)
        self.params = dataclasses.replace(self.params, admittance=p)

    def set_map_mode(self, mode: str) -> None:
        """Switch the wrench-map mode in flight ("nominal", "global" or "piecewise"), from the next step on.

        The scheduler is rebuilt for the new mode on its field of the state (the maps given to the controller
        are needed for "global" and "piecewise"); in piecewise mode the region follows the attitude from the next
        step. The map itself changes at the switch (that is the point).

        Raises:
            InputError: an unknown mode, or a mode whose maps the controller was not given.
        """
        if mode not in MAP_MODES:
            raise InputError(f"map mode must be one of {MAP_MODES}, got {mode!r}")
        maps_params = dataclasses.replace(self.params.maps, mode=mode)
        saved = self.state["maps"].copy(), self.state["maps_arrays"].copy()
        try:
            scheduler = type(self.scheduler)(
                self.vehicle, self._wrench_maps, maps_params, state=self.state["maps"], arrays=self.state["maps_arrays"]
            )
        except InputError:
            self.state["maps"], self.state["maps_arrays"] = saved  # the running scheduler stays as it was
            raise
        self.scheduler = scheduler
        self.params = dataclasses.replace(self.params, maps=maps_params)
        self._piecewise = bool(scheduler.follows_attitude)
        self._own["piecewise"] = 1 if self._piecewise else 0
        if self._trajectory is not None:
            self._prepare_step()

    # -- the 1 kHz step -----------------------------------------------------------------------------------

    def step(self, frame: SensorFrame) -> RotorCommand:
        """One control period: sensor frame in, rotor command out (module docstring).

        Returns:
            A command with fresh arrays; its speeds are finite and within the vehicle's limits.
        """
        if self._trajectory is None:
            raise InputError("InteractionController.step before reset(frame, trajectory)")
        record = frame.record
        if record is None or record.dtype is not self._frame_dtype:  # (the common case inline: _record)
            record = self._record(frame)
        row = self.log.next_record()  # the log's next row as a (1,) record: the step writes it in place
        if row is None:  # a full log that does not grow: nothing logged
            row = self._no_row
        if self._fast and self.estimator is self._kernel_estimator:
            # A compiled estimator and QP: one compiled call, typed once (_typed_arrays) if its arrays are ours;
            # the check's common case inline (the same state; a row of the log memory checked last time).
            state = self.state
            if (
                state is self._typed_state
                and (row.base is self._typed_row_base or row is self._no_row)
                and (record is self._frame_buf or (record.dtype is self._frame_dtype and record.ndim == 1))
            ) or self._typed_arrays(record, row):
                bits = self._typed_step(state, record, row)
            else:
                bits = _c.controller_step(state, record, row)
        else:
            bits = self._step_slow(frame, record, row)
        if bits == _c.STEP_NO_ESTIMATE:  # (unreachable after reset: the bypass state is checked there)
            raise InputError("the bypass estimator needs SensorFrame.state (ground truth); this plant gives none")
        if self._piecewise:
            self.scheduler.sync()
        return RotorCommand(frame.t, self._omega_cmd.copy(), _STATUS_BY_BITS[bits])

    def _typed_arrays(self, record: np.ndarray, row: np.ndarray) -> bool:
        """Whether the step's arrays have the numba types :attr:`_typed_step` was compiled for.

        That entry point does not type its arguments (:func:`omnirotor._jit.typed_entry`), so this check
        stands in for numba's, cheaply: the state is the one it was found for (on the first step from Python,
        not at :meth:`reset`: a compiled closed loop never needs it, and typing the record the first time in a
        process takes tens of milliseconds); the frame record is the
        controller's own buffer, or a frame's own copy (:meth:`SensorFrame.from_record`: a fresh, writeable,
        contiguous ``(1,)`` array) of the same dtype object; the log row is the empty one or a row of an array
        of the log (a row's ``base``) whose type was checked once (the log's memory changes only when it grows).
        """
        if self.state is not self._typed_state:
            self._typed_step = typed_entry(_c.controller_step, self.state, self._frame_buf, self._no_row)
            self._typed_state = self.state
            self._typed_row_base = None
        if not (record is self._frame_buf or (record.dtype is self._frame_dtype and record.ndim == 1)):
            return False
        if row is self._no_row:
            return True
        base = row.base
        if base is self._typed_row_base:
            return True
        f = row.flags  # what numba's type of a 1-D array depends on besides its dtype (as self._no_row's)
        if not (row.dtype == self.log_dtype and row.ndim == 1 and f.c_contiguous and f.writeable and f.aligned):
            return False
        self._typed_row_base = base
        return True

    def _record(self, frame: SensorFrame) -> np.ndarray:
        """The frame's record (:mod:`omnirotor.messages`): its own, or the frame written into the controller's.

        A frame whose own record has the controller's dtype needs no copy: its rotor speeds are a view of it, so
        there are as many as the vehicle has rotors.

        Raises:
            InputError: arrays of the wrong size (rotor speeds: not one per rotor, not even broadcast).
        """
        record = frame.record
        if record is not None and (record.dtype is self._frame_dtype or record.dtype == self._frame_dtype):
            return record
        if np.shape(frame.rotor_hz) != self._rotor_shape:
            raise InputError(f"frame.rotor_hz has shape {np.shape(frame.rotor_hz)}; the vehicle has {self._n} rotors")
        try:
            frame.write_record(self._frame_buf)
        except ValueError as exc:
            raise InputError(f"sensor frame of the wrong shape: {exc}") from None
        return self._frame_buf

    def _step_slow(self, frame: SensorFrame, record: np.ndarray, row: np.ndarray) -> int:
        """:meth:`step` through the same composer when an estimator or a QP solver runs from Python."""
        kind = self._own_estimator_kind
        if not self._estimator_compiled():
            kind = self._give_estimate(frame)
        elif kind == _c.EST_GIVEN:
            self._give_estimate(frame)
        if kind != int(self._own["estimator"]):
            self._own["estimator"] = kind
        if self.allocator.solves_compiled:
            return _c.controller_step(self.state, record, row)
        # A QP solver called from Python, between the composer's two halves.
        code = _c.step_begin(self.state, record, row)
        if code >= 0:
            solved = (code == BEGIN_SOLVE or code == BEGIN_SOLVE_NEW_MAP) and self.allocator.solve_qp(code)
            return _c.step_end(self.state, solved, row)
        if code == _c.BEGIN_DONE:
            return int(self._own["status"])
        return code

    def _give_estimate(self, frame: SensorFrame) -> int:
        """Run an estimator the compiled step does not run (a stand-in, one not initialised) from Python.

        Its estimate is given to the composer; returns ``EST_GIVEN``.
        """
        estimator = self.estimator
        state = estimator.step(frame)
        code = 0
        if estimator.degraded or not state.valid:
            code |= _ek.STEP_DEGRADED
        if estimator.last_input_rejected:  # a bad sensor sample, replaced by the estimator
            code |= _ek.STEP_REJECTED
        e = self._estimate
        e["p_W"], e["v_W"], e["a_W"], e["omega_B"] = state.p_W, state.v_W, state.a_W, state.omega_B
        e["R_WB"] = np.reshape(state.R_WB, (1, 3, 3))
        self._own["given_code"] = code
        return _c.EST_GIVEN
