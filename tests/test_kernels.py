"""The compiled kernels of the 1 kHz loop against reference implementations, and the fast paths around them.

* the controller's compiled step gives the same commands and log as the blocks' own public methods
  composed by hand;
* small kernels (SO(3), Cholesky, inverse, quaternion perturbation, the interference truth) agree with
  NumPy / Python float references;
* the simulator's flat truth row is the :class:`GroundTruth` record in the layout of the closed loop's
  truth log, contact included;
* a block accepts a caller's buffer for its packed state, and rejects a wrong one;
* the messages stay frozen dataclasses with their signatures;
* ``Recorder.next_row`` hands out rows and counts drops.
"""

import dataclasses
import math

import numpy as np
import pytest

from omnirotor.control import _estimator_kernels as ek
from omnirotor.control.admittance import AdmittanceFilter, body_reference_from_ee, ee_wrench_W
from omnirotor.control.controller import ControllerParams, InteractionController
from omnirotor.control.estimator import EstimatorParams
from omnirotor.control.observer import WrenchObserver
from omnirotor.control.pose import PoseController
from omnirotor.control.trajectory import PoseTrajectory, ReferenceSample, Waypoint
from omnirotor.errors import InputError
from omnirotor.experiments.loop import TRUTH_GROUPS
from omnirotor.messages import ControlStatus, RotorCommand, SensorFrame, StateEstimate
from omnirotor.recorder import Recorder
from omnirotor.sim import SimParams, Simulator
from omnirotor.sim.aero import InterferenceAero
from omnirotor.sim.params import AeroParams
from omnirotor.so3 import (
    R9_from_quat_into,
    R_from_quat_wxyz,
    exp_so3,
    exp_so3_into,
    log_so3,
    log_so3_into,
    quat_perturb_into,
    rot_x,
    rot_z,
)
from omnirotor.vehicle import load_vehicle

V = load_vehicle("omnirotor")
DT = 1e-3
OBS_FLOATS = 69


def _random_rotation(rng):
    return exp_so3(rng.uniform(-1.0, 1.0, 3))


def _frames(n, seed=0):
    """Frames of a simulated hover with a small move, flown by a bypass controller."""
    sim = Simulator(V, "free", SimParams().undisturbed(), seed=seed)
    p, R = sim.default_start()
    p_E = p + R @ V.p_E_B_array
    traj = PoseTrajectory([Waypoint(0.0, p_E, R), Waypoint(n * DT, p_E + [0.04, -0.02, 0.03], rot_z(0.2) @ R)])
    ctl = InteractionController(V, ControllerParams(estimator=EstimatorParams(kind="bypass"), log_capacity=n))
    first = sim.reset(p, R)
    ctl.reset(first, traj)
    cmd = ctl.hold_command()
    frames = []
    for _ in range(n):
        frame = sim.step(cmd)
        cmd = ctl.step(frame)
        frames.append(frame)
    return traj, first, frames


def _jittered(first, frames, jitter: float, seed: int = 7):
    """The frames re-timed: periods drawn uniformly in ``DT (1 ± jitter)``; the periods too."""
    if jitter == 0.0:
        return frames, [DT] * len(frames)
    periods = DT * (1.0 + jitter * np.random.default_rng(seed).uniform(-1.0, 1.0, len(frames)))
    times = first.t + np.cumsum(periods)
    out = [dataclasses.replace(f, t=float(t)) for f, t in zip(frames, times, strict=True)]
    return out, list(np.diff(np.r_[first.t, times]))


@pytest.mark.parametrize("jitter", [0.0, 0.4], ids=["even", "jittered"])
def test_fused_controller_step_equals_the_blocks_composed_by_hand(jitter):
    """The compiled step is the blocks composed; with jittered frames, each block integrates the real interval.

    ``jittered``: periods of 0.6 to 1.4 ms (a real loop's jitter); the blocks stepped by hand take those exact
    periods (issue 24 item 2).
    """
    traj, first, frames = _frames(300)
    frames, periods = _jittered(first, frames, jitter)
    ctl = InteractionController(V, ControllerParams(estimator=EstimatorParams(kind="bypass"), log_capacity=400))
    ctl.reset(first, traj)
    # The same blocks, stepped one by one through their public methods.
    obs, adm, pose = WrenchObserver(V), AdmittanceFilter(), PoseController(V)
    from omnirotor.control.allocation import Allocator

    alloc = Allocator(V)
    des, comp, body = ReferenceSample(), ReferenceSample(), ReferenceSample()
    f_E, m_E = np.zeros(3), np.zeros(3)
    p_E_B = V.p_E_B_array
    for frame, dt in zip(frames, periods, strict=True):
        cmd = ctl.step(frame)
        st = frame.state
        u_obs = np.abs(frame.rotor_hz) * frame.rotor_hz
        f_hat, m_hat = obs.step(st, u_obs, V.A_nom, dt)
        ee_wrench_W(f_hat, m_hat, st.R_WB, p_E_B, f_E, m_E)
        adm.step(f_E, m_E, dt)
        traj.sample(frame.t - first.t, des)
        adm.compliant_reference(des, comp)
        body_reference_from_ee(comp, p_E_B, body)
        w_ref = pose.step(body, st, obs.f_filt_W, obs.m_filt_B, dt)
        u = alloc.solve(w_ref, st.R_WB, V.A_nom)
        omega = np.clip(np.sign(u) * np.sqrt(np.abs(u)), V.omega_min_hz, V.omega_max_hz)
        np.testing.assert_allclose(cmd.omega_hz, omega, rtol=1e-12, atol=1e-9)
        assert bool(cmd.status & ControlStatus.SATURATED) == alloc.saturated
        assert not cmd.status & ControlStatus.FRAME_REJECTED
    np.testing.assert_allclose(ctl.observer.output, obs.output, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(ctl.admittance.xi_p_W, adm.xi_p_W, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(ctl.body_ref.data, body.data, rtol=1e-12, atol=1e-15)
    # The compiled step wrote the same log row as the bound sources describe.
    row = ctl.log.data[ctl.log.n - 1]
    np.testing.assert_array_equal(row[27:51], ctl.compliant_ee.data)
    np.testing.assert_array_equal(row[51:75], ctl.desired_ee.data)
    np.testing.assert_array_equal(ctl.log.group("omega_cmd_hz")[-1], cmd.omega_hz)
    np.testing.assert_array_equal(ctl.log.group("w_ref")[-1], ctl.pose.w_ref)
    np.testing.assert_array_equal(ctl.log.group("f_ext_W")[-1], ctl.observer.f_ext_W)
    np.testing.assert_allclose(ctl.log.group("p_E_W")[-1], st.p_W + st.R_WB @ p_E_B, rtol=1e-14)


def test_so3_cholesky_and_inverse_kernels_match_numpy():
    rng = np.random.default_rng(3)
    R = np.empty((3, 3))
    out = np.empty(3)
    for phi in (rng.normal(0.0, 1.0, 3), np.array([1e-6, -2e-6, 5e-7]), np.zeros(3)):
        exp_so3_into(phi[0], phi[1], phi[2], R)
        np.testing.assert_allclose(R, exp_so3(phi), atol=1e-15)
        log_so3_into(R, out, 0)
        np.testing.assert_allclose(out, log_so3(R), atol=1e-12)
    A = rng.normal(size=(15, 15))
    P = A @ A.T + 1e-3 * np.eye(15)
    L = np.empty((15, 15))
    assert ek.cholesky_lower(P, L) == 0
    np.testing.assert_allclose(L, np.linalg.cholesky(P), rtol=1e-10, atol=1e-12)
    P[4, 4] = -1.0
    assert ek.cholesky_lower(P, L) == 5  # LAPACK's info: the first column that is not positive definite
    S = rng.normal(size=(6, 6))
    S_inv = np.empty((6, 6))
    assert ek.invert(S, S_inv)
    np.testing.assert_allclose(S_inv @ S, np.eye(6), atol=1e-12)
    S[:, 2] = 0.0  # singular
    assert not ek.invert(S, S_inv)


def _hamilton_left(q: np.ndarray) -> np.ndarray:
    """The 4x4 matrix L(q) with q ⊗ p = L(q) p (wxyz)."""
    w, x, y, z = q
    return np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])


def test_sensor_kernels_match_independent_oracles():
    rng = np.random.default_rng(4)
    out = np.empty(9)
    q4 = np.empty(4)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        d = rng.normal(0.0, 0.01, 3)
        quat_perturb_into(q, d, q4)
        want = _hamilton_left(q) @ np.concatenate([[1.0], 0.5 * d])  # q ⊗ [1, d/2], normalised
        np.testing.assert_allclose(q4, want / np.linalg.norm(want), rtol=0, atol=1e-15)
        R9_from_quat_into(*q4, out, 0)
        np.testing.assert_allclose(out, R_from_quat_wxyz(q4).ravel(), rtol=0, atol=1e-15)


def test_interference_kernel_matches_the_vectorised_spec_formula():
    aero = InterferenceAero(V, AeroParams(tilt_error_std_deg=1.0, gain_error_std=0.02))
    p = aero.params
    radius = 0.5 * V.propeller_diameter
    K2 = aero._K2
    v_coef = np.sqrt(p.kappa0 * aero.gains * V.c_f / (2.0 * p.rho * math.pi * radius**2))
    rng = np.random.default_rng(5)
    for _ in range(50):
        u = rng.normal(0.0, 2.5e4, 8) * (rng.random(8) > 0.2)  # some rotors stopped
        n = np.maximum(np.sqrt(np.abs(u)), 1e-6)
        sv = u / n * v_coef
        V_i = K2 @ np.concatenate([np.minimum(sv, 0.0), np.maximum(sv, 0.0)]) * (u / n) / n**2
        eta = np.clip(1.0 - p.gamma / (p.advance_ratio_ref * 2 * radius) * V_i, p.eta_min, p.eta_max)
        np.testing.assert_allclose(aero.efficiency(u), eta, rtol=1e-13)
        np.testing.assert_allclose(aero.wrench_B(u), p.kappa0 * aero.A_true @ (eta * u), rtol=1e-12, atol=1e-12)


def test_truth_row_is_the_ground_truth_in_the_truth_log_layout():
    sim = Simulator(V, "wall", SimParams(aero=AeroParams(model="nominal")).undisturbed(), seed=1)
    p0, R0 = sim.default_start()
    n_W = sim.scene.normal_W
    sim.reset(p0 - (sim.params.scene.start_standoff - 0.005) * n_W, R0)
    sim.set_external_wrench(-3.0 * n_W, at="ee")
    cmd = RotorCommand(0.0, sim.hover_speeds_hz(R0))
    width = Recorder(1, TRUTH_GROUPS(V.n_rotors)).n_signals
    row = np.full(width, -7.0)
    seen_contact = False
    for k in range(1500):
        sim.step(cmd)
        if k % 100 == 99 or k == 0:
            sim.truth_row(row)
            tr = sim.truth
            expect = np.concatenate(
                [
                    [tr.t],
                    tr.p_W,
                    tr.v_W,
                    tr.R_WB.reshape(9),
                    tr.omega_B,
                    tr.p_E_W,
                    tr.contact_force_W,
                    tr.contact_moment_W,
                    [float(tr.in_contact)],
                    tr.rotor_hz,
                ]
            )
            # The row's contact wrench comes from MuJoCo's contact sensors, the record's from mj_contactForce per
            # contact: the same forces summed in another order (a rounding apart).
            wrench = slice(22, 28)
            np.testing.assert_allclose(row[wrench], expect[wrench], rtol=1e-12, atol=1e-12)
            row[wrench] = expect[wrench]
            np.testing.assert_array_equal(row[:-2], expect)
            assert row[-1] == row[-2] == -7.0  # the two timing columns are the caller's
            seen_contact |= tr.in_contact
    assert seen_contact and np.linalg.norm(sim.truth.contact_force_W) > 1.0


def test_blocks_keep_their_state_in_a_given_buffer():
    from omnirotor.control.observer import STATE_DTYPE

    outer = np.zeros(1, dtype=[("before", np.float64), ("observer", STATE_DTYPE), ("after", np.float64)])
    outer["before"], outer["after"] = 3.0, 3.0
    obs = WrenchObserver(V, state=outer["observer"])
    assert np.shares_memory(obs.f_ext_W, outer) and np.all(obs.output == 0.0)
    assert outer["before"][0] == 3.0 and outer["after"][0] == 3.0  # only its field is used
    sample = ReferenceSample(np.ones(24))
    np.testing.assert_array_equal(sample.R_WB, np.eye(3))
    other = np.dtype([(name, np.float32, STATE_DTYPE[name].shape) for name in STATE_DTYPE.names])
    for bad in (np.zeros(2, dtype=STATE_DTYPE), np.zeros(1, dtype=other), np.zeros(OBS_FLOATS)):
        with pytest.raises(InputError):
            WrenchObserver(V, state=bad)
    # The controller's blocks share its state; a step changes them through it.
    ctl = InteractionController(V, ControllerParams(estimator=EstimatorParams(kind="bypass"), log_capacity=10))
    for block in (ctl.observer, ctl.admittance, ctl.pose, ctl.allocator, ctl.estimator):
        assert np.shares_memory(block.state, ctl.state)
    for ref in (ctl.desired_ee, ctl.compliant_ee, ctl.body_ref):
        assert np.shares_memory(ref.data, ctl.state)


def test_messages_stay_frozen_dataclasses():
    x = np.zeros(3)
    st = StateEstimate(0.1, x, x, x, np.eye(3), x)
    by_name = StateEstimate(t=0.1, p_W=x, v_W=x, a_W=x, R_WB=st.R_WB, omega_B=x, valid=False)
    assert st.valid and not by_name.valid and by_name.p_W is x and by_name.R_WB is st.R_WB
    frame = SensorFrame(0.2, x, x, np.zeros(8))
    assert not frame.mocap_new and frame.mocap_p_W is None and frame.state is None
    cmd = RotorCommand(0.3, np.ones(8))
    assert cmd.status is ControlStatus.OK
    for msg, field in ((st, "t"), (frame, "imu_acc_B"), (cmd, "status")):
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(msg, field, None)
    assert dataclasses.replace(frame, mocap_new=True).mocap_new
    with pytest.raises(TypeError):
        SensorFrame(0.0, x)


def test_recorder_next_row_fills_in_place_and_counts_drops():
    rec = Recorder(2, [("a", 1), ("b", ("x", "y"))])
    rec.next_row()[:] = (1.0, 2.0, 3.0)
    rec.next_row()[:] = (4.0, 5.0, 6.0)
    assert rec.next_row() is None and rec.dropped == 1 and rec.n == 2
    np.testing.assert_array_equal(rec.group("b"), [[2.0, 3.0], [5.0, 6.0]])


def test_a_growing_recorder_never_drops_and_keeps_every_row_in_order():
    rec = Recorder(2, [("a", 1), ("b", ("x", "y"))], grow_rows=3)
    for k in range(8):  # three chunks: 2 + 3 + 3 rows, by every way of writing a row
        if k % 3 == 0:
            rec.next_row()[:] = (k, 10 * k, 100 * k)
        elif k % 3 == 1:
            assert rec.record(float(k), np.array([10.0 * k, 100.0 * k]))
        else:
            rec.bind(np.array([float(k), 10.0 * k, 100.0 * k]))
            assert rec.record_bound()
    assert rec.n == 8 and rec.dropped == 0 and rec.capacity == 8
    np.testing.assert_array_equal(rec.column("a"), np.arange(8.0))
    np.testing.assert_array_equal(rec.group("b"), np.c_[10.0 * np.arange(8), 100.0 * np.arange(8)])
    rec.next_row()[:] = 8.0  # after the chunks were joined (read), it grows again
    assert rec.n == 9 and rec.column("a")[-1] == 8.0 and rec.capacity == 11


def test_a_recorder_with_a_record_dtype_gives_each_row_as_a_record_of_the_same_memory():
    dtype = np.dtype([("a", np.float64), ("b", np.float64, (2,))])
    rec = Recorder(2, [("a", 1), ("b", ("x", "y"))], grow_rows=2, record_dtype=dtype)
    for k in range(5):  # three chunks: the records follow each new chunk
        row = rec.next_record()
        assert row.shape == (1,) and row.dtype is dtype  # the dtype object itself: numba types it fast
        row[0]["a"], row[0]["b"] = k, (10.0 * k, 100.0 * k)
    rec.next_row()[:] = (5.0, 50.0, 500.0)  # the float rows and the records are one log
    np.testing.assert_array_equal(rec.column("a"), np.arange(6.0))
    np.testing.assert_array_equal(rec.group("b"), np.c_[10.0 * np.arange(6), 100.0 * np.arange(6)])
    rec.next_record()[0]["a"] = 6.0  # after the chunks were joined (read)
    assert rec.n == 7 and rec.column("a")[-1] == 6.0
    full = Recorder(1, [("a", 1)], record_dtype=np.dtype([("a", np.float64)]))
    assert full.next_record() is not None and full.next_record() is None and full.dropped == 1
    with pytest.raises(InputError, match="record_dtype"):
        Recorder(1, [("a", 1), ("b", 2)], record_dtype=np.dtype([("a", np.float64)]))
    with pytest.raises(InputError, match="record_dtype"):
        Recorder(1, [("a", 1), ("b", 2)], record_dtype=np.dtype([("a", np.float64), ("b", np.int64, (2,))]))


def test_the_controller_log_has_no_cap():
    traj, first, frames = _frames(25)
    ctl = InteractionController(V, ControllerParams(estimator=EstimatorParams(kind="bypass"), log_capacity=10))
    ctl.reset(first, traj)
    for frame in frames:
        ctl.step(frame)
    assert ctl.log.n == 25 and ctl.log.dropped == 0
    np.testing.assert_allclose(ctl.log.group("t"), [f.t - first.t for f in frames], rtol=0, atol=1e-12)


def test_trajectory_kernel_holds_outside_and_interpolates_inside():
    w0 = Waypoint(1.0, np.array([0.0, 0.0, 1.0]), np.eye(3))
    w1 = Waypoint(2.0, np.array([1.0, 0.0, 1.0]), rot_x(0.5))
    for profile in ("quintic", "cubic"):
        traj = PoseTrajectory([w0, w1], attitude_profile=profile)
        np.testing.assert_array_equal(traj(0.5).p_W, w0.p_W)
        np.testing.assert_array_equal(traj(3.0).R_WB, w1.R_WB)
        mid = traj(1.5)
        np.testing.assert_allclose(mid.p_W, [0.5, 0.0, 1.0], atol=1e-15)
        np.testing.assert_allclose(mid.R_WB, rot_x(0.25), atol=1e-15)
