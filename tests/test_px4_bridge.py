"""``omnirotor px4-bridge`` against a stand-in PX4 *process* on real Zenoh (loopback): what PX4 receives, decoded
with the typestore (PX4's field lists), and what the node is told (issue 24 item 6; issue 26 item 5).

The test is the flight node: it publishes RotorCommands of its session (and of a second one, never obeyed), reads
the plant status the bridge publishes, and makes PX4 leave offboard (as its own failsafe or a pilot would).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from omnirotor.fly.bridge import FAILSAFE_COMMAND_LOSS, FAILSAFE_NONE, FAILSAFE_ROBOT
from omnirotor.rosmsg.convert import COMMAND, COMMAND_ARMED, COMMAND_STOP, SIM_STATUS, WireMessages
from omnirotor.sitl.server import TOPICS
from omnirotor.transport import open_transport
from omnirotor.vehicle import load_vehicle
from sitl.procs import CLI, env, free_port

pytest.importorskip("zenoh")

HERE = Path(__file__).resolve().parent


def _until(cond, timeout_s, tick=None):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if tick is not None:
            tick()
        if (r := cond()) is not None and r is not False:
            return r
        time.sleep(0.005)
    return None


@pytest.mark.slow
def test_the_bridge_flies_the_paired_node_on_px4_and_tells_it_when_px4_stops_obeying(tmp_path):
    veh = load_vehicle("omnirotor")
    n, wmax = veh.n_rotors, float(veh.omega_max_hz)
    px4_ep, bridge_ep, ns, px4_ns = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}", "/b", "/px4"
    px4 = subprocess.Popen([sys.executable, str(HERE / "sitl" / "fake_px4.py"), px4_ep, px4_ns, str(tmp_path)],
                           env=env(), stderr=open(tmp_path / "px4.err", "w"))  # noqa: SIM115  # fmt: skip
    bridge = subprocess.Popen(
        [sys.executable, "-c", CLI, "px4-bridge", "--listen", bridge_ep, "--connect", px4_ep, "--namespace", ns,
         "--px4-namespace", px4_ns, "--json", "--no-frames"],
        env=env(), stdout=subprocess.PIPE, stderr=open(tmp_path / "bridge.err", "w"), text=True,  # noqa: SIM115
    )  # fmt: skip
    try:
        with (
            open_transport(connect=[bridge_ep], namespace=ns) as t,
            open_transport(connect=[px4_ep], namespace=px4_ns) as px4_side,
        ):
            px4_status = px4_side.subscriber("/fmu/out/vehicle_status", "px4_msgs/msg/VehicleStatus", depth=64)
            status = t.subscriber(TOPICS["sim_status"], SIM_STATUS, depth=64)
            pub = t.publisher(TOPICS["rotor_cmd"], COMMAND, block=True)
            ours, theirs = WireMessages(n).command, WireMessages(n).command
            ours.session_id, theirs.session_id = 0x1234, 0x9999
            seq = {"ours": 0, "theirs": 0}
            last = {"status": None}

            def send(state=COMMAND_ARMED, hz=200.0, foreign=True):
                seq["ours"] += 1
                ours.seq, ours.frame_seq, ours.state = seq["ours"], seq["ours"], state
                ours.hz[:] = hz
                pub.put(ours)
                if foreign:  # a second commander at full speed: never obeyed
                    seq["theirs"] += 1
                    theirs.seq, theirs.state = seq["theirs"], COMMAND_ARMED
                    theirs.hz[:] = wmax
                    pub.put(theirs)

            def latest():
                while (m := status.take()) is not None:
                    last["status"] = m
                return last["status"]

            def tick():
                send()
                time.sleep(0.005)

            # armed commands stream: heartbeat, then (after 1 s) offboard, then arming; the foreign session refused
            s = _until(lambda: (m := latest()) is not None and m.commands_obeyed > 300 and m, 120.0, tick)
            assert s is not None, (tmp_path / "bridge.err").read_text()
            assert s.paired_session_id == 0x1234 and s.foreign_sessions == 1 and s.failsafe == FAILSAFE_NONE

            def px4_flying():
                m = px4_status.take_latest()
                return m is not None and m.nav_state == 14 and m.arming_state == 2

            assert _until(px4_flying, 60.0, tick)  # PX4 in offboard and armed for the node
            for _ in range(60):  # PX4's status reaches the bridge too
                tick()
            # PX4 leaves offboard (its failsafe, a pilot): the node is told; nothing more goes to the motors
            (tmp_path / "leave").touch()
            s = _until(lambda: (m := latest()) is not None and m.failsafe == FAILSAFE_ROBOT and m, 10.0, tick)
            assert s is not None and "PX4 left offboard (nav_state 4)" in s.cause
            for _ in range(100):
                tick()
            send(COMMAND_STOP, 0.0, foreign=False)  # the node disarmed (the director is told by this status)
            s = _until(lambda: (m := latest()) is not None and m.failsafe == FAILSAFE_NONE and m, 10.0,
                       lambda: (send(COMMAND_STOP, 0.0, foreign=False), time.sleep(0.01)))  # fmt: skip
            assert s is not None
            # armed again, then silence: the bridge's command loss stops the motors and disarms PX4
            for _ in range(50):
                tick()
            s = _until(lambda: (m := latest()) is not None and m.failsafe == FAILSAFE_COMMAND_LOSS and m, 10.0)
            assert s is not None and "no rotor command for" in s.cause
        bridge.send_signal(signal.SIGTERM)
        summary = json.loads(bridge.communicate(timeout=60)[0])
        px4.send_signal(signal.SIGTERM)
        px4.wait(timeout=60)
    finally:
        for p in (bridge, px4):
            if p.poll() is None:
                p.kill()
                p.wait()
    got = json.loads((tmp_path / "px4.json").read_text())
    assert summary["commands_refused"] >= 300 and summary["foreign_sessions"] == 1
    assert got["heartbeats"] > 10 and got["direct_actuator"]
    commands = [(c[0], c[1], c[2]) for c in got["vehicle_commands"]]
    assert (176, 1.0, 6.0) in commands and (400, 1.0, 0.0) in commands  # offboard, then arm
    assert commands.index((176, 1.0, 6.0)) < commands.index((400, 1.0, 0.0))
    assert commands[-1] == (400, 0.0, 0.0)  # disarmed at the command loss
    motors = got["actuator_motors"]
    want = 200.0 * 200.0 / wmax**2
    flying = [m for m in motors if m[0] is not None]
    assert flying and all(m[:n] == pytest.approx([want] * n, rel=1e-6) for m in flying)  # never the foreign speeds
    assert all(m[k] is None for m in motors for k in range(n, 12))  # motors beyond the vehicle's: stopped
    assert all(m[12] == (1 << n) - 1 for m in motors)  # reversible
    stopped = [i for i, m in enumerate(motors) if all(c is None for c in m[:12])]
    assert stopped  # the STOP command and the command loss sent NaN
    # nothing reached the motors while PX4 was out of offboard after it had flown there
    left = next(i for i, m in enumerate(motors) if m[13] == 4 and m[14] == 2 and i > 0 and motors[i - 1][13] == 14)
    stop = next(i for i in stopped if i > left)  # the node's STOP after it was told
    assert stop - left <= 5  # at most those already on their way when PX4 left; the 100 armed commands since: none
    assert len(motors) > 300
