"""Time of one InteractionController.step (the whole 1 kHz stack), with the bypass and the UKF estimator.

Frames are first recorded from a closed-loop simulator run (a hover with a small move, so that every block
does real work); the controller is then timed alone on those frames, one ``time.perf_counter`` pair per
step. Goal: <= 30 µs per step.

Run: ``python benchmarks/bench_controller.py [--n 3000] [--profile] [--parts]`` (``--profile`` prints the
cProfile of the UKF and bypass steps, sorted by own time; ``--parts`` times the step's parts instead,
:func:`step_parts`).
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


def _dispatch_probe():
    """A compiled function of the step's three record arrays that does nothing: numba's call cost alone."""
    from omnirotor._jit import jit

    @jit
    def _noop(state, frame, row) -> int:
        return 0

    return _noop


def _typed_probe(noop, ctl):
    """The same no-op's specialisation for the controller's arrays, called as the step calls its own (typed once)."""
    from omnirotor._jit import typed_entry

    return typed_entry(noop, ctl.state, ctl._frame_buf, ctl._no_row)


def step_parts(n: int = 3000, passes: int = 3) -> dict:
    """Where ``InteractionController.step`` from Python goes, part by part [µs, median over the frames].

    The method's body is replayed with a ``time.perf_counter_ns`` between its parts (the frame's record, the
    log's next record, the compiled call, the command message; private attributes, as the method does), best
    of ``passes`` passes over the same frames on a fresh controller. ``dispatch_us``: a compiled function of
    the same three record arrays that does nothing (numba's dispatch: typing the three arguments and unboxing
    them); ``typed_dispatch_us``: that no-op called as the step calls its compiled step
    (:func:`omnirotor._jit.typed_entry`: no typing per call, only the arguments' unboxing). ``compiled_call``
    is the step's call as the method makes it (its check of the arrays' types and the typed call); minus
    ``typed_dispatch_us`` it is the step's own work, to be compared with the step inside the compiled loop
    (``bench_run.py``'s ``controller_step_us_in_loop``).
    """
    from omnirotor.control import composer as _c
    from omnirotor.control.controller import _STATUS_BY_BITS
    from omnirotor.messages import RotorCommand

    vehicle, traj, first, frames = _setup(n)
    clock = time.perf_counter_ns
    noop = _dispatch_probe()
    out: dict = {"n": n, "passes": passes}
    for kind in ("bypass", "ukf"):
        best: dict[str, float] = {}
        for _ in range(passes):
            ctl = _controller(vehicle, kind, n)
            ctl.reset(first, traj)
            typed_noop = _typed_probe(noop, ctl)
            t = np.empty((n, 6))
            for k, f in enumerate(frames):
                t0 = clock()
                record = ctl._record(f)
                t1 = clock()
                row = ctl.log.next_record()
                t2 = clock()
                if ctl._typed_arrays(record, row):
                    bits = ctl._typed_step(ctl.state, record, row)
                else:
                    bits = _c.controller_step(ctl.state, record, row)
                t3 = clock()
                RotorCommand(f.t, ctl._omega_cmd.copy(), _STATUS_BY_BITS[bits])
                t4 = clock()
                noop(ctl.state, record, row)
                t5 = clock()
                typed_noop(ctl.state, record, row)
                t6 = clock()
                t[k] = (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4, t6 - t5)
            med = np.median(t, axis=0) / 1e3
            names = ("frame_record", "next_record", "compiled_call", "command", "dispatch", "typed_dispatch")
            for name, v in zip(names, med, strict=True):
                best[name] = min(best.get(name, np.inf), float(v))
            whole = np.empty(n)
            ctl = _controller(vehicle, kind, n)
            ctl.reset(first, traj)
            for k, f in enumerate(frames):
                t0 = clock()
                ctl.step(f)
                whole[k] = clock() - t0
            best["step"] = min(best.get("step", np.inf), float(np.median(whole)) / 1e3)
        best["compiled_call_minus_dispatch"] = best["compiled_call"] - best["typed_dispatch"]
        best["rest_of_method"] = best["step"] - sum(
            best[p] for p in ("frame_record", "next_record", "compiled_call", "command")
        )
        out[kind] = {f"{name}_us": round(v, 3) for name, v in best.items()}
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
    ap.add_argument("--parts", action="store_true", help="where the step from Python goes, part by part")
    args = ap.parse_args()
    if args.profile:
        profile_controller_step(args.n)
    if args.parts:
        print(json.dumps(step_parts(args.n), indent=1))
        raise SystemExit(0)
    print(json.dumps(bench_controller_step(args.n), indent=1))
