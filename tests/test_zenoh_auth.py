"""Zenoh's user/password authentication and access control, with the shipped example configs (issue 26 item 5).

Three kinds of process on loopback, as on a robot's shared network: the simulator with ``examples/zenoh-auth/
plant.json5`` (only peers that log in connect; only the user ``node`` may publish), the flight node with
``node.json5`` (it logs in as ``node``), and intruders in this test's process that start flooding foreign rotor
commands *before* the node: one without credentials, one logged in as the read-only ``viewer``. The plant runs
first come (no ``--pair-session``), so any intruder's command that reached its gate would take the pairing.
What Zenoh does, asserted through the plant's counters and what each intruder hears: the anonymous connection
is refused (it hears nothing), the viewer connects (it hears the plant's status) but every put of its own is
denied before the plant's subscriber (no command refused, no foreign session seen), and the node flies.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import pytest

from omnirotor.rosmsg.convert import SIM_STATUS
from omnirotor.transport import open_transport
from sitl.flood import Flood, status_until
from sitl.procs import ROOT, Pair

EXAMPLES = ROOT / "examples" / "zenoh-auth"


def _configs(tmp: Path) -> Path:
    """The shipped example files, verbatim, in a folder of their own (the processes' working folder)."""
    where = tmp / "zenoh"
    shutil.copytree(EXAMPLES, where)
    return where


def test_the_examples_are_what_the_test_flies():
    names = {p.name for p in EXAMPLES.iterdir()}
    assert {"plant.json5", "plant-users.txt", "node.json5", "node-users.txt", "ctl.json5", "viewer.json5"} <= names


@pytest.mark.slow
def test_only_the_logged_in_node_commands_the_rotors(tmp_path):
    cfg = _configs(tmp_path)
    with Pair(tmp_path, "hover", ["--seed", "4", "--duration", "2", "--zenoh-config", str(cfg / "plant.json5")],
              lockstep=True, node_args=("--zenoh-config", str(cfg / "node.json5")), start_node=False,
              cwd=cfg) as pair:  # fmt: skip
        ns, plant = pair.namespace, [pair.endpoint]
        with (
            open_transport(listen=[], connect=plant, namespace=ns) as anonymous,
            open_transport(listen=[], connect=plant, namespace=ns, config_file=str(cfg / "viewer.json5")) as viewer,
        ):
            seen_by_viewer = viewer.subscriber("/omnirotor/sim_status", SIM_STATUS, depth=8)
            seen_by_anonymous = anonymous.subscriber("/omnirotor/sim_status", SIM_STATUS, depth=8)
            up = status_until(seen_by_viewer, lambda m: True, 300)  # the viewer is connected: it hears the plant
            assert up, pair.text("sim")[-2000:]
            with Flood(anonymous) as flood_a, Flood(viewer) as flood_v:
                time.sleep(2.0)  # a flood of both before the node: nothing of it reaches the plant's gate
                early = status_until(seen_by_viewer, lambda m: True, 30)
                assert early.paired_session_id == 0 and early.commands_refused == 0 and early.steps == 0
                pair.start_node()
                sitl, node = pair.wait(timeout_s=900)
            sent = flood_a.sent + flood_v.sent
            assert seen_by_anonymous.take_latest() is None  # its connection was refused: it heard nothing
    s = sitl["sitl"]
    assert sent > 1000
    assert s["foreign_sessions"] == 0 and s["commands_refused"] == 0  # no intruder's put ever reached the gate
    assert s["commands_obeyed"] >= s["steps"] > 0 and not s["failsafe"]
    assert f"paired with controller session {node['session_id']}" in pair.text("sim")
    assert sitl["success"] and max(sitl["ee_max_error"][a] for a in ("x_cm", "y_cm", "z_cm")) < 5.0
