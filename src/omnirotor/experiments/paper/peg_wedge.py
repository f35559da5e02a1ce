"""Quasi-static wedge of the peg in the bore: where the admittance's push stops paying for the friction.

The peg-in-hole task (SPEC §5.2, paper §5.3) inserts a Ø16 mm rod ending in a Ø16 mm sphere through a funnel into
a Ø19 mm bore, approaching with a roll misalignment θ0, under the admittance of SPEC §5.1 (Table 2, "PiH").
Past the funnel the rod touches the bore at two points (Whitney's two-point contact): the tip's sphere on one
wall, the rod on the funnel-bore junction on the other, ``s`` apart along the axis (``s``: how far the sphere's
centre is past the junction). The bore then allows a misalignment of at most θ_g(s), the largest θ with

    -(R - r) + s tan θ + r / cos θ <= R        (R, r: the bore's and the rod's radii),

and the couple that turns the peg to θ_g against the admittance's rotational stiffness, M = K_R (θ0 - θ_g), has
normal forces N = M / s at both points. Each costs friction μ N along the axis, and the junction's normal,
perpendicular to the tilted rod, pushes back by N sin θ_g. What pays is the admittance's translational
stiffness times the reference's lead, K_p (L - d), with L the commanded insertion and d the tip's depth
(d = funnel length + r + s: the EE point is the sphere's outermost point, its contact with the wall level with
its centre). The peg advances while

    K_p (L - d) >= (M / s) (2 μ + sin θ_g);

the first ``s`` where this fails is the jam, its θ_g the roll held there. The balance assumes a rigid tool
aligned with the body, an observer that reads the contact wrench exactly, no lateral admittance force and a
reference at rest (the moving reference's damping pushes a little more); used in docs/fidelity.md to check the
simulated jam.
"""

from __future__ import annotations

import dataclasses
import math

from omnirotor.control.admittance import AdmittanceParams
from omnirotor.sim.model import ROD_RADIUS
from omnirotor.sim.params import SceneParams

__all__ = ["WedgeJam", "max_misalignment", "wedge_jam"]


def max_misalignment(s: float, bore_radius: float, rod_radius: float) -> float:
    """Largest misalignment [rad] of the rod with its tip's centre ``s`` [m] past the bore's mouth.

    Args:
        s: axial distance of the tip sphere's centre past the funnel-bore junction [m], >= 0.
        bore_radius: the bore's radius R [m].
        rod_radius: the rod's (and the tip sphere's) radius r [m], < R.

    Returns:
        θ_g in (0, π/2) [rad] (small angles are meant: the two contacts are modelled as points).
    """

    def gap(theta: float) -> float:
        return -(bore_radius - rod_radius) + s * math.tan(theta) + rod_radius / math.cos(theta) - bore_radius

    lo, hi = 0.0, 0.5 * math.pi - 1e-9  # gap(lo) < 0 < gap(hi)
    for _ in range(100):  # gap rises monotonically on [0, π/2) for s >= 0: bisection
        mid = 0.5 * (lo + hi)
        if gap(mid) > 0.0:
            hi = mid
        else:
            lo = mid
    return lo


@dataclasses.dataclass(frozen=True)
class WedgeJam:
    """Where the quasi-static wedge stops the peg.

    Attributes:
        jammed: the peg stops before the commanded insertion.
        depth: the EE's depth from the funnel's mouth there [m] (the commanded insertion when not jammed).
        roll_deg: the peg's misalignment there [deg] (θ_g at the stop; at the commanded insertion otherwise).
        normal_force: the normal force at each of the two contacts there [N].
    """

    jammed: bool
    depth: float
    roll_deg: float
    normal_force: float


def wedge_jam(
    friction: float,
    approach_deg: float,
    insertion: float,
    scene: SceneParams | None = None,
    admittance: AdmittanceParams | None = None,
    steps: int = 2000,
) -> WedgeJam:
    """The quasi-static jam of the peg (module docstring), about the roll axis.

    Args:
        friction: Coulomb's coefficient μ at both contacts [-].
        approach_deg: the roll misalignment θ0 the admittance holds the peg at in free flight [deg].
        insertion: the commanded depth of the EE from the funnel's mouth L [m].
        scene: the hole's geometry (default :class:`SceneParams`).
        admittance: the admittance (default: SPEC §5.1's "PiH"); its x-axis values (roll) are used.
        steps: depths tried between the junction and the commanded insertion.

    Returns:
        The :class:`WedgeJam`.
    """
    scene = SceneParams() if scene is None else scene
    adm = AdmittanceParams.preset("PiH") if admittance is None else admittance
    k_pos, k_rot = float(adm.stiffness_pos[1]), float(adm.stiffness_rot[0])  # push along the hole's y, roll about x
    theta0 = math.radians(approach_deg)
    bore, r = 0.5 * scene.hole_diameter, ROD_RADIUS
    start = scene.funnel_length + r  # the EE's depth with the tip's centre at the junction
    theta = theta0
    for i in range(1, steps + 1):
        s = (insertion - start) * i / steps
        theta = min(theta0, max_misalignment(s, bore, r))
        if theta >= theta0:
            continue  # the bore does not turn the peg yet: no couple
        normal = k_rot * (theta0 - theta) / s
        if k_pos * (insertion - start - s) < normal * (2.0 * friction + math.sin(theta)):
            return WedgeJam(True, start + s, math.degrees(theta), normal)
    return WedgeJam(False, insertion, math.degrees(theta), 0.0)
