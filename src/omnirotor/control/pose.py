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


def _sat(x: float, lim: float) -> float:
    return lim if x > lim else (-lim if x < -lim else x)


class PoseController:
    """The pose controller of SPEC §4.1 (module docstring): body reference + state -> wrench reference.

    Args:
        vehicle: mass, inertia (diagonal) and gravity are used.
        params: gains and saturations.

    Attributes:
        w_ref: (6,) output ``[f_ref_W [N]; m_ref_B [N·m]]``, overwritten by every :meth:`step`.
        errors: (12,) the errors of the last step ``[e_p_W [m], e_v_W [m/s], e_R_B [-], e_omega_B [rad/s]]``.
    """

    def __init__(self, vehicle: VehicleParams, params: PoseControlParams | None = None) -> None:
        self.params = params if params is not None else PoseControlParams()
        self.vehicle = vehicle
        p = self.params
        self._m = vehicle.mass
        self._g = vehicle.gravity
        jx, jy, jz = vehicle.inertia_diag
        self._J = (float(jx), float(jy), float(jz))
        self._comp = 1.0 if p.compensate_ext_wrench else 0.0
        self._ff = 1.0 if p.feedforward_angular_acc else 0.0
        self.w_ref = np.zeros(6)
        self.errors = np.zeros(12)
        self._ei = [0.0, 0.0, 0.0]

    def reset(self) -> None:
        """Zero the integral."""
        self._ei = [0.0, 0.0, 0.0]

    @property
    def e_i_W(self) -> np.ndarray:
        """(3,) the clamped integral of the position error [m·s] (a new array)."""
        return np.array(self._ei)

    def step(
        self,
        ref: ReferenceSample,
        state: StateEstimate,
        f_ext_hat_W: np.ndarray,
        m_ext_hat_B: np.ndarray,
        dt: float,
    ) -> np.ndarray:
        """One control step.

        Args:
            ref: body (CoM) reference, world-frame rates.
            state: state estimate.
            f_ext_hat_W: (3,) estimated external force [N], world frame.
            m_ext_hat_B: (3,) estimated external moment about the CoM [N·m], body frame.
            dt: control period [s] (integral of the position error).

        Returns:
            :attr:`w_ref`, the (6,) wrench reference ``[f_ref_W; m_ref_B]`` (reused buffer; copy to keep).
        """
        p = self.params
        m, g = self._m, self._g
        jx, jy, jz = self._J
        kp, kv, ki, kR, kw = p.k_p, p.k_v, p.k_i, p.k_R, p.k_omega
        lim_p, lim_v, lim_i = p.max_pos_error, p.max_vel_error, p.max_integral
        rd = ref.data.tolist()  # p 0:3, v 3:6, a 6:9, R 9:18 (row-major), omega_W 18:21, alpha_W 21:24
        px, py, pz = state.p_W.tolist()
        vx, vy, vz = state.v_W.tolist()
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = state.R_WB.tolist()
        wx, wy, wz = state.omega_B.tolist()
        fhx, fhy, fhz = f_ext_hat_W.tolist()
        mhx, mhy, mhz = m_ext_hat_B.tolist()

        # --- translation (world frame)
        epx = _sat(rd[0] - px, lim_p)
        epy = _sat(rd[1] - py, lim_p)
        epz = _sat(rd[2] - pz, lim_p)
        evx = _sat(rd[3] - vx, lim_v)
        evy = _sat(rd[4] - vy, lim_v)
        evz = _sat(rd[5] - vz, lim_v)
        ei = self._ei
        eix = ei[0] = _sat(ei[0] + epx * dt, lim_i)
        eiy = ei[1] = _sat(ei[1] + epy * dt, lim_i)
        eiz = ei[2] = _sat(ei[2] + epz * dt, lim_i)
        c = self._comp
        fx = m * (rd[6] + kp[0] * epx + kv[0] * evx + ki[0] * eix) - c * fhx
        fy = m * (rd[7] + kp[1] * epy + kv[1] * evy + ki[1] * eiy) - c * fhy
        fz = m * (rd[8] + g + kp[2] * epz + kv[2] * evz + ki[2] * eiz) - c * fhz

        # --- rotation (body frame): E = R^T R^r, e_R = 1/2 (E - E^T)^v
        q00, q01, q02, q10, q11, q12, q20, q21, q22 = rd[9:18]
        e01 = r00 * q01 + r10 * q11 + r20 * q21
        e02 = r00 * q02 + r10 * q12 + r20 * q22
        e10 = r01 * q00 + r11 * q10 + r21 * q20
        e12 = r01 * q02 + r11 * q12 + r21 * q22
        e20 = r02 * q00 + r12 * q10 + r22 * q20
        e21 = r02 * q01 + r12 * q11 + r22 * q21
        eRx = 0.5 * (e21 - e12)
        eRy = 0.5 * (e02 - e20)
        eRz = 0.5 * (e10 - e01)
        # R^T omega^r_W and R^T alpha^r_W
        ox, oy, oz, ax, ay, az = rd[18:24]
        ewx = r00 * ox + r10 * oy + r20 * oz - wx
        ewy = r01 * ox + r11 * oy + r21 * oz - wy
        ewz = r02 * ox + r12 * oy + r22 * oz - wz
        ff = self._ff
        dwx = kR[0] * eRx + kw[0] * ewx + ff * (r00 * ax + r10 * ay + r20 * az)
        dwy = kR[1] * eRy + kw[1] * ewy + ff * (r01 * ax + r11 * ay + r21 * az)
        dwz = kR[2] * eRz + kw[2] * ewz + ff * (r02 * ax + r12 * ay + r22 * az)
        hx, hy, hz = jx * wx, jy * wy, jz * wz  # J omega
        self.w_ref[:] = (
            fx,
            fy,
            fz,
            wy * hz - wz * hy + jx * dwx - c * mhx,
            wz * hx - wx * hz + jy * dwy - c * mhy,
            wx * hy - wy * hx + jz * dwz - c * mhz,
        )
        self.errors[:] = (epx, epy, epz, evx, evy, evz, eRx, eRy, eRz, ewx, ewy, ewz)
        return self.w_ref
