"""Real-time software in the loop over real Zenoh on loopback (issue 24, items 4(b), 4(c), 4(e)).

Two processes (``omnirotor sim --serve`` and the flight node), free ports and a namespace per test, every wait
bounded, children killed on failure.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from omnirotor.experiments.tasks.common import SETTLE_S
from omnirotor.rosmsg.convert import COMMAND, LOOP_STATUS, SIM_STATUS
from sitl.procs import Pair, wait_until

MSG_ROOT = Path(__file__).resolve().parents[1] / "src" / "omnirotor" / "rosmsg"


def flying(pair: Pair, t, frames: int) -> None:
    """Wait until the node has answered ``frames`` frames (its LoopStatus says so)."""
    sub = t.subscriber("/omnirotor/loop_status", LOOP_STATUS, depth=4)
    got = wait_until(lambda: (m := sub.take_latest()) is not None and m.frames >= frames, timeout_s=300)
    assert got, pair.text("node")[-2000:] + pair.text("sim")[-2000:]


@pytest.mark.slow
def test_real_time_hover_holds_its_pose_over_the_transport(tmp_path):
    with Pair(tmp_path, "hover", ["--seed", "5", "--quick"], lockstep=False) as pair:
        sitl, node = pair.wait(timeout_s=600)
    assert not sitl["sitl"]["failsafe"] and not sitl["sitl"]["lockstep"]
    # the node flew it: its commands were obeyed, and each period without a fresh one held the last. What share of
    # the periods got their command in time is a speed figure of the machine (benchmarks/bench_transport.py,
    # BENCHMARKS.md), not a behaviour: on a loaded 2-core runner it fell to 87 %
    s = sitl["sitl"]
    assert s["commands_obeyed"] > 0 and s["commands_obeyed"] + s["commands_held"] >= s["steps"]
    # the hover's own verdict (every position error within HOVER_SUCCESS_CM after settling). How close the tracking
    # comes to the in-process run is the machine's too (the periods held): 0.35 cm RMS in x in process, 0.36 cm
    # over the transport alone, 0.87-0.90 cm on a loaded CI runner; not asserted here
    assert sitl["success"], sitl["ee_max_error_true"]
    assert node["link_losses"] == 0


@pytest.mark.slow
def test_killing_the_simulator_loses_the_link_and_stops_the_commands(tmp_path):
    with Pair(tmp_path, "hover", ["--seed", "1", "--duration", "60"], lockstep=False) as pair, pair.transport() as t:
        commands = t.subscriber("/omnirotor/rotor_cmd", COMMAND, depth=4096)
        loop = t.subscriber("/omnirotor/loop_status", LOOP_STATUS, depth=64)
        flying(pair, t, 1000)
        while commands.take() is not None:
            pass
        killed_at = time.monotonic()
        os.kill(pair.sim.pid, signal.SIGKILL)
        late, lost, sessions = [], False, set()
        while time.monotonic() < killed_at + 0.5:  # poll every millisecond: a take's time is its arrival's
            while (m := commands.take()) is not None:
                if time.monotonic() > killed_at + 0.06:
                    late.append(m.seq)
            while (m := loop.take()) is not None:
                lost = lost or m.link_lost
                sessions.add(m.session_id)
            time.sleep(0.001)
        assert lost, pair.text("node")[-2000:]
        _, node = pair.wait(timeout_s=60, sim_ok=False)
    assert node["link_lost"] and node["link_losses"] == 1
    assert node["link_lost_after_ms"] <= 50 + 25  # the 50 ms limit plus one loop pause on a loaded machine
    assert late == []  # nothing commanded once the link was lost
    assert "link lost" in pair.text("node")
    assert sessions == {int(node["session_id"], 16)}  # the node's status carries its session (a plant's --pair-session)


@pytest.mark.slow
def test_killing_the_node_engages_the_simulator_failsafe(tmp_path):
    """The rotors stop; the run has no metrics (a task's are over its whole protocol), what was flown is kept."""
    with Pair(tmp_path, "hover", ["--seed", "1", "--duration", "6"], lockstep=False) as pair, pair.transport() as t:
        status = t.subscriber("/omnirotor/sim_status", SIM_STATUS, depth=64)
        flying(pair, t, int(1000 * SETTLE_S) + 500)
        os.kill(pair.node.pid, signal.SIGKILL)
        engaged = wait_until(lambda: (m := status.take()) is not None and m.failsafe == 1, timeout_s=5)
        assert engaged, pair.text("sim")[-2000:]
        pair.wait(timeout_s=300, sim_ok=False, node_ok=False)
        assert pair.sim.returncode == 1, pair.text("sim")[-3000:]
        sitl = json.loads((pair.out / "hover-sitl.json").read_text())
        truth = np.load(pair.out / "truth.npz")
        ctl = np.load(pair.out / "controller.npz")
    s = sitl["sitl"]
    assert sitl["metrics"] is None and s["failsafe"] and 0.5 <= s["failsafe_after_s"] <= 0.5 + 0.05
    err = pair.text("sim")
    assert "offboard-loss failsafe" in err and "metrics cannot be computed" in err and "Traceback" not in err
    # the controller log ends with the node's last row (the periods after it said), its time increasing
    assert s["log_rows_cut"] > 500 and "the controller log ends with the node's last row" in err
    t_ctl = ctl["t"].ravel()
    assert t_ctl.size == s["steps"] - s["log_rows_cut"] and np.all(np.diff(t_ctl) > 0)
    rotor = truth["rotor_hz"]
    assert np.all(np.abs(rotor[-100:]) < 1.0)  # the rotors stopped by the end


@pytest.mark.slow
def test_an_independent_ros2_listener_decodes_every_topic(tmp_path):
    """Raw Zenoh and a rosbags store built from the shipped .msg files alone: what a ROS 2 listener needs."""
    import zenoh
    from zenoh.ext import Int64, z_deserialize

    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for path in sorted(MSG_ROOT.glob("*/msg/*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"{path.parts[-3]}/msg/{path.stem}"))
    store.register(types)
    with Pair(tmp_path, "hover", ["--seed", "2", "--duration", "30"], lockstep=False) as pair:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("listen/endpoints", "[]")
        conf.insert_json5("connect/endpoints", f'["{pair.endpoint}", "{pair.node_endpoint}"]')
        conf.insert_json5("scouting/multicast/enabled", "false")
        session = zenoh.open(conf)
        try:
            sub = session.declare_subscriber(f"0/{pair.namespace.strip('/')}/**", zenoh.handlers.FifoChannel(100000))
            end = time.monotonic() + 300
            seen: dict[str, int] = {}
            want = {"frame", "imu", "mocap", "rotor_speeds", "sim_status", "rotor_cmd", "loop_status", "wrench_est",
                    "controller_log"}  # fmt: skip
            while time.monotonic() < end and not want <= set(seen):
                sample = sub.try_recv()
                if sample is None:
                    time.sleep(0.001)
                    continue
                parts = str(sample.key_expr).split("/")
                topic, mangled, digest = parts[-3], parts[-2], parts[-1]
                pkg, kind, dds, name = mangled.split("::")
                assert dds == "dds_" and name.endswith("_")
                msgtype = f"{pkg}/{kind}/{name[:-1]}"
                assert digest == store.hash_rihs01(msgtype), msgtype
                msg = store.deserialize_cdr(sample.payload.to_bytes(), msgtype)
                assert msg.__msgtype__ == msgtype
                # rmw_zenoh's attachment (zenoh-cpp's serializer): int64 sequence number, int64 source time
                # stamp [ns], the 16-byte publisher id as a sequence
                seq, stamp, gid = z_deserialize(tuple[Int64, Int64, bytes], sample.attachment)
                assert seq >= 1 and len(gid) == 16 and abs(stamp - time.time_ns()) < 60 * 10**9
                seen[topic] = seen.get(topic, 0) + 1
        finally:
            session.close()
        pair.kill()
    assert want <= set(seen), sorted(seen)


@pytest.mark.slow
def test_a_task_cut_by_the_failsafe_says_why_it_has_no_metrics_without_a_traceback(tmp_path):
    """Point contact with the node killed early: the metrics of the unflown contact cannot exist (once a traceback)."""
    with Pair(tmp_path, "point-contact", ["--seed", "1", "--quick"], lockstep=False) as pair, pair.transport() as t:
        flying(pair, t, 1000)
        os.kill(pair.node.pid, signal.SIGKILL)
        try:
            sim_out, _ = pair.sim.communicate(timeout=300)
        finally:
            pair.kill()
    err = pair.text("sim")
    assert pair.sim.returncode == 1, err[-3000:]
    assert "Traceback" not in err
    assert "offboard-loss failsafe stopped the rotors after" in err and "metrics cannot be computed" in err
    out = json.loads(sim_out)
    assert out["metrics"] is None and out["sitl"]["failsafe"] and out["task"] == "point-contact"
