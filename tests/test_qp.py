"""The compiled box-constrained QP solver of the allocation (``control/_qp.py``, SPEC §4.2).

* on random SPD problems of the allocation's shape (H = AsᵀAs + lambda_s I, As 6 x n), with bounds active and
  variables pinned: the KKT conditions hold to 1e-12 relative, and the answer agrees with daqp and with SciPy's
  bounded least squares (an independent method);
* any warm start, however wrong, gives the cold start's answer; the right one finishes in 1 iteration, and so
  does nearly every step of a slowly varying 1 kHz-like sequence, also across a change of H;
* non-finite input, a non-positive-definite H, an empty box and the iteration cap give their codes;
* the solver can be called from compiled code (the future one-loop control period);
* ``alloc_set_map`` writes the allocator's arrays as the NumPy code it replaced, and the allocator's default
  backend keeps its arrays as shared attributes.
"""

from __future__ import annotations

import daqp
import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import lsq_linear

from omnirotor.control import _qp
from omnirotor.control.allocation import AllocationParams, Allocator, alloc_set_map
from omnirotor.vehicle import load_vehicle

VEHICLE = load_vehicle("omnirotor")
SETTINGS = settings(max_examples=80, deadline=None, derandomize=True)
KKT_TOL = 1e-12  # relative to the rounding scale |f_i| + sum_j |H_ij x_j| of each gradient entry
# The allocation's regulariser in scaled units: lambda u_scale² = 1e-12 * 48 400² (SPEC §4.2, allocation.py).
LAM_SCALED = AllocationParams().reg_lambda * max(abs(VEHICLE.u_min), abs(VEHICLE.u_max)) ** 2
# Scale of the scaled map As = A u_scale of the Omnirotor [N per unit x]: entries of a few units.
AS_SCALE = float(np.abs(VEHICLE.A_nom).max() * max(abs(VEHICLE.u_min), abs(VEHICLE.u_max)))
WRENCH_DIM = 6
MAX_ITER = 100
# Two minimisers of the same strongly convex QP, both exact to machine precision, differ by about
# cond(H) * eps (cond ~1e5 here): far below this bound on the scaled variables (|x| <= 1).
X_AGREE = 1e-8


def problem(seed: int, n: int, f_scale: float, n_pinned: int):
    """A random allocation-shaped QP: H = AsᵀAs + lambda_s I (As 6 x n), f = -Asᵀ w, box [-1, 1], pins at 0."""
    rng = np.random.default_rng(seed)
    As = rng.normal(size=(WRENCH_DIM, n)) * AS_SCALE
    H = As.T @ As + LAM_SCALED * np.eye(n)
    f = -As.T @ (rng.normal(size=WRENCH_DIM) * f_scale)
    lo = -np.ones(n)
    hi = np.ones(n)
    pinned = rng.choice(n, size=n_pinned, replace=False)
    lo[pinned] = 0.0
    hi[pinned] = 0.0
    return H, f, lo, hi


def solve(H, f, lo, hi, active=None, max_iter=MAX_ITER):
    """boxqp_solve with fresh arrays; returns (code, x, active)."""
    n = f.shape[0]
    x = np.full(n, np.nan)
    act = np.zeros(n, dtype=np.int64) if active is None else np.array(active, dtype=np.int64)
    work = np.full(_qp.boxqp_work_size(n), np.nan)
    code = _qp.boxqp_solve(H, f, lo, hi, x, act, work, max_iter)
    return code, x, act


def assert_kkt(H, f, lo, hi, x, active):
    """Feasibility, stationarity on the free variables and multiplier signs on the bounds, and ``active`` says which."""
    assert np.all(lo <= x) and np.all(x <= hi)
    g = H @ x + f
    scale = np.abs(f) + np.abs(H) @ np.abs(x)
    tol = KKT_TOL * scale.max()
    free = active == _qp.FREE
    at_lo = active == _qp.AT_LOWER
    at_hi = active == _qp.AT_UPPER
    assert np.all(free | at_lo | at_hi)
    np.testing.assert_array_equal(x[at_lo], lo[at_lo])
    np.testing.assert_array_equal(x[at_hi], hi[at_hi])
    assert np.all(np.abs(g[free]) <= tol), np.abs(g[free]).max() / scale.max()
    movable = lo < hi  # a pinned variable's multiplier may have either sign
    assert np.all(g[at_lo & movable] >= -tol)
    assert np.all(g[at_hi & movable] <= tol)
    assert not np.any(free & ~movable)


def daqp_solution(H, f, lo, hi):
    n = f.shape[0]
    x, _, exitflag, _ = daqp.solve(H, f, np.zeros((0, n)), hi, lo, np.zeros(n, dtype=np.int32))
    assert exitflag >= 1
    return np.asarray(x)


def scipy_solution(H, f, lo, hi):
    """Bounded least squares (BVLS) on 1/2 |K x - b|² with KᵀK = H, Kᵀb = -f; pinned variables removed."""
    free = lo < hi
    x = lo.copy()
    K = np.linalg.cholesky(H).T
    b = -np.linalg.solve(K.T, f)
    res = lsq_linear(K[:, free], b - K[:, ~free] @ lo[~free], bounds=(lo[free], hi[free]), method="bvls", tol=1e-15)
    x[free] = res.x
    return x


def cost(H, f, x):
    return 0.5 * x @ H @ x + f @ x


problems = st.builds(
    problem,
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(WRENCH_DIM + 1, 16),
    f_scale=st.sampled_from([0.3, 3.0, 30.0, 300.0]),  # from all free to most variables at a bound
    n_pinned=st.integers(0, 2),
)


@SETTINGS
@given(qp=problems)
def test_cold_start_is_optimal_and_agrees_with_daqp_and_scipy(qp):
    H, f, lo, hi = qp
    code, x, active = solve(H, f, lo, hi)
    assert code >= 1
    assert_kkt(H, f, lo, hi, x, active)
    assert np.all(x[lo == hi] == 0.0)  # pinned rotors exactly at 0
    x_daqp = daqp_solution(H, f, lo, hi)
    np.testing.assert_allclose(x, x_daqp, rtol=0.0, atol=X_AGREE)
    x_scipy = scipy_solution(H, f, lo, hi)
    np.testing.assert_allclose(x, x_scipy, rtol=0.0, atol=X_AGREE)
    # No lower cost in the box: daqp's answer may leave it by ~1e-12 (e.g. a pinned variable), so it is clipped.
    c_scale = abs(cost(H, np.abs(f), np.abs(x))) + np.finfo(float).tiny
    others = (np.clip(x_daqp, lo, hi), np.clip(x_scipy, lo, hi))
    assert cost(H, f, x) <= min(cost(H, f, y) for y in others) + KKT_TOL * c_scale


def test_problems_exercise_the_bounds():
    """The generator of the property tests really produces free, lower-bound and upper-bound solutions."""
    counts = {_qp.FREE: 0, _qp.AT_LOWER: 0, _qp.AT_UPPER: 0}
    for seed in range(40):
        _, _, active = solve(*problem(seed, 8, 30.0, 1))
        for k in counts:
            counts[k] += int(np.sum(active == k))
    assert min(counts.values()) >= 20, counts


@SETTINGS
@given(qp=problems, seed=st.integers(0, 2**32 - 1))
def test_any_warm_start_gives_the_cold_start_answer(qp, seed):
    H, f, lo, hi = qp
    n = f.shape[0]
    code0, x0, active0 = solve(H, f, lo, hi)
    assert code0 >= 1
    rng = np.random.default_rng(seed)
    for wrong in (rng.integers(-3, 4, n), -active0, np.full(n, 7), np.full(n, -1)):
        code, x, active = solve(H, f, lo, hi, active=wrong)
        assert code >= 1
        # The answer is the subproblem minimiser of the final active set: the same set, the same bits.
        np.testing.assert_array_equal(active, active0)
        np.testing.assert_array_equal(x, x0)
    # The optimal set as warm start: one iteration.
    code, x, active = solve(H, f, lo, hi, active=active0)
    assert code == 1
    np.testing.assert_array_equal(x, x0)


def test_slowly_varying_sequence_needs_one_iteration_almost_always():
    """A 1 kHz-like sequence: the wrench sweeps into saturation and back, the working set is carried over."""
    n = VEHICLE.n_rotors
    rng = np.random.default_rng(4)
    As = rng.normal(size=(WRENCH_DIM, n)) * AS_SCALE
    H = As.T @ As + LAM_SCALED * np.eye(n)
    lo = -np.ones(n)
    hi = np.ones(n)
    # An elliptic sweep of period 1 s at 1 kHz, large enough to saturate several rotors at its extremes.
    period = 1000
    n_steps = 2 * period
    w_a, w_b = rng.normal(size=(2, WRENCH_DIM)) * (4.0 * AS_SCALE)
    x = np.zeros(n)
    active = np.zeros(n, dtype=np.int64)
    work = np.zeros(_qp.boxqp_work_size(n))
    codes = np.zeros(n_steps, dtype=np.int64)
    changed = np.zeros(n_steps, dtype=bool)
    for step in range(n_steps):
        if step == period:  # a new wrench map, warm start kept
            As = As * 1.1
            H = As.T @ As + LAM_SCALED * np.eye(n)
        phase = 2.0 * np.pi * step / period
        f = -As.T @ (w_a * np.sin(phase) + w_b * np.cos(phase))
        before = active.copy()
        codes[step] = _qp.boxqp_solve(H, f, lo, hi, x, active, work, MAX_ITER)
        changed[step] = not np.array_equal(active, before)
        assert codes[step] >= 1
        assert_kkt(H, f, lo, hi, x, active)
        if step % 100 == 0:
            np.testing.assert_array_equal(x, solve(H, f, lo, hi)[1])
    assert changed[1:].sum() >= 20  # the sweep did move the rotors in and out of saturation
    # An unchanged working set is confirmed in one iteration (one factorisation), a changed one in a few.
    assert np.all(codes[~changed] == 1)
    assert codes.max() <= 1 + len(active) // 2
    assert np.mean(codes == 1) >= 0.95


def test_new_hessian_with_the_old_working_set():
    n = VEHICLE.n_rotors
    H1, f1, lo, hi = problem(21, n, 30.0, 1)
    H2, f2, _, _ = problem(22, n, 30.0, 0)
    _, x1, active1 = solve(H1, f1, lo, hi)
    code, x2, active2 = solve(H2, f2, lo, hi, active=active1)
    assert code >= 1
    assert_kkt(H2, f2, lo, hi, x2, active2)
    np.testing.assert_array_equal(x2, solve(H2, f2, lo, hi)[1])
    assert not np.array_equal(x1, x2)


@pytest.mark.parametrize("which", ["H", "f", "lo", "hi"])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nonfinite_input_is_rejected(which, bad):
    qp = dict(zip(("H", "f", "lo", "hi"), problem(5, 8, 3.0, 0), strict=True))
    arr = qp[which]
    arr.flat[arr.size // 2] = bad
    code, _, _ = solve(qp["H"], qp["f"], qp["lo"], qp["hi"])
    assert code == _qp.BOXQP_NONFINITE


def test_failed_factorisation_and_empty_box():
    n = 8
    _, f, lo, hi = problem(6, n, 3.0, 0)
    assert solve(-np.eye(n), f, lo, hi)[0] == _qp.BOXQP_NONFINITE  # negative definite
    assert solve(np.zeros((n, n)), f, lo, hi)[0] == _qp.BOXQP_NONFINITE  # singular
    H, f, lo, hi = problem(6, n, 3.0, 0)
    lo[3] = hi[3] + 0.5
    assert solve(H, f, lo, hi)[0] == _qp.BOXQP_INFEASIBLE
    # A singular H with every variable bound needs no factorisation: still solved.
    code, x, active = solve(np.zeros((n, n)), np.ones(n), np.full(n, -1.0), np.full(n, 1.0), active=np.full(n, -1))
    assert code == 1 and np.all(x == -1.0) and np.all(active == _qp.AT_LOWER)


def test_iteration_cap():
    # Saturated enough that the cold start's clipped first iterate is not optimal.
    for seed in range(100):
        H, f, lo, hi = problem(seed, 8, 30.0, 0)
        code_full, x_full, _ = solve(H, f, lo, hi)
        if code_full >= 3:
            break
    assert code_full >= 3
    code, x, _ = solve(H, f, lo, hi, max_iter=1)
    assert code == _qp.BOXQP_MAX_ITER
    assert np.all((lo <= x) & (x <= hi))  # the last iterate is feasible
    assert cost(H, f, x) > cost(H, f, x_full)
    assert solve(H, f, lo, hi, max_iter=code_full - 1)[0] == _qp.BOXQP_MAX_ITER
    assert solve(H, f, lo, hi, max_iter=code_full)[0] == code_full
    # An interior solution is found in one iteration from the cold start.
    H, f, lo, hi = problem(7, 8, 0.01, 0)
    code, x, active = solve(H, f, lo, hi, max_iter=1)
    assert code == 1 and np.all(active == _qp.FREE)


@numba.njit
def _solve_sequence(H, fs, lo, hi, x, active, work, out):
    """A compiled caller: one warm-started solve per row of ``fs``, the codes into ``out``."""
    for k in range(fs.shape[0]):
        out[k] = _qp.boxqp_solve(H, fs[k], lo, hi, x, active, work, MAX_ITER)


def test_callable_from_compiled_code():
    n = 8
    H, _, lo, hi = problem(9, n, 1.0, 1)
    rng = np.random.default_rng(9)
    fs = rng.normal(size=(20, n)) * 10.0
    x = np.zeros(n)
    active = np.zeros(n, dtype=np.int64)
    work = np.zeros(_qp.boxqp_work_size(n))
    codes = np.zeros(20, dtype=np.int64)
    _solve_sequence(H, fs, lo, hi, x, active, work, codes)
    assert np.all(codes >= 1)
    np.testing.assert_array_equal(x, solve(H, fs[-1], lo, hi)[1])


# -- the allocator's side ------------------------------------------------------------------------------------------


def test_alloc_set_map_matches_the_numpy_code():
    alloc = Allocator(VEHICLE)
    rng = np.random.default_rng(12)
    n = VEHICLE.n_rotors
    ar = alloc.arrays
    scale = alloc.state["u_scale_hz2"][0]
    lam = AllocationParams().reg_lambda * scale**2
    assert alloc.state["lam_scaled"][0] == lam
    written = ("As", "H", "G", "A_key")
    for k in range(20):
        A = VEHICLE.A_nom * (1.0 + 0.2 * rng.normal(size=VEHICLE.A_nom.shape)) if k else VEHICLE.A_nom
        before_state = alloc.state.copy()
        before = {name: getattr(ar, name).copy() for name in ar.dtype.names if name not in written}
        alloc_set_map(alloc.state[0], ar, A)
        As_ref = A * scale
        np.testing.assert_array_equal(ar.As, As_ref)
        np.testing.assert_array_equal(ar.G, -As_ref.T)
        np.testing.assert_array_equal(ar.A_key, A)
        for name, value in before.items():  # nothing else is touched
            np.testing.assert_array_equal(getattr(ar, name), value)
        assert alloc.state.tobytes() == before_state.tobytes()
        np.testing.assert_array_equal(ar.H, ar.H.T)
        H_ref = As_ref.T @ As_ref + lam * np.eye(n)
        # Sums of 6 products in another order (BLAS): a few roundings of the largest entry.
        assert np.abs(ar.H - H_ref).max() <= 4 * np.finfo(float).eps * np.abs(H_ref).max()


def test_default_backend_shares_the_allocators_arrays():
    alloc = Allocator(VEHICLE)
    assert alloc.params.solver == "active-set"
    be = alloc._backend
    assert be.H is alloc._H
    for arr, name in ((be.lo, "lo"), (be.hi, "hi"), (be.x, "x"), (be.active, "active"), (be.work, "work")):
        field = getattr(alloc.arrays, name)  # the compiled controller step continues the same warm start
        assert arr.shape == field.shape and arr.ctypes.data == field.ctypes.data
    assert be.active.dtype == np.int64 and be.x.shape == (VEHICLE.n_rotors,)
    assert be.work.size >= _qp.boxqp_work_size(VEHICLE.n_rotors) and be.max_iter == AllocationParams().max_iter
    # Upright hover from the cold start, then a warm step: one iteration, the answer in be.x.
    hover = np.array([0.0, 0.0, VEHICLE.weight, 0.0, 0.0, 0.0])
    alloc.solve(hover, np.eye(3), VEHICLE.A_nom)
    u = alloc.solve(hover + 0.01, np.eye(3), VEHICLE.A_nom)
    assert be.iterations == 1
    np.testing.assert_array_equal(u, be.x * alloc.state["u_scale_hz2"][0])
    # A failed rotor changes the bound arrays in place: the next solve pins it.
    mask = np.zeros(VEHICLE.n_rotors, dtype=bool)
    mask[2] = True
    alloc.set_failed_rotors(mask)
    assert be.lo[2] == be.hi[2] == 0.0
    u = alloc.solve(hover, np.eye(3), VEHICLE.A_nom)
    assert u[2] == 0.0 and be.active[2] != _qp.FREE
    # A solver failure reaches the allocator's fallback.
    be.max_iter = 0
    be.active[:] = _qp.AT_UPPER  # the cold start is far from optimal: the cap is hit
    alloc.solve(hover, np.eye(3), VEHICLE.A_nom)
    assert be.iterations == _qp.BOXQP_MAX_ITER and alloc.n_fallbacks == 1
