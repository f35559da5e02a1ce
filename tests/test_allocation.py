"""Allocation QP (SPEC §4.2): both backends against an independent bounded least-squares oracle."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear
from scipy.spatial.transform import Rotation

from omnirotor.config import from_mapping
from omnirotor.control.allocation import SOLVERS, AllocationParams, AllocationStatus, Allocator
from omnirotor.errors import InputError
from omnirotor.so3 import rot_x
from omnirotor.vehicle import load_vehicle

VEHICLE = load_vehicle("omnirotor")
LAMBDA = AllocationParams().reg_lambda
# Largest zero-moment force of the Omnirotor is ~37 N (SPEC §1.3): the wrench scale of the tolerances.
WRENCH_SCALE_N = 37.0


def oracle(w_ref, R_WB, A, lo=None, hi=None):
    """argmin ||w_ref - blkdiag(R, I3) A u||² + lambda ||u||² over the box, by scipy's BVLS.

    Works in u / 48400 so that the columns are O(1); the world-frame M is built here independently of the
    allocator's body-frame reformulation.
    """
    n = A.shape[1]
    s = VEHICLE.u_max
    lo = np.full(n, VEHICLE.u_min) if lo is None else lo
    hi = np.full(n, VEHICLE.u_max) if hi is None else hi
    free = lo < hi  # rotors pinned to lo == hi are removed from the problem
    M = np.vstack([R_WB @ A[:3], A[3:]]) * s
    K = np.vstack([M[:, free], np.sqrt(LAMBDA) * s * np.eye(free.sum())])
    b = np.concatenate([w_ref - M[:, ~free] @ (lo[~free] / s), np.zeros(free.sum())])
    res = lsq_linear(K, b, bounds=(lo[free] / s, hi[free] / s), method="bvls", tol=1e-15)
    u = lo.copy()
    u[free] = res.x * s
    return u


def wrench_W(u, R_WB, A=VEHICLE.A_nom):
    w = A @ u
    return np.concatenate([R_WB @ w[:3], w[3:]])


def cost(u, w_ref, R_WB, A=VEHICLE.A_nom):
    r = w_ref - wrench_W(u, R_WB, A)
    return float(r @ r + LAMBDA * u @ u)


def test_params_validate():
    for bad in (
        {"solver": "osqp"},
        {"reg_lambda": 0.0},
        {"reg_lambda": float("nan")},
        {"max_iter": 0},
        {"eps_abs": -1.0},
        {"saturation_tol": 0.7},
    ):
        with pytest.raises(InputError):
            AllocationParams(**bad)
    with pytest.raises(InputError):
        from_mapping(AllocationParams, {"solver": "daqp", "lambda": 1e-12})
    assert from_mapping(AllocationParams, {"solver": "proxsuite"}).solver == "proxsuite"


@pytest.mark.parametrize("solver", SOLVERS)
def test_upright_hover_is_the_spec_value(solver):
    alloc = Allocator(VEHICLE, AllocationParams(solver=solver))
    w_ref = np.array([0.0, 0.0, VEHICLE.weight, 0.0, 0.0, 0.0])
    u = alloc.solve(w_ref, np.eye(3), VEHICLE.A_nom)
    # SPEC §1.2: every rotor at 20 667 Hz² (143.8 Hz); SPEC §4.2: ~2e-4 N wrench error from lambda.
    np.testing.assert_allclose(u, 20667.0, atol=1.0)
    np.testing.assert_allclose(np.sqrt(u), 143.8, atol=0.05)
    assert np.abs(wrench_W(u, np.eye(3)) - w_ref).max() <= 1e-3
    assert alloc.status is AllocationStatus.OK
    assert not alloc.saturated


@pytest.mark.parametrize("solver", SOLVERS)
def test_matches_oracle_on_random_wrenches_and_attitudes(solver):
    rng = np.random.default_rng(11)
    alloc = Allocator(VEHICLE, AllocationParams(solver=solver))
    A = VEHICLE.A_nom
    n_saturated = 0
    for k in range(40):
        R = Rotation.random(random_state=rng).as_matrix()
        if k % 2 == 0:  # feasible: the wrench of an input well inside the box
            u_true = rng.uniform(0.8 * VEHICLE.u_min, 0.8 * VEHICLE.u_max, VEHICLE.n_rotors)
            w_ref = wrench_W(u_true, R)
        else:  # mostly infeasible: 40-90 N and up to 8 N·m in random directions
            d = rng.normal(size=6)
            w_ref = np.concatenate(
                [rng.uniform(40, 90) * d[:3] / np.linalg.norm(d[:3]), rng.uniform(0, 8) * d[3:] / np.linalg.norm(d[3:])]
            )
        u = alloc.solve(w_ref, R, A).copy()
        u_star = oracle(w_ref, R, A)
        assert np.all(np.isfinite(u))
        assert np.all(u >= VEHICLE.u_min) and np.all(u <= VEHICLE.u_max)
        # The achieved wrench agrees with the oracle's to 1e-6 of the wrench scale ...
        err = np.abs(wrench_W(u, R) - wrench_W(u_star, R)).max()
        assert err <= 1e-6 * WRENCH_SCALE_N, (k, err)
        # ... the cost is optimal, and the inputs themselves agree (the solution is unique).
        assert cost(u, w_ref, R) <= cost(u_star, w_ref, R) * (1 + 1e-9) + 1e-12
        np.testing.assert_allclose(u, u_star, atol=1e-5 * VEHICLE.u_max)
        if k % 2 == 0 and not alloc.saturated:
            # Feasible and unconstrained: only the regulariser's bias remains, |r| <= lambda/sigma_min² |w|.
            bound = LAMBDA / np.linalg.svd(A, compute_uv=False)[-1] ** 2 * np.linalg.norm(w_ref)
            assert np.linalg.norm(wrench_W(u, R) - w_ref) <= bound
        n_saturated += alloc.saturated
        assert alloc.saturated == bool(np.any(np.abs(np.abs(u_star) - VEHICLE.u_max) < 1.0))
    assert n_saturated >= 10  # the infeasible half really exercised the bounds


@pytest.mark.parametrize("solver", SOLVERS)
def test_infeasible_thrust_saturates_every_rotor(solver):
    alloc = Allocator(VEHICLE, AllocationParams(solver=solver))
    w_ref = np.array([0.0, 0.0, 100.0, 0.0, 0.0, 0.0])  # far beyond the ~37 N available upward
    u = alloc.solve(w_ref, np.eye(3), VEHICLE.A_nom)
    # Every rotor axis has a positive z component (cos 50 deg), so all rotors go to full forward speed.
    np.testing.assert_allclose(u, VEHICLE.u_max, rtol=1e-9)
    np.testing.assert_allclose(u, oracle(w_ref, np.eye(3), VEHICLE.A_nom), rtol=1e-9)
    assert alloc.saturated and alloc.status is AllocationStatus.OK
    # Upside down, the same world force needs every rotor reversed.
    R = rot_x(np.pi)
    u = alloc.solve(w_ref, R, VEHICLE.A_nom)
    np.testing.assert_allclose(u, VEHICLE.u_min, rtol=1e-9)


@pytest.mark.parametrize("solver", SOLVERS)
def test_new_map_rebuilds_the_problem(solver):
    rng = np.random.default_rng(3)
    alloc = Allocator(VEHICLE, AllocationParams(solver=solver))
    A_big = VEHICLE.A_nom * np.array([1.15, 1.15, 1.15, 1.0, 1.0, 1.0])[:, None]
    for A in (VEHICLE.A_nom, A_big, VEHICLE.A_nom, A_big):
        R = Rotation.random(random_state=rng).as_matrix()
        w_ref = np.concatenate([[0, 0, VEHICLE.weight] + rng.normal(0, 1.0, 3), rng.normal(0, 0.2, 3)])
        u = alloc.solve(w_ref, R, A)
        np.testing.assert_allclose(u, oracle(w_ref, R, A), atol=1e-5 * VEHICLE.u_max)
    # The larger map needs 1/1.15 of the input for the same hover force, up to the regulariser's
    # relative bias lambda / sigma_min(A)² (6e-4).
    hover = np.array([0, 0, VEHICLE.weight, 0, 0, 0.0])
    u_nom = alloc.solve(hover, np.eye(3), VEHICLE.A_nom).copy()
    u_big = alloc.solve(hover, np.eye(3), A_big).copy()
    bias = LAMBDA / np.linalg.svd(VEHICLE.A_nom, compute_uv=False)[-1] ** 2
    np.testing.assert_allclose(u_big, u_nom / 1.15, rtol=bias)
    assert np.abs(u_big - u_nom / 1.15).max() > 0.01  # and it is really the other map's solution


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_nonfinite_input_holds_last_safe_command(solver):
    alloc = Allocator(VEHICLE, AllocationParams(solver=solver))
    # Before any solve the held command is the upright hover input.
    bad = np.array([np.nan, 0, VEHICLE.weight, 0, 0, 0])
    np.testing.assert_allclose(alloc.solve(bad, np.eye(3), VEHICLE.A_nom), VEHICLE.hover_input())
    assert alloc.status is AllocationStatus.NONFINITE
    R = rot_x(0.3)
    w_ref = np.array([1.0, -0.5, VEHICLE.weight, 0.1, 0.0, -0.05])
    u_good = alloc.solve(w_ref, R, VEHICLE.A_nom).copy()
    assert alloc.status is AllocationStatus.OK
    R_nan = R.copy()
    R_nan[1, 2] = np.nan
    A_inf = VEHICLE.A_nom.copy()
    A_inf[4, 5] = np.inf
    cases = [
        (bad, R, VEHICLE.A_nom),
        (w_ref * np.inf, R, VEHICLE.A_nom),
        (w_ref, R_nan, VEHICLE.A_nom),
        (w_ref, R, A_inf),
    ]
    for i, args in enumerate(cases, start=1):
        u = alloc.solve(*args)
        np.testing.assert_array_equal(u, u_good)
        assert alloc.status is AllocationStatus.NONFINITE
        assert alloc.n_nonfinite == i + 1
    # Good input again: back to normal, and the map is the nominal one again.
    np.testing.assert_allclose(alloc.solve(w_ref, R, VEHICLE.A_nom), u_good, rtol=1e-9)
    assert alloc.status is AllocationStatus.OK


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("failure", ["status", "nan"])
def test_solver_failure_falls_back_to_clipped_pinv(solver, failure, monkeypatch):
    alloc = Allocator(VEHICLE, AllocationParams(solver=solver))
    result = None if failure == "status" else np.full(VEHICLE.n_rotors, np.nan)
    monkeypatch.setattr(alloc._backend, "solve", lambda f: result)
    R = rot_x(-0.4)
    A = VEHICLE.A_nom
    for k, f_up in enumerate((VEHICLE.weight, 80.0), start=1):  # feasible, then far beyond the bounds
        w_ref = np.array([0.3, 0.0, f_up, 0.0, 0.1, 0.0])
        w_B = np.concatenate([R.T @ w_ref[:3], w_ref[3:]])
        expected = np.clip(np.linalg.pinv(A) @ w_B, VEHICLE.u_min, VEHICLE.u_max)
        u = alloc.solve(w_ref, R, A)
        np.testing.assert_allclose(u, expected, rtol=1e-9, atol=1e-6)
        assert alloc.status is AllocationStatus.FALLBACK
        assert alloc.n_fallbacks == k
    assert alloc.saturated  # the 80 N request clipped some rotors
    alloc.reset()
    assert alloc.n_fallbacks == 0 and alloc.status is AllocationStatus.OK


@pytest.mark.parametrize("solver", SOLVERS)
def test_failed_rotor_hover_on_seven(solver):
    alloc = Allocator(VEHICLE, AllocationParams(solver=solver))
    w_ref = np.array([0.0, 0.0, VEHICLE.weight, 0.0, 0.0, 0.0])
    for i in range(VEHICLE.n_rotors):
        mask = np.zeros(VEHICLE.n_rotors, dtype=bool)
        mask[i] = True
        alloc.set_failed_rotors(mask)
        u = alloc.solve(w_ref, np.eye(3), VEHICLE.A_nom)
        assert u[i] == 0.0
        # The Omnirotor hovers upright on any seven rotors, within the ±220 Hz limits.
        assert np.abs(wrench_W(u, np.eye(3)) - w_ref).max() <= 1e-3
        lo = np.where(mask, 0.0, VEHICLE.u_min)
        hi = np.where(mask, 0.0, VEHICLE.u_max)
        np.testing.assert_allclose(u, oracle(w_ref, np.eye(3), VEHICLE.A_nom, lo, hi), atol=1e-5 * VEHICLE.u_max)
        assert not alloc.saturated  # the pinned rotor does not count
        np.testing.assert_array_equal(alloc.failed_rotors, mask)
    # Two rotors out: rotors 1 and 7 (diagonal) still allow upright hover with 6 square columns; rotors
    # 1 and 2 (adjacent, both on top) do not, and the QP returns the best saturated compromise.
    for pair, feasible in (([0, 6], True), ([0, 1], False)):
        mask = np.zeros(VEHICLE.n_rotors, dtype=bool)
        mask[pair] = True
        alloc.set_failed_rotors(mask)
        u = alloc.solve(w_ref, np.eye(3), VEHICLE.A_nom)
        assert np.all(u[pair] == 0.0)
        lo = np.where(mask, 0.0, VEHICLE.u_min)
        hi = np.where(mask, 0.0, VEHICLE.u_max)
        np.testing.assert_allclose(u, oracle(w_ref, np.eye(3), VEHICLE.A_nom, lo, hi), atol=1e-5 * VEHICLE.u_max)
        assert alloc.saturated != feasible
        assert (np.abs(wrench_W(u, np.eye(3)) - w_ref).max() <= 1e-3) == feasible
    alloc.set_failed_rotors(None)
    u = alloc.solve(w_ref, np.eye(3), VEHICLE.A_nom)
    np.testing.assert_allclose(u, 20667.0, atol=1.0)
    with pytest.raises(InputError):
        alloc.set_failed_rotors(np.ones(VEHICLE.n_rotors, dtype=bool))
    with pytest.raises(InputError):
        alloc.set_failed_rotors(np.zeros(3, dtype=bool))


@pytest.mark.parametrize("solver", SOLVERS)
def test_output_always_finite_and_bounded(solver):
    rng = np.random.default_rng(5)
    alloc = Allocator(VEHICLE, AllocationParams(solver=solver))
    for _ in range(30):
        R = Rotation.random(random_state=rng).as_matrix()
        w_ref = rng.normal(0, 1, 6) * 10.0 ** rng.uniform(-3, 6)
        u = alloc.solve(w_ref, R, VEHICLE.A_nom)
        assert np.all(np.isfinite(u))
        assert np.all((VEHICLE.u_min <= u) & (u <= VEHICLE.u_max))


def test_backends_agree_step_by_step():
    rng = np.random.default_rng(8)
    allocs = [Allocator(VEHICLE, AllocationParams(solver=s)) for s in SOLVERS]
    R = np.eye(3)
    for _ in range(100):  # a warm-started sequence near hover
        R = R @ rot_x(rng.normal(0, 0.02))
        w_ref = np.concatenate([[0, 0, VEHICLE.weight] + rng.normal(0, 0.5, 3), rng.normal(0, 0.1, 3)])
        u0, *others = (a.solve(w_ref, R, VEHICLE.A_nom).copy() for a in allocs)
        for u1 in others:
            np.testing.assert_allclose(u0, u1, atol=1e-5 * VEHICLE.u_max)


def test_regulariser_scales_with_the_thrust_coefficient():
    """SPEC §4.2's lambda is the Omnirotor's; on a small vehicle it is scaled by c_f² (else the hover sags)."""
    import dataclasses

    from omnirotor.control.allocation import REG_REFERENCE_C_F

    assert VEHICLE.c_f == REG_REFERENCE_C_F  # the Omnirotor's factor is exactly 1
    assert Allocator(VEHICLE).reg_lambda_used == AllocationParams().reg_lambda
    quad = load_vehicle("quadrotor")
    weight = quad.mass * quad.gravity
    w_ref = np.array([0.0, 0.0, weight, 0.0, 0.0, 0.0])
    scaled = Allocator(quad)
    assert scaled.reg_lambda_used == pytest.approx(1e-12 * (quad.c_f / REG_REFERENCE_C_F) ** 2, rel=1e-12)
    thrust = (quad.A_nom @ scaled.solve(w_ref, np.eye(3), quad.A_nom))[2]
    assert abs(thrust - weight) < 1e-3 * weight
    absolute = Allocator(quad, dataclasses.replace(AllocationParams(), reg_scale_with_c_f=False))
    short = (quad.A_nom @ absolute.solve(w_ref, np.eye(3), quad.A_nom))[2]
    assert short < 0.9 * weight  # the unscaled regulariser eats a tenth or more of the hover thrust
    with pytest.raises(InputError):
        AllocationParams(reg_scale_with_c_f="yes")
