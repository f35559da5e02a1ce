"""Median time of one simulator step (truth and nominal aerodynamics) and of one truth-model call (SPEC §7).

Run: ``python benchmarks/bench_sim.py [n]``. The Omnirotor hovers in the wall scene with speed commands
perturbed by ~2 Hz per rotor, as in closed-loop flight; the commands are generated before timing. The
in-contact figure pushes the tip against the wall with 3 N.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from omnirotor.messages import RotorCommand
from omnirotor.sim import AeroParams, SimParams, Simulator
from omnirotor.vehicle import load_vehicle


def _time_steps(sim: Simulator, cmds: list[RotorCommand]) -> np.ndarray:
    for c in cmds[:200]:  # warm up
        sim.step(c)
    times = np.empty(len(cmds))
    for k, c in enumerate(cmds):
        t0 = time.perf_counter()
        sim.step(c)
        times[k] = time.perf_counter() - t0
    return times


def bench_sim_step(n: int = 2000, seed: int = 0) -> dict[str, float]:
    """Median (and 99th percentile) microseconds of ``Simulator.step`` and of ``aero.wrench_B``.

    Args:
        n: timed calls per case.
        seed: seed of the command perturbations.

    Returns:
        ``{"step_interference_median_us", "step_nominal_median_us", "step_in_contact_median_us",
        "aero_wrench_median_us", ... "_p99_us"}``.
    """
    vehicle = load_vehicle("omnirotor")
    rng = np.random.default_rng(seed)
    out: dict[str, float] = {}
    for model in ("interference", "nominal"):
        sim = Simulator(vehicle, "wall", SimParams(aero=AeroParams(model=model)), seed=seed)
        hover = sim.hover_speeds_hz(sim.truth.R_WB)
        cmds = [RotorCommand(0.0, hover + rng.normal(0.0, 2.0, hover.shape)) for _ in range(n)]
        times = _time_steps(sim, cmds)
        out[f"step_{model}_median_us"] = float(np.median(times) * 1e6)
        out[f"step_{model}_p99_us"] = float(np.percentile(times, 99) * 1e6)

    sim = Simulator(vehicle, "wall", SimParams(), seed=seed)
    p0, R0 = sim.default_start()
    sim.reset(p0 - sim.params.scene.start_standoff * sim.scene.normal_W, R0)  # tip on the wall
    sim.set_external_wrench(-3.0 * sim.scene.normal_W, at="ee")
    hover = sim.hover_speeds_hz(R0)
    cmds = [RotorCommand(0.0, hover + rng.normal(0.0, 2.0, hover.shape)) for _ in range(n)]
    times = _time_steps(sim, cmds)
    out["step_in_contact_median_us"] = float(np.median(times) * 1e6)
    out["step_in_contact_p99_us"] = float(np.percentile(times, 99) * 1e6)

    aero = sim.aero
    us = [c.omega_hz * np.abs(c.omega_hz) for c in cmds]
    w = np.empty(6)
    times = np.empty(n)
    for k, u in enumerate(us):
        t0 = time.perf_counter()
        aero.wrench_B(u, out=w)
        times[k] = time.perf_counter() - t0
    out["aero_wrench_median_us"] = float(np.median(times) * 1e6)
    out["aero_wrench_p99_us"] = float(np.percentile(times, 99) * 1e6)
    return out


if __name__ == "__main__":
    result = bench_sim_step(int(sys.argv[1]) if len(sys.argv) > 1 else 2000)
    for key, value in result.items():
        print(f"{key:28s} {value:8.1f}")
