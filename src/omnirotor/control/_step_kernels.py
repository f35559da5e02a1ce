"""The controller's whole 1 kHz step as one compiled call: packed sensor frame in, rotor command out.

:func:`controller_step` is :meth:`omnirotor.control.controller.InteractionController.step` (the module
docstring there gives the blocks and their order) without Python in between: the state estimate
(:func:`~omnirotor.control._estimator_kernels.ukf_step` or :func:`bypass_step`), the map selection
(:func:`~omnirotor.control._map_kernels.schedule_select`), the blocks before the QP
(:func:`~omnirotor.control._kernels.controller_pre`), the QP rebuilt on a map change
(:func:`~omnirotor.control._qp.alloc_set_map`) and solved (:func:`~omnirotor.control._qp.boxqp_solve`), the
pseudo-inverse fallback, and the command with the log row (:func:`~omnirotor.control._kernels.controller_post`).
The Python method calls it once per step; a compiled closed loop (:mod:`omnirotor.experiments._loop`) calls
it directly. Its input is the packed frame of :mod:`omnirotor.messages`, its output the controller's command
array (``omega_cmd``, inside the controller's arena) and the ``ControlStatus`` bits it returns.

Arguments come as one tuple, ``InteractionController.kernel_args``:
``(state, arena, ints, floats, est, sched, alloc, traj, est_out)`` with

* ``state``: the controller's ``(1,)`` structured state; its fields are the states of the converted blocks
  (``observer``) and ``arrays``, the addresses of the other arrays (:func:`controller_step_by_state`);
* ``arena``: the other blocks' packed states (:func:`~omnirotor.control._kernels.controller_layout`);
* ``ints``: int64 parameters and flags ``CI_*``; ``floats``: float64 parameters ``CF_*``;
* ``est``: ``(ukf_mem, ukf_counters, bypass_last, bypass_counters)`` (the arrays of the estimator not in use
  are placeholders);
* ``sched``: the scheduler's ``(schedule, maps, out, weights, state)``;
* ``alloc``: the QP's ``(H, lo, hi, x, active, work, As, failed, counters)``, ``counters`` being the
  allocator's int64 ``AC_*`` (status, fallback and non-finite counts, saturation flag);
* ``traj``: the packed trajectory; ``est_out``: (21,) scratch for the estimate.
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor._jit import address_table, f64_view, f64_view2, i64_view, jit
from omnirotor.control import _estimator_kernels as _ek
from omnirotor.control import _kernels as _k
from omnirotor.control import _map_kernels as _mk
from omnirotor.control._qp import alloc_set_map, boxqp_solve
from omnirotor.messages import (
    FRAME_ACC_B,
    FRAME_GYRO_B,
    FRAME_HAS_STATE,
    FRAME_MOCAP_NEW,
    FRAME_MOCAP_P_W,
    FRAME_MOCAP_Q_WB,
    FRAME_MOCAP_T,
    FRAME_ROTOR_HZ,
    FRAME_STATE,
    FRAME_STATE_SIZE,
    FRAME_T,
)

__all__ = ["controller_step", "controller_step_by_state", "kernel_arrays", "bypass_step", "allocation_fallback"]

# -- the int parameters (ints) --------------------------------------------------------------------------------------
CI_EST_KIND = 0  # EST_UKF or EST_BYPASS
CI_MEASURED = 1  # 1: the observer takes the measured rotor speeds, 0: the last command
CI_PIECEWISE = 2  # 1: the map follows the attitude (piecewise mode)
CI_EXCLUDED = 3  # 1: some rotor is excluded from the allocation
CI_MAX_ITER = 4  # iteration cap of the QP
CI_COMPENSATE = 5  # 1: the UKF fuses a motion-capture sample at the time it was taken
CI_SIZE = 6
EST_UKF, EST_BYPASS = 0, 1

# -- the float parameters (floats) ----------------------------------------------------------------------------------
CF_T0 = 0  # time of the reset frame [s]; trajectory time is frame time minus this
CF_DT = 1  # control period [s]
CF_LAM = 2  # the allocation's regulariser in scaled units
CF_SIZE = 3

# -- the allocator's counters (Allocator.kernel_counters) ------------------------------------------------------
AC_STATUS = 0  # AllocationStatus of the last solve: 0 OK, 1 FALLBACK, 2 NONFINITE
AC_N_FALLBACKS = 1
AC_N_NONFINITE = 2
AC_SATURATED = 3
AC_SIZE = 4
ALLOC_OK, ALLOC_FALLBACK, ALLOC_NONFINITE = 0, 1, 2

# -- the bypass estimator's counters (BypassEstimator.kernel_counters) -------------------------------------------
BY_INITIALISED = 0
BY_DEGRADED = 1
BY_LAST_REJECTED = 2
BY_REJECTED_INPUTS = 3
BY_SIZE = 4
BYPASS_NO_STATE = -1
""":func:`bypass_step`: the frame has no finite state and none was ever received (the plant gives none)."""

STEP_NO_ESTIMATE = -1
""":func:`controller_step`: the estimator cannot give a state (bypass without any); nothing was updated."""

_BIT_QP_FALLBACK = 1
_BIT_NONFINITE = 2
_BIT_DEGRADED = 8
_BIT_EXCLUDED = 16


@jit
def bypass_step(frame, last, counters, out) -> int:
    """The bypass estimator (:class:`omnirotor.control.estimator.BypassEstimator`) on a packed frame.

    A frame with a finite state: that state (kept as the last good one). Otherwise the last good state, flagged.

    Args:
        frame: the packed frame.
        last: (21,) the last good state, updated.
        counters: (BY_SIZE,) int64 flags and counts, updated.
        out: (21,) the estimate.

    Returns:
        0, or ``STEP_REJECTED | STEP_DEGRADED`` of :mod:`omnirotor.control._estimator_kernels` when the last
        state is repeated, or ``BYPASS_NO_STATE`` (nothing written) when there is none.
    """
    finite = frame[FRAME_HAS_STATE] != 0.0
    if finite:
        for i in range(FRAME_STATE_SIZE):
            if not math.isfinite(frame[FRAME_STATE + i]):
                finite = False
                break
    if finite:
        for i in range(FRAME_STATE_SIZE):
            last[i] = frame[FRAME_STATE + i]
            out[i] = last[i]
        counters[BY_INITIALISED] = 1
        counters[BY_DEGRADED] = 0
        counters[BY_LAST_REJECTED] = 0
        return 0
    if counters[BY_INITIALISED] == 0:
        return BYPASS_NO_STATE
    counters[BY_REJECTED_INPUTS] += 1
    counters[BY_LAST_REJECTED] = 1
    counters[BY_DEGRADED] = 1
    for i in range(FRAME_STATE_SIZE):
        out[i] = last[i]
    return _ek.STEP_REJECTED | _ek.STEP_DEGRADED


@jit
def allocation_fallback(As, failed, w_B, counters):
    """The QP-failure fallback of :class:`omnirotor.control.allocation.Allocator`: ``pinv(As) w_B`` (scaled x).

    The map restricted to the working rotors (the failed ones' columns zeroed); the caller clips it. Counts the
    fallback and sets the status. Allocates (a rare path).
    """
    counters[AC_STATUS] = ALLOC_FALLBACK
    counters[AC_N_FALLBACKS] += 1
    Aw = As.copy()
    for j in range(As.shape[1]):
        if failed[j] != 0.0:
            for r in range(As.shape[0]):
                Aw[r, j] = 0.0
    return np.linalg.pinv(Aw) @ w_B


@jit
def controller_step(args, frame, row) -> int:
    """One control period (module docstring): the packed ``frame`` in, the command in the arena, ``row`` logged.

    Args:
        args: ``InteractionController.kernel_args``.
        frame: the packed sensor frame (:mod:`omnirotor.messages`).
        row: the log row to fill (length 0: none).

    Returns:
        The ``ControlStatus`` bits of the command, or ``STEP_NO_ESTIMATE``.
    """
    state, arena, ints, floats, est, sched, alloc, traj, eo = args
    st = state[0]
    ukf_mem, ukf_cnt, by_last, by_cnt = est
    sch, maps_flat, map_out, weights, sch_state = sched
    H, lo, hi, x, active, work, As, failed, actr = alloc
    n = frame.shape[0] - FRAME_ROTOR_HZ
    rotor_hz = frame[FRAME_ROTOR_HZ:]
    t = frame[FRAME_T] - floats[CF_T0]
    dt = floats[CF_DT]
    # 1. the state estimate
    bits = 0
    if ints[CI_EST_KIND] == EST_UKF:
        code, _ = _ek.ukf_step(
            ukf_mem, frame[FRAME_GYRO_B : FRAME_GYRO_B + 3], frame[FRAME_ACC_B : FRAME_ACC_B + 3], frame[FRAME_T],
            frame[FRAME_MOCAP_NEW] != 0.0, frame[FRAME_MOCAP_T], frame[FRAME_MOCAP_P_W : FRAME_MOCAP_P_W + 3],
            frame[FRAME_MOCAP_Q_WB : FRAME_MOCAP_Q_WB + 4], ints[CI_COMPENSATE] != 0, eo, ukf_cnt,
        )  # fmt: skip
    else:
        code = bypass_step(frame, by_last, by_cnt, eo)
        if code == BYPASS_NO_STATE:
            return STEP_NO_ESTIMATE
    if code & _ek.STEP_DEGRADED:
        bits |= _BIT_DEGRADED
    if code & _ek.STEP_REJECTED:
        bits |= _BIT_NONFINITE
    if ints[CI_EXCLUDED] != 0:
        bits |= _BIT_EXCLUDED
    p, v, a, w = eo[0:3], eo[3:6], eo[6:9], eo[18:21]
    R = eo[9:18].reshape(3, 3)
    measured = ints[CI_MEASURED] != 0
    o_obs, o_adm, o_pose, o_des, o_comp, o_body, o_alloc, size = _k.controller_layout(n)
    ws = arena[0:o_obs]
    al = arena[o_alloc:size]
    # 2. the wrench map of this attitude
    A = map_out.reshape(6, n)
    region = -1.0
    packed = False
    pre = _k.PRE_OK
    if ints[CI_PIECEWISE] != 0:  # the region follows the attitude only while the estimate is finite
        packed = _k.pack_inputs(ws, p, v, a, R, w, rotor_hz, measured)
        if packed:
            _mk.schedule_select(sch, R, maps_flat, map_out, weights, sch_state)
        else:
            pre = _k.PRE_STATE_NONFINITE
        region = sch_state[_mk.STATE_REGION]
    # 3.-6. observer, admittance, references, pose controller, the QP's linear term
    if pre == _k.PRE_OK:
        pre = _k.controller_pre(st, arena, p, v, a, R, w, rotor_hz, measured, packed, A, traj, t, dt)
    o_ucmd = _k.CTL_U_OBS + n
    if pre == _k.PRE_STATE_NONFINITE:  # no stateful block was updated: hold the last safe command
        bits |= _BIT_NONFINITE
        for i in range(n):
            ws[o_ucmd + n + i] = ws[o_ucmd + 2 * n + i]
        ws[0], ws[1], ws[2] = t, region, bits
        if row.shape[0] > 0:
            _k.write_log_row(
                row, ws, arena[o_comp:o_body], arena[o_des:o_comp], arena[o_adm:o_pose], st.observer.output,
                arena[o_pose:o_des],
            )  # fmt: skip
        return bits
    # 7. the allocation QP
    w_ref = arena[o_pose + _k.POSE_W_REF : o_pose + _k.POSE_W_REF + 6]
    if pre == _k.PRE_MAP_CHANGED:
        finite = True
        for r in range(6):
            for j in range(n):
                finite = finite and math.isfinite(A[r, j])
        if finite:
            alloc_set_map(al, A, As, H, floats[CF_LAM])
            pre = _k.alloc_prepare(al, w_ref, R, A)
        else:
            pre = _k.PRE_ALLOC_NONFINITE
    mode = _k.FINISH_QP
    o_f = _k.alloc_offsets(n)[0]
    w_B = al[_k.ALLOC_W_B : _k.ALLOC_W_B + 6]
    sol = x
    if pre != _k.PRE_OK:  # the allocator holds its last input
        actr[AC_STATUS] = ALLOC_NONFINITE
        actr[AC_N_NONFINITE] += 1
        o_u, o_u_safe = _k.alloc_offsets(n)[7], _k.alloc_offsets(n)[8]
        for i in range(n):
            al[o_u + i] = al[o_u_safe + i]
        bits |= _BIT_NONFINITE
        mode = _k.FINISH_HELD
    elif boxqp_solve(H, al[o_f : o_f + n], lo, hi, x, active, work, ints[CI_MAX_ITER]) < 1:
        sol = allocation_fallback(As, failed, w_B, actr)
        bits |= _BIT_QP_FALLBACK
        mode = _k.FINISH_FALLBACK
    out, sat = _k.controller_post(st, arena, sol, mode, actr[AC_SATURATED] != 0, bits, region, t, row)
    if out < 0:  # the QP's answer was not finite: nothing was written
        bits |= _BIT_QP_FALLBACK
        mode = _k.FINISH_FALLBACK
        sol = allocation_fallback(As, failed, w_B, actr)
        out, sat = _k.controller_post(st, arena, sol, mode, actr[AC_SATURATED] != 0, bits, region, t, row)
    if mode != _k.FINISH_HELD:
        actr[AC_SATURATED] = sat
        if mode == _k.FINISH_QP:
            actr[AC_STATUS] = ALLOC_OK
    return out


N_ARRAYS = 23
"""Arrays of ``kernel_args`` reached by address (all but ``state``), the length of ``state["arrays"]`` / 3."""


def kernel_arrays(args: tuple) -> list[np.ndarray]:
    """The arrays of a ``kernel_args`` tuple but its state, in the order :func:`controller_step_by_state` reads."""
    state, arena, ints, floats, est, sched, alloc, traj, eo = args
    return [arena, ints, floats, *est, *sched, *alloc, traj, eo]


def store_addresses(args: tuple) -> None:
    """Write the addresses of the arrays of ``args`` into its state's ``arrays`` field.

    The arrays must stay alive and in place while the state is used: the controller keeps them in ``args``.
    """
    args[0]["arrays"][0] = address_table(kernel_arrays(args))


@jit
def controller_step_by_state(state, frame, row) -> int:
    """:func:`controller_step` from the controller's state alone (the other arrays by their stored addresses).

    The same step; from Python it costs one structured array instead of some twenty array arguments to unbox.
    """
    table = state[0].arrays
    args = (
        state,
        f64_view(table, 0),
        i64_view(table, 1),
        f64_view(table, 2),
        (f64_view(table, 3), i64_view(table, 4), f64_view(table, 5), i64_view(table, 6)),
        (f64_view(table, 7), f64_view2(table, 8), f64_view(table, 9), f64_view(table, 10), f64_view(table, 11)),
        (
            f64_view2(table, 12), f64_view(table, 13), f64_view(table, 14), f64_view(table, 15), i64_view(table, 16),
            f64_view(table, 17), f64_view2(table, 18), f64_view(table, 19), i64_view(table, 20),
        ),
        f64_view(table, 21),
        f64_view(table, 22),
    )  # fmt: skip
    return controller_step(args, frame, row)
