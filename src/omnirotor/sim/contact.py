"""The truth contact wrench on the end-effector, from the model's EE contact sensors (SPEC §7, §2).

Each EE geom (tip, rod) carries a MuJoCo contact sensor (``reduce="netforce"``, :mod:`omnirotor.sim.model`)
giving the number of its contacts and the net force and torque they exert *from* the geom on the
environment about their force-weighted centroid, in the world frame. The truth is the reaction on the EE
and its moment about the EE tip ``p_E_W``; the EE touches when any sensor found a contact.

The block (:class:`EeContact`, registered as ``("contact", "ee-sensors")``) owns its parameters (the
sensors' addresses in ``sensordata``, :data:`PARAMS_DTYPE`), its output record (:data:`STATE_DTYPE`) and the
compiled step (:func:`contact_wrench`), the one algorithm of the truth contact wrench. :func:`other_contact`
tells whether another part of the vehicle touches the environment (no wrench).

**Friction of the compliant tool** (:data:`FRICTION_DTYPE`, :func:`friction_step`, docs/fidelity.md "Friction
as a force"). MuJoCo's friction cones are convex relaxations of Coulomb's law: a sliding contact gets a normal
separating acceleration of about mu times the friction rows' reference acceleration, which lifts the sliding
tip off the pipe for single steps (the chatter of issue 12). With the compliant tool the EE geoms' MuJoCo
contacts are frictionless (``condim`` 1) and Coulomb's law is applied here, as a force on the tool body, after
every physics step: per contact, the tangential force of the last step corrected by half of what would stop the
contact point within one step (from the tool's mass and the slip velocity it has and gained over the last step,
Jacobi-split over the contacts; stable for effective masses from 0.4 to any multiple of the tool's), capped at
mu times the contact's normal force (sliding: mu f_n against the slip). It sticks under any load inside the cone
and slides at mu f_n outside it, with no normal coupling. The truth wrench adds these forces.
"""

from __future__ import annotations

import mujoco
import numpy as np

from omnirotor._jit import f64_at, jit, jit_inline
from omnirotor.blocks import register
from omnirotor.sim.model import (
    EE_ROD_GEOM,
    EE_TIP_GEOM,
    FRICTION_SLOTS,
    TOOL_BODY,
    TOOL_SENSORS,
    ee_contact_sensor,
    ee_contacts_sensor,
)

__all__ = [
    "EeContact",
    "contact_wrench",
    "other_contact",
    "friction_step",
    "friction_reset",
    "PARAMS_DTYPE",
    "STATE_DTYPE",
    "FRICTION_DTYPE",
    "SENSOR_SIZE",
    "FRICTION_SLOTS",
    "FRICTION_SLOT_SIZE",
]

SENSOR_SIZE = 10
"""Entries of one EE contact sensor: contacts found, net force (3) [N], torque (3) [N·m], centroid (3) [m]."""
_EE_GEOMS = (EE_TIP_GEOM, EE_ROD_GEOM)

PARAMS_DTYPE = np.dtype([("sensor_adr", np.int64, (len(_EE_GEOMS),))])
"""Addresses of the EE contact sensors in ``sensordata`` (-1: that geom is absent)."""
STATE_DTYPE = np.dtype([("f_W", np.float64, (3,)), ("m_W", np.float64, (3,)), ("in_contact", np.bool_)])
"""The last wrench: force on the EE [N], its moment about the tip [N·m], world frame; whether it touches."""

FRICTION_SLOT_SIZE = 10
"""Entries of one contact in a per-contact sensor: contacts found, force (3, contact frame: normal first) [N],
position (3) [m], normal (3, from the EE geom into the surface)."""
_MATCH_M = 0.002
"""A contact continues one of the last step within this distance [m] (else it starts unloaded)."""

FRICTION_DTYPE = np.dtype(
    [
        ("enabled", np.bool_),
        ("mu", np.float64),  # Coulomb's coefficient
        ("mass", np.float64),  # the tool's mass [kg]: the contact point's effective mass across the normal
        ("h", np.float64),  # physics step [s]
        ("sensor_adr", np.int64, (len(_EE_GEOMS),)),  # per-contact sensors of the EE geoms (-1: absent)
        ("vel_adr", np.int64, (3,)),  # the tool body's linear velocity, angular velocity, origin (3 each)
        ("xfrc", np.int64),  # address of the tool body's xfrc_applied row (6)
        ("n", np.int64, (len(_EE_GEOMS),)),  # contacts of each geom at the last step
        ("pos", np.float64, (len(_EE_GEOMS), FRICTION_SLOTS, 3)),  # their positions [m]
        ("f", np.float64, (len(_EE_GEOMS), FRICTION_SLOTS, 3)),  # the friction force on the tool [N]
        ("v", np.float64, (len(_EE_GEOMS), FRICTION_SLOTS, 3)),  # the contact point's slip velocity [m/s]
        ("scratch", np.float64, (3, FRICTION_SLOTS, 3)),  # new pos, f, v of one geom
    ]
)
"""The friction law's parameters, the MuJoCo addresses it reads and writes, and its per-contact state."""


@jit_inline
def _add_force_at(f, fo: int, m, mo: int, fx, fy, fz, rx, ry, rz) -> None:
    """Add the force ``(fx, fy, fz)`` into ``f[fo:fo+3]`` and its moment ``r x f`` (arm ``r``) into ``m[mo:mo+3]``.

    Inlined: its callers pass constant offsets, for which numba would compile one version each.
    """
    f[fo] += fx
    f[fo + 1] += fy
    f[fo + 2] += fz
    m[mo] += ry * fz - rz * fy
    m[mo + 1] += rz * fx - rx * fz
    m[mo + 2] += rx * fy - ry * fx


@jit
def friction_reset(fr) -> None:
    """Forget the contacts and take the friction force off the tool (``fr``: a :data:`FRICTION_DTYPE` record)."""
    fr["n"][:] = 0
    fr["f"][:] = 0.0
    if fr["enabled"]:
        xfrc = f64_at(fr["xfrc"], 6)
        xfrc[:] = 0.0


@jit
def friction_step(fr, sensordata) -> bool:
    """Coulomb friction of the EE contacts MuJoCo found at this step, into the tool's ``xfrc_applied`` (module docs).

    The caller then recomputes the accelerations (``mj_fwdAcceleration``, ``mj_fwdConstraint``) and the
    acceleration-stage sensors (``mj_sensorAcc``) when this returns True, so that the next physics step
    integrates this force (``mj_Euler`` integrates the last computed ``qacc``).

    Args:
        fr: a :data:`FRICTION_DTYPE` record (its state is updated).
        sensordata: MuJoCo's ``sensordata`` after ``mj_forward``.

    Returns:
        True when the tool's friction force changed (it is or was in contact).
    """
    if not fr["enabled"]:
        return False
    had = fr["n"][0] + fr["n"][1] > 0
    xfrc = f64_at(fr["xfrc"], 6)
    va, wa, oa = fr["vel_adr"][0], fr["vel_adr"][1], fr["vel_adr"][2]
    n_all = 0
    for g in range(fr["sensor_adr"].shape[0]):
        a = fr["sensor_adr"][g]
        if a >= 0:
            n_all += min(int(sensordata[a]), FRICTION_SLOTS)
    if n_all == 0 and not had:
        return False
    for i in range(6):
        xfrc[i] = 0.0
    # half the deadbeat gain: the law f_k = f_k-1 - m/(2h) (2 v_k - v_k-1) on a point of effective mass m/e has
    # the poles z^2 + (3e/2 - 2) z + 1 - e/2 = 0, inside the unit circle for 0 < e < 8/3 (|z| = 0.71 at e = 1)
    gain = 0.5 * fr["mass"] / (fr["h"] * max(n_all, 1))
    mu = fr["mu"]
    new_pos, new_f, new_v = fr["scratch"][0], fr["scratch"][1], fr["scratch"][2]
    for g in range(fr["sensor_adr"].shape[0]):
        a = fr["sensor_adr"][g]
        found = min(int(sensordata[a]), FRICTION_SLOTS) if a >= 0 else 0
        old_pos, old_f, old_v, n_old = fr["pos"][g], fr["f"][g], fr["v"][g], fr["n"][g]
        used = 0  # bit j: old contact j continues a new one already (coincident contacts take one each)
        for s in range(found):
            b = a + s * FRICTION_SLOT_SIZE
            fn = sensordata[b + 1]
            px, py, pz = sensordata[b + 4], sensordata[b + 5], sensordata[b + 6]
            nx, ny, nz = sensordata[b + 7], sensordata[b + 8], sensordata[b + 9]
            rx, ry, rz = px - sensordata[oa], py - sensordata[oa + 1], pz - sensordata[oa + 2]
            wx, wy, wz = sensordata[wa], sensordata[wa + 1], sensordata[wa + 2]
            vx = sensordata[va] + wy * rz - wz * ry
            vy = sensordata[va + 1] + wz * rx - wx * rz
            vz = sensordata[va + 2] + wx * ry - wy * rx
            vn = vx * nx + vy * ny + vz * nz
            vx, vy, vz = vx - vn * nx, vy - vn * ny, vz - vn * nz  # slip velocity
            # the same contact at the last step: its force and slip velocity (else unloaded, no change)
            fpx, fpy, fpz, vpx, vpy, vpz = 0.0, 0.0, 0.0, vx, vy, vz
            best, match = _MATCH_M * _MATCH_M, -1
            for j in range(n_old):
                if used & (1 << j):
                    continue
                dx, dy, dz = old_pos[j, 0] - px, old_pos[j, 1] - py, old_pos[j, 2] - pz
                d2 = dx * dx + dy * dy + dz * dz
                if d2 < best:
                    best, match = d2, j
            if match >= 0:
                used |= 1 << match
                fpx, fpy, fpz = old_f[match, 0], old_f[match, 1], old_f[match, 2]
                vpx, vpy, vpz = old_v[match, 0], old_v[match, 1], old_v[match, 2]
            # the last force plus what undoes (half of) the slip and its last change
            fx = fpx - gain * (2.0 * vx - vpx)
            fy = fpy - gain * (2.0 * vy - vpy)
            fz = fpz - gain * (2.0 * vz - vpz)
            fdn = fx * nx + fy * ny + fz * nz
            fx, fy, fz = fx - fdn * nx, fy - fdn * ny, fz - fdn * nz
            mag = np.sqrt(fx * fx + fy * fy + fz * fz)
            cap = mu * max(fn, 0.0)
            if mag > cap:  # outside the cone: slide at mu f_n
                k = cap / mag
                fx, fy, fz = fx * k, fy * k, fz * k
            new_pos[s, 0], new_pos[s, 1], new_pos[s, 2] = px, py, pz
            new_f[s, 0], new_f[s, 1], new_f[s, 2] = fx, fy, fz
            new_v[s, 0], new_v[s, 1], new_v[s, 2] = vx, vy, vz
            _add_force_at(xfrc, 0, xfrc, 3, fx, fy, fz, rx, ry, rz)
        for s in range(found):
            for i in range(3):
                old_pos[s, i] = new_pos[s, i]
                old_f[s, i] = new_f[s, i]
                old_v[s, i] = new_v[s, i]
        fr["n"][g] = found
    return had or n_all > 0


@jit
def contact_wrench(par, fr, sensordata, p_E_W, f_W, m_W) -> bool:
    """Add the environment's contact wrench on the end-effector into ``f_W`` and ``m_W`` (3,) each.

    The friction the law of :func:`friction_step` applies to the tool counts with the contacts' own forces.

    Args:
        par: a :data:`PARAMS_DTYPE` record.
        fr: a :data:`FRICTION_DTYPE` record.
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
        _add_force_at(f_W, 0, m_W, 0, fx, fy, fz, rx, ry, rz)
        m_W[0] -= sensordata[a + 4]
        m_W[1] -= sensordata[a + 5]
        m_W[2] -= sensordata[a + 6]
    if fr["enabled"]:
        for g in range(fr["n"].shape[0]):
            for s in range(fr["n"][g]):
                fx, fy, fz = fr["f"][g, s, 0], fr["f"][g, s, 1], fr["f"][g, s, 2]
                rx = fr["pos"][g, s, 0] - p_E_W[0]
                ry = fr["pos"][g, s, 1] - p_E_W[1]
                rz = fr["pos"][g, s, 2] - p_E_W[2]
                _add_force_at(f_W, 0, m_W, 0, fx, fy, fz, rx, ry, rz)
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
        friction: (1,) :data:`FRICTION_DTYPE` record to live in (default: its own).
        data: the MuJoCo data (needed when the model carries the tool's friction sensors).
        mu: Coulomb's coefficient of the tool's friction.
        tool_mass: the tool's mass [kg].
    """

    state_dtype = STATE_DTYPE
    params_dtype = PARAMS_DTYPE
    log_fields = ("f_W", "m_W", "in_contact")

    def __init__(
        self,
        model: mujoco.MjModel,
        par: np.ndarray | None = None,
        state: np.ndarray | None = None,
        friction: np.ndarray | None = None,
        data: mujoco.MjData | None = None,
        mu: float = 0.0,
        tool_mass: float = 0.0,
    ) -> None:
        self.par = np.zeros(1, PARAMS_DTYPE) if par is None else par
        self.state = np.zeros(1, STATE_DTYPE) if state is None else state
        self.friction = np.zeros(1, FRICTION_DTYPE) if friction is None else friction

        def adr(name: str) -> int:
            sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, name)
            return int(model.sensor_adr[sid]) if sid >= 0 else -1

        fr = self.friction[0]
        for i, geom in enumerate(_EE_GEOMS):
            self.par["sensor_adr"][0, i] = adr(ee_contact_sensor(geom))
            fr["sensor_adr"][i] = adr(ee_contacts_sensor(geom))
        fr["vel_adr"][:] = [adr(name) for name in TOOL_SENSORS]
        tool = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, TOOL_BODY)
        fr["enabled"] = bool(np.any(fr["sensor_adr"] >= 0)) and data is not None and tool >= 0
        fr["mu"], fr["mass"], fr["h"] = mu, tool_mass, model.opt.timestep
        if fr["enabled"]:
            self._xfrc = data.xfrc_applied[tool]  # a view: its address stays valid with the data
            fr["xfrc"] = self._xfrc.ctypes.data

    def reset(self) -> None:
        """Clear the last wrench and the friction's contacts (the tool's friction force too)."""
        self.state[0] = 0
        friction_reset(self.friction[0])

    def step(self, sensordata: np.ndarray, p_E_W: np.ndarray) -> None:
        """The contact wrench of MuJoCo's current ``sensordata`` into :attr:`state`."""
        s = self.state[0]
        s["f_W"], s["m_W"] = 0.0, 0.0
        s["in_contact"] = contact_wrench(
            self.par[0],
            self.friction[0],
            sensordata,
            np.asarray(p_E_W, dtype=np.float64),
            self.state["f_W"][0],
            self.state["m_W"][0],
        )
