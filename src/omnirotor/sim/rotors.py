"""Rotor speed dynamics: a first-order lag on omega [Hz] with saturation and an optional dead band (SPEC §1.4).

Each control period the commanded speed is clipped to ``[omega_min_hz, omega_max_hz]``, set to zero inside
the dead band when it is enabled, and the speed follows it exactly as a first-order system held over the
period: ``omega += (1 - exp(-dt / tau_m)) (omega_cmd - omega)``.

The block (:class:`RotorBank`, registered as ``("rotors", "first-order-lag")``) owns its named parameters
(:data:`PARAMS_DTYPE`), its state (:data:`STATE_DTYPE`: speeds and inputs, room for :data:`MAX_ROTORS`) and
its compiled step (:func:`rotor_step`), which the simulator's compiled step calls too.
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor._jit import jit
from omnirotor.blocks import register
from omnirotor.errors import InputError
from omnirotor.sim.params import RotorDynamicsParams
from omnirotor.vehicle import VehicleParams

__all__ = ["RotorBank", "rotor_step", "MAX_ROTORS", "PARAMS_DTYPE", "STATE_DTYPE"]

MAX_ROTORS = 16
"""Rotors the simulator's fixed-size records have room for."""

PARAMS_DTYPE = np.dtype(
    [
        ("n_rotors", np.int64),
        ("omega_min_hz", np.float64),
        ("omega_max_hz", np.float64),
        ("alpha", np.float64),  # 1 - exp(-dt / tau_m)
        ("dead_band_hz", np.float64),  # half-width; 0 disables the dead band
    ]
)
"""Parameters of :func:`rotor_step`."""

STATE_DTYPE = np.dtype([("omega_hz", np.float64, (MAX_ROTORS,)), ("u_hz2", np.float64, (MAX_ROTORS,))])
"""Speeds [Hz] and inputs ``|omega| omega`` [Hz²] of the first ``n_rotors`` rotors."""


@jit
def rotor_step(par, st, cmd_hz) -> None:
    """One period of the rotor speed lag, in place.

    Per rotor: the command is set to 0 inside the dead band ``(-db, db)`` (when ``db > 0``), clipped to
    ``[lo, hi]`` (a NaN command holds the speed), and ``omega += alpha (target - omega)``; then
    ``u = |omega| omega``.

    Args:
        par: a :data:`PARAMS_DTYPE` record.
        st: a :data:`STATE_DTYPE` record, updated.
        cmd_hz: (n,) commanded speeds [Hz].
    """
    lo, hi, alpha, dead_band_hz = par["omega_min_hz"], par["omega_max_hz"], par["alpha"], par["dead_band_hz"]
    omega_hz, u_hz2 = st["omega_hz"], st["u_hz2"]
    for i in range(par["n_rotors"]):
        c = cmd_hz[i]
        if dead_band_hz > 0.0 and -dead_band_hz < c < dead_band_hz:
            c = 0.0
        w = omega_hz[i]
        if lo <= c <= hi:
            target = c
        elif c > hi:
            target = hi
        elif c < lo:
            target = lo
        else:  # NaN: hold
            target = w
        w = w + alpha * (target - w)
        omega_hz[i] = w
        u_hz2[i] = abs(w) * w


@register("rotors", "first-order-lag")
class RotorBank:
    """The rotors' speed states.

    Args:
        vehicle: gives the number of rotors and the speed limits.
        params: the speed-loop parameters.
        dt: the period of :meth:`step` [s].

    Raises:
        InputError: more rotors than :data:`MAX_ROTORS`.
    """

    state_dtype = STATE_DTYPE
    params_dtype = PARAMS_DTYPE
    log_fields = ("omega_hz",)

    def __init__(self, vehicle: VehicleParams, params: RotorDynamicsParams, dt: float) -> None:
        n = vehicle.n_rotors
        if n > MAX_ROTORS:
            raise InputError(f"the simulator supports up to {MAX_ROTORS} rotors, the vehicle has {n}")
        self.params = params
        self.omega_min_hz = float(vehicle.omega_min_hz)
        self.omega_max_hz = float(vehicle.omega_max_hz)
        self.alpha = 1.0 - math.exp(-dt / params.tau_m)
        self.dead_band_hz = float(params.dead_band_hz) if params.dead_band else 0.0
        self.n_rotors = n
        self.par = np.zeros(1, PARAMS_DTYPE)
        """(1,) the :data:`PARAMS_DTYPE` record of the compiled step."""
        p = self.par[0]
        p["n_rotors"], p["omega_min_hz"], p["omega_max_hz"] = n, self.omega_min_hz, self.omega_max_hz
        p["alpha"], p["dead_band_hz"] = self.alpha, self.dead_band_hz
        self.state = np.zeros(1, STATE_DTYPE)
        """(1,) the :data:`STATE_DTYPE` record (or the simulator's field it was moved into)."""
        self._initial = np.zeros(n)

    def adopt(self, par: np.ndarray, state: np.ndarray) -> None:
        """Move parameters and state into ``par`` and ``state``, fields of a composer's record (views)."""
        par[...] = self.par
        state[...] = self.state
        self.par, self.state = par, state

    @property
    def omega_hz(self) -> np.ndarray:
        """(n,) current signed speeds [Hz] (a view of the state)."""
        return self.state["omega_hz"][0, : self.n_rotors]

    @property
    def u_hz2(self) -> np.ndarray:
        """(n,) current inputs ``|omega| omega`` [Hz²] (a view of the state)."""
        return self.state["u_hz2"][0, : self.n_rotors]

    def reset(self, omega_hz: np.ndarray | None = None) -> None:
        """Set the speeds (clipped to the limits) [Hz]; default: the speeds of the previous reset."""
        if omega_hz is not None:
            self._initial = np.clip(np.asarray(omega_hz, dtype=float), self.omega_min_hz, self.omega_max_hz)
        w = self._initial
        self.state[0] = 0.0
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
        rotor_step(self.par[0], self.state[0], np.asarray(omega_cmd_hz, dtype=np.float64))
