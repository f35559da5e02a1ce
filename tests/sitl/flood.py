"""A foreign publisher for the pairing and authentication tests: well-formed rotor commands of another controller
session on the command key, and (``frames=True``) well-formed sensor frames of another plant session on the frame
key, with plausible numbers."""

from __future__ import annotations

import threading
import time

import numpy as np

from omnirotor.messages import new_frame
from omnirotor.rosmsg.convert import COMMAND, COMMAND_ARMED, FRAME, WireMessages
from sitl.procs import wait_until

FLOOD = 0x0BAD5E55105E0001
"""The foreign controller session's id (its commands)."""
FLOOD_PLANT = 0x0BAD5E55F7A3E001
"""The foreign plant session's id (its frames)."""


class Flood:
    """Foreign well-formed messages, from a thread, every 0.5 ms (module docstring).

    Args:
        transport: the session to publish from.
        answer_start_frame: the commands answer the plant's start frame (number 0), else frames never sent.
        commands: publish the foreign commands (full speeds, increasing numbers).
        frames: publish foreign frames: a vehicle hovering at rest (the IMU reads +g), numbered 1, 2, ... as a
            plant that has just started, its time 1 ms a number.
    """

    def __init__(self, transport, answer_start_frame: bool = True, commands: bool = True, frames: bool = False) -> None:
        w = WireMessages(8)
        self._cmd_pub = transport.publisher("/omnirotor/rotor_cmd", COMMAND) if commands else None
        self._msg = m = w.command
        m.session_id, m.state, m.hz[:] = FLOOD, COMMAND_ARMED, 400.0
        self._frame_pub = transport.publisher("/omnirotor/frame", FRAME) if frames else None
        self._frames = w
        self._record = new_frame(8)
        self._record[0]["imu"]["acc_B"] = (0.0, 0.0, 9.81)
        self._record[0]["rotor_hz"] = 150.0 * np.array([1, -1] * 4)
        w.frame.session_id = FLOOD_PLANT
        self._start = answer_start_frame
        self.sent = 0
        self.frames_sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        m = self._msg
        while not self._stop.is_set():
            if self._cmd_pub is not None:
                m.seq += 1
                # answering the start frame (number 0) would start the plant's run if it were obeyed
                m.frame_seq = 0 if self._start else m.seq
                self._cmd_pub.put(m)
                self.sent += 1
            if self._frame_pub is not None:
                self.frames_sent += 1
                self._record[0]["t"] = 0.001 * self.frames_sent
                self._frame_pub.put(self._frames.fill_frame(self._record, self.frames_sent))
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
