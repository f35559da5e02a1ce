"""The project's messages (:mod:`omnirotor.messages`) in their ROS 2 forms, without loss.

``omnirotor_msgs`` and standard types: every number of ``omnirotor_msgs/msg/SensorFrame`` and ``RotorCommand`` is
float64, so a frame packed, sent and unpacked is the same bits (the lockstep SITL depends on it).

The ROS views (``sensor_msgs/msg/Imu``, ``geometry_msgs/msg/PoseStamped``, ``RotorSpeeds``,
``geometry_msgs/msg/WrenchStamped``) are for ROS 2 tools and listeners; the node reads the frame message.
Message objects are built once (:class:`WireMessages`) and refilled every period.
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor.messages import (
    FRAME_ACC_B,
    FRAME_GYRO_B,
    FRAME_HAS_STATE,
    FRAME_MOCAP_NEW,
    FRAME_MOCAP_P_W,
    FRAME_MOCAP_Q_WB,
    FRAME_MOCAP_T,
    FRAME_ROTOR_HZ,
    FRAME_STATE,
    FRAME_T,
    frame_size,
)
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

    def fill_frame(self, packed: np.ndarray, seq: int) -> object:
        """The frame message of a packed frame (:mod:`omnirotor.messages`), exact; returns :attr:`frame`."""
        m = self.frame
        m.seq = seq
        m.t = float(packed[FRAME_T])
        set_stamp(m.header, m.t)
        m.imu_acc_b[:] = packed[FRAME_ACC_B : FRAME_ACC_B + 3]
        m.imu_gyro_b[:] = packed[FRAME_GYRO_B : FRAME_GYRO_B + 3]
        m.mocap_new = bool(packed[FRAME_MOCAP_NEW] != 0.0)
        m.mocap_t = float(packed[FRAME_MOCAP_T])
        m.mocap_p_w[:] = packed[FRAME_MOCAP_P_W : FRAME_MOCAP_P_W + 3]
        m.mocap_q_wb[:] = packed[FRAME_MOCAP_Q_WB : FRAME_MOCAP_Q_WB + 4]
        m.has_state = bool(packed[FRAME_HAS_STATE] != 0.0)
        m.state[:] = packed[FRAME_STATE : FRAME_STATE + _STATE_SIZE]
        m.rotor_hz[:] = packed[FRAME_ROTOR_HZ:]
        return m

    def fill_views(self, packed: np.ndarray) -> None:
        """The ROS views of a packed frame: :attr:`imu`, :attr:`speeds` and (with a sample) :attr:`pose`."""
        t = float(packed[FRAME_T])
        for m in (self.imu, self.speeds):
            set_stamp(m.header, t)
        a, g = self.imu.linear_acceleration, self.imu.angular_velocity
        a.x, a.y, a.z = (float(v) for v in packed[FRAME_ACC_B : FRAME_ACC_B + 3])
        g.x, g.y, g.z = (float(v) for v in packed[FRAME_GYRO_B : FRAME_GYRO_B + 3])
        self.speeds.t = t
        self.speeds.hz[:] = packed[FRAME_ROTOR_HZ:]
        if packed[FRAME_MOCAP_NEW] != 0.0:
            set_stamp(self.pose.header, float(packed[FRAME_MOCAP_T]))
            p, q = self.pose.pose.position, self.pose.pose.orientation
            p.x, p.y, p.z = (float(v) for v in packed[FRAME_MOCAP_P_W : FRAME_MOCAP_P_W + 3])
            q.w, q.x, q.y, q.z = (float(v) for v in packed[FRAME_MOCAP_Q_WB : FRAME_MOCAP_Q_WB + 4])


def unpack_frame(msg, out: np.ndarray) -> np.ndarray:
    """Write a frame message into the packed layout ``out`` (``frame_size(n)`` entries), exact; returns ``out``."""
    out[FRAME_T] = msg.t
    out[FRAME_ACC_B : FRAME_ACC_B + 3] = msg.imu_acc_b
    out[FRAME_GYRO_B : FRAME_GYRO_B + 3] = msg.imu_gyro_b
    out[FRAME_MOCAP_NEW] = 1.0 if msg.mocap_new else 0.0
    out[FRAME_MOCAP_T] = msg.mocap_t
    out[FRAME_MOCAP_P_W : FRAME_MOCAP_P_W + 3] = msg.mocap_p_w
    out[FRAME_MOCAP_Q_WB : FRAME_MOCAP_Q_WB + 4] = msg.mocap_q_wb
    out[FRAME_HAS_STATE] = 1.0 if msg.has_state else 0.0
    out[FRAME_STATE : FRAME_STATE + _STATE_SIZE] = msg.state
    out[FRAME_ROTOR_HZ:] = msg.rotor_hz
    return out


def frame_check(n_rotors: int):
    """A subscriber check: a frame message with one rotor speed per rotor (values are the controller's to judge)."""
    size = frame_size(n_rotors) - FRAME_ROTOR_HZ

    def check(msg) -> bool:
        return msg.rotor_hz.shape == (size,)

    return check


def command_check(n_rotors: int):
    """A subscriber check: a command with one finite speed per rotor (a non-finite one never reaches a motor)."""

    def check(msg) -> bool:
        hz = msg.hz
        return hz.shape == (n_rotors,) and bool(np.isfinite(hz).all()) and msg.session_id != 0

    return check
