"""``omnirotor px4-bridge`` against a stand-in PX4 *process* on real Zenoh (loopback): what PX4 receives, decoded
with the typestore (PX4's field lists), what the node is told (issue 24 item 6; issue 26 item 5), and the frames
the bridge makes of PX4's sensors (:mod:`sitl.fake_px4` publishes known IMU, ESC and odometry values).

In the command tests the test is the flight node: it publishes RotorCommands of its session (and of a second one,
never obeyed, which starts first: the bridge is pinned to the node's session with ``--pair-session``), reads the
plant status the bridge publishes, and makes PX4 leave offboard (as its own failsafe or a pilot would). In the
frame tests it listens to the node's frames as an independent subscriber, is the motion-capture driver (a
PoseStamped publisher), and runs a real ``omnirotor fly`` node on the bridge's frames.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from omnirotor.cli import main
from omnirotor.fly.bridge import FAILSAFE_COMMAND_LOSS, FAILSAFE_NONE, FAILSAFE_ROBOT
from omnirotor.rosmsg.convert import COMMAND, COMMAND_ARMED, COMMAND_STOP, FRAME, POSE, SIM_STATUS, WireMessages
from omnirotor.sitl.server import TOPICS
from omnirotor.transport import open_transport
from omnirotor.vehicle import load_vehicle
from sitl import fake_px4
from sitl.procs import CLI, ZENOH_IO_THREADS, env, fifo_permitted, free_port, threads_of, wait_until

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
         "--px4-namespace", px4_ns, "--json", "--no-frames", "--pair-session", "1234"],
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

            def foreign_first():
                seq["theirs"] += 1
                theirs.seq, theirs.state, theirs.hz[:] = seq["theirs"], COMMAND_ARMED, wmax
                pub.put(theirs)
                time.sleep(0.002)

            # a foreign commander first: the bridge is pinned to the node's session (--pair-session), never to it
            s = _until(lambda: (m := latest()) is not None and m.commands_refused >= 50 and m, 120.0, foreign_first)
            assert s is not None, (tmp_path / "bridge.err").read_text()
            assert s.commands_obeyed == 0 and s.paired_session_id == 0x1234
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
            before_told = {"ticks": 0}

            def counted_tick():  # the armed commands sent before the bridge has said PX4 left
                before_told["ticks"] += 1
                tick()

            s = _until(lambda: (m := latest()) is not None and m.failsafe == FAILSAFE_ROBOT and m, 10.0, counted_tick)
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
    assert summary["commands_refused"] >= 350 and summary["foreign_sessions"] == 1
    assert got["heartbeats"] > 10 and got["direct_actuator"]
    commands = [(c[0], c[1], c[2]) for c in got["vehicle_commands"]]
    assert (176, 1.0, 6.0) in commands and (400, 1.0, 0.0) in commands  # offboard, then arm
    assert commands.index((176, 1.0, 6.0)) < commands.index((400, 1.0, 0.0))
    # PX4 ends disarmed, the last arm/disarm it got a disarm (the node's STOP disarmed it; re-armed, the node fell
    # silent before PX4 was armed again). Not "the last command": a re-arm whose 50 commands outlast the 1 s
    # heartbeat lead on a loaded machine also sends the mode switch, and PX4, not armed, needs no disarm then
    assert [c for c in commands if c[0] == 400][-1] == (400, 0.0, 0.0) and got["states"][-1][1] == 1
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
    # at most the armed commands sent before the bridge said so (it forwards until PX4's status reaches it, which
    # takes as long as the machine makes it) and a few already on their way; none of the 100 sent after it had
    assert 0 < stop - left <= before_told["ticks"] + 5
    assert len(motors) > 300


class _Px4Rig:
    """The fake PX4 and the bridge as processes; the test's own session listens (the bridge connects to it too,
    so that its subscribers exist before the bridge's first frame)."""

    def __init__(self, tmp: Path, px4_args: list[str], bridge_args: list[str], prefix: tuple[str, ...] = ()) -> None:
        self.tmp = tmp
        self.px4_ep, self.test_ep, self.px4_side_ep = (f"tcp/127.0.0.1:{free_port()}" for _ in range(3))
        self.ns, self.px4_ns = "/b", "/px4"
        self.px4 = subprocess.Popen(
            [sys.executable, str(HERE / "sitl" / "fake_px4.py"), self.px4_ep, self.px4_ns, str(tmp), *px4_args],
            env=env(), stderr=open(tmp / "px4.err", "w"),  # noqa: SIM115
        )  # fmt: skip
        self.t = open_transport(listen=[self.test_ep], namespace=self.ns)
        self.px4_side = open_transport(listen=[self.px4_side_ep], namespace=self.px4_ns)  # as PX4 (the garbage)
        self.frames = self.t.subscriber(TOPICS["frame"], FRAME, depth=1 << 14)
        self.bridge_err = tmp / "bridge.err"
        self.bridge = subprocess.Popen(
            [*prefix, sys.executable, "-c", CLI, "px4-bridge", "--connect", self.px4_ep, "--connect", self.test_ep,
             "--connect", self.px4_side_ep,
             "--namespace", self.ns, "--px4-namespace", self.px4_ns, "--json", *bridge_args],
            env=env(), stdout=subprocess.PIPE, stderr=open(self.bridge_err, "w"), text=True,  # noqa: SIM115
        )  # fmt: skip
        self.procs = [self.bridge, self.px4]

    def collect(self, n: int, timeout_s: float, tick=None) -> list:
        """At least ``n`` frames as the node receives them (copies), or what came within ``timeout_s``."""
        got = []
        end = time.monotonic() + timeout_s
        while len(got) < n and time.monotonic() < end and self.bridge.poll() is None:
            m = self.frames.take(0.05)
            if m is not None:
                got.append((int(m.seq), float(m.t), m.imu_acc_b.copy(), m.imu_gyro_b.copy(), m.rotor_hz.copy(),
                            bool(m.mocap_new), float(m.mocap_t), m.mocap_p_w.copy(), m.mocap_q_wb.copy(),
                            int(m.session_id)))  # fmt: skip
            if tick is not None:
                tick()
        return got

    def stop(self) -> tuple[dict, dict]:
        """SIGTERM both; the bridge's summary and what the fake PX4 received."""
        self.bridge.send_signal(signal.SIGTERM)
        summary = json.loads(self.bridge.communicate(timeout=60)[0])
        self.px4.send_signal(signal.SIGTERM)
        self.px4.wait(timeout=60)
        return summary, json.loads((self.tmp / "px4.json").read_text())

    def close(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        for t in (self.t, self.px4_side):
            t.close()


@pytest.mark.skipif(not fifo_permitted(), reason="SCHED_FIFO not permitted here (needs CAP_SYS_NICE or rtprio)")
def test_the_bridges_transport_threads_run_fifo_below_its_own_with_transport_priority(tmp_path):
    """``px4-bridge --fifo-priority 20 --transport-priority 10``, read from /proc while it bridges: its main thread
    at 20, Zenoh's I/O threads at 10, no thread above 20 (tests/test_transport_priority.py: the node and the
    simulator)."""
    rig = _Px4Rig(tmp_path, ["--imu-hz", "1000"], ["--fifo-priority", "20", "--transport-priority", "10"])
    try:
        assert len(rig.collect(200, 120.0)) >= 200, rig.bridge_err.read_text()[-2000:]
        threads = threads_of(rig.bridge.pid)
        rig.stop()
    finally:
        rig.close()
    assert threads[rig.bridge.pid][1:] == (os.SCHED_FIFO, 20), threads
    io = {tid: v for tid, v in threads.items() if v[0].startswith(ZENOH_IO_THREADS)}
    assert any(v[0].startswith("rx-") for v in io.values()) and all(
        v[1:] == (os.SCHED_FIFO, 10) for v in io.values()
    ), threads
    assert all(v[2] <= 20 for v in threads.values()), threads


@pytest.mark.slow
def test_the_bridge_makes_the_nodes_frames_of_px4s_imu_esc_telemetry_and_odometry(tmp_path):
    """Known values through the whole path: PX4's FRD/NED samples in, the node's FLU/NWU frame messages out."""
    rig = _Px4Rig(tmp_path, ["--imu-hz", "1000", "--esc", "--odometry", "--nan-every", "200"],
                  ["--mocap", "odometry", "--session-id", "b41d9e0000000003"])  # fmt: skip
    try:
        first = rig.collect(1, 120.0)
        assert first, rig.bridge_err.read_text()
        garbage = [rig.px4_side.publisher(f"/fmu/out/{k}", f"px4_msgs/msg/{m}") for k, m in
                   (("sensor_combined", "SensorCombined"), ("esc_status", "EscStatus"),
                    ("vehicle_odometry", "VehicleOdometry"))]  # fmt: skip
        for k in range(30):  # malformed payloads on every topic the frames come from: counted, never a crash
            for g in garbage:
                g.put_raw(bytes([0, 1, 0, 0]) + bytes(range(k % 7)))
            time.sleep(0.002)
        frames = first + rig.collect(1500, 120.0)
        summary, px4 = rig.stop()
    finally:
        rig.close()
    assert rig.bridge.returncode == 0 and len(frames) >= 1500, rig.bridge_err.read_text()
    seq = np.array([f[0] for f in frames])
    assert seq[0] == 0 and (np.diff(seq) > 0).all()  # numbered from 0, increasing
    # every frame says its plant (--session-id, said at the start; a node's --plant-session follows it)
    assert {fr[9] for fr in frames} == {0xB41D9E0000000003} and summary["plant_session_id"] == "b41d9e0000000003"
    assert "plant session b41d9e0000000003 (a node's --plant-session b41d9e0000000003" in rig.bridge_err.read_text()
    f = summary["frames"]
    assert f["frames"] >= seq[-1] + 1 and f["errors"] == 0 and f["imu_rate_hz"] == 1000.0
    # each topic's garbage counted (a subscriber keeps the newest `depth` samples, 16 for the ESC telemetry: on a
    # slow runner a burst can lose a few before the bridge takes them, so not necessarily all 30)
    assert all(1 <= v <= 30 for v in f["bad_payloads"].values()), f["bad_payloads"]
    # one clock: PX4's IMU stamps (t0 + k ms exactly, in µs) in seconds
    t_us = np.array([fr[1] for fr in frames]) * 1e6
    assert np.abs(t_us - np.round(t_us)).max() < 1e-3 and (np.diff(np.round(t_us)) % 1000 == 0).all()
    # IMU: FRD -> FLU, the broken samples passed as they are
    frd_acc, frd_gyro = fake_px4.IMU_FRD["accelerometer_m_s2"], fake_px4.IMU_FRD["gyro_rad"]
    flu = np.array([1.0, -1.0, -1.0])
    nan_gyro = 0
    for fr in frames:
        np.testing.assert_array_equal(fr[2], flu * frd_acc)
        if math.isnan(fr[3][0]):
            nan_gyro += 1
            np.testing.assert_array_equal(fr[3][1:], (flu * frd_gyro)[1:])
        else:
            np.testing.assert_array_equal(fr[3], flu * frd_gyro)
    assert nan_gyro >= 5
    # rotor speeds: rpm / 60 by motor number (the reports come in another order), NaN only for want of a report
    want_hz = np.array([fake_px4.esc_rpm(m) / 60.0 for m in range(8)])
    with_speeds = [fr for fr in frames if not np.isnan(fr[4]).all()]
    assert len(with_speeds) >= 0.9 * len(frames) and f["esc_nan_frames"] < f["frames"]
    for fr in with_speeds:
        np.testing.assert_array_equal(fr[4], want_hz)
    # motion capture: PX4's odometry NED/FRD -> NWU/FLU, in the frame after its sample, each sample once
    s = math.sqrt(0.5)
    sent = set(px4["odometry_sent"])
    new = [fr for fr in frames if fr[5]]
    assert len(new) >= 0.8 * len(frames) / 10
    for fr in new:
        np.testing.assert_allclose(fr[7], [0.5, -0.25, 0.125], rtol=1e-7)
        np.testing.assert_allclose(fr[8], [s, 0.0, 0.0, s], rtol=1e-7, atol=1e-7)  # yawed west: +90° about up
        assert round(fr[6] * 1e6) in sent and fr[6] <= fr[1]
    assert len({fr[6] for fr in new}) == len(new)
    assert all(fr[6] == 0.0 and not fr[7].any() and not fr[8].any() for fr in frames if not fr[5])  # no sample


@pytest.mark.slow
def test_px4s_imu_at_another_rate_than_the_nodes_is_refused_before_any_frame(tmp_path):
    rig = _Px4Rig(tmp_path, ["--imu-hz", "250", "--esc"], [])
    try:
        code = rig.bridge.wait(timeout=120)
        frames = rig.collect(1, 0.5)
        rig.px4.send_signal(signal.SIGTERM)
        rig.px4.wait(timeout=60)
    finally:
        rig.close()
    err = rig.bridge_err.read_text()
    assert code == 2 and not frames, err
    errors = [line for line in err.splitlines() if line.startswith("omnirotor: error:")]
    assert len(errors) == 1 and "Traceback" not in err
    assert "publishes at 250.0 Hz, the node's controller runs at 1000 Hz" in errors[0]
    assert "IMU_GYRO_RATEMAX" in errors[0]


@pytest.mark.slow
def test_a_node_arms_on_the_bridges_frames_with_a_mocap_pose_and_no_esc_telemetry(tmp_path, capsys):
    """The real node on PX4's IMU and a mocap driver's PoseStamped: it arms where the motion capture puts it."""
    rig = _Px4Rig(tmp_path, ["--imu-hz", "1000"], [])  # no ESC telemetry
    node_ep = f"tcp/127.0.0.1:{free_port()}"
    node_err = open(tmp_path / "node.err", "w")  # noqa: SIM115
    node = subprocess.Popen(
        [sys.executable, "-c", CLI, "fly", "--connect", rig.test_ep, "--listen", node_ep, "--namespace", rig.ns,
         "--fifo-priority", "0"], env=env(), stdout=subprocess.DEVNULL, stderr=node_err,
    )  # fmt: skip
    rig.procs.append(node)
    # the motion capture driver: our frames (z-up world, FLU body), stamped 4 ms before it publishes
    pose_pub = rig.t.publisher("/omnirotor/mocap", POSE)
    pose = WireMessages(8).pose
    pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = 0.3, -0.2, 0.12
    q = pose.pose.orientation
    q.w, q.x, q.y, q.z = math.cos(0.25), 0.0, 0.0, math.sin(0.25)  # yawed 0.5 rad
    stop = threading.Event()

    def mocap() -> None:
        while not stop.wait(0.01):
            stamp = time.time() - 0.004
            pose.header.stamp.sec, pose.header.stamp.nanosec = int(stamp), int((stamp % 1.0) * 1e9)
            pose_pub.put(pose)

    driver = threading.Thread(target=mocap, daemon=True)
    driver.start()
    base = ["ctl", "--connect", node_ep, "--namespace", rig.ns, "--timeout", "2"]
    try:
        frames = rig.collect(300, 120.0)

        def answered():
            code = main([*base, "status"])
            return capsys.readouterr().out if code == 0 else None

        assert wait_until(answered, timeout_s=300.0, step_s=0.5), (tmp_path / "node.err").read_text()[-2000:]
        assert main([*base, "arm"]) == 0
        assert "accepted: arm: disarmed -> armed (ground at (0.300, -0.200, 0.120))" in capsys.readouterr().out
        frames += rig.collect(200, 60.0)
        stop.set()
        driver.join(5)
        summary, _ = rig.stop()
    finally:
        stop.set()
        rig.close()
        node_err.close()
    err = rig.bridge_err.read_text()
    assert err.count("no ESC telemetry on /px4/fmu/out/esc_status after 1 s") == 1, err  # said once, PX4's name
    assert summary["commands_obeyed"] > 0  # the node's commands, answering the bridge's frames
    assert all(np.isnan(fr[4]).all() for fr in frames)  # no telemetry: NaN rotor speeds (the node rejects them)
    new = [fr for fr in frames if fr[5]]
    assert new and len(new) <= len(frames) / 5  # a 100 Hz sample in the 1 kHz frame after it, once
    for fr in new:
        np.testing.assert_array_equal(fr[7], [0.3, -0.2, 0.12])  # as the driver gave it
        np.testing.assert_array_equal(fr[8], [math.cos(0.25), 0.0, 0.0, math.sin(0.25)])
        assert fr[1] - 0.5 <= fr[6] <= fr[1]  # its stamp on PX4's clock, before the frame's IMU sample


def _unprivileged() -> tuple[str, ...]:
    """A command prefix under which a process may not use SCHED_FIFO: an rtprio limit of 0 (util-linux's prlimit)
    and, as root, no CAP_SYS_NICE (setpriv); skips when the tools are missing."""
    prlimit, setpriv = shutil.which("prlimit"), shutil.which("setpriv")
    if prlimit is None or (os.geteuid() == 0 and setpriv is None):
        pytest.skip("prlimit (and, as root, setpriv) needed to refuse SCHED_FIFO to the bridge")
    prefix = (prlimit, "--rtprio=0")
    if os.geteuid() == 0:
        prefix += (setpriv, "--bounding-set", "-sys_nice", "--inh-caps", "-sys_nice")
    return prefix


def _move(tmp: Path, name: str, value: float) -> None:
    """Tell the fake PX4 something through a file of its folder (written whole, then renamed into place)."""
    (tmp / f"{name}.tmp").write_text(str(value))
    (tmp / f"{name}.tmp").rename(tmp / name)


@pytest.mark.slow
def test_the_bridge_watches_px4s_imu_rate_all_flight_and_runs_on_when_sched_fifo_is_refused(tmp_path):
    """PX4's IMU slows to 800 Hz for 3 s mid-flight, then stops for 150 ms: each said once (and the recovery),
    counted in the summary, shown on /diagnostics and sent in SimStatus, the frames going on throughout (the node's
    controller integrates the real intervals); a real node reads the counts from SimStatus, says them and has them
    in its summary and its recording; the bridge asked for SCHED_FIFO and a CPU, was refused the first (one line)
    and bridged all the same."""
    from omnirotor.fly.bridge import DIAGNOSTIC_ARRAY, DIAGNOSTICS_TOPIC
    from omnirotor.fly.record import read_recording

    cpu = (os.cpu_count() or 1) - 1
    rig = _Px4Rig(tmp_path, ["--imu-hz", "1000", "--esc"], ["--fifo-priority", "50", "--cpu", str(cpu)],
                  prefix=_unprivileged())  # fmt: skip
    diag_sub = rig.t.subscriber(DIAGNOSTICS_TOPIC, DIAGNOSTIC_ARRAY, depth=64)
    status_sub = rig.t.subscriber(TOPICS["sim_status"], SIM_STATUS, depth=64)
    diags: list[tuple[int, str]] = []
    statuses: list[tuple[int, float, int, float]] = []
    bag = tmp_path / "flight"
    node_err = tmp_path / "node.err"
    node = subprocess.Popen(
        [sys.executable, "-c", CLI, "fly", "--connect", rig.test_ep, "--listen", f"tcp/127.0.0.1:{free_port()}",
         "--namespace", rig.ns, "--fifo-priority", "0", "--json", "--record", str(bag)],
        env=env(), stdout=subprocess.PIPE, stderr=open(node_err, "w"), text=True,  # noqa: SIM115
    )  # fmt: skip
    rig.procs.append(node)

    def tick() -> None:
        while (m := diag_sub.take()) is not None:
            diags.extend((int(st.level), st.message) for st in m.status)
        while (m := status_sub.take()) is not None:
            statuses.append((m.imu_rate_off_episodes, m.imu_rate_off_s, m.imu_gaps, m.imu_worst_gap_s))

    try:
        frames = rig.collect(1, 120.0)
        assert frames, rig.bridge_err.read_text()
        frames += rig.collect(1500, 30.0, tick)
        _move(tmp_path, "imu-hz", 800)
        end = time.monotonic() + 3.0
        frames += rig.collect(10**6, 3.0, tick)
        _move(tmp_path, "imu-hz", 1000)
        while time.monotonic() < end + 2.0:
            frames += rig.collect(10**6, 0.5, tick)
        _move(tmp_path, "imu-gap", 150)
        frames += rig.collect(10**6, 1.5, tick)
        # the node (its controller compiled or loaded meanwhile) has heard the counts in SimStatus: it says them
        heard = _until(lambda: "the plant says its IMU stream paused" in node_err.read_text(), 300.0,
                       lambda: rig.collect(10**6, 0.05))  # fmt: skip
        assert heard, node_err.read_text()[-3000:]
        node.send_signal(signal.SIGTERM)
        node_summary = json.loads(node.communicate(timeout=60)[0].strip().splitlines()[-1])
        summary, _ = rig.stop()
    finally:
        rig.close()
    err = rig.bridge_err.read_text()
    assert rig.bridge.returncode == 0, err
    lines = err.splitlines()
    refused = [line for line in lines if "SCHED_FIFO not permitted" in line]
    assert len(refused) == 1 and refused[0].startswith("omnirotor px4-bridge: SCHED_FIFO not permitted"), err
    assert not any("CPU affinity" in line for line in lines), err  # the CPU was granted
    slow = [line for line in lines if "at 800.0 Hz for more than 1 s" in line]
    back = [line for line in lines if "back at 1000.0 Hz after" in line]
    gap = [line for line in lines if "no sample for" in line]
    assert len(slow) == 1 and "frames go on" in slow[0] and len(back) == 1 and len(gap) == 1, err
    w = summary["frames"]["imu_watch"]
    assert w["off_episodes"] == 1 and 1.0 < w["off_s"] < 4.0 and w["worst_off_rate_hz"] == 800.0, w
    assert w["gaps"] >= 1 and w["worst_gap_ms"] > 100.0 and w["rate_hz"] == 1000.0, w
    # the frames went on: PX4's samples 1.25 ms apart carried into frames, and the 150 ms jump of its clock
    t_us = np.round(np.array([fr[1] for fr in frames]) * 1e6)
    seq = np.array([fr[0] for fr in frames])
    step = np.diff(t_us)[np.diff(seq) == 1]  # consecutive frames
    assert (step == 1250).sum() > 1500 and (step >= 150_000).sum() == 1, np.unique(step)
    # /diagnostics once a second: OK at the rate, WARN while it was off and after the gap
    assert (0, "1000.0 Hz") in diags, diags
    assert any(lv == 1 and m.startswith("800.0 Hz, off --rate-hz 1000 for ") for lv, m in diags), diags
    assert any(lv == 1 and "gap(s) over 20 ms" in m for lv, m in diags), diags
    # SimStatus carries the counts: no episode before the slow-down; the episode, the gap after it
    assert statuses[0][0] == 0 and statuses[-1][0] == 1, (statuses[:3], statuses[-1])
    assert 1.0 < statuses[-1][1] < 4.0 and 1 <= statuses[-1][2] <= w["gaps"] and statuses[-1][3] > 0.1, statuses[-1]
    # the node heard them: said once each, in its summary, and recorded with the plant's status
    node_lines = node_err.read_text().splitlines()
    assert sum("the plant says its IMU rate is off the control rate (1 time(s)" in x for x in node_lines) == 1
    assert sum("the plant says its IMU stream paused" in x for x in node_lines) == 1
    p = node_summary["plant_imu"]
    assert p["rate_off_episodes"] == 1 and 1.0 < p["rate_off_s"] < 4.0, p
    assert p["gaps"] >= 1 and p["worst_gap_ms"] > 100.0, p
    rec = read_recording(bag).plant_status
    assert rec and rec[-1].imu_rate_off_episodes == 1 and rec[-1].imu_gaps == p["gaps"]


def test_the_bridge_imports_neither_the_controller_nor_the_simulator():
    """The bridge stands where the simulator stands: it meets the node through the messages only (a fresh process);
    its command and the real-time module it shares with the node neither."""
    code = (
        "import sys, omnirotor.fly.bridge, omnirotor.fly.px4, omnirotor.px4.frames, omnirotor.realtime\n"
        "import omnirotor.cli.cmd_px4_bridge, omnirotor.cli.realtime_options\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[:2] in (['omnirotor', 'control'], ['omnirotor', 'sim'])"
        " or m == 'mujoco')\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], env=env(), capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "", out.stdout + out.stderr
