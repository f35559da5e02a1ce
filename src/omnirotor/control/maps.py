"""Which wrench map the controller uses at the current attitude (SPEC §3.3).

The controller keeps one map ``A`` (6 x n, body frame, SPEC §1.2) per region of the sphere of up
directions ``v_B = R_WBᵀ e3`` (the third row of ``R_WB``; see :mod:`omnirotor.regions`). The map selected
here is used **both** by the allocation QP and by the wrench observer (SPEC §3.3). Modes:

* ``nominal``: always the vehicle's nominal map ``A_nom`` (no map file needed);
* ``global``: always the single map identified on all data (``WrenchMapSet.global_``);
* ``piecewise``: the map of the attitude's region, in one of two blends:

  - ``hard`` (the paper): the map of the *first* region whose closed azimuth and elevation intervals
    contain ``v_B`` (:meth:`omnirotor.regions.Partition.index_of_direction`); no interpolation and no
    hysteresis, so the map, and with it the rotor command, jumps when a border is crossed;
  - ``smooth`` (an extension, [A]): a convex combination ``A = sum_k w_k A_k`` whose weights change
    continuously across a band of total width ``blend_width_deg`` centred on every border.

Smooth weights. Let ``S(t) = 3t² - 2t³`` on ``t`` clipped to [0, 1] (so ``S(t) + S(1 - t) = 1``) and
``b`` the band width [rad]. A closed interval ``[lo, hi]`` of a coordinate ``x`` gets the soft indicator
``S((x - lo)/b + 1/2) · S((hi - x)/b + 1/2)``: 1 deeper than ``b/2`` inside, 1/2 on the edge, 0 beyond
``b/2`` outside. Edges that are not borders get no ramp: the poles (elevation ±90°) and an azimuth
interval that spans the whole circle. Azimuth intervals of one region that meet across ±180° (the paper's
R5 and R10) are merged first into one circular interval, and azimuth distances are taken on the circle. A
region's raw weight is (azimuth indicator) x (elevation indicator), and the weights are normalised to sum
to 1. On a border shared by two regions the two ramps are mirror images, so the pair of weights goes
continuously from (1, 0) to (0, 1) across the band, with (1/2, 1/2) on the border itself; at a corner
where three regions meet the products still sum to 1. Away from every border (further than ``b/2`` in
both angles) the weights are one-hot and the map equals the hard map. Bands are measured in azimuth and
elevation *angles*: near the caps an azimuth band is narrower on the sphere (by cos(elevation)). The
construction assumes regions that meet only on their borders, as the paper's do, and a band narrower than
every region's extent (checked).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from omnirotor.blocks import new_state, record_view, register, state_array
from omnirotor.config import check_positive
from omnirotor.control import _map_kernels as _mk
from omnirotor.errors import InputError
from omnirotor.regions import Partition, Region
from omnirotor.vehicle import VehicleParams
from omnirotor.wrench_maps import WrenchMapSet

__all__ = ["schedule_sizes", "MapParams", "MapScheduler", "MAP_MODES", "BLENDS"]

MAP_MODES = ("nominal", "global", "piecewise")
"""Which map(s) the controller flies with."""
BLENDS = ("hard", "smooth")
"""How the piecewise map changes across a region border."""

_TWO_PI = 2.0 * math.pi
_HALF_PI = 0.5 * math.pi
_EDGE_TOL_RAD = 1e-12  # an interval edge this close to ±pi/2 or to a full circle is not a border


@dataclasses.dataclass(frozen=True)
class MapParams:
    """Wrench-map scheduling in the loop (SPEC §3.3).

    Attributes:
        mode: "nominal" (default; the map of SPEC §1.2), "global" (one identified map) or "piecewise".
        blend: "hard" (default; the paper's first-region switch) or "smooth" (blended near borders).
        blend_width_deg: total width of the blending band centred on each border [deg] (smooth only).
    """

    mode: str = "nominal"
    blend: str = "hard"
    blend_width_deg: float = 10.0

    def __post_init__(self) -> None:
        if self.mode not in MAP_MODES:
            raise InputError(f"map mode must be one of {', '.join(MAP_MODES)}, got {self.mode!r}")
        if self.blend not in BLENDS:
            raise InputError(f"map blend must be one of {', '.join(BLENDS)}, got {self.blend!r}")
        check_positive("map blend_width_deg", self.blend_width_deg)
        if self.blend_width_deg > 90.0:
            raise InputError(f"map blend_width_deg must be <= 90, got {self.blend_width_deg}")


@dataclasses.dataclass(frozen=True)
class _SoftRegion:
    """A region as circular azimuth intervals (centre, half-width) [rad] and an elevation interval."""

    az_full: bool
    az_centres: tuple[float, ...]
    az_halves: tuple[float, ...]
    el_lo: float  # -inf when the lower edge is the south pole (no border)
    el_hi: float  # +inf when the upper edge is the north pole

    @classmethod
    def from_region(cls, region: Region) -> _SoftRegion:
        ivs = sorted((math.radians(lo), math.radians(hi)) for lo, hi in region.azimuth_deg)
        merged: list[list[float]] = []
        for lo, hi in ivs:
            if merged and lo <= merged[-1][1]:
                merged[-1][1] = max(merged[-1][1], hi)
            else:
                merged.append([lo, hi])
        # Intervals touching -pi and +pi are one interval across the seam.
        if len(merged) > 1 and merged[0][0] <= -math.pi + _EDGE_TOL_RAD and merged[-1][1] >= math.pi - _EDGE_TOL_RAD:
            first = merged.pop(0)
            merged[-1][1] = first[1] + _TWO_PI
        full = any(hi - lo >= _TWO_PI - _EDGE_TOL_RAD for lo, hi in merged)
        lo_el, hi_el = (math.radians(e) for e in region.elevation_deg)
        return cls(
            az_full=full,
            az_centres=tuple(0.5 * (lo + hi) for lo, hi in merged),
            az_halves=tuple(0.5 * (hi - lo) for lo, hi in merged),
            el_lo=-math.inf if lo_el <= -_HALF_PI + _EDGE_TOL_RAD else lo_el,
            el_hi=math.inf if hi_el >= _HALF_PI - _EDGE_TOL_RAD else hi_el,
        )

    def narrowest_rad(self) -> float:
        """Widest band [rad] the region supports.

        Its two border ramps must not overlap, and a ramp must not reach a pole (where the azimuth of the
        neighbours' weights would be undefined).
        """
        widths = [] if self.az_full else [2.0 * h for h in self.az_halves]
        lo_border, hi_border = math.isfinite(self.el_lo), math.isfinite(self.el_hi)
        if lo_border and hi_border:
            widths.append(self.el_hi - self.el_lo)
        elif lo_border:
            widths.append(2.0 * (_HALF_PI - self.el_lo))
        elif hi_border:
            widths.append(2.0 * (self.el_hi + _HALF_PI))
        return min(widths, default=math.inf)


def schedule_sizes(maps: WrenchMapSet | None) -> tuple[int, int]:
    """(regions, azimuth-interval slots) a scheduler needs for any mode with ``maps`` (its partition's).

    The controller sizes its field ``maps_arrays`` so, so that :meth:`InteractionController.set_map_mode`
    rebuilds the scheduler in place for any mode.
    """
    if maps is None:
        return 0, 0
    regions = maps.partition.regions
    return len(regions), _mk.n_intervals(regions, [_SoftRegion.from_region(r) for r in regions])


@register("maps", "regions")
class MapScheduler:
    """Select the wrench map for the current attitude (SPEC §3.3), for the allocation and the observer.

    The selection runs in one compiled call (:func:`omnirotor.control._map_kernels.schedule_select`) on the
    state record and the arrays below, which the controller's compiled step passes to the same function;
    after such a call made elsewhere, :meth:`sync` brings :attr:`region_index` and :attr:`region_name` up to
    date.

    Attributes:
        state: the ``(1,)`` record (:data:`~omnirotor.control._map_kernels.STATE_DTYPE`: current region,
            blend flag, count of non-finite attitudes, blending band; a field of the controller's state when
            the controller owns the scheduler).
        region_index: index in ``maps.partition`` of the attitude's region (first match, as the hard
            switch), updated by :meth:`select` in piecewise mode; -1 in nominal and global modes, where no
            region is used.
        region_name: name of that region, or "nominal" / "global" in those modes.
        weights: (K,) read-only blending weights of the K regions from the last :meth:`select` (one-hot
            with hard blending); empty outside piecewise mode.
        n_nonfinite: count of :meth:`select` calls with a non-finite attitude (the map was kept).
        arrays: the partition and the maps, a ``(1,)`` array of
            :func:`~omnirotor.control._map_kernels.arrays_dtype` (the controller's field ``maps_arrays``): its
            ``out`` (6n,) is the array behind the map :meth:`select` returns, its ``weights`` the array behind
            :attr:`weights`.
    """

    state_dtype = _mk.STATE_DTYPE
    log_fields = ()
    kernel = _mk.schedule_select  # the maps kind's step (omnirotor.blocks.KIND_STEPS)

    def __init__(
        self,
        vehicle: VehicleParams,
        maps: WrenchMapSet | None,
        params: MapParams | None = None,
        *,
        state: np.ndarray | None = None,
        arrays: np.ndarray | None = None,
    ):
        """Prepare the maps of the chosen mode.

        Args:
            vehicle: the vehicle; its ``A_nom`` is the nominal map.
            maps: identified maps (``omnirotor.wrench_maps``); needed for the global and piecewise modes.
            params: scheduling parameters; defaults to :class:`MapParams()` (nominal).
            state: optional ``(1,)`` array of ``STATE_DTYPE`` to keep the state in (e.g. a field of the
                controller's state).
            arrays: optional ``(1,)`` array of ``_map_kernels.arrays_dtype(K, M, n)`` to keep the partition and
                the maps in, sized by :func:`schedule_sizes` (e.g. the controller's field); an exact one by
                default.

        Raises:
            InputError: a mode that needs maps without them, no global map in global mode, maps of the
                wrong shape or with NaN/inf, or a blending band wider than a region.
        """
        self.params = params if params is not None else MapParams()
        self.vehicle = vehicle
        n = vehicle.n_rotors
        mode = self.params.mode
        self._maps: np.ndarray  # (K, 6, n) maps to choose from
        self._partition: Partition | None = None
        if mode == "nominal":
            self._maps = vehicle.A_nom[None].copy()
        else:
            if maps is None:
                raise InputError(f"map mode {mode!r} needs a wrench-map file")
            if mode == "global":
                if maps.global_ is None:
                    raise InputError("map mode 'global' needs a global map, and the wrench-map file has none")
                self._maps = np.asarray(maps.global_.A, dtype=float)[None].copy()
            else:
                self._partition = maps.partition
                region_maps = [np.asarray(A, dtype=float) for A in maps.region_maps()]
                for name, A in zip(maps.partition.names, region_maps, strict=True):
                    if A.shape != (6, n):
                        raise InputError(f"wrench map of {name} has shape {A.shape}, the vehicle needs (6, {n})")
                self._maps = np.array(region_maps)
        if self._maps.shape[1:] != (6, n):
            raise InputError(f"wrench map has shape {self._maps.shape[1:]}, the vehicle needs (6, {n})")
        if not np.all(np.isfinite(self._maps)):
            raise InputError("wrench maps contain NaN or inf")
        K = self._maps.shape[0]
        smooth = self._partition is not None and self.params.blend == "smooth"
        band = math.radians(self.params.blend_width_deg)
        regions: tuple[Region, ...] = ()
        soft: tuple[_SoftRegion, ...] = ()
        if self._partition is not None:
            regions = self._partition.regions
            soft = tuple(_SoftRegion.from_region(r) for r in regions)
            if smooth:
                narrow = min(s.narrowest_rad() for s in soft)
                if band > narrow:
                    raise InputError(
                        f"map blend_width_deg {self.params.blend_width_deg} is wider than the narrowest region "
                        f"({math.degrees(narrow):.1f} deg) of partition {self._partition.name!r}"
                    )
        self._names = tuple(r.name for r in regions)
        self.state = state_array(_mk.STATE_DTYPE, state, "map scheduler")
        if arrays is None:
            arrays = new_state(_mk.arrays_dtype(len(regions), _mk.n_intervals(regions, soft), n))
        self.arrays = arrays
        rec = record_view(arrays)
        try:
            _mk.pack_schedule(self.state[0], rec, regions, soft, smooth, band, self._maps.reshape(K, 6 * n))
        except ValueError as exc:
            raise InputError(f"map scheduler: {exc}") from None
        self._out = rec.out
        self._view = self._out.view()
        self._view.flags.writeable = False
        self._weights = rec.weights[: len(regions)]
        self._weights_view = self._weights.view()
        self._weights_view.flags.writeable = False
        self.region_index = -1
        self.region_name = mode
        self._initial = (self._out.copy(), self._weights.copy(), self.state.copy())
        if self._partition is not None:
            self.select(np.eye(3))
            self._initial = (self._out.copy(), self._weights.copy(), self.state.copy())

    def reset(self) -> None:
        """Back to the selection made at construction (upright), the counter cleared."""
        out, weights, state = self._initial
        self._out[...] = out
        self._weights[:] = weights
        self.state[...] = state
        self.sync()

    @property
    def follows_attitude(self) -> bool:
        """True in piecewise mode: the controller's step runs the kernel every period (else the map is constant)."""
        return self._partition is not None

    @property
    def n_nonfinite(self) -> int:
        """Count of :meth:`select` calls with a non-finite attitude (the map was kept)."""
        return int(self.state[0]["n_nonfinite"])

    @property
    def weights(self) -> np.ndarray:
        """(K,) blending weights of the regions at the last :meth:`select` (read-only)."""
        return self._weights_view

    @property
    def n_maps(self) -> int:
        """Number of distinct maps the scheduler chooses from (1 in nominal and global modes)."""
        return self._maps.shape[0]

    def select(self, R_WB: np.ndarray) -> np.ndarray:
        """The (6, n) wrench map to use at attitude ``R_WB``.

        Args:
            R_WB: (3, 3) attitude, body to world; its third row is the up direction ``v_B``.

        Returns:
            (6, n) read-only map, an array owned by the scheduler and overwritten by later calls. With a
            non-finite attitude the previous map is kept.
        """
        if self._partition is None:
            return self._view
        if type(R_WB) is not np.ndarray or R_WB.dtype != np.float64 or not R_WB.flags.c_contiguous:
            R_WB = np.ascontiguousarray(R_WB, dtype=np.float64)
        k = _mk.schedule_select_entry(self.state, self.arrays, R_WB)
        if k != self.region_index:
            self.region_index = k
            self.region_name = self._names[k]
        return self._view

    def sync(self) -> None:
        """Update :attr:`region_index` and :attr:`region_name` from :attr:`state`.

        Needed only after :func:`_map_kernels.schedule_select` was called on this scheduler's records from
        elsewhere (a compiled loop); :meth:`select` keeps them up to date itself.
        """
        if self._partition is None:
            return
        k = int(self.state[0]["region"])
        if k != self.region_index:
            self.region_index = k
            self.region_name = self._names[k] if k >= 0 else self.params.mode
