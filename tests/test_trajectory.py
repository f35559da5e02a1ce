"""Minimum-jerk pose trajectory (SPEC §4.5): waypoints, rest at waypoints, derivatives, validation."""

import math

import numpy as np
import pytest

from omnirotor.control.trajectory import PoseTrajectory, ReferenceSample, Waypoint
from omnirotor.errors import InputError
from omnirotor.so3 import R_from_rpy, exp_so3, log_so3, vee


def _random_trajectory(rng: np.random.Generator, n: int = 4, profile: str = "quintic") -> PoseTrajectory:
    times = np.cumsum(rng.uniform(0.5, 3.0, n)) - 1.0
    wps = [Waypoint(t=float(t), p_W=rng.normal(size=3), R_WB=exp_so3(rng.uniform(-1.5, 1.5, 3))) for t in times]
    return PoseTrajectory(wps, attitude_profile=profile)


@pytest.mark.parametrize("profile", ["quintic", "cubic"])
def test_waypoints_are_hit_exactly_at_rest(profile):
    rng = np.random.default_rng(1)
    traj = _random_trajectory(rng, 5, profile)
    out = ReferenceSample()
    for w in traj.waypoints:
        traj.sample(w.t, out)
        np.testing.assert_allclose(out.p_W, w.p_W, atol=1e-12)
        np.testing.assert_allclose(out.R_WB, w.R_WB, atol=1e-12)
        np.testing.assert_allclose(out.v_W, 0.0, atol=1e-12)
        np.testing.assert_allclose(out.omega_W, 0.0, atol=1e-12)
        if profile == "quintic":
            np.testing.assert_allclose(out.a_W, 0.0, atol=1e-12)
            np.testing.assert_allclose(out.alpha_W, 0.0, atol=1e-12)


def test_pose_is_held_outside_the_time_range():
    rng = np.random.default_rng(2)
    traj = _random_trajectory(rng, 3)
    out = ReferenceSample()
    for t, w in ((traj.t_start - 5.0, traj.waypoints[0]), (traj.t_end + 5.0, traj.waypoints[-1])):
        traj.sample(t, out)
        np.testing.assert_allclose(out.p_W, w.p_W, atol=1e-15)
        np.testing.assert_allclose(out.R_WB, w.R_WB, atol=1e-15)
        for d in (out.v_W, out.a_W, out.omega_W, out.alpha_W):
            np.testing.assert_array_equal(d, 0.0)


@pytest.mark.parametrize("profile", ["quintic", "cubic"])
def test_derivatives_match_finite_differences(profile):
    rng = np.random.default_rng(3)
    traj = _random_trajectory(rng, 4, profile)
    h = 1e-5
    a, b, c = ReferenceSample(), ReferenceSample(), ReferenceSample()
    for t in rng.uniform(traj.t_start + 1e-3, traj.t_end - 1e-3, 40):
        traj.sample(t - h, a)
        traj.sample(t, b)
        traj.sample(t + h, c)
        np.testing.assert_allclose((c.p_W - a.p_W) / (2 * h), b.v_W, atol=1e-6)
        np.testing.assert_allclose((c.v_W - a.v_W) / (2 * h), b.a_W, atol=1e-6)
        # dR/dt = [omega_W]x R  =>  omega_W = vee(dR/dt R^T)
        Rdot = (c.R_WB - a.R_WB) / (2 * h)
        np.testing.assert_allclose(vee(Rdot @ b.R_WB.T), b.omega_W, atol=1e-6)
        np.testing.assert_allclose((c.omega_W - a.omega_W) / (2 * h), b.alpha_W, atol=1e-5)
        # The sampled attitude stays a rotation.
        np.testing.assert_allclose(b.R_WB.T @ b.R_WB, np.eye(3), atol=1e-12)


def test_minimum_jerk_midpoint_and_peak_speed():
    # Rest-to-rest quintic: half way at mid-time, peak speed 15/8 * distance / T.
    p0, p1 = np.zeros(3), np.array([0.3, -0.1, 0.2])
    T = 3.0
    traj = PoseTrajectory([Waypoint(0.0, p0, np.eye(3)), Waypoint(T, p1, R_from_rpy(0.0, 0.0, 0.4))])
    out = traj(T / 2)
    np.testing.assert_allclose(out.p_W, 0.5 * (p0 + p1), atol=1e-14)
    np.testing.assert_allclose(out.v_W, 15.0 / 8.0 * (p1 - p0) / T, atol=1e-14)
    np.testing.assert_allclose(log_so3(out.R_WB), [0.0, 0.0, 0.2], atol=1e-14)


def test_attitude_follows_the_geodesic():
    # Intermediate attitudes rotate about the single axis log(R0^T R1) (no detour).
    rng = np.random.default_rng(4)
    R0, R1 = exp_so3(rng.normal(size=3)), exp_so3(rng.normal(size=3))
    traj = PoseTrajectory([Waypoint(0.0, np.zeros(3), R0), Waypoint(2.0, np.zeros(3), R1)])
    phi = log_so3(R0.T @ R1)
    for t in (0.3, 1.0, 1.7):
        rel = log_so3(R0.T @ traj(t).R_WB)
        assert abs(np.linalg.norm(np.cross(rel, phi))) < 1e-9
        assert rel @ phi > 0


def test_single_waypoint_holds_forever():
    R = R_from_rpy(0.1, -0.2, 0.3)
    traj = PoseTrajectory([Waypoint(0.0, [1.0, 2.0, 3.0], R)])
    for t in (-1.0, 0.0, 10.0):
        out = traj(t)
        np.testing.assert_array_equal(out.p_W, [1.0, 2.0, 3.0])
        np.testing.assert_allclose(out.R_WB, R, atol=1e-15)


def test_validation():
    eye = np.eye(3)
    with pytest.raises(InputError):
        PoseTrajectory([])
    with pytest.raises(InputError):
        PoseTrajectory([Waypoint(0.0, np.zeros(3), eye), Waypoint(0.0, np.ones(3), eye)])
    with pytest.raises(InputError):
        PoseTrajectory([Waypoint(1.0, np.zeros(3), eye), Waypoint(0.5, np.ones(3), eye)])
    with pytest.raises(InputError):
        Waypoint(math.nan, np.zeros(3), eye)
    with pytest.raises(InputError):
        Waypoint(0.0, [0.0, math.inf, 0.0], eye)
    with pytest.raises(InputError):
        Waypoint(0.0, np.zeros(2), eye)
    with pytest.raises(InputError):
        Waypoint(0.0, np.zeros(3), np.diag([1.0, 1.0, -1.0]))  # reflection
    with pytest.raises(InputError):
        Waypoint(0.0, np.zeros(3), 1.01 * eye)  # not orthonormal
    with pytest.raises(InputError):
        PoseTrajectory([Waypoint(0.0, np.zeros(3), eye)], attitude_profile="linear")


def test_waypoint_arrays_are_private_copies():
    p = np.zeros(3)
    w = Waypoint(0.0, p, np.eye(3))
    p[0] = 5.0
    assert w.p_W[0] == 0.0
    with pytest.raises(ValueError):
        w.p_W[0] = 1.0


@pytest.mark.parametrize("quick", [False, True])
def test_every_shipped_task_fits_the_default_record(quick: bool) -> None:
    """A reset with any task's trajectory keeps the controller's record (a larger one compiles the step again,
    which a flight node cannot afford after pairing: the lockstep SITL point contact stalled 5 s on it)."""
    from omnirotor.control.controller import ControllerParams, InteractionController
    from omnirotor.experiments.tasks import scenarios
    from omnirotor.messages import SensorFrame
    from omnirotor.sim import SimParams
    from omnirotor.vehicle import load_vehicle

    vehicle = load_vehicle()
    controller = InteractionController(vehicle, ControllerParams())
    dtype = controller.state.dtype
    scene = SimParams().scene
    u = vehicle.hover_input()
    hz = np.sign(u) * np.sqrt(np.abs(u))
    for make in (scenarios.point_contact, scenarios.point_contact_tilted, scenarios.sliding, scenarios.peg_in_hole):
        sc = make(scene, quick=quick)
        w = sc.waypoints[0]
        frame = SensorFrame(
            0.0, np.array([0.0, 0.0, 9.81]), np.zeros(3), hz, True, 0.0, np.asarray(w.p_W), np.array([1.0, 0, 0, 0])
        )
        controller.reset(frame, PoseTrajectory(list(sc.waypoints)))
        assert controller.state.dtype == dtype, make.__name__
