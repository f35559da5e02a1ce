"""The simulator's compiled MuJoCo model, its parsed MJCF kept per process (SPEC §1.2: mass and inertia).

The runs of a campaign differ in the vehicle's true mass and inertia (SPEC §1.2's ``m``, ``J``) and in much that
the MJCF does not hold (the truth aerodynamics, the sensors); their MJCF differs only in the vehicle body's
``<inertial>``. Generating and parsing it again for every run was two thirds of building the plant's model
(issue 16). :func:`compiled_model` keeps the parsed :class:`mujoco.MjSpec` of :func:`~omnirotor.sim.model.build_mjcf`
per everything that function reads except the mass and the inertia (the vehicle's other fields, the scene, its
parameters, the time step), writes the run's mass and inertia into it as the MJCF would give them
(:func:`~omnirotor.sim.model.vehicle_inertial`) and compiles it: the model compiled from the run's own MJCF,
array for array (tested), in a third of the time.

The key holds the parameters, not the XML: a change to what :func:`~omnirotor.sim.model.build_mjcf` makes of them
(another scene's geometry, say) is a change of code, which a new process picks up; a test checks that the MJCF of
two vehicles differing in mass and inertia differs in the vehicle's ``<inertial>`` alone.
"""

from __future__ import annotations

import collections
import dataclasses

import mujoco

from omnirotor.sim.model import BODY_NAME, TOOL_BODY, build_mjcf, vehicle_inertial
from omnirotor.sim.params import SceneParams
from omnirotor.vehicle import VehicleParams

__all__ = ["compiled_model", "MAX_SPECS", "clear"]

MAX_SPECS = 8
"""Parsed models kept per process (least recently used dropped first)."""
_INERTIAL_FIELDS = ("mass", "inertia_diag")
"""The :class:`VehicleParams` fields the cached models take per call."""

_specs: collections.OrderedDict[tuple, tuple[mujoco.MjSpec, bool]] = collections.OrderedDict()


def _key(vehicle: VehicleParams, scene: str, params: SceneParams, timestep: float) -> tuple:
    rest = tuple(getattr(vehicle, f.name) for f in dataclasses.fields(vehicle) if f.name not in _INERTIAL_FIELDS)
    return rest, scene, params, float(timestep)


def compiled_model(vehicle: VehicleParams, scene: str, params: SceneParams, timestep: float) -> mujoco.MjModel:
    """The simulated model of ``vehicle`` in ``scene``: that of ``build_mjcf(..., textures=False)``, a new one.

    Args:
        vehicle: the vehicle.
        scene: one of :data:`omnirotor.sim.scenes.SCENES`.
        params: scene geometry and contact properties.
        timestep: physics time step [s].

    Returns:
        A new ``mujoco.MjModel`` (the caller's own).

    Raises:
        InputError: what :func:`~omnirotor.sim.model.build_mjcf` refuses (checked on every call).
    """
    key = _key(vehicle, scene, params, timestep)
    entry = _specs.get(key)
    if entry is None:
        spec = mujoco.MjSpec.from_string(build_mjcf(vehicle, scene, params, timestep, textures=False))
        entry = spec, spec.body(TOOL_BODY) is not None
        _specs[key] = entry
        while len(_specs) > MAX_SPECS:
            _specs.popitem(last=False)
    else:
        _specs.move_to_end(key)
    spec, compliant = entry
    mass, com, kind, moments = vehicle_inertial(vehicle, params, compliant)
    body = spec.body(BODY_NAME)
    body.mass = mass
    body.ipos = com
    if kind == "fullinertia":
        body.fullinertia = moments
    else:
        body.inertia = moments
    return spec.compile()


def clear() -> None:
    """Forget the parsed models (tests)."""
    _specs.clear()
