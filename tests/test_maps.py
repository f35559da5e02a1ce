"""Wrench-map scheduling in the loop (SPEC §3.3): modes, the paper's hard switch, the smooth blend."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from omnirotor.config import from_mapping
from omnirotor.control.allocation import Allocator
from omnirotor.control.maps import MapParams, MapScheduler
from omnirotor.errors import InputError
from omnirotor.regions import load_partition
from omnirotor.so3 import rot_x, rot_y, rot_z
from omnirotor.vehicle import load_vehicle
from omnirotor.wrench_maps import MapEntry, WrenchMapSet

VEHICLE = load_vehicle("omnirotor")
A_NOM = VEHICLE.A_nom
PARTITION = load_partition("paper")
FORCE_115 = np.array([1.15, 1.15, 1.15, 1.0, 1.0, 1.0])[:, None]


def map_set(regions: dict[str, np.ndarray], global_A: np.ndarray | None = None) -> WrenchMapSet:
    return WrenchMapSet(
        vehicle="omnirotor",
        nominal=A_NOM,
        partition=PARTITION,
        regions={k: MapEntry(A=A, points=10, identified=True) for k, A in regions.items()},
        global_=MapEntry(A=global_A, points=30, identified=True) if global_A is not None else None,
    )


R3_ONLY = map_set({"R3": A_NOM * FORCE_115}, global_A=A_NOM * 1.1)


def distinct_maps(seed: int) -> WrenchMapSet:
    """Every region its own map: force rows scaled by a different factor in 1.0 ... 1.3."""
    rng = np.random.default_rng(seed)
    return map_set({name: A_NOM * np.r_[rng.uniform(1.0, 1.3, 3), np.ones(3)][:, None] for name in PARTITION.names})


def roll(deg: float) -> np.ndarray:
    """SPEC §3.3 sliding attitude R = Rx(-theta): up direction (0, -sin theta, cos theta)."""
    return rot_x(-math.radians(deg))


def test_params_validate():
    for bad in ({"mode": "pwl"}, {"blend": "linear"}, {"blend_width_deg": 0.0}, {"blend_width_deg": 120.0}):
        with pytest.raises(InputError):
            MapParams(**bad)
    with pytest.raises(InputError):
        from_mapping(MapParams, {"mode": "nominal", "width": 3.0})


def test_nominal_mode_is_always_a_nom():
    rng = np.random.default_rng(1)
    for maps in (None, R3_ONLY):
        sched = MapScheduler(VEHICLE, maps, MapParams(mode="nominal"))
        for _ in range(20):
            np.testing.assert_array_equal(sched.select(Rotation.random(random_state=rng).as_matrix()), A_NOM)
        assert sched.region_index == -1 and sched.region_name == "nominal"


def test_global_mode_is_always_the_global_map():
    rng = np.random.default_rng(2)
    sched = MapScheduler(VEHICLE, R3_ONLY, MapParams(mode="global"))
    for _ in range(20):
        np.testing.assert_array_equal(sched.select(Rotation.random(random_state=rng).as_matrix()), A_NOM * 1.1)
    assert sched.region_index == -1 and sched.region_name == "global"


def test_bad_configurations_raise():
    with pytest.raises(InputError, match="needs a wrench-map file"):
        MapScheduler(VEHICLE, None, MapParams(mode="piecewise"))
    with pytest.raises(InputError, match="needs a wrench-map file"):
        MapScheduler(VEHICLE, None, MapParams(mode="global"))
    with pytest.raises(InputError, match="no"):
        MapScheduler(VEHICLE, map_set({}), MapParams(mode="global"))
    with pytest.raises(InputError, match="shape"):
        MapScheduler(VEHICLE, map_set({"R3": A_NOM[:, :7]}), MapParams(mode="piecewise"))
    with pytest.raises(InputError, match="NaN"):
        MapScheduler(VEHICLE, map_set({"R3": A_NOM * np.nan}), MapParams(mode="piecewise"))
    # R2-R5 and R7-R10 span 60 deg of elevation, and R1 reaches 30 deg from its border to the pole: a 70-deg
    # band would overlap the ramps of both borders and pull the neighbours' weights over the pole.
    with pytest.raises(InputError, match="wider than the narrowest region"):
        MapScheduler(VEHICLE, R3_ONLY, MapParams(mode="piecewise", blend="smooth", blend_width_deg=70.0))
    MapScheduler(VEHICLE, R3_ONLY, MapParams(mode="piecewise", blend="smooth", blend_width_deg=60.0))


def test_hard_switch_follows_the_paper_regions():
    sched = MapScheduler(VEHICLE, R3_ONLY, MapParams(mode="piecewise"))
    np.testing.assert_array_equal(sched.select(np.eye(3)), A_NOM)
    assert sched.region_name == "R1"
    np.testing.assert_array_equal(sched.select(roll(45.0)), A_NOM * FORCE_115)
    assert sched.region_name == "R3"
    # SPEC §3.3: R1 (elevation >= 60 deg, closed) up to 30 deg of roll, R3 just past it.
    sched.select(roll(30.0 - 1e-6))
    assert sched.region_name == "R1"
    sched.select(roll(30.0 + 1e-6))
    assert sched.region_name == "R3"
    # Everywhere: the region of the first-match rule, and that region's map.
    maps = distinct_maps(4)
    sched = MapScheduler(VEHICLE, maps, MapParams(mode="piecewise"))
    rng = np.random.default_rng(4)
    seen = set()
    for _ in range(300):
        R = Rotation.random(random_state=rng).as_matrix()
        A = sched.select(R)
        k = PARTITION.index_of_attitude(R)
        assert sched.region_index == k and sched.region_name == PARTITION.names[k]
        np.testing.assert_array_equal(A, maps.region_maps()[k])
        np.testing.assert_array_equal(sched.weights, np.eye(len(PARTITION.names))[k])
        seen.add(k)
    assert seen == set(range(10))


def test_select_returns_one_read_only_array_and_ignores_nan():
    sched = MapScheduler(VEHICLE, R3_ONLY, MapParams(mode="piecewise"))
    A1 = sched.select(np.eye(3))
    A2 = sched.select(roll(45.0))
    assert A1 is A2
    with pytest.raises(ValueError):
        A1[0, 0] = 1.0
    bad = roll(45.0)
    bad[2, 1] = np.nan
    np.testing.assert_array_equal(sched.select(bad), A_NOM * FORCE_115)
    assert sched.region_name == "R3"


def up_at(az_deg: float, el_deg: float) -> np.ndarray:
    """An attitude whose up direction v_B = R_WBᵀ e3 has the given azimuth and elevation."""
    return rot_x(-math.radians(90.0 - el_deg)) @ rot_z(math.radians(-90.0 - az_deg))


def test_up_at_helper():
    for az, el in ((-90.0, 60.0), (170.0, -20.0), (10.0, 45.0)):
        v = up_at(az, el)[2]
        assert math.degrees(math.atan2(v[1], v[0])) == pytest.approx(az)
        assert math.degrees(math.asin(v[2])) == pytest.approx(el)


@pytest.mark.parametrize(
    ("label", "path", "lo", "hi"),
    [
        ("roll through R1/R3", lambda d: roll(d), 20.0, 40.0),
        ("pitch through R1/R2", lambda d: rot_y(math.radians(d)), 20.0, 40.0),
        # At 40 deg of elevation, the azimuth across R3/R2 (-45 deg) ...
        ("azimuth R3/R2", lambda d: up_at(d, 40.0), -60.0, -30.0),
        # ... and through the +-180 deg seam inside R5 into R3 (-135 deg).
        ("azimuth seam R5/R3", lambda d: up_at(d, 40.0), 150.0, 240.0),
        # Down through the equator (R3 -> R8) and into the bottom cap (R8 -> R6).
        ("elevation R3/R8/R6", lambda d: roll(d), 80.0, 160.0),
        # Diagonally through the triple corner of R1, R2 and R3 (azimuth -45, elevation 60).
        ("corner R1/R2/R3", lambda d: up_at(d - 75.0, 90.0 - d), 20.0, 40.0),
    ],
)
def test_smooth_blend_is_continuous_and_hard_away_from_borders(label, path, lo, hi):
    maps = distinct_maps(7)
    stack = np.array(maps.region_maps())
    hard = MapScheduler(VEHICLE, maps, MapParams(mode="piecewise", blend="hard"))
    smooth = MapScheduler(VEHICLE, maps, MapParams(mode="piecewise", blend="smooth", blend_width_deg=10.0))
    step = 0.01
    degs = np.arange(lo, hi + step / 2, step)
    A_hard, A_smooth, regions, weights = [], [], [], []
    for R in (path(d) for d in degs):
        A_hard.append(hard.select(R).copy())
        A_smooth.append(smooth.select(R).copy())
        regions.append(hard.region_index)
        weights.append(smooth.weights.copy())
    A_hard, A_smooth, weights = np.array(A_hard), np.array(A_smooth), np.array(weights)
    assert len(set(regions)) >= 2, label  # the path really crosses a border
    # Weights are a convex combination, and the map is that combination of the region maps.
    assert np.all(weights >= 0.0)
    np.testing.assert_allclose(weights.sum(axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(A_smooth, np.einsum("sk,kij->sij", weights, stack), rtol=1e-12, atol=1e-18)
    # Hard switching jumps by a whole map difference; the blend moves by at most the smoothstep's largest
    # slope (1.5 per band width) times the step, for each unit of map difference.
    hard_jump = np.abs(np.diff(A_hard, axis=0)).max()
    smooth_jump = np.abs(np.diff(A_smooth, axis=0)).max()
    max_diff = np.abs(stack[:, None] - stack[None]).max()
    assert hard_jump > 0.01 * np.abs(A_NOM).max()
    # Every path moves azimuth and elevation by at most one step per step, so the same bound holds.
    assert smooth_jump <= 1.5 * step / 10.0 * max_diff * 1.01, (label, smooth_jump, hard_jump)
    # More than 5 deg (half a band) away from every border, the blend is the hard map.
    far = np.ones(len(degs), dtype=bool)
    switch = np.flatnonzero(np.diff(regions)) + 0.5
    for s in switch:
        far &= np.abs(np.arange(len(degs)) - s) * step > 5.0 + step
    assert far.any()
    np.testing.assert_array_equal(A_smooth[far], A_hard[far])


def test_rotor_command_jump_at_the_border_hard_vs_smooth():
    """Hover allocated at roll 30 deg -/+ eps with the R3 map's force rows 15% larger (SPEC §3.5)."""
    eps = 1e-4  # deg
    w_hover = np.array([0.0, 0.0, VEHICLE.weight, 0.0, 0.0, 0.0])
    jumps = {}
    for mode, blend in (("piecewise", "hard"), ("piecewise", "smooth"), ("nominal", "hard")):
        sched = MapScheduler(VEHICLE, R3_ONLY, MapParams(mode=mode, blend=blend))
        alloc = Allocator(VEHICLE)
        omegas = []
        for deg in (30.0 - eps, 30.0 + eps):
            R = roll(deg)
            u = alloc.solve(w_hover, R, sched.select(R))
            omegas.append(np.sign(u) * np.sqrt(np.abs(u)))
        jumps[blend if mode == "piecewise" else mode] = float(np.abs(omegas[1] - omegas[0]).max())
    print(
        f"\nrotor-speed jump across roll 30 deg +- {eps} deg: hard {jumps['hard']:.3f} Hz, "
        f"smooth {jumps['smooth']:.2e} Hz, one map (attitude change alone) {jumps['nominal']:.2e} Hz"
    )
    # Hard: the whole change of speed by the map's 15% at once (several Hz on ~140 Hz). Smooth: of the
    # order of what the 2e-4 deg attitude change alone causes with a single map.
    assert jumps["hard"] > 5.0
    assert jumps["smooth"] < 1e-3 * jumps["hard"]
    assert jumps["smooth"] < 3.0 * jumps["nominal"]
