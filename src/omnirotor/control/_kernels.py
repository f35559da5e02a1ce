"""Compiled kernels of the controller's 1 kHz step (see :mod:`omnirotor._jit` for how they are compiled).

Each block keeps its state, parameters and outputs in **one** float64 array (its ``kernel_state``; the public
attributes are views into it) whose layout is fixed here. The block's own Python method (``step``,
``sample``, ...) calls the kernel of this module that implements it; the controller's compiled step
(:mod:`omnirotor.control._step_kernels`) calls the two fused kernels :func:`controller_pre` and
:func:`controller_post`, which run the same kernels one after the other, around the allocation QP (and the
Python path of the controller calls them around a QP solver with a Python interface). Each block's
equations and their SPEC section are in the docstring of the block's module; the arithmetic here is written
in the order of the Python float code it replaced, so results agree with it to the last bit
except where a small matrix-vector product used to be summed by BLAS (a rounding).
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor._jit import jit
from omnirotor.blocks import compiled_step
from omnirotor.control import observer as _observer  # noqa: F401 (registers the default observer)
from omnirotor.errors import InputError

observer_step = compiled_step("observer")

# -- admittance (omnirotor.control.admittance, SPEC §4.4) ------------------------------------------------------
ADM_XI_P = 0  # (3,)
ADM_XI_P_DOT = 3
ADM_XI_P_DDOT = 6
ADM_OMEGA_XI = 9
ADM_OMEGA_XI_DOT = 12
ADM_R_XI = 15  # (9,) row-major
ADM_Q = 24  # (4,) R_xi as a unit quaternion wxyz
ADM_INV_M = 28  # (3,) 1 / M_p
ADM_D = 31
ADM_K = 34
ADM_INV_J = 37  # (3,) 1 / M_R
ADM_D_R = 40
ADM_K_R = 43
ADM_SIZE = 46

# -- reference samples (omnirotor.control.trajectory.ReferenceSample) -----------------------------------------
REF_P, REF_V, REF_A, REF_R, REF_OMEGA, REF_ALPHA = 0, 3, 6, 9, 18, 21
REF_SIZE = 24

# -- trajectory (omnirotor.control.trajectory.PoseTrajectory, SPEC §4.5) ---------------------------------------
# Packed as: n_waypoints, cubic, times (n_wp), thetas (n_wp - 1), hold_first (24 x 8), hold_last (24 x 8),
# then one (24 x 8) basis per segment.
TRAJ_N_BASIS = 8
TRAJ_BASIS_SIZE = REF_SIZE * TRAJ_N_BASIS

# -- pose controller (omnirotor.control.pose, SPEC §4.1) -------------------------------------------------------
POSE_W_REF = 0  # (6,) f_ref_W, m_ref_B
POSE_ERRORS = 6  # (12,) e_p, e_v, e_R, e_omega
POSE_EI = 18  # (3,) position-error integral
POSE_MASS = 21
POSE_GRAVITY = 22
POSE_J = 23  # (3,)
POSE_COMP = 26  # 1: subtract the estimated external wrench
POSE_FF = 27  # 1: angular-acceleration feed-forward
POSE_KP = 28
POSE_KV = 31
POSE_KI = 34
POSE_KR = 37
POSE_KW = 40
POSE_LIM_P = 43
POSE_LIM_V = 44
POSE_LIM_I = 45
POSE_SIZE = 46

# -- allocation (omnirotor.control.allocation, SPEC §4.2); n rotors --------------------------------------------
ALLOC_SCALE = 0  # u_scale [Hz²]
ALLOC_W_B = 1  # (6,) body-frame wrench reference


@jit
def alloc_offsets(n: int) -> tuple[int, int, int, int, int, int, int, int, int, int]:
    """Offsets of the n-dependent parts of the allocation state, and its size.

    The parts: f, A key (6n), G (n x 6, row-major), lo, hi, lo_sat, hi_sat, u, u_safe (n each unless said).

    Args:
        n: number of rotors.
    """
    f = 7
    key = f + n
    G = key + 6 * n
    lo = G + 6 * n
    hi = lo + n
    lo_sat = hi + n
    hi_sat = lo_sat + n
    u = hi_sat + n
    u_safe = u + n
    return f, key, G, lo, hi, lo_sat, hi_sat, u, u_safe, u_safe + n


# -- controller (omnirotor.control.controller); n rotors -------------------------------------------------------
CTL_HEAD = 0  # (27,) the logged head: t, region, status, estimate (p, v, a, R, omega), EE tip
CTL_HEAD_SIZE = 27
CTL_EST = 3  # (21,) the estimate inside the head
CTL_P_E = 24  # (3,) EE tip inside the head
CTL_F_E = 27  # (3,) force at the EE [N], world
CTL_M_E = 30  # (3,) moment about the EE [N·m], world
CTL_P_E_B = 33  # (3,) EE tip in the body frame [m]
CTL_OMEGA_LO = 36
CTL_OMEGA_HI = 37
CTL_U_OBS = 38  # then u_obs (n), u_cmd (n), omega_cmd (n), omega_safe (n)


@jit
def controller_layout(n: int) -> tuple[int, int, int, int, int, int, int, int]:
    """Offsets in the controller's one array of its blocks' packed states, for n rotors, and the size.

    Order: the controller's own part (``CTL_*``, ``CTL_U_OBS + 4n``), the
    admittance filter (``ADM_SIZE``), the pose controller (``POSE_SIZE``), the desired, compliant and body
    references (``REF_SIZE`` each) and the allocator (``alloc_offsets(n)[-1]``).

    Returns:
        ``(obs, adm, pose, des, comp, body, alloc, size)``; ``obs`` is the end of the controller's own part
        (the observer's state is a field of the controller's structured state).
    """
    o_obs = CTL_U_OBS + 4 * n
    o_adm = o_obs
    o_pose = o_adm + ADM_SIZE
    o_des = o_pose + POSE_SIZE
    o_comp = o_des + REF_SIZE
    o_body = o_comp + REF_SIZE
    o_alloc = o_body + REF_SIZE
    return o_obs, o_adm, o_pose, o_des, o_comp, o_body, o_alloc, o_alloc + 7 + 19 * n


# Return codes of controller_pre.
PRE_OK = 0
PRE_MAP_CHANGED = 1  # the wrench map differs from the allocator's: rebuild the QP, then alloc_prepare again
PRE_ALLOC_NONFINITE = 2  # the QP's linear term is not finite: the allocator holds
PRE_STATE_NONFINITE = 3  # the estimate (or the measured rotor speeds) is not finite: hold the last command

# Modes of controller_post / alloc_finish.
FINISH_QP = 0  # x is the QP's answer: check it is finite
FINISH_FALLBACK = 1  # x is the pseudo-inverse fallback: clip it as it is
FINISH_HELD = 2  # the allocator held its last input: u is already set

# ControlStatus bits (omnirotor.messages.ControlStatus), for controller_post.
_BIT_NONFINITE = 2
_BIT_SATURATED = 4


def state_buffer(buffer: np.ndarray | None, size: int, owner: str) -> np.ndarray:
    """The packed-state array of a block: ``buffer`` (zeroed) when given, else a new one.

    A caller passes a slice of a larger array to keep several blocks' states in one place (the controller
    does, so that its compiled step takes one array instead of one per block).

    Raises:
        InputError: ``buffer`` is not a writeable, contiguous 1-D float64 array of ``size`` entries.
    """
    if buffer is None:
        return np.zeros(size)
    ok = (
        isinstance(buffer, np.ndarray)
        and buffer.dtype == np.float64
        and buffer.shape == (size,)
        and buffer.flags.c_contiguous
        and buffer.flags.writeable
    )
    if not ok:
        raise InputError(f"{owner} buffer must be a writeable contiguous float64 array of shape ({size},)")
    buffer[:] = 0.0
    return buffer


# -- small helpers ---------------------------------------------------------------------------------------------


@jit
def _all_finite(x) -> bool:
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            return False
    return True


@jit
def pack_state(p, v, a, R, w, out, o: int) -> bool:
    """Copy a state estimate into ``out[o:o+21]`` (p, v, a, R row-major, omega); True if all are finite."""
    for i in range(3):
        out[o + i] = p[i]
        out[o + 3 + i] = v[i]
        out[o + 6 + i] = a[i]
        out[o + 18 + i] = w[i]
    for i in range(3):
        for j in range(3):
            out[o + 9 + 3 * i + j] = R[i, j]
    return _all_finite(out[o : o + 21])


@jit
def state_finite(p, v, a, R, w) -> bool:
    """True if every entry of the five arrays of a state estimate is finite."""
    return _all_finite(p) and _all_finite(v) and _all_finite(a) and _all_finite(R.ravel()) and _all_finite(w)


# -- blocks ----------------------------------------------------------------------------------------------------


@jit
def ee_wrench(f_ext_W, m_ext_B, R, p_E_B, f_E_W, m_E_W) -> None:
    """The external wrench moved to the EE tip, world frame (:func:`omnirotor.control.admittance.ee_wrench_W`)."""
    fx, fy, fz = f_ext_W[0], f_ext_W[1], f_ext_W[2]
    mx, my, mz = m_ext_B[0], m_ext_B[1], m_ext_B[2]
    r00, r01, r02 = R[0, 0], R[0, 1], R[0, 2]
    r10, r11, r12 = R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22 = R[2, 0], R[2, 1], R[2, 2]
    ex, ey, ez = p_E_B[0], p_E_B[1], p_E_B[2]
    rx = r00 * ex + r01 * ey + r02 * ez
    ry = r10 * ex + r11 * ey + r12 * ez
    rz = r20 * ex + r21 * ey + r22 * ez
    f_E_W[0], f_E_W[1], f_E_W[2] = fx, fy, fz
    m_E_W[0] = r00 * mx + r01 * my + r02 * mz - (ry * fz - rz * fy)
    m_E_W[1] = r10 * mx + r11 * my + r12 * mz - (rz * fx - rx * fz)
    m_E_W[2] = r20 * mx + r21 * my + r22 * mz - (rx * fy - ry * fx)


@jit
def body_reference(e, p_E_B, d) -> None:
    """Body (CoM) reference ``d`` (24,) from the EE reference ``e`` (24,); ``d`` may be ``e``.

    See :func:`omnirotor.control.admittance.body_reference_from_ee`.
    """
    px, py, pz, vx, vy, vz, ax, ay, az = e[0], e[1], e[2], e[3], e[4], e[5], e[6], e[7], e[8]
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = e[9], e[10], e[11], e[12], e[13], e[14], e[15], e[16], e[17]
    wx, wy, wz, bx, by, bz = e[18], e[19], e[20], e[21], e[22], e[23]
    ex, ey, ez = p_E_B[0], p_E_B[1], p_E_B[2]
    rx = r00 * ex + r01 * ey + r02 * ez
    ry = r10 * ex + r11 * ey + r12 * ez
    rz = r20 * ex + r21 * ey + r22 * ez
    cx, cy, cz = wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx
    ccx, ccy, ccz = wy * cz - wz * cy, wz * cx - wx * cz, wx * cy - wy * cx
    d[0] = px - rx
    d[1] = py - ry
    d[2] = pz - rz
    d[3] = vx - cx
    d[4] = vy - cy
    d[5] = vz - cz
    d[6] = ax - (by * rz - bz * ry) - ccx
    d[7] = ay - (bz * rx - bx * rz) - ccy
    d[8] = az - (bx * ry - by * rx) - ccz
    for i in range(9, 24):
        d[i] = e[i]  # attitude and its rates are the EE's (R_E^B = I)


@jit
def admittance_step(s, f_E_W, m_E_W, dt: float) -> None:
    """Advance the admittance filter (:class:`omnirotor.control.admittance.AdmittanceFilter`) by ``dt``."""
    xp, yp, zp = s[ADM_XI_P], s[ADM_XI_P + 1], s[ADM_XI_P + 2]
    xv, yv, zv = s[ADM_XI_P_DOT], s[ADM_XI_P_DOT + 1], s[ADM_XI_P_DOT + 2]
    wx, wy, wz = s[ADM_OMEGA_XI], s[ADM_OMEGA_XI + 1], s[ADM_OMEGA_XI + 2]
    fx, fy, fz = f_E_W[0], f_E_W[1], f_E_W[2]
    mx, my, mz = m_E_W[0], m_E_W[1], m_E_W[2]
    ax = s[ADM_INV_M] * (fx - s[ADM_D] * xv - s[ADM_K] * xp)
    ay = s[ADM_INV_M + 1] * (fy - s[ADM_D + 1] * yv - s[ADM_K + 1] * yp)
    az = s[ADM_INV_M + 2] * (fz - s[ADM_D + 2] * zv - s[ADM_K + 2] * zp)
    half_dt2 = 0.5 * dt * dt
    # Rotational spring: 1/2 (R_xi - R_xi^T)^v = 2 q_w q_v for a unit quaternion.
    qw, qx, qy, qz = s[ADM_Q], s[ADM_Q + 1], s[ADM_Q + 2], s[ADM_Q + 3]
    alx = s[ADM_INV_J] * (mx - s[ADM_D_R] * wx - s[ADM_K_R] * 2.0 * qw * qx)
    aly = s[ADM_INV_J + 1] * (my - s[ADM_D_R + 1] * wy - s[ADM_K_R + 1] * 2.0 * qw * qy)
    alz = s[ADM_INV_J + 2] * (mz - s[ADM_D_R + 2] * wz - s[ADM_K_R + 2] * 2.0 * qw * qz)
    wx += alx * dt
    wy += aly * dt
    wz += alz * dt
    s[0] = xp + xv * dt + ax * half_dt2
    s[1] = yp + yv * dt + ay * half_dt2
    s[2] = zp + zv * dt + az * half_dt2
    s[3] = xv + ax * dt
    s[4] = yv + ay * dt
    s[5] = zv + az * dt
    s[6], s[7], s[8] = ax, ay, az
    s[9], s[10], s[11] = wx, wy, wz
    s[12], s[13], s[14] = alx, aly, alz
    # R_xi <- exp([omega dt]x) R_xi, i.e. q <- dq (x) q with dq the world-frame increment.
    angle = math.sqrt(wx * wx + wy * wy + wz * wz) * dt
    if angle > 0.0:
        c = math.cos(0.5 * angle)
        sn = math.sin(0.5 * angle) / angle * dt
        dw, dx, dy, dz = c, sn * wx, sn * wy, sn * wz
        qw, qx, qy, qz = (
            dw * qw - dx * qx - dy * qy - dz * qz,
            dw * qx + dx * qw + dy * qz - dz * qy,
            dw * qy - dx * qz + dy * qw + dz * qx,
            dw * qz + dx * qy - dy * qx + dz * qw,
        )
        norm = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        qw, qx, qy, qz = qw * norm, qx * norm, qy * norm, qz * norm
        s[ADM_Q], s[ADM_Q + 1], s[ADM_Q + 2], s[ADM_Q + 3] = qw, qx, qy, qz
        o = ADM_R_XI
        s[o + 0] = 1.0 - 2.0 * (qy * qy + qz * qz)
        s[o + 1] = 2.0 * (qx * qy - qw * qz)
        s[o + 2] = 2.0 * (qx * qz + qw * qy)
        s[o + 3] = 2.0 * (qx * qy + qw * qz)
        s[o + 4] = 1.0 - 2.0 * (qx * qx + qz * qz)
        s[o + 5] = 2.0 * (qy * qz - qw * qx)
        s[o + 6] = 2.0 * (qx * qz - qw * qy)
        s[o + 7] = 2.0 * (qy * qz + qw * qx)
        s[o + 8] = 1.0 - 2.0 * (qx * qx + qy * qy)


@jit
def compliant_reference(s, des, out) -> None:
    """The desired EE reference ``des`` (24,) displaced by the admittance offsets ``s``, into ``out`` (24,).

    See :meth:`omnirotor.control.admittance.AdmittanceFilter.compliant_reference`; ``out`` is not ``des``.
    """
    for i in range(9):
        out[i] = des[i] + s[i]
    o = ADM_R_XI
    r00, r01, r02 = s[o], s[o + 1], s[o + 2]
    r10, r11, r12 = s[o + 3], s[o + 4], s[o + 5]
    r20, r21, r22 = s[o + 6], s[o + 7], s[o + 8]
    # R_r = R_xi R_d
    for i in range(3):
        a0, a1, a2 = s[o + 3 * i], s[o + 3 * i + 1], s[o + 3 * i + 2]
        for j in range(3):
            out[REF_R + 3 * i + j] = a0 * des[REF_R + j] + a1 * des[REF_R + 3 + j] + a2 * des[REF_R + 6 + j]
    ox, oy, oz = des[REF_OMEGA], des[REF_OMEGA + 1], des[REF_OMEGA + 2]
    bx, by, bz = des[REF_ALPHA], des[REF_ALPHA + 1], des[REF_ALPHA + 2]
    wx, wy, wz = s[ADM_OMEGA_XI], s[ADM_OMEGA_XI + 1], s[ADM_OMEGA_XI + 2]
    vx, vy, vz = s[ADM_OMEGA_XI_DOT], s[ADM_OMEGA_XI_DOT + 1], s[ADM_OMEGA_XI_DOT + 2]
    rox = r00 * ox + r01 * oy + r02 * oz
    roy = r10 * ox + r11 * oy + r12 * oz
    roz = r20 * ox + r21 * oy + r22 * oz
    out[18] = wx + rox
    out[19] = wy + roy
    out[20] = wz + roz
    out[21] = vx + r00 * bx + r01 * by + r02 * bz + wy * roz - wz * roy
    out[22] = vy + r10 * bx + r11 * by + r12 * bz + wz * rox - wx * roz
    out[23] = vz + r20 * bx + r21 * by + r22 * bz + wx * roy - wy * rox


@jit
def trajectory_sample(pk, t: float, out) -> None:
    """The reference at time ``t`` [s] of a packed trajectory (:meth:`PoseTrajectory.sample`), into ``out``."""
    n_wp = int(pk[0])
    cubic = pk[1] != 0.0
    times = pk[2 : 2 + n_wp]
    thetas = pk[2 + n_wp : 2 + 2 * n_wp - 1]
    o_hold = 2 * n_wp + 1
    B = TRAJ_BASIS_SIZE
    NB = TRAJ_N_BASIS
    if not t > times[0]:
        for r in range(REF_SIZE):
            out[r] = pk[o_hold + r * NB]  # the hold basis times (1, 0, ..., 0)
        return
    if not t < times[n_wp - 1]:
        for r in range(REF_SIZE):
            out[r] = pk[o_hold + B + r * NB]
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
    o = o_hold + 2 * B + i * B
    for r in range(REF_SIZE):
        b = o + r * NB
        acc = 0.0
        acc += pk[b] * 1.0
        acc += pk[b + 1] * k1
        acc += pk[b + 2] * k2
        acc += pk[b + 3] * k3
        acc += pk[b + 4] * k4
        acc += pk[b + 5] * k5
        acc += pk[b + 6] * sd
        acc += pk[b + 7] * sdd
        out[r] = acc


@jit
def _sat(x: float, lim: float) -> float:
    return lim if x > lim else (-lim if x < -lim else x)


@jit
def pose_step(ps, rd, p, v, R, w, f_hat, m_hat, dt: float) -> None:
    """One step of the pose controller (:class:`omnirotor.control.pose.PoseController`), in place.

    Args:
        ps: the controller's packed state (``POSE_*``); ``w_ref`` and the errors are written there.
        rd: (24,) body reference (:class:`ReferenceSample` layout).
        p: (3,) position [m].
        v: (3,) velocity [m/s].
        R: (3, 3) ``R_WB``.
        w: (3,) ``omega_B`` [rad/s].
        f_hat: (3,) estimated external force [N], world frame.
        m_hat: (3,) estimated external moment [N·m], body frame.
        dt: period [s].
    """
    m, g = ps[POSE_MASS], ps[POSE_GRAVITY]
    jx, jy, jz = ps[POSE_J], ps[POSE_J + 1], ps[POSE_J + 2]
    lim_p, lim_v, lim_i = ps[POSE_LIM_P], ps[POSE_LIM_V], ps[POSE_LIM_I]
    px, py, pz = p[0], p[1], p[2]
    vx, vy, vz = v[0], v[1], v[2]
    r00, r01, r02 = R[0, 0], R[0, 1], R[0, 2]
    r10, r11, r12 = R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22 = R[2, 0], R[2, 1], R[2, 2]
    wx, wy, wz = w[0], w[1], w[2]
    fhx, fhy, fhz = f_hat[0], f_hat[1], f_hat[2]
    mhx, mhy, mhz = m_hat[0], m_hat[1], m_hat[2]
    # --- translation (world frame)
    epx = _sat(rd[0] - px, lim_p)
    epy = _sat(rd[1] - py, lim_p)
    epz = _sat(rd[2] - pz, lim_p)
    evx = _sat(rd[3] - vx, lim_v)
    evy = _sat(rd[4] - vy, lim_v)
    evz = _sat(rd[5] - vz, lim_v)
    E = POSE_EI
    eix = ps[E] = _sat(ps[E] + epx * dt, lim_i)
    eiy = ps[E + 1] = _sat(ps[E + 1] + epy * dt, lim_i)
    eiz = ps[E + 2] = _sat(ps[E + 2] + epz * dt, lim_i)
    c = ps[POSE_COMP]
    kp, kv, ki = POSE_KP, POSE_KV, POSE_KI
    fx = m * (rd[6] + ps[kp] * epx + ps[kv] * evx + ps[ki] * eix) - c * fhx
    fy = m * (rd[7] + ps[kp + 1] * epy + ps[kv + 1] * evy + ps[ki + 1] * eiy) - c * fhy
    fz = m * (rd[8] + g + ps[kp + 2] * epz + ps[kv + 2] * evz + ps[ki + 2] * eiz) - c * fhz
    # --- rotation (body frame): E = R^T R^r, e_R = 1/2 (E - E^T)^v
    q00, q01, q02, q10, q11, q12, q20, q21, q22 = rd[9], rd[10], rd[11], rd[12], rd[13], rd[14], rd[15], rd[16], rd[17]
    e01 = r00 * q01 + r10 * q11 + r20 * q21
    e02 = r00 * q02 + r10 * q12 + r20 * q22
    e10 = r01 * q00 + r11 * q10 + r21 * q20
    e12 = r01 * q02 + r11 * q12 + r21 * q22
    e20 = r02 * q00 + r12 * q10 + r22 * q20
    e21 = r02 * q01 + r12 * q11 + r22 * q21
    eRx = 0.5 * (e21 - e12)
    eRy = 0.5 * (e02 - e20)
    eRz = 0.5 * (e10 - e01)
    # R^T omega^r_W and R^T alpha^r_W
    ox, oy, oz, ax, ay, az = rd[18], rd[19], rd[20], rd[21], rd[22], rd[23]
    ewx = r00 * ox + r10 * oy + r20 * oz - wx
    ewy = r01 * ox + r11 * oy + r21 * oz - wy
    ewz = r02 * ox + r12 * oy + r22 * oz - wz
    ff = ps[POSE_FF]
    kR, kw = POSE_KR, POSE_KW
    dwx = ps[kR] * eRx + ps[kw] * ewx + ff * (r00 * ax + r10 * ay + r20 * az)
    dwy = ps[kR + 1] * eRy + ps[kw + 1] * ewy + ff * (r01 * ax + r11 * ay + r21 * az)
    dwz = ps[kR + 2] * eRz + ps[kw + 2] * ewz + ff * (r02 * ax + r12 * ay + r22 * az)
    hx, hy, hz = jx * wx, jy * wy, jz * wz  # J omega
    W = POSE_W_REF
    ps[W], ps[W + 1], ps[W + 2] = fx, fy, fz
    ps[W + 3] = wy * hz - wz * hy + jx * dwx - c * mhx
    ps[W + 4] = wz * hx - wx * hz + jy * dwy - c * mhy
    ps[W + 5] = wx * hy - wy * hx + jz * dwz - c * mhz
    er = POSE_ERRORS
    ps[er], ps[er + 1], ps[er + 2] = epx, epy, epz
    ps[er + 3], ps[er + 4], ps[er + 5] = evx, evy, evz
    ps[er + 6], ps[er + 7], ps[er + 8] = eRx, eRy, eRz
    ps[er + 9], ps[er + 10], ps[er + 11] = ewx, ewy, ewz


@jit
def alloc_prepare(al, w_ref, R, A) -> int:
    """Body-frame reference and the QP's linear term ``f = G w_B`` (:meth:`Allocator.solve`).

    Returns:
        ``PRE_MAP_CHANGED`` when ``A`` differs from the map the QP was built for (nothing computed; rebuild,
        then call again), ``PRE_ALLOC_NONFINITE`` when ``f`` is not finite, else ``PRE_OK``.
    """
    n = A.shape[1]
    o_f, o_key, o_G = 7, 7 + n, 7 + 7 * n
    for r in range(6):
        for j in range(n):
            if A[r, j] != al[o_key + r * n + j]:
                return PRE_MAP_CHANGED
    W = ALLOC_W_B
    for j in range(3):
        al[W + j] = w_ref[0] * R[0, j] + w_ref[1] * R[1, j] + w_ref[2] * R[2, j]  # R^T f_ref
    for j in range(3, 6):
        al[W + j] = w_ref[j]
    ff = 0.0
    for i in range(n):
        acc = 0.0
        for k in range(6):
            acc += al[o_G + 6 * i + k] * al[W + k]
        al[o_f + i] = acc
        ff += acc * acc
    if not math.isfinite(ff):  # a NaN/inf anywhere in w_ref or R reaches f (0 * inf is NaN too)
        return PRE_ALLOC_NONFINITE
    return PRE_OK


@jit
def alloc_finish(al, x, mode: int) -> int:
    """Clip the QP's answer ``x`` (scaled) to the bounds, scale it to u [Hz²] and flag saturation.

    Args:
        al: the allocator's packed state.
        x: (n,) the solution in scaled units.
        mode: ``FINISH_QP`` (reject a non-finite x) or ``FINISH_FALLBACK``.

    Returns:
        -1 when ``mode`` is ``FINISH_QP`` and x is not finite (nothing written), else 1 if some active rotor
        is at a bound, 0 if not. ``u`` and ``u_safe`` are written.
    """
    n = x.shape[0]
    o_lo = 7 + 13 * n
    o_hi, o_lo_sat, o_hi_sat, o_u, o_u_safe = o_lo + n, o_lo + 2 * n, o_lo + 3 * n, o_lo + 4 * n, o_lo + 5 * n
    if mode == FINISH_QP and not _all_finite(x):
        return -1
    scale = al[ALLOC_SCALE]
    saturated = 0
    for i in range(n):
        xi = x[i]
        if xi < al[o_lo + i]:
            xi = al[o_lo + i]
        elif xi > al[o_hi + i]:
            xi = al[o_hi + i]
        if xi <= al[o_lo_sat + i] or xi >= al[o_hi_sat + i]:
            saturated = 1
        u = xi * scale
        al[o_u + i] = u
        al[o_u_safe + i] = u
    return saturated


# -- the controller ------------------------------------------------------------------------------------------------


@jit
def pack_inputs(ws, p, v, a, R, w, rotor_hz, measured: bool) -> bool:
    """Copy the estimate into the controller's head and, with ``measured``, ``u_obs = |omega| omega``.

    Returns:
        True when the estimate (and the measured rotor speeds, with ``measured``) are finite.
    """
    if not pack_state(p, v, a, R, w, ws, CTL_EST):
        return False
    if measured:
        n = rotor_hz.shape[0]
        for i in range(n):
            ws[CTL_U_OBS + i] = abs(rotor_hz[i]) * rotor_hz[i]
        return _all_finite(ws[CTL_U_OBS : CTL_U_OBS + n])
    return True


@jit
def controller_pre(
    st, arena, p, v, a, R, w, rotor_hz, measured: bool, packed: bool, A, traj, t: float, dt: float
) -> int:  # fmt: skip
    """Everything of a control period before the QP (:meth:`InteractionController.step`, steps 3-6).

    Packs the inputs (:func:`pack_inputs`, unless ``packed`` says it was done) and checks them finite, then
    runs the observer, the EE wrench, the admittance filter, the trajectory, the compliant and body
    references, the pose controller and the QP's linear term. With a non-finite input nothing is updated.

    Args:
        st: the controller's state record (its blocks' states as fields: ``st.observer``).
        arena: the controller's array (:func:`controller_layout`).
        p: (3,) estimated position [m].
        v: (3,) velocity [m/s].
        a: (3,) acceleration [m/s²].
        R: (3, 3) attitude ``R_WB``.
        w: (3,) angular velocity ``omega_B`` [rad/s].
        rotor_hz: (n,) measured rotor speeds [Hz].
        measured: the observer takes the measured speeds (else the last command).
        packed: :func:`pack_inputs` was already called on these inputs.
        A: (6, n) the wrench map in use.
        traj: the packed trajectory (:attr:`PoseTrajectory.kernel_data`).
        t: trajectory time [s].
        dt: period [s].

    Returns:
        ``PRE_STATE_NONFINITE``, or the code of :func:`alloc_prepare`.
    """
    n = rotor_hz.shape[0]
    o_obs, o_adm, o_pose, o_des, o_comp, o_body, o_alloc, size = controller_layout(n)
    ws = arena[0:o_obs]
    if not packed and not pack_inputs(ws, p, v, a, R, w, rotor_hz, measured):
        return PRE_STATE_NONFINITE
    obs = st.observer
    adm = arena[o_adm:o_pose]
    ps = arena[o_pose:o_des]
    des = arena[o_des:o_comp]
    comp = arena[o_comp:o_body]
    body = arena[o_body:o_alloc]
    al = arena[o_alloc:size]
    o_u = CTL_U_OBS if measured else CTL_U_OBS + n  # u_obs, or the last command u_cmd
    observer_step(obs, A, ws[o_u : o_u + n], a, R, w, dt)
    f_E = ws[CTL_F_E : CTL_F_E + 3]
    m_E = ws[CTL_M_E : CTL_M_E + 3]
    p_E_B = ws[CTL_P_E_B : CTL_P_E_B + 3]
    ee_wrench(obs.output[0:3], obs.output[3:6], R, p_E_B, f_E, m_E)
    admittance_step(adm, f_E, m_E, dt)
    trajectory_sample(traj, t, des)
    compliant_reference(adm, des, comp)
    body_reference(comp, p_E_B, body)
    # The pose controller compensates the whole unexplained wrench (before bias and zeroing).
    pose_step(ps, body, p, v, R, w, obs.filtered[0:3], obs.filtered[3:6], dt)
    return alloc_prepare(al, ps[POSE_W_REF : POSE_W_REF + 6], R, A)


@jit
def write_log_row(row, ws, comp, des, adm, obs_output, ps) -> None:
    """One controller log row (:data:`omnirotor.control.controller.LOG_GROUPS`) from the blocks' buffers."""
    n = (row.shape[0] - CTL_HEAD_SIZE - 2 * REF_SIZE - 3 - 6 - 18) // 2
    k = 0
    for i in range(CTL_HEAD_SIZE):
        row[k] = ws[i]
        k += 1
    for i in range(REF_SIZE):
        row[k] = comp[i]
        k += 1
    for i in range(REF_SIZE):
        row[k] = des[i]
        k += 1
    for i in range(3):
        row[k] = adm[ADM_XI_P + i]
        k += 1
    for i in range(6):
        row[k] = obs_output[i]
        k += 1
    for i in range(18):
        row[k] = ps[POSE_W_REF + i]  # w_ref (6) then the errors (12)
        k += 1
    o = CTL_U_OBS + n
    for i in range(2 * n):  # u_cmd, omega_cmd
        row[k] = ws[o + i]
        k += 1


@jit
def controller_post(st, arena, x, mode: int, saturated_before: bool, bits: int, region: float, t: float, row) -> tuple:
    """Everything of a control period after the QP (:meth:`InteractionController.step`, step 7, and the log).

    Finishes the allocation (``mode``: ``FINISH_QP``, ``FINISH_FALLBACK``, or ``FINISH_HELD`` when the
    allocator held its last input), turns u into the speed command ``omega = sign(u) sqrt|u|`` clipped to the
    limits (the last safe command is held, flagged, should it not be finite), computes the EE tip, writes the
    head and, when ``row`` is not empty, the log row (:func:`write_log_row`).

    Args:
        st: the controller's state record.
        arena: the controller's array (:func:`controller_layout`).
        x: (n,) the QP's answer (ignored with ``FINISH_HELD``).
        mode: see above.
        saturated_before: the allocator's saturation flag of the last step (kept with ``FINISH_HELD``).
        bits: the ``ControlStatus`` bits known so far.
        region: the map region index.
        t: trajectory time [s].
        row: the log row to fill (length 0: none).

    Returns:
        ``(bits, saturated)``, or ``(-1, 0)`` when ``mode`` is ``FINISH_QP`` and x is not finite (nothing
        written: fall back, then call again).
    """
    n = x.shape[0]
    o_obs, o_adm, o_pose, o_des, o_comp, o_body, o_alloc, size = controller_layout(n)
    ws = arena[0:o_obs]
    al = arena[o_alloc:size]
    saturated = 1 if saturated_before else 0
    if mode != FINISH_HELD:
        saturated = alloc_finish(al, x, mode)
        if saturated < 0:
            return -1, 0
    if saturated:
        bits |= _BIT_SATURATED
    o_u = 7 + 17 * n
    o_ucmd = CTL_U_OBS + n
    o_cmd, o_safe = o_ucmd + n, o_ucmd + 2 * n
    lo, hi = ws[CTL_OMEGA_LO], ws[CTL_OMEGA_HI]
    finite = True
    for i in range(n):  # a first pass checks the clipped speeds, the second writes them (no array per call)
        u = al[o_u + i]
        om = math.copysign(math.sqrt(abs(u)), u)
        om = lo if om < lo else (hi if om > hi else om)
        if not math.isfinite(om):
            finite = False
    if finite:
        for i in range(n):
            u = al[o_u + i]
            om = math.copysign(math.sqrt(abs(u)), u)
            om = lo if om < lo else (hi if om > hi else om)
            ws[o_ucmd + i] = u
            ws[o_cmd + i] = om
            ws[o_safe + i] = om
    else:
        bits |= _BIT_NONFINITE
        for i in range(n):
            ws[o_cmd + i] = ws[o_safe + i]
    # Estimated EE tip, for the log.
    E, P = CTL_EST, CTL_P_E_B
    ex, ey, ez = ws[P], ws[P + 1], ws[P + 2]
    for i in range(3):
        ws[CTL_P_E + i] = ws[E + i] + ws[E + 9 + 3 * i] * ex + ws[E + 10 + 3 * i] * ey + ws[E + 11 + 3 * i] * ez
    ws[0], ws[1], ws[2] = t, region, bits
    if row.shape[0] > 0:
        write_log_row(
            row,
            ws,
            arena[o_comp:o_body],
            arena[o_des:o_comp],
            arena[o_adm:o_pose],
            st.observer.output,
            arena[o_pose:o_des],
        )
    return bits, saturated
