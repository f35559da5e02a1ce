"""``omnirotor identify``: wrench maps from hover data (SPEC §3), per region and global."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from omnirotor.cli import app
from omnirotor.errors import InputError
from omnirotor.identification import DEFAULT_WEIGHTS, IdentificationParams, identify, load_hover_data
from omnirotor.regions import load_partition
from omnirotor.vehicle import load_vehicle
from omnirotor.wrench_maps import WrenchMapSet


def _weights(text: str | None) -> tuple[float, ...]:
    if text is None:
        return DEFAULT_WEIGHTS
    try:
        w = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise InputError(f"--weights: expected 6 comma-separated numbers, got {text!r}") from None
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
    data: Annotated[list[Path], typer.Argument(help="Hover data: .mat, .csv or PX4 .ulg files, or folders of them.")],
    delta: Annotated[str, typer.Option(help="Bound on each entry's change from nominal (units of A).")] = "3e-5",
    region: Annotated[str | None, typer.Option(help="Put every point of this call in region Rk.")] = None,
    out: Annotated[Path | None, typer.Option(help="Write the wrench-map JSON here.")] = None,
    vehicle: Annotated[
        str | None,
        typer.Option(help="Preset, vehicle TOML, PX4 airframe or ULog (default: a ULog's own, else omnirotor)."),
    ] = None,
    vehicle_overlay: Annotated[
        Path | None, typer.Option(help="TOML of what PX4 does not store (mass, inertia, c_f, ...).")
    ] = None,
    partition: Annotated[str, typer.Option(help="Region partition: preset name or TOML file.")] = "paper",
    weights: Annotated[str | None, typer.Option(help="Row weights fx,fy,fz,mx,my,mz.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Identify per-region and global wrench maps from hover data (box-constrained weighted QP)."""
    try:
        delta_value = float(delta)
    except ValueError:
        raise InputError(f"--delta: not a number: {delta!r}") from None
    if not (math.isfinite(delta_value) and delta_value > 0):
        raise InputError(f"--delta must be a finite number > 0, got {delta}")
    if out is not None and out.exists() and out.is_dir():
        raise InputError(f"--out {out}: is a folder")
    if vehicle is None:  # a PX4 log carries its own rotor geometry
        vehicle = next((str(d) for d in data if d.suffix.lower() == ".ulg"), "omnirotor")
        if vehicle.endswith((".ulg", ".ULG")):
            from omnirotor.px4.flight import check_flight_log

            check_flight_log(vehicle)  # name missing attitude or rotor speeds before missing geometry
    veh = load_vehicle(vehicle, vehicle_overlay)
    part = load_partition(partition)
    params = IdentificationParams(delta=delta_value, weights=_weights(weights))
    hover = load_hover_data(data, veh)
    maps = identify(hover, veh, params, part, region)
    if out is not None:
        maps.save(out)
    rep = summary(maps)
    if as_json:
        print(json.dumps(rep, indent=1))
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
    if out is not None:
        con.print(f"maps written to {out}")
