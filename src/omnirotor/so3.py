"""Tiny pure functions on SO(3), named target-from-source.

Conventions fixed here once for the whole project:

* ``R_WB`` maps body coordinates to world coordinates: ``v_W = R_WB @ v_B``.
* Quaternions are Hamilton, scalar first (``wxyz``), as MuJoCo stores them. SciPy uses ``xyzw``;
  convert only through :func:`quat_wxyz_from_xyzw` / :func:`quat_xyzw_from_wxyz`.
* Roll-pitch-yaw means the ZYX convention ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (SPEC §3.1).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
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
