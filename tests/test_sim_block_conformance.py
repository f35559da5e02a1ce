"""Every block of the simulator follows the block contract (:mod:`omnirotor.blocks`).

Parametrised over the simulator's blocks (rotors, sensors, contact, faults, airflow; the aerodynamics are tested
with their model): each is registered under its kind, has its named state record, and

* equal seeds and inputs give equal runs (two fresh blocks, bit for bit);
* its outputs do not alias its inputs, and a step leaves its inputs untouched;
* non-finite input is handled as documented (held, counted, or passed on visibly; never an exception);
* after a run, ``reset`` gives back the state of a fresh block, and the run repeats exactly.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from omnirotor.blocks import Block, block_class
from omnirotor.messages import new_frame
from omnirotor.sim import AirflowParams, SimParams, Simulator
from omnirotor.sim.airflow import AirflowForce
from omnirotor.sim.contact import SENSOR_SIZE, EeContact
from omnirotor.sim.faults import FaultSchedule, faults_command
from omnirotor.sim.rotors import RotorBank
from omnirotor.sim.sensors import STATE_NOISY, Sensors, needs_refill, sense
from omnirotor.vehicle import load_vehicle

V = load_vehicle("omnirotor")
N = V.n_rotors
DT = 1e-3
STEPS = 300


@dataclasses.dataclass
class Case:
    """A block and how to drive it: ``make()`` a fresh block, ``inputs(rng, k)``, ``step(block, inputs)``."""

    kind: str
    name: str
    make: object
    inputs: object
    step: object
    nonfinite: object  # (block) -> None: feed non-finite input and check the documented handling


def _rotors_make():
    p = dataclasses.replace(SimParams().rotors, thrust_noise_rel=0.05, reversal_delay_s=0.02)  # disturbances on
    b = RotorBank(V, p, DT, seed=11)
    b.reset(np.full(N, 120.0))
    return b


def _rotors_nonfinite(b):
    before = b.omega_hz.copy()
    cmd = np.full(N, 150.0)
    cmd[[1, 4]] = np.nan
    cmd[2] = np.inf
    b.step(cmd)
    assert b.omega_hz[1] == before[1] and b.omega_hz[4] == before[4]  # a NaN command holds the speed
    assert np.all(np.isfinite(b.omega_hz)) and b.omega_hz[2] <= V.omega_max_hz  # inf is clipped


def _sensors_make():
    p = dataclasses.replace(SimParams().sensors, state_pos_noise_std=0.01, state_att_noise_std=0.01)
    b = Sensors(p, V.gravity, DT, N, STATE_NOISY, seed=7)
    b.reset(np.array([0.1, 0.2, 1.0]), np.array([1.0, 0.0, 0.0, 0.0]))
    return b


def _sensors_inputs(rng, k):
    q = np.r_[1.0, rng.normal(0.0, 0.05, 3)]
    return {
        "pose": np.r_[rng.normal(0.0, 0.1, 3), q / np.linalg.norm(q)],
        "vel": rng.normal(0.0, 0.1, 6),
        "acc": rng.normal(0.0, 0.1, 6),
        "R9": np.eye(3).ravel().copy(),
        "omega_hz": rng.uniform(100.0, 150.0, N),
        "k": k,
        "frame": new_frame(N)[0],
    }


def _sensors_step(b, x):
    b.refill()
    assert not needs_refill(b.state[0])
    sense(b.state[0], x["pose"], x["vel"], x["acc"], x["R9"], x["omega_hz"], x["k"], x["k"] * DT, x["frame"])
    return x["frame"]


def _sensors_nonfinite(b):
    x = _sensors_inputs(np.random.default_rng(0), 1)
    x["acc"][:] = np.nan
    frame = _sensors_step(b, x)
    assert np.all(np.isnan(frame["imu"]["acc_B"]))  # passed on visibly, for the controller to flag
    assert np.all(np.isfinite(frame["rotor_hz"]))  # and nowhere else


def _contact_model():
    sim = Simulator(V, "wall", seed=0)
    return sim.model


_MODEL = None


def _contact_make():
    global _MODEL
    if _MODEL is None:
        _MODEL = _contact_model()
    return EeContact(_MODEL)


def _contact_inputs(rng, k):
    sd = np.zeros(_MODEL.nsensordata)
    b = EeContact(_MODEL)
    for a in b.par["sensor_adr"][0]:
        if a >= 0:
            sd[a] = float(rng.integers(0, 3))
            sd[a + 1 : a + SENSOR_SIZE] = rng.normal(0.0, 2.0, SENSOR_SIZE - 1)
    return {"sensordata": sd, "p_E_W": rng.normal(0.0, 0.5, 3)}


def _contact_step(b, x):
    b.step(x["sensordata"], x["p_E_W"])
    return b.state


def _contact_nonfinite(b):
    x = _contact_inputs(np.random.default_rng(1), 0)
    a = int(b.par["sensor_adr"][0, 0])
    x["sensordata"][a] = 1.0
    x["sensordata"][a + 1] = np.nan
    b.step(x["sensordata"], x["p_E_W"])
    s = b.state[0]
    assert s["in_contact"] and np.isnan(s["f_W"][0])  # a NaN force shows, it is not dropped


def _faults_make():
    b = FaultSchedule(N, float(V.omega_min_hz), float(V.omega_max_hz))
    b.add_rotor_failure(2, 0.1, None)
    b.add_gust(0.05, 0.1, (1.0, 2.0, 3.0), (0.0, 0.0, 0.1), "1-cos")
    b.add_corruption("imu_gyro", "spike", 0.02, 0.05, 0.3, None)
    b.reset()
    return b


def _faults_inputs(rng, k):
    return {"cmd": rng.uniform(-50.0, 250.0, N), "k": k}


def _faults_step(b, x):
    return faults_command(b.state[0], x["k"] * DT, x["cmd"])


def _faults_nonfinite(b):
    cmd = np.full(N, 100.0)
    cmd[0] = np.nan
    out = faults_command(b.state[0], 0.0, cmd)
    assert b.commands_nonfinite == 1 and np.isnan(out[0])  # counted, and passed on (the rotor holds)
    cmd[0] = np.inf
    faults_command(b.state[0], 0.0, cmd)
    assert b.commands_nonfinite == 2


def _airflow_make():
    return AirflowForce(AirflowParams(force_std=1.0, corner_hz=2.0), DT, seed=11)


def _airflow_step(b, x):
    b.step()
    return b.state


def _airflow_nonfinite(b):
    b.step()  # it has no input: its force stays finite
    assert np.all(np.isfinite(b.f_W)) and np.any(b.f_W != 0.0)


CASES = [
    Case("rotors", "first-order-lag", _rotors_make, lambda rng, k: {"cmd": rng.uniform(-250, 250, N)},
         lambda b, x: b.step(x["cmd"]) or b.state, _rotors_nonfinite),
    Case("sensors", "imu-mocap", _sensors_make, _sensors_inputs, _sensors_step, _sensors_nonfinite),
    Case("contact", "ee-sensors", _contact_make, _contact_inputs, _contact_step, _contact_nonfinite),
    Case("faults", "schedule", _faults_make, _faults_inputs, _faults_step, _faults_nonfinite),
    Case("airflow", "recirculation", _airflow_make, lambda rng, k: {}, _airflow_step, _airflow_nonfinite),
]  # fmt: skip


def _run(case: Case, block, seed: int = 3) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    trace = []
    for k in range(STEPS):
        x = case.inputs(rng, k)
        frozen = {key: np.copy(v) for key, v in x.items() if isinstance(v, np.ndarray) and key != "frame"}
        out = case.step(block, x)
        for key, v in frozen.items():
            np.testing.assert_array_equal(x[key], v)  # inputs untouched
            assert not np.shares_memory(np.asarray(out), x[key])  # outputs do not alias inputs
            assert not np.shares_memory(block.state, x[key])
        trace.append(np.array(out, copy=True))
        trace.append(block.state.copy())
    return trace


@pytest.fixture(params=CASES, ids=lambda c: c.kind)
def case(request) -> Case:
    return request.param


def test_block_is_registered_and_declares_its_state(case):
    block = case.make()
    assert block_class(case.kind, case.name) is type(block)
    assert isinstance(block, Block)
    assert block.kind == case.kind and block.name == case.name
    assert block.state.shape == (1,) and block.state.dtype == block.state_dtype
    assert set(block.log_fields) <= set(block.state_dtype.names)


def test_equal_seeds_give_equal_runs(case):
    a, b = _run(case, case.make()), _run(case, case.make())
    assert len(a) == len(b) == 2 * STEPS
    for x, y in zip(a, b, strict=True):
        assert x.tobytes() == y.tobytes()


def test_nonfinite_input_is_handled(case):
    case.nonfinite(case.make())


def test_state_survives_a_reset(case):
    fresh = case.make()
    block = case.make()
    first = _run(case, block)
    block.reset()
    assert block.state.tobytes() == fresh.state.tobytes()
    again = _run(case, block)
    for x, y in zip(first, again, strict=True):
        assert x.tobytes() == y.tobytes()


def test_the_simulator_composes_the_blocks_in_its_record():
    sim = Simulator(V, "free", seed=0)
    rec = sim.kernel_state
    for block in (sim.rotors, sim.sensors, sim.faults, sim.airflow):
        assert np.shares_memory(block.state, rec)
    assert np.shares_memory(sim.contact.par, rec)
    assert not np.shares_memory(sim.frame_record, rec)
    assert mujoco.mj_name2id(sim.model, mujoco.mjtObj.mjOBJ_BODY, "vehicle") >= 0
