"""PX4's frames and ours (SPEC §1.1).

PX4 writes positions and velocities in a local NED world frame (x north, y east, z down), body vectors in FRD
(x forward, y right, z down), and attitudes as quaternions ``q = (w, x, y, z)`` rotating FRD body vectors into
NED (``R_NF``). Ours: a z-up world frame W and a body frame B. We take

* W = NED rotated by π about its x axis: x north, y west, z up (NWU);
* B = FRD rotated by π about its x axis: x forward, y left, z up (FLU);

so both conversions are the same proper rotation ``D = diag(1, -1, -1)``, its own inverse: ``v_W = D v_NED``,
``v_B = D v_FRD`` and ``R_WB = D R_NF D``. Cross products (rotor moments) keep their form under ``D``.
"""

from __future__ import annotations

import numpy as np

from omnirotor.so3 import R_from_quat_wxyz, quat_wxyz_from_R

__all__ = ["D_FLIP", "vec_from_px4", "R_WB_from_px4_quat", "px4_quat_from_R_WB", "quat_wxyz_of"]

D_FLIP = np.diag([1.0, -1.0, -1.0])
"""Rotation by π about x: NED → NWU (world) and FRD → FLU (body); ``D_FLIP @ D_FLIP = I``."""


def vec_from_px4(v: np.ndarray) -> np.ndarray:
    """(..., 3) vectors from NED (world) or FRD (body) to our z-up world or FLU body; also the inverse."""
    out = np.array(v, dtype=float, copy=True)
    out[..., 1:] *= -1.0
    return out


def R_WB_from_px4_quat(q_wxyz: np.ndarray) -> np.ndarray:
    """(N, 3, 3) ``R_WB`` from (N, 4) PX4 quaternions (w, x, y, z, FRD → NED); normalises each.

    With ``D = diag(1, -1, -1)``, ``R_WB = D R_NF D``; in quaternion terms (w, x, -y, -z).
    """
    q = np.array(np.atleast_2d(q_wxyz), dtype=float)
    q[:, 2:] *= -1.0
    return np.array([R_from_quat_wxyz(qi) for qi in q]).reshape(-1, 3, 3)


def px4_quat_from_R_WB(R_WB: np.ndarray) -> np.ndarray:
    """(N, 4) PX4 quaternions (w, x, y, z, FRD → NED, w >= 0) of (N, 3, 3) attitudes ``R_WB``."""
    q = quat_wxyz_of(R_WB)
    q[:, 2:] *= -1.0  # the inverse of R_WB_from_px4_quat: (w, x, y, z) -> (w, x, -y, -z)
    return q


def quat_wxyz_of(R: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions (w, x, y, z; w >= 0) of (N, 3, 3) rotation matrices (same frames)."""
    Rs = np.asarray(R, dtype=float).reshape(-1, 3, 3)
    return np.array([quat_wxyz_from_R(r) for r in Rs]).reshape(-1, 4)
