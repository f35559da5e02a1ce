"""The controller's compiled 1 kHz step: the blocks of :mod:`omnirotor.control.controller` wired by name.

One period, the sensor frame record (:mod:`omnirotor.messages`) in, the rotor command out (the blocks and
their SPEC sections are in the controller's module docstring)::

    frame ──> supervisor ──> checked frame ──> estimator ──> (p_W, v_W, a_W, R_WB, omega_B) ──┬──> map scheduler ──> A
                                                            │
    u_obs_hz2 (measured) or u_cmd_hz2 (last command), A ──> observer ──> f_ext_W, m_ext_B; f_filt_W, m_filt_B
    f_ext_W, m_ext_B ──> EE wrench (f_E_W, m_E_W) ──> admittance ──> xi
    trajectory(t) or set-point segment(t) ──> desired_ee ──(xi)──> compliant_ee ──(p_E_B)──> body_ref
    body_ref, estimate, f_filt_W, m_filt_B ──> pose ──> f_ref_W, m_ref_B ──> allocation (A, R_WB) ──> u_hz2 ──> omega_hz

The supervisor (:mod:`omnirotor.control.supervisor`) checks the frame first: the estimator reads its checked
copy (rejected parts replaced by the prediction), the observer the last command in place of rejected rotor
speeds, and after a clock reset or a long dropout the UKF re-initialises from motion capture.

Every block's state is a field of the controller's structured state (:func:`controller_dtype`): the
composer reads and writes the signals by name (``st.observer.f_ext_W``, ``st.pose.f_ref_W``, ``rot.u_cmd_hz2``)
and calls each block's own kernel (the observer through :func:`omnirotor.blocks.compiled_step`, so that any
registered observer fits). The step is split around the allocation QP: :func:`step_begin` (estimate to
:func:`~omnirotor.control.allocation.alloc_begin`) and :func:`step_end` (the QP's answer to the command and
the log row); :func:`controller_step` runs both around the compiled QP, and a controller with a QP solver
called from Python (daqp, ProxSuite) runs the same two around that solver.

``kernel_args`` (:attr:`InteractionController.kernel_args`): ``(state, rot, ar, est, sch, traj)``, the state,
then the NamedTuples of the arrays of the controller (:class:`RotorArrays`), the allocator
(:class:`~omnirotor.control.allocation.AllocArrays`), the UKF (:class:`EstimatorArrays`) and the map scheduler
(:class:`SchedulerArrays`), and the packed trajectory. The state's ``arrays`` field holds their addresses, so
that :func:`controller_step_by_state` needs the state alone.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from omnirotor._jit import (
    address_table,
    f64_view,
    f64_view2,
    i64_view,
    jit,
    jit_entry,
    jit_inline,
    records_at,
    void_pointer,
)
from omnirotor.blocks import compiled_step
from omnirotor.control import _estimator_kernels as _ek
from omnirotor.control import _map_kernels as _mk
from omnirotor.control import admittance as _adm
from omnirotor.control import allocation as _al
from omnirotor.control import estimator as _est
from omnirotor.control import observer as _obs
from omnirotor.control import pose as _pose
from omnirotor.control import supervisor as _sup
from omnirotor.control import trajectory as _traj
from omnirotor.frame_kernels import state_finite
from omnirotor.messages import ESTIMATE_DTYPE

__all__ = [
    "CONTROLLER_DTYPE_FIELDS",
    "RotorArrays",
    "EstimatorArrays",
    "SchedulerArrays",
    "controller_dtype",
    "store_addresses",
    "step_begin",
    "step_end",
    "controller_step",
    "controller_step_by_state",
    "controller_step_by_table",
    "DEFAULT_DTYPE",
    "step_begin_by_state",
    "step_end_by_state",
]

observer_step = compiled_step("observer")

_F8, _I8 = np.float64, np.int64
OWN_DTYPE = np.dtype(
    [
        # the logged head (LOG_GROUPS order)
        ("t", _F8),  # trajectory time [s]
        ("region", _F8),  # map region index (-1: none)
        ("status", _F8),  # ControlStatus bits
        ("estimate", ESTIMATE_DTYPE),  # the state estimate of this period (the last one before the step)
        ("p_E_W", _F8, 3),  # estimated EE tip [m]
        # signals
        ("f_E_W", _F8, 3),  # force at the EE [N]
        ("m_E_W", _F8, 3),  # moment about the EE [N·m], world frame
        # parameters
        ("p_E_B", _F8, 3),  # EE tip in the body frame [m]
        ("omega_min_hz", _F8),
        ("omega_max_hz", _F8),
        ("t0", _F8),  # time of the reset frame [s]
        ("dt", _F8),  # control period [s]
        ("estimator", _I8),  # EST_UKF, EST_BYPASS or EST_GIVEN
        ("measured", _I8),  # 1: the observer takes the measured rotor speeds, 0: the last command
        ("piecewise", _I8),  # 1: the map follows the attitude
        ("excluded", _I8),  # 1: some rotor is excluded from the allocation
        ("given_code", _I8),  # EST_GIVEN: the estimator's STEP_* code of this period
        ("alloc_code", _I8),  # this period's result of alloc_begin
    ]
)
"""The controller's own part of its state."""

EST_UKF, EST_BYPASS, EST_GIVEN = 0, 1, 2
"""Where the estimate comes from: the UKF's or the bypass's kernel, or given (written by Python)."""

STEP_NO_ESTIMATE = -1
"""The estimator cannot give a state (bypass without any): nothing was updated."""
BEGIN_DONE = -2
""":func:`step_begin`: the estimate (or a measured rotor speed) was not finite: the last safe command is held."""

_BIT_QP_FALLBACK = 1
_BIT_NONFINITE = 2
_BIT_SATURATED = 4
_BIT_DEGRADED = 8
_BIT_EXCLUDED = 16
_BIT_REJECTED = 32
_BIT_NOISE_RAISED = 64
_BIT_MOCAP_REJECTED = 128
_BIT_FAILSAFE = 256
_BIT_BIAS_RANGE = 512


class RotorArrays(NamedTuple):
    """The controller's own per-rotor arrays."""

    u_obs_hz2: np.ndarray  # (n,) the measured inputs |omega| omega [Hz²]
    u_cmd_hz2: np.ndarray  # (n,) the last allocated inputs [Hz²]
    omega_cmd_hz: np.ndarray  # (n,) the command [Hz]
    omega_safe_hz: np.ndarray  # (n,) the last finite command [Hz]


class EstimatorArrays(NamedTuple):
    """The UKF's ring buffers and scratch (:class:`~omnirotor.control._estimator_kernels.UKFArrays`).

    Its record is the state's field ``ukf``; placeholders of one entry with another estimator.
    """

    imu_buf: np.ndarray  # (cap,) IMU_SAMPLE_DTYPE
    state_buf: np.ndarray  # (cap,) NOMINAL_DTYPE
    work: np.ndarray  # (1,) WORK_DTYPE

    @classmethod
    def placeholder(cls) -> EstimatorArrays:
        """Arrays of one entry, for a controller whose compiled step does not run the UKF."""
        return cls(*_ek.new_arrays(1)[1:])


SchedulerArrays = _mk.SchedulerArrays
"""The map scheduler's partition and maps (its record is the state's field ``maps``)."""

N_ARRAYS = sum(len(t._fields) for t in (RotorArrays, _al.AllocArrays, EstimatorArrays, SchedulerArrays)) + 1
"""Arrays reached through the state's ``arrays`` field."""

CONTROLLER_DTYPE_FIELDS = ("own", "observer", "admittance", "pose", "desired_ee", "compliant_ee", "body_ref")


def controller_dtype(observer_dtype: np.dtype) -> np.dtype:
    """The controller's structured state: its own part, its blocks' states, the addresses of its arrays."""
    ref = _traj.REFERENCE_DTYPE
    return np.dtype(
        [
            ("own", OWN_DTYPE),
            ("observer", observer_dtype),
            ("admittance", _adm.STATE_DTYPE),
            ("pose", _pose.STATE_DTYPE),
            ("desired_ee", ref),
            ("compliant_ee", ref),
            ("body_ref", ref),
            ("segment", _traj.SEGMENT_DTYPE),  # an in-flight set-point replacing the trajectory (when active)
            ("allocation", _al.STATE_DTYPE),
            ("bypass", _est.BYPASS_DTYPE),  # the estimators, by their registered names
            ("ukf", _ek.UKF_DTYPE),
            ("supervisor", _sup.STATE_DTYPE),
            ("maps", _mk.STATE_DTYPE),
            ("arrays", _I8, (3 * N_ARRAYS,)),
        ]
    )


def _arrays(args: tuple) -> list[np.ndarray]:
    state, rot, ar, est, sch, traj = args
    return [*rot, *ar, *est, *sch, traj]


def store_addresses(args: tuple) -> None:
    """Write the addresses of the arrays of ``args`` into its state's ``arrays`` field.

    The arrays must stay alive and in place while the state is used: the controller keeps them in ``args``.
    """
    args[0]["arrays"][0] = address_table(_arrays(args))


@jit_inline
def _args_of(state):
    """``kernel_args`` rebuilt from the state's ``arrays`` (the order of :func:`_arrays`)."""
    t = state[0].arrays
    rot = RotorArrays(f64_view(t, 0), f64_view(t, 1), f64_view(t, 2), f64_view(t, 3))
    ar = _al.AllocArrays(
        f64_view(t, 4), f64_view2(t, 5), f64_view2(t, 6), f64_view(t, 7), f64_view(t, 8), f64_view(t, 9),
        f64_view(t, 10), f64_view(t, 11), f64_view(t, 12), f64_view(t, 13), f64_view2(t, 14), f64_view2(t, 15),
        f64_view(t, 16), i64_view(t, 17), f64_view(t, 18),
    )  # fmt: skip
    est = EstimatorArrays(
        records_at(t, 19, _ek.IMU_SAMPLE_DTYPE), records_at(t, 20, _ek.NOMINAL_DTYPE), records_at(t, 21, _ek.WORK_DTYPE)
    )
    return state, rot, ar, est, _mk.arrays_at(t, 22), f64_view(t, 30)


@jit
def _all_finite(x) -> bool:
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            return False
    return True


@jit_inline
def _put(row, k: int, v) -> int:
    """Copy the 1-D array ``v`` into ``row[k:]``; the next free index."""
    for i in range(v.shape[0]):
        row[k + i] = v[i]
    return k + v.shape[0]


@jit_inline
def _put_pose(row, k: int, p, v, a, R, w, b) -> int:
    """Copy three 3-vectors, a 3 x 3 matrix (row-major) and two 3-vectors into ``row[k:]``; the next index."""
    k = _put(row, _put(row, _put(row, k, p), v), a)
    for i in range(3):
        k = _put(row, k, R[i])
    return _put(row, _put(row, k, w), b)


@jit
def write_log_row(row, st, rot) -> None:
    """One log row (:data:`omnirotor.control.controller.LOG_GROUPS`) from the named signals."""
    c = st.own
    row[0], row[1], row[2] = c.t, c.region, c.status
    e = c.estimate
    k = _put_pose(row, 3, e.p_W, e.v_W, e.a_W, e.R_WB, e.omega_B, c.p_E_W)
    for ref in (st.compliant_ee, st.desired_ee):
        k = _put_pose(row, k, ref.p_W, ref.v_W, ref.a_W, ref.R_WB, ref.omega_W, ref.alpha_W)
    k = _put(row, k, st.admittance.xi_p_W)
    k = _put(row, _put(row, k, st.observer.f_ext_W), st.observer.m_ext_B)
    k = _put(row, _put(row, k, st.pose.f_ref_W), st.pose.m_ref_B)
    k = _put(row, k, st.pose.errors)
    k = _put(row, _put(row, k, rot.u_cmd_hz2), rot.omega_cmd_hz)
    row[k] = st.supervisor.cause


@jit
def _finish_held(st, rot, bits: int, row) -> None:
    """Hold the last safe command (nothing else updated), flagged; write the head and the log row."""
    c = st.own
    for i in range(rot.omega_cmd_hz.shape[0]):
        rot.omega_cmd_hz[i] = rot.omega_safe_hz[i]
    c.status = bits
    if row.shape[0] > 0:
        write_log_row(row, st, rot)


@jit_inline
def step_begin(args, frame, row) -> int:
    """Everything of a period before the allocation QP (module docstring), the frame's supervision first.

    Returns:
        ``STEP_NO_ESTIMATE`` (nothing updated), ``BEGIN_DONE`` (a non-finite estimate or measured rotor
        speed, or a rejected bypass state: the last safe command is held, flagged, and logged; no stateful
        block was updated), or the
        code of :func:`~omnirotor.control.allocation.alloc_begin` (its linear term is then ready, or the
        allocator holds its last input).
    """
    state, rot, ar, est, sch, traj = args
    st = state[0]
    c = st.own
    fr = frame[0]
    rotor_hz = fr.rotor_hz
    n = rotor_hz.shape[0]
    e = c.estimate
    # 0. the frame's supervision: the estimator reads the checked frame f (e still holds the last estimate)
    sv = st.supervisor
    act = _sup.supervise(sv, fr, e)
    cause = sv.cause
    f = sv.clean
    # 1. the state estimate
    kind = c.estimator
    if kind == EST_UKF:
        m = f.mocap
        st.ukf.coasting = sv.coasting
        code, _ = _ek.ukf_step(
            st.ukf, est.imu_buf, est.state_buf, est.work[0], f.imu.gyro_B, f.imu.acc_B, f.t, m.new != 0.0, m.t,
            m.p_W, m.q_WB, e,
        )  # fmt: skip
        if act & _sup.ACT_REINIT:
            _ek.ukf_reinit(st.ukf, m.p_W, m.q_WB, e, sv.reinit_v_W)
            code &= ~_ek.STEP_DEGRADED
    elif kind == EST_BYPASS:
        code = _est.bypass_step(f.state, st.bypass, e)
        if code == _est.BYPASS_NO_STATE:
            return STEP_NO_ESTIMATE
    else:
        code = c.given_code
    bits = 0
    if cause & _sup.REJECTING:
        bits |= _BIT_REJECTED
    if cause & _sup.INVALID_VALUE:
        bits |= _BIT_NONFINITE
    if cause & (_sup.CAUSE_STATE | _sup.CAUSE_STATE_JUMP | _sup.CAUSE_HOLD_TIMEOUT):
        bits |= _BIT_DEGRADED  # the bypass runs on the prediction
    if code & _ek.STEP_DEGRADED:
        bits |= _BIT_DEGRADED
    if code & _ek.STEP_REJECTED:
        bits |= _BIT_NONFINITE
    if code & _ek.STEP_NOISE_RAISED:
        bits |= _BIT_NOISE_RAISED
    if code & _ek.STEP_MOCAP_REJECTED:
        bits |= _BIT_MOCAP_REJECTED
    if kind == EST_UKF and code & _ek.STEP_BIAS_RANGE:
        bits |= _BIT_BIAS_RANGE
    if c.excluded != 0:
        bits |= _BIT_EXCLUDED
    if cause & _sup.CAUSE_FAILSAFE:
        bits |= _BIT_FAILSAFE
        if sv.fs_mode == _sup.FS_LANDED:  # touchdown: the rotors stop (supervisor docstring)
            for i in range(n):
                rot.omega_safe_hz[i] = 0.0
            _finish_held(st, rot, bits, row)
            return BEGIN_DONE
    e.valid = 0.0 if bits & _BIT_DEGRADED else 1.0
    t = f.t - c.t0
    dt = sv.dt_s  # the frame's real interval (the period for evenly spaced frames: supervisor docstring)
    c.t = t
    p, v, a, w, R = e.p_W, e.v_W, e.a_W, e.omega_B, e.R_WB
    finite = state_finite(e)
    measured = c.measured != 0 and (cause & _sup.CAUSE_ROTOR) == 0  # rejected speeds: the last command
    if measured:
        for i in range(n):
            rot.u_obs_hz2[i] = abs(rotor_hz[i]) * rotor_hz[i]
        finite = finite and _all_finite(rot.u_obs_hz2)
    # 2. the wrench map of this attitude (it follows the attitude only while the estimate is finite)
    A = sch.out.reshape(6, n)
    c.region = -1.0
    if c.piecewise != 0:
        if finite:
            _mk.schedule_select(st.maps, sch, R)
        c.region = st.maps.region
    if cause & (_sup.CAUSE_STATE | _sup.CAUSE_STATE_JUMP) or sv.blind != 0:  # no state to act on: hold
        finite = False
    if not finite:  # no stateful block is updated: hold the last safe command
        _finish_held(st, rot, bits | _BIT_NONFINITE, row)
        return BEGIN_DONE
    # 3. the observer, on the measured rotor inputs or the last command
    u = rot.u_obs_hz2 if measured else rot.u_cmd_hz2
    obs = st.observer
    observer_step(obs, A, u, a, R, w, dt)
    # 4. the EE wrench, the admittance filter, the desired, compliant and body references
    _adm.ee_wrench(obs.f_ext_W, obs.m_ext_B, R, c.p_E_B, c.f_E_W, c.m_E_W)
    _adm.admittance_step(st.admittance, c.f_E_W, c.m_E_W, dt)
    if st.segment.active != 0:
        _traj.segment_sample(st.segment, t, st.desired_ee)
    else:
        _traj.trajectory_sample(traj, t, st.desired_ee)
    if sv.fs_mode != _sup.FS_OFF:  # the failsafe's hold-then-land replaces the reference
        _sup.failsafe_reference(sv, e, c.p_E_B, dt, st.desired_ee)
    _adm.compliant_reference(st.admittance, st.desired_ee, st.compliant_ee)
    _adm.body_reference(st.compliant_ee, c.p_E_B, st.body_ref)
    # 5. the pose controller compensates the whole unexplained wrench (before bias and zeroing)
    _pose.pose_step(st.pose, st.body_ref, p, v, R, w, obs.f_filt_W, obs.m_filt_B, dt)
    # 6. the allocation up to its QP
    alloc = _al.alloc_begin(st.allocation, ar, st.pose.f_ref_W, st.pose.m_ref_B, R, A)
    if alloc == _al.BEGIN_HELD:
        bits |= _BIT_NONFINITE
    c.status = bits
    c.alloc_code = alloc
    return alloc


@jit_inline
def step_end(args, solved: bool, row) -> int:
    """Everything of a period after the allocation QP (module docstring).

    The QP's answer (``ar.x``; ``solved`` says whether the solver succeeded) to the inputs (the pseudo-inverse
    fallback if needed), the command ``omega = sign(u) sqrt|u|`` clipped to the limits (the last safe command
    is held, flagged, should it not be finite), the EE tip, the head and the log row.

    Returns:
        The ``ControlStatus`` bits.
    """
    state, rot, ar, est, sch, traj = args
    st = state[0]
    c = st.own
    al = st.allocation
    bits = int(c.status)
    if c.alloc_code != _al.BEGIN_HELD:
        _al.alloc_end(al, ar, solved)
        if al.status == _al._FALLBACK:
            bits |= _BIT_QP_FALLBACK
    if al.saturated != 0.0:
        bits |= _BIT_SATURATED
    n = rot.u_cmd_hz2.shape[0]
    u_al = ar.u_hz2
    lo, hi = c.omega_min_hz, c.omega_max_hz
    finite = True
    for i in range(n):  # a first pass checks the clipped speeds, the second writes them (no array per call)
        u = u_al[i]
        om = math.copysign(math.sqrt(abs(u)), u)
        om = lo if om < lo else (hi if om > hi else om)
        if not math.isfinite(om):
            finite = False
    if finite:
        for i in range(n):
            u = u_al[i]
            om = math.copysign(math.sqrt(abs(u)), u)
            om = lo if om < lo else (hi if om > hi else om)
            rot.u_cmd_hz2[i] = u
            rot.omega_cmd_hz[i] = om
            rot.omega_safe_hz[i] = om
    else:
        bits |= _BIT_NONFINITE
        for i in range(n):
            rot.omega_cmd_hz[i] = rot.omega_safe_hz[i]
    # Estimated EE tip, for the log.
    ex, ey, ez = c.p_E_B[0], c.p_E_B[1], c.p_E_B[2]
    e = c.estimate
    for i in range(3):
        c.p_E_W[i] = e.p_W[i] + e.R_WB[i, 0] * ex + e.R_WB[i, 1] * ey + e.R_WB[i, 2] * ez
    c.status = bits
    if row.shape[0] > 0:
        write_log_row(row, st, rot)
    return bits


@jit_inline
def controller_step(args, frame, row) -> int:
    """One control period (module docstring): the ``frame`` record in, the command in ``rot.omega_cmd_hz``.

    Args:
        args: ``InteractionController.kernel_args``.
        frame: (1,) the sensor frame record (:func:`omnirotor.messages.frame_dtype`).
        row: the log row to fill (length 0: none).

    Returns:
        The ``ControlStatus`` bits of the command, or ``STEP_NO_ESTIMATE``.
    """
    code = step_begin(args, frame, row)
    if code == STEP_NO_ESTIMATE:
        return code
    if code == BEGIN_DONE:
        return int(args[0][0].own.status)
    solved = False
    if code != _al.BEGIN_HELD:
        state, rot, ar, est, sch, traj = args
        al = state[0].allocation
        solved = _al.boxqp_solve_arrays(ar, int(al.max_iter)) >= 1
    return step_end(args, solved, row)


@jit
def controller_step_by_state(state, frame, row) -> int:
    """:func:`controller_step` from the controller's state alone (its arrays by their stored addresses).

    The same step; from Python it costs one structured array instead of some thirty arrays to unbox.
    """
    return controller_step(_args_of(state), frame, row)


@jit
def step_begin_by_state(state, frame, row) -> int:
    """:func:`step_begin` from the controller's state alone."""
    return step_begin(_args_of(state), frame, row)


@jit
def step_end_by_state(state, solved: bool, row) -> int:
    """:func:`step_end` from the controller's state alone."""
    return step_end(_args_of(state), solved, row)


DEFAULT_DTYPE = controller_dtype(_obs.STATE_DTYPE)
"""The controller's state with the default observer, the one :func:`controller_step_by_table` knows."""


@jit_entry
def controller_step_by_table(table, frame, row) -> int:
    """:func:`controller_step_by_state` for a state of :data:`DEFAULT_DTYPE` given by its address ``table[0]``.

    The same step. Typing a structured array argument costs numba some 14 µs per call from Python (no fast
    path for record dtypes), an int64 array nothing: the controller with the default blocks calls this one.
    """
    state = numba.carray(void_pointer(table[0]), (1,), DEFAULT_DTYPE)
    return controller_step(_args_of(state), frame, row)
