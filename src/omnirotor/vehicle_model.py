"""Vehicle model of a fixed-tilt multirotor and its nominal wrench map (SPEC §1, §2).

A vehicle is a rigid body with ``n`` rotors, each with a position ``p_B`` [m], a thrust axis ``z_B``
(unit), a spin direction ``k`` (+1 / -1) and shared coefficients ``c_f`` [N/Hz²] and ``c_tau`` [N·m/Hz²].
The input of rotor i is ``u_i = |omega_i| omega_i`` in Hz² with ``omega_i`` in Hz (rev/s), SPEC §1.1.
Rotor i produces, at the CoM in the body frame,

    f_i = c_f u_i z_i,     m_i = p_i x f_i + k_i c_tau u_i z_i,

so the body wrench is ``w_B = A u`` with ``A`` (6 x n), rows ``fx fy fz mx my mz`` (SPEC §1.2).

Vehicles are read from files by :mod:`omnirotor.vehicle` (which re-exports the names of this module); this
module imports nothing that reads files, so the PX4 readers can build vehicles without importing the loaders.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from omnirotor.config import check_finite, check_positive
from omnirotor.errors import InputError
from omnirotor.so3 import rot_x, rot_y

__all__ = [
    "RotorParams",
    "VehicleParams",
    "wrench_map",
    "ForceEnvelope",
    "force_envelope",
    "zero_moment_force_basis",
    "max_zero_torque_force",
    "fibonacci_sphere",
]


@dataclasses.dataclass(frozen=True)
class RotorParams:
    """One rotor of a vehicle file.

    Attributes:
        position: (3,) rotor centre in the body frame [m].
        spin: +1 or -1, the sign k_i of the drag moment ``k_i c_tau u_i z_i``.
        axis: (3,) thrust axis in the body frame (normalised on load), or empty to use the tilt.
        tilt_about: "x" or "y": the body axis of the elementary tilt applied to e3 when ``axis`` is empty.
        tilt_deg: the tilt angle [deg] (SPEC §1.2: ``s_i * alpha``).
    """

    position: tuple[float, float, float]
    spin: int
    axis: tuple[float, ...] = ()
    tilt_about: str = ""
    tilt_deg: float = 0.0

    def __post_init__(self) -> None:
        check_finite("rotor position", *self.position)
        if self.spin not in (-1, 1):
            raise InputError(f"rotor spin must be +1 or -1, got {self.spin}")
        if self.axis:
            if len(self.axis) != 3:
                raise InputError(f"rotor axis must have 3 components, got {len(self.axis)}")
            check_finite("rotor axis", *self.axis)
            if math.hypot(*self.axis) < 1e-9:
                raise InputError("rotor axis must be non-zero")
        elif self.tilt_about not in ("x", "y"):
            raise InputError('a rotor needs either axis = [x, y, z] or tilt_about = "x"|"y" with tilt_deg')
        check_finite("rotor tilt_deg", self.tilt_deg)

    def axis_B(self) -> np.ndarray:
        """Unit thrust axis ``z_B`` of the rotor."""
        if self.axis:
            a = np.asarray(self.axis, dtype=float)
            return a / np.linalg.norm(a)
        rot = rot_x if self.tilt_about == "x" else rot_y
        return rot(math.radians(self.tilt_deg))[:, 2].copy()


@dataclasses.dataclass(frozen=True)
class VehicleParams:
    """A fixed-tilt multirotor (SPEC §1).

    Attributes:
        name: preset or file name.
        mass: [kg].
        inertia_diag: principal moments of inertia at the CoM [kg·m²], body axes.
        gravity: [m/s²].
        c_f: thrust coefficient [N/Hz²].
        c_tau: drag-moment coefficient [N·m/Hz²].
        omega_max_hz: largest rotor speed [Hz].
        omega_min_hz: smallest rotor speed [Hz]; negative for bidirectional rotors.
        propeller_diameter: [m].
        actuated_dof: declared rank of the wrench map (6 fully actuated, 4 for a coplanar quadrotor).
        p_E_B: end-effector tip position in the body frame [m] (SPEC §1.5).
        frame_size: body box edge for rendering and collisions [m].
        rotors: the rotors.
    """

    name: str
    mass: float
    inertia_diag: tuple[float, float, float]
    c_f: float
    c_tau: float
    omega_max_hz: float
    omega_min_hz: float
    rotors: tuple[RotorParams, ...]
    gravity: float = 9.81
    propeller_diameter: float = 0.2032
    actuated_dof: int = 6
    p_E_B: tuple[float, float, float] = (0.0, 0.0, 0.0)
    frame_size: float = 0.25

    def __post_init__(self) -> None:
        where = f"vehicle {self.name!r}"
        for label, v in (
            ("mass", self.mass),
            ("c_f", self.c_f),
            ("gravity", self.gravity),
            ("propeller_diameter", self.propeller_diameter),
            ("frame_size", self.frame_size),
            ("omega_max_hz", self.omega_max_hz),
        ):
            check_positive(f"{where}: {label}", v)
        check_finite(f"{where}: c_tau", self.c_tau)
        if self.c_tau < 0:
            raise InputError(f"{where}: c_tau must be >= 0, got {self.c_tau}")
        for j in self.inertia_diag:
            check_positive(f"{where}: inertia_diag", j)
        a, b, c = self.inertia_diag
        # Measured inertias of flat vehicles sit on the bound J_z = J_x + J_y (RotorPy's Crazyflie is 1%
        # past it), so allow 2% before calling the body non-physical.
        slack = 1.02
        if slack * (a + b) < c or slack * (a + c) < b or slack * (b + c) < a:
            raise InputError(f"{where}: inertia_diag {self.inertia_diag} violates the triangle inequality")
        check_finite(f"{where}: omega_min_hz", self.omega_min_hz)
        if self.omega_min_hz >= self.omega_max_hz:
            raise InputError(f"{where}: omega_min_hz must be < omega_max_hz")
        check_finite(f"{where}: p_E_B", *self.p_E_B)
        if len(self.rotors) < 4:
            raise InputError(f"{where}: needs at least 4 rotors, got {len(self.rotors)}")
        if self.actuated_dof not in (4, 5, 6):
            raise InputError(f"{where}: actuated_dof must be 4, 5 or 6, got {self.actuated_dof}")
        # Every wrench the rotors can produce must be a finite number (c_f = 1e308 or limits of 1e200 Hz are not).
        with np.errstate(over="ignore", invalid="ignore"):
            reach = np.abs(self.A_nom) * max(abs(self.u_min), self.u_max)
            weight = self.mass * self.gravity
        if not (np.all(np.isfinite(reach)) and math.isfinite(self.u_min) and math.isfinite(weight)):
            raise InputError(f"{where}: c_f, c_tau, rotor limits or positions too large: the wrenches overflow")
        rank = int(np.linalg.matrix_rank(self.A_nom, tol=1e-9 * np.abs(self.A_nom).max()))
        if rank < self.actuated_dof:
            raise InputError(
                f"{where}: wrench map has rank {rank} but the file declares actuated_dof = {self.actuated_dof}"
            )

    @property
    def n_rotors(self) -> int:
        """Number of rotors."""
        return len(self.rotors)

    @functools.cached_property
    def positions_B(self) -> np.ndarray:
        """(n, 3) rotor positions in the body frame [m]."""
        return np.array([r.position for r in self.rotors], dtype=float)

    @functools.cached_property
    def axes_B(self) -> np.ndarray:
        """(n, 3) unit thrust axes in the body frame."""
        return np.array([r.axis_B() for r in self.rotors])

    @functools.cached_property
    def spins(self) -> np.ndarray:
        """(n,) spin signs k_i."""
        return np.array([r.spin for r in self.rotors], dtype=float)

    @functools.cached_property
    def inertia(self) -> np.ndarray:
        """(3, 3) inertia matrix J at the CoM [kg·m²]."""
        return np.diag(self.inertia_diag).astype(float)

    @functools.cached_property
    def A_nom(self) -> np.ndarray:
        """(6, n) nominal wrench map, body frame: ``w_B = A_nom @ u`` with u in Hz² (SPEC §1.2)."""
        return wrench_map(self.positions_B, self.axes_B, self.spins, self.c_f, self.c_tau)

    @property
    def u_min(self) -> float:
        """Lower input bound [Hz²]: ``omega_min |omega_min|``."""
        return self.omega_min_hz * abs(self.omega_min_hz)

    @property
    def u_max(self) -> float:
        """Upper input bound [Hz²]: ``omega_max²``."""
        return self.omega_max_hz * self.omega_max_hz

    @property
    def weight(self) -> float:
        """M g [N]."""
        return self.mass * self.gravity

    @property
    def p_E_B_array(self) -> np.ndarray:
        """(3,) end-effector tip position in the body frame [m]."""
        return np.asarray(self.p_E_B, dtype=float)

    def hover_input(self, R_WB: np.ndarray | None = None) -> np.ndarray:
        """Least-norm input u [Hz²] that holds the weight at attitude ``R_WB`` with zero moment (not clipped)."""
        R = np.eye(3) if R_WB is None else R_WB
        w = np.zeros(6)
        w[:3] = R.T @ np.array([0.0, 0.0, self.weight])
        return np.linalg.pinv(self.A_nom) @ w

    def to_dict(self) -> dict:
        """Plain-data form for JSON reports."""
        return dataclasses.asdict(self)


def wrench_map(positions_B: np.ndarray, axes_B: np.ndarray, spins: np.ndarray, c_f: float, c_tau: float) -> np.ndarray:
    """(6, n) map from rotor inputs u [Hz²] to the body wrench at the CoM (SPEC §1.2)."""
    f = c_f * axes_B
    m = np.cross(positions_B, f) + (spins * c_tau)[:, None] * axes_B
    return np.vstack([f.T, m.T])


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) nearly uniform unit vectors on the sphere."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = math.pi * (3.0 - math.sqrt(5.0)) * i
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


@dataclasses.dataclass(frozen=True)
class ForceEnvelope:
    """The largest force at zero moment along each sampled body direction (SPEC §1.3).

    Attributes:
        directions_B: (k, 3) unit directions.
        force_N: (k,) largest force magnitude along each direction [N].
    """

    directions_B: np.ndarray
    force_N: np.ndarray

    @property
    def min_N(self) -> float:
        """Smallest over directions of the largest zero-moment force [N]."""
        return float(self.force_N.min())

    @property
    def max_N(self) -> float:
        """Largest zero-moment force over directions [N]."""
        return float(self.force_N.max())


def _max_force_along(A: np.ndarray, d: np.ndarray, lo: float, hi: float) -> float:
    from scipy.optimize import linprog  # here: importing scipy.optimize costs every process 0.15-0.3 s

    n = A.shape[1]
    # Variables: x = u / hi (scaled to [lo/hi, 1]) and t [N]. Maximise t s.t. A u = [t d; 0].
    c = np.zeros(n + 1)
    c[-1] = -1.0
    A_eq = np.zeros((6, n + 1))
    A_eq[:, :n] = A * hi
    A_eq[:3, -1] = -d
    bounds = [(lo / hi, 1.0)] * n + [(0.0, None)]
    res = linprog(c, A_eq=A_eq, b_eq=np.zeros(6), bounds=bounds, method="highs")
    return max(0.0, float(res.x[-1])) if res.status == 0 else 0.0


def max_zero_torque_force(vehicle: VehicleParams, d_B: np.ndarray) -> float:
    """Largest force [N] the vehicle can produce along body direction ``d_B`` with zero moment (LP)."""
    d = np.asarray(d_B, dtype=float)
    return _max_force_along(vehicle.A_nom, d / np.linalg.norm(d), vehicle.u_min, vehicle.u_max)


def zero_moment_force_basis(A: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """(3, k) orthonormal basis of the forces a map ``A`` (6, n) makes with zero moment, rotor bounds aside.

    ``k = 3`` for a fully actuated vehicle; a quadrotor's is its thrust axis (``k = 1``).
    """
    _, s2, Vt2 = np.linalg.svd(A[3:])
    null = Vt2[int(np.sum(s2 > rtol * max(s2[0], 1e-300))) :].T  # inputs that make no moment
    if null.shape[1] == 0:
        return np.zeros((3, 0))
    U, s1, _ = np.linalg.svd(A[:3] @ null, full_matrices=False)
    return U[:, : int(np.sum(s1 > rtol * max(s1[0], 1e-300)))] if s1.size else np.zeros((3, 0))


def force_envelope(vehicle: VehicleParams, n_directions: int = 400, refine: bool = True) -> ForceEnvelope:
    """Largest zero-moment force along directions of the body frame, by linear programming.

    Args:
        vehicle: the vehicle.
        n_directions: number of Fibonacci-sphere directions sampled.
        refine: polish the minimum and maximum with a local search on the sphere.

    Returns:
        The sampled envelope; with ``refine``, the polished extremes are appended to it.
    """
    A, lo, hi = vehicle.A_nom, vehicle.u_min, vehicle.u_max
    D = fibonacci_sphere(n_directions)
    basis = zero_moment_force_basis(A)
    if basis.shape[1] == 1:  # e.g. a quadrotor: only along its thrust axis; the sphere's samples miss it
        D = np.vstack([D, basis.T, -basis.T])
    elif basis.shape[1] == 2:  # a plane of directions: sample its circle too
        phi = np.linspace(0.0, 2.0 * math.pi, 72, endpoint=False)
        D = np.vstack([D, (basis @ np.vstack([np.cos(phi), np.sin(phi)])).T])
    F = np.array([_max_force_along(A, d, lo, hi) for d in D])
    if refine:
        extra_d, extra_f = [], []
        for sign, idx in ((1.0, int(np.argmin(F))), (-1.0, int(np.argmax(F)))):
            d, f, step = D[idx].copy(), F[idx], 0.1
            while step > 1e-4:
                improved = False
                t1 = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
                t1 /= np.linalg.norm(t1)
                t2 = np.cross(d, t1)
                for t in (t1, -t1, t2, -t2):
                    cand = d + step * t
                    cand /= np.linalg.norm(cand)
                    fc = _max_force_along(A, cand, lo, hi)
                    if sign * (f - fc) > 0:
                        d, f, improved = cand, fc, True
                        break
                if not improved:
                    step *= 0.5
            extra_d.append(d)
            extra_f.append(f)
        D = np.vstack([D, extra_d])
        F = np.concatenate([F, extra_f])
    return ForceEnvelope(directions_B=D, force_N=F)
