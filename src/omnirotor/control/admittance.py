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

from omnirotor.config import check_finite
from omnirotor.control.trajectory import ReferenceSample
from omnirotor.errors import InputError

__all__ = [
    "AdmittanceParams",
    "AdmittanceFilter",
    "ADMITTANCE_PRESETS",
    "ee_wrench_W",
    "body_reference_from_ee",
]

Vec3 = tuple[float, float, float]


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
    fx, fy, fz = f_ext_W.tolist()
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R_WB.tolist()
    mx, my, mz = m_ext_B.tolist()
    ex, ey, ez = p_E_B.tolist()
    rx = r00 * ex + r01 * ey + r02 * ez
    ry = r10 * ex + r11 * ey + r12 * ez
    rz = r20 * ex + r21 * ey + r22 * ez
    f_E_W[:] = f_ext_W
    m_E_W[:] = (
        r00 * mx + r01 * my + r02 * mz - (ry * fz - rz * fy),
        r10 * mx + r11 * my + r12 * mz - (rz * fx - rx * fz),
        r20 * mx + r21 * my + r22 * mz - (rx * fy - ry * fx),
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
    e = ee.data  # layout (see trajectory.ReferenceSample): p 0:3, v 3:6, a 6:9, R 9:18, omega 18:21, alpha 21:24
    px, py, pz, vx, vy, vz, ax, ay, az, r00, r01, r02, r10, r11, r12, r20, r21, r22, wx, wy, wz, bx, by, bz = e.tolist()
    ex, ey, ez = p_E_B.tolist()
    # r = R^r p_E^B, c = omega x r, cc = omega x (omega x r)
    rx = r00 * ex + r01 * ey + r02 * ez
    ry = r10 * ex + r11 * ey + r12 * ez
    rz = r20 * ex + r21 * ey + r22 * ez
    cx, cy, cz = wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx
    ccx, ccy, ccz = wy * cz - wz * cy, wz * cx - wx * cz, wx * cy - wy * cx
    d = out.data
    d[0:9] = (
        px - rx,
        py - ry,
        pz - rz,
        vx - cx,
        vy - cy,
        vz - cz,
        ax - (by * rz - bz * ry) - ccx,
        ay - (bz * rx - bx * rz) - ccy,
        az - (bx * ry - by * rx) - ccz,
    )
    d[9:24] = e[9:24]  # attitude and its rates are the EE's (R_E^B = I)
    return out


class AdmittanceFilter:
    """The admittance filter of SPEC §4.4 (see the module docstring for the equations).

    Args:
        params: virtual mass, damping and stiffness.

    Attributes:
        xi_p_W: (3,) position offset [m]. Read-only view; updated by :meth:`step`.
        xi_p_dot_W: (3,) its rate [m/s].
        xi_p_ddot_W: (3,) its acceleration [m/s²] at the last step.
        R_xi: (3, 3) rotation offset (world to world).
        omega_xi_W: (3,) angular rate of the offset [rad/s], world frame.
        omega_xi_dot_W: (3,) its derivative [rad/s²] at the last step.
    """

    def __init__(self, params: AdmittanceParams | None = None) -> None:
        self.params = params if params is not None else AdmittanceParams()
        p = self.params
        self._inv_m = tuple(1.0 / m for m in p.mass_pos)
        self._d = p.damping_pos
        self._k = p.stiffness_pos
        self._inv_j = tuple(1.0 / m for m in p.mass_rot)
        self._d_r = p.damping_rot
        self._k_r = p.stiffness_rot
        self._state = np.zeros(27)
        s = self._state
        self.xi_p_W = s[0:3]
        self.xi_p_dot_W = s[3:6]
        self.xi_p_ddot_W = s[6:9]
        self.omega_xi_W = s[9:12]
        self.omega_xi_dot_W = s[12:15]
        self.R_xi = s[15:24].reshape(3, 3)
        self._q = [1.0, 0.0, 0.0, 0.0]  # R_xi as a unit quaternion, wxyz
        self.reset()

    def reset(self) -> None:
        """Zero the offsets (compliant reference = desired reference)."""
        self._state[:] = 0.0
        self.R_xi[...] = np.eye(3)
        self._q = [1.0, 0.0, 0.0, 0.0]

    def rotation_offset_vector(self) -> np.ndarray:
        """(3,) ``1/2 (R_xi - R_xi^T)^v`` = sin(angle) * axis: the spring's generalized deflection."""
        w, x, y, z = self._q
        return np.array([2.0 * w * x, 2.0 * w * y, 2.0 * w * z])

    def step(self, f_E_W: np.ndarray, m_E_W: np.ndarray, dt: float) -> None:
        """Advance the filter by ``dt`` [s] under the EE wrench.

        Args:
            f_E_W: (3,) force at the EE [N], world frame.
            m_E_W: (3,) moment about the EE [N·m], world frame.
            dt: step [s].
        """
        s = self._state
        xp, yp, zp, xv, yv, zv, _, _, _, wx, wy, wz = s[0:12].tolist()
        fx, fy, fz = f_E_W.tolist()
        mx, my, mz = m_E_W.tolist()
        im, d, k = self._inv_m, self._d, self._k
        ax = im[0] * (fx - d[0] * xv - k[0] * xp)
        ay = im[1] * (fy - d[1] * yv - k[1] * yp)
        az = im[2] * (fz - d[2] * zv - k[2] * zp)
        half_dt2 = 0.5 * dt * dt
        # Rotational spring: 1/2 (R_xi - R_xi^T)^v = 2 q_w q_v for a unit quaternion.
        qw, qx, qy, qz = self._q
        ij, dr, kr = self._inv_j, self._d_r, self._k_r
        alx = ij[0] * (mx - dr[0] * wx - kr[0] * 2.0 * qw * qx)
        aly = ij[1] * (my - dr[1] * wy - kr[1] * 2.0 * qw * qy)
        alz = ij[2] * (mz - dr[2] * wz - kr[2] * 2.0 * qw * qz)
        wx += alx * dt
        wy += aly * dt
        wz += alz * dt
        s[0:15] = (
            xp + xv * dt + ax * half_dt2,
            yp + yv * dt + ay * half_dt2,
            zp + zv * dt + az * half_dt2,
            xv + ax * dt,
            yv + ay * dt,
            zv + az * dt,
            ax,
            ay,
            az,
            wx,
            wy,
            wz,
            alx,
            aly,
            alz,
        )
        # R_xi <- exp([omega dt]x) R_xi, i.e. q <- dq (x) q with dq the world-frame increment.
        angle = math.sqrt(wx * wx + wy * wy + wz * wz) * dt
        if angle > 0.0:
            c = math.cos(0.5 * angle)
            sn = math.sin(0.5 * angle) / angle * dt
            dw, dx, dy, dz = c, sn * wx, sn * wy, sn * wz
            qw, qx, qy, qz = (
                dw * qw - dx * qx - dy * qy - dz * qz,
                dw * qx + dx * qw + dy * qz - dz * qy,
                dw * qy - dx * qz + dy * qw + dz * qx,
                dw * qz + dx * qy - dy * qx + dz * qw,
            )
            norm = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
            qw, qx, qy, qz = qw * norm, qx * norm, qy * norm, qz * norm
            self._q = [qw, qx, qy, qz]
            s[15:24] = (
                1.0 - 2.0 * (qy * qy + qz * qz),
                2.0 * (qx * qy - qw * qz),
                2.0 * (qx * qz + qw * qy),
                2.0 * (qx * qy + qw * qz),
                1.0 - 2.0 * (qx * qx + qz * qz),
                2.0 * (qy * qz - qw * qx),
                2.0 * (qx * qz - qw * qy),
                2.0 * (qy * qz + qw * qx),
                1.0 - 2.0 * (qx * qx + qy * qy),
            )

    def compliant_reference(self, desired: ReferenceSample, out: ReferenceSample) -> ReferenceSample:
        """The compliant EE reference: the desired one displaced by the filter's offsets.

        Args:
            desired: desired EE reference (world-frame rates).
            out: the compliant reference to overwrite (may not be ``desired``).

        Returns:
            ``out``.
        """
        s = self._state
        d = out.data
        # p, v, a (layout of ReferenceSample.data): desired + offsets.
        np.add(desired.data[0:9], s[0:9], out=d[0:9])
        # R_r = R_xi R_d, omega_r = omega_xi + R_xi omega_d,
        # alpha_r = omega_xi' + R_xi alpha_d + omega_xi x (R_xi omega_d).
        np.dot(self.R_xi, desired.R_WB, out=out.R_WB)
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = self.R_xi.tolist()
        ox, oy, oz = desired.omega_W.tolist()
        bx, by, bz = desired.alpha_W.tolist()
        wx, wy, wz, vx, vy, vz = s[9:15].tolist()
        rox = r00 * ox + r01 * oy + r02 * oz
        roy = r10 * ox + r11 * oy + r12 * oz
        roz = r20 * ox + r21 * oy + r22 * oz
        d[18:24] = (
            wx + rox,
            wy + roy,
            wz + roz,
            vx + r00 * bx + r01 * by + r02 * bz + wy * roz - wz * roy,
            vy + r10 * bx + r11 * by + r12 * bz + wz * rox - wx * roz,
            vz + r20 * bx + r21 * by + r22 * bz + wx * roy - wy * rox,
        )
        return out
