import json
import subprocess
import sys
from importlib.resources import files

import numpy as np
import pytest

from omnirotor.cli import main


def run(args, capsys):
    code = main(args)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_info_json_keys(capsys):
    code, out, _ = run(["info", "--json", "--directions", "100"], capsys)
    assert code == 0
    rep = json.loads(out)
    assert rep["rank"] == 6
    assert rep["condition_number"] == pytest.approx(6.68, abs=0.01)
    np.testing.assert_allclose(rep["hover_speeds_hz"], 143.76, atol=0.01)
    assert rep["min_zero_torque_force_N"] == pytest.approx(21.7, abs=0.1)
    assert rep["max_zero_torque_force_N"] == pytest.approx(37.3, abs=0.1)


def test_info_table_for_each_preset(capsys):
    for preset in ("omnirotor", "quadrotor", "hexarotor-tilted"):
        code, out, _ = run(["info", "--vehicle", preset, "--directions", "40"], capsys)
        assert code == 0 and "condition number" in out


def test_identify_writes_maps_and_reports(tmp_path, capsys, flight_data):
    out_file = tmp_path / "maps.json"
    code, out, _ = run(["identify", str(flight_data), "--out", str(out_file), "--json"], capsys)
    assert code == 0
    rep = json.loads(out)
    assert rep["regions"]["R3"]["points"] == 9
    assert rep["regions"]["R1"]["force_residual_rms_N"] < 0.4 < rep["regions"]["R1"]["nominal_force_residual_rms_N"]
    # the shared checker accepts the file
    check = subprocess.run(
        [
            sys.executable,
            str(flight_data.parents[1] / "checks" / "compare_maps.py"),
            str(out_file),
            str(flight_data),
        ],
        capture_output=True,
        text=True,
    )
    assert check.returncode == 0, check.stdout + check.stderr


def test_identify_single_file_with_region(tmp_path, capsys, flight_data):
    code, out, _ = run(["identify", str(flight_data / "wrenchMap_reg4.mat"), "--region", "R9", "--json"], capsys)
    assert code == 0
    assert list(json.loads(out)["regions"]) == ["R9"]


@pytest.mark.parametrize(
    "args,needle",
    [
        (["identify", "{tmp}/missing.mat"], "no such file"),
        (["identify", "{data}", "--delta", "0"], "--delta"),
        (["identify", "{data}", "--delta", "-3e-5"], "--delta"),
        (["identify", "{data}", "--delta", "nan"], "--delta"),
        (["identify", "{data}", "--delta", "abc"], "--delta"),
        (["identify", "{data}", "--region", "R42"], "unknown region"),
        (["identify", "{data}", "--vehicle", "nope"], "unknown vehicle preset"),
        (["identify", "{data}", "--vehicle", "quadrotor"], "rotors"),
        (["identify", "{data}", "--weights", "1,2"], "--weights"),
        (["identify", "{tmp}/corrupt.mat"], "MATLAB"),
        (["info", "--vehicle", "{tmp}/bad.toml"], "mass"),
        (["info", "--bogus"], "No such option"),
        (["frobnicate"], "No such command"),
    ],
)
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, flight_data, args, needle):
    (tmp_path / "corrupt.mat").write_bytes(b"MATLAB 5.0 junk" * 10)
    preset = (files("omnirotor") / "presets" / "vehicles" / "omnirotor.toml").read_text()
    (tmp_path / "bad.toml").write_text(preset.replace("mass = 1.625", "mass = -1.625"))
    out_file = tmp_path / "out" / "maps.json"
    argv = [a.format(tmp=tmp_path, data=flight_data) for a in args]
    if argv[0] == "identify":
        argv += ["--out", str(out_file)]
    code, out, err = run(argv, capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("omnirotor: error:") and needle in lines[0], err
    assert "Traceback" not in err + out
    assert not out_file.exists()


def test_console_script_exit_status(tmp_path):
    exe = [sys.executable, "-c", "from omnirotor.cli import main; main()"]
    r = subprocess.run(exe + ["identify", str(tmp_path / "none.csv")], capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "no such file" in r.stderr
