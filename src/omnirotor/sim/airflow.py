"""Room airflow: the vehicle's own wake recirculating off the walls and floor, a random force at the CoM.

Indoors, a multirotor's downwash hits the floor and the surfaces it works on and comes back as slow,
large eddies that push the whole airframe (issue 12, item 2; docs/fidelity.md). The block models their
net effect as a force on the CoM, world frame, each axis an independent first-order Gauss-Markov process of
standard deviation ``force_std`` [N] and corner frequency ``corner_hz`` [Hz]:
``f = decay f + drive n``, ``decay = exp(-2 pi f_c dt)``, ``drive = sigma sqrt(1 - decay²)``, n standard
normal from the block's own generator (:mod:`omnirotor.sim.prng`, seeded by the simulator's seed). The
standard deviation scales with the flown vehicle's weight (``AirflowParams.ref_weight_N``).
Unlike the rotors' thrust fluctuation (:mod:`omnirotor.sim.rotors`), which comes with the moments of the
rotors' lever arms, this force turns nothing.

The block (:class:`AirflowForce`, registered as ``("airflow", "recirculation")``) owns its parameters
(:data:`PARAMS_DTYPE`), its state (:data:`STATE_DTYPE`) and its compiled step (:func:`airflow_step`), which
the simulator's compiled step (:mod:`omnirotor.sim.step`) calls once per control period.
"""

from __future__ import annotations

import numpy as np

from omnirotor._jit import jit
from omnirotor.blocks import register
from omnirotor.sim import prng
from omnirotor.sim.params import AirflowParams

__all__ = ["AirflowForce", "airflow_step", "PARAMS_DTYPE", "STATE_DTYPE"]

PARAMS_DTYPE = np.dtype([("decay", np.float64), ("drive", np.float64)])
"""``exp(-2 pi f_c dt)`` and ``sigma sqrt(1 - decay²)`` [N] of :func:`airflow_step`."""
STATE_DTYPE = np.dtype([("f_W", np.float64, (3,)), ("rng", np.uint64)])
"""The force at the CoM, world frame [N], and the generator's state."""
_RNG_STREAM = 103
"""Index of the airflow's generator among the simulator's streams (:func:`prng.seed_state`)."""


@jit
def airflow_step(par, st) -> None:
    """One period of the force: ``f = decay f + drive n`` per axis (nothing when ``drive`` is 0)."""
    drive = par["drive"]
    if drive == 0.0:
        return
    decay = par["decay"]
    f = st["f_W"]
    for j in range(3):
        f[j] = prng.gauss_markov_next(f[j], decay, drive, st)


@register("airflow", "recirculation")
class AirflowForce:
    """The recirculation force (module docstring).

    Args:
        params: its standard deviation (at ``params.ref_weight_N``) and corner frequency.
        dt: the period of :meth:`step` [s].
        seed: the simulator's seed (equal seeds, equal runs).
        weight_N: the flown vehicle's weight [N]: the standard deviation is ``force_std * weight_N /
            ref_weight_N`` (:class:`~omnirotor.sim.params.AirflowParams`); None: ``ref_weight_N``.
    """

    state_dtype = STATE_DTYPE
    params_dtype = PARAMS_DTYPE
    log_fields = ("f_W",)

    def __init__(self, params: AirflowParams, dt: float, seed: int = 0, weight_N: float | None = None) -> None:
        self.params = params
        self.seed = int(seed)
        scale = 1.0 if weight_N is None else float(weight_N) / params.ref_weight_N
        self.force_std = params.force_std * scale
        """Standard deviation of each axis of the force for this vehicle [N]."""
        self.par = np.zeros(1, PARAMS_DTYPE)
        """(1,) the :data:`PARAMS_DTYPE` record of the compiled step."""
        self.par["decay"], self.par["drive"] = prng.gauss_markov_coefficients(self.force_std, params.corner_hz, dt)
        self.state = np.zeros(1, STATE_DTYPE)
        """(1,) the :data:`STATE_DTYPE` record (or the simulator's field it was moved into)."""
        self.reset()

    def adopt(self, par: np.ndarray, state: np.ndarray) -> None:
        """Move parameters and state into ``par`` and ``state``, fields of a composer's record (views)."""
        par[...] = self.par
        state[...] = self.state
        self.par, self.state = par, state

    @property
    def f_W(self) -> np.ndarray:
        """(3,) the current force, world frame [N] (a view of the state)."""
        return self.state["f_W"][0]

    def reset(self) -> None:
        """Force zero (its first periods are its transient), generator back to the seed."""
        self.state[0] = 0
        self.state["rng"] = prng.seed_state(self.seed, _RNG_STREAM)

    def step(self) -> None:
        """Advance the force one period."""
        airflow_step(self.par[0], self.state[0])
