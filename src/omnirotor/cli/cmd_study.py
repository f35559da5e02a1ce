"""``omnirotor study``: studies beyond the paper (its §6): partitions compared, points per region, torque rows."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from omnirotor.cli import CommandGroup, app
from omnirotor.cli.texts import VEHICLE_HELP
from omnirotor.errors import InputError
from omnirotor.safe_io import atomic_path, check_output_dir, dumps_json, make_dir, write_json_atomic

NOISE_NAMES = "low, medium, high"
"""The noise levels named in the options' help (:data:`omnirotor.studies.hover_pool.NOISE_LEVELS`)."""

study_app = typer.Typer(
    cls=CommandGroup, help="Studies beyond the paper; each writes a JSON and a figure into --out.", no_args_is_help=True
)
app.add_typer(study_app, name="study")


def _noise_level(name: str):
    """The :class:`~omnirotor.studies.hover_pool.HoverNoise` named by ``--noise``."""
    from omnirotor.studies.hover_pool import NOISE_LEVELS

    if name not in NOISE_LEVELS:
        raise InputError(f"--noise must be one of {', '.join(NOISE_LEVELS)}, got {name!r}")
    return NOISE_LEVELS[name]


def _ints(text: str, what: str) -> tuple[int, ...]:
    try:
        vals = tuple(int(x) for x in text.split(","))
    except ValueError:
        raise InputError(f"{what}: expected comma-separated integers, got {text!r}") from None
    return vals


@study_app.command("points-per-region")
def points_per_region_cmd(
    out: Annotated[Path, typer.Option(help="Folder for points-per-region.json and .png.")],
    counts: Annotated[str, typer.Option(help="Points per region, comma separated.")] = "3,4,5,6,8,10,12,15,20,25,30",
    noise: Annotated[str, typer.Option(help=f"Noise levels, comma separated ({NOISE_NAMES}).")] = "low,medium,high",
    reps: Annotated[int, typer.Option(help="Seeded repetitions per (count, noise).")] = 40,
    validation: Annotated[int, typer.Option(help="Validation attitudes.")] = 300,
    workers: Annotated[int, typer.Option(help="Processes.")] = 2,
    seed: Annotated[int, typer.Option(help="Seed of the study.")] = 0,
    vehicle: Annotated[str, typer.Option(help=VEHICLE_HELP)] = "omnirotor",
    partition: Annotated[str, typer.Option(help="Region partition: preset name or TOML file.")] = "paper",
) -> None:
    """Validation error of the identified maps against hover points per region and hover noise."""
    from omnirotor.regions import load_partition
    from omnirotor.studies.points_per_region import plot_points_per_region, points_per_region_study
    from omnirotor.vehicle import load_vehicle

    check_output_dir(out, "--out")
    result = points_per_region_study(
        load_vehicle(vehicle),
        counts=_ints(counts, "--counts"),
        noises=tuple(n.strip() for n in noise.split(",")),
        reps=reps,
        n_validation=validation,
        seed=seed,
        workers=workers,
        partition=load_partition(partition),
    )
    make_dir(out, "--out")
    write_json_atomic(out / "points-per-region.json", result, "--out")
    with atomic_path(out / "points-per-region.png", "--out") as tmp:
        plot_points_per_region(result, tmp)
    for name, res in result["results"].items():
        cells = ", ".join(f"{k}: {v['mean']:.3f}" for k, v in res.items())
        print(f"noise {name}: validation force residual RMS [N] by points per region: {cells}")
    print(f"nominal map: {result['nominal_force_residual_rms_N']:.3f} N; written to {out}")


@study_app.command("partitions")
def partitions_cmd(
    out: Annotated[Path, typer.Option(help="Folder for partitions.json and .png.")],
    partition: Annotated[
        list[str], typer.Option(help="Partitions to compare (preset name or TOML file); repeat the option.")
    ] = None,  # noqa: B008
    total: Annotated[int, typer.Option(help="Hover points in total per identification.")] = 150,
    reps: Annotated[int, typer.Option(help="Seeded repetitions.")] = 10,
    noise: Annotated[str, typer.Option(help=f"Noise level ({NOISE_NAMES}).")] = "medium",
    validation: Annotated[int, typer.Option(help="Validation attitudes.")] = 300,
    sliding: Annotated[bool, typer.Option("--sliding/--no-sliding", help="Fly one sliding run per partition.")] = True,
    full_sliding: Annotated[
        bool, typer.Option("--full-sliding", help="The paper's sliding run, not the quick one.")
    ] = (False),
    seed: Annotated[int, typer.Option(help="Seed of the study.")] = 0,
    vehicle: Annotated[str, typer.Option(help=VEHICLE_HELP)] = "omnirotor",
) -> None:
    """Compare partitions at equal total hover points: residual, hover bias, sliding (closed loop)."""
    from omnirotor.regions import load_partition
    from omnirotor.studies.partitions import compare_partitions, plot_comparison, write_json
    from omnirotor.vehicle import load_vehicle

    noise_level = _noise_level(noise)
    check_output_dir(out, "--out")
    names = partition or ["paper"]
    parts = {}
    for spec in names:
        p = load_partition(spec)
        key = Path(spec).stem if spec.endswith(".toml") else spec
        if key in parts:
            raise InputError(f"--partition {spec}: named twice")
        parts[key] = p
    result = compare_partitions(
        load_vehicle(vehicle),
        parts,
        total_points=total,
        reps=reps,
        noise=noise_level,
        n_validation=validation,
        seed=seed,
        sliding=sliding,
        sliding_quick=not full_sliding,
    )
    make_dir(out, "--out")
    with atomic_path(out / "partitions.png", "--out") as tmp:
        plot_comparison(result, tmp)
    write_json(result, out / "partitions.json")
    for name, e in result["partitions"].items():
        line = (
            f"{name}: {e['regions']} regions, residual RMS {e['force_residual_rms_N']['mean']:.3f} N, "
            f"hover force bias RMS {e['bias_f_rms_N']['mean']:.3f} N, "
            f"moment bias RMS {e['bias_m_rms_Nm']['mean']:.3f} N·m"
        )
        if "sliding" in e:
            s = e["sliding"]
            line += f", sliding contact {100 * s['contact_fraction']:.0f} %, {s['map_switches']} map switches"
        print(line)
    print(dumps_json(result["nominal"], indent=None))


@study_app.command("torque-rows")
def torque_rows_cmd(
    out: Annotated[Path, typer.Option(help="Folder for the flights, maps, torque-rows.json and .png.")],
    quick: Annotated[bool, typer.Option("--quick", help="Shortened flights (R1 only for the sweeps).")] = False,
    seed: Annotated[int, typer.Option(help="Seed of the flights.")] = 0,
    vehicle: Annotated[str, typer.Option(help=VEHICLE_HELP)] = "omnirotor",
    validation_attitudes: Annotated[
        int | None, typer.Option(help="Validation attitudes per region (default: the hover protocol's, 5 or 2).")
    ] = None,
) -> None:
    """Torque rows from attitude-sweep flights against hover-only maps (closed loop, paper Fig. 3 moments)."""
    import dataclasses

    import numpy as np

    from omnirotor.experiments.tasks.common import HoverProtocol
    from omnirotor.studies.torque_rows import plot_hover_moments, plot_torque_rows, torque_rows_study
    from omnirotor.vehicle import load_vehicle

    check_output_dir(out, "--out")
    load_vehicle(vehicle)  # a bad vehicle is one line before the folder is made
    protocol = None
    if validation_attitudes is not None:
        if not 2 <= validation_attitudes <= 100:
            raise InputError(f"--validation-attitudes must be in [2, 100], got {validation_attitudes}")
        base = HoverProtocol.quick() if quick else HoverProtocol()
        protocol = dataclasses.replace(base, validation_per_region=validation_attitudes)
    make_dir(out, "--out")
    result = torque_rows_study(out, quick=quick, seed=seed, vehicle_name=vehicle, validation=protocol)
    write_json_atomic(out / "torque-rows.json", result, "--out")
    with atomic_path(out / "torque-rows.png", "--out") as tmp:
        plot_torque_rows(result, tmp)
    with atomic_path(out / "torque-moments.png", "--out") as tmp:
        plot_hover_moments(result, tmp)
    for r, e in result["torque_rows"].items():
        print(
            f"{r}: mean |A2 entry - truth| nominal {e['entry_abs_error_nominal_mean']:.2e}, identified "
            f"{e['entry_abs_error_identified_mean']:.2e} N·m/Hz² ({e['samples']} samples)"
        )
    for mname, regs in result["hover_validation_moments"].items():
        cells = "; ".join(
            f"{r} mean {np.round(v['moment_B_mean_Nm'], 3).tolist()} "
            f"spread over attitudes {np.round(v['moment_B_std_over_attitudes_Nm'], 3).tolist()}"
            for r, v in regs.items()
        )
        print(f"hover moment estimate [N·m], {mname}: {cells}")
