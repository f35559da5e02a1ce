"""Rigid body, rotor wrench and contact of the simulator (SPEC §2, §5.2, §7)."""

import math

import numpy as np
import pytest

from omnirotor.errors import InputError
from omnirotor.messages import RotorCommand
from omnirotor.sim import SCENES, AeroParams, SceneParams, SensorParams, SimParams, Simulator
from omnirotor.sim.aero import InterferenceAero, WakeAero, hover_equilibrium, make_aero
from omnirotor.so3 import log_so3, rot_x, rot_z
from omnirotor.vehicle import load_vehicle, preset_names

V = load_vehicle("omnirotor")
QUIET = SensorParams(
    **{name: 0.0 for name in SensorParams.__dataclass_fields__ if name.endswith("_std") or name.endswith("_std_hz")}
)
# The rigid-body plant: these tests check the rigid body, its contacts and exact equilibria, so the tool is rigid
# (the compliant tool sags under gravity and lags a push; tests/test_sim_tool.py covers it), and the disturbances
# are off (tests/test_disturbances.py covers them).
NOMINAL = SimParams(
    aero=AeroParams(model="nominal"), sensors=QUIET, scene=SceneParams(tool_compliant=False)
).undisturbed()


def run(sim, omega_hz, steps):
    cmd = RotorCommand(0.0, np.asarray(omega_hz, dtype=float))
    frame = None
    for _ in range(steps):
        frame = sim.step(cmd)
    return frame


@pytest.mark.parametrize("substeps", [1, 2])
def test_free_fall_follows_gravity_and_accelerometer_reads_zero(substeps):
    sim = Simulator(
        V, "free", SimParams(aero=AeroParams(model="nominal"), sensors=QUIET, substeps=substeps).undisturbed()
    )
    p0 = np.array([0.0, 0.0, 2.0])
    sim.reset(p0, rot_x(0.3), omega_hz=np.zeros(8))
    frame = run(sim, np.zeros(8), 400)
    t = sim.t
    assert t == pytest.approx(0.4)
    g = V.gravity
    # Semi-implicit Euler with step h: z_k = z0 - g h² k (k + 1) / 2, i.e. z0 - g t²/2 - g t h / 2.
    h = 1e-3 / substeps
    assert sim.truth.p_W[2] == pytest.approx(p0[2] - 0.5 * g * t * t - 0.5 * g * t * h, abs=1e-9)
    np.testing.assert_allclose(sim.truth.p_W[:2], 0.0, atol=1e-12)
    np.testing.assert_allclose(sim.truth.v_W, [0, 0, -g * t], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(sim.truth.a_W, [0, 0, -g], atol=1e-9)
    np.testing.assert_allclose(frame.imu_acc_B, 0.0, atol=1e-9)
    np.testing.assert_allclose(frame.state.a_W, [0, 0, -g], atol=1e-9)


@pytest.mark.parametrize(
    "R", [np.eye(3), rot_x(math.radians(-45)), rot_z(1.0) @ rot_x(2.0)], ids=["upright", "roll-45", "tumbled"]
)
def test_hover_under_nominal_truth_stays_put_and_reads_g_up(R):
    sim = Simulator(V, "free", NOMINAL)
    p0 = np.array([0.1, -0.2, 1.5])
    sim.reset(p0, R)
    u = V.hover_input(R)
    frame = run(sim, np.sign(u) * np.sqrt(np.abs(u)), 3000)
    tr = sim.truth
    assert np.linalg.norm(tr.p_W - p0) < 1e-6
    assert np.linalg.norm(log_so3(tr.R_WB @ R.T)) < 1e-6
    np.testing.assert_allclose(frame.imu_acc_B, R.T @ [0, 0, V.gravity], atol=1e-6)
    np.testing.assert_allclose(tr.rotor_wrench_B, [*(R.T @ [0, 0, V.weight]), 0, 0, 0], atol=1e-9)


@pytest.mark.parametrize("model", ["wake", "spec7"])
def test_interaction_truth_lifts_the_nominal_hover(model):
    # At the nominal hover speeds either interaction model (the default rotor-wake one, and SPEC §7's) gives
    # more thrust than the nominal map (real data: 1.117 in R1, SPEC §3.5), and the compiled step evaluates it.
    sim = Simulator(V, "free", SimParams(sensors=QUIET, aero=AeroParams(model=model)).undisturbed())
    sim.reset(np.array([0.0, 0.0, 1.5]), np.eye(3))
    run(sim, sim.hover_speeds_hz(np.eye(3)), 5)
    aero = make_aero(V, AeroParams(model=model))
    assert isinstance(aero, WakeAero if model == "wake" else InterferenceAero)
    expect = aero.wrench_B(V.hover_input())
    lift_ratio = expect[2] / V.weight
    assert lift_ratio > 1.08 and lift_ratio < 1.16
    np.testing.assert_allclose(sim.truth.rotor_wrench_B, expect, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(sim.truth.a_W, (expect[:3] - [0, 0, V.weight]) / V.mass, atol=1e-6)
    # At the truth equilibrium (a controller with integral action) the vehicle does stay put.
    u = hover_equilibrium(aero, V, np.eye(3))
    sim.reset(np.array([0.0, 0.0, 1.5]), np.eye(3), omega_hz=np.sign(u) * np.sqrt(np.abs(u)))
    run(sim, np.sign(u) * np.sqrt(np.abs(u)), 1000)
    assert np.linalg.norm(sim.truth.p_W - [0, 0, 1.5]) < 1e-6


def press_into(scene, push_N=3.0, steps=2500, params=NOMINAL, vehicle=V):
    """Tip 5 mm off the surface in the scene's start attitude, then pushed along -normal at the EE."""
    sim = Simulator(vehicle, scene, params)
    p0, R0 = sim.default_start()
    n = sim.scene.normal_W
    gap = sim.params.scene.start_standoff - 0.005
    sim.reset(p0 - gap * n, R0)
    sim.set_external_wrench(-push_N * n, at="ee")
    run(sim, sim.hover_speeds_hz(R0), steps)
    return sim


@pytest.mark.parametrize("scene", ["wall", "tilted-wall", "pipe"])
def test_static_contact_force_balances_the_push(scene):
    sim = press_into(scene)
    tr = sim.truth
    n = sim.scene.normal_W
    assert tr.in_contact and not tr.other_contact
    assert np.linalg.norm(tr.v_W) < 1e-4 and np.linalg.norm(tr.omega_B) < 1e-3
    np.testing.assert_allclose(tr.contact_force_W, 3.0 * n, atol=0.03 * 3.0)
    # A point contact at the tip has (almost) no moment about the tip.
    assert np.linalg.norm(tr.contact_moment_W) < 1e-3
    # The tip sits on the surface (soft contact: sub-millimetre penetration).
    assert abs((tr.p_E_W - sim.scene.surface_point_W) @ n) < 5e-4 or scene == "pipe"


def test_static_contact_force_with_an_oblique_push_has_friction():
    # Push along -normal plus a small tangential component: the contact (with friction) balances both.
    sim = Simulator(V, "wall", NOMINAL)
    p0, R0 = sim.default_start()
    sim.reset(p0 - 0.295 * sim.scene.normal_W, R0)
    push = np.array([0.5, -3.0, 0.0])  # tangential 0.5 N < mu * 3 N = 0.9 N: sticks
    sim.set_external_wrench(push, at="ee")
    run(sim, sim.hover_speeds_hz(R0), 3000)
    tr = sim.truth
    assert tr.in_contact
    assert np.linalg.norm(tr.v_W) < 1e-3
    np.testing.assert_allclose(tr.contact_force_W, -push, atol=0.03 * 3.0)


def test_free_flight_has_no_contact_force():
    sim = Simulator(V, "wall", NOMINAL)
    run(sim, sim.hover_speeds_hz(sim.truth.R_WB), 200)
    tr = sim.truth
    assert not tr.in_contact and not tr.other_contact
    np.testing.assert_array_equal(tr.contact_force_W, np.zeros(3))
    np.testing.assert_array_equal(tr.contact_moment_W, np.zeros(3))


def test_external_wrench_at_com_accelerates_the_body():
    sim = Simulator(V, "free", NOMINAL)
    sim.reset(np.array([0.0, 0.0, 1.5]), np.eye(3))
    sim.set_external_wrench([1.625, 0.0, 0.0], m_W=[0.0, 0.0, 0.0113], at="com")
    run(sim, sim.hover_speeds_hz(np.eye(3)), 10)
    np.testing.assert_allclose(sim.truth.a_W, [1.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(sim.data.qacc[3:6], [0.0, 0.0, 1.0], atol=1e-6)
    with pytest.raises(InputError):
        sim.set_external_wrench([1.0, 0.0], at="ee")
    with pytest.raises(InputError):
        sim.set_external_wrench([1.0, 0.0, 0.0], at="tip")


@pytest.mark.parametrize("preset", preset_names())
@pytest.mark.parametrize("scene", SCENES)
def test_every_scene_builds_and_steps_for_every_preset(scene, preset):
    v = load_vehicle(preset)
    sim = Simulator(v, scene, SimParams(), seed=1)
    p0, R0 = sim.default_start()
    np.testing.assert_allclose(sim.truth.p_W, p0, atol=1e-12)
    if sim.scene.surface_point_W is not None and np.linalg.norm(v.p_E_B_array) > 0:
        # The start pose points the EE at the surface, start_standoff away.
        n = sim.scene.normal_W
        tip_dir = R0 @ v.p_E_B_array / np.linalg.norm(v.p_E_B_array)
        np.testing.assert_allclose(tip_dir, -n, atol=1e-12)
        gap = (sim.truth.p_E_W - sim.scene.surface_point_W) @ n
        assert gap == pytest.approx(sim.params.scene.start_standoff, abs=1e-12)
    frame = run(sim, sim.hover_speeds_hz(R0), 50)
    assert frame.t == pytest.approx(0.05)
    assert np.all(np.isfinite(frame.imu_acc_B)) and frame.rotor_hz.shape == (v.n_rotors,)
    assert not sim.truth.in_contact and not sim.truth.other_contact


def test_default_start_attitudes_match_the_paper():
    sim = Simulator(V, "wall")
    np.testing.assert_allclose(sim.default_start()[1], rot_z(math.pi), atol=1e-12)
    sim = Simulator(V, "tilted-wall")
    np.testing.assert_allclose(sim.default_start()[1], rot_z(math.pi) @ rot_x(math.radians(30)), atol=1e-12)
    sim = Simulator(V, "pipe")
    np.testing.assert_allclose(sim.default_start()[1], np.eye(3), atol=1e-12)


def test_scene_anchors_follow_the_params():
    sp = SceneParams(wall_point=(0.1, -1.0, 1.2), pipe_radius=0.4, hole_entrance=(0.5, -0.9, 1.3))
    sim = Simulator(V, "wall", SimParams(scene=sp))
    np.testing.assert_array_equal(sim.scene.surface_point_W, [0.1, -1.0, 1.2])
    np.testing.assert_array_equal(sim.scene.normal_W, [0, 1, 0])
    assert Simulator(V, "pipe", SimParams(scene=sp)).scene.pipe_radius == 0.4
    hole = Simulator(V, "peg-in-hole", SimParams(scene=sp)).scene
    np.testing.assert_array_equal(hole.hole_entrance_W, [0.5, -0.9, 1.3])
    assert hole.funnel_length == 0.10 and hole.insertion_depth_max >= 0.17
    tilted = Simulator(V, "tilted-wall").scene
    np.testing.assert_allclose(tilted.normal_W, [0, math.cos(math.pi / 6), -math.sin(math.pi / 6)])
    with pytest.raises(InputError):
        Simulator(V, "moon")


def _tip_on_axis(sim, depth, offset):
    a = sim.scene
    R = rot_z(math.pi)
    p_E = a.hole_entrance_W - depth * a.hole_axis_W + offset
    sim.reset(p_E - R @ V.p_E_B_array, R)
    return sim.truth


def test_peg_fits_straight_along_the_hole_axis():
    sim = Simulator(V, "peg-in-hole", NOMINAL)
    for depth in np.arange(-0.05, 0.17 + 1e-9, 0.002):
        tr = _tip_on_axis(sim, depth, np.zeros(3))
        assert not tr.in_contact and not tr.other_contact, depth
    # 1.2 mm off the axis still fits the 1.5 mm radial play; 2 mm does not.
    assert not _tip_on_axis(sim, 0.15, np.array([0.0012, 0.0, 0.0])).in_contact
    assert _tip_on_axis(sim, 0.15, np.array([0.002, 0.0, 0.0])).in_contact


def test_peg_offset_at_the_entrance_is_guided_by_the_funnel():
    """A compliant driver pushes the tip along -y, 2 cm off the axis: the funnel guides it into the hole."""
    sp = SceneParams()
    sim = Simulator(V, "peg-in-hole", NOMINAL)
    a = sim.scene
    R0 = rot_z(math.pi)
    offset = np.array([0.02, 0.0, 0.0])
    start = a.hole_entrance_W + 0.03 * a.hole_axis_W + offset
    sim.reset(start - R0 @ V.p_E_B_array, R0)
    K = np.diag([15.0, 60.0, 15.0])
    D = 2 * np.sqrt(K * V.mass)
    r_mouth, r_hole = sp.funnel_entrance_diameter / 2, sp.hole_diameter / 2
    cos_phi = sp.funnel_length / math.hypot(sp.funnel_length, r_mouth - r_hole)
    touched, worst = False, np.inf
    hover = sim.hover_speeds_hz(R0)
    for _ in range(4000):
        tr = sim.truth
        depth_ref = min(-0.03 + 0.06 * sim.t, 0.17)
        f = K @ (a.hole_entrance_W - depth_ref * a.hole_axis_W + offset - tr.p_E_W) - D @ tr.v_W
        m = 2.0 * log_so3(R0 @ tr.R_WB.T) - 0.3 * tr.R_WB @ tr.omega_B
        sim.set_external_wrench(f, m, at="ee")
        sim.step(RotorCommand(sim.t, hover))
        tr = sim.truth
        touched |= tr.in_contact
        # Clearance of the tip sphere (radius 8 mm, centre 8 mm behind p_E) from the funnel/hole wall.
        centre = tr.p_E_W + 0.008 * a.hole_axis_W
        rel = centre - a.hole_entrance_W
        s = -rel @ a.hole_axis_W
        radial = math.hypot(rel[0], rel[2])
        if 0.0 < s < sp.funnel_length:
            wall = r_mouth - (r_mouth - r_hole) * s / sp.funnel_length
            worst = min(worst, (wall - radial) * cos_phi - 0.008)
        elif s >= sp.funnel_length:
            worst = min(worst, r_hole - radial - 0.008)
    depth = -(sim.truth.p_E_W - a.hole_entrance_W) @ a.hole_axis_W
    assert touched
    assert depth > 0.16  # guided into the hole, not stopped at the funnel
    assert worst > -1e-3  # never through the wall (polygonal wall and soft contact: < 1 mm)
