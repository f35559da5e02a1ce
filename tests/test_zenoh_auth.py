"""Zenoh's authentication and access control, with the shipped example configs (issue 26 item 5).

Two recipes, each tested as shipped: ``examples/zenoh-auth/`` (user/password login) and ``examples/zenoh-tls/``
(mutual TLS, its certificates made by its own ``make-certs.sh`` with the openssl command). Three kinds of process on
loopback, as on a robot's shared network: the simulator with ``plant.json5`` (only peers that log in, or show a
certificate of the CA, connect; only the peer named ``node`` may publish), the flight node with ``node.json5``,
and intruders in this test's process that start flooding foreign rotor commands *before* the node: one without
credentials, one logged in as the read-only ``viewer`` and (TLS) a colleague with a valid certificate of another
name, whom the access control allows nothing (it connects, and hears nothing).
The plant runs first come (no ``--pair-session``), so any intruder's command that reached its gate would take the
pairing. What Zenoh does, asserted through the plant's counters and what each intruder hears: a connection without
credentials is refused (it hears nothing), a logged-in intruder connects (it hears the plant's status) but every
put of its own is denied before the plant's subscriber (no command refused, no foreign session seen), and the node
flies.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from omnirotor.rosmsg.convert import SIM_STATUS
from omnirotor.transport import open_transport
from sitl.flood import Flood, status_until
from sitl.procs import CLI, ROOT, Pair, env, free_port

EXAMPLES = ROOT / "examples"
RECIPES = ("zenoh-auth", "zenoh-tls")


def _configs(tmp: Path, recipe: str) -> Path:
    """The shipped example files, verbatim, in a folder of their own (the processes' working folder); TLS: with
    certificates made by the recipe's own script, and a config that trusts the CA but shows no certificate."""
    where = tmp / recipe
    shutil.copytree(EXAMPLES / recipe, where)
    if recipe == "zenoh-tls":
        if shutil.which("openssl") is None or shutil.which("sh") is None:
            pytest.skip("the TLS recipe's certificates need the openssl command and sh")
        subprocess.run(["sh", "make-certs.sh", "127.0.0.1", "node", "viewer", "colleague"], cwd=where, check=True,
                       capture_output=True)  # fmt: skip
        (where / "anonymous.json5").write_text('{transport: {link: {tls: {root_ca_certificate: "ca.pem"}}}}')
        (where / "colleague.json5").write_text((where / "viewer.json5").read_text().replace("viewer.", "colleague."))
    return where


def test_the_examples_are_what_the_test_flies():
    assert {"plant.json5", "plant-users.txt", "node.json5", "node-users.txt", "ctl.json5", "viewer.json5"} <= {
        p.name for p in (EXAMPLES / "zenoh-auth").iterdir()
    }
    assert {"plant.json5", "node.json5", "viewer.json5", "make-certs.sh"} <= {
        p.name for p in (EXAMPLES / "zenoh-tls").iterdir()
    }
    assert not list((EXAMPLES / "zenoh-tls").glob("*.key"))  # no private key is shipped: each user makes theirs


@pytest.mark.slow
@pytest.mark.parametrize("recipe", RECIPES)
def test_only_the_authenticated_node_commands_the_rotors(recipe, tmp_path, monkeypatch):
    cfg = _configs(tmp_path, recipe)
    monkeypatch.chdir(cfg)  # the configs' relative paths, for the intruders' sessions in this process
    tls = recipe == "zenoh-tls"
    sim_args = ["--seed", "4", "--duration", "2", "--zenoh-config", str(cfg / "plant.json5")]
    with Pair(tmp_path, "hover", sim_args, lockstep=True, node_args=("--zenoh-config", str(cfg / "node.json5")),
              start_node=False, cwd=cfg, link="tls" if tls else "tcp") as pair:  # fmt: skip
        ns, plant = pair.namespace, [pair.endpoint]
        logged_in = ["viewer.json5"] + (["colleague.json5"] if tls else [])
        with contextlib.ExitStack() as stack:

            def session(config: str | None):
                return stack.enter_context(open_transport(listen=[], connect=plant, namespace=ns, config_file=config))

            anonymous = session(str(cfg / "anonymous.json5") if tls else None)
            others = [session(str(cfg / name)) for name in logged_in]
            heard_by = [t.subscriber("/omnirotor/sim_status", SIM_STATUS, depth=8) for t in (anonymous, *others)]
            # the viewer is connected: it hears the plant (the colleague, connected too, is allowed nothing at all)
            assert status_until(heard_by[1], lambda m: True, 300), pair.text("sim")[-2000:]
            floods = [stack.enter_context(Flood(t)) for t in (anonymous, *others)]
            time.sleep(2.0)  # a flood of each before the node: nothing of it reaches the plant's gate
            early = status_until(heard_by[1], lambda m: True, 30)
            assert early.paired_session_id == 0 and early.commands_refused == 0 and early.steps == 0
            pair.start_node()
            sitl, node = pair.wait(timeout_s=900)
            sent = sum(f.sent for f in floods)
            assert heard_by[0].take_latest() is None  # the connection without credentials was refused
            assert all(sub.take_latest() is None for sub in heard_by[2:])  # default deny: the colleague hears nothing
    s = sitl["sitl"]
    assert sent > 1000
    assert s["foreign_sessions"] == 0 and s["commands_refused"] == 0  # no intruder's put ever reached the gate
    assert s["commands_obeyed"] >= s["steps"] > 0 and not s["failsafe"]
    assert f"paired with controller session {node['session_id']}" in pair.text("sim")
    assert sitl["success"] and max(sitl["ee_max_error"][a] for a in ("x_cm", "y_cm", "z_cm")) < 5.0


@pytest.mark.slow
@pytest.mark.parametrize("recipe", RECIPES)
def test_the_px4_bridge_as_the_plant_obeys_only_the_authenticated_node(recipe, tmp_path, monkeypatch):
    """``omnirotor px4-bridge`` with the recipe's ``plant.json5`` on the node's side (PX4's side in its own plain
    session, ``--px4-connect``: PX4's Zenoh peer is not asked for the login): the node logs in and gets the
    bridge's frames of the stand-in PX4's IMU, its commands reach PX4 through the bridge; the intruders' floods from
    before the node never reach the bridge's gate (first come: one would take the pairing)."""
    cfg = _configs(tmp_path, recipe)
    monkeypatch.chdir(cfg)
    tls = recipe == "zenoh-tls"
    ns, px4_ns = "/b", "/px4"
    plant = [f"{'tls' if tls else 'tcp'}/127.0.0.1:{free_port()}"]
    px4_ep = f"tcp/127.0.0.1:{free_port()}"
    procs: list[subprocess.Popen] = []

    def spawn(args: list[str], name: str) -> subprocess.Popen:
        p = subprocess.Popen(args, env=env(), cwd=cfg, stdout=subprocess.PIPE, text=True,
                             stderr=open(tmp_path / f"{name}.err", "w"))  # noqa: SIM115  # fmt: skip
        procs.append(p)
        return p

    def text(name: str) -> str:
        return (tmp_path / f"{name}.err").read_text()[-3000:]

    px4 = spawn([sys.executable, str(ROOT / "tests" / "sitl" / "fake_px4.py"), px4_ep, px4_ns, str(tmp_path),
                 "--imu-hz", "1000", "--esc"], "px4")  # fmt: skip
    bridge = spawn([sys.executable, "-c", CLI, "px4-bridge", "--zenoh-config", str(cfg / "plant.json5"),
                    "--listen", plant[0], "--namespace", ns, "--px4-namespace", px4_ns, "--px4-connect", px4_ep,
                    "--json"], "bridge")  # fmt: skip
    node_cmd = [sys.executable, "-c", CLI, "fly", "--zenoh-config", str(cfg / "node.json5"), "--connect", plant[0],
                "--listen", f"tcp/127.0.0.1:{free_port()}", "--namespace", ns, "--fifo-priority", "0",
                "--json"]  # fmt: skip
    try:
        with contextlib.ExitStack() as stack:

            def session(config: str | None):
                return stack.enter_context(open_transport(listen=[], connect=plant, namespace=ns, config_file=config))

            anonymous = session(str(cfg / "anonymous.json5") if tls else None)
            others = [session(str(cfg / name)) for name in ["viewer.json5"] + (["colleague.json5"] if tls else [])]
            heard_by = [t.subscriber("/omnirotor/sim_status", SIM_STATUS, depth=8) for t in (anonymous, *others)]
            # the viewer hears the bridge's status once it bridges (after measuring PX4's IMU rate)
            assert status_until(heard_by[1], lambda m: True, 300), text("bridge")
            floods = [stack.enter_context(Flood(t)) for t in (anonymous, *others)]
            time.sleep(2.0)  # a flood of each before the node: nothing of it reaches the bridge's gate
            early = status_until(heard_by[1], lambda m: True, 30)
            assert early.paired_session_id == 0 and early.commands_refused == 0
            node = spawn(node_cmd, "node")
            # the node's commands (answering the bridge's frames, disarmed: zeros) obeyed: it paired
            paired = status_until(heard_by[1], lambda m: m.paired_session_id != 0 and m.commands_obeyed > 500, 300)
            assert paired, text("node") + text("bridge")
            sent = sum(f.sent for f in floods)
            assert heard_by[0].take_latest() is None  # the connection without credentials was refused
            assert all(sub.take_latest() is None for sub in heard_by[2:])  # default deny: the colleague hears nothing
        node.send_signal(signal.SIGTERM)
        node_summary = json.loads(node.communicate(timeout=60)[0].strip().splitlines()[-1])
        bridge.send_signal(signal.SIGTERM)
        summary = json.loads(bridge.communicate(timeout=60)[0])
        px4.send_signal(signal.SIGTERM)
        px4.wait(timeout=60)
        received = json.loads((tmp_path / "px4.json").read_text())
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    assert sent > 1000
    assert summary["foreign_sessions"] == 0 and summary["commands_refused"] == 0  # no intruder's put got through
    assert summary["paired_session_id"] == node_summary["session_id"] == f"{paired.paired_session_id:016x}"
    assert summary["commands_obeyed"] > 500 and summary["frames"]["frames"] > 500  # both ways through the login
    assert node_summary["frames"] > 500 and node_summary["frames_bad"] == 0
    assert len(received["actuator_motors"]) > 500  # the node's (stopped) commands reached PX4 through the bridge
