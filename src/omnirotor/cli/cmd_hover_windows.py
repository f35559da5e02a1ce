"""``omnirotor hover-windows``: the steady hover windows found in a PX4 flight log, as a figure and a CSV."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from omnirotor.cli import app
from omnirotor.errors import InputError


@app.command("hover-windows")
def hover_windows_cmd(
    log: Annotated[Path, typer.Argument(help="PX4 flight log (.ulg).")],
    out: Annotated[Path, typer.Option(help="Figure (PNG): speeds, attitude and motion over time, windows shaded.")],
    csv: Annotated[Path | None, typer.Option(help="Write the hover points here (the CSV of `identify`).")] = None,
    vehicle: Annotated[str | None, typer.Option(help="Vehicle (default: the log's own CA_* parameters).")] = None,
    vehicle_overlay: Annotated[
        Path | None, typer.Option(help="TOML of what PX4 does not store (mass, inertia, c_f, ...).")
    ] = None,
    min_duration: Annotated[float, typer.Option(help="Shortest window [s].")] = 1.0,
    accel_max: Annotated[float, typer.Option(help="Largest acceleration in a window [m/s²].")] = 0.3,
    rate_max: Annotated[float, typer.Option(help="Largest angular rate in a window [rad/s].")] = 0.1,
    drift_max: Annotated[float, typer.Option(help="Largest attitude drift within a window [deg].")] = 3.0,
) -> None:
    """Find steady hover windows in a PX4 log; plot them and write one hover point per window."""
    from omnirotor.identification import write_csv
    from omnirotor.px4.flight import check_flight_log, read_flight
    from omnirotor.px4.windows import ACTUATOR_MOTORS_NOTE, WindowCriteria, hover_points, plot_windows
    from omnirotor.vehicle import load_vehicle

    if out.suffix.lower() != ".png":
        raise InputError(f"--out {out}: expected a .png file name")
    for target in (out, csv):
        if target is not None and target.is_dir():
            raise InputError(f"{target}: is a folder")
    criteria = WindowCriteria(
        accel_max=accel_max, rate_max=rate_max, drift_max_deg=drift_max, min_duration_s=min_duration
    )
    if log.suffix.lower() != ".ulg":
        raise InputError(f"{log}: expected a PX4 flight log (.ulg)")
    check_flight_log(log)
    veh = load_vehicle(vehicle if vehicle is not None else str(log), vehicle_overlay)
    flight = read_flight(log, veh.n_rotors, veh.omega_max_hz)
    pts = hover_points(flight, criteria)
    if flight.speed_source == "actuator_motors":
        print(f"omnirotor: {log.name}: {ACTUATOR_MOTORS_NOTE.format(omega_max=veh.omega_max_hz)}", file=sys.stderr)
    for note in pts.notes:
        print(f"omnirotor: {log.name}: {note}", file=sys.stderr)
    plot_windows(flight, pts, out)
    if csv is not None:
        write_csv(csv, list(pts.R_WB), pts.omega_hz)
    for w in pts.windows:
        print(f"{w.t0_s:8.2f} {w.t1_s:8.2f}  ({w.t1_s - w.t0_s:.2f} s)")
    print(f"{len(pts.windows)} hover window(s); figure {out}" + (f", points {csv}" if csv is not None else ""))
