"""What ``omnirotor ctl`` asks the flight node and what the node answers: requests, replies, status.

Python-side types of ``omnirotor_msgs/msg/FlightRequest``, ``FlightReply``, ``FlightStatus`` and
``Setpoint`` (``src/omnirotor/rosmsg/omnirotor_msgs/msg/``), with conversions both ways
(:meth:`FlightRequest.from_msg`, :meth:`FlightRequest.to_fields`, ...): the transport serialises the ROS 2
messages (rosbags' CDR; ``to_msg`` builds the message objects), the director works on these. Not-given numbers
travel as NaN. Light to import (no controller, no numba): the ``ctl`` client uses it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from omnirotor.errors import InputError
from omnirotor.fly.modes import REQUEST_IDS, REQUESTS, FlightMode

__all__ = ["FlightRequest", "FlightReply", "FlightStatus", "Setpoint", "request_from", "CTL_TOPIC"]

CTL_TOPIC = "/omnirotor/ctl"
"""The request/reply topic of the flight node (FlightRequest -> FlightReply)."""

_NAN = math.nan
MAX_NAME_CHARS = 100
"""The longest preset or map name a request may carry (a longer one is refused, never echoed whole)."""


def _header(t: float, frame_id: str) -> Any:
    """A ``std_msgs/msg/Header`` stamped ``t`` [s] (>= 0)."""
    from omnirotor.rosmsg import msg_type

    sec = int(t)
    nanosec = min(int(round((t - sec) * 1e9)), 999_999_999)
    return msg_type("std_msgs/msg/Header")(stamp=msg_type("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec),
                                           frame_id=frame_id)  # fmt: skip


def _msg(type_name: str, fields: dict[str, Any]) -> Any:
    """A message object of ``omnirotor_msgs/msg/<type_name>`` from the shipped definitions (rosbags)."""
    from omnirotor.rosmsg import msg_type

    return msg_type(f"omnirotor_msgs/msg/{type_name}")(**fields)


def _opt(x: float) -> float | None:
    return None if x is None or x != x else float(x)


def _nan(x: float | None) -> float:
    return _NAN if x is None else float(x)


@dataclasses.dataclass(frozen=True)
class Setpoint:
    """An end-effector target (``omnirotor_msgs/msg/Setpoint``).

    Attributes:
        p_W: (3,) EE tip position [m], world frame.
        q_WB: (4,) attitude wxyz, or None: keep the current one (then roll/pitch/yaw replace its angles).
        roll_deg, pitch_deg, yaw_deg: attitude angles [deg] (ZYX, as ``so3.R_from_rpy``) replacing those of the
            current attitude; None keeps each.
        duration_s: segment duration [s], or None: the shortest within the flight limits.
    """

    p_W: tuple[float, float, float]
    q_WB: tuple[float, float, float, float] | None = None
    roll_deg: float | None = None
    pitch_deg: float | None = None
    yaw_deg: float | None = None
    duration_s: float | None = None

    def to_fields(self) -> dict[str, Any]:
        """The fields of the ROS message (NaN for not given; a zero quaternion for none)."""
        return {
            "p_w": [float(v) for v in self.p_W],
            "q_wb": [0.0, 0.0, 0.0, 0.0] if self.q_WB is None else [float(v) for v in self.q_WB],
            "roll_deg": _nan(self.roll_deg),
            "pitch_deg": _nan(self.pitch_deg),
            "yaw_deg": _nan(self.yaw_deg),
            "duration_s": _nan(self.duration_s),
        }

    def to_msg(self) -> Any:
        """The ``omnirotor_msgs/msg/Setpoint`` message object (rosbags)."""
        f = self.to_fields()
        f["p_w"], f["q_wb"] = np.array(f["p_w"]), np.array(f["q_wb"])
        return _msg("Setpoint", f)

    @classmethod
    def from_fields(cls, m: Any) -> Setpoint:
        """From a ROS message object or a mapping with the message's field names."""
        get = m.get if isinstance(m, Mapping) else lambda k, d=None: getattr(m, k, d)
        q = [float(v) for v in get("q_wb", [0.0] * 4)]
        return cls(
            p_W=tuple(float(v) for v in get("p_w", [_NAN] * 3)),
            q_WB=None if not any(q) else tuple(q),
            roll_deg=_opt(get("roll_deg", _NAN)),
            pitch_deg=_opt(get("pitch_deg", _NAN)),
            yaw_deg=_opt(get("yaw_deg", _NAN)),
            duration_s=_opt(get("duration_s", _NAN)),
        )


@dataclasses.dataclass(frozen=True)
class FlightRequest:
    """One request to the flight node (``omnirotor_msgs/msg/FlightRequest``).

    Attributes:
        kind: one of :data:`omnirotor.fly.modes.REQUESTS`.
        height_m: take-off height [m] above the armed pose (None: the flight file's).
        setpoint: goto target.
        depth_m: penetration depth along the contact normal [m] (push).
        name: admittance preset (preset) or map mode (map).
        force: disarm in flight (stops the rotors).
    """

    kind: str
    height_m: float | None = None
    setpoint: Setpoint | None = None
    depth_m: float | None = None
    name: str = ""
    force: bool = False

    def __post_init__(self) -> None:
        if self.kind not in REQUEST_IDS:
            raise InputError(f"unknown request {str(self.kind)[:MAX_NAME_CHARS]!r}; requests: {', '.join(REQUESTS)}")
        if len(self.name) > MAX_NAME_CHARS:
            raise InputError(f"a preset or map name is at most {MAX_NAME_CHARS} characters, got {len(self.name)}")

    def to_fields(self) -> dict[str, Any]:
        """The fields of the ROS message."""
        sp = self.setpoint if self.setpoint is not None else Setpoint((_NAN, _NAN, _NAN))
        return {
            "kind": REQUEST_IDS[self.kind],
            "height_m": _nan(self.height_m),
            "setpoint": sp.to_fields(),
            "depth_m": _nan(self.depth_m),
            "name": self.name,
            "force": bool(self.force),
        }

    def to_msg(self) -> Any:
        """The ``omnirotor_msgs/msg/FlightRequest`` message object (rosbags)."""
        f = self.to_fields()
        f["setpoint"] = (self.setpoint or Setpoint((_NAN, _NAN, _NAN))).to_msg()
        return _msg("FlightRequest", f)

    @classmethod
    def from_msg(cls, m: Any) -> FlightRequest:
        """From a ROS message object (or a mapping with its field names: ``kind`` an index or a name).

        Raises:
            InputError: an unknown kind or a malformed field.
        """
        get = m.get if isinstance(m, Mapping) else lambda k, d=None: getattr(m, k, d)
        kind = get("kind", None)
        try:
            if not isinstance(kind, str):
                if not 0 <= int(kind) < len(REQUESTS):
                    raise ValueError(
                        f"unknown request kind {int(kind)} (0 to {len(REQUESTS) - 1}: {', '.join(REQUESTS)})"
                    )
                kind = REQUESTS[int(kind)]
            sp = get("setpoint", None)
            setpoint = Setpoint.from_fields(sp) if sp is not None else None
            if setpoint is not None and not all(v == v for v in setpoint.p_W):
                setpoint = None
            return cls(
                kind=kind,
                height_m=_opt(get("height_m", _NAN)),
                setpoint=setpoint,
                depth_m=_opt(get("depth_m", _NAN)),
                name=str(get("name", "") or ""),
                force=bool(get("force", False)),
            )
        except (TypeError, ValueError, IndexError) as exc:
            raise InputError(f"malformed flight request: {exc}") from None


def request_from(req: Any) -> FlightRequest:
    """A :class:`FlightRequest` from itself, a mapping (``{"kind": "goto", "setpoint": {...}}``) or a message."""
    if isinstance(req, FlightRequest):
        return req
    if isinstance(req, Mapping) and isinstance(req.get("setpoint"), Setpoint):
        return FlightRequest(**req)
    return FlightRequest.from_msg(req)


@dataclasses.dataclass(frozen=True)
class FlightReply:
    """The node's answer (``omnirotor_msgs/msg/FlightReply``).

    Attributes:
        accepted: the request was accepted.
        kind: the request.
        mode_from: the mode when it arrived.
        mode: the mode after it.
        message: why it was refused, or what was done (one line).
    """

    accepted: bool
    kind: str
    mode_from: FlightMode
    mode: FlightMode
    message: str

    def line(self) -> str:
        """One line for a terminal: ``accepted: takeoff: armed -> takeoff (0.50 m in 3.1 s)``."""
        verdict = "accepted" if self.accepted else "refused"
        if self.accepted and self.mode != self.mode_from:
            what = f"{self.mode_from.label} -> {self.mode.label}"
            return f"{verdict}: {self.kind}: {what}" + (f" ({self.message})" if self.message else "")
        return f"{verdict}: {self.kind}: {self.message or self.mode.label}"

    def to_fields(self) -> dict[str, Any]:
        """The fields of the ROS message."""
        return {
            "accepted": bool(self.accepted),
            "kind": REQUEST_IDS[self.kind],
            "mode_from": int(self.mode_from),
            "mode": int(self.mode),
            "message": self.message,
        }

    def to_msg(self) -> Any:
        """The ``omnirotor_msgs/msg/FlightReply`` message object (rosbags)."""
        return _msg("FlightReply", self.to_fields())

    @classmethod
    def from_msg(cls, m: Any) -> FlightReply:
        """From a ROS message object or a mapping with its field names."""
        get = m.get if isinstance(m, Mapping) else lambda k, d=None: getattr(m, k, d)
        return cls(
            bool(get("accepted")), REQUESTS[int(get("kind"))], FlightMode(int(get("mode_from"))),
            FlightMode(int(get("mode"))), str(get("message")),
        )  # fmt: skip


@dataclasses.dataclass(frozen=True)
class FlightStatus:
    """The flight logic's state, published about 50 times a second (``omnirotor_msgs/msg/FlightStatus``).

    Attributes:
        t: time of the last frame [s].
        mode: the flight mode.
        failsafe: the failsafe level reached (:class:`omnirotor.fly.failsafe.Failsafe`).
        cause: :class:`omnirotor.fly.failsafe.Cause` bits of what is wrong now.
        control_status: :class:`omnirotor.messages.ControlStatus` bits of the last command.
        preset: the admittance preset flown.
        map_mode: the wrench-map mode flown.
        depth_m: the penetration depth commanded [m] (0 out of contact).
        target: the EE target of the current segment (None on the ground).
        frames, steps: frames seen, controller steps.
        requests_accepted, requests_refused: requests so far.
        failsafe_events: failsafe actions taken (hold, land, stop).
        bad_commands: periods whose command was missing or not finite (the last good one was sent).
        message: the last transition, one line.
    """

    t: float
    mode: FlightMode
    failsafe: int
    cause: int
    control_status: int
    preset: str
    map_mode: str
    depth_m: float
    target: Setpoint | None
    frames: int
    steps: int
    requests_accepted: int
    requests_refused: int
    failsafe_events: int
    bad_commands: int
    message: str

    def to_fields(self, frame_id: str = "") -> dict[str, Any]:
        """The keyword arguments of the ROS message class: nested Setpoint and the header as message objects."""
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        d["mode"] = int(self.mode)
        d["target"] = (self.target or Setpoint((_NAN, _NAN, _NAN))).to_msg()
        t = self.t if math.isfinite(self.t) and self.t >= 0.0 else 0.0
        d["header"] = _header(t, frame_id)
        return d

    def to_msg(self, frame_id: str = "") -> Any:
        """The ``omnirotor_msgs/msg/FlightStatus`` message object (rosbags), stamped with :attr:`t`."""
        return _msg("FlightStatus", self.to_fields(frame_id))

    @classmethod
    def from_msg(cls, m: Any) -> FlightStatus:
        """From a ROS message object or a mapping with its field names."""
        get = m.get if isinstance(m, Mapping) else lambda k, d=None: getattr(m, k, d)
        target = Setpoint.from_fields(get("target"))
        kw = {f.name: get(f.name) for f in dataclasses.fields(cls)}
        kw["mode"] = FlightMode(int(kw["mode"]))
        kw["target"] = target if all(v == v for v in target.p_W) else None
        for name in ("failsafe", "cause", "control_status", "frames", "steps", "requests_accepted",
                     "requests_refused", "failsafe_events", "bad_commands"):  # fmt: skip
            kw[name] = int(kw[name])
        return cls(**kw)
