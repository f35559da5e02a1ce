"""The truth contact wrench on the end-effector, from the model's EE contact sensors (SPEC §7, §2).

Each EE geom (tip, rod) carries a MuJoCo contact sensor (``reduce="netforce"``, :mod:`omnirotor.sim.model`)
giving the number of its contacts and the net force and torque they exert *from* the geom on the
environment about their force-weighted centroid, in the world frame. The truth is the reaction on the EE
and its moment about the EE tip ``p_E_W``; the EE touches when any sensor found a contact.

The block (:class:`EeContact`, registered as ``("contact", "ee-sensors")``) owns its parameters (the
sensors' addresses in ``sensordata``, :data:`PARAMS_DTYPE`), its output record (:data:`STATE_DTYPE`) and the
compiled step (:func:`contact_wrench`), the one algorithm of the truth contact wrench. :func:`other_contact`
tells whether another part of the vehicle touches the environment (no wrench).
"""

from __future__ import annotations

import mujoco
import numpy as np

from omnirotor._jit import jit
from omnirotor.blocks import register
from omnirotor.sim.model import EE_ROD_GEOM, EE_TIP_GEOM, ee_contact_sensor

__all__ = ["EeContact", "contact_wrench", "other_contact", "PARAMS_DTYPE", "STATE_DTYPE", "SENSOR_SIZE"]

SENSOR_SIZE = 10
"""Entries of one EE contact sensor: contacts found, net force (3) [N], torque (3) [N·m], centroid (3) [m]."""
_EE_GEOMS = (EE_TIP_GEOM, EE_ROD_GEOM)

PARAMS_DTYPE = np.dtype([("sensor_adr", np.int64, (len(_EE_GEOMS),))])
"""Addresses of the EE contact sensors in ``sensordata`` (-1: that geom is absent)."""
STATE_DTYPE = np.dtype([("f_W", np.float64, (3,)), ("m_W", np.float64, (3,)), ("in_contact", np.bool_)])
"""The last wrench: force on the EE [N], its moment about the tip [N·m], world frame; whether it touches."""


@jit
def contact_wrench(par, sensordata, p_E_W, f_W, m_W) -> bool:
    """Add the environment's contact wrench on the end-effector into ``f_W`` and ``m_W`` (3,) each.

    Args:
        par: a :data:`PARAMS_DTYPE` record.
        sensordata: MuJoCo's ``sensordata``.
        p_E_W: (3,) the EE tip [m], the moment's reference point.
        f_W: (3,) force [N], added to.
        m_W: (3,) moment about ``p_E_W`` [N·m], added to.

    Returns:
        True when any EE geom touches the environment.
    """
    touching = False
    adr = par["sensor_adr"]
    for s in range(adr.shape[0]):
        a = adr[s]
        if a < 0 or sensordata[a] <= 0.0:
            continue
        touching = True
        fx, fy, fz = -sensordata[a + 1], -sensordata[a + 2], -sensordata[a + 3]
        rx = sensordata[a + 7] - p_E_W[0]
        ry = sensordata[a + 8] - p_E_W[1]
        rz = sensordata[a + 9] - p_E_W[2]
        f_W[0] += fx
        f_W[1] += fy
        f_W[2] += fz
        m_W[0] += -sensordata[a + 4] + ry * fz - rz * fy
        m_W[1] += -sensordata[a + 5] + rz * fx - rx * fz
        m_W[2] += -sensordata[a + 6] + rx * fy - ry * fx
    return touching


def other_contact(data: mujoco.MjData, robot_geom: np.ndarray, ee_geom: np.ndarray) -> bool:
    """True when a vehicle geom other than the end-effector's touches the environment.

    Args:
        data: MuJoCo's data (after ``mj_forward``).
        robot_geom: (ngeom,) bool, the vehicle's geoms.
        ee_geom: (ngeom,) bool, the end-effector's geoms.
    """
    for c in range(data.ncon):
        g1, g2 = data.contact.geom1[c], data.contact.geom2[c]
        r1, r2 = robot_geom[g1], robot_geom[g2]
        if r1 != r2 and not ee_geom[g1 if r1 else g2]:
            return True
    return False


@register("contact", "ee-sensors")
class EeContact:
    """The end-effector's contact wrench from the model's EE contact sensors (module docstring).

    Args:
        model: the MuJoCo model (built by :func:`omnirotor.sim.model.build_mjcf`).
        par: (1,) :data:`PARAMS_DTYPE` record to live in (default: its own).
        state: (1,) :data:`STATE_DTYPE` record to live in (default: its own).
    """

    state_dtype = STATE_DTYPE
    params_dtype = PARAMS_DTYPE
    log_fields = ("f_W", "m_W", "in_contact")

    def __init__(self, model: mujoco.MjModel, par: np.ndarray | None = None, state: np.ndarray | None = None) -> None:
        self.par = np.zeros(1, PARAMS_DTYPE) if par is None else par
        self.state = np.zeros(1, STATE_DTYPE) if state is None else state
        for i, geom in enumerate(_EE_GEOMS):
            sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, ee_contact_sensor(geom))
            self.par["sensor_adr"][0, i] = int(model.sensor_adr[sid]) if sid >= 0 else -1

    def reset(self) -> None:
        """Clear the last wrench."""
        self.state[0] = 0

    def step(self, sensordata: np.ndarray, p_E_W: np.ndarray) -> None:
        """The contact wrench of MuJoCo's current ``sensordata`` into :attr:`state`."""
        s = self.state[0]
        s["f_W"], s["m_W"] = 0.0, 0.0
        s["in_contact"] = contact_wrench(
            self.par[0], sensordata, np.asarray(p_E_W, dtype=np.float64), self.state["f_W"][0], self.state["m_W"][0]
        )
