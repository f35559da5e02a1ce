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
        (["fly", "--transport-priority", "50"], "--transport-priority must be in 0..49 (below the loop's"),
        (["fly", "--fifo-priority", "0", "--transport-priority", "10"], "needs the loop in SCHED_FIFO above it"),
        (
            ["sim", "--serve", "--task", "hover", "--fifo-priority", "20", "--transport-priority", "30"],
            "--transport-priority must be in 0..19",
        ),
        (["sim", "--serve", "--transport-priority", "5"], "needs the loop in SCHED_FIFO above it"),
        (["px4-bridge", "--fifo-priority", "20", "--transport-priority", "-1"], "--transport-priority must be in"),
        (["fly", "--foxglove-port", "70000"], "--foxglove-port"),
        (["fly", "--ctl-rate", "0"], "--ctl-rate must be in (0, 1000]"),
        (["fly", "--ctl-rate", "1001"], "--ctl-rate must be in (0, 1000]"),
        (["fly", "--ctl-rate", "nan"], "--ctl-rate"),
        (["fly", "--maps", "missing.json"], "--maps"),
        (["fly", "--mission-from-sim", "--maps", "missing.json"], "--maps is for interactive flights"),
        (["fly", "--record", "no/such/folder/bag"], "--record"),
        (["sim", "--serve", "--foxglove-port", "-1"], "--foxglove-port"),
        (["sim", "--serve", "--task", "hover", "--record", "no/such/folder/bag"], "--record"),
        (["fly", "--session-id", "xyz"], "--session-id must be 1 to 16 hex digits"),
        (["fly", "--mission-from-sim", "--session-id", "0"], "--session-id must not be 0"),
        (["sim", "--serve", "--task", "hover", "--pair-session", "1ffffffffffffffff"], "--pair-session must be"),
        (["sim", "--serve", "--pair-session", "0x0"], "--pair-session must not be 0"),
        (["px4-bridge", "--pair-session", "12 34"], "--pair-session must be"),
        (["fly", "--plant-session", "xyz"], "--plant-session must be 1 to 16 hex digits"),
        (["fly", "--mission-from-sim", "--plant-session", "0"], "--plant-session must not be 0"),
        (["sim", "--serve", "--task", "hover", "--session-id", "g1"], "--session-id must be"),
        (["sim", "--serve", "--session-id", "00"], "--session-id must not be 0"),
        (["px4-bridge", "--session-id", "1ffffffffffffffff"], "--session-id must be"),
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


@pytest.mark.parametrize("argv", [["fly"], ["sim", "--serve", "--task", "hover"]])
def test_a_recording_that_exists_is_refused_before_anything_runs(argv, capsys, tmp_path):
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "keep.txt").write_text("mine")
    assert main([*argv, "--record", str(tmp_path / "bag")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists already" in err[0], err
    assert [p.name for p in (tmp_path / "bag").iterdir()] == ["keep.txt"]
