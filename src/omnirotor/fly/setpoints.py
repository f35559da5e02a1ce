"""Live setpoints: reference segments timed from the flight limits, and the controller's in-flight API.

Durations. A rest-to-rest minimum-jerk segment over a distance ``d`` in time ``T`` (SPEC §4.5's quintic
``s = 10τ³ - 15τ⁴ + 6τ⁵``) peaks at speed ``15/8 · d/T`` (τ = 1/2) and acceleration ``10/√3 · d/T²``
(τ = 1/2 ∓ √3/6); the attitude follows the same profile over its geodesic angle. :func:`segment_duration`
takes the shortest ``T`` that keeps speed, acceleration and angular rate within :class:`FlyParams`'s limits.

In-flight API. :class:`InFlight` is what the director calls to change the controller's reference in flight
(a minimum-jerk segment to a new pose, the admittance parameters, the map mode). It uses the controller's
own in-flight methods where the controller has them (``InteractionController.move_to``, ``set_admittance``,
``set_map_mode``: a segment that starts from the current desired reference with its velocity and
acceleration). On a
controller without them it falls back to what a rest-to-rest trajectory allows: the new pose is appended
after the segment the reference is flying (so the reference stays smooth; a goto given mid-segment starts
when that segment ends), the admittance parameters are written into the filter's parameter fields (its
offsets are kept, so the compliant reference does not jump), and a map-mode switch is refused.
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor.control.admittance import AdmittanceFilter, AdmittanceParams
from omnirotor.control.trajectory import PoseTrajectory, ReferenceSample, Waypoint
from omnirotor.errors import InputError
from omnirotor.fly.presets import FlyParams
from omnirotor.messages import SensorFrame
from omnirotor.so3 import log_so3

__all__ = ["segment_duration", "InFlight", "PEAK_SPEED", "PEAK_ACC"]

_ADMITTANCE_PARAMETER_FIELDS = (
    "inv_mass_pos",
    "damping_pos",
    "stiffness_pos",
    "inv_mass_rot",
    "damping_rot",
    "stiffness_rot",
)
"""The parameter fields of the admittance filter's state (the rest are its offsets, kept by a switch)."""

PEAK_SPEED = 15.0 / 8.0
"""Peak speed of a rest-to-rest quintic, in units of distance / duration."""
PEAK_ACC = 10.0 / math.sqrt(3.0)
"""Peak acceleration of a rest-to-rest quintic, in units of distance / duration²."""


def segment_duration(distance_m: float, angle_rad: float, params: FlyParams, speed_mps: float | None = None) -> float:
    """Shortest duration [s] of a rest-to-rest segment within the limits (module docstring).

    Args:
        distance_m: straight-line distance of the EE tip [m].
        angle_rad: geodesic angle of the attitude change [rad].
        params: the flight limits (``max_acc_mps2``, ``max_rate_dps``, ``min_segment_s``).
        speed_mps: speed limit [m/s]; default ``params.max_speed_mps``.
    """
    v = params.max_speed_mps if speed_mps is None else speed_mps
    rate = math.radians(params.max_rate_dps)
    return max(
        params.min_segment_s,
        PEAK_SPEED * distance_m / v,
        math.sqrt(PEAK_ACC * distance_m / params.max_acc_mps2),
        PEAK_SPEED * angle_rad / rate,
    )


def geodesic_angle(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle [rad] of the rotation from ``R_a`` to ``R_b``."""
    return float(np.linalg.norm(log_so3(R_a.T @ R_b)))


class InFlight:
    """The controller seen by the director: start, the current reference, and in-flight changes.

    Args:
        controller: an :class:`~omnirotor.control.controller.InteractionController` (or anything with its
            ``reset``, ``trajectory``, ``admittance`` and, optionally, the in-flight methods).
    """

    def __init__(self, controller) -> None:
        self.controller = controller
        self.t0 = 0.0
        self._native_move = getattr(controller, "move_to", None)
        self._native_admittance = getattr(controller, "set_admittance", None)
        self._native_map = getattr(controller, "set_map_mode", None)
        self._sample = ReferenceSample()

    @property
    def native(self) -> bool:
        """True if the controller has its own in-flight segment API (continuous velocity and acceleration)."""
        return self._native_move is not None

    def start(self, frame: SensorFrame, trajectory: PoseTrajectory) -> None:
        """Reset the controller on ``frame`` to fly ``trajectory`` from the frame's time (its time 0)."""
        self.controller.reset(frame, trajectory)
        self.t0 = float(frame.t)

    def time(self, t_frame: float) -> float:
        """The trajectory time [s] of a frame time [s]."""
        return t_frame - self.t0

    def reference(self, t: float) -> ReferenceSample:
        """The desired EE reference at trajectory time ``t`` [s] (a sample overwritten by the next call).

        With the controller's own in-flight API, the desired reference of its last step.
        """
        if self._native_move is not None:
            self._sample.copy_from(self.controller.desired_ee)
            return self._sample
        return self.controller.trajectory.sample(t, self._sample)

    def move_to(self, t: float, p_W: np.ndarray, R_WB: np.ndarray, duration_s: float) -> float:
        """A minimum-jerk segment to the EE pose ``(p_W [m], R_WB)`` lasting ``duration_s`` [s], from time ``t``.

        Returns:
            The trajectory time [s] at which the reference arrives.
        """
        if self._native_move is not None:
            self._native_move(p_W, R_WB, duration_s)
            return t + duration_s
        traj = self.controller.trajectory
        wps = traj.waypoints
        if t >= traj.t_end:
            last = wps[-1]
            start = (Waypoint(t, last.p_W, last.R_WB),)
        elif t < traj.t_start:
            start = (wps[0],)
        else:
            i = max(k for k, w in enumerate(wps) if w.t <= t)
            start = (wps[i], wps[i + 1])
        t_go = start[-1].t
        new = PoseTrajectory((*start, Waypoint(t_go + duration_s, p_W, R_WB)), traj.attitude_profile)
        self._replace_trajectory(new)
        return t_go + duration_s

    def _replace_trajectory(self, trajectory: PoseTrajectory) -> None:
        """Fly ``trajectory`` on the controller's clock from the next step (the stand-in's one private touch).

        The controller of this version keeps its trajectory in the arguments of its compiled step, built by
        ``_build_kernel_args``; its in-flight API (``move_to``) replaces this.
        """
        c = self.controller
        c._trajectory = trajectory
        c._build_kernel_args()

    def set_admittance(self, params: AdmittanceParams) -> None:
        """Fly with the admittance parameters ``params`` from the next step (the offsets are kept)."""
        if self._native_admittance is not None:
            self._native_admittance(params)
            return
        f = self.controller.admittance
        fresh = AdmittanceFilter(params).state  # the filter's own constructor writes the parameter fields
        for name in _ADMITTANCE_PARAMETER_FIELDS:
            f.state[name] = fresh[name]
        f.params = params

    @property
    def map_mode(self) -> str:
        """The map mode the controller flies with."""
        return self.controller.params.maps.mode

    def set_map_mode(self, mode: str) -> None:
        """Switch the wrench-map mode in flight.

        Raises:
            InputError: the controller cannot (no in-flight API, or no maps for that mode).
        """
        if mode == self.map_mode:
            return
        if self._native_map is None:
            raise InputError("this controller cannot switch the map mode in flight (no set_map_mode)")
        self._native_map(mode)
