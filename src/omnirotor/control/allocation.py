"""Control allocation: the bounded, regularised least-squares QP of eq. 6 (SPEC §4.2).

Given the wrench reference ``w_ref = [f_ref_W; m_ref_B]`` (force in the world frame [N], moment in the body
frame [N·m]), the attitude ``R_WB`` and the wrench map ``A`` (6 x n, body frame, SPEC §1.2) in use now, the
allocator returns the rotor inputs ``u`` [Hz²] that solve

    min_u  || w_ref - blkdiag(R_WB, I3) A u ||² + lambda ||u||²    s.t.   u_min <= u_i <= u_max.

Because ``blkdiag(R_WB, I3)`` is orthogonal the cost equals ``|| w_B - A u ||² + lambda ||u||²`` with the
body-frame reference ``w_B = [R_WBᵀ f_ref_W; m_ref_B]``, so the Hessian ``2 (AᵀA + lambda I)`` does not
depend on the attitude: it is rebuilt only when the map changes (a region switch, SPEC §3.3), and each step
only changes the linear term. The problem is solved in the scaled variable ``x = u / u_scale`` with
``u_scale = max(|u_min|, |u_max|)`` (48 400 Hz² on the Omnirotor), so that the Hessian entries are O(1..100)
instead of O(1e-8); the regulariser becomes ``lambda u_scale²`` in scaled units, the same problem exactly.

Backends (set up once, then only their numbers change, warm-started):

* ``active-set`` (default): our own compiled primal active-set solver (:func:`omnirotor.control._qp.boxqp_solve`),
  exact to machine precision, warm-started from the last step's active set (one Cholesky factorisation of an
  8 x 8 matrix when the saturated rotors did not change). A QP this small is solved in about a microsecond, so
  the cost of calling an external solver from Python dominated the allocation; and the whole control period is
  to run inside one compiled loop, which can call this solver but not a Python interface. Its arrays are
  attributes of the backend (``H``, ``lo``, ``hi``, ``x``, ``active``, ``work``, ``max_iter``), ready to be
  passed to the kernel.
* ``daqp``: a persistent :class:`daqp.Model` with simple bounds; ``update`` keeps the previous active set as the
  warm start (a dual active-set method, exact to machine precision on a problem this size). Kept as an option
  and as the tests' oracle (daqp also solves the identification QP, SPEC §3.2).
* ``proxsuite``: the paper's solver, a dense :class:`proxsuite.proxqp.dense.QP` with box constraints,
  ``WARM_START_WITH_PREVIOUS_RESULT``. ProxSuite 0.8 needs three precautions, all taken here: the option is
  set before ``init``, one ``solve`` follows ``init`` (an ``update`` before the first solve segfaults), and
  the duality-gap test is on (without it a warm start whose multipliers are stale, e.g. after the bounds
  change, is accepted as optimal and the previous answer comes back).

A map that changes every step (the smooth blend of :mod:`omnirotor.control.maps` inside a blending band)
refactors the Hessian every step, which costs a little more than a plain step.

Failure handling (nothing non-finite reaches the motors):

* solver status not optimal or non-finite output: the clipped pseudo-inverse ``clip(pinv(A) w_B)`` is
  returned, :attr:`Allocator.status` is ``FALLBACK`` and :attr:`Allocator.n_fallbacks` counts it;
* a NaN or inf in ``w_ref``, ``R_WB`` or ``A``: the last returned input is held (initially the clipped
  upright hover input) and the status is ``NONFINITE``.

Rotors declared failed with :meth:`Allocator.set_failed_rotors` get the bounds [0, 0], so the remaining
rotors carry the whole wrench (the Omnirotor still hovers upright on any seven of its eight rotors).
"""

from __future__ import annotations

import dataclasses
import enum
import math

import numpy as np

from omnirotor._jit import jit, jit_entry, jit_inline
from omnirotor.blocks import record_view, register, state_array
from omnirotor.config import check_positive
from omnirotor.control import _qp
from omnirotor.errors import InputError
from omnirotor.vehicle import VehicleParams

__all__ = [
    "AllocationParams",
    "AllocationStatus",
    "Allocator",
    "SOLVERS",
    "REG_REFERENCE_C_F",
    "STATE_DTYPE",
    "arrays_dtype",
    "alloc_begin",
    "alloc_end",
    "alloc_solve",
]

SOLVERS = ("active-set", "daqp", "proxsuite")
"""Names of the QP backends :class:`Allocator` can use."""

REG_REFERENCE_C_F = 1.5e-4
"""Thrust coefficient [N/Hz²] of the Omnirotor (SPEC §1.1), the vehicle SPEC §4.2's regulariser is stated for."""

_DAQP_SIMPLE_BOUND = 0  # daqp ``sense`` value of an inactive inequality (warm start picks the rest)


@dataclasses.dataclass(frozen=True)
class AllocationParams:
    """Parameters of the allocation QP (SPEC §4.2).

    Attributes:
        solver: QP backend, "active-set" (default, compiled), "daqp" or "proxsuite" (the paper's solver).
        reg_lambda: weight lambda of ``lambda ||u||²`` with u in Hz² [N²/Hz⁴]; SPEC §4.2: 1e-12 (2e-4 N
            wrench error at hover, and a unique solution since AᵀA has rank 6 < n), stated for the Omnirotor's
            thrust coefficient :data:`REG_REFERENCE_C_F`.
        reg_scale_with_c_f: use ``reg_lambda (c_f / REG_REFERENCE_C_F)²`` on a vehicle of thrust coefficient
            ``c_f``, so that the regulariser weighs as much against the wrench error as on the Omnirotor (the
            cost's wrench term scales with c_f²). Without it a vehicle with a much smaller c_f (a Crazyflie's is
            165 times smaller) gets a regulariser 27 000 times heavier: its hover thrust falls 23 % short. The
            Omnirotor's factor is exactly 1. False: ``reg_lambda`` is used as it is.
        max_iter: iteration cap of the backend (a solve that hits it counts as a failure).
        eps_abs: ProxSuite absolute KKT tolerance, in the scaled problem (x = u / u_scale, wrench in N and
            N·m); the active-set solvers (ours and daqp) solve to machine precision regardless.
        saturation_tol: relative distance to a bound [-] below which a rotor counts as saturated.
    """

    solver: str = "active-set"
    reg_lambda: float = 1e-12
    reg_scale_with_c_f: bool = True
    max_iter: int = 200
    eps_abs: float = 1e-9
    saturation_tol: float = 1e-6

    def __post_init__(self) -> None:
        if self.solver not in SOLVERS:
            raise InputError(f"allocation solver must be one of {', '.join(SOLVERS)}, got {self.solver!r}")
        check_positive("allocation reg_lambda", self.reg_lambda)
        if not isinstance(self.reg_scale_with_c_f, bool):
            raise InputError(f"allocation reg_scale_with_c_f must be true or false, got {self.reg_scale_with_c_f!r}")
        if isinstance(self.max_iter, bool) or not isinstance(self.max_iter, int) or self.max_iter < 1:
            raise InputError(f"allocation max_iter must be an integer >= 1, got {self.max_iter!r}")
        check_positive("allocation eps_abs", self.eps_abs)
        check_positive("allocation saturation_tol", self.saturation_tol)
        if self.saturation_tol >= 0.5:
            raise InputError(f"allocation saturation_tol must be < 0.5, got {self.saturation_tol}")


class AllocationStatus(enum.IntEnum):
    """Outcome of the last :meth:`Allocator.solve`."""

    OK = 0
    """The QP was solved."""
    FALLBACK = 1
    """The QP failed; the command is the pseudo-inverse solution clipped to the bounds."""
    NONFINITE = 2
    """An input was NaN or inf; the last safe command is held."""


# -- the block's state and its compiled step -------------------------------------------------------------------

_F8 = np.float64
STATE_DTYPE = np.dtype(
    [
        ("w_B", _F8, 6),  # body-frame wrench reference [N; N·m]
        ("status", _F8),  # AllocationStatus of the last solve
        ("n_fallbacks", _F8),  # pseudo-inverse fallbacks since reset
        ("n_nonfinite", _F8),  # calls with a non-finite input since reset (the last safe input held)
        ("saturated", _F8),  # 1 when an active rotor sits at a bound in the last result
        # parameters
        ("u_scale_hz2", _F8),  # u = x u_scale [Hz²]
        ("lam_scaled", _F8),  # the regulariser in scaled units, lambda u_scale²
        ("max_iter", _F8),  # iteration cap of the compiled QP
    ]
)
"""The allocator's scalar state and parameters (named fields); its per-rotor arrays are :func:`arrays_dtype`."""


def arrays_dtype(n: int) -> np.dtype:
    """The allocator's per-rotor arrays for ``n`` rotors, one record (compiled code reads ``ar.f``, ``ar.lo``, ...).

    A field of the controller's state (``allocation_arrays``) beside the scalar :data:`STATE_DTYPE`.
    """
    return np.dtype(
        [
            ("f", _F8, (n,)),  # the QP's linear term G w_B (scaled)
            ("A_key", _F8, (6, n)),  # the map the QP was built for (NaN: none yet)
            ("G", _F8, (n, 6)),  # -(A u_scale)ᵀ
            ("lo", _F8, (n,)),  # scaled lower bounds (0 for a failed rotor)
            ("hi", _F8, (n,)),  # scaled upper bounds
            ("lo_sat", _F8, (n,)),  # saturation thresholds
            ("hi_sat", _F8, (n,)),
            ("u_hz2", _F8, (n,)),  # the allocated inputs [Hz²]
            ("u_safe_hz2", _F8, (n,)),  # the last finite, in-bounds inputs [Hz²]
            ("failed", _F8, (n,)),  # 1.0 for a failed rotor
            ("As", _F8, (6, n)),  # A u_scale
            ("H", _F8, (n, n)),  # Hessian, scaled units
            ("x", _F8, (n,)),  # the QP's solution (scaled)
            ("active", np.int64, (n,)),  # working set of the compiled QP (warm start)
            ("work", _F8, (_qp.boxqp_work_size(n),)),  # scratch of the compiled QP
        ]
    )


_OK, _FALLBACK, _NONFINITE = 0.0, 1.0, 2.0  # AllocationStatus values, as the state stores them

# Results of alloc_begin.
BEGIN_SOLVE = 0  # the QP's linear term is ready
BEGIN_SOLVE_NEW_MAP = 1  # ready, after a new map rebuilt H (a Python backend must be given the new H)
BEGIN_HELD = 2  # an input was not finite: the last safe input is held (status NONFINITE)
ALLOC_DONE = 3  # (an allocation block without a QP) the inputs are final in ``u_hz2``: nothing to solve


@jit_entry
def alloc_set_map(r, ar, A) -> None:
    """Rebuild the QP for a new wrench map ``A`` (finite), in place.

    ``As = A u_scale``, ``G = -Asᵀ``, the map key and ``H = AsᵀAs + lam_scaled I`` (each entry summed over the
    wrench rows in order, the regulariser added on the diagonal; exactly symmetric).
    """
    m, n = A.shape
    scale = r.u_scale_hz2
    As, G, key, H = ar.As, ar.G, ar.A_key, ar.H
    for i in range(m):
        for j in range(n):
            a = A[i, j]
            s = a * scale
            As[i, j] = s
            G[j, i] = -s
            key[i, j] = a
    lam = r.lam_scaled
    for i in range(n):
        for j in range(i + 1):
            acc = 0.0
            for k in range(m):
                acc += As[k, i] * As[k, j]
            if i == j:
                acc += lam
            H[i, j] = acc
            H[j, i] = acc


@jit_inline
def _prepare(r, ar, f_ref_W, m_ref_B, R, A) -> int:
    """Body-frame reference and ``f = G w_B``.

    Returns:
        0; 1 when ``A`` is not the QP's map (nothing computed); 2 when f is not finite.
    """
    n = A.shape[1]
    key = ar.A_key
    for i in range(6):
        for j in range(n):
            if A[i, j] != key[i, j]:
                return 1
    W = r.w_B
    for j in range(3):
        W[j] = f_ref_W[0] * R[0, j] + f_ref_W[1] * R[1, j] + f_ref_W[2] * R[2, j]  # R^T f_ref
    for j in range(3):
        W[3 + j] = m_ref_B[j]
    G, f = ar.G, ar.f
    ff = 0.0
    for i in range(n):
        acc = 0.0
        for k in range(6):
            acc += G[i, k] * W[k]
        f[i] = acc
        ff += acc * acc
    if not math.isfinite(ff):  # a NaN/inf anywhere in w_ref or R reaches f (0 * inf is NaN too)
        return 2
    return 0


@jit_inline
def alloc_begin(r, ar, f_ref_W, m_ref_B, R, A) -> int:
    """Everything of an allocation before the QP (module docstring).

    Returns:
        ``BEGIN_SOLVE``, ``BEGIN_SOLVE_NEW_MAP`` (the map changed and the QP was rebuilt) or ``BEGIN_HELD``
        (a NaN/inf in ``w_ref``, ``R`` or ``A``: the last safe input is held, the status is NONFINITE).
    """
    code = _prepare(r, ar, f_ref_W, m_ref_B, R, A)
    new_map = False
    if code == 1:
        finite = True
        for i in range(A.shape[0]):
            for j in range(A.shape[1]):
                finite = finite and math.isfinite(A[i, j])
        code = 2
        if finite:
            alloc_set_map(r, ar, A[:])  # [:]: an array, the type Python sets the map with (one compiled copy)
            new_map = True
            code = _prepare(r, ar, f_ref_W, m_ref_B, R, A)
    if code != 0:
        r.status = _NONFINITE
        r.n_nonfinite += 1.0
        for i in range(ar.u_hz2.shape[0]):
            ar.u_hz2[i] = ar.u_safe_hz2[i]
        return BEGIN_HELD
    return BEGIN_SOLVE_NEW_MAP if new_map else BEGIN_SOLVE


@jit_inline
def _finish(r, ar, x) -> int:
    """Clip the scaled ``x`` to the bounds, scale it to u [Hz²] (also the new safe input); 1 if saturated."""
    n = x.shape[0]
    scale = r.u_scale_hz2
    lo, hi, lo_sat, hi_sat, u, u_safe = ar.lo, ar.hi, ar.lo_sat, ar.hi_sat, ar.u_hz2, ar.u_safe_hz2
    saturated = 0
    for i in range(n):
        xi = x[i]
        if xi < lo[i]:
            xi = lo[i]
        elif xi > hi[i]:
            xi = hi[i]
        if xi <= lo_sat[i] or xi >= hi_sat[i]:
            saturated = 1
        ui = xi * scale
        u[i] = ui
        u_safe[i] = ui
    return saturated


@jit_inline
def alloc_end(r, ar, solved: bool) -> None:
    """Everything after the QP, once for every solver: the inputs ``ar.u_hz2`` and ``saturated``.

    ``ar.x`` clipped and scaled when ``solved`` and finite, else the clipped pseudo-inverse of the map
    restricted to the working rotors (status FALLBACK, counted; this allocates, a rare path).
    """
    x = ar.x
    ok = solved
    if ok:
        for i in range(x.shape[0]):
            ok = ok and math.isfinite(x[i])
    if ok:
        r.status = _OK
        r.saturated = float(_finish(r, ar, x))
        return
    r.status = _FALLBACK
    r.n_fallbacks += 1.0
    Aw = ar.As.copy()
    for j in range(Aw.shape[1]):
        if ar.failed[j] != 0.0:
            for i in range(Aw.shape[0]):
                Aw[i, j] = 0.0
    r.saturated = float(_finish(r, ar, np.linalg.pinv(Aw) @ r.w_B))


@jit
def alloc_solve(r, ar, f_ref_W, m_ref_B, R, A) -> int:
    """One allocation with the compiled QP (:func:`omnirotor.control._qp.boxqp_solve`).

    Returns:
        The code of :func:`alloc_begin`; the inputs are in ``ar.u_hz2``.
    """
    code = alloc_begin(r, ar, f_ref_W, m_ref_B, R, A)
    if code != BEGIN_HELD:
        alloc_end(r, ar, boxqp_solve_arrays(ar, int(r.max_iter)) >= 1)
    return code


class _ActiveSetBackend:
    """Our compiled primal active-set solver (:func:`omnirotor.control._qp.boxqp_solve`), warm-started.

    Attributes:
        H: (n, n) the allocator's Hessian array itself (not a copy), scaled units.
        lo, hi: (n,) the allocator's scaled bound arrays (changed in place by the allocator).
        x: (n,) the last solution (scaled).
        active: (n,) int64 working set of the last solve (0 free, -1 at lo, +1 at hi), the next warm start.
        work: float64 scratch of ``boxqp_work_size(n)`` entries.
        max_iter: iteration cap (``AllocationParams.max_iter``).
        iterations: iterations of the last solve, or its negative ``BOXQP_*`` code.
    """

    def __init__(
        self,
        H: np.ndarray,
        f: np.ndarray,
        lo: np.ndarray,
        hi: np.ndarray,
        params: AllocationParams,
        arrays: np.record | None = None,
    ):
        """Wrap the solver; ``arrays``: the allocator's, whose ``x``, ``active`` and ``work`` it then uses.

        Shared with the controller's compiled step, so both continue the same warm start; new ones by default.
        """
        n = f.shape[0]
        self.H = H
        self.lo = lo
        self.hi = hi
        self.x = np.zeros(n) if arrays is None else arrays.x
        self.active = np.zeros(n, dtype=np.int64) if arrays is None else arrays.active
        self.work = np.zeros(_qp.boxqp_work_size(n)) if arrays is None else arrays.work
        self.max_iter = int(params.max_iter)
        self.iterations = 0
        self.setup(H, f)

    def setup(self, H: np.ndarray, f: np.ndarray) -> None:
        """Cold start: every variable free in the next solve's initial working set."""
        self.H = H
        self.active[:] = _qp.FREE
        self.iterations = 0

    def set_hessian(self, H: np.ndarray) -> None:
        """New Hessian (a new wrench map); the active set of the last solve stays as warm start."""
        self.H = H

    def set_bounds(self) -> None:
        """The bound arrays given at construction changed in place (read at every solve: nothing to do)."""

    def solve(self, f: np.ndarray) -> np.ndarray | None:
        """Solve with linear term ``f``; the minimiser (scaled, the array :attr:`x`), or None on failure."""
        self.iterations = _qp.boxqp_solve(self.H, f, self.lo, self.hi, self.x, self.active, self.work, self.max_iter)
        return self.x if self.iterations >= 1 else None


class _DaqpBackend:
    """A persistent daqp workspace over simple bounds (no general constraint rows)."""

    def __init__(self, H: np.ndarray, f: np.ndarray, lo: np.ndarray, hi: np.ndarray, params: AllocationParams):
        n = f.shape[0]
        import daqp  # imported here so that a missing backend only fails when chosen

        self._model = daqp.Model()
        self._no_rows = np.zeros((0, n))
        self._sense = np.full(n, _DAQP_SIMPLE_BOUND, dtype=np.int32)
        self._lo = lo
        self._hi = hi
        self._params = params
        self.setup(H, f)

    def setup(self, H: np.ndarray, f: np.ndarray) -> None:
        """(Re)build the workspace from scratch (cold start)."""
        self._model.setup(H, f, self._no_rows, self._hi, self._lo, self._sense)
        self._model.settings = {"iter_limit": self._params.max_iter}

    def set_hessian(self, H: np.ndarray) -> None:
        """New Hessian (a new wrench map); the active set of the last solve stays as warm start."""
        self._model.update(H=H)

    def set_bounds(self) -> None:
        """The bound arrays given at construction changed in place."""
        self._model.update(bupper=self._hi, blower=self._lo)

    def solve(self, f: np.ndarray) -> np.ndarray | None:
        """Solve with linear term ``f``; the minimiser (scaled), or None unless optimal."""
        self._model.update(f=f)
        x, _, exitflag, _ = self._model.solve()
        return x if exitflag >= 1 else None


class _ProxsuiteBackend:
    """A dense ProxQP model with box constraints, warm-started from the previous result."""

    def __init__(self, H: np.ndarray, f: np.ndarray, lo: np.ndarray, hi: np.ndarray, params: AllocationParams):
        from proxsuite import proxqp

        self._proxqp = proxqp
        self._lo = lo
        self._hi = hi
        self._params = params
        self._n = f.shape[0]
        self._solved = proxqp.QPSolverOutput.PROXQP_SOLVED
        self.setup(H, f)

    def setup(self, H: np.ndarray, f: np.ndarray) -> None:
        """(Re)build the model from scratch (cold start)."""
        qp = self._proxqp.dense.QP(self._n, 0, 0, True)
        # The warm-start mode must be chosen before init (ProxSuite 0.8 crashes otherwise).
        qp.settings.initial_guess = self._proxqp.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
        qp.settings.eps_abs = self._params.eps_abs
        qp.settings.eps_rel = 0.0
        # ProxQP's default test (primal and dual residuals) accepts a warm start whose stale multipliers
        # violate complementarity, e.g. after a bound changes: the old answer comes back as "solved".
        # The duality-gap test rejects it.
        qp.settings.check_duality_gap = True
        qp.settings.eps_duality_gap_abs = self._params.eps_abs
        qp.settings.eps_duality_gap_rel = 0.0
        qp.settings.max_iter = self._params.max_iter
        qp.settings.verbose = False
        qp.init(H, f, None, None, None, None, None, self._lo, self._hi)
        # A solve right after init gives the warm start its "previous result": ProxSuite 0.8 segfaults
        # when update() precedes the first solve() in WARM_START_WITH_PREVIOUS_RESULT mode.
        qp.solve()
        self._qp = qp

    def set_hessian(self, H: np.ndarray) -> None:
        """New Hessian (a new wrench map)."""
        self._qp.update(H=H)

    def set_bounds(self) -> None:
        """The bound arrays given at construction changed in place."""
        self._qp.update(l_box=self._lo, u_box=self._hi)

    def solve(self, f: np.ndarray) -> np.ndarray | None:
        """Solve with linear term ``f``; the minimiser (scaled), or None unless solved."""
        self._qp.update(g=f)
        self._qp.solve()
        results = self._qp.results
        return results.x if results.info.status == self._solved else None


@register("allocation", "box-qp")
class Allocator:
    """Rotor inputs [Hz²] from a wrench reference by the bounded least-squares QP of SPEC §4.2.

    Attributes:
        state: the ``(1,)`` record of :data:`STATE_DTYPE` (status, counters, body-frame reference, scale).
        arrays: the per-rotor arrays (a record of :func:`arrays_dtype`, fields as attributes) the compiled step
            reads and writes.
        status: :class:`AllocationStatus` of the last :meth:`solve`.
        n_fallbacks: number of solver failures (pseudo-inverse fallbacks) since construction or :meth:`reset`.
        n_nonfinite: number of calls with a NaN/inf input since construction or :meth:`reset`.
        saturated: True when some active rotor sits at a bound in the last result.
        failed_rotors: (n,) bool mask of the rotors excluded from the allocation (read-only view).
    """

    state_dtype = STATE_DTYPE
    log_fields = ()
    arrays_dtype = staticmethod(arrays_dtype)
    # The allocation kind's entries (omnirotor.blocks.KIND_STEPS): up to the QP, the compiled QP, its answer.
    kernel = alloc_begin
    finish = alloc_end

    def __init__(
        self,
        vehicle: VehicleParams,
        params: AllocationParams | None = None,
        *,
        state: np.ndarray | None = None,
        arrays: np.ndarray | None = None,
    ):
        """Set up the QP for ``vehicle`` with the nominal map and upright hover as a first solution.

        Args:
            vehicle: the vehicle (rotor count and input bounds ``u_min``/``u_max`` [Hz²]).
            params: allocation parameters; defaults to :class:`AllocationParams()`.
            state: optional ``(1,)`` array of :data:`STATE_DTYPE` to hold :attr:`state` (e.g. a field of the
                controller's state); a new one by default.
            arrays: optional ``(1,)`` array of ``arrays_dtype(n)`` to hold :attr:`arrays` (the controller's
                field ``allocation_arrays``); a new one by default.
        """
        self.params = params if params is not None else AllocationParams()
        self.vehicle = vehicle
        n = vehicle.n_rotors
        self.n = n
        self._u_scale = max(abs(vehicle.u_min), abs(vehicle.u_max))
        self._lam_scaled = self.reg_lambda_used * self._u_scale**2
        self.state = st = state_array(STATE_DTYPE, state, "allocator")
        st["u_scale_hz2"] = self._u_scale
        st["lam_scaled"] = self._lam_scaled
        st["max_iter"] = float(self.params.max_iter)
        self._rec = st[0]
        self._w_B = self._rec["w_B"]  # body-frame reference [N; N·m]
        self.arrays = ar = record_view(state_array(arrays_dtype(n), arrays, "allocator arrays"))
        ar.A_key[...] = math.nan  # no map yet
        ar.lo[:] = vehicle.u_min / self._u_scale
        ar.hi[:] = vehicle.u_max / self._u_scale
        self._f, self._lo, self._hi, self._u = ar.f, ar.lo, ar.hi, ar.u_hz2
        self._lo_sat, self._hi_sat = ar.lo_sat, ar.hi_sat
        self._u_safe, self._As, self._H = ar.u_safe_hz2, ar.As, ar.H
        # Scaled bounds of every rotor.
        self._lo_all = ar.lo.copy()
        self._hi_all = ar.hi.copy()
        self._failed = np.zeros(n, dtype=bool)
        self._sat_margin = self.params.saturation_tol * float(self._hi_all[0] - self._lo_all[0])
        alloc_set_map(self._rec, ar, np.ascontiguousarray(vehicle.A_nom, dtype=np.float64))
        self._refresh_bound_lists()
        self._backend = self._make_backend()
        self.reset()

    # -- set-up -----------------------------------------------------------------------------------------

    # -- the outcome of the last solve, kept in the state (the compiled step updates it) ---------------------

    @property
    def status(self) -> AllocationStatus:
        """:class:`AllocationStatus` of the last solve."""
        return AllocationStatus(int(self._rec["status"]))

    @property
    def n_fallbacks(self) -> int:
        """Solver failures (pseudo-inverse fallbacks) since construction or :meth:`reset`."""
        return int(self._rec["n_fallbacks"])

    @property
    def n_nonfinite(self) -> int:
        """Calls with a NaN/inf input since construction or :meth:`reset`."""
        return int(self._rec["n_nonfinite"])

    @property
    def saturated(self) -> bool:
        """True when some active rotor sits at a bound in the last result."""
        return bool(self._rec["saturated"])

    @property
    def kernel_backend(self) -> _ActiveSetBackend | None:
        """The compiled solver's backend, or None for daqp and proxsuite (solved from Python)."""
        return self._backend if isinstance(self._backend, _ActiveSetBackend) else None

    @property
    def solves_compiled(self) -> bool:
        """True when the compiled step solves the QP itself (active-set); False: :meth:`solve_qp` from Python."""
        return self.kernel_backend is not None

    @property
    def reg_lambda_used(self) -> float:
        """The regulariser this vehicle gets [N²/Hz⁴] (``reg_lambda``, scaled by c_f² unless told not to)."""
        lam = self.params.reg_lambda
        if self.params.reg_scale_with_c_f:
            lam *= (self.vehicle.c_f / REG_REFERENCE_C_F) ** 2
        return lam

    def _make_backend(self) -> _ActiveSetBackend | _DaqpBackend | _ProxsuiteBackend:
        if self.params.solver == "active-set":
            return _ActiveSetBackend(self._H, self._f, self._lo, self._hi, self.params, self.arrays)
        cls = {"daqp": _DaqpBackend, "proxsuite": _ProxsuiteBackend}
        return cls[self.params.solver](self._H, self._f, self._lo, self._hi, self.params)

    @property
    def failed_rotors(self) -> np.ndarray:
        """(n,) bool mask of the rotors excluded from the allocation (read-only view)."""
        v = self._failed.view()
        v.flags.writeable = False
        return v

    def set_failed_rotors(self, mask: np.ndarray | None) -> None:
        """Exclude rotors from the allocation: their input is forced to 0.

        Args:
            mask: (n,) bool, True for a failed rotor; None (or all False) restores every rotor.

        Raises:
            InputError: wrong shape, or every rotor excluded.
        """
        if mask is None:
            failed = np.zeros(self.n, dtype=bool)
        else:
            failed = np.asarray(mask, dtype=bool)
            if failed.shape != (self.n,):
                raise InputError(f"failed-rotor mask must have shape ({self.n},), got {failed.shape}")
            if failed.all():
                raise InputError("cannot exclude every rotor")
        self._failed[:] = failed
        self.arrays.failed[:] = failed
        self._lo[:] = np.where(failed, 0.0, self._lo_all)
        self._hi[:] = np.where(failed, 0.0, self._hi_all)
        self._refresh_bound_lists()
        self._backend.set_bounds()
        np.clip(self._u_safe, self._lo * self._u_scale, self._hi * self._u_scale, out=self._u_safe)

    def _refresh_bound_lists(self) -> None:
        """Saturation thresholds: a failed rotor sits at its [0, 0] bounds by design and never counts."""
        inf = math.inf
        margin = self._sat_margin
        self._lo_sat[:] = np.where(self._failed, -inf, self._lo + margin)
        self._hi_sat[:] = np.where(self._failed, inf, self._hi - margin)

    def reset(self) -> None:
        """Forget the history: cold-start the solver, clear counters, hold the clipped upright hover input.

        The failed-rotor mask and the current map are kept.
        """
        self._backend.setup(self._H, self._f)
        hover = self.vehicle.hover_input()
        np.clip(hover, self._lo * self._u_scale, self._hi * self._u_scale, out=self._u_safe)
        self._u[:] = self._u_safe
        for name in ("w_B", "status", "n_fallbacks", "n_nonfinite", "saturated"):
            self.state[name] = 0.0
        for arr in (self.arrays.f, self.arrays.x, self.arrays.work):  # last step's values and scratch
            arr[:] = 0.0

    # -- the 1 kHz call -----------------------------------------------------------------------------------

    def solve(self, w_ref: np.ndarray, R_WB: np.ndarray, A: np.ndarray) -> np.ndarray:
        """Allocate the wrench reference to the rotors (:func:`alloc_begin`, the backend's QP, :func:`alloc_end`).

        Args:
            w_ref: (6,) ``[f_ref_W [N]; m_ref_B [N·m]]``.
            R_WB: (3, 3) attitude, body to world.
            A: (6, n) wrench map in use (body frame, SPEC §1.2), e.g. from ``MapScheduler.select``.

        Returns:
            (n,) inputs u [Hz²], finite and within bounds. The array belongs to the allocator and is
            overwritten by the next call: copy it to keep it.
        """
        f64 = np.float64
        w = np.asarray(w_ref, dtype=f64)
        if w.shape != (6,):
            raise InputError(f"w_ref must have shape (6,), got {w.shape}")
        code = alloc_begin(self._rec, self.arrays, w[:3], w[3:], np.asarray(R_WB, dtype=f64), np.asarray(A, dtype=f64))
        if code != BEGIN_HELD:
            alloc_end(self._rec, self.arrays, self.solve_qp(code))
        return self._u

    def solve_qp(self, begin_code: int) -> bool:
        """The backend's QP on the prepared linear term; its answer in ``arrays.x``. True when solved.

        Args:
            begin_code: the result of :func:`alloc_begin` (``BEGIN_SOLVE_NEW_MAP``: the backend is given the
                rebuilt Hessian first).
        """
        if begin_code == BEGIN_SOLVE_NEW_MAP:
            self._backend.set_hessian(self._H)
        x = self._backend.solve(self._f)
        if x is None:
            return False
        if x is not self.arrays.x:
            self.arrays.x[:] = x
        return True


@jit_inline
def boxqp_solve_arrays(ar, max_iter: int) -> int:
    """The compiled QP (:func:`omnirotor.control._qp.boxqp_solve`) on the allocator's arrays; its code."""
    return _qp.boxqp_solve(ar.H, ar.f, ar.lo, ar.hi, ar.x, ar.active, ar.work, max_iter)


@jit_inline
def boxqp_solve_record(r, ar) -> bool:
    """The allocation kind's entry ``qp``: the compiled QP on the allocator's arrays; True when it solved."""
    return boxqp_solve_arrays(ar, int(r.max_iter)) >= 1


Allocator.qp = boxqp_solve_record  # the kind's entry ``qp`` (defined after the class, beside the solver it calls)
