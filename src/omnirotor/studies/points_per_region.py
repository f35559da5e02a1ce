"""How many hover points a region needs (issue 15, item 3; SPEC §3.2-§3.4).

The paper flew about 15 points per region; hover data determine a region's force rows on the
(n - 3)-dimensional space the hover inputs span, so n - 3 = 5 points are the least that pin them (the
identification refuses fewer). This study measures the identified map's validation error against the
number of points per region and the hover noise, over many seeded repetitions:

* a pool of truth hover points per region of the paper's partition (:mod:`omnirotor.studies.hover_pool`,
  the simulator's truth aerodynamics), and one validation set of attitudes uniform on the sphere;
* for each (points per region k, noise level, repetition): k noisy points per region drawn without
  replacement, one map per region by the paper's QP (:func:`omnirotor.identification.solve_map`; below
  n - 3 points with ``require_determined=False``, the proximal term keeping the undetermined directions at
  nominal), and the RMS force residual of the piecewise map over the validation set [N];
* per (k, noise): the mean over repetitions with its 95 % confidence interval (Student t) and the 10-90 %
  range of single identifications.

Jobs run in a local process pool (one job per (k, noise), all its repetitions).
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import math
from pathlib import Path

import numpy as np
from scipy import stats

from omnirotor.errors import InputError
from omnirotor.identification import IdentificationParams, solve_map
from omnirotor.regions import Partition, load_partition
from omnirotor.sim.aero import make_aero
from omnirotor.studies.hover_pool import NOISE_LEVELS, HoverNoise, HoverPool, build_pool, draw
from omnirotor.studies.partitions import ValidationSet, piecewise_force_residuals, validation_set
from omnirotor.vehicle import VehicleParams

__all__ = ["DEFAULT_COUNTS", "points_per_region_study", "plot_points_per_region", "summarise"]

DEFAULT_COUNTS = (3, 4, 5, 6, 8, 10, 12, 15, 20, 25, 30)
"""Points per region of the study (the paper: about 15)."""


@dataclasses.dataclass(frozen=True)
class _Job:
    vehicle: VehicleParams
    partition: Partition
    pool: HoverPool
    val: ValidationSet
    k: int
    noise_name: str
    noise: HoverNoise
    reps: int
    seed: int


def _run_job(job: _Job) -> tuple[int, str, list[float]]:
    params = IdentificationParams()
    out = []
    for rep in range(job.reps):
        rng = np.random.default_rng([job.seed, job.k, rep, sum(map(ord, job.noise_name))])
        data = draw(job.pool, job.vehicle, {n: job.k for n in job.partition.names}, job.noise, rng)
        names = np.array(data.region)
        maps = [
            solve_map(data.subset(names == n), job.vehicle.A_nom, params, require_determined=False)
            for n in job.partition.names
        ]
        r = piecewise_force_residuals(job.partition, maps, job.vehicle, job.val)
        out.append(float(np.sqrt(np.mean(r**2))))
    return job.k, job.noise_name, out


def summarise(values: list[float]) -> dict:
    """Mean, its 95 % confidence interval (Student t), and the 10 / 50 / 90 % quantiles."""
    x = np.asarray(values, dtype=float)
    mean = float(x.mean())
    half = float(stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size)) if x.size > 1 else 0.0
    q10, q50, q90 = (float(v) for v in np.percentile(x, [10, 50, 90]))
    return {"mean": mean, "ci95": [mean - half, mean + half], "p10": q10, "median": q50, "p90": q90, "n": x.size}


def points_per_region_study(
    vehicle: VehicleParams,
    counts: tuple[int, ...] = DEFAULT_COUNTS,
    noises: tuple[str, ...] = ("low", "medium", "high"),
    reps: int = 30,
    n_validation: int = 300,
    seed: int = 0,
    workers: int = 2,
    partition: Partition | None = None,
) -> dict:
    """Run the study (module docstring); returns a JSON-able dict.

    Args:
        vehicle: the vehicle.
        counts: points per region to try (each >= 1).
        noises: names of :data:`omnirotor.studies.hover_pool.NOISE_LEVELS`.
        reps: repetitions per (count, noise).
        n_validation: validation attitudes.
        seed: the study's seed.
        workers: processes (1: in this process).
        partition: regions (default the paper's ten).
    """
    if not counts or any(isinstance(k, bool) or not isinstance(k, int) or k < 1 for k in counts):
        raise InputError(f"points per region must be integers >= 1, got {counts}")
    unknown = [n for n in noises if n not in NOISE_LEVELS]
    if unknown:
        raise InputError(f"unknown noise level(s) {', '.join(unknown)}; known: {', '.join(NOISE_LEVELS)}")
    if reps < 2:
        raise InputError(f"reps must be >= 2 for a confidence interval, got {reps}")
    partition = partition or load_partition("paper")
    aero = make_aero(vehicle)
    pool = build_pool(vehicle, aero, partition, 2 * max(counts), np.random.default_rng([seed, 10]))
    short = [n for n in partition.names if pool.size(n) < max(counts)]
    if short:
        raise InputError(f"the truth holds too few attitudes in region(s) {', '.join(short)}")
    val = validation_set(vehicle, aero, n_validation, np.random.default_rng([seed, 11]))
    jobs = [
        _Job(vehicle, partition, pool, val, k, name, NOISE_LEVELS[name], reps, seed) for name in noises for k in counts
    ]
    results: dict[str, dict[int, list[float]]] = {name: {} for name in noises}
    if workers <= 1:
        done = map(_run_job, jobs)
    else:
        ex = cf.ProcessPoolExecutor(max_workers=workers)
        done = ex.map(_run_job, jobs)
    for k, name, vals in done:
        results[name][k] = vals
    if workers > 1:
        ex.shutdown()
    up = np.array([0.0, 0.0, vehicle.weight])
    nominal = np.linalg.norm(np.einsum("kji,j->ki", val.R_WB, up) - val.u_hz2 @ vehicle.A_nom[:3].T, axis=1)
    return {
        "vehicle": vehicle.name,
        "partition": partition.name,
        "regions": len(partition.regions),
        "reps": reps,
        "validation_attitudes": int(len(val.R_WB)),
        "nominal_force_residual_rms_N": float(np.sqrt(np.mean(nominal**2))),
        "noise": {n: dataclasses.asdict(NOISE_LEVELS[n]) for n in noises},
        "counts": list(counts),
        "results": {n: {str(k): summarise(results[n][k]) for k in counts} for n in noises},
    }


def plot_points_per_region(result: dict, path: str | Path) -> None:
    """Figure: validation force residual against points per region, one curve per noise, CI and 10-90 % bands."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    ks = np.array(result["counts"])
    for name, res in result["results"].items():
        s = [res[str(k)] for k in ks]
        mean = np.array([v["mean"] for v in s])
        noise = result["noise"][name]
        label = f"{name} noise: speeds ±{noise['speed_std_hz']:g} Hz, attitude ±{noise['attitude_std_deg']:g}° (1σ)"
        (line,) = ax.plot(ks, mean, "o-", label=label)
        ax.fill_between(ks, [v["ci95"][0] for v in s], [v["ci95"][1] for v in s], color=line.get_color(), alpha=0.35)
        ax.fill_between(ks, [v["p10"] for v in s], [v["p90"] for v in s], color=line.get_color(), alpha=0.1)
    ax.axvline(5, color="k", lw=0.8, ls=":")
    ax.text(5.2, ax.get_ylim()[1] * 0.95, "n - 3 = 5", va="top", fontsize=8)
    ax.axvline(15, color="gray", lw=0.8, ls="--")
    ax.text(15.2, ax.get_ylim()[1] * 0.95, "paper: 15", va="top", fontsize=8)
    ax.set_xlabel("hover points per region")
    ax.set_ylabel("validation force residual RMS [N]")
    ax.set_title(
        f"{result['regions']} regions, {result['reps']} repetitions (band: 95 % CI of the mean; light: 10-90 %)",
        fontsize=9,
    )
    ax.legend(fontsize=7)
    ax.set_yscale("log")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
