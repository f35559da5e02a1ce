"""Metrics of an interaction run: Table 1 errors (SPEC §6), contact, forces, insertion.

Table 1 of the paper reports the RMS and maximum of the end-effector pose error against the *compliant*
reference (the admittance filter's output), position in cm and attitude in degrees, the attitude error being
the controller's ``e_R = ½(RᵀR^r − R^rᵀR)^∨`` (SPEC §4.1, §6). The authors' ``metrics/rmse.m`` takes the pose
from their logs, i.e. the pose the robot *believed* (motion capture through the state estimator, the pose the
controller's ``e_R`` is computed from): :func:`pose_errors` computes that by default (``pose="believed"``,
the ``ee_rms_error`` / ``ee_max_error`` of a run). The simulator also knows the *true* pose
(``pose="true"``, ``ee_rms_error_true`` / ``ee_max_error_true``): a slow error of the believed pose (a
motion-capture drift) moves the true robot while the believed one stays near the reference, so it shows
mostly there. The simulator adds what the paper could not measure: the true contact force at the end-effector and
whether the tip touches.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from omnirotor._jit import jit_entry, jit_inline

__all__ = [
    "PEG_DEPTH_GOAL_CM",
    "PEG_TILT_GOAL_DEG",
    "peg_depth_tilt",
    "RunLog",
    "held_contact",
    "CONTACT_WINDOW_S",
    "smoothed",
    "PAPER_TABLE1",
    "pose_errors",
    "error_stats",
    "table1_errors",
    "contact_stats",
    "force_stats",
    "AXES",
    "POSES",
]

AXES = ("x_cm", "y_cm", "z_cm", "roll_deg", "pitch_deg", "yaw_deg")
POSES = ("believed", "true")
"""Whose end-effector pose the Table 1 errors use: the state estimate's (the paper's, SPEC §6) or the truth."""

# SPEC §6 (paper Table 1): RMS and max of (ex, ey, ez [cm], e_phi, e_theta, e_psi [deg]).
PAPER_TABLE1: dict[str, dict[str, tuple[float, ...]]] = {
    "point-contact/nominal": {"rms": (2.09, 1.87, 0.56, 0.40, 0.16, 0.50), "max": (5.06, 4.01, 2.50, 1.70, 0.63, 1.55)},
    "point-contact-tilted/nominal": {
        "rms": (1.66, 1.44, 1.13, 0.47, 0.24, 0.41),
        "max": (3.75, 3.03, 2.77, 2.03, 0.95, 1.38),
    },
    "sliding/nominal": {"rms": (1.96, 0.71, 0.76, 0.51, 0.20, 0.20), "max": (3.48, 2.03, 3.64, 3.85, 1.32, 1.51)},
    "sliding/global": {"rms": (3.0, 0.50, 0.32, 0.29, 0.16, 0.16), "max": (4.90, 1.17, 1.32, 1.63, 0.59, 0.70)},
    "sliding/piecewise": {"rms": (0.88, 0.68, 1.29, 0.25, 0.13, 0.15), "max": (1.65, 1.53, 3.09, 1.45, 0.54, 0.72)},
    "peg-in-hole/nominal": {"rms": (2.02, 1.36, 1.14, 0.29, 0.13, 0.17), "max": (2.45, 2.94, 1.52, 0.67, 0.38, 0.44)},
}


@dataclasses.dataclass(frozen=True)
class RunLog:
    """The signals of one closed-loop run, sampled at the control rate (N samples).

    Attributes:
        t: (N,) time [s].
        p_E_W: (N, 3) true end-effector tip position [m].
        R_WE: (N, 3, 3) true end-effector attitude.
        p_E_est_W: (N, 3) end-effector tip position the controller believed (its state estimate) [m].
        R_WE_est: (N, 3, 3) end-effector attitude the controller believed.
        p_Er_W: (N, 3) compliant end-effector reference position [m] (admittance output).
        R_WEr: (N, 3, 3) compliant end-effector reference attitude.
        p_Ed_W: (N, 3) desired (planned) end-effector position [m].
        f_ext_hat_W: (N, 3) observer's external force estimate, world frame [N].
        m_ext_hat_B: (N, 3) observer's external moment estimate, body frame [N·m].
        f_contact_W: (N, 3) true contact force on the robot at the tip, world frame [N].
        in_contact: (N,) true contact flag.
        region: (N,) index of the wrench-map region in use (-1 when not piecewise).
        omega_hz: (N, n) rotor speed commands [Hz].
        status: (N,) controller status flags.
    """

    t: np.ndarray
    p_E_W: np.ndarray
    R_WE: np.ndarray
    p_E_est_W: np.ndarray
    R_WE_est: np.ndarray
    p_Er_W: np.ndarray
    R_WEr: np.ndarray
    p_Ed_W: np.ndarray
    f_ext_hat_W: np.ndarray
    m_ext_hat_B: np.ndarray
    f_contact_W: np.ndarray
    in_contact: np.ndarray
    region: np.ndarray
    omega_hz: np.ndarray
    status: np.ndarray

    def window(self, t0: float, t1: float) -> np.ndarray:
        """Boolean mask of samples with t0 <= t <= t1."""
        return (self.t >= t0) & (self.t <= t1)


RAD2DEG = 180.0 / math.pi
"""Degrees per radian: the factor of ``np.degrees``, so the compiled errors equal NumPy's to the last bit."""


@jit_inline
def _pose_error_into(p, R, p_r, R_r, i: int, e) -> None:
    """Row ``i`` of :func:`pose_errors` into ``e`` (6,): position [cm], then ``e_R = ½(RᵀR^r − R^rᵀR)^∨`` [deg].

    ``M = RᵀR^r`` is summed over its inner index in order (as ``np.einsum`` does), so the row is NumPy's, bit for bit.
    """
    for a in range(3):
        e[a] = (p[i, a] - p_r[i, a]) * 100.0
    # e_R: ½ (M[2,1] − M[1,2]), ½ (M[0,2] − M[2,0]), ½ (M[1,0] − M[0,1]) with M[a,b] = Σ_j R[j,a] R^r[j,b]
    for c, (a, b) in enumerate(((2, 1), (0, 2), (1, 0))):
        m_ab = R[i, 0, a] * R_r[i, 0, b] + R[i, 1, a] * R_r[i, 1, b] + R[i, 2, a] * R_r[i, 2, b]
        m_ba = R[i, 0, b] * R_r[i, 0, a] + R[i, 1, b] * R_r[i, 1, a] + R[i, 2, b] * R_r[i, 2, a]
        e[3 + c] = (0.5 * (m_ab - m_ba)) * RAD2DEG


@jit_entry
def _pose_error_rows(p, R, p_r, R_r, out) -> None:
    """Every row of :func:`pose_errors` into ``out`` (N, 6)."""
    for i in range(out.shape[0]):
        _pose_error_into(p, R, p_r, R_r, i, out[i])


@jit_entry
def _pose_error_sums(p, R, p_r, R_r, mask, sq_sum, abs_max) -> int:
    """Σ e² and max |e| per axis of :func:`pose_errors` over the rows of ``mask``, in one pass; the rows counted.

    The sums run over the rows in order, as NumPy's ``mean(axis=0)`` of the masked rows does; a NaN propagates into
    the maximum as in ``np.max``.
    """
    e = np.empty(6)
    sq_sum[:] = 0.0
    abs_max[:] = -np.inf
    count = 0
    for i in range(mask.shape[0]):
        if not mask[i]:
            continue
        _pose_error_into(p, R, p_r, R_r, i, e)
        count += 1
        for j in range(6):
            sq_sum[j] += e[j] * e[j]
            a = abs(e[j])
            if a > abs_max[j] or a != a:
                abs_max[j] = a
    return count


def _pose_signals(log: RunLog, pose: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    if pose not in POSES:
        raise ValueError(f"pose must be one of {POSES}, got {pose!r}")
    p, R = (log.p_E_est_W, log.R_WE_est) if pose == "believed" else (log.p_E_W, log.R_WE)
    return p, R, log.p_Er_W, log.R_WEr


def pose_errors(log: RunLog, pose: str = "believed") -> np.ndarray:
    """(N, 6) errors: EE − compliant reference position [cm], attitude error e_R [deg] (SPEC §6).

    Args:
        log: the run's signals.
        pose: "believed" (the state estimate's EE pose, as the paper's ``metrics/rmse.m``) or "true".
    """
    signals = _pose_signals(log, pose)
    e = np.empty((log.t.size, 6))
    _pose_error_rows(*signals, e)
    return e


def error_stats(
    log: RunLog, mask: np.ndarray | None = None, pose: str = "believed"
) -> tuple[dict[str, float], dict[str, float]]:
    """RMS and max absolute errors per axis of :func:`pose_errors` (``ee_rms_error``, ``ee_max_error``).

    One compiled pass over the rows (no (N, 3, 3) temporaries), equal to the mean and maximum of the masked rows of
    :func:`pose_errors` to the last bit (tested).

    Raises:
        ValueError: ``mask`` selects no row.
    """
    signals = _pose_signals(log, pose)
    keep = np.ones(log.t.size, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    sq_sum, abs_max = np.empty(6), np.empty(6)
    count = _pose_error_sums(*signals, keep, sq_sum, abs_max)
    if count == 0:
        raise ValueError("error_stats: the mask selects no sample")
    rms = np.sqrt(sq_sum / count)
    return dict(zip(AXES, map(float, rms), strict=True)), dict(zip(AXES, map(float, abs_max), strict=True))


def table1_errors(log: RunLog, mask: np.ndarray | None = None) -> dict[str, dict[str, float]]:
    """The run JSON's four Table 1 objects of :func:`error_stats`.

    ``ee_rms_error``/``ee_max_error`` of the believed pose (the paper's), ``ee_rms_error_true``/``ee_max_error_true``
    of the true pose.
    """
    out: dict[str, dict[str, float]] = {}
    for pose, suffix in (("believed", ""), ("true", "_true")):
        out[f"ee_rms_error{suffix}"], out[f"ee_max_error{suffix}"] = error_stats(log, mask, pose)
    return out


CONTACT_WINDOW_S = 0.02
"""Contact is judged like a force sensor of ~50 Hz bandwidth would: touching within the last 20 ms counts.

A rigid tip dragged with friction over a rigid surface chatters at a few hundred hertz in simulation (stick-slip,
micrometre lift-offs); an FT sensor or a person watching would call that continuous contact."""


def held_contact(in_contact: np.ndarray, t: np.ndarray, window_s: float = CONTACT_WINDOW_S) -> np.ndarray:
    """Contact flags held for ``window_s`` after each touch (see :data:`CONTACT_WINDOW_S`)."""
    c = in_contact.astype(bool)
    if c.size < 2 or window_s <= 0:
        return c
    w = max(1, int(round(window_s / float(np.median(np.diff(t))))))
    return np.convolve(c.astype(float), np.ones(w), mode="full")[: c.size] > 0


HF_CUTOFF_HZ = 20.0
"""Frequency above which contact-force content counts as chatter (issue 12: a real tool tip shows little)."""


def high_frequency_ratio(x: np.ndarray, t: np.ndarray, cutoff_hz: float = HF_CUTOFF_HZ) -> float | None:
    """RMS of the part of ``x`` above ``cutoff_hz`` over the mean of ``x`` (zero-phase FFT split); None if too short.

    Args:
        x: (N,) samples (e.g. the true contact-force magnitude [N]).
        t: (N,) their times [s], evenly spaced.
        cutoff_hz: the split frequency [Hz].
    """
    if x.size < 8 or t.size != x.size:
        return None
    dt = float(np.median(np.diff(t)))
    mean = float(np.mean(x))
    if mean == 0.0 or x.size * dt < 2.0 / cutoff_hz:
        return None
    spec = np.fft.rfft(x - mean)
    spec[np.fft.rfftfreq(x.size, dt) < cutoff_hz] = 0.0
    hf = np.fft.irfft(spec, n=x.size)
    return float(math.sqrt(np.mean(hf * hf)) / abs(mean))


def contact_stats(log: RunLog, phase: np.ndarray, settle_s: float = 0.5) -> dict:
    """Contact over the contact phase: fraction in contact, whether and when contact was lost, chatter.

    Contact is :func:`held_contact` (touching within the last 20 ms). It counts as lost when the tip stays off
    the surface for longer than ``settle_s`` after it first touched within the phase. ``force_hf_ratio`` is
    :func:`high_frequency_ratio` of the true contact-force magnitude in steady contact (from ``settle_s`` after
    the first touch to the end of the phase, or to the loss), None without such a stretch.
    """
    c = held_contact(log.in_contact, log.t)[phase]
    t = log.t[phase]
    if c.size == 0:
        return {"fraction": 0.0, "lost": False, "first_loss_s": None, "first_contact_s": None, "force_hf_ratio": None}
    first = int(np.argmax(c)) if c.any() else -1
    lost, first_loss = False, None
    if first >= 0:
        dt = float(np.median(np.diff(t))) if t.size > 1 else 1e-3
        need = max(1, int(round(settle_s / dt)))
        off = ~c[first:]
        run = 0
        for i, o in enumerate(off):
            run = run + 1 if o else 0
            if run >= need:
                lost, first_loss = True, float(t[first + i - need + 1])
                break
    hf = None
    if first >= 0:
        steady = (t >= t[first] + settle_s) & (t < (first_loss if first_loss is not None else np.inf))
        f = np.linalg.norm(log.f_contact_W[phase], axis=1)
        hf = high_frequency_ratio(f[steady], t[steady])
    return {
        "fraction": float(c.mean()),
        "lost": lost,
        "first_loss_s": first_loss,
        "first_contact_s": float(t[first]) if first >= 0 else None,
        "force_hf_ratio": hf,
    }


def smoothed(x: np.ndarray, t: np.ndarray, window_s: float = CONTACT_WINDOW_S) -> np.ndarray:
    """Moving average of a signal over ``window_s`` (what a force sensor of that bandwidth reads)."""
    w = max(1, int(round(window_s / float(np.median(np.diff(t)))))) if t.size > 1 else 1
    k = np.ones(w) / w
    if x.ndim == 1:
        return np.convolve(x, k, mode="same")
    return np.column_stack([np.convolve(x[:, j], k, mode="same") for j in range(x.shape[1])])


def force_stats(log: RunLog, mask: np.ndarray) -> dict:
    """True contact force against the observer's estimate over ``mask`` (world frame, N)."""
    if not mask.any():
        return {"true_mean_N": None, "estimated_mean_N": None, "estimate_rms_error_N": None}
    ft, fe = log.f_contact_W[mask], log.f_ext_hat_W[mask]
    err = np.linalg.norm(fe - ft, axis=1)
    return {
        "true_mean_N": ft.mean(axis=0).tolist(),
        "estimated_mean_N": fe.mean(axis=0).tolist(),
        "estimate_rms_error_N": float(math.sqrt(np.mean(err * err))),
    }


PEG_DEPTH_GOAL_CM = 16.5
"""The peg-in-hole claim's depth goal [cm] (of the 17 cm insertion; paper/claims.py's ten-seed goal)."""
PEG_TILT_GOAL_DEG = (3.0, 7.0)
"""The band the inserted peg's tilt should settle in [deg] (paper ~5°; paper/claims.py's ten-seed goal)."""


def peg_depth_tilt(log: RunLog, hole_entrance, axis_in=(0.0, -1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """The peg's insertion depth [m] past the hole's entrance and its tilt [deg] from the hole's inward axis.

    The peg runs along the end effector's +y through the tip (SPEC §5.2); both are the true pose's, per sample.
    """
    a = np.asarray(axis_in, dtype=float)
    depth = (log.p_E_W - np.asarray(hole_entrance, dtype=float)) @ a
    tilt = np.degrees(np.arccos(np.clip(log.R_WE[:, :, 1] @ a, -1.0, 1.0)))
    return depth, tilt
