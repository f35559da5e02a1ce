"""The only types the controller and a plant (simulator or real robot) exchange.

A plant produces a :class:`SensorFrame` every control period and consumes a :class:`RotorCommand`.
Neither side imports the other: the controller can fly a real robot whose driver fills the same frame.
Arrays in a message belong to that message (the producer hands over fresh arrays or copies).
"""

from __future__ import annotations

import dataclasses
import enum

import numpy as np

__all__ = ["StateEstimate", "SensorFrame", "RotorCommand", "ControlStatus"]


class ControlStatus(enum.IntFlag):
    """Flags a controller raises on a command; ``OK`` (0) when nothing happened."""

    OK = 0
    QP_FALLBACK = 1
    """The allocation QP failed; the command is the clipped pseudo-inverse."""
    NONFINITE_INPUT = 2
    """A sensor value or reference was NaN/inf or out of range; the last safe command is held."""
    SATURATED = 4
    """At least one rotor is at a speed limit."""
    ESTIMATE_DEGRADED = 8
    """The state estimate runs on the IMU alone (motion capture missing or stale)."""
    ROTOR_EXCLUDED = 16
    """The allocation excludes at least one rotor declared failed."""


@dataclasses.dataclass(frozen=True, slots=True)
class StateEstimate:
    """Rigid-body state of the vehicle's CoM (body frame B).

    Attributes:
        t: time [s].
        p_W: (3,) position [m].
        v_W: (3,) velocity [m/s].
        a_W: (3,) acceleration [m/s²] (gravity not included: p̈).
        R_WB: (3, 3) attitude, body to world.
        omega_B: (3,) angular velocity [rad/s].
        valid: False when the estimate is degraded (e.g. motion capture lost for too long).
    """

    t: float
    p_W: np.ndarray
    v_W: np.ndarray
    a_W: np.ndarray
    R_WB: np.ndarray
    omega_B: np.ndarray
    valid: bool = True


@dataclasses.dataclass(frozen=True, slots=True)
class SensorFrame:
    """What the plant measured during one control period.

    Attributes:
        t: time of the frame [s].
        imu_acc_B: (3,) accelerometer specific force [m/s²], body axes (reads +g up at rest).
        imu_gyro_B: (3,) gyroscope [rad/s], body axes.
        rotor_hz: (n,) measured rotor speeds [Hz], signed.
        mocap_new: True when a motion-capture sample arrived in this period.
        mocap_t: time at which that sample was taken [s] (earlier than ``t`` by the latency).
        mocap_p_W: (3,) measured position of the body frame [m].
        mocap_q_WB: (4,) measured attitude, unit quaternion wxyz.
        state: optional full state (ground truth plus noise) for estimator-bypass studies; None on a robot.
    """

    t: float
    imu_acc_B: np.ndarray
    imu_gyro_B: np.ndarray
    rotor_hz: np.ndarray
    mocap_new: bool = False
    mocap_t: float = 0.0
    mocap_p_W: np.ndarray | None = None
    mocap_q_WB: np.ndarray | None = None
    state: StateEstimate | None = None


@dataclasses.dataclass(frozen=True, slots=True)
class RotorCommand:
    """Rotor speed set-points for one control period.

    Attributes:
        t: time [s].
        omega_hz: (n,) signed rotor speed commands [Hz]; always finite and within the vehicle's limits.
        status: what happened while computing it.
    """

    t: float
    omega_hz: np.ndarray
    status: ControlStatus = ControlStatus.OK


def _fast_frozen_init(cls: type) -> None:
    """Give a frozen, slotted dataclass an ``__init__`` that sets its slots through their descriptors.

    Same signature, defaults and result as the generated one (the instance stays frozen), but about twice as
    fast: the generated ``__init__`` of a frozen dataclass goes through ``object.__setattr__`` for every
    field, and a control period builds three or four messages.
    """
    fields = dataclasses.fields(cls)
    namespace = {f"_set_{f.name}": cls.__dict__[f.name].__set__ for f in fields}
    params = []
    for f in fields:
        if f.default is dataclasses.MISSING:
            params.append(f.name)
        else:
            namespace[f"_default_{f.name}"] = f.default
            params.append(f"{f.name}=_default_{f.name}")
    body = "\n".join(f"    _set_{f.name}(self, {f.name})" for f in fields)
    exec(f"def __init__(self, {', '.join(params)}):\n{body}\n", namespace)  # as dataclasses itself does
    init = namespace["__init__"]
    init.__qualname__ = f"{cls.__qualname__}.__init__"
    init.__annotations__ = dict(cls.__init__.__annotations__)
    cls.__init__ = init


for _cls in (StateEstimate, SensorFrame, RotorCommand):
    _fast_frozen_init(_cls)
del _cls
