"""State estimation: IMU at 1 kHz fused with delayed motion capture (SPEC §4.5).

The paper's robot ran LAAS ``pom``, an unscented Kalman filter fusing the 1 kHz IMU with OptiTrack (SPEC
§4.5). :class:`UKFEstimator` is this project's version of that filter; :class:`BypassEstimator` passes the
plant's noisy ground truth (``SensorFrame.state``) through for fast studies.

Model (world z up, gravity ``-g e3``, SPEC §1.1). Nominal state ``x = (p_W, v_W, R_WB, b_a, b_g)``; the
accelerometer reads the specific force ``acc_B = R_WBᵀ (a_W + g e3) + b_a + noise`` and the gyro
``gyro_B = omega_B + b_g + noise``. One IMU sample of duration ``dt`` moves the state by

    a_W = R_WB (acc_B - b_a) - g e3,   p_W += v_W dt + a_W dt²/2,   v_W += a_W dt,
    R_WB <- R_WB exp((gyro_B - b_g) dt),   biases constant (random walks).

The filter is an error-state UKF on SO(3): the error ``dx = (dp, dv, dtheta, db_a, db_g)`` (15) with the
attitude error on the right, ``R = R_hat exp(dtheta)``, and covariance ``P`` (15 x 15).

How it spends its time (cost matters: this runs every 1 ms inside the controller):

* every IMU sample: only the **mean** is propagated, noise-free, on plain floats (quaternion, exact
  exponential), as in UKF-M (Brossard, Barrau and Bonnabel, "A code for unscented Kalman filtering on
  manifolds", ICRA 2020): the unscented transform is used for the covariance, not for the mean;
* at each motion-capture arrival: the unscented transform (2n+1 = 31 sigma points, vectorised) carries P
  over the buffered interval since the last fusion, in steps of at most 10 ms with the step's mean IMU
  reading (one step per 100 Hz period; the error this makes in P is second order in ``omega * step``),
  then the pose is fused. The pose measurement is linear in the error coordinates (``h = (dp, dtheta)``
  exactly, as ``log(R_hatᵀ R_hat exp(dtheta)) = dtheta``), so the unscented update reduces exactly to the
  Kalman update and is computed in that closed form. The attitude error is then folded into the mean and
  ``P`` transported by the reset Jacobian ``I - [dtheta/2]x`` (skipped below 1 mrad, where it is < 0.05 %).

Latency. A motion-capture sample taken at ``mocap_t`` arrives ``t - mocap_t`` later (5-10 ms on a typical
rig). The filter therefore keeps a *delayed* fused state at the time of the last fused sample and a ring
buffer of the IMU samples since then (preallocated). On arrival it predicts the fused state to
``mocap_t`` (the buffered sample nearest that time), updates there, and re-propagates the mean over the
buffered samples up to now (the output). Without motion capture the fused state is advanced in chunks so
that it never lags more than ``mocap_max_latency_s`` plus one chunk (its covariance grows meanwhile).
``compensate_latency = False`` treats every sample as taken at its arrival time (for comparison only).

Dropout and bad data. After ``mocap_timeout_s`` without an accepted sample the estimate is flagged
(``degraded``, ``StateEstimate.valid = False``) and keeps flying on the IMU; the next accepted sample clears
it. IMU samples that are non-finite or beyond the sensor ranges are replaced by the last good sample and
counted (``rejected_inputs``, ``last_input_rejected``). Motion-capture samples that are non-finite, stale
(older than the fused state or the buffer; a sample taken just before the start-up pose is fused at
start-up instead) or fail the chi-square innovation gate are skipped and counted;
``mocap_reinit_after`` consecutive gate failures re-initialise the pose from motion capture (the filter,
not the sensor, is then assumed lost).

Outputs (``StateEstimate``): pose, velocity, ``omega_B = gyro - b_g`` and ``a_W`` (p̈ without gravity, as
the wrench observer of SPEC §4.3 needs it), each optionally low-passed by a first-order filter
``y += lam (x - y)``, ``lam = 2 pi dt f_c / (2 pi dt f_c + 1)`` (the form of SPEC §4.3).

* ``acc_cutoff_hz = 5``: the paper's on-board accelerometer filter (SPEC §4.5). It only feeds the wrench
  observer, whose own dynamics (L = 15 rad/s and a 10 Hz output filter, SPEC §4.3) are slower still.
* ``gyro_cutoff_hz = 0`` (off). The robot's on-board 20 Hz gyro filter (SPEC §4.5) sits inside the
  attitude loop: with K_R = 300, K_omega = 80 (SPEC §4.1) and the assumed 25 ms rotor lag (SPEC §1.4 [A])
  it cuts the loop's phase margin from about 34 to 14 degrees, so it is not applied by default; set 20 to
  reproduce it.

An IMU away from the CoM (``imu_offset_B``, 0.041 m in z on the real robot, SPEC §4.5) reads
``acc + omega x (omega x r) + omega_dot x r`` on top of the CoM's; both terms are removed, with
``omega_dot`` the derivative of the gyro low-passed at ``lever_arm_cutoff_hz``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.linalg.lapack import dpotrf as _dpotrf

from omnirotor.config import check_finite, check_positive
from omnirotor.errors import InputError
from omnirotor.messages import SensorFrame, StateEstimate
from omnirotor.vehicle import VehicleParams

__all__ = ["EstimatorParams", "UKFEstimator", "BypassEstimator", "make_estimator", "ESTIMATOR_KINDS"]

ESTIMATOR_KINDS = ("ukf", "bypass")
"""Names of the estimators :func:`make_estimator` builds."""

_N_ERR = 15  # error-state dimension: dp, dv, dtheta, db_a, db_g
_ADVANCE_CHUNK_S = 0.01  # without motion capture, advance the delayed fused state in steps of this much
_COV_STEP_S = 0.01  # longest step of the sigma-point (covariance) propagation [s]
_RESET_MIN_RAD2 = (0.5e-3) ** 2  # squared half attitude correction [rad²] above which P is reset-transported
_QUAT_NORM_TOL = 0.1  # a motion-capture quaternion whose norm is off by more than this is rejected


@dataclasses.dataclass(frozen=True)
class EstimatorParams:
    """State-estimator parameters (SPEC §4.5).

    Noise values are [A] defaults for an MPU-6000-class IMU on a vibrating airframe and an OptiTrack rig;
    tune them to the sensors.

    Attributes:
        kind: "ukf" (default) or "bypass" (pass ``SensorFrame.state`` through).
        imu_rate_hz: nominal IMU rate [Hz]; sizes the buffers and replaces an invalid frame period.
        acc_noise_density: accelerometer white noise [m/s²/√Hz].
        gyro_noise_density: gyroscope white noise [rad/s/√Hz].
        acc_bias_walk: accelerometer bias random walk [m/s³/√Hz].
        gyro_bias_walk: gyroscope bias random walk [rad/s²/√Hz].
        acc_range: accelerometer full scale [m/s²]; larger readings are rejected (16 g).
        gyro_range: gyroscope full scale [rad/s]; larger readings are rejected (2000 deg/s).
        mocap_pos_std: motion-capture position noise, one sigma [m].
        mocap_att_std_deg: motion-capture attitude noise, one sigma per axis [deg].
        mocap_timeout_s: time without an accepted motion-capture sample after which the estimate is
            flagged degraded [s].
        mocap_max_latency_s: largest motion-capture latency handled [s]; older samples are rejected.
        mocap_gate_chi2: chi-square gate on the 6-D pose innovation (22.5 is the 99.9 % quantile).
        mocap_reinit_after: consecutive gate failures after which the pose is re-initialised from motion
            capture.
        compensate_latency: fuse each sample at the time it was taken (True) or at arrival (False, naive).
        imu_offset_B: IMU position relative to the CoM, body frame [m].
        lever_arm_cutoff_hz: cut-off of the gyro filter differentiated for the lever-arm correction [Hz].
        gyro_cutoff_hz: first-order low-pass on the ``omega_B`` output [Hz]; 0 = off (see module docs).
        acc_cutoff_hz: first-order low-pass on the ``a_W`` output [Hz]; 0 = off (SPEC §4.5: 5 Hz).
        init_pos_std: initial position uncertainty, one sigma [m].
        init_vel_std: initial velocity uncertainty [m/s].
        init_att_std_deg: initial attitude uncertainty per axis [deg].
        init_acc_bias_std: initial accelerometer-bias uncertainty [m/s²].
        init_gyro_bias_std: initial gyro-bias uncertainty [rad/s].
        ut_alpha: unscented-transform spread alpha.
        ut_beta: unscented-transform beta (2 is optimal for Gaussians).
        ut_kappa: unscented-transform kappa.
    """

    kind: str = "ukf"
    imu_rate_hz: float = 1000.0
    acc_noise_density: float = 0.02
    gyro_noise_density: float = 1e-3
    acc_bias_walk: float = 1e-3
    gyro_bias_walk: float = 1e-4
    acc_range: float = 156.9
    gyro_range: float = 34.9
    mocap_pos_std: float = 1e-3
    mocap_att_std_deg: float = 0.5
    mocap_timeout_s: float = 0.1
    mocap_max_latency_s: float = 0.03
    mocap_gate_chi2: float = 50.0
    mocap_reinit_after: int = 20
    compensate_latency: bool = True
    imu_offset_B: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lever_arm_cutoff_hz: float = 30.0
    gyro_cutoff_hz: float = 0.0
    acc_cutoff_hz: float = 5.0
    init_pos_std: float = 0.01
    init_vel_std: float = 0.1
    init_att_std_deg: float = 2.0
    init_acc_bias_std: float = 0.3
    init_gyro_bias_std: float = 0.05
    ut_alpha: float = 1.0
    ut_beta: float = 2.0
    ut_kappa: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ESTIMATOR_KINDS:
            raise InputError(f"estimator kind must be one of {', '.join(ESTIMATOR_KINDS)}, got {self.kind!r}")
        for name in (
            "imu_rate_hz",
            "acc_noise_density",
            "gyro_noise_density",
            "acc_bias_walk",
            "gyro_bias_walk",
            "acc_range",
            "gyro_range",
            "mocap_pos_std",
            "mocap_att_std_deg",
            "mocap_timeout_s",
            "mocap_max_latency_s",
            "mocap_gate_chi2",
            "lever_arm_cutoff_hz",
            "init_pos_std",
            "init_vel_std",
            "init_att_std_deg",
            "init_acc_bias_std",
            "init_gyro_bias_std",
            "ut_alpha",
        ):
            check_positive(f"estimator {name}", getattr(self, name))
        for name in ("gyro_cutoff_hz", "acc_cutoff_hz"):
            value = getattr(self, name)
            check_finite(f"estimator {name}", value)
            if value < 0:
                raise InputError(f"estimator {name} must be >= 0 (0 = off), got {value}")
        check_finite("estimator ut_beta", self.ut_beta)
        check_finite("estimator ut_kappa", self.ut_kappa)
        if self.ut_alpha**2 * (_N_ERR + self.ut_kappa) <= 0:
            raise InputError("estimator ut_alpha² (15 + ut_kappa) must be > 0")
        if isinstance(self.mocap_reinit_after, bool) or not isinstance(self.mocap_reinit_after, int):
            raise InputError(f"estimator mocap_reinit_after must be an integer, got {self.mocap_reinit_after!r}")
        if self.mocap_reinit_after < 1:
            raise InputError(f"estimator mocap_reinit_after must be >= 1, got {self.mocap_reinit_after}")
        if len(self.imu_offset_B) != 3:
            raise InputError(f"estimator imu_offset_B needs 3 values, got {len(self.imu_offset_B)}")
        check_finite("estimator imu_offset_B", *self.imu_offset_B)


# -- small helpers --------------------------------------------------------------------------------------------


def _lpf_gain(dt: float, cutoff_hz: float) -> float:
    """Gain ``lam`` of the discrete first-order filter ``y += lam (x - y)`` (SPEC §4.3); 1 when off."""
    if cutoff_hz <= 0.0:
        return 1.0
    k = 2.0 * math.pi * dt * cutoff_hz
    return k / (k + 1.0)


def _R_from_q(qw: float, qx: float, qy: float, qz: float) -> list[float]:
    """Row-major ``R_WB`` (9 floats) of a unit quaternion wxyz."""
    xx, yy, zz = qx * qx, qy * qy, qz * qz
    xy, xz, yz = qx * qy, qx * qz, qy * qz
    wx, wy, wz = qw * qx, qw * qy, qw * qz
    return [
        1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy),
        2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx),
        2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy),
    ]  # fmt: skip


def _q_from_R(R: np.ndarray) -> list[float]:
    """Unit quaternion wxyz (w >= 0) of a (3, 3) rotation matrix (Shepperd)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    if q[0] < 0:
        q = [-c for c in q]
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return [c / n for c in q]


def _propagate(s: list[float], R: list[float], dt: float, g: float, imu: list[float]) -> None:
    """One IMU sample on the nominal state, in place (module docstring).

    Args:
        s: 16 floats ``[p_W(3), v_W(3), q_WB wxyz(4), b_a(3), b_g(3)]``.
        R: the 9 floats of ``R_WB(q)``, row-major; updated to the new attitude.
        dt: sample duration [s].
        g: gravity [m/s²].
        imu: ``[gyro_B(3) [rad/s], acc_B(3) [m/s²]]`` (lever-arm corrected).
    """
    fx, fy, fz = imu[3] - s[10], imu[4] - s[11], imu[5] - s[12]
    ax = R[0] * fx + R[1] * fy + R[2] * fz
    ay = R[3] * fx + R[4] * fy + R[5] * fz
    az = R[6] * fx + R[7] * fy + R[8] * fz - g
    h = 0.5 * dt * dt
    s[0] += s[3] * dt + ax * h
    s[1] += s[4] * dt + ay * h
    s[2] += s[5] * dt + az * h
    s[3] += ax * dt
    s[4] += ay * dt
    s[5] += az * dt
    wx, wy, wz = (imu[0] - s[13]) * dt, (imu[1] - s[14]) * dt, (imu[2] - s[15]) * dt
    th2 = wx * wx + wy * wy + wz * wz
    if th2 > 1e-24:
        th = math.sqrt(th2)
        c, k = math.cos(0.5 * th), math.sin(0.5 * th) / th
    else:
        c, k = 1.0 - th2 / 8.0, 0.5 - th2 / 48.0
    dx, dy, dz = k * wx, k * wy, k * wz
    qw, qx, qy, qz = s[6], s[7], s[8], s[9]
    nw = qw * c - qx * dx - qy * dy - qz * dz
    nx = qw * dx + qx * c + qy * dz - qz * dy
    ny = qw * dy - qx * dz + qy * c + qz * dx
    nz = qw * dz + qx * dy - qy * dx + qz * c
    inv = 1.0 / math.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
    s[6], s[7], s[8], s[9] = nw * inv, nx * inv, ny * inv, nz * inv
    R[:] = _R_from_q(s[6], s[7], s[8], s[9])


# so(3) generators: hat(a) = sum_k a_k _GEN[k], and vee(skew(M)) = 0.5 sum_ij _GEN[k, i, j] M[i, j].
_GEN = np.zeros((3, 3, 3))
_GEN[0, 2, 1], _GEN[0, 1, 2] = 1.0, -1.0
_GEN[1, 0, 2], _GEN[1, 2, 0] = 1.0, -1.0
_GEN[2, 1, 0], _GEN[2, 0, 1] = 1.0, -1.0
_GEN_FLAT = _GEN.reshape(3, 9)
_I3 = np.eye(3)


def _exp_batch(phi: np.ndarray) -> np.ndarray:
    """(S, 3, 3) rotation matrices of (S, 3) rotation vectors [rad] (Rodrigues, few numpy calls)."""
    th2 = np.add.reduce(phi * phi, axis=1)
    th = np.sqrt(th2)
    big = th2 > 1e-8  # below, the series to th² are exact in double precision
    a = np.divide(np.sin(th), th, out=1.0 - th2 / 6.0, where=big)  # sin(th) / th
    b = np.divide(1.0 - np.cos(th), th2, out=0.5 - th2 / 24.0, where=big)  # (1 - cos th) / th²
    K = (phi @ _GEN_FLAT).reshape(-1, 3, 3)
    R = K @ K
    R *= b[:, None, None]
    K *= a[:, None, None]
    R += K
    R += _I3
    return R


def _log_batch(R: np.ndarray) -> np.ndarray:
    """(S, 3) rotation vectors [rad] of (S, 3, 3) rotations with angles below pi."""
    w = R.reshape(-1, 9) @ _GEN_FLAT.T
    w *= 0.5  # sin(th) * axis
    sn = np.sqrt(np.einsum("sk,sk->s", w, w))
    th = np.arctan2(sn, 0.5 * (np.einsum("sii->s", R) - 1.0))
    k = np.divide(th, sn, out=np.ones_like(th), where=sn > 1e-12)
    w *= k[:, None]
    return w


def _q_mul(a: list[float], b: list[float]) -> list[float]:
    """Hamilton product ``a ⊗ b`` of wxyz quaternions."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return [
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ]


def _q_log(q: list[float]) -> list[float]:
    """Rotation vector [rad] of a unit quaternion wxyz (the shorter way round)."""
    w, x, y, z = q
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(x * x + y * y + z * z)
    k = 2.0 * math.atan2(n, w) / n if n > 1e-12 else 2.0
    return [k * x, k * y, k * z]


def _q_exp(phi: list[float]) -> list[float]:
    """Unit quaternion wxyz of a rotation vector [rad]."""
    th = math.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    k = math.sin(0.5 * th) / th if th > 1e-12 else 0.5
    return [math.cos(0.5 * th), k * phi[0], k * phi[1], k * phi[2]]


def _q_normalised(q: list[float]) -> list[float]:
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return [c / n for c in q]


# -- the UKF ------------------------------------------------------------------------------------------------


class UKFEstimator:
    """Error-state unscented Kalman filter: 1 kHz IMU with delayed motion capture (module docstring).

    Attributes:
        degraded: True while no motion-capture sample was accepted for ``mocap_timeout_s`` (or before the
            filter is initialised).
        initialised: True once the filter has a first pose.
        rejected_inputs: count of frames in which something was rejected: an IMU sample (non-finite or
            beyond the sensor range), the frame period (non-finite or not increasing) or the
            motion-capture sample.
        rejected_mocap: count of motion-capture samples rejected (invalid, stale or outside the gate).
        last_input_rejected: True when something in the last frame was rejected.
        n_mocap_fused: count of motion-capture samples fused.
        n_reinit: count of re-initialisations from motion capture after repeated gate failures.
    """

    def __init__(self, vehicle: VehicleParams, params: EstimatorParams | None = None):
        """Allocate the filter; it initialises on the first frame with a pose (see :meth:`reset`).

        Args:
            vehicle: the vehicle (gravity).
            params: estimator parameters; defaults to :class:`EstimatorParams()`.
        """
        self.params = p = params if params is not None else EstimatorParams()
        self.vehicle = vehicle
        self._g = vehicle.gravity
        self._dt_nom = 1.0 / p.imu_rate_hz
        # Ring buffer of IMU samples: t [s], dt [s], gyro_B (3), acc_B (3) (lever-arm corrected).
        self._lag_n = int(math.ceil(p.mocap_max_latency_s * p.imu_rate_hz))
        self._chunk_n = max(1, int(round(_ADVANCE_CHUNK_S * p.imu_rate_hz)))
        self._cap = self._lag_n + self._chunk_n + 8
        self._buf = [[0.0] * 8 for _ in range(self._cap)]
        self._sbuf = [[0.0] * 16 for _ in range(self._cap)]  # output state after each buffered sample
        self._cov_n = max(1, int(round(_COV_STEP_S * p.imu_rate_hz)))
        # Unscented-transform weights.
        n = _N_ERR
        lam = p.ut_alpha**2 * (n + p.ut_kappa) - n
        self._ut_scale = math.sqrt(n + lam)
        self._wm = np.full(2 * n + 1, 0.5 / (n + lam))
        self._wc = self._wm.copy()
        self._wm[0] = lam / (n + lam)
        self._wc[0] = lam / (n + lam) + 1.0 - p.ut_alpha**2 + p.ut_beta
        # Measurement noise (position, attitude) and the initial covariance.
        att = math.radians(p.mocap_att_std_deg)
        self._Rn = np.diag([p.mocap_pos_std**2] * 3 + [att * att] * 3)
        self._P0 = np.diag(
            [p.init_pos_std**2] * 3 + [p.init_vel_std**2] * 3 + [math.radians(p.init_att_std_deg) ** 2] * 3
            + [p.init_acc_bias_std**2] * 3 + [p.init_gyro_bias_std**2] * 3
        )  # fmt: skip
        self._r = [float(c) for c in p.imu_offset_B]
        self._lever = any(c != 0.0 for c in self._r)
        self._Q1, self._Q2, self._Q3 = self._process_noise_terms()
        self._E = np.zeros((2 * n + 1, n))  # sigma-point errors
        self._D = np.zeros((2 * n + 1, n))  # sigma-point offsets
        self._n_sigma = 2 * n + 1
        self.P = self._P0.copy()
        self._clear()

    # -- state -------------------------------------------------------------------------------------------

    def _clear(self) -> None:
        """Forget everything: uninitialised, counters cleared, covariance back to the initial one."""
        self.initialised = False
        self.degraded = True
        self.rejected_inputs = 0
        self.rejected_mocap = 0
        self.last_input_rejected = False
        self.n_mocap_fused = 0
        self.n_reinit = 0
        self._gate_fails = 0
        self._s = [0.0] * 6 + [1.0, 0.0, 0.0, 0.0] + [0.0] * 6  # output (current) nominal state
        self._Rs = _R_from_q(1.0, 0.0, 0.0, 0.0)
        self._f = list(self._s)  # delayed fused state
        self._Rf = list(self._Rs)
        self._t_f = 0.0
        self._k = 0  # IMU samples pushed so far
        self._kf = 0  # samples already in the fused state
        self._t = 0.0
        self._t_accept = -math.inf  # frame time of the last accepted motion-capture sample
        self._just_reset = True  # no sample fused since the start-up pose
        self._imu = [0.0, 0.0, 0.0, 0.0, 0.0, self._g]  # last good sample: gyro_B, acc_B (raw)
        self._gyro_lp = [0.0, 0.0, 0.0]  # for the lever arm's omega_dot
        self._omega_out = [0.0, 0.0, 0.0]
        self._acc_out = [0.0, 0.0, 0.0]
        self._lpf_dt = math.nan
        self._lam_w = self._lam_a = 1.0
        self.P[:] = self._P0

    def reset(self, frame: SensorFrame) -> None:
        """(Re)initialise from a frame: its motion-capture pose if it has one, else ``frame.state``.

        The motion-capture pose is taken as the pose at ``frame.t`` (the latency is ignored at start-up);
        the velocity comes from ``frame.state`` when the frame has one, else it is zero.

        Raises:
            InputError: the frame has neither a valid motion-capture sample nor a state.
        """
        self._clear()
        s = self._s
        state = frame.state if frame.state is not None and _state_finite(frame.state) else None
        if state is not None:
            s[3:6] = state.v_W.tolist()
        if self._mocap_valid(frame):
            s[0:3] = frame.mocap_p_W.tolist()
            q = np.asarray(frame.mocap_q_WB, dtype=float)
            s[6:10] = (q / np.linalg.norm(q)).tolist()
        elif state is not None:
            s[0:3] = state.p_W.tolist()
            s[6:10] = _q_from_R(state.R_WB)
        else:
            raise InputError("the estimator needs a motion-capture sample or a state to initialise")
        self._Rs = _R_from_q(*s[6:10])
        self._f = list(s)
        self._Rf = list(self._Rs)
        self._t = self._t_f = frame.t
        self._t_accept = frame.t
        self.initialised = True
        self.degraded = False
        gyro, acc = frame.imu_gyro_B.tolist(), frame.imu_acc_B.tolist()
        if self._imu_valid(gyro, acc):
            self._imu = gyro + acc
        self._gyro_lp = list(self._imu[0:3])
        self._omega_out = [self._imu[i] - s[13 + i] for i in range(3)]
        self._acc_out = [0.0, 0.0, 0.0]

    @property
    def bias_acc_B(self) -> np.ndarray:
        """(3,) estimated accelerometer bias [m/s²]."""
        return np.array(self._s[10:13])

    @property
    def bias_gyro_B(self) -> np.ndarray:
        """(3,) estimated gyro bias [rad/s]."""
        return np.array(self._s[13:16])

    @property
    def lag_s(self) -> float:
        """How far the delayed fused state lags the output [s]."""
        return self._t - self._t_f

    # -- validation ----------------------------------------------------------------------------------------

    def _imu_valid(self, gyro: list[float], acc: list[float]) -> bool:
        sg, sa = gyro[0] + gyro[1] + gyro[2], acc[0] + acc[1] + acc[2]
        if not (math.isfinite(sg) and math.isfinite(sa)):
            return False
        gr, ar = self.params.gyro_range, self.params.acc_range
        return max(abs(gyro[0]), abs(gyro[1]), abs(gyro[2])) <= gr and max(abs(acc[0]), abs(acc[1]), abs(acc[2])) <= ar

    @staticmethod
    def _mocap_valid(frame: SensorFrame) -> bool:
        if not frame.mocap_new or frame.mocap_p_W is None or frame.mocap_q_WB is None:
            return False
        p, q = frame.mocap_p_W, frame.mocap_q_WB
        if p.shape != (3,) or q.shape != (4,) or not math.isfinite(frame.mocap_t):
            return False
        if not (math.isfinite(float(p.sum())) and math.isfinite(float(q.sum()))):
            return False
        return abs(float(np.linalg.norm(q)) - 1.0) <= _QUAT_NORM_TOL

    # -- the 1 kHz step ------------------------------------------------------------------------------------

    def step(self, frame: SensorFrame) -> StateEstimate:
        """Propagate with the frame's IMU sample, fuse its motion-capture sample if any, return the estimate.

        Args:
            frame: this period's sensor data.

        Returns:
            The estimate at ``frame.t`` (fresh arrays). ``valid`` is False while degraded.
        """
        if not self.initialised:
            if self._mocap_valid(frame) or (frame.state is not None and _state_finite(frame.state)):
                self.reset(frame)
                return self._estimate(frame.t)
            return self._estimate(frame.t)
        p = self.params
        rejected = False
        # Period: an invalid one (not finite, not increasing) is replaced by the nominal period.
        dt = frame.t - self._t
        if not (dt > 0.0 and math.isfinite(dt)):
            dt = self._dt_nom
            rejected = True
        t = self._t + dt
        self._t = t
        # IMU sample: an invalid one is replaced by the last good one.
        gyro, acc = frame.imu_gyro_B.tolist(), frame.imu_acc_B.tolist()
        if self._imu_valid(gyro, acc):
            self._imu = gyro + acc
        else:
            rejected = True
        imu = list(self._imu)
        s = self._s
        if self._lever:
            self._correct_lever_arm(imu, dt)
        # Buffer the sample and move the output state.
        row = self._buf[self._k % self._cap]
        row[0] = t
        row[1] = dt
        row[2:8] = imu
        _propagate(s, self._Rs, dt, self._g, imu)
        self._sbuf[self._k % self._cap][:] = s
        self._k += 1
        # Motion capture.
        if frame.mocap_new:
            if self._mocap_valid(frame):
                t_m = frame.mocap_t if p.compensate_latency else t
                if not self._fuse(t_m, frame.mocap_p_W, frame.mocap_q_WB, t):
                    rejected = True
            else:
                self.rejected_mocap += 1
                rejected = True
        # Without motion capture, keep the delayed state within the buffer.
        if self._k - self._kf > self._lag_n + self._chunk_n:
            self._predict(self._k - self._lag_n)
        if rejected:
            self.rejected_inputs += 1
        self.last_input_rejected = rejected
        self.degraded = t - self._t_accept > p.mocap_timeout_s
        # Outputs: bias-corrected rate and acceleration, low-passed.
        if dt != self._lpf_dt:
            self._lpf_dt = dt
            self._lam_w = _lpf_gain(dt, p.gyro_cutoff_hz)
            self._lam_a = _lpf_gain(dt, p.acc_cutoff_hz)
        lam_w, lam_a = self._lam_w, self._lam_a
        R = self._Rs
        fx, fy, fz = imu[3] - s[10], imu[4] - s[11], imu[5] - s[12]
        wo, ao = self._omega_out, self._acc_out
        wo[0] += lam_w * (imu[0] - s[13] - wo[0])
        wo[1] += lam_w * (imu[1] - s[14] - wo[1])
        wo[2] += lam_w * (imu[2] - s[15] - wo[2])
        ao[0] += lam_a * (R[0] * fx + R[1] * fy + R[2] * fz - ao[0])
        ao[1] += lam_a * (R[3] * fx + R[4] * fy + R[5] * fz - ao[1])
        ao[2] += lam_a * (R[6] * fx + R[7] * fy + R[8] * fz - self._g - ao[2])
        return self._estimate(t)

    def _correct_lever_arm(self, imu: list[float], dt: float) -> None:
        """Remove ``omega x (omega x r) + omega_dot x r`` from the accelerometer sample, in place."""
        r = self._r
        s = self._s
        lam = _lpf_gain(dt, self.params.lever_arm_cutoff_hz)
        lp = self._gyro_lp
        wd = [0.0, 0.0, 0.0]
        for i in range(3):
            new = lp[i] + lam * (imu[i] - lp[i])
            wd[i] = (new - lp[i]) / dt
            lp[i] = new
        wx, wy, wz = imu[0] - s[13], imu[1] - s[14], imu[2] - s[15]
        cx, cy, cz = wy * r[2] - wz * r[1], wz * r[0] - wx * r[2], wx * r[1] - wy * r[0]  # omega x r
        imu[3] -= wy * cz - wz * cy + wd[1] * r[2] - wd[2] * r[1]
        imu[4] -= wz * cx - wx * cz + wd[2] * r[0] - wd[0] * r[2]
        imu[5] -= wx * cy - wy * cx + wd[0] * r[1] - wd[1] * r[0]

    def _estimate(self, t: float) -> StateEstimate:
        # One fresh array per message; the fields are views into it.
        x = np.array(self._s[0:6] + self._acc_out + self._Rs + self._omega_out)
        return StateEstimate(
            t=t,
            p_W=x[0:3],
            v_W=x[3:6],
            a_W=x[6:9],
            R_WB=x[9:18].reshape(3, 3),
            omega_B=x[18:21],
            valid=self.initialised and not self.degraded,
        )

    # -- unscented prediction of the delayed state -----------------------------------------------------------

    def _predict(self, k_end: int) -> None:
        """Unscented prediction of the delayed fused state over the buffered samples [kf, k_end).

        The mean is the noise-free propagation of the previous mean, sample by sample: exactly the output
        state the filter already computed for sample ``k_end - 1`` (kept in the state buffer), as in UKF-M
        (Brossard, Barrau and Bonnabel, 2020). The covariance is the unscented transform of P through the
        same motion model, applied in steps of at most ``_COV_STEP_S`` with the step's mean IMU reading
        (one step per 10 ms motion-capture period): the error this makes in P is second order in
        ``omega * step``.
        """
        if k_end <= self._kf:
            return
        n = _N_ERR
        L, info = _dpotrf(self.P, lower=1)  # LAPACK directly: np.linalg.cholesky costs 2.5x more here
        if info != 0:  # lost positive definiteness to rounding: symmetrise and add a little jitter
            L, info = _dpotrf(0.5 * (self.P + self.P.T) + 1e-12 * np.eye(n), lower=1)
            if info != 0:
                self.P[:] = self._P0
                L, info = _dpotrf(self.P, lower=1)
        D = self._D
        np.multiply(L.T, self._ut_scale, out=D[1 : n + 1])
        np.negative(D[1 : n + 1], out=D[n + 1 :])
        f = self._f
        X = np.array(f[0:6] + f[10:16]) + D[:, _NOT_ATT]  # p, v, b_a, b_g of the sigma points
        Ps, Vs, BA, BG = X[:, 0:3], X[:, 3:6], X[:, 6:9], X[:, 9:12]
        # Mean IMU reading [gyro (3), acc (3)] and duration of each covariance step.
        cap, buf = self._cap, self._buf
        steps: list[tuple[float, list[float]]] = []
        k = self._kf
        while k < k_end:
            k1 = min(k_end, k + self._cov_n)
            T = 0.0
            m = [0.0] * 6
            for j in range(k, k1):
                row = buf[j % cap]
                dt = row[1]
                T += dt
                for i in range(6):
                    m[i] += row[2 + i] * dt
            steps.append((T, [x / T for x in m]))
            k = k1
        # One Rodrigues call for the sigma points' attitudes and every step's rotation increment.
        phi = np.empty(((1 + len(steps)) * self._n_sigma, 3))
        S = self._n_sigma
        phi[:S] = D[:, 6:9]
        for i, (T, m) in enumerate(steps):
            np.multiply(np.subtract(m[0:3], BG), T, out=phi[(i + 1) * S : (i + 2) * S])
        rot = _exp_batch(phi)
        Rs = np.array(self._Rf).reshape(3, 3) @ rot[:S]
        g = self._g
        T_total = 0.0
        for i, (T, m) in enumerate(steps):
            a = np.einsum("sij,sj->si", Rs, np.subtract(m[3:6], BA))
            a[:, 2] -= g
            Ps += Vs * T + a * (0.5 * T * T)
            Vs += a * T
            Rs = Rs @ rot[(i + 1) * S : (i + 2) * S]
            T_total += T
        E = self._E
        np.subtract(Ps, Ps[0], out=E[:, 0:3])
        np.subtract(Vs, Vs[0], out=E[:, 3:6])
        E[:, 6:9] = _log_batch(np.einsum("ji,sjk->sik", Rs[0], Rs))
        E[:, 9:15] = D[:, 9:15]
        dE = E - self._wm @ E
        P_new = (dE.T * self._wc) @ dE  # symmetric up to rounding, which the update's symmetrisation removes
        P_new += self._process_noise(T_total)
        self.P = P_new
        # The mean: the output state already propagated to sample k_end - 1.
        f[:] = self._sbuf[(k_end - 1) % cap]
        self._Rf = _R_from_q(f[6], f[7], f[8], f[9])
        self._t_f = buf[(k_end - 1) % cap][0]
        self._kf = k_end

    def _process_noise_terms(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Q(T) = T Q1 + T² Q2 + T³ Q3: additive process noise over T seconds, error coordinates.

        White accelerometer noise integrates into velocity (T) and position (T³/3, cross T²/2), white gyro
        noise into attitude (T), and the bias random walks into the biases (T).
        """
        p = self.params
        qa = p.acc_noise_density**2
        Q1, Q2, Q3 = (np.zeros((_N_ERR, _N_ERR)) for _ in range(3))
        i3 = np.eye(3)
        Q3[0:3, 0:3] = qa / 3.0 * i3
        Q2[0:3, 3:6] = Q2[3:6, 0:3] = qa / 2.0 * i3
        Q1[3:6, 3:6] = qa * i3
        Q1[6:9, 6:9] = p.gyro_noise_density**2 * i3
        Q1[9:12, 9:12] = p.acc_bias_walk**2 * i3
        Q1[12:15, 12:15] = p.gyro_bias_walk**2 * i3
        return Q1, Q2, Q3

    def _process_noise(self, T: float) -> np.ndarray:
        """Additive process noise over an interval of T seconds (error-state coordinates)."""
        Q = self._Q1 * T
        Q += self._Q2 * (T * T)
        Q += self._Q3 * (T * T * T)
        return Q

    # -- fusion ----------------------------------------------------------------------------------------------

    def _fuse(self, t_m: float, p_m: np.ndarray, q_m: np.ndarray, t_now: float) -> bool:
        """Fuse a pose taken at ``t_m``: predict the delayed state there, update, re-propagate to now.

        Returns:
            False when the sample was rejected (stale, from the future, or outside the gate).
        """
        half = 0.5 * self._dt_nom
        if t_m < self._t_f - half and self._just_reset:
            t_m = self._t_f  # taken before the start-up pose: there is no earlier state, fuse it at start-up
        if t_m < self._t_f - half or t_m > t_now + half or t_now - t_m > self.params.mocap_max_latency_s + half:
            self.rejected_mocap += 1  # stale (older than the fused state or the buffer) or from the future
            return False
        # The buffered samples up to t_m (nearest sample).
        k_m = self._kf
        while k_m < self._k and self._buf[k_m % self._cap][0] <= t_m + half:
            k_m += 1
        self._predict(k_m)
        f = self._f
        qm = _q_normalised(q_m.tolist())
        pm = p_m.tolist()
        # Innovation in the error coordinates: (p_m - p, log(R_fᵀ R_m)).
        q_conj = [f[6], -f[7], -f[8], -f[9]]
        r = np.array([pm[0] - f[0], pm[1] - f[1], pm[2] - f[2], *_q_log(_q_mul(q_conj, qm))])
        P = self.P
        PHt = P[:, _SEL]
        S = PHt[_SEL] + self._Rn
        try:
            S_inv = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            self.rejected_mocap += 1
            return False
        d2 = float(r @ S_inv @ r)
        if not d2 <= self.params.mocap_gate_chi2:
            self.rejected_mocap += 1
            self._gate_fails += 1
            if self._gate_fails >= self.params.mocap_reinit_after:
                self._reinit_pose(pm, qm)
            return False
        self._gate_fails = 0
        K = PHt @ S_inv
        dx = (K @ r).tolist()
        P = P - K @ PHt.T  # (I - K H) P
        # Inject the error into the nominal state.
        for i in (0, 1, 2, 3, 4, 5):
            f[i] += dx[i]
        f[6:10] = _q_normalised(_q_mul(f[6:10], _q_exp(dx[6:9])))
        self._Rf = _R_from_q(*f[6:10])
        for i in range(9, 15):
            f[i + 1] += dx[i]
        # Reset: the attitude error is now relative to the corrected mean, P -> G P Gᵀ, G = I - [dtheta/2]x.
        # It changes P by a relative |dtheta|/2, so it is skipped for the usual sub-milliradian corrections.
        hx, hy, hz = 0.5 * dx[6], 0.5 * dx[7], 0.5 * dx[8]
        if hx * hx + hy * hy + hz * hz > _RESET_MIN_RAD2:
            Gt = np.array([[1.0, hz, -hy], [-hz, 1.0, hx], [hy, -hx, 1.0]])
            P[6:9] = Gt @ P[6:9]
            P[:, 6:9] = P[:, 6:9] @ Gt.T
        P += P.T
        P *= 0.5
        self.P = P
        self.n_mocap_fused += 1
        self._t_accept = t_now
        self._just_reset = False
        self._repropagate()
        return True

    def _reinit_pose(self, p_m: list[float], q_m: list[float]) -> None:
        """The filter is lost: take the motion-capture pose, keep velocity and biases, reset P."""
        f = self._f
        f[0:3] = p_m
        f[6:10] = q_m
        self._Rf = _R_from_q(*f[6:10])
        self.P = self._P0.copy()
        self._gate_fails = 0
        self.n_reinit += 1
        self._t_accept = self._t
        self._repropagate()

    def _repropagate(self) -> None:
        """Output state = fused state moved over the buffered samples after it (mean only)."""
        s = self._s
        s[:] = self._f
        R = list(self._Rf)
        g = self._g
        cap, buf, sbuf = self._cap, self._buf, self._sbuf
        for k in range(self._kf, self._k):
            row = buf[k % cap]
            _propagate(s, R, row[1], g, row[2:8])
            sbuf[k % cap][:] = s
        self._Rs = R


_SEL = np.array([0, 1, 2, 6, 7, 8])  # error coordinates measured by motion capture: dp, dtheta
_NOT_ATT = np.r_[0:6, 9:15]  # error coordinates other than the attitude


def _state_finite(state: StateEstimate) -> bool:
    return all(math.isfinite(float(np.sum(a))) for a in (state.p_W, state.v_W, state.a_W, state.R_WB, state.omega_B))


# -- bypass ----------------------------------------------------------------------------------------------------


class BypassEstimator:
    """Pass the plant's ``SensorFrame.state`` (ground truth plus noise) through, for fast studies.

    A frame without a state, or with a non-finite one, repeats the last good state flagged invalid.

    Attributes:
        degraded: True when the last frame's state was missing or non-finite.
        initialised: True once a state was received.
        rejected_inputs: count of frames whose state was missing or non-finite.
        last_input_rejected: True when the last frame's state was rejected.
    """

    def __init__(self, vehicle: VehicleParams, params: EstimatorParams | None = None):
        """Args: vehicle: the vehicle (unused, for a uniform interface). params: estimator parameters."""
        self.params = params if params is not None else EstimatorParams(kind="bypass")
        self.vehicle = vehicle
        self._last: StateEstimate | None = None
        self.initialised = False
        self.degraded = True
        self.rejected_inputs = 0
        self.last_input_rejected = False

    def reset(self, frame: SensorFrame) -> None:
        """Start from the frame's state.

        Raises:
            InputError: the frame has no (finite) state: the plant does not provide one.
        """
        if frame.state is None or not _state_finite(frame.state):
            raise InputError("the bypass estimator needs SensorFrame.state (ground truth); this plant gives none")
        self._last = frame.state
        self.initialised = True
        self.degraded = False
        self.rejected_inputs = 0
        self.last_input_rejected = False

    def step(self, frame: SensorFrame) -> StateEstimate:
        """Return ``frame.state``, or the last good state flagged invalid.

        Raises:
            InputError: no state was ever received (the plant does not provide one).
        """
        state = frame.state
        if state is not None and _state_finite(state):
            self._last = state
            self.initialised = True
            self.degraded = False
            self.last_input_rejected = False
            return state
        if self._last is None:
            raise InputError("the bypass estimator needs SensorFrame.state (ground truth); this plant gives none")
        self.rejected_inputs += 1
        self.last_input_rejected = True
        self.degraded = True
        last = self._last
        return dataclasses.replace(last, t=frame.t, valid=False)


def make_estimator(vehicle: VehicleParams, params: EstimatorParams | None = None) -> UKFEstimator | BypassEstimator:
    """The estimator ``params.kind`` names ("ukf" or "bypass")."""
    params = params if params is not None else EstimatorParams()
    if params.kind == "bypass":
        return BypassEstimator(vehicle, params)
    return UKFEstimator(vehicle, params)
