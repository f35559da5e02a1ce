"""Compiled helpers on the frame and estimate records of :mod:`omnirotor.messages`, for both sides of the loop.

The controller (:mod:`omnirotor.control`) and the simulator (:mod:`omnirotor.sim`) never import each other;
both read and write the records of :mod:`omnirotor.messages` (kept free of numba, so that a transport can
import it alone) through these kernels, written once.
"""

from __future__ import annotations

import math

from omnirotor._jit import jit

__all__ = ["clear_mocap", "clear_state", "copy_state", "copy_head", "state_finite"]


@jit
def clear_mocap(m) -> None:
    """No motion-capture sample in the :data:`~omnirotor.messages.MOCAP_DTYPE` record ``m`` (every entry 0)."""
    m.new = 0.0
    m.t = 0.0
    for j in range(3):
        m.p_W[j] = 0.0
    for j in range(4):
        m.q_WB[j] = 0.0


@jit
def clear_state(s) -> None:
    """No state in the :data:`~omnirotor.messages.ESTIMATE_DTYPE` record ``s`` (every entry 0)."""
    s.valid = 0.0
    for i in range(3):
        s.p_W[i] = 0.0
        s.v_W[i] = 0.0
        s.a_W[i] = 0.0
        s.omega_B[i] = 0.0
        for j in range(3):
            s.R_WB[i, j] = 0.0


@jit
def copy_state(src, dst) -> None:
    """Copy the :data:`~omnirotor.messages.ESTIMATE_DTYPE` record ``src`` into ``dst``."""
    dst.valid = src.valid
    for i in range(3):
        dst.p_W[i] = src.p_W[i]
        dst.v_W[i] = src.v_W[i]
        dst.a_W[i] = src.a_W[i]
        dst.omega_B[i] = src.omega_B[i]
        for j in range(3):
            dst.R_WB[i, j] = src.R_WB[i, j]


@jit
def state_finite(s) -> bool:
    """True if every entry of the state record ``s`` (position, velocity, acceleration, attitude, rate) is finite."""
    for i in range(3):
        if not (
            math.isfinite(s.p_W[i])
            and math.isfinite(s.v_W[i])
            and math.isfinite(s.a_W[i])
            and math.isfinite(s.omega_B[i])
            and math.isfinite(s.R_WB[i, 0])
            and math.isfinite(s.R_WB[i, 1])
            and math.isfinite(s.R_WB[i, 2])
        ):
            return False
    return True


@jit
def copy_head(src, dst) -> None:
    """Copy a frame's time, IMU, motion capture and state (not its rotor speeds) from ``src`` into ``dst``.

    ``dst`` is a frame record or a :data:`~omnirotor.messages.FRAME_HEAD_DTYPE` record.
    """
    dst.t = src.t
    for i in range(3):
        dst.imu.acc_B[i] = src.imu.acc_B[i]
        dst.imu.gyro_B[i] = src.imu.gyro_B[i]
    m, n = src.mocap, dst.mocap
    n.new = m.new
    n.t = m.t
    for j in range(3):
        n.p_W[j] = m.p_W[j]
    for j in range(4):
        n.q_WB[j] = m.q_WB[j]
    copy_state(src.state, dst.state)
