"""The simulator's compiled step (``sim.step.sim_step``, MuJoCo called from compiled code) and its parts.

* the whole compiled step gives bit for bit the frames and truth rows of the same step run from Python
  (``mj_Euler`` / ``mj_forward`` through the bindings, the rotor and truth models' own methods);
* the truth row's contact wrench, from MuJoCo's contact sensors, equals the sum over the contacts by
  ``mj_contactForce`` (an oracle written here) with several EE contacts on both EE geoms at once, and the
  :class:`GroundTruth` record gives the same;
* the frame record round-trips through :class:`SensorFrame`;
* the compiled clock agrees with ``time.perf_counter_ns``;
* the step's cost cuts change no number: the constraint solver without islands steps bit for bit as with them,
  the step puts MuJoCo's profiler clock back as it found it, and allocates nothing per physics step.
"""

import copy
import ctypes
import time

import mujoco
import numba
import numpy as np
import pytest

from omnirotor._jit import monotonic_ns, mujoco_timer_address
from omnirotor.messages import RotorCommand, SensorFrame, StateEstimate, new_frame
from omnirotor.sim import SimParams, Simulator
from omnirotor.sim.model import EE_ROD_GEOM, EE_TIP_GEOM, ROD_RADIUS, TOOL_BODY
from omnirotor.so3 import exp_so3
from omnirotor.vehicle import load_vehicle

V = load_vehicle("omnirotor")


def _rotation_taking(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A rotation matrix R with R a = b (unit vectors, not opposite)."""
    axis = np.cross(a, b)
    angle = np.arctan2(np.linalg.norm(axis), a @ b)
    return exp_so3(axis / np.linalg.norm(axis) * angle)


def _pressed_on_wall(sim: Simulator) -> None:
    """Reset with the EE rod parallel to the wall, tip and rod sunk into it, and a force pushing it in."""
    n_W = sim.scene.normal_W
    d_B = V.p_E_B_array / np.linalg.norm(V.p_E_B_array)
    tangent = np.cross(n_W, [0.0, 0.0, 1.0])
    R = _rotation_taking(d_B, tangent / np.linalg.norm(tangent))
    p_E = sim.scene.surface_point_W + (ROD_RADIUS - 0.001) * n_W  # the rod's axis 1 mm closer than its radius
    sim.reset(p_E - R @ V.p_E_B_array, R)
    sim.set_external_wrench(-4.0 * n_W, at="com")


def test_compiled_step_equals_the_step_run_from_python():
    fused = Simulator(V, "wall", seed=4)
    plain = Simulator(V, "wall", seed=4)
    plain._fused_aero = None  # no kernel for this truth model as far as step() knows: the Python path
    assert fused.kernel_state is not None and plain.kernel_state is None
    for sim in (fused, plain):
        _pressed_on_wall(sim)  # a reset in contact: the compiled reset pass (fused) against the Python one
    for name in ("qacc", "xfrc_applied", "sensordata"):
        np.testing.assert_array_equal(getattr(fused.data, name), getattr(plain.data, name))
    assert fused.contact.friction[0]["n"].sum() > 0  # the tool's friction law found the contacts at reset
    rng = np.random.default_rng(0)
    rows = np.zeros((2, 40))
    contact_steps = 0
    for k in range(400):
        cmd = RotorCommand(k * 1e-3, fused.hover_speeds_hz() * (1.0 + 0.05 * rng.standard_normal(8)))
        frames = [fused.step(cmd), plain.step(cmd)]
        fused.truth_row(rows[0])
        plain.truth_row(rows[1])
        records = [new_frame(8), new_frame(8)]
        frames[0].write_record(records[0])
        frames[1].write_record(records[1])
        assert records[0].tobytes() == records[1].tobytes()
        np.testing.assert_array_equal(rows[0], rows[1])
        contact_steps += rows[0, 28] > 0.5
    np.testing.assert_array_equal(fused.data.qpos, plain.data.qpos)
    assert contact_steps > 100  # the comparison covered contact


def _contact_wrench_by_contact_force(sim: Simulator, p_E_W: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Oracle: the environment's force on the EE geoms and its moment about ``p_E_W``, contact by contact.

    MuJoCo's contact forces (frictionless for the compliant tool's geoms) plus the tool's friction forces.

    The robot's geoms are those of the bodies whose root is the vehicle body (the vehicle and its tool).
    """
    m, d = sim.model, sim.data
    body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "vehicle")
    ee = {mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, g) for g in (EE_TIP_GEOM, EE_ROD_GEOM)}
    force, moment, touching = np.zeros(3), np.zeros(3), False
    f6 = np.zeros(6)
    for c in range(d.ncon):
        g1, g2 = d.contact.geom1[c], d.contact.geom2[c]
        # the robot's geoms: the vehicle body's and its child tool body's (the compliant tool's rod and tip)
        r1, r2 = m.body_rootid[m.geom_bodyid[g1]] == body, m.body_rootid[m.geom_bodyid[g2]] == body
        if r1 == r2 or (g1 if r1 else g2) not in ee:
            continue
        touching = True
        mujoco.mj_contactForce(m, d, c, f6)  # on geom2, in the contact frame (rows of the frame)
        F = d.contact.frame[c].reshape(3, 3)
        sign = -1.0 if r1 else 1.0
        f_W = sign * (F.T @ f6[:3])
        force += f_W
        moment += sign * (F.T @ f6[3:]) + np.cross(d.contact.pos[c] - p_E_W, f_W)
    # the compliant tool's friction is a force the simulator applies (omnirotor.sim.contact.friction_step)
    fr = sim.contact.friction[0]
    for g in range(fr["n"].shape[0]):
        for k in range(fr["n"][g]):
            force += fr["f"][g, k]
            moment += np.cross(fr["pos"][g, k] - p_E_W, fr["f"][g, k])
    return force, moment, touching


def test_contact_sensors_give_the_summed_contact_wrench_with_several_contacts():
    sim = Simulator(V, "wall", SimParams(), seed=2)
    _pressed_on_wall(sim)
    m, d = sim.model, sim.data
    ee = {mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, g) for g in (EE_TIP_GEOM, EE_ROD_GEOM)}
    # the default (compliant) tool: the EE geoms sit on the vehicle's child body, not on the vehicle body
    assert {int(m.geom_bodyid[g]) for g in ee} == {mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, TOOL_BODY)}
    row = np.zeros(40)
    cmd = RotorCommand(0.0, sim.hover_speeds_hz())
    most, both = 0, False
    for _ in range(60):
        sim.step(cmd)
        sim.truth_row(row)
        tr = sim.truth
        f, mo, touching = _contact_wrench_by_contact_force(sim, tr.p_E_W)
        geoms = [g for c in range(d.ncon) for g in (d.contact.geom1[c], d.contact.geom2[c]) if g in ee]
        most = max(most, len(geoms))
        both |= len(set(geoms)) == 2
        np.testing.assert_allclose(row[22:25], f, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(row[25:28], mo, rtol=1e-12, atol=1e-12)
        assert (row[28] == 1.0) == touching == tr.in_contact
        np.testing.assert_array_equal(tr.contact_force_W, row[22:25])
        np.testing.assert_array_equal(tr.contact_moment_W, row[25:28])
    assert most >= 2 and both  # several EE contacts at once, on the tip and on the rod
    assert np.linalg.norm(tr.contact_force_W) > 1.0


def test_frame_record_round_trips_through_the_message():
    sim = Simulator(V, "free", seed=1)
    frame = sim.reset()
    assert frame.mocap_new and frame.state is not None
    buf = new_frame(V.n_rotors)
    frame.write_record(buf)
    assert buf.tobytes() == sim.frame_record.tobytes()
    back = SensorFrame.from_record(buf)
    for name in ("imu_acc_B", "imu_gyro_B", "rotor_hz", "mocap_p_W", "mocap_q_WB"):
        np.testing.assert_array_equal(getattr(back, name), getattr(frame, name))
    np.testing.assert_array_equal(back.state.R_WB, frame.state.R_WB)
    assert back.t == frame.t and back.mocap_t == frame.mocap_t
    buf["imu"]["acc_B"][0, 2] = 99.0
    assert back.imu_acc_B[2] != 99.0  # the message owns a copy
    bare = SensorFrame(0.5, np.ones(3), np.zeros(3), np.full(8, 140.0))
    bare.write_record(buf)
    again = SensorFrame.from_record(buf)
    assert not again.mocap_new and again.mocap_p_W is None and again.state is None and again.t == 0.5
    s = StateEstimate(0.5, np.ones(3), np.zeros(3), np.zeros(3), np.eye(3), np.zeros(3))
    SensorFrame(0.5, np.ones(3), np.zeros(3), np.full(8, 140.0), state=s).write_record(buf)
    np.testing.assert_array_equal(SensorFrame.from_record(buf).state.p_W, np.ones(3))
    assert buf["state"]["valid"][0] == 1.0 and buf["mocap"]["new"][0] == 0.0 and not np.any(buf["mocap"]["p_W"])


def test_compiled_clock_is_the_monotonic_clock():
    ts = np.zeros(2, dtype=np.int64)
    monotonic_ns(ts)
    before = time.perf_counter_ns()
    mid = monotonic_ns(ts)
    after = time.perf_counter_ns()
    assert before <= mid <= after


def test_pure_python_mode_flies_the_same_run():
    """``NUMBA_DISABLE_JIT=1`` runs the kernels as Python, MuJoCo's C step through ctypes: the same numbers."""
    import json
    import os
    import subprocess
    import sys

    code = (
        "import json\n"
        "from omnirotor.experiments.loop import TaskOptions\n"
        "from omnirotor.experiments.tasks import run_task\n"
        "r = run_task('hover', TaskOptions(duration_s=0.2, seed=3))\n"
        "print(json.dumps(r.truth_log.data[: r.truth_log.n, :-2].tolist()))\n"
    )
    runs = []
    for disable in ("0", "1"):
        env = dict(os.environ, NUMBA_DISABLE_JIT=disable)
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        runs.append(np.array(json.loads(out.stdout.strip().splitlines()[-1])))
    np.testing.assert_array_equal(runs[0], runs[1])
    assert np.ptp(runs[0][:, 3]) > 1e-6  # the body moved: MuJoCo really stepped in both modes


def test_solver_without_islands_steps_bit_for_bit_as_with_them():
    """The model disables MuJoCo's constraint islands (a cost, no physics): the same contact run either way."""
    sim = Simulator(V, "wall", seed=2)
    _pressed_on_wall(sim)
    assert sim.model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_ISLAND
    with_islands = copy.copy(sim.model)
    with_islands.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_ISLAND)
    runs = []
    for m in (sim.model, with_islands):
        d = copy.copy(sim.data)
        rows = []
        for _ in range(300):
            mujoco.mj_step(m, d)
            rows.append(np.concatenate([d.qpos, d.qvel, d.sensordata]))
        runs.append(np.array(rows))
    np.testing.assert_array_equal(runs[0], runs[1])
    in_contact = runs[0][:, sim.model.nq + sim.model.nv] > 0  # the tip's contact sensor found contacts
    assert np.count_nonzero(in_contact) > 200  # of 300 steps (265: the tip bounces once)


def test_step_restores_mujocos_profiler_clock_and_does_not_feed_it():
    sim = Simulator(V, "wall", seed=1)
    clock = ctypes.c_void_p.from_address(mujoco_timer_address())
    before = clock.value
    assert before  # the bindings installed their clock with the MjData
    cmd = RotorCommand(0.0, sim.hover_speeds_hz())
    sim.step(cmd)
    spent = sim.data.timer[int(mujoco.mjtTimer.mjTIMER_FORWARD)].duration
    for _ in range(20):
        sim.step(cmd)
    assert clock.value == before
    assert sim.data.timer[int(mujoco.mjtTimer.mjTIMER_FORWARD)].duration == spent  # stepped without the clock
    mujoco.mj_forward(sim.model, sim.data)  # a call from Python still feeds the profile
    spent_python = sim.data.timer[int(mujoco.mjtTimer.mjTIMER_FORWARD)].duration
    assert spent_python > spent
    sim.kernel_state["mj"]["timer"] = 0  # no address: the step leaves the clock alone, MuJoCo profiles it
    sim.step(cmd)
    assert sim.data.timer[int(mujoco.mjtTimer.mjTIMER_FORWARD)].duration > spent_python
    assert clock.value == before


@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="NUMBA_DISABLE_JIT=1: kernels run as Python, no numba allocator")
def test_step_allocates_nothing_per_physics_step():
    """Four physics steps per period allocate what one does (the call's argument unboxing from Python only)."""
    from numba.core.runtime import _nrt_python, rtsys

    counts = {}
    was_enabled = _nrt_python.memsys_stats_enabled()
    _nrt_python.memsys_enable_stats()
    try:
        for substeps in (1, 4):
            sim = Simulator(V, "wall", SimParams(substeps=substeps), seed=1)
            _pressed_on_wall(sim)
            cmd = RotorCommand(0.0, sim.hover_speeds_hz())
            sim.step(cmd)
            before = rtsys.get_allocation_stats()
            for _ in range(50):
                sim.step(cmd)
            after = rtsys.get_allocation_stats()
            counts[substeps] = after.alloc - before.alloc
            assert sim.truth.in_contact
    finally:
        if not was_enabled:
            _nrt_python.memsys_disable_stats()
    assert counts[1] == counts[4], counts
