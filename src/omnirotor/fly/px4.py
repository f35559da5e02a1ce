"""The PX4 profile of the flight node: offboard direct actuator control of reversible motors (docs/fly.md).

The paper's robot commands its rotor speeds straight to the ESCs; on a PX4 vehicle (v1.18) the node sends
``px4_msgs/msg/ActuatorMotors`` in offboard mode with ``direct_actuator`` set, and PX4's output module maps
each control to the ESC. This module holds that mapping and the topic names.

Mapping. ``ActuatorMotors.control[i]`` is a *normalised thrust* in [-1, 1] (PX4: 1 is the largest positive
thrust, -1 the largest negative one of a reversible motor, NaN stops the motor). The vehicle's thrust model
(SPEC §1.2) is ``f_i = c_f |ω_i| ω_i``, so the normalised thrust of a speed ω [Hz] is

    control = |ω| ω / ω_max²        (ω_max = vehicle.omega_max_hz; clipped to [-1, 1])

and the inverse ``ω = sign(control) ω_max sqrt(|control|)``. PX4's output module then inverts its own thrust
model ``control = f x² + (1 - f) x`` (``THR_MDL_FAC`` = f, symmetric in the sign for a reversible motor) to get
the ESC signal x in [-1, 1] (:func:`esc_signal_from_control`). With **THR_MDL_FAC = 1** and ESCs that run a
closed speed loop whose full scale is ω_max (e.g. DShot with RPM telemetry, or an ESC in RPM mode),
``x = ω / ω_max``: the ESC receives exactly the commanded speed, as the paper's robot does. Another
``THR_MDL_FAC`` means PX4 assumes another thrust curve than the one the controller was identified with;
keep 1 and let the ESC close the speed loop. The motors must be configured reversible in PX4 (3D mode /
``reversible_flags``): a negative control to a non-reversible motor stops it.

Frames. PX4's body frame is FRD and its world NED; ours FLU and NWU (:mod:`omnirotor.px4.frames`,
``D = diag(1, -1, -1)``): PX4's rotor axes (``CA_ROTORi_AX..AZ``) must be D times ours, so that a positive
control is thrust along our rotor axis ``z_i``. ESC telemetry (``EscStatus``) gives signed RPM per motor:
``rotor_hz = esc_rpm / 60`` in the motor order of ``actuator_function`` (Motor1 = 101).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from omnirotor.errors import InputError

__all__ = [
    "NUM_CONTROLS",
    "Px4Route",
    "PX4_PROFILE",
    "controls_from_speeds",
    "speeds_from_controls",
    "esc_signal_from_control",
    "reversible_flags",
    "rotor_hz_from_esc_status",
    "imu_from_sensor_combined",
    "pose_from_vehicle_odometry",
    "actuator_motors_msg",
    "offboard_control_mode_msg",
    "vehicle_command_msg",
    "Px4Offboard",
    "VEHICLE_CMD_DO_SET_MODE",
    "VEHICLE_CMD_COMPONENT_ARM_DISARM",
    "PX4_CUSTOM_MAIN_MODE_OFFBOARD",
]

NUM_CONTROLS = 12
"""Controls in one ``ActuatorMotors`` (PX4's ``NUM_CONTROLS``)."""
MOTOR1 = 101
"""PX4's ``actuator_function`` of Motor1 (``ACTUATOR_FUNCTION_MOTOR1``)."""
VEHICLE_CMD_DO_SET_MODE = 176
"""``VehicleCommand.command``: set the mode (param1 base mode flags, param2 PX4's custom main mode)."""
VEHICLE_CMD_COMPONENT_ARM_DISARM = 400
"""``VehicleCommand.command``: arm (param1 = 1) or disarm (param1 = 0)."""
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
"""MAVLink's base-mode flag saying param2 is the autopilot's own (custom) mode."""
PX4_CUSTOM_MAIN_MODE_OFFBOARD = 6
"""PX4's custom main mode number of *Offboard*."""


@dataclasses.dataclass(frozen=True)
class Px4Route:
    """One topic of the PX4 profile: the node's topic, PX4's, the type, and which way it flows.

    Attributes:
        node_topic: the flight node's topic (SITL profile), or "" if the route exists only with PX4.
        px4_topic: PX4's topic over its Zenoh bridge (``fmu/in/...`` PX4 subscribes, ``fmu/out/...`` publishes).
        msgtype: the ROS 2 type on PX4's side.
        to_px4: True if the node publishes it to PX4.
        what: what it carries and how the node uses it.
    """

    node_topic: str
    px4_topic: str
    msgtype: str
    to_px4: bool
    what: str


PX4_PROFILE: tuple[Px4Route, ...] = (
    Px4Route("/omnirotor/imu", "/fmu/out/sensor_combined", "px4_msgs/msg/SensorCombined", False,
             "IMU at the rate PX4 publishes it (set it to 1 kHz): gyro_rad, accelerometer_m_s2 (FRD -> FLU)"),
    Px4Route("/omnirotor/rotor_speeds", "/fmu/out/esc_status", "px4_msgs/msg/EscStatus", False,
             "measured rotor speeds: esc[i].esc_rpm / 60 [Hz], signed (the observer's input)"),
    Px4Route("/omnirotor/rotor_cmd", "/fmu/in/actuator_motors", "px4_msgs/msg/ActuatorMotors", True,
             "the command: normalised thrust |w| w / w_max^2 per motor, NaN stops (module docstring)"),
    Px4Route("", "/fmu/in/offboard_control_mode", "px4_msgs/msg/OffboardControlMode", True,
             "direct_actuator = true, at 10 Hz while the node commands (PX4's offboard proof of life; Px4Offboard)"),
    Px4Route("", "/fmu/in/vehicle_command", "px4_msgs/msg/VehicleCommand", True,
             "the switch to offboard mode (DO_SET_MODE 1, 6), then arm; disarm (COMPONENT_ARM_DISARM; Px4Offboard)"),
    Px4Route("/omnirotor/mocap", "/fmu/in/vehicle_mocap_odometry", "px4_msgs/msg/VehicleOdometry", True,
             "motion capture for PX4's own estimator and failsafes (NWU -> NED): the mocap driver's, to PX4"),
    Px4Route("", "/fmu/out/vehicle_odometry", "px4_msgs/msg/VehicleOdometry", False,
             "PX4's own estimate; the frames' motion capture with px4-bridge --mocap odometry (NED -> NWU)"),
    Px4Route("", "/fmu/out/vehicle_status", "px4_msgs/msg/VehicleStatus", False,
             "PX4's arming and navigation state: outside offboard PX4 ignores actuator_motors"),
)  # fmt: skip
"""The node's topics and PX4's names over its Zenoh bridge (docs/fly.md, "PX4")."""


def reversible_flags(omega_min_hz: float, n_rotors: int) -> int:
    """``ActuatorMotors.reversible_flags``: every motor of a vehicle with negative speeds, else none."""
    return (1 << n_rotors) - 1 if omega_min_hz < 0.0 else 0


def controls_from_speeds(
    omega_hz: np.ndarray, omega_max_hz: float, out: np.ndarray | None = None, *, stopped: bool = False
) -> np.ndarray:
    """``ActuatorMotors.control`` of the commanded speeds (module docstring).

    Args:
        omega_hz: (n,) signed rotor speeds [Hz], n <= 12.
        omega_max_hz: the vehicle's largest speed [Hz] (full scale).
        out: optional (12,) array to write into (the 1 kHz path allocates nothing).
        stopped: the node stops the rotors (disarmed, link lost): every control NaN, as PX4 expects.

    Returns:
        (12,) controls in [-1, 1]; NaN for motors beyond n and for a non-finite speed (stop, never a guess).
    """
    n = len(omega_hz)
    if out is None:
        out = np.empty(NUM_CONTROLS)
    out.fill(np.nan)
    if stopped:
        return out
    c = out[:n]
    np.multiply(np.abs(omega_hz), omega_hz, out=c)
    c *= 1.0 / (omega_max_hz * omega_max_hz)
    np.clip(c, -1.0, 1.0, out=c)
    return out


def speeds_from_controls(control: np.ndarray, omega_max_hz: float, n_rotors: int) -> np.ndarray:
    """The speeds [Hz] (n,) an ``ActuatorMotors.control`` commands: the inverse of :func:`controls_from_speeds`.

    NaN (a stopped motor) gives 0 Hz.
    """
    c = np.nan_to_num(np.asarray(control, dtype=float)[:n_rotors], nan=0.0)
    return np.sign(c) * omega_max_hz * np.sqrt(np.abs(c))


def esc_signal_from_control(control: np.ndarray, thrust_factor: float) -> np.ndarray:
    """The ESC signal x PX4's output module sends for a control (its thrust model, ``THR_MDL_FAC`` = f).

    Solves ``|control| = f x² + (1 - f) |x|`` for x with the sign of the control (a reversible motor); f = 0
    is linear. With f = 1, ``x = sign(c) sqrt(|c|)``: for our controls, ``ω / ω_max``.
    """
    c = np.asarray(control, dtype=float)
    if not 0.0 <= thrust_factor <= 1.0:
        raise InputError(f"THR_MDL_FAC must be in [0, 1], got {thrust_factor}")
    if thrust_factor == 0.0:
        return c.copy()
    a, b = thrust_factor, 1.0 - thrust_factor
    h = b / (2.0 * a)
    return np.sign(c) * (np.sqrt(h * h + np.abs(c) / a) - h)


def rotor_hz_from_esc_status(msg: Any, n_rotors: int, out: np.ndarray | None = None) -> np.ndarray:
    """Measured rotor speeds [Hz] (n,) from a ``px4_msgs/msg/EscStatus``: ``esc_rpm / 60`` by motor number.

    A motor without a report (or an ESC not online) reads NaN: the controller's frame supervision rejects it
    and uses the command instead.
    """
    if out is None:
        out = np.empty(n_rotors)
    out.fill(np.nan)
    online = int(msg.esc_online_flags)
    for k in range(min(int(msg.esc_count), len(msg.esc))):
        report = msg.esc[k]
        i = int(report.actuator_function) - MOTOR1
        if 0 <= i < n_rotors and online & (1 << k):
            out[i] = report.esc_rpm / 60.0
    return out


def imu_from_sensor_combined(
    msg: Any, acc_out: np.ndarray | None = None, gyro_out: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``(acc_B [m/s²], gyro_B [rad/s])`` in our FLU body frame from a ``px4_msgs/msg/SensorCombined`` (FRD).

    Values are passed as they are (NaN included: the controller's frame supervision judges them).

    Args:
        msg: the message.
        acc_out: optional (3,) float64 array to write the specific force into.
        gyro_out: optional (3,) float64 array to write the angular rate into.
    """
    from omnirotor.px4.frames import vec_from_px4

    return vec_from_px4(msg.accelerometer_m_s2, acc_out), vec_from_px4(msg.gyro_rad, gyro_out)


def pose_from_vehicle_odometry(msg: Any, p_out: np.ndarray, q_out: np.ndarray) -> float:
    """The pose of a ``px4_msgs/msg/VehicleOdometry`` in our frames; returns its sample time [s] on PX4's clock.

    ``position`` (NED, or PX4's FRD world: z down either way) -> ``p_W`` (z up), ``q`` (FRD body -> that world,
    wxyz) -> ``q_WB`` (FLU body -> z-up world) by :mod:`omnirotor.px4.frames`. The time is ``timestamp_sample``
    (``timestamp`` when PX4 leaves it 0) in µs since PX4's boot. NaN (PX4: "not valid") passes as it is.

    Args:
        msg: the message.
        p_out: (3,) float64 array the position [m] is written into.
        q_out: (4,) float64 array the attitude (wxyz) is written into.
    """
    from omnirotor.px4.frames import quat_from_px4, vec_from_px4

    vec_from_px4(msg.position, p_out)
    quat_from_px4(msg.q, q_out)
    return 1e-6 * int(msg.timestamp_sample or msg.timestamp)


def actuator_motors_msg(control: np.ndarray, timestamp_us: int, flags: int, timestamp_sample_us: int = 0) -> Any:
    """A ``px4_msgs/msg/ActuatorMotors`` message object (rosbags) carrying ``control`` (12,).

    Raises:
        InputError: a control outside [-1, 1] (NaN is allowed: it stops that motor).
    """
    from omnirotor.rosmsg import msg_type

    c = np.asarray(control, dtype=np.float32)
    if c.shape != (NUM_CONTROLS,) or np.any(np.abs(c[np.isfinite(c)]) > 1.0):
        raise InputError(f"ActuatorMotors.control must be {NUM_CONTROLS} values in [-1, 1] or NaN")
    if not (0 <= flags < (1 << 16)) or math.isnan(timestamp_us):
        raise InputError("ActuatorMotors: reversible_flags must fit 16 bits and the time stamp be a number")
    return msg_type("px4_msgs/msg/ActuatorMotors")(
        timestamp=int(timestamp_us), timestamp_sample=int(timestamp_sample_us or timestamp_us),
        reversible_flags=int(flags), control=c,
    )  # fmt: skip


def offboard_control_mode_msg(timestamp_us: int) -> Any:
    """``px4_msgs/msg/OffboardControlMode`` of direct actuator control (PX4's offboard proof of life)."""
    from omnirotor.rosmsg import msg_type

    return msg_type("px4_msgs/msg/OffboardControlMode")(
        timestamp=int(timestamp_us), position=False, velocity=False, acceleration=False, attitude=False,
        body_rate=False, thrust_and_torque=False, direct_actuator=True,
    )  # fmt: skip


def vehicle_command_msg(
    command: int, timestamp_us: int, param1: float = 0.0, param2: float = 0.0, *, target_system: int = 1,
    source_system: int = 1, source_component: int = 1,
) -> Any:  # fmt: skip
    """A ``px4_msgs/msg/VehicleCommand`` from an external component (this node) to PX4's commander.

    Args:
        command: ``VEHICLE_CMD_*``.
        timestamp_us: PX4's time [µs].
        param1: the command's first parameter.
        param2: its second (the others are 0).
        target_system: PX4's MAVLink system id (``MAV_SYS_ID``, 1 by default).
        source_system: the sender's system id.
        source_component: the sender's component id.
    """
    from omnirotor.rosmsg import msg_type

    return msg_type("px4_msgs/msg/VehicleCommand")(
        timestamp=int(timestamp_us), param1=float(param1), param2=float(param2), param3=0.0, param4=0.0,
        param5=0.0, param6=0.0, param7=0.0, command=int(command), target_system=int(target_system),
        target_component=1, source_system=int(source_system), source_component=int(source_component),
        confirmation=0, from_external=True,
    )  # fmt: skip


class Px4Offboard:
    """What the node sends PX4 besides ``ActuatorMotors`` to fly in offboard direct actuator control.

    PX4 (v1.18) accepts the offboard mode only while ``OffboardControlMode`` streams (at 2 Hz or more, here
    ``heartbeat_hz``) and the vehicle is armed only in a mode that allows it; so, per period, :meth:`period` gives
    the messages due: the heartbeat whenever the node commands (or wants to), and on the node's arming the
    switch to offboard (``DO_SET_MODE``: custom main mode 6) once the heartbeat has streamed for
    ``lead_s``, followed by the arming command; on disarming, the disarm command. Commands are repeated every
    ``retry_s`` until the state PX4 reports (:meth:`px4_state`, from ``VehicleStatus``) matches, at most
    ``max_tries`` times.

    Args:
        heartbeat_hz: OffboardControlMode rate [Hz] (>= 2; 10 by default).
        lead_s: heartbeat time before the mode switch [s] (PX4 wants set-points before it switches).
        retry_s: period of a command's repetition until PX4 confirms it [s].
        max_tries: repetitions of a command before it is given up (said in :attr:`gave_up`).
        target_system: PX4's MAVLink system id.
    """

    def __init__(self, heartbeat_hz: float = 10.0, lead_s: float = 1.0, retry_s: float = 0.5, max_tries: int = 10,
                 target_system: int = 1) -> None:  # fmt: skip
        if not (math.isfinite(heartbeat_hz) and heartbeat_hz >= 2.0):
            raise InputError(f"the offboard heartbeat must be at 2 Hz or more (PX4's limit), got {heartbeat_hz}")
        self.heartbeat_every_us = int(1e6 / heartbeat_hz)
        self.lead_us = int(1e6 * lead_s)
        self.retry_us = int(1e6 * retry_s)
        self.max_tries = max_tries
        self.target_system = target_system
        self._next_beat = 0
        self._streaming_since: int | None = None
        self._last_cmd = {VEHICLE_CMD_DO_SET_MODE: -(1 << 62), VEHICLE_CMD_COMPONENT_ARM_DISARM: -(1 << 62)}
        self._tries = dict.fromkeys(self._last_cmd, 0)
        self.px4_armed = False
        self.px4_offboard = False
        self.gave_up: list[str] = []

    def px4_state(self, armed: bool, offboard: bool) -> None:
        """PX4's own state (``VehicleStatus``: arming state armed, navigation state offboard)."""
        self.px4_armed, self.px4_offboard = bool(armed), bool(offboard)

    def _command(self, out: list, t_us: int, command: int, param1: float, param2: float = 0.0) -> None:
        if t_us - self._last_cmd[command] < self.retry_us:
            return
        if self._tries[command] >= self.max_tries:
            name = "mode switch to offboard" if command == VEHICLE_CMD_DO_SET_MODE else "arm/disarm"
            if name not in self.gave_up:
                self.gave_up.append(name)
            return
        self._last_cmd[command] = t_us
        self._tries[command] += 1
        out.append(("vehicle_command", vehicle_command_msg(command, t_us, param1, param2,
                                                           target_system=self.target_system)))  # fmt: skip

    def period(self, t_us: int, armed: bool) -> list[tuple[str, Any]]:
        """The messages due at PX4 time ``t_us`` [µs] when the node is ``armed`` (commands, or wants to).

        Returns:
            ``[(route, message)]`` with route ``"offboard_control_mode"`` or ``"vehicle_command"``
            (:data:`PX4_PROFILE`'s ``/fmu/in/`` topics).
        """
        out: list[tuple[str, Any]] = []
        if armed:
            if self._streaming_since is None:
                self._streaming_since = t_us
                self._next_beat = t_us
            if t_us >= self._next_beat:
                out.append(("offboard_control_mode", offboard_control_mode_msg(t_us)))
                self._next_beat += self.heartbeat_every_us
                if self._next_beat <= t_us:  # a long gap: the cadence restarts from now
                    self._next_beat = t_us + self.heartbeat_every_us
            if t_us - self._streaming_since >= self.lead_us:
                if not self.px4_offboard:
                    self._command(out, t_us, VEHICLE_CMD_DO_SET_MODE, MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                  PX4_CUSTOM_MAIN_MODE_OFFBOARD)  # fmt: skip
                elif not self.px4_armed:
                    self._command(out, t_us, VEHICLE_CMD_COMPONENT_ARM_DISARM, 1.0)
                else:
                    self._tries = dict.fromkeys(self._tries, 0)
        else:
            self._streaming_since = None
            if self.px4_armed:
                self._command(out, t_us, VEHICLE_CMD_COMPONENT_ARM_DISARM, 0.0)
            else:
                self._tries = dict.fromkeys(self._tries, 0)
        return out
