"""ROS 2 bags in and out (rosbags; no ROS installation needed): flights for identification, runs for ROS users.

**In** (:func:`read_bag_flight`): a ROS 2 bag folder (``metadata.yaml`` beside sqlite3 ``.db3`` or ``.mcap``
storage) becomes the :class:`~omnirotor.px4.flight.Flight` a ULog gives, so :mod:`omnirotor.px4.windows` finds
its hover windows the same way. Topics are recognised by their message type, whatever their names; for each
signal the first type present in this order is used (several topics of one type: the first by name, said on
stderr):

=====================  ==========================================================================================
signal                 message types (frames converted with :mod:`~omnirotor.px4.frames`)
=====================  ==========================================================================================
attitude (required)    ``px4_msgs/VehicleAttitude`` (q, FRD → NED); ``px4_msgs/VehicleOdometry`` (pose_frame NED);
                       ``nav_msgs/Odometry``, ``geometry_msgs/PoseStamped`` (ours: body FLU → world z up)
rotor speeds           ``px4_msgs/EscStatus`` (``esc[i].esc_rpm`` / 60); ``omnirotor_msgs/RotorSpeeds`` (hz);
(required)             ``omnirotor_msgs/SensorFrame`` (rotor_hz); ``px4_msgs/ActuatorMotors`` (mapped as a ULog's)
velocity               ``px4_msgs/VehicleLocalPosition`` (NED); ``px4_msgs/VehicleOdometry`` (velocity_frame NED);
                       ``nav_msgs/Odometry`` (twist in the body frame, REP 105); else the poses' positions
                       differentiated
body rate              ``px4_msgs/SensorCombined`` (gyro_rad, FRD); ``sensor_msgs/Imu`` (ours, FLU);
                       ``omnirotor_msgs/SensorFrame`` (imu_gyro_b)
=====================  ==========================================================================================

Times: PX4's ``timestamp`` [µs] for ``px4_msgs``, ``header.stamp`` for the others, measured from the earliest
sample. The message definitions are the bag's own where it stores them (MCAP does), else
:func:`omnirotor.rosmsg.typestore`'s (``px4_msgs`` as PX4 v1.18 defines them).

**Out** (:func:`write_run_rosbag`): a run's signals (:func:`omnirotor.px4.run_export.run_signals`) as a ROS 2 bag
with the types the flight node and the simulator publish (FLY-INTERFACE: ``/omnirotor/imu``
``sensor_msgs/Imu``, ``/omnirotor/mocap`` ``geometry_msgs/PoseStamped``, ``/omnirotor/rotor_speeds``
``omnirotor_msgs/RotorSpeeds``, ``/omnirotor/rotor_cmd`` ``omnirotor_msgs/RotorCommand``,
``/omnirotor/wrench_est`` ``geometry_msgs/WrenchStamped``) plus the estimate as ``nav_msgs/Odometry`` on
``/omnirotor/estimate``. Frames are ours (world z up, body FLU), as on the wire.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from omnirotor.errors import InputError
from omnirotor.px4.flight import Flight, Series
from omnirotor.px4.frames import R_WB_from_px4_quat, vec_from_px4

__all__ = ["is_rosbag", "read_bag_flight", "write_run_rosbag", "BAG_TOPICS"]

BAG_TOPICS = {
    "imu": ("/omnirotor/imu", "sensor_msgs/msg/Imu"),
    "mocap": ("/omnirotor/mocap", "geometry_msgs/msg/PoseStamped"),
    "rotor_speeds": ("/omnirotor/rotor_speeds", "omnirotor_msgs/msg/RotorSpeeds"),
    "rotor_cmd": ("/omnirotor/rotor_cmd", "omnirotor_msgs/msg/RotorCommand"),
    "wrench_est": ("/omnirotor/wrench_est", "geometry_msgs/msg/WrenchStamped"),
    "estimate": ("/omnirotor/estimate", "nav_msgs/msg/Odometry"),
}
"""Topics and types of a run written as a bag."""

_PX4 = "px4_msgs/msg/"


def is_rosbag(path: str | Path) -> bool:
    """True for a ROS 2 bag folder (one holding ``metadata.yaml``)."""
    p = Path(path)
    try:
        return p.is_dir() and (p / "metadata.yaml").is_file()
    except OSError:
        return False


def _quat_wxyz_to_R(q: np.ndarray) -> np.ndarray:
    from omnirotor.so3 import R_from_quat_wxyz

    return np.array([R_from_quat_wxyz(x / np.linalg.norm(x)) for x in q])


def _wxyz(q) -> list[float]:
    return [q.w, q.x, q.y, q.z]


def _xyz(v) -> list[float]:
    return [v.x, v.y, v.z]


def _pose(m):
    """The pose of a PoseStamped or an Odometry message."""
    return m.pose.pose if hasattr(m.pose, "covariance") else m.pose


def _stamp_s(msg) -> float:
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def _read_messages(path: Path) -> tuple[dict[str, list], list[str]]:
    """Every message of the bag by type: type -> [(topic, time [s], msg)], and what was noted."""
    from rosbags.highlevel import AnyReader

    from omnirotor.rosmsg import typestore

    wanted = {
        _PX4 + "VehicleAttitude",
        _PX4 + "VehicleOdometry",
        _PX4 + "VehicleLocalPosition",
        _PX4 + "SensorCombined",
        _PX4 + "EscStatus",
        _PX4 + "ActuatorMotors",
        "nav_msgs/msg/Odometry",
        "geometry_msgs/msg/PoseStamped",
        "sensor_msgs/msg/Imu",
        "omnirotor_msgs/msg/RotorSpeeds",
        "omnirotor_msgs/msg/SensorFrame",
    }
    out: dict[str, list] = {}
    notes: list[str] = []
    try:
        with AnyReader([path], default_typestore=typestore()) as reader:
            by_type: dict[str, list] = {}
            for c in reader.connections:
                if c.msgtype in wanted:
                    by_type.setdefault(c.msgtype, []).append(c)
            chosen = {}
            for msgtype, conns in by_type.items():
                conns = sorted(conns, key=lambda c: c.topic)
                chosen[msgtype] = conns[0]
                if len({c.topic for c in conns}) > 1:
                    notes.append(f"{msgtype}: read {conns[0].topic}, not {', '.join(c.topic for c in conns[1:])}")
            conns = list(chosen.values())
            for c, t_ns, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, c.msgtype)
                if c.msgtype.startswith(_PX4):
                    t = msg.timestamp * 1e-6
                elif hasattr(msg, "header"):
                    t = _stamp_s(msg)
                else:
                    t = t_ns * 1e-9
                out.setdefault(c.msgtype, []).append((t, msg))
    except InputError:
        raise
    except Exception as exc:  # rosbags raises many kinds on corrupt or foreign bags
        raise InputError(f"{path}: not a readable ROS 2 bag ({type(exc).__name__}: {exc})") from None
    return out, notes


def _series(rows: list, fn) -> Series:
    rows = sorted(rows, key=lambda r: r[0])
    return Series(np.array([r[0] for r in rows]), np.array([fn(m) for _, m in rows], dtype=float))


def read_bag_flight(path: str | Path, n_rotors: int | None = None, omega_max_hz: float | None = None) -> Flight:
    """Read what identification needs from a ROS 2 bag (module docstring).

    Raises:
        InputError: not a bag, or no attitude or rotor speeds; the message names everything missing.
    """
    p = Path(path)
    if not is_rosbag(p):
        raise InputError(f"{p}: not a ROS 2 bag folder (no metadata.yaml)")
    msgs, notes = _read_messages(p)
    has = {k for k, v in msgs.items() if len(v) >= 2}
    R = p_W = v_W = omega_B = omega = None
    source = ""
    if _PX4 + "VehicleAttitude" in has:
        s = _series(msgs[_PX4 + "VehicleAttitude"], lambda m: m.q)
        R = Series(s.t, R_WB_from_px4_quat(s.x))
    elif _PX4 + "VehicleOdometry" in has and msgs[_PX4 + "VehicleOdometry"][0][1].pose_frame == 1:
        s = _series(msgs[_PX4 + "VehicleOdometry"], lambda m: m.q)
        R = Series(s.t, R_WB_from_px4_quat(s.x))
    else:
        for kind in ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped"):
            if kind in has:
                q = _series(msgs[kind], lambda m: _wxyz(_pose(m).orientation))
                R = Series(q.t, _quat_wxyz_to_R(q.x))
                p_W = _series(msgs[kind], lambda m: _xyz(_pose(m).position))
                break
    if _PX4 + "EscStatus" in has:
        rows = msgs[_PX4 + "EscStatus"]
        n_esc = max(int(m.esc_count) for _, m in rows) or len(rows[0][1].esc)
        n = n_rotors or n_esc
        if n_esc < n:
            raise InputError(f"{p}: EscStatus reports {n_esc} ESCs, the vehicle has {n} rotors (pass --vehicle)")
        omega = _series(rows, lambda m: [e.esc_rpm / 60.0 for e in m.esc[:n]])
        source = "esc_status"
    elif "omnirotor_msgs/msg/RotorSpeeds" in has:
        omega = _series(msgs["omnirotor_msgs/msg/RotorSpeeds"], lambda m: m.hz[: n_rotors or len(m.hz)])
        source = "rotor_speeds"
    elif "omnirotor_msgs/msg/SensorFrame" in has:
        omega = _series(msgs["omnirotor_msgs/msg/SensorFrame"], lambda m: m.rotor_hz[: n_rotors or len(m.rotor_hz)])
        source = "sensor_frame"
    elif _PX4 + "ActuatorMotors" in has and omega_max_hz is not None:
        n = n_rotors or 12
        c = _series(msgs[_PX4 + "ActuatorMotors"], lambda m: m.control[:n])
        x = np.where(np.isfinite(c.x), c.x, 0.0)
        omega = Series(c.t, np.sign(x) * np.sqrt(np.abs(x)) * omega_max_hz)
        source = "actuator_motors"
        notes.append(
            "no EscStatus in the bag: rotor speeds mapped from ActuatorMotors as "
            f"sign(c) sqrt(|c|) x {omega_max_hz:g} Hz"
        )
    missing = []
    if R is None:
        missing.append("attitude (VehicleAttitude, VehicleOdometry in NED, nav_msgs/Odometry or PoseStamped)")
    if omega is None:
        missing.append("rotor speeds (EscStatus, omnirotor_msgs RotorSpeeds or SensorFrame, or ActuatorMotors)")
    if missing:
        raise InputError(f"{p}: no " + "; no ".join(missing) + " in the bag")
    if _PX4 + "VehicleLocalPosition" in has:
        rows = msgs[_PX4 + "VehicleLocalPosition"]
        p_W = _series(rows, lambda m: vec_from_px4(np.array([m.x, m.y, m.z], dtype=float)))
        v_W = _series(rows, lambda m: vec_from_px4(np.array([m.vx, m.vy, m.vz], dtype=float)))
    elif _PX4 + "VehicleOdometry" in has and msgs[_PX4 + "VehicleOdometry"][0][1].velocity_frame == 1:
        v_W = _series(msgs[_PX4 + "VehicleOdometry"], lambda m: vec_from_px4(np.asarray(m.velocity, dtype=float)))
    elif "nav_msgs/msg/Odometry" in has:
        odo = sorted(msgs["nav_msgs/msg/Odometry"], key=lambda r: r[0])
        v_B = np.array([_xyz(m.twist.twist.linear) for _, m in odo])
        Rs = _quat_wxyz_to_R(np.array([_wxyz(m.pose.pose.orientation) for _, m in odo]))
        v_W = Series(np.array([r[0] for r in odo]), np.einsum("nij,nj->ni", Rs, v_B))
    elif p_W is not None and p_W.t.size > 2:
        v_W = Series(p_W.t, np.gradient(p_W.x, p_W.t, axis=0))
        notes.append("no velocity in the bag: differentiated the poses' positions")
    if _PX4 + "SensorCombined" in has:
        omega_B = _series(msgs[_PX4 + "SensorCombined"], lambda m: vec_from_px4(np.asarray(m.gyro_rad, dtype=float)))
    elif "sensor_msgs/msg/Imu" in has:
        omega_B = _series(msgs["sensor_msgs/msg/Imu"], lambda m: _xyz(m.angular_velocity))
    elif "omnirotor_msgs/msg/SensorFrame" in has:
        omega_B = _series(msgs["omnirotor_msgs/msg/SensorFrame"], lambda m: m.imu_gyro_b)
    t0 = min(s.t[0] for s in (R, omega, p_W, v_W, omega_B) if s is not None)
    shift = [None if s is None else Series(s.t - t0, s.x) for s in (R, omega, p_W, v_W, omega_B)]
    return Flight(p.name, shift[0], shift[1], source, shift[2], shift[3], None, shift[4], None, {}, tuple(notes))


def write_run_rosbag(path: str | Path, signals, vehicle, storage: str = "mcap") -> Path:
    """Write a run's signals as a ROS 2 bag folder (module docstring); ``storage`` "mcap" or "sqlite3".

    The folder is written beside its destination under a temporary name and renamed into place, so a failure
    leaves nothing behind; an existing bag folder at ``path`` is replaced.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer

    from omnirotor.rosmsg import typestore
    from omnirotor.so3 import quat_wxyz_from_R

    plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
    if storage not in plugins:
        raise InputError(f"bag storage {storage!r}: expected mcap or sqlite3")
    dest = Path(path)
    if dest.exists() and not is_rosbag(dest):
        raise InputError(f"{dest}: exists and is not a ROS 2 bag folder; not replaced")
    tmp = dest.with_name(f".{dest.name}.tmp-bag")
    if tmp.exists():
        shutil.rmtree(tmp)
    ts = typestore()
    T = ts.types
    s = signals
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    Pt, Pose = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Pose"]
    Twist, Wrench = T["geometry_msgs/msg/Twist"], T["geometry_msgs/msg/Wrench"]
    zeros9 = np.zeros(9)
    try:
        with Writer(tmp, version=9, storage_plugin=plugins[storage]) as w:
            conn = {k: w.add_connection(topic, msgtype, typestore=ts) for k, (topic, msgtype) in BAG_TOPICS.items()}
            for k in range(s.t.size):
                t = float(s.t[k])
                t_ns = int(round(t * 1e9))
                stamp = Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)
                q = quat_wxyz_from_R(s.R_WB[k])
                quat = Q(x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0]))
                pose = Pose(
                    position=Pt(x=float(s.p_W[k, 0]), y=float(s.p_W[k, 1]), z=float(s.p_W[k, 2])), orientation=quat
                )
                msgs = {
                    "imu": T["sensor_msgs/msg/Imu"](
                        header=Header(stamp=stamp, frame_id="base_link"),
                        orientation=quat,
                        orientation_covariance=zeros9,
                        angular_velocity=V3(*map(float, s.omega_B[k])),
                        angular_velocity_covariance=zeros9,
                        linear_acceleration=V3(*map(float, s.accel_B[k])),
                        linear_acceleration_covariance=zeros9,
                    ),
                    "mocap": T["geometry_msgs/msg/PoseStamped"](
                        header=Header(stamp=stamp, frame_id="world"), pose=pose
                    ),
                    "rotor_speeds": T["omnirotor_msgs/msg/RotorSpeeds"](
                        header=Header(stamp=stamp, frame_id="base_link"), t=t, hz=s.rotor_hz[k].astype(float)
                    ),
                    "rotor_cmd": T["omnirotor_msgs/msg/RotorCommand"](
                        header=Header(stamp=stamp, frame_id="base_link"),
                        t=t,
                        hz=s.omega_cmd_hz[k].astype(float),
                        control_status=int(s.status[k]),
                        state=1,
                        session_id=1,
                        seq=k + 1,
                        frame_seq=k + 1,
                    ),
                    "wrench_est": T["geometry_msgs/msg/WrenchStamped"](
                        header=Header(stamp=stamp, frame_id="world"),
                        wrench=Wrench(
                            force=V3(*map(float, s.f_ext_hat_W[k])), torque=V3(*map(float, s.m_ext_hat_B[k]))
                        ),
                    ),
                    "estimate": T["nav_msgs/msg/Odometry"](
                        header=Header(stamp=stamp, frame_id="world"),
                        child_frame_id="base_link",
                        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                        twist=T["geometry_msgs/msg/TwistWithCovariance"](
                            twist=Twist(
                                linear=V3(*map(float, s.R_WB[k].T @ s.v_W[k])), angular=V3(*map(float, s.omega_B[k]))
                            ),
                            covariance=np.zeros(36),
                        ),
                    ),
                }
                for key, msg in msgs.items():
                    w.write(conn[key], t_ns, ts.serialize_cdr(msg, BAG_TOPICS[key][1]))
        if dest.exists():
            shutil.rmtree(dest)
        tmp.rename(dest)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return dest
