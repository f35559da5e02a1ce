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

__all__ = ["D_FLIP", "vec_from_px4", "quat_from_px4", "R_WB_from_px4_quat", "px4_quat_from_R_WB", "quat_wxyz_of"]

D_FLIP = np.diag([1.0, -1.0, -1.0])
"""Rotation by π about x: NED → NWU (world) and FRD → FLU (body); ``D_FLIP @ D_FLIP = I``."""


def _flip_last(v: np.ndarray, k: int, out: np.ndarray | None) -> np.ndarray:
    """``v`` (float64, into ``out`` when given) with its last ``k`` entries on the last axis negated: ``D``'s action."""
    if out is None:
        out = np.array(v, dtype=float, copy=True)
    else:
        out[...] = v
    out[..., -k:] *= -1.0
    return out


def vec_from_px4(v: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """(..., 3) vectors from NED (world) or FRD (body) to our z-up world or FLU body; also the inverse.

    Args:
        v: the vectors (any float type: PX4's messages carry float32).
        out: optional float64 array of the same shape to write into (a 1 kHz path allocates nothing).
    """
    return _flip_last(v, 2, out)


def quat_from_px4(q_wxyz: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """(..., 4) quaternions ``q_WB`` (w, x, y, z) of PX4's (FRD body -> NED world); also the inverse.

    ``R_WB = D R_NF D`` is the rotation conjugated by ``D`` (a rotation by π about x), which turns the quaternion's
    vector part by ``D``: (w, x, y, z) -> (w, x, -y, -z). Not normalised (a consumer judges the norm). ``out`` as
    in :func:`vec_from_px4`.
    """
    return _flip_last(q_wxyz, 2, out)


def R_WB_from_px4_quat(q_wxyz: np.ndarray) -> np.ndarray:
    """(N, 3, 3) ``R_WB`` from (N, 4) PX4 quaternions (w, x, y, z, FRD → NED); normalises each.

    With ``D = diag(1, -1, -1)``, ``R_WB = D R_NF D``; in quaternion terms (w, x, -y, -z).
    """
    q = quat_from_px4(np.atleast_2d(q_wxyz))
    return np.array([R_from_quat_wxyz(qi) for qi in q]).reshape(-1, 3, 3)


def px4_quat_from_R_WB(R_WB: np.ndarray) -> np.ndarray:
    """(N, 4) PX4 quaternions (w, x, y, z, FRD → NED, w >= 0) of (N, 3, 3) attitudes ``R_WB``."""
    return quat_from_px4(quat_wxyz_of(R_WB))  # its own inverse


def quat_wxyz_of(R: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions (w, x, y, z; w >= 0) of (N, 3, 3) rotation matrices (same frames)."""
    Rs = np.asarray(R, dtype=float).reshape(-1, 3, 3)
    return np.array([quat_wxyz_from_R(r) for r in Rs]).reshape(-1, 4)
