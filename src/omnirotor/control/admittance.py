"""Admittance filter: the compliant end-effector reference (SPEC §4.4, parameters §5.1).

The estimated external wrench, moved to the end-effector (EE) tip and expressed in the world frame,

    f_E = f_ext_W,     m_E = R_WB m_ext_B - (R_WB p_E_B) x f_ext_W,

drives a virtual mass-spring-damper whose states (world frame) are a position offset ``xi_p`` and a
rotation offset ``R_xi`` with angular rate ``omega_xi``:

    M_p xi_p'' + D_p xi_p' + K_p xi_p = f_E
    M_R omega_xi' + D_R omega_xi + K_R 1/2 (R_xi - R_xi^T)^v = m_E,      R_xi' = [omega_xi]x R_xi

(signs as in the authors' ``admittance.cc``: a +z estimated force raises the reference). The compliant EE
reference is the desired one displaced by the offsets, with the exact rate composition of ``R_xi R_d``:

    p_r = p_d + xi_p,   v_r = v_d + xi_p',   a_r = a_d + xi_p''
    R_r = R_xi R_d,     omega_r = omega_xi + R_xi omega_d,
    alpha_r = omega_xi' + R_xi alpha_d + omega_xi x (R_xi omega_d)        (all world frame)

(for a small ``R_xi`` this is the plain sum of the SPEC). :func:`body_reference_from_ee` then turns an EE
reference into the reference of the body (CoM) frame with ``R_E^B = I`` (SPEC §1.5):

    R^r = R_E^r,  p^r = p_E^r - R^r p_E^B,  v^r = v_E^r - omega^r x (R^r p_E^B),
    a^r = a_E^r - alpha^r x (R^r p_E^B) - omega^r x (omega^r x R^r p_E^B).

Integration, as in the authors' code, per step of ``dt`` [s]:
``xi_p += xi_p' dt + 1/2 xi_p'' dt^2``, ``xi_p' += xi_p'' dt``, ``omega_xi += omega_xi' dt``,
``R_xi <- exp([omega_xi dt]x) R_xi``. ``R_xi`` is kept as a unit quaternion, so it never drifts off SO(3).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from omnirotor._jit import jit, jit_inline
from omnirotor.blocks import register, state_array
from omnirotor.config import check_finite
from omnirotor.control.trajectory import ReferenceSample
from omnirotor.errors import InputError
from omnirotor.so3 import R_from_quat_into, quat_integrate_world_into

__all__ = [
    "AdmittanceParams",
    "AdmittanceFilter",
    "ADMITTANCE_PRESETS",
    "ee_wrench_W",
    "body_reference_from_ee",
    "STATE_DTYPE",
    "admittance_step",
    "compliant_reference",
    "ee_wrench",
    "body_reference",
]

Vec3 = tuple[float, float, float]

_F8 = np.float64
STATE_DTYPE = np.dtype(
    [
        ("xi_p_W", _F8, 3),  # position offset [m]
        ("xi_p_dot_W", _F8, 3),  # its rate [m/s]
        ("xi_p_ddot_W", _F8, 3),  # its acceleration at the last step [m/s²]
        ("omega_xi_W", _F8, 3),  # angular rate of the rotation offset [rad/s], world frame
        ("omega_xi_dot_W", _F8, 3),  # its derivative at the last step [rad/s²]
        ("R_xi", _F8, (3, 3)),  # rotation offset (world to world)
        ("q_xi", _F8, 4),  # R_xi as a unit quaternion wxyz
        ("n_nonfinite", _F8),  # steps with a non-finite input (nothing else changed)
        # parameters
        ("inv_mass_pos", _F8, 3),  # 1 / M_p [1/kg]
        ("damping_pos", _F8, 3),
        ("stiffness_pos", _F8, 3),
        ("inv_mass_rot", _F8, 3),  # 1 / M_R
        ("damping_rot", _F8, 3),
        ("stiffness_rot", _F8, 3),
    ]
)
"""State and parameters of the admittance filter (named fields; the compiled step reads them so)."""

_PARAMETERS = ("inv_mass_pos", "damping_pos", "stiffness_pos", "inv_mass_rot", "damping_rot", "stiffness_rot")


@jit
def ee_wrench(f_ext_W, m_ext_B, R, p_E_B, f_E_W, m_E_W) -> None:
    """The external wrench moved to the EE tip, world frame (:func:`ee_wrench_W`)."""
    fx, fy, fz = f_ext_W[0], f_ext_W[1], f_ext_W[2]
    mx, my, mz = m_ext_B[0], m_ext_B[1], m_ext_B[2]
    r00, r01, r02 = R[0, 0], R[0, 1], R[0, 2]
    r10, r11, r12 = R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22 = R[2, 0], R[2, 1], R[2, 2]
    ex, ey, ez = p_E_B[0], p_E_B[1], p_E_B[2]
    rx = r00 * ex + r01 * ey + r02 * ez
    ry = r10 * ex + r11 * ey + r12 * ez
    rz = r20 * ex + r21 * ey + r22 * ez
    f_E_W[0], f_E_W[1], f_E_W[2] = fx, fy, fz
    m_E_W[0] = r00 * mx + r01 * my + r02 * mz - (ry * fz - rz * fy)
    m_E_W[1] = r10 * mx + r11 * my + r12 * mz - (rz * fx - rx * fz)
    m_E_W[2] = r20 * mx + r21 * my + r22 * mz - (rx * fy - ry * fx)


@jit_inline
def body_reference(e, p_E_B, d) -> None:
    """Body (CoM) reference record ``d`` from the EE reference record ``e``; ``d`` may be ``e``.

    See :func:`body_reference_from_ee`. ``p_E_B`` may be a record's field or an array: both reach one compiled
    :func:`_body_reference` (numba types a field by its shape, ``p_E_B[:]`` as an array).
    """
    _body_reference(e, p_E_B[:], d)


@jit
def _body_reference(e, p_E_B, d) -> None:
    """:func:`body_reference` with ``p_E_B`` an array."""
    px, py, pz = e.p_W[0], e.p_W[1], e.p_W[2]
    vx, vy, vz = e.v_W[0], e.v_W[1], e.v_W[2]
    ax, ay, az = e.a_W[0], e.a_W[1], e.a_W[2]
    R = e.R_WB
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = (
        R[0, 0],
        R[0, 1],
        R[0, 2],
        R[1, 0],
        R[1, 1],
        R[1, 2],
        R[2, 0],
        R[2, 1],
        R[2, 2],
    )
    wx, wy, wz = e.omega_W[0], e.omega_W[1], e.omega_W[2]
    bx, by, bz = e.alpha_W[0], e.alpha_W[1], e.alpha_W[2]
    ex, ey, ez = p_E_B[0], p_E_B[1], p_E_B[2]
    rx = r00 * ex + r01 * ey + r02 * ez
    ry = r10 * ex + r11 * ey + r12 * ez
    rz = r20 * ex + r21 * ey + r22 * ez
    cx, cy, cz = wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx
    ccx, ccy, ccz = wy * cz - wz * cy, wz * cx - wx * cz, wx * cy - wy * cx
    d.p_W[0] = px - rx
    d.p_W[1] = py - ry
    d.p_W[2] = pz - rz
    d.v_W[0] = vx - cx
    d.v_W[1] = vy - cy
    d.v_W[2] = vz - cz
    d.a_W[0] = ax - (by * rz - bz * ry) - ccx
    d.a_W[1] = ay - (bz * rx - bx * rz) - ccy
    d.a_W[2] = az - (bx * ry - by * rx) - ccz
    # Attitude and its rates are the EE's (R_E^B = I).
    d.R_WB[0, 0], d.R_WB[0, 1], d.R_WB[0, 2] = r00, r01, r02
    d.R_WB[1, 0], d.R_WB[1, 1], d.R_WB[1, 2] = r10, r11, r12
    d.R_WB[2, 0], d.R_WB[2, 1], d.R_WB[2, 2] = r20, r21, r22
    d.omega_W[0], d.omega_W[1], d.omega_W[2] = wx, wy, wz
    d.alpha_W[0], d.alpha_W[1], d.alpha_W[2] = bx, by, bz


@jit
def admittance_step(r, f_E_W, m_E_W, dt: float) -> None:
    """Advance the admittance filter (module docstring) by ``dt`` under the EE wrench, in place.

    Args:
        r: the filter's state record (:data:`STATE_DTYPE`).
        f_E_W: (3,) force at the EE [N], world frame.
        m_E_W: (3,) moment about the EE [N·m], world frame.
        dt: step [s].
    """
    fx, fy, fz = f_E_W[0], f_E_W[1], f_E_W[2]
    mx, my, mz = m_E_W[0], m_E_W[1], m_E_W[2]
    if not math.isfinite(fx + fy + fz + mx + my + mz + dt):
        r.n_nonfinite += 1.0
        return
    P, V, A = r.xi_p_W, r.xi_p_dot_W, r.xi_p_ddot_W
    W, WD, q = r.omega_xi_W, r.omega_xi_dot_W, r.q_xi
    inv_m, D, K = r.inv_mass_pos, r.damping_pos, r.stiffness_pos
    inv_j, D_R, K_R = r.inv_mass_rot, r.damping_rot, r.stiffness_rot
    xp, yp, zp = P[0], P[1], P[2]
    xv, yv, zv = V[0], V[1], V[2]
    wx, wy, wz = W[0], W[1], W[2]
    ax = inv_m[0] * (fx - D[0] * xv - K[0] * xp)
    ay = inv_m[1] * (fy - D[1] * yv - K[1] * yp)
    az = inv_m[2] * (fz - D[2] * zv - K[2] * zp)
    half_dt2 = 0.5 * dt * dt
    # Rotational spring: 1/2 (R_xi - R_xi^T)^v = 2 q_w q_v for a unit quaternion.
    qw, qx, qy, qz = q[0], q[1], q[2], q[3]
    alx = inv_j[0] * (mx - D_R[0] * wx - K_R[0] * 2.0 * qw * qx)
    aly = inv_j[1] * (my - D_R[1] * wy - K_R[1] * 2.0 * qw * qy)
    alz = inv_j[2] * (mz - D_R[2] * wz - K_R[2] * 2.0 * qw * qz)
    wx += alx * dt
    wy += aly * dt
    wz += alz * dt
    P[0] = xp + xv * dt + ax * half_dt2
    P[1] = yp + yv * dt + ay * half_dt2
    P[2] = zp + zv * dt + az * half_dt2
    V[0] = xv + ax * dt
    V[1] = yv + ay * dt
    V[2] = zv + az * dt
    A[0], A[1], A[2] = ax, ay, az
    W[0], W[1], W[2] = wx, wy, wz
    WD[0], WD[1], WD[2] = alx, aly, alz
    # R_xi <- exp([omega dt]x) R_xi, i.e. q <- dq (x) q with dq the world-frame increment.
    if quat_integrate_world_into(q, wx, wy, wz, dt):
        R_from_quat_into(q, r.R_xi)


@jit
def admittance_block_step(r, f_E_W, m_E_W, desired, compliant, dt: float) -> None:
    """The admittance kind's step (:data:`omnirotor.blocks.KIND_STEPS`): the filter, then the compliant reference.

    :func:`admittance_step` under the EE wrench, then :func:`compliant_reference` of the desired reference record
    ``desired`` into the record ``compliant``.
    """
    admittance_step(r, f_E_W, m_E_W, dt)
    compliant_reference(r, desired, compliant)


@jit
def compliant_reference(r, des, out) -> None:
    """The desired EE reference record ``des`` displaced by the filter's offsets ``r``, into ``out``.

    See :meth:`AdmittanceFilter.compliant_reference`; ``out`` is not ``des``.
    """
    P, V, A = r.xi_p_W, r.xi_p_dot_W, r.xi_p_ddot_W
    for i in range(3):
        out.p_W[i] = des.p_W[i] + P[i]
        out.v_W[i] = des.v_W[i] + V[i]
        out.a_W[i] = des.a_W[i] + A[i]
    Rx, Rd = r.R_xi, des.R_WB
    r00, r01, r02 = Rx[0, 0], Rx[0, 1], Rx[0, 2]
    r10, r11, r12 = Rx[1, 0], Rx[1, 1], Rx[1, 2]
    r20, r21, r22 = Rx[2, 0], Rx[2, 1], Rx[2, 2]
    # R_r = R_xi R_d
    for i in range(3):
        a0, a1, a2 = Rx[i, 0], Rx[i, 1], Rx[i, 2]
        for j in range(3):
            out.R_WB[i, j] = a0 * Rd[0, j] + a1 * Rd[1, j] + a2 * Rd[2, j]
    ox, oy, oz = des.omega_W[0], des.omega_W[1], des.omega_W[2]
    bx, by, bz = des.alpha_W[0], des.alpha_W[1], des.alpha_W[2]
    W, WD = r.omega_xi_W, r.omega_xi_dot_W
    wx, wy, wz = W[0], W[1], W[2]
    vx, vy, vz = WD[0], WD[1], WD[2]
    rox = r00 * ox + r01 * oy + r02 * oz
    roy = r10 * ox + r11 * oy + r12 * oz
    roz = r20 * ox + r21 * oy + r22 * oz
    out.omega_W[0] = wx + rox
    out.omega_W[1] = wy + roy
    out.omega_W[2] = wz + roz
    out.alpha_W[0] = vx + r00 * bx + r01 * by + r02 * bz + wy * roz - wz * roy
    out.alpha_W[1] = vy + r10 * bx + r11 * by + r12 * bz + wz * rox - wx * roz
    out.alpha_W[2] = vz + r20 * bx + r21 * by + r22 * bz + wx * roy - wy * rox


def _diag(x: float) -> Vec3:
    return (x, x, x)


@dataclasses.dataclass(frozen=True)
class AdmittanceParams:
    """Virtual mass, damping and stiffness of the EE, diagonals in world axes (SPEC §5.1 Table 2).

    Defaults are the free-flight set of the authors' code (M 1.5, D 40, K 100; not in the paper).

    Attributes:
        mass_pos: (3,) translational virtual mass M_E^p [kg].
        damping_pos: (3,) translational damping D_E^p [N·s/m].
        stiffness_pos: (3,) translational stiffness K_E^p [N/m].
        mass_rot: (3,) rotational virtual inertia M_E^R [kg·m²].
        damping_rot: (3,) rotational damping D_E^R [N·m·s/rad].
        stiffness_rot: (3,) rotational stiffness K_E^R [N·m/rad].
    """

    mass_pos: Vec3 = _diag(1.5)
    damping_pos: Vec3 = _diag(40.0)
    stiffness_pos: Vec3 = _diag(100.0)
    mass_rot: Vec3 = _diag(1.5)
    damping_rot: Vec3 = _diag(40.0)
    stiffness_rot: Vec3 = _diag(100.0)

    def __post_init__(self) -> None:
        for name in ("mass_pos", "damping_pos", "stiffness_pos", "mass_rot", "damping_rot", "stiffness_rot"):
            value = getattr(self, name)
            if len(value) != 3:
                raise InputError(f"admittance.{name} must have 3 values, got {len(value)}")
            check_finite(f"admittance.{name}", *value)
            floor_ok = all(v > 0.0 for v in value) if name.startswith("mass") else all(v >= 0.0 for v in value)
            if not floor_ok:
                rule = "> 0" if name.startswith("mass") else ">= 0"
                raise InputError(f"admittance.{name} must be {rule}, got {value}")
            object.__setattr__(self, name, tuple(float(v) for v in value))

    @classmethod
    def preset(cls, name: str) -> AdmittanceParams:
        """The parameter set of one experiment: "PC", "SD", "PiH" (SPEC §5.1 Table 2) or "free".

        Raises:
            InputError: unknown name.
        """
        try:
            return ADMITTANCE_PRESETS[name]
        except KeyError:
            raise InputError(f"unknown admittance preset {name!r}; presets: {', '.join(ADMITTANCE_PRESETS)}") from None

    def damping_ratios(self) -> tuple[Vec3, Vec3]:
        """Damping ratios ``D / (2 sqrt(M K))`` per axis (translation, rotation); inf where K = 0."""

        def zeta(m: Vec3, d: Vec3, k: Vec3) -> Vec3:
            return tuple(
                di / (2.0 * math.sqrt(mi * ki)) if ki > 0 else math.inf for mi, di, ki in zip(m, d, k, strict=True)
            )

        return (
            zeta(self.mass_pos, self.damping_pos, self.stiffness_pos),
            zeta(self.mass_rot, self.damping_rot, self.stiffness_rot),
        )


def _table2(m_p: float, m_r: float, d_p: float, d_r: float, k_p: float, k_r: float) -> AdmittanceParams:
    return AdmittanceParams(_diag(m_p), _diag(d_p), _diag(k_p), _diag(m_r), _diag(d_r), _diag(k_r))


ADMITTANCE_PRESETS: dict[str, AdmittanceParams] = {
    # Columns as in SPEC §5.1 Table 2: M^p, M^R, D^p, D^R, K^p, K^R.
    "PC": _table2(1.5, 1.5, 13.5, 13.5, 30.0, 30.0),
    "SD": _table2(1.5, 1.5, 13.5, 13.5, 30.0, 30.0),
    "PiH": _table2(1.5, 0.5, 15.0, 2.14, 35.0, 2.29),
    "free": _table2(1.5, 1.5, 40.0, 40.0, 100.0, 100.0),
}


def ee_wrench_W(
    f_ext_W: np.ndarray, m_ext_B: np.ndarray, R_WB: np.ndarray, p_E_B: np.ndarray, f_E_W: np.ndarray, m_E_W: np.ndarray
) -> None:
    """The external wrench moved from the CoM to the EE tip, world frame (SPEC §4.4).

    Args:
        f_ext_W: (3,) estimated external force [N], world frame.
        m_ext_B: (3,) estimated external moment about the CoM [N·m], body frame.
        R_WB: (3, 3) attitude.
        p_E_B: (3,) EE tip position [m], body frame.
        f_E_W: (3,) output: force at the EE [N], world frame (``= f_ext_W``).
        m_E_W: (3,) output: moment about the EE tip [N·m], world frame.
    """
    f64 = np.float64
    ee_wrench(
        np.asarray(f_ext_W, dtype=f64),
        np.asarray(m_ext_B, dtype=f64),
        np.asarray(R_WB, dtype=f64),
        np.asarray(p_E_B, dtype=f64),
        f_E_W,
        m_E_W,
    )


def body_reference_from_ee(ee: ReferenceSample, p_E_B: np.ndarray, out: ReferenceSample) -> ReferenceSample:
    """Reference of the body (CoM) frame that puts the EE tip on the EE reference (SPEC §4.4, R_E^B = I).

    Args:
        ee: the EE reference (world-frame rates).
        p_E_B: (3,) EE tip position [m], body frame.
        out: the body reference to overwrite (may be ``ee`` itself).

    Returns:
        ``out``.
    """
    body_reference(ee.state[0], np.asarray(p_E_B, dtype=np.float64), out.state[0])
    return out


@register("admittance", "mass-spring-damper")
class AdmittanceFilter:
    """The admittance filter of SPEC §4.4 (see the module docstring for the equations).

    Args:
        params: virtual mass, damping and stiffness.
        state: optional ``(1,)`` array of :data:`STATE_DTYPE` to hold :attr:`state` (e.g. a field of the
            controller's state); a new one by default.

    Attributes:
        state: the ``(1,)`` state record the compiled step reads and writes (the arrays below are views).
        xi_p_W: (3,) position offset [m]. Read-only view; updated by :meth:`step`.
        xi_p_dot_W: (3,) its rate [m/s].
        xi_p_ddot_W: (3,) its acceleration [m/s²] at the last step.
        R_xi: (3, 3) rotation offset (world to world).
        omega_xi_W: (3,) angular rate of the offset [rad/s], world frame.
        omega_xi_dot_W: (3,) its derivative [rad/s²] at the last step.
    """

    state_dtype = STATE_DTYPE
    log_fields = ("xi_p_W",)
    kernel = admittance_block_step

    def __init__(self, params: AdmittanceParams | None = None, *, state: np.ndarray | None = None) -> None:
        self.state = st = state_array(STATE_DTYPE, state, "admittance")
        self.set_params(params if params is not None else AdmittanceParams())
        rec = st[0]
        self.xi_p_W = rec["xi_p_W"]
        self.xi_p_dot_W = rec["xi_p_dot_W"]
        self.xi_p_ddot_W = rec["xi_p_ddot_W"]
        self.omega_xi_W = rec["omega_xi_W"]
        self.omega_xi_dot_W = rec["omega_xi_dot_W"]
        self.R_xi = rec["R_xi"]
        self._q = rec["q_xi"]  # R_xi as a unit quaternion, wxyz
        self.reset()

    def set_params(self, params: AdmittanceParams) -> None:
        """Take new virtual mass, damping and stiffness; the offsets and their rates (the state) carry on."""
        self.params = p = params
        st = self.state
        st["inv_mass_pos"] = [1.0 / m for m in p.mass_pos]
        st["damping_pos"] = p.damping_pos
        st["stiffness_pos"] = p.stiffness_pos
        st["inv_mass_rot"] = [1.0 / m for m in p.mass_rot]
        st["damping_rot"] = p.damping_rot
        st["stiffness_rot"] = p.stiffness_rot

    def reset(self) -> None:
        """Zero the offsets (compliant reference = desired reference)."""
        st = self.state
        kept = {name: st[name].copy() for name in _PARAMETERS}
        st[...] = np.zeros(1, dtype=STATE_DTYPE)
        for name, value in kept.items():
            st[name] = value
        self.R_xi[...] = np.eye(3)
        self._q[0] = 1.0

    @property
    def n_nonfinite(self) -> int:
        """Steps whose inputs were not finite (each changed nothing else)."""
        return int(self.state["n_nonfinite"][0])

    def rotation_offset_vector(self) -> np.ndarray:
        """(3,) ``1/2 (R_xi - R_xi^T)^v`` = sin(angle) * axis: the spring's generalized deflection."""
        w, x, y, z = self._q.tolist()
        return np.array([2.0 * w * x, 2.0 * w * y, 2.0 * w * z])

    def step(self, f_E_W: np.ndarray, m_E_W: np.ndarray, dt: float) -> None:
        """Advance the filter by ``dt`` [s] under the EE wrench (:func:`admittance_step`).

        Args:
            f_E_W: (3,) force at the EE [N], world frame.
            m_E_W: (3,) moment about the EE [N·m], world frame.
            dt: step [s].
        """
        f64 = np.float64
        admittance_step(self.state[0], np.asarray(f_E_W, dtype=f64), np.asarray(m_E_W, dtype=f64), float(dt))

    def compliant_reference(self, desired: ReferenceSample, out: ReferenceSample) -> ReferenceSample:
        """The compliant EE reference: the desired one displaced by the filter's offsets.

        Args:
            desired: desired EE reference (world-frame rates).
            out: the compliant reference to overwrite (may not be ``desired``).

        Returns:
            ``out``.
        """
        compliant_reference(self.state[0], desired.state[0], out.state[0])
        return out
