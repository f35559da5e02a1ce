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

from omnirotor.config import check_positive
from omnirotor.control import _kernels as _k
from omnirotor.control import _qp
from omnirotor.control import _step_kernels as _sk
from omnirotor.errors import InputError
from omnirotor.vehicle import VehicleParams

__all__ = ["AllocationParams", "AllocationStatus", "Allocator", "SOLVERS", "REG_REFERENCE_C_F"]

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

    def __init__(self, H: np.ndarray, f: np.ndarray, lo: np.ndarray, hi: np.ndarray, params: AllocationParams):
        n = f.shape[0]
        self.H = H
        self.lo = lo
        self.hi = hi
        self.x = np.zeros(n)
        self.active = np.zeros(n, dtype=np.int64)
        self.work = np.zeros(_qp.boxqp_work_size(n))
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


class Allocator:
    """Rotor inputs [Hz²] from a wrench reference by the bounded least-squares QP of SPEC §4.2.

    Attributes:
        status: :class:`AllocationStatus` of the last :meth:`solve`.
        n_fallbacks: number of solver failures (pseudo-inverse fallbacks) since construction or :meth:`reset`.
        n_nonfinite: number of calls with a NaN/inf input since construction or :meth:`reset`.
        saturated: True when some active rotor sits at a bound in the last result.
        failed_rotors: (n,) bool mask of the rotors excluded from the allocation (read-only view).
        kernel_state: the packed per-step data the compiled kernels read and write (layout ``ALLOC_*`` and
            ``alloc_offsets`` of :mod:`omnirotor.control._kernels`).
    """

    def __init__(
        self, vehicle: VehicleParams, params: AllocationParams | None = None, *, buffer: np.ndarray | None = None
    ):
        """Set up the QP for ``vehicle`` with the nominal map and upright hover as a first solution.

        Args:
            vehicle: the vehicle (rotor count and input bounds ``u_min``/``u_max`` [Hz²]).
            params: allocation parameters; defaults to :class:`AllocationParams()`.
            buffer: optional float64 array of ``alloc_offsets(n)[-1]`` entries (:mod:`omnirotor.control._kernels`)
                to hold :attr:`kernel_state`; a new one by default.
        """
        self.params = params if params is not None else AllocationParams()
        self.vehicle = vehicle
        n = vehicle.n_rotors
        self.n = n
        self._u_scale = max(abs(vehicle.u_min), abs(vehicle.u_max))
        self._lam_scaled = self.reg_lambda_used * self._u_scale**2
        # The per-step data in one array, the layout of control._kernels (ALLOC_*, alloc_offsets): the
        # body-frame reference, the linear term f, the map the QP was built for, G = -(A u_scale)ᵀ, the scaled
        # bounds in force (failed rotors pinned to 0) and their saturation thresholds, u and the last safe u.
        o_f, o_key, o_G, o_lo, o_hi, o_lo_sat, o_hi_sat, o_u, o_u_safe, size = _k.alloc_offsets(n)
        self.kernel_state = ws = _k.state_buffer(buffer, size, "allocator")
        ws[_k.ALLOC_SCALE] = self._u_scale
        self._w_B = ws[_k.ALLOC_W_B : _k.ALLOC_W_B + 6]  # body-frame reference [N; N·m]
        self._f = ws[o_f : o_f + n]
        self._A_key = ws[o_key : o_key + 6 * n].reshape(6, n)
        self._A_key[:] = math.nan  # no map yet
        self._G = ws[o_G : o_G + 6 * n].reshape(n, 6)  # -(A u_scale)ᵀ: f = G w_B
        self._lo = ws[o_lo : o_lo + n]
        self._hi = ws[o_hi : o_hi + n]
        self._lo_sat = ws[o_lo_sat : o_lo_sat + n]
        self._hi_sat = ws[o_hi_sat : o_hi_sat + n]
        self._u = ws[o_u : o_u + n]  # returned to the caller [Hz²]
        self._u_safe = ws[o_u_safe : o_u_safe + n]  # last finite, in-bounds command [Hz²]
        # Scaled bounds of every rotor.
        self._lo_all = np.full(n, vehicle.u_min / self._u_scale)
        self._hi_all = np.full(n, vehicle.u_max / self._u_scale)
        self._lo[:] = self._lo_all
        self._hi[:] = self._hi_all
        self._failed = np.zeros(n, dtype=bool)
        self.kernel_failed = np.zeros(n)
        """(n,) 1.0 for a failed rotor (the mask as floats, for the compiled fallback)."""
        self.kernel_counters = np.zeros(_sk.AC_SIZE, dtype=np.int64)
        """int64 ``AC_*`` of :mod:`omnirotor.control._step_kernels`: status, counts and the saturation flag."""
        self._sat_margin = self.params.saturation_tol * float(self._hi_all[0] - self._lo_all[0])
        # Problem data in the scaled variables, rebuilt when the map changes.
        self._As = np.empty((6, n))  # A * u_scale  [N, N·m per unit x]
        self._H = np.empty((n, n))
        self.status = AllocationStatus.OK
        self.n_fallbacks = 0
        self.n_nonfinite = 0
        self.saturated = False
        self._set_map(vehicle.A_nom)
        self._refresh_bound_lists()
        self._backend = self._make_backend()
        self.reset()

    # -- set-up -----------------------------------------------------------------------------------------

    # -- the outcome of the last solve, kept in kernel_counters (the compiled controller step updates it) ---------

    @property
    def status(self) -> AllocationStatus:
        """:class:`AllocationStatus` of the last solve."""
        return AllocationStatus(int(self.kernel_counters[_sk.AC_STATUS]))

    @status.setter
    def status(self, value: AllocationStatus) -> None:
        self.kernel_counters[_sk.AC_STATUS] = int(value)

    @property
    def n_fallbacks(self) -> int:
        """Solver failures (pseudo-inverse fallbacks) since construction or :meth:`reset`."""
        return int(self.kernel_counters[_sk.AC_N_FALLBACKS])

    @n_fallbacks.setter
    def n_fallbacks(self, value: int) -> None:
        self.kernel_counters[_sk.AC_N_FALLBACKS] = value

    @property
    def n_nonfinite(self) -> int:
        """Calls with a NaN/inf input since construction or :meth:`reset`."""
        return int(self.kernel_counters[_sk.AC_N_NONFINITE])

    @n_nonfinite.setter
    def n_nonfinite(self, value: int) -> None:
        self.kernel_counters[_sk.AC_N_NONFINITE] = value

    @property
    def saturated(self) -> bool:
        """True when some active rotor sits at a bound in the last result."""
        return bool(self.kernel_counters[_sk.AC_SATURATED])

    @saturated.setter
    def saturated(self, value: bool) -> None:
        self.kernel_counters[_sk.AC_SATURATED] = 1 if value else 0

    @property
    def kernel_backend(self) -> _ActiveSetBackend | None:
        """The compiled solver's backend (its arrays go to the compiled step), or None for daqp and proxsuite."""
        return self._backend if isinstance(self._backend, _ActiveSetBackend) else None

    @property
    def kernel_As(self) -> np.ndarray:  # noqa: N802 (a matrix)
        """(6, n) the map in use times u_scale, the compiled fallback's and ``alloc_set_map``'s array."""
        return self._As

    @property
    def reg_lambda_used(self) -> float:
        """The regulariser this vehicle gets [N²/Hz⁴] (``reg_lambda``, scaled by c_f² unless told not to)."""
        lam = self.params.reg_lambda
        if self.params.reg_scale_with_c_f:
            lam *= (self.vehicle.c_f / REG_REFERENCE_C_F) ** 2
        return lam

    @property
    def kernel_lam_scaled(self) -> float:
        """The regulariser in scaled units, ``lambda u_scale²``."""
        return self._lam_scaled

    def _make_backend(self) -> _ActiveSetBackend | _DaqpBackend | _ProxsuiteBackend:
        cls = {"active-set": _ActiveSetBackend, "daqp": _DaqpBackend, "proxsuite": _ProxsuiteBackend}
        return cls[self.params.solver](self._H, self._f, self._lo, self._hi, self.params)

    def _set_map(self, A: np.ndarray) -> None:
        """Rebuild the Hessian for a new wrench map (A already checked finite by the caller).

        Compiled (:func:`omnirotor.control._qp.alloc_set_map`): As = A u_scale, G = -Asᵀ, H = AsᵀAs + lambda_s I
        and the map key, in place.
        """
        _qp.alloc_set_map(self.kernel_state, A, self._As, self._H, self._lam_scaled)

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
        self.kernel_failed[:] = failed
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
        self.status = AllocationStatus.OK
        self.n_fallbacks = 0
        self.n_nonfinite = 0
        self.saturated = False

    # -- the 1 kHz call -----------------------------------------------------------------------------------

    def solve(self, w_ref: np.ndarray, R_WB: np.ndarray, A: np.ndarray) -> np.ndarray:
        """Allocate the wrench reference to the rotors.

        Args:
            w_ref: (6,) ``[f_ref_W [N]; m_ref_B [N·m]]``.
            R_WB: (3, 3) attitude, body to world.
            A: (6, n) wrench map in use (body frame, SPEC §1.2), e.g. from ``MapScheduler.select``.

        Returns:
            (n,) inputs u [Hz²], finite and within bounds. The array belongs to the allocator and is
            overwritten by the next call: copy it to keep it.
        """
        f64 = np.float64
        w_ref = np.asarray(w_ref, dtype=f64)
        R_WB = np.asarray(R_WB, dtype=f64)
        A = np.asarray(A, dtype=f64)
        code = _k.alloc_prepare(self.kernel_state, w_ref, R_WB, A)
        if code != _k.PRE_OK and not self._resolve(code, w_ref, R_WB, A):
            return self._hold()
        return self._finish(self._backend.solve(self._f))

    def _resolve(self, code: int, w_ref: np.ndarray, R_WB: np.ndarray, A: np.ndarray) -> bool:
        """After :func:`alloc_prepare` did not return OK: rebuild the QP for a new map and prepare again.

        Returns:
            True when the linear term is ready, False when the inputs are not finite (the caller holds).
        """
        if code == _k.PRE_MAP_CHANGED:
            if not math.isfinite(float(A.sum())):
                return False
            self._set_map(A)
            self._backend.set_hessian(self._H)
            code = _k.alloc_prepare(self.kernel_state, w_ref, R_WB, A)
        return code == _k.PRE_OK

    def _finish(self, x: np.ndarray | None) -> np.ndarray:
        """Clip, scale and flag saturation (:func:`alloc_finish`); the clipped pseudo-inverse if x failed."""
        sat = -1 if x is None else _k.alloc_finish(self.kernel_state, np.asarray(x, dtype=np.float64), _k.FINISH_QP)
        if sat < 0:
            sat = _k.alloc_finish(self.kernel_state, self._fallback(), _k.FINISH_FALLBACK)
        else:
            self.status = AllocationStatus.OK
        self.saturated = bool(sat)
        return self._u

    def _hold(self) -> np.ndarray:
        self.status = AllocationStatus.NONFINITE
        self.n_nonfinite += 1
        self._u[:] = self._u_safe
        return self._u

    def _fallback(self) -> np.ndarray:
        """Pseudo-inverse of the map restricted to the working rotors (scaled x; clipped by the caller)."""
        self.status = AllocationStatus.FALLBACK
        self.n_fallbacks += 1
        As = np.where(self._failed, 0.0, self._As)
        return np.linalg.pinv(As) @ self._w_B
