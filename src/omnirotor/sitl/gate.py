"""Which rotor commands a plant obeys: one paired controller session, its sequence numbers increasing.

The first well-formed command pairs the plant with its session (``RotorCommand.session_id``, random per node
process). From then on a command of another session is refused, counted and flagged (said once per session on
stderr), never obeyed; so is a command of the paired session whose sequence number is not above the last obeyed
one (a replay, or an older command overtaken). The pairing is released only when the plant stopped its rotors
(the offboard-loss failsafe): a new node may then take over. A sequence number more than
:data:`MAX_SEQ_JUMP` above the last obeyed one is refused too, so that one forged or corrupted number cannot
lock the paired node out.

The session identity is a number on the wire, so this guards against a second node or a stale process, not
against a hostile one that copies it: on a shared network use Zenoh's access control or TLS (docs/fly.md).
"""

from __future__ import annotations

import sys

__all__ = ["CommandGate", "MAX_SEQ_JUMP"]

_MAX_TRACKED_SESSIONS = 1024
MAX_SEQ_JUMP = 1000
"""The largest step of the sequence number between two obeyed commands (a second of commands at 1 kHz)."""


class CommandGate:
    """The pairing rule of the module docstring.

    Attributes:
        paired: the paired session id (0: none yet).
        obeyed: commands obeyed.
        refused: commands refused (another session, or a sequence number not increasing).
        foreign_sessions: distinct other sessions seen (up to 1024 tracked).
    """

    def __init__(self, name: str = "omnirotor sim") -> None:
        self._name = name
        self.paired = 0
        self.last_seq = 0
        self.obeyed = 0
        self.refused = 0
        self._foreign: set[int] = set()

    @property
    def foreign_sessions(self) -> int:
        """Distinct other sessions that published commands."""
        return len(self._foreign)

    def offer(self, session_id: int, seq: int) -> bool:
        """True when the command of ``session_id`` numbered ``seq`` is to be obeyed (module docstring)."""
        if self.paired == 0:
            self.paired = session_id
            self.last_seq = seq - 1
            print(f"{self._name}: paired with controller session {session_id:016x}", file=sys.stderr)
        if session_id != self.paired:
            self.refused += 1
            if session_id not in self._foreign and len(self._foreign) < _MAX_TRACKED_SESSIONS:
                self._foreign.add(session_id)
                print(
                    f"{self._name}: refused rotor commands of session {session_id:016x}: paired with "
                    f"{self.paired:016x}",
                    file=sys.stderr,
                )
            return False
        if not 0 < seq - self.last_seq <= MAX_SEQ_JUMP:
            self.refused += 1
            return False
        self.last_seq = seq
        self.obeyed += 1
        return True

    def release(self) -> None:
        """Forget the pairing (after the rotors were stopped): the next session's command pairs anew."""
        self.paired = 0
        self.last_seq = 0
