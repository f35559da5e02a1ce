"""The closed-loop workloads timed by ``benchmarks/run.py``: the sliding task, the hover task, a campaign worker.

Every function builds its simulator and controller first and times only the loop (``run_closed_loop``), except
:func:`hover_task_wall`, which times a whole ``run_task("hover")`` (set-up included) as a campaign sees it.
This module is imported by name from ``benchmarks/`` so that campaign worker processes can import it too.
"""

from __future__ import annotations

import time

_T_START = time.perf_counter()  # before the imports below: start-up profile (--startup)

import json  # noqa: E402
import sys  # noqa: E402

import numpy as np  # noqa: E402

from omnirotor._jit import jit, monotonic_ns, profiler_clock_off, profiler_clock_restore  # noqa: E402
from omnirotor.control.admittance import AdmittanceParams  # noqa: E402
from omnirotor.control.controller import ControllerParams, InteractionController  # noqa: E402
from omnirotor.control.estimator import EstimatorParams  # noqa: E402
from omnirotor.control.trajectory import PoseTrajectory  # noqa: E402
from omnirotor.experiments.loop import TaskOptions, run_closed_loop  # noqa: E402
from omnirotor.experiments.tasks import run_task  # noqa: E402
from omnirotor.experiments.tasks.scenarios import sliding  # noqa: E402
from omnirotor.sim import SimParams, Simulator  # noqa: E402
from omnirotor.sim.step import mj_Euler, mj_forward  # noqa: E402
from omnirotor.vehicle import load_vehicle  # noqa: E402

SLIDING_SEED = 0
DT_S = SimParams().dt
"""Simulator and controller period [s] (1 kHz)."""


def sliding_setup(estimator: str, quick_scenario: bool, seed: int = SLIDING_SEED):
    """Simulator, controller and trajectory of the paper's sliding task on the pipe (SPEC §5.2, preset "SD").

    Args:
        estimator: "ukf" or "bypass" (ground truth plus noise).
        quick_scenario: the shortened holds of ``sliding(..., quick=True)`` (same path, contact after 6 s
            instead of 10 s).
        seed: simulator noise seed.

    Returns:
        ``(sim, controller, trajectory, scenario)``.
    """
    params = SimParams()
    scenario = sliding(params.scene, quick=quick_scenario)
    vehicle = load_vehicle("omnirotor")
    sim = Simulator(vehicle, scenario.scene, params, seed=seed)
    trajectory = PoseTrajectory(list(scenario.waypoints))
    cparams = ControllerParams(
        admittance=AdmittanceParams.preset(scenario.admittance), estimator=EstimatorParams(kind=estimator)
    )
    return sim, InteractionController(vehicle, cparams), trajectory, scenario


def run_sliding(estimator: str, duration_s: float, quick_scenario: bool, seed: int = SLIDING_SEED) -> dict:
    """Fly the first ``duration_s`` of the sliding task; time ``run_closed_loop`` only (set-up excluded).

    Returns:
        ``wall_s``, ``sim_s``, ``rtf`` (simulated seconds per wall second), ``controller_step_us_median``,
        ``_mean`` and ``_p99`` (measured in the loop), ``plant_step_us_median`` and ``_mean`` (the simulator's
        step, measured in the loop), ``steps_flagged`` (controller status bits set),
        ``contact_fraction`` (of the steps).
    """
    sim, ctl, traj, _ = sliding_setup(estimator, quick_scenario, seed)
    tic, cpu0 = time.perf_counter(), time.process_time()
    ctl_log, truth_log = run_closed_loop(sim, ctl, traj, duration_s)
    wall, cpu = time.perf_counter() - tic, time.process_time() - cpu0
    step_us = truth_log.group("controller_step_us")
    plant_us = truth_log.group("plant_step_us")
    return {
        "plant_step_us_median": float(np.median(plant_us)),
        "plant_step_us_mean": float(np.mean(plant_us)),
        "wall_s": wall,
        "sim_s": duration_s,
        "rtf": duration_s / wall,
        "rtf_cpu": duration_s / cpu,
        "controller_step_us_median": float(np.median(step_us)),
        "controller_step_us_mean": float(np.mean(step_us)),
        "controller_step_us_p99": float(np.percentile(step_us, 99)),
        "steps_flagged": int(np.count_nonzero(ctl_log.group("status"))),
        "contact_fraction": float(np.mean(truth_log.group("in_contact") > 0.5)),
    }


def hover_task_wall(duration_s: float, seed: int = 0) -> float:
    """Wall time [s] of one whole ``run_task("hover")`` (simulator and controller set-up included)."""
    tic = time.perf_counter()
    run_task("hover", TaskOptions(duration_s=duration_s, seed=seed))
    return time.perf_counter() - tic


@jit
def mujoco_loop(m: int, d: int, n: int, ts, timer_adr: int) -> float:
    """Mean µs of ``n`` x (``mj_Euler``, ``mj_forward``) on the MjModel/MjData at addresses ``m``, ``d``.

    ``ts`` is the (2,) int64 scratch of the compiled clock; ``timer_adr`` MuJoCo's profiler clock
    (``_jit.mujoco_timer_address``), off during the loop as in the simulator's step (0: left on).
    """
    clock = profiler_clock_off(timer_adr)
    t0 = monotonic_ns(ts)
    for _ in range(n):
        mj_Euler(m, d)
        mj_forward(m, d)
    t1 = monotonic_ns(ts)
    profiler_clock_restore(timer_adr, clock)
    return (t1 - t0) / n / 1e3


STARTUP_SHORT_S = 0.1
STARTUP_LONG_S = 2.1


def startup_profile() -> dict:
    """Where a fresh process's first hover runs spend their time (run by ``run.py`` in a subprocess).

    ``imports_s``: from this module's first line to the end of the imports (numpy, MuJoCo, numba, the
    package) plus the experiment modules a campaign worker imports; ``first_run_s``, ``second_run_s``: two
    ``run_task("hover")`` of ``STARTUP_SHORT_S``; ``long_run_s``: one of ``STARTUP_LONG_S``. Derived:
    ``kernel_loading_s`` (first minus second run: the compiled kernels loaded from numba's cache),
    ``stepping_s_per_sim_s`` ((long - second) / (long - short simulated)), ``setup_s`` (a run's set-up: the
    second run less its stepping).
    """
    from omnirotor.experiments.campaigns import runner  # noqa: F401  (what a campaign worker imports)
    from omnirotor.experiments.tasks import common  # noqa: F401  (the tasks' module a worker imports)

    imports = time.perf_counter() - _T_START
    walls = []
    for d in (STARTUP_SHORT_S, STARTUP_SHORT_S, STARTUP_LONG_S):
        tic = time.perf_counter()
        run_task("hover", TaskOptions(duration_s=d, seed=0))
        walls.append(time.perf_counter() - tic)
    first, second, long = walls
    per_sim_s = (long - second) / (STARTUP_LONG_S - STARTUP_SHORT_S)
    return {
        "task": "hover (omnirotor, UKF)",
        "imports_s": imports,
        "first_run_s": first,
        "second_run_s": second,
        "long_run_s": long,
        "short_s": STARTUP_SHORT_S,
        "long_s": STARTUP_LONG_S,
        "kernel_loading_s": first - second,
        "stepping_s_per_sim_s": per_sim_s,
        "setup_s": second - STARTUP_SHORT_S * per_sim_s,
    }


if __name__ == "__main__":
    if sys.argv[1:] == ["--startup"]:
        print(json.dumps(startup_profile()))
