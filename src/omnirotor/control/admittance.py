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
from omnirotor.control import _kernels as _k
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
    f64 = np.float64
    _k.ee_wrench(
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
    _k.body_reference(ee.data, np.asarray(p_E_B, dtype=np.float64), out.data)
    return out


class AdmittanceFilter:
    """The admittance filter of SPEC §4.4 (see the module docstring for the equations).

    Args:
        params: virtual mass, damping and stiffness.
        buffer: optional (``ADM_SIZE``,) float64 array to hold :attr:`kernel_state`; a new one by default.

    Attributes:
        xi_p_W: (3,) position offset [m]. Read-only view; updated by :meth:`step`.
        xi_p_dot_W: (3,) its rate [m/s].
        xi_p_ddot_W: (3,) its acceleration [m/s²] at the last step.
        R_xi: (3, 3) rotation offset (world to world).
        omega_xi_W: (3,) angular rate of the offset [rad/s], world frame.
        omega_xi_dot_W: (3,) its derivative [rad/s²] at the last step.
        kernel_state: the packed state and parameters the compiled step reads and writes (layout ``ADM_*``
            of :mod:`omnirotor.control._kernels`; the arrays above are views into it).
    """

    def __init__(self, params: AdmittanceParams | None = None, *, buffer: np.ndarray | None = None) -> None:
        self.params = params if params is not None else AdmittanceParams()
        p = self.params
        # State and parameters in one array, the layout of control._kernels (ADM_*).
        self.kernel_state = s = _k.state_buffer(buffer, _k.ADM_SIZE, "admittance")
        s[_k.ADM_INV_M : _k.ADM_INV_M + 3] = [1.0 / m for m in p.mass_pos]
        s[_k.ADM_D : _k.ADM_D + 3] = p.damping_pos
        s[_k.ADM_K : _k.ADM_K + 3] = p.stiffness_pos
        s[_k.ADM_INV_J : _k.ADM_INV_J + 3] = [1.0 / m for m in p.mass_rot]
        s[_k.ADM_D_R : _k.ADM_D_R + 3] = p.damping_rot
        s[_k.ADM_K_R : _k.ADM_K_R + 3] = p.stiffness_rot
        self.xi_p_W = s[_k.ADM_XI_P : _k.ADM_XI_P + 3]
        self.xi_p_dot_W = s[_k.ADM_XI_P_DOT : _k.ADM_XI_P_DOT + 3]
        self.xi_p_ddot_W = s[_k.ADM_XI_P_DDOT : _k.ADM_XI_P_DDOT + 3]
        self.omega_xi_W = s[_k.ADM_OMEGA_XI : _k.ADM_OMEGA_XI + 3]
        self.omega_xi_dot_W = s[_k.ADM_OMEGA_XI_DOT : _k.ADM_OMEGA_XI_DOT + 3]
        self.R_xi = s[_k.ADM_R_XI : _k.ADM_R_XI + 9].reshape(3, 3)
        self._q = s[_k.ADM_Q : _k.ADM_Q + 4]  # R_xi as a unit quaternion, wxyz
        self.reset()

    def reset(self) -> None:
        """Zero the offsets (compliant reference = desired reference)."""
        self.kernel_state[0 : _k.ADM_INV_M] = 0.0
        self.R_xi[...] = np.eye(3)
        self._q[0] = 1.0

    def rotation_offset_vector(self) -> np.ndarray:
        """(3,) ``1/2 (R_xi - R_xi^T)^v`` = sin(angle) * axis: the spring's generalized deflection."""
        w, x, y, z = self._q.tolist()
        return np.array([2.0 * w * x, 2.0 * w * y, 2.0 * w * z])

    def step(self, f_E_W: np.ndarray, m_E_W: np.ndarray, dt: float) -> None:
        """Advance the filter by ``dt`` [s] under the EE wrench (:func:`omnirotor.control._kernels.admittance_step`).

        Args:
            f_E_W: (3,) force at the EE [N], world frame.
            m_E_W: (3,) moment about the EE [N·m], world frame.
            dt: step [s].
        """
        f64 = np.float64
        _k.admittance_step(self.kernel_state, np.asarray(f_E_W, dtype=f64), np.asarray(m_E_W, dtype=f64), float(dt))

    def compliant_reference(self, desired: ReferenceSample, out: ReferenceSample) -> ReferenceSample:
        """The compliant EE reference: the desired one displaced by the filter's offsets.

        Args:
            desired: desired EE reference (world-frame rates).
            out: the compliant reference to overwrite (may not be ``desired``).

        Returns:
            ``out``.
        """
        _k.compliant_reference(self.kernel_state, desired.data, out.data)
        return out
