"""The flight director: modes, live setpoints and failsafes around the interaction controller (issue 24).

The node's process loop (:mod:`omnirotor.fly.node`) owns one :class:`FlightDirector` and, every period::

    d.on_frame(frame, ages)                      # transitions, failsafes, pending take-off
    cmd = controller.step(frame) if d.wants_step() else None
    speeds_hz = d.output(cmd)                    # what to publish: finite, within the limits

and between periods ``d.request(req)`` (one ``omnirotor ctl`` request: accepted or refused, and why) and
``d.status()`` (about 50 Hz). There is no transport here, and nothing raises out of these calls on bad
input: a bad request is refused, a bad command is replaced by the last good one and flagged.

Modes and transitions: :mod:`omnirotor.fly.modes`. Failsafes: :mod:`omnirotor.fly.failsafe`. References:
every flight segment is a minimum-jerk segment of the end-effector (EE) tip (SPEC §4.5), timed by the
flight limits (:func:`omnirotor.fly.setpoints.segment_duration`) and given to the controller through
:class:`omnirotor.fly.setpoints.InFlight`. A segment may be a chain of legs (a landing from contact first
withdraws to the contact anchor, with the contact preset, then descends with the free-flight one); the mode
changes when the last leg arrives.

Contact (SPEC §5, the paper's practical recipe): ``push DEPTH`` from hover takes the current reference as
the *anchor* (the tool at the surface), the contact normal ``n_W = R_WB p_E^B / |p_E^B|`` (the tool's
axis) and moves the desired EE to ``anchor + DEPTH n_W`` with the contact admittance preset (Table 2's PC by
default), so that the steady contact force is about ``K_E^p DEPTH`` (3 N for 0.1 m). A new depth moves the
reference along the same normal; ``push 0`` returns to the anchor and, on arrival, to hover with the
free-flight preset. A goto in contact moves the anchor (sliding at the same depth).

Take-off and landing: ``arm`` records the vehicle's pose (motion capture; the *ground* pose);
``takeoff`` resets the controller on the next frame that carries a motion-capture sample (the estimator
starts from it; rotors at idle until then) with a vertical climb of the EE to ``height`` above
it. ``land`` descends at ``land_speed_mps`` to the ground height with the armed attitude, then disarms on
touchdown (body within ``touchdown_height_m`` of the ground height, moving less than
``touchdown_speed_mps``, for ``touchdown_dwell_s``, on fresh motion capture: a stale sample proves nothing) or
``land_timeout_s`` after the reference arrived.

A *mission* (``trajectory=`` given, as ``omnirotor sim --serve`` replays a task of ``omnirotor run``) arms
and starts tracking on the first frame exactly as the in-process closed loop does: ``reset`` on that frame,
its hold command for the first period, then a step per frame; its ground pose is where the trajectory
starts.

Not thread-safe: call every method from the loop's thread (the node polls its requests between periods).
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor.control.trajectory import PoseTrajectory, Waypoint
from omnirotor.errors import InputError
from omnirotor.fly.failsafe import Cause, Failsafe, FailsafeMonitor, LinkAges
from omnirotor.fly.modes import FLYING, FlightMode, refusal
from omnirotor.fly.presets import FlyParams, admittance_presets
from omnirotor.fly.requests import FlightReply, FlightRequest, FlightStatus, Setpoint, request_from
from omnirotor.fly.setpoints import InFlight, geodesic_angle, segment_duration
from omnirotor.messages import RotorCommand, SensorFrame
from omnirotor.so3 import R_from_quat_wxyz, R_from_rpy, quat_wxyz_from_R, rpy_from_R

__all__ = ["FlightDirector", "LinkAges"]

_M = FlightMode
# Cause bits as plain ints: an IntFlag operation builds an enum member, some microseconds per period.
_NO_COMMAND = int(Cause.NO_COMMAND)
_NONFINITE_COMMAND = int(Cause.NONFINITE_COMMAND)
_LAND_TIMEOUT = int(Cause.LAND_TIMEOUT)
_CONTROLLER_ERROR = int(Cause.CONTROLLER_ERROR)
_GEOFENCE = int(Cause.GEOFENCE)
_ESTIMATE_DIVERGED = int(Cause.ESTIMATE_DIVERGED)
_PLANT_FAILSAFE = int(Cause.PLANT_FAILSAFE)
_sum = np.add.reduce  # the ufunc itself: ndarray.sum's Python wrapper costs more than the sum of 8 speeds
# What output() sends this period (decided by on_frame).
_ZERO, _IDLE, _FIRST, _STEP = range(4)


class _Leg:
    """One segment to fly: EE pose, duration [s], and the admittance preset it starts with (None: unchanged)."""

    __slots__ = ("p_W", "R_WB", "duration_s", "preset")

    def __init__(self, p_W: np.ndarray, R_WB: np.ndarray, duration_s: float, preset: str | None = None) -> None:
        self.p_W = np.array(p_W, dtype=float)
        self.R_WB = np.array(R_WB, dtype=float)
        self.duration_s = float(duration_s)
        self.preset = preset


class FlightDirector:
    """Flight modes, live setpoints and failsafes for one controller (module docstring).

    Args:
        controller: the interaction controller (:class:`~omnirotor.control.controller.InteractionController`).
        params: flight parameters (:func:`omnirotor.fly.presets.load_fly_params`).
        trajectory: a mission: arm and fly it from the first frame (module docstring); None waits for ``arm``.
        preset: the admittance preset the controller starts with (for the status), default ``params.free_preset``
            (a mission flies the controller's own parameters: its name is then "task").
    """

    def __init__(
        self, controller, params: FlyParams | None = None, *, trajectory: PoseTrajectory | None = None,
        preset: str | None = None,
    ) -> None:  # fmt: skip
        self.params = p = params if params is not None else FlyParams()
        self.controller = controller
        self.inflight = InFlight(controller)
        self._presets = admittance_presets(p)
        self._monitor = FailsafeMonitor(p)
        vehicle = controller.vehicle
        self._n = vehicle.n_rotors
        self._lo = float(vehicle.omega_min_hz)
        self._hi = float(vehicle.omega_max_hz)
        self._p_E_B = np.asarray(vehicle.p_E_B, dtype=float)
        norm = float(np.linalg.norm(self._p_E_B))
        self._tool_B = self._p_E_B / norm if norm > 0 else np.array([0.0, 0.0, -1.0])
        self._out = np.zeros(self._n)  # the speeds output() returns (one array, overwritten every period)
        self._first = np.zeros(self._n)
        self._idle = np.full(self._n, min(max(p.idle_hz, self._lo), self._hi))
        self.mode = _M.DISARMED
        self.failsafe = Failsafe.NONE  # the level reached in the current incident
        self.cause = 0  # Cause bits of what is wrong now
        self._sticky = 0  # Cause bits of this period from output() (bad commands), shown until the next
        self._plan = _ZERO
        self._t = math.nan  # time of the last frame [s]
        self._mocap_p = np.full(3, math.nan)
        self._mocap_q = np.full(4, math.nan)
        self._have_mocap = False
        self._mocap_fresh = False  # the last sample is within mocap_stale_s (touchdown is judged on fresh ones only)
        self._ground_p = np.zeros(3)  # body pose when armed
        self._ground_R = np.eye(3)
        self._pending: PoseTrajectory | None = None  # take-off/mission trajectory to reset on the next frame
        self._legs: list[_Leg] = []
        self._arrive_t = math.inf  # trajectory time at which the current leg arrives
        self._target: Setpoint | None = None
        self._anchor_p = np.zeros(3)
        self._anchor_R = np.eye(3)
        self._normal_W = np.zeros(3)
        self._depth = 0.0
        self._landed_at = math.inf  # trajectory time the landing reference reached the ground
        self._td_since = math.nan  # touchdown window start [s] and its z band
        self._td_zmin = math.inf
        self._td_zmax = -math.inf
        self._diverged_since = math.nan  # frame time the estimate began to disagree with motion capture [s]
        self._fence_lo = np.asarray(p.workspace_min_m, dtype=float) - p.geofence_margin_m
        self._fence_hi = np.asarray(p.workspace_max_m, dtype=float) + p.geofence_margin_m
        self.preset = preset if preset is not None else ("task" if trajectory is not None else p.free_preset)
        self.counts = {"frames": 0, "steps": 0, "accepted": 0, "refused": 0, "failsafe_events": 0, "bad_commands": 0}
        self.message = "disarmed"
        if trajectory is not None:
            self._pending = trajectory
            self.mode = _M.TRACK
            self._arrive_t = trajectory.t_end
            w = trajectory.waypoints[0]
            self._ground_R = np.array(w.R_WB)
            self._ground_p = w.p_W - self._ground_R @ self._p_E_B
            last = trajectory.waypoints[-1]
            self._target = Setpoint(tuple(last.p_W), tuple(quat_wxyz_from_R(last.R_WB)))
            self.message = "mission: tracking the given trajectory"
            # a mission's trajectory is not held to the workspace box: the geofence also spans its poses (tip, body)
            for w in trajectory.waypoints:
                for q in (np.asarray(w.p_W, dtype=float), w.p_W - np.asarray(w.R_WB) @ self._p_E_B):
                    np.minimum(self._fence_lo, q - p.geofence_margin_m, out=self._fence_lo)
                    np.maximum(self._fence_hi, q + p.geofence_margin_m, out=self._fence_hi)

    # -- the period ----------------------------------------------------------------------------------------

    def on_frame(self, frame: SensorFrame, ages: LinkAges) -> None:
        """Take one period's frame: failsafes, pending take-off, arrivals, touchdown (module docstring)."""
        self._t = t_frame = float(frame.t)
        self.counts["frames"] += 1
        if frame.mocap_new and frame.mocap_p_W is not None and frame.mocap_q_WB is not None:
            self._mocap_p[:] = frame.mocap_p_W
            self._mocap_q[:] = frame.mocap_q_WB
            self._have_mocap = True
        self._mocap_fresh = ages.mocap_age_s <= self.params.mocap_stale_s  # NaN: not fresh
        level, cause = self._monitor.level(ages)
        self.cause = int(cause) | self._sticky
        self._sticky = 0
        if level == Failsafe.STOP:
            if self.mode != _M.DISARMED:
                self._failsafe_action(Failsafe.STOP, "frames stopped: rotors stopped, disarmed")
                self._disarm()
            self._plan = _ZERO
            return
        self._escalate(level)
        if self._pending is not None:
            if not (frame.mocap_new or frame.state is not None):  # the estimator starts from a pose sample
                self._plan = _IDLE
                return
            traj, self._pending = self._pending, None
            try:
                self.inflight.start(frame, traj)
                self._first[:] = self.controller.hold_command(t_frame).omega_hz
            except Exception as exc:  # noqa: BLE001  (the controller refused the frame: stay on the ground, say why)
                self.cause |= _CONTROLLER_ERROR
                self.message = f"controller refused the take-off frame: {exc}"
                self._disarm()
                self._plan = _ZERO
                return
            self._plan = _FIRST
            return
        if self.mode in FLYING and frame.mocap_new and self._have_mocap:
            self._check_vehicle(t_frame)
        if self.mode in FLYING:
            self._progress(self.inflight.time(t_frame))
        if self.mode in FLYING:
            self._plan = _STEP
        elif self.mode == _M.ARMED:
            self._plan = _IDLE
        else:
            self._plan = _ZERO

    @property
    def armed(self) -> bool:
        """False when disarmed: the node then publishes zero speeds only, flagged ``STATE_STOP`` (its invariant)."""
        return self.mode != _M.DISARMED

    def wants_step(self) -> bool:
        """True if the node should step the controller on this period's frame."""
        return self._plan == _STEP

    def output(self, cmd: RotorCommand | None) -> np.ndarray:
        """The rotor speeds to publish this period [Hz] (module docstring).

        Zeros when disarmed or stopped, the idle speed when armed on the ground, the controller's hold
        command on the period of its reset, else ``cmd``'s speeds. A missing or non-finite command while
        stepping sends the last good speeds again (flagged in the status). Always finite and within the
        vehicle's limits (zero counts as stopped).

        Returns:
            (n,) the director's own array, overwritten by the next call: publish (copy) it before then.
        """
        out = self._out
        plan = self._plan
        if plan == _STEP:
            if cmd is None:
                self._sticky |= _NO_COMMAND
                self.counts["bad_commands"] += 1
            else:
                hz = cmd.omega_hz
                if type(hz) is np.ndarray and hz.shape == out.shape and math.isfinite(_sum(hz)):  # NaN, inf: sum too
                    np.copyto(out, hz)
                else:
                    self._sticky |= _NONFINITE_COMMAND
                    self.counts["bad_commands"] += 1
                self.counts["steps"] += 1
                self._control_status = int(cmd.status)
            np.maximum(out, self._lo, out=out)
            np.minimum(out, self._hi, out=out)
        elif plan == _FIRST:
            np.clip(self._first, self._lo, self._hi, out=out)
            self._plan = _STEP  # a second output() in the same period sends the same
        elif plan == _IDLE:
            np.copyto(out, self._idle)
        else:
            out.fill(0.0)
        return out

    _control_status = 0

    # -- requests ------------------------------------------------------------------------------------------

    def request(self, req) -> FlightReply:
        """Handle one request (a :class:`FlightRequest`, a mapping or a ``FlightRequest`` message).

        Returns:
            Accepted or refused, the modes before and after, and why (one line). Never raises.
        """
        before = self.mode
        try:
            r = request_from(req)
        except Exception as exc:  # noqa: BLE001  (anything that is not a request is refused, never raised)
            self.counts["refused"] += 1
            why = str(exc) if isinstance(exc, InputError) else f"malformed flight request: {type(exc).__name__}"
            return FlightReply(False, "status", before, before, why)
        try:
            why = self._check(r)
            if why is None:
                done = getattr(self, f"_do_{r.kind}")(r)
                if isinstance(done, _Refused):
                    why = str(done)
        except InputError as exc:  # a bad value, or the controller refused the change
            why = str(exc)
        except Exception as exc:  # noqa: BLE001  (never raised to the loop; said in the reply and the status)
            why = f"internal error: {type(exc).__name__}: {exc}"
            self.cause |= _CONTROLLER_ERROR
        if why is not None:
            self.counts["refused"] += 1
            return FlightReply(False, r.kind, before, self.mode, why)
        if r.kind != "status":
            self.counts["accepted"] += 1
            self.message = f"{r.kind}: {before.label} -> {self.mode.label}" + (f" ({done})" if done else "")
        return FlightReply(True, r.kind, before, self.mode, done or "")

    def _check(self, r: FlightRequest) -> str | None:
        if r.kind == "disarm" and r.force:
            return None
        why = refusal(r.kind, self.mode)
        if why is not None:
            return why
        if self.failsafe != Failsafe.NONE and r.kind not in ("status", "land", "disarm", "preset"):
            return f"failsafe {self.failsafe.name.lower()} ({_cause_text(self.cause)}): only land or disarm"
        if self._pending is not None and r.kind not in ("status", "disarm", "preset", "land"):
            return "starting (the controller resets on the next frame)"
        return None

    def _do_status(self, r: FlightRequest) -> str:
        return self._status_line()

    def _do_arm(self, r: FlightRequest) -> _Refused | str:
        if not self._estimate_valid():
            return _Refused("no valid estimate (motion capture and IMU must be fresh and finite)")
        if self.cause:
            return _Refused(f"links not healthy ({_cause_text(self.cause)})")
        self._ground_p[:] = self._mocap_p
        self._ground_R[:] = R_from_quat_wxyz(self._mocap_q)
        if not self.params.in_workspace(self._ground_p):
            return _Refused(f"the vehicle at {_xyz(self._ground_p)} is outside the workspace")
        self.mode = _M.ARMED
        self.failsafe = Failsafe.NONE
        return f"ground at {_xyz(self._ground_p)}"

    def _do_takeoff(self, r: FlightRequest) -> _Refused | str:
        p = self.params
        h = p.takeoff_height_m if r.height_m is None else r.height_m
        if not (math.isfinite(h) and 0.0 < h <= p.max_takeoff_height_m):
            return _Refused(f"height {h} m: must be in (0, {p.max_takeoff_height_m}] m")
        R = self._ground_R
        p0 = self._ground_p + R @ self._p_E_B
        p1 = p0 + np.array([0.0, 0.0, h])
        why = self._outside(p1, R)
        if why:
            return _Refused(why)
        T = segment_duration(h, 0.0, p, speed_mps=p.climb_speed_mps)
        self._pending = PoseTrajectory([Waypoint(0.0, p0, R), Waypoint(T, p1, R)])
        self._legs = []
        self._arrive_t = T
        self._target = _setpoint(p1, R, T)
        self.mode = _M.TAKEOFF
        self._set_preset(p.free_preset)
        return f"{h:.2f} m in {T:.1f} s"

    def _do_goto(self, r: FlightRequest) -> _Refused | str:
        sp = r.setpoint
        if sp is None:
            return _Refused("goto needs a target position")
        ref = self.inflight.reference()
        R = _attitude(sp, ref.R_WB)
        p_target = np.array(sp.p_W, dtype=float)
        contact = self.mode == _M.CONTACT
        p_ref = p_target + self._depth * (R @ self._tool_B) if contact else p_target
        why = self._outside(p_ref, R)
        if why:
            return _Refused(why)
        T = self._duration(ref.p_W, ref.R_WB, p_ref, R, sp.duration_s)
        if isinstance(T, _Refused):
            return T
        if contact:
            self._anchor_p[:] = p_target
            self._anchor_R[:] = R
            self._normal_W[:] = R @ self._tool_B
        self._fly([_Leg(p_ref, R, T)])
        if not contact:
            self.mode = _M.TRACK
            self._landed_at = math.inf
        return f"to {_xyz(p_target)} in {T:.1f} s" + (f" at depth {self._depth:.3f} m" if contact else "")

    def _do_hold(self, r: FlightRequest) -> str:
        return self._hold()

    def _do_push(self, r: FlightRequest) -> _Refused | str:
        p = self.params
        d = r.depth_m
        if d is None or not (math.isfinite(d) and 0.0 <= d <= p.max_depth_m):
            return _Refused(f"depth {d} m: must be in [0, {p.max_depth_m}] m")
        if self.mode == _M.HOLD:
            if d == 0.0:
                return _Refused("not in contact (depth 0 already)")
            ref = self.inflight.reference()
            self._anchor_p[:] = ref.p_W
            self._anchor_R[:] = ref.R_WB
            self._normal_W[:] = ref.R_WB @ self._tool_B
        p_ref = self._anchor_p + d * self._normal_W
        why = self._outside(p_ref, self._anchor_R)
        if why:
            return _Refused(why)
        T = segment_duration(abs(d - self._depth), 0.0, p, speed_mps=p.depth_speed_mps)
        entering = self.mode == _M.HOLD
        if entering:
            self._set_preset(p.contact_preset)
        self._depth = d
        self._fly([_Leg(p_ref, self._anchor_R, T)])
        self.mode = _M.CONTACT
        K = self._presets[self.preset].stiffness_pos
        force = float(np.dot(self._normal_W**2, K)) * d  # n^T K_E^p n d (diagonal K_E^p)
        return (
            f"depth {d:.3f} m along n_W {_xyz(self._normal_W)} in {T:.1f} s, preset {self.preset}: "
            f"about {force:.1f} N at steady state"
        )

    def _do_preset(self, r: FlightRequest) -> _Refused | str:
        if r.name not in self._presets:
            return _Refused(f"unknown preset {r.name!r}; presets: {', '.join(self._presets)}")
        self._set_preset(r.name)
        return f"admittance preset {r.name}"

    def _do_map(self, r: FlightRequest) -> str:
        self.inflight.set_map_mode(r.name)  # raises InputError: refused with its reason
        return f"map mode {r.name}"

    def _do_land(self, r: FlightRequest) -> str:
        return self._land()

    def _do_disarm(self, r: FlightRequest) -> str:
        was = self.mode
        self._disarm()
        return "rotors stopped in flight (forced)" if was in FLYING else "rotors stopped"

    # -- actions -------------------------------------------------------------------------------------------

    def _now(self) -> float:
        """Trajectory time of the last frame [s]."""
        return self.inflight.time(self._t)

    def _fly(self, legs: list[_Leg]) -> None:
        """Fly ``legs`` one after the other from now (the mode changes when the last arrives: :meth:`_progress`)."""
        self._legs = legs[1:]
        first = legs[0]
        if first.preset is not None:
            self._set_preset(first.preset)
        self._arrive_t = self.inflight.move_to(self._now(), first.p_W, first.R_WB, first.duration_s)
        last = legs[-1]
        self._target = _setpoint(last.p_W, last.R_WB, first.duration_s)

    def _progress(self, t: float) -> None:
        """Arrivals of legs and segments, and the landing's touchdown, at trajectory time ``t`` [s]."""
        if t >= self._arrive_t:
            if self._legs:
                leg = self._legs.pop(0)
                if leg.preset is not None:
                    self._set_preset(leg.preset)
                self._arrive_t = self.inflight.move_to(t, leg.p_W, leg.R_WB, leg.duration_s)
                return
            self._arrive_t = math.inf
            if self.mode == _M.LAND:
                self._landed_at = t
            elif self.mode in (_M.TAKEOFF, _M.TRACK):
                self.mode = _M.HOLD
                self.message = "arrived: hold"
            elif self.mode == _M.CONTACT and self._depth == 0.0:
                self.mode = _M.HOLD
                self._set_preset(self.params.free_preset)
                self.message = "left contact: hold"
        if self.mode == _M.LAND and math.isfinite(self._landed_at):
            self._touchdown(t)

    def _touchdown(self, t: float) -> None:
        p = self.params
        z = self._mocap_p[2]
        if self._have_mocap and self._mocap_fresh and abs(z - self._ground_p[2]) <= p.touchdown_height_m:
            if (
                self._td_since != self._td_since
                or self._td_zmax - self._td_zmin > p.touchdown_speed_mps * p.touchdown_dwell_s
            ):
                self._td_since, self._td_zmin, self._td_zmax = t, z, z
            self._td_zmin = min(self._td_zmin, z)
            self._td_zmax = max(self._td_zmax, z)
            if t - self._td_since >= p.touchdown_dwell_s:
                self._disarm()
                self.message = "landed: touchdown, disarmed"
                return
        else:
            self._td_since = math.nan
        if t - self._landed_at >= p.land_timeout_s:
            self._disarm()
            self.cause |= _LAND_TIMEOUT
            self._sticky |= _LAND_TIMEOUT
            self.message = f"landed: no touchdown within {p.land_timeout_s:g} s, disarmed"

    def _check_vehicle(self, t: float) -> None:
        """The geofence and the estimate's divergence (:mod:`omnirotor.fly.failsafe`): either terminates the flight.

        Called in flight on frames with a motion-capture sample, after the controller's reset (its estimate is
        the one of the last step: a period older than the sample at most).
        """
        p = self._mocap_p
        if not np.isfinite(p).all():
            return
        if bool(np.any(p < self._fence_lo)) or bool(np.any(p > self._fence_hi)):
            self._terminate(
                _GEOFENCE,
                f"failsafe stop: the body at {_xyz(p)} is more than {self.params.geofence_margin_m:g} m outside the "
                f"workspace {_box(self.params)}: rotors stopped, disarmed",
            )
            return
        est = self.inflight.estimate_p_W()
        if est is None:
            self._diverged_since = math.nan
            return
        off = float(np.linalg.norm(est - p))
        if not off <= self.params.divergence_m:  # NaN too
            if self._diverged_since != self._diverged_since:
                self._diverged_since = t
            if t - self._diverged_since >= self.params.divergence_s:
                self._terminate(
                    _ESTIMATE_DIVERGED,
                    f"failsafe stop: the position estimate {_xyz(est)} is {off:.2f} m from motion capture "
                    f"{_xyz(p)} for {t - self._diverged_since:.2f} s: rotors stopped, disarmed",
                )
        else:
            self._diverged_since = math.nan

    def plant_failsafe(self, why: str) -> None:
        """The plant stopped obeying the commands: disarm (zeros from now on), said in the status.

        The simulator's offboard-loss failsafe, or PX4 out of offboard or disarmed (said by the robot bridge).
        """
        if self.mode == _M.DISARMED:
            return
        self.cause |= _PLANT_FAILSAFE
        self._sticky |= _PLANT_FAILSAFE
        self._disarm()
        self._failsafe_action(Failsafe.STOP, f"the robot stopped obeying ({why}): disarmed")

    def _terminate(self, cause: int, message: str) -> None:
        """Stop the rotors and disarm now, flagged with ``cause`` (shown until the next frame)."""
        self.cause |= cause
        self._sticky |= cause
        self._disarm()
        self._failsafe_action(Failsafe.STOP, message)

    def _hold(self) -> str:
        """Stop the reference: a braking segment from where it is, at the acceleration limit."""
        ref = self.inflight.reference()
        v = float(np.linalg.norm(ref.v_W))
        T = max(self.params.min_segment_s, 2.0 * v / self.params.max_acc_mps2)
        stop = ref.p_W + ref.v_W * (T / 2.0)  # about where a smooth braking from v ends
        self._fly([_Leg(stop, ref.R_WB, T)])
        if self.mode in (_M.TRACK, _M.TAKEOFF, _M.LAND):
            self.mode = _M.TRACK
            self._landed_at = math.inf
        return f"braking to {_xyz(stop)} in {T:.1f} s"

    def _land(self) -> str:
        """Descend to the ground height with the armed attitude (from contact: first back to the anchor)."""
        p = self.params
        ref = self.inflight.reference()
        legs = []
        start_p, start_R = np.array(ref.p_W), np.array(ref.R_WB)
        if self.mode == _M.CONTACT:
            T = segment_duration(self._depth, 0.0, p, speed_mps=p.depth_speed_mps)
            legs.append(_Leg(self._anchor_p, self._anchor_R, T))  # out of contact with the contact preset
            start_p = self._anchor_p.copy()
            self._depth = 0.0
        R = self._ground_R
        body = start_p - start_R @ self._p_E_B
        body[2] = self._ground_p[2]
        p_land = body + R @ self._p_E_B
        dist = float(np.linalg.norm(p_land - start_p))
        T = segment_duration(dist, geodesic_angle(start_R, R), p, speed_mps=p.land_speed_mps)
        legs.append(_Leg(p_land, R, T, p.free_preset))
        self._landed_at = math.inf
        self._td_since = math.nan
        self._fly(legs)
        self.mode = _M.LAND
        return f"to {_xyz(body)} (body) in {sum(leg.duration_s for leg in legs):.1f} s"

    def _disarm(self) -> None:
        self.mode = _M.DISARMED
        self._pending = None
        self._legs = []
        self._arrive_t = math.inf
        self._landed_at = math.inf
        self._depth = 0.0
        self._target = None
        self._plan = _ZERO
        self._diverged_since = math.nan

    def _set_preset(self, name: str) -> None:
        if name != self.preset:
            self.inflight.set_admittance(self._presets[name])
            self.preset = name

    def _escalate(self, level: Failsafe) -> None:
        """Act on a failsafe level higher than the one reached in this incident (module docstring)."""
        if level == Failsafe.NONE:
            self.failsafe = Failsafe.NONE
            return
        if level <= self.failsafe:
            return
        self.failsafe = level
        if level == Failsafe.DEGRADED or self.mode not in FLYING or self._pending is not None:
            return
        why = _cause_text(self.cause)
        try:
            if level == Failsafe.HOLD and self.mode not in (_M.HOLD, _M.LAND):
                if self.mode == _M.CONTACT:  # withdraw to the anchor, hover there
                    T = segment_duration(self._depth, 0.0, self.params, speed_mps=self.params.depth_speed_mps)
                    self._depth = 0.0
                    self._fly([_Leg(self._anchor_p, self._anchor_R, T)])
                else:
                    self._hold()
                self._failsafe_action(level, f"failsafe hold ({why})")
            elif level == Failsafe.LAND and self.mode != _M.LAND:
                self._land()
                self._failsafe_action(level, f"failsafe land ({why})")
        except Exception as exc:  # noqa: BLE001  (the controller refused the change: stop trying, say so)
            self.cause |= _CONTROLLER_ERROR
            self.message = f"failsafe {level.name.lower()} failed: {exc}"

    def _failsafe_action(self, level: Failsafe, message: str) -> None:
        self.failsafe = level
        self.counts["failsafe_events"] += 1
        self.message = message

    # -- checks --------------------------------------------------------------------------------------------

    def _estimate_valid(self) -> bool:
        q = self._mocap_q
        return (
            self._have_mocap
            and bool(np.isfinite(self._mocap_p).all() and np.isfinite(q).all())
            and abs(float(q @ q) - 1.0) < 1e-3
        )

    def _outside(self, p_E_W: np.ndarray, R_WB: np.ndarray) -> str | None:
        """Why an EE pose is outside the workspace (tip or body), or None."""
        if not np.isfinite(p_E_W).all():
            return "target not finite"
        if not self.params.in_workspace(p_E_W):
            return f"tool tip {_xyz(p_E_W)} outside the workspace {_box(self.params)}"
        body = p_E_W - R_WB @ self._p_E_B
        if not self.params.in_workspace(body):
            return f"body {_xyz(body)} outside the workspace {_box(self.params)}"
        return None

    def _duration(self, p0, R0, p1, R1, given: float | None) -> float | _Refused:
        """The segment's duration: the shortest within the limits, or the one given if it is not shorter."""
        T = segment_duration(float(np.linalg.norm(p1 - p0)), geodesic_angle(R0, R1), self.params)
        if given is None:
            return T
        if not (math.isfinite(given) and given >= T):
            return _Refused(f"duration {given} s is shorter than the limits allow ({T:.2f} s)")
        return given

    # -- status --------------------------------------------------------------------------------------------

    def status(self) -> FlightStatus:
        """The current status (a fresh object; about 50 Hz is fine)."""
        c = self.counts
        return FlightStatus(
            t=self._t, mode=self.mode, failsafe=int(self.failsafe), cause=int(self.cause),
            control_status=self._control_status, preset=self.preset, map_mode=self.inflight.map_mode,
            depth_m=self._depth, target=self._target, frames=c["frames"], steps=c["steps"],
            requests_accepted=c["accepted"], requests_refused=c["refused"], failsafe_events=c["failsafe_events"],
            bad_commands=c["bad_commands"], message=self.message,
        )  # fmt: skip

    def _status_line(self) -> str:
        s = f"mode {self.mode.label}, preset {self.preset}, map {self.inflight.map_mode}"
        if self.mode == _M.CONTACT:
            s += f", depth {self._depth:.3f} m"
        if self.failsafe != Failsafe.NONE or self.cause:
            s += f", failsafe {self.failsafe.name.lower()} ({_cause_text(self.cause)})"
        return s + f"; {self.message}"


class _Refused(str):
    """A refusal's reason, returned by a ``_do_*`` handler instead of what was done."""


def _attitude(sp: Setpoint, current: np.ndarray) -> np.ndarray:
    """The target attitude of a setpoint: its quaternion, or the current one with the angles given replaced."""
    if sp.q_WB is not None:
        q = np.asarray(sp.q_WB, dtype=float)
        if not (np.isfinite(q).all() and abs(float(q @ q) - 1.0) < 1e-6):
            raise InputError("target quaternion must be a finite unit quaternion (w, x, y, z)")
        return R_from_quat_wxyz(q)
    rpy = rpy_from_R(np.asarray(current))
    for i, given in enumerate((sp.roll_deg, sp.pitch_deg, sp.yaw_deg)):
        if given is not None:
            if not math.isfinite(given):
                raise InputError("target angles must be finite")
            rpy[i] = math.radians(given)
    return R_from_rpy(*rpy)


def _setpoint(p_W: np.ndarray, R_WB: np.ndarray, duration_s: float) -> Setpoint:
    return Setpoint(
        tuple(float(v) for v in p_W), tuple(float(v) for v in quat_wxyz_from_R(R_WB)), duration_s=duration_s
    )


def _xyz(v) -> str:
    return "(" + ", ".join(f"{float(x):.3f}" for x in v) + ")"


def _box(p: FlyParams) -> str:
    return f"{_xyz(p.workspace_min_m)}..{_xyz(p.workspace_max_m)} m"


def _cause_text(cause: int) -> str:
    names = [c.name.lower().replace("_", " ") for c in Cause if c and cause & c]
    return ", ".join(names) if names else "none"
