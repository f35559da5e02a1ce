"""Continuous flight recording: every period to a ROS 2 bag (MCAP storage), streamed, in bounded memory.

The 1 kHz loop must neither serialise nor write nor wait on a disk, and a Python thread doing that work
would take the interpreter's lock from it for milliseconds; so the recording runs in **its own process**.
The loop copies each period into one row of a ring of structured records in shared memory
(:meth:`FlightRecorder.period`: field copies, no allocation, never blocks; a full ring drops the row and
counts it) and the writer process drains the ring, builds the ROS 2 messages and appends them to the bag
with rosbags' MCAP writer, which writes each 1 MiB chunk as it fills (memory: the ring, one chunk, and an
index entry of about 100 bytes per chunk). There is no cap on the duration.

The bag (a directory with ``metadata.yaml`` and one ``.mcap``) has the flight node's topics and types, so
rosbags, ``ros2 bag``, Foxglove and the project's bag readers read it:

======================== ====================================== ==============================================
topic                    type                                   what
======================== ====================================== ==============================================
/omnirotor/frame         omnirotor_msgs/msg/SensorFrame         the sensor frame of each period
/omnirotor/rotor_cmd     omnirotor_msgs/msg/RotorCommand        the speeds sent, the controller's status bits
/omnirotor/pose          geometry_msgs/msg/PoseStamped          the state estimate (body, world frame)
/omnirotor/reference     geometry_msgs/msg/PoseStamped          the compliant EE reference
/omnirotor/desired       geometry_msgs/msg/PoseStamped          the desired EE reference
/omnirotor/wrench_est    geometry_msgs/msg/WrenchStamped        the observer's estimate, force and moment in W
/omnirotor/status        omnirotor_msgs/msg/FlightStatus        the director's status (as often as given)
/omnirotor/sim_status    omnirotor_msgs/msg/SimStatus           the plant's status as the node heard it (about
                                                                50 Hz: failsafe, pairing, its IMU watch's counts)
======================== ====================================== ==============================================

The estimate, references and wrench (at 100 Hz by default: ``derived_every``) come from the controller's log
row, found by its column names
(:data:`omnirotor.control.controller.LOG_GROUPS`); a row without those columns records frames, commands
and status only. :func:`read_recording` reads a bag back into arrays.
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing as mp
import queue
import time
from multiprocessing.shared_memory import SharedMemory
from pathlib import Path
from typing import Any

import numpy as np

from omnirotor.errors import InputError
from omnirotor.messages import SensorFrame

__all__ = ["FlightRecorder", "record_dtype", "read_recording", "TOPICS", "column_groups", "check_recording_path"]

TOPICS = {
    "/omnirotor/frame": "omnirotor_msgs/msg/SensorFrame",
    "/omnirotor/rotor_cmd": "omnirotor_msgs/msg/RotorCommand",
    "/omnirotor/pose": "geometry_msgs/msg/PoseStamped",
    "/omnirotor/reference": "geometry_msgs/msg/PoseStamped",
    "/omnirotor/desired": "geometry_msgs/msg/PoseStamped",
    "/omnirotor/wrench_est": "geometry_msgs/msg/WrenchStamped",
    "/omnirotor/status": "omnirotor_msgs/msg/FlightStatus",
    "/omnirotor/sim_status": "omnirotor_msgs/msg/SimStatus",
}
"""The recorded topics and their types (module docstring)."""

_F8 = np.float64
# The log's column groups each derived topic needs: (position, rotation) of a pose, (force, moment, rotation).
_POSES = {"/omnirotor/pose": ("p_W", "R_WB"), "/omnirotor/reference": ("p_E_ref_W", "R_E_ref"),
          "/omnirotor/desired": ("p_E_des_W", "R_E_des")}  # fmt: skip
_WRENCH = ("f_ext_W", "m_ext_B", "R_WB")


def record_dtype(n_rotors: int, n_log: int) -> np.dtype:
    """The ring's record of one period: frame, command, director state and the controller's log row."""
    return np.dtype(
        [
            ("seq", np.int64),  # period counter (the row's index + 1)
            ("plant_session", np.uint64),  # the session of the plant that sent the frame (SensorFrame.session_id)
            ("t", _F8),  # frame time [s]
            ("acc_B", _F8, 3),  # [m/s²]
            ("gyro_B", _F8, 3),  # [rad/s]
            ("mocap_new", np.uint8),
            ("mocap_t", _F8),  # [s]
            ("mocap_p_W", _F8, 3),  # [m]
            ("mocap_q_WB", _F8, 4),  # wxyz
            ("rotor_hz", _F8, n_rotors),  # measured [Hz]
            ("cmd_hz", _F8, n_rotors),  # sent [Hz]
            ("control_status", np.uint32),
            ("armed", np.uint8),  # the command is meant to fly (else: stopped)
            ("has_log", np.uint8),
            ("log", _F8, n_log),  # the controller's log row (its column names given to the recorder)
        ]
    )


def output_options(record: Path | None, foxglove: bool, foxglove_port: int) -> dict:
    """``--record``/``--foxglove``/``--foxglove-port`` of ``fly`` and ``sim --serve``, checked before anything runs.

    Returns:
        ``{"record": path or None, "foxglove_port": port or None}``.

    Raises:
        InputError: a recording path that cannot be a new bag folder, or a port outside 0..65535.
    """
    if record is not None:
        check_recording_path(record, "--record")
    if not 0 <= foxglove_port <= 65535:
        raise InputError(f"--foxglove-port must be in 0..65535, got {foxglove_port}")
    return {"record": str(record) if record is not None else None, "foxglove_port": foxglove_port if foxglove else None}


def check_recording_path(path: str | Path, label: str = "recording") -> Path:
    """A new bag folder's path, checked before anything runs (``--record``).

    Raises:
        InputError: the path exists (a recording is never written over), its folder does not exist or is not
            writable, or the name is not one a folder can have.
    """
    from omnirotor.safe_io import check_output_dir

    path = Path(path)
    check_output_dir(path, label)
    if path.exists() or path.is_symlink():
        raise InputError(f"{label} {path}: exists already; give a new folder name")
    if not path.parent.is_dir():
        raise InputError(f"{label} {path}: folder {path.parent} does not exist")
    return path


class FlightRecorder:
    """Record a flight into the ROS 2 bag ``path`` from a writer process (module docstring).

    Args:
        path: the bag directory to create (must not exist).
        n_rotors: rotors of the vehicle.
        log_columns: column names of the controller's log row (``controller.log.column_names``), or () for none.
        capacity: rows of the ring (at 1 kHz, 4096 rows give the writer 4 s of slack).
        derived_every: the estimate, references and wrench are recorded every this many periods (10: 100 Hz at
            1 kHz; the frames and commands, from which everything can be replayed, every period).

    Raises:
        InputError: the path exists or its parent does not, or the writer process did not start.
    """

    def __init__(
        self, path: str | Path, n_rotors: int, log_columns=(), capacity: int = 4096, derived_every: int = 10
    ) -> None:
        path = check_recording_path(path)
        if isinstance(derived_every, bool) or not isinstance(derived_every, int) or derived_every < 1:
            raise InputError(f"derived_every must be an integer >= 1, got {derived_every!r}")
        self.path = path
        self.capacity = int(capacity)
        self.dtype = record_dtype(n_rotors, len(log_columns))
        self._shm = SharedMemory(create=True, size=self.dtype.itemsize * self.capacity)
        self._ring = np.ndarray((self.capacity,), dtype=self.dtype, buffer=self._shm.buf)
        self._fields = {name: self._ring[name] for name in self.dtype.names}
        ctx = mp.get_context("spawn")  # never fork a process with the transport's threads
        self._head = ctx.Value("q", 0, lock=False)  # rows written by the loop, published under _publish
        self._publish = ctx.Lock()  # taken around the head's update and read: the memory barrier both sides need
        self._tail = ctx.Value("q", 0, lock=False)  # rows taken by the writer (a stale read only drops early)
        self._written = 0
        self.dropped = 0
        self._seq = 0
        self._status: Any = ctx.Queue(maxsize=256)
        self._stop = ctx.Event()
        self._result: Any = ctx.Queue()
        args = (self._shm.name, self.dtype.descr, self.capacity, self._head, self._publish, self._tail,
                self._status, self._stop, self._result, str(path), list(log_columns), derived_every)  # fmt: skip
        self._proc = ctx.Process(target=_writer_main, args=args, name="omnirotor-recorder", daemon=True)
        self._proc.start()
        self._closed = False

    def period(self, frame: SensorFrame, cmd_hz: np.ndarray, control_status: int = 0, log_row=None, *, block=False,
               plant_session: int = 0):  # fmt: skip
        """Copy one period into the ring: the frame, the speeds sent, and the controller's log row (or None).

        ``plant_session`` is the session of the plant that sent the frame (the recorded frame's ``session_id``).

        Never blocks unless ``block`` (offline replays): a full ring drops the row (:attr:`dropped`).

        Returns:
            True if recorded.
        """
        head = self._written
        while head - self._tail.value >= self.capacity:
            if not block or not self._proc.is_alive():
                self.dropped += 1
                return False
            time.sleep(0.001)
        i = head % self.capacity
        f = self._fields  # one view per field of the ring: an indexed store each, no record object
        self._seq += 1
        f["seq"][i] = self._seq
        f["plant_session"][i] = plant_session
        f["t"][i] = frame.t
        f["acc_B"][i] = frame.imu_acc_B
        f["gyro_B"][i] = frame.imu_gyro_B
        f["rotor_hz"][i] = frame.rotor_hz
        mocap = frame.mocap_new and frame.mocap_p_W is not None and frame.mocap_q_WB is not None
        f["mocap_new"][i] = mocap
        if mocap:
            f["mocap_t"][i] = frame.mocap_t
            f["mocap_p_W"][i] = frame.mocap_p_W
            f["mocap_q_WB"][i] = frame.mocap_q_WB
        f["cmd_hz"][i] = cmd_hz
        f["control_status"][i] = control_status
        f["armed"][i] = cmd_hz.any()
        f["has_log"][i] = log_row is not None
        if log_row is not None:
            f["log"][i] = log_row
        self._written = head + 1
        with self._publish:
            self._head.value = head + 1
        return True

    def status(self, status) -> None:
        """Record a :class:`~omnirotor.fly.requests.FlightStatus` (about 50 Hz; dropped if the writer lags)."""
        try:
            self._status.put_nowait(status)
        except queue.Full:
            self.dropped += 1

    def plant_status(self, msg, t: float) -> None:
        """Record the plant's ``SimStatus`` as heard, at the node's frame time ``t`` [s]; dropped if the writer lags.

        The node's frame time is the bag's one clock (a robot bridge stamps its status on its own host's clock).
        """
        from omnirotor.rosmsg import typestore

        try:
            self._status.put_nowait((t, bytes(typestore().serialize_cdr(msg, TOPICS["/omnirotor/sim_status"]))))
        except queue.Full:
            self.dropped += 1

    def close(self, timeout_s: float = 30.0) -> dict:
        """Drain the ring, finish the bag and stop the writer; returns its summary (messages per topic, ...).

        Raises:
            InputError: the writer failed (its reason) or did not finish within ``timeout_s``.
        """
        if self._closed:
            return {}
        self._closed = True
        self._stop.set()
        result = None
        deadline = time.monotonic() + timeout_s
        while result is None and time.monotonic() < deadline:
            try:
                result = self._result.get(timeout=0.1)
            except queue.Empty:
                if not self._proc.is_alive() and self._result.empty():
                    result = {"error": f"the writer process ended (exit code {self._proc.exitcode}) without a summary"}
        if result is None:
            result = {"error": f"the writer did not finish within {timeout_s:g} s"}
        self._proc.join(timeout=5.0)
        if self._proc.is_alive():
            self._proc.kill()
        self._shm.close()
        self._shm.unlink()
        if "error" in result:
            raise InputError(f"recording {self.path}: {result['error']}")
        result["dropped"] = self.dropped
        return result

    @property
    def writer_pid(self) -> int | None:
        """The writer process's id."""
        return self._proc.pid

    def __enter__(self) -> FlightRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# -- the writer process ------------------------------------------------------------------------------------


def column_groups(columns: list[str]) -> dict[str, np.ndarray]:
    """Column indices of each group of the log (``g.x`` -> group ``g``), by name."""
    out: dict[str, list[int]] = {}
    for i, name in enumerate(columns):
        out.setdefault(name.split(".")[0], []).append(i)
    return {k: np.array(v) for k, v in out.items()}


def _stamp(store, t: float):
    ns = max(0, int(round(t * 1e9)))
    return store.types["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _writer_main(
    shm_name, descr, capacity, head, publish, tail, status_q, stop, result_q, path, columns, every
) -> None:
    """Drain the ring into the bag until stopped and drained; put a summary (or an error) on ``result_q``."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from omnirotor.rosmsg import typestore
    from omnirotor.so3 import quat_wxyz_from_R

    shm = SharedMemory(name=shm_name)
    try:
        ring = np.ndarray((capacity,), dtype=np.dtype(descr), buffer=shm.buf)
        store = typestore()
        T = store.types
        groups = column_groups(columns)
        poses = {topic: (groups[p], groups[r]) for topic, (p, r) in _POSES.items() if p in groups and r in groups}
        wrench = tuple(groups[g] for g in _WRENCH) if all(g in groups for g in _WRENCH) else None
        counts = dict.fromkeys(TOPICS, 0)
        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.open()
        conns = {topic: writer.add_connection(topic, msgtype, typestore=store) for topic, msgtype in TOPICS.items()}

        def put(topic: str, t: float, msg) -> None:
            put_raw(topic, t, store.serialize_cdr(msg, TOPICS[topic]))

        def put_raw(topic: str, t: float, raw: bytes) -> None:
            writer.write(conns[topic], max(0, int(round(t * 1e9))), raw)
            counts[topic] += 1

        def header(t: float, frame_id: str):
            return T["std_msgs/msg/Header"](stamp=_stamp(store, t), frame_id=frame_id)

        def pose(t: float, p: np.ndarray, R: np.ndarray):
            q = quat_wxyz_from_R(R.reshape(3, 3))
            return T["geometry_msgs/msg/PoseStamped"](
                header=header(t, "world"),
                pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
                    orientation=T["geometry_msgs/msg/Quaternion"](x=q[1], y=q[2], z=q[3], w=q[0]),
                ),
            )

        zeros21 = np.zeros(21)
        taken = 0

        def published() -> int:
            with publish:
                return head.value

        while True:
            h = published()
            if taken == h:
                _drain_status(status_q, put, put_raw)
                if stop.is_set() and published() == taken:
                    break
                time.sleep(0.002)
                continue
            while taken < h:
                r = ring[taken % capacity].copy()
                taken += 1
                tail.value = taken
                t = float(r["t"])
                seq = int(r["seq"])
                put("/omnirotor/frame", t, T["omnirotor_msgs/msg/SensorFrame"](
                    header=header(t, "base_link"), session_id=int(r["plant_session"]), seq=seq, t=t,
                    imu_acc_b=r["acc_B"], imu_gyro_b=r["gyro_B"], mocap_new=bool(r["mocap_new"]),
                    mocap_t=float(r["mocap_t"]), mocap_p_w=r["mocap_p_W"], mocap_q_wb=r["mocap_q_WB"], has_state=False,
                    state=zeros21, rotor_hz=r["rotor_hz"],
                ))  # fmt: skip
                put("/omnirotor/rotor_cmd", t, T["omnirotor_msgs/msg/RotorCommand"](
                    header=header(t, "base_link"), t=t, hz=r["cmd_hz"], control_status=int(r["control_status"]),
                    state=1 if r["armed"] else 2, session_id=0, seq=seq, frame_seq=seq,
                ))  # fmt: skip
                if r["has_log"] and (seq - 1) % every == 0:
                    log = r["log"]
                    for topic, (ip, iR) in poses.items():
                        put(topic, t, pose(t, log[ip], log[iR]))
                    if wrench is not None:
                        f, m_B = log[wrench[0]], log[wrench[1]]
                        m_W = log[wrench[2]].reshape(3, 3) @ m_B
                        put("/omnirotor/wrench_est", t, T["geometry_msgs/msg/WrenchStamped"](
                            header=header(t, "world"),
                            wrench=T["geometry_msgs/msg/Wrench"](
                                force=T["geometry_msgs/msg/Vector3"](x=f[0], y=f[1], z=f[2]),
                                torque=T["geometry_msgs/msg/Vector3"](x=m_W[0], y=m_W[1], z=m_W[2]),
                            ),
                        ))  # fmt: skip
            _drain_status(status_q, put, put_raw)
        writer.close()
        result_q.put({"messages": counts, "rows": taken, "path": path})
    except Exception as exc:  # noqa: BLE001  (the reason goes back to the node, which says it)
        result_q.put({"error": f"{type(exc).__name__}: {exc}"})
    finally:
        shm.close()


def _drain_status(status_q, put, put_raw) -> None:
    while True:
        try:
            st = status_q.get_nowait()
        except (queue.Empty, OSError, EOFError):
            return
        if isinstance(st, tuple):  # the plant's SimStatus, serialised as heard (FlightRecorder.plant_status)
            t, raw = st
            put_raw("/omnirotor/sim_status", t if math.isfinite(t) else 0.0, raw)
            continue
        t = st.t if math.isfinite(st.t) else 0.0
        put("/omnirotor/status", t, st.to_msg())


# -- reading back ------------------------------------------------------------------------------------------


@dataclasses.dataclass
class Recording:
    """A recorded flight as arrays (:func:`read_recording`).

    Attributes:
        counts: messages per topic.
        t: (N,) frame times [s].
        plant_session: (N,) the session of the plant that sent each frame (uint64).
        mocap_new: (N,) motion capture arrived in the period.
        rotor_hz: (N, n) measured speeds [Hz].
        cmd_hz: (N, n) speeds sent [Hz].
        control_status: (N,) the controller's status bits.
        pose_t, p_W: (M,) times [s] and (M, 3) positions [m] of the state estimate.
        f_ext_W: (M, 3) estimated external force [N], world frame.
        status: the FlightStatus messages, in order.
        plant_status: the plant's SimStatus messages as the node heard them (rosbags objects), in order.
    """

    counts: dict[str, int]
    t: np.ndarray
    plant_session: np.ndarray
    mocap_new: np.ndarray
    rotor_hz: np.ndarray
    cmd_hz: np.ndarray
    control_status: np.ndarray
    pose_t: np.ndarray
    p_W: np.ndarray
    f_ext_W: np.ndarray
    status: list
    plant_status: list = dataclasses.field(default_factory=list)


def read_recording(path: str | Path) -> Recording:
    """Read a flight recording (a ROS 2 bag of :data:`TOPICS`) with rosbags and the shipped definitions.

    Raises:
        InputError: not a readable bag.
    """
    from rosbags.highlevel import AnyReader

    from omnirotor.fly.requests import FlightStatus
    from omnirotor.rosmsg import typestore

    names = ("t", "session", "mocap", "rotor", "cmd", "cs", "pose_t", "p", "f", "status", "plant")
    cols: dict[str, list] = {k: [] for k in names}
    try:
        with AnyReader([Path(path)], default_typestore=typestore()) as reader:
            counts = {c.topic: c.msgcount for c in reader.connections}
            for conn, _, raw in reader.messages():
                msg = reader.deserialize(raw, conn.msgtype)
                if conn.topic == "/omnirotor/frame":
                    cols["t"].append(msg.t)
                    cols["session"].append(msg.session_id)
                    cols["mocap"].append(msg.mocap_new)
                    cols["rotor"].append(np.asarray(msg.rotor_hz))
                elif conn.topic == "/omnirotor/rotor_cmd":
                    cols["cmd"].append(np.asarray(msg.hz))
                    cols["cs"].append(msg.control_status)
                elif conn.topic == "/omnirotor/pose":
                    s = msg.header.stamp
                    cols["pose_t"].append(s.sec + 1e-9 * s.nanosec)
                    p = msg.pose.position
                    cols["p"].append((p.x, p.y, p.z))
                elif conn.topic == "/omnirotor/wrench_est":
                    f = msg.wrench.force
                    cols["f"].append((f.x, f.y, f.z))
                elif conn.topic == "/omnirotor/status":
                    cols["status"].append(FlightStatus.from_msg(msg))
                elif conn.topic == "/omnirotor/sim_status":
                    cols["plant"].append(msg)
    except Exception as exc:  # noqa: BLE001  (rosbags raises several kinds for a damaged or foreign bag)
        raise InputError(f"{path}: not a readable flight recording ({type(exc).__name__}: {exc})") from None
    return Recording(
        counts=counts, t=np.array(cols["t"]), plant_session=np.array(cols["session"], dtype=np.uint64),
        mocap_new=np.array(cols["mocap"], dtype=bool),
        rotor_hz=np.array(cols["rotor"]), cmd_hz=np.array(cols["cmd"]), control_status=np.array(cols["cs"]),
        pose_t=np.array(cols["pose_t"]), p_W=np.array(cols["p"]).reshape(-1, 3),
        f_ext_W=np.array(cols["f"]).reshape(-1, 3), status=cols["status"],
        plant_status=cols["plant"],
    )  # fmt: skip
