"""Pose controller (SPEC §4.1): feed-forward terms, saturations, anti-windup, signs, closed-loop tracking."""

import math

import numpy as np
import pytest

from omnirotor.control.pose import PoseController, PoseControlParams
from omnirotor.control.trajectory import PoseTrajectory, ReferenceSample, Waypoint
from omnirotor.errors import InputError
from omnirotor.messages import StateEstimate
from omnirotor.so3 import R_from_rpy, exp_so3, log_so3
from omnirotor.vehicle import load_vehicle

DT = 1e-3


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("omnirotor")


def _state(p, v, R, omega_B, a=(0.0, 0.0, 0.0)):
    return StateEstimate(
        t=0.0,
        p_W=np.asarray(p, float),
        v_W=np.asarray(v, float),
        a_W=np.asarray(a, float),
        R_WB=np.asarray(R, float),
        omega_B=np.asarray(omega_B, float),
    )


def test_zero_error_gives_gravity_and_gyroscopic_terms_minus_the_estimate(vehicle):
    rng = np.random.default_rng(7)
    J = vehicle.inertia
    for comp in (True, False):
        ctl = PoseController(vehicle, PoseControlParams(compensate_ext_wrench=comp))
        for _ in range(5):
            R = exp_so3(rng.normal(size=3))
            omega_B = rng.normal(size=3)
            ref = ReferenceSample.at_rest(rng.normal(size=3), R)
            ref.v_W[:] = rng.normal(size=3)
            ref.omega_W[:] = R @ omega_B  # same angular velocity as the body: e_omega = 0
            st = _state(ref.p_W, ref.v_W, R, omega_B)
            f_hat, m_hat = rng.normal(size=3), rng.normal(size=3)
            w = ctl.step(ref, st, f_hat, m_hat, DT)
            c = 1.0 if comp else 0.0
            np.testing.assert_allclose(w[:3], [0, 0, vehicle.mass * vehicle.gravity] - c * f_hat, atol=1e-12)
            np.testing.assert_allclose(w[3:], np.cross(omega_B, J @ omega_B) - c * m_hat, atol=1e-12)
            np.testing.assert_allclose(ctl.errors, 0.0, atol=1e-12)


def test_feedforward_accelerations(vehicle):
    ctl = PoseController(vehicle)
    R = R_from_rpy(0.3, -0.2, 1.0)
    ref = ReferenceSample.at_rest(np.zeros(3), R)
    ref.a_W[:] = [1.0, -2.0, 0.5]
    ref.alpha_W[:] = [3.0, 1.0, -2.0]
    w = ctl.step(ref, _state(np.zeros(3), np.zeros(3), R, np.zeros(3)), np.zeros(3), np.zeros(3), DT)
    np.testing.assert_allclose(w[:3], vehicle.mass * (ref.a_W + [0, 0, vehicle.gravity]), atol=1e-12)
    np.testing.assert_allclose(w[3:], vehicle.inertia @ R.T @ ref.alpha_W, atol=1e-12)
    off = PoseController(vehicle, PoseControlParams(feedforward_angular_acc=False))
    w = off.step(ref, _state(np.zeros(3), np.zeros(3), R, np.zeros(3)), np.zeros(3), np.zeros(3), DT)
    np.testing.assert_allclose(w[3:], 0.0, atol=1e-12)


def test_error_saturations(vehicle):
    p = PoseControlParams(k_i=(0.0, 0.0, 0.0))
    ctl = PoseController(vehicle, p)
    ref = ReferenceSample.at_rest(np.array([5.0, -5.0, 0.1]), np.eye(3))
    ref.v_W[:] = [0.0, 10.0, -10.0]
    w = ctl.step(ref, _state(np.zeros(3), np.zeros(3), np.eye(3), np.zeros(3)), np.zeros(3), np.zeros(3), DT)
    m = vehicle.mass
    kp, kv = np.array(p.k_p), np.array(p.k_v)
    e_p = np.array([0.2, -0.2, 0.1])
    e_v = np.array([0.0, 2.0, -2.0])
    np.testing.assert_allclose(w[:3], m * (kp * e_p + kv * e_v + [0, 0, vehicle.gravity]), atol=1e-12)


def test_integral_is_clamped_and_unwinds_at_once(vehicle):
    ctl = PoseController(vehicle)
    st = _state(np.zeros(3), np.zeros(3), np.eye(3), np.zeros(3))
    ref = ReferenceSample.at_rest(np.array([1.0, -0.05, 0.0]), np.eye(3))
    for _ in range(5000):
        ctl.step(ref, st, np.zeros(3), np.zeros(3), DT)
    # x saturates at 0.2 m -> 0.1 m s after 0.5 s; y = -0.05 m * 5 s = -0.25 -> clamped at -0.1.
    np.testing.assert_allclose(ctl.e_i_W, [0.1, -0.1, 0.0], atol=1e-12)
    ref.p_W[:] = [-1.0, 0.05, 0.0]
    ctl.step(ref, st, np.zeros(3), np.zeros(3), DT)
    np.testing.assert_allclose(ctl.e_i_W, [0.1 - 0.2 * DT, -0.1 + 0.05 * DT, 0.0], atol=1e-12)
    ctl.reset()
    np.testing.assert_array_equal(ctl.e_i_W, 0.0)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_attitude_error_gives_a_restoring_moment(vehicle, axis):
    ctl = PoseController(vehicle)
    R = R_from_rpy(0.4, 0.2, -0.7)
    delta = np.zeros(3)
    delta[axis] = 0.05
    ref = ReferenceSample.at_rest(np.zeros(3), R @ exp_so3(delta))  # reference rotated about body axis
    w = ctl.step(ref, _state(np.zeros(3), np.zeros(3), R, np.zeros(3)), np.zeros(3), np.zeros(3), DT)
    J = vehicle.inertia_diag[axis]
    assert w[3 + axis] == pytest.approx(J * 300.0 * math.sin(0.05), rel=1e-9)
    np.testing.assert_allclose(np.delete(w[3:], axis), 0.0, atol=1e-12)
    # The rate error pushes the same way: body spinning away from the reference gets a braking moment.
    omega = np.zeros(3)
    omega[axis] = -1.0
    w = ctl.step(ref, _state(np.zeros(3), np.zeros(3), R, omega), np.zeros(3), np.zeros(3), DT)
    assert w[3 + axis] == pytest.approx(J * (300.0 * math.sin(0.05) + 80.0), rel=1e-9)


def test_closed_loop_rigid_body_tracks_a_trajectory(vehicle):
    # Exact rigid-body dynamics driven by the wrench reference (no allocation, no disturbance):
    # the controller must follow a 0.3 m, 60 deg move to high accuracy and settle on the last pose.
    m, J = vehicle.mass, vehicle.inertia
    Jinv = np.linalg.inv(J)
    traj = PoseTrajectory(
        [
            Waypoint(0.0, [0.0, 0.0, 1.0], np.eye(3)),
            Waypoint(2.0, [0.3, -0.1, 1.2], R_from_rpy(0.4, -0.3, 0.9)),
        ]
    )
    ctl = PoseController(vehicle)
    ref = ReferenceSample()
    p, v, R, w = np.array([0.0, 0.0, 1.0]), np.zeros(3), np.eye(3), np.zeros(3)
    worst_p, worst_R = 0.0, 0.0
    for k in range(3000):
        t = k * DT
        traj.sample(t, ref)
        wr = ctl.step(ref, _state(p, v, R, w), np.zeros(3), np.zeros(3), DT)
        worst_p = max(worst_p, np.abs(p - ref.p_W).max())
        worst_R = max(worst_R, np.linalg.norm(log_so3(R.T @ ref.R_WB)))
        acc = wr[:3] / m - [0, 0, vehicle.gravity]
        wdot = Jinv @ (wr[3:] - np.cross(w, J @ w))
        p = p + v * DT + 0.5 * acc * DT**2
        v = v + acc * DT
        R = R @ exp_so3((w + 0.5 * wdot * DT) * DT)
        w = w + wdot * DT
    assert worst_p < 2e-3
    assert math.degrees(worst_R) < 0.2
    np.testing.assert_allclose(p, traj.waypoints[-1].p_W, atol=1e-4)
    assert np.linalg.norm(log_so3(R.T @ traj.waypoints[-1].R_WB)) < 1e-4


def test_validation():
    with pytest.raises(InputError):
        PoseControlParams(k_p=(1.0, 2.0))
    with pytest.raises(InputError):
        PoseControlParams(k_R=(1.0, -2.0, 3.0))
    with pytest.raises(InputError):
        PoseControlParams(max_pos_error=0.0)
    with pytest.raises(InputError):
        PoseControlParams(max_integral=math.inf)
