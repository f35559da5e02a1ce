"""Which rotor commands a plant obeys: one paired controller session, its sequence numbers increasing.

Two ways to pair:

* **pinned** (``pinned``, the plant's ``--pair-session HEX``, the id the node prints at its start or was given
  with ``--session-id``): the plant obeys that session only, from the very first command; every other session is
  refused, counted and flagged. A flood of foreign commands that starts before the node cannot take the pairing.
* **first come** (no ``pinned``): the first well-formed command pairs the plant with its session
  (``RotorCommand.session_id``, random per node process unless given). Whoever publishes first is obeyed: a
  foreign publisher that starts before the node pairs the plant with itself, and the node is then refused.

From then on a command of another session is refused, counted and flagged (said once per session on stderr), never
obeyed; so is a command of the paired session whose sequence number is not above the last obeyed one (a replay,
or an older command overtaken). The pairing is released only when the plant stopped its rotors (the
offboard-loss failsafe): first come, a new node may then take over; pinned, the same session starts its numbers
anew. A sequence number more than :data:`MAX_SEQ_JUMP` above the last obeyed one is refused too, so that one
forged or corrupted number cannot lock the paired node out. The first command obeyed (after the start or a
release) sets where the numbers start.

The session identity is a number on the wire, so this guards against a second node or a stale process, not
against a hostile one that copies it: on a shared network use Zenoh's authentication and access control
(docs/transport.md, ``examples/zenoh-auth/``).
"""

from __future__ import annotations

import secrets
import sys

__all__ = ["CommandGate", "MAX_SEQ_JUMP", "new_session_id", "parse_session_id"]

_MAX_TRACKED_SESSIONS = 1024
MAX_SEQ_JUMP = 1000
"""The largest step of the sequence number between two obeyed commands (a second of commands at 1 kHz)."""


def new_session_id() -> int:
    """A random controller session id (63 bits, odd: never 0), as a node takes when none is given."""
    return secrets.randbits(63) | 1


def parse_session_id(text: str, option: str) -> int:
    """A controller session id written as the node prints it: 1 to 16 hex digits, not zero.

    Raises:
        ValueError: anything else, with one line naming ``option``.
    """
    s = text.strip().lower().removeprefix("0x")
    if not 1 <= len(s) <= 16 or any(c not in "0123456789abcdef" for c in s):
        raise ValueError(f"{option} must be 1 to 16 hex digits (as `omnirotor fly` prints its session), got {text!r}")
    value = int(s, 16)
    if value == 0:
        raise ValueError(f"{option} must not be 0 (0 means no session)")
    return value


class CommandGate:
    """The pairing rule of the module docstring.

    Args:
        name: the plant's name in its notices.
        pinned: obey this session only (pinned pairing); None: the first come is paired.

    Attributes:
        paired: the paired session id (0: none yet; pinned: the pinned id from the start).
        obeyed: commands obeyed.
        refused: commands refused (another session, or a sequence number not increasing).
        foreign_sessions: distinct other sessions seen (up to 1024 tracked).
    """

    def __init__(self, name: str = "omnirotor sim", pinned: int | None = None) -> None:
        if pinned is not None and not 0 < pinned < 1 << 64:
            raise ValueError(f"a pinned session id is a nonzero 64-bit number, got {pinned!r}")
        self._name = name
        self.pinned = pinned
        self.paired = pinned or 0
        self.last_seq = 0
        self._fresh = True  # the next obeyed command sets where the numbers start
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
            print(f"{self._name}: paired with controller session {session_id:016x}", file=sys.stderr)
        if session_id != self.paired:
            self.refused += 1
            if session_id not in self._foreign and len(self._foreign) < _MAX_TRACKED_SESSIONS:
                self._foreign.add(session_id)
                how = " (--pair-session)" if self.pinned else ""
                print(
                    f"{self._name}: refused rotor commands of session {session_id:016x}: paired with "
                    f"{self.paired:016x}{how}",
                    file=sys.stderr,
                )
            return False
        if self._fresh:
            self._fresh = False
            if self.pinned:
                print(f"{self._name}: the pinned controller session {session_id:016x} commands", file=sys.stderr)
        elif not 0 < seq - self.last_seq <= MAX_SEQ_JUMP:
            self.refused += 1
            return False
        self.last_seq = seq
        self.obeyed += 1
        return True

    def release(self) -> None:
        """Forget the pairing after the rotors were stopped.

        First come, the next session's command pairs anew; pinned, the pinned session's next command is obeyed
        whatever its number.
        """
        self.paired = self.pinned or 0
        self.last_seq = 0
        self._fresh = True
