"""Which session a receiver follows: one paired sender, its numbers increasing — both directions of the wire.

One rule (:class:`SessionGate`), written once, serves both directions:

* **commands at the plant** (:class:`CommandGate`): the simulator (``omnirotor sim --serve``) and the robot bridge
  (``omnirotor px4-bridge``) obey the rotor commands of one controller session (``RotorCommand.session_id``, the
  node's, random per node process unless given with ``omnirotor fly --session-id``), pinned with the plant's
  ``--pair-session HEX``;
* **frames at the node** (:class:`FrameGate`): the flight node (``omnirotor fly``) follows the sensor frames of
  one plant session (``SensorFrame.session_id``, the plant's, random per plant process unless given with the
  plant's ``--session-id``), pinned with ``omnirotor fly --plant-session HEX``.

Two ways to pair:

* **pinned** (``pinned``: the id the other side prints at its start, or was given): only that session, from the
  very first message; every other session is refused, counted and flagged. A flood of foreign messages that starts
  before the receiver cannot take the pairing.
* **first come** (no ``pinned``): the first well-formed message pairs the receiver with its session. Whoever
  publishes first is followed: a foreign publisher that starts first pairs the receiver with itself, and the real
  sender is then refused (and said).

From then on a message of another session is refused, counted and flagged (said once per session on stderr: the
first 8 sessions one by one, the rest in one line), never followed; so is a message of the paired session whose
number is not above the last one followed (a replay, or an older message overtaken), or more than
:data:`MAX_SEQ_JUMP` above it (a number beyond it, forged or corrupted, cannot lock the paired sender out; one
within it is followed, and the sender's own messages are then refused until their numbers pass it). The first
message followed (after the start, a :meth:`~SessionGate.release` or a :meth:`~SessionGate.renumber`) sets where
the numbers start.

What ends a pairing is the receiver's to decide, from what its side knows:

* the plant releases it (:meth:`~SessionGate.release`) when it stopped its rotors (the offboard-loss failsafe):
  first come, a new node may then take over; pinned, the same session starts its numbers anew;
* the node restarts the plant's numbers after a link loss (:meth:`~SessionGate.renumber`: the plant may have
  restarted, or its numbers jumped while nothing arrived), keeping the session; a first-come pairing is released
  only while the link is lost *and* the node is disarmed (on the ground, or stopped by the link-loss failsafe),
  never in flight: the next plant's first frame is then followed, and said. A pinned plant is never released.

The session identity is a number on the wire, so this guards against a second node or plant, a stale process, or
a flood, not against a hostile publisher that copies the number: on a shared network use Zenoh's authentication
and access control (docs/transport.md, ``examples/zenoh-auth/``).
"""

from __future__ import annotations

import dataclasses
import secrets
import sys
from collections.abc import Callable

__all__ = [
    "SessionGate",
    "CommandGate",
    "FrameGate",
    "MAX_SEQ_JUMP",
    "new_session_id",
    "parse_session_id",
]

_MAX_TRACKED_SESSIONS = 1024
_SAID_SESSIONS = 8
"""Other sessions said one by one on stderr; those after are counted and said once together (a flood of distinct
sessions would otherwise print a line per session, up to the tracked 1024, from the receiving loop)."""
MAX_SEQ_JUMP = 1000
"""The largest step of the sequence number between two messages followed (a second of messages at 1 kHz)."""


def new_session_id() -> int:
    """A random session id (63 bits, odd: never 0), as a node or a plant takes when none is given."""
    return secrets.randbits(63) | 1


def parse_session_id(text: str, option: str) -> int:
    """A session id written as the processes print it: 1 to 16 hex digits, not zero.

    Raises:
        ValueError: anything else, with one line naming ``option``.
    """
    s = text.strip().lower().removeprefix("0x")
    if not 1 <= len(s) <= 16 or any(c not in "0123456789abcdef" for c in s):
        raise ValueError(f"{option} must be 1 to 16 hex digits (a session as the processes print it), got {text!r}")
    value = int(s, 16)
    if value == 0:
        raise ValueError(f"{option} must not be 0 (0 means no session)")
    return value


@dataclasses.dataclass(frozen=True)
class _Words:
    """What a gate says (``{s}``: the session concerned, ``{p}``: the paired one, ``{how}``: the pinning option)."""

    paired: str
    refused: str
    pinned_first: str
    option: str
    more: str


_COMMAND_WORDS = _Words(
    paired="paired with controller session {s:016x}",
    refused="refused rotor commands of session {s:016x}: paired with {p:016x}{how}",
    pinned_first="the pinned controller session {s:016x} commands",
    option="--pair-session",
    more="refused rotor commands of more controller sessions: counted (foreign_sessions), not said one by one",
)
_FRAME_WORDS = _Words(
    paired="following plant session {s:016x}, the first to send frames (first come: --plant-session pins one)",
    refused="refused sensor frames of plant session {s:016x}: following {p:016x}{how}",
    pinned_first="the pinned plant session {s:016x} sends frames",
    option="--plant-session",
    more="refused sensor frames of more plant sessions: counted (foreign_plant_sessions), not said one by one",
)


class SessionGate:
    """The pairing rule of the module docstring, for one direction.

    Args:
        name: the receiver's name in its notices (``name: ...`` on stderr).
        pinned: follow this session only (pinned pairing); None: the first come is paired.
        words: what it says (:data:`_COMMAND_WORDS`, :data:`_FRAME_WORDS`).
        say: where its notices go (a line without the name); None: stderr, prefixed with ``name``.

    Attributes:
        paired: the paired session id (0: none yet; pinned: the pinned id from the start).
        last_seq: the last number followed.
        accepted: messages followed.
        refused: messages refused (another session, or a number not increasing or beyond the jump).
        refused_foreign: of those, the messages of another session.
        foreign_sessions: distinct other sessions seen, up to 1024 (a flood of more distinct sessions shows 1024;
            :attr:`refused_foreign` counts every message). The first 8 are said one by one, the rest together.
    """

    def __init__(
        self, name: str, pinned: int | None = None, words: _Words = _COMMAND_WORDS,
        say: Callable[[str], None] | None = None,
    ) -> None:  # fmt: skip
        if pinned is not None and not 0 < pinned < 1 << 64:
            raise ValueError(f"a pinned session id is a nonzero 64-bit number, got {pinned!r}")
        self._name = name
        self._words = words
        self._say = say if say is not None else (lambda line: print(f"{name}: {line}", file=sys.stderr))
        self.pinned = pinned
        self.paired = pinned or 0
        self.last_seq = 0
        self._fresh = True  # the next message followed sets where the numbers start
        self.accepted = 0
        self.refused = 0
        self.refused_foreign = 0
        self._foreign: set[int] = set()

    @property
    def foreign_sessions(self) -> int:
        """Distinct other sessions that published."""
        return len(self._foreign)

    def admits(self, session_id: int, seq: int) -> bool:
        """True when the message of ``session_id`` numbered ``seq`` may be followed (module docstring).

        Pairs a first-come gate with ``session_id``, counts and says refusals, but does not advance the numbers:
        :meth:`follow` does, once the message is taken (a receiver that judges several queued messages, newest
        first, and takes one, advances by that one only).
        """
        if self.paired == 0:
            self.paired = session_id
            self._say(self._words.paired.format(s=session_id))
        if session_id != self.paired:
            self.refused += 1
            self.refused_foreign += 1
            if session_id not in self._foreign and len(self._foreign) < _MAX_TRACKED_SESSIONS:
                self._foreign.add(session_id)
                if len(self._foreign) <= _SAID_SESSIONS:
                    how = f" ({self._words.option})" if self.pinned else ""
                    self._say(self._words.refused.format(s=session_id, p=self.paired, how=how))
                elif len(self._foreign) == _SAID_SESSIONS + 1:
                    self._say(self._words.more)
            return False
        if not self._fresh and not 0 < seq - self.last_seq <= MAX_SEQ_JUMP:
            self.refused += 1
            return False
        return True

    def follow(self, seq: int) -> None:
        """The paired session's message numbered ``seq`` (admitted) was taken: the numbers go on from it."""
        if self._fresh:
            self._fresh = False
            if self.pinned:
                self._say(self._words.pinned_first.format(s=self.paired))
        self.last_seq = seq
        self.accepted += 1

    def offer(self, session_id: int, seq: int) -> bool:
        """:meth:`admits`, and :meth:`follow` when it does: True when the message is to be followed."""
        if not self.admits(session_id, seq):
            return False
        self.follow(seq)
        return True

    def renumber(self) -> None:
        """Keep the pairing; the paired session's next message is followed whatever its number."""
        self.last_seq = 0
        self._fresh = True

    def release(self) -> None:
        """Forget the pairing: first come, the next session's message pairs anew; pinned, :meth:`renumber`."""
        self.paired = self.pinned or 0
        self.renumber()


class CommandGate(SessionGate):
    """The plant's gate on rotor commands (module docstring): obeys one controller session.

    Args:
        name: the plant's name in its notices.
        pinned: obey this session only (``--pair-session``); None: the first come is paired.
    """

    def __init__(self, name: str = "omnirotor sim", pinned: int | None = None) -> None:
        super().__init__(name, pinned, _COMMAND_WORDS)

    @property
    def obeyed(self) -> int:
        """Commands obeyed."""
        return self.accepted


class FrameGate(SessionGate):
    """The node's gate on sensor frames (module docstring): follows one plant session.

    A plant repeats its start frame (number 0) until it has obeyed a command answering it
    (:mod:`omnirotor.sitl.server`): right after the start frame was followed, a frame numbered 0 again is
    admitted (:attr:`start_repeated` tells the node to answer it again, nothing stepped).

    Args:
        pinned: follow this plant session only (``omnirotor fly --plant-session``); None: the first come.
        say: where its notices go (the node's).
    """

    def __init__(self, pinned: int | None = None, say: Callable[[str], None] | None = None) -> None:
        super().__init__("omnirotor fly", pinned, _FRAME_WORDS, say)

    def admits(self, session_id: int, seq: int) -> bool:
        """:meth:`SessionGate.admits`, and the plant's repeated start frame (class docstring)."""
        if seq == 0 and session_id == self.paired and self.start_repeated:
            return True
        return super().admits(session_id, seq)

    @property
    def start_repeated(self) -> bool:
        """True while the last frame followed was the start frame (number 0): a 0 again is its repetition."""
        return not self._fresh and self.last_seq == 0
