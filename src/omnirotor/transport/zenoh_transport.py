"""The Zenoh transport (eclipse-zenoh), with rmw_zenoh's key expressions and attachments.

Names follow ``rmw_zenoh`` (ROS 2 Humble, Jazzy, Kilted), so that a ROS 2 node using ``rmw_zenoh`` on the same
Zenoh network hears these topics with their types:

* a topic's key expression is ``<domain_id>/<fully qualified topic without its leading slash>/<type>/<hash>``,
  e.g. ``0/omnirotor/rotor_cmd/omnirotor_msgs::msg::dds_::RotorCommand_/RIHS01_afdd...``: the type mangled as
  ``pkg::msg::dds_::Name_`` and its RIHS01 type hash (rosbags computes it from the definitions);
* every sample carries rmw_zenoh's attachment, written with Zenoh's own serialiser (``zenoh.ext``, the format of
  zenoh-cpp's serializer that rmw_zenoh uses): the sequence number (int64), the source time stamp (int64, ns of
  the system clock) and the publisher's 16-byte id (a sequence: its length, then the bytes);
* every publisher and subscriber (and the node itself) declares rmw_zenoh's liveliness token
  (:func:`liveliness_key`), so the ROS 2 graph (``ros2 topic list``, ``ros2 node list``) sees them;
* a request/reply is a Zenoh queryable on the same kind of key (``ctl``'s ``FlightRequest``).

The session is a Zenoh peer with multicast scouting off: it listens on the given endpoints (loopback by default) and
connects to the given ones, and hears nothing else. Receiving: each subscriber is a Zenoh ring channel (the
newest ``depth`` samples are kept, older ones dropped, so a flood on a key costs its subscriber little more than the
ring), filled by Zenoh's own threads without Python; the caller takes from it at once, or sleeps in the channel's
``recv`` until a sample arrives: one wake-up of the caller per message, no Python callback and no queue hand-off in
between (measured against that hand-off: ``benchmarks/bench_zenoh_floor.py``, BENCHMARKS.md). The channel's ``recv``
has no time-out, so a wait with a time-out is ended by the session's *waker* thread (:class:`_Waker`): at the
deadline it puts an empty sample marked by its attachment on the key, delivered to this session only; a waiting
subscriber takes it as "time out", any other ignores it. The waker sleeps at least :data:`WAKE_TICK_S` between its
rounds, so a time-out ends up to about that late (a frame that comes ends the wait at once); callers that need a
precise time (the simulator's wall-clock step) sleep on the clock and take what arrived without waiting. Spinning
on ``try_recv`` instead was measured slower on a busy 2-core machine (it takes the CPU the peer needs).

Publishers are ``express`` (sent from the caller's thread: a starved send thread cannot hold them back) at
real-time priority, and by default drop rather than block when the network is congested, so the 1 kHz loop never
waits on a slow receiver (``block=True`` for what must all arrive: lockstep frames and commands, log rows).
"""

from __future__ import annotations

import contextlib
import hashlib
import ipaddress
import json
import math
import re
import struct
import sys
import threading
import time
from collections.abc import Callable, Sequence

from omnirotor.errors import InputError
from omnirotor.rosmsg import typestore
from omnirotor.transport.base import Transport, register_transport

__all__ = [
    "ZenohTransport",
    "key_expression",
    "dds_type_name",
    "ros_attachment",
    "AttachmentWriter",
    "liveliness_key",
    "qos_key",
    "WAKE_TICK_S",
]

_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream)/(.+)$")
_LOOPBACK_NAMES = ("localhost",)


def dds_type_name(msgtype: str) -> str:
    """``pkg/msg/Name`` as ROS 2's DDS-mangled type name ``pkg::msg::dds_::Name_`` (rmw_zenoh's key part)."""
    pkg, kind, name = msgtype.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def key_expression(domain_id: int, name: str, msgtype: str) -> str:
    """rmw_zenoh's key expression of the fully qualified topic ``name`` carrying ``msgtype`` (module docstring)."""
    return f"{domain_id}/{name.strip('/')}/{dds_type_name(msgtype)}/{typestore().hash_rihs01(msgtype)}"


def ros_attachment(seq: int, gid: bytes, stamp_ns: int | None = None) -> bytes:
    """rmw_zenoh's attachment of a sample: sequence number, source time stamp [ns] and the 16-byte publisher id.

    Args:
        seq: the publisher's sample number.
        gid: the publisher's 16-byte id.
        stamp_ns: the source time stamp [ns, system clock]; None: now.
    """
    from zenoh.ext import Int64, z_serialize

    stamp = Int64(time.time_ns() if stamp_ns is None else stamp_ns)
    return z_serialize((Int64(seq), stamp, gid)).to_bytes()


class AttachmentWriter:
    """rmw_zenoh's attachment of one publisher (:func:`ros_attachment`), written into a template per sample.

    The template is Zenoh's own serialisation of the attachment; the two int64 fields sit at fixed offsets in it
    (found once by serialising marker values and comparing with other values), so a sample costs two
    ``pack_into`` instead of a serialisation. :meth:`__call__` gives the bytes :func:`ros_attachment` gives
    (tested).
    """

    _PACK = struct.Struct("<q")

    def __init__(self, gid: bytes) -> None:
        seq, stamp = 0x0102030405060708, 0x1112131415161718
        a = ros_attachment(seq, gid, stamp)
        b = ros_attachment(seq ^ -1, gid, stamp ^ -1)
        self._seq_at = a.find(self._PACK.pack(seq))
        self._stamp_at = a.find(self._PACK.pack(stamp))
        at = sorted((self._seq_at, self._stamp_at))
        diff = [i for i in range(len(a)) if i < len(b) and a[i] != b[i]]
        if len(a) != len(b) or at[0] < 0 or diff != [*range(at[0], at[0] + 8), *range(at[1], at[1] + 8)]:
            raise RuntimeError("zenoh.ext's serialisation of rmw_zenoh's attachment is not the expected layout")
        self._buf = bytearray(a)

    def __call__(self, seq: int) -> bytes:
        """The attachment of the sample number ``seq``, stamped now."""
        self._PACK.pack_into(self._buf, self._seq_at, seq)
        self._PACK.pack_into(self._buf, self._stamp_at, time.time_ns())
        return bytes(self._buf)


def qos_key(best_effort: bool = False, depth: int = 10) -> str:
    """rmw_zenoh's QoS part of a liveliness token (only the reliability and the depth ever differ here).

    ``<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:<liveliness>,<s>,<ns>``;
    an empty entry is rmw_zenoh's default (reliable, volatile, keep last 10, none, none, automatic).
    """
    rel = "2" if best_effort else ""  # RMW_QOS_POLICY_RELIABILITY_BEST_EFFORT
    return f"{rel}::,{'' if depth == 10 else depth}:,:,:,,"


def liveliness_key(
    domain_id: int, zid: str, nid: int, eid: int, kind: str, namespace: str, node: str,
    topic: str | None = None, msgtype: str | None = None, qos: str = "",
) -> str:  # fmt: skip
    """rmw_zenoh's liveliness token of a node (``kind`` ``NN``) or of its publisher (``MP``) or subscriber (``MS``).

    ``@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node>`` and, for a topic's
    entity, ``/<topic>/<DDS type name>/<RIHS01 hash>/<QoS>``; each name with its slashes replaced by ``%``
    (the empty namespace and the enclave, ``/``, are ``%``); ``topic`` is the fully qualified topic name.
    """

    def mangle(name: str) -> str:
        return (name or "/").replace("/", "%")

    parts = ["@ros2_lv", str(domain_id), zid, str(nid), str(eid), kind, "%", mangle(namespace), mangle(node)]
    if kind != "NN":
        if topic is None or msgtype is None:
            raise ValueError(f"a {kind} token needs its topic and type")
        parts += [mangle(topic), dds_type_name(msgtype), typestore().hash_rihs01(msgtype), qos]
    return "/".join(parts)


def _check_endpoints(what: str, endpoints: Sequence[str]) -> list[str]:
    """Endpoints as a list; a listening one that is not on loopback is said on stderr (it is network-exposed).

    Raises:
        InputError: an endpoint that is not ``proto/address``.
    """
    out = []
    for e in endpoints:
        m = _ENDPOINT.match(str(e))
        if m is None:
            raise InputError(f"{what} endpoint {e!r} is not a Zenoh locator such as tcp/127.0.0.1:7447")
        out.append(str(e))
        if what == "listen" and m.group(1) != "unixsock-stream" and not _is_loopback(m.group(2)):
            print(
                f"omnirotor: listening on {e}, outside loopback: anyone on that network can publish and subscribe "
                "unless Zenoh login and access control are configured (docs/transport.md, examples/zenoh-auth/)",
                file=sys.stderr,
            )
    return out


def _is_loopback(address: str) -> bool:
    host = address.rsplit(":", 1)[0].strip("[]")
    if host in _LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


WAKE_TICK_S = 0.002
"""The waker's shortest sleep [s]: a receive's time-out ends up to about this late (module docstring)."""
_WAKE_IDLE_S = 0.05
_WAKE = b"omnirotor/wake"
"""The attachment that marks the waker's empty sample (never on the wire: it is delivered to its session only)."""


def _is_wake(sample) -> bool:
    attachment = sample.attachment
    return attachment is not None and attachment.to_bytes() == _WAKE


class _WakeSlot:
    """One subscriber's pending time-out: its key and deadline (monotonic [s]; inf when it does not wait)."""

    __slots__ = ("key", "deadline")

    def __init__(self, key: str) -> None:
        self.key = key
        self.deadline = math.inf


class _Waker:
    """Ends the blocking receives of a session at their time-outs (module docstring); one thread, from the first slot.

    A waiting subscriber arms its slot with its deadline (:meth:`arm`: no wake-up of this thread unless the deadline
    comes more than :data:`WAKE_TICK_S` before the thread's planned round); each round puts the marked empty sample
    on the key of every slot whose deadline passed, then sleeps until the earliest armed deadline, at least
    :data:`WAKE_TICK_S` and at most 50 ms. While frames flow the subscriber re-arms a later deadline every period
    and this thread wakes about every :data:`WAKE_TICK_S`, off the frame's path.
    """

    def __init__(self, session, local) -> None:
        self._session = session
        self._local = local
        self._slots: list[_WakeSlot] = []
        self._cond = threading.Condition()
        self._planned = math.inf  # the next round [monotonic s]; inf while a round runs (an arm then notifies)
        self._thread: threading.Thread | None = None
        self._closed = False

    def slot(self, key: str) -> _WakeSlot:
        """A new slot for a subscriber on ``key``; the thread starts with the first (from the declaring thread).

        Started at the declaration, not at the first wait: a real-time loop's first wait would start it at the
        loop's priority, above the transport's (:func:`omnirotor.realtime.set_transport_priority`).
        """
        s = _WakeSlot(key)
        self._slots.append(s)
        with self._cond:
            if self._thread is None and not self._closed:
                self._thread = threading.Thread(target=self._run, name="omnirotor-zenoh-waker", daemon=True)
                self._thread.start()
        return s

    def arm(self, slot: _WakeSlot, deadline: float) -> None:
        """``slot`` waits until ``deadline`` at the latest (ended up to :data:`WAKE_TICK_S` after it)."""
        slot.deadline = deadline
        if deadline + WAKE_TICK_S < self._planned:  # else the planned round is soon enough
            with self._cond:
                self._cond.notify()

    def _run(self) -> None:
        mono, put, marked, local = time.monotonic, self._session.put, _WAKE, self._local
        with self._cond:
            while not self._closed:
                self._planned = math.inf
                now = mono()
                planned = now + _WAKE_IDLE_S
                for s in self._slots:
                    d = s.deadline
                    if d <= now:
                        s.deadline = math.inf
                        with contextlib.suppress(Exception):  # a closing session: the wait ends with it
                            put(s.key, b"", attachment=marked, allowed_destination=local)
                    elif d < planned:
                        planned = d
                self._planned = planned = max(planned, now + WAKE_TICK_S)
                self._cond.wait(planned - now)

    def close(self) -> None:
        """Stop the thread (idempotent)."""
        with self._cond:
            self._closed = True
            self._cond.notify()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)


class ZenohTransport(Transport):
    """A Zenoh peer session (module docstring).

    Args:
        domain_id: ROS 2 domain id (the first part of every key).
        namespace: ROS 2 namespace of every topic.
        listen: endpoints to listen on; ``()`` for none (a pure client).
        connect: endpoints to connect to.
        attachment: attach rmw_zenoh's sequence number, time stamp and publisher id to every sample
            (about 7 µs per sample); False for bare payloads.
        config: further Zenoh configuration as ``{json5 path: value}`` (e.g. access control, TLS).
        config_file: a Zenoh configuration file (JSON5) to start from; its endpoints stand unless ``listen`` or
            ``connect`` are given.
        express: publish each sample at once from the caller's thread (Zenoh's ``express``, the default) instead
            of handing it to Zenoh's send thread. Measured in the flight node's loop (lockstep hover, loaded 2-core
            machine): serialising and publishing a command took about 250 µs express and 57 µs not; but not
            express, on a machine at load 5-7, real-time runs lost 50 ms of frames right at their start (a
            starved send thread and a dropping publisher: link lost), which express did not; so express.
        node: the ROS 2 node name this session is (``omnirotor_fly``): it and every publisher and subscriber
            then declare rmw_zenoh's liveliness tokens (:func:`liveliness_key`); None: no tokens (clients).
    """

    def __init__(
        self,
        *,
        domain_id: int = 0,
        namespace: str = "",
        listen: Sequence[str] = ("tcp/127.0.0.1:7447",),
        connect: Sequence[str] = (),
        attachment: bool = True,
        config: dict | None = None,
        config_file: str | None = None,
        node: str | None = None,
        express: bool = True,
    ) -> None:
        super().__init__(domain_id=domain_id, namespace=namespace)
        import zenoh

        self._z = zenoh
        if config_file is not None:  # access control, TLS, credentials: docs/transport.md
            try:
                conf = zenoh.Config.from_file(str(config_file))
            except Exception as exc:  # noqa: BLE001  (zenoh's own error for a file it cannot read or parse)
                raise InputError(f"Zenoh configuration {config_file}: {str(exc).splitlines()[0]}") from None
        else:
            conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        if listen or config_file is None:
            conf.insert_json5("listen/endpoints", json.dumps(_check_endpoints("listen", listen)))
        if connect or config_file is None:
            conf.insert_json5("connect/endpoints", json.dumps(_check_endpoints("connect", connect)))
        conf.insert_json5("scouting/multicast/enabled", "false")
        for path, value in (config or {}).items():
            conf.insert_json5(path, json.dumps(value))
        try:
            self._session = zenoh.open(conf)
        except Exception as exc:  # noqa: BLE001  (zenoh raises its own ZError for a port in use, etc.)
            raise InputError(f"cannot open the Zenoh session: {str(exc).splitlines()[0]}") from None
        self._attachment = attachment
        self._express = bool(express)
        self._waker = _Waker(self._session, zenoh.Locality.SESSION_LOCAL)
        self._zid = str(self._session.zid()).encode()
        self._entities: list = []
        self._closed = False
        self._node = node
        self._next_id = 0
        if node is not None:
            if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", node):
                self._session.close()
                raise InputError(f"node name {node!r} is not a ROS 2 node name (letters, digits, _)")
            self._token("NN")

    def _gid(self, key: str) -> bytes:
        return hashlib.blake2b(self._zid + key.encode(), digest_size=16).digest()

    def _publisher(self, name: str, msgtype: str, block: bool) -> tuple[Callable[[bytes, int], None], str]:
        z = self._z
        key = key_expression(self.domain_id, name, msgtype)
        congestion = z.CongestionControl.BLOCK if block else z.CongestionControl.DROP
        pub = self._session.declare_publisher(
            key, congestion_control=congestion, priority=z.Priority.REAL_TIME, express=self._express
        )
        self._entities.append(pub)
        self._token("MP", name, msgtype, qos_key(best_effort=not block))
        put = pub.put
        if not self._attachment:
            return (lambda payload, seq: put(payload)), key
        attachment = AttachmentWriter(self._gid(key))
        return (lambda payload, seq: put(payload, attachment=attachment(seq))), key

    def _subscriber(
        self, name: str, msgtype: str, depth: int
    ) -> tuple[Callable[[float], bytes | None], Callable[[], None], str]:
        key = key_expression(self.domain_id, name, msgtype)
        # Zenoh's threads fill a ring channel (the newest ``depth`` kept); the caller sleeps in its recv, woken by
        # a sample or, at a time-out, by the waker's marked empty sample (module docstring)
        sub = self._session.declare_subscriber(key, self._z.handlers.RingChannel(depth))
        self._entities.append(sub)
        self._token("MS", name, msgtype, qos_key(best_effort=True, depth=depth))
        rx = sub.handler
        try_recv, recv, mono = rx.try_recv, rx.recv, time.monotonic
        slot = self._waker.slot(key)
        arm = self._waker.arm

        def poll(timeout_s: float) -> bytes | None:
            while (sample := try_recv()) is not None:
                payload = sample.payload.to_bytes()
                if payload or not _is_wake(sample):
                    return payload
            if not timeout_s > 0:
                return None
            deadline = mono() + timeout_s
            try:
                while True:
                    arm(slot, deadline)
                    sample = recv()
                    payload = sample.payload.to_bytes()
                    if payload or not _is_wake(sample):
                        return payload
                    if mono() >= deadline:
                        return None
            finally:
                slot.deadline = math.inf

        return poll, sub.undeclare, key

    def _token(self, kind: str, topic: str | None = None, msgtype: str | None = None, qos: str = "") -> None:
        """Declare rmw_zenoh's liveliness token of this node (``NN``) or of one of its entities."""
        if self._node is None:
            return
        eid = 0 if kind == "NN" else self._next_id + 1
        self._next_id = max(self._next_id, eid)
        key = liveliness_key(self.domain_id, self._zid.decode(), 0, eid, kind, self.namespace, self._node,
                             topic, msgtype, qos)  # fmt: skip
        self._entities.append(self._session.liveliness().declare_token(key))

    def _serve(self, name: str, reqtype: str, on_request: Callable[[bytes], bytes | None]) -> None:
        key = key_expression(self.domain_id, name, reqtype)

        def answer(query) -> None:
            payload = query.payload
            reply = on_request(b"" if payload is None else payload.to_bytes())
            if reply is not None:
                query.reply(query.key_expr, reply)

        self._entities.append(self._session.declare_queryable(key, answer))

    def _request(self, name: str, reqtype: str, payload: bytes, timeout_s: float) -> bytes | None:
        key = key_expression(self.domain_id, name, reqtype)
        deadline = time.monotonic() + max(0.0, timeout_s)
        # a peer just connected may not have declared its queryable to us yet: ask again until the deadline
        while True:
            left = deadline - time.monotonic()
            for reply in self._session.get(key, payload=payload, timeout=max(left, 0.001)):
                if reply.ok is not None:
                    return reply.ok.payload.to_bytes()
            if deadline - time.monotonic() <= 0.05:
                return None
            time.sleep(0.05)

    def close(self) -> None:
        """Undeclare everything and close the session (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._waker.close()
        for entity in reversed(self._entities):
            try:
                entity.undeclare()
            except Exception:  # noqa: BLE001,S110  (already gone with a closing session)
                pass
        self._entities.clear()
        self._session.close()


register_transport("zenoh", ZenohTransport)
