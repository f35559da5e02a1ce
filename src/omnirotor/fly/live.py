"""The live view: a Foxglove WebSocket server (foxglove-sdk) on the flight node and on the simulator.

The channels are those of a run's MCAP (:data:`omnirotor.px4.mcap_export.CHANNELS`, same schemas, same JSON
shapes, our frames and SI units), so a Foxglove layout made for ``omnirotor run --mcap`` shows a live flight:

* the node (:meth:`LiveView.node_period`): ``/pose`` (the estimate), ``/reference`` (compliant and desired EE
  positions), ``/wrench`` (the observer's estimate, the wrench reference), ``/rotors`` (measured and
  commanded speeds), ``/imu``, ``/contact`` (map region, status bits), and ``/status`` (the director's);
* the simulator (:meth:`LiveView.sim_period`): ``/pose_true``, ``/tf`` (world -> body), ``/wrench`` (the true
  contact wrench), ``/contact`` (the true contact flag), ``/rotors`` (true speeds).

Cost in the 1 kHz loop: each channel is published at ``rate_hz`` (50 Hz by default) of the samples' own time,
the channels staggered so that a period publishes at most one (one JSON message, some tens of µs); the
server (foxglove-sdk, in Rust) sends from its own threads. Listens on loopback by default.
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor.errors import InputError
from omnirotor.fly.record import column_groups
from omnirotor.px4.mcap_export import CHANNELS, FOXGLOVE_SCHEMAS, OWN_SCHEMAS, pose_json, stamp_json
from omnirotor.so3 import quat_wxyz_from_R

__all__ = ["LiveView", "STATUS_SCHEMA", "start_live_view"]

STATUS_SCHEMA = {
    "title": "omnirotor.FlightStatus",
    "type": "object",
    "properties": {
        "t_s": {"type": "number", "description": "time of the last frame [s]"},
        "mode": {"type": "string", "description": "flight mode"},
        "failsafe": {"type": "integer", "description": "failsafe level (omnirotor.fly.failsafe.Failsafe)"},
        "cause": {"type": "integer", "description": "cause bits (omnirotor.fly.failsafe.Cause)"},
        "preset": {"type": "string", "description": "admittance preset"},
        "map_mode": {"type": "string", "description": "wrench-map mode"},
        "depth_m": {"type": "number", "description": "penetration depth commanded [m]"},
        "message": {"type": "string", "description": "the last transition"},
    },
}
"""The JSON schema of the director's ``/status`` (omnirotor.fly.requests.FlightStatus)."""

_NODE = ("/pose", "/reference", "/wrench", "/rotors", "/imu", "/contact")
_SIM = ("/pose_true", "/tf", "/wrench", "/contact", "/rotors")


def _xyz(v) -> list[float]:
    return [float(v[0]), float(v[1]), float(v[2])]


class LiveView:
    """A Foxglove WebSocket server with the run channels, fed one period at a time (module docstring).

    Args:
        host: address to listen on (loopback by default).
        port: TCP port (0: any free one; :attr:`port` says which).
        rate_hz: publishing rate of each channel [Hz] of sample time.
        log_columns: the controller log's column names (the node side; ``controller.log.column_names``).
        name: the server's name, shown by Foxglove.

    Raises:
        InputError: a bad rate, or a server that cannot start (e.g. the port is taken).
    """

    def __init__(
        self, *, host: str = "127.0.0.1", port: int = 8765, rate_hz: float = 50.0, log_columns=(), name="omnirotor"
    ) -> None:
        import foxglove

        if not (math.isfinite(rate_hz) and 0.0 < rate_hz <= 1000.0):
            raise InputError(f"live view rate must be in (0, 1000] Hz, got {rate_hz}")
        self._ctx = foxglove.Context()
        try:
            self.server = foxglove.start_server(name=name, host=host, port=port, context=self._ctx)
        except Exception as exc:  # noqa: BLE001  (the SDK raises its own error for a port in use)
            raise InputError(f"cannot start the Foxglove server on {host}:{port}: {exc}") from None
        self.port = self.server.port
        schemas = {**FOXGLOVE_SCHEMAS, **OWN_SCHEMAS}
        self._chan = {
            topic: foxglove.Channel(topic, schema=schemas[schema], context=self._ctx)
            for topic, schema in CHANNELS.items()
            if topic != "/scene"
        }
        self._chan["/status"] = foxglove.Channel("/status", schema=STATUS_SCHEMA, context=self._ctx)
        self._every = 1.0 / rate_hz
        topics = sorted(set(_NODE) | set(_SIM))
        # Channels staggered over one publishing interval, so a period publishes at most one of them.
        self._next = {topic: -math.inf for topic in topics}
        self._phase = {topic: i * self._every / len(topics) for i, topic in enumerate(topics)}
        g = column_groups(list(log_columns))
        self._g = g
        self._have = {
            "/pose": "p_W" in g and "R_WB" in g,
            "/reference": "p_E_ref_W" in g and "p_E_des_W" in g,
            "/wrench": "f_ext_W" in g and "m_ext_B" in g,
        }
        self.published = dict.fromkeys(self._chan, 0)

    def _due(self, topics, t: float) -> str | None:
        """The channel to publish at sample time ``t`` [s] (the one longest due), and its next time."""
        best = None
        if self._next[topics[0]] == -math.inf:  # the first sample starts the staggered schedule
            for topic in topics:
                self._next[topic] = t + self._phase[topic]
        for topic in topics:
            nxt = self._next[topic]
            if t >= nxt and (best is None or nxt < self._next[best]):
                best = topic
        if best is not None:
            self._next[best] = max(self._next[best] + self._every, t)
        return best

    def _log(self, topic: str, t: float, msg: dict) -> None:
        self._chan[topic].log(msg, log_time=max(0, int(round(t * 1e9))))
        self.published[topic] += 1

    def node_period(self, frame, cmd_hz: np.ndarray, log_row: np.ndarray | None = None) -> None:
        """The node's period: the frame, the speeds sent and the controller's log row (its columns at start)."""
        t = float(frame.t)
        topic = self._due(_NODE, t)
        if topic is None:
            return
        g, st = self._g, stamp_json(t)
        if topic == "/rotors":
            self._log(topic, t, {"t_s": t, "omega_hz": np.asarray(frame.rotor_hz).tolist(),
                                 "omega_cmd_hz": np.asarray(cmd_hz).tolist()})  # fmt: skip
        elif topic == "/imu":
            self._log(topic, t, {"t_s": t, "omega_B": _xyz(frame.imu_gyro_B), "accel_B": _xyz(frame.imu_acc_B)})
        elif log_row is None or (topic in self._have and not self._have[topic]):
            return
        elif topic == "/pose":
            q = quat_wxyz_from_R(log_row[g["R_WB"]].reshape(3, 3))
            self._log(topic, t, {"timestamp": st, "frame_id": "world", "pose": pose_json(log_row[g["p_W"]], q)})
        elif topic == "/reference":
            self._log(topic, t, {"t_s": t, "p_E_ref_W": _xyz(log_row[g["p_E_ref_W"]]),
                                 "p_E_des_W": _xyz(log_row[g["p_E_des_W"]])})  # fmt: skip
        elif topic == "/wrench":
            msg = {"t_s": t, "f_ext_hat_W": _xyz(log_row[g["f_ext_W"]]), "m_ext_hat_B": _xyz(log_row[g["m_ext_B"]])}
            if "w_ref" in g:
                msg["w_ref"] = log_row[g["w_ref"]].tolist()
            self._log(topic, t, msg)
        elif topic == "/contact" and "region" in g and "status" in g:
            self._log(topic, t, {"t_s": t, "region": int(log_row[g["region"]][0]),
                                 "status": int(log_row[g["status"]][0])})  # fmt: skip

    def sim_period(self, t: float, truth) -> None:
        """The simulator's period: its ground truth (``Simulator.truth``: p_W, R_WB, contact, rotors)."""
        topic = self._due(_SIM, t)
        if topic is None:
            return
        st = stamp_json(t)
        if topic in ("/pose_true", "/tf"):
            pose = pose_json(truth.p_W, quat_wxyz_from_R(np.asarray(truth.R_WB)))
            if topic == "/pose_true":
                self._log(topic, t, {"timestamp": st, "frame_id": "world", "pose": pose})
            else:
                self._log(topic, t, {"timestamp": st, "parent_frame_id": "world", "child_frame_id": "body",
                                     "translation": pose["position"], "rotation": pose["orientation"]})  # fmt: skip
        elif topic == "/wrench":
            self._log(topic, t, {"t_s": t, "f_contact_W": _xyz(truth.contact_force_W),
                                 "m_contact_W": _xyz(truth.contact_moment_W)})  # fmt: skip
        elif topic == "/contact":
            self._log(topic, t, {"t_s": t, "in_contact": bool(truth.in_contact)})
        elif topic == "/rotors":
            self._log(topic, t, {"t_s": t, "omega_hz": np.asarray(truth.rotor_hz).tolist()})

    def status(self, status) -> None:
        """Publish the director's :class:`~omnirotor.fly.requests.FlightStatus` (call it at its own rate)."""
        t = status.t if math.isfinite(status.t) else 0.0
        self._log("/status", t, {
            "t_s": t, "mode": status.mode.label, "failsafe": int(status.failsafe), "cause": int(status.cause),
            "preset": status.preset, "map_mode": status.map_mode, "depth_m": float(status.depth_m),
            "message": status.message,
        })  # fmt: skip

    def close(self) -> None:
        """Stop the server (idempotent)."""
        if self.server is not None:
            self.server.stop()
            self.server = None


def start_live_view(port: int = 8765, *, log_columns=(), rate_hz: float = 50.0, host: str = "127.0.0.1") -> LiveView:
    """The one call that enables the live view (``--foxglove``): a :class:`LiveView` serving on ``host:port``."""
    return LiveView(host=host, port=port, rate_hz=rate_hz, log_columns=log_columns)


def open_outputs(record, foxglove_port: int | None, n_rotors: int, columns, say) -> tuple:
    """The recording and the live view a process was asked for (``fly``, ``sim --serve``); None where not.

    Args:
        record: a new bag folder to record into, or None.
        foxglove_port: the live view's port, or None.
        n_rotors: rotors of the vehicle.
        columns: the log (or ground-truth) columns recorded and viewed.
        say: where the live view's address is said.

    Returns:
        ``(recorder, live)``. A live view that cannot start closes the recording first, then raises.
    """
    from omnirotor.fly.record import FlightRecorder

    recorder = FlightRecorder(record, n_rotors, columns) if record is not None else None
    live = None
    if foxglove_port is not None:
        try:
            live = start_live_view(foxglove_port, log_columns=columns)
        except InputError:
            close_outputs(recorder, None)
            raise
        say(f"live view on ws://127.0.0.1:{live.port} (Foxglove: Open connection)")
    return recorder, live


def close_outputs(recorder, live) -> dict:
    """Stop the live view and finish the recording; what the recording wrote (``{}`` without one).

    Returns:
        ``{"path", "dropped", "messages"}``, or ``{"path", "error"}`` if finishing the bag failed.
    """
    if live is not None:
        live.close()
    if recorder is None:
        return {}
    try:
        summary = recorder.close()
    except InputError as exc:
        return {"path": str(recorder.path), "error": str(exc)}
    return {"path": str(recorder.path), "dropped": int(summary.get("dropped", 0)),
            "messages": summary.get("messages", {})}  # fmt: skip
