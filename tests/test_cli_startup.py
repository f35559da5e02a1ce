"""The CLI's help loads no heavy module (NumPy, SciPy, MuJoCo, numba, matplotlib, pydantic, the package's kernels).

Speed itself is a benchmark (``benchmarks/bench_startup.py``); this checks the cause: lazy imports.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parent.parent / "src"
HEAVY = (
    "numpy",
    "scipy",
    "mujoco",
    "numba",
    "matplotlib",
    "pydantic",  # typer's coercion of a group's --help flag left None (omnirotor.cli.CommandGroup)
    "omnirotor.vehicle",
    "omnirotor.sim",
    "omnirotor.control",
)

PROBE = """
import contextlib, io, json, sys
from omnirotor.cli import main
with contextlib.redirect_stdout(io.StringIO()) as out:
    code = main(sys.argv[1:])
print(json.dumps({"code": code, "text": out.getvalue(), "modules": sorted(sys.modules)}))
"""


@pytest.mark.parametrize(
    "args",
    [
        ["--help"],
        ["identify", "--help"],
        ["run", "--help"],
        ["campaign", "--help"],
        ["regions", "--help"],
        ["study", "points-per-region", "--help"],
    ],
)
def test_help_imports_no_heavy_module(args: list[str]) -> None:
    import json

    env = dict(os.environ, PYTHONPATH=str(SRC))
    proc = subprocess.run([sys.executable, "-c", PROBE, *args], env=env, capture_output=True, text=True, check=True)
    rep = json.loads(proc.stdout)
    assert rep["code"] == 0
    assert "Usage" in rep["text"]
    loaded = [m for m in rep["modules"] if any(m == h or m.startswith(h + ".") for h in HEAVY)]
    assert loaded == []


def test_package_attributes_still_resolve_lazily() -> None:
    import omnirotor
    import omnirotor.vehicle

    assert omnirotor.load_vehicle is omnirotor.vehicle.load_vehicle
    assert omnirotor.VehicleParams is omnirotor.vehicle.VehicleParams
    with pytest.raises(AttributeError):
        omnirotor.no_such_attribute  # noqa: B018
