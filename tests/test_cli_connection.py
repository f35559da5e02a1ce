"""The connection options shared by ``fly``, ``sim --serve`` and ``px4-bridge`` (omnirotor.cli.connection_options)."""

from __future__ import annotations

import pytest

from omnirotor.cli import main
from omnirotor.cli.connection_options import transport_args


def test_endpoints_given_stand_else_the_commands_defaults_unless_a_configuration_file_gives_them(tmp_path):
    common = {"zenoh_config": None, "domain_id": 3, "namespace": "/r1"}
    a = transport_args(listen=None, connect=None, default_listen=["tcp/l:1"], default_connect=["tcp/c:2"], **common)
    assert a == {"domain_id": 3, "namespace": "/r1", "listen": ["tcp/l:1"], "connect": ["tcp/c:2"], "config_file": None}
    a = transport_args(listen=["tcp/x:5"], connect=["tcp/y:6"], default_listen=["tcp/l:1"], **common)
    assert a["listen"] == ["tcp/x:5"] and a["connect"] == ["tcp/y:6"]
    conf = tmp_path / "zenoh.json5"
    conf.write_text("{}")
    a = transport_args(listen=None, connect=None, zenoh_config=str(conf), domain_id=0, namespace="",
                       default_listen=["tcp/l:1"], default_connect=["tcp/c:2"])  # fmt: skip
    assert a["listen"] == [] and a["connect"] == [] and a["config_file"] == str(conf)  # the file's endpoints stand


@pytest.mark.parametrize("command", [["fly"], ["sim", "--serve"], ["px4-bridge"]])
def test_a_missing_zenoh_configuration_file_is_one_line_and_exit_2_in_every_command(command, tmp_path, capsys):
    assert main([*command, "--zenoh-config", str(tmp_path / "none.json5")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--zenoh-config" in err[0], err
