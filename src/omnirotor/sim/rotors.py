"""Rotor speed dynamics: a first-order lag on omega [Hz] with saturation and an optional dead band (SPEC §1.4).

Each control period the commanded speed is clipped to ``[omega_min_hz, omega_max_hz]``, set to zero inside
the dead band when it is enabled, and the speed follows it exactly as a first-order system held over the
period: ``omega += (1 - exp(-dt / tau_m)) (omega_cmd - omega)``.
"""

from __future__ import annotations

import math

import numpy as np

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
        self.dead_band_hz = params.dead_band_hz if params.dead_band else 0.0
        n = vehicle.n_rotors
        self.n_rotors = n
        self.omega_hz = np.zeros(n)
        """(n,) current signed speeds [Hz]."""
        self.u_hz2 = np.zeros(n)
        """(n,) current inputs ``|omega| omega`` [Hz²]."""
        # The loop runs on Python floats: for a handful of rotors that beats a chain of numpy calls.
        self._w = [0.0] * n

    def reset(self, omega_hz: np.ndarray) -> None:
        """Set the speeds (clipped to the limits) [Hz]."""
        w = np.clip(np.asarray(omega_hz, dtype=float), self.omega_min_hz, self.omega_max_hz)
        self._w = w.tolist()
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
        lo, hi, a = self.omega_min_hz, self.omega_max_hz, self.alpha
        cmd = omega_cmd_hz.tolist()
        if self.dead_band_hz > 0.0:
            db = self.dead_band_hz
            cmd = [0.0 if -db < c < db else c for c in cmd]
        w = [
            wi + a * ((c if lo <= c <= hi else hi if c > hi else lo if c < lo else wi) - wi)
            for c, wi in zip(cmd, self._w, strict=True)
        ]
        self._w = w
        self.omega_hz[:] = w
        np.abs(self.omega_hz, out=self.u_hz2)
        self.u_hz2 *= self.omega_hz
