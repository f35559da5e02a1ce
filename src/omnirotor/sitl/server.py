"""``omnirotor sim --serve``: the MuJoCo plant in its own process, on the flight topics (issue 24, item 3).

Topics (ROS 2 names, in the transport's namespace; types in :mod:`omnirotor.rosmsg`):

    /omnirotor/frame            omnirotor_msgs/msg/SensorFrame   every period: IMU, motion capture (at its rate
                                                                 and latency), rotor speeds; float64, exact time
    /omnirotor/imu              sensor_msgs/msg/Imu              every period (ROS view)
    /omnirotor/mocap            geometry_msgs/msg/PoseStamped    when a motion-capture sample arrives (ROS view)
    /omnirotor/rotor_speeds     omnirotor_msgs/msg/RotorSpeeds   every period (ROS view)
    /omnirotor/sim_status       omnirotor_msgs/msg/SimStatus     about 50 Hz
    /omnirotor/rotor_cmd        omnirotor_msgs/msg/RotorCommand  consumed: obeyed from the paired session only
    /omnirotor/controller_log   omnirotor_msgs/msg/ControllerLog consumed: the obeyed node's log rows (missions)
    /omnirotor/mission          std_msgs/msg/String (request/reply): the task this server flies, as JSON

A *task* (``--task``, every task of ``omnirotor run``) runs the task function of ``omnirotor run`` unchanged —
its plant, protocol and metrics — with the in-process controller step replaced by the wire
(:func:`omnirotor.experiments.loop.loop_override`): frame ``k`` goes out, command ``k`` comes back from the
node (which flies the same task: ``omnirotor fly --mission-from-sim``), the plant steps under it. The controller
object the task builds here never steps; it only holds the log rows the node sends back, from which the task
computes its metrics as ``omnirotor run`` does.

Clocks: ``lockstep`` steps the plant when the command answering the last frame has arrived (deterministic: the
run is the in-process run's to the last bit); otherwise the plant steps on the wall clock at its period, and a
period without a new command holds the last one, as an ESC does. Either way the plant starts with the first
command obeyed (it publishes its start frame until then), and when no command has been obeyed for
``offboard_loss_s`` (0.5 s; in lockstep 5 s of wall time, so that a descheduled process does not end a
deterministic run) the offboard-loss failsafe stops the rotors, says so on stderr and in its status; a lockstep
run then goes on in real time.

Only an armed node's speeds are flown: a command flagged ``STATE_STOP`` (the node disarmed: landed, stopped by a
failsafe or its operator, link lost) is obeyed as zeros whatever speeds it carries (counted when they were not
zeros), and held as zeros; a robot bridge does the same (:mod:`omnirotor.fly.px4`).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import sys
import threading
import time
from collections.abc import Callable

import numpy as np

from omnirotor.errors import InputError
from omnirotor.messages import RotorCommand
from omnirotor.realtime import freeze_gc, set_transport_priority, thaw_gc
from omnirotor.recorder import Recorder
from omnirotor.rosmsg import typestore
from omnirotor.rosmsg.convert import (
    COMMAND,
    COMMAND_ARMED,
    CONTROLLER_LOG,
    FRAME,
    IMU,
    POSE,
    SIM_STATUS,
    SPEEDS,
    STRING,
    CommandWire,
    FrameCodec,
    FrameEncoder,
    WireMessages,
    command_check,
    set_stamp,
)
from omnirotor.sitl.gate import CommandGate, new_session_id
from omnirotor.transport import Transport

__all__ = [
    "ServeOptions", "SimLink", "SitlReport", "serve_task", "serve_free", "stand_in_rows", "TOPICS",
    "MISSION_OPTION_FIELDS",
]  # fmt: skip

TOPICS = {
    "frame": "/omnirotor/frame",
    "imu": "/omnirotor/imu",
    "mocap": "/omnirotor/mocap",
    "rotor_speeds": "/omnirotor/rotor_speeds",
    "sim_status": "/omnirotor/sim_status",
    "rotor_cmd": "/omnirotor/rotor_cmd",
    "controller_log": "/omnirotor/controller_log",
    "mission": "/omnirotor/mission",
    "status": "/omnirotor/status",
    "loop_status": "/omnirotor/loop_status",
    "wrench_est": "/omnirotor/wrench_est",
    "ctl": "/omnirotor/ctl",
}
"""Every topic of the flight node and the simulator, by short name (ROS 2 names, before the namespace)."""

MISSION_OPTION_FIELDS = (
    "solver", "estimator", "duration_s", "seed", "truth", "vehicle", "controller_config", "overrides",
    "disturbances", "map_mode", "maps", "blend", "quick", "zero_observer", "sim_overrides",
)  # fmt: skip
"""The options of a task that travel to the node with the mission (both sides build the same task)."""

_COMMAND_DEPTH = 64
_LOG_DEPTH = 1 << 15
_START_REPEAT_S = 0.01
"""The start frame is repeated this often until a command answering it is obeyed [s] (well inside the node's
50 ms link loss: each repetition is answered again and keeps its link alive)."""
_LOCKSTEP_WAIT_S = 0.05  # lockstep: the longest sleep on the command queue before the failsafe's clock is read [s]


@dataclasses.dataclass(frozen=True)
class ServeOptions:
    """How the server runs.

    Attributes:
        lockstep: step k+1 only when command k arrived (deterministic); False: on the wall clock.
        offboard_loss_s: no command obeyed for this long stops the rotors [s] (real time).
        lockstep_offboard_loss_s: the same in lockstep, where the plant waits for each command [s]: a test
            harness on a loaded machine must not fail a deterministic run because a process was descheduled.
        start_timeout_s: how long to wait for the node's first command before giving up [s].
        status_hz: SimStatus rate [Hz].
        ros_views: also publish the standard ROS views (Imu, PoseStamped, RotorSpeeds) every period.
        row_wait_s: at the end of a run, how long to wait for the node's last log rows [s].
        record: a ROS 2 bag to record the plant into (a new folder): every period's frame, the speeds it flew
            and its ground truth (``/omnirotor/pose`` is the true pose), streamed from a writer process; or None.
        foxglove_port: serve the simulator's live view (true pose, contact, rotors) on this loopback port (0: any
            free one), or None.
        pair_session: obey this controller session only, from the first command (``--pair-session``: pinned
            pairing, :mod:`omnirotor.sitl.gate`); None: the first session that commands is paired.
        session_id: this plant's session, carried by every frame (``--session-id``; a node's ``--plant-session``
            follows this plant only: :mod:`omnirotor.sitl.gate`); None: random.
        transport_priority: ``SCHED_FIFO`` priority of the process's other threads (the transport's), given once
            the link's publishers and subscribers are declared (:func:`omnirotor.realtime.set_transport_priority`,
            called from the loop's thread); None: not asked. Real time only.
    """

    lockstep: bool = False
    offboard_loss_s: float = 0.5
    lockstep_offboard_loss_s: float = 5.0
    start_timeout_s: float = 60.0
    status_hz: float = 50.0
    ros_views: bool = True
    row_wait_s: float = 2.0
    record: str | None = None
    foxglove_port: int | None = None
    pair_session: int | None = None
    session_id: int | None = None
    transport_priority: int | None = None

    def __post_init__(self) -> None:
        for name in ("offboard_loss_s", "lockstep_offboard_loss_s", "start_timeout_s", "status_hz", "row_wait_s"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a finite number > 0, got {v!r}")


@dataclasses.dataclass
class SitlReport:
    """What the server counted during a run (printed at its end, added to the run's JSON as ``sitl``)."""

    lockstep: bool = False
    steps: int = 0
    commands_obeyed: int = 0
    commands_held: int = 0
    commands_refused: int = 0
    stop_with_speeds: int = 0
    foreign_sessions: int = 0
    plant_session_id: str = ""
    """This plant's session (its frames' ``session_id``, hex): what a node's ``--plant-session`` takes."""
    bad_payloads: int = 0
    failsafe: bool = False
    failsafe_after_s: float | None = None
    log_rows_missing: int = 0
    """Controller-log rows that never arrived (:func:`stand_in_rows`): stood in, or cut (``log_rows_cut``)."""
    log_rows_cut: int = 0
    """Of them, the periods after the node's last row when the failsafe cut the run: the log ends before them."""
    recording: dict = dataclasses.field(default_factory=dict)
    metrics_error: str = ""
    late_steps: int = 0
    wall_s: float = 0.0
    real_time_factor: float = 0.0
    round_trip_us: dict = dataclasses.field(default_factory=dict)
    """Frame out -> command in [µs] (p50, p99, max) in lockstep; empty in real time (:func:`_sleep_until`)."""
    flown: tuple | None = dataclasses.field(default=None, repr=False, compare=False)
    """``(controller log, truth log)`` of a run the failsafe cut (no task result carries them); not in the JSON."""

    def as_dict(self) -> dict:
        """A JSON-ready dict (without :attr:`flown`)."""
        return copy.deepcopy({f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "flown"})


class RunCut(Exception):  # noqa: N818  (not an error of the program: the run was cut, said by the caller)
    """The offboard-loss failsafe cut a task's run: its metrics are over its whole protocol, so there are none."""


class SimLink:
    """The simulator's side of the wire for one vehicle: frames out, commands in through the gate, status.

    Args:
        transport: an open transport.
        n_rotors: the vehicle's rotors.
        options: the server's options.
    """

    def __init__(self, transport: Transport, n_rotors: int, options: ServeOptions) -> None:
        self.options = options
        self.n = n_rotors
        self.msgs = WireMessages(n_rotors)
        self.session_id = options.session_id if options.session_id is not None else new_session_id()
        self._frame_wire = FrameEncoder(n_rotors, session_id=self.session_id)
        self._pub_frame = transport.publisher(TOPICS["frame"], FRAME, block=options.lockstep)
        self._views = (
            (transport.publisher(TOPICS["imu"], IMU), transport.publisher(TOPICS["mocap"], POSE),
             transport.publisher(TOPICS["rotor_speeds"], SPEEDS))
            if options.ros_views else None
        )  # fmt: skip
        self._pub_status = transport.publisher(TOPICS["sim_status"], SIM_STATUS)
        self._sub_cmd = transport.subscriber(
            TOPICS["rotor_cmd"], COMMAND, depth=_COMMAND_DEPTH, check=command_check(n_rotors),
            decoder=CommandWire(n_rotors).decode,
        )  # fmt: skip
        self.gate = gate = CommandGate(pinned=options.pair_session)
        # the rows of the controller session obeyed only: another process's rows never enter the run's metrics
        self._sub_rows = transport.subscriber(
            TOPICS["controller_log"], CONTROLLER_LOG, depth=_LOG_DEPTH,
            check=lambda msg: gate.paired != 0 and int(msg.session_id) == gate.paired,
        )  # fmt: skip
        self.rows_malformed = 0
        self.stale_commands = 0
        self.stop_nonzero = 0
        """Commands of the paired session flagged ``STATE_STOP`` whose speeds were not zeros (zeros were flown)."""
        self.cmd_hz = np.zeros(n_rotors)
        self.cmd_frame_seq = -1
        self.cmd_wall_s = -math.inf  # monotonic time of the last obeyed command
        self.cmd_t = 0.0
        T = typestore().types
        self._status = T[SIM_STATUS](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="world"),
            t=0.0, steps=0, lockstep=options.lockstep, failsafe=0, cause="", paired_session_id=0, commands_obeyed=0,
            commands_held=0, commands_refused=0, foreign_sessions=0, bad_payloads=0, command_age_s=math.inf,
            finished=False, plant_session_id=self.session_id,
            imu_rate_off_episodes=0, imu_rate_off_s=0.0, imu_gaps=0, imu_worst_gap_s=0.0,
        )  # fmt: skip
        self._status_every_s = 1.0 / options.status_hz
        self._status_next = 0.0

    @property
    def bad_payloads(self) -> int:
        """Bad payloads on the command and log keys: undecodable, malformed, or rows of another session."""
        return self._sub_cmd.n_bad + self._sub_rows.n_bad + self.rows_malformed

    def send_frame(self, record: np.ndarray, seq: int) -> None:
        """Publish a frame record as ``SensorFrame`` number ``seq`` (:class:`FrameEncoder`), and its ROS views."""
        self._pub_frame.put_raw(self._frame_wire.encode(record, seq))
        if self._views is not None:
            imu, pose, speeds = self._views
            m = self.msgs
            m.fill_views(record)
            imu.put(m.imu)
            if record[0]["mocap"]["new"] != 0.0:
                pose.put(m.pose)
            speeds.put(m.speeds)

    def poll_commands(self, timeout_s: float = 0.0) -> bool:
        """Take every queued command through the gate; True if one was obeyed (the newest obeyed is kept).

        Args:
            timeout_s: wait (asleep) up to this long [s] for a first command.
        """
        got = False
        msg = self._sub_cmd.take(timeout_s)
        while msg is not None:
            if int(msg.session_id) == self.gate.paired and int(msg.frame_seq) <= self.cmd_frame_seq:
                # an answer to a frame already answered (the repeated start frame's second answer), or to an older
                self.stale_commands += 1
            elif self.gate.offer(int(msg.session_id), int(msg.seq)):
                if int(msg.state) == COMMAND_ARMED:
                    self.cmd_hz[:] = msg.hz
                else:  # the node is disarmed (landed, stopped): zeros, whatever speeds the message carries
                    if msg.hz.any():
                        self.stop_nonzero += 1
                    self.cmd_hz.fill(0.0)
                self.cmd_frame_seq = int(msg.frame_seq)
                self.cmd_t = float(msg.t)
                self.cmd_wall_s = time.monotonic()
                got = True
            msg = self._sub_cmd.take()
        return got

    def drain_rows(self, store: Callable[[int, np.ndarray], None]) -> None:
        """Hand every queued controller-log row (they come in batches) to ``store(frame_seq, row)``."""
        while (msg := self._sub_rows.take()) is not None:
            n, k = int(msg.n_columns), len(msg.frame_seq)
            if n <= 0 or msg.rows.size != n * k:
                self.rows_malformed += 1
                continue
            rows = msg.rows.reshape(k, n)
            for seq, row in zip(msg.frame_seq, rows, strict=True):
                store(int(seq), row)

    def send_status(self, t: float, steps: int, held: int, failsafe: bool, cause: str, finished: bool = False,
                    force: bool = False) -> None:  # fmt: skip
        """Publish SimStatus when due (about ``status_hz``), or now with ``force``."""
        now = time.monotonic()
        if not force and now < self._status_next:
            return
        self._status_next = now + self._status_every_s
        s = self._status
        s.t = t
        set_stamp(s.header, t)
        s.steps = steps
        s.failsafe = 1 if failsafe else 0
        s.cause = cause
        s.paired_session_id = self.gate.paired
        s.commands_obeyed = self.gate.obeyed
        s.commands_held = held
        s.commands_refused = self.gate.refused
        s.foreign_sessions = self.gate.foreign_sessions
        s.bad_payloads = self.bad_payloads
        s.command_age_s = now - self.cmd_wall_s
        s.finished = finished
        self._pub_status.put(s)


class SimOutputs:
    """The plant's recording and live view (:attr:`ServeOptions.record`, :attr:`ServeOptions.foxglove_port`).

    :meth:`period` is called after each plant step, with the speeds the plant flew; nothing when neither is on.
    """

    def __init__(self, sim, options: ServeOptions, say: Callable[[str], None]) -> None:
        from omnirotor.experiments.loop import TRUTH_GROUPS

        n = sim.vehicle.n_rotors
        self._sim = sim
        self._codec = FrameCodec(n, sim.frame_record)
        self._session = options.session_id or 0
        columns = Recorder(1, TRUTH_GROUPS(n)).column_names
        self._row = np.zeros(len(columns))
        self.recorder = self.live = None
        self.errors = 0
        if options.record is not None or options.foxglove_port is not None:
            from omnirotor.fly.live import open_outputs

            self.recorder, self.live = open_outputs(options.record, options.foxglove_port, n, columns, say)
        self.active = self.recorder is not None or self.live is not None

    def period(self, cmd_hz: np.ndarray) -> None:
        """The period just stepped: its frame, the speeds flown and the ground truth."""
        sim = self._sim
        try:
            if self.recorder is not None:
                sim.truth_row(self._row)
                self.recorder.period(self._codec.refresh(), cmd_hz, 0, self._row, plant_session=self._session)
            if self.live is not None:
                self.live.sim_period(sim.t, sim.truth)
        except Exception:  # noqa: BLE001  (a recording or a view that fails never stops the plant: counted)
            self.errors += 1

    def close(self) -> dict:
        """Finish the recording, stop the live view (idempotent); what the recording wrote."""
        from omnirotor.fly.live import close_outputs

        (rec, self.recorder), (live, self.live) = (self.recorder, None), (self.live, None)
        self.active = False
        return close_outputs(rec, live)


def _percentiles_us(samples: np.ndarray) -> dict:
    if samples.size == 0:
        return {}
    p50, p99 = np.percentile(samples, [50, 99])
    return {"p50": float(p50), "p99": float(p99), "max": float(samples.max()), "n": int(samples.size)}


def remote_loop(link: SimLink, report: SitlReport) -> Callable:
    """A replacement of :func:`~omnirotor.experiments.loop.run_closed_loop` that flies over ``link``.

    Same arguments and result; ``video`` is not supported (refused), ``on_step`` is called as there.
    """

    def loop(sim, controller, trajectory, duration_s, progress=None, video=None, on_step=None):
        from omnirotor.experiments.loop import TRUTH_GROUPS, start_pose_of

        if video is not None:
            raise InputError("--video is not available with the simulator served on the wire")
        if not (math.isfinite(duration_s) and duration_s > 0):
            raise InputError(f"duration must be a finite number of seconds > 0, got {duration_s}")
        dt = sim.dt
        n_steps = int(round(duration_s / dt))
        p0, R0 = start_pose_of(trajectory, controller.vehicle)
        # compile (or load) the plant's kernels now, not while the node waits for frame 1; reset repeats exactly
        sim.reset(p_W=p0, R_WB=R0)
        sim.step(RotorCommand(0.0, sim.hover_speeds_hz(R0)))
        sim.reset(p_W=p0, R_WB=R0)
        log = controller.log
        log.clear()
        log.ensure_capacity(n_steps)
        have_row = np.zeros(n_steps, dtype=bool)
        truth_log = Recorder(n_steps, TRUTH_GROUPS(controller.vehicle.n_rotors))

        def store_row(frame_seq: int, row: np.ndarray) -> None:
            j = frame_seq - 1  # the step on frame j writes the controller's log row j - 1
            if 0 <= j < n_steps and row.shape == (log.n_signals,):
                log.data[j] = row
                have_row[j] = True

        outputs = SimOutputs(sim, link.options, _say)
        try:
            _run(link, report, sim, n_steps, truth_log, store_row, progress, on_step, outputs)
        finally:
            report.recording = outputs.close()
        # the last rows may still be on their way
        end = time.monotonic() + link.options.row_wait_s
        while not have_row.all() and time.monotonic() < end and not report.failsafe:
            link.drain_rows(store_row)
            time.sleep(0.001)
        link.drain_rows(store_row)
        report.log_rows_missing, report.log_rows_cut = stand_in_rows(log, have_row, dt, end_at_last=report.failsafe)
        if report.failsafe:  # the vehicle fell with its rotors stopped: not the task's protocol, no metric of it
            report.flown = (log, truth_log)
            t_end = float(log.data[log.n - 1, log.column_names.index("t")])
            raise RunCut(
                f"the node's last controller row is at t = {t_end:.3f} s of the task's {duration_s:g} s, and a "
                "task's metrics are over its whole protocol"
            )
        return log, truth_log

    return loop


def stand_in_rows(log: Recorder, have_row: np.ndarray, dt: float, end_at_last: bool = False) -> tuple[int, int]:
    """Fill the controller-log rows that never arrived (``~have_row``) with stand-ins.

    Each stand-in is the previous row (the first received one before it) with its own period's time: the time
    column ``t`` is the nearest earlier received row's plus ``dt`` per period (the first received row's minus
    ``dt`` per period before it), so that the log's time keeps increasing and a metric masked by time sees a
    stand-in at the instant it stands for, not twice at the old one.

    With ``end_at_last`` (the offboard-loss failsafe cut the run: the node stopped commanding) the rows after the
    node's last one are not stood in: the controller flew none of those periods, so the log ends with its last
    row (``log.n``), and a metric whose window lies past it cannot be computed, as in an in-process run that
    stopped there. Both counts are said by the caller (``log_rows_missing``, ``log_rows_cut``).

    Args:
        log: the controller log; rows ``[0, len(have_row))`` are filled in place and ``log.n`` set.
        have_row: which rows arrived.
        dt: the period between two rows [s] (the plant's frame period).
        end_at_last: end the log at the last received row.

    Returns:
        ``(rows missing, of them cut from the log's end)``.

    Raises:
        InputError: no row arrived at all (the run has no metrics).
    """
    n = have_row.size
    missing = np.flatnonzero(~have_row)
    if missing.size == n:
        raise InputError("the flight node sent no controller log rows: the run has no metrics")
    end = n - int(np.argmax(have_row[::-1])) if end_at_last else n  # one past the last received row
    t = log.column_names.index("t")
    data = log.data
    first = int(np.argmax(have_row))
    for j in missing[missing < end]:  # ascending: a row before j is received or already stood in
        if j > first:
            data[j] = data[j - 1]
            data[j, t] = data[j - 1, t] + dt
        else:
            data[j] = data[first]
            data[j, t] = data[first, t] - (first - j) * dt
    log.n = end
    return int(missing.size), n - end


def _run(link: SimLink, report: SitlReport, sim, n_steps: int, truth_log, store_row, progress, on_step,
         outputs: SimOutputs) -> None:  # fmt: skip
    """Step the plant ``n_steps`` periods over the link (module docstring), filling the truth log."""
    opts = link.options
    dt = sim.dt
    record = sim.frame_record
    every = max(1, n_steps // 100)
    rtt = np.zeros(n_steps)
    cmd = RotorCommand(0.0, link.cmd_hz)
    zeros = np.zeros(link.n)
    lockstep = opts.lockstep
    held = 0
    freeze_gc()  # now, not between the first command and the first step
    # wait for the node: the start frame goes out every 10 ms until a command answering it is obeyed
    deadline = time.monotonic() + opts.start_timeout_s
    next_send = 0.0
    try:
        while link.cmd_frame_seq != 0:
            now = time.monotonic()
            if now > deadline:
                raise InputError(
                    f"no controller answered within {opts.start_timeout_s:g} s (is `omnirotor fly` running?)"
                )
            if now >= next_send:
                link.send_frame(record, 0)
                link.send_status(float(record["t"][0]), 0, 0, False, "", force=True)
                next_send = now + _START_REPEAT_S
            link.poll_commands()
            time.sleep(0.0005)
        wall0 = time.monotonic()
        sent_at = wall0
        failsafe = False
        for k in range(n_steps):
            # the command of frame k
            if not failsafe:
                if lockstep:
                    while True:
                        link.poll_commands(_LOCKSTEP_WAIT_S)
                        if link.cmd_frame_seq >= k:
                            break
                        now = time.monotonic()
                        if now - link.cmd_wall_s > opts.lockstep_offboard_loss_s:
                            failsafe = _engage(link, report, now)
                            break
                    rtt[k] = (link.cmd_wall_s - sent_at) * 1e6
                else:
                    due = wall0 + k * dt
                    _sleep_until(due, link)
                    now = time.monotonic()
                    if now - due > 0.0005:
                        report.late_steps += 1
                    rtt[k] = np.nan  # taken at the period, not as it arrived (_sleep_until): the node's figure
                    if link.cmd_frame_seq != k:
                        held += 1
                    if now - link.cmd_wall_s > opts.offboard_loss_s:
                        failsafe = _engage(link, report, now)
            if failsafe:
                if lockstep:  # the rest of a lockstep run in real time, rotors stopped
                    _sleep_until(wall0 + k * dt, None)
                cmd = RotorCommand(cmd.t, zeros)
            else:
                cmd = RotorCommand(link.cmd_t, link.cmd_hz)
            if on_step is not None:
                on_step(sim, sim.t)
            sim.step(cmd)
            if outputs.active:
                outputs.period(cmd.omega_hz)
            row = truth_log.next_row()
            if row is not None:
                sim.truth_row(row)
                row[-2] = 0.0
                row[-1] = rtt[k] if math.isfinite(rtt[k]) else 0.0
            link.send_frame(record, k + 1)
            sent_at = time.monotonic()
            link.drain_rows(store_row)
            link.send_status(sim.t, k + 1, held, failsafe, "offboard loss" if failsafe else "")
            if progress is not None and (k + 1) % every == 0:
                progress((k + 1) / n_steps)
        wall = time.monotonic() - wall0
    finally:
        thaw_gc()
    report.lockstep = lockstep
    report.steps = n_steps
    report.commands_obeyed = link.gate.obeyed
    report.commands_held = held
    report.commands_refused = link.gate.refused
    report.stop_with_speeds = link.stop_nonzero
    report.foreign_sessions = link.gate.foreign_sessions
    report.plant_session_id = f"{link.session_id:016x}"
    report.bad_payloads = link.bad_payloads
    report.wall_s = wall
    report.real_time_factor = n_steps * dt / wall if wall > 0 else math.inf
    report.round_trip_us = _percentiles_us(rtt[np.isfinite(rtt) & (rtt > 0)])
    for _ in range(3):  # the end, said a few times (a best-effort status)
        link.send_status(sim.t, n_steps, held, failsafe, "offboard loss" if failsafe else "", True, force=True)
        time.sleep(0.01)
    if progress is not None:
        progress(1.0)


def _resting_pose(sim, p0: np.ndarray, R0: np.ndarray, say: Callable[[str], None],
                  settle_s: float = 4.0) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Where the vehicle comes to rest on the floor when dropped (rotors stopped) from ``(p0, R0)``.

    An interactive flight starts (and lands) on the ground, as a robot does, not held in the air at the task's
    start height: a landing there would disarm in the air. A scene without a floor under the start (the vehicle
    still falling, or 3 m down, after ``settle_s`` of simulated time) keeps ``(p0, R0)``, said.
    """
    zeros = np.zeros(sim.vehicle.n_rotors)
    sim.reset(p_W=p0, R_WB=R0, omega_hz=zeros)
    stop = RotorCommand(0.0, zeros)
    still = 0
    for _ in range(int(round(settle_s / sim.dt))):
        sim.step(stop)
        truth = sim.truth
        if float(p0[2] - truth.p_W[2]) > 3.0:
            break
        still = still + 1 if float(np.linalg.norm(truth.v_W)) < 1e-3 else 0
        if still * sim.dt >= 0.2:
            return truth.p_W.copy(), np.asarray(truth.R_WB).copy()
    say("no floor under the scene's start pose: the vehicle waits held in the air there")
    return p0, R0


def _say(line: str) -> None:
    print(f"omnirotor sim: {line}", file=sys.stderr)


def _engage(link: SimLink, report: SitlReport, now: float) -> bool:
    """The offboard-loss failsafe: rotors stopped, said once, the pairing released."""
    age = now - link.cmd_wall_s
    report.failsafe = True
    report.failsafe_after_s = age
    print(
        f"omnirotor sim: no rotor command for {age * 1000:.0f} ms: rotors stopped (offboard-loss failsafe)",
        file=sys.stderr,
    )
    link.gate.release()
    link.send_status(float("nan"), 0, 0, True, "offboard loss", force=True)
    return True


def _sleep_until(when: float, link: SimLink | None) -> None:
    """Sleep on the clock until the monotonic time ``when``, then take every command ``link`` received meanwhile.

    One wake-up per period, at the period (the commands wait in the transport's channel meanwhile): the plant's
    step keeps the clock's precision, and the simulator's CPU is not woken by each command (on a 2-core machine it
    is the node's). The price: in real time the simulator does not see when a command arrived, only that it did
    by the period's time (its round trip is the node's frame-to-command figure).
    """
    left = when - time.monotonic()
    if left > 0:
        time.sleep(left)
    if link is not None:
        link.poll_commands()


def mission_json(task: str, options, lockstep: bool, plant_session: int = 0) -> str:
    """The mission the server flies, as the JSON the node's ``--mission-from-sim`` reads.

    ``plant_session``: the server's own session (its frames'), so that the node knows which plant served it.
    """
    fields = {name: getattr(options, name) for name in MISSION_OPTION_FIELDS}
    session = f"{plant_session:016x}" if plant_session else None
    return json.dumps({"task": task, "options": fields, "lockstep": lockstep, "plant_session": session})


def serve_task(
    transport: Transport,
    task: str,
    options,
    serve: ServeOptions,
    progress: Callable[[float], None] | None = None,
) -> tuple[object, SitlReport]:
    """Fly ``task`` (an ``omnirotor run`` task with its ``ExperimentOptions``) with the controller on the wire.

    Returns:
        ``(the task's result, the server's report)``; the result is None when the offboard-loss failsafe cut
        the run: the task's metrics cannot be computed from the part flown (why: ``report.metrics_error``; the
        logs of what was flown: ``report.flown``); otherwise its summary is the run's JSON as ``omnirotor run``
        gives it (its timing entries are the wire's: the truth log's ``controller_step_us`` is the frame-to-command
        round trip in lockstep; 0 in real time, where the node's summary has it as its frame-to-command figure).

    Raises:
        InputError: bad options, or no controller within ``serve.start_timeout_s``.
    """
    from omnirotor.experiments.loop import loop_override
    from omnirotor.experiments.tasks import run_task
    from omnirotor.vehicle import load_vehicle

    vehicle = load_vehicle(options.vehicle)
    link = SimLink(transport, vehicle.n_rotors, serve)
    if not serve.lockstep:
        set_transport_priority(serve.transport_priority, _say)  # the link's threads exist now (ServeOptions)
    T = typestore().types
    mission = mission_json(task, options, serve.lockstep, link.session_id)
    transport.serve(TOPICS["mission"], STRING, STRING, lambda req: T[STRING](data=mission))
    report = SitlReport(lockstep=serve.lockstep)
    with loop_override(remote_loop(link, report)):
        try:
            result = run_task(task, options, progress=progress)
        except InputError:
            raise
        except Exception as exc:  # noqa: BLE001  (only after the failsafe cut the run: its metrics are undefined)
            if not report.failsafe:
                raise
            report.metrics_error = str(exc) if isinstance(exc, RunCut) else f"{type(exc).__name__}: {exc}"
            return None, report
    return result, report


def serve_free(
    transport: Transport,
    sim,
    serve: ServeOptions,
    stop: threading.Event | None = None,
    say: Callable[[str], None] = lambda line: print(f"omnirotor sim: {line}", file=sys.stderr),
) -> SitlReport:
    """Interactive flight (no task): the plant on its stand until the paired node commands rotor speeds.

    The plant starts where the vehicle comes to rest when dropped, rotors stopped, from the scene's start pose (on
    the scene's floor: :func:`_resting_pose`), *held* there: not stepped, its start frame published every period
    (fresh numbers, the same time), so that the node can ``arm`` on it and lands back on a floor. The first nonzero
    command of the paired session (the take-off's hover command) releases it; from then on it steps on the wall
    clock, a missing command held, the offboard-loss failsafe as in a task. Runs until ``stop`` or Ctrl-C; records
    (``serve.record``) and serves the live view (``serve.foxglove_port``) when asked.
    """
    stop = stop if stop is not None else threading.Event()
    p0, R0 = sim.default_start()
    sim.reset(p_W=p0, R_WB=R0)  # compile (or load) the plant's kernels now, not at the take-off
    sim.step(RotorCommand(0.0, sim.hover_speeds_hz(R0)))
    p0, R0 = _resting_pose(sim, p0, R0, say)
    sim.reset(p_W=p0, R_WB=R0, omega_hz=np.zeros(sim.vehicle.n_rotors))
    link = SimLink(transport, sim.vehicle.n_rotors, dataclasses.replace(serve, lockstep=False))
    set_transport_priority(serve.transport_priority, say)  # the link's threads exist now (ServeOptions)
    report = SitlReport()
    outputs = SimOutputs(sim, serve, say)
    record = sim.frame_record
    zeros = np.zeros(link.n)
    dt = sim.dt
    seq = 0
    held = 0
    released = failsafe = False
    freeze_gc()
    wall0 = time.monotonic()
    k = 0
    try:
        while not stop.is_set():
            _sleep_until(wall0 + k * dt, link)
            k += 1
            now = time.monotonic()
            if not released:
                if link.gate.paired and bool(np.any(link.cmd_hz != 0.0)) and now - link.cmd_wall_s < 0.1:
                    released = True
                    say("released from its stand: the node commands the rotors")
                else:
                    link.send_frame(record, seq)
                    seq += 1
                    link.send_status(sim.t, report.steps, held, False, "")
                    continue
            if not failsafe and now - link.cmd_wall_s > serve.offboard_loss_s:
                failsafe = _engage(link, report, now)
            if link.cmd_frame_seq != seq - 1:
                held += 1
            flown = zeros if failsafe else link.cmd_hz
            sim.step(RotorCommand(sim.t, flown))
            if outputs.active:
                outputs.period(flown)
            report.steps += 1
            link.send_frame(record, seq)
            seq += 1
            link.send_status(sim.t, report.steps, held, failsafe, "offboard loss" if failsafe else "")
    except KeyboardInterrupt:
        pass  # Ctrl-C or SIGTERM ends the run here; the summary below is still written
    finally:
        thaw_gc()
        report.recording = outputs.close()
    report.commands_obeyed = link.gate.obeyed
    report.commands_held = held
    report.commands_refused = link.gate.refused
    report.stop_with_speeds = link.stop_nonzero
    report.foreign_sessions = link.gate.foreign_sessions
    report.plant_session_id = f"{link.session_id:016x}"
    report.bad_payloads = link.bad_payloads
    report.wall_s = time.monotonic() - wall0
    report.real_time_factor = report.steps * dt / report.wall_s if report.wall_s > 0 else 0.0
    return report
