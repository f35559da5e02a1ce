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

Cost. The blocks keep their states in slices of one array (:func:`omnirotor.control._kernels.controller_layout`).
With the default QP solver ("active-set", compiled) and an initialised estimator, :meth:`step` is **one**
compiled call, :func:`omnirotor.control._step_kernels.controller_step`, on the frame's packed form
(:mod:`omnirotor.messages`): a frame made by the simulator carries it, another one is packed first. That call
runs the same kernels as the blocks' own ``step`` methods, and a compiled closed loop calls it directly with
:attr:`InteractionController.kernel_args`. With the "daqp" or "proxsuite" solvers (called from Python), or
while the UKF waits for its first motion-capture sample, the step runs the blocks from Python around two
compiled calls (:func:`~omnirotor.control._kernels.controller_pre` and
:func:`~omnirotor.control._kernels.controller_post`); both paths give the same numbers.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from omnirotor.blocks import block_class, block_names
from omnirotor.config import apply_overrides, check_positive, from_mapping, load_toml
from omnirotor.control import _kernels as _k
from omnirotor.control import _step_kernels as _sk
from omnirotor.control.admittance import AdmittanceFilter, AdmittanceParams, body_reference_from_ee
from omnirotor.control.allocation import AllocationParams, AllocationStatus, Allocator
from omnirotor.control.estimator import EstimatorParams, make_estimator
from omnirotor.control.maps import MapParams, MapScheduler
from omnirotor.control.observer import ObserverParams
from omnirotor.control.pose import PoseController, PoseControlParams
from omnirotor.control.trajectory import PoseTrajectory, ReferenceSample
from omnirotor.errors import InputError
from omnirotor.messages import ControlStatus, RotorCommand, SensorFrame, frame_size
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

_XYZ = ("x", "y", "z")
_RMAT = ("xx", "xy", "xz", "yx", "yy", "yz", "zx", "zy", "zz")  # row-major entries of a rotation matrix


def _reference_groups(prefix: str) -> list[tuple[str, tuple[str, ...]]]:
    """The six groups of a logged ReferenceSample buffer (its layout: p, v, a, R, omega, alpha)."""
    return [
        (f"p_{prefix}_W", _XYZ),
        (f"v_{prefix}_W", _XYZ),
        (f"a_{prefix}_W", _XYZ),
        (f"R_{prefix}", _RMAT),
        (f"omega_{prefix}_W", _XYZ),
        (f"alpha_{prefix}_W", _XYZ),
    ]


def LOG_GROUPS(n_rotors: int) -> list[tuple[str, tuple[str, ...] | int]]:  # noqa: N802 (a table, by name)
    """Column groups of the controller log for a vehicle with ``n_rotors`` rotors.

    ``t`` [s] trajectory time; ``region`` map region index (-1 in nominal/global mode); ``status`` the
    :class:`ControlStatus` bits; ``p_W, v_W, a_W, R_WB, omega_B`` the state estimate (``R_WB`` row-major);
    ``p_E_W`` the estimated EE tip; ``*_E_ref*`` the compliant EE reference and ``*_E_des*`` the desired
    EE reference (pose, velocity, acceleration, world-frame angular velocity and acceleration);
    ``xi_p_W`` the admittance position offset; ``f_ext_W, m_ext_B`` the observer's interaction estimate;
    ``w_ref`` the pose controller's ``[f_ref_W; m_ref_B]``; ``pose_err`` ``[e_p, e_v, e_R, e_omega]`` of the
    body; ``u_hz2`` the allocated inputs; ``omega_cmd_hz`` the command.
    """
    rotors = tuple(str(i + 1) for i in range(n_rotors))
    return [
        ("t", 1),
        ("region", 1),
        ("status", 1),
        ("p_W", _XYZ),
        ("v_W", _XYZ),
        ("a_W", _XYZ),
        ("R_WB", _RMAT),
        ("omega_B", _XYZ),
        ("p_E_W", _XYZ),
        *_reference_groups("E_ref"),
        *_reference_groups("E_des"),
        ("xi_p_W", _XYZ),
        ("f_ext_W", _XYZ),
        ("m_ext_B", _XYZ),
        ("w_ref", ("fx", "fy", "fz", "mx", "my", "mz")),
        ("pose_err", tuple(f"{g}.{a}" for g in ("e_p", "e_v", "e_R", "e_omega") for a in _XYZ)),
        ("u_hz2", rotors),
        ("omega_cmd_hz", rotors),
    ]


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
        dt: control period [s] (1 kHz, SPEC §4).
        log_capacity: rows preallocated for the log [steps].
        observer_input: "measured" rotor speeds (default) or the "commanded" ones feed the observer.
        observer_kind: the registered name of the observer block (:mod:`omnirotor.blocks`; default
            "momentum", :class:`~omnirotor.control.observer.WrenchObserver`); it is built from ``observer``.
    """

    pose: PoseControlParams = dataclasses.field(default_factory=PoseControlParams)
    allocation: AllocationParams = dataclasses.field(default_factory=AllocationParams)
    maps: MapParams = dataclasses.field(default_factory=MapParams)
    observer: ObserverParams = dataclasses.field(default_factory=ObserverParams)
    admittance: AdmittanceParams = dataclasses.field(default_factory=AdmittanceParams)
    estimator: EstimatorParams = dataclasses.field(default_factory=EstimatorParams)
    dt: float = 1e-3
    log_capacity: int = 120_000
    observer_input: str = "measured"
    observer_kind: str = "momentum"

    def __post_init__(self) -> None:
        check_positive("controller dt", self.dt)
        if isinstance(self.log_capacity, bool) or not isinstance(self.log_capacity, int) or self.log_capacity < 0:
            raise InputError(f"controller log_capacity must be an integer >= 0, got {self.log_capacity!r}")
        if self.observer_input not in OBSERVER_INPUTS:
            raise InputError(f"observer_input must be one of {OBSERVER_INPUTS}, got {self.observer_input!r}")
        if self.observer_kind not in block_names("observer"):
            block_class("observer", self.observer_kind)  # raises, listing the registered observers


def load_controller_params(
    path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()
) -> ControllerParams:
    """Controller parameters from a TOML file and/or dotted ``key=value`` overrides.

    The file has top-level ``dt``, ``log_capacity``, ``observer_input``, ``observer_kind`` and sections ``[pose]``,
    ``[allocation]``, ``[maps]``, ``[observer]``, ``[admittance]``, ``[estimator]`` whose keys are the
    fields of the blocks' parameter classes; unknown keys are errors. Overrides look like
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
_STATUS_BY_BITS = tuple(ControlStatus(i) for i in range(32))
_QP_FALLBACK = int(ControlStatus.QP_FALLBACK)
_NONFINITE = int(ControlStatus.NONFINITE_INPUT)
_SATURATED = int(ControlStatus.SATURATED)
_DEGRADED = int(ControlStatus.ESTIMATE_DEGRADED)
_EXCLUDED = int(ControlStatus.ROTOR_EXCLUDED)


class InteractionController:
    """The composed interaction controller (module docstring).

    Args:
        vehicle: the vehicle model.
        params: controller parameters.
        maps: identified wrench maps; required by ``maps.mode`` "global" and "piecewise".

    Attributes:
        estimator, scheduler, observer, admittance, pose, allocator: the blocks.
        log: the step log (:data:`LOG_GROUPS`); cleared by :meth:`reset`.
        desired_ee, compliant_ee, body_ref: the references of the last step.
    """

    def __init__(
        self, vehicle: VehicleParams, params: ControllerParams | None = None, maps: WrenchMapSet | None = None
    ) -> None:
        self.vehicle = vehicle
        self.params = params if params is not None else ControllerParams()
        p = self.params
        n = vehicle.n_rotors
        # Every block's packed state is a slice of one array (layout: _kernels.controller_layout), so that the
        # compiled step takes one array for all of them.
        o_obs, o_adm, o_pose, o_des, o_comp, o_body, o_alloc, size = _k.controller_layout(n)
        self._arena = arena = np.zeros(size)
        # The controller's structured state: the converted blocks' states as fields, and the addresses of
        # the other arrays of the compiled step (_step_kernels.controller_step_by_state).
        observer_cls = block_class("observer", p.observer_kind)
        self.state = np.zeros(
            1, dtype=[("observer", observer_cls.state_dtype), ("arrays", np.int64, (3 * _sk.N_ARRAYS,))]
        )
        self.estimator = make_estimator(vehicle, p.estimator)
        self.scheduler = MapScheduler(vehicle, maps, p.maps)
        self.observer = observer_cls(vehicle, p.observer, state=self.state["observer"])
        self.admittance = AdmittanceFilter(p.admittance, buffer=arena[o_adm:o_pose])
        self.pose = PoseController(vehicle, p.pose, buffer=arena[o_pose:o_des])
        self.allocator = Allocator(vehicle, p.allocation, buffer=arena[o_alloc:size])
        self._dt = p.dt
        self._measured_input = p.observer_input == "measured"
        self._p_E_B = vehicle.p_E_B_array
        self._omega_lo = float(vehicle.omega_min_hz)
        self._omega_hi = float(vehicle.omega_max_hz)
        self._n = n
        self._piecewise = self.params.maps.mode == "piecewise"  # the map depends on the attitude
        # References.
        self.desired_ee = ReferenceSample(arena[o_des:o_comp])
        self.compliant_ee = ReferenceSample(arena[o_comp:o_body])
        self.body_ref = ReferenceSample(arena[o_body:o_alloc])
        # The controller's own values (layout CTL_* of control._kernels): the logged head (t, region, status,
        # estimate, EE tip), the EE wrench, p_E_B, the speed limits, the inputs and commands.
        self._ws = ws = arena[0:o_obs]
        self._head = ws[_k.CTL_HEAD : _k.CTL_HEAD + _k.CTL_HEAD_SIZE]
        self._f_E_W = ws[_k.CTL_F_E : _k.CTL_F_E + 3]
        self._m_E_W = ws[_k.CTL_M_E : _k.CTL_M_E + 3]
        ws[_k.CTL_P_E_B : _k.CTL_P_E_B + 3] = vehicle.p_E_B
        ws[_k.CTL_OMEGA_LO] = self._omega_lo
        ws[_k.CTL_OMEGA_HI] = self._omega_hi
        o = _k.CTL_U_OBS
        self._u_obs = ws[o : o + n]  # u fed to the observer [Hz²]
        self._u_cmd = ws[o + n : o + 2 * n]  # last allocated u [Hz²]
        self._omega_cmd = ws[o + 2 * n : o + 3 * n]  # last command [Hz]
        self._omega_safe = ws[o + 3 * n : o + 4 * n]  # last finite command [Hz]
        self._excluded = False
        # The log row is the head followed by the blocks' own buffers; the compiled step writes it directly
        # (_kernels.write_log_row), the rare held step through these bound sources.
        self.log = Recorder(p.log_capacity, LOG_GROUPS(n))
        self.log.bind(
            self._head,
            self.compliant_ee.data,
            self.desired_ee.data,
            self.admittance.xi_p_W,
            self.observer.output,
            self.pose.w_ref,
            self.pose.errors,
            self._u_cmd,
            self._omega_cmd,
        )
        self._no_row = np.zeros(0)
        self._no_x = np.zeros(n)
        self._trajectory: PoseTrajectory | None = None
        self._t0 = 0.0
        # The compiled step (_step_kernels.controller_step): its parameters, the packed frame, the estimate.
        self._ints = np.zeros(_sk.CI_SIZE, dtype=np.int64)
        self._floats = np.zeros(_sk.CF_SIZE)
        self._frame_buf = np.zeros(frame_size(n))
        self._est_out = np.zeros(21)
        self._kernel_args: tuple | None = None
        self._kernel_estimator = None  # the estimator whose arrays the kernel arguments hold

    # -- set-up -------------------------------------------------------------------------------------------

    @property
    def trajectory(self) -> PoseTrajectory | None:
        """The desired EE trajectory given to :meth:`reset`."""
        return self._trajectory

    def set_failed_rotors(self, mask: np.ndarray | None) -> None:
        """Exclude rotors from the allocation (see :meth:`Allocator.set_failed_rotors`)."""
        self.allocator.set_failed_rotors(mask)
        self._excluded = bool(np.any(self.allocator.failed_rotors))
        self._ints[_sk.CI_EXCLUDED] = 1 if self._excluded else 0

    @property
    def kernel_args(self) -> tuple | None:
        """The argument tuple of :func:`omnirotor.control._step_kernels.controller_step` (its module docstring).

        None before :meth:`reset`, with a QP solver called from Python ("daqp", "proxsuite"), while the UKF
        is not initialised, or when the estimator was replaced after :meth:`reset`: the step then runs from
        Python. Valid until the next :meth:`reset`.
        """
        if self._kernel_args is None or self.estimator is not self._kernel_estimator:
            return None
        return self._kernel_args if self.estimator.initialised else None

    @property
    def kernel_command(self) -> np.ndarray:
        """(n,) the array the compiled step writes its command into [Hz] (a compiled loop's plant input).

        Read it, never write it: it is the controller's own state (the last command).
        """
        return self._omega_cmd

    def sync(self) -> None:
        """Bring the Python-side attributes up to date after compiled steps made elsewhere (a compiled loop).

        Every block keeps its state in arrays the compiled step updates; only the map scheduler's region name
        and index are Python attributes.
        """
        self.scheduler.sync()

    def _build_kernel_args(self) -> None:
        alloc, est, sched = self.allocator, self.estimator, self.scheduler
        backend = alloc.kernel_backend
        self._kernel_args = None
        self._kernel_estimator = None
        if backend is None or not hasattr(est, "kernel_counters"):  # a Python solver, or a stand-in estimator
            return
        ints, floats = self._ints, self._floats
        kind = self.params.estimator.kind
        ints[_sk.CI_EST_KIND] = _sk.EST_BYPASS if kind == "bypass" else _sk.EST_UKF
        ints[_sk.CI_MEASURED] = 1 if self._measured_input else 0
        ints[_sk.CI_PIECEWISE] = 1 if self._piecewise else 0
        ints[_sk.CI_EXCLUDED] = 1 if self._excluded else 0
        ints[_sk.CI_MAX_ITER] = backend.max_iter
        floats[_sk.CF_T0] = self._t0
        floats[_sk.CF_DT] = self._dt
        floats[_sk.CF_LAM] = alloc.kernel_lam_scaled
        if kind == "bypass":
            est_arrays = (np.zeros(1), np.zeros(1, dtype=np.int64), est.kernel_last, est.kernel_counters)
        else:
            ints[_sk.CI_COMPENSATE] = 1 if est.kernel_compensate_latency else 0
            est_arrays = (est.kernel_mem, est.kernel_counters, np.zeros(1), np.zeros(1, dtype=np.int64))
        sched_arrays = (
            sched.kernel_schedule,
            sched.kernel_maps,
            sched.kernel_out,
            sched.kernel_weights,
            sched.kernel_state,
        )
        alloc_arrays = (
            backend.H, backend.lo, backend.hi, backend.x, backend.active, backend.work, alloc.kernel_As,
            alloc.kernel_failed, alloc.kernel_counters,
        )  # fmt: skip
        self._kernel_args = (
            self.state, self._arena, ints, floats, est_arrays, sched_arrays, alloc_arrays, self._trajectory.kernel_data,
            self._est_out,
        )  # fmt: skip
        # The same arrays by address, for step(): the arrays stay alive and in place in _kernel_args.
        _sk.store_addresses(self._kernel_args)
        self._kernel_estimator = est

    def reset(self, frame: SensorFrame, trajectory: PoseTrajectory) -> None:
        """Start a run: reset every block on the first frame and fly ``trajectory`` from ``frame.t``.

        The held "last safe" command starts as the frame's measured rotor speeds (clipped), or the upright
        hover speeds if those are not finite. The log is cleared.

        Raises:
            InputError: not a :class:`PoseTrajectory`, or a frame whose rotor count is not the vehicle's.
        """
        if not isinstance(trajectory, PoseTrajectory):
            raise InputError(f"expected a PoseTrajectory, got {type(trajectory).__name__}")
        hz = np.asarray(frame.rotor_hz, dtype=float)
        if hz.shape != (self._n,):
            raise InputError(f"frame.rotor_hz has shape {hz.shape}; the vehicle has {self._n} rotors")
        self._trajectory = trajectory
        self._t0 = float(frame.t)
        self.estimator.reset(frame)
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
        self._build_kernel_args()

    def hold_command(self, t: float | None = None) -> RotorCommand:
        """The last safe command (after :meth:`reset`: the initial frame's speeds), e.g. for the first period.

        :meth:`reset` consumes its frame; the command that flies the period until the next frame is this
        one, and :meth:`step` then takes the frames that follow.

        Args:
            t: time stamp [s] of the command; default the reset frame's time.
        """
        return RotorCommand(t=self._t0 if t is None else t, omega_hz=self._omega_safe.copy())

    # -- the 1 kHz step -----------------------------------------------------------------------------------

    def step(self, frame: SensorFrame) -> RotorCommand:
        """One control period: sensor frame in, rotor command out (module docstring).

        Returns:
            A command with fresh arrays; its speeds are finite and within the vehicle's limits.
        """
        trajectory = self._trajectory
        if trajectory is None:
            raise InputError("InteractionController.step before reset(frame, trajectory)")
        args = self._kernel_args
        estimator = self.estimator
        if args is not None and estimator is self._kernel_estimator and estimator.initialised:
            packed = frame.packed
            if packed is None or packed.shape != self._frame_buf.shape:
                packed = self._frame_buf
                try:
                    frame.pack_into(packed)
                except ValueError as exc:
                    raise InputError(f"sensor frame of the wrong shape: {exc}") from None
            row = self.log.next_row()
            bits = _sk.controller_step_by_state(self.state, packed, self._no_row if row is None else row)
            if bits == _sk.STEP_NO_ESTIMATE:  # (unreachable after reset: the bypass state is checked there)
                raise InputError("the bypass estimator needs SensorFrame.state (ground truth); this plant gives none")
            if self._piecewise:
                self.scheduler.sync()
            return RotorCommand(frame.t, self._omega_cmd.copy(), _STATUS_BY_BITS[bits])
        return self._step_python(frame, trajectory)

    def _step_python(self, frame: SensorFrame, trajectory: PoseTrajectory) -> RotorCommand:
        """:meth:`step` with the blocks called from Python (QP solvers with a Python interface, UKF start-up)."""
        t = frame.t - self._t0
        bits = 0
        estimator = self.estimator
        state = estimator.step(frame)
        if estimator.degraded or not state.valid:
            bits |= _DEGRADED
        if estimator.last_input_rejected:  # a bad sensor sample, replaced by the estimator
            bits |= _NONFINITE
        if self._excluded:
            bits |= _EXCLUDED
        ws = self._ws
        p_W, v_W, a_W, R, omega_B = state.p_W, state.v_W, state.a_W, state.R_WB, state.omega_B
        measured = self._measured_input
        scheduler = self.scheduler
        packed = False
        if self._piecewise:  # the region follows the attitude only while the estimate is finite
            packed = _k.pack_inputs(ws, p_W, v_W, a_W, R, omega_B, frame.rotor_hz, measured)
            A = scheduler.select(R) if packed else None
        else:
            A = scheduler.select(R)
        if A is None:
            code = _k.PRE_STATE_NONFINITE
        else:
            code = _k.controller_pre(
                self.state[0], self._arena, p_W, v_W, a_W, R, omega_B, frame.rotor_hz, measured, packed, A,
                trajectory.kernel_data, t, self._dt,
            )  # fmt: skip
        if code == _k.PRE_STATE_NONFINITE:  # no stateful block was updated: hold the last safe command
            bits |= _NONFINITE
            self._omega_cmd[:] = self._omega_safe
            self._head[0:3] = (t, scheduler.region_index, bits)
            self.log.record_bound()
            return RotorCommand(frame.t, self._omega_cmd.copy(), _STATUS_BY_BITS[bits])
        alloc = self.allocator
        mode = _k.FINISH_QP
        x = self._no_x
        if code != _k.PRE_OK and not alloc._resolve(code, self.pose.w_ref, R, A):
            alloc._hold()
            bits |= _NONFINITE
            mode = _k.FINISH_HELD
        else:
            x = alloc._backend.solve(alloc._f)
            if x is None:
                x = alloc._fallback()
                bits |= _QP_FALLBACK
                mode = _k.FINISH_FALLBACK
        row = self.log.next_row()
        if row is None:
            row = self._no_row
        region = float(scheduler.region_index)
        arena = self._arena
        st = self.state[0]
        out, sat = _k.controller_post(st, arena, x, mode, alloc.saturated, bits, region, t, row)
        if out < 0:  # the QP's answer was not finite: nothing was written
            bits |= _QP_FALLBACK
            mode = _k.FINISH_FALLBACK
            x = alloc._fallback()
            out, sat = _k.controller_post(st, arena, x, mode, alloc.saturated, bits, region, t, row)
        bits = out
        if mode != _k.FINISH_HELD:
            alloc.saturated = bool(sat)
            if mode == _k.FINISH_QP:
                alloc.status = AllocationStatus.OK
        return RotorCommand(frame.t, self._omega_cmd.copy(), _STATUS_BY_BITS[bits])
