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
from omnirotor.control import _kernels as _k
from omnirotor.control._kernels import lowpass_coefficient
from omnirotor.errors import InputError
from omnirotor.messages import StateEstimate
from omnirotor.vehicle import VehicleParams

__all__ = ["ObserverParams", "WrenchObserver", "lowpass_coefficient"]

Vec3 = tuple[float, float, float]


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
        buffer: optional (``OBS_SIZE``,) float64 array to hold :attr:`kernel_state` (e.g. a slice of a larger
            array); a new one by default.

    Attributes:
        output: (6,) ``[f_ext_W [N]; m_ext_B [N·m]]`` after filtering, bias and zeroing.
        f_ext_W: (3,) view of the force part of :attr:`output`.
        m_ext_B: (3,) view of the moment part of :attr:`output`.
        filtered: (6,) the low-passed estimates ``[f_hat_W; m_hat_B]``, before bias and zeroing.
        offset: (6,) the offset captured by the zeroing (zeros until captured or when disabled).
        zeroed: True once the offset is captured (always False without ``zero_at_start``).
        kernel_state: the packed state, parameters and outputs the compiled step reads and writes (layout
            ``OBS_*`` of :mod:`omnirotor.control._kernels`; the arrays above are views into it).
    """

    def __init__(
        self, vehicle: VehicleParams, params: ObserverParams | None = None, *, buffer: np.ndarray | None = None
    ) -> None:
        self.params = params if params is not None else ObserverParams()
        self.vehicle = vehicle
        prm = self.params
        # State, parameters and outputs in one array, the layout of control._kernels (OBS_*).
        self.kernel_state = x = _k.state_buffer(buffer, _k.OBS_SIZE, "observer")
        x[_k.OBS_GAIN_F : _k.OBS_GAIN_F + 3] = prm.gain_force
        x[_k.OBS_GAIN_M : _k.OBS_GAIN_M + 3] = prm.gain_moment
        x[_k.OBS_MASS] = vehicle.mass
        x[_k.OBS_GRAVITY] = vehicle.gravity
        x[_k.OBS_J : _k.OBS_J + 3] = [float(j) for j in vehicle.inertia_diag]
        x[_k.OBS_CUTOFF] = prm.cutoff_hz
        x[_k.OBS_BIAS : _k.OBS_BIAS + 6] = prm.bias
        x[_k.OBS_SETTLE] = prm.zero_settle_s
        x[_k.OBS_WINDOW] = prm.zero_window_s
        x[_k.OBS_LPF_DT] = math.nan
        self.output = x[_k.OBS_OUTPUT : _k.OBS_OUTPUT + 6]
        self.f_ext_W = self.output[0:3]
        self.m_ext_B = self.output[3:6]
        self.filtered = x[_k.OBS_FILTERED : _k.OBS_FILTERED + 6]
        self.offset = x[_k.OBS_OFFSET : _k.OBS_OFFSET + 6]
        self.reset()

    def reset(self) -> None:
        """Restart: zero estimates and filters; the momentum reference q0 is taken at the next step."""
        x = self.kernel_state
        x[0 : _k.OBS_GAIN_F] = 0.0  # outputs and state (parameters kept)
        x[_k.OBS_SUBTRACT : _k.OBS_SUBTRACT + 6] = self.params.bias
        x[_k.OBS_CAPTURING] = 1.0 if self.params.zero_at_start else 0.0

    @property
    def zeroed(self) -> bool:
        """True once the offset is captured (always False without ``zero_at_start``)."""
        return bool(self.kernel_state[_k.OBS_ZEROED])

    @property
    def raw(self) -> np.ndarray:
        """(6,) the unfiltered estimates ``[f_hat_W [N]; m_hat_B [N·m]]`` (a new array)."""
        return self.kernel_state[_k.OBS_F : _k.OBS_F + 6].copy()

    def step(self, state: StateEstimate, u_hz2: np.ndarray, A: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """One observer step (:func:`omnirotor.control._kernels.observer_step`).

        Args:
            state: state estimate (``a_W``, ``R_WB``, ``omega_B`` are used).
            u_hz2: (n,) rotor inputs acting on the vehicle [Hz²].
            A: (6, n) the wrench map in use (body frame).
            dt: period [s].

        Returns:
            ``(f_ext_W, m_ext_B)``: views of :attr:`output` (overwritten by the next step).
        """
        f64 = np.float64
        _k.observer_step(
            self.kernel_state,
            np.asarray(A, dtype=f64),
            np.asarray(u_hz2, dtype=f64),
            np.asarray(state.a_W, dtype=f64),
            np.asarray(state.R_WB, dtype=f64),
            np.asarray(state.omega_B, dtype=f64),
            float(dt),
        )
        return self.f_ext_W, self.m_ext_B
