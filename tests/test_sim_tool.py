"""The tool of the simulated vehicle and the peg-in-hole geometry, read from the built MuJoCo model (SPEC §5.2).

The tool (rod and tip, Ø16 mm) hangs on a compliant coupling (paper §5.3); the hole is a funnel 10 cm long
from Ø80 mm to a Ø19 mm bore, 1.5 mm of play around the Ø16 mm peg.
"""

import math

import mujoco
import numpy as np
import pytest

from omnirotor.messages import RotorCommand
from omnirotor.sim import SceneParams, SimParams, Simulator
from omnirotor.sim.contact import EeContact, friction_step
from omnirotor.sim.model import (
    BODY_NAME,
    EE_ROD_GEOM,
    EE_SITE,
    EE_TIP_GEOM,
    TOOL_AXIAL_JOINT,
    TOOL_BEND_JOINTS,
    TOOL_BODY,
    build_mjcf,
    tool_pivot_B,
)
from omnirotor.sim.scenes import attitude_pointing
from omnirotor.vehicle import load_vehicle

V = load_vehicle("omnirotor")


def model(scene="free", **scene_kw):
    return mujoco.MjModel.from_xml_string(build_mjcf(V, scene, SceneParams(**scene_kw), 1e-3))


def geom(m, name):
    return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)


def body(m, name):
    return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)


def test_peg_and_hole_dimensions_from_the_built_model():
    p = SceneParams()
    m = model("peg-in-hole")
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    # the peg: rod and tip are Ø16 mm
    assert m.geom_size[geom(m, EE_TIP_GEOM), 0] == pytest.approx(0.008)
    assert m.geom_size[geom(m, EE_ROD_GEOM), 0] == pytest.approx(0.008)
    e = np.asarray(p.hole_entrance)

    def radial_axial(x):
        r = x - e
        return math.hypot(r[0], r[2]), r[1]  # the hole axis is world y, opening to +y

    def inner_face(g):
        """Centre and in-plane axis of a plate's face that looks at the hole axis."""
        R = d.geom_xmat[g].reshape(3, 3)
        faces = [d.geom_xpos[g] + s * m.geom_size[g, 2] * R[:, 2] for s in (-1.0, 1.0)]
        return min(faces, key=lambda x: radial_axial(x)[0]), R[:, 1]

    bore, mouth, end = [], [], []
    for k in range(p.ring_segments):
        face, _ = inner_face(geom(m, f"hole{k}"))
        bore.append(radial_axial(face)[0])
        g = geom(m, f"funnel{k}")
        face, along = inner_face(g)
        a, b = (radial_axial(face + s * m.geom_size[g, 1] * along) for s in (-1.0, 1.0))
        lo, hi = sorted((a, b), key=lambda ra: ra[1])  # hi: the mouth (axial 0), lo: the funnel's end
        mouth.append(hi)
        end.append(lo)
    # MJCF carries 9 significant digits: positions of ~1 m are exact to ~1e-8 m
    np.testing.assert_allclose(bore, 0.0095, atol=1e-7)  # Ø19 mm bore (inradius of the plate ring)
    np.testing.assert_allclose([r for r, _ in mouth], 0.040, atol=1e-7)  # Ø80 mm entrance
    np.testing.assert_allclose([s for _, s in mouth], 0.0, atol=1e-7)
    np.testing.assert_allclose([r for r, _ in end], 0.0095, atol=1e-7)
    np.testing.assert_allclose([s for _, s in end], -0.10, atol=1e-7)  # 10 cm long
    assert bore[0] - m.geom_size[geom(m, EE_ROD_GEOM), 0] == pytest.approx(0.0015, abs=1e-7)  # 1.5 mm play


def test_tool_hangs_on_a_compliant_coupling():
    m = model()
    tool = body(m, TOOL_BODY)
    assert m.body_parentid[tool] == body(m, BODY_NAME)
    for name in (EE_TIP_GEOM, EE_ROD_GEOM):
        assert m.geom_bodyid[geom(m, name)] == tool
    # the vehicle weighs what its file says and its CoM stays the body origin
    assert m.body_subtreemass[body(m, BODY_NAME)] == pytest.approx(V.mass)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    np.testing.assert_allclose(d.subtree_com[body(m, BODY_NAME)], d.xpos[body(m, BODY_NAME)], atol=1e-12)


def test_rigid_tool_option_puts_the_tip_on_the_body():
    m = model(tool_compliant=False)
    assert body(m, TOOL_BODY) < 0 and m.nq == 7
    assert m.geom_bodyid[geom(m, EE_TIP_GEOM)] == body(m, BODY_NAME)


@pytest.mark.parametrize("pivot", ["com", "mount", "tip"])
def test_tool_pivot_keeps_the_vehicles_mass_centre_and_inertia(pivot):
    """Wherever the coupling's pivot sits, the vehicle with its tool locked is the vehicle of its file."""
    m = model(tool_pivot=pivot)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)  # identity attitude, tool at rest
    bodies = [body(m, BODY_NAME), body(m, TOOL_BODY)]
    origin = d.xpos[bodies[0]].copy()
    mass = sum(m.body_mass[b] for b in bodies)
    com = sum(m.body_mass[b] * (d.xipos[b] - origin) for b in bodies) / mass
    J = np.zeros((3, 3))
    for b in bodies:
        R, r = d.ximat[b].reshape(3, 3), d.xipos[b] - origin
        J += R @ np.diag(m.body_inertia[b]) @ R.T + m.body_mass[b] * (r @ r * np.eye(3) - np.outer(r, r))
    assert mass == pytest.approx(V.mass, rel=1e-9)
    assert np.linalg.norm(com) < 1e-9
    np.testing.assert_allclose(J, V.inertia, atol=1e-8)
    # the hinges' axes cross at the pivot, where the tool's mass sits (gravity loads no hinge)
    for name in TOOL_BEND_JOINTS:
        np.testing.assert_allclose(m.jnt_pos[m.joint(name).id], tool_pivot_B(V, SceneParams(tool_pivot=pivot)))
    np.testing.assert_allclose(m.body_ipos[body(m, TOOL_BODY)], tool_pivot_B(V, SceneParams(tool_pivot=pivot)))
    if pivot == "mount":  # where the rod leaves the cube, on the tool's axis
        p = tool_pivot_B(V, SceneParams(tool_pivot=pivot))
        assert np.max(np.abs(p)) == pytest.approx(0.5 * V.frame_size)
        assert np.linalg.norm(np.cross(p, V.p_E_B_array)) < 1e-12


@pytest.mark.parametrize(
    ("direction", "pivot"), [("axial", "com"), ("lateral", "com"), ("lateral", "mount"), ("lateral", "tip")]
)
def test_tool_deflects_by_force_over_stiffness(direction, pivot):
    """Equal and opposite forces on the tip and on the vehicle at the same point: the tool settles at F / k.

    Laterally the force bends the coupling by its moment about the pivot: none with the pivot at the tip's
    centre (a remote centre of compliance).
    """
    p = SceneParams(tool_pivot=pivot)
    m = model(tool_pivot=pivot)
    m.opt.gravity[:] = 0.0
    d = mujoco.MjData(m)
    tool, veh = body(m, TOOL_BODY), body(m, BODY_NAME)
    tip = geom(m, EE_TIP_GEOM)
    F_mag = 2.0
    F = np.array([0.0, -F_mag, 0.0]) if direction == "axial" else np.array([F_mag, 0.0, 0.0])  # tool along +y
    for _ in range(4000):
        mujoco.mj_forward(m, d)
        d.qfrc_applied[:] = 0.0
        point = d.geom_xpos[tip].copy()
        mujoco.mj_applyFT(m, d, F, np.zeros(3), point, tool, d.qfrc_applied)
        mujoco.mj_applyFT(m, d, -F, np.zeros(3), point, veh, d.qfrc_applied)
        mujoco.mj_step(m, d)
    q = {m.joint(j).name: d.qpos[m.jnt_qposadr[j]] for j in range(m.njnt) if m.joint(j).name != "root"}
    assert set(q) == {TOOL_AXIAL_JOINT, *TOOL_BEND_JOINTS}
    if direction == "axial":
        assert q[TOOL_AXIAL_JOINT] == pytest.approx(-F_mag / p.tool_axial_stiffness, rel=0.02)
        assert abs(q[TOOL_BEND_JOINTS[0]]) + abs(q[TOOL_BEND_JOINTS[1]]) < 1e-6
    else:
        centre = V.p_E_B_array * (1.0 - 0.008 / float(np.linalg.norm(V.p_E_B_array)))
        arm = float(np.linalg.norm(centre - tool_pivot_B(V, p)))  # lever from the pivot to the tip's centre
        angle = math.hypot(q[TOOL_BEND_JOINTS[0]], q[TOOL_BEND_JOINTS[1]])
        if pivot == "tip":
            assert arm == 0.0 and angle < 1e-6
        else:
            assert angle == pytest.approx(F_mag * arm / p.tool_bending_stiffness, rel=0.03)


def test_simulator_reads_the_tool_contact_as_the_end_effectors():
    """Pushed onto the wall at the EE, the vehicle leans on the tool's tip: the EE's contact, no other part's."""
    sim = Simulator(V, "wall", SimParams())
    p0, R0 = sim.default_start()
    n = sim.scene.normal_W
    sim.reset(p0 - (sim.params.scene.start_standoff - 0.005) * n, R0)
    sim.set_external_wrench(-3.0 * n, at="ee")
    cmd = RotorCommand(0.0, sim.hover_speeds_hz(R0))
    row = np.zeros(64)
    touching, peak_N = 0, 0.0
    for _ in range(1500):
        sim.step(cmd)
        tr = sim.truth
        if tr.other_contact:  # uncontrolled, the vehicle tips over onto the wall in the end: stop there
            break
        if tr.in_contact:
            touching += 1
            assert tr.contact_force_W @ n >= 0.0  # the wall pushes back along its normal, never pulls
            peak_N = max(peak_N, float(tr.contact_force_W @ n))
            sim.truth_row(row)
            np.testing.assert_allclose(row[22:25], tr.contact_force_W, atol=1e-9)  # the compiled truth row agrees
    assert touching > 100 and peak_N > 1.0  # before any other part touches, the tip leans on the wall


def _tip_contact(m, d):
    """(dist, frame normal) of the tip's contact with the environment after ``mj_forward``, or None."""
    tip = geom(m, EE_TIP_GEOM)
    for c in d.contact[: d.ncon]:
        if tip in (c.geom1, c.geom2):
            sign = 1.0 if c.geom1 == tip else -1.0  # the frame's normal points from geom1 to geom2
            return c.dist, sign * np.asarray(c.frame[:3])
    return None


def test_tip_meets_pipe_and_wall_through_exact_distances():
    """The tip's contacts are MuJoCo's analytic sphere tests: depth and normal exact wherever the tip slides.

    An iterative convex test (GJK/EPA, MPR) would give them to its tolerance only and could jitter from one
    step to the next as the tip slides (docs/fidelity.md, "Where the sliding chatter comes from").
    """
    rng = np.random.default_rng(12)
    p = SceneParams()
    centre_B = V.p_E_B_array - 0.008 * V.p_E_B_array / np.linalg.norm(V.p_E_B_array)
    for scene in ("pipe", "wall"):
        m = mujoco.MjModel.from_xml_string(build_mjcf(V, scene, SceneParams(tool_compliant=False), 1e-3))
        d = mujoco.MjData(m)
        for _ in range(40):
            depth = rng.uniform(1e-5, 5e-4)
            if scene == "pipe":  # a point of the slid arc (0 to 50 deg of roll), anywhere along the pipe
                th = math.radians(rng.uniform(0.0, 50.0))
                n_W = np.array([0.0, -math.cos(th), math.sin(th)])
                axial = np.array([rng.uniform(-0.3, 0.3), 0.0, 0.0])
                surface = np.asarray(p.pipe_centre) + axial + p.pipe_radius * n_W
            else:
                n_W = np.asarray(p.wall_normal, dtype=float)
                surface = np.asarray(p.wall_point) + rng.uniform(-0.2, 0.2, 3) * np.array([1.0, 0.0, 1.0])
            R = attitude_pointing(V.p_E_B_array / np.linalg.norm(V.p_E_B_array), -n_W)
            tip_W = surface + (0.008 - depth) * n_W
            d.qpos[:3] = tip_W - R @ centre_B
            mujoco.mju_mat2Quat(d.qpos[3:7], R.ravel())
            mujoco.mj_forward(m, d)
            dist, normal = _tip_contact(m, d)
            assert dist == pytest.approx(-depth, abs=1e-12), scene
            np.testing.assert_allclose(normal, -n_W, atol=1e-12)  # from the tip into the surface


def _push_on_wall(f_t: float, steps: int = 3000, f_n: float = 3.0):
    """The tool's tip pushed on the wall by ``f_n`` with ``f_t`` along it (on the vehicle, at the tip), no gravity.

    Steps as the simulator does (``mj_forward``, the tool's friction law, ``mj_Euler``). Returns the contact
    block (its wrench of the last step), the tip's position along the wall per step [m], the direction along
    the wall and the wall's normal.
    """
    p = SceneParams()
    m = model("wall")
    m.opt.gravity[:] = 0.0
    d = mujoco.MjData(m)
    block = EeContact(m, data=d, mu=p.friction, tool_mass=p.tool_mass)
    n = np.asarray(p.wall_normal, dtype=float)
    t = np.array([1.0, 0.0, 0.0])
    R = attitude_pointing(V.p_E_B_array / np.linalg.norm(V.p_E_B_array), -n)
    d.qpos[:3] = np.asarray(p.wall_point) - R @ V.p_E_B_array + 1e-4 * n
    mujoco.mju_mat2Quat(d.qpos[3:7], R.ravel())
    veh, tip = body(m, BODY_NAME), geom(m, EE_TIP_GEOM)
    along = []
    for _ in range(steps):
        mujoco.mj_forward(m, d)
        if friction_step(block.friction[0], d.sensordata):  # as the simulator does: the friction in qacc
            mujoco.mj_fwdAcceleration(m, d)
            mujoco.mj_fwdConstraint(m, d)
            mujoco.mj_sensorAcc(m, d)
        along.append(float(d.geom_xpos[tip] @ t))
        d.qfrc_applied[:] = 0.0
        d.qfrc_applied[:3] = -20.0 * d.qvel[:3]  # a damped vehicle: no slow sway on the tool's bending spring
        d.qfrc_applied[3:6] = -0.5 * d.qvel[3:6]
        mujoco.mj_applyFT(m, d, -f_n * n + f_t * t, np.zeros(3), d.geom_xpos[tip].copy(), veh, d.qfrc_applied)
        mujoco.mj_Euler(m, d)
    block.step(d.sensordata, d.site_xpos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, EE_SITE)].copy())
    return block, np.array(along), t, n


def test_tool_friction_sticks_inside_the_cone():
    """A tangential load below mu f_n: the contact point does not slip and friction holds the load (Coulomb)."""
    block, along, t, n = _push_on_wall(0.6)
    fr = block.friction[0]
    assert fr["n"][0] == 1 and fr["n"][1] == 0  # the tip alone touches
    assert np.linalg.norm(fr["v"][0, 0]) < 1e-6  # no slip [m/s]
    f = fr["f"][0, 0]
    f_W = block.state[0]["f_W"]  # the truth wrench: the wall's normal force plus the friction
    assert f_W @ n == pytest.approx(3.0, rel=1e-2)
    assert -0.6 < f @ t < -0.55  # holds the load (less what the damped vehicle takes)
    assert np.linalg.norm(f) < SceneParams().friction * (f_W @ n)  # inside the cone
    assert abs(f @ n) < 1e-12 and f_W @ t == pytest.approx(f @ t, abs=1e-12)
    assert np.ptp(along[-1000:]) < 1e-4  # the tip stays put (it may roll by microns)


def test_tool_friction_slides_at_mu_times_the_normal_force_outside_the_cone():
    block, along, t, n = _push_on_wall(1.5)
    assert along[-1] - along[-1000] > 0.05  # it slides (and accelerates) along the load
    fr = block.friction[0]
    f = fr["f"][0, : fr["n"][0]].sum(axis=0)
    f_n = block.state[0]["f_W"] @ n  # the wall's normal force (friction has no normal part)
    assert f_n > 1.0
    # kinetic friction mu f_n (of the normal force before the friction entered the step: 1e-5 apart)
    assert np.linalg.norm(f) == pytest.approx(SceneParams().friction * f_n, rel=1e-4)
    v = fr["v"][0, 0]
    assert v @ t > 0.01 and f @ v == pytest.approx(-np.linalg.norm(f) * np.linalg.norm(v), rel=1e-3)  # against the slip


@pytest.mark.parametrize("law", ["stick-slip", "mujoco"])
def test_friction_law_decides_who_applies_the_tools_friction(law):
    """stick-slip: MuJoCo's contacts of the EE geoms are frictionless (the simulator applies Coulomb's law to the
    tool); mujoco: MuJoCo's cone, as for every other contact."""
    m = model("pipe", friction_law=law)
    d = mujoco.MjData(m)
    block = EeContact(m, data=d, mu=0.3, tool_mass=0.01)
    for name in (EE_TIP_GEOM, EE_ROD_GEOM):
        assert m.geom_condim[geom(m, name)] == (1 if law == "stick-slip" else 3)
    assert m.geom_condim[geom(m, "pipe")] == 3
    assert bool(block.friction[0]["enabled"]) == (law == "stick-slip")
    assert block.friction[0]["h"] == pytest.approx(1e-3)
    # the rigid tool keeps MuJoCo's cone whatever the law
    rigid = model("pipe", friction_law=law, tool_compliant=False)
    assert rigid.geom_condim[geom(rigid, EE_TIP_GEOM)] == 3
    assert not EeContact(rigid, data=mujoco.MjData(rigid), mu=0.3, tool_mass=0.01).friction[0]["enabled"]
