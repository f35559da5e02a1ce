"""A stand-in for PX4 behind its Zenoh bridge, as a process, for the PX4 bridge's tests (not a mock of Zenoh).

It listens on a Zenoh endpoint in PX4's namespace, decodes what arrives on ``/fmu/in/actuator_motors``,
``offboard_control_mode`` and ``vehicle_command`` with the typestore (PX4's field lists), acts as PX4's commander
would for offboard direct actuator control (the mode switch accepted only while the heartbeat streams, arming
only in offboard), publishes ``/fmu/out/vehicle_status`` at 20 Hz, and leaves offboard (to hold, nav_state 4)
when the file ``leave`` appears in its folder. On SIGTERM it writes what it received to ``px4.json`` there.

Its sensors (the bridge's frame direction), each with the known values of :data:`IMU_FRD` and the functions
below, so that a test can follow them through the bridge into the node's frames:

* ``--imu-hz HZ``: ``/fmu/out/sensor_combined`` at HZ, paced on the wall clock, its ``timestamp`` PX4's sensor
  clock: ``t0 + k / HZ`` exactly (monotonic µs at the start), as a real IMU's samples are regular; mid-run, the
  file ``imu-hz`` in its folder (a number) changes the rate from the next sample on, and the file ``imu-gap`` (a
  number of ms) makes the IMU skip that long once: no sample, its clock runs on (each file read and removed);
* ``--nan-every N``: every N-th sample's gyro x is NaN (a broken sample the bridge must pass on, not choke on);
* ``--esc``: ``/fmu/out/esc_status`` with every IMU sample of 10 (100 Hz at 1 kHz): :func:`esc_rpm` per motor,
  reported in the order :data:`ESC_ORDER` (a report's ``actuator_function`` names its motor);
* ``--odometry``: ``/fmu/out/vehicle_odometry`` likewise at 100 Hz: :data:`ODOMETRY_NED` (position NED, q FRD ->
  NED), ``timestamp_sample`` 5 ms before the IMU sample it goes out with.

    python fake_px4.py ENDPOINT NAMESPACE FOLDER [--imu-hz HZ] [--nan-every N] [--esc] [--odometry]
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import time
from pathlib import Path

import numpy as np

from omnirotor.rosmsg import typestore
from omnirotor.transport import open_transport

IMU_FRD = {"gyro_rad": (0.125, 0.25, -0.5), "accelerometer_m_s2": (0.5, -0.25, -9.75)}
"""The IMU sample (FRD body; float32-exact values)."""
ESC_ORDER = (3, 0, 7, 1, 6, 2, 5, 4)
"""Motor numbers (0-based) in the order the ESC reports come (report k is of motor ESC_ORDER[k])."""
ODOMETRY_NED = {"position": (0.5, 0.25, -0.125), "q": (math.sqrt(0.5), 0.0, 0.0, -math.sqrt(0.5))}
"""PX4's pose: 0.5 m north, 0.25 m east, 0.125 m up; yawed 90° to the west (-90° about NED's down axis)."""


def esc_rpm(motor: int) -> int:
    """The speed of motor ``motor`` (0-based) [rpm]: (100 + motor) Hz, odd motors reversed."""
    return (-1 if motor % 2 else 1) * 60 * (100 + motor)


def _blank(cls) -> dict:
    """Every field of a message class as 0 (the caller gives its arrays)."""
    return {name: 0 for name in cls.__dataclass_fields__ if not name.startswith("__")}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("endpoint")
    ap.add_argument("namespace")
    ap.add_argument("folder", type=Path)
    ap.add_argument("--imu-hz", type=float, default=0.0)
    ap.add_argument("--nan-every", type=int, default=0)
    ap.add_argument("--esc", action="store_true")
    ap.add_argument("--odometry", action="store_true")
    a = ap.parse_args()
    folder = a.folder
    T = typestore().types
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    log = {"actuator_motors": [], "heartbeats": 0, "direct_actuator": True, "vehicle_commands": [], "states": [],
           "imu_sent": 0, "esc_sent": 0, "odometry_sent": []}  # fmt: skip
    nav, arming = 4, 1  # hold, disarmed
    last_beat = -1.0
    with open_transport(listen=[a.endpoint], namespace=a.namespace, node="fake_px4") as t:
        motors = t.subscriber("/fmu/in/actuator_motors", "px4_msgs/msg/ActuatorMotors", depth=4096)
        beats = t.subscriber("/fmu/in/offboard_control_mode", "px4_msgs/msg/OffboardControlMode", depth=256)
        cmds = t.subscriber("/fmu/in/vehicle_command", "px4_msgs/msg/VehicleCommand", depth=256)
        pub = t.publisher("/fmu/out/vehicle_status", "px4_msgs/msg/VehicleStatus")
        cls = T["px4_msgs/msg/VehicleStatus"]
        status = cls(**dict.fromkeys((f for f in cls.__dataclass_fields__ if not f.startswith("__")), 0))
        imu = esc = odo = None
        if a.imu_hz > 0:
            pub_imu = t.publisher("/fmu/out/sensor_combined", "px4_msgs/msg/SensorCombined")
            imu = T["px4_msgs/msg/SensorCombined"](**{**_blank(T["px4_msgs/msg/SensorCombined"]),
                                                     "gyro_rad": np.array(IMU_FRD["gyro_rad"], np.float32),
                                                     "accelerometer_m_s2": np.array(IMU_FRD["accelerometer_m_s2"],
                                                                                    np.float32)})  # fmt: skip
        if a.esc:
            pub_esc = t.publisher("/fmu/out/esc_status", "px4_msgs/msg/EscStatus")
            Report = T["px4_msgs/msg/EscReport"]
            reports = [Report(**{**_blank(Report), "esc_rpm": esc_rpm(m), "actuator_function": 101 + m})
                       for m in ESC_ORDER]  # fmt: skip
            reports += [Report(**_blank(Report)) for _ in range(12 - len(reports))]
            esc = T["px4_msgs/msg/EscStatus"](**{**_blank(T["px4_msgs/msg/EscStatus"]), "esc": reports,
                                                 "esc_count": len(ESC_ORDER), "esc_online_flags": 0xFF})  # fmt: skip
        if a.odometry:
            pub_odo = t.publisher("/fmu/out/vehicle_odometry", "px4_msgs/msg/VehicleOdometry")
            O = T["px4_msgs/msg/VehicleOdometry"]  # noqa: N806
            zero3 = np.zeros(3, np.float32)
            odo = O(**{**_blank(O), "position": np.array(ODOMETRY_NED["position"], np.float32),
                       "q": np.array(ODOMETRY_NED["q"], np.float32), "velocity": zero3, "angular_velocity": zero3,
                       "position_variance": zero3, "orientation_variance": zero3, "velocity_variance": zero3,
                       "pose_frame": 1, "velocity_frame": 1})  # fmt: skip
        next_status = 0.0
        t0_us = time.monotonic_ns() // 1000
        wall0 = time.monotonic()
        k = 0
        hz = a.imu_hz
        due, ts_us = wall0, float(t0_us)  # the next sample's wall time and PX4 time stamp
        skip_s = 0.0
        while not stop:
            now = time.monotonic()
            while (m := beats.take()) is not None:
                log["heartbeats"] += 1
                log["direct_actuator"] &= bool(m.direct_actuator) and not (m.position or m.velocity or m.attitude)
                last_beat = now
            while (m := cmds.take()) is not None:
                log["vehicle_commands"].append([int(m.command), float(m.param1), float(m.param2), nav, arming])
                if m.command == 176 and int(m.param2) == 6 and now - last_beat < 0.5:
                    nav = 14
                elif m.command == 400:
                    arming = 2 if (m.param1 == 1.0 and nav == 14) else (1 if m.param1 == 0.0 else arming)
            while (m := motors.take()) is not None:
                log["actuator_motors"].append(
                    [None if np.isnan(c) else float(c) for c in m.control] + [int(m.reversible_flags), nav, arming]
                )
            if nav == 14 and (folder / "leave").exists():
                nav = 4
            if now >= next_status:
                next_status = now + 0.05
                if imu is not None:
                    hz = _read_once(folder / "imu-hz", hz)
                    skip_s = 1e-3 * _read_once(folder / "imu-gap", 0.0)
                status.nav_state, status.arming_state = nav, arming
                pub.put(status)
                log["states"].append([nav, arming])
            if imu is None:
                time.sleep(0.002)
                continue
            if skip_s:  # a gap: no sample for skip_s, PX4's clock runs on
                due, ts_us, skip_s = due + skip_s, ts_us + 1e6 * skip_s, 0.0
            # the IMU's samples due by now (a late loop catches up: PX4's sensor clock is regular)
            while due <= time.monotonic() and not stop:
                ts = round(ts_us)
                due, ts_us = due + 1.0 / hz, ts_us + 1e6 / hz
                imu.timestamp = ts
                imu.gyro_rad[0] = (
                    math.nan if a.nan_every and k % a.nan_every == a.nan_every // 2 else IMU_FRD["gyro_rad"][0]
                )
                if esc is not None and k % 10 == 0:
                    esc.timestamp = ts
                    pub_esc.put(esc)
                    log["esc_sent"] += 1
                if odo is not None and k % 10 == 5:
                    odo.timestamp, odo.timestamp_sample = ts, ts - 5000
                    pub_odo.put(odo)
                    log["odometry_sent"].append(ts - 5000)
                pub_imu.put(imu)
                log["imu_sent"] += 1
                k += 1
            time.sleep(max(0.0, min(0.0005, due - time.monotonic())))
    (folder / "px4.json").write_text(json.dumps(log))


def _read_once(path: Path, default: float) -> float:
    """The number in the file ``path`` (then removed), or ``default`` when there is none (yet)."""
    try:
        value = float(path.read_text())
    except (OSError, ValueError):
        return default
    path.unlink()
    return value


if __name__ == "__main__":
    main()
