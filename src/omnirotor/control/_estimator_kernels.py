"""Compiled kernels of the UKF state estimator (:class:`omnirotor.control.estimator.UKFEstimator`, SPEC §4.5).

The estimator keeps its state in a few arrays: ``x`` (the nominal states, times, counters and parameters,
layout ``UKF_*`` below), the ring buffers ``buf`` (cap, 8: t, dt, gyro_B, acc_B of each IMU sample) and
``sbuf`` (cap, 16: the output state after each sample), the covariance ``P`` (15, 15), the unscented weights
``W`` (2, 31: mean, covariance) and the constant matrices ``M`` (5, 15, 15: the process-noise terms Q1, Q2,
Q3, the initial covariance P0 and, in its top-left 6 x 6 corner, the measurement noise Rn), followed by a
workspace ``wk`` (``WK_SIZE``: the work arrays of :func:`ukf_predict` and :func:`ukf_fuse`, layouts ``WP_*``
and ``WF_*``), all in one float64 array (:func:`memory_layout`), so that a step allocates nothing. The model
and the filter are described in the estimator's module docstring; these kernels implement them:

* :func:`ukf_imu_step`: one IMU sample (validation, lever arm, buffering, noise-free mean propagation) and,
  when no motion-capture sample is to be fused, the end of the step (:func:`ukf_finish`: the outputs);
* :func:`ukf_predict`: the unscented covariance prediction of the delayed fused state;
* :func:`ukf_fuse_at` and :func:`ukf_fuse`: where a delayed motion-capture sample belongs, and its update
  (closed-form Kalman update, error injection, reset Jacobian, re-propagation of the mean to now);
* :func:`ukf_step`: the estimator's whole 1 kHz step after initialisation in one call (the above in order,
  the motion-capture sample checks, the latency choice and the counters ``CNT_*``), for
  :meth:`UKFEstimator.step` and for a compiled control loop.

A kernel calling another compiles the callee again inside itself, so :func:`ukf_step` (which holds all of
them, :func:`ukf_predict` the slowest) takes the longest to compile; the compiled code is cached on disk.
Numba checks only the caller's own source file against its cache: after a change here, the cached kernels of
other modules that call these (the controller's compiled step, the compiled closed loop) are stale and must be
deleted (a stale copy loaded next to the new one can even call the wrong version of a helper and crash).

The arithmetic is written in the order of the Python float / NumPy code it replaced; where NumPy summed a
product with BLAS (sigma-point statistics, Cholesky, the 6 x 6 inverse) results agree within a rounding.
"""

from __future__ import annotations

import math

from omnirotor._jit import R9_from_quat_into, jit, jit_inline

N_ERR = 15
"""Error-state dimension: dp, dv, dtheta, db_a, db_g."""
N_SIGMA = 2 * N_ERR + 1

# Layout of the scalar part x = mem[0:UKF_SIZE] of the estimator's memory.
UKF_S = 0  # (16,) output (current) nominal state: p_W, v_W, q_WB (wxyz), b_a, b_g
UKF_RS = 16  # (9,) R_WB of the output state, row-major
UKF_F = 25  # (16,) delayed fused state
UKF_RF = 41  # (9,) its R_WB
UKF_IMU = 50  # (6,) last good raw IMU sample: gyro_B, acc_B
UKF_IMU_C = 56  # (6,) the sample of this step, lever-arm corrected
UKF_GLP = 62  # (3,) low-passed gyro (for the lever arm's omega_dot)
UKF_WO = 65  # (3,) omega_B output
UKF_AO = 68  # (3,) a_W output
UKF_T = 71  # time of the output state [s]
UKF_T_F = 72  # time of the fused state [s]
UKF_T_ACCEPT = 73  # frame time of the last accepted motion-capture sample [s]
UKF_LPF_DT = 74  # dt of the cached output-filter gains (NaN: none yet)
UKF_LAM_W = 75
UKF_LAM_A = 76
UKF_K = 77  # IMU samples pushed so far
UKF_KF = 78  # samples already in the fused state
UKF_JUST_RESET = 79  # 1 until a sample is fused after the start-up pose
UKF_GATE_FAILS = 80  # consecutive gate failures
UKF_DT = 81  # period of the last IMU sample [s]
# Parameters.
UKF_G = 82
UKF_DT_NOM = 83
UKF_GYRO_RANGE = 84
UKF_ACC_RANGE = 85
UKF_R_IMU = 86  # (3,) IMU offset from the CoM [m]
UKF_LEVER = 89  # 1 when the offset is not zero
UKF_LEVER_CUT = 90
UKF_GYRO_CUT = 91
UKF_ACC_CUT = 92
UKF_CAP = 93  # ring-buffer length
UKF_COV_N = 94  # samples per covariance step
UKF_UT_SCALE = 95  # sqrt(n + lambda)
UKF_MAX_LAT = 96  # largest motion-capture latency [s]
UKF_GATE = 97  # chi-square gate
UKF_REINIT_AFTER = 98
UKF_LAG_N = 99  # samples the fused state may lag ...
UKF_CHUNK_N = 100  # ... plus this many before it is advanced without motion capture
UKF_TIMEOUT = 101  # motion-capture timeout [s]
UKF_SIZE = 102

# Bits of the code ukf_imu_step and ukf_finish return.
STEP_REJECTED = 1  # the period or the IMU sample was rejected
STEP_DEGRADED = 2  # no motion-capture sample accepted for longer than the timeout
STEP_ADVANCE = 4  # the delayed fused state lags too far: advance it (ukf_predict to k - lag_n)

M_Q1, M_Q2, M_Q3, M_P0, M_RN = 0, 1, 2, 3, 4

# Layout of the counters array (int64) that ukf_step updates.
CNT_MOCAP_FUSED = 0  # motion-capture samples fused
CNT_REJECTED_MOCAP = 1  # motion-capture samples rejected (invalid, stale, singular or outside the gate)
CNT_REINIT = 2  # re-initialisations from motion capture after repeated gate failures
CNT_REJECTED_INPUTS = 3  # frames in which something (period, IMU sample, motion-capture sample) was rejected
CNT_LAST_REJECTED = 4  # 1 when something in the last frame was rejected
CNT_DEGRADED = 5  # 1 while no motion-capture sample was accepted for longer than the timeout
CNT_SIZE = 6

QUAT_NORM_TOL = 0.1
"""A motion-capture quaternion whose norm is off 1 by more than this is rejected."""

# Return codes of ukf_fuse.
FUSE_OK = 0
FUSE_STALE = 1  # older than the fused state or the buffer, or from the future
FUSE_SINGULAR = 2  # innovation covariance not invertible
FUSE_GATE = 3  # outside the chi-square gate
FUSE_REINIT = 4  # outside the gate once too often: the pose was re-initialised from motion capture

_RESET_MIN_RAD2 = (0.5e-3) ** 2  # squared half attitude correction [rad²] above which P is reset-transported


# Layout of the workspace wk (WK_SIZE,) at the end of the memory: the work arrays of ukf_predict (WP_*) and of
# ukf_fuse (WF_*). Its content means nothing between kernel calls: every kernel writes an entry before it reads
# it. ukf_predict and ukf_fuse never run inside one another, so their arrays share the region.
_NN = N_ERR * N_ERR
WP_L = 0  # (15, 15) lower Cholesky factor of P
WP_PJ = WP_L + _NN  # (15, 15) P symmetrised, with jitter on the diagonal (when P lost positive definiteness)
WP_D = WP_PJ + _NN  # (31, 15) sigma-point offsets in the error coordinates
WP_PS = WP_D + N_SIGMA * N_ERR  # (31, 3) sigma points' p_W [m]
WP_VS = WP_PS + 3 * N_SIGMA  # (31, 3) their v_W [m/s]
WP_BA = WP_VS + 3 * N_SIGMA  # (31, 3) their b_a [m/s²]
WP_BG = WP_BA + 3 * N_SIGMA  # (31, 3) their b_g [rad/s]
WP_RS = WP_BG + 3 * N_SIGMA  # (31, 3, 3) their R_WB (3 x 3 matrices here are row-major, 9 entries)
WP_ROT = WP_RS + 9 * N_SIGMA  # (3, 3) rotation of a sigma-point offset or of one covariance step
WP_TMP = WP_ROT + 9  # (3, 3) product of two rotations
WP_R0T = WP_TMP + 9  # (3, 3) transpose of the first sigma point's R_WB
WP_M = WP_R0T + 9  # (6,) mean IMU reading of a covariance step: gyro_B [rad/s], acc_B [m/s²]
WP_A = WP_M + 6  # (3,) a_W of a sigma point [m/s²]
WP_E = WP_A + 3  # (31, 15) errors of the propagated sigma points
WP_MEAN = WP_E + N_SIGMA * N_ERR  # (15,) their weighted mean
WP_SIZE = WP_MEAN + N_ERR
N_MEAS = 6
"""Dimension of the motion-capture measurement: position and attitude."""
WF_R = 0  # (6,) innovation: position [m], rotation vector [rad]
WF_PHT = WF_R + N_MEAS  # (15, 6) P Hᵀ
WF_S = WF_PHT + N_ERR * N_MEAS  # (6, 6) innovation covariance (inverted in place)
WF_SINV = WF_S + N_MEAS * N_MEAS  # (6, 6) its inverse
WF_K = WF_SINV + N_MEAS * N_MEAS  # (15, 6) Kalman gain
WF_DX = WF_K + N_ERR * N_MEAS  # (15,) error-state correction
WF_PN = WF_DX + N_ERR  # (15, 15) updated covariance (I - K H) P
WF_GT = WF_PN + _NN  # (3, 3) reset Jacobian's attitude block
WF_ROWS = WF_GT + 9  # (3, 15) its product with the attitude rows of Pn
WF_COLS = WF_ROWS + 3 * N_ERR  # (15, 3) and with the attitude columns
WF_SIZE = WF_COLS + 3 * N_ERR
WK_SIZE = max(WP_SIZE, WF_SIZE)

_H_ROWS = (0, 1, 2, 6, 7, 8)
"""The error coordinates the motion-capture pose measures (dp, dtheta): rows of H, in measurement order."""


def memory_layout(cap: int) -> tuple[int, int, int, int, int, int, int]:
    """Offsets of buf (cap x 8), sbuf (cap x 16), P (15 x 15), W (2 x 31), M (5 x 15 x 15), wk (WK_SIZE), the size.

    Args:
        cap: ring-buffer length [samples].
    """
    o_buf = UKF_SIZE
    o_sbuf = o_buf + 8 * cap
    o_P = o_sbuf + 16 * cap
    o_W = o_P + N_ERR * N_ERR
    o_M = o_W + 2 * N_SIGMA
    o_wk = o_M + 5 * N_ERR * N_ERR
    return o_buf, o_sbuf, o_P, o_W, o_M, o_wk, o_wk + WK_SIZE


@jit
def views(mem):
    """``(x, buf, sbuf, P, W, M, wk)``: the parts of the estimator's memory (module docstring)."""
    cap = int(mem[UKF_CAP])
    o_buf = UKF_SIZE
    o_sbuf = o_buf + 8 * cap
    o_P = o_sbuf + 16 * cap
    o_W = o_P + N_ERR * N_ERR
    o_M = o_W + 2 * N_SIGMA
    o_wk = o_M + 5 * N_ERR * N_ERR
    return (
        mem[0:UKF_SIZE],
        mem[o_buf:o_sbuf].reshape(cap, 8),
        mem[o_sbuf:o_P].reshape(cap, 16),
        mem[o_P:o_W].reshape(N_ERR, N_ERR),
        mem[o_W:o_M].reshape(2, N_SIGMA),
        mem[o_M:o_wk].reshape(5, N_ERR, N_ERR),
        mem[o_wk : o_wk + WK_SIZE],
    )


@jit_inline
def _work2(wk, o: int, rows: int, cols: int):
    """The (rows, cols) work array at ``wk[o:]`` (a view)."""
    return wk[o : o + rows * cols].reshape(rows, cols)


@jit
def lpf_gain(dt: float, cutoff_hz: float) -> float:
    """Gain ``lam`` of the discrete first-order filter ``y += lam (x - y)`` (SPEC §4.3); 1 when off."""
    if cutoff_hz <= 0.0:
        return 1.0
    k = 2.0 * math.pi * dt * cutoff_hz
    return k / (k + 1.0)


@jit
def propagate(s, o: int, R, oR: int, dt: float, g: float, imu, oi: int) -> None:
    """One IMU sample on the nominal state ``s[o:o+16]``, in place; ``R[oR:oR+9]`` becomes ``R_WB(q)``.

    ``imu[oi:oi+6]`` is ``gyro_B [rad/s], acc_B [m/s²]`` (lever-arm corrected); see the estimator's model.
    """
    fx, fy, fz = imu[oi + 3] - s[o + 10], imu[oi + 4] - s[o + 11], imu[oi + 5] - s[o + 12]
    ax = R[oR] * fx + R[oR + 1] * fy + R[oR + 2] * fz
    ay = R[oR + 3] * fx + R[oR + 4] * fy + R[oR + 5] * fz
    az = R[oR + 6] * fx + R[oR + 7] * fy + R[oR + 8] * fz - g
    h = 0.5 * dt * dt
    s[o] += s[o + 3] * dt + ax * h
    s[o + 1] += s[o + 4] * dt + ay * h
    s[o + 2] += s[o + 5] * dt + az * h
    s[o + 3] += ax * dt
    s[o + 4] += ay * dt
    s[o + 5] += az * dt
    wx, wy, wz = (imu[oi] - s[o + 13]) * dt, (imu[oi + 1] - s[o + 14]) * dt, (imu[oi + 2] - s[o + 15]) * dt
    th2 = wx * wx + wy * wy + wz * wz
    if th2 > 1e-24:
        th = math.sqrt(th2)
        c, k = math.cos(0.5 * th), math.sin(0.5 * th) / th
    else:
        c, k = 1.0 - th2 / 8.0, 0.5 - th2 / 48.0
    dx, dy, dz = k * wx, k * wy, k * wz
    qw, qx, qy, qz = s[o + 6], s[o + 7], s[o + 8], s[o + 9]
    nw = qw * c - qx * dx - qy * dy - qz * dz
    nx = qw * dx + qx * c + qy * dz - qz * dy
    ny = qw * dy - qx * dz + qy * c + qz * dx
    nz = qw * dz + qx * dy - qy * dx + qz * c
    inv = 1.0 / math.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
    s[o + 6], s[o + 7], s[o + 8], s[o + 9] = nw * inv, nx * inv, ny * inv, nz * inv
    R9_from_quat_into(s[o + 6], s[o + 7], s[o + 8], s[o + 9], R, oR)


@jit
def _correct_lever_arm(x, dt: float) -> None:
    """Remove ``omega x (omega x r) + omega_dot x r`` from the accelerometer sample ``x[UKF_IMU_C+3:+6]``."""
    r0, r1, r2 = x[UKF_R_IMU], x[UKF_R_IMU + 1], x[UKF_R_IMU + 2]
    lam = lpf_gain(dt, x[UKF_LEVER_CUT])
    C, S = UKF_IMU_C, UKF_S
    wd0 = _lowpass_rate(x, 0, lam, dt)  # omega_dot_B [rad/s²]
    wd1 = _lowpass_rate(x, 1, lam, dt)
    wd2 = _lowpass_rate(x, 2, lam, dt)
    wx, wy, wz = x[C] - x[S + 13], x[C + 1] - x[S + 14], x[C + 2] - x[S + 15]
    cx, cy, cz = wy * r2 - wz * r1, wz * r0 - wx * r2, wx * r1 - wy * r0  # omega x r
    x[C + 3] -= wy * cz - wz * cy + wd1 * r2 - wd2 * r1
    x[C + 4] -= wz * cx - wx * cz + wd2 * r0 - wd0 * r2
    x[C + 5] -= wx * cy - wy * cx + wd0 * r1 - wd1 * r0


@jit
def _lowpass_rate(x, i: int, lam: float, dt: float) -> float:
    """Low-pass axis ``i`` of the gyro sample into ``x[UKF_GLP + i]``; return the filtered rate's derivative."""
    L = UKF_GLP + i
    new = x[L] + lam * (x[UKF_IMU_C + i] - x[L])
    wd = (new - x[L]) / dt
    x[L] = new
    return wd


@jit
def mocap_sample_valid(p, q, tol: float) -> bool:
    """Finite position and quaternion, the quaternion's norm within ``tol`` of 1."""
    if not (math.isfinite(p[0] + p[1] + p[2]) and math.isfinite(q[0] + q[1] + q[2] + q[3])):
        return False
    return abs(math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) - 1.0) <= tol


@jit
def imu_valid(x, gyro, acc) -> bool:
    """A finite sample within the sensor ranges."""
    sg, sa = gyro[0] + gyro[1] + gyro[2], acc[0] + acc[1] + acc[2]
    if not (math.isfinite(sg) and math.isfinite(sa)):
        return False
    gr, ar = x[UKF_GYRO_RANGE], x[UKF_ACC_RANGE]
    return max(abs(gyro[0]), abs(gyro[1]), abs(gyro[2])) <= gr and max(abs(acc[0]), abs(acc[1]), abs(acc[2])) <= ar


@jit
def ukf_imu_step(mem, gyro, acc, t_frame: float, finish: bool, out) -> tuple:
    """One IMU sample: period and sample validation, lever arm, buffering, mean propagation.

    An invalid period (not finite, not increasing) is replaced by the nominal one, an invalid sample by the
    last good one. With ``finish`` (no motion-capture sample to fuse in this frame) :func:`ukf_finish` follows.

    Returns:
        ``(code, t)``: ``STEP_REJECTED`` when the period or the sample was rejected, plus ``STEP_DEGRADED``
        from :func:`ukf_finish` with ``finish``; the time of the estimate [s].
    """
    x, buf, sbuf, P, W, M, wk = views(mem)
    code, t = _imu_step(x, buf, sbuf, gyro, acc, t_frame)
    if finish:
        code |= _finish(x, out)
    return code, t


@jit
def _imu_step(x, buf, sbuf, gyro, acc, t_frame: float) -> tuple:
    """:func:`ukf_imu_step` without ``finish``, on the parts of the memory (:func:`views`)."""
    rejected = False
    dt = t_frame - x[UKF_T]
    if not (dt > 0.0 and math.isfinite(dt)):
        dt = x[UKF_DT_NOM]
        rejected = True
    t = x[UKF_T] + dt
    x[UKF_T] = t
    x[UKF_DT] = dt
    if imu_valid(x, gyro, acc):
        for i in range(3):
            x[UKF_IMU + i] = gyro[i]
            x[UKF_IMU + 3 + i] = acc[i]
    else:
        rejected = True
    for i in range(6):
        x[UKF_IMU_C + i] = x[UKF_IMU + i]
    if x[UKF_LEVER] != 0.0:
        _correct_lever_arm(x, dt)
    k = int(x[UKF_K])
    row = k % buf.shape[0]
    buf[row, 0] = t
    buf[row, 1] = dt
    for i in range(6):
        buf[row, 2 + i] = x[UKF_IMU_C + i]
    propagate(x, UKF_S, x, UKF_RS, dt, x[UKF_G], x, UKF_IMU_C)
    for i in range(16):
        sbuf[row, i] = x[UKF_S + i]
    x[UKF_K] = k + 1
    return STEP_REJECTED if rejected else 0, t


@jit
def ukf_finish(mem, out) -> int:
    """End of a step: the outputs, and whether the delayed state must be advanced.

    Outputs: bias-corrected rate and acceleration, low-passed, and the estimate ``p_W, v_W, a_W, R_WB
    (row-major), omega_B`` into ``out`` (21,). The delayed fused state is advanced by the caller
    (``ukf_predict(mem, k - lag_n)``, as :func:`ukf_step` does) when motion capture has not come for too long;
    that does not change the outputs.

    Returns:
        ``STEP_DEGRADED`` when no motion-capture sample was accepted for longer than the timeout, plus
        ``STEP_ADVANCE`` when the delayed state lags by more than the latency plus one chunk.
    """
    return _finish(mem[0:UKF_SIZE], out)


@jit
def _finish(x, out) -> int:
    """:func:`ukf_finish` on the scalar part ``x`` of the memory."""
    code = 0
    if int(x[UKF_K]) - int(x[UKF_KF]) > int(x[UKF_LAG_N]) + int(x[UKF_CHUNK_N]):
        code = STEP_ADVANCE
    dt = x[UKF_DT]
    if dt != x[UKF_LPF_DT]:
        x[UKF_LPF_DT] = dt
        x[UKF_LAM_W] = lpf_gain(dt, x[UKF_GYRO_CUT])
        x[UKF_LAM_A] = lpf_gain(dt, x[UKF_ACC_CUT])
    lam_w, lam_a = x[UKF_LAM_W], x[UKF_LAM_A]
    S, R, C, g = UKF_S, UKF_RS, UKF_IMU_C, x[UKF_G]
    fx, fy, fz = x[C + 3] - x[S + 10], x[C + 4] - x[S + 11], x[C + 5] - x[S + 12]
    Wo, Ao = UKF_WO, UKF_AO
    x[Wo] += lam_w * (x[C] - x[S + 13] - x[Wo])
    x[Wo + 1] += lam_w * (x[C + 1] - x[S + 14] - x[Wo + 1])
    x[Wo + 2] += lam_w * (x[C + 2] - x[S + 15] - x[Wo + 2])
    x[Ao] += lam_a * (x[R] * fx + x[R + 1] * fy + x[R + 2] * fz - x[Ao])
    x[Ao + 1] += lam_a * (x[R + 3] * fx + x[R + 4] * fy + x[R + 5] * fz - x[Ao + 1])
    x[Ao + 2] += lam_a * (x[R + 6] * fx + x[R + 7] * fy + x[R + 8] * fz - g - x[Ao + 2])
    write_estimate(x, out)
    if x[UKF_T] - x[UKF_T_ACCEPT] > x[UKF_TIMEOUT]:
        code |= STEP_DEGRADED
    return code


@jit
def write_estimate(x, out) -> None:
    """The estimate ``p_W, v_W, a_W, R_WB, omega_B`` (21,) of the output state into ``out``."""
    for i in range(6):
        out[i] = x[UKF_S + i]
    for i in range(3):
        out[6 + i] = x[UKF_AO + i]
        out[18 + i] = x[UKF_WO + i]
    for i in range(9):
        out[9 + i] = x[UKF_RS + i]


# -- linear algebra and SO(3) on small arrays -------------------------------------------------------------------


@jit
def cholesky_lower(A, L) -> int:
    """Lower Cholesky factor of A into L (upper triangle zeroed).

    Returns:
        0, or the 1-based column where A is not positive definite (LAPACK dpotrf's ``info``).
    """
    n = A.shape[0]
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return j + 1
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
        for i in range(j):
            L[i, j] = 0.0
    return 0


@jit
def invert(A, out) -> bool:
    """Inverse of a small square matrix by Gauss-Jordan elimination with partial pivoting; False if singular.

    Allocates a copy of A; :func:`invert_in_place` does not.
    """
    return invert_in_place(A.copy(), out)


@jit
def invert_in_place(a, out) -> bool:
    """:func:`invert` that overwrites ``a`` (same arithmetic); the inverse into ``out``; False if singular."""
    n = a.shape[0]
    for i in range(n):
        for j in range(n):
            out[i, j] = 1.0 if i == j else 0.0
    for c in range(n):
        piv = c
        big = abs(a[c, c])
        for r in range(c + 1, n):
            if abs(a[r, c]) > big:
                big = abs(a[r, c])
                piv = r
        if big == 0.0 or big != big:
            return False
        if piv != c:
            for j in range(n):
                a[c, j], a[piv, j] = a[piv, j], a[c, j]
                out[c, j], out[piv, j] = out[piv, j], out[c, j]
        inv_p = 1.0 / a[c, c]
        for j in range(n):
            a[c, j] *= inv_p
            out[c, j] *= inv_p
        for r in range(n):
            if r != c:
                fct = a[r, c]
                if fct != 0.0:
                    for j in range(n):
                        a[r, j] -= fct * a[c, j]
                        out[r, j] -= fct * out[c, j]
    return True


@jit
def exp_so3_into(p0: float, p1: float, p2: float, R) -> None:
    """Rotation matrix of the rotation vector ``(p0, p1, p2)`` [rad] into C-contiguous R (3, 3); :func:`exp_so3_at`."""
    exp_so3_at(p0, p1, p2, R.reshape(9), 0)


@jit
def exp_so3_at(p0: float, p1: float, p2: float, out, o: int) -> None:
    """Rotation matrix of the rotation vector ``(p0, p1, p2)`` [rad] into ``out[o:o+9]``, row-major.

    Rodrigues, with series near 0: ``R = I + a K + b K²``, ``K = [phi]x``, ``a = sin(th)/th``,
    ``b = (1 - cos th)/th²``.
    """
    th2 = p0 * p0 + p1 * p1 + p2 * p2
    th = math.sqrt(th2)
    if th2 > 1e-8:  # below, the series to th² are exact in double precision
        a = math.sin(th) / th
        b = (1.0 - math.cos(th)) / th2
    else:
        a = 1.0 - th2 / 6.0
        b = 0.5 - th2 / 24.0
    # K = [[0, -p2, p1], [p2, 0, -p0], [-p1, p0, 0]]; R = (K K) b + K a + I, entry by entry.
    k01, k02, k10, k12, k20, k21 = -p2, p1, p2, -p0, -p1, p0
    out[o] = (0.0 * 0.0 + k01 * k10 + k02 * k20) * b + 0.0 * a + 1.0
    out[o + 1] = (0.0 * k01 + k01 * 0.0 + k02 * k21) * b + k01 * a
    out[o + 2] = (0.0 * k02 + k01 * k12 + k02 * 0.0) * b + k02 * a
    out[o + 3] = (k10 * 0.0 + 0.0 * k10 + k12 * k20) * b + k10 * a
    out[o + 4] = (k10 * k01 + 0.0 * 0.0 + k12 * k21) * b + 0.0 * a + 1.0
    out[o + 5] = (k10 * k02 + 0.0 * k12 + k12 * 0.0) * b + k12 * a
    out[o + 6] = (k20 * 0.0 + k21 * k10 + 0.0 * k20) * b + k20 * a
    out[o + 7] = (k20 * k01 + k21 * 0.0 + 0.0 * k21) * b + k21 * a
    out[o + 8] = (k20 * k02 + k21 * k12 + 0.0 * 0.0) * b + 0.0 * a + 1.0


@jit
def log_so3_into(R, out, o: int) -> None:
    """Rotation vector [rad] of a rotation R (3, 3), C-contiguous, into ``out[o:o+3]`` (:func:`log_so3_at`)."""
    log_so3_at(R.reshape(9), 0, out, o)


@jit
def log_so3_at(R, oR: int, out, o: int) -> None:
    """Rotation vector [rad] of the rotation ``R[oR:oR+9]`` (row-major) with angle below pi into ``out[o:o+3]``."""
    w0 = (R[oR + 7] - R[oR + 5]) * 0.5  # sin(th) * axis
    w1 = (R[oR + 2] - R[oR + 6]) * 0.5
    w2 = (R[oR + 3] - R[oR + 1]) * 0.5
    sn = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    th = math.atan2(sn, 0.5 * (R[oR] + R[oR + 4] + R[oR + 8] - 1.0))
    k = th / sn if sn > 1e-12 else 1.0
    out[o], out[o + 1], out[o + 2] = w0 * k, w1 * k, w2 * k


@jit
def _copy2(src, dst) -> None:
    """``dst[...] = src`` for 2-D arrays of one shape (an explicit loop compiles much faster than a slice copy)."""
    for i in range(src.shape[0]):
        for j in range(src.shape[1]):
            dst[i, j] = src[i, j]


@jit_inline
def _mul33_at(A, oA: int, B, oB: int, out, o: int) -> None:
    """``out[o:o+9] = A[oA:oA+9] B[oB:oB+9]``: 3 x 3 matrices, row-major (out must not overlap A or B)."""
    for i in range(3):
        a0, a1, a2 = A[oA + 3 * i], A[oA + 3 * i + 1], A[oA + 3 * i + 2]
        for j in range(3):
            out[o + 3 * i + j] = a0 * B[oB + j] + a1 * B[oB + 3 + j] + a2 * B[oB + 6 + j]


# -- unscented prediction --------------------------------------------------------------------------------------


@jit
def ukf_predict(mem, k_end: int) -> None:
    """Unscented prediction of the delayed fused state over the buffered samples [kf, k_end).

    The mean is the output state already propagated to sample ``k_end - 1`` (UKF-M); the covariance is the
    unscented transform of P through the motion model in steps of at most ``cov_n`` samples with the step's
    mean IMU reading, plus the additive process noise (see the estimator's module docstring). Its work arrays
    are in the workspace (``WP_*``).
    """
    x, buf, sbuf, P, W, M, wk = views(mem)
    _predict(x, buf, sbuf, P, W, M, wk, k_end)


@jit
def _predict(x, buf, sbuf, P, W, M, wk, k_end: int) -> None:
    """:func:`ukf_predict` on the parts of the memory (:func:`views`)."""
    kf = int(x[UKF_KF])
    if k_end <= kf:
        return
    n, S = N_ERR, N_SIGMA
    cap = buf.shape[0]
    cov_n = int(x[UKF_COV_N])
    g = x[UKF_G]
    # cholesky_lower writes all of L when it succeeds, and the last attempt (P0, positive diagonal) does.
    L = _work2(wk, WP_L, n, n)
    info = cholesky_lower(P, L)
    if info != 0:  # lost positive definiteness to rounding: symmetrise and add a little jitter
        Pj = _work2(wk, WP_PJ, n, n)
        for i in range(n):
            for j in range(n):
                Pj[i, j] = 0.5 * (P[i, j] + P[j, i]) + (1e-12 if i == j else 0.0)
        info = cholesky_lower(Pj, L)
        if info != 0:
            _copy2(M[M_P0], P)
            cholesky_lower(P, L)
    # Sigma-point offsets D (S, n): 0, +columns of L, -columns of L, scaled.
    scale = x[UKF_UT_SCALE]
    D = _work2(wk, WP_D, S, n)
    for i in range(n):
        D[0, i] = 0.0
    for j in range(n):
        for i in range(n):
            D[1 + j, i] = L[i, j] * scale
            D[1 + n + j, i] = -(L[i, j] * scale)
    F = UKF_F
    Ps = _work2(wk, WP_PS, S, 3)
    Vs = _work2(wk, WP_VS, S, 3)
    BA = _work2(wk, WP_BA, S, 3)
    BG = _work2(wk, WP_BG, S, 3)
    # The 3 x 3 matrices are row-major in wk (no per-point views): R_WB of sigma point s at WP_RS + 9 s.
    for s in range(S):
        for i in range(3):
            Ps[s, i] = x[F + i] + D[s, i]
            Vs[s, i] = x[F + 3 + i] + D[s, 3 + i]
            BA[s, i] = x[F + 10 + i] + D[s, 9 + i]
            BG[s, i] = x[F + 13 + i] + D[s, 12 + i]
        exp_so3_at(D[s, 6], D[s, 7], D[s, 8], wk, WP_ROT)
        _mul33_at(x, UKF_RF, wk, WP_ROT, wk, WP_RS + 9 * s)  # R_f exp(dtheta_s)
    # Covariance steps: duration and mean IMU reading [gyro (3), acc (3)] of each.
    T_total = 0.0
    m = wk[WP_M : WP_M + 6]
    a = wk[WP_A : WP_A + 3]
    k = kf
    while k < k_end:
        k1 = min(k_end, k + cov_n)
        T = 0.0
        for i in range(6):
            m[i] = 0.0
        for j in range(k, k1):
            dtj = buf[j % cap, 1]
            T += dtj
            for i in range(6):
                m[i] += buf[j % cap, 2 + i] * dtj
        for i in range(6):
            m[i] = m[i] / T
        half_T2 = 0.5 * T * T
        for s in range(S):
            r = WP_RS + 9 * s
            b0, b1, b2 = m[3] - BA[s, 0], m[4] - BA[s, 1], m[5] - BA[s, 2]
            for i in range(3):
                a[i] = wk[r + 3 * i] * b0 + wk[r + 3 * i + 1] * b1 + wk[r + 3 * i + 2] * b2
            a[2] -= g
            for i in range(3):
                Ps[s, i] += Vs[s, i] * T + a[i] * half_T2
                Vs[s, i] += a[i] * T
            exp_so3_at((m[0] - BG[s, 0]) * T, (m[1] - BG[s, 1]) * T, (m[2] - BG[s, 2]) * T, wk, WP_ROT)
            _mul33_at(wk, r, wk, WP_ROT, wk, WP_TMP)
            for i in range(9):
                wk[r + i] = wk[WP_TMP + i]
        T_total += T
        k = k1
    # Errors of the propagated sigma points relative to the first (the mean's) point.
    E = _work2(wk, WP_E, S, n)  # row s at wk[WP_E + n s]
    for i in range(3):
        for j in range(3):
            wk[WP_R0T + 3 * i + j] = wk[WP_RS + 3 * j + i]  # R_0ᵀ
    for s in range(S):
        for i in range(3):
            E[s, i] = Ps[s, i] - Ps[0, i]
            E[s, 3 + i] = Vs[s, i] - Vs[0, i]
        _mul33_at(wk, WP_R0T, wk, WP_RS + 9 * s, wk, WP_TMP)
        log_so3_at(wk, WP_TMP, wk, WP_E + n * s + 6)
        for i in range(9, 15):
            E[s, i] = D[s, i]
    wm, wc = W[0], W[1]
    mean = wk[WP_MEAN : WP_MEAN + n]
    for i in range(n):
        mean[i] = 0.0
    for s in range(S):
        for i in range(n):
            mean[i] += wm[s] * E[s, i]
    for s in range(S):
        for i in range(n):
            E[s, i] -= mean[i]
    # P = sum_s wc_s dE_s dE_sᵀ (one triangle, as rank-one updates: contiguous and independent), plus Q(T).
    for i in range(n):
        for j in range(n):
            P[i, j] = 0.0
    for s in range(S):
        w = wc[s]
        for i in range(n):
            c = E[s, i] * w
            for j in range(i, n):
                P[i, j] += c * E[s, j]
    T2 = T_total * T_total
    T3 = T_total * T_total * T_total
    for i in range(n):
        for j in range(i, n):
            q = M[M_Q1, i, j] * T_total
            q += M[M_Q2, i, j] * T2
            q += M[M_Q3, i, j] * T3
            P[i, j] += q
            P[j, i] = P[i, j]
    # The mean: the output state already propagated to sample k_end - 1.
    last = (k_end - 1) % cap
    for i in range(16):
        x[F + i] = sbuf[last, i]
    R9_from_quat_into(x[F + 6], x[F + 7], x[F + 8], x[F + 9], x, UKF_RF)
    x[UKF_T_F] = buf[last, 0]
    x[UKF_KF] = k_end


# -- motion-capture update -------------------------------------------------------------------------------------


@jit
def _q_mul(aw, ax, ay, az, bw, bx, by, bz):
    """Hamilton product ``a ⊗ b`` of wxyz quaternions."""
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@jit
def _repropagate(x, buf, sbuf) -> None:
    """Output state = fused state moved over the buffered samples after it (mean only)."""
    for i in range(16):
        x[UKF_S + i] = x[UKF_F + i]
    for i in range(9):
        x[UKF_RS + i] = x[UKF_RF + i]
    cap, width = buf.shape
    samples = buf.reshape(cap * width)  # flat: one view, not one per sample
    g = x[UKF_G]
    for k in range(int(x[UKF_KF]), int(x[UKF_K])):
        row = k % cap
        propagate(x, UKF_S, x, UKF_RS, buf[row, 1], g, samples, width * row + 2)
        for i in range(16):
            sbuf[row, i] = x[UKF_S + i]


@jit
def ukf_fuse_at(mem, t_m: float) -> int:
    """The buffered sample at which a pose taken at ``t_m`` [s] is fused (the nearest), or -1 if it is stale.

    A sample older than the fused state or the buffer, or from the future, is stale; one taken just before the
    start-up pose is fused at start-up. The caller then predicts the delayed state there
    (:func:`ukf_predict`) and updates it (:func:`ukf_fuse`).
    """
    x, buf, sbuf, P, W, M, wk = views(mem)
    return _fuse_at(x, buf, t_m)


@jit
def _fuse_at(x, buf, t_m: float) -> int:
    """:func:`ukf_fuse_at` on the parts of the memory (:func:`views`)."""
    t_now = x[UKF_T]
    half = 0.5 * x[UKF_DT_NOM]
    if t_m < x[UKF_T_F] - half and x[UKF_JUST_RESET] != 0.0:
        t_m = x[UKF_T_F]  # taken before the start-up pose: there is no earlier state, fuse it at start-up
    if t_m < x[UKF_T_F] - half or t_m > t_now + half or t_now - t_m > x[UKF_MAX_LAT] + half:
        return -1
    # The buffered samples up to t_m (nearest sample).
    cap = buf.shape[0]
    k_m = int(x[UKF_KF])
    k = int(x[UKF_K])
    while k_m < k and buf[k_m % cap, 0] <= t_m + half:
        k_m += 1
    return k_m


@jit
def ukf_fuse(mem, p_m, q_m) -> int:
    """Update the delayed state (already predicted to the sample's time) with a pose, re-propagate to now.

    Its work arrays are in the workspace (``WF_*``).

    Args:
        mem: the estimator's memory.
        p_m: (3,) measured position [m].
        q_m: (4,) measured attitude, wxyz (normalised here).

    Returns:
        ``FUSE_OK``, or why the sample was rejected (``FUSE_*``).
    """
    x, buf, sbuf, P, W, M, wk = views(mem)
    return _fuse(x, buf, sbuf, P, M, wk, p_m, q_m)


@jit
def _fuse(x, buf, sbuf, P, M, wk, p_m, q_m) -> int:
    """:func:`ukf_fuse` on the parts of the memory (:func:`views`)."""
    t_now = x[UKF_T]
    F = UKF_F
    qn = math.sqrt(q_m[0] * q_m[0] + q_m[1] * q_m[1] + q_m[2] * q_m[2] + q_m[3] * q_m[3])
    mw, mx, my, mz = q_m[0] / qn, q_m[1] / qn, q_m[2] / qn, q_m[3] / qn
    # Innovation in the error coordinates: (p_m - p, log(R_fᵀ R_m)).
    r = wk[WF_R : WF_R + N_MEAS]
    for i in range(3):
        r[i] = p_m[i] - x[F + i]
    ew, ex, ey, ez = _q_mul(x[F + 6], -x[F + 7], -x[F + 8], -x[F + 9], mw, mx, my, mz)
    if ew < 0.0:
        ew, ex, ey, ez = -ew, -ex, -ey, -ez
    nv = math.sqrt(ex * ex + ey * ey + ez * ez)
    kq = 2.0 * math.atan2(nv, ew) / nv if nv > 1e-12 else 2.0
    r[3], r[4], r[5] = kq * ex, kq * ey, kq * ez
    n = N_ERR
    PHt = _work2(wk, WF_PHT, n, N_MEAS)
    for i in range(n):
        for j in range(6):
            PHt[i, j] = P[i, _H_ROWS[j]]
    S_mat = _work2(wk, WF_S, N_MEAS, N_MEAS)
    for i in range(6):
        for j in range(6):
            S_mat[i, j] = PHt[_H_ROWS[i], j] + M[M_RN, i, j]
    S_inv = _work2(wk, WF_SINV, N_MEAS, N_MEAS)
    if not invert_in_place(S_mat, S_inv):
        return FUSE_SINGULAR
    d2 = 0.0
    for j in range(6):
        acc = 0.0
        for i in range(6):
            acc += r[i] * S_inv[i, j]
        d2 += acc * r[j]
    if not d2 <= x[UKF_GATE]:
        x[UKF_GATE_FAILS] += 1.0
        if x[UKF_GATE_FAILS] >= x[UKF_REINIT_AFTER]:
            # The filter is lost: take the motion-capture pose, keep velocity and biases, reset P.
            for i in range(3):
                x[F + i] = p_m[i]
            x[F + 6], x[F + 7], x[F + 8], x[F + 9] = mw, mx, my, mz
            R9_from_quat_into(mw, mx, my, mz, x, UKF_RF)
            _copy2(M[M_P0], P)
            x[UKF_GATE_FAILS] = 0.0
            x[UKF_T_ACCEPT] = t_now
            _repropagate(x, buf, sbuf)
            return FUSE_REINIT
        return FUSE_GATE
    x[UKF_GATE_FAILS] = 0.0
    K = _work2(wk, WF_K, n, N_MEAS)
    for i in range(n):
        for j in range(6):
            acc = 0.0
            for l in range(6):
                acc += PHt[i, l] * S_inv[l, j]
            K[i, j] = acc
    dx = wk[WF_DX : WF_DX + n]
    for i in range(n):
        acc = 0.0
        for j in range(6):
            acc += K[i, j] * r[j]
        dx[i] = acc
    Pn = _work2(wk, WF_PN, n, n)  # (I - K H) P
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for l in range(6):
                acc += K[i, l] * PHt[j, l]
            Pn[i, j] = P[i, j] - acc
    # Inject the error into the nominal state.
    for i in range(6):
        x[F + i] += dx[i]
    th = math.sqrt(dx[6] * dx[6] + dx[7] * dx[7] + dx[8] * dx[8])
    kq = math.sin(0.5 * th) / th if th > 1e-12 else 0.5
    qw, qx, qy, qz = _q_mul(
        x[F + 6], x[F + 7], x[F + 8], x[F + 9], math.cos(0.5 * th), kq * dx[6], kq * dx[7], kq * dx[8]
    )
    qn = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    x[F + 6], x[F + 7], x[F + 8], x[F + 9] = qw / qn, qx / qn, qy / qn, qz / qn
    R9_from_quat_into(x[F + 6], x[F + 7], x[F + 8], x[F + 9], x, UKF_RF)
    for i in range(9, 15):
        x[F + i + 1] += dx[i]
    # Reset: the attitude error is now relative to the corrected mean, P -> G P Gᵀ, G = I - [dtheta/2]x.
    # It changes P by a relative |dtheta|/2, so it is skipped for the usual sub-milliradian corrections.
    hx, hy, hz = 0.5 * dx[6], 0.5 * dx[7], 0.5 * dx[8]
    if hx * hx + hy * hy + hz * hz > _RESET_MIN_RAD2:
        Gt = _work2(wk, WF_GT, 3, 3)
        Gt[0, 0], Gt[0, 1], Gt[0, 2] = 1.0, hz, -hy
        Gt[1, 0], Gt[1, 1], Gt[1, 2] = -hz, 1.0, hx
        Gt[2, 0], Gt[2, 1], Gt[2, 2] = hy, -hx, 1.0
        rows = _work2(wk, WF_ROWS, 3, n)
        for i in range(3):
            for j in range(n):
                rows[i, j] = Gt[i, 0] * Pn[6, j] + Gt[i, 1] * Pn[7, j] + Gt[i, 2] * Pn[8, j]
        for i in range(3):
            for j in range(n):
                Pn[6 + i, j] = rows[i, j]
        cols = _work2(wk, WF_COLS, n, 3)
        for i in range(n):
            for j in range(3):
                cols[i, j] = Pn[i, 6] * Gt[j, 0] + Pn[i, 7] * Gt[j, 1] + Pn[i, 8] * Gt[j, 2]
        for i in range(n):
            for j in range(3):
                Pn[i, 6 + j] = cols[i, j]
    for i in range(n):
        for j in range(n):
            P[i, j] = (Pn[i, j] + Pn[j, i]) * 0.5
    x[UKF_T_ACCEPT] = t_now
    x[UKF_JUST_RESET] = 0.0
    _repropagate(x, buf, sbuf)
    return FUSE_OK


# -- the whole step ----------------------------------------------------------------------------------------------


@jit
def ukf_step(
    mem, gyro, acc, t_frame: float, mocap_new: bool, mocap_t: float, p_m, q_m, compensate_latency: bool, out, counters
) -> tuple:
    """The estimator's 1 kHz step once initialised (SPEC §4.5): IMU sample, motion-capture fusion, outputs.

    In order: :func:`ukf_imu_step`; with a motion-capture sample, its checks (finite ``mocap_t``, finite pose,
    quaternion norm within ``QUAT_NORM_TOL`` of 1), :func:`ukf_fuse_at` at ``mocap_t`` (or at the frame time
    without ``compensate_latency``), :func:`ukf_predict` there, :func:`ukf_fuse` and :func:`ukf_finish`;
    finally :func:`ukf_predict` to ``k - lag_n`` when the delayed fused state lags too far. The same
    arithmetic, in the same order, as calling those kernels one by one.

    Args:
        mem: the estimator's memory (float64, layout :func:`memory_layout`).
        gyro: (3,) gyro sample [rad/s], body frame (float64).
        acc: (3,) accelerometer sample [m/s²], body frame (float64).
        t_frame: frame time [s].
        mocap_new: a motion-capture sample arrived in this frame.
        mocap_t: time the sample was taken [s] (ignored without ``mocap_new``).
        p_m: (3,) measured position [m], world frame (float64; ignored without ``mocap_new``). A frame that
            announces a sample without a well-formed pose passes NaN here: it is rejected and counted.
        q_m: (4,) measured attitude, wxyz (float64; as ``p_m``).
        compensate_latency: fuse at ``mocap_t`` (True) or at the frame time (False).
        out: (21,) the estimate ``p_W, v_W, a_W, R_WB (row-major), omega_B`` (as :func:`write_estimate`).
        counters: (CNT_SIZE,) int64 counters and flags (``CNT_*``), updated.

    Returns:
        ``(code, t)``: ``STEP_REJECTED`` when something in the frame was rejected, plus ``STEP_DEGRADED``
        while degraded (the estimate is then not valid); the time of the estimate [s] (``t_frame``, or the
        previous time plus the nominal period when the frame's period was rejected).
    """
    x, buf, sbuf, P, W, M, wk = views(mem)  # once: the kernels below take the parts
    code, t = _imu_step(x, buf, sbuf, gyro, acc, t_frame)
    if not mocap_new:
        code |= _finish(x, out)
    rejected = (code & STEP_REJECTED) != 0
    if mocap_new:
        if math.isfinite(mocap_t) and mocap_sample_valid(p_m, q_m, QUAT_NORM_TOL):
            t_m = mocap_t if compensate_latency else t
            k_m = _fuse_at(x, buf, t_m)
            if k_m < 0:
                fused = FUSE_STALE
            else:
                _predict(x, buf, sbuf, P, W, M, wk, k_m)
                fused = _fuse(x, buf, sbuf, P, M, wk, p_m, q_m)
            if fused == FUSE_OK:
                counters[CNT_MOCAP_FUSED] += 1
            else:
                counters[CNT_REJECTED_MOCAP] += 1
                if fused == FUSE_REINIT:
                    counters[CNT_REINIT] += 1
                rejected = True
        else:
            counters[CNT_REJECTED_MOCAP] += 1
            rejected = True
        code = _finish(x, out)
    if code & STEP_ADVANCE:
        _predict(x, buf, sbuf, P, W, M, wk, int(x[UKF_K]) - int(x[UKF_LAG_N]))
    result = code & STEP_DEGRADED
    if rejected:
        counters[CNT_REJECTED_INPUTS] += 1
        result |= STEP_REJECTED
    counters[CNT_LAST_REJECTED] = 1 if rejected else 0
    counters[CNT_DEGRADED] = 1 if result & STEP_DEGRADED else 0
    return result, t


@jit
def ukf_reinit(mem, p_m, q_m, counters, out) -> None:
    """Re-initialise the pose from a motion-capture sample at the current time (after a time glitch or a dropout).

    The output and the delayed fused state both become the sample's pose at the time of the last step; the
    velocity and the biases are kept where finite (else zero), the covariance goes back to the initial one,
    the buffer of IMU samples is emptied and the estimate is no longer degraded. Called by the controller's
    frame supervision (:mod:`omnirotor.control.supervisor`).

    Args:
        mem: the estimator's memory.
        p_m: (3,) measured position [m] (finite).
        q_m: (4,) measured attitude, wxyz (finite, non-zero; normalised here).
        counters: (CNT_SIZE,) the counters; ``CNT_REINIT`` counts it.
        out: (21,) the estimate, rewritten.
    """
    x, buf, sbuf, P, W, M, wk = views(mem)
    S = UKF_S
    qn = math.sqrt(q_m[0] * q_m[0] + q_m[1] * q_m[1] + q_m[2] * q_m[2] + q_m[3] * q_m[3])
    for i in range(3):
        x[S + i] = p_m[i]
    for i in range(4):
        x[S + 6 + i] = q_m[i] / qn
    for i in range(3, 6):
        if not math.isfinite(x[S + i]):
            x[S + i] = 0.0
    for i in range(10, 16):
        if not math.isfinite(x[S + i]):
            x[S + i] = 0.0
    R9_from_quat_into(x[S + 6], x[S + 7], x[S + 8], x[S + 9], x, UKF_RS)
    for i in range(16):
        x[UKF_F + i] = x[S + i]
    for i in range(9):
        x[UKF_RF + i] = x[UKF_RS + i]
    x[UKF_T_F] = x[UKF_T]
    x[UKF_KF] = x[UKF_K]
    x[UKF_T_ACCEPT] = x[UKF_T]
    x[UKF_JUST_RESET] = 1.0
    x[UKF_GATE_FAILS] = 0.0
    _copy2(M[M_P0], P)
    counters[CNT_REINIT] += 1
    counters[CNT_DEGRADED] = 0
    write_estimate(x, out)
