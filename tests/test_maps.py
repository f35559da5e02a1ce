"""Wrench-map scheduling in the loop (SPEC §3.3): modes, the paper's hard switch, the smooth blend."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from omnirotor.config import from_mapping
from omnirotor.control import _map_kernels as _mk
from omnirotor.control.allocation import Allocator
from omnirotor.control.maps import MapParams, MapScheduler, _SoftRegion
from omnirotor.errors import InputError
from omnirotor.regions import Partition, Region, azimuth_elevation, load_partition
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


# -- the compiled selection (control/_map_kernels.py) against the Python algorithm it replaced ----------------


def _smoothstep(t: float) -> float:
    if t <= 0.0:
        return 0.0
    if t >= 1.0:
        return 1.0
    return t * t * (3.0 - 2.0 * t)


def _wrap_pi(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _soft_weight(s: _SoftRegion, az: float, el: float, half_band: float, inv_band: float) -> float:
    lo, hi = s.el_lo, s.el_hi
    if el <= lo - half_band or el >= hi + half_band:
        return 0.0
    w = 1.0
    if el < lo + half_band:
        w = _smoothstep((el - lo) * inv_band + 0.5)
    elif el > hi - half_band:
        w = _smoothstep((hi - el) * inv_band + 0.5)
    if s.az_full:
        return w
    a = 0.0
    for c, h in zip(s.az_centres, s.az_halves, strict=True):
        d = h - abs(_wrap_pi(az - c))
        if d >= half_band:
            return w
        if d > -half_band:
            a += _smoothstep(d * inv_band + 0.5)
    return w * a


def _depth(s: _SoftRegion, az: float, el: float) -> float:
    d = math.inf
    if s.el_lo > -math.inf:
        d = el - s.el_lo
    if s.el_hi < math.inf:
        d = min(d, s.el_hi - el)
    if not s.az_full:
        d_az = -math.inf
        for c, h in zip(s.az_centres, s.az_halves, strict=True):
            d_az = max(d_az, h - abs(_wrap_pi(az - c)))
        d = min(d, d_az)
    return d


class PythonSelect:
    """The Python ``MapScheduler.select`` the kernel replaced (piecewise mode), kept as the reference.

    ``blend_dot`` is the blended map as it was computed (``np.dot``, i.e. BLAS), ``blend_seq`` the same sum
    taken over the regions in order with separate IEEE products and sums, as the kernel takes it.
    """

    def __init__(self, maps: WrenchMapSet, smooth: bool, width_deg: float):
        self.partition = maps.partition
        self.maps = np.array(maps.region_maps())
        self.flat = self.maps.reshape(len(self.maps), -1)
        self.soft = [_SoftRegion.from_region(r) for r in self.partition.regions]
        self.smooth, self.band = smooth, math.radians(width_deg)
        self.weights = np.zeros(len(self.maps))
        self.out = self.maps[0].copy()
        self.blend_seq = self.out.copy()
        self.blended = False
        self.region_index = -1
        self.select(np.eye(3))

    def select(self, R_WB: np.ndarray) -> np.ndarray:
        az, el = azimuth_elevation(R_WB[2])
        if not (math.isfinite(az) and math.isfinite(el)):
            return self.out
        k = next((j for j, r in enumerate(self.partition.regions) if r.contains(az, el)), -1)
        if k < 0:
            return self.out
        self.region_index = k
        if self.smooth and _depth(self.soft[k], az, el) < 0.5 * self.band:
            raw = [_soft_weight(s, az, el, 0.5 * self.band, 1.0 / self.band) for s in self.soft]
            total = 0.0
            for r in raw:
                total += r
            self.weights[:] = raw
            self.weights *= 1.0 / total
            self.out = np.dot(self.weights, self.flat).reshape(self.out.shape)
            acc = np.zeros(self.flat.shape[1])
            for w, row in zip(self.weights, self.flat, strict=True):
                acc = acc + w * row
            self.blend_seq = acc.reshape(self.out.shape)
            self.blended = True
        elif self.blended or self.weights[k] != 1.0:
            self.weights[:] = 0.0
            self.weights[k] = 1.0
            self.out = self.maps[k].copy()
            self.blended = False
        return self.out


def with_up(v: np.ndarray) -> np.ndarray:
    """A (3, 3) matrix whose third row is exactly ``v`` (the only row the selection reads)."""
    R = np.eye(3)
    R[2] = v
    return R


def exact_up(az_deg: float, el_deg: float, az_off: float = 0.0, el_off: float = 0.0) -> np.ndarray:
    """A direction whose (azimuth, elevation), computed as the scheduler does, is exactly
    (radians(az_deg) + az_off, radians(el_deg) + el_off): found by stepping y, then z, one ulp at a time."""
    az_t, el_t = math.radians(az_deg) + az_off, math.radians(el_deg) + el_off
    if abs(az_t) > math.pi:  # an offset across the seam
        az_t -= math.copysign(2.0 * math.pi, az_t)
    x, y, z = math.cos(el_t) * math.cos(az_t), math.cos(el_t) * math.sin(az_t), math.sin(el_t)
    if abs(az_t) == math.pi:  # the seam: atan2(+-0.0, x < 0) is +-pi
        y = math.copysign(0.0, az_t)
    for _ in range(64):
        az = math.atan2(y, x)
        if az == az_t:
            break
        y = np.nextafter(y, math.inf if (az < az_t) == (x > 0.0) else -math.inf)
    for _ in range(64):
        el = math.atan2(z, math.hypot(x, y))
        if el == el_t:
            break
        z = np.nextafter(z, math.inf if el < el_t else -math.inf)
    v = np.array([x, y, z], dtype=float)
    assert azimuth_elevation(v) == (az_t, el_t), (az_deg, el_deg, az_off, el_off)
    return v


def nudged(v: np.ndarray, ulps=(-3, -1, 1, 3)) -> list[np.ndarray]:
    """``v`` with its y or its z component moved by a few ulps: directions just across a border."""
    out = []
    for axis in (1, 2):
        for n in ulps:
            w = v.copy()
            for _ in range(abs(n)):
                w[axis] = np.nextafter(w[axis], math.copysign(math.inf, n))
            out.append(w)
    return out


# (azimuth, elevation) [deg] on the borders of the paper's partition: sector borders, the seam, the caps,
# the equator, corners where three or four regions meet.
BORDERS = [
    (-45.0, 30.0), (45.0, 30.0), (135.0, 30.0), (-135.0, 30.0), (180.0, 30.0), (-180.0, 30.0),
    (-45.0, -30.0), (135.0, -30.0), (-90.0, 60.0), (100.0, 60.0), (10.0, 0.0), (-170.0, 0.0),
    (10.0, -60.0), (-90.0, -60.0), (180.0, -60.0), (-45.0, 60.0), (135.0, 0.0), (-135.0, -60.0),
    (-45.0, 0.0), (180.0, 0.0),
]  # fmt: skip
HALF_BAND_OFFSETS_DEG = (-5.0, 5.0, -30.0, 30.0)  # half of the 10-deg band, and of the widest (60-deg) band


def border_directions() -> list[np.ndarray]:
    """Directions exactly on every border, a few ulps to each side, and exactly at the band edges."""
    dirs = []
    for az, el in BORDERS:
        v = exact_up(az, el)
        dirs += [v, *nudged(v)]
        for off in HALF_BAND_OFFSETS_DEG:
            if abs(el + off) < 90.0:
                dirs.append(exact_up(az, el, el_off=math.radians(off)))
            if abs(el) < 80.0:
                dirs.append(exact_up(az, el, az_off=math.radians(off)))
    return dirs


def pole_directions() -> list[np.ndarray]:
    """The poles with signed zeros, subnormal and huge components, the zero vector and infinities."""
    tiny, sub = 1e-300, 5e-324
    rows = [
        (0.0, 0.0, 1.0), (-0.0, 0.0, 1.0), (0.0, -0.0, -1.0), (-0.0, -0.0, -1.0), (tiny, -tiny, 1.0),
        (sub, 0.0, -1.0), (-sub, sub, 1.0), (sub, sub, sub), (-1.0, 0.0, 0.5), (-1.0, -0.0, 0.5),
        (1e200, -1e200, 3e200), (0.0, 0.0, 0.0), (math.inf, 0.0, 0.0), (-math.inf, 1.0, 0.0),
        (1.0, 1.0, math.inf), (1.0, 1.0, -math.inf), (math.inf, math.inf, 1.0),
    ]  # fmt: skip
    return [np.array(r, dtype=float) for r in rows]


def random_directions(seed: int, count: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [Rotation.random(random_state=rng).as_matrix()[2] for _ in range(count)]


@pytest.mark.parametrize(("blend", "width"), [("hard", 10.0), ("smooth", 10.0), ("smooth", 60.0)])
def test_compiled_select_is_the_python_algorithm(blend, width):
    """Region, name, weights and map of every call as the old Python select, on a sequence of attitudes
    that goes back and forth across every border, through the poles and the bands (state carried along)."""
    maps = distinct_maps(11)
    sched = MapScheduler(VEHICLE, maps, MapParams(mode="piecewise", blend=blend, blend_width_deg=width))
    ref = PythonSelect(maps, blend == "smooth", width)
    dirs = border_directions() + pole_directions() + random_directions(12, 1500)
    rng = np.random.default_rng(13)
    order = np.r_[np.arange(len(dirs)), rng.permutation(len(dirs))]  # in order, then shuffled
    max_ulp, n_blended, seen = 0, 0, set()
    for i in order:
        R = with_up(dirs[i])
        A = sched.select(R)
        A_ref = ref.select(R)
        assert sched.region_index == ref.region_index and sched.region_name == PARTITION.names[ref.region_index]
        np.testing.assert_array_equal(sched.weights, ref.weights)
        if ref.blended:
            n_blended += 1
            np.testing.assert_array_equal(A, ref.blend_seq)
            max_ulp = max(max_ulp, int(np.max(np.abs(A.view(np.int64) - A_ref.view(np.int64)))))
        else:
            np.testing.assert_array_equal(A, A_ref)
        seen.add(ref.region_index)
    assert seen == set(range(10))
    if blend == "smooth":
        assert n_blended > 100
        # np.dot (BLAS, fused multiply-adds) and the in-order sum differ only by rounding: a few ulps of
        # entries that are sums of a handful of same-signed terms.
        assert max_ulp <= 4, max_ulp
    else:
        assert n_blended == 0


def test_compiled_select_at_exact_borders_takes_the_first_region():
    """Closed intervals, first match: on a border the earlier region, one angle ulp beyond it the next one."""
    sched = MapScheduler(VEHICLE, distinct_maps(3), MapParams(mode="piecewise"))
    names = PARTITION.names
    cases = [  # (azimuth, elevation) [deg] exactly on a border, the region there, the region just past it
        ((-45.0, 30.0), "R2", ("y", -1, "R3")),
        ((45.0, 30.0), "R2", ("y", 1, "R4")),
        ((-135.0, 30.0), "R3", ("y", 1, "R5")),  # x < 0: a larger y is a smaller azimuth
        ((135.0, 30.0), "R4", ("y", -1, "R5")),
        ((-90.0, 60.0), "R1", ("z", -1, "R3")),
        ((10.0, 0.0), "R2", ("z", -1, "R7")),
        ((10.0, -60.0), "R6", ("z", 1, "R7")),
    ]
    for (az, el), on, (axis, step, past) in cases:
        v = exact_up(az, el)
        sched.select(with_up(v))
        assert sched.region_name == on, (az, el)
        w, i = v.copy(), "xyz".index(axis)
        angle = 0 if axis == "y" else 1  # y moves the azimuth (and a little the elevation), z the elevation
        while azimuth_elevation(w)[angle] == azimuth_elevation(v)[angle]:  # to the next angle past the border
            w[i] = np.nextafter(w[i], math.copysign(math.inf, step))
        sched.select(with_up(w))
        assert sched.region_name == past, (az, el)
        assert PARTITION.index_of_direction(w) == names.index(past)
    for v in (np.array([-1.0, 0.0, 0.5]), np.array([-1.0, -0.0, 0.5])):  # azimuth +pi and -pi: the seam
        sched.select(with_up(v))
        assert sched.region_name == "R5"
    for v, name in ((np.array([-0.0, -0.0, 1.0]), "R1"), (np.array([5e-324, -0.0, -1.0]), "R6")):
        sched.select(with_up(v))
        assert sched.region_name == name


def test_py_hypot_and_azimuth_elevation_are_pythons():
    """The kernel's hypot is CPython's math.hypot (not the C library's) to the last bit, and so are the
    azimuth and elevation, over unit vectors, wide and subnormal magnitudes, and the special values; its
    azimuth wrap is Python's."""
    rng = np.random.default_rng(21)
    n = 20000
    unit = rng.normal(size=(n, 3))
    unit /= np.linalg.norm(unit, axis=1)[:, None]
    wide = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-300.0, 300.0, (n, 3))
    small = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-323.0, -305.0, (n, 3))
    specials = [0.0, -0.0, 5e-324, -2.2250738585072014e-308, 1.0, -3.0, 1.7976931348623157e308, math.inf]
    special = np.array([(a, b, c) for a in specials + [math.nan] for b in specials for c in (1.0, -0.0)])
    for v in np.concatenate([unit, wide, small, special]):
        x, y, z = (float(c) for c in v)
        for got, want in (
            (_mk.py_hypot(x, y), math.hypot(x, y)),
            *zip(_mk.azimuth_elevation(x, y, z), azimuth_elevation(v), strict=True),
        ):
            assert struct.pack("<d", got) == struct.pack("<d", want) or (math.isnan(got) and math.isnan(want)), (
                v, got, want,
            )  # fmt: skip
    # The C library's hypot is not it: were the kernel to call it, unit vectors would already differ.
    libm = [np.hypot(x, y) != math.hypot(x, y) for x, y, _ in unit]
    assert any(libm)
    # The azimuth wrap is Python's float modulo, multiples of 2 pi and the seam included.
    angles = np.r_[rng.uniform(-4.0 * math.pi, 4.0 * math.pi, n), np.arange(-8, 9) * math.pi, [0.0, -0.0, 1e-300]]
    for a in np.r_[angles, np.nextafter(angles, math.inf), np.nextafter(angles, -math.inf)]:
        got, want = _mk._wrap_pi(float(a)), _wrap_pi(float(a))
        assert struct.pack("<d", got) == struct.pack("<d", want), (a, got, want)


def test_select_depends_only_on_the_attitude():
    """No hysteresis: after any history, select gives what a fresh scheduler gives (map, weights, region)."""
    maps = distinct_maps(5)
    for blend in ("hard", "smooth"):
        params = MapParams(mode="piecewise", blend=blend, blend_width_deg=20.0)
        busy = MapScheduler(VEHICLE, maps, params)
        dirs = border_directions()[::3] + random_directions(6, 200)
        rng = np.random.default_rng(7)
        for i in rng.integers(0, len(dirs), 400):
            R = with_up(dirs[i])
            A = busy.select(R)
            fresh = MapScheduler(VEHICLE, maps, params)
            np.testing.assert_array_equal(A, fresh.select(R))
            np.testing.assert_array_equal(busy.weights, fresh.weights)
            assert busy.region_index == fresh.region_index


def test_scheduler_records_for_a_compiled_loop():
    """schedule_select on the scheduler's own arrays is select: it writes the returned view and the weights,
    sync() takes over the region; NaN and the constant modes write nothing."""
    maps = distinct_maps(8)
    sched = MapScheduler(VEHICLE, maps, MapParams(mode="piecewise", blend="smooth"))
    twin = MapScheduler(VEHICLE, maps, MapParams(mode="piecewise", blend="smooth"))
    A = sched.select(np.eye(3))
    arrays = sched.arrays[0]
    assert arrays["maps"].shape == (10, 6 * VEHICLE.n_rotors) and np.shares_memory(A, arrays["out"])
    assert np.shares_memory(sched.weights, arrays["weights"])
    assert sched.state.dtype == _mk.STATE_DTYPE and arrays["regions"].dtype == _mk.REGION_DTYPE
    for deg in (45.0, 31.0, 29.0, 100.0, 150.0):  # R3, the R1/R3 band on both sides, R8, R6
        R = roll(deg)
        k = _mk.schedule_select(sched.state[0], arrays, R)
        assert k == PARTITION.index_of_attitude(R)
        assert sched.region_index != k or deg == 31.0  # not yet synced (31 deg stays in R3 after 45 deg)
        sched.sync()
        assert sched.region_index == k and sched.region_name == PARTITION.names[k]
        np.testing.assert_array_equal(A, twin.select(R))
        np.testing.assert_array_equal(sched.weights, twin.weights)
    before = (A.copy(), sched.weights.copy(), sched.state["region"].copy(), sched.state["blended"].copy())
    bad = roll(45.0)
    bad[2, 0] = np.nan
    k = _mk.schedule_select(sched.state[0], arrays, bad)
    assert k == sched.region_index and sched.n_nonfinite == 1  # the map is kept, the attitude counted
    for got, want in zip((A, sched.weights, sched.state["region"], sched.state["blended"]), before, strict=True):
        np.testing.assert_array_equal(got, want)
    for mode in ("nominal", "global"):
        const = MapScheduler(VEHICLE, R3_ONLY, MapParams(mode=mode))
        out = const.arrays["out"].copy()
        k = _mk.schedule_select(const.state[0], const.arrays[0], roll(45.0))
        assert k == -1
        np.testing.assert_array_equal(const.arrays["out"], out)
        const.sync()
        assert const.region_index == -1 and const.region_name == mode


def test_hole_in_a_user_partition_keeps_the_last_map():
    """A gap the load-time grid check missed: select keeps the previous region and map, as before."""
    gap = Partition(
        "gap",
        (
            Region("west", ((-180.0, 0.0),), (-90.0, 90.0)),
            Region("east", ((0.001, 180.0),), (-90.0, 90.0)),
        ),
    )
    A_west, A_east = A_NOM * 1.1, A_NOM * 1.2
    maps = WrenchMapSet(
        vehicle="omnirotor",
        nominal=A_NOM,
        partition=gap,
        regions={
            "west": MapEntry(A=A_west, points=10, identified=True),
            "east": MapEntry(A=A_east, points=10, identified=True),
        },
    )
    for blend in ("hard", "smooth"):
        sched = MapScheduler(VEHICLE, maps, MapParams(mode="piecewise", blend=blend, blend_width_deg=1e-4))
        in_gap = with_up(exact_up(0.0005, 10.0))
        for v, name, A in ((exact_up(90.0, 10.0), "east", A_east), (exact_up(-90.0, 10.0), "west", A_west)):
            np.testing.assert_array_equal(sched.select(with_up(v)), A)
            np.testing.assert_array_equal(sched.select(in_gap), A)
            assert sched.region_name == name
