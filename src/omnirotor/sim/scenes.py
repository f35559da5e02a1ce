"""The contact scenes of SPEC §5.2: their geometric anchors, their MJCF geoms and a default start pose.

Scenes (world frame, z up):

* ``free``: nothing but the floor.
* ``wall``: a board whose outward normal is world +y through (0.637, -0.827, 1.429); the board occupies
  y < surface. The EE approaches along -y with body R = Rz(pi).
* ``tilted-wall``: a board inclined 30 deg downward, outward normal (0, cos 30, -sin 30), through
  (0.639, -0.848, 1.365).
* ``pipe``: a cylinder of radius 0.55 m, axis along world x through (0.0261, 1.4952, 0.7648).
* ``peg-in-hole``: a funnel (10 cm long, 80 mm mouth narrowing to 19 mm) then a 19 mm hole, axis along
  world y and opening towards +y, so the EE inserts along -y. MuJoCo replaces a mesh by its convex hull,
  so both are rings of thin boxes whose inner faces are tangent to the nominal surface: the free bore is a
  regular polygon with the nominal radius as its inradius.

All positions are set by :class:`~omnirotor.sim.params.SceneParams`; :func:`scene_anchors` gives the
quantities experiments build references from.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from omnirotor.errors import InputError
from omnirotor.sim.params import SceneParams
from omnirotor.vehicle import VehicleParams

__all__ = ["SCENES", "SceneAnchors", "scene_anchors", "scene_geoms_xml", "default_start_pose"]

SCENES = ("free", "wall", "tilted-wall", "pipe", "peg-in-hole")
"""Names of the scenes."""

_ENV_RGBA = "0.78 0.74 0.66 1"
_PIPE_RGBA = "0.55 0.60 0.66 1"
_HOLE_RGBA = "0.80 0.45 0.20 1"
_STAND_RGBA = "0.35 0.35 0.38 1"
_PLATE_OVERLAP = 1.05
"""Tangential oversize of the ring plates so that neighbours overlap beyond the polygon's corners."""


def _ro(v: np.ndarray) -> np.ndarray:
    a = np.array(v, dtype=float)
    a.setflags(write=False)
    return a


@dataclasses.dataclass(frozen=True)
class SceneAnchors:
    """Geometric anchors of one scene, world frame (read-only arrays) [m].

    Attributes:
        name: the scene.
        surface_point_W: (3,) the contact point the experiments aim at: the wall points of SPEC §5.2, the
            pipe's surface point facing -y (``centre - radius e_y``), the hole entrance; None for ``free``.
        normal_W: (3,) unit outward normal of the surface at ``surface_point_W`` (for the hole: its axis,
            pointing out of the opening); None for ``free``.
        pipe_centre_W: (3,) a point of the pipe's axis (pipe only).
        pipe_axis_W: (3,) unit axis of the pipe (pipe only).
        pipe_radius: [m] (pipe only).
        hole_entrance_W: (3,) where the hole axis crosses the funnel mouth (peg-in-hole only).
        hole_axis_W: (3,) unit hole axis pointing out of the opening (+y); insertion goes along its negative.
        funnel_length: [m] (peg-in-hole only).
        funnel_entrance_diameter: [m] (peg-in-hole only).
        hole_diameter: [m] (peg-in-hole only).
        insertion_depth_max: depth from the entrance to the hole's bottom [m] (peg-in-hole only).
    """

    name: str
    surface_point_W: np.ndarray | None = None
    normal_W: np.ndarray | None = None
    pipe_centre_W: np.ndarray | None = None
    pipe_axis_W: np.ndarray | None = None
    pipe_radius: float | None = None
    hole_entrance_W: np.ndarray | None = None
    hole_axis_W: np.ndarray | None = None
    funnel_length: float | None = None
    funnel_entrance_diameter: float | None = None
    hole_diameter: float | None = None
    insertion_depth_max: float | None = None


def _check_scene(name: str) -> None:
    if name not in SCENES:
        raise InputError(f"unknown scene {name!r}; scenes: {', '.join(SCENES)}")


def tilted_wall_normal(params: SceneParams) -> np.ndarray:
    """(3,) outward normal of the tilted wall: ``(0, cos a, -sin a)``."""
    a = math.radians(params.tilted_wall_angle_deg)
    return np.array([0.0, math.cos(a), -math.sin(a)])


def scene_anchors(name: str, params: SceneParams | None = None) -> SceneAnchors:
    """The anchors of scene ``name`` built from ``params``.

    Raises:
        InputError: unknown scene name.
    """
    _check_scene(name)
    p = params or SceneParams()
    if name == "wall":
        n = np.asarray(p.wall_normal, dtype=float)
        return SceneAnchors(name, surface_point_W=_ro(p.wall_point), normal_W=_ro(n / np.linalg.norm(n)))
    if name == "tilted-wall":
        return SceneAnchors(name, surface_point_W=_ro(p.tilted_wall_point), normal_W=_ro(tilted_wall_normal(p)))
    if name == "pipe":
        c = np.asarray(p.pipe_centre, dtype=float)
        outward = np.array([0.0, -1.0, 0.0])
        return SceneAnchors(
            name,
            surface_point_W=_ro(c + p.pipe_radius * outward),
            normal_W=_ro(outward),
            pipe_centre_W=_ro(c),
            pipe_axis_W=_ro([1.0, 0.0, 0.0]),
            pipe_radius=p.pipe_radius,
        )
    if name == "peg-in-hole":
        e = np.asarray(p.hole_entrance, dtype=float)
        axis = np.array([0.0, 1.0, 0.0])
        return SceneAnchors(
            name,
            surface_point_W=_ro(e),
            normal_W=_ro(axis),
            hole_entrance_W=_ro(e),
            hole_axis_W=_ro(axis),
            funnel_length=p.funnel_length,
            funnel_entrance_diameter=p.funnel_entrance_diameter,
            hole_diameter=p.hole_diameter,
            insertion_depth_max=p.funnel_length + p.hole_depth,
        )
    return SceneAnchors(name)


def _fmt(v: np.ndarray | tuple[float, ...]) -> str:
    return " ".join(f"{float(x):.9g}" for x in v)


def _tangent_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing the unit normal n to a right-handed frame (t1, t2, n), t1 horizontal."""
    up = np.array([0.0, 0.0, 1.0])
    t1 = np.cross(up, n) if abs(n @ up) < 0.99 else np.array([1.0, 0.0, 0.0])
    t1 = t1 / np.linalg.norm(t1)
    return t1, np.cross(n, t1)


def _board_xml(name: str, point: np.ndarray, normal: np.ndarray, p: SceneParams) -> str:
    t1, t2 = _tangent_basis(normal)
    centre = point - 0.5 * p.wall_thickness * normal
    half = (p.wall_half_width, p.wall_half_width, 0.5 * p.wall_thickness)
    return (
        f'<geom name="{name}" class="env" type="box" pos="{_fmt(centre)}" size="{_fmt(half)}" '
        f'xyaxes="{_fmt(t1)} {_fmt(t2)}" rgba="{_ENV_RGBA}"/>'
    )


def _ring_xml(prefix: str, p: SceneParams) -> list[str]:
    """Funnel, hole and bottom cap of the peg-in-hole scene as boxes."""
    e = np.asarray(p.hole_entrance, dtype=float)
    a = np.array([0.0, 1.0, 0.0])  # out of the opening
    e1, e2 = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    N, t = p.ring_segments, p.hole_wall_thickness
    r_mouth, r_hole = 0.5 * p.funnel_entrance_diameter, 0.5 * p.hole_diameter
    F, H = p.funnel_length, p.hole_depth
    tan_half = math.tan(math.pi / N)
    slant = math.hypot(F, r_mouth - r_hole)
    out = []
    for k in range(N):
        th = 2.0 * math.pi * k / N
        rho = math.cos(th) * e1 + math.sin(th) * e2
        tau = -math.sin(th) * e1 + math.cos(th) * e2
        # Funnel plate: inner face from (s=0, r=r_mouth) to (s=-F, r=r_hole); m is its outward normal.
        g = (-F * a - (r_mouth - r_hole) * rho) / slant
        m = (-(r_mouth - r_hole) * a + F * rho) / slant
        centre = e - 0.5 * F * a + 0.5 * (r_mouth + r_hole) * rho + 0.5 * t * m
        half = (_PLATE_OVERLAP * (r_mouth + t) * tan_half, 0.5 * slant, 0.5 * t)
        out.append(
            f'<geom name="{prefix}funnel{k}" class="env" type="box" pos="{_fmt(centre)}" size="{_fmt(half)}" '
            f'xyaxes="{_fmt(tau)} {_fmt(g)}" rgba="{_HOLE_RGBA}"/>'
        )
        # Straight hole plate: inner face at r = r_hole for s in [-F - H, -F].
        centre = e - (F + 0.5 * H) * a + (r_hole + 0.5 * t) * rho
        half = (_PLATE_OVERLAP * (r_hole + t) * tan_half, 0.5 * H, 0.5 * t)
        out.append(
            f'<geom name="{prefix}hole{k}" class="env" type="box" pos="{_fmt(centre)}" size="{_fmt(half)}" '
            f'xyaxes="{_fmt(tau)} {_fmt(a)}" rgba="{_HOLE_RGBA}"/>'
        )
    cap = e - (F + H + 0.5 * t) * a
    size = (r_hole + 2.0 * t, r_hole + 2.0 * t, 0.5 * t)
    out.append(
        f'<geom name="{prefix}bottom" class="env" type="box" pos="{_fmt(cap)}" size="{_fmt(size)}" '
        f'xyaxes="{_fmt(e1)} {_fmt(e2)}" rgba="{_HOLE_RGBA}"/>'
    )
    if p.floor:
        # A visual stand under the funnel (no collisions: nothing is meant to touch it).
        top = e[2] - r_mouth - 2.0 * t
        if top > 0.0:
            centre = np.array([e[0], e[1] - 0.5 * (F + H), 0.5 * top])
            size = (0.02, 0.5 * (F + H), 0.5 * top)
            out.append(
                f'<geom name="{prefix}stand" type="box" pos="{_fmt(centre)}" size="{_fmt(size)}" '
                f'contype="0" conaffinity="0" rgba="{_STAND_RGBA}"/>'
            )
    return out


def scene_geoms_xml(name: str, params: SceneParams) -> str:
    """MJCF ``<geom>`` elements (in the world body) of scene ``name``, without the floor."""
    _check_scene(name)
    p = params
    if name == "wall":
        a = scene_anchors(name, p)
        return _board_xml("wall", a.surface_point_W, a.normal_W, p)
    if name == "tilted-wall":
        a = scene_anchors(name, p)
        return _board_xml("wall", a.surface_point_W, a.normal_W, p)
    if name == "pipe":
        c = np.asarray(p.pipe_centre, dtype=float)
        return (
            f'<geom name="pipe" class="env" type="cylinder" pos="{_fmt(c)}" '
            f'size="{p.pipe_radius:.9g} {0.5 * p.pipe_length:.9g}" zaxis="1 0 0" rgba="{_PIPE_RGBA}"/>'
        )
    if name == "peg-in-hole":
        return "\n".join(_ring_xml("", p))
    return ""


def attitude_pointing(ee_dir_B: np.ndarray, target_W: np.ndarray) -> np.ndarray:
    """Rotation R_WB that points the body direction ``ee_dir_B`` along ``target_W`` keeping body "up" high.

    Body "up" is the unit vector closest to body z that is orthogonal to ``ee_dir_B``; it is sent to the
    unit vector closest to world z that is orthogonal to ``target_W``.

    Args:
        ee_dir_B: (3,) unit direction in the body frame.
        target_W: (3,) unit direction in the world frame.

    Returns:
        (3, 3) rotation matrix.
    """

    def frame(d: np.ndarray) -> np.ndarray:
        up = np.array([0.0, 0.0, 1.0])
        h = up - (up @ d) * d
        if np.linalg.norm(h) < 1e-9:
            h = np.array([1.0, 0.0, 0.0]) - d[0] * d
        h = h / np.linalg.norm(h)
        return np.column_stack([d, h, np.cross(d, h)])

    return frame(target_W) @ frame(ee_dir_B).T


def default_start_pose(
    anchors: SceneAnchors, vehicle: VehicleParams, params: SceneParams
) -> tuple[np.ndarray, np.ndarray]:
    """A free-space start pose suited to the scene: the EE ``start_standoff`` off the surface, pointing at it.

    Args:
        anchors: the scene's anchors.
        vehicle: the vehicle (its EE position sets the body position).
        params: gives ``start_standoff`` and ``free_start``.

    Returns:
        ``(p_W (3,), R_WB (3, 3))``: position of the CoM [m] and attitude.
    """
    if anchors.surface_point_W is None:
        return np.asarray(params.free_start, dtype=float), np.eye(3)
    n = np.asarray(anchors.normal_W, dtype=float)
    p_E_B = vehicle.p_E_B_array
    length = float(np.linalg.norm(p_E_B))
    R = attitude_pointing(p_E_B / length, -n) if length > 1e-9 else np.eye(3)
    p_E_W = anchors.surface_point_W + params.start_standoff * n
    return p_E_W - R @ p_E_B, R
