"""``omnirotor fly``: the flight node's process loop (issue 24, item 2).

One loop, on the monotonic clock, around a :class:`~omnirotor.fly.director.FlightDirector` (or any object with
its ``on_frame``/``wants_step``/``output``/``request``/``status``), per sensor frame::

    director.on_frame(frame, ages)
    cmd = controller.step(frame) if director.wants_step() else None
    publish RotorCommand(director.output(cmd), session, seq, frame_seq)

Frames come from ``/omnirotor/frame`` (``omnirotor_msgs/msg/SensorFrame``, waited for: the newest is taken, older
ones count as missed periods, but the newest motion-capture sample among the skipped frames is carried into it when
it has none: a loop that falls behind must not lose the samples that anchor the estimate), commands go to
``/omnirotor/rotor_cmd`` with this process's random session id and increasing sequence numbers (the plant obeys one
session: :mod:`omnirotor.sitl.gate`). ``omnirotor ctl`` requests (``/omnirotor/ctl``) are answered between frames on
the loop's own thread (the director is not thread-safe), one per pass; the transport's thread takes in one request
per ``1 / NodeOptions.ctl_rate_hz`` and answers the others busy at once, before decoding them (a flood of requests
from any process must not take the loop's time). Status: ``/omnirotor/status`` (the director's,
``FlightStatus``) and ``/omnirotor/loop_status`` (``LoopStatus``, the deadline accounting below) about 50 times a
second; ``/omnirotor/wrench_est`` (``WrenchStamped``, the observer's estimate in the world frame) at 100 Hz. One
message per period is on the hot path, the command; a mission's controller-log rows go to the simulator in batches
of 20, and the rest as soon as frames pause (a lockstep plant at the end of its run, a lost link).

Real time (the default): between frames the loop sleeps in the transport's queue until a frame arrives, or until the
director's next gap call or the status is due (no polling: the CPU stays free for the plant); the garbage collector
is frozen and disabled in the loop; the loop's thread asks for CPU affinity and ``SCHED_FIFO`` (said on stderr where
the OS refuses; both in :mod:`omnirotor.realtime`). A period with no frame calls the director with the growing link
ages (its failsafes); no frame for ``link_loss_s`` (50 ms) is *link lost* (unless the plant's status, read then,
says its mission ended): said on stderr and in the status, the director told (``frames_stopped``), and no command
is published until frames come back. Deadline accounting: a
period is *late* when its command left more than ``late_threshold_s`` (0.5 ms) after its frame was taken from the
wire, when its frame came that much later than one period after the previous one, or when its frame was missed; an
*overrun* is a period whose work took longer than the period. Counts, the worst lateness and the frame-to-command
percentiles are in ``LoopStatus`` and in the summary on exit.

Lockstep (``lockstep=True``, for ``omnirotor sim --serve --lockstep``): the loop answers every frame as soon as
it arrives, with no pacing; link ages are in the frames' own time, and the link is lost after 5 s.

Which frames are followed (:class:`omnirotor.sitl.gate.FrameGate`, the plant's command gate's rule in the other
direction): those of one plant session (``SensorFrame.session_id``, random per plant process, printed at its
start). Pinned (``plant_session``, ``omnirotor fly --plant-session HEX``), only that session's, from the very first
frame; first come, the session of the first well-formed frame. A frame of another session is refused, counted
(``frames_foreign``, not in ``frames_bad``) and said once per session, never followed; a frame without a session
(0) is counted bad and said once. Of the followed session, a frame whose number is not above the last one
followed, or more than :data:`MAX_FRAME_JUMP` above it, is counted bad and dropped (a replay, a forged or
corrupted number that would otherwise lock the real frames out). After a link loss the followed session's next
frame is followed whatever its number (the plant may have restarted its count); a pinned session is kept, and a
first-come one is released only while the link is lost *and* the director is disarmed (on the ground, or stopped
by the link-loss failsafe): then the first plant to send frames is followed again, and said, but never a second
plant in flight. The one exception to the numbers is the plant's start frame (number 0), which the simulator
repeats every 10 ms until it has obeyed a command answering it: repeated, it is answered again with the same
command (nothing stepped) and keeps the link alive, so that a first answer delayed past 50 ms on a busy machine
is not a link loss.

The plant's status (``SimStatus``: its failsafe, which disarms the director, and the end of its run) is read
only from the followed plant session (``plant_session_id``), or from a plant that sends no frames (0: a robot
bridge with ``--no-frames``) as long as no status named the followed session; a status naming another session (a
second plant, a forger), or none once the followed plant's own was heard, is ignored, counted
(``plant_statuses_foreign`` in the summary) and the other session said once.

Nothing raises out of the loop: a frame the controller refuses is counted and answered by the director's
output without a step; Ctrl-C (or ``stop``) ends it with the summary.
"""

from __future__ import annotations

import dataclasses
import math
import queue
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from omnirotor.errors import InputError
from omnirotor.fly.failsafe import LinkAges
from omnirotor.fly.modes import REQUESTS
from omnirotor.messages import SensorFrame
from omnirotor.realtime import freeze_gc, thaw_gc
from omnirotor.rosmsg import typestore
from omnirotor.rosmsg.convert import (
    COMMAND,
    COMMAND_ARMED,
    COMMAND_STOP,
    CONTROLLER_LOG,
    FRAME,
    LOOP_STATUS,
    SIM_STATUS,
    WRENCH,
    CommandWire,
    FrameCodec,
    FrameWire,
    WireMessages,
    frame_check,
    set_stamp,
)
from omnirotor.sitl.gate import MAX_SEQ_JUMP, FrameGate, new_session_id, parse_session_id
from omnirotor.sitl.server import TOPICS
from omnirotor.transport import Transport

__all__ = [
    "NodeOptions",
    "NodeLoop",
    "LoopStats",
    "LinkAges",
    "warm_up",
    "mission_from_sim",
    "fly_mission",
]

_LATENCY_WINDOW = 1 << 17
_RECENT = 1000
MAX_FRAME_JUMP = MAX_SEQ_JUMP
"""The largest step of the frame number the loop follows (a second of frames); larger ones count as bad."""
_FRAME_DEPTH = 32
_ROW_BATCH = 20
"""Controller-log rows per ControllerLog message (missions): one message every 20 steps, not one per step."""
_LOCKSTEP_WAIT_S = 0.02
REQUESTS_PER_PERIOD = 1
"""The most ``ctl`` requests the loop serves in one pass between frames."""
CTL_RATE_HZ = 100.0
"""The most ``ctl`` requests the loop serves per second by default (a person types a few; the status is on its own
topic at 50 Hz). Before the bound, a client sending ``status`` requests back to back had about 600 a second served
on the loop's thread: 80 % of a loaded machine's periods held, a degree of attitude RMS lost (BENCHMARKS.md)."""
MAX_CTL_RATE_HZ = 1000.0
"""The highest ``--ctl-rate``: one request a period."""


@dataclasses.dataclass(frozen=True)
class NodeOptions:
    """How the loop runs (module docstring).

    Attributes:
        period_s: the control period [s].
        lockstep: answer every frame at once, no pacing (SITL lockstep).
        link_loss_s: no frame for this long is link lost [s] (lockstep: ``lockstep_link_loss_s``).
        lockstep_link_loss_s: the same in lockstep [s].
        late_threshold_s: lateness beyond which a period counts late [s].
        status_hz: status rate [Hz].
        wrench_every: publish the wrench estimate every this many steps.
        log_rows: publish the controller's log rows (missions of ``omnirotor sim --serve``).
        exit_on_link_loss: end the loop when the link is lost (missions); else wait for frames again.
        max_frames: end after this many frames (None: until stopped or the simulator says it finished).
        record: a ROS 2 bag to record the flight into (a new folder; :class:`~omnirotor.fly.record.FlightRecorder`:
            every period, from a writer process, in bounded memory), or None.
        foxglove_port: serve the live view (:class:`~omnirotor.fly.live.LiveView`) on this loopback port (0: any
            free one), or None.
        frame_guard_s: real time: after answering a frame the loop sleeps on the clock until this long before the
            next frame is expected (the earliest arrivals, one period apart), then waits in the channel; so a flood
            on the frame key wakes it only within this guard instead of at every payload [s]; 0: wait in the
            channel at once. Frames come on the plant's clock, so a real one is not due before the guard; the
            default leaves 0.3 ms for the sleep's own overshoot (about 0.1 ms here) and the frame's jitter.
        session_id: the controller session id its rotor commands carry (``omnirotor fly --session-id``; a plant
            pinned to it with ``--pair-session`` obeys this node only: :mod:`omnirotor.sitl.gate`); None: random.
        plant_session: follow the frames of this plant session only (``omnirotor fly --plant-session``, the id
            the plant prints at its start or was given with its ``--session-id``); None: the first come (module
            docstring).
        ctl_rate_hz: the most ``omnirotor ctl`` requests the loop serves per second (``omnirotor fly --ctl-rate``):
            one is taken in at most every ``1 / ctl_rate_hz`` seconds and one period, the others answered busy at
            once on the transport's thread, never decoded (module docstring).
    """

    period_s: float = 0.001
    lockstep: bool = False
    link_loss_s: float = 0.05
    lockstep_link_loss_s: float = 5.0
    late_threshold_s: float = 0.0005
    status_hz: float = 50.0
    wrench_every: int = 10
    log_rows: bool = False
    exit_on_link_loss: bool = False
    max_frames: int | None = None
    record: str | None = None
    foxglove_port: int | None = None
    frame_guard_s: float = 0.0003
    session_id: int | None = None
    plant_session: int | None = None
    ctl_rate_hz: float = CTL_RATE_HZ


class LoopStats:
    """The deadline accounting of the loop (module docstring); preallocated, nothing allocated per period."""

    def __init__(self, late_threshold_s: float) -> None:
        self.late_threshold_s = late_threshold_s
        self.frames = 0
        self.periods = 0
        self.late = 0
        self.missed = 0
        self.overruns = 0
        self.worst_late_s = 0.0
        self.link_losses = 0
        self.controller_errors = 0
        self.status_errors = 0
        self.output_errors = 0
        self.disarmed_nonzero = 0
        """Periods a disarmed director gave nonzero speeds, replaced by zeros (never, unless a director is wrong)."""
        self._latency = np.zeros(_LATENCY_WINDOW)
        self._work = np.zeros(_LATENCY_WINDOW)
        self._recent = np.zeros(_RECENT)  # scratch of the status's p99
        self._i = 0

    def period(self, latency_s: float, work_s: float, arrival_late_s: float, period_s: float) -> None:
        """Account one answered frame: frame-to-command ``latency_s``, its work, how late it arrived [s]."""
        self.periods += 1
        lateness = max(latency_s, arrival_late_s)
        if lateness > self.late_threshold_s:
            self.late += 1
        if lateness > self.worst_late_s:
            self.worst_late_s = lateness
        if work_s > period_s:
            self.overruns += 1
        i = self._i % _LATENCY_WINDOW
        self._latency[i] = latency_s
        self._work[i] = work_s
        self._i += 1

    def skipped(self, n: int) -> None:
        """``n`` periods whose frames were never answered (missed): late."""
        self.periods += n
        self.missed += n
        self.late += n

    def recent_p99_s(self) -> float:
        """Frame-to-command p99 [s] of the last 1000 answered frames, for the status.

        A percentile of the whole window (up to 131 072 samples) took milliseconds: at 50 Hz it made periods late.
        The nearest-rank p99 (the ``ceil(0.99 n)``-th smallest), by a partition of a preallocated copy: about 5 µs.
        """
        n = min(self._i, _RECENT)
        if n == 0:
            return 0.0
        i = self._i % _LATENCY_WINDOW
        buf = self._recent[:n]
        if i >= n:
            buf[:] = self._latency[i - n : i]
        else:  # the last n straddle the window's end
            buf[: n - i] = self._latency[i - n :]
            buf[n - i :] = self._latency[:i]
        k = math.ceil(0.99 * n) - 1  # the nearest-rank p99: np.percentile took 90 µs, a partition 5 µs
        buf.partition(k)
        return float(buf[k])

    def latency_percentiles_us(self) -> dict:
        """Frame-to-command latency p50/p99/max [µs] over the last window."""
        return _percentiles(self._latency[: min(self._i, _LATENCY_WINDOW)])

    def work_percentiles_us(self) -> dict:
        """Work per answered frame p50/p99/max [µs] (director, controller step, publishing)."""
        return _percentiles(self._work[: min(self._i, _LATENCY_WINDOW)])

    def summary(self) -> dict:
        """The exit summary as a dict."""
        per_1e5 = 1e5 * self.late / self.periods if self.periods else 0.0
        return {
            "frames": self.frames,
            "periods": self.periods,
            "periods_late": self.late,
            "late_per_1e5": per_1e5,
            "missed": self.missed,
            "overruns": self.overruns,
            "worst_late_ms": 1000 * self.worst_late_s,
            "frame_to_command_us": self.latency_percentiles_us(),
            "work_us": self.work_percentiles_us(),
            "link_losses": self.link_losses,
            "controller_errors": self.controller_errors,
            "status_errors": self.status_errors,
            "output_errors": self.output_errors,
            "disarmed_nonzero": self.disarmed_nonzero,
        }


def _percentiles(x: np.ndarray) -> dict:
    if x.size == 0:
        return {}
    p50, p99 = np.percentile(x, [50, 99])
    return {"p50": 1e6 * float(p50), "p99": 1e6 * float(p99), "max": 1e6 * float(x.max()), "n": int(x.size)}


class NodeLoop:
    """The node's loop (module docstring).

    Args:
        transport: an open transport.
        controller: the interaction controller the director flies.
        director: the flight director (``on_frame``, ``wants_step``, ``output``; ``request``, ``status`` optional).
        options: loop options.
        say: where one-line notices go (stderr).
    """

    def __init__(
        self,
        transport: Transport,
        controller,
        director,
        options: NodeOptions | None = None,
        say: Callable[[str], None] | None = None,
    ) -> None:
        self.options = o = options if options is not None else NodeOptions()
        self.controller = controller
        self.director = director
        self._say = say if say is not None else (lambda line: print(f"omnirotor fly: {line}", file=sys.stderr))
        n = controller.vehicle.n_rotors
        self.n = n
        self.session_id = o.session_id if o.session_id is not None else new_session_id()
        self.msgs = WireMessages(n)
        self.stats = LoopStats(o.late_threshold_s)
        self._codec = FrameCodec(n)
        shape_ok = frame_check(n)
        self.plant_gate = gate = FrameGate(o.plant_session, say=self._say)
        self.frames_unsigned = 0
        """Well-formed frames without a plant session (``session_id`` 0), refused (counted in ``frames_bad``)."""

        def frame_ok(msg) -> bool:  # the right shape, the followed plant and a number it follows (module docstring)
            if not shape_ok(msg):
                return False
            if msg.session_id == 0:
                self.frames_unsigned += 1
                if self.frames_unsigned == 1:
                    self._say("refused sensor frames without a plant session (session_id 0): a plant fills it")
                return False
            return gate.admits(msg.session_id, msg.seq)

        self._frames = transport.subscriber(
            TOPICS["frame"], FRAME, depth=_FRAME_DEPTH, check=frame_ok, decoder=FrameWire(n).decode
        )
        self.statuses_foreign = 0
        """Plant statuses (``SimStatus``) naming another plant session than the followed one: ignored."""
        self._status_other = 0  # the plant session the last such status named
        self._status_named = 0  # the followed plant session, once a status named it: then none without one counts

        def status_ok(msg) -> bool:  # the followed plant's status, or a frameless bridge's (module docstring)
            own = int(msg.plant_session_id)
            if own != 0 and own == gate.paired:
                self._status_named = own
                return True
            if own == 0 and self._status_named != gate.paired:
                return True
            self.statuses_foreign += 1
            self._status_other = own
            return False

        self._sim_status = transport.subscriber(TOPICS["sim_status"], SIM_STATUS, depth=4, check=status_ok)
        self._pub_cmd = transport.publisher(TOPICS["rotor_cmd"], COMMAND, block=o.lockstep)
        self._pub_loop = transport.publisher(TOPICS["loop_status"], LOOP_STATUS)
        self._pub_wrench = transport.publisher(TOPICS["wrench_est"], WRENCH)
        self._pub_rows = (
            transport.publisher(TOPICS["controller_log"], CONTROLLER_LOG, block=True) if o.log_rows else None
        )
        self._pub_status = None
        self._flight_status_type = None
        T = typestore().types
        if hasattr(director, "status") and "omnirotor_msgs/msg/FlightStatus" in T:
            self._flight_status_type = T["omnirotor_msgs/msg/FlightStatus"]
            self._pub_status = transport.publisher(TOPICS["status"], "omnirotor_msgs/msg/FlightStatus")
        self._requests: queue.SimpleQueue = queue.SimpleQueue()
        self._admit_lock = threading.Lock()
        self._admit_after = -math.inf  # when the transport's thread may take in the next request
        self._request_every_s = max(1.0 / o.ctl_rate_hz, o.period_s)
        self._busy_replies: dict[tuple[int, int], Any] = {}
        self.requests_served = 0
        """Requests the loop served (answered by the director)."""
        self.requests_unserved = 0
        """Requests taken in that the loop did not serve within a second (no reply: the client times out)."""
        self._ctl_counts = None
        if hasattr(director, "request") and "omnirotor_msgs/msg/FlightRequest" in T:
            self._ctl_counts = transport.serve(
                TOPICS["ctl"], "omnirotor_msgs/msg/FlightRequest", "omnirotor_msgs/msg/FlightReply", self._on_request,
                busy=self._busy,
            )  # fmt: skip
        self._row_msg = T[CONTROLLER_LOG](
            session_id=self.session_id, frame_seq=np.zeros(0, np.uint64), n_columns=0, rows=np.zeros(0)
        )
        self._row_seq = np.zeros(_ROW_BATCH, np.uint64)
        self._rows: np.ndarray | None = None  # (_ROW_BATCH, columns), allocated on the first row
        self._n_rows = 0
        self._loop_msg = T[LOOP_STATUS](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=""),
            t=0.0, periods=0, periods_late=0, late_threshold_s=o.late_threshold_s, overruns=0, worst_late_s=0.0,
            frame_to_command_p99_s=0.0, frames=0, frames_bad=0, link_lost=False, session_id=self.session_id,
            plant_session_id=0, frames_foreign=0, foreign_plant_sessions=0,
        )  # fmt: skip
        self._zeros = np.zeros(n)
        self._cmd_wire = CommandWire(n)
        self._cmd_t = math.nan  # the last command's time and state (its repetition: _republish_command)
        self._cmd_state = 0
        self.cmd_seq = 0
        self.start_answers = 0
        """Times the plant's repeated start frame was answered again (its first answer had not reached it)."""
        self.mocap_carried = 0
        """Motion-capture samples of skipped frames carried into the newest frame (the loop had fallen behind)."""
        self.link_lost = False
        self._plant_failsafe = False
        self._plant_paired_other = 0  # another session the plant said it obeys (said once per session)
        self._plant_said_other = 0  # another plant session the plant's status named (said once per session)
        self.plant_imu: dict | None = None
        """The plant's watch of its IMU, from its newest ``SimStatus`` (None: no status heard); in the summary."""
        self.link_lost_age_s = math.nan
        self.finished = False
        self._finish_seq = math.inf
        self._last_seq = -1
        self.last_t = math.nan
        self.recorder = self.live = None
        columns = list(getattr(getattr(controller, "log", None), "column_names", ()))
        if o.record is not None or o.foxglove_port is not None:
            from omnirotor.fly.live import open_outputs

            self.recorder, self.live = open_outputs(o.record, o.foxglove_port, n, columns, self._say)
        self._f_idx = self._m_idx = self._R_idx = None
        log = getattr(controller, "log", None)
        if log is not None:
            try:
                self._f_idx = log._slices["f_ext_W"]  # noqa: SLF001  (the log's own column map)
                self._m_idx = log._slices["m_ext_B"]  # noqa: SLF001
                self._R_idx = log._slices["R_WB"]  # noqa: SLF001
            except (AttributeError, KeyError):
                pass

    # -- requests (transport thread -> loop thread) --------------------------------------------------------
    def _busy(self, payload: bytes) -> Any:
        """The transport's thread, before decoding: None takes the request in, else the busy reply.

        One request is taken in per ``1 / ctl_rate_hz`` (and none while one waits for the loop); the busy reply is
        a refusal with the mode unchanged, built once per request kind and mode.
        """
        now = time.monotonic()
        with self._admit_lock:
            if now >= self._admit_after and self._requests.empty():
                self._admit_after = now + self._request_every_s
                return None
        # the kind is the first field after CDR's 4-byte header (FlightRequest.msg); an unknown one is said as status
        kind = payload[4] if len(payload) > 4 and payload[4] < len(REQUESTS) else 0
        mode = int(getattr(self.director, "mode", 0))
        reply = self._busy_replies.get((kind, mode))
        if reply is None:
            reply = self._busy_replies[(kind, mode)] = typestore().types["omnirotor_msgs/msg/FlightReply"](
                accepted=False, kind=kind, mode_from=mode, mode=mode,
                message=f"busy: the node serves at most {1.0 / self._request_every_s:g} requests a second (fly "
                        "--ctl-rate); try again",
            )  # fmt: skip
        return reply

    def _on_request(self, req: Any) -> Any:
        """The transport's handler: hand ``req`` to the loop and wait (bounded) for its reply."""
        slot: queue.SimpleQueue = queue.SimpleQueue()
        self._requests.put((req, slot))
        try:
            return slot.get(timeout=1.0)
        except queue.Empty:  # no reply (the client times out)
            self.requests_unserved += 1
            raise

    def _serve_requests(self) -> None:
        """Serve one request taken in, if any: the budget of a period (the rest were answered busy: ``_busy``)."""
        for _ in range(REQUESTS_PER_PERIOD):
            try:
                req, slot = self._requests.get_nowait()
            except queue.Empty:
                return
            self.requests_served += 1
            try:
                reply = self.director.request(req)
                T = typestore().types
                fields = reply.to_fields() if hasattr(reply, "to_fields") else reply
                if getattr(reply, "kind", None) == "status" and getattr(reply, "accepted", False):
                    fields["message"] = f"{fields['message']}; {self.link_line()}"
                slot.put(T["omnirotor_msgs/msg/FlightReply"](**fields))
            except Exception as exc:  # noqa: BLE001  (a failing request never ends the loop)
                self._say(f"request failed: {exc.__class__.__name__}: {exc}")

    def link_line(self) -> str:
        """The link's pairing on one line, for ``omnirotor ctl status``: the plant followed, what was refused."""
        g = self.plant_gate
        if g.paired:
            how = "pinned" if g.pinned is not None else "first come"
            plant = f"plant session {g.paired:016x} ({how})"
        else:
            plant = "no plant session followed yet (first come)"
        s = (
            f"link {'lost' if self.link_lost else 'up'}: {plant}, {self.stats.frames} frames followed, "
            f"{self._frames.n_bad - g.refused_foreign} bad, {g.refused_foreign} of other plant sessions refused "
            f"({g.foreign_sessions} session(s)"
        )
        if self.statuses_foreign:
            s += f"; {self.statuses_foreign} of their statuses ignored"
        return s + f"); controller session {self.session_id:016x}"

    # -- publishing -------------------------------------------------------------------------------------------
    def _publish_command(self, hz: np.ndarray, t: float, frame_seq: int, control_status: int, armed: bool) -> None:
        """Publish ``hz`` answering frame ``frame_seq``: ``STATE_ARMED`` if armed, else ``STATE_STOP`` (zeros then).

        The payload is written in place (:class:`~omnirotor.rosmsg.convert.CommandWire`: rosbags' bytes, tested).
        """
        self.cmd_seq += 1
        self._cmd_t = t
        self._cmd_state = state = COMMAND_ARMED if armed else COMMAND_STOP
        self._pub_cmd.put_raw(
            self._cmd_wire.fill(hz, t, control_status, state, self.session_id, self.cmd_seq, frame_seq)
        )

    def _publish_status(self) -> None:
        s, m = self.stats, self._loop_msg
        m.t = self.last_t if math.isfinite(self.last_t) else 0.0
        set_stamp(m.header, m.t)
        m.periods, m.periods_late, m.overruns = s.periods, s.late, s.overruns
        m.worst_late_s = s.worst_late_s
        m.frame_to_command_p99_s = s.recent_p99_s()
        m.frames = s.frames
        g = self.plant_gate
        m.frames_bad = self._frames.n_bad - g.refused_foreign
        m.link_lost = self.link_lost
        m.plant_session_id, m.frames_foreign, m.foreign_plant_sessions = g.paired, g.refused_foreign, g.foreign_sessions
        self._pub_loop.put(m)
        if self._pub_status is not None:
            try:
                status = self.director.status()
                self._pub_status.put(self._flight_status_type(**status.to_fields()))
                if self.recorder is not None:
                    self.recorder.status(status)
                if self.live is not None:
                    self.live.status(status)
            except Exception:  # noqa: BLE001  (a status that cannot be built is skipped and counted, never fatal)
                self.stats.status_errors += 1

    def _republish_command(self, t: float) -> None:
        """The last command again (a new sequence number, the same frame it answers)."""
        if self.cmd_seq == 0 or self._cmd_t != t:
            return
        if self._cmd_state == COMMAND_ARMED and not getattr(self.director, "armed", True):  # disarmed since
            return
        self.cmd_seq += 1
        self._pub_cmd.put_raw(self._cmd_wire.with_seq(self.cmd_seq))
        self.start_answers += 1

    def _publish_wrench(self, t: float) -> None:
        log = self.controller.log
        if self._f_idx is None or log.n == 0:
            return
        row = log.data[log.n - 1]
        f = row[self._f_idx]
        m_W = row[self._R_idx].reshape(3, 3) @ row[self._m_idx]
        w = self.msgs.wrench
        set_stamp(w.header, t)
        w.wrench.force.x, w.wrench.force.y, w.wrench.force.z = (float(v) for v in f)
        w.wrench.torque.x, w.wrench.torque.y, w.wrench.torque.z = (float(v) for v in m_W)
        self._pub_wrench.put(w)

    def _keep_row(self, frame_seq: int) -> None:
        """Copy the step's log row into the batch; a full batch is published (:meth:`_flush_rows`)."""
        log = self.controller.log
        if log.n == 0:
            return
        row = log.data[log.n - 1]
        if self._rows is None or self._rows.shape[1] != row.shape[0]:
            self._flush_rows()
            self._rows = np.zeros((_ROW_BATCH, row.shape[0]))
        self._rows[self._n_rows] = row
        self._row_seq[self._n_rows] = frame_seq
        self._n_rows += 1
        if self._n_rows == _ROW_BATCH:
            self._flush_rows()

    def _flush_rows(self) -> None:
        """Publish the rows kept so far as one ``ControllerLog`` (missions: the simulator's metrics need them)."""
        k = self._n_rows
        if k == 0 or self._pub_rows is None:
            return
        m = self._row_msg
        m.frame_seq = self._row_seq[:k]
        m.n_columns = self._rows.shape[1]
        m.rows = self._rows[:k].reshape(-1)
        self._pub_rows.put(m)
        self._n_rows = 0

    def _record_period(self, frame: SensorFrame, hz: np.ndarray, cmd) -> None:
        """The period to the recording and the live view (after the command left: off its latency)."""
        log = self.controller.log
        row = log.data[log.n - 1] if cmd is not None and log.n else None
        try:
            if self.recorder is not None:
                self.recorder.period(
                    frame, hz, int(cmd.status) if cmd is not None else 0, row, plant_session=self.plant_gate.paired
                )
            if self.live is not None:
                self.live.node_period(frame, hz, row)
        except Exception:  # noqa: BLE001  (a recording or view that fails never ends the flight: counted)
            self.stats.output_errors += 1

    def close_outputs(self) -> dict:
        """Finish the recording and stop the live view (idempotent); what the recording wrote."""
        if self.recorder is None and self.live is None:
            return {}
        from omnirotor.fly.live import close_outputs

        (rec, self.recorder), (live, self.live) = (self.recorder, None), (self.live, None)
        recording = close_outputs(rec, live)
        if "error" in recording:
            self._say(recording["error"])
        return {"recording": recording} if recording else {}

    # -- the loop ---------------------------------------------------------------------------------------------
    def run(self, stop: threading.Event | None = None) -> dict:
        """Run until ``stop`` is set, Ctrl-C, the simulator finishes a mission, or ``max_frames``; the summary."""
        o = self.options
        stop = stop if stop is not None else threading.Event()
        period = o.period_s
        loss_s = o.lockstep_link_loss_s if o.lockstep else o.link_loss_s
        status_every = 1.0 / o.status_hz
        mono = time.monotonic
        director, controller, stats = self.director, self.controller, self.stats
        has_armed = hasattr(type(director), "armed")
        frames = self._frames
        last_seq = -1
        last_arrival = math.nan
        grid = math.nan  # the earliest arrival consistent with one frame per period (frame_guard_s)
        guard = o.frame_guard_s if not o.lockstep and o.frame_guard_s > 0 else 0.0
        sleep = time.sleep
        last_seen = math.nan
        last_frame: SensorFrame | None = None
        last_mocap_t = -math.inf
        next_status = 0.0
        next_gap_call = math.inf
        steps = 0
        cpu0, thread0 = time.process_time(), time.thread_time()
        freeze_gc()
        try:
            while not stop.is_set() and not self.finished:
                # asleep until a frame arrives or the next thing is due (the director's gap call, the status)
                now = mono()
                if guard and last_frame is not None and not self.link_lost:
                    # asleep on the clock until shortly before the next frame is due: a flood of bogus frames
                    # does not wake the loop meanwhile (NodeOptions.frame_guard_s)
                    wake = min(grid + period - guard, next_gap_call, next_status)
                    if wake > now:
                        sleep(wake - now)
                        now = mono()
                if o.lockstep or last_frame is None or self.link_lost:
                    timeout = min(_LOCKSTEP_WAIT_S, max(next_status - now, 0.0))
                else:
                    timeout = min(period, max(min(next_gap_call, next_status) - now, 0.0))
                msg, mocap = frames.take_latest_keeping(timeout, _has_mocap)
                now = mono()
                if mocap is not None:  # the newest frame has no sample, a skipped one had: not lost (docstring)
                    msg.mocap_new, msg.mocap_t = True, mocap.mocap_t
                    msg.mocap_p_w, msg.mocap_q_wb = mocap.mocap_p_w, mocap.mocap_q_wb
                    self.mocap_carried += 1

                if msg is None:
                    if self._idle(now, last_seen, last_frame, last_mocap_t, loss_s, next_gap_call):
                        next_gap_call = now + period
                    if o.lockstep or self.link_lost:
                        # frames paused (a lockstep plant at the end of its run, or a lost link): the rows kept
                        # so far go now, not at the next frame's status time, which may never come
                        self._flush_rows()
                    if now >= next_status:
                        next_status = now + status_every
                        self._poll_sim_status()
                        self._publish_status()
                    self._serve_requests()
                    if self.link_lost and o.exit_on_link_loss:
                        break
                    continue
                if msg.seq == 0 and self.plant_gate.start_repeated:
                    # the plant's start frame again: our answer has not reached it yet (it repeats the frame
                    # every 10 ms until it obeys one); the same answer again, nothing stepped, the link alive
                    self._republish_command(msg.t)
                    last_seen = mono()
                    continue
                # a new frame
                arrival = now
                # the start frame (0) repeats until answered: the plant's clock starts with frame 1
                advance = period * (msg.seq - last_seq) if last_seq > 0 else math.nan
                if self.link_lost:
                    self.link_lost = False
                    self._say("frames are back")
                    advance = math.nan  # a new grid
                elif last_seq >= 0 and msg.seq > last_seq + 1:
                    stats.skipped(int(msg.seq - last_seq - 1))
                arrival_late = 0.0
                if not o.lockstep and math.isfinite(last_arrival):
                    arrival_late = max(0.0, arrival - last_arrival - period)
                last_seq = self._last_seq = int(msg.seq)
                self.plant_gate.follow(last_seq)
                stats.frames += 1
                frame = self._codec.decode(msg)
                self.last_t = frame.t
                if frame.mocap_new:
                    last_mocap_t = frame.mocap_t
                mocap_age = frame.t - last_mocap_t
                ages = LinkAges(0.0, mocap_age if mocap_age >= 0 else 0.0, False)
                cmd = None
                try:
                    director.on_frame(frame, ages)
                    if director.wants_step():
                        cmd = controller.step(frame)
                        steps += 1
                except Exception:  # noqa: BLE001  (nothing raises out of the loop: the director holds)
                    stats.controller_errors += 1
                    cmd = None
                hz = director.output(cmd)
                armed = director.armed if has_armed else bool(hz.any())
                if not armed and hz.any():  # the invariant: a disarmed node commands zeros, whatever it was told
                    stats.disarmed_nonzero += 1
                    hz = self._zeros
                self._publish_command(hz, frame.t, last_seq, int(cmd.status) if cmd is not None else 0, armed)
                sent = mono()
                if self.recorder is not None or self.live is not None:
                    self._record_period(frame, hz, cmd)
                if cmd is not None:
                    if self._pub_rows is not None:
                        self._keep_row(last_seq)
                    if steps % o.wrench_every == 0:
                        self._publish_wrench(frame.t)
                stats.period(sent - arrival, sent - arrival, arrival_late, period)
                last_arrival = arrival
                due = grid + advance  # the grid moves by the frames' numbers (skipped ones too); NaN at first
                # the earliest arrivals: a late one leaves the grid; 10 periods late is the plant's new phase
                grid = due if arrival - 10 * period < due < arrival else arrival
                last_seen = sent  # the link's age counts from when this loop could see a frame again
                last_frame = frame
                next_gap_call = arrival + 2 * period
                if sent >= next_status:
                    next_status = sent + status_every
                    self._poll_sim_status()
                    self._publish_status()
                    self._flush_rows()
                self._serve_requests()
                if o.max_frames is not None and stats.frames >= o.max_frames:
                    break
        except KeyboardInterrupt:
            pass
        finally:
            thaw_gc()
        self._flush_rows()
        self._publish_status()
        out = stats.summary()
        out.update(self.close_outputs())
        out["cpu_per_frame_us"] = 1e6 * (time.process_time() - cpu0) / max(stats.frames, 1)
        out["loop_cpu_per_frame_us"] = 1e6 * (time.thread_time() - thread0) / max(stats.frames, 1)
        g = self.plant_gate
        out["frames_bad"] = self._frames.n_bad - g.refused_foreign
        out["frames_foreign"] = g.refused_foreign
        out["foreign_plant_sessions"] = g.foreign_sessions
        out["plant_session_id"] = f"{g.paired:016x}" if g.paired else None
        out["plant_session_pinned"] = g.pinned is not None
        out["plant_statuses_foreign"] = self.statuses_foreign
        out["link_lost"] = self.link_lost
        out["link_lost_after_ms"] = 1000 * self.link_lost_age_s if math.isfinite(self.link_lost_age_s) else None
        out["commands"] = self.cmd_seq
        out["start_frame_answered_again"] = self.start_answers
        out["mocap_carried"] = self.mocap_carried
        out["session_id"] = f"{self.session_id:016x}"
        out["plant_imu"] = self.plant_imu
        c = self._ctl_counts
        out["requests"] = {
            "served": self.requests_served, "busy": c.busy if c else 0, "bad": c.bad - self.requests_unserved if c
            else 0, "unserved": self.requests_unserved, "rate_hz": 1.0 / self._request_every_s,
        }  # fmt: skip
        return out

    def _idle(self, now, last_seen, last_frame, last_mocap_t, loss_s, next_gap_call) -> bool:
        """A period without a new frame: the director's failsafes (real time), link loss after ``loss_s``.

        Returns:
            True when the director was called for a period without a frame.
        """
        if self.link_lost:
            self._release_plant()
            return False
        if last_frame is None:
            return False
        age = now - last_seen
        if age > loss_s and self.options.log_rows:
            # a mission's plant stops its frames when its run ends and says so in its status, which the loop reads
            # only at the status rate: read it now, so that the end is not taken for a lost link
            self._poll_sim_status()
            if self.finished:
                return False
        if age > loss_s:
            self.link_lost = True
            self.link_lost_age_s = age
            self.stats.link_losses += 1
            self._say(f"link lost: no sensor frame for {1000 * age:.1f} ms; rotor commands stopped")
            self._call_director(last_frame, LinkAges(age, math.inf, True))
            self.plant_gate.renumber()  # the followed plant's next frame, whatever its number (module docstring)
            self._release_plant()
            self._publish_status()
            return False
        if not self.options.lockstep and now >= next_gap_call:
            mocap_age = last_frame.t - last_mocap_t + age
            self._call_director(last_frame, LinkAges(age, mocap_age, False))
            return True
        return False

    def _release_plant(self) -> None:
        """The link is lost: a first-come plant session is released once the director is disarmed (docstring)."""
        g = self.plant_gate
        if g.pinned is not None or g.paired == 0 or getattr(self.director, "armed", False):
            return
        self._say(
            f"plant session {g.paired:016x} released (link lost, disarmed): the next plant to send frames is "
            "followed (first come; --plant-session pins one)"
        )
        g.release()

    def _call_director(self, frame: SensorFrame, ages) -> None:
        try:
            self.director.on_frame(frame, ages)
        except Exception:  # noqa: BLE001
            self.stats.controller_errors += 1

    def _poll_sim_status(self) -> None:
        """The plant's status: its failsafe (the director disarms), another session it obeys (said), the end."""
        msg = self._sim_status.take_latest()
        if msg is not None and msg.failsafe:
            # the plant does not obey (its offboard-loss failsafe; PX4 out of offboard): the director disarms
            why = str(msg.cause) or "its failsafe"
            if not self._plant_failsafe:
                self._plant_failsafe = True
                self._say(f"the plant stopped obeying the commands: {why}")
            plant_failsafe = getattr(self.director, "plant_failsafe", None)
            if plant_failsafe is not None:
                try:
                    plant_failsafe(why)
                except Exception:  # noqa: BLE001  (never fatal: counted)
                    self.stats.controller_errors += 1
        elif msg is not None:
            self._plant_failsafe = False
        if msg is not None and int(msg.paired_session_id) not in (0, self.session_id, self._plant_paired_other):
            # first come: another publisher commanded first (sitl/gate.py); this node's commands are refused
            self._plant_paired_other = other = int(msg.paired_session_id)
            self._say(
                f"the plant obeys controller session {other:016x}, not this node's {self.session_id:016x}: its "
                f"commands are refused (pin the plant to this node: --pair-session {self.session_id:016x}; if "
                f"the node it obeys is gone, a restarted one, start this node with --session-id {other:016x})"
            )
        g = self.plant_gate
        own = self._status_other
        if own not in (0, g.paired, self._plant_said_other) and g.paired != 0:
            # a status on the key names another plant session than the one followed (first come: a foreign
            # publisher's frames came first; pinned: the wrong id was given; or a second plant): ignored, said
            self._plant_said_other = own
            self._say(
                f"the plant's status names plant session {own:016x}, not the followed {g.paired:016x}: its frames "
                f"and its status are ignored (follow it: --plant-session {own:016x})"
            )
        if msg is not None:
            self._plant_imu_status(msg)
        if msg is not None and msg.finished and self.options.log_rows:
            self._finish_seq = int(msg.steps)  # its last frame's number: answered before the loop ends
        if self._last_seq >= self._finish_seq:
            self.finished = True

    def _plant_imu_status(self, msg) -> None:
        """The plant's IMU counts (a robot bridge's watch of PX4's IMU; 0 from the simulator): kept, news said."""
        was = self.plant_imu
        now = self.plant_imu = {
            "rate_off_episodes": int(msg.imu_rate_off_episodes),
            "rate_off_s": float(msg.imu_rate_off_s),
            "gaps": int(msg.imu_gaps),
            "worst_gap_ms": 1000.0 * float(msg.imu_worst_gap_s),
        }
        if now["rate_off_episodes"] > (was["rate_off_episodes"] if was else 0):
            self._say(f"the plant says its IMU rate is off the control rate ({now['rate_off_episodes']} time(s), "
                      f"{now['rate_off_s']:.1f} s in all): the controller integrates the real intervals")  # fmt: skip
        if now["gaps"] and not (was and was["gaps"]):
            self._say(f"the plant says its IMU stream paused (worst {now['worst_gap_ms']:.0f} ms so far); gaps are "
                      "counted in the summary (plant_imu)")  # fmt: skip
        if self.recorder is not None:
            self.recorder.plant_status(msg, self.last_t)


def _has_mocap(msg) -> bool:
    return bool(msg.mocap_new)


def warm_up(controller, trajectory=None) -> None:
    """Compile (or load from numba's cache) the controller's kernels before the first real frame.

    One reset and one step on a synthetic hover frame, with ``trajectory`` (the one the flight will reset with,
    so that the controller's record is already sized for it and the director's reset compiles nothing; a
    hover at the frame's pose when None); the controller's next :meth:`reset` (the director's, on the first
    real frame) starts it anew and clears its log. Best effort: a controller that refuses the synthetic frame
    (the bypass estimator wants a state) compiles on its first real frame instead.
    """
    from omnirotor.control.trajectory import PoseTrajectory, Waypoint

    vehicle = controller.vehicle
    u = vehicle.hover_input()
    hz = np.sign(u) * np.sqrt(np.abs(u))
    p_W = np.array([0.0, 0.0, 1.0])
    acc = np.array([0.0, 0.0, 9.81])
    q = np.array([1.0, 0.0, 0.0, 0.0])
    first = SensorFrame(0.0, acc, np.zeros(3), hz.copy(), True, 0.0, p_W, q)
    second = SensorFrame(controller.params.dt, acc, np.zeros(3), hz.copy(), False)
    if trajectory is None:
        trajectory = PoseTrajectory([Waypoint(0.0, p_W + np.asarray(vehicle.p_E_B_array), np.eye(3))])
    try:
        controller.reset(first, trajectory)
        controller.step(second)
    except Exception:  # noqa: BLE001,S110  (best effort, see the docstring)
        pass
    controller.log.clear()


# -- missions: a task of `omnirotor sim --serve --task`, flown by the node ------------------------------------------


class _MissionFlown(Exception):  # noqa: N818  (control flow: the task's own metrics are the simulator's to compute)
    def __init__(self, summary: dict) -> None:
        super().__init__("mission flown")
        self.summary = summary


def mission_from_sim(transport: Transport, timeout_s: float = 10.0) -> tuple[str, dict, bool, int | None]:
    """Ask the simulator which task it serves; ``(task, options as a dict, lockstep, its plant session)``.

    The plant session is the one of the simulator that answered (None from a simulator that does not say it).

    Raises:
        InputError: no simulator answered within ``timeout_s``, or its answer is not a mission.
    """
    import json

    T = typestore().types
    rep = transport.request(
        TOPICS["mission"], "std_msgs/msg/String", T["std_msgs/msg/String"](data=""), "std_msgs/msg/String", timeout_s
    )
    if rep is None:
        raise InputError(
            f"no simulator served a mission within {timeout_s:g} s (is `omnirotor sim --serve --task` up?)"
        )
    try:
        mission = json.loads(rep.data)
        task, options, lockstep = mission["task"], mission["options"], mission["lockstep"]
        if not isinstance(task, str) or not isinstance(options, dict) or not isinstance(lockstep, bool):
            raise TypeError
        served_by = mission.get("plant_session")
        plant = parse_session_id(served_by, "plant_session") if served_by is not None else None
    except (ValueError, KeyError, TypeError, AttributeError):
        raise InputError("the simulator's mission is not a task and its options") from None
    return task, options, lockstep, plant


def fly_mission(
    transport: Transport,
    task: str,
    options: dict,
    node_options: NodeOptions,
    director_factory: Callable[[Any, Any], Any],
    realtime: Callable[[], None] | None = None,
) -> dict:
    """Fly the simulator's task: build its controller and trajectory as ``omnirotor run`` does, fly them here.

    The task function runs with :func:`~omnirotor.experiments.loop.loop_override`: where it would fly in
    process, this node's loop flies its controller (``director_factory(controller, trajectory)``) against the
    remote plant, publishing its log rows; the task's metrics are then the simulator's to compute.

    Returns:
        The loop's summary.
    """
    from omnirotor.experiments.loop import loop_override
    from omnirotor.experiments.tasks import run_task
    from omnirotor.experiments.tasks.common import ExperimentOptions

    known = {f.name for f in dataclasses.fields(ExperimentOptions)}
    unknown = sorted(set(options) - known)
    if unknown:
        raise InputError(f"the simulator's mission has options this node does not know: {', '.join(unknown)}")
    fields = {k: tuple(v) if isinstance(v, list) else v for k, v in options.items()}
    opts = ExperimentOptions(**fields)
    node_options = dataclasses.replace(node_options, log_rows=True, exit_on_link_loss=True)

    def loop(sim, controller, trajectory, duration_s, progress=None, video=None, on_step=None):
        del sim, progress, video, on_step  # the plant is the simulator's
        controller.log.ensure_capacity(int(round(duration_s / controller.params.dt)))
        warm_up(controller, trajectory)
        node = NodeLoop(transport, controller, director_factory(controller, trajectory), node_options)
        if realtime is not None and not node_options.lockstep:  # lockstep polls without pause: no real-time class
            realtime()
        raise _MissionFlown(node.run())

    try:
        with loop_override(loop):
            run_task(task, opts)
    except _MissionFlown as flown:
        return flown.summary
    raise InputError(f"task {task!r} did not fly a closed loop")
