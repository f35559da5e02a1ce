"""``omnirotor hover-windows``: the steady hover windows found in a PX4 flight log, as a figure and a CSV."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from omnirotor.cli import app
from omnirotor.cli import window_options as wo
from omnirotor.cli.texts import VEHICLE_HELP
from omnirotor.errors import InputError

D = wo.DEFAULT


@app.command("hover-windows")
def hover_windows_cmd(
    log: Annotated[Path, typer.Argument(help="PX4 flight log (.ulg) or ROS 2 bag folder (sqlite3 or MCAP).")],
    out: Annotated[Path, typer.Option(help="Figure (PNG): speeds, attitude and motion over time, windows shaded.")],
    csv: Annotated[Path | None, typer.Option(help="Write the hover points here (the CSV of `identify`).")] = None,
    vehicle: Annotated[
        str | None,
        typer.Option(help=VEHICLE_HELP + " Default: a ULog's own CA_* parameters; omnirotor for a bag."),
    ] = None,
    vehicle_overlay: Annotated[
        Path | None, typer.Option(help="TOML of what PX4 does not store (mass, inertia, c_f, ...).")
    ] = None,
    min_duration: wo.MinDuration = D.min_duration_s,
    accel_max: wo.AccelMax = D.accel_max,
    rate_max: wo.RateMax = D.rate_max,
    speed_max: wo.SpeedMax = D.speed_max,
    drift_max: wo.DriftMax = D.drift_max_deg,
    spread_max: wo.SpreadMax = D.spread_frac,
    spread_min: wo.SpreadMin = D.spread_min_hz2,
    spin_fraction: wo.SpinFraction = D.spin_fraction,
    trim: wo.Trim = D.trim_s,
    cutoff: wo.Cutoff = D.cutoff_hz,
    motion_cutoff: wo.MotionCutoff = D.motion_cutoff_hz,
) -> None:
    """Find steady hover windows in a PX4 log; plot them and write one hover point per window.

    Exits with status 2, as `identify` does, when no window is found; the figure is written all the same (it
    shows why), and stderr says how much of the flight each criterion rejected.
    """
    from omnirotor.identification import write_csv
    from omnirotor.px4.flight import check_flight_log
    from omnirotor.px4.rosbag_io import is_rosbag
    from omnirotor.px4.windows import hover_points, plot_windows, read_flight_log, say_windows
    from omnirotor.safe_io import check_output_file
    from omnirotor.vehicle import load_vehicle

    if out.suffix.lower() != ".png":
        raise InputError(f"--out {out}: expected a .png file name")
    check_output_file(out, "--out")
    if csv is not None:
        check_output_file(csv, "--csv")
    criteria = wo.criteria(
        min_duration, accel_max, rate_max, speed_max, drift_max, spread_max, spread_min, spin_fraction, trim,
        cutoff, motion_cutoff,
    )  # fmt: skip
    bag = is_rosbag(log)
    if log.suffix.lower() != ".ulg" and not bag:
        raise InputError(f"{log}: expected a PX4 flight log (.ulg) or a ROS 2 bag folder (with metadata.yaml)")
    if not bag:
        check_flight_log(log)
    veh = load_vehicle(vehicle if vehicle is not None else ("omnirotor" if bag else str(log)), vehicle_overlay)
    flight = read_flight_log(log, veh.n_rotors, veh.omega_max_hz)
    pts = hover_points(flight, criteria)
    plot_windows(flight, pts, out, criteria)
    say_windows(flight, pts, veh)
    if not pts.windows:
        raise InputError(f"{log}: no steady hover window found (the figure {out} shows the flight)")
    if csv is not None:
        write_csv(csv, list(pts.R_WB), pts.omega_hz)
    for w in pts.windows:
        print(f"{w.t0_s:8.2f} {w.t1_s:8.2f}  ({w.t1_s - w.t0_s:.2f} s)")
    print(f"{len(pts.windows)} hover window(s); figure {out}" + (f", points {csv}" if csv is not None else ""))
