"""Rotor speed dynamics: a first-order lag on omega [Hz] with saturation and an optional dead band (SPEC §1.4).

Each control period the commanded speed is clipped to ``[omega_min_hz, omega_max_hz]``, set to zero inside
the dead band when it is enabled, and the speed follows it exactly as a first-order system held over the
period: ``omega += (1 - exp(-dt / tau_m)) (omega_cmd - omega)``.
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor.sim import _kernels as _k
from omnirotor.sim.params import RotorDynamicsParams
from omnirotor.vehicle import VehicleParams

__all__ = ["RotorBank"]


class RotorBank:
    """The rotors' speed states.

    Args:
        vehicle: gives the number of rotors and the speed limits.
        params: the speed-loop parameters.
        dt: the period of :meth:`step` [s].
    """

    def __init__(self, vehicle: VehicleParams, params: RotorDynamicsParams, dt: float) -> None:
        self.params = params
        self.omega_min_hz = float(vehicle.omega_min_hz)
        self.omega_max_hz = float(vehicle.omega_max_hz)
        self.alpha = 1.0 - math.exp(-dt / params.tau_m)
        self.dead_band_hz = float(params.dead_band_hz) if params.dead_band else 0.0
        n = vehicle.n_rotors
        self.n_rotors = n
        self.omega_hz = np.zeros(n)
        """(n,) current signed speeds [Hz]."""
        self.u_hz2 = np.zeros(n)
        """(n,) current inputs ``|omega| omega`` [Hz²]."""
        self.kernel_params = np.array([self.omega_min_hz, self.omega_max_hz, self.alpha, self.dead_band_hz])
        """``lo, hi, alpha, dead_band_hz`` for :func:`omnirotor.sim._kernels.rotor_step`."""

    def reset(self, omega_hz: np.ndarray) -> None:
        """Set the speeds (clipped to the limits) [Hz]."""
        w = np.clip(np.asarray(omega_hz, dtype=float), self.omega_min_hz, self.omega_max_hz)
        self.omega_hz[:] = w
        self.u_hz2[:] = np.abs(w) * w

    def target(self, omega_cmd_hz: np.ndarray) -> np.ndarray:
        """(n,) the speeds the loop converges to for a command [Hz]: clipped, zero inside the dead band."""
        t = np.clip(np.asarray(omega_cmd_hz, dtype=float), self.omega_min_hz, self.omega_max_hz)
        if self.dead_band_hz > 0.0:
            t[np.abs(t) < self.dead_band_hz] = 0.0
        return t

    def step(self, omega_cmd_hz: np.ndarray) -> None:
        """Advance the speeds one period towards the command [Hz].

        Out-of-range commands (±inf included) are clipped; a NaN entry holds its rotor's speed.
        """
        _k.rotor_step(
            self.omega_hz,
            self.u_hz2,
            np.asarray(omega_cmd_hz, dtype=np.float64),
            self.omega_min_hz,
            self.omega_max_hz,
            self.alpha,
            self.dead_band_hz,
        )
