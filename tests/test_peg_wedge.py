"""The quasi-static wedge of the peg in the bore (omnirotor.experiments.paper.peg_wedge; docs/fidelity.md)."""

import dataclasses
import math

import numpy as np
import pytest

from omnirotor.control.admittance import AdmittanceParams
from omnirotor.experiments.paper.peg_wedge import max_misalignment, wedge_jam
from omnirotor.sim.params import SceneParams

R, r = 0.0095, 0.008  # the paper's bore and peg radii (Ø19 mm, Ø16 mm)


def test_max_misalignment_puts_the_rod_on_the_opposite_wall():
    for s in np.random.default_rng(0).uniform(0.005, 0.1, 20):
        th = max_misalignment(s, R, r)
        # the tip's sphere on one wall, the rod's far edge at the junction on the other
        assert -(R - r) + s * math.tan(th) + r / math.cos(th) == pytest.approx(R, abs=1e-12)
    # 6.5 cm of bore (16.5 cm of insertion) allows under 3 deg; deeper, less
    assert 2.0 < math.degrees(max_misalignment(0.057, R, r)) < 3.1
    angles = [max_misalignment(s, R, r) for s in (0.01, 0.02, 0.04, 0.08)]
    assert angles == sorted(angles, reverse=True)


def test_wedge_jams_deeper_with_less_friction_and_holds_more_roll_with_more():
    jams = [wedge_jam(mu, 10.0, 0.17) for mu in (0.0, 0.05, 0.1, 0.3, 0.6)]
    depths = [j.depth for j in jams]
    rolls = [j.roll_deg for j in jams]
    assert depths == sorted(depths, reverse=True) and depths[0] > depths[-1] + 0.02
    assert rolls == sorted(rolls) and rolls[-1] < 10.0
    # where it stops, the bore allows exactly the roll held
    j = jams[3]
    s = j.depth - SceneParams().funnel_length - r
    assert math.degrees(max_misalignment(s, R, r)) == pytest.approx(j.roll_deg)


def test_a_softer_rotational_admittance_or_a_smaller_misalignment_jams_later():
    pih = AdmittanceParams.preset("PiH")
    soft = dataclasses.replace(pih, stiffness_rot=tuple(0.25 * k for k in pih.stiffness_rot))
    base = wedge_jam(0.3, 10.0, 0.17)
    assert wedge_jam(0.3, 10.0, 0.17, admittance=soft).depth > base.depth
    assert wedge_jam(0.3, 5.0, 0.17).depth > base.depth
    # with no misalignment there is no couple, and nothing stops the peg before the commanded insertion
    free = wedge_jam(0.3, 0.0, 0.17)
    assert not free.jammed and free.depth == 0.17
