"""Reading a PX4 flight log (ULog) into our frames and units (SPEC §1.1, §3.1).

What is read (PX4 topic → ours):

* ``vehicle_attitude.q`` (w, x, y, z; FRD → NED) → ``R_WB`` (:mod:`~omnirotor.px4.frames`): required;
* rotor speeds: ``esc_status.esc[i].esc_rpm`` (negative for reverse rotation) / 60 → ``omega_hz`` [Hz]:
  required, unless the log has ``actuator_motors`` and the caller accepts the mapping below;
* ``vehicle_local_position`` x, y, z, vx, vy, vz, ax, ay, az (NED) → ``p_W``, ``v_W``, ``a_W``: optional;
* ``sensor_combined.gyro_rad`` (FRD) → ``omega_B`` [rad/s], else ``vehicle_angular_velocity.xyz``: optional;
* ``vehicle_land_detected.landed``: optional.

Rotor speeds without ESC telemetry (most logs), mapped with thrust proportional to the squared speed and full
thrust at the vehicle's ``omega_max_hz``; the mapping is a note said on stderr, with the values it used:

* ``actuator_motors.control`` (PX4's control allocator): each motor's normalised thrust ``c`` in [0, 1] (in
  [-1, 1] for reversible rotors) before the output stage applies its thrust curve, so
  ``omega = sign(c) sqrt(|c|) omega_max``;
* else ``actuator_outputs.output`` (PWM [µs], the first ``n`` outputs of the first instance, or the outputs
  whose ``PWM_MAIN_FUNCk`` is Motor 1..n): ``x = (pwm − min) / (max − min)`` clipped to [0, 1], with the log's
  per-output ``PWM_MAIN_MINk``/``PWM_MAIN_MAXk`` (where set, ≥ 0) else ``PWM_MIN``/``PWM_MAX`` (else PX4's
  1000/2000 µs), and PX4's thrust model ``thrust = THR_MDL_FAC x² + (1 − THR_MDL_FAC) x`` (``THR_MDL_FAC``
  from the log, else PX4's default 0), so ``omega = sqrt(thrust) omega_max``. One-way rotors only.

Both ignore idle speed, the ESCs' calibration and motor dynamics.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from omnirotor.errors import InputError
from omnirotor.px4.frames import R_WB_from_px4_quat, vec_from_px4

__all__ = ["Flight", "read_flight", "check_flight_log", "read_ulog_params", "open_ulog"]

_TOPICS = [
    "vehicle_attitude",
    "esc_status",
    "actuator_motors",
    "actuator_outputs",
    "vehicle_local_position",
    "sensor_combined",
    "vehicle_angular_velocity",
    "vehicle_land_detected",
]


@dataclasses.dataclass(frozen=True)
class Series:
    """A signal sampled at its own times.

    Attributes:
        t: (N,) time since the log's start [s].
        x: (N, ...) values.
    """

    t: np.ndarray
    x: np.ndarray


@dataclasses.dataclass(frozen=True)
class Flight:
    """A flight in our frames and units.

    Attributes:
        name: file name.
        R_WB: attitude, (N, 3, 3) samples.
        omega_hz: signed rotor speeds [Hz], (N, n).
        speed_source: "esc_status", "actuator_motors" or "actuator_outputs".
        p_W: position [m] or None.
        v_W: velocity [m/s] or None.
        a_W: acceleration [m/s²] or None.
        omega_B: body angular rate [rad/s] or None.
        landed: landed flag (0/1) or None.
        params: the log's parameters.
        notes: what was assumed reading it (for stderr).
    """

    name: str
    R_WB: Series
    omega_hz: Series
    speed_source: str
    p_W: Series | None
    v_W: Series | None
    a_W: Series | None
    omega_B: Series | None
    landed: Series | None
    params: dict
    notes: tuple[str, ...] = ()


def open_ulog(path: str | Path, topics: list[str] | None = None, header_only: bool = False):
    """Parse a ULog with pyulog once :func:`~omnirotor.px4.ulog_guard.guard` passed it; failures are InputError."""
    import contextlib
    import io

    from pyulog import ULog

    from omnirotor.px4.ulog_guard import guard

    p = Path(path)
    guard(p)  # refuses, before pyulog allocates anything, what pyulog would not read cleanly
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # pyulog prints its warnings
            return ULog(str(p), topics, parse_header_only=header_only)
    except Exception as exc:  # pyulog raises many kinds on corrupt files
        raise InputError(f"{p}: not a readable ULog ({type(exc).__name__}: {exc})") from None


def read_ulog_params(path: str | Path) -> dict[str, float]:
    """The initial parameters of a ULog (name → value)."""
    return dict(open_ulog(path, header_only=True).initial_parameters)


def _topic(ulog, name: str):
    found = [d for d in ulog.data_list if d.name == name]
    return min(found, key=lambda d: d.multi_id) if found else None


def _time(d, t0_us: int) -> np.ndarray:
    return (d.data["timestamp"].astype(np.int64) - t0_us) * 1e-6


def _stack(d, fmt: str, count: int) -> np.ndarray:
    return np.column_stack([d.data[fmt.format(i)].astype(float) for i in range(count)])


def _require(ulog, p: Path, need_omega_max: bool):
    """The attitude and rotor-speed topics of a log; refuses a log without attitude or rotor speeds.

    Returns ``(attitude, esc_status, actuator_motors, actuator_outputs)``, the last three None where absent.
    """
    att = _topic(ulog, "vehicle_attitude")
    esc = _topic(ulog, "esc_status")
    if esc is not None and ("esc[0].esc_rpm" not in esc.data or len(esc.data["timestamp"]) < 2):
        esc = None
    motors = _topic(ulog, "actuator_motors")
    if motors is not None and len(motors.data["timestamp"]) < 2:
        motors = None
    outputs = _topic(ulog, "actuator_outputs")
    if outputs is not None and (len(outputs.data["timestamp"]) < 2 or "output[0]" not in outputs.data):
        outputs = None
    missing = []
    if att is None or len(att.data["timestamp"]) < 2:
        missing.append("attitude (topic vehicle_attitude missing)")
    if esc is None and motors is None and outputs is None:
        missing.append("rotor speeds (none of esc_status with esc_rpm, actuator_motors, actuator_outputs)")
    elif esc is None and need_omega_max:
        missing.append(
            "rotor speeds (no esc_status with esc_rpm; actuator_motors or actuator_outputs need the vehicle's "
            "omega_max_hz)"
        )
    if missing:
        raise InputError(f"{p}: no " + "; no ".join(missing) + " in the log")
    return att, esc, motors, outputs


def check_flight_log(path: str | Path) -> None:
    """Refuse, before anything else is read, a file that is not a ULog or has no attitude or rotor speeds.

    Rotor speeds from ``actuator_motors`` or ``actuator_outputs`` count (the vehicle's ``omega_max_hz`` maps them
    later).
    """
    p = Path(path)
    topics = ["vehicle_attitude", "esc_status", "actuator_motors", "actuator_outputs"]
    _require(open_ulog(p, topics), p, need_omega_max=False)


def read_flight(path: str | Path, n_rotors: int | None = None, omega_max_hz: float | None = None) -> Flight:
    """Read what identification needs from a ULog.

    Args:
        path: the ``.ulg`` file.
        n_rotors: rotors to read (default: ``CA_ROTOR_COUNT`` of the log, else the ESC count).
        omega_max_hz: the vehicle's largest rotor speed [Hz], for the ``actuator_motors`` mapping.

    Raises:
        InputError: not a ULog, or no attitude, or no rotor speeds; the message names what is missing.
    """
    p = Path(path)
    ulog = open_ulog(p, _TOPICS)
    t0 = int(ulog.start_timestamp)
    params = dict(ulog.initial_parameters)
    att, esc, motors, outputs = _require(ulog, p, need_omega_max=omega_max_hz is None)
    R = Series(_time(att, t0), R_WB_from_px4_quat(_stack(att, "q[{}]", 4)))
    if n_rotors is None and "CA_ROTOR_COUNT" in params:
        n_rotors = int(params["CA_ROTOR_COUNT"])
    notes: list[str] = []
    if esc is not None:
        n_esc = sum(1 for k in esc.data if k.startswith("esc[") and k.endswith("].esc_rpm"))
        n = n_esc if n_rotors is None else n_rotors
        if n > n_esc:
            raise InputError(f"{p}: esc_status reports {n_esc} ESCs, the vehicle has {n} rotors")
        omega = Series(_time(esc, t0), _stack(esc, "esc[{}].esc_rpm", n) / 60.0)
        source = "esc_status"
    elif motors is not None:
        n = n_rotors or sum(1 for k in motors.data if k.startswith("control["))
        c = _stack(motors, "control[{}]", n)
        c = np.where(np.isfinite(c), c, 0.0)  # PX4 logs NaN for a disarmed motor
        omega = Series(_time(motors, t0), np.sign(c) * np.sqrt(np.abs(c)) * omega_max_hz)
        source = "actuator_motors"
        notes.append(
            "no esc_rpm in the log: rotor speeds mapped from actuator_motors as "
            f"sign(c) sqrt(|c|) x {omega_max_hz:g} Hz"
        )
    else:
        omega, note = _speeds_from_pwm(outputs, params, n_rotors, omega_max_hz, t0, p)
        source = "actuator_outputs"
        notes.append(note)
    lp = _topic(ulog, "vehicle_local_position")
    p_W = v_W = a_W = None
    if lp is not None and len(lp.data["timestamp"]) >= 2:
        tl = _time(lp, t0)
        p_W = Series(tl, vec_from_px4(np.column_stack([lp.data[k] for k in ("x", "y", "z")]).astype(float)))
        v_W = Series(tl, vec_from_px4(np.column_stack([lp.data[k] for k in ("vx", "vy", "vz")]).astype(float)))
        if all(k in lp.data for k in ("ax", "ay", "az")):
            a_W = Series(tl, vec_from_px4(np.column_stack([lp.data[k] for k in ("ax", "ay", "az")]).astype(float)))
    omega_B = None
    sc = _topic(ulog, "sensor_combined")
    av = _topic(ulog, "vehicle_angular_velocity")
    if sc is not None and "gyro_rad[0]" in sc.data:
        omega_B = Series(_time(sc, t0), vec_from_px4(_stack(sc, "gyro_rad[{}]", 3)))
    elif av is not None:
        omega_B = Series(_time(av, t0), vec_from_px4(_stack(av, "xyz[{}]", 3)))
    ld = _topic(ulog, "vehicle_land_detected")
    landed = Series(_time(ld, t0), ld.data["landed"].astype(float)) if ld is not None and "landed" in ld.data else None
    return Flight(p.name, R, omega, source, p_W, v_W, a_W, omega_B, landed, params, tuple(notes))


PX4_PWM_DEFAULTS = {"PWM_MIN": 1000.0, "PWM_MAX": 2000.0, "THR_MDL_FAC": 0.0}
"""PX4's defaults of the PWM range [µs] and thrust-model factor, used when a log lacks them."""


def _speeds_from_pwm(outputs, params: dict, n_rotors: int | None, omega_max_hz: float, t0: int, p: Path):
    """Rotor speeds [Hz] from ``actuator_outputs`` PWM (module docstring) and the note saying how."""
    n_out = sum(1 for k in outputs.data if k.startswith("output["))

    def number(name: str) -> float | None:  # a finite parameter value, else None (absent or corrupt)
        try:
            v = float(params[name])
        except (KeyError, TypeError, ValueError):
            return None
        return v if math.isfinite(v) else None

    funcs = {int(v): k - 1 for k in range(1, 17) if (v := number(f"PWM_MAIN_FUNC{k}")) is not None}
    motors = [funcs[101 + i] for i in range(n_rotors or 0) if 101 + i in funcs]  # 101..: Motor 1..
    n = n_rotors or n_out
    channels = motors if n_rotors and len(motors) == n_rotors else list(range(n))
    if max(channels, default=0) >= n_out:
        raise InputError(f"{p}: actuator_outputs has {n_out} outputs, the vehicle has {n} rotors")
    used, took_default = {}, []
    for key in ("PWM_MIN", "PWM_MAX", "THR_MDL_FAC"):
        v = number(key)
        if v is not None and v >= 0:
            used[key] = v
        else:
            used[key] = PX4_PWM_DEFAULTS[key]
            took_default.append(key)
    unset = -1.0  # PX4's "use PWM_MIN / PWM_MAX" for a per-output value
    lo = np.array([unset if (v := number(f"PWM_MAIN_MIN{k + 1}")) is None else v for k in channels])
    hi = np.array([unset if (v := number(f"PWM_MAIN_MAX{k + 1}")) is None else v for k in channels])
    lo = np.where(lo >= 0, lo, used["PWM_MIN"])
    hi = np.where(hi >= 0, hi, used["PWM_MAX"])
    if np.any(hi <= lo):
        raise InputError(f"{p}: the log's PWM range is empty (PWM_MIN >= PWM_MAX) for a motor output")
    pwm = np.column_stack([outputs.data[f"output[{k}]"].astype(float) for k in channels])
    x = np.clip((np.where(np.isfinite(pwm), pwm, 0.0) - lo) / (hi - lo), 0.0, 1.0)
    f = min(max(used["THR_MDL_FAC"], 0.0), 1.0)
    thrust = f * x * x + (1.0 - f) * x
    ranges = sorted({(float(a), float(b)) for a, b in zip(lo, hi, strict=True)})
    note = (
        f"no esc_rpm or actuator_motors in the log: rotor speeds mapped from actuator_outputs "
        f"{'(outputs ' + ', '.join(str(k + 1) for k in channels) + ')'} as sqrt(thrust) x {omega_max_hz:g} Hz, "
        f"thrust = THR_MDL_FAC x² + (1 - THR_MDL_FAC) x, x = (pwm - min)/(max - min); PWM range "
        + ", ".join(f"{a:g}-{b:g} µs" for a, b in ranges)
        + f", THR_MDL_FAC = {f:g}"
        + (
            f" ({', '.join(took_default)}: PX4's default, absent or invalid in the log)"
            if took_default
            else " (from the log)"
        )
        + "; idle speed and ESC calibration ignored"
    )
    return Series(_time(outputs, t0), np.sqrt(thrust) * omega_max_hz), note
