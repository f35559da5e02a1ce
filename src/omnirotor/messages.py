"""The only types the controller and a plant (simulator or real robot) exchange.

A plant produces a :class:`SensorFrame` every control period and consumes a :class:`RotorCommand`.
Neither side imports the other: the controller can fly a real robot whose driver fills the same frame.
Who sent a frame or a command (a session id) and its number travel on the wire beside these types
(:mod:`omnirotor.rosmsg.convert`, judged by :mod:`omnirotor.sitl.gate`), not in them: they are measurements
and set-points only.
Arrays in a message belong to that message (the producer hands over fresh arrays or copies).

Frame records. The same frame is also one NumPy structured record, :func:`frame_dtype` ``(n_rotors)``, whose
fields compiled code on both sides reads and writes by name (``f.imu.acc_B``, ``f.mocap.p_W``,
``f.state.R_WB``, ``f.rotor_hz``); it is also what a transport carries. Its fields:

* ``t`` [s]: the time of the frame;
* ``imu`` (:data:`IMU_DTYPE`): ``acc_B`` (3,) specific force [m/s²], ``gyro_B`` (3,) [rad/s], body axes;
* ``mocap`` (:data:`MOCAP_DTYPE`): ``new`` (1.0 when a motion-capture sample arrived in this period, else
  0.0: then the other entries are 0), ``t`` [s] when it was taken, ``p_W`` (3,) [m], ``q_WB`` (4,) wxyz;
* ``state`` (:data:`ESTIMATE_DTYPE`): the plant's (bypass) state, ``valid`` 1.0 when the plant gives one;
* ``rotor_hz`` (n,): measured rotor speeds [Hz], signed.

:data:`ESTIMATE_DTYPE` (``p_W``, ``v_W``, ``a_W``, ``R_WB`` (3, 3), ``omega_B``, ``valid``) is also the
controller's state estimate, everywhere it travels between blocks. :data:`FRAME_HEAD_DTYPE` is a frame without
its rotor speeds (the frame supervision's checked copy, whose size does not depend on the vehicle). The
flags are float64 (1.0/0.0), so that every field of the record is a float64.

The simulator's compiled step writes a ``(1,)`` array of this dtype, the controller's reads it (the closed
loop of :mod:`omnirotor.experiments.loop` runs both on one such array, without building objects);
:meth:`SensorFrame.write_record` and :meth:`SensorFrame.from_record` convert. A robot driver may fill either
form. On the command side the record is simply the ``(n,)`` speed array.
"""

from __future__ import annotations

import dataclasses
import enum
import functools

import numpy as np

__all__ = [
    "ESTIMATE_LOG_FIELDS",
    "StateEstimate",
    "SensorFrame",
    "RotorCommand",
    "ControlStatus",
    "IMU_DTYPE",
    "MOCAP_DTYPE",
    "ESTIMATE_DTYPE",
    "FRAME_HEAD_DTYPE",
    "frame_dtype",
    "new_frame",
    "n_rotors_of",
]

_F8 = np.float64
IMU_DTYPE = np.dtype([("acc_B", _F8, 3), ("gyro_B", _F8, 3)])
"""An IMU sample: specific force [m/s²] and angular rate [rad/s], body axes."""
MOCAP_DTYPE = np.dtype([("new", _F8), ("t", _F8), ("p_W", _F8, 3), ("q_WB", _F8, 4)])
"""A motion-capture sample: ``new`` (1.0 when one arrived), its time [s], position [m], attitude (wxyz)."""
ESTIMATE_DTYPE = np.dtype(
    [
        ("valid", _F8),  # 1.0: a state (a frame: the plant gives one; an estimate: not degraded)
        ("p_W", _F8, 3),  # position of the CoM [m]
        ("v_W", _F8, 3),  # velocity [m/s]
        ("a_W", _F8, 3),  # acceleration (gravity not included: p'') [m/s²]
        ("R_WB", _F8, (3, 3)),  # attitude, body to world
        ("omega_B", _F8, 3),  # angular velocity [rad/s]
    ]
)
"""The rigid-body state of the CoM: a frame's (bypass) state and the controller's estimate."""
ESTIMATE_LOG_FIELDS = ("p_W", "v_W", "a_W", "R_WB", "omega_B")
"""The fields of an estimate a log records (:mod:`omnirotor.blocks`' ``log_fields`` form)."""
FRAME_HEAD_DTYPE = np.dtype([("t", _F8), ("imu", IMU_DTYPE), ("mocap", MOCAP_DTYPE), ("state", ESTIMATE_DTYPE)])
"""A frame without its rotor speeds (module docstring)."""


@functools.cache
def frame_dtype(n_rotors: int) -> np.dtype:
    """The frame record of a vehicle with ``n_rotors`` rotors (module docstring)."""
    fields = [(name, FRAME_HEAD_DTYPE.fields[name][0]) for name in FRAME_HEAD_DTYPE.names]
    return np.dtype([*fields, ("rotor_hz", _F8, (int(n_rotors),))])


def new_frame(n_rotors: int) -> np.ndarray:
    """A zeroed ``(1,)`` frame record array for ``n_rotors`` rotors."""
    return np.zeros(1, dtype=frame_dtype(n_rotors))


def n_rotors_of(frame: np.ndarray) -> int:
    """The rotor count of a frame record array; -1 when it is not one (another dtype)."""
    dtype = getattr(frame, "dtype", None)
    if dtype is None or dtype.names is None or "rotor_hz" not in dtype.names:
        return -1
    n = dtype["rotor_hz"].shape
    return n[0] if len(n) == 1 and dtype == frame_dtype(n[0]) else -1


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
    FAILSAFE = 256
    """The controller's failsafe holds and then lands the vehicle (blind or without motion capture for too long)."""
    BIAS_BEYOND_RANGE = 512
    """An estimated IMU bias is beyond the range the estimator is documented to follow."""


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
        record: the ``(1,)`` frame record this frame was made from by :meth:`from_record` (its arrays are views
            into it), or None. Not an ``__init__`` argument: a frame built or edited (``dataclasses.replace``)
            has None, so a consumer that uses it never sees a stale copy.
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
    record: np.ndarray | None = dataclasses.field(default=None, init=False, repr=False, compare=False)

    def write_record(self, out: np.ndarray) -> None:
        """Write this frame into a ``(1,)`` frame record array (:func:`frame_dtype`, module docstring).

        No motion-capture sample or state leaves its entries at zero with its flag 0. A sample announced
        (``mocap_new``) without a well-formed pose (missing, or not of shapes (3,) and (4,)) is written as NaN,
        so that a consumer rejects it as it would the message.

        Raises:
            ValueError: IMU or rotor arrays (or a state) of the wrong size.
        """
        out["t"] = self.t
        imu, mocap, state = out["imu"], out["mocap"], out["state"]
        imu["acc_B"] = self.imu_acc_B
        imu["gyro_B"] = self.imu_gyro_B
        out["rotor_hz"] = self.rotor_hz
        p, q = self.mocap_p_W, self.mocap_q_WB
        if not self.mocap_new:
            mocap[...] = 0.0
        elif p is None or q is None or np.shape(p) != (3,) or np.shape(q) != (4,):
            mocap[...] = np.nan
            mocap["new"] = 1.0
            mocap["t"] = self.mocap_t
        else:
            mocap["new"] = 1.0
            mocap["t"] = self.mocap_t
            mocap["p_W"] = p
            mocap["q_WB"] = q
        s = self.state
        if s is None:
            state[...] = 0.0
            return
        state["valid"] = 1.0
        state["p_W"] = s.p_W
        state["v_W"] = s.v_W
        state["a_W"] = s.a_W
        state["R_WB"] = np.reshape(s.R_WB, (3, 3))
        state["omega_B"] = s.omega_B

    @classmethod
    def from_record(cls, record: np.ndarray) -> SensorFrame:
        """The frame of a ``(1,)`` frame record array; its arrays are views into a copy of ``record``.

        The copy is the frame's :attr:`record`.
        """
        b = record.copy()
        r = b[0]
        t = float(r["t"])
        imu = r["imu"]
        state = None
        s = r["state"]
        if s["valid"] != 0.0:
            state = StateEstimate(t, s["p_W"], s["v_W"], s["a_W"], s["R_WB"], s["omega_B"])
        m = r["mocap"]
        if m["new"] != 0.0:
            frame = cls(t, imu["acc_B"], imu["gyro_B"], r["rotor_hz"], True, float(m["t"]), m["p_W"], m["q_WB"], state)
        else:
            frame = cls(t, imu["acc_B"], imu["gyro_B"], r["rotor_hz"], False, 0.0, None, None, state)
        _set_record(frame, b)
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
_set_record = SensorFrame.__dict__["record"].__set__
