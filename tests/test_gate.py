"""The plant's command gate (omnirotor.sitl.gate): first-come and pinned pairing (issue 26 item 5)."""

from __future__ import annotations

import pytest

from omnirotor.sitl.gate import MAX_SEQ_JUMP, CommandGate, FrameGate, new_session_id, parse_session_id

NODE = 0x1A2B3C4D5E6F7081
FLOOD = 12345


def test_first_come_pairs_whoever_commands_first_and_refuses_the_node_after(capsys):
    gate = CommandGate()
    assert gate.paired == 0
    assert gate.offer(FLOOD, 7)  # a foreign publisher that starts first takes the pairing
    assert gate.paired == FLOOD
    assert not gate.offer(NODE, 1)
    assert not gate.offer(NODE, 2)
    assert (gate.obeyed, gate.refused, gate.foreign_sessions) == (1, 2, 1)
    err = capsys.readouterr().err
    assert f"paired with controller session {FLOOD:016x}" in err
    assert err.count(f"refused rotor commands of session {NODE:016x}") == 1  # said once per session


def test_pinned_refuses_every_other_session_from_the_first_command(capsys):
    gate = CommandGate("plant", pinned=NODE)
    assert gate.paired == NODE  # before any command
    for seq in range(1, 50):  # a flood before the node: never paired with, never obeyed
        assert not gate.offer(FLOOD + seq % 3, seq)
    assert gate.paired == NODE and gate.obeyed == 0 and gate.refused == 49 and gate.foreign_sessions == 3
    assert gate.offer(NODE, 500)  # the node's first command, whatever its number
    assert gate.offer(NODE, 501)
    assert not gate.offer(NODE, 501)  # a replay
    assert not gate.offer(NODE, 501 + MAX_SEQ_JUMP + 1)  # a jump beyond the bound
    assert not gate.offer(FLOOD, 10_000)
    assert gate.obeyed == 2 and gate.refused == 52
    err = capsys.readouterr().err
    assert "paired with controller session" not in err  # nothing is paired: it was pinned
    assert f"refused rotor commands of session {FLOOD:016x}: paired with {NODE:016x} (--pair-session)" in err
    assert f"the pinned controller session {NODE:016x} commands" in err


def test_release_keeps_the_pin_and_restarts_the_numbers():
    pinned = CommandGate(pinned=NODE)
    assert pinned.offer(NODE, 900)
    pinned.release()  # the failsafe stopped the rotors
    assert pinned.paired == NODE
    assert not pinned.offer(FLOOD, 1)  # still not the flood's to take
    assert pinned.offer(NODE, 5000)  # the node's next number, far beyond the old one, starts anew
    first = CommandGate()
    assert first.offer(NODE, 3)
    first.release()
    assert first.paired == 0
    assert first.offer(FLOOD, 1) and first.paired == FLOOD  # first come again after a release


@pytest.mark.parametrize("text, value", [("1a2b3c4d5e6f7081", NODE), ("0x1A2B3C4D5E6F7081", NODE), ("ff", 255),
                                         ("ffffffffffffffff", (1 << 64) - 1)])  # fmt: skip
def test_session_ids_parse_as_printed(text, value):
    assert parse_session_id(text, "--pair-session") == value


@pytest.mark.parametrize("text", ["", "0", "0x", "00000000", "xyz", "1ffffffffffffffff", "-1", "12 34", "1.5"])
def test_bad_session_ids_are_one_line_errors(text):
    with pytest.raises(ValueError, match="--pair-session") as exc:
        parse_session_id(text, "--pair-session")
    assert "\n" not in str(exc.value)


def test_new_session_ids_are_nonzero_and_parse_back():
    for _ in range(100):
        s = new_session_id()
        assert 0 < s < 1 << 63
        assert parse_session_id(f"{s:016x}", "--session-id") == s
    with pytest.raises(ValueError):
        CommandGate(pinned=0)


# -- the same rule at the node: the plant session whose frames it follows (FrameGate) -------------------------------

PLANT = 0x5107A7E000000001


def test_the_frame_gate_pinned_refuses_a_flood_that_came_first_and_follows_its_plant():
    said: list[str] = []
    gate = FrameGate(pinned=PLANT, say=said.append)
    for seq in range(5, 60):  # forged frames with plausible numbers before the plant's first
        assert not gate.admits(FLOOD, seq)
    assert gate.paired == PLANT and gate.accepted == 0 and gate.refused_foreign == 55 and gate.foreign_sessions == 1
    assert gate.admits(PLANT, 0)  # the plant's start frame, whatever the flood numbered
    gate.follow(0)
    assert gate.start_repeated and gate.admits(PLANT, 0)  # its repetition: answered again (the node's rule)
    assert not gate.admits(FLOOD, 1) and gate.admits(PLANT, 1)
    gate.follow(1)
    assert not gate.start_repeated and not gate.admits(PLANT, 0) and not gate.admits(PLANT, 1)  # old, a replay
    assert not gate.admits(PLANT, 2 + MAX_SEQ_JUMP) and gate.admits(PLANT, 1 + MAX_SEQ_JUMP)  # the jump's bound
    assert gate.refused == gate.refused_foreign + 3
    assert said == [
        f"refused sensor frames of plant session {FLOOD:016x}: following {PLANT:016x} (--plant-session)",
        f"the pinned plant session {PLANT:016x} sends frames",
    ]


def test_the_frame_gate_judges_without_advancing_until_a_frame_is_followed():
    """The node judges queued frames newest first and takes one: older ones of the same plant stay admissible (a
    skipped frame's motion-capture sample is carried), the numbers advance by the frame followed only."""
    gate = FrameGate(say=lambda line: None)
    assert gate.admits(PLANT, 10) and gate.paired == PLANT  # first come: paired by the first well-formed frame
    gate.follow(10)
    assert gate.admits(PLANT, 14) and gate.admits(PLANT, 12) and gate.admits(PLANT, 11)
    gate.follow(14)
    assert not gate.admits(PLANT, 12) and gate.admits(PLANT, 15) and gate.accepted == 2


def test_the_frame_gate_first_come_keeps_its_plant_through_a_renumbering_and_pairs_anew_only_when_released():
    said: list[str] = []
    gate = FrameGate(say=said.append)
    assert gate.admits(FLOOD, 3)  # whoever sends first is followed
    gate.follow(3)
    assert not gate.admits(PLANT, 4) and gate.paired == FLOOD
    gate.renumber()  # a link loss while armed: the same plant, its numbers anew
    assert not gate.admits(PLANT, 1) and gate.admits(FLOOD, 90_000)
    gate.release()  # a link loss while disarmed
    assert gate.paired == 0 and gate.admits(PLANT, 77) and gate.paired == PLANT
    assert said == [
        f"following plant session {FLOOD:016x}, the first to send frames (first come: --plant-session pins one)",
        f"refused sensor frames of plant session {PLANT:016x}: following {FLOOD:016x}",
        f"following plant session {PLANT:016x}, the first to send frames (first come: --plant-session pins one)",
    ]


def test_a_flood_of_distinct_sessions_is_counted_in_bounded_memory_and_said_in_a_few_lines():
    """3 000 distinct foreign sessions: every message refused and counted, the distinct sessions tracked up to the
    cap (memory bounded), the first few said one by one and the rest in one line, not a line per session."""
    from omnirotor.sitl import gate as gate_module

    said: list[str] = []
    gate = FrameGate(say=said.append)
    assert gate.offer(PLANT, 1)
    for session in range(100, 3100):
        assert not gate.offer(session, 2)
    assert gate.refused_foreign == gate.refused == 3000
    assert gate.foreign_sessions == gate_module._MAX_TRACKED_SESSIONS == 1024
    refused = [line for line in said if line.startswith("refused sensor frames of plant session")]
    assert len(refused) == gate_module._SAID_SESSIONS == 8
    assert said[-1] == (
        "refused sensor frames of more plant sessions: counted (foreign_plant_sessions), not said one by one"
    )
    assert len(said) == 1 + 8 + 1  # followed, 8 sessions, the rest
    assert gate.offer(PLANT, 2)  # the plant still followed
