"""Time of one InteractionController.step (the whole 1 kHz stack), with the bypass and the UKF estimator.

Frames are first recorded from a closed-loop simulator run (a hover with a small move, so that every block
does real work); the controller is then timed alone on those frames, one ``time.perf_counter`` pair per
step. Goal: <= 30 µs per step.

Run: ``python benchmarks/bench_controller.py [--n 3000] [--profile]`` (``--profile`` prints the cProfile
of the UKF and bypass steps, sorted by own time).
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import time

import numpy as np

from omnirotor.control.controller import ControllerParams, InteractionController
from omnirotor.control.estimator import EstimatorParams
from omnirotor.control.trajectory import PoseTrajectory, Waypoint
from omnirotor.sim import SimParams, Simulator
from omnirotor.so3 import rot_z
from omnirotor.vehicle import load_vehicle

GOAL_US = 30.0


def _setup(n: int):
    vehicle = load_vehicle("omnirotor")
    sim = Simulator(vehicle, "free", SimParams(), seed=0)
    p, R = sim.default_start()
    p_E = p + R @ vehicle.p_E_B_array
    T = n * 1e-3
    traj = PoseTrajectory([Waypoint(0.0, p_E, R), Waypoint(T, p_E + [0.05, -0.03, 0.02], rot_z(0.1) @ R)])
    recorder = InteractionController(vehicle, ControllerParams(estimator=EstimatorParams(kind="bypass")))
    frame = sim.reset(p, R)
    first = frame
    recorder.reset(frame, traj)
    frames = []
    cmd = recorder.hold_command()
    for _ in range(n):
        frame = sim.step(cmd)
        cmd = recorder.step(frame)
        frames.append(frame)
    return vehicle, traj, first, frames


def _controller(vehicle, kind: str, n: int) -> InteractionController:
    return InteractionController(vehicle, ControllerParams(estimator=EstimatorParams(kind=kind), log_capacity=n + 1))


def bench_controller_step(n: int = 3000) -> dict:
    """Wall time of ``InteractionController.step`` [µs], bypass and UKF: median, 90th and 99th percentiles.

    For the UKF, the steps with a motion-capture arrival (every 10th: the unscented prediction, the update and
    the re-propagation) are also reported apart (``ukf_mocap_us_*``), as they set the worst case of the loop.
    """
    vehicle, traj, first, frames = _setup(n)
    out: dict = {"n": n, "goal_us": GOAL_US}
    clock = time.perf_counter
    mocap = np.array([f.mocap_new for f in frames])
    for kind in ("bypass", "ukf"):
        warm = _controller(vehicle, kind, n)  # first calls load (or compile) the kernels: not timed
        warm.reset(first, traj)
        for f in frames[: min(n, 50)]:
            warm.step(f)
        ctl = _controller(vehicle, kind, n)
        ctl.reset(first, traj)
        times = np.empty(n)
        for k, f in enumerate(frames):
            tic = clock()
            ctl.step(f)
            times[k] = clock() - tic
        times *= 1e6
        out[f"{kind}_us_median"] = float(np.median(times))
        out[f"{kind}_us_p90"] = float(np.percentile(times, 90))
        out[f"{kind}_us_p99"] = float(np.percentile(times, 99))
        out[f"{kind}_us_mean"] = float(np.mean(times))
        if kind == "ukf":
            out["ukf_mocap_us_median"] = float(np.median(times[mocap]))
            out["ukf_mocap_us_p99"] = float(np.percentile(times[mocap], 99))
            out["ukf_imu_only_us_median"] = float(np.median(times[~mocap]))
    return out


def profile_controller_step(n: int = 3000, top: int = 20) -> None:
    """Print the cProfile of n controller steps for each estimator."""
    vehicle, traj, first, frames = _setup(n)
    for kind in ("bypass", "ukf"):
        ctl = _controller(vehicle, kind, n)
        ctl.reset(first, traj)
        prof = cProfile.Profile()
        prof.enable()
        for f in frames:
            ctl.step(f)
        prof.disable()
        print(f"--- {kind}: {n} steps")
        pstats.Stats(prof).sort_stats("tottime").print_stats(top)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=3000)
    ap.add_argument("--profile", action="store_true")
    args = ap.parse_args()
    if args.profile:
        profile_controller_step(args.n)
    print(json.dumps(bench_controller_step(args.n), indent=1))
