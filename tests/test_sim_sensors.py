"""Sensors, noise seeding and the bypass state of the simulator."""

import dataclasses

import numpy as np
import pytest

from omnirotor.messages import RotorCommand
from omnirotor.sim import AeroParams, SceneParams, SensorParams, SimParams, Simulator
from omnirotor.so3 import R_from_quat_wxyz, log_so3
from omnirotor.vehicle import load_vehicle

V = load_vehicle("omnirotor")
QUIET = SensorParams(
    **{name: 0.0 for name in SensorParams.__dataclass_fields__ if name.endswith("_std") or name.endswith("_std_hz")}
)


def hover_frames(sim, steps):
    cmd = RotorCommand(0.0, sim.hover_speeds_hz(sim.truth.R_WB))
    return [sim.step(cmd) for _ in range(steps)]


@pytest.mark.parametrize(("rate", "latency"), [(100.0, 0.004), (120.0, 0.010), (250.0, 0.0)])
def test_mocap_rate_latency_and_time_stamps(rate, latency):
    sp = dataclasses.replace(QUIET, mocap_rate_hz=rate, mocap_latency_s=latency)
    sim = Simulator(V, "free", SimParams(aero=AeroParams(model="nominal"), sensors=sp).undisturbed())
    first = sim.reset()
    assert first.mocap_new  # at rest before t = 0: the pipeline is already full
    assert first.mocap_t <= -latency + 1e-12
    frames = hover_frames(sim, 1000)
    got = [f for f in frames if f.mocap_new]
    stamps = np.array([f.mocap_t for f in got])
    arrivals = np.array([f.t for f in got])
    # Latency: delivered exactly one (rounded) latency after the sample was taken.
    np.testing.assert_allclose(arrivals - stamps, round(latency / 1e-3) * 1e-3, atol=1e-9)
    # Rate: on average 1/rate apart, never more than one step of jitter.
    gaps = np.diff(stamps)
    assert np.mean(gaps) == pytest.approx(1.0 / rate, rel=0.01)
    assert np.all(np.abs(gaps - 1.0 / rate) <= 1e-3 + 1e-9)
    assert len(got) == pytest.approx(rate, abs=2)
    # Sample time stamps are the times of the poses they carry (no noise here, the vehicle hovers).
    np.testing.assert_allclose(got[-1].mocap_p_W, sim.truth.p_W, atol=1e-9)
    assert all(f.mocap_p_W is None for f in frames if not f.mocap_new)


def test_mocap_sample_carries_the_delayed_pose():
    sp = dataclasses.replace(QUIET, mocap_latency_s=0.02)
    sim = Simulator(V, "free", SimParams(aero=AeroParams(model="nominal"), sensors=sp).undisturbed())
    sim.reset()
    sim.set_external_wrench([0.0, 0.0, 3.0], at="com")  # accelerate upwards, so poses differ in time
    cmd = RotorCommand(0.0, sim.hover_speeds_hz())
    history = {}
    for _ in range(300):
        f = sim.step(cmd)
        history[round(f.t, 6)] = sim.truth.p_W.copy()
        if f.mocap_new and f.mocap_t > 0:
            np.testing.assert_allclose(f.mocap_p_W, history[round(f.mocap_t, 6)], atol=1e-12)


def test_mocap_noise_level():
    sp = dataclasses.replace(QUIET, mocap_pos_noise_std=1e-3, mocap_att_noise_std=2e-3)
    sim = Simulator(V, "free", SimParams(aero=AeroParams(model="nominal"), sensors=sp).undisturbed(), seed=5)
    p_true = sim.truth.p_W.copy()
    frames = [f for f in hover_frames(sim, 4000) if f.mocap_new]
    dp = np.array([f.mocap_p_W - p_true for f in frames])
    dth = np.array([log_so3(sim.truth.R_WB.T @ R_from_quat_wxyz(f.mocap_q_WB)) for f in frames])
    assert np.std(dp) == pytest.approx(1e-3, rel=0.1)
    assert np.std(dth) == pytest.approx(2e-3, rel=0.1)
    assert np.abs(np.mean(dp)) < 3e-4


def test_imu_bias_and_noise_statistics():
    sp = SensorParams(acc_noise_std=0.1, acc_bias_std=0.05, gyro_noise_std=0.005, gyro_bias_std=0.002)
    sim = Simulator(V, "free", SimParams(aero=AeroParams(model="nominal"), sensors=sp).undisturbed(), seed=2)
    frames = hover_frames(sim, 4000)
    acc = np.array([f.imu_acc_B for f in frames]) - [0, 0, V.gravity]  # at rest, upright: true reading +g z
    gyro = np.array([f.imu_gyro_B for f in frames])
    np.testing.assert_allclose(acc.mean(axis=0), sim.imu.acc_bias_B, atol=4 * 0.1 / np.sqrt(4000))
    np.testing.assert_allclose(gyro.mean(axis=0), sim.imu.gyro_bias_B, atol=4 * 0.005 / np.sqrt(4000))
    np.testing.assert_allclose(acc.std(axis=0), 0.1, rtol=0.06)
    np.testing.assert_allclose(gyro.std(axis=0), 0.005, rtol=0.06)
    # Samples are white: no correlation between consecutive ones.
    a = acc[:, 0] - acc[:, 0].mean()
    assert abs(a[1:] @ a[:-1] / (a @ a)) < 0.06
    # The biases are drawn per seed with the set spread (24 draws of 3 axes).
    biases = np.array(
        [Simulator(V, "free", SimParams(sensors=sp).undisturbed(), seed=s).imu.acc_bias_B for s in range(24)]
    )
    assert np.std(biases) == pytest.approx(0.05, rel=0.3)


def test_imu_lever_arm_terms():
    """An IMU 4.1 cm above the CoM reads the centripetal and tangential accelerations of a spinning body."""
    r = np.array([0.0, 0.0, 0.041])
    runs = []
    for offset in ((0.0, 0.0, 0.0), tuple(r)):
        sp = dataclasses.replace(QUIET, imu_offset_B=offset)
        sim = Simulator(V, "free", SimParams(aero=AeroParams(model="nominal"), sensors=sp).undisturbed())
        sim.reset()
        sim.set_external_wrench([0.0, 0.0, 0.0], m_W=[0.02, 0.01, 0.0], at="com")
        runs.append((sim, hover_frames(sim, 300)[-1]))
    (sim, f0), (_, f1) = runs
    w = sim.truth.omega_B
    w_dot = sim.data.qacc[3:6]
    expect = np.cross(w_dot, r) + np.cross(w, np.cross(w, r))
    assert np.linalg.norm(expect) > 0.01
    np.testing.assert_allclose(f1.imu_acc_B - f0.imu_acc_B, expect, atol=1e-9)


def test_same_seed_same_run_different_seed_different_noise():
    def frames(seed):
        sim = Simulator(V, "wall", SimParams(), seed=seed)
        return [sim.reset()] + hover_frames(sim, 60)

    a, b, c = frames(7), frames(7), frames(8)
    for fa, fb in zip(a, b, strict=True):
        np.testing.assert_array_equal(fa.imu_acc_B, fb.imu_acc_B)
        np.testing.assert_array_equal(fa.imu_gyro_B, fb.imu_gyro_B)
        np.testing.assert_array_equal(fa.rotor_hz, fb.rotor_hz)
        np.testing.assert_array_equal(fa.state.p_W, fb.state.p_W)
        np.testing.assert_array_equal(fa.state.R_WB, fb.state.R_WB)
        assert fa.mocap_new == fb.mocap_new
        if fa.mocap_new:
            np.testing.assert_array_equal(fa.mocap_p_W, fb.mocap_p_W)
            np.testing.assert_array_equal(fa.mocap_q_WB, fb.mocap_q_WB)
    assert not np.array_equal(a[-1].imu_acc_B, c[-1].imu_acc_B)
    assert not np.array_equal(a[-1].rotor_hz, c[-1].rotor_hz)
    assert not np.array_equal(a[-1].state.p_W, c[-1].state.p_W)


def test_reset_repeats_the_run():
    sim = Simulator(V, "pipe", SimParams(), seed=3)
    run1 = [sim.reset()] + hover_frames(sim, 30)
    run2 = [sim.reset()] + hover_frames(sim, 30)
    for f1, f2 in zip(run1, run2, strict=True):
        np.testing.assert_array_equal(f1.imu_acc_B, f2.imu_acc_B)
        np.testing.assert_array_equal(f1.state.v_W, f2.state.v_W)


def test_frames_own_their_arrays():
    sim = Simulator(V, "free", SimParams(), seed=0)
    f1 = sim.step(RotorCommand(0.0, sim.hover_speeds_hz()))
    keep = [f1.imu_acc_B.copy(), f1.rotor_hz.copy(), f1.state.p_W.copy(), f1.state.R_WB.copy()]
    f2 = sim.step(RotorCommand(0.0, sim.hover_speeds_hz()))
    for before, after in zip(keep, [f1.imu_acc_B, f1.rotor_hz, f1.state.p_W, f1.state.R_WB], strict=True):
        np.testing.assert_array_equal(before, after)
    for x in (f2.state.p_W, f2.state.v_W, f2.state.R_WB, f2.rotor_hz):
        assert not np.shares_memory(x, sim.data.qpos) and not np.shares_memory(x, sim.data.xmat)
        assert not np.shares_memory(x, sim.rotors.omega_hz)
    t = sim.truth
    assert not np.shares_memory(t.p_W, sim.data.qpos) and not np.shares_memory(t.rotor_hz, sim.rotors.omega_hz)


def test_state_is_exact_truth_without_noise_and_noisy_with_it():
    # a rigid tool: a_W below is the rigid body's (the compliant tool lags the push by ~1e-7 m/s²)
    sim = Simulator(V, "free", SimParams(sensors=QUIET, scene=SceneParams(tool_compliant=False)).undisturbed(), seed=0)
    sim.set_external_wrench([0.3, 0.0, 0.0], m_W=[0.0, 0.01, 0.0], at="com")
    f = hover_frames(sim, 100)[-1]
    tr = sim.truth
    for name in ("p_W", "v_W", "a_W", "R_WB", "omega_B"):
        np.testing.assert_array_equal(getattr(f.state, name), getattr(tr, name))
    assert f.state.t == tr.t == f.t
    # a_W is the true CoM acceleration p_ddot, without gravity.
    np.testing.assert_allclose(tr.a_W, (tr.R_WB @ tr.rotor_wrench_B[:3] + [0.3, 0, -V.weight]) / V.mass, atol=1e-9)

    noisy = Simulator(V, "free", SimParams().undisturbed(), seed=0)
    cmd = RotorCommand(0.0, noisy.hover_speeds_hz())
    errs = []
    for _ in range(500):
        f = noisy.step(cmd)
        errs.append(f.state.p_W - noisy.truth.p_W)
        R_err = noisy.truth.R_WB.T @ f.state.R_WB
        assert np.linalg.norm(R_err.T @ R_err - np.eye(3)) < 1e-12  # still a rotation
    assert np.std(errs) == pytest.approx(noisy.params.sensors.state_pos_noise_std, rel=0.15)
    assert Simulator(V, "free", SimParams(provide_state=False)).step(RotorCommand(0.0, np.zeros(8))).state is None
