"""``omnirotor calibrate-truth``: fit the simulator's rotor-wake truth model to real hover data (SPEC §3.5, §7.1)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from omnirotor.cli import app
from omnirotor.errors import InputError
from omnirotor.identification import load_hover_data
from omnirotor.regions import load_partition
from omnirotor.sim.aero_calibration import calibrate, plot_measured_vs_predicted, report_markdown, write_truth_toml
from omnirotor.vehicle import load_vehicle


@app.command("calibrate-truth")
def calibrate_truth_cmd(
    data: Annotated[list[Path], typer.Argument(help="Hover data with measured wrenches: .mat/.csv files or folders.")],
    out: Annotated[Path, typer.Option(help="Write the calibrated [aero] table here (simulator TOML).")],
    report: Annotated[Path | None, typer.Option(help="Folder for report.md and measured-vs-predicted.png.")] = None,
    vehicle: Annotated[str, typer.Option(help="Preset name or vehicle TOML file.")] = "omnirotor",
    partition: Annotated[str, typer.Option(help="Region partition (groups of the cross-validation).")] = "paper",
    loo: Annotated[bool, typer.Option("--loo/--no-loo", help="Also run leave-one-point-out refits.")] = True,
    stand_prior: Annotated[
        bool, typer.Option("--stand-prior/--no-stand-prior", help="Fit with the force-stand ratios of SPEC §3.5.")
    ] = True,
) -> None:
    """Fit the rotor-wake truth model; print the comparison table and the leave-one-region-out cross-validation."""
    if out.exists() and out.is_dir():
        raise InputError(f"--out {out}: is a folder")
    if not out.parent.exists():
        raise InputError(f"--out {out}: folder {out.parent} does not exist")
    if report is not None and report.exists() and not report.is_dir():
        raise InputError(f"--report {report}: is a file, not a folder")
    veh = load_vehicle(vehicle)
    part = load_partition(partition)
    hover = load_hover_data(data, veh)
    if not hover.w_B[:, :3].any():
        raise InputError("the hover data hold no measured forces")
    result = calibrate(veh, hover, part, leave_one_point=loo, stand_prior=stand_prior)
    text = report_markdown(result)
    if report is not None:
        report.mkdir(parents=True, exist_ok=True)
        plot_measured_vs_predicted(result, report / "measured-vs-predicted.png")
        (report / "report.md").write_text(text)
    write_truth_toml(out, result.params)
    sys.stdout.write(text)
