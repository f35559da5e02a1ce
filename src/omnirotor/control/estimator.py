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

* every IMU sample: only the **mean** is propagated, noise-free (quaternion, exact
  exponential), as in UKF-M (Brossard, Barrau and Bonnabel, "A code for unscented Kalman filtering on
  manifolds", ICRA 2020): the unscented transform is used for the covariance, not for the mean;
* at each motion-capture arrival: the unscented transform (2n+1 = 31 sigma points) carries P
  over the buffered interval since the last fusion, in steps of at most 10 ms with the step's mean IMU
  reading (one step per 100 Hz period; the error this makes in P is second order in ``omega * step``),
  then the pose is fused. The pose measurement is linear in the error coordinates (``h = (dp, dtheta)``
  exactly, as ``log(R_hatᵀ R_hat exp(dtheta)) = dtheta``), so the unscented update reduces exactly to the
  Kalman update and is computed in that closed form. The attitude error is then folded into the mean and
  ``P`` transported by the reset Jacobian ``I - [dtheta/2]x`` (skipped below 1 mrad, where it is < 0.05 %).

The arithmetic runs in compiled kernels (:mod:`omnirotor.control._estimator_kernels`): once initialised, a
step is one compiled call (:func:`~omnirotor.control._estimator_kernels.ukf_step`), which a compiled control
loop can also make itself (:class:`UKFEstimator`).

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

Sustained faults (issue 26; the frame supervision, :mod:`omnirotor.control.supervisor`, decides). While the
IMU *coasts* (its samples rejected for longer than the supervision's ``imu_hold_s``, replaced by the
specific force of a body at rest) the filter adds its bias estimates back to that sample (the prediction is
bias-free: no bias is learnt from it) and white acceleration noise of ``coast_acc_std`` over a 10 ms
correlation to the covariance, so that motion capture steers the estimate. A bias drifting faster than its
random walk (a running mean of the position innovations over about 10 samples beyond ``bias_drift_m`` or 5
standard deviations of that mean under the motion-capture noise in use, 1.15 sigma) scales the bias random
walks by ``bias_drift_scale`` until the mean
falls below half the threshold. Neither happens in a run without such faults: the covariance is then what it
was, bit for bit. A bias estimate beyond the documented range (``acc_bias_range`` 3 m/s², ``gyro_bias_range``
0.5 rad/s, any component) is flagged ``ControlStatus.BIAS_BEYOND_RANGE``; the filter keeps following it.

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

from omnirotor._jit import jit, jit_entry
from omnirotor.blocks import block_class, new_records, register, state_array
from omnirotor.config import check_finite, check_positive
from omnirotor.control import _estimator_kernels as _ek
from omnirotor.errors import InputError
from omnirotor.frame_kernels import copy_state, state_finite
from omnirotor.messages import ESTIMATE_DTYPE, SensorFrame, StateEstimate, frame_dtype
from omnirotor.so3 import quat_wxyz_from_R
from omnirotor.vehicle import VehicleParams

__all__ = [
    "EstimatorParams",
    "UKFEstimator",
    "BypassEstimator",
    "make_estimator",
    "ukf_capacity",
    "ESTIMATOR_KINDS",
    "BYPASS_DTYPE",
    "bypass_step",
]

ESTIMATOR_KINDS = ("ukf", "bypass")
"""Names of the estimators :func:`make_estimator` builds."""

_N_ERR = 15  # error-state dimension: dp, dv, dtheta, db_a, db_g
_ADVANCE_CHUNK_S = 0.01  # without motion capture, advance the delayed fused state in steps of this much
_COV_STEP_S = 0.01  # longest step of the sigma-point (covariance) propagation [s]
MATCH_ON_RATIO = 2.0
"""The motion-capture noise is raised once the innovations show more than this many times the assumed one sigma
(averaged over ``mocap_adapt_samples``): a margin over the estimate's own scatter (its relative standard error
is about sqrt(2 / (3 n)) = 0.12 for 50 samples), so a filter whose noise is as assumed is never touched."""
MATCH_OFF_RATIO = 1.5
"""Once raised, the motion-capture noise goes back to the assumed one when the innovations show less than this
many times the assumed one sigma: a hysteresis, so that a noise about ``MATCH_ON_RATIO`` times the assumed is
matched rather than switched on and off (2 mm against 1 mm assumed, on and off, flew 1.2-1.35 times the position
error of a filter told the noise on the estimator's analytic flight); still far above the scatter of the estimate
for a noise as assumed (its relative standard error is about 0.12)."""
MATCH_CLIP_RATIO = 5.0
"""One motion-capture sample counts at most this many times the noise one sigma in use: an outlier moves the
running estimate by at most 25 / ``mocap_adapt_samples`` of the variance, while noise ten times the assumed
raises it by half each sample and is matched within about a dozen samples."""
MATCH_PRIOR_SAMPLES = 2
"""The running noise estimate starts as this many samples at the assumed variance, and is their plain mean with
the samples until its weight falls to ``1 / mocap_adapt_samples``: the fewest for which a noise as assumed is
raised by its first sample with a probability below 1e-5 (its mean must exceed ``MATCH_ON_RATIO``² = 4: P(χ²₃ >
30) = 1.4e-6). A noise five times the assumed is then matched from the first samples on, before the velocity and
the biases are fitted to it (7 prior samples, which no single clipped sample can move past the threshold, left
the closed-loop hover up to 1.35 times the error of a filter told the noise at 3 to 20 mm and 1.74 at 2 mm; 2 leave
at most 1.07, docs/reliability.md). A gross
outlier as the very first sample raises the noise to at most 3 times the one sigma for under twenty samples."""
_F64 = np.dtype(np.float64)  # the dtype of every array the compiled step takes


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
        mocap_adapt_noise: raise the motion-capture noise where the innovations show more than assumed
            (:func:`~omnirotor.control._estimator_kernels.match_noise`); off: always ``mocap_pos_std`` and
            ``mocap_att_std_deg``.
        mocap_adapt_samples: samples the running noise estimate averages over (its time constant).
        mocap_adapt_max_ratio: largest raised noise, as a multiple of the assumed one sigma.
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
        coast_acc_std: the acceleration the filter does not know while the IMU coasts (rejected samples
            replaced by the frame supervision's prediction, :mod:`omnirotor.control.supervisor`), one sigma
            [m/s²]: added as white acceleration noise over a 10 ms correlation, so motion capture steers it.
        bias_drift_m: a mean position innovation beyond this (or 1.15 times the motion-capture noise in use:
            5 standard deviations of the mean of white noise; the larger), averaged over about 10 samples, is a
            bias drifting faster than its random walk says; the bias random walks are then ``bias_drift_scale``
            times larger until it falls below half [m]. 4 mm: the calibrated plant's innovations (about 1 mm)
            never reach it in the paper's experiments (``reproduce --quick`` unchanged), a 1 m/s³ ramp does.
        bias_drift_scale: that factor on the bias random walks' standard deviations.
        acc_bias_range: the accelerometer bias the filter is documented to follow [m/s²]; an estimate beyond it
            (any component) is flagged ``ControlStatus.BIAS_BEYOND_RANGE``.
        gyro_bias_range: the same for the gyroscope [rad/s].
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
    mocap_adapt_noise: bool = True
    mocap_adapt_samples: int = 50
    mocap_adapt_max_ratio: float = 30.0
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
    coast_acc_std: float = 20.0
    bias_drift_m: float = 0.004
    bias_drift_scale: float = 1000.0
    acc_bias_range: float = 3.0
    gyro_bias_range: float = 0.5

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
            "mocap_adapt_max_ratio",
            "lever_arm_cutoff_hz",
            "init_pos_std",
            "init_vel_std",
            "init_att_std_deg",
            "init_acc_bias_std",
            "init_gyro_bias_std",
            "ut_alpha",
            "coast_acc_std",
            "bias_drift_m",
            "bias_drift_scale",
            "acc_bias_range",
            "gyro_bias_range",
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
        n = self.mocap_adapt_samples
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise InputError(f"estimator mocap_adapt_samples must be an integer >= 1, got {n!r}")
        if self.mocap_adapt_max_ratio < MATCH_ON_RATIO:
            raise InputError(
                f"estimator mocap_adapt_max_ratio must be >= {MATCH_ON_RATIO:g} (where raising starts), "
                f"got {self.mocap_adapt_max_ratio:g}"
            )
        if len(self.imu_offset_B) != 3:
            raise InputError(f"estimator imu_offset_B needs 3 values, got {len(self.imu_offset_B)}")
        check_finite("estimator imu_offset_B", *self.imu_offset_B)


# -- small helpers --------------------------------------------------------------------------------------------


# -- the UKF ------------------------------------------------------------------------------------------------


def _lag_and_chunk(p: EstimatorParams) -> tuple[int, int]:
    """IMU samples of the largest motion-capture latency, and of one advance of the fused state."""
    return int(math.ceil(p.mocap_max_latency_s * p.imu_rate_hz)), max(1, int(round(_ADVANCE_CHUNK_S * p.imu_rate_hz)))


def ukf_capacity(params: EstimatorParams) -> int:
    """Length of the UKF's ring buffers of IMU samples and output states for ``params``."""
    lag_n, chunk_n = _lag_and_chunk(params)
    return lag_n + chunk_n + 8


@register("estimator", "ukf")
class UKFEstimator:
    """Error-state unscented Kalman filter: 1 kHz IMU with delayed motion capture (module docstring).

    The filter's state, counters and parameters are one structured record (:attr:`state`, dtype
    :data:`~omnirotor.control._estimator_kernels.UKF_DTYPE`), its ring buffers and scratch three more
    structured record (:attr:`memory`, :func:`~omnirotor.control._estimator_kernels.memory_dtype`); once
    initialised, a step is one compiled call,
    :func:`~omnirotor.control._estimator_kernels.ukf_step`, which reads and writes their fields by name.

    A compiled loop may step the filter itself, after :meth:`reset` (or a first :meth:`step` that
    initialised it; ``initialised`` must be True), with ``ukf_step(state[0], m.imu_buf, m.state_buf, m.work,
    gyro_B, acc_B, t, mocap_new, mocap_t, p_m, q_m, out)`` (``m = memory[0]``, the record of :attr:`memory`):
    ``gyro_B``, ``acc_B`` (3,), ``p_m`` (3,), ``q_m`` (4,) and ``out`` (21,) float64 arrays (``p_m``, ``q_m``
    any such arrays without a sample, NaN for a sample announced without a well-formed pose), floats ``t``
    and ``mocap_t`` [s], the bool ``mocap_new``. It returns ``(code, t)``; the estimate is ``out`` (layout of
    ``write_estimate``) at time ``t``, valid unless ``code`` has ``STEP_DEGRADED``; the properties below then
    read the updated counters.

    Attributes:
        state: the ``(1,)`` record (``UKF_DTYPE``; a field of the controller's state when it owns the filter).
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
        P: (15, 15) covariance of the error state of the delayed fused state (a view, updated in place).
        memory: the ``(1,)`` ring buffers and scratch (:func:`~omnirotor.control._estimator_kernels.memory_dtype`
            of :func:`ukf_capacity` samples).
    """

    state_dtype = _ek.UKF_DTYPE
    log_fields = ()
    kernel = _ek.ukf_block_step

    def __init__(
        self,
        vehicle: VehicleParams,
        params: EstimatorParams | None = None,
        *,
        state: np.ndarray | None = None,
        memory: np.ndarray | None = None,
    ):
        """Allocate the filter; it initialises on the first frame with a pose (see :meth:`reset`).

        Args:
            vehicle: the vehicle (gravity).
            params: estimator parameters; defaults to :class:`EstimatorParams()`.
            state: optional ``(1,)`` array of ``UKF_DTYPE`` to keep the state in (e.g. a field of the
                controller's state).
            memory: optional ``(1,)`` array of ``memory_dtype(ukf_capacity(params))`` for the ring buffers
                and the scratch (the controller's field ``ukf_memory``).
        """
        self.params = p = params if params is not None else EstimatorParams()
        self.vehicle = vehicle
        self._g = vehicle.gravity
        self._dt_nom = 1.0 / p.imu_rate_hz
        lag_n, chunk_n = _lag_and_chunk(p)
        self.state = state_array(_ek.UKF_DTYPE, state, "UKF")
        self.memory = state_array(_ek.memory_dtype(ukf_capacity(p)), memory, "UKF memory")
        # The pose ukf_step gets for a sample announced without a well-formed one (rejected as non-finite).
        self._no_p = np.full(3, math.nan)
        self._no_q = np.full(4, math.nan)
        self._rec = u = self.state[0]
        self.P = u["P"]
        # Unscented-transform weights (mean, covariance).
        n = _N_ERR
        lam = p.ut_alpha**2 * (n + p.ut_kappa) - n
        u["w_mean"] = 0.5 / (n + lam)
        u["w_cov"] = 0.5 / (n + lam)
        u["w_mean"][0] = lam / (n + lam)
        u["w_cov"][0] = lam / (n + lam) + 1.0 - p.ut_alpha**2 + p.ut_beta
        # Process noise terms, initial covariance, measurement noise (position, attitude).
        u["Q1"], u["Q2"], u["Q3"] = self._process_noise_terms()
        u["P0"] = np.diag(
            [p.init_pos_std**2] * 3 + [p.init_vel_std**2] * 3 + [math.radians(p.init_att_std_deg) ** 2] * 3
            + [p.init_acc_bias_std**2] * 3 + [p.init_gyro_bias_std**2] * 3
        )  # fmt: skip
        att = math.radians(p.mocap_att_std_deg)
        u["var_pos_assumed"], u["var_att_assumed"] = p.mocap_pos_std**2, att * att
        u["adapt_noise"] = 1 if p.mocap_adapt_noise else 0
        u["adapt_alpha"] = 1.0 / p.mocap_adapt_samples
        u["adapt_on_ratio2"] = MATCH_ON_RATIO**2
        u["adapt_off_ratio2"] = MATCH_OFF_RATIO**2
        u["adapt_clip_ratio2"] = MATCH_CLIP_RATIO**2
        u["adapt_max_ratio2"] = p.mocap_adapt_max_ratio**2
        u["adapt_prior_n"] = float(MATCH_PRIOR_SAMPLES)
        u["g"] = self._g
        u["dt_nom"] = self._dt_nom
        u["gyro_range"] = p.gyro_range
        u["acc_range"] = p.acc_range
        u["r_imu_B"] = [float(c) for c in p.imu_offset_B]
        u["lever"] = 1 if any(c != 0.0 for c in p.imu_offset_B) else 0
        u["lever_cutoff_hz"] = p.lever_arm_cutoff_hz
        u["gyro_cutoff_hz"] = p.gyro_cutoff_hz
        u["acc_cutoff_hz"] = p.acc_cutoff_hz
        u["cov_n"] = max(1, int(round(_COV_STEP_S * p.imu_rate_hz)))
        u["ut_scale"] = math.sqrt(n + lam)
        u["max_latency_s"] = p.mocap_max_latency_s
        u["gate_chi2"] = p.mocap_gate_chi2
        u["reinit_after"] = p.mocap_reinit_after
        u["lag_n"] = lag_n
        u["chunk_n"] = chunk_n
        u["timeout_s"] = p.mocap_timeout_s
        u["q_coast"] = p.coast_acc_std**2 * 0.01
        u["drift_m"] = p.bias_drift_m
        u["drift_scale2"] = p.bias_drift_scale**2
        u["acc_bias_range"], u["gyro_bias_range"] = p.acc_bias_range, p.gyro_bias_range
        u["compensate_latency"] = 1 if p.compensate_latency else 0
        self._clear()

    # -- state -------------------------------------------------------------------------------------------

    _STATE_FIELDS = (
        "x_out", "R_WB_out", "x_fused", "R_WB_fused", "gyro_B", "acc_B", "gyro_corr_B", "acc_corr_B", "gyro_lp_B",
        "omega_dot_B", "omega_B", "a_W", "t", "t_fused", "t_accept", "lpf_dt", "lam_omega", "lam_acc", "dt", "k",
        "k_fused", "just_reset", "gate_fails", "n_mocap_fused", "n_rejected_mocap", "n_reinit", "n_rejected_inputs",
        "n_nonfinite", "last_rejected", "degraded", "noise_var_pos", "noise_var_att", "n_noise_adapted",
        "noise_pos_std_max", "noise_att_std_max", "noise_n", "noise_var_pos_top", "noise_var_att_top",
        "n_noise_discounts", "coasting", "innov_ema_W", "drift_on", "n_drift",
    )  # fmt: skip
    """The fields :meth:`reset` clears (the rest are parameters and constants)."""

    def _clear(self) -> None:
        """Forget everything: uninitialised, counters cleared, covariance back to the initial one."""
        self.initialised = False
        u = self._rec
        for name in self._STATE_FIELDS:
            u[name] = 0
        u["degraded"] = 1
        u["x_out"]["q_WB"][0] = 1.0  # output (current) nominal state: p, v, q (wxyz), b_a, b_g
        u["R_WB_out"] = np.eye(3)
        u["x_fused"] = u["x_out"]  # delayed fused state
        u["R_WB_fused"] = u["R_WB_out"]
        u["t_accept"] = -math.inf  # frame time of the last accepted motion-capture sample
        u["just_reset"] = 1  # no sample fused since the start-up pose
        u["acc_B"][2] = self._g  # last good sample: gyro_B, acc_B (raw)
        u["lpf_dt"] = math.nan
        u["lam_omega"] = u["lam_acc"] = 1.0
        u["P"] = u["P0"]
        u["Rn"] = np.diag([u["var_pos_assumed"]] * 3 + [u["var_att_assumed"]] * 3)
        # the running noise estimates start at the assumed noise (MATCH_PRIOR_SAMPLES), as its largest in use
        u["noise_var_pos"] = u["noise_var_pos_top"] = u["var_pos_assumed"]
        u["noise_var_att"] = u["noise_var_att_top"] = u["var_att_assumed"]

    def reset(self, frame: SensorFrame) -> None:
        """(Re)initialise from a frame: its motion-capture pose if it has one, else ``frame.state``.

        The motion-capture pose is taken as the pose at ``frame.t`` (the latency is ignored at start-up);
        the velocity comes from ``frame.state`` when the frame has one, else it is zero.

        Raises:
            InputError: the frame has neither a valid motion-capture sample nor a state.
        """
        self._clear()
        u = self._rec
        s = u["x_out"]
        state = frame.state if frame.state is not None and _state_finite(frame.state) else None
        if state is not None:
            s["v_W"] = state.v_W
        if self._mocap_valid(frame):
            s["p_W"] = frame.mocap_p_W
            q = np.asarray(frame.mocap_q_WB, dtype=float)
            s["q_WB"] = q / np.linalg.norm(q)
        elif state is not None:
            s["p_W"] = state.p_W
            s["q_WB"] = quat_wxyz_from_R(np.asarray(state.R_WB, dtype=float))
        else:
            raise InputError("the estimator needs a motion-capture sample or a state to initialise")
        _ek.R_from_quat_into(s["q_WB"], u["R_WB_out"])
        u["x_fused"] = s
        u["R_WB_fused"] = u["R_WB_out"]
        u["t"] = u["t_fused"] = frame.t
        u["t_accept"] = frame.t
        self.initialised = True
        u["degraded"] = 0
        gyro, acc = frame.imu_gyro_B.tolist(), frame.imu_acc_B.tolist()
        if self._imu_valid(gyro, acc):
            u["gyro_B"], u["acc_B"] = gyro, acc
        u["gyro_lp_B"] = u["gyro_B"]
        u["omega_B"] = [u["gyro_B"][i] - s["b_gyro_B"][i] for i in range(3)]
        u["a_W"] = 0.0

    @property
    def bias_acc_B(self) -> np.ndarray:
        """(3,) estimated accelerometer bias [m/s²]."""
        return self._rec["x_out"]["b_acc_B"].copy()

    @property
    def bias_gyro_B(self) -> np.ndarray:
        """(3,) estimated gyro bias [rad/s]."""
        return self._rec["x_out"]["b_gyro_B"].copy()

    @property
    def lag_s(self) -> float:
        """How far the delayed fused state lags the output [s]."""
        return float(self._rec["t"] - self._rec["t_fused"])

    # The counters and flags, kept in the state record (class docstring).

    @property
    def degraded(self) -> bool:
        """True while no motion-capture sample was accepted for the timeout (or before initialisation)."""
        return bool(self._rec["degraded"])

    @property
    def last_input_rejected(self) -> bool:
        """True when something in the last frame was rejected."""
        return bool(self._rec["last_rejected"])

    @property
    def rejected_inputs(self) -> int:
        """Count of frames in which the period, the IMU or the motion-capture sample was rejected."""
        return int(self._rec["n_rejected_inputs"])

    @property
    def rejected_mocap(self) -> int:
        """Count of motion-capture samples rejected (invalid, stale or outside the gate)."""
        return int(self._rec["n_rejected_mocap"])

    @property
    def n_mocap_fused(self) -> int:
        """Count of motion-capture samples fused."""
        return int(self._rec["n_mocap_fused"])

    @property
    def n_reinit(self) -> int:
        """Count of re-initialisations from motion capture after repeated gate failures."""
        return int(self._rec["n_reinit"])

    @property
    def n_noise_adapted(self) -> int:
        """Count of motion-capture samples weighed with a raised noise (``mocap_adapt_noise``)."""
        return int(self._rec["n_noise_adapted"])

    @property
    def mocap_noise_std(self) -> tuple[float, float]:
        """The motion-capture noise one sigma in use: position [m], attitude [rad]."""
        Rn = self._rec["Rn"]
        return math.sqrt(Rn[0, 0]), math.sqrt(Rn[3, 3])

    @property
    def mocap_noise_std_max(self) -> tuple[float, float]:
        """The largest motion-capture noise one sigma used so far: position [m], attitude [rad]."""
        return float(self._rec["noise_pos_std_max"]), float(self._rec["noise_att_std_max"])

    # -- validation ----------------------------------------------------------------------------------------

    def _imu_valid(self, gyro: list[float], acc: list[float]) -> bool:
        return bool(_ek.imu_valid(self._rec, np.asarray(gyro, dtype=float), np.asarray(acc, dtype=float)))

    @staticmethod
    def _mocap_valid(frame: SensorFrame) -> bool:
        if not frame.mocap_new or frame.mocap_p_W is None or frame.mocap_q_WB is None:
            return False
        p, q = frame.mocap_p_W, frame.mocap_q_WB
        if p.shape != (3,) or q.shape != (4,) or not math.isfinite(frame.mocap_t):
            return False
        return bool(_ek.mocap_sample_valid(p, q, _ek.QUAT_NORM_TOL))

    # -- the 1 kHz step ------------------------------------------------------------------------------------

    def step(self, frame: SensorFrame) -> StateEstimate:
        """Propagate with the frame's IMU sample, fuse its motion-capture sample if any, return the estimate.

        Args:
            frame: this period's sensor data.

        Returns:
            The estimate at ``frame.t`` (fresh arrays). ``valid`` is False while degraded.
        """
        out = new_records(ESTIMATE_DTYPE)
        if not self.initialised:
            if self._mocap_valid(frame) or (frame.state is not None and _state_finite(frame.state)):
                self.reset(frame)
            self.write_estimate(out)
            return estimate_of(frame.t, out, self.initialised and not self.degraded)
        # Every array goes to the kernel as float64 (another dtype would compile a variant of the whole step).
        gyro, acc = frame.imu_gyro_B, frame.imu_acc_B
        if gyro.dtype is not _F64 or acc.dtype is not _F64:
            gyro, acc = np.asarray(gyro, dtype=_F64), np.asarray(acc, dtype=_F64)
        mocap = bool(frame.mocap_new)
        p_m, q_m = self._no_p, self._no_q
        if mocap and frame.mocap_p_W is not None and frame.mocap_q_WB is not None:
            p, q = np.asarray(frame.mocap_p_W, dtype=_F64), np.asarray(frame.mocap_q_WB, dtype=_F64)
            if p.shape == (3,) and q.shape == (4,):
                p_m, q_m = p, q
        code, t = _ek.ukf_step_entry(
            self.state, self.memory, gyro, acc, float(frame.t), mocap, float(frame.mocap_t) if mocap else math.nan,
            p_m, q_m, out,
        )  # fmt: skip
        valid = not code & _ek.STEP_DEGRADED
        return estimate_of(t, out, valid)

    def write_estimate(self, out: np.ndarray) -> None:
        """The current estimate into ``out``, a ``(1,)`` array of :data:`~omnirotor.messages.ESTIMATE_DTYPE`."""
        _ek.write_estimate_into(self.state, out)

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


def _state_finite(state: StateEstimate) -> bool:
    """True if every entry of the estimate's arrays is finite."""
    return bool(
        np.isfinite(state.p_W).all()
        and np.isfinite(state.v_W).all()
        and np.isfinite(state.a_W).all()
        and np.isfinite(state.R_WB).all()
        and np.isfinite(state.omega_B).all()
    )


# -- bypass ----------------------------------------------------------------------------------------------------

BYPASS_DTYPE = np.dtype(
    [
        ("last", ESTIMATE_DTYPE),  # the last good state
        ("initialised", np.float64),  # 1 once a state was received
        ("degraded", np.float64),  # 1 when the last frame's state was missing or not finite
        ("last_rejected", np.float64),
        ("n_nonfinite", np.float64),  # frames whose state was missing or not finite
    ]
)
"""The bypass estimator's state (named fields)."""

BYPASS_NO_STATE = -1
""":func:`bypass_step`: the frame has no finite state and none was ever received (the plant gives none)."""


@jit
def bypass_step(s, r, out) -> int:
    """The bypass estimator on a frame's state: that state (kept as the last good one), or the last good state.

    Args:
        s: the frame's ``state`` record (:data:`~omnirotor.messages.ESTIMATE_DTYPE`; ``valid`` 0: none).
        r: the bypass state record (:data:`BYPASS_DTYPE`).
        out: the estimate record (:data:`~omnirotor.messages.ESTIMATE_DTYPE`).

    Returns:
        0, or ``STEP_REJECTED | STEP_DEGRADED`` when the last state is repeated, or ``BYPASS_NO_STATE``
        (nothing written) when there is none.
    """
    last = r.last
    if s.valid != 0.0 and state_finite(s):
        copy_state(s, last)
        copy_state(last, out)
        r.initialised = 1.0
        r.degraded = 0.0
        r.last_rejected = 0.0
        return 0
    if r.initialised == 0.0:
        return BYPASS_NO_STATE
    r.n_nonfinite += 1.0
    r.last_rejected = 1.0
    r.degraded = 1.0
    copy_state(last, out)
    return _ek.STEP_REJECTED | _ek.STEP_DEGRADED


@jit
def bypass_block_step(r, memory, f, out) -> int:
    """The estimator kind's step (:data:`omnirotor.blocks.KIND_STEPS`): :func:`bypass_step` on a frame head's state.

    ``memory`` (the controller's sized estimator memory) is not used: the signature is the kind's.
    """
    return bypass_step(f.state, r, out)


@jit_entry
def _bypass_step_entry(frame, state, out) -> int:
    """:func:`bypass_step` on ``(1,)`` arrays (a call from Python)."""
    return bypass_step(frame[0].state, state[0], out[0])


def estimate_of(t: float, record: np.ndarray, valid: bool) -> StateEstimate:
    """A :class:`~omnirotor.messages.StateEstimate` at time ``t`` (fresh arrays) of a ``(1,)`` estimate record."""
    o = record[0].copy()
    return StateEstimate(t, o["p_W"], o["v_W"], o["a_W"], o["R_WB"], o["omega_B"], valid)


@register("estimator", "bypass")
class BypassEstimator:
    """Pass the plant's ``SensorFrame.state`` (ground truth plus noise) through, for fast studies.

    A frame without a state, or with a non-finite one, repeats the last good state flagged invalid. The last
    good state and the flags live in :attr:`state` (:data:`BYPASS_DTYPE`), which :func:`bypass_step` updates
    (called by :meth:`step` and by the controller's compiled step).

    Attributes:
        state: the ``(1,)`` state record.
        degraded: True when the last frame's state was missing or non-finite.
        initialised: True once a state was received.
        rejected_inputs: count of frames whose state was missing or non-finite.
        last_input_rejected: True when the last frame's state was rejected.
    """

    state_dtype = BYPASS_DTYPE
    log_fields = ()
    kernel = bypass_block_step

    def __init__(
        self,
        vehicle: VehicleParams,
        params: EstimatorParams | None = None,
        *,
        state: np.ndarray | None = None,
        memory: np.ndarray | None = None,
    ):
        """Set up.

        Args:
            vehicle: the vehicle (unused, for a uniform interface).
            params: estimator parameters.
            state: optional ``(1,)`` array of :data:`BYPASS_DTYPE` (e.g. a field of the controller's state).
            memory: unused (the bypass has no sized memory), for the estimators' uniform interface.
        """
        self.params = params if params is not None else EstimatorParams(kind="bypass")
        self.vehicle = vehicle
        self.state = state_array(BYPASS_DTYPE, state, "bypass estimator")
        self._rec = self.state[0]
        self._rec["degraded"] = 1.0
        self._frame: np.ndarray | None = None
        self._out = new_records(ESTIMATE_DTYPE)

    @property
    def initialised(self) -> bool:
        """True once a state was received."""
        return bool(self._rec["initialised"])

    @property
    def degraded(self) -> bool:
        """True when the last frame's state was missing or non-finite."""
        return bool(self._rec["degraded"])

    @property
    def rejected_inputs(self) -> int:
        """Count of frames whose state was missing or non-finite."""
        return int(self._rec["n_nonfinite"])

    @property
    def last_input_rejected(self) -> bool:
        """True when the last frame's state was rejected."""
        return bool(self._rec["last_rejected"])

    def reset(self, frame: SensorFrame) -> None:
        """Start from the frame's state.

        Raises:
            InputError: the frame has no (finite) state: the plant does not provide one.
        """
        if frame.state is None or not _state_finite(frame.state):
            raise InputError("the bypass estimator needs SensorFrame.state (ground truth); this plant gives none")
        self.state[...] = np.zeros(1, dtype=BYPASS_DTYPE)
        self.step(frame)

    def step(self, frame: SensorFrame) -> StateEstimate:
        """Return ``frame.state``, or the last good state flagged invalid (:func:`bypass_step`).

        Raises:
            InputError: no state was ever received (the plant does not provide one).
        """
        n = np.asarray(frame.rotor_hz).shape[0]
        if self._frame is None or self._frame["rotor_hz"].shape[1] != n:
            self._frame = new_records(frame_dtype(n))
        frame.write_record(self._frame)
        code = _bypass_step_entry(self._frame, self.state, self._out)
        if code == BYPASS_NO_STATE:
            raise InputError("the bypass estimator needs SensorFrame.state (ground truth); this plant gives none")
        return estimate_of(frame.t, self._out, code == 0)


def make_estimator(
    vehicle: VehicleParams,
    params: EstimatorParams | None = None,
    *,
    state: np.ndarray | None = None,
    memory: np.ndarray | None = None,
) -> UKFEstimator | BypassEstimator:
    """The estimator ``params.kind`` names (its registered name: "ukf" or "bypass").

    Args:
        vehicle: the vehicle.
        params: estimator parameters.
        state: the ``(1,)`` array of the estimator's ``state_dtype`` to keep its state in (optional).
        memory: the ``(1,)`` array of its sized memory (the UKF's ring buffers; optional).
    """
    params = params if params is not None else EstimatorParams()
    cls = block_class("estimator", params.kind)
    return cls(vehicle, params, state=state, memory=memory)
