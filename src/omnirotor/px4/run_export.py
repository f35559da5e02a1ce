"""A simulated run written as a PX4 ULog or as MCAP (Foxglove), for Flight Review, PlotJuggler and Foxglove.

One set of channels (:func:`run_channels`), sampled at ``rate_hz`` from the 1 kHz logs, feeds both writers.
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
import json
from pathlib import Path

import numpy as np

from omnirotor.px4.frames import px4_quat_from_R_WB, vec_from_px4
from omnirotor.vehicle import VehicleParams

__all__ = ["RunSignals", "run_signals", "write_run_ulog", "write_run_mcap", "px4_params_of"]

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


def _quat_wxyz(R: np.ndarray) -> np.ndarray:
    from omnirotor.so3 import quat_wxyz_from_R

    return np.array([quat_wxyz_from_R(r) for r in R]).reshape(-1, 4)


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
    ref["q_E_ref_W"] = _quat_wxyz(s.R_E_ref)
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


# -- MCAP ----------------------------------------------------------------------------------------------------

_VEC3 = {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}
_TIME = {
    "type": "object",
    "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
    "description": "Timestamp of the sample (simulated time)",
}
_POSE = {
    "type": "object",
    "properties": {
        "position": {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}},
        "orientation": {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}},
    },
}
FOXGLOVE_SCHEMAS = {
    "foxglove.PoseInFrame": {
        "title": "foxglove.PoseInFrame",
        "type": "object",
        "properties": {"timestamp": _TIME, "frame_id": {"type": "string"}, "pose": _POSE},
    },
    "foxglove.FrameTransform": {
        "title": "foxglove.FrameTransform",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "parent_frame_id": {"type": "string"},
            "child_frame_id": {"type": "string"},
            "translation": _POSE["properties"]["position"],
            "rotation": _POSE["properties"]["orientation"],
        },
    },
    "foxglove.SceneUpdate": {
        "title": "foxglove.SceneUpdate",
        "type": "object",
        "properties": {"deletions": {"type": "array"}, "entities": {"type": "array"}},
    },
}


def _own_schema(name: str, fields: dict[str, tuple[str, str]]) -> dict:
    """A JSON schema of one of our channels: fields name → (kind, description with unit and frame)."""
    props = {"t_s": {"type": "number", "description": "simulated time [s]"}}
    for k, (kind, desc) in fields.items():
        spec = dict(_VEC3) if kind == "vec3" else {"type": kind}
        if kind == "array":
            spec = {"type": "array", "items": {"type": "number"}}
        props[k] = {**spec, "description": desc}
    return {"title": name, "type": "object", "properties": props}


OWN_SCHEMAS = {
    "omnirotor.Rotors": _own_schema(
        "omnirotor.Rotors",
        {"omega_hz": ("array", "true rotor speeds, signed [Hz]"), "omega_cmd_hz": ("array", "commanded speeds [Hz]")},
    ),
    "omnirotor.Imu": _own_schema(
        "omnirotor.Imu",
        {"omega_B": ("vec3", "true body rate, FLU body [rad/s]"), "accel_B": ("vec3", "specific force, body [m/s²]")},
    ),
    "omnirotor.Wrench": _own_schema(
        "omnirotor.Wrench",
        {
            "f_ext_hat_W": ("vec3", "observer's external force estimate, world [N]"),
            "m_ext_hat_B": ("vec3", "observer's external moment estimate, body [N·m]"),
            "f_contact_W": ("vec3", "true contact force, world [N]"),
            "m_contact_W": ("vec3", "true contact moment, world [N·m]"),
            "w_ref": ("array", "pose controller's [f_ref_W; m_ref_B] [N, N·m]"),
        },
    ),
    "omnirotor.Reference": _own_schema(
        "omnirotor.Reference",
        {
            "p_E_ref_W": ("vec3", "compliant EE reference position, world [m]"),
            "p_E_des_W": ("vec3", "desired EE position, world [m]"),
        },
    ),
    "omnirotor.Contact": _own_schema(
        "omnirotor.Contact",
        {
            "in_contact": ("boolean", "true contact flag"),
            "region": ("integer", "wrench-map region index (-1: not piecewise)"),
            "status": ("integer", "controller status bits"),
        },
    ),
}


def _stamp(t: float) -> dict:
    ns = int(round(t * 1e9))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _pose_json(p: np.ndarray, q_wxyz: np.ndarray) -> dict:
    return {
        "position": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
        "orientation": {"x": float(q_wxyz[1]), "y": float(q_wxyz[2]), "z": float(q_wxyz[3]), "w": float(q_wxyz[0])},
    }


def scene_entities(vehicle: VehicleParams, scene: str, scene_params) -> list[dict]:
    """The scene's fixed geometry (geoms welded to the world in its MuJoCo model) as foxglove primitives."""
    import mujoco

    from omnirotor.sim.model import build_mjcf
    from omnirotor.so3 import quat_wxyz_from_R

    m = mujoco.MjModel.from_xml_string(build_mjcf(vehicle, scene, scene_params, 1e-3))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    cubes, cylinders, spheres = [], [], []
    G = mujoco.mjtGeom
    for g in range(m.ngeom):
        if m.body_weldid[m.geom_bodyid[g]] != 0:  # only what is welded to the world: not the vehicle
            continue
        pos, size = d.geom_xpos[g], m.geom_size[g]
        quat = quat_wxyz_from_R(d.geom_xmat[g].reshape(3, 3))
        color = {k: float(v) for k, v in zip("rgba", m.geom_rgba[g], strict=True)}
        pose = _pose_json(pos, quat)
        kind = int(m.geom_type[g])
        if kind == int(G.mjGEOM_BOX):
            cubes.append({"pose": pose, "size": dict(zip("xyz", map(float, 2 * size), strict=True)), "color": color})
        elif kind == int(G.mjGEOM_PLANE):
            extent = [float(2 * size[0]) or 10.0, float(2 * size[1]) or 10.0, 0.001]
            cubes.append({"pose": pose, "size": dict(zip("xyz", extent, strict=True)), "color": color})
        elif kind in (int(G.mjGEOM_CYLINDER), int(G.mjGEOM_CAPSULE)):
            d = float(2 * size[0])
            cylinders.append(
                {
                    "pose": pose,
                    "size": {"x": d, "y": d, "z": float(2 * size[1])},
                    "bottom_scale": 1.0,
                    "top_scale": 1.0,
                    "color": color,
                }
            )
        elif kind == int(G.mjGEOM_SPHERE):
            d = float(2 * size[0])
            spheres.append({"pose": pose, "size": {"x": d, "y": d, "z": d}, "color": color})
    return [
        {
            "timestamp": _stamp(0.0),
            "frame_id": "world",
            "id": f"scene-{scene}",
            "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": False,
            "metadata": [{"key": "scene", "value": scene}],
            "arrows": [],
            "cubes": cubes,
            "spheres": spheres,
            "cylinders": cylinders,
            "lines": [],
            "triangles": [],
            "texts": [],
            "models": [],
        }
    ]


def write_run_mcap(
    path: str | Path, s: RunSignals, vehicle: VehicleParams, scene: str = "free", scene_params=None
) -> dict[str, int]:
    """Write a run's signals as MCAP with JSON encoding (module docstring); returns messages per topic."""
    from mcap.writer import Writer

    from omnirotor.sim.params import SceneParams

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_name(f".{p.name}.tmp")
    counts: dict[str, int] = {}
    q_est, q_true = _quat_wxyz(s.R_WB), _quat_wxyz(s.R_true_WB)
    with tmp.open("wb") as fh:
        mw = Writer(fh)
        mw.start(profile="", library="omnirotor")
        schema_ids = {}
        for name, schema in {**FOXGLOVE_SCHEMAS, **OWN_SCHEMAS}.items():
            schema_ids[name] = mw.register_schema(name=name, encoding="jsonschema", data=json.dumps(schema).encode())
        topics = {
            "/pose": "foxglove.PoseInFrame",
            "/pose_true": "foxglove.PoseInFrame",
            "/tf": "foxglove.FrameTransform",
            "/scene": "foxglove.SceneUpdate",
            "/rotors": "omnirotor.Rotors",
            "/imu": "omnirotor.Imu",
            "/wrench": "omnirotor.Wrench",
            "/reference": "omnirotor.Reference",
            "/contact": "omnirotor.Contact",
        }
        chan = {
            topic: mw.register_channel(topic=topic, message_encoding="json", schema_id=schema_ids[schema])
            for topic, schema in topics.items()
        }

        def put(topic: str, t: float, msg: dict) -> None:
            ns = int(round(t * 1e9))
            mw.add_message(chan[topic], log_time=ns, publish_time=ns, data=json.dumps(msg).encode(), sequence=0)
            counts[topic] = counts.get(topic, 0) + 1

        params = scene_params if scene_params is not None else SceneParams()
        put(
            "/scene",
            float(s.t[0]) if s.t.size else 0.0,
            {"deletions": [], "entities": scene_entities(vehicle, scene, params)},
        )
        for k in range(s.t.size):
            t = float(s.t[k])
            st = _stamp(t)
            put("/pose", t, {"timestamp": st, "frame_id": "world", "pose": _pose_json(s.p_W[k], q_est[k])})
            put("/pose_true", t, {"timestamp": st, "frame_id": "world", "pose": _pose_json(s.p_true_W[k], q_true[k])})
            tf = _pose_json(s.p_true_W[k], q_true[k])
            put(
                "/tf",
                t,
                {
                    "timestamp": st,
                    "parent_frame_id": "world",
                    "child_frame_id": "body",
                    "translation": tf["position"],
                    "rotation": tf["orientation"],
                },
            )
            put(
                "/rotors", t, {"t_s": t, "omega_hz": s.rotor_hz[k].tolist(), "omega_cmd_hz": s.omega_cmd_hz[k].tolist()}
            )
            put("/imu", t, {"t_s": t, "omega_B": s.omega_B[k].tolist(), "accel_B": s.accel_B[k].tolist()})
            put(
                "/wrench",
                t,
                {
                    "t_s": t,
                    "f_ext_hat_W": s.f_ext_hat_W[k].tolist(),
                    "m_ext_hat_B": s.m_ext_hat_B[k].tolist(),
                    "f_contact_W": s.f_contact_W[k].tolist(),
                    "m_contact_W": s.m_contact_W[k].tolist(),
                    "w_ref": s.w_ref[k].tolist(),
                },
            )
            put("/reference", t, {"t_s": t, "p_E_ref_W": s.p_E_ref_W[k].tolist(), "p_E_des_W": s.p_E_des_W[k].tolist()})
            put(
                "/contact",
                t,
                {"t_s": t, "in_contact": bool(s.in_contact[k]), "region": int(s.region[k]), "status": int(s.status[k])},
            )
        mw.finish()
    tmp.replace(p)
    return counts
