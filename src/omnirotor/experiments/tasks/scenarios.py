"""The paper's experiments as reference trajectories built from a scene's geometry (SPEC §3.4, §5.2).

A :class:`Scenario` is everything a run needs besides the vehicle, the maps and the seed: the scene, the
admittance parameter set of Table 2 (SPEC §5.1), timed end-effector waypoints, and the time window of the
contact phase over which contact and force metrics are taken. Positions come from the scene parameters of the
simulator (``SceneParams``), so moving a wall moves the experiment with it.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from omnirotor.control.trajectory import Waypoint
from omnirotor.regions import Partition
from omnirotor.so3 import rot_x, rot_y, rot_z
from omnirotor.vehicle import VehicleParams

__all__ = [
    "Scenario",
    "ScenarioParams",
    "point_contact",
    "point_contact_tilted",
    "sliding",
    "peg_in_hole",
    "hover_attitudes",
    "hover_schedule",
    "body_to_ee_waypoint",
]


@dataclasses.dataclass(frozen=True)
class ScenarioParams:
    """Knobs of the experiment protocols (defaults: the paper's, SPEC §5.2; ``quick`` variants shorten them).

    Attributes:
        segment_s: duration of one waypoint-to-waypoint segment in point contact [s].
        penetration: how far past the surface the desired tip goes in point contact [m] (f ≈ K d).
        approach_standoff: distance of the approach waypoint from the surface [m].
        tilt_deg: the ±tilts of the point-contact sequence [deg].
        pipe_inset: waypoints lie this far inside the pipe surface [m].
        slide_roll_deg: roll reached at the apex of the pipe [deg].
        peg_misalignment_deg: roll misalignment of the peg on approach [deg] (paper 10°, code 15°).
        peg_insertion: insertion depth from the funnel entrance [m].
        settle_s: time at rest before the first motion [s] (the observer is zeroed during it when asked).
    """

    segment_s: float = 3.0
    penetration: float = 0.1
    approach_standoff: float = 0.3
    tilt_deg: float = 20.0
    pipe_inset: float = 0.03
    slide_roll_deg: float = 45.0
    peg_misalignment_deg: float = 10.0
    peg_insertion: float = 0.17
    settle_s: float = 2.0


@dataclasses.dataclass(frozen=True)
class Scenario:
    """One experiment: scene, admittance set, EE waypoints and the contact phase.

    Attributes:
        task: task name (``point-contact``, ``sliding``, ...).
        scene: simulator scene name.
        admittance: admittance preset name of Table 2 (``PC``, ``SD``, ``PiH``, ``free``).
        waypoints: timed end-effector poses.
        contact_phase: (t0, t1) [s], the window where the tip is meant to touch.
        marks: labelled instants for figures, e.g. ((10.0, "contact"), ...).
    """

    task: str
    scene: str
    admittance: str
    waypoints: tuple[Waypoint, ...]
    contact_phase: tuple[float, float]
    marks: tuple[tuple[float, str], ...] = ()

    @property
    def duration_s(self) -> float:
        """Time of the last waypoint plus a short hold [s]."""
        return float(self.waypoints[-1].t) + 1.0

    def start_body_pose(self, vehicle: VehicleParams) -> tuple[np.ndarray, np.ndarray]:
        """Body position and attitude at the first waypoint (``p = p_E − R p_E^B``)."""
        w = self.waypoints[0]
        return w.p_W - w.R_WB @ vehicle.p_E_B_array, w.R_WB.copy()


def _wp(t: float, p: np.ndarray, R: np.ndarray) -> Waypoint:
    return Waypoint(t=float(t), p_W=np.asarray(p, dtype=float), R_WB=R)


def body_to_ee_waypoint(t: float, p_body_W: np.ndarray, R_WB: np.ndarray, vehicle: VehicleParams) -> Waypoint:
    """The EE waypoint that puts the body at ``p_body_W`` with attitude ``R_WB``."""
    return _wp(t, np.asarray(p_body_W, dtype=float) + R_WB @ vehicle.p_E_B_array, R_WB)


def _contact_sequence(
    task: str,
    scene: str,
    S: np.ndarray,
    n: np.ndarray,
    R0: np.ndarray,
    press: np.ndarray,
    p: ScenarioParams,
    quick: bool,
) -> Scenario:
    """Approach, press, then tilt about the tip one axis at a time, returning to R0 after each (SPEC §5.2)."""
    seg = p.segment_s
    a = math.radians(p.tilt_deg)
    tilts = [rot_x(a), rot_x(-a)] if quick else [rot_x(a), rot_x(-a), rot_y(a), rot_y(-a), rot_z(a), rot_z(-a)]
    approach = S + p.approach_standoff * n
    contact = S + press
    t = p.settle_s
    wps = [_wp(0.0, approach, R0), _wp(t, approach, R0)]
    t += seg + 2.0
    wps.append(_wp(t, contact, R0))
    t_contact = t
    for Rt in tilts:
        t += seg
        wps.append(_wp(t, contact, R0 @ Rt))
        t += seg
        wps.append(_wp(t, contact, R0))
    t += seg
    wps.append(_wp(t, contact, R0))
    t_leave = t
    t += seg + 2.0
    wps.append(_wp(t, approach, R0))
    marks = ((t_contact, "press"), (t_leave, "retreat"))
    return Scenario(task, scene, "PC", tuple(wps), (t_contact, t_leave), marks)


def point_contact(scene, p: ScenarioParams = ScenarioParams(), quick: bool = False) -> Scenario:  # noqa: B008
    """Point contact on the straight wall (SPEC §5.2).

    The tip pushes ``penetration`` past the surface along −y, then the body tilts ±20° in roll, pitch and yaw
    about the tip, one axis at a time.
    """
    S = np.asarray(scene.wall_point, dtype=float)
    n = np.asarray(scene.wall_normal, dtype=float)
    n = n / np.linalg.norm(n)
    return _contact_sequence("point-contact", "wall", S, n, rot_z(math.pi), -p.penetration * n, p, quick)


def point_contact_tilted(scene, p: ScenarioParams = ScenarioParams(), quick: bool = False) -> Scenario:  # noqa: B008
    """Point contact on the surface inclined 30° downward (SPEC §5.2).

    The body holds ``Rz(π) Rx(30°)``; the penetration offset is the paper's (0, −0.07, +0.07) m.
    """
    ang = math.radians(scene.tilted_wall_angle_deg)
    S = np.asarray(scene.tilted_wall_point, dtype=float)
    n = np.array([0.0, math.cos(ang), -math.sin(ang)])
    press = p.penetration / 0.1 * np.array([0.0, -0.07, 0.07])
    return _contact_sequence("point-contact-tilted", "tilted-wall", S, n, rot_z(math.pi) @ rot_x(ang), press, p, quick)


def sliding(scene, p: ScenarioParams = ScenarioParams(), quick: bool = False) -> Scenario:  # noqa: B008
    """Slide the tip over the pipe from its side to 45° of roll and back (SPEC §5.2, times 0–50 s).

    ``quick`` keeps the path (the contact loss depends on the attitude reached) and shortens the holds.
    """
    c = np.asarray(scene.pipe_centre, dtype=float)
    r = scene.pipe_radius - p.pipe_inset
    th = math.radians(p.slide_roll_deg)
    init = c + np.array([0.0, -r, 0.0])
    apex = c + np.array([0.0, -r * math.cos(th), r * math.sin(th)])
    approach = init - np.array([0.0, 0.1, 0.0])
    home = approach - np.array([0.0, 0.3, 0.0])
    R0, Ra = np.eye(3), rot_x(-th)
    base = (0.0, 3.0, 6.0, 18.0, 30.0, 33.0, 36.0) if quick else (0.0, 5.0, 10.0, 25.0, 40.0, 45.0, 50.0)
    times = (0.0, *(p.settle_s + t for t in base))
    poses = ((home, R0), (home, R0), (approach, R0), (init, R0), (apex, Ra), (init, R0), (approach, R0), (home, R0))
    wps = tuple(_wp(t, pp, R) for t, (pp, R) in zip(times, poses, strict=True))
    marks = ((times[3], "on pipe"), (times[4], f"apex {p.slide_roll_deg:g}°"), (times[5], "back"))
    return Scenario("sliding", "pipe", "SD", wps, (times[3], times[5]), marks)


def peg_in_hole(scene, p: ScenarioParams = ScenarioParams(), quick: bool = False) -> Scenario:  # noqa: B008
    """Peg-in-hole (SPEC §5.2, times 0–21 s).

    Insert the peg 0.17 m along −y from the funnel entrance with a roll misalignment, hold, extract.
    """
    E = np.asarray(scene.hole_entrance, dtype=float)
    axis = np.array([0.0, 1.0, 0.0])  # the hole opens toward +y
    R = rot_z(math.pi) @ rot_x(-math.radians(p.peg_misalignment_deg))
    home = E + 0.3 * axis
    approach = E + 0.1 * axis
    inserted = E - p.peg_insertion * axis
    times = (0.0, *(p.settle_s + t for t in (0.0, 3.0, 6.0, 9.0, 12.0, 15.0, 18.0, 21.0)))
    poses = (home, home, approach, E, E - 0.5 * p.peg_insertion * axis, inserted, inserted, E, approach)
    wps = tuple(_wp(t, pp, R) for t, pp in zip(times, poses, strict=True))
    marks = ((times[3], "entrance"), (times[5], "inserted"), (times[6], "extract"))
    return Scenario("peg-in-hole", "peg-in-hole", "PiH", wps, (times[3], times[7]), marks)


def hover_attitudes(
    partition: Partition,
    regions: list[str],
    per_region: int,
    rng: np.random.Generator,
    vehicle: VehicleParams,
    min_speed_hz: float = 50.0,
) -> list[tuple[str, np.ndarray]]:
    """Random attitudes whose up direction lies in each region's sampling box (SPEC §3.4).

    An attitude is rejected when any rotor's nominal hover speed is below ``min_speed_hz`` (near the zero
    crossing of a bidirectional rotor), as in the authors' protocol. Yaw is uniform.
    """
    out: list[tuple[str, np.ndarray]] = []
    for name in regions:
        region = partition.region(name)
        got = 0
        for _ in range(10000):
            if got == per_region:
                break
            v = region.sample_up_direction(rng)
            R = _attitude_with_up(v, rng.uniform(-math.pi, math.pi))
            u = vehicle.hover_input(R)
            if np.min(np.sqrt(np.abs(u))) < min_speed_hz or np.max(np.abs(u)) > vehicle.u_max:
                continue
            out.append((name, R))
            got += 1
    return out


def _attitude_with_up(v_B: np.ndarray, yaw: float) -> np.ndarray:
    """A rotation R_WB whose third row is ``v_B`` (so R_WBᵀ e3 = v_B), turned by ``yaw`` about world z."""
    z = v_B / np.linalg.norm(v_B)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = helper - (helper @ z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R0 = np.vstack([x, y, z])  # rows: world axes in body coordinates
    return rot_z(yaw) @ R0


def hover_schedule(
    attitudes: list[tuple[str, np.ndarray]],
    p_body_W: np.ndarray,
    vehicle: VehicleParams,
    transition_s: float,
    hold_s: float,
) -> tuple[tuple[Waypoint, ...], list[tuple[str, float, float]]]:
    """Waypoints visiting each attitude in turn at a fixed body position, and each hold window (region, t0, t1).

    Each attitude is reached by a ``transition_s`` geodesic from the previous one and held ``hold_s``
    (SPEC §3.4: 3 s transition, 5 s hold); the returned window is the hold.
    """
    t = 1.0
    up = np.eye(3)
    wps = [body_to_ee_waypoint(0.0, p_body_W, up, vehicle), body_to_ee_waypoint(t, p_body_W, up, vehicle)]
    holds = []
    for name, R in attitudes:
        t += transition_s
        wps.append(body_to_ee_waypoint(t, p_body_W, R, vehicle))
        t0 = t
        t += hold_s
        wps.append(body_to_ee_waypoint(t, p_body_W, R, vehicle))
        holds.append((name, t0, t))
    return tuple(wps), holds
