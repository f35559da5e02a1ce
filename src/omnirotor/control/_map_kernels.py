"""Compiled per-step wrench-map selection of :class:`omnirotor.control.maps.MapScheduler` (SPEC §3.3).

:func:`schedule_select` is the whole of :meth:`MapScheduler.select` in piecewise mode, in one compiled call
that a compiled control loop can make as well: the azimuth and elevation of the up direction
``v_B = R_WBᵀ e3`` (the third row of ``R_WB``), the first region whose closed intervals contain it (as
:meth:`omnirotor.regions.Region.contains`), and with ``blend = "smooth"`` near a border the normalised soft
weights and the blended map (the formulas are in the docstring of :mod:`omnirotor.control.maps`).

The partition is packed once by :func:`pack_schedule` into one float64 array:

* header ``SCH_*``: number of regions K (0 outside piecewise mode), interval slots M per region, smooth
  flag, half band width [rad], inverse band width [1/rad];
* then K region blocks of :func:`region_stride` (M) entries each, from ``SCH_HEADER``: the closed elevation
  interval and the count of azimuth intervals of the hard test (``REG_EL_LO``, ``REG_EL_HI``, ``REG_N_AZ``),
  the soft elevation interval (±inf where the edge is a pole), the full-circle flag and the count of
  merged circular azimuth intervals, then ``REG_N_GROUPS`` groups of M slots (padded with 0): the hard
  test's azimuth lower and upper bounds, the soft intervals' centres and half-widths [rad].

What changes from call to call is kept in a small float64 ``state`` (``STATE_*``): the current region index
(-1 before the first selection) and whether the output holds a blend.

Arithmetic is that of the Python float code it replaced, in the same order: the azimuth and elevation use
:func:`py_hypot`, which is CPython 3.11's ``math.hypot`` (the C library's ``hypot``, which numba calls, differs
from it in the last bit on about 0.7 % of unit vectors), and the azimuth wrap is Python's float modulo. The
one exception is the blended map ``sum_k w_k A_k``, summed here over k in order, where NumPy's ``np.dot``
called BLAS (with fused multiply-adds): the two differ by at most 2 ulps of an entry (measured).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from omnirotor._jit import jit
from omnirotor.regions import Region

__all__ = [
    "pack_schedule",
    "schedule_select",
    "state_buffer",
    "py_hypot",
    "azimuth_elevation",
    "region_stride",
]

# -- packed schedule: header -------------------------------------------------------------------------------
SCH_N_REGIONS = 0  # K (0: nominal or global mode, the map never changes)
SCH_MAX_IV = 1  # M: azimuth-interval slots per region block
SCH_SMOOTH = 2  # 1: smooth blend, 0: hard switch
SCH_HALF_BAND = 3  # half the band width [rad]
SCH_INV_BAND = 4  # 1 / band width [1/rad]
SCH_HEADER = 5  # first region block

# -- packed schedule: one region block ---------------------------------------------------------------------
REG_EL_LO = 0  # closed elevation interval of the hard test [rad]
REG_EL_HI = 1
REG_N_AZ = 2  # number of azimuth intervals of the hard test
REG_SOFT_EL_LO = 3  # soft elevation interval [rad]; -inf / +inf where the edge is a pole (no border)
REG_SOFT_EL_HI = 4
REG_AZ_FULL = 5  # 1: the azimuth spans the whole circle (no azimuth border)
REG_N_SOFT = 6  # number of merged circular azimuth intervals
REG_HEADER = 7
# Then REG_N_GROUPS groups of M slots each, group g at REG_HEADER + g * M:
REG_AZ_LO = 0  # the hard test's azimuth lower bounds [rad]
REG_AZ_HI = 1  # its upper bounds [rad]
REG_CENTRE = 2  # centres of the merged circular azimuth intervals [rad]
REG_HALF = 3  # their half-widths [rad]
REG_N_GROUPS = 4

# -- state between calls -----------------------------------------------------------------------------------
STATE_REGION = 0  # index of the current region; -1 before the first selection
STATE_BLENDED = 1  # 1 while the output holds a blend rather than one region's map
STATE_SIZE = 2

# -- CPython's math.hypot (Modules/mathmodule.c, 3.11) -----------------------------------------------------
_SPLIT = 134217729.0  # 2**27 + 1: Veltkamp's constant, splits a double into two halves of 26 bits
_MIN_NORMAL_EXP = -1023  # frexp exponent below which the power-of-two scaling 2**-e would overflow
_TWO_PI = 2.0 * math.pi


def region_stride(max_iv: int) -> int:
    """Length of one region block of the packed schedule with ``max_iv`` interval slots per group."""
    return REG_HEADER + REG_N_GROUPS * max_iv


def pack_schedule(regions: Sequence[Region], soft: Sequence, smooth: bool, band_rad: float) -> np.ndarray:
    """The packed schedule (layout in the module docstring) of a partition.

    Args:
        regions: the partition's regions in order (empty outside piecewise mode); their closed intervals
            are converted to radians as :class:`omnirotor.regions.Region` does for ``contains``.
        soft: the same regions as circular intervals, one per region, each with the attributes
            ``az_full``, ``az_centres``, ``az_halves`` [rad], ``el_lo``, ``el_hi`` [rad, ±inf at a pole]
            (``omnirotor.control.maps._SoftRegion``).
        smooth: blend near the borders (``blend = "smooth"``) rather than switch.
        band_rad: total width of the blending band [rad], > 0.

    Returns:
        (SCH_HEADER + K * region_stride(M),) float64 array.
    """
    if len(soft) != len(regions):
        raise ValueError(f"pack_schedule: {len(regions)} regions but {len(soft)} soft regions")
    max_iv = max((max(len(r.azimuth_deg), len(s.az_centres)) for r, s in zip(regions, soft, strict=True)), default=0)
    stride = region_stride(max_iv)
    out = np.zeros(SCH_HEADER + len(regions) * stride)
    out[SCH_N_REGIONS] = len(regions)
    out[SCH_MAX_IV] = max_iv
    out[SCH_SMOOTH] = 1.0 if smooth else 0.0
    out[SCH_HALF_BAND] = 0.5 * band_rad
    out[SCH_INV_BAND] = 1.0 / band_rad
    for j, (region, s) in enumerate(zip(regions, soft, strict=True)):
        blk = out[SCH_HEADER + j * stride : SCH_HEADER + (j + 1) * stride]
        blk[REG_EL_LO] = math.radians(region.elevation_deg[0])
        blk[REG_EL_HI] = math.radians(region.elevation_deg[1])
        blk[REG_N_AZ] = len(region.azimuth_deg)
        blk[REG_SOFT_EL_LO] = s.el_lo
        blk[REG_SOFT_EL_HI] = s.el_hi
        blk[REG_AZ_FULL] = 1.0 if s.az_full else 0.0
        blk[REG_N_SOFT] = len(s.az_centres)
        for i, (lo, hi) in enumerate(region.azimuth_deg):
            blk[REG_HEADER + REG_AZ_LO * max_iv + i] = math.radians(lo)
            blk[REG_HEADER + REG_AZ_HI * max_iv + i] = math.radians(hi)
        for i, (c, h) in enumerate(zip(s.az_centres, s.az_halves, strict=True)):
            blk[REG_HEADER + REG_CENTRE * max_iv + i] = c
            blk[REG_HEADER + REG_HALF * max_iv + i] = h
    return out


def state_buffer() -> np.ndarray:
    """A fresh (STATE_SIZE,) selection state: no region selected yet, no blend."""
    state = np.zeros(STATE_SIZE)
    state[STATE_REGION] = -1.0
    return state


@jit
def py_hypot(x: float, y: float) -> float:
    """``math.hypot(x, y)`` of CPython 3.11, to the last bit.

    The components are scaled by a power of two, squared exactly (Veltkamp split), summed with error
    compensation, and the square root gets one differential correction; when that scaling would overflow
    (both components subnormal) the sum of squares of the components divided by the largest is used.
    """
    a0 = abs(x)
    a1 = abs(y)
    if math.isinf(a0) or math.isinf(a1):
        return math.inf
    if math.isnan(a0) or math.isnan(a1):
        return math.nan
    big = 0.0
    if a0 > big:
        big = a0
    if a1 > big:
        big = a1
    if big == 0.0:
        return big
    e = math.frexp(big)[1]
    csum = 1.0
    frac1 = 0.0
    if e < _MIN_NORMAL_EXP:
        for a in (a0, a1):
            t = a / big
            t = t * t
            old = csum
            csum += t
            frac1 += (old - csum) + t
        return big * math.sqrt(csum - 1.0 + frac1)
    frac2 = 0.0
    frac3 = 0.0
    scale = math.ldexp(1.0, -e)
    for a in (a0, a1):
        v = a * scale
        t = v * _SPLIT
        hi = t - (t - v)
        lo = v - hi
        t = hi * hi
        old = csum
        csum += t
        frac1 += (old - csum) + t
        t = 2.0 * hi * lo
        old = csum
        csum += t
        frac2 += (old - csum) + t
        frac3 += lo * lo
    h = math.sqrt(csum - 1.0 + (frac1 + frac2 + frac3))
    t = h * _SPLIT
    hi = t - (t - h)
    lo = h - hi
    t = -hi * hi
    old = csum
    csum += t
    frac1 += (old - csum) + t
    t = -2.0 * hi * lo
    old = csum
    csum += t
    frac2 += (old - csum) + t
    t = -lo * lo
    old = csum
    csum += t
    frac3 += (old - csum) + t
    t = csum - 1.0 + (frac1 + frac2 + frac3)
    return (h + t / (2.0 * h)) / scale


@jit
def azimuth_elevation(x: float, y: float, z: float) -> tuple[float, float]:
    """Azimuth and elevation [rad] of a body-frame direction ``(x, y, z)`` (need not be unit).

    Same numbers as :func:`omnirotor.regions.azimuth_elevation`.
    """
    return math.atan2(y, x), math.atan2(z, py_hypot(x, y))


@jit
def _smoothstep(t: float) -> float:
    """``3t² - 2t³`` on t clipped to [0, 1]."""
    if t <= 0.0:
        return 0.0
    if t >= 1.0:
        return 1.0
    return t * t * (3.0 - 2.0 * t)


@jit
def _wrap_pi(a: float) -> float:
    """Angle [rad] wrapped to [-pi, pi): Python's ``(a + pi) % (2 pi) - pi``.

    Python's float modulo is the (exact) C ``fmod`` moved into [0, 2 pi) by adding 2 pi to a negative
    remainder; written out, as numba's own ``%`` compiles to much slower code here.
    """
    r = np.fmod(a + math.pi, _TWO_PI)
    if r < 0.0:
        r += _TWO_PI
    return r - math.pi


@jit
def _contains(sched: np.ndarray, b: int, m: int, az: float, el: float) -> bool:
    """The hard test of the region block at ``b``: (az, el) [rad] in its closed intervals."""
    if el < sched[b + REG_EL_LO] or el > sched[b + REG_EL_HI]:
        return False
    lo = b + REG_HEADER + REG_AZ_LO * m
    hi = b + REG_HEADER + REG_AZ_HI * m
    for i in range(int(sched[b + REG_N_AZ])):
        if sched[lo + i] <= az <= sched[hi + i]:
            return True
    return False


@jit
def _depth(sched: np.ndarray, b: int, m: int, az: float, el: float) -> float:
    """Smallest angular distance [rad] from (az, el), inside the region at ``b``, to one of its borders."""
    d = math.inf
    el_lo = sched[b + REG_SOFT_EL_LO]
    el_hi = sched[b + REG_SOFT_EL_HI]
    if el_lo > -math.inf:
        d = el - el_lo
    if el_hi < math.inf:
        d_hi = el_hi - el
        if d_hi < d:
            d = d_hi
    if sched[b + REG_AZ_FULL] == 0.0:
        c0 = b + REG_HEADER + REG_CENTRE * m
        h0 = b + REG_HEADER + REG_HALF * m
        d_az = -math.inf
        for i in range(int(sched[b + REG_N_SOFT])):
            di = sched[h0 + i] - abs(_wrap_pi(az - sched[c0 + i]))
            if di > d_az:
                d_az = di
        if d_az < d:
            d = d_az
    return d


@jit
def _soft_weight(sched: np.ndarray, b: int, m: int, az: float, el: float, half_band: float, inv_band: float) -> float:
    """Raw soft membership of (az, el) [rad] in the region at ``b`` (band half-width ``half_band`` [rad])."""
    lo = sched[b + REG_SOFT_EL_LO]
    hi = sched[b + REG_SOFT_EL_HI]
    if el <= lo - half_band or el >= hi + half_band:
        return 0.0
    w = 1.0
    if el < lo + half_band:
        w = _smoothstep((el - lo) * inv_band + 0.5)
    elif el > hi - half_band:
        w = _smoothstep((hi - el) * inv_band + 0.5)
    if sched[b + REG_AZ_FULL] != 0.0:
        return w
    c0 = b + REG_HEADER + REG_CENTRE * m
    h0 = b + REG_HEADER + REG_HALF * m
    a = 0.0
    for i in range(int(sched[b + REG_N_SOFT])):
        d = sched[h0 + i] - abs(_wrap_pi(az - sched[c0 + i]))  # signed distance inside the interval [rad]
        if d >= half_band:
            return w
        if d > -half_band:
            a += _smoothstep(d * inv_band + 0.5)
    return w * a


@jit
def schedule_select(
    sched: np.ndarray,
    R: np.ndarray,
    maps_flat: np.ndarray,
    out_flat: np.ndarray,
    weights: np.ndarray,
    state: np.ndarray,
) -> int:
    """Select (or blend) the wrench map of attitude ``R`` (SPEC §3.3): :meth:`MapScheduler.select`.

    Args:
        sched: packed schedule (:func:`pack_schedule`).
        R: (3, 3) attitude ``R_WB``, body to world; its third row is the up direction ``v_B``.
        maps_flat: (K, 6n) region maps, row-major (6, n) each.
        out_flat: (6n,) the selected map, written when the selection changes or a blend is computed.
        weights: (K,) blending weights, written with the map (one-hot with hard blending).
        state: (STATE_SIZE,) selection state, updated (:func:`state_buffer` makes a fresh one).

    Returns:
        Index of the region of ``R`` (first match); the current index, with nothing written, when ``R``'s
        up direction has a NaN or lies in no region; -1 when K = 0 (nominal or global mode: the map is
        constant and nothing is written).
    """
    n_regions = int(sched[SCH_N_REGIONS])
    if n_regions == 0:
        return -1
    az, el = azimuth_elevation(R[2, 0], R[2, 1], R[2, 2])
    current = int(state[STATE_REGION])
    if not (math.isfinite(az) and math.isfinite(el)):
        return current
    m = int(sched[SCH_MAX_IV])
    stride = REG_HEADER + REG_N_GROUPS * m
    k = -1
    for j in range(n_regions):
        if _contains(sched, SCH_HEADER + j * stride, m, az, el):
            k = j
            break
    if k < 0:  # a hole in a user partition (the grid check at load missed it): keep the last map
        return current
    state[STATE_REGION] = k
    half_band = sched[SCH_HALF_BAND]
    n_out = out_flat.shape[0]
    if sched[SCH_SMOOTH] != 0.0 and _depth(sched, SCH_HEADER + k * stride, m, az, el) < half_band:
        inv_band = sched[SCH_INV_BAND]
        total = 0.0
        for j in range(n_regions):
            w = _soft_weight(sched, SCH_HEADER + j * stride, m, az, el, half_band, inv_band)
            weights[j] = w
            total += w
        inv_total = 1.0 / total
        for j in range(n_regions):
            weights[j] *= inv_total
        # sum_j w_j A_j over j in order; a zero weight adds +-0.0, which leaves every sum as it is (a sum
        # that starts at +0.0 is never -0.0), so those regions are skipped.
        for i in range(n_out):
            out_flat[i] = 0.0
        for j in range(n_regions):
            w = weights[j]
            if w != 0.0:
                for i in range(n_out):
                    out_flat[i] += w * maps_flat[j, i]
        state[STATE_BLENDED] = 1.0
    elif state[STATE_BLENDED] != 0.0 or weights[k] != 1.0:
        for j in range(n_regions):
            weights[j] = 0.0
        weights[k] = 1.0
        for i in range(n_out):
            out_flat[i] = maps_flat[k, i]
        state[STATE_BLENDED] = 0.0
    return k


@jit
def region_of(state) -> float:
    """The current region index of a selection state (-1 before the first selection)."""
    return state[STATE_REGION]
