"""A stand-in for PX4 behind its Zenoh bridge, as a process, for the PX4 bridge's test (not a mock of Zenoh).

It listens on a Zenoh endpoint in PX4's namespace, decodes what arrives on ``/fmu/in/actuator_motors``,
``offboard_control_mode`` and ``vehicle_command`` with the typestore (PX4's field lists), acts as PX4's commander
would for offboard direct actuator control (the mode switch accepted only while the heartbeat streams, arming
only in offboard), publishes ``/fmu/out/vehicle_status`` at 20 Hz, and leaves offboard (to hold, nav_state 4)
when the file ``leave`` appears in its folder. On SIGTERM it writes what it received to ``px4.json`` there.

    python fake_px4.py ENDPOINT NAMESPACE FOLDER
"""

from __future__ import annotations

import json
import signal
import sys
import time
from pathlib import Path

import numpy as np

from omnirotor.rosmsg import typestore
from omnirotor.transport import open_transport


def main() -> None:
    endpoint, namespace, folder = sys.argv[1], sys.argv[2], Path(sys.argv[3])
    T = typestore().types
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    log = {"actuator_motors": [], "heartbeats": 0, "direct_actuator": True, "vehicle_commands": [], "states": []}
    nav, arming = 4, 1  # hold, disarmed
    last_beat = -1.0
    with open_transport(listen=[endpoint], namespace=namespace, node="fake_px4") as t:
        motors = t.subscriber("/fmu/in/actuator_motors", "px4_msgs/msg/ActuatorMotors", depth=4096)
        beats = t.subscriber("/fmu/in/offboard_control_mode", "px4_msgs/msg/OffboardControlMode", depth=256)
        cmds = t.subscriber("/fmu/in/vehicle_command", "px4_msgs/msg/VehicleCommand", depth=256)
        pub = t.publisher("/fmu/out/vehicle_status", "px4_msgs/msg/VehicleStatus")
        cls = T["px4_msgs/msg/VehicleStatus"]
        status = cls(**dict.fromkeys((f for f in cls.__dataclass_fields__ if not f.startswith("__")), 0))
        next_status = 0.0
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
                status.nav_state, status.arming_state = nav, arming
                pub.put(status)
                log["states"].append([nav, arming])
            time.sleep(0.002)
    (folder / "px4.json").write_text(json.dumps(log))


if __name__ == "__main__":
    main()
