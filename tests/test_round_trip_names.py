"""Everything the tool writes it reads back, whatever the file's name (issue 26 item 3).

A regions TOML takes its partition's name from the file name (``regions --from-signs --out 'we"ird.toml'``
wrote ``name = "we"ird"``, which no TOML reader accepts); names with quotes, backslashes, spaces, control-free
non-ASCII and characters beyond the basic plane are written as TOML strings and read back equal. A wrench-map
JSON under such names is read back too.
"""

import tomllib

import pytest

from omnirotor.cli import main
from omnirotor.config import toml_string
from omnirotor.regions import load_partition

NAMES = ['we"ird', "back\\slash", "a b c", "ünïcödé ✈", "𝔸 beyond the plane", "tab\tin", "del\x7fchar"]


@pytest.mark.parametrize("text", [*NAMES, "new\nline", "", "\x00\x1f"])
def test_toml_string_round_trips(text):
    assert tomllib.loads(f"name = {toml_string(text)}\n")["name"] == text


@pytest.mark.parametrize("stem", NAMES[:5])
def test_regions_toml_under_an_odd_name_reads_back(tmp_path, capsys, stem):
    out = tmp_path / f"{stem}.toml"
    assert main(["regions", "--from-signs", "--out", str(out)]) == 0, capsys.readouterr().err
    part = load_partition(str(out))
    assert part.name == stem and len(part.names) >= 2


def test_wrench_maps_under_an_odd_name_read_back(tmp_path, capsys, flight_data):
    from omnirotor.wrench_maps import load_wrench_maps

    out = tmp_path / 'we"ird ✈ maps.json'
    assert main(["identify", str(flight_data), "--out", str(out)]) == 0, capsys.readouterr().err
    maps = load_wrench_maps(out)
    assert maps.global_ is not None and len(maps.regions) >= 1
