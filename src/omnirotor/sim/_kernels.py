"""Compiled kernels of the truth aerodynamics (see :mod:`omnirotor._jit` for how they are compiled).

:func:`interference_efficiency`, :func:`interference_wrench`: the slipstream-interference truth of
:mod:`omnirotor.sim.aero` (SPEC §7), on its precomputed (n, 2n) inflow matrix packed by
:func:`pack_interference`. The simulator's step reaches them through :func:`omnirotor.sim.step.aero_wrench`.
The other blocks of the simulator own their kernels (:mod:`omnirotor.sim.rotors`, :mod:`omnirotor.sim.sensors`,
:mod:`omnirotor.sim.contact`, the composer :mod:`omnirotor.sim.step`).
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor._jit import jit

__all__ = ["pack_interference", "interference_efficiency", "interference_wrench", "AERO_NOMINAL", "AERO_INTERFERENCE"]


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


AERO_NOMINAL, AERO_INTERFERENCE = 0, 1
"""Kinds of truth model (:func:`omnirotor.sim.step.aero_wrench`): ``A_nom u``, or :func:`interference_wrench`."""
