"""Rotor speed dynamics and rotor disturbances (SPEC §1.4; issue 12 item 2, docs/fidelity.md).

Each control period the commanded speed is clipped to ``[omega_min_hz, omega_max_hz]``, set to zero inside
the dead band when it is enabled, and the speed follows it exactly as a first-order system held over the
period: ``omega += (1 - exp(-dt / tau_m)) (omega_cmd - omega)``.

Reversal (``reversal_delay_s > 0``): a bidirectional sensorless ESC cannot drive its motor smoothly through
zero speed. A rotor whose speed would cross zero, or fall below ``reversal_stop_hz`` while braking towards a
command of the other sign, stops (speed 0) and stays stopped for ``reversal_delay_s`` (the ESC aligns the
rotor and restarts it open-loop until the back-EMF can be read), then spins up in the new direction through
the same lag.

Thrust and torque fluctuation (``thrust_noise_rel > 0``): each rotor's aerodynamic input is
``u_eff = |omega| omega (1 + x)``, where ``x`` is coloured noise (a first-order Gauss-Markov process of
standard deviation ``thrust_noise_rel`` and corner frequency ``thrust_noise_corner_hz``) drawn per rotor:
the unsteady loads of a propeller in the turbulent, meandering wakes of its neighbours and in the frame's
blockage, which the speed loop does not see (the measured speeds stay ``omega``). The truth aerodynamics
read ``u_eff``, so thrust and drag torque fluctuate together.

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
from omnirotor.sim import prng
from omnirotor.sim.params import RotorDynamicsParams
from omnirotor.vehicle import VehicleParams

__all__ = ["RotorBank", "rotor_step", "MAX_ROTORS", "PARAMS_DTYPE", "STATE_DTYPE"]

MAX_ROTORS = 16
"""Rotors the simulator's fixed-size records have room for."""
_RNG_STREAM = 101
"""Index of the thrust fluctuation's generator among the simulator's streams (:func:`prng.seed_state`)."""

PARAMS_DTYPE = np.dtype(
    [
        ("n_rotors", np.int64),
        ("omega_min_hz", np.float64),
        ("omega_max_hz", np.float64),
        ("alpha", np.float64),  # 1 - exp(-dt / tau_m)
        ("dead_band_hz", np.float64),  # half-width; 0 disables the dead band
        ("reversal_steps", np.int64),  # steps a reversing rotor stays stopped; 0 disables the reversal model
        ("reversal_stop_hz", np.float64),  # below this speed a braking rotor stops [Hz]
        ("noise_decay", np.float64),  # exp(-2 pi f_c dt) of the thrust fluctuation
        ("noise_drive", np.float64),  # sigma sqrt(1 - decay^2): stationary standard deviation sigma
    ]
)
"""Parameters of :func:`rotor_step`."""

STATE_DTYPE = np.dtype(
    [
        ("omega_hz", np.float64, (MAX_ROTORS,)),
        ("u_hz2", np.float64, (MAX_ROTORS,)),
        ("u_eff_hz2", np.float64, (MAX_ROTORS,)),  # the aerodynamics' input: u (1 + thrust_noise)
        ("thrust_noise", np.float64, (MAX_ROTORS,)),  # relative thrust fluctuation x [-]
        ("stopped_steps", np.int64, (MAX_ROTORS,)),  # steps left of a reversal's stop
        ("rng", np.uint64),  # the fluctuation's generator (omnirotor.sim.prng)
    ]
)
"""Speeds [Hz], inputs ``|omega| omega`` and their fluctuating aerodynamic version [Hz²] of the first
``n_rotors`` rotors, the fluctuation, the reversal counters and the generator's state."""


@jit
def rotor_step(par, st, cmd_hz) -> None:
    """One period of the rotor speed loop and the thrust fluctuation, in place.

    Per rotor: the command is set to 0 inside the dead band ``(-db, db)`` (when ``db > 0``), clipped to
    ``[lo, hi]`` (a NaN command holds the speed), and ``omega += alpha (target - omega)``; with the reversal
    model a speed that would cross zero, or fall below ``reversal_stop_hz`` towards a target of the other
    sign, becomes 0 and is held there ``reversal_steps`` periods. Then ``u = |omega| omega``, the fluctuation
    ``x = decay x + drive n`` (n standard normal) and ``u_eff = u (1 + x)``.

    Args:
        par: a :data:`PARAMS_DTYPE` record.
        st: a :data:`STATE_DTYPE` record, updated.
        cmd_hz: (n,) commanded speeds [Hz].
    """
    lo, hi, alpha, dead_band_hz = par["omega_min_hz"], par["omega_max_hz"], par["alpha"], par["dead_band_hz"]
    rev_steps, stop_hz = par["reversal_steps"], par["reversal_stop_hz"]
    decay, drive = par["noise_decay"], par["noise_drive"]
    omega_hz, u_hz2, u_eff, x, stopped = (
        st["omega_hz"],
        st["u_hz2"],
        st["u_eff_hz2"],
        st["thrust_noise"],
        st["stopped_steps"],
    )
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
        if stopped[i] > 0:  # restarting after a reversal: the rotor stays at rest
            stopped[i] -= 1
            w = 0.0
        else:
            w_new = w + alpha * (target - w)
            if rev_steps > 0 and w * target < 0.0 and (w * w_new <= 0.0 or abs(w_new) < stop_hz):
                w_new = 0.0
                stopped[i] = rev_steps
            w = w_new
        omega_hz[i] = w
        u = abs(w) * w
        u_hz2[i] = u
        if drive > 0.0:
            x[i] = prng.gauss_markov_next(x[i], decay, drive, st)
        u_eff[i] = u * (1.0 + x[i])


@register("rotors", "first-order-lag")
class RotorBank:
    """The rotors' speed states.

    Args:
        vehicle: gives the number of rotors and the speed limits.
        params: the speed-loop parameters.
        dt: the period of :meth:`step` [s].
        seed: seed of the thrust fluctuation (the simulator's; equal seeds, equal runs).

    Raises:
        InputError: more rotors than :data:`MAX_ROTORS`.
    """

    state_dtype = STATE_DTYPE
    params_dtype = PARAMS_DTYPE
    log_fields = ("omega_hz",)

    def __init__(self, vehicle: VehicleParams, params: RotorDynamicsParams, dt: float, seed: int = 0) -> None:
        n = vehicle.n_rotors
        if n > MAX_ROTORS:
            raise InputError(f"the simulator supports up to {MAX_ROTORS} rotors, the vehicle has {n}")
        self.params = params
        self.omega_min_hz = float(vehicle.omega_min_hz)
        self.omega_max_hz = float(vehicle.omega_max_hz)
        self.alpha = 1.0 - math.exp(-dt / params.tau_m)
        self.dead_band_hz = float(params.dead_band_hz) if params.dead_band else 0.0
        self.n_rotors = n
        self.seed = int(seed)
        self.reversal_steps = int(round(params.reversal_delay_s / dt))
        decay, drive = prng.gauss_markov_coefficients(params.thrust_noise_rel, params.thrust_noise_corner_hz, dt)
        self.par = np.zeros(1, PARAMS_DTYPE)
        """(1,) the :data:`PARAMS_DTYPE` record of the compiled step."""
        p = self.par[0]
        p["n_rotors"], p["omega_min_hz"], p["omega_max_hz"] = n, self.omega_min_hz, self.omega_max_hz
        p["alpha"], p["dead_band_hz"] = self.alpha, self.dead_band_hz
        p["reversal_steps"], p["reversal_stop_hz"] = self.reversal_steps, params.reversal_stop_hz
        p["noise_decay"], p["noise_drive"] = decay, drive
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

    @property
    def u_eff_hz2(self) -> np.ndarray:
        """(n,) the inputs the aerodynamics see, ``u (1 + thrust_noise)`` [Hz²] (a view of the state)."""
        return self.state["u_eff_hz2"][0, : self.n_rotors]

    @property
    def thrust_noise(self) -> np.ndarray:
        """(n,) current relative thrust fluctuation of each rotor [-] (a view of the state)."""
        return self.state["thrust_noise"][0, : self.n_rotors]

    def reset(self, omega_hz: np.ndarray | None = None) -> None:
        """Set the speeds (clipped to the limits) [Hz], restart the fluctuation from the seed.

        The speeds default to those of the previous reset. The fluctuation starts at 0 (its first periods
        are its transient) and no rotor is reversing.
        """
        if omega_hz is not None:
            self._initial = np.clip(np.asarray(omega_hz, dtype=float), self.omega_min_hz, self.omega_max_hz)
        w = self._initial
        self.state[0] = 0
        self.state["rng"] = prng.seed_state(self.seed, _RNG_STREAM)
        self.omega_hz[:] = w
        self.u_hz2[:] = np.abs(w) * w
        self.u_eff_hz2[:] = self.u_hz2

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
