"""The live view: a WebSocket client subscribes to the Foxglove server and receives the pose at its rate."""

import json
import struct
import time

import numpy as np
import pytest

from omnirotor.control.controller import LOG_GROUPS
from omnirotor.errors import InputError
from omnirotor.fly.live import LiveView
from omnirotor.messages import SensorFrame
from omnirotor.px4.mcap_export import CHANNELS
from omnirotor.recorder import Recorder

websockets = pytest.importorskip("websockets.sync.client")
COLUMNS = Recorder(1, LOG_GROUPS(8)).column_names


def _row(k):
    row = np.zeros(len(COLUMNS))
    for a in ("xx", "yy", "zz"):
        row[COLUMNS.index(f"R_WB.{a}")] = 1.0
    row[COLUMNS.index("p_W.x")] = 1e-3 * k
    row[COLUMNS.index("f_ext_W.y")] = -3.0
    return row


def _advertised(ws):
    """Channels by topic from the server's advertise messages (after serverInfo)."""
    channels = {}
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline and "/status" not in channels:
        msg = json.loads(ws.recv(timeout=5))
        if msg["op"] == "advertise":
            channels.update({c["topic"]: c for c in msg["channels"]})
    return channels


def test_a_websocket_client_receives_the_pose_at_its_rate():
    live = LiveView(port=0, rate_hz=50.0, log_columns=COLUMNS)
    try:
        with websockets.connect(f"ws://127.0.0.1:{live.port}", subprotocols=["foxglove.sdk.v1"]) as ws:
            channels = _advertised(ws)
            assert set(CHANNELS) - {"/scene"} <= set(channels)  # the MCAP export's channels, same schemas
            assert channels["/pose"]["schemaName"] == "foxglove.PoseInFrame"
            ws.send(
                json.dumps(
                    {
                        "op": "subscribe",
                        "subscriptions": [
                            {"id": 1, "channelId": channels["/pose"]["id"]},
                            {"id": 2, "channelId": channels["/wrench"]["id"]},
                        ],
                    }
                )
            )
            time.sleep(0.3)  # the subscription reaches the server
            hz = np.full(8, 140.0)
            for k in range(2000):  # 2 s of frames at 1 kHz
                frame = SensorFrame(k * 1e-3, np.array([0.0, 0.0, 9.81]), np.zeros(3), hz)
                live.node_period(frame, hz, _row(k))
                if k % 50 == 0:
                    time.sleep(0.002)
            poses, wrenches = [], []
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and len(poses) < 100:
                try:
                    data = ws.recv(timeout=1.0)
                except TimeoutError:
                    break
                if isinstance(data, bytes) and data[0] == 1:  # message data: op, subscription, log time, payload
                    sub, log_ns = struct.unpack_from("<IQ", data, 1)
                    payload = json.loads(data[13:])
                    (poses if sub == 1 else wrenches).append((log_ns * 1e-9, payload))
    finally:
        live.close()
    assert len(poses) == 100  # 2 s at 50 Hz
    t = np.array([p[0] for p in poses])
    np.testing.assert_allclose(np.diff(t), 0.02, atol=1.5e-3)  # the rate, in the samples' own time
    x = np.array([p[1]["pose"]["position"]["x"] for p in poses])
    np.testing.assert_allclose(x, t, atol=1e-9)  # each pose is its period's estimate (p_W.x = t here)
    assert wrenches and wrenches[0][1]["f_ext_hat_W"] == [0.0, -3.0, 0.0]
    assert live.published["/pose"] == 100


def test_the_live_view_refuses_a_bad_rate_and_a_taken_port():
    with pytest.raises(InputError, match="rate"):
        LiveView(port=0, rate_hz=0.0)
    a = LiveView(port=0)
    try:
        with pytest.raises(InputError, match="cannot start the Foxglove server"):
            LiveView(port=a.port)
    finally:
        a.close()
