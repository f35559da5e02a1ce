"""A simulated run written as a PX4 ULog or as MCAP (Foxglove), for Flight Review, PlotJuggler and Foxglove.

One set of signals (:func:`run_signals`), sampled at ``rate_hz`` from the 1 kHz logs, feeds both writers:
:func:`write_run_ulog` here and :func:`omnirotor.px4.mcap_export.write_run_mcap`.
ULog topics carry PX4's names, frames (NED world, FRD body, quaternion w, x, y, z body → world) and units
(:mod:`~omnirotor.px4.frames`); MCAP channels carry ours (z-up world, FLU body, SI, Foxglove's schemas):

=======================================  ===================================================================
ULog topic / MCAP topic                  content
=======================================  ===================================================================
vehicle_attitude, /pose                  estimated attitude (controller's estimator)
vehicle_local_position, /pose            estimated position, velocity, acceleration
vehicle_attitude_groundtruth,            true attitude, position, velocity (the simulator's; PX4 SITL's
vehicle_local_position_groundtruth,      topic names); MCAP: ``/pose_true`` and ``/tf`` (world → body)
sensor_combined, /imu                    true body rate [rad/s] and specific force [m/s²] (noise-free)
esc_status, /rotors                      true rotor speeds: ``esc_rpm`` = 60 × ω [rpm], signed (reverse < 0)
actuator_motors, /rotors                 commanded ``sign(ω)(ω/ω_max)²`` in [-1, 1] (PX4's thrust command)
omnirotor_reference, /reference          compliant and desired EE references, world frame
omnirotor_wrench, /wrench                estimated external wrench (observer), true contact wrench,
                                         controller wrench reference
omnirotor_contact, /contact              true contact flag, map region index, controller status bits
vehicle_status                           armed, offboard, rotary wing (for Flight Review's flight modes)
(parameters CA_*, OMR_*), /scene         the vehicle (PX4's CA_* plus OMR_* for what PX4 lacks); MCAP: the
                                         scene's geometry as a foxglove.SceneUpdate
=======================================  ===================================================================

Our own ULog topics keep our frames: field names end in their frame (``_W`` z-up world, ``_B`` FLU body).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from omnirotor.px4.frames import px4_quat_from_R_WB, quat_wxyz_of, vec_from_px4
from omnirotor.vehicle import VehicleParams

__all__ = ["RunSignals", "run_signals", "write_run_ulog", "px4_params_of"]

GRAVITY_W = np.array([0.0, 0.0, -9.81])


@dataclasses.dataclass(frozen=True)
class RunSignals:
    """The exported signals of a run, decimated (N samples; frames in names, SI units, speeds in Hz)."""

    t: np.ndarray
    p_W: np.ndarray
    v_W: np.ndarray
    a_W: np.ndarray
    R_WB: np.ndarray
    p_true_W: np.ndarray
    v_true_W: np.ndarray
    R_true_WB: np.ndarray
    omega_B: np.ndarray
    accel_B: np.ndarray
    rotor_hz: np.ndarray
    omega_cmd_hz: np.ndarray
    p_E_ref_W: np.ndarray
    R_E_ref: np.ndarray
    p_E_des_W: np.ndarray
    f_ext_hat_W: np.ndarray
    m_ext_hat_B: np.ndarray
    f_contact_W: np.ndarray
    m_contact_W: np.ndarray
    w_ref: np.ndarray
    in_contact: np.ndarray
    region: np.ndarray
    status: np.ndarray


def run_signals(controller_log, truth_log, rate_hz: float) -> RunSignals:
    """Take the exported signals from a run's controller and truth logs at ``rate_hz`` (every k-th sample)."""
    c, g = controller_log, truth_log
    n = min(c.n, g.n)
    t = g.group("t")[:n]
    dt = float(np.median(np.diff(t))) if n > 1 else 1e-3
    every = max(1, int(round(1.0 / (rate_hz * dt))))
    idx = np.arange(0, n, every)
    v_true = g.group("v_W")[:n]
    R_true = g.group("R_WB")[:n].reshape(-1, 3, 3)
    a_true = np.gradient(v_true, t, axis=0) if n > 1 else np.zeros_like(v_true)
    specific = np.einsum("nji,nj->ni", R_true, a_true - GRAVITY_W)  # R_WBᵀ (a − g), body frame

    def pick(log, name):
        return np.array(log.group(name)[:n][idx], dtype=float)

    return RunSignals(
        t=t[idx].copy(),
        p_W=pick(c, "p_W"),
        v_W=pick(c, "v_W"),
        a_W=pick(c, "a_W"),
        R_WB=pick(c, "R_WB").reshape(-1, 3, 3),
        p_true_W=pick(g, "p_W"),
        v_true_W=v_true[idx].copy(),
        R_true_WB=R_true[idx].copy(),
        omega_B=pick(g, "omega_B"),
        accel_B=specific[idx],
        rotor_hz=pick(g, "rotor_hz").reshape(idx.size, -1),
        omega_cmd_hz=pick(c, "omega_cmd_hz").reshape(idx.size, -1),
        p_E_ref_W=pick(c, "p_E_ref_W"),
        R_E_ref=pick(c, "R_E_ref").reshape(-1, 3, 3),
        p_E_des_W=pick(c, "p_E_des_W"),
        f_ext_hat_W=pick(c, "f_ext_W"),
        m_ext_hat_B=pick(c, "m_ext_B"),
        f_contact_W=pick(g, "contact_force_W"),
        m_contact_W=pick(g, "contact_moment_W"),
        w_ref=pick(c, "w_ref"),
        in_contact=pick(g, "in_contact") > 0.5,
        region=pick(c, "region").astype(np.int8),
        status=pick(c, "status").astype(np.uint32),
    )


def px4_params_of(vehicle: VehicleParams) -> dict[str, float | int]:
    """PX4 parameters of a vehicle: ``CA_*`` geometry (FRD) and ``OMR_*`` for what PX4 does not store.

    ``OMR_*`` (mass, inertia, c_f, c_tau, speed limits, EE tip) are read back by
    :func:`omnirotor.px4.airframe.vehicle_from_px4_params`, so a run's log carries its whole vehicle.
    """
    out: dict[str, float | int] = {"CA_AIRFRAME": 0, "CA_ROTOR_COUNT": vehicle.n_rotors}
    pos, axes = vec_from_px4(vehicle.positions_B), vec_from_px4(vehicle.axes_B)
    ratio = vehicle.c_tau / vehicle.c_f
    for i in range(vehicle.n_rotors):
        for j, a in enumerate("XYZ"):
            out[f"CA_ROTOR{i}_P{a}"] = float(pos[i, j])
            out[f"CA_ROTOR{i}_A{a}"] = float(axes[i, j])
        out[f"CA_ROTOR{i}_KM"] = float(-vehicle.spins[i] * ratio)
    out["CA_R_REV"] = (1 << vehicle.n_rotors) - 1 if vehicle.omega_min_hz < 0 else 0
    ours = {
        "OMR_MASS": vehicle.mass,
        "OMR_CF": vehicle.c_f,
        "OMR_CTAU": vehicle.c_tau,
        "OMR_WMAX": vehicle.omega_max_hz,
        "OMR_WMIN": vehicle.omega_min_hz,
        "OMR_JXX": vehicle.inertia_diag[0],
        "OMR_JYY": vehicle.inertia_diag[1],
        "OMR_JZZ": vehicle.inertia_diag[2],
        "OMR_EE_X": vehicle.p_E_B[0],
        "OMR_EE_Y": vehicle.p_E_B[1],
        "OMR_EE_Z": vehicle.p_E_B[2],
        "OMR_G": vehicle.gravity,
        "OMR_PROP_D": vehicle.propeller_diameter,
    }
    out.update({k: float(v) for k, v in ours.items()})
    return out


def _us(t: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(t) * 1e6).astype(np.uint64)


def _rows(n: int, fields: list) -> np.ndarray:
    return np.zeros(n, dtype=np.dtype([("timestamp", "<u8"), *fields]))


def write_run_ulog(path: str | Path, s: RunSignals, vehicle: VehicleParams, task: str = "") -> None:
    """Write a run's signals as a PX4 ULog (module docstring); atomic."""
    from omnirotor.px4.ulog_writer import ULogWriter

    N, n = s.t.size, s.rotor_hz.shape[1]
    ts = _us(s.t)
    w = ULogWriter(start_us=0)
    w.add_info("sys_name", "omnirotor")
    w.add_info("ver_hw", "OMNIROTOR_SIM")
    w.add_info("ver_sw", "omnirotor")
    w.add_info("sys_mcu", "simulation")
    if task:
        w.add_info("omnirotor_task", task)
    for name, value in px4_params_of(vehicle).items():
        w.add_param(name, value)

    def attitude(R):
        r = _rows(N, [("timestamp_sample", "<u8"), ("q", "<f4", (4,))])
        r["timestamp"], r["timestamp_sample"], r["q"] = ts, ts, px4_quat_from_R_WB(R)
        return r

    def local_position(p, v, a):
        f = [("timestamp_sample", "<u8")] + [(k, "<f4") for k in ("x", "y", "z", "vx", "vy", "vz", "ax", "ay", "az")]
        f += [("xy_valid", "bool"), ("z_valid", "bool"), ("v_xy_valid", "bool"), ("v_z_valid", "bool")]
        r = _rows(N, f)
        r["timestamp"], r["timestamp_sample"] = ts, ts
        for keys, vec in ((("x", "y", "z"), p), (("vx", "vy", "vz"), v), (("ax", "ay", "az"), a)):
            ned = vec_from_px4(vec)
            for j, k in enumerate(keys):
                r[k] = ned[:, j]
        for k in ("xy_valid", "z_valid", "v_xy_valid", "v_z_valid"):
            r[k] = True
        return r

    vs = _rows(N, [("arming_state", "u1"), ("nav_state", "u1"), ("vehicle_type", "u1"), ("is_vtol", "bool")])
    vs["timestamp"], vs["arming_state"], vs["nav_state"], vs["vehicle_type"] = ts, 2, 14, 1  # armed, offboard, rotary
    w.add_topic("vehicle_status", vs)
    w.add_topic("vehicle_attitude", attitude(s.R_WB))
    w.add_topic("vehicle_local_position", local_position(s.p_W, s.v_W, s.a_W))
    w.add_topic("vehicle_attitude_groundtruth", attitude(s.R_true_WB))
    zero = np.zeros_like(s.v_true_W)
    w.add_topic("vehicle_local_position_groundtruth", local_position(s.p_true_W, s.v_true_W, zero))
    sc = _rows(N, [("gyro_rad", "<f4", (3,)), ("accelerometer_m_s2", "<f4", (3,))])
    sc["timestamp"], sc["gyro_rad"], sc["accelerometer_m_s2"] = ts, vec_from_px4(s.omega_B), vec_from_px4(s.accel_B)
    w.add_topic("sensor_combined", sc)
    report = np.dtype([("timestamp", "<u8"), ("esc_rpm", "<i4"), ("esc_address", "u1")])
    esc = _rows(N, [("counter", "<u2"), ("esc_count", "u1"), ("esc_online_flags", "u1"), ("esc", report, (n,))])
    esc["timestamp"], esc["counter"], esc["esc_count"] = ts, np.arange(N) % 65536, n
    esc["esc_online_flags"] = (1 << min(n, 8)) - 1
    esc["esc"]["timestamp"] = ts[:, None]
    esc["esc"]["esc_rpm"] = np.round(60.0 * s.rotor_hz).astype(np.int32)
    esc["esc"]["esc_address"] = np.arange(n)[None, :]
    w.add_topic("esc_status", esc, {"esc": "esc_report"})
    am = _rows(N, [("timestamp_sample", "<u8"), ("reversible_flags", "<u2"), ("control", "<f4", (max(n, 12),))])
    am["timestamp"], am["timestamp_sample"] = ts, ts
    am["reversible_flags"] = (1 << n) - 1 if vehicle.omega_min_hz < 0 else 0
    cmd = s.omega_cmd_hz / vehicle.omega_max_hz
    am["control"][:, :n] = np.sign(cmd) * cmd * cmd
    am["control"][:, n:] = np.nan
    w.add_topic("actuator_motors", am)
    ref = _rows(N, [("p_E_ref_W", "<f4", (3,)), ("q_E_ref_W", "<f4", (4,)), ("p_E_des_W", "<f4", (3,))])
    ref["timestamp"], ref["p_E_ref_W"], ref["p_E_des_W"] = ts, s.p_E_ref_W, s.p_E_des_W
    ref["q_E_ref_W"] = quat_wxyz_of(s.R_E_ref)
    w.add_topic("omnirotor_reference", ref)
    wr = _rows(
        N,
        [
            ("f_ext_hat_W", "<f4", (3,)),
            ("m_ext_hat_B", "<f4", (3,)),
            ("f_contact_W", "<f4", (3,)),
            ("m_contact_W", "<f4", (3,)),
            ("w_ref", "<f4", (6,)),
        ],
    )
    wr["timestamp"] = ts
    for k in ("f_ext_hat_W", "m_ext_hat_B", "f_contact_W", "m_contact_W", "w_ref"):
        wr[k] = getattr(s, k)
    w.add_topic("omnirotor_wrench", wr)
    ct = _rows(N, [("in_contact", "bool"), ("region", "i1"), ("status", "<u4")])
    ct["timestamp"], ct["in_contact"], ct["region"], ct["status"] = ts, s.in_contact, s.region, s.status
    w.add_topic("omnirotor_contact", ct)
    w.write(path)
