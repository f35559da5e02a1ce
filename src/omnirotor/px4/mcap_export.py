"""A simulated run as MCAP for Foxglove: JSON messages with Foxglove's schemas and ours (SPEC §1.1 frames).

The channels are those of :mod:`omnirotor.px4.run_export` in our frames (z-up world, FLU body) and SI units:
``/pose`` and ``/pose_true`` (``foxglove.PoseInFrame``), ``/tf`` (``foxglove.FrameTransform`` world → body),
``/scene`` (``foxglove.SceneUpdate``: the geoms welded to the world in the scene's MuJoCo model), and our own
``/rotors``, ``/imu``, ``/wrench``, ``/reference``, ``/contact`` whose JSON schemas give each field's unit and frame.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from omnirotor.px4.frames import quat_wxyz_of
from omnirotor.px4.run_export import RunSignals
from omnirotor.vehicle import VehicleParams

__all__ = ["FOXGLOVE_SCHEMAS", "OWN_SCHEMAS", "CHANNELS", "scene_entities", "write_run_mcap", "stamp_json", "pose_json"]

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


CHANNELS = {
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
"""The channels (topic -> schema name) of a run's MCAP, and of the flight node's live view (omnirotor.fly.live)."""


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

    from omnirotor.safe_io import atomic_path
    from omnirotor.sim.params import SceneParams

    p = Path(path)
    counts: dict[str, int] = {}
    q_est, q_true = quat_wxyz_of(s.R_WB), quat_wxyz_of(s.R_true_WB)
    with atomic_path(p, "--mcap") as tmp, tmp.open("wb") as fh:  # exclusive, unpredictable temporary name
        mw = Writer(fh)
        mw.start(profile="", library="omnirotor")
        schema_ids = {}
        for name, schema in {**FOXGLOVE_SCHEMAS, **OWN_SCHEMAS}.items():
            schema_ids[name] = mw.register_schema(name=name, encoding="jsonschema", data=json.dumps(schema).encode())
        chan = {
            topic: mw.register_channel(topic=topic, message_encoding="json", schema_id=schema_ids[schema])
            for topic, schema in CHANNELS.items()
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
    return counts


stamp_json = _stamp
"""``{"sec", "nsec"}`` of a time [s] (Foxglove's timestamp)."""
pose_json = _pose_json
"""Foxglove's pose ``{"position", "orientation"}`` of a position [m] and a quaternion wxyz."""
