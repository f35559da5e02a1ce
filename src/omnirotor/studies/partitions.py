"""Compare partitions of the sphere at equal total hover points (issue 15, item 2; SPEC §3.3).

For each partition (e.g. the paper's ten regions and one from :mod:`omnirotor.regions_from_signs`) the same
number of hover points in total is spread evenly over its regions, drawn from the truth aerodynamics with
measurement noise (:mod:`omnirotor.studies.hover_pool`), and the piecewise maps are identified with the
paper's QP (SPEC §3.2). Measured, over seeded repetitions, at validation attitudes drawn uniformly on the
sphere (the protocol's sampler, so near-zero-crossing attitudes are rejected as in the paper):

* **force residual** ``|R_WBᵀ m g e3 - A_k,1 u|`` [N] of the map of the attitude's region ``k`` on the true
  hover inputs ``u`` of a controller flying the nominal map (new data for the identified maps);
* **hover bias**: the steady-state estimate of the momentum observer in free hover with the piecewise map
  in the loop, ``f_hat_W = m g e3 - R_WB A_k,1 u_k`` and ``m_hat_B = -A_k,2 u_k`` with ``u_k`` the true
  equilibrium of a controller allocating with ``A_k`` (:func:`~omnirotor.sim.aero.hover_equilibrium`);
  its mean and RMS over attitudes [N, N·m];
* **sliding** (closed loop, :func:`omnirotor.experiments.tasks.run_task`): one short sliding run per
  partition with the maps of the first repetition: contact kept, EE error, and how often the map switched.
"""

from __future__ import annotations

import dataclasses
import json
import tempfile
from pathlib import Path

import numpy as np

from omnirotor.config import check_count
from omnirotor.errors import InputError
from omnirotor.identification import IdentificationParams, identify
from omnirotor.limits import MAX_STUDY_POINTS, MAX_STUDY_REPS, MAX_VALIDATION_ATTITUDES
from omnirotor.regions import Partition, Region
from omnirotor.sim.aero import TruthAero, hover_equilibrium, make_aero
from omnirotor.studies.hover_pool import HoverNoise, build_pool, draw
from omnirotor.vehicle import VehicleParams
from omnirotor.wrench_maps import WrenchMapSet

__all__ = [
    "ValidationSet",
    "validation_set",
    "piecewise_force_residuals",
    "hover_bias",
    "even_counts",
    "compare_partitions",
    "plot_comparison",
]

_SPHERE = Partition("sphere", (Region("all", ((-180.0, 180.0),), (-90.0, 90.0)),))


@dataclasses.dataclass(frozen=True)
class ValidationSet:
    """Validation attitudes and the true hover inputs there (controller on the nominal map).

    Attributes:
        R_WB: (k, 3, 3) attitudes.
        u_hz2: (k, n) true steady inputs [Hz²].
    """

    R_WB: np.ndarray
    u_hz2: np.ndarray


def validation_set(
    vehicle: VehicleParams, aero: TruthAero, n: int, rng: np.random.Generator, min_speed_hz: float = 50.0
) -> ValidationSet:
    """``n`` attitudes uniform on the sphere of up directions (uniform yaw) and their truth hover inputs."""
    check_count("--validation", n, 1, MAX_VALIDATION_ATTITUDES)
    pool = build_pool(vehicle, aero, _SPHERE, n, rng, min_speed_hz)
    return ValidationSet(pool.R_WB["all"], pool.u_hz2["all"])


def _region_maps(maps: WrenchMapSet, R_WB: np.ndarray) -> list[np.ndarray]:
    A_by_region = maps.region_maps()
    return [A_by_region[maps.partition.index_of_attitude(R)] for R in R_WB]


def piecewise_force_residuals(
    partition: Partition, region_maps: list[np.ndarray], vehicle: VehicleParams, val: ValidationSet
) -> np.ndarray:
    """(k,) force-residual norms [N] of piecewise maps (one per region, partition order) at validation points."""
    up = np.array([0.0, 0.0, vehicle.weight])
    As = [region_maps[partition.index_of_attitude(R)] for R in val.R_WB]
    return np.array([np.linalg.norm(R.T @ up - A[:3] @ u) for R, A, u in zip(val.R_WB, As, val.u_hz2, strict=True)])


def hover_bias(
    maps: WrenchMapSet | None, vehicle: VehicleParams, aero: TruthAero, R_WB: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Steady observer estimates in free hover with the piecewise maps (or the nominal map when None).

    Returns:
        ``(f_hat_W (k, 3) [N], m_hat_B (k, 3) [N·m])``; attitudes the loop cannot hold are left out.
    """
    up = np.array([0.0, 0.0, vehicle.weight])
    As = _region_maps(maps, R_WB) if maps is not None else [vehicle.A_nom] * len(R_WB)
    f, m = [], []
    for R, A in zip(R_WB, As, strict=True):
        try:
            u = hover_equilibrium(aero, vehicle, R, A)
        except InputError:
            continue
        f.append(up - R @ (A[:3] @ u))
        m.append(-(A[3:] @ u))
    return np.array(f).reshape(-1, 3), np.array(m).reshape(-1, 3)


def even_counts(partition: Partition, total: int) -> dict[str, int]:
    """``total`` points spread as evenly as possible over the regions (earlier regions get the remainder)."""
    k = len(partition.regions)
    base, extra = divmod(total, k)
    return {name: base + (1 if i < extra else 0) for i, name in enumerate(partition.names)}


def _sliding(maps: WrenchMapSet, quick: bool, seed: int) -> dict:
    from omnirotor.experiments.tasks import run_task
    from omnirotor.experiments.tasks.common import ExperimentOptions

    with tempfile.TemporaryDirectory(prefix="omnirotor-partitions-") as tmp:
        path = Path(tmp) / "maps.json"
        maps.save(path)
        opts = ExperimentOptions(map_mode="piecewise", maps=str(path), quick=quick, seed=seed)
        m = run_task("sliding", opts).summary()
    return {
        "success": m["success"],
        "contact_fraction": m["contact"]["fraction"],
        "contact_lost": m["contact"]["lost"],
        "ee_rms_error": m["ee_rms_error"],
        "map_switches": m["map_switches"],
        "force": m.get("force"),
    }


def compare_partitions(
    vehicle: VehicleParams,
    partitions: dict[str, Partition],
    total_points: int = 150,
    reps: int = 10,
    noise: HoverNoise = HoverNoise(),  # noqa: B008  (frozen)
    n_validation: int = 300,
    seed: int = 0,
    sliding: bool = True,
    sliding_quick: bool = True,
    aero: TruthAero | None = None,
) -> dict:
    """The comparison of the module docstring; a JSON-able dict.

    Args:
        vehicle: the vehicle.
        partitions: name -> partition.
        total_points: hover points per identification, in total over the regions.
        reps: seeded repetitions (new points and noise each time; same validation set).
        noise: measurement noise of the hover points.
        n_validation: validation attitudes.
        seed: the study's seed.
        sliding: also fly one sliding run per partition (closed loop).
        sliding_quick: the shortened sliding run.
        aero: truth model (default ``make_aero(vehicle)``).

    Returns:
        Per partition: regions, points per region, force residual (mean over reps of the RMS over validation
        attitudes, and its spread), hover bias, sliding metrics; plus the nominal map's figures.
    """
    check_count("--total", total_points, 1, MAX_STUDY_POINTS)
    check_count("--reps", reps, 1, MAX_STUDY_REPS)
    check_count("--validation", n_validation, 1, MAX_VALIDATION_ATTITUDES)
    aero = aero or make_aero(vehicle)
    params = IdentificationParams()
    val = validation_set(vehicle, aero, n_validation, np.random.default_rng([seed, 0]))
    bias_idx = np.random.default_rng([seed, 1]).choice(len(val.R_WB), size=min(60, len(val.R_WB)), replace=False)
    up = np.array([0.0, 0.0, vehicle.weight])
    nominal_res = np.linalg.norm(np.einsum("kji,j->ki", val.R_WB, up) - val.u_hz2 @ vehicle.A_nom[:3].T, axis=1)
    f_nom, m_nom = hover_bias(None, vehicle, aero, val.R_WB[bias_idx])
    out: dict = {
        "vehicle": vehicle.name,
        "total_points": total_points,
        "reps": reps,
        "noise": dataclasses.asdict(noise),
        "validation_attitudes": int(len(val.R_WB)),
        "bias_attitudes": int(len(bias_idx)),
        "nominal": {
            "force_residual_rms_N": float(np.sqrt(np.mean(nominal_res**2))),
            "bias_f_W_mean_N": f_nom.mean(axis=0).tolist(),
            "bias_f_rms_N": float(np.sqrt(np.mean(np.sum(f_nom**2, axis=1)))),
            "bias_m_rms_Nm": float(np.sqrt(np.mean(np.sum(m_nom**2, axis=1)))),
        },
        "partitions": {},
    }
    for p_index, (name, part) in enumerate(partitions.items()):
        counts = even_counts(part, total_points)
        if min(counts.values()) < vehicle.n_rotors - 3:
            raise InputError(
                f"partition {name}: {len(part.regions)} regions leave {min(counts.values())} point(s) per region "
                f"of {total_points}; at least {vehicle.n_rotors - 3} are needed"
            )
        pool_rng = np.random.default_rng([seed, 2, p_index])
        pool = build_pool(vehicle, aero, part, 3 * max(counts.values()), pool_rng)
        res_rms, res_all, f_rms, m_rms, f_mean = [], [], [], [], []
        first_maps = None
        for rep in range(reps):
            rng = np.random.default_rng([seed, 3, p_index, rep])
            data = draw(pool, vehicle, {n: min(c, pool.size(n)) for n, c in counts.items()}, noise, rng)
            maps = identify(data, vehicle, params, part)
            first_maps = first_maps or maps
            r = piecewise_force_residuals(part, maps.region_maps(), vehicle, val)
            res_rms.append(float(np.sqrt(np.mean(r**2))))
            res_all.append(r)
            f_b, m_b = hover_bias(maps, vehicle, aero, val.R_WB[bias_idx])
            f_rms.append(float(np.sqrt(np.mean(np.sum(f_b**2, axis=1)))))
            m_rms.append(float(np.sqrt(np.mean(np.sum(m_b**2, axis=1)))))
            f_mean.append(f_b.mean(axis=0))
        entry = {
            "regions": len(part.regions),
            "points_per_region": counts,
            "pool_sizes": {n: pool.size(n) for n in part.names},
            "force_residual_rms_N": {"mean": float(np.mean(res_rms)), "std": float(np.std(res_rms))},
            "force_residual_p90_N": float(np.percentile(np.concatenate(res_all), 90)),
            "bias_f_rms_N": {"mean": float(np.mean(f_rms)), "std": float(np.std(f_rms))},
            "bias_f_W_mean_N": np.mean(f_mean, axis=0).tolist(),
            "bias_m_rms_Nm": {"mean": float(np.mean(m_rms)), "std": float(np.std(m_rms))},
            "residuals_N": np.concatenate(res_all).tolist(),
        }
        if sliding and first_maps is not None:
            entry["sliding"] = _sliding(first_maps, sliding_quick, seed)
        out["partitions"][name] = entry
    return out


def plot_comparison(result: dict, path: str | Path) -> None:
    """Figure: residual distributions per partition, and bias bars (nominal map for reference)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(result["partitions"])
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    data = [result["partitions"][n]["residuals_N"] for n in names]
    axes[0].violinplot(data, showmedians=True)
    axes[0].axhline(result["nominal"]["force_residual_rms_N"], color="k", ls="--", lw=0.8, label="nominal map, RMS")
    labels = [f"{n}\n{result['partitions'][n]['regions']} regions" for n in names]
    axes[0].set_xticks(range(1, len(names) + 1), labels)
    axes[0].set_ylabel("force residual at validation attitudes [N]")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title(f"{result['total_points']} hover points in total, {result['reps']} repetitions")
    x = np.arange(len(names) + 1)
    f = [result["nominal"]["bias_f_rms_N"]] + [result["partitions"][n]["bias_f_rms_N"]["mean"] for n in names]
    fe = [0.0] + [result["partitions"][n]["bias_f_rms_N"]["std"] for n in names]
    m = [result["nominal"]["bias_m_rms_Nm"]] + [result["partitions"][n]["bias_m_rms_Nm"]["mean"] for n in names]
    axes[1].bar(x - 0.2, f, 0.4, yerr=fe, label="force bias RMS [N]")
    axes[1].bar(x + 0.2, np.array(m) * 10, 0.4, label="moment bias RMS [0.1 N·m]")
    axes[1].set_xticks(x, ["nominal"] + names)
    axes[1].set_title("observer bias in free hover (steady state)")
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_json(result: dict, path: str | Path) -> None:
    """Write the result (without the per-point residuals) as JSON."""
    from omnirotor.wrench_maps import write_json_atomic

    slim = json.loads(json.dumps(result))
    for entry in slim["partitions"].values():
        entry.pop("residuals_N", None)
    write_json_atomic(path, slim)
