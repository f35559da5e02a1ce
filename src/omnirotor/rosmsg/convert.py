"""The project's messages (:mod:`omnirotor.messages`) in their ROS 2 forms, without loss.

``omnirotor_msgs`` and standard types: every number of ``omnirotor_msgs/msg/SensorFrame`` and ``RotorCommand`` is
float64, so a frame record (:func:`omnirotor.messages.frame_dtype`) sent and received is the same bits (the lockstep
SITL depends on it). The message's ``state`` is the record's state as 21 numbers: ``p_W, v_W, a_W, R_WB``
(row-major), ``omega_B``. Beside the measurements, a frame carries who sent it and its number: ``session_id``
(the plant's session, random per plant process) and ``seq``, as a command carries the node's; both are the wire's,
judged by the receiver before anything is decoded (:mod:`omnirotor.sitl.gate`), so neither is in the frame record
(measurements only, every field float64, read by compiled code) nor in :class:`~omnirotor.messages.SensorFrame`.

The ROS views (``sensor_msgs/msg/Imu``, ``geometry_msgs/msg/PoseStamped``, ``RotorSpeeds``,
``geometry_msgs/msg/WrenchStamped``) are for ROS 2 tools and listeners; the node reads the frame message.
Message objects are built once (:class:`WireMessages`) and refilled every period.
"""

from __future__ import annotations

import math
import struct

import numpy as np

from omnirotor.messages import SensorFrame, StateEstimate, frame_dtype, new_frame
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
    "COMMAND_ARMED",
    "COMMAND_STOP",
    "WireMessages",
    "set_stamp",
    "frame_check",
    "command_check",
    "unpack_frame",
    "FrameCodec",
    "flat_view",
    "WireFrame",
    "FrameWire",
    "FrameEncoder",
    "CommandWire",
    "WireCommand",
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
COMMAND_ARMED = 1
"""``RotorCommand.state``: the node is armed and the speeds are meant to fly (``STATE_ARMED``)."""
COMMAND_STOP = 2
"""``RotorCommand.state``: the node is disarmed (landed, stopped, link lost): a plant flies zeros (``STATE_STOP``)."""

_STATE_SIZE = 21
_P, _V, _A, _R, _OMEGA = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 18), slice(18, 21)
"""The message's ``state`` (21 numbers): the record's state fields in this order (``R_WB`` row-major)."""


def _flat_slices(dtype: np.dtype, base: int = 0, prefix: str = "") -> dict[str, slice]:
    """Every leaf field of an all-float64 record dtype as a slice of its flat float64 view (``a.b`` names)."""
    out = {}
    for name in dtype.names:
        sub, offset = dtype.fields[name][:2]
        start = base + offset // 8
        if sub.names is not None:
            out.update(_flat_slices(sub, start, f"{prefix}{name}."))
        else:
            out[prefix + name] = slice(start, start + sub.itemsize // 8)
    return out


_F = _flat_slices(frame_dtype(1))
_T, _ACC, _GYRO = _F["t"].start, _F["imu.acc_B"], _F["imu.gyro_B"]
_M_NEW, _M_T, _M_P, _M_Q = _F["mocap.new"].start, _F["mocap.t"].start, _F["mocap.p_W"], _F["mocap.q_WB"]
_S_VALID = _F["state.valid"].start
_S_STATE = slice(_F["state.p_W"].start, _F["state.omega_B"].stop)  # p_W, v_W, a_W, R_WB (row-major), omega_B
_HZ_START = _F["rotor_hz"].start
if [_F[k] for k in ("state.p_W", "state.v_W", "state.a_W", "state.R_WB", "state.omega_B")] != [
    slice(_S_STATE.start + s.start, _S_STATE.start + s.stop) for s in (_P, _V, _A, _R, _OMEGA)
]:  # the message's state order is the record's (module docstring)
    raise ImportError("omnirotor.messages' state layout is not the SensorFrame message's")


def flat_view(record: np.ndarray) -> np.ndarray:
    """The flat float64 view of a ``(1,)`` frame record (every field of it is a float64)."""
    return record.view(np.float64)


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
            header=header(frame_id), session_id=0, seq=0, t=0.0, imu_acc_b=z3.copy(), imu_gyro_b=z3.copy(),
            mocap_new=False, mocap_t=0.0, mocap_p_w=z3.copy(), mocap_q_wb=z4.copy(), has_state=False,
            state=np.zeros(_STATE_SIZE), rotor_hz=np.zeros(n_rotors),
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
        self._record: np.ndarray | None = None
        self._flat = np.zeros(0)
        W = T["geometry_msgs/msg/Wrench"]
        self.wrench = T[WRENCH](
            header=header(world_id), wrench=W(force=V3(x=0.0, y=0.0, z=0.0), torque=V3(x=0.0, y=0.0, z=0.0))
        )

    def fill_frame(self, record: np.ndarray, seq: int) -> object:
        """The frame message of a ``(1,)`` frame record (:mod:`omnirotor.messages`), exact; returns :attr:`frame`.

        Its ``session_id`` (the plant's session, not part of the record) is left as the caller set it.
        """
        if record is not self._record:  # the plant writes the same record every period: its view is kept
            self._record, self._flat = record, flat_view(record)
        x, m = self._flat, self.frame
        m.seq = seq
        m.t = t = float(x[_T])
        set_stamp(m.header, t)
        m.imu_acc_b[:] = x[_ACC]
        m.imu_gyro_b[:] = x[_GYRO]
        m.mocap_new = x[_M_NEW] != 0.0
        m.mocap_t = float(x[_M_T])
        m.mocap_p_w[:] = x[_M_P]
        m.mocap_q_wb[:] = x[_M_Q]
        m.has_state = x[_S_VALID] != 0.0
        m.state[:] = x[_S_STATE]
        m.rotor_hz[:] = x[_HZ_START:]
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
    _unpack(msg, flat_view(out))
    return out


def _unpack(msg, x: np.ndarray) -> None:
    x[_T] = msg.t
    x[_ACC] = msg.imu_acc_b
    x[_GYRO] = msg.imu_gyro_b
    if msg.mocap_new:
        x[_M_NEW] = 1.0
        x[_M_T] = msg.mocap_t
        x[_M_P] = msg.mocap_p_w
        x[_M_Q] = msg.mocap_q_wb
    else:  # the record's convention: no sample, its entries zero
        x[_M_NEW : _M_Q.stop] = 0.0
    if msg.has_state:
        x[_S_VALID] = 1.0
        x[_S_STATE] = msg.state
    else:
        x[_S_VALID : _S_STATE.stop] = 0.0
    x[_HZ_START:] = msg.rotor_hz


_SET = {name: SensorFrame.__dict__[name].__set__ for name in ("t", "mocap_new", "mocap_t", "mocap_p_W", "mocap_q_WB",
                                                               "state")}  # fmt: skip


class FrameCodec:
    """One vehicle's frame record and :class:`SensorFrame`, refilled from each frame message in place.

    Args:
        n_rotors: the vehicle's rotors.
        record: a ``(1,)`` frame record to view (e.g. the simulator's own, which its step rewrites; then
            :meth:`refresh` gives its frame); None: a new one.

    :meth:`decode` writes the message into :attr:`record` (slices of its flat float64 view, computed once) and
    returns :attr:`frame`: a frame whose arrays are views of that record and whose scalar slots are set in place,
    so a period builds no frame object and copies no record. It is valid until the next :meth:`decode`: a
    consumer keeps copies (as the flight director and the controller do), never the frame.
    """

    def __init__(self, n_rotors: int, record: np.ndarray | None = None) -> None:
        self.record = new_frame(n_rotors) if record is None else record
        self._x = x = flat_view(self.record)
        self._p, self._q = x[_M_P], x[_M_Q]
        self.frame = SensorFrame(0.0, x[_ACC], x[_GYRO], x[_HZ_START:])
        SensorFrame.__dict__["record"].__set__(self.frame, self.record)

    def decode(self, msg) -> SensorFrame:
        """The frame of a (checked) ``SensorFrame`` message, exact."""
        _unpack(msg, self._x)
        return self.refresh()

    def refresh(self) -> SensorFrame:
        """The frame of :attr:`record` as it is now (after :meth:`decode`, or after its producer wrote it)."""
        x, f, s = self._x, self.frame, _SET
        t = float(x[_T])
        s["t"](f, t)
        new = x[_M_NEW] != 0.0
        s["mocap_new"](f, bool(new))
        s["mocap_t"](f, float(x[_M_T]) if new else 0.0)
        s["mocap_p_W"](f, self._p if new else None)
        s["mocap_q_WB"](f, self._q if new else None)
        if x[_S_VALID] != 0.0:  # bypass studies only: a state object per frame
            st = self.record[0]["state"]
            s["state"](f, StateEstimate(t, st["p_W"], st["v_W"], st["a_W"], st["R_WB"], st["omega_B"]))
        else:
            s["state"](f, None)
        return f


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


# -- the hot path's two messages without rosbags' objects (issue 24 item 5) -----------------------------------------
#
# CDR (plain, little-endian: the encapsulation header 00 01) aligns each number to its own size, counted from the
# byte after the 4-byte header. ``std_msgs/Header`` is int32 sec, uint32 nanosec, then frame_id as a uint32 length
# (the NUL included) and its bytes; everything after it is at fixed offsets from the first 8-aligned byte after the
# string. The layouts below are those of the .msg files (tested against rosbags' serialiser, byte for byte).


def _align8(i: int) -> int:
    return (i + 7) & ~7


class WireFrame:
    """A ``SensorFrame`` read in place from its CDR payload: the fields :func:`_unpack` and the node read.

    The arrays are views of the payload (float64, read-only): valid as long as the object is; the numbers are the
    payload's bits, the same as rosbags' deserialiser gives (tested).
    """

    __slots__ = ("session_id", "seq", "t", "imu_acc_b", "imu_gyro_b", "mocap_new", "mocap_t", "mocap_p_w", "mocap_q_wb",
                 "has_state", "state", "rotor_hz")  # fmt: skip


class FrameWire:
    """Decodes ``SensorFrame`` payloads of ``n_rotors`` rotors without rosbags' objects (:class:`WireFrame`).

    :meth:`decode` takes the payloads of this machine's byte order whose layout is exactly the message's with
    ``n_rotors`` speeds (any ``frame_id``), and returns None for anything else, which the caller then gives to
    rosbags' deserialiser (that decides whether it is malformed): a payload is never accepted here that rosbags
    would refuse, and what is accepted reads the same numbers.
    """

    def __init__(self, n_rotors: int) -> None:
        self.n = n_rotors
        self._little = np.little_endian
        self._ids = struct.Struct("<QQ")

    def decode(self, payload: bytes) -> WireFrame | None:
        """The frame in ``payload``, or None (not the fast layout: ask rosbags)."""
        size = len(payload)
        if size < 16 or payload[0] != 0 or payload[1] != 1 or not self._little:
            return None
        length = int.from_bytes(payload[12:16], "little")  # frame_id's, its NUL included (rosbags checks it)
        if length < 1 or 16 + length > size or payload[15 + length] != 0:
            return None
        a = 4 + _align8(12 + length)  # session_id's offset in the payload
        n = self.n
        end = a + 328 + 8 * n
        if not end <= size <= end + 3 or int.from_bytes(payload[a + 320 : a + 324], "little") != n:
            return None
        try:
            payload[16 : 15 + length].decode()
        except UnicodeDecodeError:
            return None
        f = np.frombuffer(payload, np.float64, (end - a) // 8, a)
        m = WireFrame()
        m.session_id, m.seq = self._ids.unpack_from(payload, a)
        m.t = float(f[2])
        m.imu_acc_b, m.imu_gyro_b = f[3:6], f[6:9]
        m.mocap_new = payload[a + 72] != 0
        m.mocap_t = float(f[10])
        m.mocap_p_w, m.mocap_q_wb = f[11:14], f[14:18]
        m.has_state = payload[a + 144] != 0
        m.state = f[19:40]
        m.rotor_hz = f[41:]
        return m


class FrameEncoder:
    """``SensorFrame`` payloads of a frame record, written in place (the simulator's side of :class:`FrameWire`).

    The payload is rosbags' serialisation of :meth:`WireMessages.fill_frame`'s message (``frame_id``
    ``base_link``), its numbers then overwritten from the record's flat view at their offsets: the same bytes as
    rosbags gives for the same frame (tested), without a message object per period.

    Args:
        n_rotors: the vehicle's rotors.
        frame_id: the header's frame.
        session_id: the plant's session (``SensorFrame.session_id``, written once: :attr:`session_id`).
    """

    def __init__(self, n_rotors: int, frame_id: str = "base_link", session_id: int = 0) -> None:
        store = typestore()
        body = bytes(store.serialize_cdr(WireMessages(n_rotors, frame_id).frame, FRAME))
        self.buf = bytearray(body)
        a = 4 + _align8(12 + len(frame_id.encode()) + 1)  # session_id's offset
        if a + 328 + 8 * n_rotors != len(self.buf):
            raise RuntimeError("SensorFrame's CDR layout is not the one FrameEncoder writes")
        f = np.frombuffer(self.buf, np.float64, 41 + n_rotors, a)
        self._t, self._imu, self._mocap, self._state, self._hz = f[2:3], f[3:9], f[10:18], f[19:40], f[41:]
        self._new_at, self._valid_at, self._session_at, self._seq_at = a + 72, a + 144, a, a + 8
        order = "<" if np.little_endian else ">"
        self._stamp = struct.Struct(order + "iI")
        self._seq = struct.Struct(order + "Q")
        self._record: np.ndarray | None = None
        self._x = np.zeros(0)
        self.session_id = session_id

    @property
    def session_id(self) -> int:
        """The plant session every payload carries."""
        return self._seq.unpack_from(self.buf, self._session_at)[0]

    @session_id.setter
    def session_id(self, value: int) -> None:
        self._seq.pack_into(self.buf, self._session_at, value)

    def encode(self, record: np.ndarray, seq: int) -> bytes:
        """The payload of the ``(1,)`` frame record ``record`` as frame number ``seq`` (as :meth:`fill_frame`)."""
        if record is not self._record:
            self._record, self._x = record, flat_view(record)
        x, buf = self._x, self.buf
        t = float(x[_T])
        if not (t >= 0.0) or math.isinf(t):
            sec = nanosec = 0
        else:
            sec = int(t)
            nanosec = min(int((t - sec) * 1e9), 999_999_999)
            sec = min(sec, 2**31 - 1)
        self._stamp.pack_into(buf, 4, sec, nanosec)
        self._seq.pack_into(buf, self._seq_at, seq)
        self._t[0] = t
        self._imu[:] = x[_ACC.start : _GYRO.stop]
        new = x[_M_NEW] != 0.0
        buf[self._new_at] = 1 if new else 0
        self._mocap[:] = x[_M_T : _M_Q.stop]
        buf[self._valid_at] = 1 if x[_S_VALID] != 0.0 else 0
        self._state[:] = x[_S_STATE]
        self._hz[:] = x[_HZ_START:]
        return bytes(buf)


class WireCommand:
    """A ``RotorCommand`` read in place from its CDR payload (:meth:`CommandWire.decode`); ``hz`` views it."""

    __slots__ = ("t", "hz", "control_status", "state", "session_id", "seq", "frame_seq")


class CommandWire:
    """A ``RotorCommand`` payload of ``n_rotors`` speeds kept as bytes and updated in place, field by field.

    The payload is rosbags' serialisation of a template command (so the layout is rosbags' own, and
    ``frame_id`` stays), its numbers then overwritten at their offsets: the same bytes as rosbags' serialiser gives
    for the same fields (tested), without building or walking a message object per period.
    """

    def __init__(self, n_rotors: int, frame_id: str = "base_link") -> None:
        store = typestore()
        T = store.types
        stamp = T["builtin_interfaces/msg/Time"](sec=0, nanosec=0)
        cmd = T[COMMAND](
            header=T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id),
            t=0.0, hz=np.zeros(n_rotors), control_status=0, state=0, session_id=0, seq=0, frame_seq=0,
        )  # fmt: skip
        body = bytes(store.serialize_cdr(cmd, COMMAND, little_endian=np.little_endian))
        self.buf = bytearray(body)
        a = 4 + _align8(12 + len(frame_id.encode()) + 1)  # t's offset
        hz = a + 16
        tail = hz + 8 * n_rotors
        self._floats = np.frombuffer(self.buf, np.float64, 2 + n_rotors, a)  # t, (hz's length), hz
        self._hz = self._floats[2:]
        self.n = n_rotors
        self._status_at, self._state_at, self._ids_at = tail, tail + 4, _align8(tail + 5 - 4) + 4
        if self._ids_at + 24 != len(self.buf):
            raise RuntimeError("RotorCommand's CDR layout is not the one CommandWire writes")
        order = "<" if np.little_endian else ">"
        self._stamp = struct.Struct(order + "iI")
        self._status = struct.Struct(order + "IB")
        self._ids = struct.Struct(order + "QQQ")
        self._seq = struct.Struct(order + "Q")

    def fill(self, hz: np.ndarray, t: float, control_status: int, state: int, session_id: int, seq: int,
             frame_seq: int) -> bytes:  # fmt: skip
        """The payload of these fields (header stamp from ``t``, as :func:`set_stamp`)."""
        if not (t >= 0.0) or math.isinf(t):
            sec, nanosec = 0, 0
        else:
            sec = int(t)
            nanosec = min(int((t - sec) * 1e9), 999_999_999)
            sec = min(sec, 2**31 - 1)
        buf = self.buf
        self._stamp.pack_into(buf, 4, sec, nanosec)
        self._floats[0] = t
        self._hz[:] = hz
        self._status.pack_into(buf, self._status_at, control_status, state)
        self._ids.pack_into(buf, self._ids_at, session_id, seq, frame_seq)
        return bytes(buf)

    def decode(self, payload: bytes) -> WireCommand | None:
        """The command in ``payload`` if it has this object's layout, else None (then rosbags decides).

        The layout: this machine's byte order, ``n_rotors`` speeds, any ``frame_id``. The simulator's fast path, as
        :meth:`FrameWire.decode` is the node's: it never accepts what rosbags refuses, and reads the same numbers.
        """
        size = len(payload)
        if size < 16 or payload[0] != 0 or payload[1] != 1 or not np.little_endian:
            return None
        length = int.from_bytes(payload[12:16], "little")
        if length < 1 or 16 + length > size or payload[15 + length] != 0:
            return None
        a = 4 + _align8(12 + length)  # t's offset
        n = self.n
        tail = a + 16 + 8 * n
        ids = _align8(tail + 5 - 4) + 4
        if not ids + 24 <= size <= ids + 27 or int.from_bytes(payload[a + 8 : a + 12], "little") != n:
            return None
        try:
            payload[16 : 15 + length].decode()
        except UnicodeDecodeError:
            return None
        m = WireCommand()
        f = np.frombuffer(payload, np.float64, 2 + n, a)
        m.t = float(f[0])
        m.hz = f[2:]
        m.control_status, m.state = self._status.unpack_from(payload, tail)
        m.session_id, m.seq, m.frame_seq = self._ids.unpack_from(payload, ids)
        return m

    def with_seq(self, seq: int) -> bytes:
        """The last payload again with another ``seq``."""
        self._seq.pack_into(self.buf, self._ids_at + 8, seq)
        return bytes(self.buf)
