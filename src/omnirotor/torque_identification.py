"""Torque rows of the wrench map from dynamic flight (issue 15, item 1; SPEC §1.2, §3.2).

Hover data cannot see the torque rows ``A_2`` (rows mx my mz) of a wrench map: in hover the moment is zero,
and SPEC §3.2 weighs those rows 1e-12. In free flight that excites the attitude, Euler's equation about the
centre of mass gives a moment at every sample,

    J omega_dot + omega x J omega = A_2 u,

with ``omega = omega_B`` from the gyroscope [rad/s], ``J`` the vehicle's inertia [kg·m²] and
``u = sign(w) w²`` [Hz²] from the measured rotor speeds ``w`` [Hz]. The fit:

1. the gyro and the inputs are low-passed by the same zero-phase filter (a 4th-order Butterworth run forward
   and backward, ``cutoff_hz``), so the moment and the inputs keep the same timing, and ``omega_dot`` is the
   central difference of the filtered gyro (zero phase too); ``trim_s`` at both ends is dropped (filter
   start-up) and the samples are thinned to ``sample_hz``;
2. each sample becomes a point ``(u_k, [0, 0, 0, m_k])`` and the map is the box-constrained QP of SPEC §3.2
   (:func:`omnirotor.identification.solve_map`, DAQP) around the nominal map, with the row weights
   ``(1e-12, 1e-12, 1e-12, 1, 1, 1)`` — SPEC's weights mirrored: the force rows are left to the hover data
   and stay at the proximal centre — and the same bound Δ on every entry (SPEC's 3e-5 by default). Only the
   torque rows of the result are kept: they replace the torque rows of a map identified from hover, per region
   (the samples are assigned to the region of their attitude; :func:`merge_torque_rows`).

The proximal weight is larger than SPEC's: ``rho = 1e-2`` instead of 1e-8 (scaled variables ``a / 1e-5``, at
100 samples/s). A flight whose controller allocates with (nearly) the pseudo-inverse of the nominal map puts
its inputs in the row space of ``A_nom`` only: on the Omnirotor the 2-D null space carried 0.1 % of the input
norm of the sweep flight. With rho = 1e-8 noise decides the torque rows on that null space; they fit the
flight as well, but a controller flying the new map allocates into that null space, and in simulation the
hover moment estimate in R1 grew from 0.18 N·m (hover-only maps) to 0.96 N·m. With rho = 1e-2 the unexcited
directions stay at nominal, the flight's moment residual changes from 0.0072 to 0.0074 N·m, and the hover
moment estimate falls to about 0.02 N·m.

Flight-log CSV (``omnirotor run identify-dynamic`` writes it, ``omnirotor identify --torque`` reads it)::

    t_s,gyro_x_rad_s,gyro_y_rad_s,gyro_z_rad_s,omega1_hz,...,omegaN_hz[,region]

one row per sample at a constant rate (the gyro and the measured, signed rotor speeds), ``region`` the
region of the attitude at that sample (else every sample goes to the global map only), ``#`` comment lines.
A PX4 ULog of the flight serves as well (:func:`load_flight_ulog`).

Torque rows that vary inside a region (issue 15): one set of torque rows per region cannot follow how the
truth's moment error changes from one hover attitude to another inside it (the rotor-wake interaction depends
on the ratios of the rotor speeds, which change with the attitude). :func:`refine_maps` copies the maps onto a
finer partition of *cells* (each cell takes the map of the region containing its centre, so the force rows
stay the hover data's), the flight is flown at the base of every cell (``run identify-dynamic-cells``) and
fitted per cell, and the controller blends the cells' maps with ``blend = "smooth"``
(:mod:`omnirotor.control.maps`): between two bases the torque rows change smoothly, with no change to the
compiled map scheduler.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path

import numpy as np
from scipy.signal import butter, filtfilt

from omnirotor.config import check_positive
from omnirotor.errors import InputError
from omnirotor.identification import HoverData, IdentificationParams, read_csv_rows, solve_map
from omnirotor.regions import Partition
from omnirotor.safe_io import note
from omnirotor.vehicle import VehicleParams
from omnirotor.wrench_maps import MapEntry, WrenchMapSet

__all__ = [
    "FlightLog",
    "TorqueIdParams",
    "TorqueFit",
    "TORQUE_WEIGHTS",
    "load_flight_csv",
    "load_flight_ulog",
    "ULOG_MAX_RATE_HZ",
    "write_flight_csv",
    "zero_phase_derivative",
    "moment_samples",
    "fit_torque_rows",
    "merge_torque_rows",
    "torque_residual_rms",
    "flight_torque_rows",
    "refine_maps",
    "cell_regions",
]

TORQUE_WEIGHTS = (1e-12, 1e-12, 1e-12, 1.0, 1.0, 1.0)
"""Row weights of the torque fit: SPEC §3.2's weights mirrored (the force rows are the hover data's)."""
_GYRO_COLS = ("gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s")


@dataclasses.dataclass(frozen=True)
class FlightLog:
    """A free-flight log at a constant rate.

    Attributes:
        t_s: (N,) sample times [s].
        gyro_B: (N, 3) gyroscope [rad/s], body axes.
        rotor_hz: (N, n) measured rotor speeds [Hz], signed.
        region: (N,) region name of each sample ("" = none).
    """

    t_s: np.ndarray
    gyro_B: np.ndarray
    rotor_hz: np.ndarray
    region: tuple[str, ...]

    def __post_init__(self) -> None:
        N = self.t_s.size
        if self.gyro_B.shape != (N, 3) or self.rotor_hz.shape[0] != N or len(self.region) != N:
            raise InputError("flight log: columns of different lengths")
        if N < 3:
            raise InputError(f"flight log: {N} samples; need many more")
        if not (np.all(np.isfinite(self.gyro_B)) and np.all(np.isfinite(self.rotor_hz))):
            raise InputError("flight log: contains NaN or inf")
        dt = np.diff(self.t_s)
        if not (np.all(dt > 0) and np.ptp(dt) <= 1e-3 * dt.mean()):
            raise InputError("flight log: samples must be at a constant rate (t_s evenly spaced)")

    @property
    def dt(self) -> float:
        """Sample period [s]."""
        return float(self.t_s[1] - self.t_s[0])


@dataclasses.dataclass(frozen=True)
class TorqueIdParams:
    """Settings of the torque-row fit (module docstring).

    Attributes:
        cutoff_hz: zero-phase low-pass cutoff of gyro and inputs [Hz].
        trim_s: dropped at both ends of the log [s].
        sample_hz: samples per second kept for the fit [Hz].
        delta: bound on each entry's change from nominal (SPEC §3.2's Δ).
        rho: proximal weight towards the nominal map, in the QP's scaled variables (module docstring: SPEC's
            1e-8 would let noise set the rows on the input directions the flight never excites).
    """

    cutoff_hz: float = 8.0
    trim_s: float = 0.5
    sample_hz: float = 100.0
    delta: float = 3e-5
    rho: float = 1e-2

    def __post_init__(self) -> None:
        for name in ("cutoff_hz", "sample_hz", "delta", "rho"):
            check_positive(name, getattr(self, name))
        if not (math.isfinite(self.trim_s) and self.trim_s >= 0):
            raise InputError(f"trim_s must be a finite number >= 0, got {self.trim_s}")


@dataclasses.dataclass(frozen=True)
class TorqueFit:
    """Identified torque rows of one map and how well they explain the flight.

    Attributes:
        A2: (3, n) torque rows [N·m/Hz²].
        samples: samples used.
        residual_rms_Nm: RMS of ``|m_k - A2 u_k|`` over the samples [N·m].
        base_residual_rms_Nm: the same for the torque rows it started from [N·m].
    """

    A2: np.ndarray
    samples: int
    residual_rms_Nm: float
    base_residual_rms_Nm: float


def load_flight_csv(path: str | Path, vehicle: VehicleParams) -> FlightLog:
    """Read a flight-log CSV (format in the module docstring)."""
    p = Path(path)
    n = vehicle.n_rotors
    speed_cols = tuple(f"omega{i + 1}_hz" for i in range(n))
    rows = read_csv_rows(p)
    if len(rows) < 2:
        raise InputError(f"{p}: no data rows")
    header = [h.strip() for h in rows[0]]
    need = ("t_s", *_GYRO_COLS, *speed_cols)
    missing = [c for c in need if c not in header]
    if missing:
        raise InputError(f"{p}: not a flight log; missing column(s) {', '.join(missing)}")
    unknown = [h for h in header if h not in need and h != "region"]
    if unknown:
        raise InputError(f"{p}: unknown column(s) {', '.join(unknown)}")
    col = {h: i for i, h in enumerate(header)}
    idx = [col[c] for c in need]
    try:
        body = [r for r in rows[1:]]
        if any(len(r) != len(header) for r in body):
            raise InputError(f"{p}: a row has a different number of fields than the header")
        values = np.array([[float(r[i]) for i in idx] for r in body])
    except ValueError as exc:
        raise InputError(f"{p}: not a number ({exc})") from None
    region = tuple(r[col["region"]].strip() for r in body) if "region" in col else ("",) * len(body)
    try:
        return FlightLog(values[:, 0], values[:, 1:4], values[:, 4:], region)
    except InputError as exc:
        raise InputError(f"{p}: {exc}") from None


def write_flight_csv(path: str | Path, log: FlightLog) -> None:
    """Write a flight log in the format :func:`load_flight_csv` reads (atomically)."""
    n = log.rotor_hz.shape[1]
    from omnirotor.safe_io import atomic_path

    with atomic_path(path) as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", *_GYRO_COLS, *(f"omega{i + 1}_hz" for i in range(n)), "region"])
        for k in range(log.t_s.size):
            w.writerow(
                [f"{log.t_s[k]:.6f}"]
                + [f"{v:.7g}" for v in log.gyro_B[k]]
                + [f"{v:.7g}" for v in log.rotor_hz[k]]
                + [log.region[k]]
            )


def zero_phase_derivative(x: np.ndarray, dt: float, cutoff_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-phase low-pass of ``x`` (along axis 0) and its time derivative.

    Args:
        x: (N, ...) samples at period ``dt`` [s].
        dt: sample period [s].
        cutoff_hz: cutoff of the 4th-order Butterworth filter run forward and backward [Hz].

    Returns:
        ``(filtered x, d/dt of the filtered x)``, both (N, ...).
    """
    nyq = 0.5 / dt
    if not 0 < cutoff_hz < nyq:
        raise InputError(f"cutoff {cutoff_hz} Hz must be below the Nyquist frequency {nyq:g} Hz")
    b, a = butter(4, cutoff_hz / nyq)
    if x.shape[0] <= 3 * max(len(a), len(b)):
        raise InputError(f"flight log too short for the filter ({x.shape[0]} samples)")
    xf = filtfilt(b, a, x, axis=0)
    return xf, np.gradient(xf, dt, axis=0)


def moment_samples(
    log: FlightLog, vehicle: VehicleParams, params: TorqueIdParams
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """The fit's samples: inputs u [Hz²], moments ``J omega_dot + omega x J omega`` [N·m], and their regions."""
    J = vehicle.inertia
    w, w_dot = zero_phase_derivative(log.gyro_B, log.dt, params.cutoff_hz)
    u_raw = np.sign(log.rotor_hz) * log.rotor_hz**2
    u, _ = zero_phase_derivative(u_raw, log.dt, params.cutoff_hz)
    m = w_dot @ J.T + np.cross(w, w @ J.T)
    t = log.t_s
    keep = (t >= t[0] + params.trim_s) & (t <= t[-1] - params.trim_s)
    step = max(1, int(round(1.0 / (params.sample_hz * log.dt))))
    sel = np.flatnonzero(keep)[::step]
    if sel.size < vehicle.n_rotors:
        raise InputError(f"flight log: {sel.size} samples left after trimming; the flight is too short")
    return u[sel], m[sel], tuple(log.region[i] for i in sel)


def torque_residual_rms(u_hz2: np.ndarray, m_B: np.ndarray, A2: np.ndarray) -> float:
    """RMS over samples of ``|m_k - A2 u_k|`` [N·m]."""
    r = m_B - u_hz2 @ A2.T
    return float(np.sqrt(np.mean(np.sum(r * r, axis=1))))


def fit_torque_rows(
    u_hz2: np.ndarray, m_B: np.ndarray, A_nom: np.ndarray, params: TorqueIdParams = TorqueIdParams()
) -> TorqueFit:  # noqa: B008 (frozen)
    """Torque rows from moment samples by SPEC §3.2's QP with :data:`TORQUE_WEIGHTS` (module docstring).

    Args:
        u_hz2: (N, n) inputs [Hz²].
        m_B: (N, 3) moments [N·m].
        A_nom: (6, n) the nominal map (centre of the box).
        params: Δ and the rest.
    """
    if np.linalg.matrix_rank(u_hz2, tol=1e-6 * np.abs(u_hz2).max()) < u_hz2.shape[1]:
        raise InputError("flight log: the rotor inputs do not excite every rotor independently")
    N = u_hz2.shape[0]
    data = HoverData(u_hz2, np.hstack([np.zeros((N, 3)), m_B]), ("",) * N, ("flight",) * N)
    qp = IdentificationParams(delta=params.delta, weights=TORQUE_WEIGHTS, rho=params.rho)
    A = solve_map(data, A_nom, qp, require_determined=False)
    return TorqueFit(
        A2=A[3:].copy(),
        samples=N,
        residual_rms_Nm=torque_residual_rms(u_hz2, m_B, A[3:]),
        base_residual_rms_Nm=torque_residual_rms(u_hz2, m_B, A_nom[3:]),
    )


def merge_torque_rows(
    maps: WrenchMapSet, u_hz2: np.ndarray, m_B: np.ndarray, region: tuple[str, ...], params: TorqueIdParams
) -> tuple[WrenchMapSet, dict[str, TorqueFit]]:
    """Maps whose torque rows come from the flight: per region with samples there, and the global map on all.

    Regions without flight samples keep their torque rows. Force rows are untouched.

    Returns:
        The new maps and the fit of each map (``"global"`` and region names).
    """
    fits: dict[str, TorqueFit] = {}
    names = np.array(region)
    regions = dict(maps.regions)
    for name in maps.partition.names:
        mask = names == name
        if mask.sum() < 10 * u_hz2.shape[1]:
            continue
        fit = fit_torque_rows(u_hz2[mask], m_B[mask], maps.nominal, params)
        fits[name] = fit
        base = regions.get(name, MapEntry(A=maps.nominal.copy()))
        A = base.A.copy()
        A[3:] = fit.A2
        regions[name] = dataclasses.replace(base, A=A, identified=True)
    g = maps.global_
    if g is not None:
        fit = fit_torque_rows(u_hz2, m_B, maps.nominal, params)
        fits["global"] = fit
        A = g.A.copy()
        A[3:] = fit.A2
        g = dataclasses.replace(g, A=A)
    return dataclasses.replace(maps, regions=regions, global_=g), fits


ULOG_MAX_RATE_HZ = 1000.0
"""A ULog's flight is resampled at its gyro's median rate, at most this [Hz]."""


def load_flight_ulog(path: str | Path, vehicle: VehicleParams, partition: Partition) -> tuple[FlightLog, list[str]]:
    """A flight log from a PX4 ULog (:func:`omnirotor.px4.flight.read_flight`: our frames and units).

    The gyro (``sensor_combined``, else ``vehicle_angular_velocity``) and the signed rotor speeds (``esc_status``,
    else ``actuator_motors`` mapped by the vehicle's ``omega_max_hz``) are resampled linearly onto one grid at
    the gyro's median rate (at most :data:`ULOG_MAX_RATE_HZ`), over the span where both exist and the vehicle
    is airborne (``vehicle_land_detected``; the whole span when the log has no such topic). Each sample's
    region is that of the nearest logged attitude (``vehicle_attitude``, the estimate) in ``partition``.

    Returns:
        The log and what was chosen or assumed, one line each (the CLI says them on stderr).

    Raises:
        InputError: not a ULog, no attitude, rotor speeds or gyro, or no airborne span.
    """
    from omnirotor.px4.flight import read_flight
    from omnirotor.px4.windows import on_grid

    p = Path(path)
    f = read_flight(p, vehicle.n_rotors, vehicle.omega_max_hz)
    if f.omega_B is None:
        raise InputError(f"{p}: no gyro (neither sensor_combined nor vehicle_angular_velocity)")
    t_lo = max(f.omega_B.t[0], f.omega_hz.t[0])
    t_hi = min(f.omega_B.t[-1], f.omega_hz.t[-1])
    span = "gyro and rotor speeds"
    if f.landed is not None:
        airborne = f.landed.t[f.landed.x < 0.5]
        if airborne.size == 0:
            raise InputError(f"{p}: the vehicle never left the ground (vehicle_land_detected)")
        t_lo, t_hi = max(t_lo, airborne[0]), min(t_hi, airborne[-1])
        span = "airborne"
    rate_hz = min(ULOG_MAX_RATE_HZ, 1.0 / float(np.median(np.diff(f.omega_B.t))))
    n = int(math.floor((t_hi - t_lo) * rate_hz)) + 1
    if not (math.isfinite(rate_hz) and n >= 3):
        raise InputError(f"{p}: no {span} span with gyro and rotor speeds to fit torque rows from")
    t = t_lo + np.arange(n) / rate_hz
    gyro_B = on_grid(t, f.omega_B.t, f.omega_B.x)
    rotor_hz = on_grid(t, f.omega_hz.t, f.omega_hz.x)
    i_att = np.clip(np.searchsorted(f.R_WB.t, t), 0, f.R_WB.t.size - 1)
    i_prev = np.clip(i_att - 1, 0, None)
    i_att = np.where(np.abs(f.R_WB.t[i_prev] - t) < np.abs(f.R_WB.t[i_att] - t), i_prev, i_att)
    names = {i: partition.name_of_attitude(f.R_WB.x[i]) for i in np.unique(i_att)}
    region = tuple(names[i] for i in i_att)
    notes = [
        f"{p.name}: torque flight {t[-1] - t[0]:.1f} s ({span}), gyro and rotor speeds ({f.speed_source}) "
        f"resampled at {rate_hz:g} Hz; regions from vehicle_attitude"
    ]
    try:
        return FlightLog(t, gyro_B, rotor_hz, region), notes
    except InputError as exc:
        raise InputError(f"{p}: {exc}") from None


def cell_regions(partition: Partition, cells: Partition) -> dict[str, str]:
    """The region of ``partition`` that holds each cell of ``cells`` (cell name -> region name).

    A cell's centre is the middle of its elevation interval and of its first azimuth interval (the pole for a
    cap that spans every azimuth).

    Raises:
        InputError: a cell that reaches into two regions (checked at its centre and at the corners of its
            first azimuth interval, inset by 0.1°).
    """
    out = {}
    for cell in cells.regions:
        (a_lo, a_hi), (e_lo, e_hi) = cell.azimuth_deg[0], cell.elevation_deg
        cap = e_hi >= 90.0 and any(hi - lo >= 360.0 for lo, hi in cell.azimuth_deg)
        centre = (0.5 * (a_lo + a_hi), 90.0 if cap else 0.5 * (e_lo + e_hi))
        inset = [(a + s * 0.1, e + t * 0.1) for a, s in ((a_lo, 1), (a_hi, -1)) for e, t in ((e_lo, 1), (e_hi, -1))]
        found = set()
        for az, el in (centre, *inset):
            a, e = math.radians(az), math.radians(el)
            v = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
            found.add(partition.name_of_direction(v))
        if len(found) != 1:
            raise InputError(
                f"cell {cell.name} of partition {cells.name!r} reaches into regions {', '.join(sorted(found))} "
                f"of {partition.name!r}; cells must each lie inside one region"
            )
        out[cell.name] = found.pop()
    return out


def refine_maps(maps: WrenchMapSet, cells: Partition) -> WrenchMapSet:
    """The maps on a finer partition: each cell gets the map of the region of ``maps`` holding it.

    The global map is kept; cells of regions without a map of their own get none (:func:`cell_regions`).
    """
    owner = cell_regions(maps.partition, cells)
    regions = {c: maps.regions[r] for c, r in owner.items() if r in maps.regions}
    return dataclasses.replace(maps, partition=cells, regions=regions)


def flight_torque_rows(
    maps: WrenchMapSet,
    flight: str | Path,
    vehicle: VehicleParams,
    delta: float | None = None,
    cells: Partition | None = None,
    pool: bool = False,
) -> tuple[WrenchMapSet, dict[str, TorqueFit]]:
    """Read a flight log and replace the torque rows of ``maps`` by its fit (``omnirotor identify --torque``).

    ``flight`` is a flight-log CSV (module docstring) or a PX4 ULog (``.ulg``, :func:`load_flight_ulog`; what it
    chose is said on stderr). With ``cells``, the flight's samples belong to those cells (a CSV names them, as
    ``identify-dynamic-cells`` writes): the maps are refined onto the cells (:func:`refine_maps`) and the torque
    rows are fitted per cell, or, with ``pool``, the samples of each cell go to the region of ``maps`` that
    holds it and the maps keep their partition.
    """
    owner: dict[str, str] = {}
    if cells is not None and pool:
        owner = cell_regions(maps.partition, cells)
        if Path(flight).suffix.lower() == ".ulg":
            owner = {}  # a ULog's samples are labelled with the maps' own regions already
    elif cells is not None:
        maps = refine_maps(maps, cells)
    params = TorqueIdParams(delta=delta) if delta is not None else TorqueIdParams()
    if Path(flight).suffix.lower() == ".ulg":
        log, notes = load_flight_ulog(flight, vehicle, maps.partition)
        for line in notes:
            note(line)
    else:
        log = load_flight_csv(flight, vehicle)
    u, m, region = moment_samples(log, vehicle, params)
    if owner:
        region = tuple(owner.get(r, r) for r in region)
    unknown = sorted(set(region) - set(maps.partition.names) - {""})
    if unknown:
        note(
            f"{Path(flight).name}: samples of {', '.join(unknown)} (not regions of partition "
            f"{maps.partition.name!r}) fit only the global map"
        )
    return merge_torque_rows(maps, u, m, region, params)
