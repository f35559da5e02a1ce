"""Link failsafes of the flight node: stale IMU or motion capture degrades, then holds, then lands.

Each period the node gives the director the ages of its latest IMU and motion-capture samples
(:class:`LinkAges`). A link older than its limit (IMU > ``imu_stale_s``, 20 ms; motion capture
> ``mocap_stale_s``, 200 ms, :class:`~omnirotor.fly.presets.FlyParams`) is *stale*; how long past its limit
decides the level, a pure function of the ages (:meth:`FailsafeMonitor.level`):

    stale for 0 .. hold_after_s          DEGRADED   flagged; new setpoints refused (land, disarm accepted)
    stale for hold_after_s .. land_after_s   HOLD   the reference stops where it is
    stale for land_after_s or more       LAND       the landing of :mod:`omnirotor.fly.modes`
    frames stopped altogether            STOP       no step, zero speeds (the director disarms)

Besides the links, two checks of the vehicle itself terminate a flight (STOP: rotors stopped, disarmed; the
director's, from its motion capture, :meth:`FlightDirector.on_frame <omnirotor.fly.director.FlightDirector>`):
the *geofence* (motion capture puts the body more than ``geofence_margin_m`` outside the workspace box, which
every reference stays inside) and the *estimate's divergence* (the controller's position estimate and motion
capture disagree by more than ``divergence_m`` for ``divergence_s``). Either means the controller no longer
controls where the vehicle is; flying on, even a landing flown on that estimate, is how a vehicle flies away
while its controller believes it is on its reference (PX4's geofence action "terminate" is the same choice).

The director latches the action of each level reached during one incident (a hold or a landing is not
undone when the link comes back; the operator decides), while the DEGRADED flag follows the link. Every
status carries the cause bits (:class:`Cause`) of what is wrong now and the level reached.
"""

from __future__ import annotations

import dataclasses
import enum
import math

from omnirotor.fly.presets import FlyParams

__all__ = ["LinkAges", "Failsafe", "Cause", "FailsafeMonitor"]


@dataclasses.dataclass(frozen=True, slots=True)
class LinkAges:
    """How old the node's latest inputs are, once per period (the node fills it).

    Attributes:
        imu_age_s: age of the latest IMU sample [s] (inf if none yet).
        mocap_age_s: age of the latest motion-capture sample [s] (inf if none yet).
        frames_stopped: True when no sensor frame arrives at all any more (the node's link-loss timeout).
    """

    imu_age_s: float = 0.0
    mocap_age_s: float = 0.0
    frames_stopped: bool = False


class Failsafe(enum.IntEnum):
    """Failsafe level (the ``failsafe`` of ``omnirotor_msgs/msg/FlightStatus``)."""

    NONE = 0
    DEGRADED = 1
    HOLD = 2
    LAND = 3
    STOP = 4


class Cause(enum.IntFlag):
    """Why a status is flagged (the ``cause`` bits of ``omnirotor_msgs/msg/FlightStatus``)."""

    NONE = 0
    IMU_STALE = 1
    """The IMU is older than its limit."""
    MOCAP_STALE = 2
    """Motion capture is older than its limit."""
    FRAMES_STOPPED = 4
    """No frames at all: the rotors were stopped."""
    NONFINITE_COMMAND = 8
    """A command was not finite: the last good one was sent instead."""
    NO_COMMAND = 16
    """The controller gave no command for a period it was stepped: the last one was sent again."""
    LAND_TIMEOUT = 32
    """The landing disarmed after its bounded time, without touchdown detected."""
    CONTROLLER_ERROR = 64
    """The controller refused a frame (reset or in-flight change raised): the flight was stopped or held."""
    BAD_AGES = 128
    """The link ages given were not numbers: treated as stale."""
    GEOFENCE = 256
    """Motion capture put the body outside the workspace box by more than its margin: the flight was terminated."""
    ESTIMATE_DIVERGED = 512
    """The position estimate and motion capture disagreed beyond their bound: the flight was terminated."""
    PLANT_FAILSAFE = 1024
    """The plant stopped obeying (the simulator's offboard-loss failsafe, PX4 out of offboard): disarmed."""


class FailsafeMonitor:
    """The failsafe level of the link ages (module docstring); no state besides the limits.

    Args:
        params: the flight parameters (limits and delays).
    """

    def __init__(self, params: FlyParams) -> None:
        self._imu = params.imu_stale_s
        self._mocap = params.mocap_stale_s
        self._hold = params.hold_after_s
        self._land = params.land_after_s

    def level(self, ages: LinkAges) -> tuple[Failsafe, Cause]:
        """The level and the cause bits of ``ages``; NaN ages count as stale for ever (nothing raises)."""
        if ages.frames_stopped:
            return Failsafe.STOP, Cause.FRAMES_STOPPED
        cause = Cause.NONE
        worst = -math.inf  # how long past its limit the stalest link is [s]
        imu, mocap = ages.imu_age_s, ages.mocap_age_s
        if not (imu == imu and mocap == mocap):  # NaN
            return Failsafe.LAND, Cause.BAD_AGES
        if imu > self._imu:
            cause |= Cause.IMU_STALE
            worst = imu - self._imu
        if mocap > self._mocap:
            cause |= Cause.MOCAP_STALE
            worst = max(worst, mocap - self._mocap)
        if cause == Cause.NONE:
            return Failsafe.NONE, cause
        if worst >= self._land:
            return Failsafe.LAND, cause
        if worst >= self._hold:
            return Failsafe.HOLD, cause
        return Failsafe.DEGRADED, cause
