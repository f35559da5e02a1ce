"""Output of the command line (issue 25 item 5): --version, complete --help texts."""

import pytest

from omnirotor.cli import main


def test_version_prints_the_installed_version(capsys):
    from importlib.metadata import version

    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"omnirotor {version('omnirotor')}"


@pytest.mark.parametrize("columns", ["60", "80", "100"])
def test_run_help_names_every_task_whole(columns, capsys, monkeypatch):
    from omnirotor.experiments.tasks import TASKS

    monkeypatch.setenv("COLUMNS", columns)  # the help's width: a name must not be broken at a line's end
    assert main(["run", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())  # "identify-dynamic- cells" if wrapped at its hyphen
    missing = [t for t in TASKS if t not in text]
    assert not missing, missing


@pytest.mark.parametrize(
    "command", ["info", "identify", "hover-windows", "run", "render", "regions", "calibrate-truth", "study"]
)
def test_vehicle_help_names_every_format(command, capsys):
    args = [command, "points-per-region", "--help"] if command == "study" else [command, "--help"]
    assert main(args) == 0
    text = " ".join(capsys.readouterr().out.split())
    for fmt in ("preset", "TOML", "PX4 airframe", ".params", "ULog"):
        assert fmt in text, (command, fmt)


def test_calibrate_disturbances_help_is_complete_and_true(capsys):
    assert main(["calibrate-disturbances", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    # the files it writes (cli/cmd_calibrate.py writes REPORT/disturbances.md and .json), not others
    assert "disturbances.md" in text and "disturbances.json" in text
    assert "result.json" not in text and "report.md" not in text
    # the grid's rules (experiments/disturbance_calibration.calibrate_disturbances refuses the others)
    assert "at least 4 points" in text and ">= 0" in text and "above 0 in some point" in text
