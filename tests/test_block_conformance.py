"""Every registered controller block against the block contract (:mod:`omnirotor.blocks`, issue 11).

Parametrised over the registry (blocks of the ``omnirotor`` package; blocks registered by other test files
are theirs): each block, driven through its public ``step`` by a driver of its kind,

* conforms to the :class:`~omnirotor.blocks.Block` protocol (named, structured state with ``n_nonfinite``,
  logged fields that exist);
* runs the same twice from equal seeds, bit for bit (and differently from another seed: the check is not
  vacuous);
* returns outputs that do not alias its inputs;
* handles a non-finite input: the output stays finite, the state is not poisoned, the step is flagged;
* survives a reset: after a reset it runs exactly as a new block, with its parameters kept.

A kind without a driver fails the suite, so a new kind of block cannot escape it.
"""

from __future__ import annotations

import abc
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import omnirotor.control.controller  # noqa: F401 (imports, hence registers, every controller block)
from omnirotor.blocks import CONTROLLER_KINDS, Block, block_class, block_names, log_groups
from omnirotor.control.admittance import AdmittanceParams
from omnirotor.control.allocation import AllocationParams
from omnirotor.control.estimator import EstimatorParams
from omnirotor.control.maps import MapParams
from omnirotor.control.observer import ObserverParams
from omnirotor.control.pose import PoseControlParams
from omnirotor.control.supervisor import SupervisorParams
from omnirotor.control.trajectory import PoseTrajectory, ReferenceSample, Waypoint
from omnirotor.messages import SensorFrame, StateEstimate, new_frame
from omnirotor.regions import load_partition
from omnirotor.so3 import exp_so3
from omnirotor.vehicle import load_vehicle
from omnirotor.wrench_maps import MapEntry, WrenchMapSet

sys.path.insert(0, str(Path(__file__).parent / "reference"))
from record_controller import frame_of_flat  # noqa: E402 (the stored frames' layout)

V = load_vehicle("omnirotor")
DT = 1e-3
STEPS = 40
REFERENCE = Path(__file__).parent / "data" / "controller_reference.npz"


def _controller_blocks():
    out = []
    for kind in CONTROLLER_KINDS:
        for name in block_names(kind):
            if block_class(kind, name).__module__.startswith("omnirotor."):
                out.append((kind, name))
    return out


BLOCKS = _controller_blocks()


def _state(rng) -> StateEstimate:
    R = exp_so3(rng.normal(0.0, 0.2, 3))
    return StateEstimate(
        0.0, rng.normal(0, 0.1, 3), rng.normal(0, 0.1, 3), rng.normal(0, 0.5, 3), R, rng.normal(0, 0.3, 3)
    )


def _poison(arr: np.ndarray) -> np.ndarray:
    out = np.array(arr, dtype=float, copy=True)
    out.reshape(-1)[0] = math.nan
    return out


# -- drivers: make a block, random inputs, one step (returns the outputs), the inputs with a NaN -----------------


class _Driver(abc.ABC):
    """How to drive the blocks of one kind through their public methods."""

    @abc.abstractmethod
    def make(self, cls):
        """A block of class ``cls`` with test parameters."""

    @abc.abstractmethod
    def inputs(self, rng, k: int) -> tuple:
        """Random inputs of step ``k``."""

    @abc.abstractmethod
    def step(self, block, inputs) -> tuple:
        """One step of ``block``; returns its outputs."""

    @abc.abstractmethod
    def poisoned(self, inputs) -> tuple:
        """``inputs`` with a NaN."""

    def flagged(self, block) -> int:
        return int(block.state["n_nonfinite"][0])

    def snapshot(self, block) -> bytes:
        return block.state.tobytes()

    def reset(self, block) -> None:
        block.reset()


class _Observer(_Driver):
    def make(self, cls):
        return cls(V, ObserverParams())

    def inputs(self, rng, k):
        u = V.hover_input() * rng.uniform(0.9, 1.1, V.n_rotors)
        return _state(rng), u, V.A_nom * rng.uniform(0.95, 1.05, V.A_nom.shape)

    def step(self, block, inputs):
        st, u, A = inputs
        return block.step(st, u, A, DT)

    def poisoned(self, inputs):
        st, u, A = inputs
        return StateEstimate(st.t, st.p_W, st.v_W, _poison(st.a_W), st.R_WB, st.omega_B), u, A


class _Admittance(_Driver):
    def make(self, cls):
        return cls(AdmittanceParams.preset("PC"))

    def inputs(self, rng, k):
        return rng.normal(0, 2.0, 3), rng.normal(0, 0.3, 3)

    def step(self, block, inputs):
        block.step(*inputs, DT)
        des, out = ReferenceSample(), ReferenceSample()
        return (block.compliant_reference(des, out).data,)

    def poisoned(self, inputs):
        return _poison(inputs[0]), inputs[1]


class _Pose(_Driver):
    def make(self, cls):
        return cls(V, PoseControlParams())

    def inputs(self, rng, k):
        ref = ReferenceSample.at_rest(rng.normal(0, 0.05, 3), exp_so3(rng.normal(0, 0.1, 3)))
        return ref, _state(rng), rng.normal(0, 1.0, 3), rng.normal(0, 0.2, 3)

    def step(self, block, inputs):
        return (block.step(*inputs, DT),)

    def poisoned(self, inputs):
        ref, st, f, m = inputs
        return ref, StateEstimate(st.t, _poison(st.p_W), st.v_W, st.a_W, st.R_WB, st.omega_B), f, m


class _Allocation(_Driver):
    def make(self, cls):
        return cls(V, AllocationParams())

    def inputs(self, rng, k):
        w = np.r_[rng.normal(0, 1.0, 3) + [0, 0, V.weight], rng.normal(0, 0.1, 3)]
        return w, exp_so3(rng.normal(0, 0.1, 3)), V.A_nom

    def step(self, block, inputs):
        return (block.solve(*inputs),)

    def poisoned(self, inputs):
        return _poison(inputs[0]), inputs[1], inputs[2]

    def snapshot(self, block):
        return block.state.tobytes() + block.arrays.tobytes()


class _Maps(_Driver):
    def make(self, cls):
        part = load_partition("paper")
        rng = np.random.default_rng(3)
        regions = {
            n: MapEntry(A=V.A_nom * rng.uniform(1.0, 1.2, (6, 1)), points=10, identified=True) for n in part.names
        }
        maps = WrenchMapSet(vehicle="omnirotor", nominal=V.A_nom, partition=part, regions=regions)
        return cls(V, maps, MapParams(mode="piecewise", blend="smooth", blend_width_deg=10.0))

    def inputs(self, rng, k):
        return (exp_so3(rng.normal(0, 0.8, 3)),)

    def step(self, block, inputs):
        return (block.select(*inputs),)

    def poisoned(self, inputs):
        return (_poison(inputs[0]),)

    def snapshot(self, block):
        return block.state.tobytes() + block.arrays.tobytes()


class _Estimator(_Driver):
    """Frames recorded from the simulator (tests/data/controller_reference.npz), noise included."""

    frames = None

    def make(self, cls):
        if _Estimator.frames is None:
            _Estimator.frames = np.load(REFERENCE)["ukf_piecewise_hard/frames"]
        block = cls(V, EstimatorParams(kind=cls.name))
        block.reset(frame_of_flat(self.frames[0]))
        return block

    def inputs(self, rng, k):
        frame = frame_of_flat(self.frames[1 + k])
        imu_noise, state_noise = rng.normal(0.0, 1e-3, 6), rng.normal(0.0, 1e-4, 3)
        frame.imu_acc_B[:] += imu_noise[:3]  # IMU noise of this seed
        frame.imu_gyro_B[:] += imu_noise[3:]
        if frame.state is not None:
            frame.state.p_W[:] += state_noise  # and of the state the bypass passes through
        return (frame,)

    def step(self, block, inputs):
        est = block.step(*inputs)
        return est.p_W, est.v_W, est.a_W, est.R_WB, est.omega_B

    def poisoned(self, inputs):
        record = new_frame(inputs[0].rotor_hz.shape[0])
        inputs[0].write_record(record)
        record["imu"]["gyro_B"][0, 0] = math.nan  # gyro x
        record["state"]["p_W"][0, 0] = math.nan  # the state's p_W x
        return (SensorFrame.from_record(record),)

    def snapshot(self, block):  # the UKF's sample history and scratch are unreachable after a reset: not compared
        return block.state.tobytes()

    def reset(self, block):
        block.reset(frame_of_flat(self.frames[0]))


class _Supervisor(_Driver):
    """Frames recorded from the simulator, each checked against a random estimate near the recorded state."""

    frames = None

    def make(self, cls):
        if _Supervisor.frames is None:
            _Supervisor.frames = np.load(REFERENCE)["ukf_piecewise_hard/frames"]
        block = cls(V, SupervisorParams())
        self.reset(block)
        return block

    def reset(self, block):
        record = new_frame(V.n_rotors)
        frame_of_flat(self.frames[0]).write_record(record)
        block.reset(record, dt=DT, acc_range=160.0, gyro_range=35.0, check_state=False, check_mocap=True)

    def inputs(self, rng, k):
        frame = frame_of_flat(self.frames[1 + k])
        frame.imu_acc_B[:] += rng.normal(0.0, 1e-3, 3)  # IMU noise of this seed
        return frame, _state(rng)

    def step(self, block, inputs):
        block.step(*inputs)
        clean = block.state[0]["clean"]
        return clean["imu"]["acc_B"], clean["imu"]["gyro_B"], clean["mocap"]["p_W"], block.state[0]["dt_s"]

    def poisoned(self, inputs):
        frame, estimate = inputs
        record = new_frame(frame.rotor_hz.shape[0])
        frame.write_record(record)
        record["imu"]["gyro_B"][0, 0] = math.nan  # gyro x
        return SensorFrame.from_record(record), estimate


class _Trajectory(_Driver):
    """A three-waypoint trajectory, sampled at random times."""

    def make(self, cls):
        block = cls(8)
        R0, R1 = np.eye(3), exp_so3(np.array([0.0, 0.0, 0.5]))
        waypoints = [Waypoint(0.0, np.zeros(3), R0), Waypoint(1.0, np.ones(3), R1), Waypoint(2.0, -np.ones(3), R0)]
        block.load(PoseTrajectory(waypoints))
        return block

    def inputs(self, rng, k):
        return (rng.uniform(-0.5, 2.5),)

    def step(self, block, inputs):
        return (block.sample(inputs[0], ReferenceSample()).data,)

    def poisoned(self, inputs):
        return (math.nan,)


DRIVERS = {
    "supervisor": _Supervisor(),
    "trajectory": _Trajectory(),
    "observer": _Observer(),
    "admittance": _Admittance(),
    "pose": _Pose(),
    "allocation": _Allocation(),
    "maps": _Maps(),
    "estimator": _Estimator(),
}


def _run(driver, block, seed: int) -> list[tuple]:
    rng = np.random.default_rng(seed)
    outs = []
    for k in range(STEPS):
        outs.append(tuple(np.array(o, copy=True) for o in driver.step(block, driver.inputs(rng, k))))
    return outs


def _same(run_a, run_b) -> bool:
    return all(
        len(a) == len(b) and all(x.tobytes() == y.tobytes() for x, y in zip(a, b, strict=True))
        for a, b in zip(run_a, run_b, strict=True)
    )


def test_every_controller_kind_has_blocks_and_a_driver():
    kinds = {kind for kind, _ in BLOCKS}
    assert kinds == set(CONTROLLER_KINDS)
    assert set(DRIVERS) == set(CONTROLLER_KINDS)


@pytest.fixture(params=BLOCKS, ids=[f"{k}:{n}" for k, n in BLOCKS])
def block_case(request):
    kind, name = request.param
    return DRIVERS[kind], block_class(kind, name)


def test_block_follows_the_protocol(block_case):
    driver, cls = block_case
    block = driver.make(cls)
    assert isinstance(block, Block)
    assert block_class(cls.kind, cls.name) is cls
    assert cls.state_dtype.names is not None and "n_nonfinite" in cls.state_dtype.names
    assert block.state.dtype == cls.state_dtype and block.state.shape == (1,)
    # Its logged fields exist, are numbers, and make log groups (each under its own name or the one declared).
    groups = log_groups(cls.state_dtype, [("", cls.log_fields, getattr(cls, "log_labels", {}))])
    assert len(groups) == len(cls.log_fields)
    assert all(set(g.paths) <= set(cls.state_dtype.names) for g in groups)


def test_equal_seeds_give_equal_runs(block_case):
    driver, cls = block_case
    a, b, c = driver.make(cls), driver.make(cls), driver.make(cls)
    run_a, run_b, run_c = _run(driver, a, 7), _run(driver, b, 7), _run(driver, c, 8)
    assert _same(run_a, run_b) and driver.snapshot(a) == driver.snapshot(b)
    assert not _same(run_a, run_c)  # another seed gives another run: the comparison is not vacuous


def test_outputs_do_not_alias_inputs(block_case):
    driver, cls = block_case
    block = driver.make(cls)
    rng = np.random.default_rng(1)
    for k in range(3):
        inputs = driver.inputs(rng, k)
        arrays = [a for a in inputs if isinstance(a, np.ndarray)]
        for obj in inputs:
            if isinstance(obj, StateEstimate):
                arrays += [obj.p_W, obj.v_W, obj.a_W, obj.R_WB, obj.omega_B]
            elif isinstance(obj, ReferenceSample):
                arrays.append(obj.data)
            elif isinstance(obj, SensorFrame):
                arrays += [obj.imu_acc_B, obj.imu_gyro_B, obj.rotor_hz]
        for out in driver.step(block, inputs):
            assert not any(np.shares_memory(out, a) for a in arrays)


def test_nonfinite_input_is_handled_and_flagged(block_case):
    driver, cls = block_case
    block = driver.make(cls)
    rng = np.random.default_rng(2)
    for k in range(5):
        driver.step(block, driver.inputs(rng, k))
    before = driver.flagged(block)
    outs = driver.step(block, driver.poisoned(driver.inputs(rng, 5)))
    assert driver.flagged(block) == before + 1
    for out in outs:
        assert np.all(np.isfinite(out))
    # The state was not poisoned: the next good step gives finite outputs again.
    for out in driver.step(block, driver.inputs(rng, 6)):
        assert np.all(np.isfinite(out))


def test_state_survives_a_reset(block_case):
    driver, cls = block_case
    fresh = driver.make(cls)
    used = driver.make(cls)
    initial = driver.snapshot(fresh)
    _run(driver, used, 3)
    assert driver.snapshot(used) != initial
    driver.reset(used)
    assert driver.snapshot(used) == initial  # parameters kept, the rest as new
    assert _same(_run(driver, used, 4), _run(driver, fresh, 4))
