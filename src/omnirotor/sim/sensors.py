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

__all__ = ["NoiseStream", "Imu", "Mocap", "MocapSample", "quat_perturb", "R9_from_quat", "BLOCK"]

BLOCK = 1024
"""Rows of standard normals drawn at once per stream."""


class NoiseStream:
    """Scaled standard normal vectors of a fixed size, drawn from ``rng`` in blocks.

    The block and the read position are arrays (:attr:`buf`, :attr:`pos`) that compiled code reads directly:
    a compiled consumer takes row ``buf[pos[0]]`` and advances ``pos[0]``, and hands back to Python, which calls
    :meth:`refill`, when ``pos[0]`` reaches the block's end. Each stream has its own generator, so when a block
    is drawn does not change the numbers.

    Args:
        rng: the generator (owned by this stream from now on).
        scale: standard deviation of each component (scalar or (dim,)).
        dim: size of each vector.
    """

    def __init__(self, rng: np.random.Generator, scale: float | np.ndarray, dim: int) -> None:
        self._rng = rng
        self._scale = np.broadcast_to(np.asarray(scale, dtype=float), (dim,)).copy()
        self.buf = np.empty((BLOCK, dim))
        """(BLOCK, dim) the current block of scaled normals."""
        self.pos = np.full(1, BLOCK, dtype=np.int64)
        """(1,) index of the next unread row of :attr:`buf` (``BLOCK``: exhausted, refill first)."""

    @property
    def exhausted(self) -> bool:
        """True when the block is used up (the next read needs :meth:`refill`)."""
        return int(self.pos[0]) >= BLOCK

    def refill(self) -> None:
        """Draw the next block (the generator's next ``BLOCK x dim`` normals) and rewind."""
        self._rng.standard_normal(out=self.buf)
        self.buf *= self._scale
        self.pos[0] = 0

    def next(self) -> np.ndarray:
        """(dim,) the next vector (a view, valid until the next block)."""
        i = int(self.pos[0])
        if i >= BLOCK:
            self.refill()
            i = 0
        self.pos[0] = i + 1
        return self.buf[i]


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

    The queue of samples taken but not yet delivered lives in arrays (:attr:`kernel_state`) that the compiled
    :func:`omnirotor.sim._kernels.mocap_step` updates, from :meth:`step` or from the simulator's compiled step.

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
        self._ints = np.zeros(_k.MOCAP_INT_SIZE, dtype=np.int64)  # head, count, latency [steps]
        self._ints[_k.MOCAP_LATENCY] = self.latency_steps
        self._floats = np.zeros(_k.MOCAP_FLOAT_SIZE)  # next sample time, period [s]
        self._floats[_k.MOCAP_PERIOD] = self.period
        self._t = np.zeros(cap)  # time each queued sample was taken [s]
        self._due = np.zeros(cap, dtype=np.int64)  # step of each queued sample's delivery
        self._p = np.zeros((cap, 3))
        self._q = np.zeros((cap, 4))
        self._sample = np.zeros(_k.MOCAP_SAMPLE_SIZE)  # t, p (3), q (4) of the last delivery
        self.noise: NoiseStream | None = None
        """The measurement-noise stream (6: position, small rotation), set by :meth:`reset`."""

    @property
    def kernel_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The arrays of :func:`omnirotor.sim._kernels.mocap_step`: ints, floats, t, due, p, q."""
        return self._ints, self._floats, self._t, self._due, self._p, self._q

    @property
    def latency_s(self) -> float:
        """The latency actually applied (a whole number of steps) [s]."""
        return self.latency_steps * self.dt

    def _push(self, t: float, due_step: int, p_W: np.ndarray, q_WB: np.ndarray) -> None:
        if self.noise.exhausted:
            self.noise.refill()
        _k.mocap_push(
            *self.kernel_state, self.noise.buf, self.noise.pos, t, due_step, np.asarray(p_W, dtype=np.float64),
            np.asarray(q_WB, dtype=np.float64),
        )  # fmt: skip

    def reset(self, rng: np.random.Generator, p_W: np.ndarray, q_WB: np.ndarray) -> None:
        """Restart at step 0 with the vehicle at rest at ``(p_W, q_WB)`` before t = 0.

        The last sample taken at or before ``-latency`` is delivered at step 0; later ones (taken on the step
        grid at the sample rate) are queued, so every delivery is exactly one latency after its sample.
        """
        p = self.params
        scale = np.array([p.mocap_pos_noise_std] * 3 + [p.mocap_att_noise_std] * 3)
        self.noise = NoiseStream(rng, scale, 6)
        self._ints[_k.MOCAP_HEAD] = 0
        self._ints[_k.MOCAP_COUNT] = 0
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
        self._floats[_k.MOCAP_NEXT_T] = 0.0

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
        if self.noise.exhausted:
            self.noise.refill()
        f64 = np.float64
        got = _k.mocap_step(
            *self.kernel_state, self.noise.buf, self.noise.pos, k, t, np.asarray(p_W, dtype=f64),
            np.asarray(q_WB, dtype=f64), self._sample, 0,
        )  # fmt: skip
        if not got:
            return None
        s = self._sample
        return MocapSample(float(s[0]), s[1:4].copy(), s[4:8].copy())


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
