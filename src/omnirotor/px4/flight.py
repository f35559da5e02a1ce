"""Reading a PX4 flight log (ULog) into our frames and units (SPEC §1.1, §3.1).

What is read (PX4 topic → ours):

* ``vehicle_attitude.q`` (w, x, y, z; FRD → NED) → ``R_WB`` (:mod:`~omnirotor.px4.frames`): required;
* rotor speeds: ``esc_status.esc[i].esc_rpm`` (negative for reverse rotation) / 60 → ``omega_hz`` [Hz]:
  required, unless the log has ``actuator_motors`` and the caller accepts the mapping below;
* ``vehicle_local_position`` x, y, z, vx, vy, vz, ax, ay, az (NED) → ``p_W``, ``v_W``, ``a_W``: optional;
* ``sensor_combined.gyro_rad`` (FRD) → ``omega_B`` [rad/s], else ``vehicle_angular_velocity.xyz``: optional;
* ``vehicle_land_detected.landed``: optional.

Rotor speeds from ``actuator_motors`` (when no ESC reports rpm): PX4's control allocator writes there each
motor's normalised thrust ``c`` in [0, 1] (in [-1, 1] for reversible rotors), before the output stage applies
its thrust curve (``THR_MDL_FAC``). With thrust proportional to the squared speed and full thrust at the
vehicle's ``omega_max_hz``, ``omega = sign(c) sqrt(|c|) omega_max``. It ignores idle speed, the thrust curve's
calibration and motor dynamics; the caller says on stderr that it was used.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from omnirotor.errors import InputError
from omnirotor.px4.frames import R_WB_from_px4_quat, vec_from_px4

__all__ = ["Flight", "read_flight", "check_flight_log", "read_ulog_params", "open_ulog"]

_TOPICS = [
    "vehicle_attitude",
    "esc_status",
    "actuator_motors",
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
        speed_source: "esc_status" or "actuator_motors".
        p_W: position [m] or None.
        v_W: velocity [m/s] or None.
        a_W: acceleration [m/s²] or None.
        omega_B: body angular rate [rad/s] or None.
        landed: landed flag (0/1) or None.
        params: the log's parameters.
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
    """The attitude, ESC and motor topics of a log; refuses a log without attitude or rotor speeds."""
    att = _topic(ulog, "vehicle_attitude")
    if att is None or len(att.data["timestamp"]) < 2:
        raise InputError(f"{p}: no attitude in the log (topic vehicle_attitude missing)")
    esc = _topic(ulog, "esc_status")
    if esc is not None and ("esc[0].esc_rpm" not in esc.data or len(esc.data["timestamp"]) < 2):
        esc = None
    motors = _topic(ulog, "actuator_motors")
    if motors is not None and len(motors.data["timestamp"]) < 2:
        motors = None
    if esc is None and (motors is None or need_omega_max):
        raise InputError(
            f"{p}: no rotor speeds in the log (topic esc_status with esc_rpm missing"
            + ("" if motors is None else "; actuator_motors needs the vehicle's omega_max_hz")
            + ")"
        )
    return att, esc, motors


def check_flight_log(path: str | Path) -> None:
    """Refuse, before anything else is read, a file that is not a ULog or has no attitude or rotor speeds.

    Rotor speeds from ``actuator_motors`` count (the vehicle's ``omega_max_hz`` maps them later).
    """
    p = Path(path)
    _require(open_ulog(p, ["vehicle_attitude", "esc_status", "actuator_motors"]), p, need_omega_max=False)


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
    att, esc, motors = _require(ulog, p, need_omega_max=omega_max_hz is None)
    R = Series(_time(att, t0), R_WB_from_px4_quat(_stack(att, "q[{}]", 4)))
    if n_rotors is None and "CA_ROTOR_COUNT" in params:
        n_rotors = int(params["CA_ROTOR_COUNT"])
    if esc is not None:
        n_esc = sum(1 for k in esc.data if k.startswith("esc[") and k.endswith("].esc_rpm"))
        n = n_esc if n_rotors is None else n_rotors
        if n > n_esc:
            raise InputError(f"{p}: esc_status reports {n_esc} ESCs, the vehicle has {n} rotors")
        omega = Series(_time(esc, t0), _stack(esc, "esc[{}].esc_rpm", n) / 60.0)
        source = "esc_status"
    else:
        n = n_rotors or sum(1 for k in motors.data if k.startswith("control["))
        c = _stack(motors, "control[{}]", n)
        c = np.where(np.isfinite(c), c, 0.0)  # PX4 logs NaN for a disarmed motor
        omega = Series(_time(motors, t0), np.sign(c) * np.sqrt(np.abs(c)) * omega_max_hz)
        source = "actuator_motors"
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
    return Flight(p.name, R, omega, source, p_W, v_W, a_W, omega_B, landed, params)
