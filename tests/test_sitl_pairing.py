"""Pinned pairing both ways against a flood that starts before the node (issue 26 item 5), with real processes on
loopback.

Commands: a third process publishes well-formed rotor commands of a foreign session at full speed on the
simulator's command key before the flight node has started. With ``omnirotor sim --serve --pair-session ID`` (the
id the node is given with ``omnirotor fly --session-id ID``) the simulator refuses every one of them from the very
first and flies the node's hover; without it (first come, the documented default) the flood takes the pairing and
the node's commands are refused.

Frames: the same publisher sends well-formed sensor frames of a foreign plant session, with plausible numbers (1,
2, ... as a plant that has just started), on the node's frame key before the node starts. With ``omnirotor fly
--plant-session ID`` (the id the simulator is given with ``--session-id ID``) the node refuses them from the very
first and flies the hover; without it (first come) the node follows the flood's frames, refuses the simulator's
and says which session it follows and how to pin the simulator's.
"""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import sys

import pytest

from omnirotor.rosmsg.convert import SIM_STATUS
from sitl.flood import FLOOD, FLOOD_PLANT, Flood, status_until
from sitl.procs import CLI, ROOT, Pair, env, free_port, wait_until

NODE = 0x1A2B3C4D5E6F7081
PLANT = 0x5107A7E000000001


@contextlib.contextmanager
def _waiting_plant(tmp_path, sim_args: list[str], lockstep: bool, node_args: tuple[str, ...]):
    """A hover pair whose node is not started yet, a session of the test's own on the simulator, the simulator's
    status subscriber and its first status (the plant is up, waiting): ``(pair, t, status, first)``."""
    with (
        Pair(tmp_path, "hover", sim_args, lockstep=lockstep, node_args=node_args, start_node=False) as pair,
        pair.plant_transport() as t,
    ):
        status = t.subscriber("/omnirotor/sim_status", SIM_STATUS, depth=8)
        first = status_until(status, lambda m: True, 300)
        assert first, pair.text("sim")[-2000:]
        yield pair, t, status, first


@pytest.mark.slow
def test_pinned_pairing_flies_the_node_through_a_flood_that_started_first(tmp_path):
    sim_args = ["--seed", "4", "--duration", "2", "--pair-session", f"{NODE:x}"]
    with _waiting_plant(tmp_path, sim_args, True, ("--session-id", f"{NODE:016x}")) as (pair, t, status, _):
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
    sim_args = ["--seed", "4", "--duration", "2"]
    with _waiting_plant(tmp_path, sim_args, True, ("--session-id", f"{NODE:016x}")) as (pair, t, status, _):
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


@pytest.mark.slow
@pytest.mark.parametrize(
    ("node_args", "pinned_by"),
    [(("--plant-session", f"{PLANT:016x}"), "--plant-session"), ((), "the mission's plant")],
    ids=["plant-session", "mission"],
)
def test_a_pinned_node_flies_its_plant_through_forged_frames_that_started_first(tmp_path, node_args, pinned_by):
    """Pinned by ``fly --plant-session``, or by the mission's reply, which names the simulator's session (without
    the option): the flood's frames, there before the node, are refused from the very first, counted and said once
    (first come would follow them: the next test); the node follows the simulator's frames only and its hover
    holds."""
    sim_args = ["--seed", "4", "--duration", "2", "--session-id", f"{PLANT:x}"]
    with _waiting_plant(tmp_path, sim_args, False, node_args) as (pair, t, _, up):
        assert up.plant_session_id == PLANT  # the plant is up, waiting, and says its session
        assert f"plant session {PLANT:016x}" in pair.text("sim")
        with Flood(t, commands=False, frames=True) as flood:
            assert wait_until(lambda: flood.frames_sent > 200, 60)
            pair.start_node()  # the node starts into the flood
            sitl, node = pair.wait(timeout_s=900)
    s = sitl["sitl"]
    assert node["plant_session_id"] == s["plant_session_id"] == f"{PLANT:016x}" and node["plant_session_pinned"]
    assert node["frames_foreign"] > 0 and node["foreign_plant_sessions"] == 1 and not node["link_lost"]
    err = pair.text("node")
    assert f"following the sensor frames of plant session {PLANT:016x} only ({pinned_by})" in err
    refused = f"refused sensor frames of plant session {FLOOD_PLANT:016x}: following {PLANT:016x} (--plant-session)"
    assert err.count(refused) == 1  # said once, counted throughout
    assert f"the pinned plant session {PLANT:016x} sends frames" in err
    assert "first come" not in err and "following plant session" not in err  # never first come
    assert "status names plant session" not in err
    # the node's commands flew the plant: every period commanded or held, never the failsafe, and the hover holds
    assert s["commands_obeyed"] > 0 and s["commands_obeyed"] + s["commands_held"] >= s["steps"] and not s["failsafe"]
    assert sitl["success"] and max(sitl["ee_max_error"][a] for a in ("x_cm", "y_cm", "z_cm")) < 5.0


@pytest.mark.slow
def test_a_first_come_node_follows_forged_frames_that_came_first_and_names_the_real_plant(tmp_path):
    """The default's weakness, as documented (docs/transport.md): the node follows the first plant session it hears.

    The flood is the only sender when the interactive node starts; the simulator (its stand, frames every period)
    comes up afterwards. The node keeps following the flood, refuses the simulator's frames, and names the
    simulator's session with the ``--plant-session`` that pins it (from the simulator's status).
    """
    namespace = f"/t{free_port()}"
    sim_ep, node_ep = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    cli = [sys.executable, "-c", CLI]
    node_cmd = [*cli, "fly", "--listen", node_ep, "--connect", sim_ep, "--namespace", namespace, "--json",
                "--session-id", f"{NODE:016x}", "--fifo-priority", "0"]  # fmt: skip
    sim_cmd = [*cli, "sim", "--serve", "--listen", sim_ep, "--namespace", namespace, "--session-id", f"{PLANT:x}"]
    errs = {k: open(tmp_path / f"{k}.err", "w+") for k in ("node", "sim")}  # noqa: SIM115
    procs: dict[str, subprocess.Popen] = {}

    def text(k: str) -> str:
        errs[k].flush()
        return (tmp_path / f"{k}.err").read_text()

    from omnirotor.transport import open_transport

    try:
        with (
            open_transport(listen=[], connect=[node_ep], namespace=namespace) as t,
            Flood(t, commands=False, frames=True) as flood,
        ):
            procs["node"] = subprocess.Popen(node_cmd, stdout=subprocess.PIPE, stderr=errs["node"], env=env(),
                                             text=True, cwd=str(ROOT))  # fmt: skip
            first = f"following plant session {FLOOD_PLANT:016x}, the first to send frames"
            assert wait_until(lambda: first in text("node"), 600), text("node")[-2000:]
            procs["sim"] = subprocess.Popen(sim_cmd, stdout=subprocess.DEVNULL, stderr=errs["sim"], env=env(),
                                            text=True, cwd=str(ROOT))  # fmt: skip
            refused = f"refused sensor frames of plant session {PLANT:016x}: following {FLOOD_PLANT:016x}"
            assert wait_until(lambda: refused in text("node"), 600), text("node")[-2000:] + text("sim")[-2000:]
            told = (
                f"the plant's status names plant session {PLANT:016x}, not the followed {FLOOD_PLANT:016x}: its "
                f"frames and its status are ignored (follow it: --plant-session {PLANT:016x})"
            )
            assert wait_until(lambda: told in text("node"), 120), text("node")[-2000:]
            assert flood.frames_sent > 0
            procs["node"].send_signal(signal.SIGTERM)  # ends with its summary
            out, _ = procs["node"].communicate(timeout=60)
        summary = json.loads(out.strip().splitlines()[-1])
        assert summary["plant_session_id"] == f"{FLOOD_PLANT:016x}" and not summary["plant_session_pinned"]
        assert summary["frames_foreign"] > 0 and summary["foreign_plant_sessions"] == 1
        assert "following the first plant session that sends frames (first come" in text("node")
        assert f"plant session {PLANT:016x} (a node's --plant-session {PLANT:016x}" in text("sim")
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait(timeout=10)
        for f in errs.values():
            f.close()
