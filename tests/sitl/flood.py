"""A foreign commander for the pairing and authentication tests: well-formed rotor commands of another session."""

from __future__ import annotations

import threading
import time

from omnirotor.rosmsg.convert import COMMAND, COMMAND_ARMED, WireMessages
from sitl.procs import wait_until

FLOOD = 0x0BAD5E55105E0001
"""The foreign session's id."""


class Flood:
    """Foreign well-formed commands (full speeds, increasing numbers) on the command key, from a thread."""

    def __init__(self, transport, answer_start_frame: bool = True) -> None:
        self._pub = transport.publisher("/omnirotor/rotor_cmd", COMMAND)
        w = WireMessages(8)
        self._msg = m = w.command
        m.session_id, m.state, m.hz[:] = FLOOD, COMMAND_ARMED, 400.0
        self._start = answer_start_frame
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        m = self._msg
        while not self._stop.is_set():
            m.seq += 1
            # answering the start frame (number 0) would start the plant's run if it were obeyed
            m.frame_seq = 0 if self._start else m.seq
            self._pub.put(m)
            self.sent += 1
            time.sleep(0.0005)

    def __enter__(self) -> Flood:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def status_until(sub, pred, timeout_s: float):
    """The newest message of ``sub`` for which ``pred`` holds, within ``timeout_s`` (None if none)."""
    return wait_until(lambda: (m := sub.take_latest()) is not None and pred(m) and m, timeout_s)
