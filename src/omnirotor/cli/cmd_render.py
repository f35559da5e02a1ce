"""``omnirotor render``: a picture of a simulator scene with the vehicle at its start pose (SPEC §5.2)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from omnirotor.cli import app
from omnirotor.errors import InputError

if TYPE_CHECKING:
    import numpy as np


def write_png_atomic(path: str | Path, image: np.ndarray) -> Path:
    """Write an RGB image as PNG through a temporary file and a rename (nothing half-written).

    Args:
        path: destination file.
        image: (h, w, 3) uint8.

    Returns:
        The path written.
    """
    import imageio.v3 as iio

    p = Path(path)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=p.parent, prefix=f".{p.name}.", suffix=".png")
    except OSError as exc:
        raise InputError(f"{p}: cannot write ({exc.strerror})") from None
    os.close(fd)
    try:
        iio.imwrite(tmp, image, extension=".png")
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the file the usual permissions
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return p


@app.command()
def render(
    scene: Annotated[str, typer.Argument(help="free, wall, tilted-wall, pipe or peg-in-hole.")],
    out: Annotated[Path | None, typer.Option("--out", help="PNG file (default SCENE.png).")] = None,
    vehicle: Annotated[str, typer.Option(help="Preset name or vehicle TOML file.")] = "omnirotor",
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
    image = render_scene(scene, load_vehicle(vehicle), width=width, height=height)
    print(write_png_atomic(target, image))
