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

**The frame direction** (:class:`Px4FrameSource`, on unless ``--no-frames``): the node's ``/omnirotor/frame``
(``omnirotor_msgs/msg/SensorFrame``, the record of :func:`omnirotor.messages.frame_dtype` written in place by
:class:`omnirotor.rosmsg.convert.FrameEncoder`, the simulator's encoder: rosbags' bytes, no second frame format),
one per IMU sample, so that PX4's IMU drives the node's period as a robot's IMU does:

    /fmu/out/sensor_combined    px4_msgs/msg/SensorCombined   the frame's IMU, FRD -> FLU; its ``timestamp`` [µs
                                                              since PX4's boot] / 1e6 is the frame's ``t`` [s]
    /fmu/out/esc_status         px4_msgs/msg/EscStatus        the newest rotor speeds, ``esc_rpm / 60`` [Hz] by
                                                              motor number; none, or older than ``esc_timeout_s``
                                                              of PX4's time: NaN (the controller's frame
                                                              supervision rejects them and its wrench observer
                                                              takes the last command), said once
    motion capture, when a sample arrived since the last frame (``FrameOptions.mocap``):
      "pose"      MOCAP_TOPIC   geometry_msgs/msg/PoseStamped  in the node's namespace, taken as it is: our z-up
                                                              world W and FLU body (the mocap driver's frames);
                                                              its stamp mapped onto PX4's clock (below)
      "odometry"  /fmu/out/vehicle_odometry  VehicleOdometry  PX4's estimate, NED/FRD -> NWU/FLU
                                                              (:func:`omnirotor.fly.px4.pose_from_vehicle_odometry`),
                                                              ``timestamp_sample`` on PX4's clock

One clock: every time in the frames is PX4's (its ``timestamp``, µs since boot, monotonic) in seconds. A
``PoseStamped``'s stamp (the mocap driver's capture time, ROS time: the system clock) is moved onto it by the
offset between PX4's IMU time stamps and this host's system clock at their arrival (the largest ``t_px4 -
t_arrival`` over the last seconds: the offset minus the smallest transport delay); a stamp that then lies in the
future of PX4's present (this host's clock plus the offset) or more than 0.5 s behind it is not on a synchronised
clock: its arrival time is used instead (mapped the same way), said once. A frame carries only ESC reports and
motion-capture samples taken at or before its IMU sample (later ones wait for a later frame), so that a frame
never holds a sample from its future when the IMU's queue lags behind; IMU samples lost on the way are counted
(``imu_gaps``; the node counts the frames it missed).

The node's controller assumes its period (``rate_hz``, 1 kHz): before any frame is published the IMU's rate is
measured over ``rate_window_s`` (the median interval of PX4's time stamps, not of their arrivals), and a rate more
than ``rate_tolerance`` away refuses to bridge (one line, exit status 2): a controller run at another rate than it
was tuned for is unsafe. After it, the rate is watched for the whole flight (:class:`ImuRateWatch`: the rate of
the last ``rate_window_s`` of samples, judged ten times a window): a rate off the tolerance for longer than the
window is said once and its recovery once more, and gaps (no sample arriving for ``gap_s``, 20 ms) are counted
with the worst; both in the summary (``imu_watch``) and, once a second, on ``/diagnostics`` in the node's namespace
(``diagnostic_msgs/msg/DiagnosticArray``, ROS's standard: WARN while the rate is off or after a gap, STALE when
no sample came for 0.5 s; :meth:`Px4FrameSource.diagnostics`); the counts also go with every ``SimStatus``
(``imu_rate_off_episodes``, ``imu_rate_off_s``, ``imu_gaps``, ``imu_worst_gap_s``), which the node reads, says and
puts in its summary and recording. The frames go on meanwhile: the controller integrates the real intervals between
frames, and the node's stale-IMU failsafe is the safety action on a starving IMU. Values
are passed as they are (NaN included: the node's supervision judges them); malformed payloads on any of these
topics are counted (``bad_payloads`` in the summary), never raised.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import math
import sys
import threading
import time
from collections.abc import Callable

import numpy as np

from omnirotor.config import check_positive
from omnirotor.errors import InputError
from omnirotor.fly.px4 import (
    NUM_CONTROLS,
    Px4Offboard,
    actuator_motors_msg,
    controls_from_speeds,
    imu_from_sensor_combined,
    pose_from_vehicle_odometry,
    reversible_flags,
    rotor_hz_from_esc_status,
)
from omnirotor.messages import new_frame
from omnirotor.realtime import frozen_gc
from omnirotor.rosmsg import typestore
from omnirotor.rosmsg.convert import (
    COMMAND,
    COMMAND_ARMED,
    FRAME,
    POSE,
    SIM_STATUS,
    FrameEncoder,
    command_check,
    set_stamp,
)
from omnirotor.sitl.gate import CommandGate, new_session_id
from omnirotor.sitl.server import TOPICS
from omnirotor.transport import Transport, ros_topic

__all__ = [
    "BridgeOptions",
    "FrameOptions",
    "FrameAssembler",
    "Px4FrameSource",
    "Px4Bridge",
    "PX4_TOPICS",
    "MOCAP_SOURCES",
    "NAV_OFFBOARD",
    "ARMING_ARMED",
    "imu_rate_hz",
    "ImuRateWatch",
]

PX4_TOPICS = {
    "actuator_motors": "/fmu/in/actuator_motors",
    "offboard_control_mode": "/fmu/in/offboard_control_mode",
    "vehicle_command": "/fmu/in/vehicle_command",
    "vehicle_status": "/fmu/out/vehicle_status",
    "sensor_combined": "/fmu/out/sensor_combined",
    "esc_status": "/fmu/out/esc_status",
    "vehicle_odometry": "/fmu/out/vehicle_odometry",
}
"""PX4's topics over its Zenoh bridge (:data:`omnirotor.fly.px4.PX4_PROFILE`), before PX4's namespace."""
_PX4_TYPES = {
    "actuator_motors": "px4_msgs/msg/ActuatorMotors",
    "offboard_control_mode": "px4_msgs/msg/OffboardControlMode",
    "vehicle_command": "px4_msgs/msg/VehicleCommand",
    "vehicle_status": "px4_msgs/msg/VehicleStatus",
    "sensor_combined": "px4_msgs/msg/SensorCombined",
    "esc_status": "px4_msgs/msg/EscStatus",
    "vehicle_odometry": "px4_msgs/msg/VehicleOdometry",
}
_PX4_OUT = ("vehicle_status", "sensor_combined", "esc_status", "vehicle_odometry")
"""The topics PX4 publishes (the bridge subscribes)."""
NAV_OFFBOARD = 14
"""``VehicleStatus.nav_state`` of PX4's offboard mode."""
ARMING_ARMED = 2
"""``VehicleStatus.arming_state`` armed."""
FAILSAFE_NONE, FAILSAFE_COMMAND_LOSS, FAILSAFE_ROBOT = 0, 1, 2
"""``SimStatus.failsafe`` values the bridge reports (the plant status the node reads)."""
DIAGNOSTICS_TOPIC = "/diagnostics"
"""ROS's diagnostics topic (in the node's namespace): the frame direction's state once a second."""
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"


@dataclasses.dataclass(frozen=True)
class BridgeOptions:
    """How the bridge runs.

    Attributes:
        command_loss_s: no command obeyed for this long while armed stops the motors and disarms PX4 [s].
        heartbeat_hz: OffboardControlMode rate [Hz] (PX4 wants 2 Hz or more).
        lead_s: heartbeat time before the switch to offboard [s].
        status_hz: plant status rate [Hz].
        pair_session: obey this controller session only, from the first command (``--pair-session``,
            :mod:`omnirotor.sitl.gate`); None: the first session that commands is paired.
        session_id: the plant session its frames carry (``--session-id``; a node's ``--plant-session`` follows
            this bridge only); None: random.
    """

    command_loss_s: float = 0.5
    heartbeat_hz: float = 10.0
    lead_s: float = 1.0
    status_hz: float = 20.0
    pair_session: int | None = None
    session_id: int | None = None

    def __post_init__(self) -> None:
        for name in ("command_loss_s", "heartbeat_hz", "lead_s", "status_hz"):
            check_positive(name, getattr(self, name))


MOCAP_SOURCES = ("pose", "odometry")
"""Where the frames' motion capture comes from (module docstring): a ``PoseStamped`` topic, or PX4's odometry."""


@dataclasses.dataclass(frozen=True)
class FrameOptions:
    """The frame direction (module docstring).

    Attributes:
        mocap: ``"pose"`` (``geometry_msgs/msg/PoseStamped`` on ``mocap_topic``, z-up world, FLU body) or
            ``"odometry"`` (PX4's ``/fmu/out/vehicle_odometry``, NED/FRD).
        mocap_topic: the ``PoseStamped`` topic, in the node's namespace.
        rate_hz: the node's control rate [Hz] (its controller's ``1 / dt``): PX4's IMU must publish at it.
        rate_tolerance: the largest relative difference of the measured IMU rate from ``rate_hz``.
        rate_window_s: the IMU rate is measured over this much of PX4's time before any frame is published [s].
        esc_timeout_s: ESC telemetry older than this (PX4's time) reads NaN [s].
        gap_s: no IMU sample for longer than this is a gap (counted; the node's stale-IMU limit) [s].
        clock_window_s: the span of the running offset between PX4's clock and this host's [s] (``"pose"``).
    """

    mocap: str = "pose"
    mocap_topic: str = "/omnirotor/mocap"
    rate_hz: float = 1000.0
    rate_tolerance: float = 0.05
    rate_window_s: float = 1.0
    esc_timeout_s: float = 0.1
    gap_s: float = 0.02
    clock_window_s: float = 2.0

    def __post_init__(self) -> None:
        if self.mocap not in MOCAP_SOURCES:
            raise InputError(f"the motion capture source must be one of {', '.join(MOCAP_SOURCES)}, got {self.mocap!r}")
        for name in ("rate_hz", "rate_tolerance", "rate_window_s", "esc_timeout_s", "gap_s", "clock_window_s"):
            check_positive(name, getattr(self, name))
        if not self.mocap_topic.startswith("/"):
            raise InputError(f"the motion capture topic must be absolute (start with /), got {self.mocap_topic!r}")


def imu_rate_hz(timestamps_us: np.ndarray) -> float:
    """An IMU's publication rate [Hz] from its samples' time stamps [µs]: one over their median interval.

    The median of PX4's own time stamps, so that neither the transport's jitter nor a sample lost on the way changes
    it; NaN with fewer than two samples or no positive interval.
    """
    d = np.diff(np.asarray(timestamps_us, dtype=np.float64))
    d = d[d > 0]
    return 1e6 / float(np.median(d)) if d.size else math.nan


class ImuRateWatch:
    """PX4's IMU rate and its gaps over the whole flight (module docstring: the rate watch).

    :meth:`sample` takes every IMU sample: its PX4 time stamp [µs] into a ring of the last ``window_s`` or more, its
    arrival on this host's monotonic clock for the gaps. Every tenth of a window of PX4's time the rate of the last
    ``window_s`` of samples is judged (:func:`imu_rate_hz`: the median interval, so a lost sample does not move it),
    once the samples span a whole window. A rate more than ``tolerance`` away from ``rate_hz`` in every judgement
    for longer than ``window_s`` is an *episode*: said once when it has lasted that long, and once more when a
    judgement finds the rate back within the tolerance. A *gap* is an arrival more than ``gap_s`` after the previous
    one (the first said, all counted, the worst kept). A time stamp that goes backwards (PX4 restarted) is said and
    starts the window afresh (an open episode ends there). Nothing allocates per sample; a judgement (ten a second)
    sorts one window.

    Args:
        rate_hz: the node's control rate [Hz].
        tolerance: the largest relative difference of the rate from ``rate_hz``.
        window_s: the sliding window [s of PX4's time].
        gap_s: an arrival more than this after the previous is a gap [s].
        name: the IMU's name in what is said (e.g. its topic).
        say: where the lines go.

    Attributes:
        rate_hz: the newest judged rate [Hz] (NaN before the first).
        episodes: episodes said; ``off_s``: their total length [s of PX4's time] (an open one up to now);
        worst_hz: of the judged rates off the tolerance (in an episode or not), the farthest from ``rate_hz``
            (NaN: none).
        gaps: gaps counted; ``worst_gap_s``: the longest [s] (0 without).
    """

    def __init__(self, rate_hz: float, tolerance: float = 0.05, window_s: float = 1.0, gap_s: float = 0.02,
                 name: str = "PX4's IMU", say: Callable[[str], None] | None = None) -> None:  # fmt: skip
        self.nominal_hz, self.tolerance, self.window_s, self.gap_s = rate_hz, tolerance, window_s, gap_s
        self.name = name
        self._say = say if say is not None else (lambda line: None)
        self._ring = np.zeros(int(4 * rate_hz * window_s) + 16)  # room for a window at 4x the nominal rate
        self._window_us = 1e6 * window_s
        self._check_us = self._window_us / 10
        self._n = 0  # samples in the ring since the window started (may exceed its size: it wraps)
        self._first_us = self._last_us = math.nan
        self._next_check_us = math.nan
        self._last_arrival = math.nan
        self._off_since_us = math.nan  # PX4's time of the first judgement off in a row
        self._said = False
        self.rate_hz = math.nan
        self.episodes = 0
        self._off_closed_s = 0.0
        self.worst_hz = math.nan
        self.gaps = 0
        self.worst_gap_s = 0.0
        self._gaps_told = 0  # gaps counted at the previous :meth:`diagnostic`

    def sample(self, t_us: int, arrival_s: float) -> None:
        """One IMU sample: PX4's ``timestamp`` [µs], its arrival [s, monotonic; NaN: not counted for gaps]."""
        gap = arrival_s - self._last_arrival
        self._last_arrival = arrival_s
        if gap > self.gap_s:
            self.gaps += 1
            if gap > self.worst_gap_s:
                self.worst_gap_s = gap
            if self.gaps == 1:
                self._say(f"{self.name}: no sample for {1000 * gap:.0f} ms (more than {1000 * self.gap_s:g} ms; the "
                          "node's stale-IMU failsafe acts on it); gaps are counted in the summary")  # fmt: skip
        t = float(t_us)
        if not t >= self._last_us:  # the first sample, or PX4's clock went back: a new window
            if self._n:
                self._say(f"{self.name}: time stamps went back {1e-6 * (self._last_us - t):.3f} s (PX4 restarted?); "
                          "its rate is judged afresh")  # fmt: skip
            if self._said:  # an open episode ends with the old clock
                self._off_closed_s += 1e-6 * (self._last_us - self._off_since_us)
            self._said = False
            self._off_since_us = math.nan
            self._n = 0
            self._first_us = t
            self._next_check_us = t + self._window_us
        self._last_us = t
        ring = self._ring
        ring[self._n % ring.size] = t
        self._n += 1
        if t >= self._next_check_us:
            self._next_check_us = t + self._check_us
            self._judge(t)

    def window_us(self) -> np.ndarray:
        """The time stamps of the last ``window_s`` of samples [µs], oldest first (a new array)."""
        ring, n = self._ring, self._n
        if n <= ring.size:
            s = ring[:n]
        else:
            k = n % ring.size
            s = np.concatenate((ring[k:], ring[:k]))
        if not s.size:
            return s.copy()
        return s[int(np.searchsorted(s, s[-1] - self._window_us)) :].copy()

    def _judge(self, t_us: float) -> None:
        self.rate_hz = rate = imu_rate_hz(self.window_us())
        off = abs(rate / self.nominal_hz - 1.0)
        if off <= self.tolerance:  # NaN (no interval) is not judged within
            if self._said:
                self._off_closed_s += 1e-6 * (t_us - self._off_since_us)
                self._say(f"{self.name} back at {rate:.1f} Hz after {1e-6 * (t_us - self._off_since_us):.1f} s off")
            self._said = False
            self._off_since_us = math.nan
            return
        if math.isnan(self.worst_hz) or off > abs(self.worst_hz / self.nominal_hz - 1.0):
            self.worst_hz = rate
        if math.isnan(self._off_since_us):
            self._off_since_us = t_us
        elif not self._said and t_us - self._off_since_us > self._window_us:
            self._said = True
            self.episodes += 1
            self._say(
                f"{self.name} at {rate:.1f} Hz for more than {self.window_s:g} s, the node's controller runs at "
                f"{self.nominal_hz:g} Hz (tolerance {100 * self.tolerance:g} %): frames go on (the controller "
                "integrates the real intervals; the node's stale-IMU failsafe acts on gaps); check PX4's load and "
                "IMU_GYRO_RATEMAX"
            )

    @property
    def span_s(self) -> float:
        """PX4's time from the window's first sample (since the start or a clock reset) to the newest [s]."""
        return 1e-6 * (self._last_us - self._first_us) if self._n else 0.0

    @property
    def off_s(self) -> float:
        """The episodes' total length [s of PX4's time], an open one up to the newest sample."""
        open_s = 1e-6 * (self._last_us - self._off_since_us) if self._said else 0.0
        return self._off_closed_s + open_s

    def diagnostic(self, now_s: float, stale_s: float = 0.5) -> tuple[int, str]:
        """The IMU's state now (``now_s`` on the arrivals' clock) as a ROS diagnostic level and message.

        ``diagnostic_msgs/msg/DiagnosticStatus``' levels: STALE (3) with no sample arrived yet or none for
        ``stale_s``; WARN (1) while an episode is open, or when gaps came since the previous call; else OK (0).
        """
        rate = "rate not judged yet" if math.isnan(self.rate_hz) else f"{self.rate_hz:.1f} Hz"
        new_gaps, self._gaps_told = self.gaps - self._gaps_told, self.gaps
        age = now_s - self._last_arrival
        if not age <= stale_s:
            return 3, "no sample yet" if math.isnan(age) else f"no sample for {age:.1f} s"
        if self._said:
            off_s = 1e-6 * (self._last_us - self._off_since_us)
            return 1, f"{rate}, off --rate-hz {self.nominal_hz:g} for {off_s:.1f} s"
        if new_gaps:
            return 1, f"{rate}; {new_gaps} gap(s) over {1000 * self.gap_s:g} ms since the last report"
        return 0, rate

    def summary(self) -> dict:
        """What the watch counted (JSON-ready: None for a rate not judged)."""
        return {
            "rate_hz": None if math.isnan(self.rate_hz) else self.rate_hz,
            "off_episodes": self.episodes,
            "off_s": self.off_s,
            "worst_off_rate_hz": None if math.isnan(self.worst_hz) else self.worst_hz,
            "gaps": self.gaps,
            "worst_gap_ms": 1000 * self.worst_gap_s,
        }


class FrameAssembler:
    """One vehicle's frame record, filled from PX4's messages: the sample-by-sample part of :class:`Px4FrameSource`.

    :meth:`imu` starts a frame (its time and IMU), :meth:`esc` and :meth:`mocap_pose` / :meth:`mocap_odometry` keep
    the newest rotor speeds and motion-capture sample, :meth:`frame` completes the record: rotor speeds NaN when
    the ESC telemetry is missing or older than ``esc_timeout_s``, the motion capture only when a sample arrived
    since the last frame, no state (``valid`` 0). Nothing allocates per sample.

    Args:
        n_rotors: the vehicle's rotors.
        esc_timeout_s: ESC telemetry older than this [s of PX4's time] reads NaN.

    Attributes:
        record: the ``(1,)`` frame record (:func:`omnirotor.messages.frame_dtype`) rewritten for every frame.
        frames: frames completed; ``esc_nan_frames``: of them, with NaN speeds for want of telemetry;
        mocap_samples: motion-capture samples taken into a frame; ``mocap_replaced``: samples that arrived after
            another not yet taken (the newer wins).
    """

    def __init__(self, n_rotors: int, esc_timeout_s: float = 0.1) -> None:
        self.n = n_rotors
        self.esc_timeout_s = esc_timeout_s
        self.record = r = new_frame(n_rotors)
        self._t = r["t"]
        self._acc, self._gyro = r["imu"]["acc_B"][0], r["imu"]["gyro_B"][0]
        self._hz = r["rotor_hz"][0]
        self._mocap = r["mocap"]
        self._m_p, self._m_q = r["mocap"]["p_W"][0], r["mocap"]["q_WB"][0]
        self._esc_hz = np.full(n_rotors, np.nan)
        self.esc_t = -math.inf  # PX4's time of the newest ESC report [s]
        self._p, self._q = np.zeros(3), np.zeros(4)
        self._sample_t = 0.0
        self._pending = False
        self._m_written = False  # the record's motion capture holds a sample (zeroed at the next frame without)
        self.t = math.nan  # the time of the frame being assembled [s]
        self.frames = self.esc_nan_frames = self.mocap_samples = self.mocap_replaced = 0

    def imu(self, msg) -> float:
        """Start a frame from a ``px4_msgs/msg/SensorCombined``; returns its time [s] (PX4's ``timestamp``)."""
        self.t = 1e-6 * int(msg.timestamp)
        self._t[0] = self.t
        imu_from_sensor_combined(msg, self._acc, self._gyro)
        return self.t

    def esc(self, msg) -> None:
        """The newest ``px4_msgs/msg/EscStatus``: its speeds [Hz] by motor number, NaN for a motor not reported."""
        rotor_hz_from_esc_status(msg, self.n, self._esc_hz)
        self.esc_t = 1e-6 * int(msg.timestamp)

    def _sample(self) -> None:
        if self._pending:
            self.mocap_replaced += 1
        self._pending = True

    def mocap_pose(self, msg, t_s: float) -> None:
        """A ``geometry_msgs/msg/PoseStamped`` in our frames (z-up world, FLU body), taken at ``t_s`` (PX4's clock)."""
        p, q = msg.pose.position, msg.pose.orientation
        self._p[0], self._p[1], self._p[2] = p.x, p.y, p.z
        self._q[0], self._q[1], self._q[2], self._q[3] = q.w, q.x, q.y, q.z
        self._sample_t = t_s
        self._sample()

    def mocap_odometry(self, msg) -> None:
        """A ``px4_msgs/msg/VehicleOdometry`` (NED/FRD), converted; its time is PX4's ``timestamp_sample``."""
        self._sample_t = pose_from_vehicle_odometry(msg, self._p, self._q)
        self._sample()

    def esc_fresh(self) -> bool:
        """True when the newest ESC report is within ``esc_timeout_s`` of the frame's time (either side)."""
        return abs(self.t - self.esc_t) <= self.esc_timeout_s

    def frame(self) -> np.ndarray:
        """Complete the frame started by :meth:`imu`; returns :attr:`record`."""
        if self.esc_fresh():
            self._hz[:] = self._esc_hz
        else:
            self._hz.fill(np.nan)
            self.esc_nan_frames += 1
        m = self._mocap
        if self._pending:
            m["new"], m["t"] = 1.0, self._sample_t
            self._m_p[:] = self._p
            self._m_q[:] = self._q
            self._pending = False
            self._m_written = True
            self.mocap_samples += 1
        elif self._m_written:  # the record's convention: no sample, its entries zero (they stay so until one)
            m[...] = 0.0
            self._m_written = False
        self.frames += 1
        return self.record


class _ClockOffset:
    """PX4's clock minus this host's system clock [s]: the largest ``t_px4 - t_arrival`` over the last window.

    Each IMU sample arrives after PX4 stamped it, so ``t_px4 - t_arrival`` is the offset minus that sample's delay;
    its largest value over a window is the offset minus the smallest delay. Two half-windows keep it following a
    slow drift of either clock.
    """

    def __init__(self, window_s: float) -> None:
        self.half_s = 0.5 * window_s
        self._cur = self._prev = -math.inf
        self._block_end = -math.inf

    def imu(self, t_px4: float, t_arrival: float) -> None:
        if t_px4 >= self._block_end:
            self._prev, self._cur = self._cur, -math.inf
            self._block_end = t_px4 + self.half_s
        self._cur = max(self._cur, t_px4 - t_arrival)

    @property
    def offset_s(self) -> float:
        """The offset [s]; -inf before the first IMU sample."""
        return max(self._cur, self._prev)


class Px4FrameSource:
    """The frame direction of the bridge (module docstring): PX4's sensors into the node's ``SensorFrame``s.

    Args:
        node: a transport session in the node's namespace (frames out; the ``PoseStamped`` motion capture in).
        px4: a transport session in PX4's namespace.
        n_rotors: the vehicle's rotors.
        options: the frame options.
        say: where one-line notices go.
        session_id: the plant session every frame carries (:mod:`omnirotor.sitl.gate`).
    """

    def __init__(self, node: Transport, px4: Transport, n_rotors: int, options: FrameOptions,
                 say: Callable[[str], None], session_id: int) -> None:  # fmt: skip
        self.options = o = options
        self._say = say
        self.assembler = FrameAssembler(n_rotors, o.esc_timeout_s)
        self._imu = px4.subscriber(PX4_TOPICS["sensor_combined"], _PX4_TYPES["sensor_combined"], depth=256)
        self._esc = px4.subscriber(PX4_TOPICS["esc_status"], _PX4_TYPES["esc_status"], depth=16)
        if o.mocap == "odometry":
            self._mocap = px4.subscriber(PX4_TOPICS["vehicle_odometry"], _PX4_TYPES["vehicle_odometry"], depth=64)
        else:
            self._mocap = node.subscriber(o.mocap_topic, POSE, depth=64)
        self._pub = node.publisher(TOPICS["frame"], FRAME)
        self._encoder = FrameEncoder(n_rotors, session_id=session_id)
        self._clock = _ClockOffset(o.clock_window_s)
        self.imu_where = ros_topic(px4.namespace, PX4_TOPICS["sensor_combined"])
        self.esc_where = ros_topic(px4.namespace, PX4_TOPICS["esc_status"])
        self.mocap_where = (
            ros_topic(px4.namespace, PX4_TOPICS["vehicle_odometry"])
            if o.mocap == "odometry"
            else ros_topic(node.namespace, o.mocap_topic)
        )
        self.seq = 0
        self.rate_hz = math.nan
        self.stamps_unsynced = 0
        self.errors = 0
        self.imu_gaps = 0
        self.watch = ImuRateWatch(o.rate_hz, o.rate_tolerance, o.rate_window_s, o.gap_s,
                                  f"PX4's IMU ({self.imu_where})", say)  # fmt: skip
        self._esc_q: collections.deque = collections.deque(maxlen=64)
        self._mocap_q: collections.deque = collections.deque(maxlen=64)
        self._said: set[str] = set()
        self._t0 = math.nan  # PX4's time of the first frame [s]

    def _once(self, key: str, line: str) -> None:
        if key not in self._said:
            self._said.add(key)
            self._say(line)

    def measure_rate(self, stop: threading.Event | None = None) -> float:
        """Measure PX4's IMU rate over ``rate_window_s`` of its time before any frame goes out (module docstring).

        Waits for the samples (said once when none came for 2 s) until ``stop``; returns the rate [Hz] (NaN when
        stopped first).

        Raises:
            InputError: the rate is more than ``rate_tolerance`` away from ``rate_hz`` (the node's control rate).
        """
        o = self.options
        last = time.monotonic()  # of the last sample (or the start)
        while stop is None or not stop.is_set():
            msg = self._imu.take(0.05)
            if msg is None:
                if time.monotonic() - last > 2.0:
                    self._once("no-imu", f"waiting for PX4's IMU on {self.imu_where} (no frame goes to the node "
                                         "before its rate is measured)")  # fmt: skip
                continue
            last = time.monotonic()
            t_us = int(msg.timestamp)
            self.watch.sample(t_us, math.nan)  # its window, not its gaps: no frame is due yet
            self._clock.imu(1e-6 * t_us, time.time())
            if self.watch.span_s >= o.rate_window_s:
                break
        else:
            return math.nan
        stamps = self.watch.window_us()
        self.rate_hz = rate = imu_rate_hz(stamps)
        if not (abs(rate / o.rate_hz - 1.0) <= o.rate_tolerance):
            raise InputError(
                f"PX4's IMU ({self.imu_where}) publishes at {rate:.1f} Hz, the node's controller runs at "
                f"{o.rate_hz:g} Hz (tolerance {100 * o.rate_tolerance:g} %): refusing to bridge frames, a controller "
                "run at another rate is unsafe; set PX4's IMU_GYRO_RATEMAX and IMU_INTEG_RATE (docs/fly.md)"
            )
        self._mocap.take_latest()  # samples queued while measuring are old by now: the first frame takes a new one
        self._say(f"PX4's IMU at {rate:.1f} Hz ({len(stamps)} samples in {o.rate_window_s:g} s): frames to the node")
        return rate

    def poll(self, timeout_s: float = 0.05) -> int:
        """Wait up to ``timeout_s`` for IMU samples; one frame published per sample; returns how many."""
        msg = self._imu.take(timeout_s)
        n = 0
        while msg is not None:
            try:
                self._one(msg)
                n += 1
            except Exception as exc:  # noqa: BLE001  (a message that decodes but cannot be used: counted, said once)
                self.errors += 1
                self._once("error", f"a PX4 sample could not be made into a frame ({type(exc).__name__}: {exc}); "
                                    "counted, the bridge goes on")  # fmt: skip
            msg = self._imu.take()
        return n

    def _one(self, msg) -> None:
        a = self.assembler
        arrival = time.time()
        t_prev = a.t
        t = a.imu(msg)
        self._clock.imu(t, arrival)
        self.watch.sample(int(msg.timestamp), time.monotonic())
        if t - t_prev > 1.5 / self.options.rate_hz:
            self.imu_gaps += 1  # samples lost on the way (the node counts the frames it missed)
        # ESC reports and motion-capture samples wait until the frame's time reaches theirs (a frame never carries
        # a sample taken after its IMU sample, even when the IMU's queue lags behind theirs)
        while (m := self._esc.take()) is not None:
            self._esc_q.append((1e-6 * int(m.timestamp), m))
        while (m := self._mocap.take()) is not None:
            self._mocap_q.append((self._mocap_time(m), m))
        while self._esc_q and self._esc_q[0][0] <= t:
            a.esc(self._esc_q.popleft()[1])
        while self._mocap_q and self._mocap_q[0][0] <= t:
            t_m, m = self._mocap_q.popleft()
            if self.options.mocap == "odometry":
                a.mocap_odometry(m)
            else:
                a.mocap_pose(m, t_m)
        if math.isnan(self._t0):
            self._t0 = t
        self._notices(t)
        self._pub.put_raw(self._encoder.encode(a.frame(), self.seq))
        self.seq += 1

    def _mocap_time(self, msg) -> float:
        """A motion-capture sample's time on PX4's clock [s] (module docstring: one clock)."""
        if self.options.mocap == "odometry":
            return 1e-6 * int(msg.timestamp_sample or msg.timestamp)
        off = self._clock.offset_s
        px4_now = time.time() + off
        st = msg.header.stamp
        t = st.sec + 1e-9 * st.nanosec + off
        if px4_now - 0.5 <= t <= px4_now + 0.005:
            return t
        self.stamps_unsynced += 1
        self._once("unsynced", f"the motion capture's stamps ({self.mocap_where}) are {t - px4_now:+.3f} s from "
                               "PX4's clock: not synchronised with this host; arrival times used")  # fmt: skip
        return px4_now

    def _notices(self, t: float) -> None:
        a = self.assembler
        if t - self._t0 < 1.0:
            return
        if a.esc_t == -math.inf:
            self._once("no-esc", f"no ESC telemetry on {self.esc_where} after 1 s: the frames' rotor speeds "
                                 "are NaN (the controller then takes its commands for the speeds)")  # fmt: skip
        elif not a.esc_fresh():
            self._once("stale-esc", f"ESC telemetry {1000 * (t - a.esc_t):.0f} ms old: the frames' rotor speeds are "
                                    "NaN while it is older than the timeout")  # fmt: skip
        if a.mocap_samples == 0:
            self._once("no-mocap", f"no motion capture on {self.mocap_where} after 1 s of frames")

    def run(self, stop: threading.Event) -> None:
        """Frames until ``stop`` (the bridge's frame thread)."""
        while not stop.is_set():
            self.poll(0.05)

    def diagnostics(self, wall_s: float) -> object:
        """A ``diagnostic_msgs/msg/DiagnosticArray`` of the frame direction now, stamped ``wall_s``.

        ``wall_s`` is this host's system clock, as ROS's diagnostics tools expect. One status, ``omnirotor
        px4-bridge: PX4's IMU``, with :meth:`ImuRateWatch.diagnostic`'s level and message and the counts of the
        summary as key-values.
        """
        T = typestore().types
        w, a = self.watch, self.assembler
        level, message = w.diagnostic(time.monotonic())
        values = {
            "topic": self.imu_where, "rate_hz": f"{w.rate_hz:.1f}", "rate_expected_hz": f"{w.nominal_hz:g}",
            "off_episodes": str(w.episodes), "off_s": f"{w.off_s:.1f}", "gaps": str(w.gaps),
            "worst_gap_ms": f"{1000 * w.worst_gap_s:.0f}", "frames": str(a.frames),
            "frames_esc_nan": str(a.esc_nan_frames), "mocap_samples": str(a.mocap_samples),
            "imu_samples_lost": str(self.imu_gaps),
        }  # fmt: skip
        status = T["diagnostic_msgs/msg/DiagnosticStatus"](
            level=level,
            name="omnirotor px4-bridge: PX4's IMU", message=message, hardware_id="px4",
            values=[T["diagnostic_msgs/msg/KeyValue"](key=k, value=v) for k, v in values.items()],
        )  # fmt: skip
        msg = T[DIAGNOSTIC_ARRAY](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=""),
            status=[status],
        )
        set_stamp(msg.header, wall_s)
        return msg

    def summary(self) -> dict:
        """What the frame direction counted."""
        a = self.assembler
        return {
            "frames": a.frames,
            "imu_rate_hz": None if math.isnan(self.rate_hz) else self.rate_hz,  # None: not measured (stopped first)
            "esc_nan_frames": a.esc_nan_frames,
            "mocap_samples": a.mocap_samples,
            "mocap_replaced": a.mocap_replaced,
            "mocap_stamps_unsynced": self.stamps_unsynced,
            "errors": self.errors,
            "imu_gaps": self.imu_gaps,
            "imu_watch": self.watch.summary(),
            "bad_payloads": {
                "sensor_combined": self._imu.n_bad,
                "esc_status": self._esc.n_bad,
                "mocap": self._mocap.n_bad,
            },
        }


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
        frames: the frame direction's options (:class:`Px4FrameSource`); None: no frames (the node's frames come
            from another driver).
    """

    def __init__(self, node: Transport, px4: Transport, n_rotors: int, omega_min_hz: float, omega_max_hz: float,
                 options: BridgeOptions | None = None, say: Callable[[str], None] | None = None,
                 frames: FrameOptions | None = None) -> None:  # fmt: skip
        if not 0 < n_rotors <= NUM_CONTROLS:
            raise InputError(f"PX4 drives at most {NUM_CONTROLS} motors, the vehicle has {n_rotors}")
        self.options = o = options if options is not None else BridgeOptions()
        self._say = say if say is not None else (lambda line: print(f"omnirotor px4-bridge: {line}", file=sys.stderr))
        self.n = n_rotors
        self.omega_max_hz = float(omega_max_hz)
        self.flags = reversible_flags(omega_min_hz, n_rotors)
        self._cmd = node.subscriber(TOPICS["rotor_cmd"], COMMAND, depth=64, check=command_check(n_rotors))
        self._pub_status = node.publisher(TOPICS["sim_status"], SIM_STATUS)
        self._pub = {k: px4.publisher(PX4_TOPICS[k], _PX4_TYPES[k]) for k in _PX4_TYPES if k not in _PX4_OUT}
        self._vstatus = px4.subscriber(PX4_TOPICS["vehicle_status"], _PX4_TYPES["vehicle_status"], depth=4)
        self.gate = CommandGate("omnirotor px4-bridge", pinned=o.pair_session)
        self.session_id = o.session_id if o.session_id is not None else new_session_id()
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
            finished=False, plant_session_id=0 if frames is None else self.session_id,  # no frames: not the plant's
            imu_rate_off_episodes=0, imu_rate_off_s=0.0, imu_gaps=0, imu_worst_gap_s=0.0,
        )  # fmt: skip
        self._status_next = 0.0
        self.frames = (
            None if frames is None else Px4FrameSource(node, px4, n_rotors, frames, self._say, self.session_id)
        )
        self._pub_diag = None if frames is None else node.publisher(DIAGNOSTICS_TOPIC, DIAGNOSTIC_ARRAY)
        self._diag_next = 0.0

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
        if self._pub_diag is not None and now >= self._diag_next:
            self._diag_next = now + 1.0
            self._pub_diag.put(self.frames.diagnostics(time.time()))

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
        if self.frames is not None:  # PX4's IMU as the frame thread's watch sees it (plain numbers: no lock needed)
            w = self.frames.watch
            s.imu_rate_off_episodes, s.imu_rate_off_s = w.episodes, w.off_s
            s.imu_gaps, s.imu_worst_gap_s = w.gaps, w.worst_gap_s
        self._pub_status.put(s)

    def run(self, stop: threading.Event | None = None) -> dict:
        """Bridge until ``stop`` or Ctrl-C; at the end NaN to every motor and PX4 disarmed if the node had it armed.

        With frames, PX4's IMU rate is measured first (nothing is bridged before), then the frames go out from
        their own thread while this one obeys the commands. Both threads inherit the calling thread's scheduling
        (:func:`omnirotor.realtime.set_realtime` before this call); the garbage collector is frozen while they run
        (:func:`omnirotor.realtime.frozen_gc`: each sample allocates its decoded messages, freed by reference
        counting, and no collection pauses a period).

        Raises:
            InputError: PX4's IMU rate is not the node's control rate (:meth:`Px4FrameSource.measure_rate`).
        """
        stop = stop if stop is not None else threading.Event()
        thread = None
        with contextlib.suppress(KeyboardInterrupt):  # Ctrl-C ends the bridging; the motors are stopped below
            if self.frames is not None:
                self.frames.measure_rate(stop)
            with frozen_gc():
                if self.frames is not None:
                    thread = threading.Thread(target=self.frames.run, args=(stop,), name="px4-frames", daemon=True)
                    thread.start()
                try:
                    while not stop.is_set():
                        self.poll(0.02)
                finally:
                    stop.set()
                    if thread is not None:
                        thread.join(5.0)
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
            "plant_session_id": f"{self.session_id:016x}" if self.frames is not None else None,
            "commands_obeyed": self.gate.obeyed,
            "commands_refused": self.gate.refused,
            "foreign_sessions": self.gate.foreign_sessions,
            "bad_payloads": self._cmd.n_bad,
            "stop_with_speeds": self.stop_with_speeds,
            "sent": dict(self.sent),
            "failsafe": self.failsafe,
            "cause": self.cause,
            "px4_gave_up": list(self.offboard.gave_up),
            "frames": None if self.frames is None else self.frames.summary(),
        }
