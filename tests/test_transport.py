"""The transport interface over real Zenoh sessions on loopback (issue 24, item 1)."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from omnirotor.errors import InputError
from omnirotor.rosmsg import typestore
from omnirotor.transport import TRANSPORTS, Transport, key_expression, open_transport, register_transport, ros_topic

SPEEDS = "omnirotor_msgs/msg/RotorSpeeds"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def speeds(t: float, n: int = 8):
    T = typestore().types
    header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=0), frame_id="b")
    return T[SPEEDS](header=header, t=t, hz=np.arange(float(n)) + t)


def wait_for(fn, timeout_s: float = 5.0):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        out = fn()
        if out is not None:
            return out
        time.sleep(0.002)
    return None


@pytest.fixture
def pair():
    port = free_port()
    a = open_transport(listen=[f"tcp/127.0.0.1:{port}"])
    b = open_transport(listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    yield a, b
    a.close()
    b.close()


def connected(pub, sub) -> None:
    """Publish until the subscriber hears (the peers' declarations take a moment to propagate)."""
    assert wait_for(lambda: (pub.put(speeds(0.0)), sub.take())[1]) is not None
    time.sleep(0.2)  # the probes still on their way
    while sub.take() is not None:
        pass


def test_key_expression_follows_rmw_zenoh():
    key = key_expression(3, "/robot1/omnirotor/rotor_cmd", "omnirotor_msgs/msg/RotorCommand")
    parts = key.split("/")
    assert parts[:4] == ["3", "robot1", "omnirotor", "rotor_cmd"]
    assert parts[4] == "omnirotor_msgs::msg::dds_::RotorCommand_"
    assert parts[5] == typestore().hash_rihs01("omnirotor_msgs/msg/RotorCommand")
    assert parts[5].startswith("RIHS01_") and len(parts[5]) == 7 + 64


def test_publish_subscribe_round_trip_and_bad_payloads(pair):
    a, b = pair
    sub = b.subscriber("/omnirotor/rotor_speeds", SPEEDS, depth=16)
    pub = a.publisher("/omnirotor/rotor_speeds", SPEEDS, block=True)  # what is counted must arrive
    connected(pub, sub)
    pub.put(speeds(1.25))
    pub.put_raw(b"\x00\x01junk")  # not CDR of the type
    pub.put_raw(b"")
    pub.put(speeds(2.5))
    got = [wait_for(sub.take), wait_for(sub.take)]
    assert [m.t for m in got] == [1.25, 2.5]
    assert np.array_equal(got[1].hz, np.arange(8.0) + 2.5)
    assert sub.n_bad == 2
    assert sub.take() is None


def test_take_latest_skips_older(pair):
    a, b = pair
    sub = b.subscriber("/x", SPEEDS, depth=8)
    pub = a.publisher("/x", SPEEDS, block=True)
    connected(pub, sub)
    for k in range(5):
        pub.put(speeds(float(k)))
    time.sleep(0.2)
    assert sub.take_latest().t == 4.0
    assert sub.n_skipped == 4
    assert sub.take_latest() is None


def test_ring_keeps_the_newest_depth(pair):
    a, b = pair
    sub = b.subscriber("/x", SPEEDS, depth=3)
    pub = a.publisher("/x", SPEEDS, block=True)
    connected(pub, sub)
    for k in range(50):
        pub.put(speeds(float(k)))
    time.sleep(0.3)
    got = []
    while (m := sub.take()) is not None:
        got.append(m.t)
    assert got == [47.0, 48.0, 49.0]


def test_check_refuses_semantically_bad_messages(pair):
    a, b = pair
    sub = b.subscriber("/x", SPEEDS, check=lambda m: m.hz.shape == (8,) and bool(np.all(np.isfinite(m.hz))))
    pub = a.publisher("/x", SPEEDS, block=True)
    connected(pub, sub)
    pub.put(speeds(1.0, n=3))
    bad = speeds(2.0)
    bad.hz[0] = np.nan
    pub.put(bad)
    pub.put(speeds(3.0))
    assert wait_for(sub.take).t == 3.0
    assert sub.n_bad == 2


def test_namespaces_and_domains_do_not_cross():
    port = free_port()
    a = open_transport(listen=[f"tcp/127.0.0.1:{port}"], namespace="/r1")
    b = open_transport(listen=[], connect=[f"tcp/127.0.0.1:{port}"], namespace="/r2")
    c = open_transport(listen=[], connect=[f"tcp/127.0.0.1:{port}"], domain_id=7, namespace="/r1")
    d = open_transport(listen=[], connect=[f"tcp/127.0.0.1:{port}"], namespace="/r1")
    try:
        subs = [t.subscriber("/x", SPEEDS) for t in (b, c, d)]
        pub = a.publisher("/x", SPEEDS, block=True)
        assert wait_for(lambda: (pub.put(speeds(1.0)), subs[2].take())[1]) is not None
        time.sleep(0.2)
        assert subs[0].take() is None and subs[1].take() is None
    finally:
        for t in (a, b, c, d):
            t.close()


def test_request_reply(pair):
    a, b = pair
    T = typestore().types

    def handler(req):
        if req.t < 0:
            raise RuntimeError("refused")  # a failing handler: no reply, no crash
        return T[SPEEDS](header=req.header, t=2 * req.t, hz=req.hz[::-1].copy())

    a.serve("/omnirotor/ctl", SPEEDS, SPEEDS, handler)
    rep = b.request("/omnirotor/ctl", SPEEDS, speeds(1.5), SPEEDS, timeout_s=3.0)
    assert rep is not None and rep.t == 3.0 and rep.hz[0] == 7.0 + 1.5
    assert b.request("/omnirotor/ctl", SPEEDS, speeds(-1.0), SPEEDS, timeout_s=0.3) is None
    assert b.request("/omnirotor/nobody", SPEEDS, speeds(1.0), SPEEDS, timeout_s=0.2) is None


def test_bad_names_and_options_are_input_errors(capsys):
    with pytest.raises(InputError):
        ros_topic("", "/1bad")
    with pytest.raises(InputError):
        ros_topic("no space", "/x")
    assert ros_topic("/r1/", "x/y") == "/r1/x/y"
    with pytest.raises(InputError, match="unknown transport"):
        open_transport("carrier-pigeon")
    with pytest.raises(InputError, match="domain id"):
        open_transport(domain_id=233, listen=[])
    with pytest.raises(InputError, match="locator"):
        open_transport(listen=["127.0.0.1:7447"])
    t = open_transport(listen=[])
    try:
        with pytest.raises(InputError, match="unknown message type"):
            t.publisher("/x", "nope_msgs/msg/Nothing")
        with pytest.raises(InputError, match="depth"):
            t.subscriber("/x", SPEEDS, depth=0)
    finally:
        t.close()


def test_listening_outside_loopback_is_said(capsys):
    t = open_transport(listen=[f"tcp/0.0.0.0:{free_port()}"])
    t.close()
    assert "outside loopback" in capsys.readouterr().err


def test_registry_takes_another_transport():
    class Null(Transport):
        def __init__(self, **kw):
            super().__init__(domain_id=kw["domain_id"], namespace=kw["namespace"])

        def _publisher(self, name, msgtype, block):
            return (lambda payload, seq: None), name

        def _subscriber(self, name, msgtype, depth):
            return (lambda timeout_s: None), (lambda: None), name

        def _serve(self, name, reqtype, on_request):
            """A transport that carries nothing serves nothing."""

        def _request(self, name, reqtype, payload, timeout_s):
            return None

        def close(self):
            """Nothing to release."""

    register_transport("null-test", Null)
    try:
        t = open_transport("null-test", namespace="/n")
        assert t.subscriber("/x", SPEEDS).take() is None
        t.publisher("/x", SPEEDS).put(speeds(1.0))
    finally:
        del TRANSPORTS["null-test"]


def test_a_zenoh_configuration_file_is_the_base(tmp_path):
    port = free_port()
    conf = tmp_path / "zenoh.json5"
    conf.write_text(f'{{ listen: {{ endpoints: ["tcp/127.0.0.1:{port}"] }} }}')
    a = open_transport(config_file=str(conf))  # its listen endpoint stands
    b = open_transport(listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    try:
        sub = b.subscriber("/x", SPEEDS)
        pub = a.publisher("/x", SPEEDS, block=True)
        assert wait_for(lambda: (pub.put(speeds(1.0)), sub.take())[1]) is not None
    finally:
        a.close()
        b.close()
    bad = tmp_path / "bad.json5"
    bad.write_text("{ listen: ")
    with pytest.raises(InputError, match="Zenoh configuration"):
        open_transport(config_file=str(bad))


def test_attachment_writer_gives_zenohs_own_serialisation():
    """The template patched per sample is byte for byte what zenoh.ext serialises for the same values."""
    import struct

    from omnirotor.transport.zenoh_transport import AttachmentWriter, ros_attachment

    gid = bytes(range(16))
    write = AttachmentWriter(gid)
    for seq in (1, 2, 1000, 2**40 + 3):
        a = write(seq)
        stamp = struct.unpack_from("<q", a, 8)[0]  # after the int64 sequence number
        assert abs(stamp - time.time_ns()) < 10**9
        assert a == ros_attachment(seq, gid, stamp)


def test_publisher_payload_is_rosbags_serialisation_and_reuses_no_stale_bytes():
    """The kept buffer gives Typestore.serialize_cdr's bytes, also when the message's size changes."""
    store = typestore()
    port = free_port()
    with open_transport(listen=[f"tcp/127.0.0.1:{port}"]) as t:
        pub = t.publisher("/x", SPEEDS)
        for n in (8, 3, 3, 12):
            msg = speeds(float(n), n=n)
            assert pub.serialize(msg) == bytes(store.serialize_cdr(msg, SPEEDS))


def test_take_waits_for_a_payload_and_times_out(pair):
    a, b = pair
    sub = b.subscriber("/x", SPEEDS, depth=8)
    pub = a.publisher("/x", SPEEDS, block=True)
    connected(pub, sub)
    t0 = time.monotonic()
    assert sub.take(timeout_s=0.05) is None
    assert time.monotonic() - t0 >= 0.045
    pub.put(speeds(7.0))
    assert sub.take(timeout_s=5.0).t == 7.0


def test_liveliness_tokens_follow_rmw_zenoh_and_a_liveliness_subscriber_sees_them():
    """A node's tokens (rmw_zenoh's graph discovery) as a ROS 2 graph cache receives them, and their removal."""
    from omnirotor.transport import liveliness_key

    port = free_port()
    with open_transport(listen=[f"tcp/127.0.0.1:{port}"]) as watcher:
        seen: dict[str, str] = {}
        session = watcher._session  # noqa: SLF001  (a raw Zenoh session, as a ROS 2 graph cache has)

        def on_token(sample) -> None:
            seen[str(sample.key_expr)] = str(sample.kind)

        sub = session.liveliness().declare_subscriber("@ros2_lv/3/**", on_token)
        node = open_transport(listen=[], connect=[f"tcp/127.0.0.1:{port}"], domain_id=3, namespace="/r1",
                              node="omnirotor_fly")  # fmt: skip
        node.publisher("/omnirotor/rotor_cmd", "omnirotor_msgs/msg/RotorCommand", block=True)
        node.subscriber("/omnirotor/frame", "omnirotor_msgs/msg/SensorFrame", depth=32)
        assert wait_for(lambda: True if len(seen) >= 3 else None)
        zid = str(node._session.zid())  # noqa: SLF001
        keys = {k.split("/")[5]: k.split("/") for k in seen}
        assert keys["NN"] == ["@ros2_lv", "3", zid, "0", "0", "NN", "%", "%r1", "omnirotor_fly"]
        mp, ms = keys["MP"], keys["MS"]
        assert mp[:5] == ["@ros2_lv", "3", zid, "0", mp[4]] and mp[6:9] == ["%", "%r1", "omnirotor_fly"]
        assert mp[9:12] == ["%r1%omnirotor%rotor_cmd", "omnirotor_msgs::msg::dds_::RotorCommand_",
                            typestore().hash_rihs01("omnirotor_msgs/msg/RotorCommand")]  # fmt: skip
        assert mp[12] == "::,:,:,:,,"  # reliable (it blocks), keep last 10: rmw_zenoh's defaults, all empty
        assert ms[9] == "%r1%omnirotor%frame" and ms[12] == "2::,32:,:,:,,"  # best effort, depth 32
        assert len({mp[4], ms[4]}) == 2 and "0" not in (mp[4], ms[4])  # entity ids unique, not the node's
        assert "/".join(mp) == liveliness_key(3, zid, 0, int(mp[4]), "MP", "/r1", "omnirotor_fly",
                                              "/r1/omnirotor/rotor_cmd", "omnirotor_msgs/msg/RotorCommand",
                                              "::,:,:,:,,")  # fmt: skip
        assert all(kind == "SampleKind.PUT" for kind in seen.values())
        node.close()
        assert wait_for(lambda: True if all(k == "SampleKind.DELETE" for k in seen.values()) else None)
        sub.undeclare()


def test_a_session_without_a_node_name_declares_no_token_and_a_bad_name_is_refused():
    port = free_port()
    with open_transport(listen=[f"tcp/127.0.0.1:{port}"]) as watcher:
        seen = []
        sub = watcher._session.liveliness().declare_subscriber("@ros2_lv/**", lambda s: seen.append(s))  # noqa: SLF001
        with open_transport(listen=[], connect=[f"tcp/127.0.0.1:{port}"]) as client:
            client.publisher("/x", SPEEDS)
            time.sleep(0.5)
        assert seen == []
        sub.undeclare()
    with pytest.raises(InputError, match="node name"):
        open_transport(listen=[], node="bad name")


def test_a_timed_out_wait_is_not_a_bad_payload_and_a_second_subscriber_ignores_the_wake(pair):
    """A wait's time-out ends with the waker's marked empty sample (delivered to this session only): it is neither
    a message nor a bad payload, for the waiting subscriber or another one on the same key; the peer never sees it;
    a real empty payload is still counted bad."""
    a, b = pair
    sub = b.subscriber("/w", SPEEDS, depth=8)
    other = b.subscriber("/w", SPEEDS, depth=8)
    remote = a.subscriber("/w", SPEEDS, depth=8)
    pub = a.publisher("/w", SPEEDS, block=True)
    connected(pub, sub)
    for drained in (other, remote):  # what came before the test's own samples
        list(iter(drained.take, None))
    n_ok = sub.n_ok
    for _ in range(20):
        assert sub.take(timeout_s=0.003) is None
    assert sub.take_latest(timeout_s=0.003) is None
    assert sub.take_latest_keeping(0.003, lambda m: True) == (None, None)
    assert other.take() is None and remote.take(timeout_s=0.05) is None
    assert sub.n_bad == other.n_bad == remote.n_bad == 0 and sub.n_ok == n_ok
    pub.put_raw(b"")  # an empty payload from the wire: bad
    assert wait_for(lambda: sub.take() or (sub.n_bad or None)) == 1
    pub.put(speeds(3.0))
    assert sub.take(timeout_s=5.0).t == 3.0


def test_a_wait_ends_at_a_payload_before_its_time_out_and_a_stale_wake_is_skipped(pair):
    """A message that comes during a long wait ends it with that message; the waker's late wake of an earlier wait
    (the sample came first) is skipped by the next take, not returned or counted."""
    a, b = pair
    sub = b.subscriber("/v", SPEEDS, depth=8)
    pub = a.publisher("/v", SPEEDS, block=True)
    connected(pub, sub)
    timer = threading.Timer(0.05, lambda: pub.put(speeds(5.0)))
    timer.start()
    msg = sub.take(timeout_s=30.0)
    timer.join()
    assert msg is not None and msg.t == 5.0
    for k in range(50):  # waits that a payload ends just around their deadline, then instant takes
        pub.put(speeds(float(k)))
        got = sub.take(timeout_s=0.002)
        while got is None:
            got = sub.take(timeout_s=0.5)
        assert got.t == float(k)
    time.sleep(0.02)
    assert sub.take() is None and sub.n_bad == 0
