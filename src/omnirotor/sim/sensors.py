"""Sensor models of the simulator: IMU, motion capture, rotor speeds and the bypass state (SPEC §4.5).

* IMU, every control period: accelerometer specific force ``R^T (p_ddot + g e3)`` plus the lever-arm terms
  ``omega_dot x r + omega x (omega x r)`` of an IMU at ``r`` from the CoM, and gyroscope ``omega_B``; both
  with a constant bias drawn per run and white noise.
* Motion capture: the body pose sampled at ``mocap_rate_hz`` (on the first step at or after each sample
  time), with position noise and a small random rotation, delivered ``mocap_latency_s`` later (rounded to
  the step). The vehicle is at rest before t = 0, so the first frame already carries a sample.
* Rotor speeds: the true speeds plus white noise.
* Bypass state: ground truth plus white noise (exact truth when the noise levels are zero).

Noise comes from generators the simulator seeds; each sensor draws its standard normals in blocks, so a
step costs a slice, not a call into the generator.
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor.sim import _kernels as _k
from omnirotor.sim.params import SensorParams

__all__ = ["NoiseStream", "Imu", "Mocap", "MocapSample", "quat_perturb", "R9_from_quat"]

_BLOCK = 1024
"""Rows of standard normals drawn at once per stream."""


class NoiseStream:
    """Scaled standard normal vectors of a fixed size, drawn from ``rng`` in blocks.

    Args:
        rng: the generator (owned by this stream from now on).
        scale: standard deviation of each component (scalar or (dim,)).
        dim: size of each vector.
        as_list: return Python lists of floats (for float arithmetic) instead of numpy rows.
    """

    def __init__(self, rng: np.random.Generator, scale: float | np.ndarray, dim: int, as_list: bool = False) -> None:
        self._rng = rng
        self._scale = np.broadcast_to(np.asarray(scale, dtype=float), (dim,)).copy()
        self._buf = np.empty((_BLOCK, dim))
        self._as_list = as_list
        self._rows: list | np.ndarray = self._buf
        self._i = _BLOCK

    def next(self) -> np.ndarray | list[float]:
        """(dim,) the next vector (a numpy view valid until the next block, or a list)."""
        if self._i >= _BLOCK:
            self._rng.standard_normal(out=self._buf)
            self._buf *= self._scale
            # Rows as a list (of lists, or of row views made once per block): indexing it is cheap.
            self._rows = self._buf.tolist() if self._as_list else list(self._buf)
            self._i = 0
        row = self._rows[self._i]
        self._i += 1
        return row


def quat_perturb(q_wxyz, dtheta, out):
    """``q ⊗ [1, dtheta/2]`` normalised: q rotated by the small body rotation ``dtheta`` [rad].

    Args:
        q_wxyz: (4,) unit quaternion (array or sequence).
        dtheta: (3,) small rotation vector in the body frame [rad].
        out: (4,) output: a numpy array or a list.

    Returns:
        ``out``.
    """
    w, x, y, z = q_wxyz
    a, b, c = dtheta
    a, b, c = 0.5 * a, 0.5 * b, 0.5 * c
    rw = w - x * a - y * b - z * c
    rx = x + w * a + y * c - z * b
    ry = y + w * b + z * a - x * c
    rz = z + w * c + x * b - y * a
    s = 1.0 / math.sqrt(rw * rw + rx * rx + ry * ry + rz * rz)
    out[0], out[1], out[2], out[3] = rw * s, rx * s, ry * s, rz * s
    return out


class Imu:
    """Accelerometer and gyroscope at ``imu_offset_B``, body axes.

    Args:
        params: sensor parameters.
        gravity: [m/s²].
    """

    def __init__(self, params: SensorParams, gravity: float) -> None:
        self.params = params
        self.gravity = gravity
        self.offset_B = np.asarray(params.imu_offset_B, dtype=float)
        self.acc_bias_B = np.zeros(3)
        self.gyro_bias_B = np.zeros(3)
        self.kernel_params = np.zeros(_k.IMU_PAR_SIZE)
        """Gravity, biases and offset packed for :func:`omnirotor.sim._kernels.imu_measure_into`."""
        self.noise: NoiseStream | None = None
        """The white-noise stream (6: accelerometer, gyroscope), set by :meth:`reset`."""
        self._pack()

    def _pack(self) -> None:
        r = [float(x) for x in self.params.imu_offset_B]
        has_offset = 1.0 if any(x != 0.0 for x in r) else 0.0
        self.kernel_params[:] = [self.gravity, *self.acc_bias_B, *self.gyro_bias_B, *r, has_offset]

    def reset(self, bias_rng: np.random.Generator, noise_rng: np.random.Generator) -> None:
        """Draw the constant biases and take over the white-noise generator."""
        p = self.params
        self.acc_bias_B[:] = p.acc_bias_std * bias_rng.standard_normal(3)
        self.gyro_bias_B[:] = p.gyro_bias_std * bias_rng.standard_normal(3)
        self._pack()
        scale = np.array([p.acc_noise_std] * 3 + [p.gyro_noise_std] * 3)
        self.noise = NoiseStream(noise_rng, scale, 6)

    def measure(
        self, R9: list[float], a_W: list[float], omega_B: list[float], omega_dot_B: list[float]
    ) -> tuple[np.ndarray, np.ndarray]:
        """One IMU sample (:func:`omnirotor.sim._kernels.imu_measure_into`).

        Args:
            R9: the 9 entries of ``R_WB``, row-major.
            a_W: 3 components of the CoM acceleration, world frame [m/s²] (without gravity).
            omega_B: 3 components of the angular velocity [rad/s].
            omega_dot_B: 3 components of the angular acceleration [rad/s²].

        Returns:
            ``(acc_B [m/s²], gyro_B [rad/s])``, fresh (3,) arrays.
        """
        out = np.empty(6)
        f64 = np.float64
        _k.imu_measure_into(
            np.asarray(R9, dtype=f64).reshape(9),
            np.asarray(a_W, dtype=f64),
            np.asarray(omega_B, dtype=f64),
            np.asarray(omega_dot_B, dtype=f64),
            self.kernel_params,
            self.noise.next(),
            out,
            0,
        )
        return out[0:3], out[3:6]


class MocapSample:
    """A delivered motion-capture sample (fresh arrays).

    Attributes:
        t: time the pose was taken [s].
        p_W: (3,) position [m].
        q_WB: (4,) attitude, wxyz.
    """

    __slots__ = ("t", "p_W", "q_WB")

    def __init__(self, t: float, p_W: np.ndarray, q_WB: np.ndarray) -> None:
        self.t = t
        self.p_W = p_W
        self.q_WB = q_WB


class Mocap:
    """Motion capture with a fixed rate and latency.

    Args:
        params: sensor parameters.
        dt: control period [s].
    """

    def __init__(self, params: SensorParams, dt: float) -> None:
        self.params = params
        self.dt = dt
        self.period = 1.0 / params.mocap_rate_hz
        self.latency_steps = int(round(params.mocap_latency_s / dt))
        cap = int(math.ceil((self.latency_steps + 1) * dt / self.period)) + 2
        self._t = np.zeros(cap)
        self._due = [0] * cap  # step of each queued sample's delivery (a list: read every step)
        self._p = np.zeros((cap, 3))
        self._q = np.zeros((cap, 4))
        self._head = 0
        self._count = 0
        self._next_t = 0.0
        self._noise: NoiseStream | None = None

    @property
    def latency_s(self) -> float:
        """The latency actually applied (a whole number of steps) [s]."""
        return self.latency_steps * self.dt

    def _push(self, t: float, due_step: int, p_W: np.ndarray, q_WB: np.ndarray) -> None:
        cap = self._t.shape[0]
        if self._count == cap:  # only when the rate exceeds the step rate: drop the oldest
            self._head = (self._head + 1) % cap
            self._count -= 1
        i = (self._head + self._count) % cap
        noise = self._noise.next()
        self._t[i] = t
        self._due[i] = due_step
        np.add(noise[:3], p_W, out=self._p[i])
        # On Python floats: arithmetic on NumPy scalars costs ten times more.
        q = quat_perturb(np.asarray(q_WB, dtype=float).tolist(), noise[3:].tolist(), [0.0] * 4)
        self._q[i] = q
        self._count += 1

    def reset(self, rng: np.random.Generator, p_W: np.ndarray, q_WB: np.ndarray) -> None:
        """Restart at step 0 with the vehicle at rest at ``(p_W, q_WB)`` before t = 0.

        The last sample taken at or before ``-latency`` is delivered at step 0; later ones (taken on the step
        grid at the sample rate) are queued, so every delivery is exactly one latency after its sample.
        """
        p = self.params
        scale = np.array([p.mocap_pos_noise_std] * 3 + [p.mocap_att_noise_std] * 3)
        self._noise = NoiseStream(rng, scale, 6)
        self._head = 0
        self._count = 0
        # Samples taken before t = 0 on the step grid, newest first, back to the last one already delivered.
        earlier: list[tuple[int, int]] = []
        j = 1
        while True:
            k = -int(round(j * self.period / self.dt))
            if not earlier or k < earlier[-1][0]:
                earlier.append((k, k + self.latency_steps))
                if k + self.latency_steps <= 0:
                    break
            j += 1
        for k, due in reversed(earlier):
            self._push(k * self.dt, max(due, 0), p_W, q_WB)
        self._next_t = 0.0

    def step(self, k: int, t: float, p_W: np.ndarray, q_WB: np.ndarray) -> MocapSample | None:
        """Take a sample if one is due at step ``k`` (time ``t``) and deliver the newest one that has arrived.

        Args:
            k: step index.
            t: its time [s].
            p_W: (3,) true position [m].
            q_WB: (4,) true attitude, wxyz.

        Returns:
            The delivered sample, or None.
        """
        if t >= self._next_t - 1e-9:
            self._push(t, k + self.latency_steps, p_W, q_WB)
            self._next_t += self.period
            while self._next_t <= t + 1e-9:  # a rate above the step rate: one sample per step
                self._next_t += self.period
        if self._count == 0 or self._due[self._head] > k:
            return None
        cap = self._t.shape[0]
        i = self._head
        while True:  # newest arrived sample wins
            self._head = (self._head + 1) % cap
            self._count -= 1
            if self._count == 0 or self._due[self._head] > k:
                break
            i = self._head
        return MocapSample(float(self._t[i]), self._p[i].copy(), self._q[i].copy())


def R9_from_quat(q) -> list[float]:
    """The 9 entries (row-major) of the rotation matrix of a unit quaternion (wxyz), float arithmetic."""
    w, x, y, z = q
    xx, yy, zz, xy, xz, yz, wx, wy, wz = x * x, y * y, z * z, x * y, x * z, y * z, w * x, w * y, w * z
    return [
        1.0 - 2.0 * (yy + zz),
        2.0 * (xy - wz),
        2.0 * (xz + wy),
        2.0 * (xy + wz),
        1.0 - 2.0 * (xx + zz),
        2.0 * (yz - wx),
        2.0 * (xz - wy),
        2.0 * (yz + wx),
        1.0 - 2.0 * (xx + yy),
    ]
