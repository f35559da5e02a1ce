"""Numba set-up shared by the compiled kernels of the 1 kHz loop (``control/_kernels.py``, ``sim/_kernels.py``).

Every kernel is compiled with :data:`jit`: ``nopython``, ``cache=True`` (machine code is kept in the
``__pycache__`` folder next to the module, so only the first import on a machine compiles), ``fastmath=False``
(IEEE arithmetic in the order written, so a kernel reproduces the NumPy / Python float reference it replaces to
the last bit or within a rounding) and NumPy's error model (a division by zero gives inf or NaN as in NumPy;
it never raises inside the loop). Kernels are compiled lazily, on their first call.

Set ``NUMBA_DISABLE_JIT=1`` to run every kernel as plain Python (debugging, coverage).

The few SO(3) helpers both kernel modules need live here, as the simulator and the controller must not
import each other. They follow the conventions of :mod:`omnirotor.so3` (quaternions wxyz, Hamilton).
"""

from __future__ import annotations

import numba

__all__ = ["jit", "R9_from_quat_into"]

jit = numba.njit(cache=True, fastmath=False, error_model="numpy")
"""The decorator of every kernel (see the module docstring)."""


@jit
def R9_from_quat_into(qw: float, qx: float, qy: float, qz: float, out, o: int) -> None:
    """Write the row-major rotation matrix of the unit quaternion ``(qw, qx, qy, qz)`` into ``out[o:o+9]``.

    Same arithmetic as :func:`omnirotor.sim.sensors.R9_from_quat`.
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
