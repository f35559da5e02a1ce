"""The simulator's compiled step: the composer that wires its blocks through named signals (SPEC §2, §1.4, §7).

One control period (:func:`sim_step`, the step of :meth:`omnirotor.sim.simulator.Simulator.step`): the
fault schedule (:mod:`omnirotor.sim.faults`) checks the command, stops failed rotors and sets the gusts; then
``substeps`` x (``mj_Euler``; on the last one the rotors (:func:`omnirotor.sim.rotors.rotor_step`: speeds,
reversals, thrust fluctuation) and the truth aerodynamics (:func:`aero_wrench` of the fluctuating inputs
``u_eff_hz2``) give the new rotor wrench ``w_B``, and the airflow block
(:func:`omnirotor.sim.airflow.airflow_step`) its force at the CoM; :func:`apply_wrench` puts them and the
external wrench into ``xfrc_applied``; ``mj_forward`` (its sensor stage skipped except on the period's last
physics step, or on every one while the tool's friction reads its contacts); the tool's friction
(:func:`omnirotor.sim.contact.friction_step`), then :func:`observe` at the new time: the sensors
(:func:`omnirotor.sim.sensors.sense`) write the frame record, the fault schedule edits it (dropouts,
corruptions), the truth row is filled and the contact block (:func:`omnirotor.sim.contact.contact_wrench`)
adds the EE contact wrench to it.

Everything the step reads and updates is one record of :data:`SIM_DTYPE`, whose fields are the blocks' own
records (``rotor_par``, ``rotors``, ``sensors``, ``contact_par``, ``faults``, ``airflow_par``, ``airflow``)
and the composer's wiring: the addresses of MuJoCo's arrays for the vehicle (``mj``), the truth model
(``aero``), the external wrench (``ext``) and the rotor wrench ``w_B``. MuJoCo's C step functions are called
directly (:func:`omnirotor._jit.mujoco_function`). MuJoCo's profiler clock (``mjcb_time``, which the
``mujoco`` bindings install) is cleared for those calls and restored after them: MuJoCo reads it about 30
times per physics step, a sixth of a free-flight step's cost, and the step never reads ``MjData.timer``. So
:meth:`~omnirotor.sim.simulator.Simulator.step` leaves MuJoCo's stage timers alone (they do not count it).

The truth row (:data:`TRUTH_ROW_SIZE` + n entries; the simulator owns its layout): ``t, p_W (3), v_W (3),
R_WB (9), omega_B (3), p_E_W (3), contact_force_W (3), contact_moment_W (3), in_contact, rotor_hz (n)``.
"""

from __future__ import annotations

import numpy as np

from omnirotor._jit import (
    f64_at,
    f64_at2,
    jit,
    jit_entry,
    mujoco_function,
    profiler_clock_off,
    profiler_clock_restore,
)
from omnirotor.sim import aero as _aero
from omnirotor.sim import airflow, contact, faults, rotors, sensors
from omnirotor.so3 import R9_from_quat_into

__all__ = [
    "SIM_DTYPE",
    "MJ_DTYPE",
    "AERO_DTYPE",
    "EXT_DTYPE",
    "TRUTH_ROW_SIZE",
    "sim_step",
    "observe",
    "apply_wrench",
    "aero_wrench",
    "pre_step",
    "reset_forward",
]

mj_Euler = mujoco_function("mj_Euler")
"""MuJoCo's ``void mj_Euler(const mjModel* m, mjData* d)``, callable from kernels with the two addresses."""
mj_forward = mujoco_function("mj_forward")
"""MuJoCo's ``void mj_forward(const mjModel* m, mjData* d)``, callable from kernels with the two addresses."""
mj_fwdAcceleration = mujoco_function("mj_fwdAcceleration")
mj_fwdConstraint = mujoco_function("mj_fwdConstraint")
mj_sensorAcc = mujoco_function("mj_sensorAcc")
mj_forwardSkip = mujoco_function("mj_forwardSkip", int_args=2)
"""MuJoCo's ``void mj_forwardSkip(const mjModel* m, mjData* d, int skipstage, int skipsensor)``."""
_MJ_STAGE_NONE = 0  # mjtStage.mjSTAGE_NONE: skip no stage

MJ_DTYPE = np.dtype(
    [
        ("model", np.int64),  # MjModel._address
        ("data", np.int64),  # MjData._address
        ("substeps", np.int64),  # physics steps per control period
        ("pose", np.int64),  # address of the vehicle's qpos: p_W (3), q_WB (4, wxyz)
        ("vel", np.int64),  # address of its qvel: v_W (3), omega_B (3)
        ("acc", np.int64),  # address of its qacc: p_ddot_W (3), omega_dot_B (3)
        ("R_WB", np.int64),  # address of its xmat row (9, row-major)
        ("p_E_W", np.int64),  # address of the EE tip's site_xpos row (3)
        ("sensordata", np.int64),  # address of sensordata
        ("n_sensordata", np.int64),
        ("xfrc", np.int64),  # address of its xfrc_applied row (6: force, torque, world frame)
        ("timer", np.int64),  # address of MuJoCo's global mjcb_time (_jit.mujoco_timer_address; 0: left alone)
    ]
)
"""Where the step finds the vehicle in MuJoCo's arrays (MjData never reallocates them)."""

AERO_DTYPE = np.dtype([("kind", np.int64), ("model", np.int64), ("rows", np.int64), ("cols", np.int64)])
"""The truth model: its kind (``AERO_NOMINAL``, ``AERO_WAKE``, ``AERO_INTERFERENCE``), its array's address and shape."""

EXT_DTYPE = np.dtype(
    [
        ("f_W", np.float64, (3,)),
        ("m_W", np.float64, (3,)),
        ("p_E_B", np.float64, (3,)),
        ("active", np.bool_),
        ("at_ee", np.bool_),  # the force acts at the EE tip (adds its moment about the CoM), else at the CoM
    ]
)
"""A constant external wrench, world frame."""

SIM_DTYPE = np.dtype(
    [
        ("rotor_par", rotors.PARAMS_DTYPE),
        ("rotors", rotors.STATE_DTYPE),
        ("sensors", sensors.STATE_DTYPE),
        ("contact_par", contact.PARAMS_DTYPE),
        ("friction", contact.FRICTION_DTYPE),
        ("faults", faults.STATE_DTYPE),
        ("airflow_par", airflow.PARAMS_DTYPE),
        ("airflow", airflow.STATE_DTYPE),
        ("mj", MJ_DTYPE),
        ("aero", AERO_DTYPE),
        ("ext", EXT_DTYPE),
        ("w_B", np.float64, (6,)),  # the rotor wrench at the CoM, body frame [N, N·m]
        ("R9", np.float64, (9,)),  # scratch of apply_wrench: R_WB of the integrated pose, row-major
    ]
)
"""The record of :func:`sim_step`: the blocks' records and the composer's wiring."""

TRUTH_ROW_SIZE = 29
"""Entries of the truth row before the rotor speeds."""
_ROW_T, _ROW_P, _ROW_V, _ROW_R, _ROW_OMEGA, _ROW_P_E, _ROW_F, _ROW_M, _ROW_FLAG = 0, 1, 4, 7, 16, 19, 22, 25, 28


@jit_entry
def apply_wrench(pose, w_B, ext, f_air_W, xfrc, R) -> None:
    """Rotor wrench ``w_B`` (body frame) rotated to the world, plus the external wrench, into ``xfrc`` (6,).

    ``f_air_W`` (3,) is the recirculating airflow's force at the CoM (:mod:`omnirotor.sim.airflow`).

    ``R_WB`` is that of the quaternion ``pose[3:7]`` (written into the scratch ``R`` (9,), row-major); an
    active external force applied at the EE tip adds its moment ``(R p_E_B) x f_W``.
    """
    R9_from_quat_into(pose[3], pose[4], pose[5], pose[6], R, 0)
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = R[0], R[1], R[2], R[3], R[4], R[5], R[6], R[7], R[8]
    fx, fy, fz, mx, my, mz = w_B[0], w_B[1], w_B[2], w_B[3], w_B[4], w_B[5]
    Fx = r00 * fx + r01 * fy + r02 * fz
    Fy = r10 * fx + r11 * fy + r12 * fz
    Fz = r20 * fx + r21 * fy + r22 * fz
    Mx = r00 * mx + r01 * my + r02 * mz
    My = r10 * mx + r11 * my + r12 * mz
    Mz = r20 * mx + r21 * my + r22 * mz
    if ext["active"]:
        ef, em = ext["f_W"], ext["m_W"]
        ex, ey, ez = ef[0], ef[1], ef[2]
        Fx, Fy, Fz = Fx + ex, Fy + ey, Fz + ez
        Mx, My, Mz = Mx + em[0], My + em[1], Mz + em[2]
        if ext["at_ee"]:
            pe = ext["p_E_B"]
            px, py, pz = pe[0], pe[1], pe[2]
            rx = r00 * px + r01 * py + r02 * pz
            ry = r10 * px + r11 * py + r12 * pz
            rz = r20 * px + r21 * py + r22 * pz
            Mx += ry * ez - rz * ey
            My += rz * ex - rx * ez
            Mz += rx * ey - ry * ex
    xfrc[0] = Fx + f_air_W[0]
    xfrc[1] = Fy + f_air_W[1]
    xfrc[2] = Fz + f_air_W[2]
    xfrc[3] = Mx
    xfrc[4] = My
    xfrc[5] = Mz


@jit
def aero_wrench(aero, u_hz2, w_B) -> None:
    """The truth model's rotor wrench at the CoM, body frame, for inputs ``u_hz2`` [Hz²], into ``w_B`` (6,)."""
    model = f64_at2(aero["model"], aero["rows"], aero["cols"])
    if aero["kind"] == _aero.AERO_WAKE:
        _aero.wake_wrench(u_hz2, model, w_B)
    elif aero["kind"] == _aero.AERO_INTERFERENCE:
        _aero.interference_wrench(u_hz2, model, w_B)
    else:  # the nominal map A_nom (6, n)
        n = u_hz2.shape[0]
        for r in range(6):
            acc = 0.0
            for j in range(n):
                acc += model[r, j] * u_hz2[j]
            w_B[r] = acc


@jit_entry
def observe(sim, k: int, dt: float, frame, row) -> None:
    """The frame and the truth row at step ``k`` (time ``k dt``) from MuJoCo's current state.

    Args:
        sim: (1,) the :data:`SIM_DTYPE` record.
        k: step index.
        dt: control period [s].
        frame: (1,) the frame record (:func:`omnirotor.messages.frame_dtype`), written whole.
        row: the truth row, at least ``TRUTH_ROW_SIZE + n`` entries.
    """
    s = sim[0]
    mj = s["mj"]
    pose, vel, acc = f64_at(mj["pose"], 7), f64_at(mj["vel"], 6), f64_at(mj["acc"], 6)
    R9, p_E_W = f64_at(mj["R_WB"], 9), f64_at(mj["p_E_W"], 3)
    omega_hz = s["rotors"]["omega_hz"]
    t = k * dt
    fr = frame[0]
    sensors.sense(s["sensors"], pose, vel, acc, R9, omega_hz, k, t, fr)
    faults.faults_frame(s["faults"], fr)
    row[_ROW_T] = t
    for i in range(3):
        row[_ROW_P + i] = pose[i]
        row[_ROW_V + i] = vel[i]
        row[_ROW_OMEGA + i] = vel[3 + i]
        row[_ROW_P_E + i] = p_E_W[i]
        row[_ROW_F + i] = 0.0
        row[_ROW_M + i] = 0.0
    for i in range(9):
        row[_ROW_R + i] = R9[i]
    for i in range(s["rotor_par"]["n_rotors"]):
        row[TRUTH_ROW_SIZE + i] = omega_hz[i]
    touching = contact.contact_wrench(
        s["contact_par"], s["friction"], f64_at(mj["sensordata"], mj["n_sensordata"]), row[_ROW_P_E : _ROW_P_E + 3],
        row[_ROW_F : _ROW_F + 3], row[_ROW_M : _ROW_M + 3],
    )  # fmt: skip
    row[_ROW_FLAG] = 1.0 if touching else 0.0


@jit
def friction_forward(fr, m, d, sensordata) -> None:
    """The tool's friction after ``mj_forward``, for the next physics step to integrate.

    The friction of the contacts found (:func:`omnirotor.sim.contact.friction_step`) and, when it acts, the
    accelerations and their sensors again (``mj_Euler`` integrates the last computed ``qacc``).
    """
    if contact.friction_step(fr, sensordata):
        mj_fwdAcceleration(m, d)
        mj_fwdConstraint(m, d)
        mj_sensorAcc(m, d)


@jit_entry
def reset_forward(sim) -> None:
    """The forward pass of :meth:`omnirotor.sim.simulator.Simulator.reset` once the state is set, compiled.

    The rotors' wrench of their reset speeds into ``xfrc_applied`` (:func:`aero_wrench`, :func:`apply_wrench`),
    the tool's friction forgotten, ``mj_forward``, then the friction of the contacts found (and the
    accelerations again when it acts): what a period's last physics step does, without integrating. One
    compiled call, so that these kernels are compiled once, for the step (a call from Python compiles a twin).

    Args:
        sim: (1,) the :data:`SIM_DTYPE` record.
    """
    s = sim[0]
    mj = s["mj"]
    pose, xfrc = f64_at(mj["pose"], 7), f64_at(mj["xfrc"], 6)
    m, d = mj["model"], mj["data"]
    w_B = s["w_B"]
    aero_wrench(s["aero"], s["rotors"]["u_eff_hz2"][: s["rotor_par"]["n_rotors"]], w_B)
    apply_wrench(pose, w_B, s["ext"], s["airflow"]["f_W"], xfrc, s["R9"])
    contact.friction_reset(s["friction"])
    clock = profiler_clock_off(mj["timer"])
    mj_forward(m, d)
    friction_forward(s["friction"], m, d, f64_at(mj["sensordata"], mj["n_sensordata"]))
    profiler_clock_restore(mj["timer"], clock)


@jit_entry
def pre_step(sim, cmd_hz, k: int, dt: float):
    """The fault schedule's part before a period from step ``k`` (the Python step's); returns the rotors' command."""
    s = sim[0]
    t = k * dt
    cmd = faults.faults_command(s["faults"], t, cmd_hz)
    faults.faults_wrench(s["faults"], t, s["ext"])
    return cmd


@jit_entry
def sim_step(sim, cmd_hz, k: int, dt: float, frame, row) -> None:
    """A whole control period of :meth:`omnirotor.sim.simulator.Simulator.step` (module docstring).

    Args:
        sim: (1,) the :data:`SIM_DTYPE` record.
        cmd_hz: (n,) commanded rotor speeds [Hz] (clipped by the rotor model; NaN holds a rotor's speed).
        k: the step index before the period.
        dt: control period [s].
        frame: (1,) the frame record (output).
        row: the truth row (output).
    """
    s = sim[0]
    mj = s["mj"]
    pose, xfrc = f64_at(mj["pose"], 7), f64_at(mj["xfrc"], 6)
    w_B, ext = s["w_B"], s["ext"]
    m, d = mj["model"], mj["data"]
    t = k * dt
    cmd = faults.faults_command(s["faults"], t, cmd_hz)
    faults.faults_wrench(s["faults"], t, ext)
    substeps = mj["substeps"]
    friction_on = s["friction"]["enabled"]
    sensordata = f64_at(mj["sensordata"], mj["n_sensordata"])
    # MuJoCo's profiler clock off for these calls (module docstring), restored after them (0: no address given).
    timer_adr = mj["timer"]
    clock = profiler_clock_off(timer_adr)
    for i in range(substeps):
        mj_Euler(m, d)
        last = i == substeps - 1
        if last:
            rotors.rotor_step(s["rotor_par"], s["rotors"], cmd)
            airflow.airflow_step(s["airflow_par"], s["airflow"], pose)
            aero_wrench(s["aero"], s["rotors"]["u_eff_hz2"][: s["rotor_par"]["n_rotors"]], w_B)
        apply_wrench(pose, w_B, ext, s["airflow"]["f_W"], xfrc, s["R9"])
        # The sensors are read after the period only (computed on its last physics step), except by the tool's
        # friction law, which reads the EE contacts after every physics step.
        mj_forwardSkip(m, d, _MJ_STAGE_NONE, 0 if (last or friction_on) else 1)
        friction_forward(s["friction"], m, d, sensordata)  # the tool's friction over the next physics step
    profiler_clock_restore(timer_adr, clock)
    observe(sim, k + 1, dt, frame, row)
