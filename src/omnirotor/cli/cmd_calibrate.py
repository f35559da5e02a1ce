"""``omnirotor calibrate-truth``: fit the simulator's rotor-wake truth model to real hover data (SPEC §3.5, §7.1)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from omnirotor.cli import app
from omnirotor.cli.texts import VEHICLE_HELP
from omnirotor.errors import InputError


@app.command("calibrate-truth")
def calibrate_truth_cmd(
    data: Annotated[list[Path], typer.Argument(help="Hover data with measured wrenches: .mat/.csv files or folders.")],
    out: Annotated[Path, typer.Option(help="Write the calibrated [aero] table here (simulator TOML).")],
    report: Annotated[
        Path | None,
        typer.Option(
            help="Folder for report.md and measured-vs-predicted.png (default: the report beside --out, as "
            "OUT-report.md)."
        ),
    ] = None,
    vehicle: Annotated[str, typer.Option(help=VEHICLE_HELP)] = "omnirotor",
    partition: Annotated[str, typer.Option(help="Region partition (groups of the cross-validation).")] = "paper",
    loo: Annotated[bool, typer.Option("--loo/--no-loo", help="Also run leave-one-point-out refits.")] = True,
    stand_prior: Annotated[
        bool, typer.Option("--stand-prior/--no-stand-prior", help="Fit with the force-stand ratios of SPEC §3.5.")
    ] = True,
) -> None:
    """Fit the rotor-wake truth model; write the report (comparison table, cross-validations) to a file.

    stdout gets one summary line; stderr shows progress (about 90 s with --loo on the paper's 39 points).
    """
    if out.exists() and out.is_dir():
        raise InputError(f"--out {out}: is a folder")
    if not out.parent.exists():
        raise InputError(f"--out {out}: folder {out.parent} does not exist")
    if report is not None and report.exists() and not report.is_dir():
        raise InputError(f"--report {report}: is a file, not a folder")
    from omnirotor.experiments.calibration.truth import (
        calibrate,
        plot_measured_vs_predicted,
        report_markdown,
        write_truth_toml,
    )
    from omnirotor.identification import load_hover_data
    from omnirotor.regions import load_partition
    from omnirotor.vehicle import load_vehicle

    veh = load_vehicle(vehicle)
    part = load_partition(partition)
    hover = load_hover_data(data, veh)
    if not hover.w_B[:, :3].any():
        raise InputError("the hover data hold no measured forces")
    from rich.console import Console

    from omnirotor.safe_io import write_text_atomic

    what = "fit, leave-one-region-out" + (" and leave-one-point-out refits" if loo else " refits")
    with Console(stderr=True).status(f"calibrating the rotor-wake truth on {hover.n_points} hover points ({what})"):
        result = calibrate(veh, hover, part, leave_one_point=loo, stand_prior=stand_prior)
    text = report_markdown(result)
    if report is not None:
        report.mkdir(parents=True, exist_ok=True)
        plot_measured_vs_predicted(result, report / "measured-vs-predicted.png")
        report_file = report / "report.md"
    else:
        report_file = out.with_name(f"{out.stem}-report.md")
    write_text_atomic(report_file, text)
    write_truth_toml(out, result.params)
    rms = {name: row["all"] for name, row in result.table.items()}
    cv = max(result.cv_region.values()) if result.cv_region else float("nan")
    calibrated = rms.get("rotor-wake model (calibrated)", float("nan"))
    print(
        f"rotor-wake truth: force RMS {calibrated:.3f} N over {hover.n_points} points (SPEC §7 model "
        f"{rms.get('SPEC §7 model', float('nan')):.3f} N, nominal map {rms.get('nominal', float('nan')):.3f} N), "
        f"worst held-out region {cv:.3f} N; table {out}, report {report_file}"
    )


@app.command("calibrate-disturbances")
def calibrate_disturbances_cmd(
    out: Annotated[
        Path, typer.Option(help="Write the calibrated [sensors] and [airflow] values here (simulator TOML).")
    ],
    report: Annotated[
        Path, typer.Option(help="Folder for disturbances.md, disturbances.json and the prediction's runs.")
    ],
    grid: Annotated[
        str | None,
        typer.Option(
            help="Points acc_vib_noise_std:force_std:mocap_drift_pos_std [m/s²:N:m] flown on the calibration "
            "row, comma-separated (default: 0, 2, 4 m/s² x 0, 2, 4 N next to a surface x 0, 10, 20 mm: 27 runs). "
            "Rules: at least 4 points, every value finite and >= 0, every parameter above 0 in some point (each "
            "cell's mean square is fitted as a0 + sum a_i s_i², which needs them)."
        ),
    ] = None,
    quick: Annotated[bool, typer.Option(help="Shortened protocols.")] = False,
    seed: Annotated[int, typer.Option(help="Seed of every run.")] = 0,
    workers: Annotated[int, typer.Option(min=1, max=64, help="Processes.")] = 2,
    doc: Annotated[
        Path | None, typer.Option(help="Also put the report into this Markdown file, between its markers.")
    ] = None,
) -> None:
    """Calibrate the disturbances on Table 1's straight point-contact row; predict the other rows.

    Flies the point-contact task at every grid point, fits each RMS cell, flies the best values again and
    predicts the other five rows with `reproduce`. Writes the [sensors] and [airflow] values to --out, the report
    to REPORT/disturbances.md (and --doc), the numbers to REPORT/disturbances.json; progress on stderr.
    """
    from omnirotor.config import parse_float
    from omnirotor.experiments.calibration.disturbances import (
        DEFAULT_GRID,
        PARAMETERS,
        calibrate_disturbances,
        report_markdown,
        save_json,
        write_toml,
    )
    from omnirotor.limits import MAX_SEED
    from omnirotor.safe_io import check_output_dir

    if out.exists() and out.is_dir():
        raise InputError(f"--out {out}: is a folder")
    if not out.parent.exists():
        raise InputError(f"--out {out}: folder {out.parent} does not exist")
    if doc is not None and not doc.is_file():
        raise InputError(f"--doc {doc}: no such file")
    if not 0 <= seed <= MAX_SEED:
        raise InputError("--seed must be an integer in [0, 2^63 - 1]")
    values = list(DEFAULT_GRID)
    if grid is not None:
        values = []
        names = ":".join(p.split(".")[1] for p in PARAMETERS)
        for point in grid.split(","):
            parts = point.split(":")
            if len(parts) != len(PARAMETERS):
                raise InputError(f"--grid: {point.strip()!r} is not a point {names}")
            values.append(tuple(parse_float(x, "--grid") for x in parts))
    check_output_dir(report, "--report")
    result = calibrate_disturbances(
        report, values, quick=quick, seed=seed, workers=workers, progress=lambda line: sys.stderr.write(line + "\n")
    )
    text = report_markdown(result)
    (report / "disturbances.md").write_text(text)
    save_json(report / "disturbances.json", result)
    write_toml(out, result.value)
    if doc is not None:
        from omnirotor.experiments.calibration.disturbances import replace_section

        replace_section(doc, text)
    sys.stdout.write(text)
