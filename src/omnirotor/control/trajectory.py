"""Desired end-effector trajectory through timed pose waypoints (SPEC §4.5).

Between two waypoints the position follows the rest-to-rest minimum-jerk quintic and the attitude moves
along the geodesic of SO(3) with a smooth time scaling ``s(t)`` in [0, 1]:

    p(t) = p_i + s(t) (p_{i+1} - p_i),       s = 10 tau^3 - 15 tau^4 + 6 tau^5,  tau = (t - t_i) / T_i
    R(t) = R_i exp(s_R(t) [phi_i]x),         phi_i = log(R_i^T R_{i+1})  (body-frame rotation vector)

The attitude scaling ``s_R`` is the same quintic by default (``attitude_profile="quintic"``: angular
acceleration continuous, zero at every waypoint). ``attitude_profile="cubic"`` uses
``s_R = 3 tau^2 - 2 tau^3``, the rest-to-rest profile of minimum integrated squared angular acceleration
(the authors' ``minAaccPolyTraj``); its angular acceleration jumps at the waypoints.

Because ``phi_i`` is constant on a segment, the angular velocity and acceleration have a fixed world
direction: ``omega_W = R_i phi_i s_R'`` and ``alpha_W = R_i phi_i s_R''``. Every sampled quantity is
therefore linear in the eight scalars ``(1, s, s', s'', sin(theta s_R), 1 - cos(theta s_R), s_R', s_R'')``
(Rodrigues' formula with ``theta = |phi_i|``); a segment stores that linear map as one (24, 8) matrix, and
sampling is a single matrix-vector product into the flat buffer of a :class:`ReferenceSample` (no
allocation per call; :func:`trajectory_sample`).

Velocities are zero at every waypoint; before the first and after the last waypoint the trajectory holds
that pose at rest. Angular velocity and acceleration are **world-frame** vectors (``omega_W``,
``alpha_W``), with ``dR/dt = [omega_W]x R``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from omnirotor._jit import jit, jit_entry, jit_inline
from omnirotor.blocks import new_state, register, state_array
from omnirotor.errors import InputError
from omnirotor.so3 import hat, log_so3

__all__ = [
    "Waypoint",
    "ReferenceSample",
    "PoseTrajectory",
    "ATTITUDE_PROFILES",
    "ROTATION_TOLERANCE",
    "REFERENCE_DTYPE",
    "SEGMENT_DTYPE",
    "trajectory_sample",
    "segment_sample",
    "start_segment",
    "packed_size",
    "reference_log_fields",
    "MIN_CAPACITY_WAYPOINTS",
    "capacity_for",
    "TRAJECTORY_DTYPE",
    "WaypointTrajectory",
    "min_jerk_step",
]

ATTITUDE_PROFILES = ("quintic", "cubic")
ROTATION_TOLERANCE = 1e-6
"""Largest entry of ``R^T R - I`` accepted for a waypoint attitude."""

_F8 = np.float64
REFERENCE_DTYPE = np.dtype(
    [
        ("p_W", _F8, 3),  # position [m]
        ("v_W", _F8, 3),  # velocity [m/s]
        ("a_W", _F8, 3),  # acceleration [m/s²]
        ("R_WB", _F8, (3, 3)),  # attitude (frame to world)
        ("omega_W", _F8, 3),  # angular velocity [rad/s], world frame
        ("alpha_W", _F8, 3),  # angular acceleration [rad/s²], world frame
    ]
)
"""A pose reference with its derivatives (named fields; 24 contiguous floats in this order)."""

# The rows of the (24, 8) segment bases, one per float of a reference (the order of REFERENCE_DTYPE).
_P, _V, _A, _R, _OMEGA, _ALPHA = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 18), slice(18, 21), slice(21, 24)
_N_FLAT = 24
# Columns of the per-segment basis: the scalar functions of time the sample is linear in.
_K_ONE, _K_S, _K_SD, _K_SDD, _K_SIN, _K_VERS, _K_SR_D, _K_SR_DD = range(8)
_N_BASIS = 8


class ReferenceSample:
    """A mutable pose reference with its derivatives: a record of :data:`REFERENCE_DTYPE` and views into it.

    Attributes:
        state: the ``(1,)`` record the compiled kernels read and write by field name.
        data: (24,) the same memory as floats: ``p_W, v_W, a_W, R_WB (row-major), omega_W, alpha_W``.
        p_W: (3,) position [m], world frame.
        v_W: (3,) velocity [m/s], world frame.
        a_W: (3,) acceleration [m/s²], world frame.
        R_WB: (3, 3) attitude (frame to world).
        omega_W: (3,) angular velocity [rad/s], **world frame**: ``dR_WB/dt = [omega_W]x R_WB``.
        alpha_W: (3,) angular acceleration [rad/s²], world frame (time derivative of ``omega_W``).
    """

    __slots__ = ("state", "data", "p_W", "v_W", "a_W", "R_WB", "omega_W", "alpha_W")

    def __init__(self, data: np.ndarray | None = None) -> None:
        """A sample at the origin with identity attitude, at rest.

        Args:
            data: optional memory to use (zeroed): a ``(1,)`` array of :data:`REFERENCE_DTYPE` (e.g. a field of
                the controller's state) or a contiguous (24,) float64 array; a new one by default.

        Raises:
            InputError: ``data`` is neither.
        """
        if data is None:
            state = new_state(REFERENCE_DTYPE)
        elif (
            isinstance(data, np.ndarray)
            and data.dtype == REFERENCE_DTYPE
            and data.shape == (1,)
            and data.flags.writeable
        ):
            state = data
        elif (
            isinstance(data, np.ndarray)
            and data.dtype == np.float64
            and data.shape == (_N_FLAT,)
            and data.flags.c_contiguous
            and data.flags.writeable
        ):
            state = data.view(REFERENCE_DTYPE)
            state = state.view(np.recarray) if isinstance(new_state(REFERENCE_DTYPE), np.recarray) else state
        else:
            raise InputError(
                "ReferenceSample memory must be a (1,) REFERENCE_DTYPE or a contiguous (24,) float64 array"
            )
        state[...] = np.zeros(1, dtype=REFERENCE_DTYPE)
        self.state = state
        self.data = state.view(np.float64)
        rec = state[0]
        self.p_W = rec["p_W"]
        self.v_W = rec["v_W"]
        self.a_W = rec["a_W"]
        self.R_WB = rec["R_WB"]
        self.omega_W = rec["omega_W"]
        self.alpha_W = rec["alpha_W"]
        self.R_WB[...] = np.eye(3)

    @classmethod
    def at_rest(cls, p_W: np.ndarray, R_WB: np.ndarray) -> ReferenceSample:
        """A sample holding pose ``(p_W [m], R_WB)`` with zero velocities and accelerations."""
        out = cls()
        out.p_W[:] = p_W
        out.R_WB[:] = R_WB
        return out

    def copy_from(self, other: ReferenceSample) -> None:
        """Overwrite this sample with ``other`` (no allocation)."""
        np.copyto(self.data, other.data)

    def copy(self) -> ReferenceSample:
        """An independent copy."""
        out = ReferenceSample()
        out.copy_from(self)
        return out

    def __repr__(self) -> str:
        return f"ReferenceSample(p_W={self.p_W.tolist()}, R_WB={self.R_WB.tolist()})"


# Packed trajectory (PoseTrajectory.kernel_data): n_waypoints, cubic flag, times (n_wp), thetas (n_wp - 1),
# then (24 x 8) bases, row-major: hold first, hold last, one per segment.
_BASIS_SIZE = _N_FLAT * _N_BASIS


def reference_log_fields(role: str) -> tuple[tuple[str, tuple[str]], ...]:
    """The fields of a reference record a log records, named for its ``role`` (``"E_ref"``: ``p_E_ref_W``, ...)."""
    return (
        (f"p_{role}_W", ("p_W",)),
        (f"v_{role}_W", ("v_W",)),
        (f"a_{role}_W", ("a_W",)),
        (f"R_{role}", ("R_WB",)),
        (f"omega_{role}_W", ("omega_W",)),
        (f"alpha_{role}_W", ("alpha_W",)),
    )


def packed_size(n_waypoints: int) -> int:
    """Floats of the packed trajectory of ``n_waypoints`` waypoints (:attr:`PoseTrajectory.kernel_data`)."""
    return 2 + n_waypoints + (n_waypoints - 1) + _BASIS_SIZE * (n_waypoints + 1)


MIN_CAPACITY_WAYPOINTS = 32
"""The waypoints the controller's trajectory field holds by default (``ControllerParams.trajectory_waypoints``):
every shipped contact task's trajectory fits (the longest, the point contacts', has 17)."""


def capacity_for(n_waypoints: int) -> int:
    """A trajectory capacity [waypoints] for a run that flies ``n_waypoints``, set before its controller is built.

    The next power of two (at least :data:`MIN_CAPACITY_WAYPOINTS`), so that runs of similar length share one
    controller record, and one compiled step.
    """
    w = MIN_CAPACITY_WAYPOINTS
    while w < n_waypoints:
        w *= 2
    return w


@jit
def _basis_row(pk, b: int, k1: float, k2: float, k3: float, k4: float, k5: float, sd: float, sdd: float) -> float:
    """One row of a segment basis times the scalars of time (the columns' order)."""
    acc = 0.0
    acc += pk[b] * 1.0
    acc += pk[b + 1] * k1
    acc += pk[b + 2] * k2
    acc += pk[b + 3] * k3
    acc += pk[b + 4] * k4
    acc += pk[b + 5] * k5
    acc += pk[b + 6] * sd
    acc += pk[b + 7] * sdd
    return acc


@jit
def _write_rows(pk, o: int, k1: float, k2: float, k3: float, k4: float, k5: float, sd: float, sdd: float, out) -> None:
    """The reference from the basis at ``pk[o:]`` into the record ``out``, field by field."""
    nb = _N_BASIS
    for i in range(3):
        out.p_W[i] = _basis_row(pk, o + i * nb, k1, k2, k3, k4, k5, sd, sdd)
        out.v_W[i] = _basis_row(pk, o + (3 + i) * nb, k1, k2, k3, k4, k5, sd, sdd)
        out.a_W[i] = _basis_row(pk, o + (6 + i) * nb, k1, k2, k3, k4, k5, sd, sdd)
    for i in range(3):
        for j in range(3):
            out.R_WB[i, j] = _basis_row(pk, o + (9 + 3 * i + j) * nb, k1, k2, k3, k4, k5, sd, sdd)
    for i in range(3):
        out.omega_W[i] = _basis_row(pk, o + (18 + i) * nb, k1, k2, k3, k4, k5, sd, sdd)
        out.alpha_W[i] = _basis_row(pk, o + (21 + i) * nb, k1, k2, k3, k4, k5, sd, sdd)


@jit
def _write_hold(pk, o: int, out) -> None:
    """The hold basis at ``pk[o:]`` times (1, 0, ..., 0), i.e. its first column, into record ``out``."""
    nb = _N_BASIS
    for i in range(3):
        out.p_W[i] = pk[o + i * nb]
        out.v_W[i] = pk[o + (3 + i) * nb]
        out.a_W[i] = pk[o + (6 + i) * nb]
    for i in range(3):
        for j in range(3):
            out.R_WB[i, j] = pk[o + (9 + 3 * i + j) * nb]
    for i in range(3):
        out.omega_W[i] = pk[o + (18 + i) * nb]
        out.alpha_W[i] = pk[o + (21 + i) * nb]


@jit_inline
def trajectory_sample(pk, t: float, out) -> None:
    """The reference at time ``t`` [s] of a packed trajectory (:meth:`PoseTrajectory.sample`) into record ``out``.

    ``pk`` may be a record's field (the controller's ``trajectory``) or an array: both reach one compiled
    :func:`_sample` (numba types a field by its shape, ``pk[:]`` as an array), not one version each.
    """
    _sample(pk[:], t, out)


@jit
def _sample(pk, t: float, out) -> None:
    """:func:`trajectory_sample` of the packed trajectory array ``pk``."""
    n_wp = int(pk[0])
    cubic = pk[1] != 0.0
    times = pk[2 : 2 + n_wp]
    thetas = pk[2 + n_wp : 2 + 2 * n_wp - 1]
    o_hold = 2 * n_wp + 1
    if not t > times[0]:
        _write_hold(pk, o_hold, out)
        return
    if not t < times[n_wp - 1]:
        _write_hold(pk, o_hold + _BASIS_SIZE, out)
        return
    i = np.searchsorted(times, t, side="right") - 1
    t0 = times[i]
    T = times[i + 1] - t0
    tau = (t - t0) / T
    tau2 = tau * tau
    tau3 = tau2 * tau
    # The basis values k0 ... k7 (scalars: no array per call).
    k1 = s = tau3 * (10.0 - 15.0 * tau + 6.0 * tau2)
    k2 = sd = 30.0 * tau2 * (1.0 - tau) * (1.0 - tau) / T
    k3 = sdd = 60.0 * tau * (1.0 - 3.0 * tau + 2.0 * tau2) / (T * T)
    if cubic:
        s = tau2 * (3.0 - 2.0 * tau)
        sd = 6.0 * tau * (1.0 - tau) / T
        sdd = (6.0 - 12.0 * tau) / (T * T)
    angle = thetas[i] * s
    k4 = math.sin(angle)
    k5 = 1.0 - math.cos(angle)
    _write_rows(pk, o_hold + 2 * _BASIS_SIZE + i * _BASIS_SIZE, k1, k2, k3, k4, k5, sd, sdd, out)


def _check_rotation(R: np.ndarray, where: str) -> None:
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise InputError(f"{where}: R_WB must be a finite (3, 3) matrix")
    if np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(R) <= 0.0:
        raise InputError(f"{where}: R_WB is not a proper rotation (R^T R = I, det R = +1)")


@dataclasses.dataclass(frozen=True)
class Waypoint:
    """A timed end-effector pose (the EE frame's attitude equals the body's, R_E^B = I, SPEC §1.5).

    Attributes:
        t: time [s], relative to the start of the trajectory.
        p_W: (3,) EE position [m], world frame.
        R_WB: (3, 3) EE attitude (EE to world).
    """

    t: float
    p_W: np.ndarray
    R_WB: np.ndarray

    def __post_init__(self) -> None:
        if not math.isfinite(self.t):
            raise InputError(f"waypoint time must be finite, got {self.t}")
        p = np.array(self.p_W, dtype=float)
        R = np.array(self.R_WB, dtype=float)
        where = f"waypoint at t = {self.t} s"
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise InputError(f"{where}: p_W must be a finite 3-vector")
        _check_rotation(R, where)
        p.flags.writeable = False
        R.flags.writeable = False
        object.__setattr__(self, "t", float(self.t))
        object.__setattr__(self, "p_W", p)
        object.__setattr__(self, "R_WB", R)


def _segment_basis(a: Waypoint, b: Waypoint) -> tuple[np.ndarray, float]:
    """(24, 8) map from the time-scaling scalars to the flat sample on segment a -> b, and theta [rad]."""
    M = np.zeros((_N_FLAT, _N_BASIS))
    dp = b.p_W - a.p_W
    M[_P, _K_ONE] = a.p_W
    M[_P, _K_S] = dp
    M[_V, _K_SD] = dp
    M[_A, _K_SDD] = dp
    phi_B = log_so3(a.R_WB.T @ b.R_WB)
    theta = float(np.linalg.norm(phi_B))
    M[_R, _K_ONE] = a.R_WB.reshape(-1)
    if theta > 0.0:
        K = hat(phi_B / theta)
        M[_R, _K_SIN] = (a.R_WB @ K).reshape(-1)
        M[_R, _K_VERS] = (a.R_WB @ K @ K).reshape(-1)
    phi_W = a.R_WB @ phi_B
    M[_OMEGA, _K_SR_D] = phi_W
    M[_ALPHA, _K_SR_DD] = phi_W
    return M, theta


class PoseTrajectory:
    """Minimum-jerk position and smooth geodesic attitude through timed waypoints (SPEC §4.5).

    Args:
        waypoints: at least one :class:`Waypoint`, with strictly increasing times.
        attitude_profile: "quintic" (default) or "cubic" time scaling of the attitude (module docstring).

    Raises:
        InputError: no waypoints, times not strictly increasing, or an unknown profile.
    """

    def __init__(self, waypoints: Sequence[Waypoint], attitude_profile: str = "quintic") -> None:
        wps = tuple(waypoints)
        if not wps:
            raise InputError("a trajectory needs at least one waypoint")
        for w in wps:
            if not isinstance(w, Waypoint):
                raise InputError(f"expected Waypoint objects, got {type(w).__name__}")
        for w0, w1 in zip(wps[:-1], wps[1:], strict=True):
            if not w1.t > w0.t:
                raise InputError(f"waypoint times must be strictly increasing: {w0.t} s then {w1.t} s")
        if attitude_profile not in ATTITUDE_PROFILES:
            raise InputError(f"attitude_profile must be one of {ATTITUDE_PROFILES}, got {attitude_profile!r}")
        self.waypoints = wps
        self.attitude_profile = attitude_profile
        self._times = [w.t for w in wps]
        bases = []
        thetas = []
        for w0, w1 in zip(wps[:-1], wps[1:], strict=True):
            M, theta = _segment_basis(w0, w1)
            bases.append(M)
            thetas.append(theta)
        hold_first = np.zeros((_N_FLAT, _N_BASIS))
        hold_first[_P, _K_ONE] = wps[0].p_W
        hold_first[_R, _K_ONE] = wps[0].R_WB.reshape(-1)
        hold_last = np.zeros((_N_FLAT, _N_BASIS))
        hold_last[_P, _K_ONE] = wps[-1].p_W
        hold_last[_R, _K_ONE] = wps[-1].R_WB.reshape(-1)
        self.kernel_data = np.concatenate(
            [[float(len(wps)), 1.0 if attitude_profile == "cubic" else 0.0], self._times, thetas]
            + [M.reshape(-1) for M in (hold_first, hold_last, *bases)]
        )
        """The packed trajectory :func:`trajectory_sample` reads: waypoint count,
        cubic flag, times, segment angles theta [rad], then the (24, 8) bases (hold first, hold last, one per
        segment), row-major."""

    @property
    def t_start(self) -> float:
        """Time of the first waypoint [s]."""
        return self._times[0]

    @property
    def t_end(self) -> float:
        """Time of the last waypoint [s]."""
        return self._times[-1]

    def sample(self, t: float, out: ReferenceSample) -> ReferenceSample:
        """Write the reference at time ``t`` [s] into ``out`` and return it (one compiled call).

        Args:
            t: time [s] on the waypoints' clock; outside their range the first/last pose is held at rest.
            out: the sample to overwrite.

        Returns:
            ``out``.
        """
        trajectory_sample(self.kernel_data, float(t), out.state[0])
        return out

    def __call__(self, t: float) -> ReferenceSample:
        """A freshly allocated sample at time ``t`` [s] (convenience; use :meth:`sample` in loops)."""
        return self.sample(t, ReferenceSample())


# -- a segment from a moving reference (the in-flight set-point) -----------------------------------------------

SEGMENT_DTYPE = np.dtype(
    [
        ("active", np.int64),  # 1: the desired reference is this segment's (from t0 on), not the trajectory's
        ("t0", _F8),  # controller time the segment starts at [s]
        ("T", _F8),  # its duration [s]
        ("p0_W", _F8, 3),  # start position [m] ...
        ("v0_W", _F8, 3),  # ... velocity [m/s] ...
        ("a0_W", _F8, 3),  # ... and acceleration [m/s²]: those of the reference it replaces
        ("dp_W", _F8, 3),  # target position minus start position [m]
        ("R0_WB", _F8, (3, 3)),  # start attitude
        ("axis_W", _F8, 3),  # unit axis of the rotation to the target attitude, world frame
        ("theta", _F8),  # its angle [rad]
    ]
)
"""A minimum-jerk segment from a moving reference to a pose at rest (:func:`segment_sample`)."""


@jit
def segment_sample(g, t: float, out) -> None:
    """The reference of segment ``g`` (:data:`SEGMENT_DTYPE`) at controller time ``t`` [s] into record ``out``.

    Position: the quintic that leaves ``p0`` with the velocity ``v0`` and acceleration ``a0`` of the reference
    it replaces and reaches ``p0 + dp`` at rest after ``T``: the rest-to-rest minimum-jerk term ``s(tau) dp``
    plus the quintic Hermite terms ``h1(t) v0 + h2(t) a0``, which carry the initial rates and vanish with their
    first two derivatives at ``T``. So position, velocity and acceleration are continuous where the segment
    takes over. Attitude: the geodesic from ``R0`` to the target with the same quintic time scaling (its
    angular velocity starts at zero). From ``T`` on, the target pose is held at rest.
    """
    T = g.T
    tt = t - g.t0
    if tt < 0.0:
        tt = 0.0
    if tt > T:
        tt = T
    tau = tt / T
    tau2 = tau * tau
    tau3 = tau2 * tau
    s = tau3 * (10.0 - 15.0 * tau + 6.0 * tau2)
    sd = 30.0 * tau2 * (1.0 - tau) * (1.0 - tau) / T
    sdd = 60.0 * tau * (1.0 - 3.0 * tau + 2.0 * tau2) / (T * T)
    # The Hermite terms of the initial velocity (h1) and acceleration (h2), in t' = t - t0.
    x, x2, T2, T3 = tt, tt * tt, T * T, T * T * T
    x3, x4 = x2 * x, x2 * x2
    h1 = x - 6.0 * x3 / T2 + 8.0 * x4 / T3 - 3.0 * x4 * x / (T2 * T2)
    h1d = 1.0 - 18.0 * x2 / T2 + 32.0 * x3 / T3 - 15.0 * x4 / (T2 * T2)
    h1dd = -36.0 * x / T2 + 96.0 * x2 / T3 - 60.0 * x3 / (T2 * T2)
    h2 = 0.5 * x2 - 1.5 * x3 / T + 1.5 * x4 / T2 - 0.5 * x4 * x / T3
    h2d = x - 4.5 * x2 / T + 6.0 * x3 / T2 - 2.5 * x4 / T3
    h2dd = 1.0 - 9.0 * x / T + 18.0 * x2 / T2 - 10.0 * x3 / T3
    for i in range(3):
        dp, v0, a0 = g.dp_W[i], g.v0_W[i], g.a0_W[i]
        out.p_W[i] = g.p0_W[i] + s * dp + h1 * v0 + h2 * a0
        out.v_W[i] = sd * dp + h1d * v0 + h2d * a0
        out.a_W[i] = sdd * dp + h1dd * v0 + h2dd * a0
    # R = exp(s theta [k]x) R0 (Rodrigues), omega = k theta s', alpha = k theta s''.
    k = g.axis_W
    ang = g.theta * s
    sn, vs = math.sin(ang), 1.0 - math.cos(ang)
    k0, k1, k2 = k[0], k[1], k[2]
    for j in range(3):
        r0, r1, r2 = g.R0_WB[0, j], g.R0_WB[1, j], g.R0_WB[2, j]
        c0 = k1 * r2 - k2 * r1  # k x r (the column of K R0)
        c1 = k2 * r0 - k0 * r2
        c2 = k0 * r1 - k1 * r0
        d0 = k1 * c2 - k2 * c1  # k x (k x r) (the column of K² R0)
        d1 = k2 * c0 - k0 * c2
        d2 = k0 * c1 - k1 * c0
        out.R_WB[0, j] = r0 + sn * c0 + vs * d0
        out.R_WB[1, j] = r1 + sn * c1 + vs * d1
        out.R_WB[2, j] = r2 + sn * c2 + vs * d2
    for i in range(3):
        out.omega_W[i] = k[i] * g.theta * sd
        out.alpha_W[i] = k[i] * g.theta * sdd


def start_segment(
    segment: np.ndarray, current: ReferenceSample, t0: float, p_W: np.ndarray, R_WB: np.ndarray, duration_s: float
) -> None:
    """Start a segment (:data:`SEGMENT_DTYPE`, a ``(1,)`` array) at controller time ``t0`` from ``current``.

    The segment leaves the pose, velocity and acceleration of the reference ``current`` and reaches the pose
    ``(p_W, R_WB)`` at rest after ``duration_s`` (:func:`segment_sample`).

    Raises:
        InputError: a target that is not a finite position and a proper rotation, or a duration that is not
            positive and finite.
    """
    p = np.asarray(p_W, dtype=float)
    R = np.asarray(R_WB, dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise InputError("segment target p_W must be a finite 3-vector")
    _check_rotation(R, "segment target")
    if not (isinstance(duration_s, int | float) and math.isfinite(duration_s) and duration_s > 0.0):
        raise InputError(f"segment duration_s must be positive and finite, got {duration_s!r}")
    R0 = np.array(current.R_WB, dtype=float)
    phi_W = R0 @ log_so3(R0.T @ R)  # the rotation to the target, world frame (R = exp([phi_W]x) R0)
    theta = float(np.linalg.norm(phi_W))
    g = segment[0]
    g["t0"], g["T"] = float(t0), float(duration_s)
    g["p0_W"], g["v0_W"], g["a0_W"] = current.p_W, current.v_W, current.a_W
    g["dp_W"] = p - current.p_W
    g["R0_WB"] = R0
    g["axis_W"] = phi_W / theta if theta > 0.0 else 0.0
    g["theta"] = theta
    g["active"] = 1


# -- the trajectory block: the kind the controller's step samples (omnirotor.blocks.KIND_STEPS) ----------------

TRAJECTORY_DTYPE = np.dtype(
    [
        ("n_waypoints", np.int64),  # waypoints of the trajectory loaded (0: none)
        ("capacity", np.int64),  # the most waypoints its data holds (fixed when it is built)
        ("t_s", _F8),  # the time of the last sample [s]
        ("n_nonfinite", _F8),  # samples asked at a non-finite time (the reference was kept)
    ]
)
"""The state of :class:`WaypointTrajectory` (its waypoints are packed in its ``data``, a field of its own)."""


@jit
def min_jerk_step(r, data, t: float, ref) -> None:
    """The trajectory kind's step: the reference of the packed trajectory ``data`` at time ``t`` into ``ref``.

    A non-finite ``t`` is counted and leaves ``ref`` as it was (:func:`trajectory_sample` otherwise).
    """
    if not math.isfinite(t):
        r.n_nonfinite += 1.0
        return
    r.t_s = t
    trajectory_sample(data, t, ref)


@jit_entry
def _min_jerk_entry(state, data, t: float, ref) -> None:
    min_jerk_step(state[0], data, t, ref[0])


@register("trajectory", "min-jerk")
class WaypointTrajectory:
    """The controller's desired EE trajectory: a :class:`PoseTrajectory` packed into a capacity fixed at build.

    The capacity (waypoints) is fixed when the block, and so the controller's record, is built: the record's
    type, hence its compiled step, never changes when a trajectory is loaded, and a flight node never waits for a
    compilation between two frames. A trajectory with more waypoints than that is refused with one line
    (:meth:`load`); raise ``ControllerParams.trajectory_waypoints`` for it.

    Args:
        capacity_waypoints: the most waypoints it holds (default :data:`MIN_CAPACITY_WAYPOINTS`).
        state: optional ``(1,)`` array of :data:`TRAJECTORY_DTYPE` (the controller's field ``trajectory``).
        data: optional ``(data_size(capacity_waypoints),)`` float array for the packed trajectory (the
            controller's field ``trajectory_data``).

    Raises:
        InputError: a capacity that is not an integer >= 1, or ``data`` of the wrong size.
    """

    state_dtype = TRAJECTORY_DTYPE
    log_fields = ()
    kernel = min_jerk_step

    @classmethod
    def data_size(cls, capacity_waypoints: int) -> int:
        """Floats of the packed data of ``capacity_waypoints`` waypoints (:func:`packed_size`)."""
        return packed_size(capacity_waypoints)

    def __init__(
        self,
        capacity_waypoints: int = MIN_CAPACITY_WAYPOINTS,
        *,
        state: np.ndarray | None = None,
        data: np.ndarray | None = None,
    ) -> None:
        n = capacity_waypoints
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise InputError(f"trajectory capacity must be an integer >= 1 (waypoints), got {n!r}")
        size = self.data_size(n)
        if data is None:
            data = np.zeros(size)
        elif not (isinstance(data, np.ndarray) and data.shape == (size,) and data.dtype == np.float64):
            raise InputError(f"trajectory data must be a ({size},) float64 array")
        self.capacity_waypoints = n
        self.data = data
        self.data[:] = 0.0
        self.state = state_array(TRAJECTORY_DTYPE, state, "waypoint trajectory")
        self.state["capacity"] = n
        self.trajectory: PoseTrajectory | None = None

    def load(self, trajectory: PoseTrajectory) -> None:
        """Fly ``trajectory`` from now on (its waypoints packed into :attr:`data`).

        Raises:
            InputError: not a :class:`PoseTrajectory`, or more waypoints than the capacity.
        """
        if not isinstance(trajectory, PoseTrajectory):
            raise InputError(f"expected a PoseTrajectory, got {type(trajectory).__name__}")
        n = len(trajectory.waypoints)
        if n > self.capacity_waypoints:
            raise InputError(
                f"trajectory of {n} waypoints exceeds the controller's capacity of {self.capacity_waypoints} "
                "(raise ControllerParams.trajectory_waypoints)"
            )
        packed = trajectory.kernel_data
        self.data[: packed.shape[0]] = packed
        self.data[packed.shape[0] :] = 0.0
        self.state["n_waypoints"] = n
        self.trajectory = trajectory

    def reset(self) -> None:
        """Clear the counter and the last sample's time (the trajectory loaded is kept)."""
        self.state["t_s"] = 0.0
        self.state["n_nonfinite"] = 0.0

    def sample(self, t: float, out: ReferenceSample) -> ReferenceSample:
        """The reference at time ``t`` [s] into ``out`` (the kind's step, as the controller's runs it)."""
        _min_jerk_entry(self.state, self.data, float(t), out.state)
        return out
