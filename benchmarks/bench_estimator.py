"""Time per 1 kHz step of the UKF state estimator with 100 Hz motion capture 8 ms late (SPEC §4.5).

Run: ``python benchmarks/bench_estimator.py [seconds]``. The flight is a slow hover-like motion with IMU
noise; the frames are built before timing. Steps with a motion-capture arrival (the unscented prediction,
the update and the re-propagation over the latency) are reported apart from the plain IMU steps.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from omnirotor.control.estimator import EstimatorParams, UKFEstimator
from omnirotor.messages import SensorFrame
from omnirotor.so3 import R_from_rpy, quat_wxyz_from_R
from omnirotor.vehicle import load_vehicle


def _frames(seconds: float, seed: int) -> list[SensorFrame]:
    rng = np.random.default_rng(seed)
    dt, latency, every = 1e-3, 8, 10
    n = int(round(seconds / dt))
    ts = (np.arange(n) + 1) * dt
    p = np.stack([0.1 * np.sin(0.5 * ts), 0.1 * np.cos(0.4 * ts), 1.0 + 0.05 * np.sin(0.3 * ts)], -1)
    frames = []
    for k in range(n):
        R = R_from_rpy(0.1 * np.sin(0.7 * ts[k]), 0.1 * np.sin(0.5 * ts[k]), 0.2 * ts[k])
        acc = R.T @ np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.6, 3)
        gyro = np.array([0.07, 0.05, 0.2]) + rng.normal(0.0, 0.03, 3)
        j = k - latency
        extra = {}
        if j >= 0 and j % every == 0:
            R_j = R_from_rpy(0.1 * np.sin(0.7 * ts[j]), 0.1 * np.sin(0.5 * ts[j]), 0.2 * ts[j])
            extra = dict(
                mocap_new=True,
                mocap_t=float(ts[j]),
                mocap_p_W=p[j] + rng.normal(0.0, 5e-4, 3),
                mocap_q_WB=quat_wxyz_from_R(R_j),
            )
        frames.append(SensorFrame(t=float(ts[k]), imu_acc_B=acc, imu_gyro_B=gyro, rotor_hz=np.zeros(8), **extra))
    return frames


def bench_estimator(seconds: float = 5.0, seed: int = 0) -> dict[str, float]:
    """Microseconds per ``UKFEstimator.step``.

    Args:
        seconds: simulated time (1 kHz steps, 100 Hz motion capture).
        seed: noise seed.

    Returns:
        ``imu_step_median_us`` / ``imu_step_p99_us`` (steps without motion capture),
        ``mocap_step_median_us`` / ``mocap_step_max_us`` (steps with an arrival), ``mean_us`` (all steps).
    """
    frames = _frames(seconds, seed)
    est = UKFEstimator(load_vehicle("omnirotor"), EstimatorParams())
    warm = min(len(frames) // 5, 1000)
    for f in frames[:warm]:
        est.step(f)
    plain, mocap = [], []
    for f in frames[warm:]:
        t0 = time.perf_counter()
        est.step(f)
        (mocap if f.mocap_new else plain).append(time.perf_counter() - t0)
    everything = np.array(plain + mocap) * 1e6
    plain_us, mocap_us = np.array(plain) * 1e6, np.array(mocap) * 1e6
    return {
        "imu_step_median_us": float(np.median(plain_us)),
        "imu_step_p99_us": float(np.percentile(plain_us, 99)),
        "mocap_step_median_us": float(np.median(mocap_us)),
        "mocap_step_max_us": float(mocap_us.max()),
        "mean_us": float(everything.mean()),
    }


if __name__ == "__main__":
    result = bench_estimator(float(sys.argv[1]) if len(sys.argv) > 1 else 5.0)
    for key, value in result.items():
        print(f"{key:24s} {value:9.1f}")
