"""``omnirotor px4-bridge``: the flight node's rotor commands to a PX4 vehicle over PX4's Zenoh bridge (docs/fly.md).

The bridge stands where the simulator stands in software in the loop: it consumes the node's
``/omnirotor/rotor_cmd`` (``omnirotor_msgs/msg/RotorCommand``) and publishes the plant's status on
``/omnirotor/sim_status``; towards PX4 (v1.18, its own namespace) it publishes, per obeyed command,

    /fmu/in/actuator_motors         px4_msgs/msg/ActuatorMotors      normalised thrust |w| w / w_max^2 per motor
                                                                      (:func:`omnirotor.fly.px4.controls_from_speeds`);
                                                                      NaN for every motor while the node is disarmed
    /fmu/in/offboard_control_mode   px4_msgs/msg/OffboardControlMode direct_actuator, at 10 Hz while the node is armed
    /fmu/in/vehicle_command         px4_msgs/msg/VehicleCommand      offboard switch, arm, disarm (:class:`Px4Offboard`)

and reads ``/fmu/out/vehicle_status`` (``px4_msgs/msg/VehicleStatus``: arming state, navigation state).

Who is obeyed: the paired session only (:class:`omnirotor.sitl.gate.CommandGate`: one session, increasing
sequence numbers; another session is refused, counted and said). A command flagged ``STATE_STOP`` (the node is
disarmed) sends NaN (motors stopped) whatever its speeds, and the bridge then disarms PX4.

Failsafes, each said on stderr and in the plant status the node reads (the node's director disarms,
:meth:`omnirotor.fly.director.FlightDirector.plant_failsafe`):

* **PX4 stopped obeying**: PX4 was armed in offboard for this node and then left offboard (its own failsafe, a
  pilot taking over, ``COM_OF_LOSS_T``) or disarmed. PX4 then ignores ``ActuatorMotors``: the bridge stops sending
  them and the heartbeat, sends no disarm (a pilot may be flying), and reports ``FAILSAFE_ROBOT`` until the node
  disarms (its next ``STATE_STOP`` command), after which a new arming may begin.
* **Command loss**: no command obeyed for ``command_loss_s`` (0.5 s) while armed: NaN to every motor, the
  heartbeat stops (PX4's own offboard-loss failsafe follows) and PX4 is disarmed; the pairing is released.

Time stamps to PX4 are this process's monotonic clock in microseconds (PX4's bridge time-syncs; a bridge on a
robot without time sync should use PX4's ``timesync_status``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import sys
import threading
import time
from collections.abc import Callable

import numpy as np

from omnirotor.errors import InputError
from omnirotor.fly.px4 import (
    NUM_CONTROLS,
    Px4Offboard,
    actuator_motors_msg,
    controls_from_speeds,
    reversible_flags,
)
from omnirotor.rosmsg import typestore
from omnirotor.rosmsg.convert import COMMAND, COMMAND_ARMED, SIM_STATUS, command_check, set_stamp
from omnirotor.sitl.gate import CommandGate
from omnirotor.sitl.server import TOPICS
from omnirotor.transport import Transport

__all__ = ["BridgeOptions", "Px4Bridge", "PX4_TOPICS", "NAV_OFFBOARD", "ARMING_ARMED"]

PX4_TOPICS = {
    "actuator_motors": "/fmu/in/actuator_motors",
    "offboard_control_mode": "/fmu/in/offboard_control_mode",
    "vehicle_command": "/fmu/in/vehicle_command",
    "vehicle_status": "/fmu/out/vehicle_status",
}
"""PX4's topics over its Zenoh bridge (:data:`omnirotor.fly.px4.PX4_PROFILE`), before PX4's namespace."""
_PX4_TYPES = {
    "actuator_motors": "px4_msgs/msg/ActuatorMotors",
    "offboard_control_mode": "px4_msgs/msg/OffboardControlMode",
    "vehicle_command": "px4_msgs/msg/VehicleCommand",
    "vehicle_status": "px4_msgs/msg/VehicleStatus",
}
NAV_OFFBOARD = 14
"""``VehicleStatus.nav_state`` of PX4's offboard mode."""
ARMING_ARMED = 2
"""``VehicleStatus.arming_state`` armed."""
FAILSAFE_NONE, FAILSAFE_COMMAND_LOSS, FAILSAFE_ROBOT = 0, 1, 2
"""``SimStatus.failsafe`` values the bridge reports (the plant status the node reads)."""


@dataclasses.dataclass(frozen=True)
class BridgeOptions:
    """How the bridge runs.

    Attributes:
        command_loss_s: no command obeyed for this long while armed stops the motors and disarms PX4 [s].
        heartbeat_hz: OffboardControlMode rate [Hz] (PX4 wants 2 Hz or more).
        lead_s: heartbeat time before the switch to offboard [s].
        status_hz: plant status rate [Hz].
    """

    command_loss_s: float = 0.5
    heartbeat_hz: float = 10.0
    lead_s: float = 1.0
    status_hz: float = 20.0

    def __post_init__(self) -> None:
        for name in ("command_loss_s", "heartbeat_hz", "lead_s", "status_hz"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a finite number > 0, got {v!r}")


class Px4Bridge:
    """The bridge of the module docstring, for one vehicle.

    Args:
        node: a transport session in the flight node's namespace.
        px4: a transport session in PX4's namespace (may be the same object when both namespaces are equal).
        n_rotors: the vehicle's rotors (at most 12).
        omega_min_hz: the vehicle's smallest speed [Hz] (negative: reversible motors).
        omega_max_hz: its largest speed [Hz] (the full scale of a control).
        options: timing.
        say: where one-line notices go (stderr).
    """

    def __init__(self, node: Transport, px4: Transport, n_rotors: int, omega_min_hz: float, omega_max_hz: float,
                 options: BridgeOptions | None = None, say: Callable[[str], None] | None = None) -> None:  # fmt: skip
        if not 0 < n_rotors <= NUM_CONTROLS:
            raise InputError(f"PX4 drives at most {NUM_CONTROLS} motors, the vehicle has {n_rotors}")
        self.options = o = options if options is not None else BridgeOptions()
        self._say = say if say is not None else (lambda line: print(f"omnirotor px4-bridge: {line}", file=sys.stderr))
        self.n = n_rotors
        self.omega_max_hz = float(omega_max_hz)
        self.flags = reversible_flags(omega_min_hz, n_rotors)
        self._cmd = node.subscriber(TOPICS["rotor_cmd"], COMMAND, depth=64, check=command_check(n_rotors))
        self._pub_status = node.publisher(TOPICS["sim_status"], SIM_STATUS)
        self._pub = {k: px4.publisher(PX4_TOPICS[k], _PX4_TYPES[k]) for k in _PX4_TYPES if k != "vehicle_status"}
        self._vstatus = px4.subscriber(PX4_TOPICS["vehicle_status"], _PX4_TYPES["vehicle_status"], depth=4)
        self.gate = CommandGate("omnirotor px4-bridge")
        self.offboard = Px4Offboard(heartbeat_hz=o.heartbeat_hz, lead_s=o.lead_s)
        self.armed = False  # the node's state, from its last obeyed command
        self.controls = np.full(NUM_CONTROLS, np.nan)
        self.cmd_wall_s = -math.inf
        self.failsafe = FAILSAFE_NONE
        self.cause = ""
        self._flying = False  # PX4 was seen armed in offboard while the node was armed
        self.sent = {"actuator_motors": 0, "offboard_control_mode": 0, "vehicle_command": 0}
        self.stop_with_speeds = 0
        T = typestore().types
        self._status = T[SIM_STATUS](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=""),
            t=0.0, steps=0, lockstep=False, failsafe=0, cause="", paired_session_id=0, commands_obeyed=0,
            commands_held=0, commands_refused=0, foreign_sessions=0, bad_payloads=0, command_age_s=math.inf,
            finished=False,
        )  # fmt: skip
        self._status_next = 0.0

    @staticmethod
    def _now_us() -> int:
        return time.monotonic_ns() // 1000

    def poll(self, timeout_s: float = 0.0) -> None:
        """One turn: PX4's status, the node's commands (each one to PX4 at once), the failsafes, heartbeat, status."""
        vs = self._vstatus.take_latest()
        if vs is not None:
            self._px4_status(int(vs.arming_state) == ARMING_ARMED, int(vs.nav_state) == NAV_OFFBOARD, int(vs.nav_state))
        msg = self._cmd.take(timeout_s)
        while msg is not None:
            if self.gate.offer(int(msg.session_id), int(msg.seq)):
                self._obey(msg)
            msg = self._cmd.take()
        now = time.monotonic()
        if self.armed and self.failsafe == FAILSAFE_NONE and now - self.cmd_wall_s > self.options.command_loss_s:
            self._command_loss(now - self.cmd_wall_s)
        self._offboard(self._now_us())
        self._publish_status(now)

    def _obey(self, msg) -> None:
        armed = int(msg.state) == COMMAND_ARMED
        if not armed and msg.hz.any():
            self.stop_with_speeds += 1
        self.cmd_wall_s = time.monotonic()
        if not armed and self.failsafe != FAILSAFE_NONE:
            self.failsafe, self.cause = FAILSAFE_NONE, ""  # the node disarmed: the incident is over
            self._say("the node disarmed: a new arming may begin")
        self.armed = armed
        if self.failsafe != FAILSAFE_NONE:
            return  # PX4 does not obey now: nothing sent until the node disarms
        controls_from_speeds(msg.hz, self.omega_max_hz, self.controls, stopped=not armed)
        self._send("actuator_motors", actuator_motors_msg(self.controls, self._now_us(), self.flags))

    def _px4_status(self, px4_armed: bool, offboard: bool, nav_state: int) -> None:
        self.offboard.px4_state(px4_armed, offboard)
        if self.armed and px4_armed and offboard:
            self._flying = True
        elif self._flying and self.failsafe == FAILSAFE_NONE:
            self._flying = False
            if self.armed:
                why = "PX4 disarmed" if not px4_armed else f"PX4 left offboard (nav_state {nav_state})"
                self._engage(FAILSAFE_ROBOT, why + ": it ignores the rotor commands")

    def _command_loss(self, age_s: float) -> None:
        self.controls.fill(np.nan)
        self._send("actuator_motors", actuator_motors_msg(self.controls, self._now_us(), self.flags))
        self.armed = False  # the heartbeat stops and PX4 is disarmed (:meth:`_offboard`)
        self._flying = False
        self.gate.release()
        self._engage(FAILSAFE_COMMAND_LOSS, f"no rotor command for {1000 * age_s:.0f} ms: motors stopped, PX4 disarmed")

    def _engage(self, level: int, why: str) -> None:
        self.failsafe, self.cause = level, why
        self._say(why)
        self._publish_status(time.monotonic(), force=True)

    def _offboard(self, t_us: int) -> None:
        if self.failsafe == FAILSAFE_ROBOT:
            return  # no heartbeat, no disarm: PX4 (or its pilot) flies now
        for route, m in self.offboard.period(t_us, self.armed and self.failsafe == FAILSAFE_NONE):
            self._send(route, m)

    def _send(self, route: str, msg) -> None:
        self._pub[route].put(msg)
        self.sent[route] += 1

    def _publish_status(self, now: float, force: bool = False) -> None:
        if not force and now < self._status_next:
            return
        self._status_next = now + 1.0 / self.options.status_hz
        s = self._status
        set_stamp(s.header, now)
        s.t = now
        s.failsafe = self.failsafe
        s.cause = self.cause
        s.paired_session_id = self.gate.paired
        s.commands_obeyed, s.commands_refused = self.gate.obeyed, self.gate.refused
        s.foreign_sessions = self.gate.foreign_sessions
        s.bad_payloads = self._cmd.n_bad
        s.command_age_s = now - self.cmd_wall_s
        self._pub_status.put(s)

    def run(self, stop: threading.Event | None = None) -> dict:
        """Bridge until ``stop`` or Ctrl-C; at the end NaN to every motor and PX4 disarmed if the node had it armed."""
        stop = stop if stop is not None else threading.Event()
        with contextlib.suppress(KeyboardInterrupt):  # Ctrl-C ends the bridging; the motors are stopped below
            while not stop.is_set():
                self.poll(0.02)
        if self.armed and self.failsafe == FAILSAFE_NONE:
            self.controls.fill(np.nan)
            self._send("actuator_motors", actuator_motors_msg(self.controls, self._now_us(), self.flags))
            self.armed = False
            self._offboard(self._now_us())
        return self.summary()

    def summary(self) -> dict:
        """What the bridge counted."""
        return {
            "paired_session_id": f"{self.gate.paired:016x}",
            "commands_obeyed": self.gate.obeyed,
            "commands_refused": self.gate.refused,
            "foreign_sessions": self.gate.foreign_sessions,
            "bad_payloads": self._cmd.n_bad,
            "stop_with_speeds": self.stop_with_speeds,
            "sent": dict(self.sent),
            "failsafe": self.failsafe,
            "cause": self.cause,
            "px4_gave_up": list(self.offboard.gave_up),
        }
