"""Room airflow: the vehicle's own wake recirculating off the surfaces near it, a random force at the CoM.

Indoors, a multirotor's downwash hits the floor and the surfaces it works on and comes back as slow,
large eddies that push the whole airframe (issue 12, item 2; docs/fidelity.md). The block models their
net effect as a force on the CoM, world frame, each axis an independent first-order Gauss-Markov process of
corner frequency ``corner_hz`` [Hz]: ``f = decay f + s(p) drive n``, ``decay = exp(-2 pi f_c dt)``,
``drive = sigma sqrt(1 - decay²)``, n standard normal from the block's own generator
(:mod:`omnirotor.sim.prng`, seeded by the simulator's seed). ``sigma`` (``force_std``) scales with the flown
vehicle's weight (``AirflowParams.ref_weight_N``).

The force needs a surface. A wake in free air leaves as a jet and does not come back (the downwash of a
multirotor in hover is a turbulent jet a few vehicle sizes below it, Bauersfeld et al., "Robotics meets fluid
dynamics", 2024); it is turned back where it meets a surface, and the recirculation grows as the vehicle gets
closer (the ground effect of a rotor, Cheeseman and Bennett 1955, and the recirculation between a wall's
fountain flow and the rotor inflow near corners, Aeronautical Journal 2025; in the method of images the flow a
surface sends back falls as the inverse square of the distance to the mirrored wake). So the standard deviation
is ``sigma s(p)``, with ``s² = Σ_i (l² / (l² + d_i²))²`` over the scene's large surfaces (independent eddies from
each), ``d_i`` the distance of the CoM ``p`` from surface ``i`` and ``l`` the radius of the vehicle's wake
source (its rotors' farthest centre plus a rotor radius: 0.32 m for the Omnirotor). ``sigma`` is thus the
force next to one surface; in the paper's point contact (CoM 0.5 m off the wall) ``s`` is 0.29, in free hover
1.5 m above the floor 0.04. The surfaces (:func:`scene_surfaces`) are planes (``d = n · (p - p0)``) and the
pipe's cylinder (``d = |p - c|_perp - r``), both taken as unbounded [A]; a block given no surface keeps
``s = 1`` (the force of ``sigma`` everywhere, the model before the surfaces; ``AirflowParams.near_surfaces``
false also gives it).

Unlike the rotors' thrust fluctuation (:mod:`omnirotor.sim.rotors`), which comes with the moments of the
rotors' lever arms, this force turns nothing.

The block (:class:`AirflowForce`, registered as ``("airflow", "recirculation")``) owns its parameters
(:data:`PARAMS_DTYPE`), its state (:data:`STATE_DTYPE`) and its compiled step (:func:`airflow_step`), which
the simulator's compiled step (:mod:`omnirotor.sim.step`) calls once per control period.
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor._jit import jit
from omnirotor.blocks import register
from omnirotor.sim import prng
from omnirotor.sim.params import AirflowParams, SceneParams
from omnirotor.sim.scenes import scene_anchors
from omnirotor.vehicle import VehicleParams

__all__ = [
    "AirflowForce",
    "airflow_step",
    "surface_scale",
    "scene_surfaces",
    "wake_radius",
    "PARAMS_DTYPE",
    "STATE_DTYPE",
]

MAX_SURFACES = 4
"""Surfaces one block can take (a scene has its work surface and the floor)."""
PLANE, CYLINDER = 0, 1
"""Kinds of surface: a plane through ``point`` with outward unit ``normal``; a cylinder of axis ``normal``
through ``point`` and radius ``radius``."""

SURFACE_DTYPE = np.dtype(
    [("kind", np.int64), ("point", np.float64, (3,)), ("normal", np.float64, (3,)), ("radius", np.float64)]
)
"""One surface the wake recirculates from, world frame [m]."""
PARAMS_DTYPE = np.dtype(
    [
        ("decay", np.float64),
        ("drive", np.float64),
        ("wake_radius2", np.float64),  # l² [m²]
        ("n_surfaces", np.int64),  # 0: s = 1
        ("surfaces", SURFACE_DTYPE, (MAX_SURFACES,)),
    ]
)
"""``exp(-2 pi f_c dt)``, ``sigma sqrt(1 - decay²)`` [N] and the surfaces of :func:`airflow_step`."""
STATE_DTYPE = np.dtype([("f_W", np.float64, (3,)), ("scale", np.float64), ("rng", np.uint64)])
"""The force at the CoM, world frame [N], the last surface factor ``s`` [-] and the generator's state."""
_RNG_STREAM = 103
"""Index of the airflow's generator among the simulator's streams (:func:`prng.seed_state`)."""


@jit
def surface_scale(par, p_W) -> float:
    """The factor ``s`` of the force's standard deviation at CoM position ``p_W`` (3,) [m] (module docstring)."""
    n = par["n_surfaces"]
    if n == 0:
        return 1.0
    l2 = par["wake_radius2"]
    acc = 0.0
    for i in range(n):
        srf = par["surfaces"][i]
        q0 = p_W[0] - srf["point"][0]
        q1 = p_W[1] - srf["point"][1]
        q2 = p_W[2] - srf["point"][2]
        a = srf["normal"]
        along = q0 * a[0] + q1 * a[1] + q2 * a[2]
        if srf["kind"] == PLANE:
            d = along
        else:
            r0, r1, r2 = q0 - along * a[0], q1 - along * a[1], q2 - along * a[2]
            d = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2) - srf["radius"]
        d = max(d, 0.0)
        g = l2 / (l2 + d * d)
        acc += g * g
    return math.sqrt(acc)


@jit
def airflow_step(par, st, p_W) -> None:
    """One period of the force: ``f = decay f + s(p_W) drive n`` per axis (nothing when ``drive`` is 0)."""
    drive = par["drive"]
    if drive == 0.0:
        return
    s = surface_scale(par, p_W)
    st["scale"] = s
    decay = par["decay"]
    f = st["f_W"]
    for j in range(3):
        f[j] = prng.gauss_markov_next(f[j], decay, s * drive, st)


def scene_surfaces(scene: str, params: SceneParams) -> list[tuple[int, np.ndarray, np.ndarray, float]]:
    """The large surfaces of a scene the wake comes back from: ``(kind, point, normal or axis, radius)``.

    The floor (when the scene has one), the wall boards, the pipe, and for the peg the plane of the funnel's
    mouth [A: the funnel is held in a mount of the size of a wall board]; ``free`` has the floor only.
    """
    out: list[tuple[int, np.ndarray, np.ndarray, float]] = []
    if params.floor:
        out.append((PLANE, np.zeros(3), np.array([0.0, 0.0, 1.0]), 0.0))
    a = scene_anchors(scene, params)
    if a.pipe_centre_W is not None:
        out.append((CYLINDER, np.array(a.pipe_centre_W), np.array(a.pipe_axis_W), float(a.pipe_radius)))
    elif a.surface_point_W is not None:
        out.append((PLANE, np.array(a.surface_point_W), np.array(a.normal_W), 0.0))
    return out


def wake_radius(vehicle: VehicleParams) -> float:
    """``l`` [m]: the farthest rotor centre from the CoM plus a rotor radius (module docstring)."""
    return float(np.max(np.linalg.norm(vehicle.positions_B, axis=1)) + 0.5 * vehicle.propeller_diameter)


@register("airflow", "recirculation")
class AirflowForce:
    """The recirculation force (module docstring).

    Args:
        params: its standard deviation next to one surface (at ``params.ref_weight_N``) and corner frequency.
        dt: the period of :meth:`step` [s].
        seed: the simulator's seed (equal seeds, equal runs).
        weight_N: the flown vehicle's weight [N]: the standard deviation is ``force_std * weight_N /
            ref_weight_N`` (:class:`~omnirotor.sim.params.AirflowParams`); None: ``ref_weight_N``.
        surfaces: the surfaces of :func:`scene_surfaces` (at most :data:`MAX_SURFACES`); None or empty, or
            ``params.near_surfaces`` false: ``s = 1`` everywhere.
        wake_radius_m: ``l`` [m], the radius of the vehicle's wake source (needed with surfaces).
    """

    state_dtype = STATE_DTYPE
    params_dtype = PARAMS_DTYPE
    log_fields = ("f_W",)

    def __init__(
        self,
        params: AirflowParams,
        dt: float,
        seed: int = 0,
        weight_N: float | None = None,
        surfaces: list[tuple[int, np.ndarray, np.ndarray, float]] | None = None,
        wake_radius_m: float | None = None,
    ) -> None:
        self.params = params
        self.seed = int(seed)
        scale = 1.0 if weight_N is None else float(weight_N) / params.ref_weight_N
        self.force_std = params.force_std * scale
        """Standard deviation of each axis of the force next to one surface, for this vehicle [N]."""
        self.par = np.zeros(1, PARAMS_DTYPE)
        """(1,) the :data:`PARAMS_DTYPE` record of the compiled step."""
        self.par["decay"], self.par["drive"] = prng.gauss_markov_coefficients(self.force_std, params.corner_hz, dt)
        surfaces = list(surfaces or []) if params.near_surfaces else []
        if surfaces:
            if len(surfaces) > MAX_SURFACES:
                raise ValueError(f"airflow: at most {MAX_SURFACES} surfaces, got {len(surfaces)}")
            if wake_radius_m is None or not wake_radius_m > 0:
                raise ValueError("airflow: surfaces need a wake radius > 0")
            self.par["wake_radius2"] = float(wake_radius_m) ** 2
            self.par["n_surfaces"] = len(surfaces)
            for i, (kind, point, normal, radius) in enumerate(surfaces):
                srf = self.par["surfaces"][0, i]
                srf["kind"], srf["point"], srf["radius"] = kind, point, radius
                srf["normal"] = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
        self.state = np.zeros(1, STATE_DTYPE)
        """(1,) the :data:`STATE_DTYPE` record (or the simulator's field it was moved into)."""
        self._p0 = np.zeros(3)
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

    @property
    def scale(self) -> float:
        """The surface factor ``s`` of the last step [-] (module docstring)."""
        return float(self.state["scale"][0])

    def reset(self) -> None:
        """Force zero (its first periods are its transient), generator back to the seed."""
        self.state[0] = 0
        self.state["scale"] = 1.0
        self.state["rng"] = prng.seed_state(self.seed, _RNG_STREAM)

    def step(self, p_W: np.ndarray | None = None) -> None:
        """Advance the force one period with the CoM at ``p_W`` (3,) [m] (None: the origin)."""
        airflow_step(self.par[0], self.state[0], self._p0 if p_W is None else p_W)
