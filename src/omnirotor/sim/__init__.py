"""MuJoCo simulator standing in for the robot (SPEC §2, §1.4, §5.2, §7).

The controller talks to it only through :mod:`omnirotor.messages`: :meth:`Simulator.step` takes a
:class:`~omnirotor.messages.RotorCommand` and returns a :class:`~omnirotor.messages.SensorFrame`.
Rigid-body dynamics and contact come from MuJoCo; the rotor wrench from the project's truth aerodynamics
(:mod:`omnirotor.sim.aero`, usable without MuJoCo). This package never imports the controller.

Rendering (:func:`render_scene`, :class:`VideoRecorder`) is imported lazily, so that using the simulator
does not open a GL context.
"""

from __future__ import annotations

import os

# Headless rendering by default; must be decided before the first ``import mujoco`` of the process.
os.environ.setdefault("MUJOCO_GL", "egl")

from typing import Any  # noqa: E402

from omnirotor.sim.aero import InterferenceAero, NominalAero, hover_equilibrium, make_aero
from omnirotor.sim.params import (
    AeroParams,
    AirflowParams,
    RotorDynamicsParams,
    SceneParams,
    SensorParams,
    SimParams,
    load_sim_params,
)
from omnirotor.sim.scenes import SCENES, SceneAnchors, default_start_pose, scene_anchors
from omnirotor.sim.simulator import GroundTruth, Simulator

__all__ = [
    "Simulator",
    "SimParams",
    "GroundTruth",
    "SceneParams",
    "SceneAnchors",
    "SCENES",
    "load_sim_params",
    "VideoRecorder",
    "render_scene",
    "render_frame",
    "RotorDynamicsParams",
    "AeroParams",
    "SensorParams",
    "AirflowParams",
    "InterferenceAero",
    "NominalAero",
    "make_aero",
    "hover_equilibrium",
    "scene_anchors",
    "default_start_pose",
]

_LAZY = {"VideoRecorder", "render_scene", "render_frame"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        from omnirotor.sim import render

        return getattr(render, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
