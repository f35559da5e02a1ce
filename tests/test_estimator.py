"""State estimation (SPEC §4.5) on analytic flights with synthetic IMU and delayed motion capture.

No simulator: a smooth 3-D flight with rotation is written in closed form, the IMU reads its specific force
and rate with white noise and constant biases, and motion capture samples the pose at 100 Hz, noisy and
late by 8 ms.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numba
import numpy as np
import pytest

from omnirotor.config import from_mapping
from omnirotor.control import _estimator_kernels as _ek
from omnirotor.control.estimator import BypassEstimator, EstimatorParams, UKFEstimator, estimate_of, make_estimator
from omnirotor.errors import InputError
from omnirotor.messages import ESTIMATE_DTYPE, SensorFrame, StateEstimate
from omnirotor.so3 import R_from_rpy, exp_so3, log_so3, quat_wxyz_from_R, vee
from omnirotor.vehicle import load_vehicle

VEHICLE = load_vehicle("omnirotor")
G = VEHICLE.gravity
DT = 1e-3
LATENCY_STEPS = 8
MOCAP_EVERY = 10  # 100 Hz
POS_SIGMA = 5e-4  # m
ATT_SIGMA_DEG = 0.2
ACC_SIGMA = 0.02 * math.sqrt(1000.0)  # per sample at 1 kHz, i.e. the default density 0.02 m/s²/√Hz
GYRO_SIGMA = 1e-3 * math.sqrt(1000.0)
B_A = np.array([0.15, -0.10, 0.20])
B_G = np.array([0.020, -0.015, 0.010])


# -- the analytic flight --------------------------------------------------------------------------------------


def pos(t):
    return np.stack([0.4 * np.sin(0.8 * t), 0.3 * np.sin(0.6 * t + 1.0), 1.0 + 0.2 * np.sin(1.1 * t)], -1)


def vel(t):
    return np.stack([0.32 * np.cos(0.8 * t), 0.18 * np.cos(0.6 * t + 1.0), 0.22 * np.cos(1.1 * t)], -1)


def acc(t):
    return np.stack([-0.256 * np.sin(0.8 * t), -0.108 * np.sin(0.6 * t + 1.0), -0.242 * np.sin(1.1 * t)], -1)


def rot(t, rate=1.0):
    """Roll, pitch and yaw swinging by 29, 23 and 46 degrees."""
    t = rate * t
    return R_from_rpy(0.5 * math.sin(0.9 * t), 0.4 * math.sin(0.7 * t + 0.5), 0.8 * math.sin(0.3 * t))


def omega_B(t, rate=1.0, h=1e-5):
    return vee(rot(t, rate).T @ (rot(t + h, rate) - rot(t - h, rate)) / (2 * h))


@dataclasses.dataclass
class Flight:
    ts: np.ndarray
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    R: np.ndarray
    w: np.ndarray
    frames: list


def make_flight(
    T=8.0, seed=0, noise=True, dropout=None, imu_offset=None, rate=1.0, mocap_shift=None, pos_sigma=POS_SIGMA
):
    """Frames of a flight; samples are read at the end of each 1 ms period (as a simulator reports them)."""
    rng = np.random.default_rng(seed)
    n = int(round(T / DT))
    ts = (np.arange(n) + 1) * DT
    P, V, A = pos(ts), vel(ts), acc(ts)
    R = np.array([rot(t, rate) for t in ts])
    W = np.array([omega_B(t, rate) for t in ts])
    f_B = np.einsum("sji,sj->si", R, A + [0.0, 0.0, G])
    if imu_offset is not None:  # the IMU away from the CoM also feels omega_dot x r + omega x (omega x r)
        Wd = np.gradient(W, DT, axis=0)
        f_B = f_B + np.cross(Wd, imu_offset) + np.cross(W, np.cross(W, imu_offset))
    acc_m = f_B + B_A + (rng.normal(0.0, ACC_SIGMA, (n, 3)) if noise else 0.0)
    gyr_m = W + B_G + (rng.normal(0.0, GYRO_SIGMA, (n, 3)) if noise else 0.0)
    frames = []
    for k in range(n):
        j = k - LATENCY_STEPS
        mocap = j >= 0 and j % MOCAP_EVERY == 0 and not (dropout and dropout[0] <= ts[j] < dropout[1])
        extra = {}
        if mocap:
            p_m = P[j] + rng.normal(0.0, pos_sigma, 3)
            if mocap_shift is not None and ts[j] >= mocap_shift[0]:
                p_m = p_m + mocap_shift[1]
            R_m = R[j] @ exp_so3(rng.normal(0.0, math.radians(ATT_SIGMA_DEG), 3))
            extra = dict(mocap_new=True, mocap_t=float(ts[j]), mocap_p_W=p_m, mocap_q_WB=quat_wxyz_from_R(R_m))
        frames.append(
            SensorFrame(
                t=float(ts[k]), imu_acc_B=acc_m[k].copy(), imu_gyro_B=gyr_m[k].copy(), rotor_hz=np.zeros(8), **extra
            )
        )
    return Flight(ts, P, V, A, R, W, frames)


@functools.cache
def flight(**kw):
    return make_flight(**kw)


def run(frames, params=None):
    est = UKFEstimator(VEHICLE, params or EstimatorParams())
    return est, [est.step(f) for f in frames]


def errors(fl, out):
    p = np.array([o.p_W for o in out]) - fl.p
    v = np.array([o.v_W for o in out]) - fl.v
    att_deg = np.array([np.degrees(np.linalg.norm(log_so3(fl.R[i].T @ o.R_WB))) for i, o in enumerate(out)])
    return np.linalg.norm(p, axis=1), np.linalg.norm(v, axis=1), att_deg


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def lowpass(x, cutoff_hz):
    lam = 2 * math.pi * DT * cutoff_hz / (2 * math.pi * DT * cutoff_hz + 1)
    y = np.zeros_like(x)
    acc_ = x[0] * 0.0
    for i, xi in enumerate(x):
        acc_ = acc_ + lam * (xi - acc_)
        y[i] = acc_
    return y


# -- tests ----------------------------------------------------------------------------------------------------


def test_params_validate():
    for bad in (
        {"kind": "ekf"},
        {"mocap_pos_std": 0.0},
        {"acc_cutoff_hz": -1.0},
        {"mocap_reinit_after": 0},
        {"imu_offset_B": (0.0, 0.0)},
        {"gyro_noise_density": float("nan")},
        {"ut_alpha": 0.0},
        {"mocap_adapt_samples": 0},
        {"mocap_adapt_samples": 2.5},
        {"mocap_adapt_max_ratio": 1.5},
    ):
        with pytest.raises(InputError):
            EstimatorParams(**bad)
    with pytest.raises(InputError):
        from_mapping(EstimatorParams, {"kind": "ukf", "latency": 0.01})
    assert from_mapping(EstimatorParams, {"imu_offset_B": [0, 0, 0.041]}).imu_offset_B == (0.0, 0.0, 0.041)


def test_tracks_a_rotating_flight_with_noise_biases_and_latency():
    fl = flight()
    est, out = run(fl.frames, EstimatorParams(acc_cutoff_hz=5.0))
    after = fl.ts > 2.0  # past the bias convergence
    e_p, e_v, e_att = errors(fl, out)
    # Better than one raw motion-capture sample (3-D noise sqrt(3) sigma), which is also 8 ms late.
    assert rms(e_p[after]) < math.sqrt(3) * POS_SIGMA
    assert rms(e_att[after]) < math.sqrt(3) * ATT_SIGMA_DEG and e_att[after].max() < 1.0
    # Three times better than differentiating motion capture (sqrt(2) sigma / 10 ms per axis).
    assert rms(e_v[after]) < math.sqrt(3) * math.sqrt(2) * POS_SIGMA / 0.01 / 3
    # The constant biases are found.
    np.testing.assert_allclose(est.bias_gyro_B, B_G, atol=2e-3)
    np.testing.assert_allclose(est.bias_acc_B, B_A, atol=0.03)
    # Outputs: p̈ without gravity (through the 5 Hz filter) and the bias-free rate (unfiltered by default).
    a_est = np.array([o.a_W for o in out])
    a_err = np.linalg.norm(a_est - lowpass(fl.a, 5.0), axis=1)
    assert rms(a_err[after]) < 0.2  # the filtered accelerometer noise is ~0.14 m/s²
    w_err = np.array([o.omega_B for o in out]) - fl.w
    assert np.abs(w_err[after].mean(axis=0)).max() < 2e-3  # no bias left
    assert rms(np.linalg.norm(w_err[after], axis=1)) < 1.3 * math.sqrt(3) * GYRO_SIGMA  # just the white noise
    first = next(k for k, f in enumerate(fl.frames) if f.mocap_new)  # initialises the filter
    assert not any(o.valid for o in out[:first]) and all(o.valid for o in out[first:]) and not est.degraded
    assert est.rejected_inputs == 0 and est.rejected_mocap == 0
    assert est.n_mocap_fused == sum(f.mocap_new for f in fl.frames) - 1  # the first one initialised


def test_latency_compensation_matters():
    fl = flight()
    after = fl.ts > 2.0
    _, out = run(fl.frames)
    _, out_naive = run(fl.frames, EstimatorParams(compensate_latency=False))
    e_p, _, e_att = errors(fl, out)
    e_p_naive, _, e_att_naive = errors(fl, out_naive)
    # Fusing 8 ms old poses as if they were current drags the estimate ~v * 8 ms (up to 3.5 mm) behind.
    assert rms(e_p_naive[after]) > 3.0 * rms(e_p[after])
    assert rms(e_att_naive[after]) > 1.5 * rms(e_att[after])


def test_dropout_degrades_then_recovers():
    t0, t1 = 5.0, 5.5
    fl = flight(dropout=(t0, t1))
    est, out = run(fl.frames, EstimatorParams(mocap_timeout_s=0.1))
    e_p, _, e_att = errors(fl, out)
    valid = np.array([o.valid for o in out])
    ts = fl.ts
    last_before = t0 - DT * MOCAP_EVERY + LATENCY_STEPS * DT  # arrival of the last sample before the dropout
    first_after = t1 + LATENCY_STEPS * DT  # arrival of the first one after
    assert valid[(ts > 2.0) & (ts < last_before + 0.1 - 1e-9)].all()
    assert not valid[(ts > last_before + 0.1 + 2e-3) & (ts < first_after - 1e-9)].any()
    assert valid[ts >= first_after + 1e-9].all() and not est.degraded
    # On the IMU alone for 0.5 s the estimate drifts, but only by millimetres.
    during = (ts >= t0) & (ts < first_after)
    assert e_p[during].max() < 0.01
    assert e_att[during].max() < 0.5
    assert e_p[during].max() > 2.0 * rms(e_p[(ts > 2.0) & (ts < t0)])  # it does drift without motion capture
    settled = ts > first_after + 0.3
    assert rms(e_p[settled]) < math.sqrt(3) * POS_SIGMA


def test_bad_imu_samples_are_rejected_without_harm():
    fl = flight(T=4.0)
    bad = list(fl.frames)
    corrupt = {
        2000: dict(imu_acc_B=np.array([np.nan, 0.0, G])),
        2001: dict(imu_gyro_B=np.array([0.0, np.inf, 0.0])),
        2500: dict(imu_acc_B=np.array([0.0, 0.0, 5e3])),  # beyond the 16 g range
        3000: dict(imu_gyro_B=np.array([100.0, 0.0, 0.0])),
    }  # beyond 2000 deg/s
    for k, change in corrupt.items():
        bad[k] = dataclasses.replace(bad[k], **change)
    est_ok, out_ok = run(fl.frames)
    est, out = run(bad)
    assert est.rejected_inputs == len(corrupt)
    est2 = UKFEstimator(VEHICLE, EstimatorParams())  # replay, reading the per-step flag
    flags = []
    for f in bad:
        est2.step(f)
        flags.append(est2.last_input_rejected)
    assert [k for k, x in enumerate(flags) if x] == sorted(corrupt)
    for o in out:
        assert all(np.all(np.isfinite(a)) for a in (o.p_W, o.v_W, o.a_W, o.R_WB, o.omega_B))
    # Holding the previous sample for one period changes the estimate by micrometres.
    diff = np.array([np.linalg.norm(a.p_W - b.p_W) for a, b in zip(out, out_ok, strict=True)])
    assert diff.max() < 1e-4
    e_p, _, _ = errors(fl, out)
    assert rms(e_p[fl.ts > 2.0]) < math.sqrt(3) * POS_SIGMA


def test_bad_motion_capture_is_rejected():
    fl = flight(T=4.0)
    frames = list(fl.frames)
    k_jump = next(k for k in range(3000, 3100) if frames[k].mocap_new)
    k_nan = next(k for k in range(k_jump + 1, k_jump + 50) if frames[k].mocap_new)
    k_quat = next(k for k in range(k_nan + 1, k_nan + 50) if frames[k].mocap_new)
    frames[k_jump] = dataclasses.replace(frames[k_jump], mocap_p_W=frames[k_jump].mocap_p_W + [0.0, 0.3, 0.0])
    frames[k_nan] = dataclasses.replace(frames[k_nan], mocap_p_W=np.array([np.nan, 0.0, 1.0]))
    frames[k_quat] = dataclasses.replace(frames[k_quat], mocap_q_WB=np.array([0.1, 0.0, 0.0, 0.0]))
    est, out = run(frames)
    assert est.rejected_mocap == 3 and est.rejected_inputs == 3
    e_p, _, _ = errors(fl, out)
    assert e_p[k_jump : k_jump + 100].max() < 3e-3  # not pulled towards the 0.3 m outlier
    assert est.n_reinit == 0
    assert est.n_noise_adapted == 0  # one outlier is no evidence of a noisier motion capture


def test_noise_as_assumed_runs_exactly_as_without_matching():
    # 0.5 mm of noise against the 1 mm assumed: the matching never acts, to the last bit.
    fl = flight()
    est, out = run(fl.frames)
    _, out_off = run(fl.frames, EstimatorParams(mocap_adapt_noise=False))
    for a, b in zip(out, out_off, strict=True):
        assert np.array_equal(a.p_W, b.p_W) and np.array_equal(a.v_W, b.v_W) and np.array_equal(a.R_WB, b.R_WB)
    assert est.n_noise_adapted == 0 and est.mocap_noise_std == pytest.approx((1e-3, math.radians(0.5)), rel=1e-12)


@pytest.mark.parametrize("sigma", [3e-3, 1e-2])
def test_noisier_motion_capture_than_assumed_is_matched(sigma):
    """Motion capture 3 and 10 times noisier than the 1 mm assumed: the filter finds the noise and flies as well
    as one told the true noise; without the matching, 10 mm flew tens of metres off in closed loop."""
    fl = make_flight(T=8.0, pos_sigma=sigma)
    after = fl.ts > 3.0
    est, out = run(fl.frames)
    _, out_told = run(fl.frames, EstimatorParams(mocap_pos_std=sigma))
    est_off, out_off = run(fl.frames, EstimatorParams(mocap_adapt_noise=False))
    e_p = rms(errors(fl, out)[0][after])
    e_told = rms(errors(fl, out_told)[0][after])
    e_off = rms(errors(fl, out_off)[0][after])
    # measured: 1.85 / 1.84 mm (3 mm), 4.61 / 4.55 mm (10 mm) against the filter told the noise
    assert e_p < 1.1 * e_told
    assert e_off > 1.2 * e_p  # and it matters: 2.36 mm (3 mm), 234 mm with 28 re-initialisations (10 mm)
    # the noise it found (per axis, beyond what its own uncertainty explains): 2.78 and 9.36 mm measured
    assert 0.8 * sigma < est.mocap_noise_std[0] < 1.1 * sigma
    assert est.mocap_noise_std[1] == pytest.approx(math.radians(0.5), rel=1e-12)  # the attitude noise was as assumed
    assert est.n_noise_adapted > 0.9 * sum(f.mocap_new for f in fl.frames if f.t > 1.0)
    assert est.rejected_mocap < 0.1 * est_off.rejected_mocap + 20


def test_matching_stays_within_its_bounds_and_ends_with_the_noise():
    """Fed innovations directly: the running estimate follows the noise's variance, the noise in use never
    exceeds ``mocap_adapt_max_ratio`` times the assumed, and returns to the assumed one when the noise does."""
    params = EstimatorParams(mocap_adapt_max_ratio=8.0)
    est = UKFEstimator(VEHICLE, params)
    est.reset(flight(T=0.2).frames[LATENCY_STEPS])
    u = est.state[0]
    rng = np.random.default_rng(3)
    r = np.zeros(6)
    used = []
    for k in range(1500):
        sigma = 20e-3 if k < 500 else (4e-3 if k < 1000 else 0.5e-3)
        r[:3] = rng.normal(0.0, sigma, 3)
        r[3:] = rng.normal(0.0, math.radians(0.1), 3)
        u["P"][:] = 0.0  # a certain state (no update here shrinks P0 after the reset): the innovation is the noise
        _ek.match_noise(u, r)
        used.append(math.sqrt(u["Rn"][0, 0]))
    used = np.array(used)
    assert used[300:500].max() == pytest.approx(8e-3)  # 20 mm capped at 8 x 1 mm
    assert np.median(used[800:1000]) == pytest.approx(4e-3, rel=0.15)
    assert np.all(used[1300:] == 1e-3)  # back to the assumed noise
    assert math.sqrt(u["Rn"][3, 3]) == pytest.approx(math.radians(0.5))  # the attitude: never raised


@pytest.mark.parametrize("sigma", [2e-3, 5e-3, 20e-3])
def test_matched_filter_flies_as_one_told_the_noise_from_the_start(sigma):
    """2 to 20 times the assumed noise (1 mm), seeds 0 to 2, the start-up included: the noise is matched within a
    few samples, before the velocity and biases are fitted to it, so the filter flies as one told the noise and
    gates nothing out. Before (a slow start, P reset to P0 past 5 times the assumed sigma, no hysteresis) 5 mm
    gated 17 samples out and was reset mid-start, and 2 mm, switched on and off about the threshold, flew 1.2 to
    1.35 times the error of the filter told the noise."""
    n_samples = None
    for seed in range(3):
        fl = make_flight(T=5.0, pos_sigma=sigma, seed=seed)
        after = fl.ts > 0.5
        est, out = run(fl.frames)
        est_told, out_told = run(fl.frames, EstimatorParams(mocap_pos_std=sigma))
        e_p = rms(errors(fl, out)[0][after])
        e_told = rms(errors(fl, out_told)[0][after])
        assert e_p < 1.1 * e_told  # measured 1.00 to 1.02 times
        # a few samples gated out before the noise is found (20 mm: up to 3; before: 17 at 5 mm)
        assert est.rejected_mocap <= est_told.rejected_mocap + 3 and est.n_reinit == 0
        n_samples = sum(f.mocap_new for f in fl.frames)
        assert est.n_noise_adapted > n_samples - 10  # raised within a few samples and held (the hysteresis)
        assert 0.8 * sigma < est.mocap_noise_std[0] < 1.2 * sigma


def test_told_more_noise_than_there_is_the_filter_runs_as_without_matching():
    """Told 5 mm of a 1 mm motion capture: the matching never acts (the estimate starts at the assumed noise and
    only raises it), so the filter is not made worse: to the last bit, as without the matching."""
    fl = make_flight(T=4.0, pos_sigma=1e-3)
    told = EstimatorParams(mocap_pos_std=5e-3)
    est, out = run(fl.frames, told)
    _, out_off = run(fl.frames, dataclasses.replace(told, mocap_adapt_noise=False))
    for a, b in zip(out, out_off, strict=True):
        assert np.array_equal(a.p_W, b.p_W) and np.array_equal(a.v_W, b.v_W) and np.array_equal(a.R_WB, b.R_WB)
    assert est.n_noise_adapted == 0


def _fed(est, sigmas, seed=4):
    """Feed ``match_noise`` innovations of the position noise ``sigmas[k]`` on a certain state; the noise in use."""
    u = est.state[0]
    rng = np.random.default_rng(seed)
    r = np.zeros(6)
    used = []
    for sigma in sigmas:
        r[:3] = rng.normal(0.0, sigma, 3)
        r[3:] = rng.normal(0.0, math.radians(0.1), 3)
        u["P"][:] = 0.0
        _ek.match_noise(u, r)
        used.append(math.sqrt(u["Rn"][0, 0]))
    return np.array(used)


def test_matching_starts_fast_and_holds_a_noise_about_its_threshold():
    est = UKFEstimator(VEHICLE)
    est.reset(flight(T=0.2).frames[LATENCY_STEPS])
    # five times the assumed sigma: raised from the first few samples (the plain mean of the start)
    used = _fed(est, [5e-3] * 20)
    assert np.argmax(used > 1e-3) <= 4 and np.all(used[4:] > 2e-3)
    # then 1.8 times: between the off (1.5) and on (2) thresholds, it stays matched instead of switching off
    used = _fed(est, [1.8e-3] * 400)
    assert np.all(used[200:] > 1e-3) and np.median(used[200:]) == pytest.approx(1.8e-3, rel=0.15)
    # a gross outlier as the very first sample: at most 3 times the sigma (the clip and the start's 2 prior
    # samples), back to the assumed within about twenty samples (17)
    est.reset(flight(T=0.2).frames[LATENCY_STEPS])
    used = _fed(est, [1.0] + [1e-3] * 30)
    assert used.max() <= 3e-3 + 1e-12 and np.all(used[20:] == 1e-3)
    # a noise as assumed: never raised from the start on
    est.reset(flight(T=0.2).frames[LATENCY_STEPS])
    assert np.all(_fed(est, [1e-3] * 300) == 1e-3)


def test_covariance_is_discounted_by_the_noise_ratio_up_to_the_start_up_uncertainty():
    rng = np.random.default_rng(5)
    A = rng.normal(size=(15, 15))
    P = A @ A.T * 1e-4
    P0 = np.diag(np.diag(P) * rng.uniform(1.0, 40.0, 15))
    d = np.minimum(9.0, np.diag(P0) / np.diag(P))
    out = P.copy()
    _ek.discount_covariance(out, P0, 9.0)
    np.testing.assert_allclose(np.diag(out), np.diag(P) * d, rtol=1e-12)
    assert np.diag(out).max() > np.diag(P).max() and np.all(np.diag(out) <= np.diag(P0) * (1 + 1e-12))
    corr = lambda M: M / np.sqrt(np.outer(np.diag(M), np.diag(M)))  # noqa: E731
    np.testing.assert_allclose(corr(out), corr(P), atol=1e-12)  # the correlations are kept
    assert np.linalg.eigvalsh(out).min() > 0.0
    # matching in a filter: the discount follows each rise of the noise in use, once per new top
    est = UKFEstimator(VEHICLE)
    est.reset(flight(T=0.2).frames[LATENCY_STEPS])
    u = est.state[0]
    u["P"][:] = np.diag(np.diag(u["P0"])) * 1e-4
    before = u["P"][0, 0]
    _ek.match_noise(u, np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))  # nothing raised: P untouched
    assert u["P"][0, 0] == before and u["n_noise_discounts"] == 0
    r = np.array([0.03, -0.03, 0.03, 0.0, 0.0, 0.0])
    _ek.match_noise(u, r)
    _ek.match_noise(u, r)
    assert u["n_noise_discounts"] >= 1
    assert u["P"][0, 0] == pytest.approx(before * u["Rn"][0, 0] / 1e-6, rel=1e-9)


def test_persistent_offset_reinitialises_the_pose():
    shift = np.array([0.5, 0.0, 0.0])  # the rig re-zeroed by 0.5 m at t = 3 s
    fl = make_flight(T=5.0, mocap_shift=(3.0, shift))
    params = EstimatorParams(mocap_reinit_after=10)
    est, out = run(fl.frames, params)
    assert est.n_reinit == 1
    p_est = np.array([o.p_W for o in out])
    end = fl.ts > 4.5
    assert rms(np.linalg.norm(p_est[end] - (fl.p[end] + shift), axis=1)) < 2e-3  # follows the new frame


def test_initialisation_waits_for_a_pose():
    fl = flight(T=1.0)
    est = UKFEstimator(VEHICLE)
    first = next(k for k, f in enumerate(fl.frames) if f.mocap_new)
    for f in fl.frames[:first]:
        e = est.step(f)
        assert not e.valid and not est.initialised
    e = est.step(fl.frames[first])
    assert e.valid and est.initialised
    np.testing.assert_allclose(e.p_W, fl.frames[first].mocap_p_W)
    with pytest.raises(InputError):
        est.reset(fl.frames[0])
    # A frame with a state (and no motion capture) also initialises, velocity included.
    f = fl.frames[0]
    state = StateEstimate(t=f.t, p_W=fl.p[0], v_W=fl.v[0], a_W=fl.a[0], R_WB=fl.R[0], omega_B=fl.w[0])
    est.reset(dataclasses.replace(f, state=state))
    e = est.step(fl.frames[1])
    np.testing.assert_allclose(e.v_W, fl.v[1], atol=0.05)
    # Started from a state, the filter still takes a motion-capture sample taken just before start-up.
    start = first - 2  # the first sample was taken at frames[first - LATENCY_STEPS].t < frames[start].t
    f = fl.frames[start]
    state = StateEstimate(
        t=f.t, p_W=fl.p[start], v_W=fl.v[start], a_W=fl.a[start], R_WB=fl.R[start], omega_B=fl.w[start]
    )
    est.reset(dataclasses.replace(f, state=state))
    for f in fl.frames[start + 1 : first + 1]:
        est.step(f)
    assert est.rejected_mocap == 0 and est.n_mocap_fused == 1


def test_lever_arm_is_compensated():
    r = (0.05, -0.03, 0.2)
    fl = flight(T=3.0, noise=False, imu_offset=r, rate=3.0)
    after = fl.ts > 1.0
    results = {}
    for label, offset in (("compensated", r), ("ignored", (0.0, 0.0, 0.0))):
        _, out = run(fl.frames, EstimatorParams(imu_offset_B=offset, acc_cutoff_hz=0.0))
        a_err = np.linalg.norm(np.array([o.a_W for o in out]) - fl.a, axis=1)
        results[label] = rms(a_err[after])
    assert results["ignored"] > 0.05  # the lever arm is visible ...
    assert results["compensated"] < 0.2 * results["ignored"]  # ... and removed


def test_bypass_passes_the_state_through():
    f = flight(T=0.1).frames[0]
    est = make_estimator(VEHICLE, EstimatorParams(kind="bypass"))
    assert isinstance(est, BypassEstimator)
    with pytest.raises(InputError):
        est.step(f)
    state = StateEstimate(t=f.t, p_W=np.ones(3), v_W=np.zeros(3), a_W=np.zeros(3), R_WB=np.eye(3), omega_B=np.zeros(3))
    passed = est.step(dataclasses.replace(f, state=state))
    assert passed.valid and passed.t == state.t
    for name in ("p_W", "v_W", "a_W", "R_WB", "omega_B"):
        np.testing.assert_array_equal(getattr(passed, name), getattr(state, name))
    held = est.step(dataclasses.replace(f, t=f.t + DT))
    assert not held.valid and held.t == f.t + DT and est.degraded and est.rejected_inputs == 1
    np.testing.assert_array_equal(held.p_W, state.p_W)
    nan_state = dataclasses.replace(state, p_W=np.array([np.nan, 0.0, 0.0]))
    assert not est.step(dataclasses.replace(f, state=nan_state)).valid
    assert est.step(dataclasses.replace(f, state=state)).valid and not est.degraded
    assert isinstance(make_estimator(VEHICLE), UKFEstimator)


def test_estimates_are_fresh_and_runs_deterministic():
    fl = flight(T=0.3)
    est_a, out_a = run(fl.frames)
    est_b, out_b = run(fl.frames)
    for a, b in zip(out_a, out_b, strict=True):
        for name in ("p_W", "v_W", "a_W", "R_WB", "omega_B"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    # Each estimate owns its arrays: a later step does not change an earlier message.
    first, second = out_a[-2], out_a[-1]
    for name in ("p_W", "v_W", "a_W", "R_WB", "omega_B"):
        assert not np.shares_memory(getattr(first, name), getattr(second, name))
    np.testing.assert_allclose(est_a.P, est_b.P)


# -- the compiled step against the orchestration it replaced ---------------------------------------------------


def _reference_mocap_valid(frame):
    """The motion-capture checks UKFEstimator.step made in Python before ukf_step."""
    if not frame.mocap_new or frame.mocap_p_W is None or frame.mocap_q_WB is None:
        return False
    p, q = frame.mocap_p_W, frame.mocap_q_WB
    if p.shape != (3,) or q.shape != (4,) or not math.isfinite(frame.mocap_t):
        return False
    return bool(_ek.mocap_sample_valid(p, q, _ek.QUAT_NORM_TOL))


def _reference_step(est, frame, c):
    """UKFEstimator.step as it was before ukf_step: one kernel call per stage, counters in the dict ``c``.

    ``est`` supplies the memory and the Python start-up (reset); its own counters are not used. ``c`` also
    counts the stale samples and the advances of the delayed state, to show what the sequence exercised.
    """
    out_record = np.zeros(1, ESTIMATE_DTYPE)
    out = out_record[0]
    if not est.initialised:
        if _reference_mocap_valid(frame):
            est.reset(frame)
            c.update(fused=0, rejected_mocap=0, reinit=0, rejected_inputs=0, last_rejected=False, degraded=False)
        _ek.write_estimate_into(est.state, out_record)
        valid = est.initialised and not c["degraded"]
        return estimate_of(float(frame.t), out_record, valid)
    m = est.memory[0]
    u, buf, sbuf, w = est.state[0], m["imu_buf"], m["state_buf"], m["work"]
    mocap = frame.mocap_new
    code, t = _ek.imu_step(u, buf, sbuf, frame.imu_gyro_B, frame.imu_acc_B, frame.t)
    if not mocap:
        code |= _ek.finish(u, out)
    rejected = code & _ek.STEP_REJECTED
    if mocap:
        if _reference_mocap_valid(frame):
            t_m = frame.mocap_t if est.params.compensate_latency else t
            p_m, q_m = np.asarray(frame.mocap_p_W, dtype=float), np.asarray(frame.mocap_q_WB, dtype=float)
            k_m = _ek.fuse_at(u, buf, float(t_m))
            if k_m < 0:
                fused = _ek.FUSE_STALE
                c["stale"] += 1
            else:
                _ek.predict(u, buf, sbuf, w, k_m)
                fused = _ek.fuse(u, buf, sbuf, w, p_m, q_m)
            if fused == _ek.FUSE_OK:
                c["fused"] += 1
            else:
                c["rejected_mocap"] += 1
                c["reinit"] += fused == _ek.FUSE_REINIT
                rejected = True
        else:
            c["rejected_mocap"] += 1
            rejected = True
        code = _ek.finish(u, out)
    if code & _ek.STEP_ADVANCE:
        c["advance"] += 1
        _ek.predict(u, buf, sbuf, w, int(u["k"]) - int(u["lag_n"]))
    if rejected:
        c["rejected_inputs"] += 1
    c["last_rejected"] = bool(rejected)
    c["degraded"] = degraded = bool(code & _ek.STEP_DEGRADED)
    return estimate_of(t, out_record, not degraded)


def _faulty_frames():
    """A flight with every kind of bad input, a dropout that degrades, and a re-zeroed rig that re-initialises.

    Returns the frames, the indices of the frames in which something is rejected by construction, and those of
    the samples that are rejected only when the latency is compensated (taken too early or in the future).
    """
    fl = make_flight(T=1.6, seed=3, dropout=(0.9, 1.15), mocap_shift=(1.3, np.array([0.3, 0.0, 0.0])))
    frames = list(fl.frames)
    mocap_ks = [k for k, f in enumerate(frames) if f.mocap_new]

    def mocap_after(t):
        return next(k for k in mocap_ks if frames[k].t > t)

    rep = dataclasses.replace
    changes = {
        300: dict(imu_acc_B=np.array([np.nan, 0.0, G])),
        301: dict(imu_gyro_B=np.array([0.0, 100.0, 0.0])),  # beyond the range
        350: dict(t=frames[349].t),  # the period does not increase
    }
    k = mocap_after(0.4)
    changes[k] = dict(mocap_q_WB=frames[k].mocap_q_WB * 0.1)  # not a unit quaternion
    k = mocap_after(0.45)
    changes[k] = dict(mocap_p_W=np.array([np.nan, 0.0, 1.0]))
    late = [mocap_after(0.5), mocap_after(0.55)]
    changes[late[0]] = dict(mocap_t=frames[late[0]].t - 0.1)  # stale: older than the largest latency
    changes[late[1]] = dict(mocap_t=frames[late[1]].t + 0.01)  # from the future
    k = mocap_after(0.6)
    changes[k] = dict(mocap_p_W=None)  # announced without a pose
    k = mocap_after(0.65)
    changes[k] = dict(mocap_t=math.nan)
    k = mocap_after(0.7)
    changes[k] = dict(mocap_p_W=frames[k].mocap_p_W + [0.0, 0.3, 0.0])  # outside the gate
    k = mocap_after(0.75)
    changes[k] = dict(imu_gyro_B=np.array([np.inf, 0.0, 0.0]))  # a bad IMU sample with a good pose
    for k, change in changes.items():
        frames[k] = rep(frames[k], **change)
    return frames, sorted(set(changes) - set(late)), late


@pytest.mark.parametrize(
    "params",
    [
        EstimatorParams(),
        EstimatorParams(
            compensate_latency=False, mocap_reinit_after=3, imu_offset_B=(0.01, -0.02, 0.04), gyro_cutoff_hz=20.0
        ),
    ],
    ids=["default", "naive-lever-arm"],
)
def test_compiled_step_is_bit_identical_to_the_kernel_orchestration(params):
    frames, bad, late = _faulty_frames()
    if params.compensate_latency:
        bad = bad + late
    est, ref = UKFEstimator(VEHICLE, params), UKFEstimator(VEHICLE, params)
    c = dict(fused=0, rejected_mocap=0, reinit=0, rejected_inputs=0, last_rejected=False, degraded=True)
    c.update(stale=0, advance=0)
    flagged, degraded = [], []
    for k, f in enumerate(frames):
        a, b = est.step(f), _reference_step(ref, f, c)
        assert a.t == b.t and a.valid == b.valid, k
        for name in ("p_W", "v_W", "a_W", "R_WB", "omega_B"):
            assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), (k, name)
        assert _memory(est, counters=False) == _memory(ref, counters=False), k  # every state, buffer and P
        counters = (est.n_mocap_fused, est.rejected_mocap, est.n_reinit, est.rejected_inputs)
        assert counters == (c["fused"], c["rejected_mocap"], c["reinit"], c["rejected_inputs"]), k
        assert (est.last_input_rejected, est.degraded) == (c["last_rejected"], c["degraded"]), k
        flagged.append(est.last_input_rejected)
        degraded.append(est.degraded)
    # The sequence exercised what it was built for.
    assert set(bad) <= {k for k, x in enumerate(flagged) if x}  # plus the gate failures of the re-zeroed rig
    assert (
        c["stale"] >= (len(late) if params.compensate_latency else 0)
        and c["reinit"] == 1
        and c["fused"] > 0
        and c["advance"] > 0
    )
    assert any(degraded) and not degraded[-1]


# -- the kernels' workspace ------------------------------------------------------------------------------------

_NAIVE_LEVER_ARM = EstimatorParams(
    compensate_latency=False, mocap_reinit_after=3, imu_offset_B=(0.01, -0.02, 0.04), gyro_cutoff_hz=20.0
)


_COUNTERS = ("n_mocap_fused", "n_rejected_mocap", "n_reinit", "n_rejected_inputs", "n_nonfinite", "last_rejected")


def _memory(est, counters: bool = True) -> bytes:
    """The estimator's state record and ring buffers (not its scratch), as bytes; without the counters if asked."""
    state = est.state.copy()
    if not counters:
        for name in (*_COUNTERS, "degraded"):
            state[name] = 0
    m = est.memory[0]
    return b"".join(a.tobytes() for a in (state, m["imu_buf"], m["state_buf"]))


@pytest.mark.parametrize("params", [EstimatorParams(), _NAIVE_LEVER_ARM], ids=["default", "naive-lever-arm"])
def test_workspace_holds_no_state(params):
    """NaN in the workspace before every step changes nothing: it overlaps no state and is written before read."""
    frames, _, _ = _faulty_frames()
    est, ref = UKFEstimator(VEHICLE, params), UKFEstimator(VEHICLE, params)
    work = est.memory["work"]
    assert not any(np.shares_memory(work, a) for a in (est.state, est.memory["imu_buf"], est.memory["state_buf"]))
    # Before these frames P loses positive definiteness, so that the next prediction takes the Cholesky
    # fall-backs (P symmetrised with jitter; P reset to P0) and their work arrays.
    broken = {600: -1e-13, 1000: -1.0}
    used = 0
    for k, f in enumerate(frames):
        if k in broken:
            for e in (est, ref):
                e.P[3, 3] = broken[k]
                e.P[3, 4] += 1e-9
        work.view(np.float64)[:] = np.nan
        a, b = est.step(f), ref.step(f)
        used += not np.isnan(work.view(np.float64)).all()
        assert a.t == b.t and a.valid == b.valid, k
        for name in ("p_W", "v_W", "a_W", "R_WB", "omega_B"):
            assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), (k, name)
        assert _memory(est) == _memory(ref), k  # states, counters, buffers, P
    # The steps did use the workspace (every fusion does), and the sequence re-initialised once.
    assert est.n_mocap_fused > 0 and est.n_reinit == 1 and used >= est.n_mocap_fused
    u = est.state[0]
    floats = [u[name] for name in u.dtype.names if u.dtype[name].base == np.float64]
    floats += [u[x][name] for x in ("x_out", "x_fused") for name in _ek.NOMINAL_DTYPE.names]
    assert all(np.isfinite(a).all() for a in floats)


@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="NUMBA_DISABLE_JIT=1: kernels run as Python, no numba allocator")
def test_compiled_step_allocates_nothing():
    """A step that fuses motion capture allocates no more than one that does not (the arguments' unboxing)."""
    from numba.core.runtime import _nrt_python, rtsys

    fl = flight(T=0.3)
    est = UKFEstimator(VEHICLE, EstimatorParams())
    frames = fl.frames
    for f in frames[:100]:  # initialised, compiled, fused
        est.step(f)
    was_enabled = _nrt_python.memsys_stats_enabled()
    _nrt_python.memsys_enable_stats()
    try:
        counts = {True: set(), False: set()}
        for f in frames[100:200]:
            before = rtsys.get_allocation_stats()
            est.step(f)
            after = rtsys.get_allocation_stats()
            counts[bool(f.mocap_new)].add((after.alloc - before.alloc, after.mi_alloc - before.mi_alloc))
    finally:
        if not was_enabled:
            _nrt_python.memsys_disable_stats()
    assert len(counts[True]) == 1 and counts[True] == counts[False], counts
