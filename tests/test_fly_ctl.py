"""``omnirotor ctl`` against a flight director served over real Zenoh on loopback (no mock transport)."""

import shutil
import socket
from pathlib import Path

import numpy as np
import pytest

from omnirotor.cli import main
from omnirotor.control.controller import ControllerParams, InteractionController
from omnirotor.fly.director import FlightDirector
from omnirotor.fly.failsafe import LinkAges
from omnirotor.fly.modes import FlightMode
from omnirotor.fly.presets import FlyParams
from omnirotor.fly.requests import CTL_TOPIC
from omnirotor.messages import SensorFrame
from omnirotor.vehicle import load_vehicle

pytest.importorskip("zenoh")


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def served():
    """A director with a frame of a vehicle at rest (motion capture fresh), answering on CTL_TOPIC."""
    from omnirotor.transport import open_transport

    vehicle = load_vehicle("omnirotor")
    ctl = InteractionController(vehicle, ControllerParams(log_capacity=0))
    d = FlightDirector(ctl, FlyParams())
    u = vehicle.hover_input()
    frame = SensorFrame(0.0, np.array([0, 0, 9.81]), np.zeros(3), np.sign(u) * np.sqrt(np.abs(u)), True, 0.0,
                        np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0, 0.0]))  # fmt: skip
    d.on_frame(frame, LinkAges())
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    t = open_transport(listen=[endpoint], namespace="/ctltest")
    t.serve(CTL_TOPIC, "omnirotor_msgs/msg/FlightRequest", "omnirotor_msgs/msg/FlightReply",
            lambda req: d.request(req).to_msg())  # fmt: skip
    yield d, ["ctl", "--connect", endpoint, "--namespace", "/ctltest"]
    t.close()


def test_ctl_prints_the_transition_and_exits_by_the_verdict(served, capsys):
    d, base = served
    assert main([*base, "takeoff"]) == 1
    out = capsys.readouterr().out
    assert out == "refused: takeoff: disarmed (arm first)\n"
    assert main([*base, "arm"]) == 0
    assert capsys.readouterr().out.startswith("accepted: arm: disarmed -> armed (ground at (0.000, 0.000, 1.000))")
    assert d.mode == FlightMode.ARMED
    assert main([*base, "push", "0.05"]) == 1
    assert "push: not flying (mode armed): take off first" in capsys.readouterr().out
    assert main([*base, "preset", "PiH"]) == 0
    assert capsys.readouterr().out == "accepted: preset: admittance preset PiH\n"
    assert main([*base, "status"]) == 0
    assert capsys.readouterr().out.startswith("accepted: status: mode armed, preset PiH, map nominal")
    assert main([*base, "takeoff", "--height", "0.3"]) == 0
    assert capsys.readouterr().out.startswith("accepted: takeoff: armed -> takeoff (0.30 m in")
    assert main([*base, "disarm"]) == 1
    assert "land first, or disarm --force" in capsys.readouterr().out
    assert main([*base, "disarm", "--force"]) == 0
    assert "rotors stopped in flight (forced)" in capsys.readouterr().out
    assert d.mode == FlightMode.DISARMED


def test_ctl_bad_input_and_no_node_exit_2_with_one_line(served, capsys):
    _, base = served
    assert main([*base, "goto", "1", "2", "nan"]) == 2
    assert capsys.readouterr().err == "omnirotor: error: Z must be a finite number, got nan\n"
    assert main([*base, "goto", "0.5", "-0.3", "1.2", "--yaw", "-90"]) == 1  # negative numbers are not options
    assert capsys.readouterr().out == "refused: goto: not flying (mode disarmed): take off first\n"
    assert main([*base, "goto", "1", "2", "3", "--bogus"]) == 2
    assert "unexpected extra argument" in capsys.readouterr().err
    free = f"tcp/127.0.0.1:{_free_port()}"
    assert main(["ctl", "--connect", free, "--timeout", "0.3", "arm"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no answer from a flight node on /omnirotor/ctl" in err


def test_connection_options_may_follow_the_request(served, capsys):
    """``ctl status --connect X`` as a user types it: the group's options after the request's name."""
    _, base = served
    connect, namespace = base[2], base[4]
    assert main(["ctl", "status", "--connect", connect, "--namespace", namespace, "--timeout", "2"]) == 0
    assert capsys.readouterr().out.startswith("accepted: status: mode")
    assert main(["ctl", "goto", "0.5", "-0.3", "1.2", f"--connect={connect}", "--yaw", "-90",
                 f"--namespace={namespace}"]) == 1  # fmt: skip
    assert capsys.readouterr().out.startswith("refused: goto: not flying")
    assert main(["ctl", "--connect", connect, "status", "--namespace", namespace]) == 0  # either side
    assert capsys.readouterr().out.startswith("accepted: status: mode")


def test_ctl_logs_in_to_a_node_that_requires_it(served, capsys, tmp_path, monkeypatch):
    """A node with ``examples/zenoh-auth/node.json5`` answers ``ctl --zenoh-config ctl.json5`` only (Zenoh refuses
    the connection of a ctl without the login, or with a wrong password)."""
    from omnirotor.transport import open_transport

    d, _ = served
    cfg = tmp_path / "zenoh"
    shutil.copytree(Path(__file__).resolve().parents[1] / "examples" / "zenoh-auth", cfg)
    monkeypatch.chdir(cfg)  # the dictionary file's relative path
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    (cfg / "wrong.json5").write_text(
        (cfg / "ctl.json5").read_text().replace("change-me-ctl-password", "not-the-password")
    )
    with open_transport(listen=[endpoint], namespace="/ctlauth", config_file=str(cfg / "node.json5"),
                        config={"connect/endpoints": []}) as t:  # fmt: skip
        t.serve(CTL_TOPIC, "omnirotor_msgs/msg/FlightRequest", "omnirotor_msgs/msg/FlightReply",
                lambda req: d.request(req).to_msg())  # fmt: skip
        base = ["ctl", "--connect", endpoint, "--namespace", "/ctlauth", "--timeout", "1"]
        assert main([*base, "status", "--zenoh-config", str(cfg / "ctl.json5")]) == 0
        assert capsys.readouterr().out.startswith("accepted: status: mode")
        for refused in ([], ["--zenoh-config", str(cfg / "wrong.json5")]):
            assert main([*base, *refused, "status"]) == 2
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and "no answer from a flight node" in err
        assert main([*base, "--zenoh-config", "missing.json5", "status"]) == 2
        assert "--zenoh-config" in capsys.readouterr().err
