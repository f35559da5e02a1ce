"""Pose controller: the wrench reference that tracks a body reference (SPEC §4.1, eqs. 4-5).

Errors (position in the world frame, attitude in the body frame, as the authors' ``full_attitude`` mode):

    e_p = sat(p^r - p, 0.2 m),   e_v = sat(v^r - v, 2 m/s),   e_i = sat(e_i + e_p dt, 0.1 m·s)   (per axis)
    e_R = 1/2 (R^T R^r - R^rT R)^v,      e_omega = R^T omega^r_W - omega_B

The reference's angular velocity is world-frame here (``omega^r_W``, see
:class:`~omnirotor.control.trajectory.ReferenceSample`), so the SPEC's ``R^T R^r omega^r`` (reference body
frame) reads ``R^T omega^r_W``, and the feed-forward ``R^T R^r d(omega^r)/dt`` reads ``R^T alpha^r_W``.

Control law (``e3`` world up, gains diagonal):

    f^r_W = m (a^r + g e3 + K_p e_p + K_v e_v + K_i e_i) - f_ext_hat_W
    m^r_B = omega x J omega + J (K_R e_R + K_omega e_omega + R^T alpha^r_W) - m_ext_hat_B

The integral is accumulated from the saturated position error and clamped (anti-windup). Subtracting the
estimated external wrench is the paper's law (``compensate_ext_wrench``; the authors' code had it
commented out); the angular feed-forward is the code's (``feedforward_angular_acc``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from omnirotor.config import check_finite, check_positive
from omnirotor.control import _kernels as _k
from omnirotor.control.trajectory import ReferenceSample
from omnirotor.errors import InputError
from omnirotor.messages import StateEstimate
from omnirotor.vehicle import VehicleParams

__all__ = ["PoseControlParams", "PoseController"]

Vec3 = tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class PoseControlParams:
    """Gains and saturations of the pose controller (SPEC §4.1, paper values).

    Gains are per axis (diagonals); translational ones in world axes, rotational ones in body axes. They
    are acceleration-level: the force is ``m`` times, the moment ``J`` times the weighted errors.

    Attributes:
        k_p: position gain K_p [1/s²].
        k_v: velocity gain K_v [1/s].
        k_i: integral gain K_i [1/s³].
        k_R: attitude gain K_R [1/s²] (paper 300; the authors' code used 330 about z).
        k_omega: angular-rate gain K_omega [1/s].
        max_pos_error: saturation of each position-error component [m].
        max_vel_error: saturation of each velocity-error component [m/s].
        max_integral: clamp of each component of the position-error integral [m·s].
        compensate_ext_wrench: subtract the observer's wrench estimate (paper eqs. 4-5).
        feedforward_angular_acc: add the reference angular acceleration ``R^T alpha^r_W``.
    """

    k_p: Vec3 = (23.0, 23.0, 25.0)
    k_v: Vec3 = (15.0, 15.0, 20.0)
    k_i: Vec3 = (4.0, 4.0, 6.0)
    k_R: Vec3 = (300.0, 300.0, 300.0)
    k_omega: Vec3 = (80.0, 80.0, 80.0)
    max_pos_error: float = 0.2
    max_vel_error: float = 2.0
    max_integral: float = 0.1
    compensate_ext_wrench: bool = True
    feedforward_angular_acc: bool = True

    def __post_init__(self) -> None:
        for name in ("k_p", "k_v", "k_i", "k_R", "k_omega"):
            value = getattr(self, name)
            if len(value) != 3:
                raise InputError(f"pose.{name} must have 3 values, got {len(value)}")
            check_finite(f"pose.{name}", *value)
            if any(v < 0 for v in value):
                raise InputError(f"pose.{name} must be >= 0, got {value}")
            object.__setattr__(self, name, tuple(float(v) for v in value))
        check_positive("pose.max_pos_error", self.max_pos_error)
        check_positive("pose.max_vel_error", self.max_vel_error)
        check_positive("pose.max_integral", self.max_integral)


class PoseController:
    """The pose controller of SPEC §4.1 (module docstring): body reference + state -> wrench reference.

    Args:
        vehicle: mass, inertia (diagonal) and gravity are used.
        params: gains and saturations.
        buffer: optional (``POSE_SIZE``,) float64 array to hold :attr:`kernel_state`; a new one by default.

    Attributes:
        w_ref: (6,) output ``[f_ref_W [N]; m_ref_B [N·m]]``, overwritten by every :meth:`step`.
        errors: (12,) the errors of the last step ``[e_p_W [m], e_v_W [m/s], e_R_B [-], e_omega_B [rad/s]]``.
        kernel_state: the packed outputs, state and parameters the compiled step reads and writes (layout
            ``POSE_*`` of :mod:`omnirotor.control._kernels`; the arrays above are views into it).
    """

    def __init__(
        self, vehicle: VehicleParams, params: PoseControlParams | None = None, *, buffer: np.ndarray | None = None
    ) -> None:
        self.params = params if params is not None else PoseControlParams()
        self.vehicle = vehicle
        p = self.params
        # Outputs, state and parameters in one array, the layout of control._kernels (POSE_*).
        self.kernel_state = x = _k.state_buffer(buffer, _k.POSE_SIZE, "pose controller")
        x[_k.POSE_MASS] = vehicle.mass
        x[_k.POSE_GRAVITY] = vehicle.gravity
        x[_k.POSE_J : _k.POSE_J + 3] = [float(j) for j in vehicle.inertia_diag]
        x[_k.POSE_COMP] = 1.0 if p.compensate_ext_wrench else 0.0
        x[_k.POSE_FF] = 1.0 if p.feedforward_angular_acc else 0.0
        for name, at in (("k_p", _k.POSE_KP), ("k_v", _k.POSE_KV), ("k_i", _k.POSE_KI)):
            x[at : at + 3] = getattr(p, name)
        x[_k.POSE_KR : _k.POSE_KR + 3] = p.k_R
        x[_k.POSE_KW : _k.POSE_KW + 3] = p.k_omega
        x[_k.POSE_LIM_P] = p.max_pos_error
        x[_k.POSE_LIM_V] = p.max_vel_error
        x[_k.POSE_LIM_I] = p.max_integral
        self.w_ref = x[_k.POSE_W_REF : _k.POSE_W_REF + 6]
        self.errors = x[_k.POSE_ERRORS : _k.POSE_ERRORS + 12]
        self._ei = x[_k.POSE_EI : _k.POSE_EI + 3]

    def reset(self) -> None:
        """Zero the integral."""
        self._ei[:] = 0.0

    @property
    def e_i_W(self) -> np.ndarray:
        """(3,) the clamped integral of the position error [m·s] (a new array)."""
        return self._ei.copy()

    def step(
        self,
        ref: ReferenceSample,
        state: StateEstimate,
        f_ext_hat_W: np.ndarray,
        m_ext_hat_B: np.ndarray,
        dt: float,
    ) -> np.ndarray:
        """One control step (:func:`omnirotor.control._kernels.pose_step`).

        Args:
            ref: body (CoM) reference, world-frame rates.
            state: state estimate.
            f_ext_hat_W: (3,) estimated external force [N], world frame.
            m_ext_hat_B: (3,) estimated external moment about the CoM [N·m], body frame.
            dt: control period [s] (integral of the position error).

        Returns:
            :attr:`w_ref`, the (6,) wrench reference ``[f_ref_W; m_ref_B]`` (reused buffer; copy to keep).
        """
        f64 = np.float64
        _k.pose_step(
            self.kernel_state,
            ref.data,
            np.asarray(state.p_W, dtype=f64),
            np.asarray(state.v_W, dtype=f64),
            np.asarray(state.R_WB, dtype=f64),
            np.asarray(state.omega_B, dtype=f64),
            np.asarray(f_ext_hat_W, dtype=f64),
            np.asarray(m_ext_hat_B, dtype=f64),
            float(dt),
        )
        return self.w_ref
