"""Bad input to ``omnirotor sim --serve`` and ``omnirotor fly``: one line on stderr, exit status 2, nothing left."""

from __future__ import annotations

import socket

import pytest

from omnirotor.cli import main


def _taken_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen()
    return s


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["sim"], "needs --serve"),
        (["sim", "--serve", "--scene", "moon"], "unknown scene"),
        (["sim", "--serve", "--task", "levitate"], "unknown task"),
        (["sim", "--serve", "--task", "hover", "--listen", "127.0.0.1:7447"], "not a Zenoh locator"),
        (["sim", "--serve", "--task", "hover", "--domain-id", "300"], "domain id"),
        (["sim", "--serve", "--task", "hover", "--namespace", "no space"], "namespace"),
        (["sim", "--serve", "--task", "hover", "--fifo-priority", "100"], "--fifo-priority"),
        (["fly", "--cpu", "4096"], "--cpu"),
        (["fly", "--fifo-priority", "-1"], "--fifo-priority"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(argv, says, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err
    assert list(tmp_path.iterdir()) == []


def test_a_port_in_use_is_one_line(capsys):
    with _taken_port() as s:
        port = s.getsockname()[1]
        code = main(["sim", "--serve", "--task", "hover", "--listen", f"tcp/127.0.0.1:{port}", "--wait", "1"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("omnirotor: error: cannot open the Zenoh session"), err
