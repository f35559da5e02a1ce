"""External wrench observer: acceleration-based force, momentum-based moment (SPEC §4.3, eqs. 7-8).

Force, world frame, a first-order filter of the force residual (``a`` = world acceleration p̈):

    d/dt f_hat = L (m (a + g e3) - R A1 u - f_hat)         discrete: f_hat += L dt (... - f_hat)

Moment, body frame, the generalized-momentum observer with ``q = J omega`` and ``q0 = q(t0)``:

    s += (omega x J omega - A2 u - m_hat) dt,     m_hat = K_I (J omega - q0 + s)

which gives ``d/dt m_hat = K_I (m_ext - m_hat)``: both raw estimates converge to the true wrench as
first-order lags with time constants ``1/L`` and ``1/K_I``. ``A`` is the wrench map selected for the
current attitude (the same one the allocation uses, SPEC §3.3) and ``u`` [Hz²] the rotor inputs acting on
the vehicle (measured rotor speeds on the robot, ``u = |omega| omega``).

Both raw estimates then pass a first-order low-pass ``y += lambda_f (x - y)`` with
``lambda_f = 2 pi dt f_c / (2 pi dt f_c + 1)`` (0.0591 at f_c = 10 Hz, dt = 1 ms), and a constant
``bias`` (6,) is subtracted from the filtered output.

Optional zeroing (LAAS ``set_wo_zero``, SPEC §4.3 [A]): with ``zero_at_start`` the observer outputs zero
for ``zero_settle_s`` after :meth:`WrenchObserver.reset` (the vehicle is expected to hover at its initial
attitude, free of contact), then averages its filtered output over the next ``zero_window_s`` and from
then on subtracts that average. What remains is the attitude-dependent part of the model error. The
output stays zero until the offset is captured, so the capture causes no jump.

Two estimates are therefore available after each step:

* ``f_filt_W``, ``m_filt_B`` (:attr:`WrenchObserver.filtered`): the low-passed estimate of *everything* the
  model does not explain (interaction plus model error), which the pose controller subtracts (eqs. 4-5): a
  thrust-model error is then compensated whether or not it was zeroed;
* ``f_ext_W``, ``m_ext_B`` (:attr:`WrenchObserver.output`) = ``filtered - bias - offset``: the *interaction*
  wrench estimate, which drives the admittance filter (and is what :meth:`WrenchObserver.step` returns).

Without bias and zeroing the two are equal, as in the paper.

Block contract (:mod:`omnirotor.blocks`): registered as ``("observer", "momentum")``; state
:data:`STATE_DTYPE`; compiled step :func:`observer_step`, which the controller's compiled step reaches through
``compiled_step("observer")``. Every observer variant has the fields ``f_ext_W``, ``m_ext_B`` (the
interaction estimate, which drives the admittance) and ``f_filt_W``, ``m_filt_B`` (what the pose controller
compensates), and a step ``kernel(record, A, u_hz2, a_W, R_WB, omega_B, dt)``; with a non-finite input the step changes
nothing but ``n_nonfinite``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from omnirotor._jit import jit
from omnirotor.blocks import register, state_array
from omnirotor.config import check_finite, check_positive
from omnirotor.errors import InputError
from omnirotor.messages import StateEstimate
from omnirotor.vehicle import VehicleParams

__all__ = ["ObserverParams", "WrenchObserver", "STATE_DTYPE", "observer_step", "lowpass_coefficient"]

Vec3 = tuple[float, float, float]

_F8 = np.float64
STATE_DTYPE = np.dtype(
    [
        # outputs
        ("f_ext_W", _F8, 3),  # interaction force [N] after the low-pass, bias and zeroing
        ("m_ext_B", _F8, 3),  # interaction moment [N·m], likewise
        ("f_filt_W", _F8, 3),  # the low-passed force estimate f_hat_W [N]
        ("m_filt_B", _F8, 3),  # the low-passed moment estimate m_hat_B [N·m]
        ("offset", _F8, 6),  # offset captured by the zeroing
        # state
        ("f_hat_W", _F8, 3),  # raw force estimate [N]
        ("m_hat_B", _F8, 3),  # raw moment estimate [N·m]
        ("s_B", _F8, 3),  # momentum integral [N·m·s]
        ("q0_B", _F8, 3),  # momentum reference J omega(t0) [kg·m²/s]
        ("q0_set", _F8),  # 1 once q0 is taken
        ("subtract", _F8, 6),  # bias plus the captured offset
        ("capturing", _F8),  # 1 while the zeroing runs
        ("elapsed_s", _F8),  # time since reset during the zeroing [s]
        ("acc", _F8, 6),  # sum of the filtered estimate over the capture window
        ("n_acc", _F8),  # samples in that sum
        ("zeroed", _F8),  # 1 once the offset is captured
        ("lpf_dt_s", _F8),  # dt of the cached low-pass coefficient (NaN: none yet)
        ("lpf_lambda", _F8),
        ("n_nonfinite", _F8),  # steps with a non-finite input (nothing else changed)
        # parameters
        ("gain_force", _F8, 3),  # L [1/s]
        ("gain_moment", _F8, 3),  # K_I [1/s]
        ("mass_kg", _F8),
        ("gravity", _F8),  # [m/s²]
        ("J_diag", _F8, 3),  # inertia diagonal [kg·m²]
        ("cutoff_hz", _F8),  # low-pass cut-off (inf: none)
        ("bias", _F8, 6),
        ("settle_s", _F8),
        ("window_s", _F8),
    ]
)
"""State, parameters and outputs of the momentum observer (named fields; the compiled step reads them so)."""

_PARAMETERS = ("gain_force", "gain_moment", "mass_kg", "gravity", "J_diag", "cutoff_hz", "bias", "settle_s", "window_s")


@jit
def lowpass_coefficient(cutoff_hz: float, dt: float) -> float:
    """Coefficient ``lambda_f`` of the discrete low-pass ``y += lambda_f (x - y)`` (SPEC §4.3).

    Args:
        cutoff_hz: cut-off frequency [Hz]; ``inf`` disables the filter (coefficient 1).
        dt: sample period [s].
    """
    if math.isinf(cutoff_hz):
        return 1.0
    a = 2.0 * math.pi * dt * cutoff_hz
    return a / (a + 1.0)


@jit
def observer_step(r, A, u, a_W, R, omega_B, dt: float) -> None:
    """One step of the momentum observer (module docstring), in place.

    Args:
        r: the observer's state record (:data:`STATE_DTYPE`).
        A: (6, n) wrench map [N/Hz², N·m/Hz²].
        u: (n,) rotor inputs acting on the vehicle [Hz²].
        a_W: (3,) acceleration [m/s²].
        R: (3, 3) ``R_WB``.
        omega_B: (3,) angular velocity [rad/s].
        dt: period [s].
    """
    n = u.shape[0]
    f1 = f2 = f3 = t1 = t2 = t3 = 0.0  # A u, body frame (each row summed over the rotors in order)
    for j in range(n):
        uj = u[j]
        f1 += A[0, j] * uj
        f2 += A[1, j] * uj
        f3 += A[2, j] * uj
        t1 += A[3, j] * uj
        t2 += A[4, j] * uj
        t3 += A[5, j] * uj
    m, g = r.mass_kg, r.gravity
    ax, ay, az = a_W[0], a_W[1], a_W[2]
    r00, r01, r02 = R[0, 0], R[0, 1], R[0, 2]
    r10, r11, r12 = R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22 = R[2, 0], R[2, 1], R[2, 2]
    wx, wy, wz = omega_B[0], omega_B[1], omega_B[2]
    # One sum of every input: finite unless one is not (or they overflow).
    check = f1 + f2 + f3 + t1 + t2 + t3 + ax + ay + az + wx + wy + wz + dt
    check += r00 + r01 + r02 + r10 + r11 + r12 + r20 + r21 + r22
    if not math.isfinite(check):
        r.n_nonfinite += 1.0
        return
    # Force: first-order filter of m (a + g e3) - R A1 u.
    F, L = r.f_hat_W, r.gain_force
    F[0] += L[0] * dt * (m * ax - (r00 * f1 + r01 * f2 + r02 * f3) - F[0])
    F[1] += L[1] * dt * (m * ay - (r10 * f1 + r11 * f2 + r12 * f3) - F[1])
    F[2] += L[2] * dt * (m * (az + g) - (r20 * f1 + r21 * f2 + r22 * f3) - F[2])
    # Moment: generalized momentum q = J omega.
    J = r.J_diag
    hx, hy, hz = J[0] * wx, J[1] * wy, J[2] * wz
    S, MH, Q0, K = r.s_B, r.m_hat_B, r.q0_B, r.gain_moment
    if r.q0_set == 0.0:  # first step after reset: t0, the momentum reference (m_hat stays 0)
        Q0[0], Q0[1], Q0[2] = hx, hy, hz
        r.q0_set = 1.0
    else:
        S[0] += (wy * hz - wz * hy - t1 - MH[0]) * dt
        S[1] += (wz * hx - wx * hz - t2 - MH[1]) * dt
        S[2] += (wx * hy - wy * hx - t3 - MH[2]) * dt
        MH[0] = K[0] * (hx - Q0[0] + S[0])
        MH[1] = K[1] * (hy - Q0[1] + S[1])
        MH[2] = K[2] * (hz - Q0[2] + S[2])
    # Output low-pass, bias, zeroing.
    if dt != r.lpf_dt_s:
        r.lpf_dt_s = dt
        r.lpf_lambda = lowpass_coefficient(r.cutoff_hz, dt)
    lam = r.lpf_lambda
    Yf, Ym = r.f_filt_W, r.m_filt_B
    for i in range(3):
        Yf[i] += lam * (F[i] - Yf[i])
    for i in range(3):
        Ym[i] += lam * (MH[i] - Ym[i])
    fo, mo, sub = r.f_ext_W, r.m_ext_B, r.subtract  # sub: [force; moment] (bias plus the captured offset)
    if r.capturing != 0.0:
        # Zeroing phase: output zero, average the filtered estimate over the window, then latch it.
        r.elapsed_s += dt
        if r.elapsed_s > r.settle_s:
            acc = r.acc
            for i in range(3):
                acc[i] += Yf[i]
                acc[3 + i] += Ym[i]
            r.n_acc += 1.0
            if r.elapsed_s >= r.settle_s + r.window_s:
                for i in range(6):
                    sub[i] = acc[i] / r.n_acc
                    r.offset[i] = sub[i] - r.bias[i]
                r.zeroed = 1.0
                r.capturing = 0.0
        for i in range(3):
            fo[i] = 0.0
            mo[i] = 0.0
    else:
        for i in range(3):
            fo[i] = Yf[i] - sub[i]
            mo[i] = Ym[i] - sub[3 + i]


@dataclasses.dataclass(frozen=True)
class ObserverParams:
    """Gains and filtering of the wrench observer (SPEC §4.3, paper values).

    Attributes:
        gain_force: L, per world axis [1/s] (paper 15; the authors' code used 12 along x).
        gain_moment: K_I, per body axis [1/s].
        cutoff_hz: output low-pass cut-off [Hz]; ``inf`` disables it.
        bias: (6,) constant subtracted from the filtered output ``[f_W [N]; m_B [N·m]]``.
        zero_at_start: capture and subtract the output at the initial hover (module docstring).
        zero_settle_s: time after reset before the capture window opens [s].
        zero_window_s: length of the averaging window of the capture [s].
    """

    gain_force: Vec3 = (15.0, 15.0, 15.0)
    gain_moment: Vec3 = (25.0, 25.0, 25.0)
    cutoff_hz: float = 10.0
    bias: tuple[float, float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    zero_at_start: bool = False
    zero_settle_s: float = 1.0
    zero_window_s: float = 0.5

    def __post_init__(self) -> None:
        for name in ("gain_force", "gain_moment"):
            value = getattr(self, name)
            if len(value) != 3:
                raise InputError(f"observer.{name} must have 3 values, got {len(value)}")
            for v in value:
                check_positive(f"observer.{name}", v)
            object.__setattr__(self, name, tuple(float(v) for v in value))
        if not (self.cutoff_hz > 0):  # inf is allowed (no filter)
            raise InputError(f"observer.cutoff_hz must be > 0 (inf disables the filter), got {self.cutoff_hz}")
        if len(self.bias) != 6:
            raise InputError(f"observer.bias must have 6 values, got {len(self.bias)}")
        check_finite("observer.bias", *self.bias)
        object.__setattr__(self, "bias", tuple(float(v) for v in self.bias))
        check_finite("observer.zero_settle_s", self.zero_settle_s)
        if self.zero_settle_s < 0:
            raise InputError(f"observer.zero_settle_s must be >= 0, got {self.zero_settle_s}")
        check_positive("observer.zero_window_s", self.zero_window_s)


@register("observer", "momentum")
class WrenchObserver:
    """The wrench observer of SPEC §4.3 (module docstring).

    Args:
        vehicle: mass, gravity and the (diagonal) inertia are used.
        params: gains, filter, bias and zeroing.
        state: optional ``(1,)`` array of :data:`STATE_DTYPE` to hold :attr:`state` (e.g. a field of the
            controller's state); a new one by default.

    Attributes:
        state: the ``(1,)`` state record the compiled step reads and writes (:data:`STATE_DTYPE`; the arrays
            below are views into it).
        f_ext_W: (3,) the interaction force [N], world frame, after filtering, bias and zeroing (a view).
        m_ext_B: (3,) the interaction moment [N·m], body frame, likewise (a view).
        f_filt_W: (3,) the low-passed force estimate ``f_hat_W``, before bias and zeroing (a view).
        m_filt_B: (3,) the low-passed moment estimate ``m_hat_B``, likewise (a view).
        offset: (6,) the offset captured by the zeroing (zeros until captured or when disabled).
        zeroed: True once the offset is captured (always False without ``zero_at_start``).
    """

    state_dtype = STATE_DTYPE
    log_fields = ("f_ext_W", "m_ext_B")
    kernel = observer_step

    def __init__(
        self, vehicle: VehicleParams, params: ObserverParams | None = None, *, state: np.ndarray | None = None
    ) -> None:
        self.params = params if params is not None else ObserverParams()
        self.vehicle = vehicle
        prm = self.params
        self.state = st = state_array(STATE_DTYPE, state, "observer")
        st["gain_force"] = prm.gain_force
        st["gain_moment"] = prm.gain_moment
        st["mass_kg"] = vehicle.mass
        st["gravity"] = vehicle.gravity
        st["J_diag"] = [float(j) for j in vehicle.inertia_diag]
        st["cutoff_hz"] = prm.cutoff_hz
        st["bias"] = prm.bias
        st["settle_s"] = prm.zero_settle_s
        st["window_s"] = prm.zero_window_s
        rec = st[0]
        self.f_ext_W = rec["f_ext_W"]
        self.m_ext_B = rec["m_ext_B"]
        self.f_filt_W = rec["f_filt_W"]
        self.m_filt_B = rec["m_filt_B"]
        self.offset = rec["offset"]
        self.reset()

    def reset(self) -> None:
        """Restart: zero estimates and filters; the momentum reference q0 is taken at the next step."""
        st = self.state
        kept = {name: st[name].copy() for name in _PARAMETERS}
        st[...] = np.zeros(1, dtype=STATE_DTYPE)
        for name, value in kept.items():
            st[name] = value
        st["lpf_dt_s"] = math.nan
        st["subtract"] = self.params.bias
        st["capturing"] = 1.0 if self.params.zero_at_start else 0.0

    @property
    def zeroed(self) -> bool:
        """True once the offset is captured (always False without ``zero_at_start``)."""
        return bool(self.state["zeroed"][0])

    @property
    def n_nonfinite(self) -> int:
        """Steps whose inputs were not finite (each changed nothing else)."""
        return int(self.state["n_nonfinite"][0])

    @property
    def output(self) -> np.ndarray:
        """(6,) ``[f_ext_W [N]; m_ext_B [N·m]]``, the interaction estimate (a new array)."""
        return np.r_[self.f_ext_W, self.m_ext_B]

    @property
    def filtered(self) -> np.ndarray:
        """(6,) ``[f_filt_W [N]; m_filt_B [N·m]]``, the low-passed estimates before bias and zeroing (a new array)."""
        return np.r_[self.f_filt_W, self.m_filt_B]

    @property
    def raw(self) -> np.ndarray:
        """(6,) the unfiltered estimates ``[f_hat_W [N]; m_hat_B [N·m]]`` (a new array)."""
        return np.r_[self.state["f_hat_W"][0], self.state["m_hat_B"][0]]

    def step(self, state: StateEstimate, u_hz2: np.ndarray, A: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """One observer step (:func:`observer_step`).

        Args:
            state: state estimate (``a_W``, ``R_WB``, ``omega_B`` are used).
            u_hz2: (n,) rotor inputs acting on the vehicle [Hz²].
            A: (6, n) the wrench map in use (body frame).
            dt: period [s].

        Returns:
            ``(f_ext_W, m_ext_B)``: views of the state (overwritten by the next step).
        """
        f64 = np.float64
        type(self).kernel(
            self.state[0],
            np.asarray(A, dtype=f64),
            np.asarray(u_hz2, dtype=f64),
            np.asarray(state.a_W, dtype=f64),
            np.asarray(state.R_WB, dtype=f64),
            np.asarray(state.omega_B, dtype=f64),
            float(dt),
        )
        return self.f_ext_W, self.m_ext_B
