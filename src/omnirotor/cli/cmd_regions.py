"""``omnirotor regions``: regions from the hover sign pattern, or how well a partition follows it (SPEC §3.3)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from omnirotor.cli import app
from omnirotor.cli.texts import VEHICLE_HELP
from omnirotor.errors import InputError
from omnirotor.safe_io import atomic_path, check_output_file, dumps_json, note


@app.command("regions")
def regions_cmd(
    from_signs: Annotated[
        bool, typer.Option("--from-signs", help="Derive regions from which rotors spin backwards in hover.")
    ] = False,
    vehicle: Annotated[str, typer.Option(help=VEHICLE_HELP)] = "omnirotor",
    bands: Annotated[int, typer.Option(help="Number of elevation bands.")] = 4,
    min_area_frac: Annotated[
        float, typer.Option(help="Merge regions smaller than this fraction of the sphere.")
    ] = 0.02,
    step: Annotated[float, typer.Option(help="Grid step in azimuth and elevation [deg].")] = 5.0,
    out: Annotated[Path | None, typer.Option(help="Write the regions TOML here (with --from-signs).")] = None,
    figure: Annotated[Path | None, typer.Option(help="Write the figure (PNG) here (with --from-signs).")] = None,
    partition: Annotated[str, typer.Option(help="Without --from-signs: the partition to measure.")] = "paper",
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Regions from rotor sign patterns (--from-signs), or how well a partition follows them."""
    if not from_signs:
        if out is not None or figure is not None:
            raise InputError("--out and --figure need --from-signs")
    elif out is None:
        raise InputError("--from-signs needs --out FILE.toml")
    if figure is not None and figure.suffix.lower() != ".png":
        raise InputError(f"--figure {figure}: expected a .png file name")
    replacing = {
        flag: p is not None and check_output_file(p, flag) for flag, p in (("--out", out), ("--figure", figure))
    }

    from omnirotor.regions import load_partition
    from omnirotor.regions_from_signs import mismatch_fraction, partition_from_signs
    from omnirotor.vehicle import load_vehicle

    veh = load_vehicle(vehicle)
    if not from_signs:
        part = load_partition(partition)
        miss, areas, n_pat = mismatch_fraction(veh, part)
        rep = {"partition": part.name, "regions": len(areas), "local_patterns": n_pat, "mismatch_frac": miss}
        print(dumps_json(rep) if as_json else _line(rep))
        return

    from omnirotor.regions_from_signs import plot_sign_partition, write_partition_toml

    result = partition_from_signs(veh, bands=bands, min_area_frac=min_area_frac, step_deg=step, name=out.stem)
    write_partition_toml(out, result, veh, label="--out")
    if figure is not None:
        with atomic_path(figure, "--figure") as tmp:
            plot_sign_partition(result, veh, tmp)
    for flag, p in (("--out", out), ("--figure", figure)):
        if replacing[flag]:
            note(f"{flag} {p}: replaced the existing file")
    rep = {
        "partition": result.partition.name,
        "regions": len(result.partition.regions),
        "local_patterns": result.n_patterns,
        "mismatch_frac": result.mismatch_frac,
        "band_edges_deg": list(result.band_edges_deg),
        "out": str(out),
    }
    print(dumps_json(rep) if as_json else _line(rep))


def _line(rep: dict) -> str:
    return (
        f"{rep['partition']}: {rep['regions']} regions; {rep['local_patterns']} local sign patterns; "
        f"area where the local pattern is not the region's: {100 * rep['mismatch_frac']:.1f} %"
        + (f"; written to {rep['out']}" if "out" in rep else "")
    )
