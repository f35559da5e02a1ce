"""A partition of the sphere of up directions from the sign pattern of the hover allocation (SPEC §3.3, §4.2).

The paper chose its ten regions by hand, as attitudes "with similar propeller patterns". Here the pattern is
computed: at the up direction ``v_B = R_WBᵀ e3`` the vehicle hovers on the inputs that the controller's
allocation (SPEC §4.2, ``min |w_B - A u|² + lambda |u|²`` within the rotor bounds) gives for the hover wrench
``w_B = [m g v_B; 0]`` with the nominal map, and the pattern is which rotors spin backwards (``u_i < 0``).

Where no bound binds, and with SPEC's tiny lambda, that allocation is the pseudo-inverse ``u = pinv(A) w_B``
(to 1e-12 relative): then ``u_i = m g p_iᵀ v_B`` with ``p_i`` the i-th row of the first three columns of
``pinv(A)``, so rotor i reverses exactly on one side of the great circle ``p_iᵀ v = 0``, and the cells of
equal pattern are the faces of an arrangement of n great circles (57 faces on the Omnirotor, areas from
0.01 % to 11 % of the sphere). On the Omnirotor no bound binds at any hover attitude (largest hover
``|u|`` 41 134 Hz² against 48 400 Hz²); on a vehicle where one does, :func:`hover_allocation` solves the
bounded problem with SciPy's BVLS instead.

The regions file format (:mod:`omnirotor.regions`) allows a region only as a union of azimuth intervals times
ONE elevation interval, so the faces cannot be copied as they are. :func:`partition_from_signs` therefore

1. evaluates the pattern at the centres of a grid of ``step_deg`` cells in azimuth and elevation;
2. splits the elevation range into ``bands`` bands, adding one edge at a time on the grid line that lowers
   the mismatched area most (the lines where the pattern changes along most of the circle);
3. in each band gives every azimuth column the band's area-weighted dominant pattern of that column, and
   makes one region of all columns of a band that share a pattern (a union of azimuth intervals);
4. merges tiny regions (area below ``min_area_frac`` of the sphere) into the neighbouring column run whose
   pattern differs in the fewest rotors, then joins vertically adjacent regions with the same pattern and
   the same azimuth intervals.

It reports honestly what the format costs: the area fraction of the sphere where the local sign pattern is
not its region's pattern (measured on a Fibonacci sphere through :meth:`Partition.index_of_direction`, i.e.
the written file as the tool reads it).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
from scipy.optimize import lsq_linear

from omnirotor.config import check_positive
from omnirotor.errors import InputError
from omnirotor.regions import Partition, partition_from_dict
from omnirotor.safe_io import write_text_atomic
from omnirotor.vehicle import VehicleParams, fibonacci_sphere

__all__ = [
    "SignPartition",
    "hover_allocation",
    "sign_codes",
    "partition_from_signs",
    "mismatch_fraction",
    "write_partition_toml",
    "plot_sign_partition",
    "distinct_colors",
]

REG_LAMBDA = 1e-12
"""SPEC §4.2's allocation regulariser [N²/Hz⁴] for the Omnirotor's c_f = 1.5e-4 N/Hz² (scaled by c_f² elsewhere)."""
_REF_C_F = 1.5e-4


def hover_allocation(vehicle: VehicleParams, v_B: np.ndarray) -> np.ndarray:
    """Inputs [Hz²] the allocation gives for the hover wrench at up directions ``v_B`` (nominal map).

    Args:
        vehicle: the vehicle.
        v_B: (k, 3) up directions (unit).

    Returns:
        (k, n) inputs: ``pinv(A_nom) [m g v; 0]``, or, for a direction where that leaves the rotor bounds,
        the bounded regularised least squares of SPEC §4.2.
    """
    A = vehicle.A_nom
    v_B = np.atleast_2d(np.asarray(v_B, dtype=float))
    w = np.zeros((v_B.shape[0], 6))
    w[:, :3] = vehicle.weight * v_B
    u = w @ np.linalg.pinv(A).T
    out = np.abs(u).max(axis=1) > min(-vehicle.u_min, vehicle.u_max)
    if out.any():
        lam = REG_LAMBDA * (vehicle.c_f / _REF_C_F) ** 2
        M = np.vstack([A, math.sqrt(lam) * np.eye(A.shape[1])])
        for k in np.flatnonzero(out):
            b = np.concatenate([w[k], np.zeros(A.shape[1])])
            u[k] = lsq_linear(M, b, bounds=(vehicle.u_min, vehicle.u_max), method="bvls", tol=1e-12).x
    return u


def sign_codes(vehicle: VehicleParams, v_B: np.ndarray) -> np.ndarray:
    """(k,) sign-pattern codes: bit i set when rotor i spins backwards in hover at ``v_B``."""
    u = hover_allocation(vehicle, v_B)
    return ((u < 0).astype(np.int64) << np.arange(u.shape[1])).sum(axis=1)


def _reversed(code: int, n: int) -> list[int]:
    """Rotor numbers (1-based) that spin backwards in a pattern."""
    return [i + 1 for i in range(n) if code >> i & 1]


def _unit(az: np.ndarray, el: np.ndarray) -> np.ndarray:
    az, el = np.broadcast_arrays(az, el)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)


@dataclasses.dataclass(frozen=True)
class SignPartition:
    """A partition built from sign patterns, with what it costs.

    Attributes:
        partition: the regions (as the tool reads them).
        codes: (k,) the sign-pattern code of each region (bit i: rotor i reversed).
        area_frac: (k,) area of each region as a fraction of the sphere.
        band_edges_deg: elevation edges of the bands, from -90 to 90.
        mismatch_frac: area fraction of the sphere where the local pattern is not its region's pattern.
        n_patterns: number of distinct local patterns on the sphere (faces of the arrangement, sampled).
        step_deg: grid step [deg].
    """

    partition: Partition
    codes: tuple[int, ...]
    area_frac: tuple[float, ...]
    band_edges_deg: tuple[float, ...]
    mismatch_frac: float
    n_patterns: int
    step_deg: float


def _band_assignment(codes: np.ndarray, area: np.ndarray, lo: int, hi: int) -> tuple[np.ndarray, float]:
    """Dominant code per column of rows [lo, hi) and the mismatched area of that choice."""
    n_az = codes.shape[1]
    dom = np.empty(n_az, dtype=np.int64)
    miss = 0.0
    for j in range(n_az):
        col, wts = codes[lo:hi, j], area[lo:hi]
        vals = np.unique(col)
        tot = np.array([wts[col == c].sum() for c in vals])
        dom[j] = vals[int(np.argmax(tot))]
        miss += wts.sum() - tot.max()
    return dom, miss


def _runs(dom: np.ndarray) -> list[tuple[int, int]]:
    """Circular runs [start, stop) of equal values (indices may wrap: stop may exceed len)."""
    n = dom.size
    if np.all(dom == dom[0]):
        return [(0, n)]
    start = next(j for j in range(n) if dom[j] != dom[j - 1])
    runs, j0 = [], start
    for k in range(1, n + 1):
        j = (start + k) % n
        if k == n or dom[j] != dom[(start + k - 1) % n]:
            runs.append((j0, start + k))
            j0 = start + k
    return runs


def _merge_tiny(dom: np.ndarray, col_area: float, min_area: float, n_rotors: int) -> np.ndarray:
    """Give the columns of codes whose total area is below ``min_area`` the code of the closest neighbour run."""
    dom = dom.copy()
    n = dom.size
    while True:
        vals, counts = np.unique(dom, return_counts=True)
        tiny = [(cnt, int(c)) for c, cnt in zip(vals, counts, strict=True) if cnt * col_area < min_area]
        if not tiny or len(vals) == 1:
            return dom
        _, code = min(tiny)
        runs = _runs(dom)
        for a, b in runs:
            if dom[a % n] != code:
                continue
            left, right = int(dom[(a - 1) % n]), int(dom[b % n])
            cands = [c for c in (left, right) if c != code]
            best = min(cands, key=lambda c: (bin(c ^ code).count("1"), -int(np.sum(dom == c))))
            for j in range(a, b):
                dom[j % n] = best


def _intervals(cols: np.ndarray, step: float) -> list[list[float]]:
    """Azimuth intervals [deg] covered by a boolean column mask (column j spans -180 + j step ...)."""
    out, n, j = [], cols.size, 0
    while j < n:
        if cols[j]:
            k = j
            while k < n and cols[k]:
                k += 1
            out.append([-180.0 + j * step, -180.0 + k * step])
            j = k
        else:
            j += 1
    return out


def partition_from_signs(
    vehicle: VehicleParams,
    bands: int = 4,
    min_area_frac: float = 0.02,
    step_deg: float = 5.0,
    name: str = "signs",
    n_check: int = 20000,
) -> SignPartition:
    """Build a partition of the sphere from the hover sign pattern (module docstring).

    Args:
        vehicle: the vehicle (its nominal map).
        bands: number of elevation bands (>= 1).
        min_area_frac: regions smaller than this fraction of the sphere are merged into a neighbour.
        step_deg: grid step in azimuth and elevation [deg]; must divide 180.
        name: the partition's name.
        n_check: Fibonacci-sphere points for the mismatch measure.

    Returns:
        The partition and its costs.
    """
    check_positive("step_deg", step_deg)
    n_el = round(180.0 / step_deg)
    if abs(n_el * step_deg - 180.0) > 1e-9 or n_el < 2:
        raise InputError(f"--step {step_deg} deg must divide 180 into at least 2 cells")
    if isinstance(bands, bool) or not isinstance(bands, int) or not 1 <= bands <= n_el:
        raise InputError(f"bands must be an integer in [1, {n_el}], got {bands!r}")
    if not (math.isfinite(min_area_frac) and 0.0 <= min_area_frac < 0.5):
        raise InputError(f"min-area-frac must be in [0, 0.5), got {min_area_frac}")
    n_az = 2 * n_el
    el_edges = np.radians(np.linspace(-90.0, 90.0, n_el + 1))
    az_c = np.radians(-180.0 + step_deg * (np.arange(n_az) + 0.5))
    el_c = 0.5 * (el_edges[:-1] + el_edges[1:])
    # area of one cell of each row, as a fraction of the sphere
    row_area = (np.sin(el_edges[1:]) - np.sin(el_edges[:-1])) / (2.0 * n_az)
    grid = _unit(az_c[None, :], el_c[:, None]).reshape(-1, 3)
    codes = sign_codes(vehicle, grid).reshape(n_el, n_az)

    def cost(edges: list[int]) -> float:
        return sum(_band_assignment(codes, row_area, a, b)[1] for a, b in zip(edges[:-1], edges[1:], strict=True))

    edges = [0, n_el]
    while len(edges) - 1 < bands:
        trial = [(cost(sorted(edges + [k])), k) for k in range(1, n_el) if k not in edges]
        edges = sorted(edges + [min(trial)[1]])
    # regions per band: (lo_row, hi_row, code, column mask)
    cells: list[tuple[int, int, int, np.ndarray]] = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        dom, _ = _band_assignment(codes, row_area, a, b)
        band_area = float(row_area[a:b].sum())  # one column of the band
        dom = _merge_tiny(dom, band_area, min_area_frac, vehicle.n_rotors)
        for c in sorted(set(dom.tolist()), key=lambda c: -int(np.sum(dom == c))):
            cells.append((a, b, int(c), dom == c))
    # join vertically adjacent regions with the same code and the same columns
    joined: list[tuple[int, int, int, np.ndarray]] = []
    for a, b, c, cols in cells:
        for i, (a2, b2, c2, cols2) in enumerate(joined):
            if c2 == c and b2 == a and np.array_equal(cols, cols2):
                joined[i] = (a2, b, c, cols)
                break
        else:
            joined.append((a, b, c, cols))
    joined.sort(key=lambda r: (-r[1], -int(r[3].sum())))  # top band first, then by width
    regions, region_codes = [], []
    for k, (a, b, c, cols) in enumerate(joined):
        el = [round(math.degrees(el_edges[a]), 6), round(math.degrees(el_edges[b]), 6)]
        regions.append({"name": f"S{k + 1}", "azimuth_deg": _intervals(cols, step_deg), "elevation_deg": el})
        region_codes.append(c)
    partition = partition_from_dict({"name": name, "region": regions}, f"partition {name}")
    mism, areas, n_pat = mismatch_fraction(vehicle, partition, region_codes, n_check)
    return SignPartition(
        partition=partition,
        codes=tuple(region_codes),
        area_frac=tuple(areas),
        band_edges_deg=tuple(round(math.degrees(el_edges[e]), 6) for e in edges),
        mismatch_frac=mism,
        n_patterns=n_pat,
        step_deg=step_deg,
    )


def mismatch_fraction(
    vehicle: VehicleParams, partition: Partition, codes: list[int] | tuple[int, ...] | None = None, n: int = 20000
) -> tuple[float, list[float], int]:
    """Area fraction where the local sign pattern is not its region's; region areas; number of local patterns.

    Args:
        vehicle: the vehicle.
        partition: any partition (e.g. the paper's).
        codes: each region's pattern code; None: each region's area-weighted dominant pattern.
        n: Fibonacci-sphere points (equal areas).

    Returns:
        ``(mismatch fraction, area fraction of each region, number of distinct local patterns)``.
    """
    pts = fibonacci_sphere(n)
    local = sign_codes(vehicle, pts)
    idx = np.array([partition.index_of_direction(v) for v in pts])
    k = len(partition.regions)
    if codes is None:
        codes = []
        for i in range(k):
            vals, counts = np.unique(local[idx == i], return_counts=True)
            codes.append(int(vals[np.argmax(counts)]) if vals.size else -1)
    miss = float(np.mean(local != np.asarray(codes)[idx]))
    areas = [float(np.mean(idx == i)) for i in range(k)]
    return miss, areas, int(np.unique(local).size)


def write_partition_toml(path: str | Path, result: SignPartition, vehicle: VehicleParams, label: str = "") -> None:
    """Write the partition as a regions TOML (``presets/regions/paper.toml``'s format) atomically.

    The file is written by :func:`omnirotor.safe_io.write_text_atomic`: a folder, device, FIFO or symbolic link
    at ``path`` is refused with an :class:`InputError` naming ``label`` (an option such as ``--out``).
    """
    n = vehicle.n_rotors
    lines = [
        f"# Regions from the hover sign pattern of vehicle {vehicle.name!r} (omnirotor regions --from-signs).",
        f"# {len(result.partition.regions)} regions in {len(result.band_edges_deg) - 1} elevation bands "
        f"(edges {', '.join(f'{e:g}' for e in result.band_edges_deg)} deg), grid {result.step_deg:g} deg.",
        f"# {result.n_patterns} distinct local patterns; area where the local pattern is not the region's: "
        f"{100 * result.mismatch_frac:.1f} %.",
        "# A direction belongs to the first region whose closed intervals contain it (SPEC §3.3).",
        f'name = "{result.partition.name}"',
        "",
    ]
    for r, c, a in zip(result.partition.regions, result.codes, result.area_frac, strict=True):
        rev = ", ".join(str(i) for i in _reversed(c, n)) or "none"
        lines += [
            "[[region]]",
            f"# reversed rotors: {rev}; {100 * a:.1f} % of the sphere",
            f'name = "{r.name}"',
            "azimuth_deg = [" + ", ".join(f"[{lo:g}, {hi:g}]" for lo, hi in r.azimuth_deg) + "]",
            f"elevation_deg = [{r.elevation_deg[0]:g}, {r.elevation_deg[1]:g}]",
            "",
        ]
    write_text_atomic(path, "\n".join(lines), label)


def distinct_colors(k: int) -> np.ndarray:
    """(k, 3) RGB colours as far apart as a greedy choice makes them (the 57 sign patterns of the Omnirotor too).

    Farthest-point selection over an 11-level RGB grid, away from white (the background) and black (the
    figure's mismatch marks): each new colour is the one farthest from all chosen so far and from those two.
    """
    levels = np.linspace(0.0, 1.0, 11)
    grid = np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), axis=-1).reshape(-1, 3)
    far = np.full(grid.shape[0], np.inf)
    for avoid in (np.zeros(3), np.ones(3)):
        far = np.minimum(far, np.linalg.norm(grid - avoid, axis=1))
    chosen = []
    for _ in range(k):
        j = int(np.argmax(far))
        chosen.append(grid[j])
        far = np.minimum(far, np.linalg.norm(grid - grid[j], axis=1))
    return np.array(chosen).reshape(k, 3)


def plot_sign_partition(result: SignPartition, vehicle: VehicleParams, path: str | Path, n: int = 15000) -> None:
    """Figure: local sign patterns on an azimuth-elevation map, the regions' borders, and mismatched area."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = fibonacci_sphere(n)
    az = np.degrees(np.arctan2(pts[:, 1], pts[:, 0]))
    el = np.degrees(np.arcsin(np.clip(pts[:, 2], -1, 1)))
    local = sign_codes(vehicle, pts)
    _, inv = np.unique(local, return_inverse=True)
    idx = np.array([result.partition.index_of_direction(v) for v in pts])
    wrong = local != np.asarray(result.codes)[idx]
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.2), sharey=True)
    colors = distinct_colors(int(max(inv.max(), idx.max())) + 1)
    axes[0].scatter(az, el, c=colors[inv], s=3, rasterized=True)
    axes[0].set_title(f"local hover sign pattern ({result.n_patterns} patterns)")
    axes[1].scatter(az, el, c=colors[idx], s=3, rasterized=True)
    axes[1].scatter(az[wrong], el[wrong], c="k", s=3, rasterized=True)
    axes[1].set_title(
        f"{len(result.partition.regions)} regions; black: pattern differs from the region's "
        f"({100 * result.mismatch_frac:.1f} %)"
    )
    for ax in axes:
        ax.set_xlabel("azimuth of v_B [deg]")
        ax.set_xlim(-180, 180)
        ax.set_ylim(-90, 90)
    for r in result.partition.regions:
        for lo, hi in r.azimuth_deg:
            e0, e1 = r.elevation_deg
            axes[1].plot([lo, hi, hi, lo, lo], [e0, e0, e1, e1, e0], "k-", lw=0.6)
            axes[1].text(0.5 * (lo + hi), 0.5 * (e0 + e1), r.name, ha="center", va="center", fontsize=7)
    axes[0].set_ylabel("elevation of v_B [deg]")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)
