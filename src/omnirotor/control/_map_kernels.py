"""Compiled per-step wrench-map selection of :class:`omnirotor.control.maps.MapScheduler` (SPEC §3.3).

:func:`schedule_select` is the whole of :meth:`MapScheduler.select` in piecewise mode, in one compiled call
that the controller's compiled step makes as well: the azimuth and elevation of the up direction
``v_B = R_WBᵀ e3`` (the third row of ``R_WB``), the first region whose closed intervals contain it (as
:meth:`omnirotor.regions.Region.contains`), and with ``blend = "smooth"`` near a border the normalised soft
weights and the blended map (the formulas are in the docstring of :mod:`omnirotor.control.maps`).

The scheduler's state and parameters are one structured record (:data:`STATE_DTYPE`: the current region,
the blend flag, the count of non-finite attitudes, the blending band); the partition and the maps, whose
sizes depend on the partition (K regions, at most M azimuth intervals per region) and on the vehicle (n
rotors), are the subarray fields of one more record (:func:`arrays_dtype`, sized for a partition of at most K
regions of at most M intervals), written once by :func:`pack_schedule`: one :data:`REGION_DTYPE` record per
region (its elevation intervals and interval counts) and the (K, M) tables of its azimuth intervals (padded
with 0). In the controller both records are fields of its state (``maps``, ``maps_arrays``).

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

from omnirotor._jit import jit, jit_entry
from omnirotor.regions import Region

__all__ = [
    "STATE_DTYPE",
    "REGION_DTYPE",
    "arrays_dtype",
    "pack_schedule",
    "schedule_select",
    "schedule_select_entry",
    "py_hypot",
    "azimuth_elevation",
]

_F8, _I8 = np.float64, np.int64
STATE_DTYPE = np.dtype(
    [
        ("region", _I8),  # index of the current region; -1 before the first selection (and outside piecewise)
        ("blended", _I8),  # 1 while the output holds a blend rather than one region's map
        ("n_nonfinite", _F8),  # selections asked for a non-finite attitude (the map was kept)
        # parameters
        ("n_regions", _I8),  # K (0: nominal or global mode, the map never changes)
        ("smooth", _I8),  # 1: smooth blend, 0: hard switch
        ("half_band_rad", _F8),  # half the band width [rad]
        ("inv_band_per_rad", _F8),  # 1 / band width [1/rad]
    ]
)
"""The scheduler's state and parameters (named fields; the kernel reads them so)."""

REGION_DTYPE = np.dtype(
    [
        ("el_lo_rad", _F8),  # closed elevation interval of the hard test [rad]
        ("el_hi_rad", _F8),
        ("n_az", _I8),  # number of azimuth intervals of the hard test
        ("soft_el_lo_rad", _F8),  # soft elevation interval [rad]; -inf / +inf where the edge is a pole
        ("soft_el_hi_rad", _F8),
        ("az_full", _I8),  # 1: the azimuth spans the whole circle (no azimuth border)
        ("n_soft", _I8),  # number of merged circular azimuth intervals
    ]
)
"""One region of the partition, as the kernel reads it."""


def arrays_dtype(n_regions: int, n_intervals: int, n_rotors: int) -> np.dtype:
    """The partition's and the maps' arrays for up to ``n_regions`` regions of ``n_intervals`` azimuth intervals.

    Sizes of at least 1 (a nominal or global scheduler uses one map and no region). Fields: ``regions`` (K,)
    :data:`REGION_DTYPE`; ``az_lo_rad``, ``az_hi_rad`` (K, M) the hard test's azimuth bounds [rad];
    ``az_centre_rad``, ``az_half_rad`` (K, M) the merged circular intervals' centres and half-widths [rad];
    ``maps`` (K, 6n) the region maps, (6, n) row-major each (one map outside piecewise mode); ``out`` (6, n) the
    map in use (a 2-D field: compiled code reads it without a reshape); ``weights`` (K,) the blending weights
    (one-hot with hard blending).
    """
    K, M, m = max(1, n_regions), max(1, n_intervals), 6 * n_rotors
    return np.dtype(
        [
            ("regions", REGION_DTYPE, (K,)),
            ("az_lo_rad", _F8, (K, M)),
            ("az_hi_rad", _F8, (K, M)),
            ("az_centre_rad", _F8, (K, M)),
            ("az_half_rad", _F8, (K, M)),
            ("maps", _F8, (K, m)),
            ("out", _F8, (6, n_rotors)),
            ("weights", _F8, (K,)),
        ]
    )


def n_intervals(regions: Sequence[Region], soft: Sequence) -> int:
    """The azimuth-interval slots ``regions`` need (the hard intervals or the merged soft ones, the larger)."""
    return max((max(len(r.azimuth_deg), len(s.az_centres)) for r, s in zip(regions, soft, strict=True)), default=0)


def pack_schedule(
    state, arrays, regions: Sequence[Region], soft: Sequence, smooth: bool, band_rad: float, maps
) -> None:
    """Write the parameters of a partition into the records ``state`` and ``arrays``.

    Args:
        state: the scheduler's record (:data:`STATE_DTYPE`); its state is set to "no region selected yet".
        arrays: its arrays' record (:func:`arrays_dtype`, fields as attributes), large enough; zeroed here.
        regions: the partition's regions in order (empty outside piecewise mode); their closed intervals
            are converted to radians as :class:`omnirotor.regions.Region` does for ``contains``.
        soft: the same regions as circular intervals, one per region, each with the attributes
            ``az_full``, ``az_centres``, ``az_halves`` [rad], ``el_lo``, ``el_hi`` [rad, ±inf at a pole]
            (``omnirotor.control.maps._SoftRegion``).
        smooth: blend near the borders (``blend = "smooth"``) rather than switch.
        band_rad: total width of the blending band [rad], > 0.
        maps: (K', 6n) the maps to choose from (K' = K, or 1 outside piecewise mode); the output starts as
            the first.

    Raises:
        ValueError: ``arrays`` too small for the partition, or ``soft`` not one per region.
    """
    if len(soft) != len(regions):
        raise ValueError(f"pack_schedule: {len(regions)} regions but {len(soft)} soft regions")
    max_iv = n_intervals(regions, soft)
    K = len(regions)
    maps = np.asarray(maps, dtype=np.float64)
    cap_k, cap_m = arrays.az_lo_rad.shape
    if K > cap_k or max_iv > cap_m or maps.shape[0] > arrays.maps.shape[0] or maps.shape[1] != arrays.out.size:
        raise ValueError(
            f"pack_schedule: {K} regions of {max_iv} intervals and {maps.shape} maps do not fit arrays for "
            f"{cap_k} regions of {cap_m} intervals and {arrays.maps.shape} maps"
        )
    for name in arrays.dtype.names:
        arrays[name] = 0
    state["region"] = -1
    state["blended"] = 0
    state["n_regions"] = K
    state["smooth"] = 1 if smooth else 0
    state["half_band_rad"] = 0.5 * band_rad
    state["inv_band_per_rad"] = 1.0 / band_rad
    table = arrays.regions
    az = (arrays.az_lo_rad, arrays.az_hi_rad, arrays.az_centre_rad, arrays.az_half_rad)
    for j, (region, s) in enumerate(zip(regions, soft, strict=True)):
        r = table[j]
        r["el_lo_rad"] = math.radians(region.elevation_deg[0])
        r["el_hi_rad"] = math.radians(region.elevation_deg[1])
        r["n_az"] = len(region.azimuth_deg)
        r["soft_el_lo_rad"] = s.el_lo
        r["soft_el_hi_rad"] = s.el_hi
        r["az_full"] = 1 if s.az_full else 0
        r["n_soft"] = len(s.az_centres)
        for i, (lo, hi) in enumerate(region.azimuth_deg):
            az[0][j, i] = math.radians(lo)
            az[1][j, i] = math.radians(hi)
        for i, (c, h) in enumerate(zip(s.az_centres, s.az_halves, strict=True)):
            az[2][j, i] = c
            az[3][j, i] = h
    arrays.maps[: maps.shape[0]] = maps
    arrays.out[:] = maps[0].reshape(arrays.out.shape)


# -- CPython's math.hypot (Modules/mathmodule.c, 3.11) -----------------------------------------------------
_SPLIT = 134217729.0  # 2**27 + 1: Veltkamp's constant, splits a double into two halves of 26 bits
_MIN_NORMAL_EXP = -1023  # frexp exponent below which the power-of-two scaling 2**-e would overflow
_TWO_PI = 2.0 * math.pi


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
def _contains(r, az_lo, az_hi, az: float, el: float) -> bool:
    """The hard test of the region ``r`` (its azimuth bounds ``az_lo``, ``az_hi``): (az, el) [rad] inside."""
    if el < r.el_lo_rad or el > r.el_hi_rad:
        return False
    for i in range(r.n_az):
        if az_lo[i] <= az <= az_hi[i]:
            return True
    return False


@jit
def _depth(r, centres, halves, az: float, el: float) -> float:
    """Smallest angular distance [rad] from (az, el), inside the region ``r``, to one of its borders."""
    d = math.inf
    el_lo = r.soft_el_lo_rad
    el_hi = r.soft_el_hi_rad
    if el_lo > -math.inf:
        d = el - el_lo
    if el_hi < math.inf:
        d_hi = el_hi - el
        if d_hi < d:
            d = d_hi
    if r.az_full == 0:
        d_az = -math.inf
        for i in range(r.n_soft):
            di = halves[i] - abs(_wrap_pi(az - centres[i]))
            if di > d_az:
                d_az = di
        if d_az < d:
            d = d_az
    return d


@jit
def _soft_weight(r, centres, halves, az: float, el: float, half_band: float, inv_band: float) -> float:
    """Raw soft membership of (az, el) [rad] in the region ``r`` (band half-width ``half_band`` [rad])."""
    lo = r.soft_el_lo_rad
    hi = r.soft_el_hi_rad
    if el <= lo - half_band or el >= hi + half_band:
        return 0.0
    w = 1.0
    if el < lo + half_band:
        w = _smoothstep((el - lo) * inv_band + 0.5)
    elif el > hi - half_band:
        w = _smoothstep((hi - el) * inv_band + 0.5)
    if r.az_full != 0:
        return w
    a = 0.0
    for i in range(r.n_soft):
        d = halves[i] - abs(_wrap_pi(az - centres[i]))  # signed distance inside the interval [rad]
        if d >= half_band:
            return w
        if d > -half_band:
            a += _smoothstep(d * inv_band + 0.5)
    return w * a


@jit
def schedule_select(st, arrays, R) -> int:
    """Select (or blend) the wrench map of attitude ``R`` (SPEC §3.3): :meth:`MapScheduler.select`.

    Args:
        st: the scheduler's record (:data:`STATE_DTYPE`), updated.
        arrays: its arrays' record (:func:`arrays_dtype`); ``out`` and ``weights`` are written when the
            selection changes or a blend is computed.
        R: (3, 3) attitude ``R_WB``, body to world; its third row is the up direction ``v_B``.

    Returns:
        Index of the region of ``R`` (first match); the current index, with nothing written, when ``R``'s
        up direction has a NaN or lies in no region; -1 when K = 0 (nominal or global mode: the map is
        constant and nothing is written). A non-finite ``R`` is counted in ``n_nonfinite``.
    """
    n_regions = st.n_regions
    if n_regions == 0:
        return -1
    current = st.region
    finite = True
    for i in range(3):
        for j in range(3):
            finite = finite and math.isfinite(R[i, j])
    if not finite:
        st.n_nonfinite += 1.0
    az, el = azimuth_elevation(R[2, 0], R[2, 1], R[2, 2])
    if not (math.isfinite(az) and math.isfinite(el)):
        return current
    regions, maps, out, weights = arrays.regions, arrays.maps, arrays.out, arrays.weights
    k = -1
    for j in range(n_regions):
        if _contains(regions[j], arrays.az_lo_rad[j], arrays.az_hi_rad[j], az, el):
            k = j
            break
    if k < 0:  # a hole in a user partition (the grid check at load missed it): keep the last map
        return current
    st.region = k
    half_band = st.half_band_rad
    n_cols = out.shape[1]
    centres, halves = arrays.az_centre_rad, arrays.az_half_rad
    if st.smooth != 0 and _depth(regions[k], centres[k], halves[k], az, el) < half_band:
        inv_band = st.inv_band_per_rad
        total = 0.0
        for j in range(n_regions):
            w = _soft_weight(regions[j], centres[j], halves[j], az, el, half_band, inv_band)
            weights[j] = w
            total += w
        inv_total = 1.0 / total
        for j in range(n_regions):
            weights[j] *= inv_total
        # sum_j w_j A_j over j in order; a zero weight adds +-0.0, which leaves every sum as it is (a sum
        # that starts at +0.0 is never -0.0), so those regions are skipped.
        for r in range(6):
            for c in range(n_cols):
                out[r, c] = 0.0
        for j in range(n_regions):
            w = weights[j]
            if w != 0.0:
                for r in range(6):
                    for c in range(n_cols):
                        out[r, c] += w * maps[j, r * n_cols + c]
        st.blended = 1
    elif st.blended != 0 or weights[k] != 1.0:
        for j in range(n_regions):
            weights[j] = 0.0
        weights[k] = 1.0
        for r in range(6):
            for c in range(n_cols):
                out[r, c] = maps[k, r * n_cols + c]
        st.blended = 0
    return k


@jit_entry
def schedule_select_entry(state, arrays, R) -> int:
    """:func:`schedule_select` on the ``(1,)`` arrays of the state and of the arrays' record (from Python)."""
    return schedule_select(state[0], arrays[0], R)
