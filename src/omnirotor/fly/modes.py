"""Flight modes and the rules of their transitions (issue 24 item 2, as PX4's commander arms and switches).

    disarmed --arm--> armed --takeoff--> takeoff --(reference arrived)--> hold
    hold --goto--> track --(arrived)--> hold          hold/contact --push DEPTH--> contact
    contact --push 0 (arrived)--> hold                 takeoff/hold/track/contact --land--> land
    land --(touchdown, or the bounded time)--> disarmed    armed --disarm--> disarmed
    land --goto/hold--> track/hold (the operator aborts a landing; not a failsafe's)

Every request is accepted or refused with one line saying why (:func:`refusal`). A failsafe
(:mod:`omnirotor.fly.failsafe`) may force ``hold`` or ``land``, or stop everything (``disarmed``); while one
is active only ``land``, ``disarm``, ``preset`` and ``status`` are accepted. ``disarm --force`` is accepted in
every mode: it stops the rotors in flight (a kill switch).
"""

from __future__ import annotations

import enum

__all__ = ["FlightMode", "REQUESTS", "ALLOWED", "refusal", "FLYING", "REQUEST_IDS"]


class FlightMode(enum.IntEnum):
    """The flight mode (its value is the ``mode`` of ``omnirotor_msgs/msg/FlightStatus``)."""

    DISARMED = 0
    """Rotors stopped; the controller is not stepped."""
    ARMED = 1
    """On the ground, rotors at idle, ready to take off; the controller is not stepped yet."""
    TAKEOFF = 2
    """Climbing to the take-off height."""
    HOLD = 3
    """Hovering at the reference's pose."""
    TRACK = 4
    """Flying a goto segment."""
    CONTACT = 5
    """Pushing along the contact normal with the contact admittance preset."""
    LAND = 6
    """Descending at a bounded speed to the take-off height; disarms on touchdown."""

    @property
    def label(self) -> str:
        """Lower-case name, as the CLI and the status say it."""
        return self.name.lower()


FLYING = frozenset({FlightMode.TAKEOFF, FlightMode.HOLD, FlightMode.TRACK, FlightMode.CONTACT, FlightMode.LAND})
"""Modes in which the controller is stepped."""

REQUESTS = ("status", "arm", "takeoff", "goto", "hold", "push", "preset", "map", "land", "disarm")
"""Request kinds (``omnirotor ctl`` subcommands); the index is the ``kind`` of ``FlightRequest``."""
REQUEST_IDS = {name: i for i, name in enumerate(REQUESTS)}

_M = FlightMode
ALLOWED: dict[str, frozenset[FlightMode]] = {
    "status": frozenset(_M),
    "arm": frozenset({_M.DISARMED}),
    "takeoff": frozenset({_M.ARMED}),
    "goto": frozenset({_M.HOLD, _M.TRACK, _M.CONTACT, _M.LAND}),
    "hold": frozenset({_M.TAKEOFF, _M.HOLD, _M.TRACK, _M.CONTACT, _M.LAND}),
    "push": frozenset({_M.HOLD, _M.CONTACT}),
    "preset": frozenset(_M),
    "map": frozenset(_M),
    "land": frozenset({_M.TAKEOFF, _M.HOLD, _M.TRACK, _M.CONTACT}),
    "disarm": frozenset({_M.DISARMED, _M.ARMED}),
}
"""The modes in which each request may be accepted (further checks follow: limits, estimate, failsafe)."""

_WHY = {
    ("arm", _M.ARMED): "already armed",
    ("takeoff", _M.DISARMED): "disarmed (arm first)",
    ("land", _M.DISARMED): "not flying (disarmed)",
    ("land", _M.ARMED): "not flying (armed on the ground: disarm instead)",
    ("land", _M.LAND): "already landing",
    ("push", _M.TRACK): "not hovering (wait until the goto arrives)",
    ("push", _M.TAKEOFF): "not hovering (still taking off)",
    ("disarm", _M.LAND): "landing: it disarms on touchdown (disarm --force stops the rotors in flight)",
}


def refusal(kind: str, mode: FlightMode) -> str | None:
    """Why request ``kind`` is refused in ``mode`` (one line), or None if the mode allows it."""
    if mode in ALLOWED[kind]:
        return None
    why = _WHY.get((kind, mode))
    if why is not None:
        return why
    if kind == "arm" or mode in FLYING and kind in ("takeoff", "arm"):
        return f"already flying (mode {mode.label})"
    if kind == "disarm":
        return f"in flight (mode {mode.label}): land first, or disarm --force to stop the rotors"
    if mode in (_M.DISARMED, _M.ARMED):
        return f"not flying (mode {mode.label}): take off first"
    return f"not allowed in mode {mode.label}"
