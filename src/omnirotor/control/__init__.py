"""The 1 kHz sensorless interaction controller (SPEC §4), one module per block of the paper's Figure 4.

Blocks: :mod:`~omnirotor.control.trajectory` (desired EE trajectory), :mod:`~omnirotor.control.estimator`
(state), :mod:`~omnirotor.control.maps` (wrench map of the attitude), :mod:`~omnirotor.control.observer`
(external wrench), :mod:`~omnirotor.control.admittance` (compliant EE reference),
:mod:`~omnirotor.control.pose` (wrench reference), :mod:`~omnirotor.control.allocation` (rotor inputs);
:mod:`~omnirotor.control.controller` wires them together. The package talks to a plant only through
:mod:`omnirotor.messages` and never imports the simulator.
"""

from omnirotor.control.admittance import ADMITTANCE_PRESETS, AdmittanceFilter, AdmittanceParams
from omnirotor.control.allocation import AllocationParams, AllocationStatus, Allocator
from omnirotor.control.controller import ControllerParams, InteractionController, load_controller_params
from omnirotor.control.estimator import EstimatorParams, make_estimator
from omnirotor.control.maps import MapParams, MapScheduler
from omnirotor.control.observer import ObserverParams, WrenchObserver
from omnirotor.control.pose import PoseController, PoseControlParams
from omnirotor.control.trajectory import PoseTrajectory, ReferenceSample, Waypoint

__all__ = [
    "ADMITTANCE_PRESETS",
    "AdmittanceFilter",
    "AdmittanceParams",
    "AllocationParams",
    "AllocationStatus",
    "Allocator",
    "ControllerParams",
    "EstimatorParams",
    "InteractionController",
    "MapParams",
    "MapScheduler",
    "ObserverParams",
    "PoseControlParams",
    "PoseController",
    "PoseTrajectory",
    "ReferenceSample",
    "Waypoint",
    "WrenchObserver",
    "load_controller_params",
    "make_estimator",
]
