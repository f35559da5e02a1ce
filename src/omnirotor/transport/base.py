"""The flight transport's small interface and its registry (issue 24, item 1).

A transport moves ROS 2 messages, serialised as CDR by rosbags (:func:`omnirotor.rosmsg.typestore`), between
the flight node, the simulator and clients. A concrete transport (Zenoh: :mod:`.zenoh_transport`) moves bytes
only; serialisation, decoding errors, sequence numbers and counting live here, once::

    t = open_transport("zenoh", domain_id=0, namespace="", listen=["tcp/127.0.0.1:7447"])
    pub = t.publisher("/omnirotor/rotor_cmd", "omnirotor_msgs/msg/RotorCommand")
    pub.put(msg)
    sub = t.subscriber("/omnirotor/imu", "omnirotor_msgs/msg/SensorFrame", depth=8)
    msg = sub.take()          # non-blocking; None when nothing (valid) arrived
    t.close()

Receiving: the concrete transport queues raw payloads (at most ``depth``, the oldest dropped first) in its own
threads, and :meth:`Subscriber.take` decodes them on the caller's thread, at once or after waiting (asleep, not
polling) up to a time-out for the first one. A payload that does
not decode, or that the subscriber's ``check`` refuses, is counted (:attr:`Subscriber.n_bad`) and dropped,
never raised. Another transport (DDS, say) is one module with a :class:`Transport` subclass and one
:func:`register_transport` line.
"""

from __future__ import annotations

import abc
import dataclasses
import re
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

from omnirotor.errors import InputError
from omnirotor.rosmsg import typestore

__all__ = [
    "Transport",
    "ServeCounts",
    "Publisher",
    "Subscriber",
    "register_transport",
    "open_transport",
    "TRANSPORTS",
    "DEFAULT_TRANSPORT",
    "ros_topic",
    "MAX_DOMAIN_ID",
]

MAX_DOMAIN_ID = 232
"""The largest ROS 2 domain id (ROS 2's own limit)."""

_TOPIC = re.compile(r"^(/[A-Za-z_][A-Za-z0-9_]*)+$")
_NAMESPACE = re.compile(r"^(/[A-Za-z_][A-Za-z0-9_]*)*$")


def ros_topic(namespace: str, topic: str) -> str:
    """The fully qualified ROS 2 name of ``topic`` in ``namespace`` (both absolute, ``/a/b``; namespace may be "").

    Raises:
        InputError: a name ROS 2 would refuse (empty tokens, tokens starting with a digit, other characters).
    """
    ns = namespace.rstrip("/") if namespace not in ("", "/") else ""
    if ns and not ns.startswith("/"):
        ns = "/" + ns
    if not _NAMESPACE.match(ns):
        raise InputError(f"namespace {namespace!r} is not a ROS 2 namespace (/word/word, letters, digits, _)")
    name = topic if topic.startswith("/") else "/" + topic
    if not _TOPIC.match(name):
        raise InputError(f"topic {topic!r} is not a ROS 2 topic name (/word/word, letters, digits, _)")
    return ns + name


class Publisher:
    """Publishes messages of one type on one topic; :meth:`put` serialises with rosbags' CDR.

    The type's serialiser (rosbags' generated function, :meth:`Typestore.get_msgdef`) is looked up once, and the
    payload is written into a buffer kept between calls (reallocated only when the message's size changes):
    the same bytes as ``Typestore.serialize_cdr``, without its per-call lookup and allocation.
    """

    def __init__(self, send: Callable[[bytes, int], None], msgtype: str, key: str) -> None:
        store = typestore()
        msgdef = store.get_msgdef(msgtype)
        self._send = send
        self._store = store
        self._static_size = 4 + msgdef.size_cdr if msgdef.size_cdr else 0
        self._getsize = msgdef.getsize_cdr
        little = sys.byteorder == "little"
        self._serialize = msgdef.serialize_cdr_le if little else msgdef.serialize_cdr_be
        self._head = b"\x00\x01" if little else b"\x00\x00"  # CDR encapsulation: plain CDR, the byte order
        self._buf = bytearray()
        self._body = memoryview(self._buf)
        self.msgtype = msgtype
        self.key = key
        self.n_sent = 0

    def serialize(self, msg: Any) -> bytes:
        """The CDR payload of ``msg`` (an instance of the store's class for :attr:`msgtype`)."""
        size = self._static_size or 4 + self._getsize(0, msg, self._store)
        if len(self._buf) != size:
            self._body.release()
            self._buf = bytearray(size)
            self._buf[:2] = self._head
            self._body = memoryview(self._buf)[4:]
        end = self._serialize(self._body, 0, msg, self._store)
        if end + 4 != size:
            raise ValueError(f"{self.msgtype}: serialised {end + 4} bytes, sized {size}")
        return bytes(self._buf)

    def put(self, msg: Any) -> None:
        """Serialise ``msg`` and send it."""
        self.put_raw(self.serialize(msg))

    def put_raw(self, payload: bytes) -> None:
        """Send an already serialised payload (fuzz tests, relays, batches)."""
        self.n_sent += 1
        self._send(payload, self.n_sent)


class Subscriber:
    """Receives messages of one type on one topic; decoding errors are counted, never raised.

    :meth:`take` and :meth:`take_latest` return at once by default, or wait up to ``timeout_s`` for a payload
    (the waiting thread sleeps in the transport's channel, no polling; a time-out may end a few ms late: see the
    transport, e.g. :data:`omnirotor.transport.zenoh_transport.WAKE_TICK_S`).

    Attributes:
        n_ok: messages decoded and accepted.
        n_bad: payloads that did not decode or that ``check`` refused (dropped).
        n_skipped: payloads :meth:`take_latest` dropped undecoded because a newer one was taken.
    """

    def __init__(
        self,
        poll: Callable[[float], bytes | None],
        msgtype: str,
        key: str,
        check: Callable[[Any], bool] | None = None,
        close: Callable[[], None] | None = None,
        decoder: Callable[[bytes], Any | None] | None = None,
    ) -> None:
        store = typestore()
        self._fast = decoder
        msgdef = store.get_msgdef(msgtype)
        self._poll = poll
        self._store = store
        self._cls = msgdef.cls
        self._deserialize = (msgdef.deserialize_cdr_be, msgdef.deserialize_cdr_le)
        self._check = check
        self._close = close
        self.msgtype = msgtype
        self.key = key
        self.n_ok = 0
        self.n_bad = 0
        self.n_skipped = 0
        self.last_take_s = -1.0
        """Monotonic time [s] of the last accepted message (``time.monotonic``), -1 before the first."""

    def _decode(self, payload: bytes) -> Any | None:
        # rosbags' generated deserialiser of the type, with Typestore.deserialize_cdr's checks: the CDR
        # encapsulation (plain CDR, either byte order) and no bytes left over beyond the final alignment
        msg = self._fast(payload) if self._fast is not None else None
        if msg is not None:
            if self._check is not None and not self._check(msg):
                msg = None
        elif len(payload) >= 4 and payload[0] == 0 and payload[1] <= 1:
            try:
                msg, end = self._deserialize[payload[1]](memoryview(payload)[4:], 0, self._cls, self._store)
                if end + 4 + 3 < len(payload) or (self._check is not None and not self._check(msg)):
                    msg = None
            except Exception:  # noqa: BLE001  (any malformed payload: counted and dropped, never raised)
                msg = None
        if msg is None:
            self.n_bad += 1
            return None
        self.n_ok += 1
        self.last_take_s = time.monotonic()
        return msg

    def take(self, timeout_s: float = 0.0) -> Any | None:
        """The oldest queued message that decodes, or None; bad payloads on the way are dropped.

        Args:
            timeout_s: wait up to this long [s] for a first payload (0: do not wait).
        """
        payload = self._poll(timeout_s)
        while payload is not None:
            msg = self._decode(payload)
            if msg is not None:
                return msg
            payload = self._poll(0.0)
        return None

    def take_latest(self, timeout_s: float = 0.0) -> Any | None:
        """The newest queued message that decodes, or None; older queued payloads are dropped (counted skipped).

        Args:
            timeout_s: wait up to this long [s] for a first payload (0: do not wait).
        """
        payload = self._poll(timeout_s)
        if payload is None:
            return None
        queued = [payload]
        while (payload := self._poll(0.0)) is not None:
            queued.append(payload)
        while queued:
            msg = self._decode(queued.pop())
            if msg is not None:
                self.n_skipped += len(queued)
                return msg
        return None

    def take_latest_keeping(self, timeout_s: float, keep: Callable[[Any], bool]) -> tuple[Any | None, Any | None]:
        """:meth:`take_latest`, and the newest of the older queued messages for which ``keep`` is true.

        The older payloads are decoded (newest first) only until one is kept, and only when some were queued:
        a loop that fell behind takes the newest message without losing a rarer content carried by one it
        skips (the flight node: the newest frame, and the newest motion-capture sample among the frames skipped).

        Returns:
            ``(newest, kept)``: either may be None.
        """
        payload = self._poll(timeout_s)
        if payload is None:
            return None, None
        queued = [payload]
        while (payload := self._poll(0.0)) is not None:
            queued.append(payload)
        msg = None
        while queued and msg is None:
            msg = self._decode(queued.pop())
        if msg is None:
            return None, None
        self.n_skipped += len(queued)
        kept = None
        if not keep(msg):
            while queued and kept is None:
                older = self._decode(queued.pop())
                if older is not None and keep(older):
                    kept = older
        return msg, kept

    def close(self) -> None:
        """Stop receiving."""
        if self._close is not None:
            self._close()
            self._close = None


@dataclasses.dataclass
class ServeCounts:
    """What a :meth:`Transport.serve` did with its requests (updated from the transport's thread).

    Attributes:
        answered: requests handled and answered.
        busy: requests answered at once by its ``busy`` callable, never decoded nor handled.
        bad: requests that did not decode, or whose handler raised (no reply).
    """

    answered: int = 0
    busy: int = 0
    bad: int = 0


class Transport(abc.ABC):
    """A session on a message transport: publishers, subscribers, request/reply; ROS 2 names and types.

    Subclasses implement the byte-moving ``_publisher``, ``_subscriber``, ``_serve``, ``_request`` and
    ``close``; this class checks names and types and does the (de)serialisation.
    """

    def __init__(self, *, domain_id: int = 0, namespace: str = "") -> None:
        if isinstance(domain_id, bool) or not isinstance(domain_id, int) or not 0 <= domain_id <= MAX_DOMAIN_ID:
            raise InputError(f"domain id must be an integer in [0, {MAX_DOMAIN_ID}], got {domain_id!r}")
        ros_topic(namespace, "/x")  # validates the namespace
        self.domain_id = domain_id
        self.namespace = namespace

    # -- the public interface ---------------------------------------------------------------------------
    def publisher(self, topic: str, msgtype: str, block: bool = False) -> Publisher:
        """A publisher of ``msgtype`` (``pkg/msg/Name``) on ``topic`` (in this transport's namespace).

        Args:
            topic: ROS 2 topic name.
            msgtype: message type.
            block: when the link is congested, wait rather than drop the message (for data that must all
                arrive: lockstep frames and commands, log rows); default drop (a stale sample is worthless).
        """
        name = ros_topic(self.namespace, topic)
        _known(msgtype)
        send, key = self._publisher(name, msgtype, block)
        return Publisher(send, msgtype, key)

    def subscriber(
        self,
        topic: str,
        msgtype: str,
        depth: int = 8,
        check: Callable[[Any], bool] | None = None,
        decoder: Callable[[bytes], Any | None] | None = None,
    ) -> Subscriber:
        """A polling subscriber keeping at most ``depth`` undelivered payloads (older ones are dropped).

        Args:
            topic: ROS 2 topic name.
            msgtype: message type (``pkg/msg/Name``).
            depth: queue length [messages], >= 1.
            check: optional semantic check of a decoded message; False counts it bad and drops it.
            decoder: optional fast path, ``decoder(payload) -> message | None``: a message object with the fields
                the caller reads, or None to leave the payload to rosbags' deserialiser (which decides whether it
                is malformed); it must never accept a payload rosbags refuses (the frame's:
                :class:`omnirotor.rosmsg.convert.FrameWire`).
        """
        name = ros_topic(self.namespace, topic)
        _known(msgtype)
        if not isinstance(depth, int) or depth < 1:
            raise InputError(f"subscriber depth must be an integer >= 1, got {depth!r}")
        poll, close, key = self._subscriber(name, msgtype, depth)
        return Subscriber(poll, msgtype, key, check=check, close=close, decoder=decoder)

    def serve(
        self,
        topic: str,
        reqtype: str,
        reptype: str,
        handler: Callable[[Any], Any],
        busy: Callable[[bytes], Any] | None = None,
    ) -> ServeCounts:
        """Answer requests of ``reqtype`` on ``topic`` with ``handler(request) -> reply`` (a ``reptype``).

        A request that does not decode, or a handler that raises, gets no reply (the client times out) and is
        counted (``bad`` of the returned counts); the handler runs on the transport's thread, so it must only hand
        the request over (e.g. to a queue or a lock-protected director) and return quickly. ``busy(payload)``, if
        given, is asked first, before anything is decoded: a reply (a ``reptype``) it returns is the answer at
        once, without the handler (counted in ``busy``; the same object again is not serialised again), None goes
        on to decode and handle.
        """
        name = ros_topic(self.namespace, topic)
        _known(reqtype)
        _known(reptype)
        store = typestore()
        counts = ServeCounts()
        cached: list = [(None, b"")]  # the last busy reply and its bytes, one tuple: threads swap it whole

        def on_request(payload: bytes) -> bytes | None:
            try:
                if busy is not None and (rep := busy(payload)) is not None:
                    counts.busy += 1
                    last = cached[0]
                    if last[0] is not rep:
                        last = cached[0] = (rep, bytes(store.serialize_cdr(rep, reptype)))
                    return last[1]
                req = store.deserialize_cdr(payload, reqtype)
                out = bytes(store.serialize_cdr(handler(req), reptype))
            except Exception:  # noqa: BLE001  (a bad request or a failing handler: no reply, never a crash)
                counts.bad += 1
                return None
            counts.answered += 1
            return out

        self._serve(name, reqtype, on_request)
        return counts

    def request(self, topic: str, reqtype: str, req: Any, reptype: str, timeout_s: float = 1.0) -> Any | None:
        """Send ``req`` and wait up to ``timeout_s`` for the reply; None on time-out or an undecodable reply."""
        name = ros_topic(self.namespace, topic)
        _known(reqtype)
        _known(reptype)
        store = typestore()
        raw = self._request(name, reqtype, bytes(store.serialize_cdr(req, reqtype)), timeout_s)
        if raw is None:
            return None
        try:
            return store.deserialize_cdr(raw, reptype)
        except Exception:  # noqa: BLE001
            return None

    @abc.abstractmethod
    def close(self) -> None:
        """End the session (idempotent)."""

    def __enter__(self) -> Transport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- what a concrete transport implements -------------------------------------------------------------
    @abc.abstractmethod
    def _publisher(self, name: str, msgtype: str, block: bool) -> tuple[Callable[[bytes, int], None], str]:
        """``(send(payload, seq), key)`` for the fully qualified topic ``name`` (``block``: see :meth:`publisher`)."""

    @abc.abstractmethod
    def _subscriber(
        self, name: str, msgtype: str, depth: int
    ) -> tuple[Callable[[float], bytes | None], Callable[[], None], str]:
        """``(poll(timeout_s) -> payload | None, close(), key)``.

        ``poll`` gives the oldest queued payload, waiting up to ``timeout_s`` for one (0: not at all); at most
        ``depth`` are kept, the oldest dropped first.
        """

    @abc.abstractmethod
    def _serve(self, name: str, reqtype: str, on_request: Callable[[bytes], bytes | None]) -> None:
        """Answer raw requests on ``name``."""

    @abc.abstractmethod
    def _request(self, name: str, reqtype: str, payload: bytes, timeout_s: float) -> bytes | None:
        """One raw request/reply."""


def _known(msgtype: str) -> None:
    if msgtype not in typestore().types:
        raise InputError(f"unknown message type {msgtype!r} (not a ROS 2 Jazzy or shipped type)")


TRANSPORTS: dict[str, Callable[..., Transport]] = {}
"""Registered transports by name (:func:`register_transport`)."""
DEFAULT_TRANSPORT = "zenoh"


def register_transport(name: str, factory: Callable[..., Transport]) -> None:
    """Register ``factory(**options) -> Transport`` under ``name`` (``open_transport(name, ...)``)."""
    if name in TRANSPORTS and TRANSPORTS[name] is not factory:
        raise ValueError(f"transport {name!r} registered twice")
    TRANSPORTS[name] = factory


def open_transport(
    name: str = DEFAULT_TRANSPORT,
    *,
    domain_id: int = 0,
    namespace: str = "",
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    **options: Any,
) -> Transport:
    """Open a session on the transport registered as ``name``.

    Args:
        name: registered transport ("zenoh").
        domain_id: ROS 2 domain id (0..232): sessions of different domains do not hear each other.
        namespace: ROS 2 namespace prefixed to every topic ("" or ``/robot1``).
        listen: endpoints to listen on (Zenoh locators, e.g. ``tcp/127.0.0.1:7447``); loopback by default.
        connect: endpoints of peers to connect to.
        options: transport-specific options.

    Raises:
        InputError: unknown transport, bad names or endpoints, or a session that cannot be opened.
    """
    if name not in TRANSPORTS:
        import omnirotor.transport  # noqa: F401  (registers the shipped transports)
    if name not in TRANSPORTS:
        raise InputError(f"unknown transport {name!r}; transports: {', '.join(sorted(TRANSPORTS))}")
    return TRANSPORTS[name](domain_id=domain_id, namespace=namespace, listen=listen, connect=connect, **options)
