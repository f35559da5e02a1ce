"""Truth aerodynamics of the simulator: the slipstream-interference model of SPEC §7, or ``A_nom u``.

The model (SPEC §7 [A], calibrated on the authors' flight data): rotor j with input ``u_j`` [Hz²] has an
isolated thrust ``T_j = kappa0 c_f |u_j|``, a disk induced speed ``v_j = sqrt(T_j / (2 rho pi R²))`` and
a slipstream along ``d_j = -sign(u_j) z_j``. At a point ``x`` with ``r = x - p_j``, ``s = r . d_j`` and
``r_perp² = |r|² - s²`` the jet speed is (for s > 0, zero otherwise)

    U_j(x) = v_j (1 + s / sqrt(s² + R²)) (R/sqrt(2)) / b(s) exp(-r_perp² / b(s)²),  b(s) = R/sqrt(2) + beta s.

Disk i sees the axial inflow ``V_i = sum_{j != i} <U_j>_disk_i (d_j . d_i)`` (mean over the hub and 8
points at 0.7 R) and keeps the efficiency ``eta_i = clip(1 - gamma V_i / (J0 n_i D), eta_min, eta_max)``
with ``n_i = |u_i|^(1/2)`` [rev/s]. The true wrench is ``A (kappa0 eta * u)`` with ``A`` the map of the
(optionally perturbed) rotor geometry.

Everything geometric is precomputed: since ``s = -sign(u_j) (r . z_j)`` and ``r_perp`` does not depend on
the sign, the disk-averaged profile ``<U_j / v_j>_disk_i`` takes one of two precomputed values per pair
(i, j), chosen by the sign of ``u_j``. A call is then one compiled pass over an (n, 2n) matrix
(:func:`omnirotor.sim._kernels.interference_wrench`).
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor.errors import InputError
from omnirotor.sim import _kernels as _k
from omnirotor.sim.params import AeroParams
from omnirotor.vehicle import VehicleParams, wrench_map

__all__ = ["InterferenceAero", "NominalAero", "make_aero", "hover_equilibrium", "TruthAero"]

_DISK_RING_FRACTION = 0.7
"""Radius of the ring of disk samples, as a fraction of the propeller radius (SPEC §7)."""
_DISK_RING_POINTS = 8
"""Samples on that ring; with the hub, 9 samples per disk (SPEC §7)."""
_N_FLOOR = 1e-6
"""Smallest rotor speed [rev/s] in the advance ratio (a stopped rotor makes no force anyway)."""


class NominalAero:
    """Truth model equal to the nominal wrench map: ``w_B = A_nom u`` exactly.

    Args:
        vehicle: the vehicle.
    """

    def __init__(self, vehicle: VehicleParams) -> None:
        self.n_rotors = vehicle.n_rotors
        self.A_nom = vehicle.A_nom.copy()
        self.A_true = self.A_nom
        self.kernel_kind = _k.AERO_NOMINAL
        """How the simulator's compiled step evaluates this model (:func:`omnirotor.sim._kernels.actuate`)."""
        self.kernel_model = np.ascontiguousarray(self.A_nom, dtype=np.float64)

    def wrench_B(self, u_hz2: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Body wrench at the CoM.

        Args:
            u_hz2: (n,) rotor inputs [Hz²].
            out: optional (6,) output buffer.

        Returns:
            (6,) ``[f_B [N]; m_B [N·m]]``.
        """
        return np.matmul(self.A_nom, u_hz2, out=out)

    def efficiency(self, u_hz2: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(n,) rotor efficiencies: all ones."""
        if out is None:
            return np.ones(self.n_rotors)
        out[:] = 1.0
        return out


class InterferenceAero:
    """SPEC §7 slipstream-interference truth model, optionally with per-rotor manufacturing errors.

    Args:
        vehicle: the vehicle (positions, axes, spins, c_f, c_tau, propeller diameter).
        params: the model's parameters.
    """

    def __init__(self, vehicle: VehicleParams, params: AeroParams | None = None) -> None:
        p = params or AeroParams()
        n = vehicle.n_rotors
        self.params = p
        self.n_rotors = n
        radius = p.rotor_radius if p.rotor_radius > 0 else 0.5 * vehicle.propeller_diameter
        diameter = 2.0 * radius
        positions = vehicle.positions_B.copy()
        axes, gains = _manufactured_axes_and_gains(vehicle.axes_B, p)
        self.positions_B = positions
        self.axes_B = axes
        """(n, 3) the manufactured thrust axes (the nominal ones without tilt errors)."""
        self.gains = gains
        """(n,) the manufactured thrust gains (ones without gain errors)."""
        self.A_nom = vehicle.A_nom.copy()
        self.A_true = wrench_map(positions, axes, vehicle.spins, vehicle.c_f, vehicle.c_tau) * gains[None, :]
        """(6, n) map of the manufactured rotors; the truth is ``A_true (kappa0 eta * u)``."""

        samples = _disk_samples(positions, axes, radius)  # (n, 9, 3)
        prof_pos = np.zeros((n, n))  # <U_j / v_j>_disk_i when s = +r.z_j (u_j < 0: jet along +z_j)
        prof_neg = np.zeros((n, n))  # when s = -r.z_j (u_j > 0: jet along -z_j)
        for j in range(n):
            r = samples - positions[j]  # (n, 9, 3)
            a = r @ axes[j]
            rperp2 = np.maximum(np.einsum("ikc,ikc->ik", r, r) - a * a, 0.0)
            prof_pos[:, j] = _jet_profile(a, rperp2, radius, p.jet_spread).mean(axis=1)
            prof_neg[:, j] = _jet_profile(-a, rperp2, radius, p.jet_spread).mean(axis=1)
        np.fill_diagonal(prof_pos, 0.0)
        np.fill_diagonal(prof_neg, 0.0)
        cos_ij = axes @ axes.T
        # V_i = sign_i sum_j [prof^{sign_j}_ij (z_i . z_j)] sign_j v_j, since d_j . d_i = sign_i sign_j z_i . z_j.
        # Stacked as K2 @ [min(sign v, 0); max(sign v, 0)]: negative inputs blow along +z_j, positive along -z_j.
        self._K2 = np.hstack([prof_pos * cos_ij, prof_neg * cos_ij])
        # v_j = sqrt(kappa0 g_j c_f |u_j| / (2 rho pi R²)) = v_coef_j * n_j
        self._v_coef = np.sqrt(p.kappa0 * gains * vehicle.c_f / (2.0 * p.rho * math.pi * radius * radius))
        self._neg_eta_gain = float(-p.gamma / (p.advance_ratio_ref * diameter))
        self._A_kappa = p.kappa0 * self.A_true
        self._eta_lo, self._eta_hi = float(p.eta_min), float(p.eta_max)
        self._model = _k.pack_interference(
            self._K2, self._v_coef, self._A_kappa, self._neg_eta_gain, self._eta_lo, self._eta_hi, _N_FLOOR
        )
        self.kernel_kind = _k.AERO_INTERFERENCE
        """How the simulator's compiled step evaluates this model (:func:`omnirotor.sim._kernels.actuate`)."""
        self.kernel_model = self._model

    def efficiency(self, u_hz2: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Per-rotor efficiencies eta_i of SPEC §7.

        Args:
            u_hz2: (n,) rotor inputs [Hz²].
            out: optional (n,) output buffer.

        Returns:
            (n,) eta (a fresh array unless ``out`` is given).
        """
        eta = np.empty(self.n_rotors)
        _k.interference_efficiency(np.asarray(u_hz2, dtype=np.float64), self._model, eta)
        if out is None:
            return eta
        out[:] = eta
        return out

    def wrench_B(self, u_hz2: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """True body wrench at the CoM.

        Args:
            u_hz2: (n,) rotor inputs [Hz²].
            out: optional (6,) output buffer.

        Returns:
            (6,) ``[f_B [N]; m_B [N·m]]``.
        """
        if out is None:
            out = np.empty(6)
        _k.interference_wrench(np.asarray(u_hz2, dtype=np.float64), self._model, out)
        return out


TruthAero = InterferenceAero | NominalAero


def make_aero(vehicle: VehicleParams, params: AeroParams | None = None) -> TruthAero:
    """The truth model named by ``params.model`` for ``vehicle``."""
    p = params or AeroParams()
    if p.model == "nominal":
        return NominalAero(vehicle)
    return InterferenceAero(vehicle, p)


def hover_equilibrium(
    aero: TruthAero,
    vehicle: VehicleParams,
    R_WB: np.ndarray,
    A_map: np.ndarray | None = None,
    tol: float = 1e-9,
    max_iter: int = 50,
) -> np.ndarray:
    """Rotor inputs of a controller that allocates with ``pinv(A_map)`` and hovers under the truth model.

    Solves ``aero.wrench_B(pinv(A_map) c) = [R_WB^T m g e3; 0]`` for the commanded wrench ``c`` by Newton's
    method with a finite-difference Jacobian (least squares for maps of rank < 6). This is the steady state
    of any controller with integral action whose allocation is the pseudo-inverse of ``A_map``.

    Args:
        aero: the truth model.
        vehicle: the vehicle.
        R_WB: (3, 3) attitude.
        A_map: (6, n) the controller's map; default the nominal one.
        tol: stop when the wrench residual is below this [N, N·m].
        max_iter: Newton iterations.

    Returns:
        (n,) the equilibrium inputs u [Hz²] (not clipped to the rotor limits).

    Raises:
        InputError: when the iteration does not converge (e.g. an attitude the vehicle cannot hold).
    """
    A = vehicle.A_nom if A_map is None else np.asarray(A_map, dtype=float)
    pinv = np.linalg.pinv(A)
    w = np.zeros(6)
    w[:3] = np.asarray(R_WB, dtype=float).T @ np.array([0.0, 0.0, vehicle.weight])
    c = w.copy()
    h = 1e-6 * max(vehicle.weight, 1.0)
    for _ in range(max_iter):
        r = aero.wrench_B(pinv @ c) - w
        if np.max(np.abs(r)) < tol:
            return pinv @ c
        J = np.empty((6, 6))
        for k in range(6):
            ck = c.copy()
            ck[k] += h
            J[:, k] = (aero.wrench_B(pinv @ ck) - w - r) / h
        c = c - np.linalg.lstsq(J, r, rcond=1e-10)[0]
    r = aero.wrench_B(pinv @ c) - w
    if np.max(np.abs(r)) < max(tol, 1e-6):
        return pinv @ c
    raise InputError(f"hover equilibrium did not converge (residual {np.max(np.abs(r)):.3g})")


def _jet_profile(s: np.ndarray, rperp2: np.ndarray, radius: float, beta: float) -> np.ndarray:
    """``U / v`` of SPEC §7 at axial distance s [m] and squared radial distance rperp2 [m²]."""
    r0 = radius / math.sqrt(2.0)
    downstream = s > 0.0
    s_pos = np.where(downstream, s, 0.0)
    b = r0 + beta * s_pos
    value = (1.0 + s_pos / np.sqrt(s_pos * s_pos + radius * radius)) * (r0 / b) * np.exp(-rperp2 / (b * b))
    return np.where(downstream, value, 0.0)


def _disk_samples(positions: np.ndarray, axes: np.ndarray, radius: float) -> np.ndarray:
    """(n, 9, 3) the hub and 8 points at 0.7 R on each rotor disk [m]."""
    n = positions.shape[0]
    out = np.empty((n, 1 + _DISK_RING_POINTS, 3))
    angles = 2.0 * math.pi * np.arange(_DISK_RING_POINTS) / _DISK_RING_POINTS
    for i in range(n):
        e1, e2 = _plane_basis(axes[i])
        out[i, 0] = positions[i]
        ring = np.cos(angles)[:, None] * e1 + np.sin(angles)[:, None] * e2
        out[i, 1:] = positions[i] + _DISK_RING_FRACTION * radius * ring
    return out


def _plane_basis(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane normal to the unit vector z."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(z, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(z, e1)


def _manufactured_axes_and_gains(axes_B: np.ndarray, p: AeroParams) -> tuple[np.ndarray, np.ndarray]:
    """Per-rotor axes tilted and gains scaled by errors drawn from ``p.error_seed`` (none if the stds are 0)."""
    n = axes_B.shape[0]
    rng = np.random.default_rng(p.error_seed)
    gain_draw = rng.standard_normal(n)
    tilt_draw = rng.standard_normal(n)
    azimuth_draw = rng.uniform(0.0, 2.0 * math.pi, n)
    gains = 1.0 + p.gain_error_std * gain_draw
    if np.any(gains <= 0.0):
        raise InputError("aero.gain_error_std is so large that a rotor gain became <= 0")
    axes = axes_B.copy()
    if p.tilt_error_std_deg > 0.0:
        for i in range(n):
            e1, e2 = _plane_basis(axes_B[i])
            tilt = math.radians(p.tilt_error_std_deg) * tilt_draw[i]
            lateral = math.cos(azimuth_draw[i]) * e1 + math.sin(azimuth_draw[i]) * e2
            axes[i] = math.cos(tilt) * axes_B[i] + math.sin(tilt) * lateral
    return axes, gains
