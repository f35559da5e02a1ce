"""Live setpoints: reference segments timed from the flight limits, and the controller's in-flight API.

Durations. A rest-to-rest minimum-jerk segment over a distance ``d`` in time ``T`` (SPEC §4.5's quintic
``s = 10τ³ - 15τ⁴ + 6τ⁵``) peaks at speed ``15/8 · d/T`` (τ = 1/2) and acceleration ``10/√3 · d/T²``
(τ = 1/2 ∓ √3/6); the attitude follows the same profile over its geodesic angle. :func:`segment_duration`
takes the shortest ``T`` that keeps speed, acceleration and angular rate within :class:`FlyParams`'s limits.

In-flight API. :class:`InFlight` is what the director calls to change the controller's reference in flight,
through the controller's own methods (:meth:`InteractionController.retarget`: a minimum-jerk segment from the
desired reference of its last step, position, velocity and acceleration continuous; ``set_admittance``: new
parameters, the filter's offsets kept, so the compliant reference does not jump; ``set_map_mode``).
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor.control.admittance import AdmittanceParams
from omnirotor.control.trajectory import PoseTrajectory, ReferenceSample
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

    Every change goes through the controller's own in-flight API (module docstring); none touches its state.

    Args:
        controller: an :class:`~omnirotor.control.controller.InteractionController`.
    """

    def __init__(self, controller) -> None:
        self.controller = controller
        self.t0 = 0.0
        self._sample = ReferenceSample()

    def start(self, frame: SensorFrame, trajectory: PoseTrajectory) -> None:
        """Reset the controller on ``frame`` to fly ``trajectory`` from the frame's time (its time 0)."""
        self.controller.reset(frame, trajectory)
        self.t0 = float(frame.t)

    def time(self, t_frame: float) -> float:
        """The trajectory time [s] of a frame time [s]."""
        return t_frame - self.t0

    def reference(self) -> ReferenceSample:
        """The desired EE reference of the controller's last step (a sample overwritten by the next call)."""
        self._sample.copy_from(self.controller.desired_ee)
        return self._sample

    def estimate_p_W(self) -> np.ndarray | None:  # noqa: N802  (a frame in the name)
        """The controller's position estimate of its last step (body, world frame) [m]; None when not finite.

        Read from the controller's record (``own.estimate``, :mod:`omnirotor.control.composer`): a copy.
        """
        state = getattr(self.controller, "state", None)
        if state is None:
            return None
        try:
            est = state[0]["own"]["estimate"]
        except (KeyError, ValueError, IndexError, TypeError):
            return None
        p = np.array(est["p_W"], dtype=float)
        return p if np.isfinite(p).all() else None  # a degraded (coasting) estimate is compared too

    def move_to(self, t: float, p_W: np.ndarray, R_WB: np.ndarray, duration_s: float) -> float:
        """A minimum-jerk segment from the current reference to the EE pose ``(p_W [m], R_WB)`` in ``duration_s``.

        Args:
            t: the trajectory time [s] it starts at (the last frame's).
            p_W: (3,) target EE position [m], world frame.
            R_WB: (3, 3) target EE attitude.
            duration_s: its duration [s].

        Returns:
            The trajectory time [s] at which the reference arrives.

        Raises:
            InputError: the controller refused the segment.
        """
        self.controller.retarget(p_W, R_WB, duration_s)
        return t + duration_s

    def set_admittance(self, params: AdmittanceParams) -> None:
        """Fly with the admittance parameters ``params`` from the next step (the offsets are kept)."""
        self.controller.set_admittance(params)

    @property
    def map_mode(self) -> str:
        """The map mode the controller flies with."""
        return self.controller.params.maps.mode

    def set_map_mode(self, mode: str) -> None:
        """Switch the wrench-map mode in flight.

        Raises:
            InputError: an unknown mode, or one whose maps the controller was not given.
        """
        if mode != self.map_mode:
            self.controller.set_map_mode(mode)
