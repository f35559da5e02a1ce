"""Torque rows from dynamic flight against hover-only maps, in closed loop (issue 15, item 1; paper Fig. 3).

Steps, all in the simulator with its truth aerodynamics (``make_aero(vehicle)``):

1. ``identify-flights`` (closed loop, nominal map): hover points; ``identify`` gives the hover-only maps,
   whose torque rows stay nominal (SPEC §3.2 weighs them 1e-12);
2. ``identify-dynamic`` (closed loop, nominal map): the attitude sweeps; their gyro and measured rotor
   speeds give the torque rows per region (:mod:`omnirotor.torque_identification`), which replace those
   of the hover-only maps;
3. the truth's torque rows per region, for comparison entry by entry: the truth model is not linear in u, so
   its "A_2" is defined here as the least-squares linear map ``min Σ |m_true(u) - A_2 u|²`` over the
   flight's inputs of that region, each repeated 4 times with every rotor's input scaled by an independent
   factor ``1 + 0.2 N(0, 1)`` (seeded): the flight's own inputs leave the 2-D null space of the nominal map
   unexcited, so a fit on them alone would not define every entry. The moment residuals on the flight's
   own inputs are reported too;
4. ``identify-dynamic-cells`` (closed loop, nominal map, null-space dither): the same sweeps at the base of
   every cell of the ``torque-cells`` partition; torque rows per cell on the hover-only maps refined onto
   the cells (:func:`omnirotor.torque_identification.refine_maps`);
5. ``hover-validation`` (closed loop, new attitudes: drawn from the seed, neither the identification
   attitudes nor the sweep bases) with the nominal map, the hover-only piecewise maps, the hover + flight
   piecewise maps, two ablations (the flight of step 2 again with the cells' null-space dither; the cell
   flight pooled into one set of torque rows per region, hard switch) and the hover + cell-flight maps
   blended smoothly (``blend = "smooth"``): the observer's moment estimate in free hover, whose mean is its
   bias and whose spread over the attitudes (``moment_B_std_over_attitudes_Nm``) is how the moment error
   changes from one attitude to another (paper Fig. 3, moments).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from omnirotor.errors import InputError
from omnirotor.experiments.tasks import run_task
from omnirotor.experiments.tasks.common import ExperimentOptions, HoverProtocol
from omnirotor.experiments.tasks.identify_dynamic import (
    CELL_BASES,
    CELL_NULL_DITHER_HZ2,
    CELL_PARTITION,
    SweepProtocol,
    base_attitude,
    fly_sweeps,
)
from omnirotor.experiments.tasks.scenarios import hover_attitudes
from omnirotor.identification import identify, load_csv
from omnirotor.regions import load_partition
from omnirotor.sim.aero import hover_equilibrium, make_aero
from omnirotor.sim.params import AeroParams
from omnirotor.torque_identification import (
    TorqueIdParams,
    cell_regions,
    load_flight_csv,
    merge_torque_rows,
    moment_samples,
    refine_maps,
    torque_residual_rms,
)
from omnirotor.vehicle import VehicleParams, load_vehicle
from omnirotor.wrench_maps import WrenchMapSet

__all__ = [
    "truth_torque_rows",
    "torque_rows_study",
    "plot_torque_rows",
    "plot_hover_moments",
    "spread_sources",
    "base_hover_moments",
]


def truth_torque_rows(aero, u_hz2: np.ndarray, rng: np.random.Generator, spread: float = 0.2) -> np.ndarray:
    """(3, n) least-squares torque rows of the truth model around the inputs ``u_hz2`` (N, n) [Hz²] (step 3)."""
    U = np.repeat(u_hz2, 4, axis=0)
    U = U * (1.0 + spread * rng.standard_normal(U.shape))
    m = np.array([aero.wrench_B(u)[3:] for u in U])
    return np.linalg.lstsq(U, m, rcond=None)[0].T


def spread_sources(vehicle: VehicleParams, per_region: int, seed: int) -> dict:
    """Offline: the spread over hover attitudes of the nominal map's moment estimate, truth terms switched off.

    At ``per_region`` attitudes per region of the hover protocol (drawn as ``hover-validation`` draws them),
    the truth's hover equilibrium under the nominal map's allocation (:func:`hover_equilibrium`) gives the
    inputs ``u`` and the estimate ``-A2_nom u``; its standard deviation over the attitudes, per region and
    component [N·m], for the full truth and with the rotor-wake interaction, the reverse gain or the frame yaw
    switched off.
    """
    base = AeroParams()
    variants = {
        "full": base,
        "no wake interaction": dataclasses.replace(base, ingest_gain=0.0, counter_gain=0.0),
        "no reverse gain": dataclasses.replace(base, reverse_gain=0.0),
        "no frame yaw": dataclasses.replace(base, frame_yaw_deg=0.0),
    }
    proto = HoverProtocol()
    attitudes = hover_attitudes(
        load_partition("paper"),
        list(proto.regions),
        per_region,
        np.random.default_rng([seed, 2]),
        vehicle,
        proto.min_speed_hz,
    )
    out: dict = {}
    for name, params in variants.items():
        aero = make_aero(vehicle, params)
        est = {r: [] for r in proto.regions}
        for r, R in attitudes:
            est[r].append(-(vehicle.A_nom[3:] @ hover_equilibrium(aero, vehicle, R)))
        out[name] = {r: np.std(np.array(v), axis=0).tolist() for r, v in est.items() if v}
    return out


def base_hover_moments(maps: WrenchMapSet, vehicle: VehicleParams, bases: dict[str, tuple[float, float]]) -> dict:
    """At each cell's base attitude: the hover moment its torque rows leave, at two hover inputs.

    ``flown``: the inputs of the identification flight's hover there (the nominal map's allocation);
    ``allocated``: the inputs of a controller flying the cell's own map; and how much of those lies in the
    null space of the nominal map [Hz²] (``pinv`` allocation, truth equilibrium, :func:`hover_equilibrium`).
    """
    aero = make_aero(vehicle)
    null = np.linalg.svd(vehicle.A_nom)[2][6:]
    out = {}
    for cell, az_el in bases.items():
        R = base_attitude(az_el)
        A = maps.regions[cell].A
        u_flown = hover_equilibrium(aero, vehicle, R)
        u_alloc = hover_equilibrium(aero, vehicle, R, A_map=A)
        out[cell] = {
            "flown_Nm": float(np.abs(A[3:] @ u_flown).max()),
            "allocated_Nm": float(np.abs(A[3:] @ u_alloc).max()),
            "allocated_null_space_hz2": float(np.linalg.norm(null @ u_alloc)),
            "allocated_null_fraction": float(np.linalg.norm(null @ u_alloc) / np.linalg.norm(u_alloc)),
        }
    return out


def _validation(
    maps_path: str | None, mode: str, quick: bool, seed: int, protocol: HoverProtocol | None, blend: str = "hard"
) -> dict:
    opts = ExperimentOptions(
        map_mode=mode, maps=maps_path, quick=quick, seed=seed, out_dir=None, protocol=protocol, blend=blend
    )
    m = run_task("hover-validation", opts).summary()
    return {
        r: {k: v for k, v in e.items() if k.startswith("moment") or k == "attitudes"} for r, e in m["regions"].items()
    }


def torque_rows_study(
    out: str | Path,
    quick: bool = False,
    seed: int = 0,
    vehicle_name: str = "omnirotor",
    validation: HoverProtocol | None = None,
) -> dict:
    """Run the study (module docstring); files go to ``out``; returns a JSON-able dict.

    Args:
        out: folder for the flights, the maps and the figure.
        quick: shortened flights (the sweeps in R1 only).
        seed: seed of the flights and of the validation attitudes.
        vehicle_name: vehicle preset or TOML.
        validation: hover protocol of the validation runs (None: the task's, quick or full).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    vehicle = load_vehicle(vehicle_name)
    aero = make_aero(vehicle)
    common = {"quick": quick, "seed": seed, "vehicle": vehicle_name}
    run_task("identify-flights", ExperimentOptions(out_dir=str(out), **common))
    run_task("identify-dynamic", ExperimentOptions(out_dir=str(out), **common))
    hover = load_csv(out / "hover_points.csv", vehicle)
    maps_hover = identify(hover, vehicle)
    params = TorqueIdParams()
    flight = load_flight_csv(out / "flight.csv", vehicle)
    u, m, region = moment_samples(flight, vehicle, params)
    maps_dyn, fits = merge_torque_rows(maps_hover, u, m, region, params)
    if not any(k != "global" for k in fits):
        raise InputError("the flight left no region with enough samples for a torque fit")
    maps_hover.save(out / "maps-hover.json")
    maps_dyn.save(out / "maps-hover-flight.json")
    names = np.array(region)
    entries = {}
    for r, fit in fits.items():
        mask = np.ones(names.size, dtype=bool) if r == "global" else names == r
        A2_true = truth_torque_rows(aero, u[mask], np.random.default_rng([seed, 7]))
        m_true = np.array([aero.wrench_B(x)[3:] for x in u[mask]])
        A2_nom = vehicle.A_nom[3:]
        entries[r] = {
            "samples": fit.samples,
            "A2_nominal": A2_nom.tolist(),
            "A2_truth": A2_true.tolist(),
            "A2_identified": fit.A2.tolist(),
            "entry_abs_error_nominal_mean": float(np.abs(A2_nom - A2_true).mean()),
            "entry_abs_error_identified_mean": float(np.abs(fit.A2 - A2_true).mean()),
            "entry_abs_error_nominal_max": float(np.abs(A2_nom - A2_true).max()),
            "entry_abs_error_identified_max": float(np.abs(fit.A2 - A2_true).max()),
            "truth_moment_residual_rms_Nm": {
                "nominal": torque_residual_rms(u[mask], m_true, A2_nom),
                "identified": torque_residual_rms(u[mask], m_true, fit.A2),
                "truth_local_ls": torque_residual_rms(u[mask], m_true, A2_true),
            },
            "measured_moment_residual_rms_Nm": {"nominal": fit.base_residual_rms_Nm, "identified": fit.residual_rms_Nm},
        }
    # ablation: the one-base flight with the cells' null-space dither
    base = SweepProtocol.quick() if quick else SweepProtocol()
    dithered = dataclasses.replace(base, null_dither_hz2=CELL_NULL_DITHER_HZ2)
    fly_sweeps(ExperimentOptions(out_dir=str(out / "dither"), **common), dithered)
    d_flight = load_flight_csv(out / "dither" / "flight.csv", vehicle)
    maps_dither, _ = merge_torque_rows(maps_hover, *moment_samples(d_flight, vehicle, params), params)
    maps_dither.save(out / "maps-hover-flight-dither.json")
    run_task("identify-dynamic-cells", ExperimentOptions(out_dir=str(out / "cells"), **common))
    cell_flight = load_flight_csv(out / "cells" / "flight.csv", vehicle)
    u_c, m_c, region_c = moment_samples(cell_flight, vehicle, params)
    maps_cells, cell_fits = merge_torque_rows(
        refine_maps(maps_hover, load_partition(CELL_PARTITION)), u_c, m_c, region_c, params
    )
    maps_cells.save(out / "maps-hover-cells.json")
    # the same flight, one set of torque rows per region (the cells' samples pooled): what the cells add
    owner = cell_regions(maps_hover.partition, maps_cells.partition)
    pooled_region = tuple(owner.get(c, "") for c in region_c)
    maps_pooled, _ = merge_torque_rows(maps_hover, u_c, m_c, pooled_region, params)
    maps_pooled.save(out / "maps-hover-cells-pooled.json")
    flown = {
        c: b
        for r in (SweepProtocol.quick("cells") if quick else SweepProtocol()).regions
        for c, b in CELL_BASES[r].items()
    }
    at_bases = base_hover_moments(maps_cells, vehicle, flown)
    cells = {
        r: {
            "samples": f.samples,
            "measured_moment_residual_rms_Nm": {"nominal": f.base_residual_rms_Nm, "identified": f.residual_rms_Nm},
            **({"at_base": at_bases[r]} if r in at_bases else {}),
        }
        for r, f in cell_fits.items()
    }
    v = validation
    hover_val = {
        "nominal": _validation(None, "nominal", quick, seed, v),
        "hover-only": _validation(str(out / "maps-hover.json"), "piecewise", quick, seed, v),
        "hover+flight": _validation(str(out / "maps-hover-flight.json"), "piecewise", quick, seed, v),
        "hover+flight dither": _validation(str(out / "maps-hover-flight-dither.json"), "piecewise", quick, seed, v),
        "hover+cells pooled": _validation(str(out / "maps-hover-cells-pooled.json"), "piecewise", quick, seed, v),
        "hover+cells": _validation(str(out / "maps-hover-cells.json"), "piecewise", quick, seed, v, "smooth"),
    }
    result = {
        "vehicle": vehicle_name,
        "quick": quick,
        "seed": seed,
        "params": dataclasses.asdict(params),
        "torque_rows": entries,
        "cells": cells,
        "hover_validation_moments": hover_val,
        "spread_sources_offline_Nm": spread_sources(vehicle, 8 if quick else 40, seed),
    }
    return result


def plot_torque_rows(result: dict, path: str | Path) -> None:
    """Figure: torque-row entries (nominal, truth, identified) and the hover moment estimate per region and map."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    regions = [r for r in result["torque_rows"] if r != "global"]
    fig, axes = plt.subplots(1 + len(regions), 1, figsize=(11, 2.6 * (1 + len(regions))))
    axes = np.atleast_1d(axes)
    for ax, r in zip(axes[: len(regions)], regions, strict=True):
        e = result["torque_rows"][r]
        x = np.arange(np.asarray(e["A2_truth"]).size)
        for k, (key, lab) in enumerate(
            (("A2_nominal", "nominal"), ("A2_truth", "truth (LS)"), ("A2_identified", "identified from flight"))
        ):
            ax.bar(x + (k - 1) * 0.27, np.asarray(e[key]).ravel() * 1e5, 0.27, label=lab)
        n = np.asarray(e["A2_truth"]).shape[1]
        ax.set_xticks(x, [f"{'xyz'[i // n]}{i % n + 1}" for i in x], fontsize=7)
        ax.set_ylabel("A2 [1e-5 N·m/Hz²]")
        ax.set_title(
            f"{r}: torque-row entries (row m_x/m_y/m_z, rotor); mean |entry - truth|: nominal "
            f"{e['entry_abs_error_nominal_mean'] * 1e5:.2f}, "
            f"identified {e['entry_abs_error_identified_mean'] * 1e5:.2f}",
            fontsize=9,
        )
        ax.legend(fontsize=7, ncol=3)
    ax = axes[-1]
    hv = result["hover_validation_moments"]
    maps = list(hv)
    regs = sorted({r for m in maps for r in hv[m]})
    width = 0.8 / len(maps)
    for i, mname in enumerate(maps):
        for j, r in enumerate(regs):
            if r not in hv[mname]:
                continue
            mean = np.asarray(hv[mname][r]["moment_B_mean_Nm"])
            std = np.asarray(hv[mname][r]["moment_B_std_over_attitudes_Nm"])
            xs = j * 4 + np.arange(3) + (i - (len(maps) - 1) / 2) * width
            ax.bar(xs, mean, width, yerr=std, color=f"C{i}", label=mname if j == 0 else None)
    ax.set_xticks([j * 4 + k for j in range(len(regs)) for k in range(3)], [f"{r} m{a}" for r in regs for a in "xyz"])
    ax.axhline(0, color="k", lw=0.6)
    ax.set_ylabel("estimated moment in hover [N·m]")
    ax.set_title(
        "observer's moment estimate in free hover at new attitudes (mean ± spread over attitudes; no moment acts)",
        fontsize=9,
    )
    ax.legend(fontsize=7)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_hover_moments(result: dict, path: str | Path) -> None:
    """Figure like the paper's Fig. 3 for moments: each validation attitude's mean moment estimate, per map."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    hv = result["hover_validation_moments"]
    maps = list(hv)
    regs = sorted({r for m in maps for r in hv[m]})
    fig, axes = plt.subplots(
        2, len(regs), figsize=(4.4 * len(regs), 6.4), sharey="row", squeeze=False, height_ratios=(3, 2)
    )
    width = 0.8 / len(maps)
    for ax, r in zip(axes[1], regs, strict=True):
        for i, mname in enumerate(maps):
            if r in hv[mname]:
                xs = np.arange(3) + (i - (len(maps) - 1) / 2) * width
                ax.bar(xs, hv[mname][r]["moment_B_std_over_attitudes_Nm"], width, color=f"C{i}")
        ax.set_xticks(range(3), ["m_x", "m_y", "m_z"])
        ax.grid(axis="y", alpha=0.3)
    axes[1][0].set_ylabel("spread over attitudes [N·m]")
    for ax, r in zip(axes[0], regs, strict=True):
        for i, mname in enumerate(maps):
            e = hv[mname].get(r)
            if e is None:
                continue
            pts = np.asarray(e["moment_B_per_attitude_Nm"])
            xs = np.arange(3) + (i - (len(maps) - 1) / 2) * width
            ax.bar(xs, pts.mean(axis=0), width, color=f"C{i}", alpha=0.35, label=mname)
            for k in range(3):
                ax.plot(np.full(pts.shape[0], xs[k]), pts[:, k], "o", ms=3, color=f"C{i}")
            sd = np.asarray(e["moment_B_std_over_attitudes_Nm"])
            ax.errorbar(xs, pts.mean(axis=0), yerr=sd, fmt="none", ecolor="k", elinewidth=0.8, capsize=2)
        ax.axhline(0, color="k", lw=0.6)
        ax.set_xticks(range(3), ["m_x", "m_y", "m_z"])
        n = hv[maps[0]][r]["attitudes"] if r in hv[maps[0]] else 0
        ax.set_title(f"{r} ({n} attitudes)", fontsize=9)
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel("moment estimate in free hover [N·m]")
    axes[0][0].legend(fontsize=7)
    fig.suptitle(
        f"observer's moment estimate per validation attitude (dots), mean (bar) ± spread over attitudes; "
        f"seed {result['seed']}",
        fontsize=9,
    )
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
