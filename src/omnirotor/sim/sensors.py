"""Sensor models of the simulator: IMU, motion capture, rotor speeds and the bypass state (SPEC §4.5).

* IMU, every control period: accelerometer specific force ``R^T (p_ddot + g e3)`` plus the lever-arm terms
  ``omega_dot x r + omega x (omega x r)`` of an IMU at ``r`` from the CoM, and gyroscope ``omega_B``; both
  with a constant bias drawn per run and white noise (the accelerometer's: its own and the airframe's vibration
  aliased over the band, ``acc_vib_noise_std``), plus the rotors' vibration: each rotor adds a
  once-per-revolution sinusoid (its phase advancing with its own speed) of amplitude
  ``imu_vib_*_amp (omega / imu_vib_ref_hz)²`` along a direction drawn per rotor and run.
* Motion capture: the body pose sampled at ``mocap_rate_hz`` (on the first step at or after each sample
  time), with position noise and a small random rotation, delivered ``mocap_latency_s`` later (rounded to
  the step) plus a jitter uniform in ``[0, mocap_latency_jitter_s]`` per sample (samples stay in order: a late
  one holds back the next). Each sample also carries a slow error (``mocap_drift_*``): per world position axis
  and per axis of a small body rotation, a first-order Gauss-Markov process advanced at every sample, the
  rigid-body fit wandering as markers drop in and out of view (docs/fidelity.md). The vehicle is at rest before
  t = 0, so the first frame already carries a sample.
* Rotor speeds: the true speeds plus white noise.
* Bypass state: ground truth plus white noise (exact truth when the noise levels are zero).

Noise comes from generators the simulator seeds; each sensor draws its standard normals in blocks, so a
step costs a slice, not a call into the generator.

The block (:class:`Sensors`, registered as ``("sensors", "imu-mocap")``) owns one record
(:data:`STATE_DTYPE`: the IMU's parameters and drawn biases, the motion capture's queue, the four noise
blocks) and the compiled step (:func:`sense`) that writes the frame record (:mod:`omnirotor.messages`) from
the vehicle's true state; :class:`Imu`, :class:`Mocap` and :class:`NoiseStream` are its parts' Python set-up
(views of that record).
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor._jit import jit, jit_entry
from omnirotor.blocks import register
from omnirotor.errors import InputError
from omnirotor.frame_kernels import clear_mocap, clear_state
from omnirotor.sim import prng
from omnirotor.sim.params import SensorParams
from omnirotor.sim.rotors import MAX_ROTORS
from omnirotor.so3 import R9_from_quat_into, quat_perturb_into

__all__ = [
    "NoiseStream",
    "Imu",
    "Mocap",
    "MocapSample",
    "Sensors",
    "sense",
    "needs_refill",
    "BLOCK",
    "STATE_DTYPE",
    "STATE_NONE",
    "STATE_EXACT",
    "STATE_NOISY",
]

BLOCK = 1024
"""Rows of standard normals drawn at once per stream."""
MOCAP_QUEUE_MAX = 64
"""Motion-capture samples the queue has room for (samples taken, not yet delivered)."""
MOCAP_CLOCK_TOL_S = 1e-9
"""Tolerance [s] of the sample clock against the step grid (times are multiples of dt up to rounding)."""
STATE_NONE, STATE_EXACT, STATE_NOISY = 0, 1, 2
"""What :func:`sense` writes into the frame's bypass state: nothing, the truth, or the truth plus noise."""
_STATE_DIM = 15  # bypass-state noise: p, v, a, small body rotation, omega


def _noise_dtype(dim: int) -> np.dtype:
    return np.dtype([("buf", np.float64, (BLOCK, dim)), ("pos", np.int64)])


IMU_DTYPE = np.dtype(
    [
        ("gravity", np.float64),
        ("acc_bias_B", np.float64, (3,)),
        ("gyro_bias_B", np.float64, (3,)),
        ("offset_B", np.float64, (3,)),
        ("has_offset", np.bool_),
        ("dt", np.float64),  # the sampling period [s]
        ("vib_acc_amp", np.float64),  # one rotor's accelerometer vibration amplitude at vib_ref_hz [m/s²]
        ("vib_gyro_amp", np.float64),  # the same at the gyroscope [rad/s]
        ("vib_ref_hz", np.float64),
        ("vib_dir_acc_B", np.float64, (MAX_ROTORS, 3)),  # unit direction of each rotor's vibration, drawn per run
        ("vib_dir_gyro_B", np.float64, (MAX_ROTORS, 3)),
        ("vib_phase", np.float64, (MAX_ROTORS,)),  # each rotor's angle [rad]
    ]
)
"""The IMU's parameters, the biases and vibration directions drawn for the run, the rotors' phases."""

MOCAP_DTYPE = np.dtype(
    [
        ("head", np.int64),  # queue: index of the oldest sample
        ("count", np.int64),  # queue length
        ("cap", np.int64),  # queue capacity used (<= MOCAP_QUEUE_MAX)
        ("latency_steps", np.int64),
        ("next_t", np.float64),  # time of the next sample [s]
        ("period", np.float64),  # sample period [s]
        ("t", np.float64, (MOCAP_QUEUE_MAX,)),  # time each queued sample was taken [s]
        ("due", np.int64, (MOCAP_QUEUE_MAX,)),  # step of each queued sample's delivery
        ("p_W", np.float64, (MOCAP_QUEUE_MAX, 3)),
        ("q_WB", np.float64, (MOCAP_QUEUE_MAX, 4)),
        ("sample", np.float64, (8,)),  # the last delivery: t, p_W (3), q_WB (4)
        ("jitter_steps", np.int64),  # largest extra latency [steps]
        ("rng", np.uint64),  # the jitter's generator (omnirotor.sim.prng)
        ("drift", np.float64, (6,)),  # slow error of the samples: position (world) [m], small rotation [rad]
        ("drift_decay", np.float64),  # its Gauss-Markov coefficients per sample period
        ("drift_drive_p", np.float64),
        ("drift_drive_a", np.float64),
        ("drift_gen", [("rng", np.uint64)]),  # the drift's generator (its own stream)
    ]
)
"""The motion capture's queue of samples taken but not yet delivered."""

STATE_DTYPE = np.dtype(
    [
        ("n_rotors", np.int64),
        ("state_mode", np.int64),  # STATE_NONE, STATE_EXACT or STATE_NOISY
        ("imu", IMU_DTYPE),
        ("mocap", MOCAP_DTYPE),
        ("noise_imu", _noise_dtype(6)),
        ("noise_rotor", _noise_dtype(MAX_ROTORS)),
        ("noise_state", _noise_dtype(_STATE_DIM)),
        ("noise_mocap", _noise_dtype(6)),
    ]
)
"""Everything the sensors' compiled step reads and updates."""


class NoiseStream:
    """Scaled standard normal vectors of a fixed size, drawn from ``rng`` in blocks.

    The block and the read position are views of a noise field of the sensors' record (:attr:`buf`,
    :attr:`pos`) that compiled code reads directly: a compiled consumer takes row ``buf[pos[0]]`` and advances
    ``pos[0]``, and hands back to Python, which calls :meth:`refill`, when ``pos[0]`` reaches the block's
    end. Each stream has its own generator, so when a block is drawn does not change the numbers.

    Args:
        rng: the generator (owned by this stream from now on).
        scale: standard deviation of each component (scalar or (dim,)).
        dim: size of each vector.
        rec: (1,) record of a ``noise_*`` field to draw into (default: a record of its own).
    """

    def __init__(
        self, rng: np.random.Generator, scale: float | np.ndarray, dim: int, rec: np.ndarray | None = None
    ) -> None:
        self._rng = rng
        self._scale = np.broadcast_to(np.asarray(scale, dtype=float), (dim,)).copy()
        if rec is None:
            rec = np.zeros(1, _noise_dtype(dim))
        self._draw = np.empty((BLOCK, dim))
        self.buf = rec["buf"][0][:, :dim]
        """(BLOCK, dim) the current block of scaled normals."""
        self.pos = rec["pos"]
        """(1,) index of the next unread row of :attr:`buf` (``BLOCK``: exhausted, refill first)."""
        self.pos[0] = BLOCK

    @property
    def exhausted(self) -> bool:
        """True when the block is used up (the next read needs :meth:`refill`)."""
        return int(self.pos[0]) >= BLOCK

    def refill(self) -> None:
        """Draw the next block (the generator's next ``BLOCK x dim`` normals) and rewind."""
        self._rng.standard_normal(out=self._draw)
        np.multiply(self._draw, self._scale, out=self.buf)
        self.pos[0] = 0

    def next(self) -> np.ndarray:
        """(dim,) the next vector (a view, valid until the next block)."""
        i = int(self.pos[0])
        if i >= BLOCK:
            self.refill()
            i = 0
        self.pos[0] = i + 1
        return self.buf[i]


# -- compiled parts ---------------------------------------------------------------------------------------------


@jit
def imu_measure_into(imu, R9, a_W, omega_B, omega_dot_B, noise, acc_B, gyro_B) -> None:
    """One IMU sample: ``acc_B (3) [m/s²]`` and ``gyro_B (3) [rad/s]`` written into the two outputs.

    ``acc_B = R^T (a_W + g e3) + b_a + n_a`` plus ``omega_dot x r + omega x (omega x r)`` when the IMU sits at
    ``r != 0``; ``gyro_B = omega_B + b_g + n_g``.

    Args:
        imu: an :data:`IMU_DTYPE` record.
        R9: (9,) ``R_WB`` row-major.
        a_W: (3,) CoM acceleration without gravity [m/s²].
        omega_B: (3,) angular velocity [rad/s].
        omega_dot_B: (3,) angular acceleration [rad/s²].
        noise: (6,) white noise ``n_a, n_g``.
        acc_B: (3,) output.
        gyro_B: (3,) output.
    """
    ba, bg = imu["acc_bias_B"], imu["gyro_bias_B"]
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = R9[0], R9[1], R9[2], R9[3], R9[4], R9[5], R9[6], R9[7], R9[8]
    sx, sy, sz = a_W[0], a_W[1], a_W[2] + imu["gravity"]
    ax = r00 * sx + r10 * sy + r20 * sz + ba[0] + noise[0]
    ay = r01 * sx + r11 * sy + r21 * sz + ba[1] + noise[1]
    az = r02 * sx + r12 * sy + r22 * sz + ba[2] + noise[2]
    wx, wy, wz = omega_B[0], omega_B[1], omega_B[2]
    if imu["has_offset"]:
        r = imu["offset_B"]
        rx, ry, rz = r[0], r[1], r[2]
        dx, dy, dz = omega_dot_B[0], omega_dot_B[1], omega_dot_B[2]
        cx, cy, cz = wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx
        ax += dy * rz - dz * ry + wy * cz - wz * cy
        ay += dz * rx - dx * rz + wz * cx - wx * cz
        az += dx * ry - dy * rx + wx * cy - wy * cx
    acc_B[0] = ax
    acc_B[1] = ay
    acc_B[2] = az
    gyro_B[0] = wx + bg[0] + noise[3]
    gyro_B[1] = wy + bg[1] + noise[4]
    gyro_B[2] = wz + bg[2] + noise[5]


@jit
def imu_vibration_add(imu, omega_hz, n: int, acc_B, gyro_B) -> None:
    """Advance the rotors' phases one period and add their vibration to ``acc_B`` and ``gyro_B`` (3,) in place.

    Rotor ``i`` turning at ``omega_i`` [Hz] adds ``amp (omega_i / ref)² sin(phi_i)`` along its direction, for the
    accelerometer and the gyroscope; ``phi_i`` advances by ``2 pi omega_i dt`` (the sign of the speed is the
    sense of rotation).
    """
    a_amp, g_amp = imu["vib_acc_amp"], imu["vib_gyro_amp"]
    if a_amp == 0.0 and g_amp == 0.0:
        return
    inv_ref2 = 1.0 / (imu["vib_ref_hz"] * imu["vib_ref_hz"])
    step = 2.0 * math.pi * imu["dt"]
    phase, da, dg = imu["vib_phase"], imu["vib_dir_acc_B"], imu["vib_dir_gyro_B"]
    for i in range(n):
        w = omega_hz[i]
        if not math.isfinite(w):
            continue
        ph = phase[i] + step * w
        ph -= 2.0 * math.pi * math.floor(ph / (2.0 * math.pi))
        phase[i] = ph
        s = math.sin(ph) * w * w * inv_ref2
        sa, sg = a_amp * s, g_amp * s
        for j in range(3):
            acc_B[j] += sa * da[i, j]
            gyro_B[j] += sg * dg[i, j]


@jit_entry
def mocap_push(moc, noise, t: float, due: int, p, q) -> None:
    """Queue a sample taken at ``t`` of the pose ``(p, q)``, with its noise, for delivery at step ``due``.

    Takes the next row of the noise record ``noise`` (the caller makes sure one is left). A full queue (only
    with a sample rate above the step rate) drops its oldest sample.
    """
    cap = moc["cap"]
    if moc["count"] == cap:
        moc["head"] = (moc["head"] + 1) % cap
        moc["count"] -= 1
    i = (moc["head"] + moc["count"]) % cap
    r = noise["pos"]
    noise["pos"] = r + 1
    e = noise["buf"][r]
    moc["t"][i] = t
    moc["due"][i] = due
    mp = moc["p_W"][i]
    d = moc["drift"]
    for j in range(3):
        mp[j] = e[j] + d[j] + p[j]
        e[3 + j] += d[3 + j]  # the row is read once: its rotation becomes the sample's whole error
    quat_perturb_into(q, e[3:6], moc["q_WB"][i])
    moc["count"] += 1


@jit
def mocap_drift_step(moc) -> None:
    """Advance the samples' slow error one sample period (first-order Gauss-Markov per component)."""
    dp, da = moc["drift_drive_p"], moc["drift_drive_a"]
    if dp == 0.0 and da == 0.0:
        return
    decay, d, gen = moc["drift_decay"], moc["drift"], moc["drift_gen"]
    for j in range(6):
        d[j] = prng.gauss_markov_next(d[j], decay, dp if j < 3 else da, gen)


@jit
def mocap_step(moc, noise, k: int, t: float, p, q) -> bool:
    """One step of the motion capture: sample ``(p, q)`` if due at step ``k`` (time ``t`` [s]), deliver.

    The newest queued sample that has arrived, if any, goes to ``moc.sample`` (t, p, q).

    Returns:
        True when a sample was delivered.
    """
    if t >= moc["next_t"] - MOCAP_CLOCK_TOL_S:
        due = k + moc["latency_steps"]
        if moc["jitter_steps"] > 0:
            due += int(prng.next_uniform(moc) * (moc["jitter_steps"] + 1))
        mocap_drift_step(moc)
        mocap_push(moc, noise, t, due, p, q)
        moc["next_t"] += moc["period"]
        while moc["next_t"] <= t + MOCAP_CLOCK_TOL_S:  # a rate above the step rate: one sample per step
            moc["next_t"] += moc["period"]
    if moc["count"] == 0 or moc["due"][moc["head"]] > k:
        return False
    cap = moc["cap"]
    i = moc["head"]
    while True:  # the newest arrived sample wins
        moc["head"] = (moc["head"] + 1) % cap
        moc["count"] -= 1
        if moc["count"] == 0 or moc["due"][moc["head"]] > k:
            break
        i = moc["head"]
    out = moc["sample"]
    out[0] = moc["t"][i]
    for j in range(3):
        out[1 + j] = moc["p_W"][i, j]
    for j in range(4):
        out[4 + j] = moc["q_WB"][i, j]
    return True


@jit
def needs_refill(sens) -> bool:
    """True when a noise block the next :func:`sense` may read is used up (Python refills it)."""
    return (
        sens["noise_imu"]["pos"] >= BLOCK
        or sens["noise_rotor"]["pos"] >= BLOCK
        or sens["noise_mocap"]["pos"] >= BLOCK
        or (sens["state_mode"] == STATE_NOISY and sens["noise_state"]["pos"] >= BLOCK)
    )


@jit
def sense(sens, pose, vel, acc, R9, omega_hz, k: int, t: float, frame) -> None:
    """The sensors at step ``k`` (time ``t``): the whole frame record (:mod:`omnirotor.messages`).

    IMU, measured rotor speeds, the bypass state (none, the truth, or the truth plus noise, the attitude
    perturbed as :func:`quat_perturb_into`) and the motion capture's delivery. Reads one row of each noise
    block it uses (the caller checks :func:`needs_refill` first).

    Args:
        sens: the :data:`STATE_DTYPE` record, updated.
        pose: (7,) the vehicle's ``p_W, q_WB`` (MuJoCo's free joint in ``qpos``).
        vel: (6,) ``v_W, omega_B`` (``qvel``).
        acc: (6,) ``p_ddot_W, omega_dot_B`` (``qacc``).
        R9: (9,) ``R_WB`` row-major (MuJoCo's ``xmat`` row of the body).
        omega_hz: (n,) true rotor speeds [Hz].
        k: step index.
        t: its time [s].
        frame: the frame record (:func:`omnirotor.messages.frame_dtype`), written whole.
    """
    frame.t = t
    ni, nr = sens["noise_imu"], sens["noise_rotor"]
    i_imu = ni["pos"]
    ni["pos"] = i_imu + 1
    i_rot = nr["pos"]
    nr["pos"] = i_rot + 1
    mode = sens["state_mode"]
    imu = frame.imu
    imu_measure_into(sens["imu"], R9, acc[0:3], vel[3:6], acc[3:6], ni["buf"][i_imu], imu.acc_B, imu.gyro_B)
    imu_vibration_add(sens["imu"], omega_hz, sens["n_rotors"], imu.acc_B, imu.gyro_B)
    rot_noise = nr["buf"][i_rot]
    for i in range(sens["n_rotors"]):
        frame.rotor_hz[i] = omega_hz[i] + rot_noise[i]
    st = frame.state
    R = st.R_WB
    if mode == STATE_NONE:
        clear_state(st)
    else:
        st.valid = 1.0
        if mode == STATE_EXACT:
            for i in range(3):
                st.p_W[i] = pose[i]
                st.v_W[i] = vel[i]
                st.a_W[i] = acc[i]
                st.omega_B[i] = vel[3 + i]
            for i in range(3):
                for j in range(3):
                    R[i, j] = R9[3 * i + j]
        else:
            ns = sens["noise_state"]
            i_st = ns["pos"]
            ns["pos"] = i_st + 1
            e = ns["buf"][i_st]
            for i in range(3):
                st.p_W[i] = pose[i] + e[i]
                st.v_W[i] = vel[i] + e[3 + i]
                st.a_W[i] = acc[i] + e[6 + i]
                st.omega_B[i] = vel[3 + i] + e[12 + i]
            # The perturbed quaternion goes through R's first entries (overwritten by its matrix right after).
            r9 = R.flat  # its row-major entries (a reshape would compile numba's error text)
            quat_perturb_into(pose[3:7], e[9:12], r9)
            R9_from_quat_into(r9[0], r9[1], r9[2], r9[3], r9, 0)
    moc = sens["mocap"]
    m = frame.mocap
    if mocap_step(moc, sens["noise_mocap"], k, t, pose[0:3], pose[3:7]):
        m.new = 1.0
        s = moc["sample"]
        m.t = s[0]
        for j in range(3):
            m.p_W[j] = s[1 + j]
        for j in range(4):
            m.q_WB[j] = s[4 + j]
    else:
        clear_mocap(m)


# -- Python set-up ---------------------------------------------------------------------------------------------


class Imu:
    """Accelerometer and gyroscope at ``imu_offset_B``, body axes.

    Args:
        params: sensor parameters.
        gravity: [m/s²].
        rec: (1,) :data:`IMU_DTYPE` record to live in (default: its own).
        noise_rec: (1,) record of its noise block (default: its own).
        dt: sampling period [s] (advances the rotors' vibration phases).
    """

    def __init__(
        self,
        params: SensorParams,
        gravity: float,
        rec: np.ndarray | None = None,
        noise_rec: np.ndarray | None = None,
        dt: float = 1e-3,
    ) -> None:
        self.params = params
        self.gravity = gravity
        self.rec = np.zeros(1, IMU_DTYPE) if rec is None else rec
        """(1,) the :data:`IMU_DTYPE` record (gravity, biases, offset)."""
        self._noise_rec = noise_rec
        r = self.rec[0]
        r["gravity"] = gravity
        r["offset_B"] = params.imu_offset_B
        r["has_offset"] = any(float(x) != 0.0 for x in params.imu_offset_B)
        r["dt"] = dt
        self.offset_B = np.asarray(params.imu_offset_B, dtype=float)
        self.acc_bias_B = self.rec["acc_bias_B"][0]
        """(3,) the accelerometer bias drawn for the run [m/s²] (a view of the record)."""
        self.gyro_bias_B = self.rec["gyro_bias_B"][0]
        """(3,) the gyroscope bias drawn for the run [rad/s] (a view of the record)."""
        self.noise: NoiseStream | None = None
        """The white-noise stream (6: accelerometer, gyroscope), set by :meth:`reset`."""

    def reset(
        self,
        bias_rng: np.random.Generator,
        noise_rng: np.random.Generator,
        vib_rng: np.random.Generator | None = None,
    ) -> None:
        """Draw the constant biases and the vibration's directions and phases; take over the noise generator."""
        p = self.params
        self.acc_bias_B[:] = p.acc_bias_std * bias_rng.standard_normal(3)
        self.gyro_bias_B[:] = p.gyro_bias_std * bias_rng.standard_normal(3)
        r = self.rec[0]
        r["vib_acc_amp"], r["vib_gyro_amp"], r["vib_ref_hz"] = p.imu_vib_acc_amp, p.imu_vib_gyro_amp, p.imu_vib_ref_hz
        if vib_rng is not None:
            for name in ("vib_dir_acc_B", "vib_dir_gyro_B"):
                d = vib_rng.standard_normal((MAX_ROTORS, 3))
                r[name] = d / np.linalg.norm(d, axis=1, keepdims=True)
            r["vib_phase"] = vib_rng.uniform(0.0, 2.0 * math.pi, MAX_ROTORS)
        acc_std = math.hypot(p.acc_noise_std, p.acc_vib_noise_std)  # sensor noise and aliased vibration
        scale = np.array([acc_std] * 3 + [p.gyro_noise_std] * 3)
        self.noise = NoiseStream(noise_rng, scale, 6, self._noise_rec)

    def measure(
        self, R9: list[float], a_W: list[float], omega_B: list[float], omega_dot_B: list[float]
    ) -> tuple[np.ndarray, np.ndarray]:
        """One IMU sample (:func:`imu_measure_into`).

        Args:
            R9: the 9 entries of ``R_WB``, row-major.
            a_W: 3 components of the CoM acceleration, world frame [m/s²] (without gravity).
            omega_B: 3 components of the angular velocity [rad/s].
            omega_dot_B: 3 components of the angular acceleration [rad/s²].

        Returns:
            ``(acc_B [m/s²], gyro_B [rad/s])``, fresh (3,) arrays.
        """
        acc, gyro = np.empty(3), np.empty(3)
        f64 = np.float64
        imu_measure_into(
            self.rec[0],
            np.asarray(R9, dtype=f64).reshape(9),
            np.asarray(a_W, dtype=f64),
            np.asarray(omega_B, dtype=f64),
            np.asarray(omega_dot_B, dtype=f64),
            self.noise.next(),
            acc,
            gyro,
        )
        return acc, gyro


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

    The queue of samples taken but not yet delivered lives in a :data:`MOCAP_DTYPE` record (:attr:`rec`) that
    the compiled :func:`mocap_step` updates, from :meth:`step` or from the simulator's compiled step.

    Args:
        params: sensor parameters.
        dt: control period [s].
        rec: (1,) record to live in (default: its own).
        noise_rec: (1,) record of its noise block (default: its own).

    Raises:
        InputError: a rate and latency that need more than :data:`MOCAP_QUEUE_MAX` queued samples.
    """

    def __init__(
        self, params: SensorParams, dt: float, rec: np.ndarray | None = None, noise_rec: np.ndarray | None = None
    ) -> None:
        self.params = params
        self.dt = dt
        self.period = 1.0 / params.mocap_rate_hz
        self.latency_steps = int(round(params.mocap_latency_s / dt))
        self.jitter_steps = int(round(params.mocap_latency_jitter_s / dt))
        cap = int(math.ceil((self.latency_steps + self.jitter_steps + 1) * dt / self.period)) + 2
        if cap > MOCAP_QUEUE_MAX:
            raise InputError(
                f"sensors: motion capture at {params.mocap_rate_hz:g} Hz with {params.mocap_latency_s:g} s latency "
                f"queues {cap} samples; the simulator has room for {MOCAP_QUEUE_MAX}"
            )
        self.rec = np.zeros(1, MOCAP_DTYPE) if rec is None else rec
        """(1,) the :data:`MOCAP_DTYPE` record."""
        self._noise_rec = noise_rec
        r = self.rec[0]
        r["cap"], r["latency_steps"], r["period"] = cap, self.latency_steps, self.period
        r["jitter_steps"] = self.jitter_steps
        decay, drive_p = prng.gauss_markov_coefficients(
            params.mocap_drift_pos_std, params.mocap_drift_corner_hz, self.period
        )
        r["drift_decay"], r["drift_drive_p"] = decay, drive_p
        r["drift_drive_a"] = prng.gauss_markov_coefficients(
            params.mocap_drift_att_std, params.mocap_drift_corner_hz, self.period
        )[1]
        self.noise: NoiseStream | None = None
        """The measurement-noise stream (6: position, small rotation), set by :meth:`reset`."""

    @property
    def latency_s(self) -> float:
        """The latency actually applied (a whole number of steps) [s]."""
        return self.latency_steps * self.dt

    def _push(self, t: float, due_step: int, p_W: np.ndarray, q_WB: np.ndarray) -> None:
        if self.noise.exhausted:
            self.noise.refill()
        mocap_push(
            self.rec[0], self._noise_rec[0], t, due_step, np.asarray(p_W, dtype=np.float64),
            np.asarray(q_WB, dtype=np.float64),
        )  # fmt: skip

    def reset(self, rng: np.random.Generator, p_W: np.ndarray, q_WB: np.ndarray, seed: int = 0) -> None:
        """Restart at step 0 with the vehicle at rest at ``(p_W, q_WB)`` before t = 0.

        The last sample taken at or before ``-latency`` is delivered at step 0; later ones (taken on the step
        grid at the sample rate) are queued, so every delivery before t = 0 is exactly one latency after its
        sample; samples from t = 0 on add their jitter, drawn from the generator seeded with ``seed``.
        """
        p = self.params
        self.rec["rng"] = prng.seed_state(seed, _MOCAP_RNG_STREAM)
        self.rec["drift_gen"]["rng"] = prng.seed_state(seed, _MOCAP_DRIFT_RNG_STREAM)
        self.rec["drift"] = 0.0  # starts at zero: its first second is its transient, as the airflow's
        scale = np.array([p.mocap_pos_noise_std] * 3 + [p.mocap_att_noise_std] * 3)
        if self._noise_rec is None:
            self._noise_rec = np.zeros(1, _noise_dtype(6))
        self.noise = NoiseStream(rng, scale, 6, self._noise_rec)
        r = self.rec[0]
        r["head"], r["count"] = 0, 0
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
        r["next_t"] = 0.0

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
        got = mocap_step(self.rec[0], self._noise_rec[0], k, t, np.asarray(p_W, dtype=f64), np.asarray(q_WB, dtype=f64))
        if not got:
            return None
        s = self.rec["sample"][0]
        return MocapSample(float(s[0]), s[1:4].copy(), s[4:8].copy())


_N_STREAMS = 6
"""Independent noise streams spawned from the seed: IMU biases, IMU noise, mocap, rotor speeds, state, IMU vibration."""
_MOCAP_RNG_STREAM = 102
"""Index of the motion capture's jitter generator among the simulator's streams (:func:`prng.seed_state`)."""
_MOCAP_DRIFT_RNG_STREAM = 104
"""Index of the motion capture's drift generator."""
_CONSTANTS = (
    ("n_rotors", None),
    ("state_mode", None),
    ("imu", "gravity"),
    ("imu", "offset_B"),
    ("imu", "has_offset"),
    ("imu", "dt"),
    ("mocap", "cap"),
    ("mocap", "latency_steps"),
    ("mocap", "period"),
    ("mocap", "jitter_steps"),
    ("mocap", "drift_decay"),
    ("mocap", "drift_drive_p"),
    ("mocap", "drift_drive_a"),
)
"""The fields of the record that are parameters (kept by a reset)."""


@register("sensors", "imu-mocap")
class Sensors:
    """IMU, motion capture, measured rotor speeds and the bypass state, in one record (module docstring).

    Args:
        params: sensor parameters.
        gravity: [m/s²].
        dt: control period [s].
        n_rotors: rotors whose speeds are measured (at most :data:`~omnirotor.sim.rotors.MAX_ROTORS`).
        state_mode: :data:`STATE_NONE`, :data:`STATE_EXACT` or :data:`STATE_NOISY`.
        seed: seed of every noise source (same seed, same run).
        state: (1,) :data:`STATE_DTYPE` record to live in, e.g. a field of the simulator's (default: its own).
    """

    state_dtype = STATE_DTYPE
    log_fields = ("imu",)

    def __init__(
        self,
        params: SensorParams,
        gravity: float,
        dt: float,
        n_rotors: int,
        state_mode: int,
        seed: int = 0,
        state: np.ndarray | None = None,
    ) -> None:
        self.params = params
        self.n_rotors = n_rotors
        self.seed = int(seed)
        self.state = np.zeros(1, STATE_DTYPE) if state is None else state
        """(1,) the :data:`STATE_DTYPE` record."""
        s = self.state
        s["n_rotors"], s["state_mode"] = n_rotors, state_mode
        self.state_mode = state_mode
        self.imu = Imu(params, gravity, s["imu"], s["noise_imu"], dt)
        self.mocap = Mocap(params, dt, s["mocap"], s["noise_mocap"])
        self.rotor_noise: NoiseStream | None = None
        self.state_noise: NoiseStream | None = None
        self._pose0 = (np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))

    def reset(self, p_W: np.ndarray | None = None, q_WB: np.ndarray | None = None) -> None:
        """Restart every noise stream from the seed, draw the biases, restart the motion capture at rest.

        Args:
            p_W: (3,) position the vehicle rests at before t = 0 [m] (default: that of the last reset).
            q_WB: (4,) its attitude, wxyz.
        """
        if p_W is not None:
            self._pose0 = (np.array(p_W, dtype=float), np.array(q_WB, dtype=float))
        streams = [np.random.default_rng(s) for s in np.random.SeedSequence(self.seed).spawn(_N_STREAMS)]
        p = self.params
        s = self.state
        kept = [(s[a][b] if b else s[a]).copy() for a, b in _CONSTANTS]
        s[...] = 0  # nothing of the last run is left, not even unread noise or delivered samples
        for (a, b), v in zip(_CONSTANTS, kept, strict=True):
            if b:
                s[a][b] = v
            else:
                s[a] = v
        self.imu.reset(streams[0], streams[1], streams[5])
        self.mocap.reset(streams[2], *self._pose0, seed=self.seed)
        self.rotor_noise = NoiseStream(streams[3], p.rotor_speed_noise_std_hz, self.n_rotors, s["noise_rotor"])
        state_scale = np.repeat(
            [p.state_pos_noise_std, p.state_vel_noise_std, p.state_acc_noise_std, p.state_att_noise_std,
             p.state_omega_noise_std],
            3,
        )  # fmt: skip
        self.state_noise = NoiseStream(streams[4], state_scale, _STATE_DIM, s["noise_state"])

    @property
    def noise_streams(self) -> tuple[NoiseStream, ...]:
        """The streams :func:`sense` reads (refill the exhausted ones before a compiled call)."""
        st = (self.state_noise,) if self.state_mode == STATE_NOISY else ()
        return (self.imu.noise, self.rotor_noise, *st, self.mocap.noise)

    def refill(self) -> None:
        """Draw the next block of every exhausted stream."""
        for stream in self.noise_streams:
            if stream.exhausted:
                stream.refill()
