"""The only types the controller and a plant (simulator or real robot) exchange.

A plant produces a :class:`SensorFrame` every control period and consumes a :class:`RotorCommand`.
Neither side imports the other: the controller can fly a real robot whose driver fills the same frame.
Arrays in a message belong to that message (the producer hands over fresh arrays or copies).

Packed frames. The same frame also has a flat float64 layout (the ``FRAME_*`` offsets below, ``frame_size(n)``
entries for ``n`` rotors): time, accelerometer, gyroscope, the motion-capture flag, time, position and
quaternion, the state flag and the 21 entries of a :class:`StateEstimate` (p, v, a, R row-major, omega), then
the rotor speeds. Compiled code on both sides reads and writes it directly (the closed loop of
:mod:`omnirotor.experiments.loop` runs the plant and the controller on one such buffer, without building
objects), and :meth:`SensorFrame.pack_into` / :meth:`SensorFrame.from_packed` convert. A robot driver may fill
either form. On the command side the packed form is simply the ``(n,)`` speed array.
"""

from __future__ import annotations

import dataclasses
import enum

import numpy as np

__all__ = [
    "StateEstimate",
    "SensorFrame",
    "RotorCommand",
    "ControlStatus",
    "frame_size",
    "FRAME_T",
    "FRAME_ACC_B",
    "FRAME_GYRO_B",
    "FRAME_MOCAP_NEW",
    "FRAME_MOCAP_T",
    "FRAME_MOCAP_P_W",
    "FRAME_MOCAP_Q_WB",
    "FRAME_HAS_STATE",
    "FRAME_STATE",
    "FRAME_ROTOR_HZ",
]

# -- the packed frame (module docstring) ----------------------------------------------------------------------
FRAME_T = 0
"""Time of the frame [s]."""
FRAME_ACC_B = 1
"""(3,) accelerometer [m/s²]."""
FRAME_GYRO_B = 4
"""(3,) gyroscope [rad/s]."""
FRAME_MOCAP_NEW = 7
"""1.0 when a motion-capture sample arrived in this period, else 0.0."""
FRAME_MOCAP_T = 8
"""Time the sample was taken [s]."""
FRAME_MOCAP_P_W = 9
"""(3,) measured position [m]."""
FRAME_MOCAP_Q_WB = 12
"""(4,) measured attitude, wxyz."""
FRAME_HAS_STATE = 16
"""1.0 when the plant gives a (bypass) state, else 0.0."""
FRAME_STATE = 17
"""(21,) the state: p_W (3) [m], v_W (3) [m/s], a_W (3) [m/s²], R_WB (9, row-major), omega_B (3) [rad/s]."""
FRAME_STATE_SIZE = 21
FRAME_ROTOR_HZ = 38
"""(n,) measured rotor speeds [Hz]; the last entries of the frame."""


def frame_size(n_rotors: int) -> int:
    """Entries of the packed frame of a vehicle with ``n_rotors`` rotors."""
    return FRAME_ROTOR_HZ + n_rotors


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
    FRAME_REJECTED = 32
    """The frame supervision rejected a part of the sensor frame (its cause is logged); the prediction replaced it."""
    MOCAP_NOISE_RAISED = 64
    """The estimator weighs motion capture as noisier than configured: its innovations showed more noise."""
    MOCAP_REJECTED = 128
    """The estimator did not fuse a well-formed motion-capture sample (outside its innovation gate, or too late)."""


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
        packed: the packed form this frame was made from by :meth:`from_packed` (its arrays are views into
            it), or None. Not an ``__init__`` argument: a frame built or edited (``dataclasses.replace``) has
            None, so a consumer that uses it never sees a stale copy.
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
    packed: np.ndarray | None = dataclasses.field(default=None, init=False, repr=False, compare=False)

    def pack_into(self, out: np.ndarray) -> None:
        """Write this frame into the packed layout (module docstring); ``out`` has ``frame_size(n)`` entries.

        No motion-capture sample or state leaves its entries at zero with its flag 0. A sample announced
        (``mocap_new``) without a well-formed pose (missing, or not of shapes (3,) and (4,)) is written as NaN,
        so that a consumer rejects it as it would the message.

        Raises:
            ValueError: IMU or rotor arrays (or a state) of the wrong size.
        """
        out[FRAME_T] = self.t
        out[FRAME_ACC_B : FRAME_ACC_B + 3] = self.imu_acc_B
        out[FRAME_GYRO_B : FRAME_GYRO_B + 3] = self.imu_gyro_B
        out[FRAME_ROTOR_HZ:] = self.rotor_hz
        out[FRAME_MOCAP_NEW] = 1.0 if self.mocap_new else 0.0
        out[FRAME_MOCAP_T] = self.mocap_t if self.mocap_new else 0.0
        p, q = self.mocap_p_W, self.mocap_q_WB
        if not self.mocap_new:
            out[FRAME_MOCAP_P_W : FRAME_MOCAP_Q_WB + 4] = 0.0
        elif p is None or q is None or np.shape(p) != (3,) or np.shape(q) != (4,):
            out[FRAME_MOCAP_P_W : FRAME_MOCAP_Q_WB + 4] = np.nan
        else:
            out[FRAME_MOCAP_P_W : FRAME_MOCAP_P_W + 3] = p
            out[FRAME_MOCAP_Q_WB : FRAME_MOCAP_Q_WB + 4] = q
        s = self.state
        if s is None:
            out[FRAME_HAS_STATE] = 0.0
            out[FRAME_STATE : FRAME_STATE + FRAME_STATE_SIZE] = 0.0
            return
        o = FRAME_STATE
        out[FRAME_HAS_STATE] = 1.0
        out[o : o + 3] = s.p_W
        out[o + 3 : o + 6] = s.v_W
        out[o + 6 : o + 9] = s.a_W
        out[o + 9 : o + 18] = np.reshape(s.R_WB, 9)
        out[o + 18 : o + 21] = s.omega_B

    @classmethod
    def from_packed(cls, packed: np.ndarray) -> SensorFrame:
        """The frame of a packed buffer (module docstring); its arrays are views into a copy of ``packed``.

        The copy is the frame's :attr:`packed`.
        """
        b = np.array(packed, dtype=np.float64)
        t = float(b[FRAME_T])
        state = None
        if b[FRAME_HAS_STATE] != 0.0:
            o = FRAME_STATE
            state = StateEstimate(
                t, b[o : o + 3], b[o + 3 : o + 6], b[o + 6 : o + 9], b[o + 9 : o + 18].reshape(3, 3), b[o + 18 : o + 21]
            )
        if b[FRAME_MOCAP_NEW] != 0.0:
            frame = cls(
                t, b[FRAME_ACC_B : FRAME_ACC_B + 3], b[FRAME_GYRO_B : FRAME_GYRO_B + 3], b[FRAME_ROTOR_HZ:], True,
                float(b[FRAME_MOCAP_T]), b[FRAME_MOCAP_P_W : FRAME_MOCAP_P_W + 3],
                b[FRAME_MOCAP_Q_WB : FRAME_MOCAP_Q_WB + 4], state,
            )  # fmt: skip
        else:
            frame = cls(
                t, b[FRAME_ACC_B : FRAME_ACC_B + 3], b[FRAME_GYRO_B : FRAME_GYRO_B + 3], b[FRAME_ROTOR_HZ:], False,
                0.0, None, None, state,
            )  # fmt: skip
        _set_packed(frame, b)
        return frame


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
    body_lines = []
    for f in fields:
        if f.default is not dataclasses.MISSING:
            namespace[f"_default_{f.name}"] = f.default
        if not f.init:  # set to its default, as the generated __init__ does
            body_lines.append(f"    _set_{f.name}(self, _default_{f.name})")
            continue
        params.append(f.name if f.default is dataclasses.MISSING else f"{f.name}=_default_{f.name}")
        body_lines.append(f"    _set_{f.name}(self, {f.name})")
    body = "\n".join(body_lines)
    exec(f"def __init__(self, {', '.join(params)}):\n{body}\n", namespace)  # as dataclasses itself does
    init = namespace["__init__"]
    init.__qualname__ = f"{cls.__qualname__}.__init__"
    init.__annotations__ = dict(cls.__init__.__annotations__)
    cls.__init__ = init


for _cls in (StateEstimate, SensorFrame, RotorCommand):
    _fast_frozen_init(_cls)
del _cls
_set_packed = SensorFrame.__dict__["packed"].__set__
