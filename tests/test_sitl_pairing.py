"""Pinned pairing against a flood that starts before the node (issue 26 item 5), with real processes on loopback.

A third process publishes well-formed rotor commands of a foreign session at full speed on the simulator's command
key before the flight node has started. With ``omnirotor sim --serve --pair-session ID`` (the id the node is given
with ``omnirotor fly --session-id ID``) the simulator refuses every one of them from the very first and flies the
node's hover; without it (first come, the documented default) the flood takes the pairing and the node's commands
are refused.
"""

from __future__ import annotations

import pytest

from omnirotor.rosmsg.convert import SIM_STATUS
from sitl.flood import FLOOD, Flood, status_until
from sitl.procs import Pair, wait_until

NODE = 0x1A2B3C4D5E6F7081


@pytest.mark.slow
def test_pinned_pairing_flies_the_node_through_a_flood_that_started_first(tmp_path):
    sim_args = ["--seed", "4", "--duration", "2", "--pair-session", f"{NODE:x}"]
    with (
        Pair(tmp_path, "hover", sim_args, lockstep=True, node_args=("--session-id", f"{NODE:016x}"),
             start_node=False) as pair,
        pair.plant_transport() as t,
    ):  # fmt: skip
        status = t.subscriber("/omnirotor/sim_status", SIM_STATUS, depth=8)
        assert status_until(status, lambda m: True, 300), pair.text("sim")[-2000:]  # the plant is up, waiting
        with Flood(t, answer_start_frame=True) as flood:
            before = status_until(status, lambda m: m.commands_refused >= 200, 120)
            assert before, pair.text("sim")[-2000:]
            assert before.paired_session_id == NODE and before.commands_obeyed == 0 and before.foreign_sessions == 1
            pair.start_node()  # the node starts into the flood
            sitl, node = pair.wait(timeout_s=900)
        sent = flood.sent
    s = sitl["sitl"]
    assert node["session_id"] == f"{NODE:016x}"
    assert f"controller session {NODE:016x}" in pair.text("node")
    # every period flown was commanded by the node; the flood is refused throughout, never obeyed
    assert s["commands_obeyed"] >= s["steps"] > 0 and s["commands_held"] == 0 and not s["failsafe"]
    assert s["foreign_sessions"] == 1 and s["commands_refused"] >= before.commands_refused and sent > 1000
    sim_err = pair.text("sim")
    assert f"refused rotor commands of session {FLOOD:016x}: paired with {NODE:016x} (--pair-session)" in sim_err
    assert "paired with controller session" not in sim_err  # never first come
    assert "the plant obeys controller session" not in pair.text("node")
    # the node's commands reached the rotors: its hover holds
    assert sitl["success"] and max(sitl["ee_max_error"][a] for a in ("x_cm", "y_cm", "z_cm")) < 5.0


@pytest.mark.slow
def test_first_come_pairs_with_a_flood_that_started_first_and_refuses_the_node(tmp_path):
    """The default's weakness, as documented (docs/transport.md): whoever commands first is obeyed."""
    with (
        Pair(tmp_path, "hover", ["--seed", "4", "--duration", "2"], lockstep=True,
             node_args=("--session-id", f"{NODE:016x}"), start_node=False) as pair,
        pair.plant_transport() as t,
    ):  # fmt: skip
        status = t.subscriber("/omnirotor/sim_status", SIM_STATUS, depth=8)
        assert status_until(status, lambda m: True, 300), pair.text("sim")[-2000:]
        # the flood's commands answer frames the plant never sent: the plant pairs but does not start its run
        with Flood(t, answer_start_frame=False):
            paired = status_until(status, lambda m: m.paired_session_id != 0, 120)
            assert paired and paired.paired_session_id == FLOOD, pair.text("sim")[-2000:]
            pair.start_node()
            refused = f"refused rotor commands of session {NODE:016x}: paired with {FLOOD:016x}"
            assert wait_until(lambda: refused in pair.text("sim"), 600), pair.text("node")[-2000:]
            after = status_until(status, lambda m: m.commands_refused > 0, 60)
            assert after and after.paired_session_id == FLOOD and after.foreign_sessions == 1
            assert after.steps == 0  # nothing flown: the node's answers to the start frame are refused
            told = f"the plant obeys controller session {FLOOD:016x}, not this node's {NODE:016x}"
            assert wait_until(lambda: told in pair.text("node"), 60), pair.text("node")[-2000:]
