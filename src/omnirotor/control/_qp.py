"""Compiled box-constrained QP solver for the allocation (SPEC §4.2), and the compiled map set-up of the allocator.

The allocation QP of :mod:`omnirotor.control.allocation`, in the scaled variable ``x = u / u_scale`` [-], is

    min_x  1/2 xᵀ H x + fᵀ x    s.t.  lo <= x <= hi,

with ``H = AsᵀAs + lambda_s I`` symmetric positive definite (n x n, n = 8 rotors on the Omnirotor) and
``lo == hi`` allowed (a failed rotor pinned to 0). :func:`boxqp_solve` solves it by a **primal active-set
method** on the working set of bounds, exact to machine precision (each iterate solves the equality-constrained
subproblem by a Cholesky factorisation of the free block of H), warm-started from the working set of the last
call: at 1 kHz the set of saturated rotors rarely changes, so a warm solve is one factorisation of an (at most)
8 x 8 matrix and one gradient check. Everything runs in caller-provided arrays (no allocation), so the solver
can be called from inside a compiled control loop.

The method (Nocedal & Wright, *Numerical Optimization*, 2nd ed., Algorithm 16.3, specialised to bounds):

1. The working set W (``active``: 0 free, -1 at the lower bound, +1 at the upper bound; pinned variables are
   always in W) fixes the bound variables; the free ones minimise the cost with those fixed:
   ``H_FF x_F = -(f_F + H_FB x_B)``.
2. First iterate: the subproblem minimiser of the warm-start set, clipped to the box if it leaves it (the
   clipped variables join W). The clipped point is feasible, and from there on every step decreases the cost.
3. If the subproblem minimiser of W is feasible it becomes the iterate; the multipliers of the bounds in W are
   read off the gradient ``g = H x + f`` (``g_i`` at a lower bound, ``-g_i`` at an upper bound). If none is
   below ``-DUAL_TOL_REL`` times the rounding scale of ``g_i`` the iterate is optimal (KKT conditions hold);
   else the bound with the most negative multiplier leaves W.
4. If it is not feasible, the iterate moves towards it up to the first bound it meets (ratio test), and that
   bound joins W.
"""

from __future__ import annotations

import math

from omnirotor._jit import jit

__all__ = [
    "BOXQP_INFEASIBLE",
    "BOXQP_MAX_ITER",
    "BOXQP_NONFINITE",
    "AT_LOWER",
    "AT_UPPER",
    "FREE",
    "DUAL_TOL_REL",
    "boxqp_solve",
    "boxqp_work_size",
]

# Return codes of boxqp_solve (success returns the number of iterations, >= 1).
BOXQP_MAX_ITER = -1  # the iteration cap was hit; x is the last (feasible, not optimal) iterate
BOXQP_NONFINITE = -2  # NaN/inf in H, f, lo or hi, or H's free block is not numerically positive definite
BOXQP_INFEASIBLE = -3  # lo > hi for some variable (empty box)

# Values of the working-set array ``active``.
FREE = 0
AT_LOWER = -1
AT_UPPER = 1

DUAL_TOL_REL = 1e-13
"""A bound's multiplier counts as negative below ``-DUAL_TOL_REL * (|f_i| + sum_j |H_ij x_j|)``: the rounding
scale of the gradient entry it is read from, with a margin for the conditioning of H (cond ~1e5 for the
allocation), so that a multiplier that is zero up to rounding does not make the working set cycle."""


@jit
def boxqp_work_size(n: int) -> int:
    """float64 entries of the ``work`` array :func:`boxqp_solve` needs for ``n`` variables.

    Layout: the Cholesky factor of the free block (n x n, row-major), the subproblem's right-hand side and
    solution (n), the subproblem minimiser (n), the indices of the free variables (n, stored as floats).
    """
    return n * n + 3 * n


@jit
def _check_inputs(H, f, lo, hi) -> int:
    """0 when every entry is finite and ``lo <= hi``, else ``BOXQP_NONFINITE`` or ``BOXQP_INFEASIBLE``."""
    n = f.shape[0]
    zero = 0.0
    for i in range(n):
        zero += f[i] * 0.0 + lo[i] * 0.0 + hi[i] * 0.0  # 0 * (NaN or inf) is NaN, and NaN propagates
        for j in range(n):
            zero += H[i, j] * 0.0
    if zero != 0.0:
        return BOXQP_NONFINITE
    for i in range(n):
        if lo[i] > hi[i]:
            return BOXQP_INFEASIBLE
    return 0


@jit
def _subspace_minimiser(H, f, lo, hi, active, xs, work) -> bool:
    """Step 1 of the module docstring: ``xs`` = the minimiser over the free variables of ``active``.

    Bound variables get their bound, free ones solve ``H_FF x_F = -(f_F + H_FB x_B)`` by Cholesky
    (Cholesky-Banachiewicz, row by row, into ``work``).

    Returns:
        False when the free block is not numerically positive definite (a pivot <= 0 or NaN).
    """
    n = f.shape[0]
    o_b = n * n
    o_idx = o_b + 2 * n
    nf = 0
    for i in range(n):
        a = active[i]
        if a == AT_LOWER:
            xs[i] = lo[i]
        elif a == AT_UPPER:
            xs[i] = hi[i]
        else:
            work[o_idx + nf] = i
            nf += 1
    # Right-hand side -(f_F + H_FB x_B).
    for k in range(nf):
        i = int(work[o_idx + k])
        acc = f[i]
        for j in range(n):
            if active[j] != FREE:
                acc += H[i, j] * xs[j]
        work[o_b + k] = -acc
    # H_FF = L Lᵀ, L lower triangular, row k at work[k * n : k * n + k + 1].
    for k in range(nf):
        i = int(work[o_idx + k])
        for m in range(k + 1):
            s = H[i, int(work[o_idx + m])]
            for p in range(m):
                s -= work[k * n + p] * work[m * n + p]
            if m < k:
                work[k * n + m] = s / work[m * n + m]
            elif s > 0.0:
                work[k * n + k] = math.sqrt(s)
            else:  # not positive definite, or NaN
                return False
    # L z = b (in place), then Lᵀ y = z (in place).
    for k in range(nf):
        s = work[o_b + k]
        for p in range(k):
            s -= work[k * n + p] * work[o_b + p]
        work[o_b + k] = s / work[k * n + k]
    for k in range(nf - 1, -1, -1):
        s = work[o_b + k]
        for p in range(k + 1, nf):
            s -= work[p * n + k] * work[o_b + p]
        work[o_b + k] = s / work[k * n + k]
    for k in range(nf):
        xs[int(work[o_idx + k])] = work[o_b + k]
    return True


@jit
def _most_negative_multiplier(H, f, lo, hi, x, active) -> int:
    """Step 3 of the module docstring at the subproblem minimiser ``x``: the bound to release, or -1 if optimal.

    Also turns each pinned variable (``lo == hi``) to the side whose multiplier is >= 0 (they never leave W).
    """
    n = f.shape[0]
    worst = -1
    worst_mu = 0.0
    for i in range(n):
        a = active[i]
        if a == FREE:
            continue
        g = f[i]
        scale = abs(f[i])
        for j in range(n):
            t = H[i, j] * x[j]
            g += t
            scale += abs(t)
        if lo[i] == hi[i]:
            active[i] = AT_LOWER if g >= 0.0 else AT_UPPER
            continue
        mu = g if a == AT_LOWER else -g
        if mu < -DUAL_TOL_REL * scale and mu < worst_mu:
            worst = i
            worst_mu = mu
    return worst


@jit
def boxqp_solve(H, f, lo, hi, x, active, work, max_iter: int) -> int:
    """Solve ``min 1/2 xᵀ H x + fᵀ x  s.t.  lo <= x <= hi`` (H SPD) by the primal active-set method of the module.

    Args:
        H: (n, n) symmetric positive definite Hessian (only read).
        f: (n,) linear term.
        lo: (n,) lower bounds; ``lo[i] == hi[i]`` pins variable i.
        hi: (n,) upper bounds.
        x: (n,) float64 output: the minimiser (on ``BOXQP_MAX_ITER``: the last feasible iterate; on the other
            failures: unspecified).
        active: (n,) int64 working set, in/out: the warm start on entry (0 free, < 0 at the lower bound, > 0 at
            the upper bound; any values are allowed, e.g. all 0 for a cold start), the optimal active set on exit
            (pinned variables count as bound, on the side of their non-negative multiplier).
        work: float64 scratch of at least ``boxqp_work_size(n)`` entries.
        max_iter: cap on the number of iterations (subproblem solves), >= 1.

    Returns:
        The number of iterations (>= 1; 1 when the warm start was the optimal active set) on success, else
        ``BOXQP_MAX_ITER``, ``BOXQP_NONFINITE`` (also when H's free block is not numerically positive definite)
        or ``BOXQP_INFEASIBLE``.
    """
    n = f.shape[0]
    code = _check_inputs(H, f, lo, hi)
    if code != 0:
        return code
    xs = work[n * n + n : n * n + 2 * n]  # a view: no allocation
    for i in range(n):
        a = active[i]
        if lo[i] == hi[i] or a < 0:
            active[i] = AT_LOWER
        elif a > 0:
            active[i] = AT_UPPER
    # Iteration 1: the warm start's subproblem minimiser, clipped into the box (step 2).
    if not _subspace_minimiser(H, f, lo, hi, active, xs, work):
        return BOXQP_NONFINITE
    feasible = True
    for i in range(n):
        xi = xs[i]
        if xi < lo[i]:
            xi = lo[i]
            active[i] = AT_LOWER
            feasible = False
        elif xi > hi[i]:
            xi = hi[i]
            active[i] = AT_UPPER
            feasible = False
        x[i] = xi
    it = 1
    while True:
        if feasible:  # x is the minimiser on W: optimal, or release one bound
            release = _most_negative_multiplier(H, f, lo, hi, x, active)
            if release < 0:
                return it
            active[release] = FREE
        if it >= max_iter:
            return BOXQP_MAX_ITER
        it += 1
        if not _subspace_minimiser(H, f, lo, hi, active, xs, work):
            return BOXQP_NONFINITE
        # Ratio test (step 4): the largest step in [0, 1] from x towards xs that stays in the box.
        alpha = 1.0
        block = -1
        side = FREE
        for i in range(n):
            if active[i] != FREE:
                continue
            if xs[i] < lo[i]:
                step = (lo[i] - x[i]) / (xs[i] - x[i])
                if step < alpha:
                    alpha, block, side = step, i, AT_LOWER
            elif xs[i] > hi[i]:
                step = (hi[i] - x[i]) / (xs[i] - x[i])
                if step < alpha:
                    alpha, block, side = step, i, AT_UPPER
        if block < 0:
            for i in range(n):
                x[i] = xs[i]
            feasible = True
            continue
        for i in range(n):
            if active[i] == FREE:
                xi = x[i] + alpha * (xs[i] - x[i])
                x[i] = min(max(xi, lo[i]), hi[i])  # rounding only
            else:
                x[i] = xs[i]
        x[block] = lo[block] if side == AT_LOWER else hi[block]
        active[block] = side
        feasible = False
