"""MJCF of a vehicle in a scene, generated from the vehicle file (SPEC §1.2, §1.5, §5.2).

The vehicle is one free body whose CoM is the body origin, with the vehicle's mass and principal inertia
given explicitly (the geoms carry no mass), and by default a compliant tool. Its geoms:

* the frame: the 12 edges of a cube of side ``frame_size`` when the rotors span three dimensions (the
  Omnirotor), otherwise a flat hub plate with one arm per rotor;
* one propeller disk per rotor (radius half the propeller diameter, collision-enabled so that a crash
  shows as a contact) and one site ``rotor<i>`` whose z axis is the thrust axis;
* the end-effector: a Ø16 mm rod from the frame to a Ø16 mm tip sphere whose outermost point is ``p_E_B``
  (SPEC §1.5; Ø16 mm is the paper's peg, SPEC §5.2), and a site ``ee`` there on the body. With
  ``SceneParams.tool_compliant`` the rod and the tip sit on a child body ``ee_tool`` joined to the vehicle by a
  slide along the tool axis and two hinges across it (spring-dampers: the paper's vibration-damping coupling,
  §5.3) whose axes cross at the pivot ``SceneParams.tool_pivot`` (the vehicle's CoM by default). The tool's
  mass, taken from the body's, sits at that pivot with the moment of inertia of that mass at the tip, also taken
  from the body's, and the vehicle's own CoM moves against a pivot off the origin, so the vehicle's mass, CoM
  and (tool locked) inertia stay those of its file. Its joints follow the free joint in ``qpos``.

Contacts use MuJoCo's soft contact (``solref`` of ``SceneParams``) and, by default, the elliptic friction cone;
with the compliant tool and ``SceneParams.friction_law = "stick-slip"`` (the default) the EE geoms' contacts are
frictionless in MuJoCo (``condim`` 1, ``priority`` 1) and :func:`omnirotor.sim.contact.friction_step` applies
Coulomb's law to the tool, reading per-contact sensors of the EE geoms and the tool body's velocity sensors.
The constraint solver works on the whole model rather than per constraint island (``<flag island="disable"/>``):
the vehicle and its tool are the one island there is, the results are bit-identical, and finding the islands
cost about 0.5 µs per physics step in contact.

Measured inertias of flat vehicles may violate the triangle inequality by a hair (the quadrotor preset by
1%); MuJoCo's ``balanceinertia`` then nudges them onto it.

Rotor forces are not MuJoCo actuators: the simulator writes the body wrench into ``xfrc_applied``.
"""

from __future__ import annotations

import itertools

import numpy as np

from omnirotor.errors import InputError
from omnirotor.sim.params import SceneParams
from omnirotor.sim.scenes import scene_geoms_xml
from omnirotor.vehicle import VehicleParams

__all__ = [
    "build_mjcf",
    "BODY_NAME",
    "EE_TIP_GEOM",
    "EE_ROD_GEOM",
    "EE_SITE",
    "TIP_RADIUS",
    "ROD_RADIUS",
    "TOOL_BODY",
    "TOOL_AXIAL_JOINT",
    "TOOL_BEND_JOINTS",
    "tool_pivot_B",
    "ee_contact_sensor",
    "ee_contacts_sensor",
    "TOOL_SENSORS",
    "FRICTION_SLOTS",
    "vehicle_inertial",
]

BODY_NAME = "vehicle"
EE_TIP_GEOM = "ee_tip"
EE_ROD_GEOM = "ee_rod"
EE_SITE = "ee"
TIP_RADIUS = 0.008
"""Radius of the end-effector tip [m] (Ø16 mm, SPEC §5.2's peg)."""
ROD_RADIUS = 0.008
"""Radius of the end-effector rod [m]: the paper's end-effector is Ø16 mm along what enters the hole (§5.3)."""
TOOL_BODY = "ee_tool"
"""Child body of the vehicle carrying the rod and the tip when the tool is compliant."""
TOOL_AXIAL_JOINT = "tool_axial"
TOOL_BEND_JOINTS = ("tool_bend_a", "tool_bend_b")
TOOL_SENSORS = ("tool_linvel", "tool_angvel", "tool_pos")
"""The tool body's velocity sensors (linear, angular, world frame) and its origin, read by the friction law."""
FRICTION_SLOTS = 6
"""Contacts per EE geom its per-contact sensor reports (:data:`omnirotor.sim.contact.FRICTION_SLOTS`)."""
EDGE_RADIUS = 0.006
"""Radius of the frame's edges and arms [m] [A]."""
PROP_HALF_THICKNESS = 0.004
"""Half-thickness of a propeller disk [m] [A]."""
OFFSCREEN_SIZE = (1920, 1080)
"""Default offscreen framebuffer (the renderer enlarges it when asked for more)."""

_ROBOT_RGBA = "0.18 0.19 0.22 1"
_PROP_CW_RGBA = "0.15 0.45 0.85 0.45"
_PROP_CCW_RGBA = "0.90 0.55 0.10 0.45"
_TIP_RGBA = "0.85 0.12 0.12 1"


def _fmt(v) -> str:
    return " ".join(f"{float(x):.9g}" for x in v)


def _frame_geoms(vehicle: VehicleParams) -> list[str]:
    h = 0.5 * vehicle.frame_size
    P = vehicle.positions_B
    geoms = []
    if np.ptp(P[:, 2]) > 0.25 * vehicle.frame_size:
        corners = [np.array(c, dtype=float) * h for c in itertools.product((-1, 1), repeat=3)]
        k = 0
        for a, b in itertools.combinations(corners, 2):
            if np.count_nonzero(np.abs(a - b) > 1e-12) == 1:  # cube edge: differs in one coordinate
                geoms.append(
                    f'<geom name="edge{k}" class="robot" type="capsule" size="{EDGE_RADIUS}" '
                    f'fromto="{_fmt(a)} {_fmt(b)}"/>'
                )
                k += 1
        hub = 0.3 * h
        geoms.append(f'<geom name="hub" class="robot" type="box" size="{_fmt((hub, hub, hub))}"/>')
    else:
        geoms.append(f'<geom name="hub" class="robot" type="box" size="{_fmt((h, h, 0.25 * h))}"/>')
        for i, p in enumerate(P):
            if np.linalg.norm(p) > 1e-9:
                geoms.append(
                    f'<geom name="arm{i}" class="robot" type="capsule" size="{EDGE_RADIUS}" fromto="0 0 0 {_fmt(p)}"/>'
                )
    return geoms


def _rotor_elements(vehicle: VehicleParams) -> list[str]:
    r = 0.5 * vehicle.propeller_diameter
    out = []
    for i, (p, z, k) in enumerate(zip(vehicle.positions_B, vehicle.axes_B, vehicle.spins, strict=True)):
        rgba = _PROP_CW_RGBA if k > 0 else _PROP_CCW_RGBA
        out.append(f'<site name="rotor{i + 1}" pos="{_fmt(p)}" zaxis="{_fmt(z)}" size="{0.1 * r:.6g}" rgba="1 1 1 1"/>')
        out.append(
            f'<geom name="prop{i + 1}" class="robot" type="cylinder" pos="{_fmt(p)}" zaxis="{_fmt(z)}" '
            f'size="{r:.9g} {PROP_HALF_THICKNESS}" rgba="{rgba}"/>'
        )
    return out


def _perpendiculars(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing the unit vector d to a right-handed orthonormal frame."""
    a = np.eye(3)[int(np.argmin(np.abs(d)))]
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(d, e1)


def _tool_joints(d: np.ndarray, arm: float, pivot_B: np.ndarray, params: SceneParams) -> list[str]:
    """The coupling's joints: a slide along the tool axis ``d`` and two hinges across it through ``pivot_B`` [m].

    Damping gives each mode (the tool's mass, or its moment of inertia ``tool_mass arm²``, on the coupling's
    stiffness) the damping ratio of ``params``.
    """
    m, zeta = params.tool_mass, params.tool_damping_ratio
    k_ax, k_rot = params.tool_axial_stiffness, params.tool_bending_stiffness
    c_ax = 2.0 * zeta * np.sqrt(k_ax * m)
    c_rot = 2.0 * zeta * np.sqrt(k_rot * m * arm * arm)
    e1, e2 = _perpendiculars(d)
    out = [
        f'<joint name="{TOOL_AXIAL_JOINT}" type="slide" axis="{_fmt(d)}" stiffness="{k_ax:.9g}" damping="{c_ax:.9g}"/>'
    ]
    for name, e in zip(TOOL_BEND_JOINTS, (e1, e2), strict=True):
        out.append(
            f'<joint name="{name}" type="hinge" pos="{_fmt(pivot_B)}" axis="{_fmt(e)}" stiffness="{k_rot:.9g}" '
            f'damping="{c_rot:.9g}"/>'
        )
    return out


def _tool_axis(vehicle: VehicleParams) -> tuple[np.ndarray, float, np.ndarray]:
    """The tool's axis ``d`` (unit, body axes), where the rod leaves the frame along it [m], the tip's centre [m].

    The rod starts where the EE ray leaves the frame's cube (or at the CoM for a flat frame) and the tip sphere's
    outermost point is ``p_E_B``.
    """
    p_E = vehicle.p_E_B_array
    length = float(np.linalg.norm(p_E))
    d = p_E / length
    h = 0.5 * vehicle.frame_size
    return d, min(h / float(np.max(np.abs(d))), length - TIP_RADIUS), p_E - TIP_RADIUS * d


def tool_pivot_B(vehicle: VehicleParams, params: SceneParams) -> np.ndarray:
    """(3,) the compliant coupling's bending pivot, body axes [m] (:attr:`SceneParams.tool_pivot`)."""
    d, start_len, centre = _tool_axis(vehicle)
    return {"com": np.zeros(3), "mount": start_len * d, "tip": centre}[params.tool_pivot]


def _shift(r: np.ndarray) -> np.ndarray:
    """(3, 3) ``|r|² I − r rᵀ``: what a unit mass at ``r`` adds to an inertia about the origin [m²]."""
    return float(r @ r) * np.eye(3) - np.outer(r, r)


def _tool_inertia(vehicle: VehicleParams, params: SceneParams) -> np.ndarray:
    """(3, 3) inertia of the compliant tool about its pivot, body axes [kg·m²].

    That of ``tool_mass`` at the tip about the vehicle's CoM, whatever the pivot: moving the compliance centre
    changes no inertia (the lumped tool stands for a rod along the whole length).
    """
    p_E = vehicle.p_E_B_array
    length = float(np.linalg.norm(p_E))
    d = p_E / length
    i_perp = params.tool_mass * length * length
    i_ax = 0.4 * params.tool_mass * TIP_RADIUS**2
    return i_perp * (np.eye(3) - np.outer(d, d)) + i_ax * np.outer(d, d)


def _r9(x: float) -> float:
    """``x`` as the MJCF writes it (9 significant digits) and MuJoCo reads it back."""
    return float(f"{float(x):.9g}")


def vehicle_inertial(
    vehicle: VehicleParams, params: SceneParams, compliant: bool
) -> tuple[float, np.ndarray, str, tuple]:
    """The vehicle body's ``<inertial>``: the file's mass and inertia, less the compliant tool's (its own body's).

    The tool's inertia is taken from the body's as its mass is, so that the vehicle with its tool locked has
    the inertia of its file (what the controller and the torque identification's rigid-body model assume). The
    tool's mass sits at its pivot; a pivot off the origin moves the vehicle body's own CoM the other way, so that
    the whole stays centred on the body origin.

    Args:
        vehicle: the vehicle.
        params: the scene parameters (the tool's mass).
        compliant: the tool is a child body of its own.

    Returns:
        ``(mass [kg], CoM (3,) [m], "diaginertia" or "fullinertia", its 3 or 6 values [kg·m²])``, rounded as the
        MJCF writes them (:func:`build_mjcf`; :mod:`omnirotor.sim.model_cache` gives the same numbers to a parsed
        model).

    Raises:
        InputError: when the tool leaves the body half the vehicle's mass or less, or a non-physical inertia.
    """
    mass = vehicle.mass - (params.tool_mass if compliant else 0.0)
    if mass <= 0.5 * vehicle.mass:
        raise InputError(f"scene.tool_mass ({params.tool_mass} kg) must be below half the vehicle's mass")
    if not compliant:
        return _r9(mass), np.zeros(3), "diaginertia", tuple(_r9(j) for j in vehicle.inertia_diag)
    m = params.tool_mass
    pivot = tool_pivot_B(vehicle, params)
    com = -m * pivot / mass + 0.0  # + 0.0: no negative zeros in the MJCF
    J = vehicle.inertia - _tool_inertia(vehicle, params) - m * _shift(pivot) - mass * _shift(com)
    ev = np.linalg.eigvalsh(J)
    if ev[0] <= 0.0 or 2.0 * ev[-1] > ev.sum() * (1.0 + 0.02):
        raise InputError(
            f"scene.tool_mass ({params.tool_mass} kg) at the tip: the tool's inertia leaves the body a non-physical"
            f" inertia (principal moments {ev.tolist()})"
        )
    full = (J[0, 0], J[1, 1], J[2, 2], J[0, 1], J[0, 2], J[1, 2])
    return _r9(mass), np.array([_r9(x) for x in com]), "fullinertia", tuple(_r9(x) for x in full)


def _ee_elements(vehicle: VehicleParams, params: SceneParams) -> tuple[list[str], str]:
    """The EE site (on the body) and the tool: a Ø16 mm rod ending in a Ø16 mm tip sphere (SPEC §5.2's peg).

    Returns:
        ``(elements of the vehicle body, the tool's child body or "")``: with ``params.tool_compliant`` the rod
        and the tip sit on a child body ``ee_tool`` joined to the vehicle at :func:`tool_pivot_B`.
    """
    p_E = vehicle.p_E_B_array
    length = float(np.linalg.norm(p_E))
    out = [f'<site name="{EE_SITE}" pos="{_fmt(p_E)}" size="0.006" rgba="1 1 0 1"/>']
    if length <= TIP_RADIUS:
        out.append(
            f'<geom name="{EE_TIP_GEOM}" class="robot" type="sphere" size="{TIP_RADIUS}" '
            f'pos="{_fmt(p_E)}" rgba="{_TIP_RGBA}"/>'
        )
        return out, ""
    d, start_len, centre = _tool_axis(vehicle)
    # The rod ends one radius short of the tip's centre, so that its cap stays inside the tip and only the tip
    # meets a surface.
    start = d * start_len
    rod_end = centre - ROD_RADIUS * d
    compliant = params.tool_compliant
    # with the tool's own friction law MuJoCo's contacts of the EE geoms are frictionless (module docstring)
    own = ' condim="1" priority="1"' if _explicit_friction(params) else ""
    tool = [
        f'<geom name="{EE_TIP_GEOM}" class="robot" type="sphere" size="{TIP_RADIUS}" '
        f'pos="{_fmt(centre)}" rgba="{_TIP_RGBA}"{own}/>'
    ]
    if length - TIP_RADIUS - ROD_RADIUS - start_len > 1e-6:
        tool.append(
            f'<geom name="{EE_ROD_GEOM}" class="robot" type="capsule" size="{ROD_RADIUS}" '
            f'fromto="{_fmt(start)} {_fmt(rod_end)}"{own}/>'
        )
    if not compliant:
        return out + tool, ""
    # Lumped tool: its mass sits at the pivot (so that gravity loads no hinge; vehicle_inertial keeps the whole
    # centred on the body origin) with the moment of inertia about the pivot of that mass at the tip.
    m = params.tool_mass
    inertia = _tool_inertia(vehicle, params)
    full = (inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2])
    pivot = tool_pivot_B(vehicle, params)
    inner = _tool_joints(d, length, pivot, params)
    inner.append(f'<inertial pos="{_fmt(pivot + 0.0)}" mass="{m:.9g}" fullinertia="{_fmt(full)}"/>')
    body = "\n        ".join(inner + tool)
    # The tool's body frame is the vehicle's at rest.
    return out, f'<body name="{TOOL_BODY}" pos="0 0 0">\n        {body}\n      </body>'


def ee_contact_sensor(geom: str) -> str:
    """Name of the contact sensor of EE geom ``geom`` (present when the geom is)."""
    return f"{geom}_contact"


def ee_contacts_sensor(geom: str) -> str:
    """Name of the per-contact sensor of EE geom ``geom`` (present with the tool's own friction law)."""
    return f"{geom}_contacts"


def _explicit_friction(params: SceneParams) -> bool:
    """Whether the tool's friction is :func:`omnirotor.sim.contact.friction_step`'s (else MuJoCo's cone)."""
    return params.tool_compliant and params.friction_law == "stick-slip"


def _ee_sensors(body_xml: str, explicit_friction: bool) -> str:
    """One contact sensor per EE geom: net force, torque and centroid of its contacts (the truth's contact wrench).

    Read by :func:`omnirotor.sim.contact.contact_wrench`. With the tool's own friction law also a per-contact
    sensor per EE geom (force, position, normal of each) and the tool body's velocity, read by
    :func:`omnirotor.sim.contact.friction_step`.
    """
    out = []
    for geom in (EE_TIP_GEOM, EE_ROD_GEOM):
        if f'name="{geom}"' in body_xml:
            out.append(
                f'<contact name="{ee_contact_sensor(geom)}" geom1="{geom}" data="found force torque pos" '
                'reduce="netforce"/>'
            )
            if explicit_friction:
                out.append(
                    f'<contact name="{ee_contacts_sensor(geom)}" geom1="{geom}" data="found force pos normal" '
                    f'num="{FRICTION_SLOTS}"/>'
                )
    if explicit_friction:
        lin, ang, pos = TOOL_SENSORS
        out.append(f'<framelinvel name="{lin}" objtype="body" objname="{TOOL_BODY}"/>')
        out.append(f'<frameangvel name="{ang}" objtype="body" objname="{TOOL_BODY}"/>')
        out.append(f'<framepos name="{pos}" objtype="body" objname="{TOOL_BODY}"/>')
    return "\n    ".join(out)


TEXTURE_PX = (256, 512)
"""Sizes of the sky and floor textures of a model built for rendering [px]. A model only stepped gets 2 px
ones (:func:`build_mjcf` ``textures=False``): generating the full ones was 85 % of compiling the free scene,
and textures change nothing a simulation computes."""


def build_mjcf(vehicle: VehicleParams, scene: str, params: SceneParams, timestep: float, textures: bool = True) -> str:
    """The MJCF text of ``vehicle`` in ``scene``.

    Args:
        vehicle: the vehicle.
        scene: one of :data:`omnirotor.sim.scenes.SCENES`.
        params: scene geometry and contact properties.
        timestep: physics time step [s].
        textures: full-size textures (:data:`TEXTURE_PX`) for rendering; False: 2 px ones (same bodies, geoms
            and materials: the same simulation).

    Returns:
        The MJCF XML as a string.
    """
    sky, grid = TEXTURE_PX if textures else (2, 2)
    solref = f"{params.contact_timeconst:.9g} {params.contact_dampratio:.9g}"
    friction = f"{params.friction:.9g} 0.005 0.0001"
    floor = '<geom name="floor" class="env" type="plane" size="4 4 0.05" material="grid"/>' if params.floor else ""
    ee, tool = _ee_elements(vehicle, params)
    mass, com, kind, moments = vehicle_inertial(vehicle, params, bool(tool))
    inertial = f'<inertial pos="{_fmt(com)}" mass="{mass:.9g}" {kind}="{_fmt(moments)}"/>'
    body = "\n      ".join(_frame_geoms(vehicle) + _rotor_elements(vehicle) + ee + ([tool] if tool else []))
    return f"""<mujoco model="omnirotor-{vehicle.name}-{scene}">
  <compiler angle="radian" autolimits="true" balanceinertia="true"/>
  <option timestep="{timestep:.9g}" gravity="0 0 {-vehicle.gravity:.9g}" integrator="Euler"
    cone="{params.friction_cone}">
    <flag island="disable"/>
  </option>
  <visual>
    <global offwidth="{OFFSCREEN_SIZE[0]}" offheight="{OFFSCREEN_SIZE[1]}"/>
    <quality shadowsize="4096"/>
    <map shadowclip="3" shadowscale="0.5"/>
    <headlight ambient="0.35 0.35 0.35" diffuse="0.5 0.5 0.5"/>
  </visual>
  <asset>
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.75 0.82 0.90" rgb2="0.98 0.98 1.0"
      width="{sky}" height="{sky}"/>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.86 0.86 0.84" rgb2="0.76 0.76 0.74"
      width="{grid}" height="{grid}" mark="edge" markrgb="0.6 0.6 0.6"/>
    <material name="grid" texture="grid" texrepeat="8 8" reflectance="0.05"/>
  </asset>
  <default>
    <default class="env">
      <geom solref="{solref}" friction="{friction}" condim="3"/>
    </default>
    <default class="robot">
      <geom solref="{solref}" friction="{friction}" condim="3" rgba="{_ROBOT_RGBA}"/>
    </default>
  </default>
  <worldbody>
    <light name="sun" pos="0.3 0 5" dir="-0.15 0.1 -1" directional="true" castshadow="true"
      diffuse="0.6 0.6 0.6"/>
    {floor}
    {scene_geoms_xml(scene, params)}
    <body name="{BODY_NAME}" pos="0 0 1">
      <freejoint name="root"/>
      {inertial}
      {body}
    </body>
  </worldbody>
  <sensor>
    {_ee_sensors(body, bool(tool) and _explicit_friction(params))}
  </sensor>
</mujoco>
"""
