"""``omnirotor identify``: wrench maps from hover data (SPEC §3), per region and global."""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from omnirotor.cli import app
from omnirotor.cli import window_options as wo
from omnirotor.cli.texts import VEHICLE_HELP
from omnirotor.config import parse_float
from omnirotor.errors import InputError

if TYPE_CHECKING:
    from omnirotor.wrench_maps import WrenchMapSet

from omnirotor.safe_io import check_output_file, dumps_json, note


def _weights(text: str | None) -> tuple[float, ...]:
    from omnirotor.identification import DEFAULT_WEIGHTS

    if text is None:
        return DEFAULT_WEIGHTS
    w = tuple(parse_float(x, "--weights") for x in text.split(","))
    if len(w) != 6:
        raise InputError(f"--weights: expected 6 numbers (fx,fy,fz,mx,my,mz), got {len(w)}")
    return w


def summary(maps: WrenchMapSet) -> dict:
    """The JSON printed by ``identify --json``: residuals of each identified map against nominal."""
    rows = {
        name: {
            "points": e.points,
            "nominal_force_residual_rms_N": e.nominal_force_residual_rms_N,
            "force_residual_rms_N": e.force_residual_rms_N,
        }
        for name, e in maps.regions.items()
    }
    g = maps.global_
    return {
        "vehicle": maps.vehicle,
        "delta": maps.delta,
        "regions": rows,
        "global": {
            "points": g.points,
            "nominal_force_residual_rms_N": g.nominal_force_residual_rms_N,
            "force_residual_rms_N": g.force_residual_rms_N,
        }
        if g
        else None,
    }


@app.command("identify")
def identify_cmd(
    data: Annotated[
        list[Path],
        typer.Argument(help="Hover data: .mat, .csv or PX4 .ulg files, ROS 2 bag folders, or folders of files."),
    ],
    delta: Annotated[str, typer.Option(help="Bound on each entry's change from nominal (units of A).")] = "3e-5",
    region: Annotated[str | None, typer.Option(help="Put every point of this call in region Rk.")] = None,
    out: Annotated[Path | None, typer.Option(help="Write the wrench-map JSON here.")] = None,
    vehicle: Annotated[
        str | None,
        typer.Option(help=VEHICLE_HELP + " Default: the first ULog's own, else omnirotor."),
    ] = None,
    vehicle_overlay: Annotated[
        Path | None, typer.Option(help="TOML of what PX4 does not store (mass, inertia, c_f, ...).")
    ] = None,
    partition: Annotated[str, typer.Option(help="Region partition: preset name or TOML file.")] = "paper",
    weights: Annotated[str | None, typer.Option(help="Row weights fx,fy,fz,mx,my,mz.")] = None,
    torque: Annotated[
        Path | None, typer.Option(help="Flight log (CSV of run identify-dynamic, or PX4 .ulg): fit torque rows.")
    ] = None,
    torque_partition: Annotated[
        str | None,
        typer.Option(
            help="Fit the torque rows per cell of this partition (preset, e.g. torque-cells, or TOML); each cell "
            "keeps the force rows of its region. Fly the cells with run identify-dynamic-cells, the maps with "
            "--blend smooth."
        ),
    ] = None,
    torque_pool: Annotated[
        bool,
        typer.Option(
            help="With --torque-partition: pool each cell's samples into its region of --partition (one set of "
            "torque rows per region, the maps keep --partition)."
        ),
    ] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    min_duration: wo.MinDuration = wo.DEFAULT.min_duration_s,
    accel_max: wo.AccelMax = wo.DEFAULT.accel_max,
    rate_max: wo.RateMax = wo.DEFAULT.rate_max,
    speed_max: wo.SpeedMax = wo.DEFAULT.speed_max,
    drift_max: wo.DriftMax = wo.DEFAULT.drift_max_deg,
    spread_max: wo.SpreadMax = wo.DEFAULT.spread_frac,
    spread_min: wo.SpreadMin = wo.DEFAULT.spread_min_hz2,
    spin_fraction: wo.SpinFraction = wo.DEFAULT.spin_fraction,
    trim: wo.Trim = wo.DEFAULT.trim_s,
    cutoff: wo.Cutoff = wo.DEFAULT.cutoff_hz,
    motion_cutoff: wo.MotionCutoff = wo.DEFAULT.motion_cutoff_hz,
) -> None:
    """Identify per-region and global wrench maps from hover data (box-constrained weighted QP).

    A PX4 log gives one hover point per steady window found automatically (the hover-window options, the same
    as `hover-windows`'); stderr says what each criterion rejected when few are found.
    """
    from rich.console import Console
    from rich.table import Table

    from omnirotor.identification import (
        IdentificationParams,
        identification_warnings,
        identify,
        load_hover_data,
    )
    from omnirotor.regions import load_partition
    from omnirotor.vehicle import load_vehicle

    delta_value = parse_float(delta, "--delta")
    if not (math.isfinite(delta_value) and delta_value > 0):
        raise InputError(f"--delta must be a finite number > 0, got {delta}")
    replacing = out is not None and check_output_file(out, "--out")
    criteria = wo.criteria(
        min_duration, accel_max, rate_max, speed_max, drift_max, spread_max, spread_min, spin_fraction, trim,
        cutoff, motion_cutoff,
    )  # fmt: skip
    if vehicle is None:  # a PX4 log carries its own rotor geometry
        vehicle = next((str(d) for d in data if d.suffix.lower() == ".ulg"), "omnirotor")
        if vehicle.endswith((".ulg", ".ULG")):
            from omnirotor.px4.flight import check_flight_log

            check_flight_log(vehicle)  # name missing attitude or rotor speeds before missing geometry
    veh = load_vehicle(vehicle, vehicle_overlay)
    part = load_partition(partition)
    if torque_partition is not None and torque is None:
        raise InputError("--torque-partition needs --torque FLIGHT (the flight log whose torque rows it fits)")
    if torque_pool and torque_partition is None:
        raise InputError("--torque-pool needs --torque-partition (the cells the flight's samples belong to)")
    cells = load_partition(torque_partition) if torque_partition is not None else None
    params = IdentificationParams(delta=delta_value, weights=_weights(weights))
    hover = load_hover_data(data, veh, criteria)
    maps = identify(hover, veh, params, part, region)
    warnings_ = identification_warnings(hover, veh, maps, region)  # said once the command has succeeded
    torque_fits = {}
    if torque is not None:
        from omnirotor.torque_identification import flight_torque_rows

        maps, torque_fits = flight_torque_rows(maps, torque, veh, delta_value, cells, torque_pool)
    if out is not None:
        maps.save(out)
        if replacing:
            note(f"--out {out}: replaced the existing file")
    for line in warnings_:
        print(f"omnirotor: warning: {line}", file=sys.stderr)
    rep = summary(maps)
    if torque_fits:
        rep["torque"] = {k: dataclasses.asdict(f) | {"A2": f.A2.tolist()} for k, f in torque_fits.items()}
    if as_json:
        print(dumps_json(rep))
        return
    t = Table(title=f"wrench maps of {veh.name}, Δ = {delta_value:g}: force residual RMS [N]")
    for c in ("map", "points", "nominal", "identified", "reduction"):
        t.add_column(c, justify="right" if c != "map" else "left")
    entries = list(maps.regions.items()) + ([("global", maps.global_)] if maps.global_ else [])
    for name, e in entries:
        t.add_row(
            name,
            str(e.points),
            f"{e.nominal_force_residual_rms_N:.3f}",
            f"{e.force_residual_rms_N:.3f}",
            f"×{e.nominal_force_residual_rms_N / max(e.force_residual_rms_N, 1e-12):.1f}",
        )
    con = Console()
    con.print(t)
    for name, f in torque_fits.items():
        con.print(
            f"torque rows of {name} from {f.samples} flight samples: moment residual RMS "
            f"{f.base_residual_rms_Nm:.3f} -> {f.residual_rms_Nm:.3f} N·m"
        )
    if out is not None:
        con.print(f"maps written to {out}")
