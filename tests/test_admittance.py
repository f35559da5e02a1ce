"""Admittance filter, EE wrench and EE-to-body reference (SPEC §4.4, §5.1)."""

import math

import numpy as np
import pytest

from omnirotor.control.admittance import (
    ADMITTANCE_PRESETS,
    AdmittanceFilter,
    AdmittanceParams,
    body_reference_from_ee,
    ee_wrench_W,
)
from omnirotor.control.trajectory import PoseTrajectory, ReferenceSample, Waypoint
from omnirotor.errors import InputError
from omnirotor.so3 import exp_so3, log_so3, vee

DT = 1e-3


def _run(filt: AdmittanceFilter, f, m, seconds: float, trace: bool = False):
    f = np.asarray(f, dtype=float)
    m = np.asarray(m, dtype=float)
    xs = []
    for _ in range(int(round(seconds / DT))):
        filt.step(f, m, DT)
        if trace:
            xs.append(filt.xi_p_W.copy())
    return np.array(xs)


def test_table2_presets():
    pc = AdmittanceParams.preset("PC")
    assert pc.mass_pos == (1.5,) * 3 and pc.damping_pos == (13.5,) * 3 and pc.stiffness_pos == (30.0,) * 3
    assert pc.mass_rot == (1.5,) * 3 and pc.damping_rot == (13.5,) * 3 and pc.stiffness_rot == (30.0,) * 3
    assert AdmittanceParams.preset("SD") == pc
    pih = AdmittanceParams.preset("PiH")
    assert pih.mass_rot == (0.5,) * 3 and pih.damping_rot == (2.14,) * 3 and pih.stiffness_rot == (2.29,) * 3
    assert pih.stiffness_pos == (35.0,) * 3 and pih.damping_pos == (15.0,) * 3
    free = AdmittanceParams.preset("free")
    assert free == AdmittanceParams()
    assert free.mass_pos == (1.5,) * 3 and free.damping_pos == (40.0,) * 3 and free.stiffness_pos == (100.0,) * 3
    # The paper's sets are critically damped (SPEC §5.1: D ~ 2 sqrt(M K)).
    for name in ("PC", "SD", "PiH"):
        for zetas in ADMITTANCE_PRESETS[name].damping_ratios():
            assert all(abs(z - 1.0) < 0.04 for z in zetas), (name, zetas)
    with pytest.raises(InputError):
        AdmittanceParams.preset("bouncy")


def test_validation():
    with pytest.raises(InputError):
        AdmittanceParams(mass_pos=(0.0, 1.0, 1.0))
    with pytest.raises(InputError):
        AdmittanceParams(damping_rot=(-1.0, 1.0, 1.0))
    with pytest.raises(InputError):
        AdmittanceParams(stiffness_pos=(1.0, math.nan, 1.0))
    with pytest.raises(InputError):
        AdmittanceParams(stiffness_pos=(1.0, 1.0))
    AdmittanceParams(stiffness_pos=(0.0, 0.0, 0.0))  # a pure damper is allowed


def test_constant_force_gives_offset_f_over_k_per_axis():
    params = AdmittanceParams(stiffness_pos=(50.0, 100.0, 200.0), damping_pos=(20.0, 30.0, 40.0))
    filt = AdmittanceFilter(params)
    f = np.array([2.0, -3.0, 1.0])
    _run(filt, f, np.zeros(3), 8.0)
    np.testing.assert_allclose(filt.xi_p_W, f / np.array(params.stiffness_pos), rtol=1e-6)
    np.testing.assert_allclose(filt.xi_p_dot_W, 0.0, atol=1e-6)
    np.testing.assert_allclose(filt.R_xi, np.eye(3), atol=1e-15)  # no moment, no rotation


def test_critically_damped_step_has_no_overshoot():
    params = AdmittanceParams.preset("PC")
    filt = AdmittanceFilter(params)
    f = 3.0  # the PC design point: 3 N -> 0.1 m
    xs = _run(filt, [f, 0.0, 0.0], np.zeros(3), 6.0, trace=True)[:, 0]
    x_ss = f / params.stiffness_pos[0]
    assert abs(x_ss - 0.1) < 1e-12
    assert xs.max() <= x_ss * (1 + 1e-3)
    assert np.all(np.diff(xs) >= -1e-12)  # monotone rise
    # 2nd-order critically damped rise: at t = 1/wn the response is 1 - 2/e of the final value.
    wn = math.sqrt(params.stiffness_pos[0] / params.mass_pos[0])
    k = int(round(1.0 / wn / DT))
    assert xs[k - 1] / x_ss == pytest.approx(1 - 2 / math.e, abs=0.01)


def test_upward_force_raises_the_reference():
    filt = AdmittanceFilter(AdmittanceParams.preset("SD"))
    _run(filt, [0.0, 0.0, 1.0], np.zeros(3), 2.0)
    assert filt.xi_p_W[2] > 0.02
    desired = ReferenceSample.at_rest(np.array([0.1, 0.2, 1.0]), np.eye(3))
    out = filt.compliant_reference(desired, ReferenceSample())
    assert out.p_W[2] > desired.p_W[2] + 0.02
    np.testing.assert_allclose(out.p_W[:2], desired.p_W[:2], atol=1e-15)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_constant_moment_rotates_by_asin_m_over_k(axis):
    params = AdmittanceParams.preset("PiH")
    filt = AdmittanceFilter(params)
    m = np.zeros(3)
    m[axis] = 0.6  # PiH design point: 0.6 N m -> 15 deg
    _run(filt, np.zeros(3), m, 15.0)
    phi = log_so3(filt.R_xi)
    k_r = params.stiffness_rot[axis]
    # The spring acts on 1/2 (R - R^T)^v = sin(angle) axis, so the exact equilibrium is asin(m / K_R).
    assert phi[axis] == pytest.approx(math.asin(0.6 / k_r), rel=1e-6)
    assert math.degrees(phi[axis]) == pytest.approx(15.0, abs=0.5)  # ~ m / K_R for small angles
    np.testing.assert_allclose(np.delete(phi, axis), 0.0, atol=1e-12)
    np.testing.assert_allclose(filt.xi_p_W, 0.0, atol=1e-15)
    np.testing.assert_allclose(filt.R_xi.T @ filt.R_xi, np.eye(3), atol=1e-12)


def test_ee_wrench_of_a_force_at_the_tip_has_no_tip_moment():
    rng = np.random.default_rng(5)
    p_E_B = np.array([0.0, 0.5, 0.0])
    for _ in range(10):
        R = exp_so3(rng.normal(size=3))
        f_W = rng.normal(size=3)
        m_tip_W = rng.normal(size=3)
        # What the observer sees at the CoM for force f_W and moment m_tip_W applied at the tip:
        m_com_B = R.T @ (np.cross(R @ p_E_B, f_W) + m_tip_W)
        f_E, m_E = np.empty(3), np.empty(3)
        ee_wrench_W(f_W, m_com_B, R, p_E_B, f_E, m_E)
        np.testing.assert_allclose(f_E, f_W, atol=1e-14)
        np.testing.assert_allclose(m_E, m_tip_W, atol=1e-12)


def test_body_reference_from_ee_is_consistent():
    rng = np.random.default_rng(6)
    p_E_B = np.array([0.0, 0.5, 0.0])
    traj = PoseTrajectory(
        [
            Waypoint(0.0, rng.normal(size=3), exp_so3(rng.normal(size=3))),
            Waypoint(2.0, rng.normal(size=3), exp_so3(rng.normal(size=3))),
        ]
    )
    h = 1e-5
    ee, body = ReferenceSample(), [ReferenceSample() for _ in range(3)]
    for t in (0.4, 1.0, 1.6):
        for j, tj in enumerate((t - h, t, t + h)):
            body_reference_from_ee(traj.sample(tj, ee), p_E_B, body[j])
        a, b, c = body
        # The EE tip of the body reference is the EE reference.
        np.testing.assert_allclose(b.p_W + b.R_WB @ p_E_B, traj(t).p_W, atol=1e-14)
        np.testing.assert_allclose(b.R_WB, traj(t).R_WB, atol=1e-15)
        np.testing.assert_allclose((c.p_W - a.p_W) / (2 * h), b.v_W, atol=1e-6)
        np.testing.assert_allclose((c.v_W - a.v_W) / (2 * h), b.a_W, atol=1e-5)


def test_compliant_reference_rates_are_consistent():
    # Drive the filter with a varying wrench along a rotating desired trajectory; the compliant
    # reference's rates must be the time derivatives of its pose (exact composition of R_xi R_d).
    dt = 1e-5
    filt = AdmittanceFilter(AdmittanceParams.preset("PiH"))
    traj = PoseTrajectory(
        [Waypoint(0.0, np.zeros(3), np.eye(3)), Waypoint(1.0, [0.2, 0.0, 0.1], exp_so3(np.array([0.3, -0.5, 0.8])))]
    )
    # Put the filter into motion first.
    for _ in range(2000):
        filt.step(np.array([1.0, -2.0, 0.5]), np.array([0.3, 0.2, -0.4]), 1e-3)
    refs = []
    t0 = 0.4
    for i in range(3):
        filt.step(np.array([1.0, -2.0, 0.5]), np.array([0.3, 0.2, -0.4]), dt)
        refs.append(filt.compliant_reference(traj(t0 + i * dt), ReferenceSample()))
    a, b, c = refs
    np.testing.assert_allclose((c.p_W - a.p_W) / (2 * dt), b.v_W, rtol=1e-3, atol=1e-6)
    omega_fd = vee((c.R_WB - a.R_WB) / (2 * dt) @ b.R_WB.T)
    np.testing.assert_allclose(omega_fd, b.omega_W, rtol=1e-3, atol=1e-5)
    np.testing.assert_allclose((c.omega_W - a.omega_W) / (2 * dt), b.alpha_W, rtol=2e-3, atol=1e-4)
    # And it really differs from the naive sum omega_xi + omega_d.
    assert np.linalg.norm(b.omega_W - (filt.omega_xi_W + traj(t0 + dt).omega_W)) > 1e-3


def test_reset_returns_to_the_desired_reference():
    filt = AdmittanceFilter()
    _run(filt, [1.0, 1.0, 1.0], [0.5, 0.5, 0.5], 0.5)
    filt.reset()
    desired = ReferenceSample.at_rest(np.array([1.0, 2.0, 3.0]), exp_so3(np.array([0.1, 0.2, 0.3])))
    out = filt.compliant_reference(desired, ReferenceSample())
    np.testing.assert_array_equal(out.data, desired.data)
