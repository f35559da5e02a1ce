"""``omnirotor run identify-dynamic`` and ``identify --torque`` end to end on the shortened flight."""

import json

import numpy as np

from omnirotor.cli import main


def test_run_identify_dynamic_then_identify_torque(tmp_path, capsys, flight_data):
    ulog = tmp_path / "flight.ulg"
    code = main(["run", "identify-dynamic", "--quick", "--out", str(tmp_path), "--ulog", str(ulog), "--json"])
    out = capsys.readouterr().out
    assert code == 0, out
    rep = json.loads(out[out.index("{") :])
    assert rep["success"] and rep["samples_per_region"]["R1"] == rep["samples"]
    maps_path = tmp_path / "maps.json"
    code = main(["identify", str(flight_data), "--torque", str(tmp_path / "flight.csv"), "--out", str(maps_path)])
    assert code == 0
    text = capsys.readouterr().out
    assert "torque rows of R1" in text
    maps = json.loads(maps_path.read_text())
    hover_only = tmp_path / "hover.json"
    assert main(["identify", str(flight_data), "--out", str(hover_only)]) == 0
    before = json.loads(hover_only.read_text())
    # force rows unchanged, torque rows of R1 replaced
    assert maps["regions"]["R1"]["A"][:3] == before["regions"]["R1"]["A"][:3]
    assert maps["regions"]["R1"]["A"][3:] != before["regions"]["R1"]["A"][3:]
    assert maps["regions"]["R3"]["A"] == before["regions"]["R3"]["A"]  # no flight there

    # the same flight as a PX4 ULog (100 Hz, noise-free gyro and rotor speeds) gives nearly the same torque rows
    from_ulog = tmp_path / "maps-ulog.json"
    code = main(["identify", str(flight_data), "--torque", str(ulog), "--out", str(from_ulog)])
    captured = capsys.readouterr()
    assert code == 0
    assert "resampled at 100 Hz" in captured.err and "torque rows of R1" in captured.out
    A2_csv = np.array(maps["regions"]["R1"]["A"])[3:]
    A2_ulog = np.array(json.loads(from_ulog.read_text())["regions"]["R1"]["A"])[3:]
    A2_hover = np.array(before["regions"]["R1"]["A"])[3:]
    moved = np.abs(A2_csv - A2_hover).mean()
    assert np.abs(A2_ulog - A2_csv).mean() < 0.2 * moved


def test_identify_torque_from_ulog_without_gyro_is_one_line(tmp_path, capsys, flight_data):
    from omnirotor.px4.ulog_writer import ULogWriter

    n = 8
    rows = np.zeros(50, dtype=[("timestamp", "<u8"), ("q", "<f4", 4)])
    rows["timestamp"] = np.arange(50) * 10_000
    rows["q"][:, 0] = 1.0
    esc = np.zeros(50, dtype=[("timestamp", "<u8"), ("esc_count", "u1"), ("esc", [("esc_rpm", "<i4")], n)])
    esc["timestamp"] = rows["timestamp"]
    esc["esc_count"] = n
    esc["esc"]["esc_rpm"] = 6000
    w = ULogWriter()
    w.add_topic("vehicle_attitude", rows)
    w.add_topic("esc_status", esc, {"esc": "esc_report"})
    log = tmp_path / "nogyro.ulg"
    w.write(log)
    out = tmp_path / "maps.json"
    code = main(["identify", str(flight_data), "--torque", str(log), "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2
    # one line: the maps' own warnings (few points in R3 of the real data) are said only when identify succeeds
    assert "no gyro" in err and len(err.splitlines()) == 1
    assert not out.exists()
