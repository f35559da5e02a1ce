"""Compiled kernels of the simulator's step (see :mod:`omnirotor._jit` for how they are compiled).

Each kernel is the only implementation of its math, and the docstring of the module that calls it states
the model (SPEC section cited there):

* :func:`rotor_step`: the first-order speed lag of :mod:`omnirotor.sim.rotors` (SPEC §1.4);
* the truth aerodynamics' kernels live in :mod:`omnirotor.sim.aero` (the rotor-wake model and SPEC §7's
  slipstream interference); :func:`actuate` dispatches on the model's kind;
* :func:`apply_wrench`: body wrench to ``xfrc_applied`` (world frame, at the CoM) plus the external wrench,
  :meth:`omnirotor.sim.simulator.Simulator.step`;
* :func:`imu_measure_into`, :func:`sense_into_frame`, :func:`mocap_push`, :func:`mocap_step`: the sensor models
  of :mod:`omnirotor.sim.sensors` (IMU, motion capture, measured rotor speeds, the bypass state) read straight
  from MuJoCo's ``qpos``, ``qvel``, ``qacc``, ``xmat``, written into the packed frame of
  :mod:`omnirotor.messages`;
* :func:`truth_row_into`, :func:`contact_into_row`: the ground-truth row, the contact wrench from the model's
  contact sensors;
* :func:`observe` and :func:`sim_step`: a whole :meth:`omnirotor.sim.simulator.Simulator.step` in one call. It
  calls MuJoCo's C functions ``mj_Euler`` and ``mj_forward`` directly (:data:`mj_Euler`, :data:`mj_forward`:
  the symbols of the ``libmujoco`` that the ``mujoco`` package loaded, bound by name, so the cached machine
  code stays valid across processes), on the addresses of the simulator's ``MjModel`` and ``MjData``.

The arithmetic is written in the order of the NumPy / Python float code it replaced, so that results agree to
the last bit except where a matrix-vector product was summed by BLAS (a rounding).
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor._jit import R9_from_quat_into, f64_view, f64_view2, i64_view, jit, mujoco_function
from omnirotor.messages import (
    FRAME_ACC_B,
    FRAME_HAS_STATE,
    FRAME_MOCAP_NEW,
    FRAME_MOCAP_T,
    FRAME_ROTOR_HZ,
    FRAME_STATE,
    FRAME_T,
)
from omnirotor.sim.aero import (
    AERO_INTERFERENCE,
    AERO_NOMINAL,
    AERO_WAKE,
    interference_efficiency,
    interference_wrench,
    pack_interference,
    wake_wrench,
)

__all__ = [
    "rotor_step",
    "pack_interference",
    "interference_efficiency",
    "interference_wrench",
    "apply_wrench",
    "imu_measure_into",
    "quat_perturb_into",
    "sense_into_frame",
    "EXT_SIZE",
    "IMU_PAR_SIZE",
    "STATE_NONE",
    "STATE_EXACT",
    "STATE_NOISY",
    "actuate",
    "AERO_NOMINAL",
    "AERO_INTERFERENCE",
    "AERO_WAKE",
    "truth_into",
    "truth_row_into",
    "TRUTH_SIZE",
    "TRUTH_ROW_SIZE",
    "mocap_push",
    "mocap_step",
    "contact_into_row",
    "observe",
    "sim_step",
    "sim_step_by_address",
    "kernel_arrays",
]

mj_Euler = mujoco_function("mj_Euler")
"""MuJoCo's ``void mj_Euler(const mjModel* m, mjData* d)``, callable from kernels with the two addresses."""
mj_forward = mujoco_function("mj_forward")
"""MuJoCo's ``void mj_forward(const mjModel* m, mjData* d)``, callable from kernels with the two addresses."""

# Layout of the external-wrench array of apply_wrench: f_W (3), m_W (3), p_E_B (3), active, at the EE tip.
_EXT_F, _EXT_M, _EXT_PE, _EXT_ON, _EXT_AT_EE = 0, 3, 6, 9, 10
EXT_SIZE = 11
# Layout of the IMU parameter array: gravity, acc bias (3), gyro bias (3), offset r_B (3), has offset.
_IMU_G, _IMU_BA, _IMU_BG, _IMU_R, _IMU_HAS_R = 0, 1, 4, 7, 10
IMU_PAR_SIZE = 11
# What sense() writes after the rotor speeds.
STATE_NONE, STATE_EXACT, STATE_NOISY = 0, 1, 2


@jit
def rotor_step(omega_hz, u_hz2, cmd_hz, lo: float, hi: float, alpha: float, dead_band_hz: float) -> None:
    """One period of the rotor speed lag, in place.

    Per rotor: the command is set to 0 inside the dead band ``(-db, db)`` (when ``db > 0``), clipped to
    ``[lo, hi]`` (a NaN command holds the speed), and ``omega += alpha (target - omega)``; then
    ``u = |omega| omega``.

    Args:
        omega_hz: (n,) speeds [Hz], updated.
        u_hz2: (n,) output inputs [Hz²].
        cmd_hz: (n,) commanded speeds [Hz].
        lo: lower speed limit [Hz].
        hi: upper speed limit [Hz].
        alpha: ``1 - exp(-dt / tau_m)``.
        dead_band_hz: dead band half-width [Hz]; 0 disables it.
    """
    for i in range(omega_hz.shape[0]):
        c = cmd_hz[i]
        if dead_band_hz > 0.0 and -dead_band_hz < c < dead_band_hz:
            c = 0.0
        w = omega_hz[i]
        if lo <= c <= hi:
            target = c
        elif c > hi:
            target = hi
        elif c < lo:
            target = lo
        else:  # NaN: hold
            target = w
        w = w + alpha * (target - w)
        omega_hz[i] = w
        u_hz2[i] = abs(w) * w


@jit
def apply_wrench(qpos, qp: int, w_B, ext, xfrc) -> None:
    """Rotor wrench (body frame) rotated to the world, plus the external wrench, into ``xfrc`` (6,).

    ``R_WB`` is that of the quaternion ``qpos[qp+3 : qp+7]``; ``ext`` holds ``f_W, m_W, p_E_B, active, at_ee``
    (see ``EXT_SIZE``): an active force applied at the EE tip adds its moment ``(R p_E_B) x f_W``.
    """
    R = np.empty(9)
    R9_from_quat_into(qpos[qp + 3], qpos[qp + 4], qpos[qp + 5], qpos[qp + 6], R, 0)
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = R[0], R[1], R[2], R[3], R[4], R[5], R[6], R[7], R[8]
    fx, fy, fz, mx, my, mz = w_B[0], w_B[1], w_B[2], w_B[3], w_B[4], w_B[5]
    Fx = r00 * fx + r01 * fy + r02 * fz
    Fy = r10 * fx + r11 * fy + r12 * fz
    Fz = r20 * fx + r21 * fy + r22 * fz
    Mx = r00 * mx + r01 * my + r02 * mz
    My = r10 * mx + r11 * my + r12 * mz
    Mz = r20 * mx + r21 * my + r22 * mz
    if ext[_EXT_ON] != 0.0:
        ex, ey, ez = ext[_EXT_F], ext[_EXT_F + 1], ext[_EXT_F + 2]
        Fx, Fy, Fz = Fx + ex, Fy + ey, Fz + ez
        Mx, My, Mz = Mx + ext[_EXT_M], My + ext[_EXT_M + 1], Mz + ext[_EXT_M + 2]
        if ext[_EXT_AT_EE] != 0.0:
            px, py, pz = ext[_EXT_PE], ext[_EXT_PE + 1], ext[_EXT_PE + 2]
            rx = r00 * px + r01 * py + r02 * pz
            ry = r10 * px + r11 * py + r12 * pz
            rz = r20 * px + r21 * py + r22 * pz
            Mx += ry * ez - rz * ey
            My += rz * ex - rx * ez
            Mz += rx * ey - ry * ex
    xfrc[0] = Fx
    xfrc[1] = Fy
    xfrc[2] = Fz
    xfrc[3] = Mx
    xfrc[4] = My
    xfrc[5] = Mz


@jit
def actuate(omega_hz, u_hz2, cmd_hz, rotor_par, aero_kind: int, aero_model, qpos, qp: int, w_B, ext, xfrc) -> None:
    """The actuation of a control period in one call: :func:`rotor_step`, the truth wrench, :func:`apply_wrench`.

    Args:
        omega_hz: (n,) rotor speeds [Hz], updated.
        u_hz2: (n,) rotor inputs [Hz²], updated.
        cmd_hz: (n,) commanded speeds [Hz].
        rotor_par: (4,) ``lo, hi, alpha, dead_band_hz`` of :func:`rotor_step`.
        aero_kind: ``AERO_NOMINAL`` (``aero_model`` is the (6, n) map), ``AERO_WAKE`` (``aero_model`` from
            :func:`omnirotor.sim.aero.pack_wake`) or ``AERO_INTERFERENCE`` (from :func:`pack_interference`).
        aero_model: see ``aero_kind``.
        qpos: MuJoCo's generalized positions.
        qp: address of the vehicle's joint in ``qpos``.
        w_B: (6,) output: the rotor wrench at the CoM, body frame.
        ext: the external wrench (see :func:`apply_wrench`).
        xfrc: (6,) output: the vehicle's row of ``xfrc_applied``.
    """
    rotor_step(omega_hz, u_hz2, cmd_hz, rotor_par[0], rotor_par[1], rotor_par[2], rotor_par[3])
    if aero_kind == AERO_WAKE:
        wake_wrench(u_hz2, aero_model, w_B)
    elif aero_kind == AERO_INTERFERENCE:
        interference_wrench(u_hz2, aero_model, w_B)
    else:
        n = u_hz2.shape[0]
        for r in range(6):
            acc = 0.0
            for j in range(n):
                acc += aero_model[r, j] * u_hz2[j]
            w_B[r] = acc
    apply_wrench(qpos, qp, w_B, ext, xfrc)


@jit
def imu_measure_into(R9, a_W, omega_B, omega_dot_B, par, noise, out, o: int) -> None:
    """One IMU sample into ``out[o:o+6]`` = ``acc_B (3) [m/s²], gyro_B (3) [rad/s]``.

    ``acc_B = R^T (a_W + g e3) + b_a + n_a`` plus ``omega_dot x r + omega x (omega x r)`` when the IMU sits at
    ``r != 0``; ``gyro_B = omega_B + b_g + n_g``.

    Args:
        R9: (9,) ``R_WB`` row-major.
        a_W: (3,) CoM acceleration without gravity [m/s²].
        omega_B: (3,) angular velocity [rad/s].
        omega_dot_B: (3,) angular acceleration [rad/s²].
        par: IMU parameters (``IMU_PAR_SIZE``: gravity, acc bias, gyro bias, offset, has offset).
        noise: (6,) white noise ``n_a, n_g``.
        out: output array.
        o: offset in ``out``.
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = R9[0], R9[1], R9[2], R9[3], R9[4], R9[5], R9[6], R9[7], R9[8]
    sx, sy, sz = a_W[0], a_W[1], a_W[2] + par[_IMU_G]
    ax = r00 * sx + r10 * sy + r20 * sz + par[_IMU_BA] + noise[0]
    ay = r01 * sx + r11 * sy + r21 * sz + par[_IMU_BA + 1] + noise[1]
    az = r02 * sx + r12 * sy + r22 * sz + par[_IMU_BA + 2] + noise[2]
    wx, wy, wz = omega_B[0], omega_B[1], omega_B[2]
    if par[_IMU_HAS_R] != 0.0:
        rx, ry, rz = par[_IMU_R], par[_IMU_R + 1], par[_IMU_R + 2]
        dx, dy, dz = omega_dot_B[0], omega_dot_B[1], omega_dot_B[2]
        cx, cy, cz = wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx
        ax += dy * rz - dz * ry + wy * cz - wz * cy
        ay += dz * rx - dx * rz + wz * cx - wx * cz
        az += dx * ry - dy * rx + wx * cy - wy * cx
    out[o + 0] = ax
    out[o + 1] = ay
    out[o + 2] = az
    out[o + 3] = wx + par[_IMU_BG] + noise[3]
    out[o + 4] = wy + par[_IMU_BG + 1] + noise[4]
    out[o + 5] = wz + par[_IMU_BG + 2] + noise[5]


@jit
def quat_perturb_into(qw: float, qx: float, qy: float, qz: float, a: float, b: float, c: float, out, o: int) -> None:
    """``q ⊗ [1, dtheta/2]`` normalised into ``out[o:o+4]`` (as :func:`omnirotor.sim.sensors.quat_perturb`)."""
    a, b, c = 0.5 * a, 0.5 * b, 0.5 * c
    rw = qw - qx * a - qy * b - qz * c
    rx = qx + qw * a + qy * c - qz * b
    ry = qy + qw * b + qz * a - qx * c
    rz = qz + qw * c + qx * b - qy * a
    s = 1.0 / math.sqrt(rw * rw + rx * rx + ry * ry + rz * rz)
    out[o + 0] = rw * s
    out[o + 1] = rx * s
    out[o + 2] = ry * s
    out[o + 3] = rz * s


@jit
def sense_into_frame(
    qpos, qvel, qacc, xmat, qp: int, qv: int, body: int, imu_par, imu_noise, omega_hz, rotor_noise, mode: int,
    state_noise, frame,
) -> None:  # fmt: skip
    """The IMU, the measured rotor speeds and the bypass state of a frame, from MuJoCo's state.

    Writes the packed frame's (:mod:`omnirotor.messages`) accelerometer, gyroscope and rotor speeds, and its
    state flag and state: none (``STATE_NONE``), the truth (``STATE_EXACT``) or the truth plus ``state_noise``
    (15: p, v, a, small body rotation, omega; ``STATE_NOISY``, the attitude perturbed as
    :func:`quat_perturb_into`).

    Args:
        qpos: MuJoCo's generalized positions (the free joint's ``[p_W, q_WB]`` at ``qp``).
        qvel: generalized velocities (``[v_W, omega_B]`` at ``qv``).
        qacc: generalized accelerations (``[p_ddot_W, omega_dot_B]`` at ``qv``).
        xmat: (nbody, 9) body orientations; row ``body`` is ``R_WB``.
        qp: address of the vehicle's joint in ``qpos``.
        qv: address of the vehicle's joint in ``qvel`` and ``qacc``.
        body: the vehicle's body id.
        imu_par: IMU parameters (see :func:`imu_measure_into`).
        imu_noise: (6,) IMU white noise.
        omega_hz: (n,) true rotor speeds [Hz].
        rotor_noise: (n,) speed-measurement noise [Hz].
        mode: ``STATE_NONE``, ``STATE_EXACT`` or ``STATE_NOISY``.
        state_noise: (15,) bypass-state noise (read in ``STATE_NOISY`` only).
        frame: the packed frame.
    """
    R9 = xmat[body]
    imu_measure_into(
        R9, qacc[qv : qv + 3], qvel[qv + 3 : qv + 6], qacc[qv + 3 : qv + 6], imu_par, imu_noise, frame, FRAME_ACC_B
    )  # the gyroscope follows the accelerometer in the frame
    n = omega_hz.shape[0]
    for i in range(n):
        frame[FRAME_ROTOR_HZ + i] = omega_hz[i] + rotor_noise[i]
    o = FRAME_STATE
    if mode == STATE_NONE:
        frame[FRAME_HAS_STATE] = 0.0
        for i in range(21):
            frame[o + i] = 0.0
        return
    frame[FRAME_HAS_STATE] = 1.0
    if mode == STATE_EXACT:
        for i in range(3):
            frame[o + i] = qpos[qp + i]
            frame[o + 3 + i] = qvel[qv + i]
            frame[o + 6 + i] = qacc[qv + i]
            frame[o + 18 + i] = qvel[qv + 3 + i]
        for i in range(9):
            frame[o + 9 + i] = R9[i]
        return
    e = state_noise
    for i in range(3):
        frame[o + i] = qpos[qp + i] + e[i]
        frame[o + 3 + i] = qvel[qv + i] + e[3 + i]
        frame[o + 6 + i] = qacc[qv + i] + e[6 + i]
        frame[o + 18 + i] = qvel[qv + 3 + i] + e[12 + i]
    # The perturbed quaternion goes through the frame's R slots (overwritten by its matrix right after).
    quat_perturb_into(qpos[qp + 3], qpos[qp + 4], qpos[qp + 5], qpos[qp + 6], e[9], e[10], e[11], frame, o + 9)
    R9_from_quat_into(frame[o + 9], frame[o + 10], frame[o + 11], frame[o + 12], frame, o + 9)


# -- motion capture (omnirotor.sim.sensors.Mocap) -----------------------------------------------------------------
MOCAP_HEAD, MOCAP_COUNT, MOCAP_LATENCY = 0, 1, 2  # the int array: queue head, queue length, latency [steps]
MOCAP_INT_SIZE = 3
MOCAP_NEXT_T, MOCAP_PERIOD = 0, 1  # the float array: time of the next sample, sample period [s]
MOCAP_FLOAT_SIZE = 2
MOCAP_SAMPLE_SIZE = 8
"""A delivered sample: t [s], p_W (3) [m], q_WB (4, wxyz); the same order as the packed frame's."""
MOCAP_CLOCK_TOL_S = 1e-9
"""Tolerance [s] of the sample clock against the step grid (times are multiples of dt up to rounding)."""


@jit
def mocap_push(mi, mf, mt, mdue, mp, mq, noise_buf, noise_pos, t: float, due: int, p, q) -> None:
    """Queue a sample taken at ``t`` of the pose ``(p, q)``, with its noise, for delivery at step ``due``.

    Takes the noise row ``noise_buf[noise_pos[0]]`` (the caller makes sure one is left) and advances
    ``noise_pos``. A full queue (only with a sample rate above the step rate) drops its oldest sample.
    """
    cap = mt.shape[0]
    if mi[MOCAP_COUNT] == cap:
        mi[MOCAP_HEAD] = (mi[MOCAP_HEAD] + 1) % cap
        mi[MOCAP_COUNT] -= 1
    i = (mi[MOCAP_HEAD] + mi[MOCAP_COUNT]) % cap
    r = noise_pos[0]
    noise_pos[0] = r + 1
    e = noise_buf[r]
    mt[i] = t
    mdue[i] = due
    for j in range(3):
        mp[i, j] = e[j] + p[j]
    quat_perturb_into(q[0], q[1], q[2], q[3], e[3], e[4], e[5], mq[i], 0)
    mi[MOCAP_COUNT] += 1


@jit
def mocap_step(mi, mf, mt, mdue, mp, mq, noise_buf, noise_pos, k: int, t: float, p, q, out, o: int) -> bool:
    """One step of the motion capture (:meth:`omnirotor.sim.sensors.Mocap.step`).

    Takes a sample of ``(p, q)`` if one is due at step ``k`` (time ``t`` [s]), then delivers the newest queued
    sample that has arrived, if any, into ``out[o : o + MOCAP_SAMPLE_SIZE]`` (t, p, q).

    Returns:
        True when a sample was delivered.
    """
    if t >= mf[MOCAP_NEXT_T] - MOCAP_CLOCK_TOL_S:
        mocap_push(mi, mf, mt, mdue, mp, mq, noise_buf, noise_pos, t, k + mi[MOCAP_LATENCY], p, q)
        mf[MOCAP_NEXT_T] += mf[MOCAP_PERIOD]
        while mf[MOCAP_NEXT_T] <= t + MOCAP_CLOCK_TOL_S:  # a rate above the step rate: one sample per step
            mf[MOCAP_NEXT_T] += mf[MOCAP_PERIOD]
    if mi[MOCAP_COUNT] == 0 or mdue[mi[MOCAP_HEAD]] > k:
        return False
    cap = mt.shape[0]
    i = mi[MOCAP_HEAD]
    while True:  # the newest arrived sample wins
        mi[MOCAP_HEAD] = (mi[MOCAP_HEAD] + 1) % cap
        mi[MOCAP_COUNT] -= 1
        if mi[MOCAP_COUNT] == 0 or mdue[mi[MOCAP_HEAD]] > k:
            break
        i = mi[MOCAP_HEAD]
    out[o] = mt[i]
    for j in range(3):
        out[o + 1 + j] = mp[i, j]
    for j in range(4):
        out[o + 4 + j] = mq[i, j]
    return True


TRUTH_SIZE = 36
"""Length of the fixed part of :func:`truth_into`'s buffer (the rotor speeds follow)."""


@jit
def truth_into(qpos, qvel, qacc, xmat, site_xpos, qp: int, qv: int, body: int, site: int, omega_hz, w_B, out) -> None:
    """The ground truth of :class:`omnirotor.sim.simulator.GroundTruth` into one buffer ``out``.

    Layout: ``p_W (3), v_W (3), a_W (3), R_WB (9), omega_B (3), rotor_wrench_B (6), p_E_W (3)``, then the
    contact force and moment (6, zeroed here; the simulator sums the contacts into them) and the rotor
    speeds (n).

    Args:
        qpos: MuJoCo's generalized positions (see :func:`sense`).
        qvel: generalized velocities.
        qacc: generalized accelerations.
        xmat: (nbody, 9) body orientations.
        site_xpos: (nsite, 3) site positions; row ``site`` is the EE tip.
        qp: address of the vehicle's joint in ``qpos``.
        qv: address of the vehicle's joint in ``qvel`` and ``qacc``.
        body: the vehicle's body id.
        site: the EE tip's site id.
        omega_hz: (n,) rotor speeds [Hz].
        w_B: (6,) rotor wrench at the CoM, body frame.
        out: the buffer, ``TRUTH_SIZE + n`` floats.
    """
    for i in range(3):
        out[i] = qpos[qp + i]
        out[3 + i] = qvel[qv + i]
        out[6 + i] = qacc[qv + i]
        out[18 + i] = qvel[qv + 3 + i]
        out[27 + i] = site_xpos[site, i]
        out[30 + i] = 0.0
        out[33 + i] = 0.0
    for i in range(9):
        out[9 + i] = xmat[body, i]
    for i in range(6):
        out[21 + i] = w_B[i]
    for i in range(omega_hz.shape[0]):
        out[TRUTH_SIZE + i] = omega_hz[i]


TRUTH_ROW_SIZE = 29
"""Length of the fixed part of :func:`truth_row_into`'s row (the rotor speeds follow)."""


@jit
def truth_row_into(
    qpos, qvel, xmat, site_xpos, qp: int, qv: int, body: int, site: int, omega_hz, t: float, out
) -> None:
    """The ground truth as one flat row (:meth:`omnirotor.sim.simulator.Simulator.truth_row`).

    Layout: ``t, p_W (3), v_W (3), R_WB (9), omega_B (3), p_E_W (3)``, the contact force and moment (6, zeroed
    here; the simulator sums the contacts into them), the contact flag (0 here) and the rotor speeds (n).

    Args:
        qpos: MuJoCo's generalized positions (see :func:`sense`).
        qvel: generalized velocities.
        xmat: (nbody, 9) body orientations.
        site_xpos: (nsite, 3) site positions; row ``site`` is the EE tip.
        qp: address of the vehicle's joint in ``qpos``.
        qv: address of the vehicle's joint in ``qvel``.
        body: the vehicle's body id.
        site: the EE tip's site id.
        omega_hz: (n,) rotor speeds [Hz].
        t: time [s].
        out: the row, at least ``TRUTH_ROW_SIZE + n`` floats.
    """
    out[0] = t
    for i in range(3):
        out[1 + i] = qpos[qp + i]
        out[4 + i] = qvel[qv + i]
        out[16 + i] = qvel[qv + 3 + i]
        out[19 + i] = site_xpos[site, i]
        out[22 + i] = 0.0
        out[25 + i] = 0.0
    for i in range(9):
        out[7 + i] = xmat[body, i]
    out[28] = 0.0
    for i in range(omega_hz.shape[0]):
        out[TRUTH_ROW_SIZE + i] = omega_hz[i]


# -- the contact wrench on the end-effector (the model's contact sensors, omnirotor.sim.model) ------------------
CONTACT_SENSOR_SIZE = 10
"""Entries of one EE contact sensor: contacts found, net force (3) [N], torque (3) [N·m], centroid (3) [m]."""


@jit
def contact_into_row(sensordata, adr, row, o_p: int, o_f: int, o_m: int, o_flag: int) -> None:
    """Add the environment's contact wrench on the end-effector to a truth row, from the EE contact sensors.

    Each sensor (``reduce="netforce"``, one per EE geom) gives the number of its geom's contacts, and the net
    force and torque they exert *from* the geom on the environment about their force-weighted centroid, in the
    world frame. The row gets the reaction on the EE, its moment about the tip ``row[o_p:o_p+3]``, and 1.0 at
    ``o_flag`` when any EE geom touches the environment.

    Args:
        sensordata: MuJoCo's ``sensordata``.
        adr: (k,) int64 addresses of the EE contact sensors in ``sensordata`` (-1: geom absent).
        row: the truth row; force, moment and flag are added or set.
        o_p: offset of the tip position in ``row``.
        o_f: offset of the force.
        o_m: offset of the moment.
        o_flag: offset of the contact flag.
    """
    for s in range(adr.shape[0]):
        a = adr[s]
        if a < 0 or sensordata[a] <= 0.0:
            continue
        row[o_flag] = 1.0
        fx, fy, fz = -sensordata[a + 1], -sensordata[a + 2], -sensordata[a + 3]
        rx = sensordata[a + 7] - row[o_p]
        ry = sensordata[a + 8] - row[o_p + 1]
        rz = sensordata[a + 9] - row[o_p + 2]
        row[o_f] += fx
        row[o_f + 1] += fy
        row[o_f + 2] += fz
        row[o_m] += -sensordata[a + 4] + ry * fz - rz * fy
        row[o_m + 1] += -sensordata[a + 5] + rz * fx - rx * fz
        row[o_m + 2] += -sensordata[a + 6] + rx * fy - ry * fx


# -- a whole step --------------------------------------------------------------------------------------------------
# The int parameters of observe() and sim_step(), one int64 array (omnirotor.sim.simulator.Simulator builds it).
SI_QP, SI_QV, SI_BODY, SI_SITE, SI_STATE_MODE, SI_SUBSTEPS, SI_AERO_KIND, SI_MODEL, SI_DATA = range(9)
SI_SIZE = 9
# Offsets in the truth row (truth_row_into).
_ROW_P_E, _ROW_F, _ROW_M, _ROW_FLAG = 19, 22, 25, 28


@jit
def observe(mjv, si, omega_hz, imu_par, noise, moc, sens_adr, k: int, dt: float, frame, row) -> None:
    """The frame and the truth row at step ``k`` (time ``k dt``) from MuJoCo's current state.

    Args:
        mjv: MuJoCo's arrays ``(qpos, qvel, qacc, xmat, site_xpos, sensordata, xfrc_row)``.
        si: the int parameters (``SI_*``).
        omega_hz: (n,) true rotor speeds [Hz].
        imu_par: IMU parameters (:func:`imu_measure_into`).
        noise: the noise streams' ``(buf, pos)`` pairs flattened: IMU, rotor, state, mocap (each ``pos`` has
            a row left; the caller refills exhausted streams before the call).
        moc: the motion capture's arrays (:attr:`omnirotor.sim.sensors.Mocap.kernel_state`).
        sens_adr: (k,) addresses of the EE contact sensors (:func:`contact_into_row`).
        k: step index.
        dt: control period [s].
        frame: the packed frame (written whole).
        row: the truth row (:func:`truth_row_into`), at least ``TRUTH_ROW_SIZE + n`` entries.
    """
    qpos, qvel, qacc, xmat, site_xpos, sensordata, xfrc = mjv
    imu_buf, imu_pos, rot_buf, rot_pos, st_buf, st_pos, mc_buf, mc_pos = noise
    mi, mf, mt, mdue, mp, mq = moc
    qp, qv, body = si[SI_QP], si[SI_QV], si[SI_BODY]
    t = k * dt
    frame[FRAME_T] = t
    i_imu = imu_pos[0]
    imu_pos[0] = i_imu + 1
    i_rot = rot_pos[0]
    rot_pos[0] = i_rot + 1
    mode = si[SI_STATE_MODE]
    i_st = 0
    if mode == STATE_NOISY:
        i_st = st_pos[0]
        st_pos[0] = i_st + 1
    sense_into_frame(
        qpos, qvel, qacc, xmat, qp, qv, body, imu_par, imu_buf[i_imu], omega_hz, rot_buf[i_rot], mode,
        st_buf[i_st], frame,
    )  # fmt: skip
    got = mocap_step(
        mi, mf, mt, mdue, mp, mq, mc_buf, mc_pos, k, t, qpos[qp : qp + 3], qpos[qp + 3 : qp + 7], frame,
        FRAME_MOCAP_T,
    )  # fmt: skip
    if got:
        frame[FRAME_MOCAP_NEW] = 1.0
    else:
        frame[FRAME_MOCAP_NEW] = 0.0
        for j in range(MOCAP_SAMPLE_SIZE):
            frame[FRAME_MOCAP_T + j] = 0.0
    truth_row_into(qpos, qvel, xmat, site_xpos, qp, qv, body, si[SI_SITE], omega_hz, t, row)
    contact_into_row(sensordata, sens_adr, row, _ROW_P_E, _ROW_F, _ROW_M, _ROW_FLAG)


@jit
def sim_step(mjv, si, act, cmd_hz, imu_par, noise, moc, sens_adr, k: int, dt: float, frame, row) -> None:
    """A whole control period of :meth:`omnirotor.sim.simulator.Simulator.step` (own rotor and truth models).

    ``substeps`` x (``mj_Euler``, the actuation on the last one, ``mj_forward``), then :func:`observe` at step
    ``k + 1``.

    Args:
        mjv: MuJoCo's arrays (:func:`observe`).
        si: the int parameters (``SI_*``), with the MjModel and MjData addresses.
        act: the actuation's arrays ``(omega_hz, u_hz2, rotor_par, aero_model, w_B, ext)`` (:func:`actuate`).
        cmd_hz: (n,) commanded rotor speeds [Hz] (clipped by the rotor model; NaN holds a rotor's speed).
        imu_par: IMU parameters.
        noise: the noise streams (:func:`observe`).
        moc: the motion capture's arrays.
        sens_adr: the EE contact sensors' addresses.
        k: the step index before the period.
        dt: control period [s].
        frame: the packed frame (output).
        row: the truth row (output).
    """
    qpos, qvel, qacc, xmat, site_xpos, sensordata, xfrc = mjv
    omega_hz, u_hz2, rotor_par, aero_model, w_B, ext = act
    m, d = si[SI_MODEL], si[SI_DATA]
    qp = si[SI_QP]
    substeps = si[SI_SUBSTEPS]
    for i in range(substeps):
        mj_Euler(m, d)
        if i != substeps - 1:
            apply_wrench(qpos, qp, w_B, ext, xfrc)
        else:
            actuate(omega_hz, u_hz2, cmd_hz, rotor_par, si[SI_AERO_KIND], aero_model, qpos, qp, w_B, ext, xfrc)
        mj_forward(m, d)
    observe(mjv, si, omega_hz, imu_par, noise, moc, sens_adr, k + 1, dt, frame, row)


def kernel_arrays(args: tuple) -> list[np.ndarray]:
    """The arrays of ``Simulator.kernel_args``, flattened in the order :func:`sim_step_by_address` reads."""
    mjv, si, act, imu_par, noise, moc, sens_adr = args
    return [*mjv, si, *act, imu_par, *noise, *moc, sens_adr]


@jit
def sim_step_by_address(table, cmd_hz, k: int, dt: float, frame, row) -> None:
    """:func:`sim_step` with its arrays given by address (``_jit.address_table(kernel_arrays(args))``).

    The same step; from Python it costs one table instead of some thirty array arguments to unbox.
    """
    mjv = (
        f64_view(table, 0), f64_view(table, 1), f64_view(table, 2), f64_view2(table, 3), f64_view2(table, 4),
        f64_view(table, 5), f64_view(table, 6),
    )  # fmt: skip
    act = (
        f64_view(table, 8), f64_view(table, 9), f64_view(table, 10), f64_view2(table, 11), f64_view(table, 12),
        f64_view(table, 13),
    )  # fmt: skip
    noise = (
        f64_view2(table, 15), i64_view(table, 16), f64_view2(table, 17), i64_view(table, 18), f64_view2(table, 19),
        i64_view(table, 20), f64_view2(table, 21), i64_view(table, 22),
    )  # fmt: skip
    moc = (
        i64_view(table, 23), f64_view(table, 24), f64_view(table, 25), i64_view(table, 26), f64_view2(table, 27),
        f64_view2(table, 28),
    )  # fmt: skip
    si, imu_par, sens_adr = i64_view(table, 7), f64_view(table, 14), i64_view(table, 29)
    sim_step(mjv, si, act, cmd_hz, imu_par, noise, moc, sens_adr, k, dt, frame, row)
