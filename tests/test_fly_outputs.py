"""The recording and the live view wired into ``omnirotor fly`` and ``omnirotor sim --serve`` (issue 24, items 2, 7).

Both processes run for real over Zenoh on loopback: a lockstep SITL hover recorded by the node and by the
simulator, each bag read back; the live view of each process, with a WebSocket client receiving the pose.
"""

from __future__ import annotations

import json
import struct
import time

import numpy as np
import pytest

from omnirotor.fly.record import read_recording
from sitl.procs import Pair, free_port, wait_until

websockets = pytest.importorskip("websockets.sync.client")


@pytest.mark.slow
def test_a_lockstep_hover_recorded_by_both_processes_reads_back(tmp_path):
    node_bag, sim_bag = tmp_path / "node-bag", tmp_path / "sim-bag"
    with Pair(tmp_path, "hover", ["--seed", "2", "--duration", "2", "--record", str(sim_bag)], lockstep=True,
              node_args=("--record", str(node_bag))) as pair:  # fmt: skip
        sitl, node = pair.wait(timeout_s=900)
    steps = sitl["sitl"]["steps"]
    assert steps == 2000 and not sitl["sitl"]["failsafe"]
    # the node: every frame it answered (minus what its ring dropped), with the speeds it sent
    rec_node = node["recording"]
    assert "error" not in rec_node, rec_node
    got = read_recording(node_bag)
    n = len(got.t)
    assert n == node["frames"] - rec_node["dropped"] and n > 1500
    assert np.all(np.diff(got.t) > 0)  # in order, one per period
    assert got.cmd_hz.shape == (n, 8) and np.all(np.isfinite(got.cmd_hz)) and np.all(np.abs(got.cmd_hz) > 50)
    assert len(got.p_W) > 100 and np.all(np.abs(got.p_W[-50:, 2] - got.p_W[-1, 2]) < 0.05)  # the estimate hovers
    assert got.counts["/omnirotor/status"] >= 1
    # the simulator: every step, the speeds it flew, its true pose near the estimate's
    rec_sim = sitl["sitl"]["recording"]
    assert "error" not in rec_sim, rec_sim
    truth = read_recording(sim_bag)
    assert len(truth.t) == steps - rec_sim["dropped"] and len(truth.t) > 1500
    assert np.all(np.isfinite(truth.cmd_hz)) and len(truth.p_W) > 100
    assert abs(truth.p_W[-1, 2] - got.p_W[-1, 2]) < 0.05


def _poses(port: int, topic: str, n: int, timeout_s: float) -> list[tuple[float, dict]]:
    """Connect as a Foxglove client, subscribe to ``topic``, take ``n`` messages (log time, payload)."""
    out = []
    with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"], open_timeout=10) as ws:
        channels = {}
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and topic not in channels:
            msg = json.loads(ws.recv(timeout=10))
            if msg["op"] == "advertise":
                channels.update({c["topic"]: c for c in msg["channels"]})
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": channels[topic]["id"]}]}))
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and len(out) < n:
            try:
                data = ws.recv(timeout=2.0)
            except TimeoutError:
                continue
            if isinstance(data, bytes) and data[0] == 1:
                sub, log_ns = struct.unpack_from("<IQ", data, 1)
                out.append((log_ns * 1e-9, json.loads(data[13:])))
    return out


@pytest.mark.slow
def test_the_live_view_of_the_node_and_of_the_simulator_serve_the_pose(tmp_path):
    node_port, sim_port = free_port(), free_port()
    with Pair(tmp_path, "hover", ["--seed", "5", "--duration", "20", "--foxglove", "--foxglove-port", str(sim_port)],
              lockstep=False, node_args=("--foxglove", "--foxglove-port", str(node_port))) as pair:  # fmt: skip
        assert wait_until(lambda: "live view on" in pair.text("node") and "live view on" in pair.text("sim"), 300), (
            pair.text("node")[-1500:] + pair.text("sim")[-1500:]
        )
        node_poses = _poses(node_port, "/pose", 50, timeout_s=20)  # the estimate
        sim_poses = _poses(sim_port, "/pose_true", 50, timeout_s=20)  # the truth
        pair.kill()
    for poses in (node_poses, sim_poses):
        assert len(poses) == 50
        t = np.array([p[0] for p in poses])
        rate = (len(t) - 1) / (t[-1] - t[0])
        assert 40.0 < rate < 60.0  # 50 Hz of sample time
        z = np.array([p[1]["pose"]["position"]["z"] for p in poses])
        assert np.all(np.isfinite(z)) and np.all(z > 0.3)  # hovering
