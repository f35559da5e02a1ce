"""``omnirotor info``: rank, conditioning, hover speeds and force envelope of a vehicle (SPEC §1.2-1.3)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from omnirotor.cli import app
from omnirotor.cli.texts import VEHICLE_HELP
from omnirotor.safe_io import dumps_json


def vehicle_report(spec: str, n_directions: int = 400, overlay: Path | None = None) -> dict:
    """Properties of a vehicle's nominal wrench map, as plain data (the JSON of ``omnirotor info``)."""
    import numpy as np

    from omnirotor.vehicle import force_envelope, load_vehicle

    v = load_vehicle(spec, overlay)
    A = v.A_nom
    sv = np.linalg.svd(A, compute_uv=False)
    rank = int(np.sum(sv > 1e-9 * sv[0]))
    u = v.hover_input()
    env = force_envelope(v, n_directions=n_directions)
    return {
        "vehicle": v.name,
        "n_rotors": v.n_rotors,
        "mass_kg": v.mass,
        "weight_N": v.weight,
        "rank": rank,
        "condition_number": float(sv[0] / sv[rank - 1]),
        "singular_values": sv.tolist(),
        "hover_inputs_hz2": u.tolist(),
        "hover_speeds_hz": (np.sign(u) * np.sqrt(np.abs(u))).tolist(),
        "hover_feasible": bool(np.all((u >= v.u_min) & (u <= v.u_max))),
        "omega_limits_hz": [v.omega_min_hz, v.omega_max_hz],
        "min_zero_torque_force_N": env.min_N,
        "max_zero_torque_force_N": env.max_N,
        "thrust_to_weight_min": env.min_N / v.weight,
        "A_nom": A.tolist(),
    }


@app.command()
def info(
    vehicle: Annotated[str, typer.Option(help=VEHICLE_HELP)] = "omnirotor",
    vehicle_overlay: Annotated[
        Path | None, typer.Option(help="TOML of what PX4 does not store (mass, inertia, c_f, ...).")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    directions: Annotated[int, typer.Option(min=20, max=20000, help="Directions sampled for the envelope.")] = 400,
) -> None:
    """Show the wrench map of a vehicle: rank, condition number, hover speeds, force envelope."""
    from rich.console import Console
    from rich.table import Table

    rep = vehicle_report(vehicle, directions, vehicle_overlay)
    if as_json:
        print(dumps_json(rep))  # a non-finite number is written as null
        return
    con = Console()
    t = Table(title=f"vehicle {rep['vehicle']} ({rep['n_rotors']} rotors, {rep['mass_kg']} kg)", show_header=False)
    t.add_row("rank of A", str(rep["rank"]))
    t.add_row("condition number", f"{rep['condition_number']:.2f}")
    t.add_row("hover speeds [Hz]", " ".join(f"{w:+.1f}" for w in rep["hover_speeds_hz"]))
    t.add_row("rotor limits [Hz]", f"{rep['omega_limits_hz'][0]:+.0f} .. {rep['omega_limits_hz'][1]:+.0f}")
    t.add_row("zero-torque force, min over directions [N]", f"{rep['min_zero_torque_force_N']:.2f}")
    t.add_row("zero-torque force, max over directions [N]", f"{rep['max_zero_torque_force_N']:.2f}")
    t.add_row("weight [N]", f"{rep['weight_N']:.2f}  (min force / weight = {rep['thrust_to_weight_min']:.2f})")
    con.print(t)
