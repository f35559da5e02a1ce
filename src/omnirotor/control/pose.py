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
import math

import numpy as np

from omnirotor._jit import jit
from omnirotor.blocks import register, state_array
from omnirotor.config import check_finite, check_positive
from omnirotor.control.trajectory import ReferenceSample
from omnirotor.errors import InputError
from omnirotor.messages import StateEstimate
from omnirotor.vehicle import VehicleParams

__all__ = ["PoseControlParams", "PoseController", "STATE_DTYPE", "pose_step"]

Vec3 = tuple[float, float, float]

_F8 = np.float64
STATE_DTYPE = np.dtype(
    [
        ("f_ref_W", _F8, 3),  # output: the force reference [N], world frame ...
        ("m_ref_B", _F8, 3),  # ... and the moment reference [N·m], body frame
        ("errors", _F8, 12),  # e_p_W, e_v_W, e_R_B, e_omega_B of the last step
        ("e_i_W", _F8, 3),  # clamped integral of the position error [m·s]
        ("n_nonfinite", _F8),  # steps with a non-finite input (nothing else changed)
        # parameters
        ("mass_kg", _F8),
        ("gravity", _F8),
        ("J_diag", _F8, 3),  # inertia diagonal [kg·m²]
        ("compensate", _F8),  # 1: subtract the estimated external wrench
        ("feedforward", _F8),  # 1: angular-acceleration feed-forward
        ("k_p", _F8, 3),
        ("k_v", _F8, 3),
        ("k_i", _F8, 3),
        ("k_R", _F8, 3),
        ("k_omega", _F8, 3),
        ("max_pos_error", _F8),
        ("max_vel_error", _F8),
        ("max_integral", _F8),
    ]
)
"""Outputs, state and parameters of the pose controller (named fields; the compiled step reads them so)."""


@jit
def _sat(x: float, lim: float) -> float:
    return lim if x > lim else (-lim if x < -lim else x)


@jit
def pose_step(r, rd, p, v, R, w, f_hat, m_hat, dt: float) -> None:
    """One step of the pose controller (module docstring), in place.

    Args:
        r: the controller's state record (:data:`STATE_DTYPE`); ``w_ref`` and ``errors`` are written there.
        rd: the body reference record (:data:`omnirotor.control.trajectory.REFERENCE_DTYPE`).
        p: (3,) position [m].
        v: (3,) velocity [m/s].
        R: (3, 3) ``R_WB``.
        w: (3,) ``omega_B`` [rad/s].
        f_hat: (3,) estimated external force [N], world frame.
        m_hat: (3,) estimated external moment [N·m], body frame.
        dt: period [s].
    """
    m, g = r.mass_kg, r.gravity
    J = r.J_diag
    jx, jy, jz = J[0], J[1], J[2]
    lim_p, lim_v, lim_i = r.max_pos_error, r.max_vel_error, r.max_integral
    px, py, pz = p[0], p[1], p[2]
    vx, vy, vz = v[0], v[1], v[2]
    r00, r01, r02 = R[0, 0], R[0, 1], R[0, 2]
    r10, r11, r12 = R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22 = R[2, 0], R[2, 1], R[2, 2]
    wx, wy, wz = w[0], w[1], w[2]
    fhx, fhy, fhz = f_hat[0], f_hat[1], f_hat[2]
    mhx, mhy, mhz = m_hat[0], m_hat[1], m_hat[2]
    check = px + py + pz + vx + vy + vz + wx + wy + wz + fhx + fhy + fhz + mhx + mhy + mhz + dt
    check += r00 + r01 + r02 + r10 + r11 + r12 + r20 + r21 + r22
    if not math.isfinite(check):
        r.n_nonfinite += 1.0
        return
    # --- translation (world frame)
    epx = _sat(rd.p_W[0] - px, lim_p)
    epy = _sat(rd.p_W[1] - py, lim_p)
    epz = _sat(rd.p_W[2] - pz, lim_p)
    evx = _sat(rd.v_W[0] - vx, lim_v)
    evy = _sat(rd.v_W[1] - vy, lim_v)
    evz = _sat(rd.v_W[2] - vz, lim_v)
    E = r.e_i_W
    eix = E[0] = _sat(E[0] + epx * dt, lim_i)
    eiy = E[1] = _sat(E[1] + epy * dt, lim_i)
    eiz = E[2] = _sat(E[2] + epz * dt, lim_i)
    c = r.compensate
    kp, kv, ki = r.k_p, r.k_v, r.k_i
    fx = m * (rd.a_W[0] + kp[0] * epx + kv[0] * evx + ki[0] * eix) - c * fhx
    fy = m * (rd.a_W[1] + kp[1] * epy + kv[1] * evy + ki[1] * eiy) - c * fhy
    fz = m * (rd.a_W[2] + g + kp[2] * epz + kv[2] * evz + ki[2] * eiz) - c * fhz
    # --- rotation (body frame): E = R^T R^r, e_R = 1/2 (E - E^T)^v
    Q = rd.R_WB
    q00, q01, q02, q10, q11, q12, q20, q21, q22 = (
        Q[0, 0],
        Q[0, 1],
        Q[0, 2],
        Q[1, 0],
        Q[1, 1],
        Q[1, 2],
        Q[2, 0],
        Q[2, 1],
        Q[2, 2],
    )
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
    ox, oy, oz = rd.omega_W[0], rd.omega_W[1], rd.omega_W[2]
    ax, ay, az = rd.alpha_W[0], rd.alpha_W[1], rd.alpha_W[2]
    ewx = r00 * ox + r10 * oy + r20 * oz - wx
    ewy = r01 * ox + r11 * oy + r21 * oz - wy
    ewz = r02 * ox + r12 * oy + r22 * oz - wz
    ff = r.feedforward
    kR, kw = r.k_R, r.k_omega
    dwx = kR[0] * eRx + kw[0] * ewx + ff * (r00 * ax + r10 * ay + r20 * az)
    dwy = kR[1] * eRy + kw[1] * ewy + ff * (r01 * ax + r11 * ay + r21 * az)
    dwz = kR[2] * eRz + kw[2] * ewz + ff * (r02 * ax + r12 * ay + r22 * az)
    hx, hy, hz = jx * wx, jy * wy, jz * wz  # J omega
    F, M = r.f_ref_W, r.m_ref_B
    F[0], F[1], F[2] = fx, fy, fz
    M[0] = wy * hz - wz * hy + jx * dwx - c * mhx
    M[1] = wz * hx - wx * hz + jy * dwy - c * mhy
    M[2] = wx * hy - wy * hx + jz * dwz - c * mhz
    er = r.errors
    er[0], er[1], er[2] = epx, epy, epz
    er[3], er[4], er[5] = evx, evy, evz
    er[6], er[7], er[8] = eRx, eRy, eRz
    er[9], er[10], er[11] = ewx, ewy, ewz


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


@register("pose", "geometric-pid")
class PoseController:
    """The pose controller of SPEC §4.1 (module docstring): body reference + state -> wrench reference.

    Args:
        vehicle: mass, inertia (diagonal) and gravity are used.
        params: gains and saturations.
        state: optional ``(1,)`` array of :data:`STATE_DTYPE` to hold :attr:`state` (e.g. a field of the
            controller's state); a new one by default.

    Attributes:
        state: the ``(1,)`` state record the compiled step reads and writes (the arrays below are views).
        f_ref_W: (3,) output force reference [N], world frame, overwritten by every :meth:`step` (a view).
        m_ref_B: (3,) output moment reference [N·m], body frame, likewise.
        errors: (12,) the errors of the last step ``[e_p_W [m], e_v_W [m/s], e_R_B [-], e_omega_B [rad/s]]``.
    """

    state_dtype = STATE_DTYPE
    log_fields = (("w_ref", ("f_ref_W", "m_ref_B")), ("pose_err", ("errors",)))
    log_labels = {
        "w_ref": ("fx", "fy", "fz", "mx", "my", "mz"),
        "pose_err": tuple(f"{g}.{a}" for g in ("e_p", "e_v", "e_R", "e_omega") for a in ("x", "y", "z")),
    }
    kernel = pose_step

    def __init__(
        self, vehicle: VehicleParams, params: PoseControlParams | None = None, *, state: np.ndarray | None = None
    ) -> None:
        self.params = params if params is not None else PoseControlParams()
        self.vehicle = vehicle
        p = self.params
        self.state = st = state_array(STATE_DTYPE, state, "pose controller")
        st["mass_kg"] = vehicle.mass
        st["gravity"] = vehicle.gravity
        st["J_diag"] = [float(j) for j in vehicle.inertia_diag]
        st["compensate"] = 1.0 if p.compensate_ext_wrench else 0.0
        st["feedforward"] = 1.0 if p.feedforward_angular_acc else 0.0
        for name in ("k_p", "k_v", "k_i", "k_R", "k_omega", "max_pos_error", "max_vel_error", "max_integral"):
            st[name] = getattr(p, name)
        rec = st[0]
        self.f_ref_W = rec["f_ref_W"]
        self.m_ref_B = rec["m_ref_B"]
        self.errors = rec["errors"]
        self._ei = rec["e_i_W"]

    def reset(self) -> None:
        """Zero the integral, the outputs and the counter of rejected steps (parameters kept)."""
        for name in ("f_ref_W", "m_ref_B", "errors", "e_i_W", "n_nonfinite"):
            self.state[name] = 0.0

    @property
    def n_nonfinite(self) -> int:
        """Steps whose inputs were not finite (each changed nothing else)."""
        return int(self.state["n_nonfinite"][0])

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
        """One control step (:func:`pose_step`).

        Args:
            ref: body (CoM) reference, world-frame rates.
            state: state estimate.
            f_ext_hat_W: (3,) estimated external force [N], world frame.
            m_ext_hat_B: (3,) estimated external moment about the CoM [N·m], body frame.
            dt: control period [s] (integral of the position error).

        Returns:
            :attr:`w_ref`, the (6,) wrench reference ``[f_ref_W; m_ref_B]`` (a new array).
        """
        f64 = np.float64
        pose_step(
            self.state[0],
            ref.state[0],
            np.asarray(state.p_W, dtype=f64),
            np.asarray(state.v_W, dtype=f64),
            np.asarray(state.R_WB, dtype=f64),
            np.asarray(state.omega_B, dtype=f64),
            np.asarray(f_ext_hat_W, dtype=f64),
            np.asarray(m_ext_hat_B, dtype=f64),
            float(dt),
        )
        return self.w_ref

    @property
    def w_ref(self) -> np.ndarray:
        """(6,) ``[f_ref_W [N]; m_ref_B [N·m]]`` of the last step (a new array)."""
        return np.r_[self.f_ref_W, self.m_ref_B]
