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

Every block's state is a field of the controller's one structured record (:func:`controller_dtype`, built
from the blocks' registered dtypes and the controller's sizes, :class:`ControllerSizes`): the per-rotor
arrays (``rotors``), the allocator's (``allocation_arrays``), the UKF's ring buffers and scratch
(``ukf_memory``), the map scheduler's partition and maps (``maps_arrays``) and the trajectory block's packed
waypoints (``trajectory_data``) are subarray fields of it too. The composer reads and writes the signals by name
(``st.observer.f_ext_W``, ``st.pose.f_ref_W``, ``st.rotors.u_cmd_hz2``) and calls every block, of every kind,
through :func:`omnirotor.blocks.compiled_step` (the kind's typed step, :data:`omnirotor.blocks.KIND_STEPS`),
so that any registered block of a kind fits; the choice is made when the step compiles, per combination of the
blocks' record types, and costs nothing per period.

One period is one compiled call, :func:`controller_step` ``(state, frame, row)``, from Python
(``InteractionController.step``) and from the compiled closed loop alike. It is split around the allocation
QP: :func:`step_begin` (estimate to the allocation kind's ``kernel``, which prepares the QP) and
:func:`step_end` (the QP's answer, through the kind's ``finish``, to the command and the log row), inlined into
it around the kind's compiled ``qp``; a controller with a QP solver called from Python (daqp, ProxSuite) calls
the same two itself around that solver. An allocation block without a QP answers ``ALLOC_DONE`` at once.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numba
import numpy as np
from numba.np.numpy_support import as_dtype

from omnirotor._jit import jit, jit_entry, jit_inline
from omnirotor.blocks import LogGroup, class_of_record, compiled_step, log_dtype, log_groups, log_writer
from omnirotor.control import _estimator_kernels as _ek
from omnirotor.control import _map_kernels as _mk
from omnirotor.control import admittance as _adm
from omnirotor.control import allocation as _al
from omnirotor.control import estimator as _est
from omnirotor.control import pose as _pose
from omnirotor.control import supervisor as _sup
from omnirotor.control import trajectory as _traj
from omnirotor.frame_kernels import state_finite
from omnirotor.messages import ESTIMATE_DTYPE, ESTIMATE_LOG_FIELDS

__all__ = [
    "CONTROLLER_DTYPE_FIELDS",
    "ControllerSizes",
    "rotors_dtype",
    "controller_dtype",
    "step_begin",
    "step_end",
    "controller_step",
    "controller_log_groups",
    "log_sources",
    "write_log",
]


@jit
def _no_reference(r, estimate, p_E_B, dt, ref) -> None:
    """A supervisor without a failsafe reference (the optional entry ``reference``): the trajectory's stays."""
    return None


@jit
def _no_qp(r, arrays) -> bool:
    """An allocation block without a QP (the optional entry ``qp``): nothing solved."""
    return False


@jit
def _no_finish(r, arrays, solved: bool) -> None:
    """An allocation block without a QP (the optional entry ``finish``): its inputs are final."""
    return None


# Every controller kind through the registry (omnirotor.blocks.KIND_STEPS): resolved when the step compiles.
supervisor_step = compiled_step("supervisor")
supervisor_reference = compiled_step("supervisor", "reference", default=_no_reference)
estimator_step = compiled_step("estimator")
maps_step = compiled_step("maps")
observer_step = compiled_step("observer")
trajectory_step = compiled_step("trajectory")
admittance_block_step = compiled_step("admittance")
pose_block_step = compiled_step("pose")
allocation_step = compiled_step("allocation")
allocation_qp = compiled_step("allocation", "qp", default=_no_qp)
allocation_finish = compiled_step("allocation", "finish", default=_no_finish)

_F8, _I8 = np.float64, np.int64
OWN_DTYPE = np.dtype(
    [
        # the logged head
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


def rotors_dtype(n: int) -> np.dtype:
    """The controller's own per-rotor arrays for ``n`` rotors (its field ``rotors``)."""
    return np.dtype(
        [
            ("u_obs_hz2", _F8, (n,)),  # the measured inputs |omega| omega [Hz²]
            ("u_cmd_hz2", _F8, (n,)),  # the last allocated inputs [Hz²]
            ("omega_cmd_hz", _F8, (n,)),  # the command [Hz]
            ("omega_safe_hz", _F8, (n,)),  # the last finite command [Hz]
        ]
    )


@dataclasses.dataclass(frozen=True)
class ControllerSizes:
    """The sizes the controller's record is built for (one compiled step per distinct record).

    Attributes:
        n_rotors: rotors of the vehicle.
        ukf_capacity: length of the UKF's ring buffers (``estimator.ukf_capacity``).
        n_regions: regions of the wrench maps' partition (0 without maps).
        n_intervals: azimuth-interval slots per region (``maps.schedule_sizes``).
        trajectory_capacity: floats of the trajectory block's data (its ``data_size`` of
            ``ControllerParams.trajectory_waypoints``), fixed when the controller is built.
    """

    n_rotors: int
    ukf_capacity: int
    n_regions: int
    n_intervals: int
    trajectory_capacity: int


CONTROLLER_DTYPE_FIELDS = ("own", "observer", "admittance", "pose", "desired_ee", "compliant_ee", "body_ref")

LOGGED_KINDS = ("admittance", "observer", "pose", "supervisor", "maps", "trajectory", "allocation")
"""The kinds whose blocks' ``log_fields`` the log records (in that order, after the controller's head)."""


@functools.cache
def controller_dtype(
    observer_dtype: np.dtype,
    sizes: ControllerSizes,
    admittance_dtype: np.dtype = _adm.STATE_DTYPE,
    pose_dtype: np.dtype = _pose.STATE_DTYPE,
    supervisor_dtype: np.dtype = _sup.STATE_DTYPE,
    maps_dtype: np.dtype = _mk.STATE_DTYPE,
    trajectory_dtype: np.dtype = _traj.TRAJECTORY_DTYPE,
    allocation_dtype: np.dtype = _al.STATE_DTYPE,
    allocation_arrays_dtype: np.dtype | None = None,
) -> np.dtype:
    """The controller's one record: its own part, its blocks' states and their sized arrays (module docstring).

    ``*_dtype``: the state dtypes of the chosen blocks of those kinds; ``allocation_arrays_dtype``: the chosen
    allocation block's ``arrays_dtype(n)`` (default the box QP's). Equal arguments give the same dtype object:
    numba's dispatcher types a structured array quickly only for a dtype object it has seen (an equal but new
    one costs tens of microseconds a call).
    """
    if allocation_arrays_dtype is None:
        allocation_arrays_dtype = _al.arrays_dtype(sizes.n_rotors)
    ref = _traj.REFERENCE_DTYPE
    n = sizes.n_rotors
    return np.dtype(
        [
            ("own", OWN_DTYPE),
            ("observer", observer_dtype),
            ("admittance", admittance_dtype),
            ("pose", pose_dtype),
            ("desired_ee", ref),
            ("compliant_ee", ref),
            ("body_ref", ref),
            ("segment", _traj.SEGMENT_DTYPE),  # an in-flight set-point replacing the trajectory (when active)
            ("allocation", allocation_dtype),
            ("allocation_arrays", allocation_arrays_dtype),
            ("bypass", _est.BYPASS_DTYPE),  # the estimators, by their registered names
            ("ukf", _ek.UKF_DTYPE),
            ("ukf_memory", _ek.memory_dtype(sizes.ukf_capacity)),
            ("supervisor", supervisor_dtype),
            ("maps", maps_dtype),
            ("maps_arrays", _mk.arrays_dtype(sizes.n_regions, sizes.n_intervals, n)),
            ("rotors", rotors_dtype(n)),
            ("trajectory", trajectory_dtype),
            ("trajectory_data", _F8, (sizes.trajectory_capacity,)),  # the trajectory block's data (packed)
        ]
    )


@jit
def _all_finite(x) -> bool:
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            return False
    return True


# -- the log: one record of the blocks' logged fields ---------------------------------------------------------


def log_sources(classes: dict[str, type]) -> tuple:
    """Where the controller's log groups come from, in log order (:func:`omnirotor.blocks.log_groups`).

    Each block's own declaration (``log_fields``, ``log_labels``; ``classes``: the chosen class of each of
    :data:`LOGGED_KINDS`), and the controller's head: the time, region and status, the estimate
    (``ESTIMATE_LOG_FIELDS``), the EE tip, the compliant and the desired EE references, the allocated inputs and
    the command. The default blocks' log is the admittance's, the observer's, the pose controller's, the rotors'
    and the frame supervision's causes.
    """

    def block(kind: str, prefix: str | None = None) -> tuple:
        cls = classes[kind]
        return (prefix or kind, cls.log_fields, getattr(cls, "log_labels", {}))

    return (
        ("own", ("t", "region", "status"), {}),
        ("own.estimate", ESTIMATE_LOG_FIELDS, {}),
        ("own", ("p_E_W",), {}),
        ("compliant_ee", _traj.reference_log_fields("E_ref"), {}),
        ("desired_ee", _traj.reference_log_fields("E_des"), {}),
        block("admittance"),
        block("observer"),
        block("pose"),
        ("rotors", (("u_hz2", ("u_cmd_hz2",)), "omega_cmd_hz"), {}),
        block("supervisor"),
        block("maps"),
        block("trajectory"),
        block("allocation"),
    )


def controller_log_groups(state_dtype: np.dtype, classes: dict[str, type]) -> tuple[LogGroup, ...]:
    """The groups of the log of a controller with the record ``state_dtype`` and these blocks (:func:`log_sources`)."""
    return log_groups(state_dtype, log_sources(classes))


def _log_groups_of_types(dst, src) -> tuple[LogGroup, ...] | None:
    """The log groups for numba's record types of a log row ``dst`` and a controller ``src`` (else None)."""
    names = getattr(src, "fields", {})
    if "observer" not in names or "rotors" not in names:
        return None
    classes = {kind: class_of_record(kind, src.typeof(kind)) for kind in LOGGED_KINDS}
    if any(cls is None for cls in classes.values()):
        return None
    groups = controller_log_groups(as_dtype(src), classes)
    return groups if numba.from_dtype(log_dtype(groups)) == dst else None


write_log = log_writer("write_log", _log_groups_of_types)
"""``write_log(row, st)``: the controller's log record ``row`` from its record ``st`` (generated, by name)."""


@jit_inline
def _finish_held(st, bits: int, row) -> None:
    """Hold the last safe command (nothing else updated), flagged; write the head and the log row.

    Inlined into the step (:func:`step_begin`): numba compiles an ``overload`` such as :data:`write_log` once
    per set of compile flags of its callers, and a kernel of its own here (``jit``, without the C wrapper)
    would compile the generated writer a second time beside the one of :func:`controller_step` (``jit_entry``).
    """
    c = st.own
    rot = st.rotors
    for i in range(rot.omega_cmd_hz.shape[0]):
        rot.omega_cmd_hz[i] = rot.omega_safe_hz[i]
    c.status = bits
    if row.shape[0] > 0:
        write_log(row[0], st)


@jit_inline
def step_begin(state, frame, row) -> int:
    """Everything of a period before the allocation QP (module docstring), the frame's supervision first.

    Returns:
        ``STEP_NO_ESTIMATE`` (nothing updated), ``BEGIN_DONE`` (a non-finite estimate or measured rotor
        speed, or a rejected bypass state: the last safe command is held, flagged, and logged; no stateful
        block was updated), or the
        code of :func:`~omnirotor.control.allocation.alloc_begin` (its linear term is then ready, or the
        allocator holds its last input).
    """
    st = state[0]
    c = st.own
    rot = st.rotors
    fr = frame[0]
    rotor_hz = fr.rotor_hz
    n = rotor_hz.shape[0]
    e = c.estimate
    # 0. the frame's supervision: the estimator reads the checked frame f (e still holds the last estimate)
    sv = st.supervisor
    act = supervisor_step(sv, fr, e)
    cause = sv.cause
    f = sv.clean
    # 1. the state estimate
    kind = c.estimator
    if kind == EST_UKF:  # the registered estimators, each on its field, by the kind's one signature
        st.ukf.coasting = sv.coasting
        code = estimator_step(st.ukf, st.ukf_memory, f, e)
        if act & _sup.ACT_REINIT:
            _ek.ukf_reinit(st.ukf, f.mocap.p_W, f.mocap.q_WB, e, sv.reinit_v_W)
            code &= ~_ek.STEP_DEGRADED
    elif kind == EST_BYPASS:
        code = estimator_step(st.bypass, st.ukf_memory, f, e)
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
            _finish_held(st, bits, row)
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
    A = st.maps_arrays.out
    c.region = -1.0
    if c.piecewise != 0:
        if finite:
            maps_step(st.maps, st.maps_arrays, R)
        c.region = st.maps.region
    if cause & (_sup.CAUSE_STATE | _sup.CAUSE_STATE_JUMP) or sv.blind != 0:  # no state to act on: hold
        finite = False
    if not finite:  # no stateful block is updated: hold the last safe command
        _finish_held(st, bits | _BIT_NONFINITE, row)
        return BEGIN_DONE
    # 3. the observer, on the measured rotor inputs or the last command
    u = rot.u_obs_hz2 if measured else rot.u_cmd_hz2
    obs = st.observer
    observer_step(obs, A, u, a, R, w, dt)
    # 4. the EE wrench, the admittance filter, the desired, compliant and body references
    _adm.ee_wrench(obs.f_ext_W, obs.m_ext_B, R, c.p_E_B, c.f_E_W, c.m_E_W)
    if st.segment.active != 0:
        _traj.segment_sample(st.segment, t, st.desired_ee)
    else:
        trajectory_step(st.trajectory, st.trajectory_data, t, st.desired_ee)
    if sv.fs_mode != _sup.FS_OFF:  # the failsafe's hold-then-land replaces the reference
        supervisor_reference(sv, e, c.p_E_B, dt, st.desired_ee)
    admittance_block_step(st.admittance, c.f_E_W, c.m_E_W, st.desired_ee, st.compliant_ee, dt)
    _adm.body_reference(st.compliant_ee, c.p_E_B, st.body_ref)
    # 5. the pose controller compensates the whole unexplained wrench (before bias and zeroing)
    pose_block_step(st.pose, st.body_ref, p, v, R, w, obs.f_filt_W, obs.m_filt_B, dt)
    # 6. the allocation up to its QP
    alloc = allocation_step(st.allocation, st.allocation_arrays, st.pose.f_ref_W, st.pose.m_ref_B, R, A)
    if alloc == _al.BEGIN_HELD:
        bits |= _BIT_NONFINITE
    c.status = bits
    c.alloc_code = alloc
    return alloc


@jit_inline
def step_end(state, solved: bool, row) -> int:
    """Everything of a period after the allocation QP (module docstring).

    The QP's answer (``ar.x``; ``solved`` says whether the solver succeeded) to the inputs (the pseudo-inverse
    fallback if needed), the command ``omega = sign(u) sqrt|u|`` clipped to the limits (the last safe command
    is held, flagged, should it not be finite), the EE tip, the head and the log row.

    Returns:
        The ``ControlStatus`` bits.
    """
    st = state[0]
    c = st.own
    rot = st.rotors
    ar = st.allocation_arrays
    al = st.allocation
    bits = int(c.status)
    if c.alloc_code == _al.BEGIN_SOLVE or c.alloc_code == _al.BEGIN_SOLVE_NEW_MAP:
        allocation_finish(al, ar, solved)
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
        write_log(row[0], st)
    return bits


@jit_entry
def controller_step(state, frame, row) -> int:
    """One control period (module docstring): the ``frame`` record in, the command in ``state[0].rotors``.

    Args:
        state: (1,) the controller's record (:func:`controller_dtype`; ``InteractionController.state``).
        frame: (1,) the sensor frame record (:func:`omnirotor.messages.frame_dtype`).
        row: (1,) the log record to fill (:attr:`InteractionController.log_dtype`); (0,): none.

    Returns:
        The ``ControlStatus`` bits of the command, or ``STEP_NO_ESTIMATE``.
    """
    code = step_begin(state, frame, row)
    if code == STEP_NO_ESTIMATE:
        return code
    st = state[0]
    if code == BEGIN_DONE:
        return int(st.own.status)
    solved = False
    if code == _al.BEGIN_SOLVE or code == _al.BEGIN_SOLVE_NEW_MAP:
        solved = allocation_qp(st.allocation, st.allocation_arrays)
    return step_end(state, solved, row)
