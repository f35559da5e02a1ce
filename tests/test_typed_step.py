"""The controller's step from Python calls its compiled step typed once (``_jit.typed_entry``).

numba types every argument of every call of a dispatcher; ``InteractionController.step`` instead calls the
compiled specialisation of ``controller_step`` for its own three record arrays directly, after a cheap check
that the arrays it is given are of those types (``_typed_arrays``). Here: the entry point is numba's own
specialisation (one, shared with the dispatcher), the typed and the dispatched step give the same commands,
statuses and log rows bit for bit, and arrays of another type never reach the unchecked entry point.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from omnirotor._jit import _PURE_PYTHON, jit_entry, typed_entry
from omnirotor.control.controller import ControllerParams, InteractionController
from omnirotor.control.estimator import EstimatorParams
from omnirotor.control.trajectory import PoseTrajectory, Waypoint
from omnirotor.messages import SensorFrame
from omnirotor.sim import SimParams, Simulator
from omnirotor.vehicle import load_vehicle


@jit_entry
def _axpy(x, y, a: float) -> float:
    s = 0.0
    for i in range(x.shape[0]):
        y[i] += a * x[i]
        s += y[i]
    return s


def test_the_typed_entry_is_the_dispatchers_one_specialisation() -> None:
    x, y = np.array([1.0, 2.0, 3.0]), np.zeros(3)
    entry = typed_entry(_axpy, x, y, 2.0)
    got = entry(x, y, 2.0)
    np.testing.assert_array_equal(y, [2.0, 4.0, 6.0])
    assert got == 12.0
    assert _axpy(x, y, 0.5) == 15.0  # the dispatcher: the same compiled function
    if not _PURE_PYTHON:
        assert len(_axpy.signatures) == 1


def _frames(n: int):
    vehicle = load_vehicle("omnirotor")
    sim = Simulator(vehicle, "free", SimParams(), seed=3)
    p, R = sim.default_start()
    p_E = p + R @ vehicle.p_E_B_array
    traj = PoseTrajectory([Waypoint(0.0, p_E, R), Waypoint(0.05, p_E + [0.02, -0.01, 0.01], R)])
    first = sim.reset(p, R)
    ctl = InteractionController(vehicle, ControllerParams(estimator=EstimatorParams(kind="bypass")))
    ctl.reset(first, traj)
    frames, cmd = [], ctl.hold_command()
    for _ in range(n):
        frame = sim.step(cmd)
        cmd = ctl.step(frame)
        frames.append(frame)
    return vehicle, traj, first, frames


def _with_equal_dtype(frame: SensorFrame) -> SensorFrame:
    """The frame, its record's dtype an equal but distinct object (numba must type it: the dispatched path)."""
    record = frame.record
    other = np.zeros(record.shape, pickle.loads(pickle.dumps(record.dtype)))
    other[...] = record
    assert other.dtype == record.dtype and other.dtype is not record.dtype
    return SensorFrame.from_record(other)


@pytest.mark.parametrize("kind", ["ukf", "bypass"])
def test_the_typed_and_the_dispatched_step_agree_bit_for_bit(kind: str) -> None:
    vehicle, traj, first, frames = _frames(60)
    params = ControllerParams(estimator=EstimatorParams(kind=kind), log_capacity=16)  # the log grows 3 times
    typed, dispatched = InteractionController(vehicle, params), InteractionController(vehicle, params)
    typed.reset(first, traj)
    dispatched.reset(first, traj)
    n_typed = 0
    for f in frames:
        g = _with_equal_dtype(f)
        assert not dispatched._typed_arrays(g.record, dispatched._no_row)
        n_typed += typed._typed_arrays(f.record, typed._no_row)
        a, b = typed.step(f), dispatched.step(g)
        assert a.status == b.status
        np.testing.assert_array_equal(a.omega_hz, b.omega_hz)
    if not _PURE_PYTHON:
        assert n_typed == len(frames)
    np.testing.assert_array_equal(typed.log.data, dispatched.log.data)
    assert typed.log.n == dispatched.log.n == len(frames)


def test_arrays_of_other_types_never_reach_the_typed_entry() -> None:
    vehicle, traj, first, frames = _frames(3)
    ctl = InteractionController(vehicle, ControllerParams(estimator=EstimatorParams(kind="bypass")))
    ctl.reset(first, traj)
    frame_buf = ctl._frame_buf
    assert ctl._typed_arrays(frame_buf, ctl._no_row)
    readonly = np.zeros(2, ctl.log_dtype)
    readonly.flags.writeable = False
    assert not ctl._typed_arrays(frame_buf, readonly[0:1])  # a read-only log row: numba's dispatch
    assert ctl._typed_arrays(frame_buf, np.zeros(2, ctl.log_dtype)[0:1])  # a writeable one: checked once
    assert not ctl._typed_arrays(np.zeros((1, 1), frame_buf.dtype), ctl._no_row)  # another dimension
    ctl.state = ctl.state.copy()  # a state it was not made for
    assert not ctl._typed_arrays(frame_buf, ctl._no_row)
