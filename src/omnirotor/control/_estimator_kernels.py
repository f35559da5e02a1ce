"""Compiled kernels of the UKF state estimator (:class:`omnirotor.control.estimator.UKFEstimator`, SPEC §4.5).

The estimator's memory is two NumPy structured records whose fields the kernels read by name, its state
(:data:`UKF_DTYPE`) and its sized memory (:func:`memory_dtype`: the ring buffers and the scratch), so that a
step allocates nothing:

* ``ukf`` (1,) of :data:`UKF_DTYPE`: the output (current) and the delayed fused nominal states
  (:data:`NOMINAL_DTYPE`: ``p_W, v_W, q_WB, b_acc_B, b_gyro_B``) with their ``R_WB``, the IMU samples, the
  outputs, times and counters, the covariance ``P``, the unscented weights, the constant matrices (process
  noise terms ``Q1, Q2, Q3``, initial covariance ``P0``, measurement noise ``Rn``) and the parameters. A
  controller nests it as a field of its own state;
* the memory's ``imu_buf`` (cap,) of :data:`IMU_SAMPLE_DTYPE` and ``state_buf`` (cap,) of
  :data:`NOMINAL_DTYPE`: ring buffers of the IMU samples (lever-arm corrected) and of the output state after
  each (a controller nests the memory as its field ``ukf_memory``);
* the memory's ``work``, one :data:`WORK_DTYPE` record: the scratch arrays of :func:`predict` and
  :func:`fuse`. Its content means nothing between kernel calls: every kernel writes an entry before it reads it.

The model and the filter are described in the estimator's module docstring; these kernels implement them:

* :func:`imu_step`: one IMU sample (validation, lever arm, buffering, noise-free mean propagation) and
  :func:`finish`: the end of a step (the outputs);
* :func:`predict`: the unscented covariance prediction of the delayed fused state;
* :func:`fuse_at` and :func:`fuse`: where a delayed motion-capture sample belongs, and its update
  (closed-form Kalman update, error injection, reset Jacobian, re-propagation of the mean to now);
* :func:`ukf_step`: the estimator's whole 1 kHz step after initialisation in one call (the above in order,
  the motion-capture sample checks, the latency choice and the counters), for :meth:`UKFEstimator.step`
  and for the controller's compiled step; :func:`ukf_step_entry` the same from Python, on the two ``(1,)``
  arrays.

The arithmetic is written in the order of the Python float / NumPy code it replaced; where NumPy summed a
product with BLAS (sigma-point statistics, Cholesky, the 6 x 6 inverse) results agree within a rounding.
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor._jit import jit, jit_entry, jit_inline
from omnirotor.so3 import (
    R_from_quat_into,
    exp_so3_into,
    log_so3_into,
    quat_integrate_body_into,
    quat_mul,
    quat_of_rotvec,
)

N_ERR = 15
"""Error-state dimension: dp, dv, dtheta, db_a, db_g."""
N_SIGMA = 2 * N_ERR + 1
N_MEAS = 6
"""Dimension of the motion-capture measurement: position and attitude."""

_F8, _I8 = np.float64, np.int64
NOMINAL_DTYPE = np.dtype(
    [
        ("p_W", _F8, 3),  # position [m]
        ("v_W", _F8, 3),  # velocity [m/s]
        ("q_WB", _F8, 4),  # attitude, unit quaternion wxyz
        ("b_acc_B", _F8, 3),  # accelerometer bias [m/s²]
        ("b_gyro_B", _F8, 3),  # gyro bias [rad/s]
    ]
)
"""A nominal state of the filter."""

IMU_SAMPLE_DTYPE = np.dtype(
    [
        ("t", _F8),  # time of the sample [s]
        ("dt", _F8),  # its period [s]
        ("gyro_B", _F8, 3),  # rate [rad/s], lever-arm corrected sample
        ("acc_B", _F8, 3),  # specific force [m/s²]
    ]
)
"""One buffered IMU sample."""

UKF_DTYPE = np.dtype(
    [
        # states
        ("x_out", NOMINAL_DTYPE),  # output (current) nominal state
        ("R_WB_out", _F8, (3, 3)),  # its attitude as a matrix
        ("x_fused", NOMINAL_DTYPE),  # delayed fused state
        ("R_WB_fused", _F8, (3, 3)),
        ("gyro_B", _F8, 3),  # last good raw IMU sample [rad/s] ...
        ("acc_B", _F8, 3),  # ... [m/s²]
        ("gyro_corr_B", _F8, 3),  # the sample of this step, lever-arm corrected [rad/s] ...
        ("acc_corr_B", _F8, 3),  # ... [m/s²]
        ("gyro_lp_B", _F8, 3),  # low-passed gyro (for the lever arm's omega_dot) [rad/s]
        ("omega_dot_B", _F8, 3),  # its derivative [rad/s²]
        ("omega_B", _F8, 3),  # output rate [rad/s]
        ("a_W", _F8, 3),  # output acceleration (without gravity) [m/s²]
        ("t", _F8),  # time of the output state [s]
        ("t_fused", _F8),  # time of the fused state [s]
        ("t_accept", _F8),  # frame time of the last accepted motion-capture sample [s]
        ("lpf_dt", _F8),  # dt of the cached output-filter gains [s] (NaN: none yet)
        ("lam_omega", _F8),  # output-filter gains
        ("lam_acc", _F8),
        ("dt", _F8),  # period of the last IMU sample [s]
        ("k", _I8),  # IMU samples pushed so far
        ("k_fused", _I8),  # samples already in the fused state
        ("just_reset", _I8),  # 1 until a sample is fused after the start-up pose
        ("gate_fails", _I8),  # consecutive gate failures
        ("P", _F8, (N_ERR, N_ERR)),  # covariance of the error of the fused state
        # counters and flags
        ("n_mocap_fused", _I8),  # motion-capture samples fused
        ("n_rejected_mocap", _I8),  # rejected (invalid, stale, singular or outside the gate)
        ("n_reinit", _I8),  # re-initialisations from motion capture after repeated gate failures
        ("n_rejected_inputs", _I8),  # frames in which the period, the IMU or the motion-capture sample was rejected
        ("n_nonfinite", _I8),  # frames with a non-finite time, IMU sample or motion-capture sample
        ("last_rejected", _I8),  # 1 when something in the last frame was rejected
        ("degraded", _I8),  # 1 while no motion-capture sample was accepted for longer than the timeout
        # motion-capture noise matched to the innovations (adapt_mocap_noise)
        ("noise_var_pos", _F8),  # running estimate of the position noise variance per axis [m²]
        ("noise_var_att", _F8),  # ... of the attitude noise variance per axis [rad²]
        ("n_noise_adapted", _I8),  # motion-capture samples weighed with a raised noise
        ("noise_pos_std_max", _F8),  # largest position noise one sigma used [m]
        ("noise_att_std_max", _F8),  # largest attitude noise one sigma used [rad]
        ("noise_n", _I8),  # motion-capture samples the running noise estimates have taken in
        ("noise_var_pos_top", _F8),  # largest position noise variance used in this episode of raised noise [m²]
        ("noise_var_att_top", _F8),  # ... attitude [rad²]
        ("n_noise_discounts", _I8),  # times P was discounted for a raised noise
        # parameters
        ("g", _F8),  # gravity [m/s²]
        ("dt_nom", _F8),  # nominal IMU period [s]
        ("gyro_range", _F8),  # [rad/s]
        ("acc_range", _F8),  # [m/s²]
        ("r_imu_B", _F8, 3),  # IMU offset from the CoM [m]
        ("lever", _I8),  # 1 when the offset is not zero
        ("lever_cutoff_hz", _F8),
        ("gyro_cutoff_hz", _F8),
        ("acc_cutoff_hz", _F8),
        ("cov_n", _I8),  # samples per covariance step
        ("ut_scale", _F8),  # sqrt(n + lambda)
        ("max_latency_s", _F8),  # largest motion-capture latency
        ("gate_chi2", _F8),  # chi-square gate
        ("reinit_after", _I8),
        ("lag_n", _I8),  # samples the fused state may lag ...
        ("chunk_n", _I8),  # ... plus this many before it is advanced without motion capture
        ("timeout_s", _F8),  # motion-capture timeout
        ("compensate_latency", _I8),  # 1: fuse a sample at the time it was taken, 0: at its arrival
        ("w_mean", _F8, N_SIGMA),  # unscented weights of the mean ...
        ("w_cov", _F8, N_SIGMA),  # ... and of the covariance
        ("Q1", _F8, (N_ERR, N_ERR)),  # process noise Q(T) = T Q1 + T² Q2 + T³ Q3
        ("Q2", _F8, (N_ERR, N_ERR)),
        ("Q3", _F8, (N_ERR, N_ERR)),
        ("P0", _F8, (N_ERR, N_ERR)),  # initial covariance
        ("Rn", _F8, (N_MEAS, N_MEAS)),  # motion-capture noise in use: position [m²], attitude [rad²]
        ("adapt_noise", _I8),  # 1: raise Rn where the innovations show more noise than assumed
        ("adapt_alpha", _F8),  # weight of one sample in the running noise estimates
        ("adapt_on_ratio2", _F8),  # raised once the estimate exceeds this many times the assumed variance ...
        ("adapt_off_ratio2", _F8),  # ... and back to the assumed once it falls below this many times it ...
        ("adapt_clip_ratio2", _F8),  # ... one sample counting at most this many times the variance in use ...
        ("adapt_max_ratio2", _F8),  # ... and never above this many times the assumed variance
        ("adapt_prior_n", _F8),  # the estimates start at the assumed variance, worth this many samples
        ("var_pos_assumed", _F8),  # assumed position noise variance per axis [m²]
        ("var_att_assumed", _F8),  # assumed attitude noise variance per axis [rad²]
        # sustained faults (issue 26): coasting, drifting biases, biases beyond the documented range
        ("coasting", _I8),  # 1: this step's IMU sample is the frame supervision's prediction (set by the caller)
        ("q_coast", _F8),  # white acceleration noise added while coasting [m²/s³]
        ("innov_ema_W", _F8, 3),  # running mean of the position innovations [m]
        ("drift_m", _F8),  # its threshold ...
        ("drift_scale2", _F8),  # ... and the factor on the bias random walks' variances above it
        ("drift_on", _I8),  # 1: the biases drift (random walks scaled)
        ("n_drift", _I8),  # motion-capture samples fused with the bias walks scaled
        ("acc_bias_range", _F8),  # [m/s²]
        ("gyro_bias_range", _F8),  # [rad/s]
    ]
)
"""State, counters and parameters of the UKF (named fields; the kernels read them so)."""

WORK_DTYPE = np.dtype(
    [
        # predict
        ("L", _F8, (N_ERR, N_ERR)),  # lower Cholesky factor of P
        ("P_jit", _F8, (N_ERR, N_ERR)),  # P symmetrised, with jitter on the diagonal (P lost definiteness)
        ("sigma_d", _F8, (N_SIGMA, N_ERR)),  # sigma-point offsets in the error coordinates
        ("sigma_p_W", _F8, (N_SIGMA, 3)),  # sigma points' p_W [m]
        ("sigma_v_W", _F8, (N_SIGMA, 3)),  # their v_W [m/s]
        ("sigma_b_acc_B", _F8, (N_SIGMA, 3)),  # their b_acc_B [m/s²]
        ("sigma_b_gyro_B", _F8, (N_SIGMA, 3)),  # their b_gyro_B [rad/s]
        ("sigma_R_WB", _F8, (N_SIGMA, 3, 3)),  # their R_WB
        ("rot", _F8, (3, 3)),  # rotation of a sigma-point offset or of one covariance step
        ("tmp", _F8, (3, 3)),  # product of two rotations
        ("R0_T", _F8, (3, 3)),  # transpose of the first sigma point's R_WB
        ("gyro_mean_B", _F8, 3),  # mean IMU reading of a covariance step [rad/s] ...
        ("acc_mean_B", _F8, 3),  # ... [m/s²]
        ("a_W", _F8, 3),  # a_W of a sigma point [m/s²]
        ("err", _F8, (N_SIGMA, N_ERR)),  # errors of the propagated sigma points
        ("err_mean", _F8, N_ERR),  # their weighted mean
        # fuse
        ("innov", _F8, N_MEAS),  # innovation: position [m], rotation vector [rad]
        ("PHt", _F8, (N_ERR, N_MEAS)),  # P Hᵀ
        ("S", _F8, (N_MEAS, N_MEAS)),  # innovation covariance (inverted in place)
        ("S_inv", _F8, (N_MEAS, N_MEAS)),  # its inverse
        ("K", _F8, (N_ERR, N_MEAS)),  # Kalman gain
        ("dx", _F8, N_ERR),  # error-state correction
        ("Pn", _F8, (N_ERR, N_ERR)),  # updated covariance (I - K H) P
        ("Gt", _F8, (3, 3)),  # reset Jacobian's attitude block
        ("Gt_rows", _F8, (3, N_ERR)),  # its product with the attitude rows of Pn
        ("Gt_cols", _F8, (N_ERR, 3)),  # and with the attitude columns
    ]
)
"""Scratch of the kernels (named fields)."""


def memory_dtype(cap: int) -> np.dtype:
    """The UKF's sized memory: ring buffers of ``cap`` samples and the scratch (module docstring)."""
    return np.dtype([("imu_buf", IMU_SAMPLE_DTYPE, (cap,)), ("state_buf", NOMINAL_DTYPE, (cap,)), ("work", WORK_DTYPE)])


# Bits of the code imu_step and finish return.
STEP_REJECTED = 1  # the period or the IMU sample was rejected
STEP_DEGRADED = 2  # no motion-capture sample accepted for longer than the timeout
STEP_NOISE_RAISED = 4  # motion capture is weighed with more noise than assumed (match_noise)
STEP_MOCAP_REJECTED = 8  # a well-formed motion-capture sample was not fused (outside the gate, too late, singular)
STEP_ADVANCE = 4  # the delayed fused state lags too far: advance it (predict to k - lag_n)
STEP_BIAS_RANGE = 16  # a bias estimate is beyond the documented range

QUAT_NORM_TOL = 0.1
"""A motion-capture quaternion whose norm is off 1 by more than this is rejected."""

# Return codes of fuse.
FUSE_OK = 0
FUSE_STALE = 1  # older than the fused state or the buffer, or from the future
FUSE_SINGULAR = 2  # innovation covariance not invertible
FUSE_GATE = 3  # outside the chi-square gate
FUSE_REINIT = 4  # outside the gate once too often: the pose was re-initialised from motion capture

_RESET_MIN_RAD2 = (0.5e-3) ** 2  # squared half attitude correction [rad²] above which P is reset-transported

_H_ROWS = (0, 1, 2, 6, 7, 8)
"""The error coordinates the motion-capture pose measures (dp, dtheta): rows of H, in measurement order."""


@jit
def lpf_gain(dt: float, cutoff_hz: float) -> float:
    """Gain ``lam`` of the discrete first-order filter ``y += lam (x - y)`` (SPEC §4.3); 1 when off."""
    if cutoff_hz <= 0.0:
        return 1.0
    k = 2.0 * math.pi * dt * cutoff_hz
    return k / (k + 1.0)


@jit
def copy_nominal(src, dst) -> None:
    """``dst`` = ``src`` (:data:`NOMINAL_DTYPE` records)."""
    for i in range(3):
        dst.p_W[i] = src.p_W[i]
        dst.v_W[i] = src.v_W[i]
        dst.b_acc_B[i] = src.b_acc_B[i]
        dst.b_gyro_B[i] = src.b_gyro_B[i]
    for i in range(4):
        dst.q_WB[i] = src.q_WB[i]


@jit
def propagate(s, R, dt: float, g: float, gyro, acc) -> None:
    """One IMU sample ``gyro`` [rad/s], ``acc`` [m/s²] (3,) on the nominal state ``s``, in place; ``R`` = ``R_WB(q)``.

    The sample is lever-arm corrected; see the estimator's model.
    """
    ba, bg, p, v, q = s.b_acc_B, s.b_gyro_B, s.p_W, s.v_W, s.q_WB
    fx, fy, fz = acc[0] - ba[0], acc[1] - ba[1], acc[2] - ba[2]
    ax = R[0, 0] * fx + R[0, 1] * fy + R[0, 2] * fz
    ay = R[1, 0] * fx + R[1, 1] * fy + R[1, 2] * fz
    az = R[2, 0] * fx + R[2, 1] * fy + R[2, 2] * fz - g
    h = 0.5 * dt * dt
    p[0] += v[0] * dt + ax * h
    p[1] += v[1] * dt + ay * h
    p[2] += v[2] * dt + az * h
    v[0] += ax * dt
    v[1] += ay * dt
    v[2] += az * dt
    quat_integrate_body_into(q, (gyro[0] - bg[0]) * dt, (gyro[1] - bg[1]) * dt, (gyro[2] - bg[2]) * dt)
    R_from_quat_into(q, R)


@jit
def _correct_lever_arm(u, dt: float) -> None:
    """Remove ``omega x (omega x r) + omega_dot x r`` from the accelerometer sample ``u.acc_corr_B``."""
    r = u.r_imu_B
    r0, r1, r2 = r[0], r[1], r[2]
    lam = lpf_gain(dt, u.lever_cutoff_hz)
    lp, wd = u.gyro_lp_B, u.omega_dot_B
    for i in range(3):  # low-pass the gyro sample, differentiate
        new = lp[i] + lam * (u.gyro_corr_B[i] - lp[i])
        wd[i] = (new - lp[i]) / dt
        lp[i] = new
    wd0, wd1, wd2 = wd[0], wd[1], wd[2]
    w, bg, a = u.gyro_corr_B, u.x_out.b_gyro_B, u.acc_corr_B
    wx, wy, wz = w[0] - bg[0], w[1] - bg[1], w[2] - bg[2]
    cx, cy, cz = wy * r2 - wz * r1, wz * r0 - wx * r2, wx * r1 - wy * r0  # omega x r
    a[0] -= wy * cz - wz * cy + wd1 * r2 - wd2 * r1
    a[1] -= wz * cx - wx * cz + wd2 * r0 - wd0 * r2
    a[2] -= wx * cy - wy * cx + wd0 * r1 - wd1 * r0


@jit_entry
def mocap_sample_valid(p, q, tol: float) -> bool:
    """Finite position and quaternion, the quaternion's norm within ``tol`` of 1."""
    if not (math.isfinite(p[0] + p[1] + p[2]) and math.isfinite(q[0] + q[1] + q[2] + q[3])):
        return False
    return abs(math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) - 1.0) <= tol


@jit_entry
def imu_valid(u, gyro, acc) -> bool:
    """A finite sample within the sensor ranges of the UKF record ``u``."""
    sg, sa = gyro[0] + gyro[1] + gyro[2], acc[0] + acc[1] + acc[2]
    if not (math.isfinite(sg) and math.isfinite(sa)):
        return False
    gr, ar = u.gyro_range, u.acc_range
    return max(abs(gyro[0]), abs(gyro[1]), abs(gyro[2])) <= gr and max(abs(acc[0]), abs(acc[1]), abs(acc[2])) <= ar


@jit
def imu_step(u, buf, sbuf, gyro, acc, t_frame: float) -> tuple:
    """One IMU sample: period and sample validation, lever arm, buffering, mean propagation.

    An invalid period (not finite, not increasing) is replaced by the nominal one, an invalid sample by the
    last good one. The step ends with :func:`finish` (after the motion-capture update, if any).

    Args:
        u: the UKF record (:data:`UKF_DTYPE`).
        buf: (cap,) the IMU ring buffer.
        sbuf: (cap,) the ring buffer of output states.
        gyro: (3,) gyro sample [rad/s], body frame.
        acc: (3,) accelerometer sample [m/s²], body frame.
        t_frame: frame time [s].

    Returns:
        ``(code, t)``: ``STEP_REJECTED`` when the period or the sample was rejected; the time of the estimate [s].
    """
    rejected = False
    dt = t_frame - u.t
    if not (dt > 0.0 and math.isfinite(dt)):
        dt = u.dt_nom
        rejected = True
    t = u.t + dt
    u.t = t
    u.dt = dt
    if imu_valid(u, gyro[:], acc[:]):  # [:]: as arrays, the types of the check called from Python
        for i in range(3):
            u.gyro_B[i] = gyro[i]
            u.acc_B[i] = acc[i]
        if u.coasting != 0:  # the frame supervision's prediction is bias-free: the biases are added back
            for i in range(3):
                u.gyro_B[i] += u.x_out.b_gyro_B[i]
                u.acc_B[i] += u.x_out.b_acc_B[i]
    else:
        rejected = True
    for i in range(3):
        u.gyro_corr_B[i] = u.gyro_B[i]
        u.acc_corr_B[i] = u.acc_B[i]
    if u.lever != 0:
        _correct_lever_arm(u, dt)
    k = u.k
    sample = buf[k % buf.shape[0]]
    sample.t = t
    sample.dt = dt
    for i in range(3):
        sample.gyro_B[i] = u.gyro_corr_B[i]
        sample.acc_B[i] = u.acc_corr_B[i]
    propagate(u.x_out, u.R_WB_out, dt, u.g, u.gyro_corr_B, u.acc_corr_B)
    copy_nominal(u.x_out, sbuf[k % sbuf.shape[0]])
    u.k = k + 1
    return STEP_REJECTED if rejected else 0, t


@jit
def finish(u, out) -> int:
    """End of a step: the outputs, and whether the delayed state must be advanced.

    Outputs: bias-corrected rate and acceleration, low-passed, and the estimate ``p_W, v_W, a_W, R_WB
    (row-major), omega_B`` into the estimate record ``out``. The delayed fused state is advanced by the caller
    (``predict(..., k - lag_n)``, as :func:`ukf_step` does) when motion capture has not come for too long;
    that does not change the outputs.

    Returns:
        ``STEP_DEGRADED`` when no motion-capture sample was accepted for longer than the timeout, plus
        ``STEP_ADVANCE`` when the delayed state lags by more than the latency plus one chunk.
    """
    code = 0
    if u.k - u.k_fused > u.lag_n + u.chunk_n:
        code = STEP_ADVANCE
    dt = u.dt
    if dt != u.lpf_dt:
        u.lpf_dt = dt
        u.lam_omega = lpf_gain(dt, u.gyro_cutoff_hz)
        u.lam_acc = lpf_gain(dt, u.acc_cutoff_hz)
    lam_w, lam_a = u.lam_omega, u.lam_acc
    s, R, g = u.x_out, u.R_WB_out, u.g
    w, a, ba, bg = u.gyro_corr_B, u.acc_corr_B, s.b_acc_B, s.b_gyro_B
    fx, fy, fz = a[0] - ba[0], a[1] - ba[1], a[2] - ba[2]
    wo, ao = u.omega_B, u.a_W
    wo[0] += lam_w * (w[0] - bg[0] - wo[0])
    wo[1] += lam_w * (w[1] - bg[1] - wo[1])
    wo[2] += lam_w * (w[2] - bg[2] - wo[2])
    ao[0] += lam_a * (R[0, 0] * fx + R[0, 1] * fy + R[0, 2] * fz - ao[0])
    ao[1] += lam_a * (R[1, 0] * fx + R[1, 1] * fy + R[1, 2] * fz - ao[1])
    ao[2] += lam_a * (R[2, 0] * fx + R[2, 1] * fy + R[2, 2] * fz - g - ao[2])
    write_estimate(u, out)
    if u.t - u.t_accept > u.timeout_s:
        code |= STEP_DEGRADED
    return code


@jit
def write_estimate(u, out) -> None:
    """The estimate of the output state into the estimate record ``out`` (:data:`~omnirotor.messages.ESTIMATE_DTYPE`).

    Its ``valid`` flag is the caller's (the step's code says whether the filter is degraded).
    """
    s = u.x_out
    for i in range(3):
        out.p_W[i] = s.p_W[i]
        out.v_W[i] = s.v_W[i]
        out.a_W[i] = u.a_W[i]
        out.omega_B[i] = u.omega_B[i]
    for i in range(3):
        for j in range(3):
            out.R_WB[i, j] = u.R_WB_out[i, j]


@jit_entry
def write_estimate_into(state, out) -> None:
    """:func:`write_estimate` of the ``(1,)`` UKF state into the ``(1,)`` estimate array ``out`` (from Python)."""
    write_estimate(state[0], out[0])


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


@jit_inline
def _copy2(src, dst) -> None:
    """``dst[...] = src`` for 2-D arrays of one shape (an explicit loop compiles much faster than a slice copy).

    Records' fields and arrays alike reach one compiled :func:`_copy2_arrays` (numba types a field by its shape;
    ``[:]`` is an array), and so for :func:`_mul33`.
    """
    _copy2_arrays(src[:], dst[:])


@jit
def _copy2_arrays(src, dst) -> None:
    for i in range(src.shape[0]):
        for j in range(src.shape[1]):
            dst[i, j] = src[i, j]


@jit_inline
def _mul33(A, B, out) -> None:
    """``out = A B`` for 3 x 3 matrices (out must not overlap A or B)."""
    _mul33_arrays(A[:], B[:], out[:])


@jit
def _mul33_arrays(A, B, out) -> None:
    for i in range(3):
        a0, a1, a2 = A[i, 0], A[i, 1], A[i, 2]
        for j in range(3):
            out[i, j] = a0 * B[0, j] + a1 * B[1, j] + a2 * B[2, j]


# -- unscented prediction --------------------------------------------------------------------------------------


@jit
def predict(u, buf, sbuf, w, k_end: int) -> None:
    """Unscented prediction of the delayed fused state over the buffered samples [k_fused, k_end).

    The mean is the output state already propagated to sample ``k_end - 1`` (UKF-M); the covariance is the
    unscented transform of P through the motion model in steps of at most ``cov_n`` samples with the step's
    mean IMU reading, plus the additive process noise (see the estimator's module docstring).

    Args:
        u: the UKF record.
        buf: (cap,) the IMU ring buffer.
        sbuf: (cap,) the ring buffer of output states.
        w: the scratch record (:data:`WORK_DTYPE`).
        k_end: the sample to predict to (exclusive).
    """
    kf = u.k_fused
    if k_end <= kf:
        return
    n, S = N_ERR, N_SIGMA
    cap = buf.shape[0]
    cov_n = u.cov_n
    g = u.g
    P = u.P
    # cholesky_lower writes all of L when it succeeds, and the last attempt (P0, positive diagonal) does.
    L = w.L
    info = cholesky_lower(P, L)
    if info != 0:  # lost positive definiteness to rounding: symmetrise and add a little jitter
        Pj = w.P_jit
        for i in range(n):
            for j in range(n):
                Pj[i, j] = 0.5 * (P[i, j] + P[j, i]) + (1e-12 if i == j else 0.0)
        info = cholesky_lower(Pj, L)
        if info != 0:
            _copy2(u.P0, P)
            cholesky_lower(P, L)
    # Sigma-point offsets D (S, n): 0, +columns of L, -columns of L, scaled.
    scale = u.ut_scale
    D = w.sigma_d
    for i in range(n):
        D[0, i] = 0.0
    for j in range(n):
        for i in range(n):
            D[1 + j, i] = L[i, j] * scale
            D[1 + n + j, i] = -(L[i, j] * scale)
    f = u.x_fused
    Ps, Vs, BA, BG, Rs = w.sigma_p_W, w.sigma_v_W, w.sigma_b_acc_B, w.sigma_b_gyro_B, w.sigma_R_WB
    rot, tmp = w.rot, w.tmp
    for s in range(S):
        for i in range(3):
            Ps[s, i] = f.p_W[i] + D[s, i]
            Vs[s, i] = f.v_W[i] + D[s, 3 + i]
            BA[s, i] = f.b_acc_B[i] + D[s, 9 + i]
            BG[s, i] = f.b_gyro_B[i] + D[s, 12 + i]
        exp_so3_into(D[s, 6], D[s, 7], D[s, 8], rot)
        _mul33(u.R_WB_fused, rot, Rs[s])  # R_f exp(dtheta_s)
    # Covariance steps: duration and mean IMU reading of each.
    T_total = 0.0
    mg, ma, a = w.gyro_mean_B, w.acc_mean_B, w.a_W
    k = kf
    while k < k_end:
        k1 = min(k_end, k + cov_n)
        T = 0.0
        for i in range(3):
            mg[i] = 0.0
            ma[i] = 0.0
        for j in range(k, k1):
            sample = buf[j % cap]
            dtj = sample.dt
            T += dtj
            for i in range(3):
                mg[i] += sample.gyro_B[i] * dtj
            for i in range(3):
                ma[i] += sample.acc_B[i] * dtj
        for i in range(3):
            mg[i] = mg[i] / T
            ma[i] = ma[i] / T
        half_T2 = 0.5 * T * T
        for s in range(S):
            R = Rs[s]
            b0, b1, b2 = ma[0] - BA[s, 0], ma[1] - BA[s, 1], ma[2] - BA[s, 2]
            for i in range(3):
                a[i] = R[i, 0] * b0 + R[i, 1] * b1 + R[i, 2] * b2
            a[2] -= g
            for i in range(3):
                Ps[s, i] += Vs[s, i] * T + a[i] * half_T2
                Vs[s, i] += a[i] * T
            exp_so3_into((mg[0] - BG[s, 0]) * T, (mg[1] - BG[s, 1]) * T, (mg[2] - BG[s, 2]) * T, rot)
            _mul33(R, rot, tmp)
            _copy2(tmp, R)
        T_total += T
        k = k1
    # Errors of the propagated sigma points relative to the first (the mean's) point.
    E = w.err
    R0_T = w.R0_T
    for i in range(3):
        for j in range(3):
            R0_T[i, j] = Rs[0][j, i]
    for s in range(S):
        for i in range(3):
            E[s, i] = Ps[s, i] - Ps[0, i]
            E[s, 3 + i] = Vs[s, i] - Vs[0, i]
        _mul33(R0_T, Rs[s], tmp)
        log_so3_into(tmp, E[s], 6)
        for i in range(9, 15):
            E[s, i] = D[s, i]
    wm, wc = u.w_mean, u.w_cov
    mean = w.err_mean
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
        ws = wc[s]
        for i in range(n):
            c = E[s, i] * ws
            for j in range(i, n):
                P[i, j] += c * E[s, j]
    T2 = T_total * T_total
    T3 = T_total * T_total * T_total
    Q1, Q2, Q3 = u.Q1, u.Q2, u.Q3
    for i in range(n):
        for j in range(i, n):
            q = Q1[i, j] * T_total
            q += Q2[i, j] * T2
            q += Q3[i, j] * T3
            P[i, j] += q
            P[j, i] = P[i, j]
    _extra_process_noise(u, P, T_total)
    # The mean: the output state already propagated to sample k_end - 1.
    last = (k_end - 1) % cap
    copy_nominal(sbuf[last], f)
    R_from_quat_into(f.q_WB, u.R_WB_fused)
    u.t_fused = buf[last].t
    u.k_fused = k_end


@jit
def _extra_process_noise(u, P, T: float) -> None:
    """Process noise beyond the model's, over ``T`` seconds (none in a run without sustained faults).

    While coasting, white acceleration noise ``q_coast`` (velocity ``q T``, position ``q T³ / 3``, cross ``q T² /
    2``); while the biases drift, their random walks' variances ``drift_scale2`` times the model's.
    """
    if u.coasting != 0:
        q = u.q_coast
        for i in range(3):
            P[i, i] += q * T * T * T / 3.0
            P[3 + i, 3 + i] += q * T
            P[i, 3 + i] += q * T * T / 2.0
            P[3 + i, i] = P[i, 3 + i]
    if u.drift_on != 0 and u.coasting == 0:
        c = (u.drift_scale2 - 1.0) * T
        for i in range(9, 15):
            P[i, i] += c * u.Q1[i, i]


@jit
def _track_drift(u, r) -> None:
    """The running mean of the position innovations ``r[:3]`` (about 10 samples) against the drift threshold.

    Not while coasting: the innovations then say how the unmeasured acceleration went, not how the biases did.
    """
    if u.coasting != 0:
        return
    e2 = 0.0
    for i in range(3):
        u.innov_ema_W[i] += 0.1 * (r[i] - u.innov_ema_W[i])
        e2 += u.innov_ema_W[i] * u.innov_ema_W[i]
    threshold = max(u.drift_m, 1.15 * math.sqrt(u.Rn[0, 0]))  # 5 sigma of the running mean of white noise
    e = math.sqrt(e2)
    if e > threshold:
        u.drift_on = 1
    elif e < 0.5 * threshold:
        u.drift_on = 0
    if u.drift_on != 0:
        u.n_drift += 1


@jit
def bias_beyond_range(u) -> bool:
    """Whether a bias estimate of the output state is beyond the documented range (a component)."""
    ba, bg = u.x_out.b_acc_B, u.x_out.b_gyro_B
    for i in range(3):
        if not (abs(ba[i]) <= u.acc_bias_range and abs(bg[i]) <= u.gyro_bias_range):
            return True
    return False


# -- motion-capture update -------------------------------------------------------------------------------------


@jit
def _repropagate(u, buf, sbuf) -> None:
    """Output state = fused state moved over the buffered samples after it (mean only)."""
    copy_nominal(u.x_fused, u.x_out)
    _copy2(u.R_WB_fused, u.R_WB_out)
    cap = buf.shape[0]
    g = u.g
    for k in range(u.k_fused, u.k):
        sample = buf[k % cap]
        propagate(u.x_out, u.R_WB_out, sample.dt, g, sample.gyro_B, sample.acc_B)
        copy_nominal(u.x_out, sbuf[k % cap])


@jit
def fuse_at(u, buf, t_m: float) -> int:
    """The buffered sample at which a pose taken at ``t_m`` [s] is fused (the nearest), or -1 if it is stale.

    A sample older than the fused state or the buffer, or from the future, is stale; one taken just before the
    start-up pose is fused at start-up. The caller then predicts the delayed state there (:func:`predict`)
    and updates it (:func:`fuse`).
    """
    t_now = u.t
    half = 0.5 * u.dt_nom
    if t_m < u.t_fused - half and u.just_reset != 0:
        t_m = u.t_fused  # taken before the start-up pose: there is no earlier state, fuse it at start-up
    if t_m < u.t_fused - half or t_m > t_now + half or t_now - t_m > u.max_latency_s + half:
        return -1
    # The buffered samples up to t_m (nearest sample).
    cap = buf.shape[0]
    k_m = u.k_fused
    k = u.k
    while k_m < k and buf[k_m % cap].t <= t_m + half:
        k_m += 1
    return k_m


@jit
def _matched_variance(u, r, o: int, est: float, assumed: float) -> float:
    """One block of :func:`match_noise`: the updated running estimate; writes the block's variance into ``Rn``."""
    P = u.P
    excess = 0.0  # the innovation's square beyond what the state's own uncertainty explains, per axis
    for i in range(3):
        excess += r[o + i] * r[o + i] - P[_H_ROWS[o + i], _H_ROWS[o + i]]
    in_use = u.Rn[o, o]
    # The weight of this sample: the plain mean of the samples so far and of adapt_prior_n samples at the assumed
    # variance (the estimate's start), until that is less than adapt_alpha (the running average's).
    weight = max(u.adapt_alpha, 1.0 / (u.adapt_prior_n + u.noise_n))
    # clipped to [0, adapt_clip_ratio2 * in_use]: a state less certain than its P says (just re-initialised)
    # proves nothing about the noise, and one outlier must not move the estimate far
    est += weight * (min(max(excess / 3.0, 0.0), u.adapt_clip_ratio2 * in_use) - est)
    # raised above adapt_on_ratio2 times the assumed variance, back to it below adapt_off_ratio2 (hysteresis: a
    # noise about the threshold is matched, not switched on and off)
    threshold = u.adapt_on_ratio2 if in_use == assumed else u.adapt_off_ratio2
    var = assumed
    if est > threshold * assumed:
        var = min(est, u.adapt_max_ratio2 * assumed)
    for i in range(3):
        u.Rn[o + i, o + i] = var
    return est


@jit
def noise_raised(u) -> bool:
    """True while :func:`match_noise` weighs motion capture as noisier than assumed (in either block)."""
    return u.Rn[0, 0] != u.var_pos_assumed or u.Rn[3, 3] != u.var_att_assumed


@jit
def discount_covariance(P, P0, c: float) -> None:
    """Discount the confidence in ``P`` (15, 15) for a noise ``c`` > 1 times larger than it was built with, in place.

    Each error coordinate's variance is multiplied by ``d_i = min(c, P0_ii / P_ii)`` (at least 1): what the filter
    learnt from samples it thought ``c`` times less noisy is worth ``c`` times less (a measurement-dominated
    covariance scales with the measurement noise), but it is never less certain than at start-up (``P0``). The
    correlations are kept: ``P <- D P D`` with ``D = diag(sqrt(d))``, which keeps ``P`` positive semi-definite.
    """
    n = P.shape[0]
    for i in range(n):
        d = 1.0
        if P[i, i] > 0.0:
            d = max(1.0, min(c, P0[i, i] / P[i, i]))
        s = math.sqrt(d)
        for j in range(n):
            P[i, j] *= s
            P[j, i] *= s


@jit
def match_noise(u, r) -> None:
    """Match the motion-capture noise to the innovations (covariance matching, per block; SPEC §4.5 [A]).

    A filter that assumes less noise than its motion capture has gates out most samples, re-initialises from
    single noisy ones and corrupts its bias estimates: 10 mm of noise against 1 mm assumed flew a hover tens of
    metres away. So the variance the innovation ``r`` shows beyond the state's own uncertainty, ``(|r|² -
    tr(H P Hᵀ)) / 3`` per axis, is averaged over the samples (before the gate: a gated sample is evidence too),
    each sample counting at most ``adapt_clip_ratio2`` times the variance in use so that single outliers barely
    move it. The average starts as ``adapt_prior_n`` samples at the assumed variance and is a plain mean until
    its weight falls to ``adapt_alpha`` (then a running average): a wrong noise is found within a few samples,
    before the filter has fitted its velocity and biases to it. Where the average
    exceeds ``adapt_on_ratio2`` times the assumed variance it replaces the assumed one in ``Rn`` (at most
    ``adapt_max_ratio2`` times it), so the gate and the update of this sample already use it, until it falls
    below ``adapt_off_ratio2`` times the assumed (hysteresis); never raised, ``Rn`` is the assumed noise, so a
    filter whose noise is as assumed (or less) runs exactly as without this.

    Whenever the noise in use rises above the largest used so far in the episode (of raised noise), by a factor
    ``c`` (the larger of the two blocks'), the covariance is discounted by ``c`` (:func:`discount_covariance`):
    the confidence built on samples thought less noisy is unfounded. A rule without a threshold: the discount
    follows the noise however far it is raised, and the noise's fluctuations about its level do not repeat it.
    """
    u.noise_n += 1
    # np.int64(...): an int64, not a literal (numba compiles a callee once per literal value it is given)
    u.noise_var_pos = _matched_variance(u, r, np.int64(0), u.noise_var_pos, u.var_pos_assumed)
    u.noise_var_att = _matched_variance(u, r, np.int64(3), u.noise_var_att, u.var_att_assumed)
    sp, sa = math.sqrt(u.Rn[0, 0]), math.sqrt(u.Rn[3, 3])
    if noise_raised(u):
        u.n_noise_adapted += 1
        c = max(u.Rn[0, 0] / u.noise_var_pos_top, u.Rn[3, 3] / u.noise_var_att_top)
        if c > 1.0:
            discount_covariance(u.P, u.P0, c)
            u.n_noise_discounts += 1
        u.noise_var_pos_top = max(u.noise_var_pos_top, u.Rn[0, 0])
        u.noise_var_att_top = max(u.noise_var_att_top, u.Rn[3, 3])
    else:  # back to the noise assumed: the episode is over
        u.noise_var_pos_top = u.var_pos_assumed
        u.noise_var_att_top = u.var_att_assumed
    u.noise_pos_std_max = max(u.noise_pos_std_max, sp)
    u.noise_att_std_max = max(u.noise_att_std_max, sa)


@jit
def fuse(u, buf, sbuf, w, p_m, q_m) -> int:
    """Update the delayed state (already predicted to the sample's time) with a pose, re-propagate to now.

    Args:
        u: the UKF record.
        buf: (cap,) the IMU ring buffer.
        sbuf: (cap,) the ring buffer of output states.
        w: the scratch record.
        p_m: (3,) measured position [m].
        q_m: (4,) measured attitude, wxyz (normalised here).

    Returns:
        ``FUSE_OK``, or why the sample was rejected (``FUSE_*``).
    """
    t_now = u.t
    f = u.x_fused
    fq = f.q_WB
    P = u.P
    qn = math.sqrt(q_m[0] * q_m[0] + q_m[1] * q_m[1] + q_m[2] * q_m[2] + q_m[3] * q_m[3])
    mw, mx, my, mz = q_m[0] / qn, q_m[1] / qn, q_m[2] / qn, q_m[3] / qn
    # Innovation in the error coordinates: (p_m - p, log(R_fᵀ R_m)).
    r = w.innov
    for i in range(3):
        r[i] = p_m[i] - f.p_W[i]
    ew, ex, ey, ez = quat_mul(fq[0], -fq[1], -fq[2], -fq[3], mw, mx, my, mz)
    if ew < 0.0:
        ew, ex, ey, ez = -ew, -ex, -ey, -ez
    nv = math.sqrt(ex * ex + ey * ey + ez * ez)
    kq = 2.0 * math.atan2(nv, ew) / nv if nv > 1e-12 else 2.0
    r[3], r[4], r[5] = kq * ex, kq * ey, kq * ez
    if u.adapt_noise != 0:
        match_noise(u, r)
    _track_drift(u, r)
    n = N_ERR
    PHt = w.PHt
    for i in range(n):
        for j in range(6):
            PHt[i, j] = P[i, _H_ROWS[j]]
    S_mat = w.S
    Rn = u.Rn
    for i in range(6):
        for j in range(6):
            S_mat[i, j] = PHt[_H_ROWS[i], j] + Rn[i, j]
    S_inv = w.S_inv
    if not invert_in_place(S_mat, S_inv):
        return FUSE_SINGULAR
    d2 = 0.0
    for j in range(6):
        acc = 0.0
        for i in range(6):
            acc += r[i] * S_inv[i, j]
        d2 += acc * r[j]
    if not d2 <= u.gate_chi2:
        u.gate_fails += 1
        if u.gate_fails >= u.reinit_after:
            # The filter is lost: take the motion-capture pose, keep velocity and biases, reset P.
            for i in range(3):
                f.p_W[i] = p_m[i]
            fq[0], fq[1], fq[2], fq[3] = mw, mx, my, mz
            R_from_quat_into(fq, u.R_WB_fused)
            _copy2(u.P0, P)
            u.gate_fails = 0
            u.t_accept = t_now
            _repropagate(u, buf, sbuf)
            return FUSE_REINIT
        return FUSE_GATE
    u.gate_fails = 0
    K = w.K
    for i in range(n):
        for j in range(6):
            acc = 0.0
            for l in range(6):
                acc += PHt[i, l] * S_inv[l, j]
            K[i, j] = acc
    dx = w.dx
    for i in range(n):
        acc = 0.0
        for j in range(6):
            acc += K[i, j] * r[j]
        dx[i] = acc
    Pn = w.Pn  # (I - K H) P
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for l in range(6):
                acc += K[i, l] * PHt[j, l]
            Pn[i, j] = P[i, j] - acc
    # Inject the error into the nominal state.
    for i in range(3):
        f.p_W[i] += dx[i]
        f.v_W[i] += dx[3 + i]
    # q <- q ⊗ Exp(dx[6:9]), normalised by a division (the order the controller reference was recorded with;
    # so3.quat_integrate_body_into multiplies by the inverse norm instead).
    dw, dqx, dqy, dqz = quat_of_rotvec(dx[6], dx[7], dx[8])
    qw, qx, qy, qz = quat_mul(fq[0], fq[1], fq[2], fq[3], dw, dqx, dqy, dqz)
    qn = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    fq[0], fq[1], fq[2], fq[3] = qw / qn, qx / qn, qy / qn, qz / qn
    R_from_quat_into(fq, u.R_WB_fused)
    for i in range(3):
        f.b_acc_B[i] += dx[9 + i]
        f.b_gyro_B[i] += dx[12 + i]
    # Reset: the attitude error is now relative to the corrected mean, P -> G P Gᵀ, G = I - [dtheta/2]x.
    # It changes P by a relative |dtheta|/2, so it is skipped for the usual sub-milliradian corrections.
    hx, hy, hz = 0.5 * dx[6], 0.5 * dx[7], 0.5 * dx[8]
    if hx * hx + hy * hy + hz * hz > _RESET_MIN_RAD2:
        Gt = w.Gt
        Gt[0, 0], Gt[0, 1], Gt[0, 2] = 1.0, hz, -hy
        Gt[1, 0], Gt[1, 1], Gt[1, 2] = -hz, 1.0, hx
        Gt[2, 0], Gt[2, 1], Gt[2, 2] = hy, -hx, 1.0
        rows = w.Gt_rows
        for i in range(3):
            for j in range(n):
                rows[i, j] = Gt[i, 0] * Pn[6, j] + Gt[i, 1] * Pn[7, j] + Gt[i, 2] * Pn[8, j]
        for i in range(3):
            for j in range(n):
                Pn[6 + i, j] = rows[i, j]
        cols = w.Gt_cols
        for i in range(n):
            for j in range(3):
                cols[i, j] = Pn[i, 6] * Gt[j, 0] + Pn[i, 7] * Gt[j, 1] + Pn[i, 8] * Gt[j, 2]
        for i in range(n):
            for j in range(3):
                Pn[i, 6 + j] = cols[i, j]
    for i in range(n):
        for j in range(n):
            P[i, j] = (Pn[i, j] + Pn[j, i]) * 0.5
    u.t_accept = t_now
    u.just_reset = 0
    _repropagate(u, buf, sbuf)
    return FUSE_OK


# -- the whole step ----------------------------------------------------------------------------------------------


@jit_inline
def ukf_step(u, buf, sbuf, w, gyro, acc, t_frame: float, mocap_new: bool, mocap_t: float, p_m, q_m, out) -> tuple:
    """The estimator's 1 kHz step once initialised (SPEC §4.5): IMU sample, motion-capture fusion, outputs.

    Inlined into its two callers, the estimator kind's step (:func:`ukf_block_step`, inside the controller's)
    and :func:`ukf_step_entry` (Python's): as a kernel of its own, its machine code (with the prediction and the
    fusion it calls) was optimised and emitted once more for the level it added between them.

    In order: :func:`imu_step`; without a motion-capture sample :func:`finish`; with one, its checks (finite
    ``mocap_t``, finite pose, quaternion norm within ``QUAT_NORM_TOL`` of 1), :func:`fuse_at` at ``mocap_t``
    (or at the frame time without ``u.compensate_latency``), :func:`predict` there, :func:`fuse` and
    :func:`finish`; finally :func:`predict` to ``k - lag_n`` when the delayed fused state lags too far.

    Args:
        u: the UKF record (:data:`UKF_DTYPE`); its counters are updated.
        buf: (cap,) the IMU ring buffer (:data:`IMU_SAMPLE_DTYPE`).
        sbuf: (cap,) the ring buffer of output states (:data:`NOMINAL_DTYPE`).
        w: the scratch record (:data:`WORK_DTYPE`).
        gyro: (3,) gyro sample [rad/s], body frame (float64).
        acc: (3,) accelerometer sample [m/s²], body frame (float64).
        t_frame: frame time [s].
        mocap_new: a motion-capture sample arrived in this frame.
        mocap_t: time the sample was taken [s] (ignored without ``mocap_new``).
        p_m: (3,) measured position [m], world frame (float64; ignored without ``mocap_new``). A frame that
            announces a sample without a well-formed pose passes NaN here: it is rejected and counted.
        q_m: (4,) measured attitude, wxyz (float64; as ``p_m``).
        out: the estimate record (:data:`~omnirotor.messages.ESTIMATE_DTYPE`, as :func:`write_estimate`).

    Returns:
        ``(code, t)``: ``STEP_REJECTED`` when something in the frame was not well-formed (the period, the IMU
        sample, the motion-capture sample), else ``STEP_MOCAP_REJECTED`` when a well-formed motion-capture
        sample was not fused (:func:`fuse`'s gate, too late for the buffer, singular), plus ``STEP_DEGRADED``
        while degraded (the estimate is then not valid), plus ``STEP_NOISE_RAISED`` while motion capture is
        weighed as noisier than assumed (:func:`match_noise`); the time of the estimate [s] (``t_frame``, or
        the previous time plus the nominal period when the frame's period was rejected).
    """
    nonfinite = not (math.isfinite(t_frame) and math.isfinite(gyro[0] + gyro[1] + gyro[2] + acc[0] + acc[1] + acc[2]))
    code, t = imu_step(u, buf, sbuf, gyro, acc, t_frame)
    if not mocap_new:
        code |= finish(u, out)
    rejected = (code & STEP_REJECTED) != 0
    invalid = rejected  # an input not well-formed (as against a well-formed sample the filter did not fuse)
    if mocap_new:
        # [:]: as arrays, the types Python and the supervisor check with (one compiled check, not two)
        if math.isfinite(mocap_t) and mocap_sample_valid(p_m[:], q_m[:], QUAT_NORM_TOL):
            t_m = mocap_t if u.compensate_latency != 0 else t
            k_m = fuse_at(u, buf, t_m)
            if k_m < 0:
                fused = FUSE_STALE
            else:
                predict(u, buf, sbuf, w, k_m)
                fused = fuse(u, buf, sbuf, w, p_m, q_m)
            if fused == FUSE_OK:
                u.n_mocap_fused += 1
            else:
                u.n_rejected_mocap += 1
                if fused == FUSE_REINIT:
                    u.n_reinit += 1
                rejected = True
        else:
            u.n_rejected_mocap += 1
            rejected = invalid = True
            if not math.isfinite(mocap_t + p_m[0] + p_m[1] + p_m[2] + q_m[0] + q_m[1] + q_m[2] + q_m[3]):
                nonfinite = True
        code = finish(u, out)
    if code & STEP_ADVANCE:
        predict(u, buf, sbuf, w, u.k - u.lag_n)
    result = code & STEP_DEGRADED
    if noise_raised(u):
        result |= STEP_NOISE_RAISED
    if u.acc_bias_range > 0.0 and bias_beyond_range(u):
        result |= STEP_BIAS_RANGE
    if rejected:
        u.n_rejected_inputs += 1
        result |= STEP_REJECTED if invalid else STEP_MOCAP_REJECTED
    if nonfinite:
        u.n_nonfinite += 1
    u.last_rejected = 1 if rejected else 0
    u.degraded = 1 if result & STEP_DEGRADED else 0
    return result, t


@jit_entry
def ukf_step_entry(state, memory, gyro, acc, t_frame: float, mocap_new: bool, mocap_t: float, p_m, q_m, out) -> tuple:
    """:func:`ukf_step` on the ``(1,)`` arrays of the state, the memory (:func:`memory_dtype`) and the estimate."""
    m = memory[0]
    return ukf_step(state[0], m.imu_buf, m.state_buf, m.work, gyro, acc, t_frame, mocap_new, mocap_t, p_m, q_m, out[0])


@jit
def ukf_block_step(u, memory, f, out) -> int:
    """The estimator kind's step (:data:`omnirotor.blocks.KIND_STEPS`): :func:`ukf_step` on a checked frame head.

    Args:
        u: the UKF's record (:data:`UKF_DTYPE`).
        memory: its memory record (:func:`memory_dtype`).
        f: the frame without its rotor speeds (:data:`omnirotor.messages.FRAME_HEAD_DTYPE`).
        out: the estimate record (:data:`omnirotor.messages.ESTIMATE_DTYPE`).

    Returns:
        The ``STEP_*`` bits of :func:`ukf_step`.
    """
    m = f.mocap
    code, _ = ukf_step(
        u, memory.imu_buf, memory.state_buf, memory.work, f.imu.gyro_B, f.imu.acc_B, f.t, m.new != 0.0, m.t, m.p_W,
        m.q_WB, out,
    )  # fmt: skip
    return code


@jit
def ukf_reinit(u, p_m, q_m, out, v_m=None) -> None:
    """Re-initialise the pose from a motion-capture sample at the current time (after a time glitch or a dropout).

    The output and the delayed fused state both become the sample's pose at the time of the last step; the
    velocity and the biases are kept where finite (else zero), the covariance goes back to the initial one,
    the buffer of IMU samples is emptied and the estimate is no longer degraded. Called by the controller's
    frame supervision (:mod:`omnirotor.control.supervisor`).

    Args:
        u: the UKF record; ``n_reinit`` counts it.
        p_m: (3,) measured position [m] (finite).
        q_m: (4,) measured attitude, wxyz (finite, non-zero; normalised here).
        out: the estimate record, rewritten.
        v_m: (3,) the velocity to take [m/s] (after the IMU coasted, from two samples), NaN or None: keep it.
    """
    s = u.x_out
    qn = math.sqrt(q_m[0] * q_m[0] + q_m[1] * q_m[1] + q_m[2] * q_m[2] + q_m[3] * q_m[3])
    for i in range(3):
        s.p_W[i] = p_m[i]
    for i in range(4):
        s.q_WB[i] = q_m[i] / qn
    if v_m is not None:
        for i in range(3):
            if math.isfinite(v_m[i]):
                s.v_W[i] = v_m[i]
    for i in range(3):
        if not math.isfinite(s.v_W[i]):
            s.v_W[i] = 0.0
    for i in range(3):
        if not math.isfinite(s.b_acc_B[i]):
            s.b_acc_B[i] = 0.0
    for i in range(3):
        if not math.isfinite(s.b_gyro_B[i]):
            s.b_gyro_B[i] = 0.0
    R_from_quat_into(s.q_WB, u.R_WB_out)
    copy_nominal(s, u.x_fused)
    _copy2(u.R_WB_out, u.R_WB_fused)
    u.t_fused = u.t
    u.k_fused = u.k
    u.t_accept = u.t
    u.just_reset = 1
    u.gate_fails = 0
    _copy2(u.P0, u.P)
    u.n_reinit += 1
    u.degraded = 0
    write_estimate(u, out)
