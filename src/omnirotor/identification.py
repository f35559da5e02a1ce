"""Piecewise-linear wrench-map identification from hover data (SPEC §3).

Each hover point j gives the rotor inputs ``u_j`` [Hz²] (from the mean measured speeds) and the body wrench
that held the vehicle still, ``w_j = [R_jᵀ m g e3; 0]`` (SPEC §3.1). With ``a = vec(A)`` column-major and
``U_j = u_jᵀ ⊗ I6`` we have ``A u_j = U_j a``, and the map of a region is the box-constrained weighted least
squares of SPEC §3.2 (eq. 3):

    min_a  ½ aᵀ H a + fᵀ a,   H = Ūᵀ W Ū,  f = −Ūᵀ W w̄,   a_nom − Δ ≤ a ≤ a_nom + Δ,

with ``W = diag(10, 10, 10, 1e-12, 1e-12, 1e-12)`` per point, so only the force rows are fitted. The QP is
solved by the active-set solver DAQP on scaled variables ``x = a / 1e-5`` with a proximal tie-breaker
``ρ ‖x − x_nom‖²`` (ρ = 1e-8, SPEC §3.2 recipe) that keeps the almost unweighted torque rows at nominal.
:func:`solve_map_lsq` solves the same problem with SciPy's bounded least squares, as an independent oracle.

Hover data come from the authors' MATLAB files (``U``, ``Z``, ``W`` fields; see the shared data README),
from a CSV of hover points (format in :func:`load_csv`) or from a PX4 flight log (``.ulg``, hover windows found
automatically by :mod:`omnirotor.px4.windows`). The region of a point follows from the direction
of its body-frame force (SPEC §3.3), unless the caller names it.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path

import daqp
import numpy as np

from omnirotor.config import check_positive, parse_float
from omnirotor.errors import InputError
from omnirotor.hover_data import HoverData
from omnirotor.limits import MAX_INPUT_BYTES, MAX_ULOG_BYTES, SPEED_MARGIN
from omnirotor.regions import Partition, load_partition
from omnirotor.safe_io import atomic_path, check_input_file, read_bytes, read_text
from omnirotor.so3 import R_from_quat_wxyz, R_from_rpy
from omnirotor.vehicle import VehicleParams
from omnirotor.wrench_maps import MapEntry, WrenchMapSet

__all__ = [
    "IdentificationParams",
    "HoverData",
    "load_mat",
    "load_csv",
    "read_csv_rows",
    "load_hover_data",
    "write_csv",
    "solve_map",
    "solve_map_lsq",
    "force_residual_rms",
    "identify",
    "assign_regions",
    "DEFAULT_WEIGHTS",
    "PAPER_POINTS_PER_REGION",
    "few_points",
    "WEIGHT_MISS_WARN",
    "identification_warnings",
]

DEFAULT_WEIGHTS = (10.0, 10.0, 10.0, 1e-12, 1e-12, 1e-12)
"""Per-point weights of the wrench rows fx fy fz mx my mz (SPEC §3.2)."""

PAPER_POINTS_PER_REGION = 15
"""Hover points per region of the paper's protocol (SPEC §3.4)."""

WEIGHT_MISS_WARN = 0.10
"""Relative miss of the weight by the nominal map above which identification warns (a wrong mass or c_f)."""


@dataclasses.dataclass(frozen=True)
class IdentificationParams:
    """Settings of the identification QP (SPEC §3.2).

    Attributes:
        delta: absolute bound on each entry's change from nominal, in the units of A (N/Hz², N·m/Hz²).
        weights: weights of the six wrench rows of every point.
        rho: proximal tie-breaker weight in scaled variables (keeps unweighted rows at nominal).
        scale: variable scaling, ``x = a / scale``.
    """

    delta: float = 3e-5
    weights: tuple[float, float, float, float, float, float] = DEFAULT_WEIGHTS
    rho: float = 1e-8
    scale: float = 1e-5

    def __post_init__(self) -> None:
        check_positive("delta", self.delta)
        check_positive("scale", self.scale)
        if not (math.isfinite(self.rho) and self.rho >= 0):
            raise InputError(f"rho must be a finite number >= 0, got {self.rho}")
        if len(self.weights) != 6 or not all(math.isfinite(w) and w >= 0 for w in self.weights):
            raise InputError(f"weights must be 6 finite numbers >= 0, got {self.weights}")
        if max(self.weights[:3]) <= 0:
            raise InputError("at least one force-row weight must be > 0")


def load_mat(path: str | Path, n_rotors: int = 8) -> HoverData:
    """Read hover points from the authors' MATLAB file (struct ``wMapStruct`` with ``U`` and ``Z``).

    ``U`` stacks ``U_j = u_jᵀ ⊗ I6`` (6N x 6n), so ``u_j[i] = U[6j, 6i]``; ``Z`` stacks the wrenches ``w_j``.
    """
    import io

    import scipy.io as sio

    p = Path(path)
    blob = read_bytes(p)  # a regular file (never a FIFO or a device)
    try:
        raw = sio.loadmat(io.BytesIO(blob), squeeze_me=True, struct_as_record=False)
    except Exception as exc:  # scipy raises many kinds for corrupt files
        raise InputError(f"{p}: not a readable MATLAB file ({type(exc).__name__})") from None
    s = raw.get("wMapStruct")
    if s is None or not hasattr(s, "U") or not hasattr(s, "Z"):
        raise InputError(f"{p}: no struct wMapStruct with fields U and Z")
    try:
        if np.iscomplexobj(s.U) or np.iscomplexobj(s.Z):
            raise TypeError("complex")
        U = np.atleast_2d(np.asarray(s.U, dtype=float))
        Z = np.asarray(s.Z, dtype=float).ravel()
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{p}: U and Z must be real numeric arrays") from None
    if U.shape[1] != 6 * n_rotors or U.shape[0] % 6 or U.shape[0] != Z.shape[0]:
        raise InputError(
            f"{p}: U has shape {U.shape} and Z {Z.shape}; expected (6N, {6 * n_rotors}) and (6N,) for {n_rotors} rotors"
        )
    if not np.all(np.isfinite(U)):
        raise InputError(f"{p}: U contains NaN or inf")
    N = U.shape[0] // 6
    u = U[0::6, 0::6].copy()
    # Check the whole Kronecker structure (diagonal and zeros elsewhere), so a file of another layout is
    # refused rather than misread.
    expected = u[:, None, :, None] * np.eye(6)[None, :, None, :]
    if not np.allclose(U.reshape(N, 6, n_rotors, 6), expected, rtol=0, atol=1e-9 * max(1.0, np.abs(u).max())):
        raise InputError(f"{p}: U is not of the form u_jᵀ ⊗ I6")
    return HoverData(u, Z.reshape(N, 6), ("",) * N, (p.name,) * N)


_Q_COLS = ("qw", "qx", "qy", "qz")
_RPY_COLS = ("roll_deg", "pitch_deg", "yaw_deg")
_W_COLS = ("fx_N", "fy_N", "fz_N", "mx_Nm", "my_Nm", "mz_Nm")


def read_csv_rows(path: Path) -> list[list[str]]:
    """The non-empty rows of a CSV file, ``#`` comment lines left out; unreadable files are an InputError.

    The file must be a regular one (:func:`omnirotor.safe_io.read_text`: a FIFO named ``*.csv`` is refused, never
    waited on).
    """
    import io

    text = read_text(path)
    try:
        return [r for r in csv.reader(io.StringIO(text, newline="")) if r and not r[0].lstrip().startswith("#")]
    except csv.Error as exc:
        raise InputError(f"{path}: cannot read as CSV ({exc})") from None


def load_csv(path: str | Path, vehicle: VehicleParams) -> HoverData:
    """Read hover points from a CSV file.

    Format (one header row, comma separated, ``#`` comment lines allowed)::

        qw,qx,qy,qz,omega1_hz,...,omegaN_hz[,fx_N,fy_N,fz_N,mx_Nm,my_Nm,mz_Nm][,region][,t_s]

    The attitude ``R_WB`` is a unit quaternion (wxyz) or ``roll_deg,pitch_deg,yaw_deg`` (ZYX). The rotor
    speeds are the mean measured speeds of the hold [Hz, signed]. Without the optional measured body
    wrench columns, the wrench is the hover wrench ``[R_WBᵀ m g e3; 0]`` of the vehicle. ``region`` may name
    the region of the point; ``t_s`` is informational.
    """
    p = Path(path)
    n = vehicle.n_rotors
    speed_cols = tuple(f"omega{i + 1}_hz" for i in range(n))
    rows = read_csv_rows(p)
    if not rows:
        raise InputError(f"{p}: empty file")
    header = [h.strip() for h in rows[0]]
    col = {h: i for i, h in enumerate(header)}
    if len(col) != len(header):
        raise InputError(f"{p}: duplicate column names")
    has_q = all(c in col for c in _Q_COLS)
    has_rpy = all(c in col for c in _RPY_COLS)
    if has_q == has_rpy:
        raise InputError(f"{p}: needs either columns {','.join(_Q_COLS)} or {','.join(_RPY_COLS)} (not both)")
    missing = [c for c in speed_cols if c not in col]
    if missing:
        raise InputError(f"{p}: missing rotor-speed column(s) {', '.join(missing)} for a {n}-rotor vehicle")
    has_w = any(c in col for c in _W_COLS)
    if has_w and not all(c in col for c in _W_COLS):
        raise InputError(f"{p}: a measured wrench needs all of {','.join(_W_COLS)}")
    allowed = set(speed_cols) | set(_Q_COLS if has_q else _RPY_COLS) | (set(_W_COLS) if has_w else set())
    allowed |= {"region", "t_s"}
    unknown = [h for h in header if h not in allowed]
    if unknown:
        raise InputError(f"{p}: unknown column(s) {', '.join(unknown)}")
    u_rows, w_rows, regions = [], [], []
    up = np.array([0.0, 0.0, vehicle.weight])
    for line_no, r in enumerate(rows[1:], start=2):
        if len(r) != len(header):
            raise InputError(f"{p}: line {line_no} has {len(r)} fields, header has {len(header)}")

        def num(name: str, r: list[str] = r, line_no: int = line_no) -> float:
            v = parse_float(r[col[name]], f"{p}: line {line_no}, {name}")
            if not math.isfinite(v):
                raise InputError(f"{p}: line {line_no}, {name}: not finite")
            return v

        if has_q:
            q = np.array([num(c) for c in _Q_COLS])
            if abs(np.linalg.norm(q) - 1.0) > 1e-3:
                raise InputError(f"{p}: line {line_no}: quaternion is not unit (norm {np.linalg.norm(q):.4f})")
            R = R_from_quat_wxyz(q)
        else:
            R = R_from_rpy(*(math.radians(num(c)) for c in _RPY_COLS))
        omega = np.array([num(c) for c in speed_cols])
        u_rows.append(np.sign(omega) * omega**2)
        if has_w:
            w_rows.append([num(c) for c in _W_COLS])
        else:
            w_rows.append(np.concatenate([R.T @ up, np.zeros(3)]))
        regions.append(r[col["region"]].strip() if "region" in col else "")
    if not u_rows:
        raise InputError(f"{p}: no data rows")
    N = len(u_rows)
    return HoverData(np.array(u_rows), np.array(w_rows, dtype=float), tuple(regions), (p.name,) * N)


def write_csv(path: str | Path, R_WB: Sequence[np.ndarray], omega_hz: np.ndarray, region: Sequence[str] = ()) -> None:
    """Write hover points in the format :func:`load_csv` reads (quaternion attitude, no measured wrench)."""
    from omnirotor.so3 import quat_wxyz_from_R

    omega_hz = np.atleast_2d(omega_hz)
    n = omega_hz.shape[1]
    header = list(_Q_COLS) + [f"omega{i + 1}_hz" for i in range(n)] + (["region"] if region else [])
    with atomic_path(path) as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for j, R in enumerate(R_WB):
            row = [f"{v:.12f}" for v in quat_wxyz_from_R(R)] + [f"{v:.8f}" for v in omega_hz[j]]
            w.writerow(row + ([region[j]] if region else []))


def load_hover_data(paths: Sequence[str | Path], vehicle: VehicleParams, window_criteria=None) -> HoverData:
    """Read hover points from files and folders (their ``.mat``, ``.csv`` and ``.ulg`` files).

    A PX4 flight log (``.ulg``) or a ROS 2 bag folder gives one point per automatically found steady hover window
    (:func:`omnirotor.px4.windows.flight_hover_points`, with ``window_criteria``: a
    :class:`~omnirotor.px4.criteria.WindowCriteria`, default its defaults).
    """
    from omnirotor.px4.rosbag_io import is_rosbag

    files: list[Path] = []
    for item in paths:
        p = Path(item)
        try:
            is_dir = p.is_dir()
        except OSError:  # e.g. a name too long: check_input_file says so
            is_dir = False
        if is_dir and is_rosbag(p):
            files.append(p)
        elif is_dir:
            found = sorted(q for q in p.iterdir() if q.suffix.lower() in (".mat", ".csv", ".ulg"))
            if not found:
                raise InputError(f"{p}: folder holds no .mat, .csv or .ulg hover data")
            files.extend(_check_data_file(q) for q in found)
        else:
            files.append(_check_data_file(p))
    if not files:
        raise InputError("no hover data given")
    parts = []
    for f in files:
        if is_rosbag(f) or f.suffix.lower() == ".ulg":
            parts.append(_load_flight_log(f, vehicle, window_criteria))
        elif f.suffix.lower() == ".mat":
            parts.append(load_mat(f, vehicle.n_rotors))
        elif f.suffix.lower() == ".csv":
            parts.append(load_csv(f, vehicle))
        else:
            raise InputError(f"{f}: unknown data format (expected .mat, .csv or .ulg)")
        _check_speeds(parts[-1], vehicle, f)
    return HoverData.concatenate(parts)


def _check_data_file(p: Path) -> Path:
    """A hover-data file to read: a regular file within its format's size limit (a ULog's is larger)."""
    return check_input_file(p, max_bytes=MAX_ULOG_BYTES if p.suffix.lower() == ".ulg" else MAX_INPUT_BYTES)


def _load_flight_log(path: Path, vehicle: VehicleParams, window_criteria) -> HoverData:
    """One hover point per automatic hover window of a ULog or ROS 2 bag, with the hover wrench (SPEC §3.1)."""
    from omnirotor.px4.windows import flight_hover_points  # pyulog and rosbags only when a log is read

    pts = flight_hover_points(path, vehicle, window_criteria)
    N = len(pts.windows)
    up = np.array([0.0, 0.0, vehicle.weight])
    w_B = np.array([np.concatenate([R.T @ up, np.zeros(3)]) for R in pts.R_WB])
    return HoverData(pts.u_hz2, w_B, ("",) * N, (path.name,) * N)


def _check_speeds(data: HoverData, vehicle: VehicleParams, path: Path) -> None:
    """Refuse hover points whose rotor speeds exceed the vehicle's limits by more than :data:`SPEED_MARGIN`."""
    omega = np.sign(data.u_hz2) * np.sqrt(np.abs(data.u_hz2))
    lo = min(SPEED_MARGIN * vehicle.omega_min_hz, vehicle.omega_min_hz / SPEED_MARGIN)
    hi = SPEED_MARGIN * vehicle.omega_max_hz
    bad = np.flatnonzero(np.any((omega < lo) | (omega > hi), axis=1))
    if bad.size:
        j = int(bad[0])
        raise InputError(
            f"{path}: point {j + 1} has rotor speeds up to {np.abs(omega[j]).max():.0f} Hz, beyond the limits "
            f"[{vehicle.omega_min_hz:g}, {vehicle.omega_max_hz:g}] Hz of vehicle {vehicle.name!r} (+5 %)"
        )


def _stacked(data: HoverData, weights: Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ū (6N x 6n), w̄ (6N,), and the diagonal of W (6N,)."""
    N = data.n_points
    Ubar = np.vstack([np.kron(u[None, :], np.eye(6)) for u in data.u_hz2])
    return Ubar, data.w_B.reshape(6 * N), np.tile(np.asarray(weights, dtype=float), N)


def _check_enough(data: HoverData, what: str) -> None:
    # In hover the moment is zero, so every u_j lies in the (n - 3)-dimensional null space of the true
    # torque rows: hover data can only ever pin down A_1 on that subspace, and the proximal term keeps
    # the rest at nominal. Fewer independent points than that leaves the fit underdetermined.
    need = data.u_hz2.shape[1] - 3
    if data.n_points < need:
        raise InputError(f"{what}: {data.n_points} hover point(s); at least {need} are needed")
    if np.linalg.matrix_rank(data.u_hz2, tol=1e-6 * np.abs(data.u_hz2).max()) < need:
        raise InputError(f"{what}: the hover inputs span fewer than {need} independent directions")


def _qp_terms(data: HoverData, A_nom: np.ndarray, p: IdentificationParams):
    Ubar, wbar, Wd = _stacked(data, p.weights)
    s = p.scale
    x_nom = A_nom.reshape(-1, order="F") / s
    H = (s * s) * (Ubar.T * Wd) @ Ubar + p.rho * np.eye(x_nom.size)
    f = -s * (Ubar.T * Wd) @ wbar - p.rho * x_nom
    return H, f, x_nom, p.delta / s


def solve_map(
    data: HoverData, A_nom: np.ndarray, params: IdentificationParams, require_determined: bool = True
) -> np.ndarray:
    """Identify one wrench map with DAQP (SPEC §3.2). Returns A (6 x n).

    ``require_determined=False`` solves even with fewer than n - 3 independent points (the proximal term
    and the box then decide the rest; used by the points-per-region study).
    """
    if require_determined:
        _check_enough(data, "identification")
    H, f, x_nom, d = _qp_terms(data, A_nom, params)
    H = 0.5 * (H + H.T)
    A_empty = np.zeros((0, x_nom.size))
    x, _, exitflag, _ = daqp.solve(H, f, A_empty, x_nom + d, x_nom - d)
    if exitflag < 1:  # DAQP: 1 optimal, 2 soft optimal; below 1 a failure
        raise InputError(f"identification QP failed (DAQP exit flag {exitflag})")
    if not np.all(np.isfinite(x)):
        raise InputError("identification QP gave non-finite values (hover data too large or ill-conditioned)")
    return (np.asarray(x) * params.scale).reshape(A_nom.shape, order="F")


def solve_map_lsq(data: HoverData, A_nom: np.ndarray, params: IdentificationParams) -> np.ndarray:
    """The same problem as :func:`solve_map`, solved by SciPy's bounded least squares (the test oracle)."""
    from scipy.optimize import lsq_linear  # here: every campaign and run imports this module, few need SciPy's

    _check_enough(data, "identification")
    Ubar, wbar, Wd = _stacked(data, params.weights)
    s = params.scale
    x_nom = A_nom.reshape(-1, order="F") / s
    sw = np.sqrt(Wd)
    M = np.vstack([sw[:, None] * Ubar * s, math.sqrt(params.rho) * np.eye(x_nom.size)])
    b = np.concatenate([sw * wbar, math.sqrt(params.rho) * x_nom])
    d = params.delta / s
    res = lsq_linear(M, b, bounds=(x_nom - d, x_nom + d), method="bvls", tol=1e-14, max_iter=10_000)
    return (res.x * s).reshape(A_nom.shape, order="F")


def force_residual_rms(data: HoverData, A: np.ndarray) -> float:
    """RMS over points of the force-residual norm ``|f_j − A_1 u_j|`` [N]."""
    r = data.w_B[:, :3] - data.u_hz2 @ A[:3].T
    return float(np.sqrt(np.mean(np.sum(r * r, axis=1))))


def assign_regions(data: HoverData, partition: Partition, region: str | None = None) -> list[str]:
    """Region of each point: ``region`` if given, else the point's own label, else from its force direction."""
    if region is not None:
        partition.region(region)
        return [region] * data.n_points
    out = []
    for j in range(data.n_points):
        if data.region[j]:
            partition.region(data.region[j])
            out.append(data.region[j])
            continue
        f = data.w_B[j, :3]
        if np.linalg.norm(f) < 1e-9:
            raise InputError(f"{data.source[j]}: point {j + 1} has zero force; its region is undefined")
        out.append(partition.name_of_direction(f))
    return out


def _entry(data: HoverData, A_nom: np.ndarray, params: IdentificationParams) -> MapEntry:
    A = solve_map(data, A_nom, params)
    return MapEntry(
        A=A,
        points=data.n_points,
        force_residual_rms_N=force_residual_rms(data, A),
        nominal_force_residual_rms_N=force_residual_rms(data, A_nom),
        identified=True,
    )


def identify(
    data: HoverData,
    vehicle: VehicleParams,
    params: IdentificationParams = IdentificationParams(),  # noqa: B008  (frozen, immutable)
    partition: Partition | None = None,
    region: str | None = None,
) -> WrenchMapSet:
    """Identify the global map and one map per region that has data.

    Args:
        data: hover points.
        vehicle: the vehicle (its nominal map is the centre of the box).
        params: QP settings (Δ, weights).
        partition: regions of the sphere (default: the paper's ten).
        region: put every point in this region instead of deriving it from the force direction.

    Returns:
        The maps; regions without data keep the nominal map and are left out of ``regions``.
    """
    partition = partition or load_partition("paper")
    if data.u_hz2.shape[1] != vehicle.n_rotors:
        raise InputError(
            f"hover data have {data.u_hz2.shape[1]} rotors, vehicle {vehicle.name!r} has {vehicle.n_rotors}"
        )
    names = np.array(assign_regions(data, partition, region))
    A_nom = vehicle.A_nom
    regions = {}
    for name in partition.names:
        mask = names == name
        if mask.any():
            sub = data.subset(mask)
            try:
                regions[name] = _entry(sub, A_nom, params)
            except InputError as exc:
                raise InputError(f"region {name}: {exc}") from None
    return WrenchMapSet(
        vehicle=vehicle.name,
        nominal=A_nom.copy(),
        partition=partition,
        regions=regions,
        global_=_entry(data, A_nom, params),
        delta=params.delta,
        weights=tuple(params.weights),
        rho=params.rho,
    )


def few_points(n_rotors: int) -> int:
    """Points per region below which identification warns: twice the ``n - 3`` its force rows need."""
    return 2 * max(n_rotors - 3, 1)


def identification_warnings(
    data: HoverData,
    vehicle: VehicleParams,
    maps: WrenchMapSet,
    region: str | None = None,
) -> list[str]:
    """What makes identified maps less meaningful than their table suggests, one line each (for stderr).

    * a region fitted from fewer points than :func:`few_points` (twice the ``n - 3`` independent hover inputs its
      force rows need, SPEC §3.2: at the minimum the points' noise goes straight into the map);
    * the nominal map missing the weight by more than :data:`WEIGHT_MISS_WARN` at the hover points: the
      vehicle's mass or ``c_f`` is likely off; the line gives the mass (or ``c_f``) that would explain the
      median miss, and whether the identified global map absorbed it within Δ;
    * ``region`` contradicting the points' attitudes (SPEC §3.3): how many points' force directions lie in
      another region.
    """
    out: list[str] = []
    n = vehicle.n_rotors
    for name, e in maps.regions.items():
        if e.points < few_points(n):
            out.append(
                f"{name}: {e.points} hover point(s); its force rows need {n - 3} independent ones and fewer than "
                f"{few_points(n)} leave the map further from its error floor (docs/beyond-the-paper.md: the "
                f"minimum, 30-60 % further; 10, 5-15 %; the paper flew about {PAPER_POINTS_PER_REGION} per region)"
            )
    weight = np.linalg.norm(data.w_B[:, :3], axis=1)
    ok = weight > 0
    if ok.any():
        nominal = np.linalg.norm(data.u_hz2[ok] @ vehicle.A_nom[:3].T, axis=1)
        ratio = float(np.median(nominal / weight[ok]))
        if abs(ratio - 1.0) > WEIGHT_MISS_WARN:
            fitted = np.linalg.norm(data.u_hz2[ok] @ maps.global_.A[:3].T, axis=1) if maps.global_ else nominal
            after = float(np.median(fitted / weight[ok]))
            verdict = (
                f"the identified global map absorbs it within Δ ({100 * (after - 1):+.0f} %)"
                if abs(after - 1.0) <= WEIGHT_MISS_WARN
                else f"the bound Δ = {maps.delta:g} cannot absorb it (identified global map {100 * (after - 1):+.0f} %)"
            )
            out.append(
                f"the nominal map gives {100 * (ratio - 1):+.0f} % of the weight at the hover points (median "
                f"{float(np.median(nominal)):.2f} N for {float(np.median(weight[ok])):.2f} N): a mass of "
                f"{vehicle.mass * ratio:.3g} kg (not {vehicle.mass:g}) or c_f = {vehicle.c_f / ratio:.3g} N/Hz² "
                f"(not {vehicle.c_f:.3g}) would explain it; {verdict}"
            )
    if region is not None:
        own = [maps.partition.name_of_direction(f) for f in data.w_B[:, :3] if np.linalg.norm(f) > 1e-9]
        other = [r for r in own if r != region]
        if other:
            counts = ", ".join(f"{r}: {other.count(r)}" for r in sorted(set(other)))
            out.append(
                f"--region {region}: {len(other)} of {data.n_points} point(s) have attitudes of another region "
                f"({counts}); they were fitted into {region} as asked"
            )
    return out
