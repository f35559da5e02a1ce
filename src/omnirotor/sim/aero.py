"""Truth aerodynamics of the simulator: the rotor-wake model (default), SPEC §7's interference, or ``A_nom u``.

**Rotor-wake model** (``model = "wake"``, the default; calibrated on the authors' flight data by
:mod:`omnirotor.experiments.calibration.truth`, see ``docs/fidelity.md``). Each rotor i has the input ``u_i`` [Hz²],
the speed ``n_i = |u_i|^(1/2)`` [rev/s] and the slipstream direction ``d_i = -sign(u_i) z_i`` (SPEC §7). For
an ordered pair (j blows, i receives) with ``e_ji`` the unit vector from rotor j to rotor i and ``L_ij`` their
distance, the pair's geometry and flow directions give

* the aim of j's wake at i, ``a_ij = d_j . e_ji`` (only ``a_ij > 0`` counts: the wake goes towards i);
* the side of i it reaches, ``c_ij = d_i . e_ji``: ``> +0.05`` it enters i's *intake* (i ingests j's wake,
  like a rotor in climb: less thrust), ``< -0.05`` it meets i's *outlet* (j's wake blows against i's own
  slipstream), otherwise it passes edge-on;

and the wake's axial speed at i scales like j's induced speed (momentum theory): ``sqrt(T_j / (2 rho A))``,
i.e. like ``s_j = n_j sqrt(factor_j)`` where ``factor_j`` is j's thrust over its isolated thrust at ``n_j``.
With the propeller law linear in the advance ratio (SPEC §7, item 4) the efficiency of rotor i is

    eta_i = clip(1 - sum_j G(a_ij, c_ij) |a_ij|^m max(|c_ij|, 0.05)^q (L0 / L_ij)^k s_j / n_i, eta_min, eta_max),

``G = ingest_gain`` (intake), ``counter_gain`` (outlet) or their mean (edge-on) when j's wake comes towards i;
``facing_gain`` / ``upstream_gain`` / their mean when i sits in j's intake field (``a_ij < 0``; 0 by default);
``m = aim_exponent`` (the wake's angular spread), ``q = side_exponent`` and ``k = distance_exponent`` (0 and 1 by
default), ``L0`` the shortest rotor distance (the cube side). ``factor_j`` in ``s_j`` is the first-order one
(every ``s = n``; the fixed point differs by less than 0.005 N of force RMS on the authors' data);
``wake_coupling = False`` takes ``s_j = n_j``, the previous model (docs/fidelity.md). A reversed rotor (``u_i < 0``)
makes ``(1 + reverse_gain)`` times the thrust of a forward one (bidirectional propellers are not quite
symmetric in reverse). The two propeller handednesses (drag-torque sign ``k_i = ±1``, SPEC §1.2: rotors 1, 3,
5, 7 against 2, 4, 6, 8) are mirror-image propellers whose thrust coefficients differ by ``± handedness_gain``.
The true wrench is ``A_built (kappa eta (1 + reverse_gain [u < 0]) * u)`` where ``A_built`` is the map of the
(optionally perturbed) rotors with gains ``1 + handedness_gain k_i``, the whole rotor geometry turned by
``Rz(frame_yaw_deg) Ry(frame_pitch_deg) Rx(frame_roll_deg)``: the rotation between the rotors' frame and the
measured (motion-capture) body frame, which the real data are expressed in (see ``docs/fidelity.md``). The
rotation turns positions and axes alike, so the pair geometry does not change. Every geometric term is
precomputed for the four sign combinations of (u_i, u_j), so a call is two compiled passes over an (n, n)
pattern (:func:`wake_wrench`, no allocation: the strengths go to scratch rows of the packed model).

**SPEC §7 model** (``model = "spec7"``, also accepted as ``"interference"``): rotor j with input ``u_j`` [Hz²]
has an isolated thrust ``T_j = kappa0 c_f |u_j|``, a disk induced speed ``v_j = sqrt(T_j / (2 rho pi R²))``
and a slipstream along ``d_j = -sign(u_j) z_j``. At a point ``x`` with ``r = x - p_j``, ``s = r . d_j`` and
``r_perp² = |r|² - s²`` the jet speed is (for s > 0, zero otherwise)

    U_j(x) = v_j (1 + s / sqrt(s² + R²)) (R/sqrt(2)) / b(s) exp(-r_perp² / b(s)²),  b(s) = R/sqrt(2) + beta s.

Disk i sees the axial inflow ``V_i = sum_{j != i} <U_j>_disk_i (d_j . d_i)`` (mean over the hub and 8
points at 0.7 R) and keeps the efficiency ``eta_i = clip(1 - gamma V_i / (J0 n_i D), eta_min, eta_max)``
with ``n_i = |u_i|^(1/2)`` [rev/s]. The true wrench is ``A (kappa0 eta * u)`` with ``A`` the map of the
(optionally perturbed) rotor geometry. Since ``s = -sign(u_j) (r . z_j)`` and ``r_perp`` does not depend on
the sign, the disk-averaged profile ``<U_j / v_j>_disk_i`` takes one of two precomputed values per pair
(i, j), chosen by the sign of ``u_j``; a call is one compiled pass over an (n, 2n) matrix
(:func:`interference_wrench`).

The compiled kernels of both models are here; the simulator's step calls them through
:func:`omnirotor.sim.step.aero_wrench`, which dispatches on ``kernel_kind``.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from omnirotor._jit import jit
from omnirotor.errors import InputError
from omnirotor.sim.params import AeroParams
from omnirotor.vehicle import VehicleParams, wrench_map

__all__ = [
    "WakeAero",
    "InterferenceAero",
    "NominalAero",
    "make_aero",
    "hover_equilibrium",
    "TruthAero",
    "AERO_NOMINAL",
    "AERO_INTERFERENCE",
    "AERO_WAKE",
    "pack_wake",
    "frame_rotation",
    "wake_efficiency",
    "wake_wrench",
    "pack_interference",
    "interference_efficiency",
    "interference_wrench",
]

AERO_NOMINAL, AERO_INTERFERENCE, AERO_WAKE = 0, 1, 2
"""Kinds of truth model :func:`omnirotor.sim.step.aero_wrench` evaluates: ``A_nom u``,
:func:`interference_wrench` or :func:`wake_wrench`."""

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
        self.kernel_kind = AERO_NOMINAL
        """How the simulator's compiled step evaluates this model (:func:`omnirotor.sim.step.aero_wrench`)."""
        self.kernel_model = np.ascontiguousarray(self.A_nom, dtype=np.float64)

    def wrench_B(self, u_hz2: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Body wrench ``A_nom u`` at the CoM, ``[f_B [N]; m_B [N·m]]`` (6,), for inputs ``u_hz2`` (n,) [Hz²]."""
        return np.matmul(self.A_nom, u_hz2, out=out)

    def efficiency(self, u_hz2: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(n,) rotor efficiencies: all ones."""
        if out is None:
            return np.ones(self.n_rotors)
        out[:] = 1.0
        return out


class _CompiledAero:
    """What the interaction models share: the body wrench and the efficiencies from their compiled kernels."""

    n_rotors: int
    kernel_model: np.ndarray

    def __init__(self, wrench_kernel, efficiency_kernel) -> None:
        self._wrench_kernel = wrench_kernel
        self._efficiency_kernel = efficiency_kernel

    def efficiency(self, u_hz2: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Per-rotor efficiencies: the thrust of each rotor over its isolated thrust (see the model's docs).

        Args:
            u_hz2: (n,) rotor inputs [Hz²].
            out: optional (n,) output buffer.

        Returns:
            (n,) the efficiencies (a fresh array unless ``out`` is given).
        """
        eta = np.empty(self.n_rotors) if out is None else out
        self._efficiency_kernel(np.asarray(u_hz2, dtype=np.float64), self.kernel_model, eta)
        return eta

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
        self._wrench_kernel(np.asarray(u_hz2, dtype=np.float64), self.kernel_model, out)
        return out


_SAID_EXTRAPOLATED: set[str] = set()


@functools.cache
def _calibration_geometry() -> tuple[np.ndarray, np.ndarray]:
    """Rotor positions and axes of the vehicle the rotor-wake parameters were calibrated on (the Omnirotor)."""
    from omnirotor.vehicle import load_vehicle

    v = load_vehicle("omnirotor")
    return v.positions_B, v.axes_B


def _say_if_extrapolated(vehicle: VehicleParams) -> None:
    """Say on stderr, once per vehicle and process, that the calibrated pair gains meet a geometry of their own."""
    positions, axes = _calibration_geometry()
    same = vehicle.positions_B.shape == positions.shape and (
        np.allclose(vehicle.positions_B, positions, rtol=0.0, atol=1e-6)
        and np.allclose(vehicle.axes_B, axes, rtol=0.0, atol=1e-6)
    )
    if same or vehicle.name in _SAID_EXTRAPOLATED:
        return
    _SAID_EXTRAPOLATED.add(vehicle.name)
    from omnirotor.safe_io import note

    note(
        f"truth aerodynamics: the rotor-wake model calibrated on the Omnirotor is extrapolated to vehicle "
        f"{vehicle.name!r}, whose rotor geometry differs (--truth nominal flies its own map)"
    )


class WakeAero(_CompiledAero):
    """The rotor-wake truth model (module docstring), optionally with per-rotor manufacturing errors.

    Args:
        vehicle: the vehicle (positions, axes, spins, c_f, c_tau).
        params: the model's parameters (``thrust_gain``, ``reverse_gain``, ``ingest_gain``, ``counter_gain``,
            ``aim_exponent``, ``handedness_gain``, the frame rotation, ``eta_min``, ``eta_max`` and the
            manufacturing errors).
    """

    def __init__(self, vehicle: VehicleParams, params: AeroParams | None = None) -> None:
        super().__init__(wake_wrench, wake_efficiency)
        p = params or AeroParams()
        n = vehicle.n_rotors
        _say_if_extrapolated(vehicle)
        self.params = p
        self.n_rotors = n
        axes, gains = _manufactured_axes_and_gains(vehicle.axes_B, p)
        gains = gains * (1.0 + p.handedness_gain * np.asarray(vehicle.spins, dtype=float))
        Q = frame_rotation(p.frame_roll_deg, p.frame_pitch_deg, p.frame_yaw_deg)
        self.positions_B = vehicle.positions_B @ Q.T
        """(n, 3) the rotor positions in the measured body frame (the rotors' frame turned by the frame rotation)."""
        self.axes_B = axes @ Q.T
        """(n, 3) the rotor axes: manufactured (tilt errors), then turned by the frame rotation."""
        self.gains = gains
        """(n,) the rotors' thrust gains: manufacturing errors times ``1 ± handedness_gain``."""
        self.A_nom = vehicle.A_nom.copy()
        self.A_true = wrench_map(self.positions_B, self.axes_B, vehicle.spins, vehicle.c_f, vehicle.c_tau)
        self.A_true *= gains[None, :]
        """(6, n) map of the rotors as built; the truth is ``A_true (kappa eta_rev eta * u)``."""
        self.pair_weights = wake_pair_weights(
            self.positions_B,
            self.axes_B,
            p.ingest_gain,
            p.counter_gain,
            p.aim_exponent,
            p.facing_gain,
            p.upstream_gain,
            p.side_exponent,
            p.distance_exponent,
        )
        """(4, n, n) ``G(c_ij) max(a_ij, 0)^m L0 / L_ij`` for the sign blocks (u_i < 0, u_j < 0) = (b // 2, b % 2)."""
        self._model = pack_wake(
            self.pair_weights, p.thrust_gain * self.A_true, p.reverse_gain, p.eta_min, p.eta_max, p.wake_coupling
        )
        self.kernel_kind = AERO_WAKE
        """How the simulator's compiled step evaluates this model (:func:`omnirotor.sim.step.aero_wrench`)."""
        self.kernel_model = self._model


class InterferenceAero(_CompiledAero):
    """SPEC §7 slipstream-interference truth model, optionally with per-rotor manufacturing errors.

    Args:
        vehicle: the vehicle (positions, axes, spins, c_f, c_tau, propeller diameter).
        params: the model's parameters.
    """

    def __init__(self, vehicle: VehicleParams, params: AeroParams | None = None) -> None:
        super().__init__(interference_wrench, interference_efficiency)
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

        prof_pos, prof_neg = _pair_profiles(positions, axes, radius, p.jet_spread)
        cos_ij = axes @ axes.T
        # V_i = sign_i sum_j [prof^{sign_j}_ij (z_i . z_j)] sign_j v_j, since d_j . d_i = sign_i sign_j z_i . z_j.
        # Stacked as K2 @ [min(sign v, 0); max(sign v, 0)]: negative inputs blow along +z_j, positive along -z_j.
        self._K2 = np.hstack([prof_pos * cos_ij, prof_neg * cos_ij])
        # v_j = sqrt(kappa0 g_j c_f |u_j| / (2 rho pi R²)) = v_coef_j * n_j
        self._v_coef = np.sqrt(p.kappa0 * gains * vehicle.c_f / (2.0 * p.rho * math.pi * radius * radius))
        self._neg_eta_gain = float(-p.gamma / (p.advance_ratio_ref * diameter))
        self._A_kappa = p.kappa0 * self.A_true
        self._eta_lo, self._eta_hi = float(p.eta_min), float(p.eta_max)
        self._model = pack_interference(
            self._K2, self._v_coef, self._A_kappa, self._neg_eta_gain, self._eta_lo, self._eta_hi, _N_FLOOR
        )
        self.kernel_kind = AERO_INTERFERENCE
        """How the simulator's compiled step evaluates this model (:func:`omnirotor.sim.step.aero_wrench`)."""
        self.kernel_model = self._model


TruthAero = WakeAero | InterferenceAero | NominalAero


def make_aero(vehicle: VehicleParams, params: AeroParams | None = None) -> TruthAero:
    """The truth model named by ``params.model`` for ``vehicle`` (default: the calibrated rotor-wake model)."""
    p = params or AeroParams()
    if p.model == "nominal":
        return NominalAero(vehicle)
    if p.model in ("spec7", "interference"):
        return InterferenceAero(vehicle, p)
    return WakeAero(vehicle, p)


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


_PROFILES_KEPT = 16
"""Rotor geometries whose jet profiles :func:`_pair_profiles` keeps per process."""
_profiles: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}


def _pair_profiles(
    positions: np.ndarray, axes: np.ndarray, radius: float, spread: float
) -> tuple[np.ndarray, np.ndarray]:
    """(n, n) disk-averaged jet profiles ``<U_j / v_j>_disk_i`` of every rotor pair, both jet directions.

    The first for ``s = +r.z_j`` (u_j < 0: jet along +z_j), the second for ``s = -r.z_j`` (u_j > 0: along -z_j);
    zero diagonals. They depend on the rotor geometry alone, which a campaign's runs share while their gains and
    interference strengths differ: computed once per geometry and process (read-only arrays).
    """
    key = (positions.shape, positions.tobytes(), axes.tobytes(), float(radius), float(spread))
    kept = _profiles.get(key)
    if kept is not None:
        return kept
    n = positions.shape[0]
    samples = _disk_samples(positions, axes, radius)  # (n, 9, 3)
    prof_pos = np.zeros((n, n))
    prof_neg = np.zeros((n, n))
    for j in range(n):
        r = samples - positions[j]  # (n, 9, 3)
        a = r @ axes[j]
        rperp2 = np.maximum(np.einsum("ikc,ikc->ik", r, r) - a * a, 0.0)
        prof_pos[:, j] = _jet_profile(a, rperp2, radius, spread).mean(axis=1)
        prof_neg[:, j] = _jet_profile(-a, rperp2, radius, spread).mean(axis=1)
    np.fill_diagonal(prof_pos, 0.0)
    np.fill_diagonal(prof_neg, 0.0)
    prof_pos.setflags(write=False)
    prof_neg.setflags(write=False)
    if len(_profiles) >= _PROFILES_KEPT:
        _profiles.pop(next(iter(_profiles)))
    _profiles[key] = prof_pos, prof_neg
    return prof_pos, prof_neg


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


def pack_interference(K2, v_coef, A_kappa, neg_eta_gain: float, eta_lo: float, eta_hi: float, n_floor: float):
    """The (n + 8, 2n) array the interference kernels read (one argument instead of seven).

    Rows ``0:n``: the inflow matrix ``K2`` (n, 2n); rows ``n:n+6``, columns ``0:n``: ``A_kappa`` (6, n);
    row ``n+6``, columns ``0:n``: ``v_coef``; row ``n+7``: ``neg_eta_gain, eta_lo, eta_hi, n_floor``.
    """
    n = v_coef.shape[0]
    model = np.zeros((n + 8, max(2 * n, 4)))
    model[0:n, 0 : 2 * n] = K2
    model[n : n + 6, 0:n] = A_kappa
    model[n + 6, 0:n] = v_coef
    model[n + 7, 0:4] = (neg_eta_gain, eta_lo, eta_hi, n_floor)
    return model


@jit
def interference_efficiency(u, model, eta) -> None:
    """Rotor efficiencies of SPEC §7 (:class:`omnirotor.sim.aero.InterferenceAero`), written into ``eta``.

    ``n_i = max(sqrt|u_i|, n_floor)``, ``b = [min(s v, 0); max(s v, 0)]`` with ``s_j v_j = u_j / n_j v_coef_j``,
    ``eta_i = clip(1 + neg_eta_gain (K2 b)_i (u_i / n_i) / n_i², eta_lo, eta_hi)`` (NaN propagates).

    Args:
        u: (n,) inputs [Hz²].
        model: the packed model of :func:`pack_interference`.
        eta: (n,) output.
    """
    n = u.shape[0]
    v_coef = model[n + 6]
    neg_eta_gain, eta_lo, eta_hi, n_floor = model[n + 7, 0], model[n + 7, 1], model[n + 7, 2], model[n + 7, 3]
    b = np.empty(2 * n)
    for j in range(n):
        nj = math.sqrt(abs(u[j]))
        if nj < n_floor:
            nj = n_floor
        t = (u[j] / nj) * v_coef[j]
        b[j] = t if (t < 0.0 or t != t) else 0.0
        b[n + j] = t if (t > 0.0 or t != t) else 0.0
    for i in range(n):
        acc = 0.0
        for j in range(2 * n):
            acc += model[i, j] * b[j]
        ni = math.sqrt(abs(u[i]))
        if ni < n_floor:
            ni = n_floor
        e = acc * ((u[i] / ni) / (ni * ni))
        e = e * neg_eta_gain
        e = e + 1.0
        if e > eta_hi:
            e = eta_hi
        if e < eta_lo:
            e = eta_lo
        eta[i] = e


@jit
def interference_wrench(u, model, out) -> None:
    """True body wrench ``A_kappa (eta * u)`` of SPEC §7 into ``out`` (6,) (model: :func:`pack_interference`)."""
    n = u.shape[0]
    eta = np.empty(n)
    interference_efficiency(u, model, eta)
    for r in range(6):
        acc = 0.0
        for j in range(n):
            acc += model[n + r, j] * (eta[j] * u[j])
        out[r] = acc


EDGE_ON_COS = 0.05
"""``|c_ij|`` below which a wake passes rotor i edge-on (within 3 deg of its disk plane) rather than entering
its intake or outlet [A; of 0.05 and 0.25, the one with the lower cross-validated error, docs/fidelity.md]."""


def frame_rotation(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """(3, 3) ``Rz(yaw) Ry(pitch) Rx(roll)``: the rotors' frame in the measured body frame (angles in degrees)."""
    r, p, y = math.radians(roll_deg), math.radians(pitch_deg), math.radians(yaw_deg)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ Ry @ Rx


def wake_pair_geometry(positions_B: np.ndarray, axes_B: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Aim, side and distance ratio of every ordered rotor pair, for the four sign blocks.

    Args:
        positions_B: (n, 3) rotor positions [m].
        axes_B: (n, 3) unit thrust axes.

    Returns:
        ``aim`` (4, n, n): ``a_ij = d_j . e_ji``; ``side`` (4, n, n): ``c_ij = d_i . e_ji``; ``closeness`` (n, n):
        ``L0 / L_ij`` (0 on the diagonal). Block ``b`` holds ``u_i < 0`` iff ``b // 2`` and ``u_j < 0`` iff
        ``b % 2``, with ``d = -sign(u) z``.
    """
    n = positions_B.shape[0]
    diff = positions_B[:, None, :] - positions_B[None, :, :]  # [i, j] = p_i - p_j
    dist = np.linalg.norm(diff, axis=2)
    off = ~np.eye(n, dtype=bool)
    e = np.zeros_like(diff)
    e[off] = diff[off] / dist[off][:, None]
    closeness = np.zeros((n, n))
    closeness[off] = dist[off].min() / dist[off]
    aim = np.empty((4, n, n))
    side = np.empty((4, n, n))
    for b in range(4):
        s_i = -1.0 if b // 2 else 1.0
        s_j = -1.0 if b % 2 else 1.0
        aim[b] = np.einsum("ijc,jc->ij", e, -s_j * axes_B)
        side[b] = np.einsum("ijc,ic->ij", e, -s_i * axes_B)
    return aim, side, closeness


def wake_pair_weights(
    positions_B: np.ndarray,
    axes_B: np.ndarray,
    ingest_gain: float,
    counter_gain: float,
    aim_exponent: float,
    facing_gain: float = 0.0,
    upstream_gain: float = 0.0,
    side_exponent: float = 0.0,
    distance_exponent: float = 1.0,
) -> np.ndarray:
    """(4, n, n) ``G(a_ij, c_ij) |a_ij|^m max(|c_ij|, band)^q (L0 / L_ij)^k`` of the rotor-wake model.

    ``G`` by the flow configuration (module docstring): ``a_ij > 0`` (j's wake comes towards i) with
    ``ingest_gain`` / ``counter_gain`` on i's intake / outlet side, ``a_ij < 0`` (i in j's intake field) with
    ``facing_gain`` / ``upstream_gain``; edge-on (``|c_ij| <= band``) the mean of the two; ``a_ij = 0`` nothing.
    """
    aim, side, closeness = wake_pair_geometry(positions_B, axes_B)
    toward = np.where(side > EDGE_ON_COS, ingest_gain, np.where(side < -EDGE_ON_COS, counter_gain, 0.0))
    toward = np.where(np.abs(side) <= EDGE_ON_COS, 0.5 * (ingest_gain + counter_gain), toward)
    away = np.where(side > EDGE_ON_COS, facing_gain, np.where(side < -EDGE_ON_COS, upstream_gain, 0.0))
    away = np.where(np.abs(side) <= EDGE_ON_COS, 0.5 * (facing_gain + upstream_gain), away)
    gain = np.where(aim > 0.0, toward, np.where(aim < 0.0, away, 0.0))
    reach = np.abs(aim) ** aim_exponent * (aim != 0.0)
    side_factor = np.maximum(np.abs(side), EDGE_ON_COS) ** side_exponent
    return gain * reach * side_factor * closeness[None] ** distance_exponent


def pack_wake(
    pair_weights: np.ndarray,
    A_kappa: np.ndarray,
    reverse_gain: float,
    eta_lo: float,
    eta_hi: float,
    wake_coupling: bool = True,
):
    """The (4n + 8, n + 5) array the wake kernels read (and write: two scratch parts, so one model per thread).

    Rows ``b n : (b+1) n``: the pair weights of sign block ``b`` (:func:`wake_pair_weights`); rows
    ``4n : 4n+6``: ``A_kappa`` (6, n); row ``4n+6``: ``reverse_gain, eta_lo, eta_hi, n_floor, wake_coupling``,
    then n scratch values (the first-order factors); row ``4n+7``: scratch (the slipstream strengths).
    """
    n = A_kappa.shape[1]
    model = np.zeros((4 * n + 8, n + 5))
    model[0 : 4 * n, 0:n] = pair_weights.reshape(4 * n, n)
    model[4 * n : 4 * n + 6, 0:n] = A_kappa
    model[4 * n + 6, 0:5] = (reverse_gain, eta_lo, eta_hi, _N_FLOOR, 1.0 if wake_coupling else 0.0)
    return model


@jit
def _wake_clip(ui: float, acc: float, model, n: int) -> float:
    """``clip(1 - acc / n_i, eta_lo, eta_hi) (1 + reverse_gain [u_i < 0])`` (NaN inputs give NaN)."""
    rev, eta_lo, eta_hi, n_floor = model[4 * n + 6, 0], model[4 * n + 6, 1], model[4 * n + 6, 2], model[4 * n + 6, 3]
    ni = math.sqrt(abs(ui))
    if ni < n_floor:
        ni = n_floor
    e = 1.0 - acc / ni
    if e > eta_hi:
        e = eta_hi
    if e < eta_lo:
        e = eta_lo
    if ui != ui:
        e = ui
    if ui < 0.0:
        e = e * (1.0 + rev)
    return e


@jit
def _wake_factor(u, model, strength, i: int) -> float:
    """Thrust factor ``eta_i (1 + reverse_gain [u_i < 0])`` of rotor i for slipstream strengths ``strength``."""
    n = u.shape[0]
    row = i + (2 * n if u[i] < 0.0 else 0)
    acc = 0.0
    for j in range(n):
        acc += model[row + (n if u[j] < 0.0 else 0), j] * strength[j]
    return _wake_clip(u[i], acc, model, n)


@jit
def _wake_strengths(u, model):
    """The slipstream strengths of the rotors into the model's scratch row ``4n+7``, which it returns.

    ``n_j``, then with the wake coupling on (``model[4n+6, 4] != 0``) ``n_j sqrt(factor_j)``, ``factor_j`` the
    thrust factor those first strengths give (first order). NaN propagates.
    """
    n = u.shape[0]
    strength = model[4 * n + 7]
    for j in range(n):
        strength[j] = math.sqrt(abs(u[j]))
    if model[4 * n + 6, 4] != 0.0:
        first = model[4 * n + 6]  # columns 5 .. 5+n: the first-order factors (scratch)
        for j in range(n):
            first[5 + j] = _wake_factor(u, model, strength, j)
        for j in range(n):
            strength[j] *= math.sqrt(first[5 + j])
    return strength


@jit
def wake_efficiency(u, model, eta) -> None:
    """Per-rotor thrust factors of the rotor-wake model into ``eta`` (n,) (model: :func:`pack_wake`)."""
    strength = _wake_strengths(u, model)
    for i in range(u.shape[0]):
        eta[i] = _wake_factor(u, model, strength, i)


@jit
def wake_wrench(u, model, out) -> None:
    """True body wrench ``A_kappa (factor * u)`` of the rotor-wake model into ``out`` (6,) (:func:`pack_wake`)."""
    n = u.shape[0]
    strength = _wake_strengths(u, model)
    for r in range(6):
        out[r] = 0.0
    for i in range(n):
        t = _wake_factor(u, model, strength, i) * u[i]
        for r in range(6):
            out[r] += model[4 * n + r, i] * t
