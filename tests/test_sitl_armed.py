"""The plant flies only an armed node's speeds (issue 24 item 1 of the fly brief: after "landed/disarmed" only zeros).

A simulator link (:class:`omnirotor.sitl.server.SimLink`) and a commanding session on real Zenoh on loopback, in
one process: a command flagged ``STATE_STOP`` is flown as zeros whatever speeds it carries (counted), and a later
armed command of the paired session is flown again (re-arming is the node's to decide); an older armed command
arriving after the stop is never flown (its sequence number).
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from omnirotor.rosmsg.convert import COMMAND, COMMAND_ARMED, COMMAND_STOP, WireMessages
from omnirotor.sitl.server import TOPICS, ServeOptions, SimLink
from omnirotor.transport import open_transport
from sitl.procs import free_port

pytest.importorskip("zenoh")

N = 8


def _until(cond, timeout_s=10.0):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return True
    return False


def test_a_stop_command_is_flown_as_zeros_and_an_old_armed_one_is_never_flown():
    ep, ns = f"tcp/127.0.0.1:{free_port()}", "/armed"
    with open_transport(listen=[ep], namespace=ns) as plant, open_transport(connect=[ep], namespace=ns) as node:
        link = SimLink(plant, N, ServeOptions(ros_views=False))
        pub = node.publisher(TOPICS["rotor_cmd"], COMMAND, block=True)
        w = WireMessages(N)
        m = w.command
        m.session_id = 77

        def send(seq: int, frame_seq: int, hz: float, state: int) -> None:
            m.seq, m.frame_seq, m.state = seq, frame_seq, state
            m.hz[:] = hz
            pub.put(m)

        # the link needs a moment to match the publisher: resend the first armed command until it is obeyed
        assert _until(lambda: (send(1, 0, 300.0, COMMAND_ARMED), link.poll_commands(0.05))[1])
        assert np.all(link.cmd_hz == 300.0)
        send(2, 1, 300.0, COMMAND_STOP)  # disarmed, but speeds not zeros (a wrong node): zeros flown, counted
        assert _until(lambda: link.poll_commands(0.05))
        assert not link.cmd_hz.any() and link.stop_nonzero == 1
        send(2, 2, 300.0, COMMAND_ARMED)  # an armed command numbered as old as the stop: refused, zeros held
        send(3, 2, 0.0, COMMAND_STOP)
        assert _until(lambda: link.poll_commands(0.05))
        assert not link.cmd_hz.any() and link.gate.refused == 1 and link.stop_nonzero == 1
        send(4, 3, 250.0, COMMAND_ARMED)  # armed again by the node: flown
        assert _until(lambda: link.poll_commands(0.05))
        assert np.all(link.cmd_hz == 250.0)


def test_controller_log_rows_of_another_session_never_enter_the_run():
    """The rows the simulator computes a mission's metrics from are the obeyed node's only: rows of another
    controller session (a second node, a forger) are dropped and counted as bad payloads (issue 26 item 5)."""
    from omnirotor.rosmsg import typestore
    from omnirotor.rosmsg.convert import CONTROLLER_LOG

    T = typestore().types
    ep, ns = f"tcp/127.0.0.1:{free_port()}", "/rows"
    with open_transport(listen=[ep], namespace=ns) as plant, open_transport(connect=[ep], namespace=ns) as node:
        link = SimLink(plant, N, ServeOptions(ros_views=False, pair_session=77))
        rows = node.publisher(TOPICS["controller_log"], CONTROLLER_LOG, block=True)
        stored: dict[int, float] = {}

        def send(session: int, seq: int, value: float) -> None:
            rows.put(T[CONTROLLER_LOG](session_id=session, frame_seq=np.array([seq], np.uint64), n_columns=2,
                                       rows=np.full(2, value)))  # fmt: skip

        def drained(seq: int) -> bool:
            link.drain_rows(lambda s, row: stored.__setitem__(s, float(row[0])))
            return seq in stored

        assert _until(lambda: (send(77, 1, 1.0), drained(1))[1])  # the obeyed node's row (once the key matched)
        for seq in (1, 2, 3):
            send(99, seq, -1.0)  # a forger's rows over the node's and ahead of them
        send(77, 2, 2.0)
        assert _until(lambda: drained(2))
        link.drain_rows(lambda s, row: stored.__setitem__(s, float(row[0])))
    assert stored == {1: 1.0, 2: 2.0}  # the forged rows never stored
    assert link.bad_payloads >= 3
