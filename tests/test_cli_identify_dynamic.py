"""``omnirotor run identify-dynamic`` and ``identify --torque`` end to end on the shortened flight."""

import json

from omnirotor.cli import main


def test_run_identify_dynamic_then_identify_torque(tmp_path, capsys, flight_data):
    code = main(["run", "identify-dynamic", "--quick", "--out", str(tmp_path), "--json"])
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
