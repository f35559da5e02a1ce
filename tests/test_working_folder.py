"""No command imports code from the folder it is run in (issue 26, item 4).

Every command runs from a temporary folder full of modules named like the command's dependencies, standard
and third-party (``numpy.py``, ``queue.py``, ``proxsuite.py``, ``mujoco.py``, ``typer.py``, ...), each of which
writes a marker file when imported. The commands start as the installed ``omnirotor`` script starts them (a
launcher script in another folder: ``sys.path[0]`` is the script's folder, as for a console script), once
plainly and once with the working folder put on ``PYTHONPATH`` too (a user's shell may well have ``.`` there).
Covered: ``--help`` of every command and sub-command, ``info``, a short ``run`` and a two-run campaign on two
pool workers. A control shows that the traps do fire when the working folder is on ``sys.path``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import typer

from omnirotor.cli import _register, app, drop_working_folder

SRC = Path(__file__).resolve().parent.parent / "src"

TRAPS = (
    # third-party dependencies (pyproject.toml) and what they pull in
    "numpy", "scipy", "mujoco", "numba", "llvmlite", "daqp", "proxsuite", "typer", "click", "rich",
    "matplotlib", "imageio", "imageio_ffmpeg", "pyulog", "mcap", "zenoh", "rosbags", "foxglove", "ray", "PIL",
    # standard modules the package and its dependencies import after start-up
    "queue", "typing", "json", "tomllib", "pickle", "signal", "threading", "tempfile", "random", "hashlib",
    "logging", "dataclasses", "ctypes", "concurrent", "multiprocessing", "subprocess", "socket", "struct",
    "inspect", "importlib_metadata", "shutil", "contextlib", "textwrap", "fcntl", "platform", "uuid", "csv",
    "__future__",
)  # fmt: skip
"""Module names planted in the working folder."""

LAUNCHER = "import sys\nfrom omnirotor.cli import main\nsys.exit(main())\n"


def _plant(folder: Path, markers: Path) -> None:
    for name in TRAPS:
        (folder / f"{name}.py").write_text(
            f"open({str(markers / name)!r}, 'w').close()\nraise ImportError('planted {name} imported')\n"
        )


@pytest.fixture(scope="module")
def trap(tmp_path_factory):
    """``(folder, markers, launcher)``: the planted working folder, where markers land, the launcher script."""
    root = tmp_path_factory.mktemp("working-folder")
    folder, markers, bin_dir = root / "here", root / "markers", root / "bin"
    for d in (folder, markers, bin_dir):
        d.mkdir()
    _plant(folder, markers)
    launcher = bin_dir / "omnirotor"
    launcher.write_text(LAUNCHER)
    return folder, markers, launcher


def _omnirotor(trap, *args: str, cwd_on_path: bool = False, timeout: float = 3600) -> subprocess.CompletedProcess:
    folder, markers, launcher = trap
    path = [str(SRC)] + ([str(folder)] if cwd_on_path else [])
    env = {k: v for k, v in os.environ.items() if k != "PYTHONSAFEPATH"}
    env.update(PYTHONPATH=os.pathsep.join(path), MUJOCO_GL="egl")
    proc = subprocess.run(
        [sys.executable, str(launcher), *args], cwd=folder, env=env, capture_output=True, text=True, timeout=timeout
    )
    imported = sorted(p.name for p in markers.iterdir())
    assert imported == [], f"omnirotor {' '.join(args)} imported {imported} from its working folder"
    assert "planted" not in proc.stderr
    return proc


def _command_paths() -> list[tuple[str, ...]]:
    """Every command and sub-command of the CLI, as argument tuples."""
    _register()
    out: list[tuple[str, ...]] = [()]

    def walk(group, prefix: tuple[str, ...]) -> None:
        for name, cmd in sorted(getattr(group, "commands", {}).items()):
            out.append((*prefix, name))
            walk(cmd, (*prefix, name))

    walk(typer.main.get_command(app), ())
    return out


def test_every_command_module_is_listed():
    from omnirotor.cli import COMMAND_MODULES

    files = sorted(p.stem for p in (SRC / "omnirotor" / "cli").glob("cmd_*.py"))
    assert sorted(COMMAND_MODULES) == files


def test_the_traps_fire_when_the_working_folder_is_on_the_path(trap):
    folder, markers, _ = trap
    proc = subprocess.run(
        [sys.executable, "-c", "import queue"], cwd=folder, capture_output=True, text=True, env=dict(os.environ)
    )
    assert proc.returncode != 0 and "planted queue imported" in proc.stderr
    assert (markers / "queue").exists()
    (markers / "queue").unlink()


def test_drop_working_folder_removes_every_spelling_of_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sub").mkdir()
    path = ["", ".", str(tmp_path), str(tmp_path / "sub" / ".."), str(SRC), "/usr/lib/python3.11"]
    removed = drop_working_folder(path)
    assert path == [str(SRC), "/usr/lib/python3.11"]
    assert len(removed) == 4


@pytest.mark.parametrize("cwd_on_path", [False, True], ids=["plain", "cwd-on-PYTHONPATH"])
def test_every_commands_help_imports_nothing_from_the_working_folder(trap, cwd_on_path):
    for args in _command_paths():
        proc = _omnirotor(trap, *args, "--help", cwd_on_path=cwd_on_path)
        assert proc.returncode == 0, (args, proc.stderr[-500:])
        assert "Usage" in proc.stdout


@pytest.mark.parametrize("cwd_on_path", [False, True], ids=["plain", "cwd-on-PYTHONPATH"])
def test_info_run_and_a_campaign_import_nothing_from_the_working_folder(trap, cwd_on_path, tmp_path):
    proc = _omnirotor(trap, "info", "--json", cwd_on_path=cwd_on_path)
    assert proc.returncode == 0, proc.stderr[-500:]
    assert json.loads(proc.stdout)["n_rotors"] == 8
    proc = _omnirotor(trap, "run", "hover", "--quick", "--duration", "0.2", "--json", cwd_on_path=cwd_on_path)
    assert proc.returncode == 0, proc.stderr[-500:]
    assert json.loads(proc.stdout)["task"] == "hover"
    out = tmp_path / "campaign"
    args = ("campaign", "hover", "--runs", "2", "--workers", "2", "--quick", "--out", str(out), "--json")
    proc = _omnirotor(trap, *args, cwd_on_path=cwd_on_path)
    assert proc.returncode == 0, proc.stderr[-500:]
    records = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines() if x]
    assert sorted(r["index"] for r in records) == [0, 1] and all(r["status"] == "ok" for r in records)
