"""omnirotor: sensorless 6-D physical interaction with omnidirectional multirotors.

The library implements the system of Veenstra et al., "6D Physical Interaction with an Omnidirectional
Aerial Robot" (Drones 2026), restored in ``SPEC.md``: the vehicle model and piecewise-linear wrench-map
identification (:mod:`omnirotor.vehicle`, :mod:`omnirotor.identification`), the 1 kHz interaction
controller (:mod:`omnirotor.control`), a MuJoCo simulator standing in for the robot (:mod:`omnirotor.sim`),
and the paper's experiments.
"""

from omnirotor.errors import InputError, OmnirotorError

# Imported before the CLI takes the working folder off sys.path (omnirotor.cli): nothing but this package here,
# not even typing (a typing.py in the folder a command runs from would run as code).
TYPE_CHECKING = False
if TYPE_CHECKING:
    from omnirotor.vehicle import VehicleParams, load_vehicle

__all__ = ["InputError", "OmnirotorError", "VehicleParams", "load_vehicle", "__version__"]
__version__ = "0.1.0"


def __getattr__(name: str):
    """Import :mod:`omnirotor.vehicle` (NumPy, SciPy) on first use, so ``omnirotor --help`` starts fast."""
    if name in ("VehicleParams", "load_vehicle"):
        from omnirotor import vehicle

        return getattr(vehicle, name)
    raise AttributeError(f"module 'omnirotor' has no attribute {name!r}")
