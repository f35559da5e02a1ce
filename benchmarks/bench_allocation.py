"""Median time of one warm-started allocation QP solve per backend, near hover (SPEC §4.2).

Run: ``python benchmarks/bench_allocation.py [n]``. Each step perturbs the hover wrench by ~0.3 N / 0.03 N·m
and the attitude by ~1 deg, as in closed-loop flight; the inputs are generated before timing.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from omnirotor.control.allocation import SOLVERS, AllocationParams, Allocator
from omnirotor.so3 import exp_so3
from omnirotor.vehicle import load_vehicle


def bench_allocation(n: int = 2000, seed: int = 0) -> dict[str, float]:
    """Median and 99th-percentile microseconds per ``Allocator.solve`` for each backend.

    Args:
        n: number of timed solves per backend.
        seed: seed of the random perturbations.

    Returns:
        ``{"<solver>_median_us": ..., "<solver>_p99_us": ...}`` for every solver.
    """
    vehicle = load_vehicle("omnirotor")
    rng = np.random.default_rng(seed)
    hover = np.array([0.0, 0.0, vehicle.weight, 0.0, 0.0, 0.0])
    w_refs = hover + rng.normal(0.0, 1.0, (n, 6)) * np.array([0.3, 0.3, 0.3, 0.03, 0.03, 0.03])
    Rs = [exp_so3(rng.normal(0.0, np.radians(1.0), 3)) for _ in range(n)]
    A = vehicle.A_nom
    out: dict[str, float] = {}
    for solver in SOLVERS:
        alloc = Allocator(vehicle, AllocationParams(solver=solver))
        for k in range(min(n, 200)):  # warm up
            alloc.solve(w_refs[k], Rs[k], A)
        times = np.empty(n)
        for k in range(n):
            t0 = time.perf_counter()
            alloc.solve(w_refs[k], Rs[k], A)
            times[k] = time.perf_counter() - t0
        out[f"{solver}_median_us"] = float(np.median(times) * 1e6)
        out[f"{solver}_p99_us"] = float(np.percentile(times, 99) * 1e6)
    return out


if __name__ == "__main__":
    result = bench_allocation(int(sys.argv[1]) if len(sys.argv) > 1 else 2000)
    for key, value in result.items():
        print(f"{key:24s} {value:8.1f}")
