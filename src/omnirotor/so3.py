"""Tiny pure functions on SO(3), named target-from-source.

Conventions fixed here once for the whole project:

* ``R_WB`` maps body coordinates to world coordinates: ``v_W = R_WB @ v_B``.
* Quaternions are Hamilton, scalar first (``wxyz``), as MuJoCo stores them. SciPy uses ``xyzw``;
  convert only through :func:`quat_wxyz_from_xyzw` / :func:`quat_xyzw_from_wxyz`.
* Roll-pitch-yaw means the ZYX convention ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (SPEC §3.1).

Two families live here, once each for the whole package:

* NumPy functions (:func:`exp_so3`, :func:`R_from_quat_wxyz`, ...) for set-up, analysis and tests;
* compiled helpers for the 1 kHz kernels of the controller and the simulator (:func:`quat_mul`,
  :func:`quat_integrate_body_into`, :func:`quat_integrate_world_into`, :func:`R9_from_quat_into`,
  :func:`R_from_quat_into`, :func:`exp_so3_at`, :func:`log_so3_at`, :func:`quat_perturb_into`). They take and
  return scalars or write into caller-owned arrays (nothing allocated), and keep the operation order of the
  kernels they replaced, so the controller reproduces its recorded reference bit for bit
  (``tests/test_controller_reference.py``). Rotation increments follow SPEC §4.4 (the admittance filter's
  ``R_xi <- exp([omega_xi dt]x) R_xi``, world frame) and SPEC §4.5 (the estimator's attitude ``q <- q ⊗ Exp(omega dt)``,
  body frame).

This module imports nothing of the package (it sits at the ground floor: the controller and the simulator both
use it and must not import each other). Its compiled helpers are plain ``numba.njit`` functions with the
package's numeric settings (IEEE arithmetic in the order written, NumPy's error model); a kernel that calls them
compiles them into itself, and the kernel's cache key covers this file (``omnirotor._jit``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "quat_mul",
    "quat_of_rotvec",
    "quat_integrate_body_into",
    "quat_integrate_world_into",
    "quat_perturb_into",
    "R9_from_quat_into",
    "R_from_quat_into",
    "exp_so3_at",
    "exp_so3_into",
    "log_so3_at",
    "log_so3_into",
    "hat",
    "vee",
    "rot_x",
    "rot_y",
    "rot_z",
    "exp_so3",
    "log_so3",
    "quat_wxyz_from_xyzw",
    "quat_xyzw_from_wxyz",
    "R_from_quat_wxyz",
    "quat_wxyz_from_R",
    "R_from_rpy",
    "rpy_from_R",
    "project_to_SO3",
]


def hat(a: np.ndarray) -> np.ndarray:
    """Skew matrix ``[a]x`` of a 3-vector, so that ``hat(a) @ b == cross(a, b)``.

    Args:
        a: (3,) vector.

    Returns:
        (3, 3) skew-symmetric matrix.
    """
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def vee(S: np.ndarray) -> np.ndarray:
    """Inverse of :func:`hat`: the 3-vector of a (3, 3) skew matrix (its skew part is used)."""
    return np.array([S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]]) * 0.5


def rot_x(theta: float) -> np.ndarray:
    """Elementary rotation about x by ``theta`` [rad]: ``rot_x(t) @ e3 = (0, -sin t, cos t)``."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(theta: float) -> np.ndarray:
    """Elementary rotation about y by ``theta`` [rad]: ``rot_y(t) @ e3 = (sin t, 0, cos t)``."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(theta: float) -> np.ndarray:
    """Elementary rotation about z by ``theta`` [rad]."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def exp_so3(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``phi`` [rad] (Rodrigues)."""
    theta = math.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    K = hat(phi)
    if theta < 1e-8:
        return np.eye(3) + K + 0.5 * (K @ K)
    return np.eye(3) + (math.sin(theta) / theta) * K + ((1.0 - math.cos(theta)) / theta**2) * (K @ K)


def log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vector [rad] of a rotation matrix; inverse of :func:`exp_so3` for angles below pi."""
    c = max(-1.0, min(1.0, 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)))
    theta = math.acos(c)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if theta < 1e-6:
        return 0.5 * w
    if math.pi - theta < 1e-4:
        # Near pi: take the axis from the symmetric part.
        B = 0.5 * (R + np.eye(3))
        axis = np.sqrt(np.clip(np.diag(B), 0.0, None))
        i = int(np.argmax(axis))
        axis = B[:, i] / math.sqrt(max(B[i, i], 1e-300))
        if w @ axis < 0:
            axis = -axis
        return theta * axis / np.linalg.norm(axis)
    return (theta / (2.0 * math.sin(theta))) * w


def quat_wxyz_from_xyzw(q: np.ndarray) -> np.ndarray:
    """Reorder a scalar-last quaternion (SciPy) to scalar-first (MuJoCo, this project)."""
    q = np.asarray(q, dtype=float)
    return np.concatenate([q[..., 3:4], q[..., 0:3]], axis=-1)


def quat_xyzw_from_wxyz(q: np.ndarray) -> np.ndarray:
    """Reorder a scalar-first quaternion to scalar-last."""
    q = np.asarray(q, dtype=float)
    return np.concatenate([q[..., 1:4], q[..., 0:1]], axis=-1)


def R_from_quat_wxyz(q: np.ndarray) -> np.ndarray:
    """Rotation matrix ``R_WB`` of a unit quaternion ``q_WB`` (wxyz, Hamilton); normalises first."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_wxyz_from_R(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (wxyz, w >= 0) of a rotation matrix (Shepperd's method)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = np.array([(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s])
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = np.array([(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s])
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = np.array([(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s])
    if q[0] < 0:
        q = -q
    return q / np.linalg.norm(q)


def R_from_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """``R_WB = Rz(yaw) Ry(pitch) Rx(roll)`` from angles [rad] (ZYX)."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def rpy_from_R(R: np.ndarray) -> np.ndarray:
    """ZYX angles (roll, pitch, yaw) [rad] of ``R_WB``; inverse of :func:`R_from_rpy` away from gimbal lock."""
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    roll = math.atan2(R[2, 1], R[2, 2])
    yaw = math.atan2(R[1, 0], R[0, 0])
    return np.array([roll, pitch, yaw])


def project_to_SO3(M: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix to ``M`` (SVD), to undo drift after integration."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.linalg.det(U @ Vt)])
    return U @ D @ Vt


# -- compiled helpers of the 1 kHz kernels ----------------------------------------------------------------------

# Without numba's C-pointer wrapper (``no_cfunc_wrapper``, as the package's kernels, ``omnirotor._jit``): nothing
# calls these through a C pointer, and the wrapper would be optimised and emitted again in every kernel linking one.
_kernel = numba.njit(cache=True, fastmath=False, error_model="numpy", no_cfunc_wrapper=True)
_inline = numba.njit(cache=True, fastmath=False, error_model="numpy", inline="always", no_cfunc_wrapper=True)


@_kernel
def quat_mul(aw: float, ax: float, ay: float, az: float, bw: float, bx: float, by: float, bz: float):
    """Hamilton product ``a ⊗ b`` of two wxyz quaternions given as scalars; returns ``(w, x, y, z)``."""
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@_kernel
def quat_of_rotvec(px: float, py: float, pz: float):
    """Unit quaternion ``Exp(p)`` of the rotation vector ``p`` [rad]: ``(cos(th/2), sin(th/2) p / th)``.

    Below ``th = 1e-12`` the series ``(1 - th²/8, (1/2 - th²/48) p)``, equal to the closed form there in double
    precision.
    """
    th2 = px * px + py * py + pz * pz
    if th2 > 1e-24:
        th = math.sqrt(th2)
        c, k = math.cos(0.5 * th), math.sin(0.5 * th) / th
    else:
        c, k = 1.0 - th2 / 8.0, 0.5 - th2 / 48.0
    return c, k * px, k * py, k * pz


@_kernel
def quat_integrate_body_into(q, px: float, py: float, pz: float) -> None:
    """``q <- q ⊗ Exp(p)`` normalised, in place: ``q`` (4,) wxyz turned by the body-frame rotation vector ``p``.

    The estimator's attitude propagation over one IMU sample (``p = (omega_B - b_gyro) dt``, SPEC §4.5).
    """
    dw, dx, dy, dz = quat_of_rotvec(px, py, pz)
    nw, nx, ny, nz = quat_mul(q[0], q[1], q[2], q[3], dw, dx, dy, dz)
    inv = 1.0 / math.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
    q[0], q[1], q[2], q[3] = nw * inv, nx * inv, ny * inv, nz * inv


@_kernel
def quat_integrate_world_into(q, wx: float, wy: float, wz: float, dt: float) -> bool:
    """``q <- Exp(omega dt) ⊗ q`` normalised, in place: ``q`` (4,) wxyz turned by the world-frame rate ``omega``.

    ``omega`` [rad/s] over ``dt`` [s] (the admittance filter's ``R_xi <- exp([omega_xi dt]x) R_xi``, SPEC §4.4).
    Leaves ``q`` as it is and returns False when the angle is zero; True when it turned.
    """
    angle = math.sqrt(wx * wx + wy * wy + wz * wz) * dt
    if not angle > 0.0:
        return False
    sn = math.sin(0.5 * angle) / angle * dt
    qw, qx, qy, qz = quat_mul(math.cos(0.5 * angle), sn * wx, sn * wy, sn * wz, q[0], q[1], q[2], q[3])
    norm = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    q[0], q[1], q[2], q[3] = qw * norm, qx * norm, qy * norm, qz * norm
    return True


@_inline  # into its two callers (the simulator's motion capture): one compile, not one per caller's types
def quat_perturb_into(q, dtheta, out) -> None:
    """``q ⊗ [1, dtheta/2]`` normalised into ``out`` (4,): ``q`` (wxyz) turned by the small body rotation ``dtheta``.

    The first-order retraction of the simulated motion capture's attitude noise (written out, in the order the
    simulator's recorded runs were made with; :func:`quat_mul` with ``b = (1, dtheta/2)`` up to rounding).
    """
    qw, qx, qy, qz = q[0], q[1], q[2], q[3]
    a, b, c = 0.5 * dtheta[0], 0.5 * dtheta[1], 0.5 * dtheta[2]
    rw = qw - qx * a - qy * b - qz * c
    rx = qx + qw * a + qy * c - qz * b
    ry = qy + qw * b + qz * a - qx * c
    rz = qz + qw * c + qx * b - qy * a
    s = 1.0 / math.sqrt(rw * rw + rx * rx + ry * ry + rz * rz)
    out[0] = rw * s
    out[1] = rx * s
    out[2] = ry * s
    out[3] = rz * s


@_inline
def R9_from_quat_into(qw: float, qx: float, qy: float, qz: float, out, o: int) -> None:
    """Write the row-major rotation matrix of the unit quaternion ``(qw, qx, qy, qz)`` into ``out[o:o+9]``.

    The entries of :func:`R_from_quat_wxyz`, as scalars. Inlined into its callers: they pass constant offsets,
    for which numba would otherwise compile one version each.
    """
    xx, yy, zz = qx * qx, qy * qy, qz * qz
    xy, xz, yz = qx * qy, qx * qz, qy * qz
    wx, wy, wz = qw * qx, qw * qy, qw * qz
    out[o + 0] = 1.0 - 2.0 * (yy + zz)
    out[o + 1] = 2.0 * (xy - wz)
    out[o + 2] = 2.0 * (xz + wy)
    out[o + 3] = 2.0 * (xy + wz)
    out[o + 4] = 1.0 - 2.0 * (xx + zz)
    out[o + 5] = 2.0 * (yz - wx)
    out[o + 6] = 2.0 * (xz - wy)
    out[o + 7] = 2.0 * (yz + wx)
    out[o + 8] = 1.0 - 2.0 * (xx + yy)


@_kernel
def R_from_quat_into(q, R) -> None:
    """``R`` (3, 3), C-contiguous, = the rotation of the unit quaternion ``q`` (4,), wxyz."""
    R9_from_quat_into(q[0], q[1], q[2], q[3], R.flat, 0)  # R.flat: its row-major entries (no reshape)


@_kernel
def exp_so3_at(p0: float, p1: float, p2: float, out, o: int) -> None:
    """Rotation matrix of the rotation vector ``(p0, p1, p2)`` [rad] into ``out[o:o+9]``, row-major.

    Rodrigues, with series near 0: ``R = I + a K + b K²``, ``K = [phi]x``, ``a = sin(th)/th``,
    ``b = (1 - cos th)/th²``.
    """
    th2 = p0 * p0 + p1 * p1 + p2 * p2
    th = math.sqrt(th2)
    if th2 > 1e-8:  # below, the series to th² are exact in double precision
        a = math.sin(th) / th
        b = (1.0 - math.cos(th)) / th2
    else:
        a = 1.0 - th2 / 6.0
        b = 0.5 - th2 / 24.0
    # K = [[0, -p2, p1], [p2, 0, -p0], [-p1, p0, 0]]; R = (K K) b + K a + I, entry by entry.
    k01, k02, k10, k12, k20, k21 = -p2, p1, p2, -p0, -p1, p0
    out[o] = (0.0 * 0.0 + k01 * k10 + k02 * k20) * b + 0.0 * a + 1.0
    out[o + 1] = (0.0 * k01 + k01 * 0.0 + k02 * k21) * b + k01 * a
    out[o + 2] = (0.0 * k02 + k01 * k12 + k02 * 0.0) * b + k02 * a
    out[o + 3] = (k10 * 0.0 + 0.0 * k10 + k12 * k20) * b + k10 * a
    out[o + 4] = (k10 * k01 + 0.0 * 0.0 + k12 * k21) * b + 0.0 * a + 1.0
    out[o + 5] = (k10 * k02 + 0.0 * k12 + k12 * 0.0) * b + k12 * a
    out[o + 6] = (k20 * 0.0 + k21 * k10 + 0.0 * k20) * b + k20 * a
    out[o + 7] = (k20 * k01 + k21 * 0.0 + 0.0 * k21) * b + k21 * a
    out[o + 8] = (k20 * k02 + k21 * k12 + 0.0 * 0.0) * b + 0.0 * a + 1.0


@_kernel
def exp_so3_into(p0: float, p1: float, p2: float, R) -> None:
    """Rotation matrix of the rotation vector ``(p0, p1, p2)`` [rad] into C-contiguous R (3, 3); :func:`exp_so3_at`."""
    exp_so3_at(p0, p1, p2, R.flat, 0)


@_kernel
def log_so3_at(R, oR: int, out, o: int) -> None:
    """Rotation vector [rad] of the rotation ``R[oR:oR+9]`` (row-major) with angle below pi into ``out[o:o+3]``."""
    w0 = (R[oR + 7] - R[oR + 5]) * 0.5  # sin(th) * axis
    w1 = (R[oR + 2] - R[oR + 6]) * 0.5
    w2 = (R[oR + 3] - R[oR + 1]) * 0.5
    sn = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    th = math.atan2(sn, 0.5 * (R[oR] + R[oR + 4] + R[oR + 8] - 1.0))
    k = th / sn if sn > 1e-12 else 1.0
    out[o], out[o + 1], out[o + 2] = w0 * k, w1 * k, w2 * k


@_kernel
def log_so3_into(R, out, o: int) -> None:
    """Rotation vector [rad] of a rotation R (3, 3), C-contiguous, into ``out[o:o+3]`` (:func:`log_so3_at`)."""
    log_so3_at(R.flat, 0, out, o)
