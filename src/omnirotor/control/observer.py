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

* :attr:`WrenchObserver.filtered`: the low-passed estimate of *everything* the model does not explain
  (interaction plus model error), which the pose controller subtracts (eqs. 4-5): a thrust-model error
  is then compensated whether or not it was zeroed;
* :attr:`WrenchObserver.output` = ``filtered - bias - offset``: the *interaction* wrench estimate, which
  drives the admittance filter (and is what :meth:`WrenchObserver.step` returns).

Without bias and zeroing the two are equal, as in the paper.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from omnirotor.config import check_finite, check_positive
from omnirotor.errors import InputError
from omnirotor.messages import StateEstimate
from omnirotor.vehicle import VehicleParams

__all__ = ["ObserverParams", "WrenchObserver", "lowpass_coefficient"]

Vec3 = tuple[float, float, float]


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


class WrenchObserver:
    """The wrench observer of SPEC §4.3 (module docstring).

    Args:
        vehicle: mass, gravity and the (diagonal) inertia are used.
        params: gains, filter, bias and zeroing.

    Attributes:
        output: (6,) ``[f_ext_W [N]; m_ext_B [N·m]]`` after filtering, bias and zeroing.
        f_ext_W: (3,) view of the force part of :attr:`output`.
        m_ext_B: (3,) view of the moment part of :attr:`output`.
        filtered: (6,) the low-passed estimates ``[f_hat_W; m_hat_B]``, before bias and zeroing.
        offset: (6,) the offset captured by the zeroing (zeros until captured or when disabled).
        zeroed: True once the offset is captured (always False without ``zero_at_start``).
    """

    def __init__(self, vehicle: VehicleParams, params: ObserverParams | None = None) -> None:
        self.params = params if params is not None else ObserverParams()
        self.vehicle = vehicle
        self._m = vehicle.mass
        self._g = vehicle.gravity
        self._J = tuple(float(j) for j in vehicle.inertia_diag)
        self.output = np.zeros(6)
        self.f_ext_W = self.output[0:3]
        self.m_ext_B = self.output[3:6]
        self.filtered = np.zeros(6)
        self.offset = np.zeros(6)
        self._w = np.zeros(6)  # A u, body frame
        self._lpf_cache = (math.nan, 1.0)
        self.reset()

    def reset(self) -> None:
        """Restart: zero estimates and filters; the momentum reference q0 is taken at the next step."""
        self._f = [0.0, 0.0, 0.0]
        self._mh = [0.0, 0.0, 0.0]
        self._s = [0.0, 0.0, 0.0]
        self._q0 = None
        self._y = [0.0] * 6
        self._elapsed = 0.0
        self._acc = [0.0] * 6
        self._n_acc = 0
        self._subtract = list(self.params.bias)
        self._capturing = self.params.zero_at_start
        self.zeroed = False
        self.output[:] = 0.0
        self.filtered[:] = 0.0
        self.offset[:] = 0.0

    @property
    def raw(self) -> np.ndarray:
        """(6,) the unfiltered estimates ``[f_hat_W [N]; m_hat_B [N·m]]`` (a new array)."""
        return np.array(self._f + self._mh)

    def _lambda(self, dt: float) -> float:
        cached_dt, lam = self._lpf_cache
        if dt != cached_dt:
            lam = lowpass_coefficient(self.params.cutoff_hz, dt)
            self._lpf_cache = (dt, lam)
        return lam

    def step(self, state: StateEstimate, u_hz2: np.ndarray, A: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """One observer step.

        Args:
            state: state estimate (``a_W``, ``R_WB``, ``omega_B`` are used).
            u_hz2: (n,) rotor inputs acting on the vehicle [Hz²].
            A: (6, n) the wrench map in use (body frame).
            dt: period [s].

        Returns:
            ``(f_ext_W, m_ext_B)``: views of :attr:`output` (overwritten by the next step).
        """
        prm = self.params
        m, g = self._m, self._g
        jx, jy, jz = self._J
        lx, ly, lz = prm.gain_force
        kx, ky, kz = prm.gain_moment
        np.dot(A, u_hz2, out=self._w)
        f1, f2, f3, t1, t2, t3 = self._w.tolist()
        ax, ay, az = state.a_W.tolist()
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = state.R_WB.tolist()
        wx, wy, wz = state.omega_B.tolist()

        # Force: first-order filter of m (a + g e3) - R A1 u.
        f = self._f
        f[0] += lx * dt * (m * ax - (r00 * f1 + r01 * f2 + r02 * f3) - f[0])
        f[1] += ly * dt * (m * ay - (r10 * f1 + r11 * f2 + r12 * f3) - f[1])
        f[2] += lz * dt * (m * (az + g) - (r20 * f1 + r21 * f2 + r22 * f3) - f[2])

        # Moment: generalized momentum q = J omega.
        hx, hy, hz = jx * wx, jy * wy, jz * wz
        s, mh = self._s, self._mh
        q0 = self._q0
        if q0 is None:  # first step after reset: t0, the momentum reference (m_hat stays 0)
            self._q0 = (hx, hy, hz)
        else:
            s[0] += (wy * hz - wz * hy - t1 - mh[0]) * dt
            s[1] += (wz * hx - wx * hz - t2 - mh[1]) * dt
            s[2] += (wx * hy - wy * hx - t3 - mh[2]) * dt
            mh[0] = kx * (hx - q0[0] + s[0])
            mh[1] = ky * (hy - q0[1] + s[1])
            mh[2] = kz * (hz - q0[2] + s[2])

        # Output low-pass, bias, zeroing.
        lam = self._lambda(dt)
        y = self._y
        raw = (f[0], f[1], f[2], mh[0], mh[1], mh[2])
        for i in range(6):
            y[i] += lam * (raw[i] - y[i])
        self.filtered[:] = y
        if self._capturing:
            self._capture(y, dt)
        else:
            c = self._subtract  # bias, plus the captured offset once zeroed
            self.output[:] = (y[0] - c[0], y[1] - c[1], y[2] - c[2], y[3] - c[3], y[4] - c[4], y[5] - c[5])
        return self.f_ext_W, self.m_ext_B

    def _capture(self, y: list[float], dt: float) -> None:
        """Zeroing phase: output zero, average the filtered estimate over the window, then latch it."""
        self._elapsed += dt
        prm = self.params
        if self._elapsed > prm.zero_settle_s:
            acc = self._acc
            for i in range(6):
                acc[i] += y[i]
            self._n_acc += 1
            if self._elapsed >= prm.zero_settle_s + prm.zero_window_s:
                self._subtract = [a / self._n_acc for a in acc]  # output = filtered - its mean at hover
                self.offset[:] = [a - b for a, b in zip(self._subtract, prm.bias, strict=True)]
                self.zeroed = True
                self._capturing = False
        self.output[:] = 0.0
