"""``omnirotor render``: a picture of a simulator scene with the vehicle at its start pose (SPEC §5.2)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from omnirotor.cli import app
from omnirotor.cli.texts import VEHICLE_HELP
from omnirotor.errors import InputError
from omnirotor.safe_io import atomic_path, check_output_file, note

if TYPE_CHECKING:
    import numpy as np


def write_png_atomic(path: str | Path, image: np.ndarray) -> Path:
    """Write an RGB image as PNG atomically (:func:`omnirotor.safe_io.atomic_path`).

    Args:
        path: destination file.
        image: (h, w, 3) uint8.

    Returns:
        The path written.
    """
    import imageio.v3 as iio

    with atomic_path(path, "--out") as tmp:
        iio.imwrite(tmp, image, extension=".png")
    return Path(path)


@app.command()
def render(
    scene: Annotated[str, typer.Argument(help="free, wall, tilted-wall, pipe or peg-in-hole.")],
    out: Annotated[Path | None, typer.Option("--out", help="PNG file (default SCENE.png).")] = None,
    vehicle: Annotated[str, typer.Option(help=VEHICLE_HELP)] = "omnirotor",
    width: Annotated[int, typer.Option(min=16, max=4096, help="Image width [px].")] = 960,
    height: Annotated[int, typer.Option(min=16, max=4096, help="Image height [px].")] = 720,
) -> None:
    """Render a simulator scene with the vehicle at its default start pose to a PNG."""
    from omnirotor.sim.scenes import SCENES

    if scene not in SCENES:
        raise InputError(f"unknown scene {scene!r}; scenes: {', '.join(SCENES)}")
    from omnirotor.sim.render import render_scene
    from omnirotor.vehicle import load_vehicle

    target = out if out is not None else Path(f"{scene}.png")
    if target.suffix.lower() != ".png":
        raise InputError(f"{target}: the output must be a .png file")
    replacing = check_output_file(target, "--out")
    from omnirotor.safe_io import route_mujoco_log

    route_mujoco_log(None)  # MuJoCo's log: nowhere (no MUJOCO_LOG.TXT in the working folder)
    image = render_scene(scene, load_vehicle(vehicle), width=width, height=height)
    print(write_png_atomic(target, image))
    if replacing:
        note(f"--out {target}: replaced the existing file")
