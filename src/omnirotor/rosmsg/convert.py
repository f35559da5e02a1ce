"""The project's messages (:mod:`omnirotor.messages`) in their ROS 2 forms, without loss.

``omnirotor_msgs`` and standard types: every number of ``omnirotor_msgs/msg/SensorFrame`` and ``RotorCommand`` is
float64, so a frame record (:func:`omnirotor.messages.frame_dtype`) sent and received is the same bits (the lockstep
SITL depends on it). The message's ``state`` is the record's state as 21 numbers: ``p_W, v_W, a_W, R_WB``
(row-major), ``omega_B``.

The ROS views (``sensor_msgs/msg/Imu``, ``geometry_msgs/msg/PoseStamped``, ``RotorSpeeds``,
``geometry_msgs/msg/WrenchStamped``) are for ROS 2 tools and listeners; the node reads the frame message.
Message objects are built once (:class:`WireMessages`) and refilled every period.
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor.rosmsg import typestore

__all__ = [
    "FRAME",
    "COMMAND",
    "SPEEDS",
    "SIM_STATUS",
    "LOOP_STATUS",
    "CONTROLLER_LOG",
    "IMU",
    "POSE",
    "WRENCH",
    "STRING",
    "WireMessages",
    "set_stamp",
    "frame_check",
    "command_check",
    "unpack_frame",
]

FRAME = "omnirotor_msgs/msg/SensorFrame"
COMMAND = "omnirotor_msgs/msg/RotorCommand"
SPEEDS = "omnirotor_msgs/msg/RotorSpeeds"
SIM_STATUS = "omnirotor_msgs/msg/SimStatus"
LOOP_STATUS = "omnirotor_msgs/msg/LoopStatus"
CONTROLLER_LOG = "omnirotor_msgs/msg/ControllerLog"
IMU = "sensor_msgs/msg/Imu"
POSE = "geometry_msgs/msg/PoseStamped"
WRENCH = "geometry_msgs/msg/WrenchStamped"
STRING = "std_msgs/msg/String"

_STATE_SIZE = 21
_P, _V, _A, _R, _OMEGA = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 18), slice(18, 21)
"""The message's ``state`` (21 numbers): the record's state fields in this order (``R_WB`` row-major)."""


def set_stamp(header, t: float) -> None:
    """Write ``t`` [s] into ``header.stamp`` (seconds and nanoseconds, rounded down; negative or NaN as 0)."""
    if not (t >= 0.0) or math.isinf(t):
        t = 0.0
    sec = int(t)
    header.stamp.sec = min(sec, 2**31 - 1)
    header.stamp.nanosec = min(int((t - sec) * 1e9), 999_999_999)


class WireMessages:
    """Preallocated ROS 2 messages of one vehicle (``n_rotors``), refilled every period.

    Attributes:
        frame, command, speeds, imu, pose, wrench: message objects (their arrays are written in place).
    """

    def __init__(self, n_rotors: int, frame_id: str = "base_link", world_id: str = "world") -> None:
        T = typestore().types
        self.n_rotors = n_rotors
        Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]

        def header(fid: str):
            return Header(stamp=Time(sec=0, nanosec=0), frame_id=fid)

        z3, z4 = np.zeros(3), np.zeros(4)
        self.frame = T[FRAME](
            header=header(frame_id), seq=0, t=0.0, imu_acc_b=z3.copy(), imu_gyro_b=z3.copy(), mocap_new=False,
            mocap_t=0.0, mocap_p_w=z3.copy(), mocap_q_wb=z4.copy(), has_state=False, state=np.zeros(_STATE_SIZE),
            rotor_hz=np.zeros(n_rotors),
        )  # fmt: skip
        self.command = T[COMMAND](
            header=header(frame_id), t=0.0, hz=np.zeros(n_rotors), control_status=0, state=0, session_id=0, seq=0,
            frame_seq=0,
        )  # fmt: skip
        self.speeds = T[SPEEDS](header=header(frame_id), t=0.0, hz=np.zeros(n_rotors))
        V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
        cov = np.zeros(9)
        self.imu = T[IMU](
            header=header(frame_id), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=cov.copy(),
            angular_velocity=V3(x=0.0, y=0.0, z=0.0), angular_velocity_covariance=cov.copy(),
            linear_acceleration=V3(x=0.0, y=0.0, z=0.0), linear_acceleration_covariance=cov.copy(),
        )  # fmt: skip
        self.imu.orientation_covariance[0] = -1.0  # REP 145: no orientation estimate in this message
        P, Pose = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Pose"]
        self.pose = T[POSE](
            header=header(world_id),
            pose=Pose(position=P(x=0.0, y=0.0, z=0.0), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0)),
        )
        W = T["geometry_msgs/msg/Wrench"]
        self.wrench = T[WRENCH](
            header=header(world_id), wrench=W(force=V3(x=0.0, y=0.0, z=0.0), torque=V3(x=0.0, y=0.0, z=0.0))
        )

    def fill_frame(self, record: np.ndarray, seq: int) -> object:
        """The frame message of a ``(1,)`` frame record (:mod:`omnirotor.messages`), exact; returns :attr:`frame`."""
        m = self.frame
        r = record[0]
        m.seq = seq
        m.t = float(r["t"])
        set_stamp(m.header, m.t)
        imu, mocap, state = r["imu"], r["mocap"], r["state"]
        m.imu_acc_b[:] = imu["acc_B"]
        m.imu_gyro_b[:] = imu["gyro_B"]
        m.mocap_new = bool(mocap["new"] != 0.0)
        m.mocap_t = float(mocap["t"])
        m.mocap_p_w[:] = mocap["p_W"]
        m.mocap_q_wb[:] = mocap["q_WB"]
        m.has_state = bool(state["valid"] != 0.0)
        x = m.state
        x[_P], x[_V], x[_A], x[_R], x[_OMEGA] = (
            state["p_W"],
            state["v_W"],
            state["a_W"],
            state["R_WB"].reshape(9),
            state["omega_B"],
        )
        m.rotor_hz[:] = r["rotor_hz"]
        return m

    def fill_views(self, record: np.ndarray) -> None:
        """The ROS views of a frame record: :attr:`imu`, :attr:`speeds` and (with a sample) :attr:`pose`."""
        r = record[0]
        t = float(r["t"])
        for m in (self.imu, self.speeds):
            set_stamp(m.header, t)
        a, g = self.imu.linear_acceleration, self.imu.angular_velocity
        a.x, a.y, a.z = (float(v) for v in r["imu"]["acc_B"])
        g.x, g.y, g.z = (float(v) for v in r["imu"]["gyro_B"])
        self.speeds.t = t
        self.speeds.hz[:] = r["rotor_hz"]
        mocap = r["mocap"]
        if mocap["new"] != 0.0:
            set_stamp(self.pose.header, float(mocap["t"]))
            p, q = self.pose.pose.position, self.pose.pose.orientation
            p.x, p.y, p.z = (float(v) for v in mocap["p_W"])
            q.w, q.x, q.y, q.z = (float(v) for v in mocap["q_WB"])


def unpack_frame(msg, out: np.ndarray) -> np.ndarray:
    """Write a frame message into the ``(1,)`` frame record ``out``, exact; returns ``out``."""
    r = out[0]
    r["t"] = msg.t
    imu, mocap, state = r["imu"], r["mocap"], r["state"]
    imu["acc_B"] = msg.imu_acc_b
    imu["gyro_B"] = msg.imu_gyro_b
    mocap["new"] = 1.0 if msg.mocap_new else 0.0
    mocap["t"] = msg.mocap_t
    mocap["p_W"] = msg.mocap_p_w
    mocap["q_WB"] = msg.mocap_q_wb
    state["valid"] = 1.0 if msg.has_state else 0.0
    x = msg.state
    state["p_W"], state["v_W"], state["a_W"], state["omega_B"] = x[_P], x[_V], x[_A], x[_OMEGA]
    state["R_WB"] = x[_R].reshape(3, 3)
    r["rotor_hz"] = msg.rotor_hz
    return out


def frame_check(n_rotors: int):
    """A subscriber check: a frame message with one rotor speed per rotor (values are the controller's to judge)."""

    def check(msg) -> bool:
        return msg.rotor_hz.shape == (n_rotors,) and msg.state.shape == (_STATE_SIZE,)

    return check


def command_check(n_rotors: int):
    """A subscriber check: a command with one finite speed per rotor (a non-finite one never reaches a motor)."""

    def check(msg) -> bool:
        hz = msg.hz
        return hz.shape == (n_rotors,) and bool(np.isfinite(hz).all()) and msg.session_id != 0

    return check
