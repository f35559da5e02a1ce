"""A ULog checked message by message before pyulog parses it (issue 26, "Every PX4 file fails cleanly").

pyulog is a tolerant reader: it allocates what a file declares, flattens any array a format names, skips what
it does not understand and says so on stdout, and stops silently where the file stops making sense. A
corrupt or hostile file then hangs it (an attitude array declared with 2³¹ elements; 2 GiB of zeros), makes it
raise deep inside (a start time of 2⁶⁴−1 µs), or reads garbage that looks like a result (a ``char[16]``
attitude). :func:`check_ulog` walks the file first, with the rules of PX4's "ULog File Format" (version 1:
16-byte header, definitions section, data section; every message ``uint16 msg_size, uint8 msg_type``,
little-endian), and refuses, in one :class:`~omnirotor.errors.InputError`, every file pyulog would not read
cleanly:

* the file larger than :data:`~omnirotor.limits.MAX_ULOG_BYTES`, its header or a message cut short
  (a message cut at the very end of the data section, as when the logger lost power, is read up to it and
  said in the returned notes), a message type that is not an ASCII letter, an incompatible flag pyulog does
  not know, appended-data offsets outside the file;
* a format that does not parse, names an unknown type, declares an array beyond 65 535 elements, nests
  deeper than :data:`MAX_NESTING` or into itself, or is larger than a message can hold (65 535 bytes), so
  nothing is ever allocated beyond what the file's own size allows;
* a subscription to an unknown format, or a format without a ``uint64_t timestamp`` (pyulog reads one at its
  offset in every data message);
* a data message of an unsubscribed id or of a size other than its format's (pyulog drops those as
  corrupt);
* a time stamp (header or data) beyond :data:`~omnirotor.limits.MAX_ULOG_TIME_US`;
* a topic omnirotor reads (:data:`READ_FIELDS`) whose field has the wrong type or shape (an attitude ``q``
  of ``char[16]``, time stamps as doubles) or is missing when the topic is present.

The walk reads only headers and time stamps (one ``struct.unpack_from`` per message), so its time is a small
part of pyulog's parse of the same file and its memory is one memory map of the file.
"""

from __future__ import annotations

import dataclasses
import mmap
import os
import re
import stat
import struct
from pathlib import Path

from omnirotor.errors import InputError
from omnirotor.limits import MAX_ULOG_BYTES, MAX_ULOG_TIME_US

__all__ = ["check_ulog", "UlogCheck", "READ_FIELDS", "MAX_NESTING", "MAX_MESSAGE_BYTES"]

MAGIC = b"ULog\x01\x12\x35"
HEADER_BYTES = 16
MAX_MESSAGE_BYTES = 0xFFFF
"""Largest payload of one message: ``msg_size`` is a uint16."""
MAX_NESTING = 8
"""Deepest nesting of formats (PX4's messages nest 2 deep)."""
MAX_ARRAY = 0xFFFF
"""Largest array length a format may declare (an array in a data message fits in 65 535 bytes)."""

_SIZES = {
    "int8_t": 1,
    "uint8_t": 1,
    "int16_t": 2,
    "uint16_t": 2,
    "int32_t": 4,
    "uint32_t": 4,
    "int64_t": 8,
    "uint64_t": 8,
    "float": 4,
    "double": 8,
    "bool": 1,
    "char": 1,
}
_FLOATS = ("float", "double")
_NUMBERS = (*_FLOATS, "int8_t", "uint8_t", "int16_t", "uint16_t", "int32_t", "uint32_t", "int64_t", "uint64_t")
_FIELD = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)(?:\[([0-9]{1,10})\])? ([A-Za-z_][A-Za-z0-9_]*)$")

READ_FIELDS: dict[str, dict[str, tuple[tuple[str, ...], int | None, bool]]] = {
    "vehicle_attitude": {"q": (_FLOATS, 4, True)},
    "esc_status": {"esc": (("esc_report",), None, False)},
    "esc_report": {"esc_rpm": (_NUMBERS, 0, False)},
    "actuator_motors": {"control": (_FLOATS, None, True)},
    "actuator_outputs": {"output": (_FLOATS, None, True)},  # PWM [µs] (px4/flight.py's fallback)
    "vehicle_local_position": {
        **{k: (_NUMBERS, 0, True) for k in ("x", "y", "z", "vx", "vy", "vz")},
        **{k: (_NUMBERS, 0, False) for k in ("ax", "ay", "az")},
    },
    "sensor_combined": {"gyro_rad": (_FLOATS, 3, False)},
    "vehicle_angular_velocity": {"xyz": (_FLOATS, 3, True)},
    "vehicle_land_detected": {"landed": (("bool", "uint8_t"), 0, False)},
}
"""The fields omnirotor reads (:mod:`omnirotor.px4.flight`), per format: (allowed types, array length (0: a
scalar, None: any array), required when the format is present)."""


@dataclasses.dataclass(frozen=True)
class UlogCheck:
    """What the walk found.

    Attributes:
        n_messages: messages walked.
        end: offset of the end of the last whole message (the file's size unless cut short at the end).
        notes: what a reader should say on stderr (a message cut at the end).
    """

    n_messages: int
    end: int
    notes: tuple[str, ...]


@dataclasses.dataclass
class _Format:
    name: str
    fields: list[tuple[str, int, str]]  # (type, array length (0: scalar), field name)


class _Walk:
    def __init__(self, path: Path, buf, size: int) -> None:
        self.path, self.buf, self.size = path, buf, size
        self.formats: dict[str, _Format] = {}
        self.sizes: dict[str, int] = {}
        self.subs: dict[int, tuple[str, int, int]] = {}  # msg_id -> (format, data size, timestamp offset)
        self.n = 0
        self.notes: list[str] = []

    def fail(self, offset: int, what: str) -> InputError:
        return InputError(f"{self.path}: not a readable ULog: {what} (at byte {offset})")

    # -- formats ---------------------------------------------------------------------------------------------

    def parse_format(self, offset: int, payload: bytes) -> None:
        try:
            text = payload.decode("ascii")
        except UnicodeDecodeError:
            raise self.fail(offset, "a format definition that is not ASCII text") from None
        name, sep, body = text.partition(":")
        if not sep or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
            raise self.fail(offset, f"a format definition without a valid name ({text[:40]!r})")
        fields = []
        for part in body.split(";"):
            if not part:
                continue
            m = _FIELD.match(part)
            if m is None:
                raise self.fail(offset, f"format {name}: field {part[:40]!r} is not 'type name' or 'type[n] name'")
            count = int(m.group(2)) if m.group(2) is not None else 0
            if m.group(2) is not None and not 1 <= count <= MAX_ARRAY:
                raise self.fail(offset, f"format {name}: field {m.group(3)} declares {count} elements")
            fields.append((m.group(1), count, m.group(3)))
        if not fields:
            raise self.fail(offset, f"format {name} has no fields")
        self.formats[name] = _Format(name, fields)
        self.sizes.clear()  # a format redefined changes the sizes of those that nest it

    def size_of(self, name: str, offset: int, depth: int = 0) -> int:
        if name in self.sizes:
            return self.sizes[name]
        if depth > MAX_NESTING:
            raise self.fail(offset, f"format {name} nests deeper than {MAX_NESTING} levels (or into itself)")
        fmt = self.formats.get(name)
        if fmt is None:
            raise self.fail(offset, f"unknown format or type {name!r}")
        total = 0
        for type_name, count, _ in fmt.fields:
            one = _SIZES.get(type_name)
            if one is None:
                one = self.size_of(type_name, offset, depth + 1)
            total += one * max(count, 1)
            if total > MAX_MESSAGE_BYTES:
                raise self.fail(offset, f"format {name} is larger than a message can hold ({MAX_MESSAGE_BYTES} bytes)")
        self.sizes[name] = total
        return total

    def check_fields(self, name: str, offset: int) -> None:
        """The topic's fields omnirotor reads (READ_FIELDS), nested formats included."""
        rules = READ_FIELDS.get(name)
        fmt = self.formats[name]
        if rules is not None:
            have = {f: (t, c) for t, c, f in fmt.fields}
            for field, (types, count, required) in rules.items():
                if field not in have:
                    if required:
                        raise self.fail(offset, f"topic {name} has no field {field} ({_spell(types, count)})")
                    continue
                t, c = have[field]
                if t not in types or (count is not None and c != count) or (count is None and c == 0):
                    raise self.fail(
                        offset, f"topic {name}: field {field} is {_spell((t,), c)}, expected {_spell(types, count)}"
                    )
        for t, _, _ in fmt.fields:
            if t not in _SIZES and t in READ_FIELDS:
                self.check_fields(t, offset)

    def subscribe(self, offset: int, payload: bytes) -> None:
        if len(payload) < 4:
            raise self.fail(offset, "a subscription message too short")
        msg_id = struct.unpack_from("<H", payload, 1)[0]
        try:
            name = payload[3:].decode("ascii")
        except UnicodeDecodeError:
            raise self.fail(offset, "a subscription whose name is not ASCII") from None
        if name not in self.formats:
            raise self.fail(offset, f"a subscription to {name!r}, which has no format")
        size = self.size_of(name, offset)
        fields = self.formats[name].fields
        stamp_at, pos = None, 0
        for t, c, f in fields:
            if f == "timestamp":
                if t != "uint64_t" or c != 0:
                    raise self.fail(offset, f"topic {name}: timestamp is {_spell((t,), c)}, expected uint64_t")
                stamp_at = pos
            pos += (_SIZES.get(t) or self.size_of(t, offset)) * max(c, 1)
        if stamp_at is None:
            raise self.fail(offset, f"topic {name} has no uint64_t timestamp")
        for t, c, f in reversed(fields):  # pyulog drops trailing padding from a data message's size
            if not f.startswith("_padding"):
                break
            size -= (_SIZES.get(t) or self.size_of(t, offset)) * max(c, 1)
        self.check_fields(name, offset)
        self.subs[msg_id] = (name, size, stamp_at)

    # -- the walk --------------------------------------------------------------------------------------------

    def walk(self, start: int, stop: int, definitions: bool) -> tuple[int, bool]:
        """Walk messages from ``start`` to ``stop``; returns (offset reached, in the definitions still)."""
        buf, unpack = self.buf, struct.unpack_from
        pos = start
        while pos < stop:
            if pos + 3 > stop:
                return self.cut(pos, stop, definitions), definitions
            msg_size, kind = unpack("<HB", buf, pos)
            end = pos + 3 + msg_size
            if not (65 <= kind <= 90 or 97 <= kind <= 122):
                raise self.fail(pos, f"message type {kind} is not a letter (a corrupt file)")
            if end > stop:
                return self.cut(pos, stop, definitions), definitions
            self.n += 1
            if kind == 68:  # 'D'
                if definitions:
                    raise self.fail(pos, "a data message before any subscription")
                if msg_size < 2:
                    raise self.fail(pos, "a data message too short")
                sub = self.subs.get(unpack("<H", buf, pos + 3)[0])
                if sub is None:
                    raise self.fail(pos, f"a data message of unknown id {unpack('<H', buf, pos + 3)[0]}")
                if msg_size - 2 != sub[1]:
                    raise self.fail(pos, f"a {sub[0]} message of {msg_size - 2} bytes, its format has {sub[1]}")
                stamp = unpack("<Q", buf, pos + 5 + sub[2])[0]
                if stamp > MAX_ULOG_TIME_US:
                    raise self.fail(pos, f"a {sub[0]} time stamp of {stamp} µs, beyond {MAX_ULOG_TIME_US}")
            elif kind in (65, 76, 67) and definitions:  # 'A', 'L', 'C' begin the data section
                definitions = False
                continue
            elif kind == 70:  # 'F'
                if not definitions:
                    raise self.fail(pos, "a format definition in the data section")
                self.parse_format(pos, bytes(buf[pos + 3 : end]))
            elif kind == 65:  # 'A'
                self.subscribe(pos, bytes(buf[pos + 3 : end]))
            elif kind == 66:  # 'B'
                if pos != HEADER_BYTES:
                    raise self.fail(pos, "a flag-bits message that is not the first one")
            elif kind in (73, 77, 80, 81):  # 'I', 'M', 'P', 'Q': key-value messages
                self.key_value(pos, bytes(buf[pos + 3 : end]), kind)
            elif kind in (76, 67):  # 'L', 'C'
                if msg_size < (9 if kind == 76 else 11):
                    raise self.fail(pos, "a logged-text message too short")
            elif kind == 79 and msg_size < 2:  # 'O'
                raise self.fail(pos, "a dropout message too short")
            pos = end
        return pos, definitions

    def key_value(self, offset: int, payload: bytes, kind: int) -> None:
        """An information ('I', 'M') or parameter ('P', 'Q') message: ``uint8 key_len, key "type name", value``."""
        skip = 1 if kind in (77, 81) else 0  # 'M' starts with is_continued, 'Q' with default_types
        if len(payload) < skip + 1:
            raise self.fail(offset, "a key-value message too short")
        n_key = payload[skip]
        key = payload[skip + 1 : skip + 1 + n_key]
        if len(key) != n_key:
            raise self.fail(offset, "a key-value message whose key runs past its end")
        m = re.fullmatch(rb"([a-z0-9_]+)(\[[0-9]{1,5}\])? ([^ ]+)", key)
        if m is None or m.group(1).decode() not in _SIZES:
            raise self.fail(offset, f"a key-value message with key {key[:40]!r}")
        have = len(payload) - skip - 1 - n_key
        if m.group(2) is None and have != _SIZES[m.group(1).decode()]:  # pyulog unpacks a scalar exactly
            raise self.fail(offset, f"{key[:40].decode()!r} with a value of {have} bytes")
        if kind in (80, 81) and m.group(2) is not None:
            raise self.fail(offset, f"parameter {key[:40].decode()!r} is an array")

    def cut(self, pos: int, stop: int, definitions: bool) -> int:
        if definitions or stop != self.size:
            raise self.fail(pos, f"cut short: a message runs past the end at byte {stop}")
        self.notes.append(f"the file is cut short in its last message (byte {pos} of {self.size}); read up to it")
        return pos


def _spell(types: tuple[str, ...], count: int | None) -> str:
    if count == 0:
        return " or ".join(types)
    return " or ".join(f"{t}[{count if count is not None else 'n'}]" for t in types)


def check_ulog(path: str | Path) -> UlogCheck:
    """Walk a ULog's messages before it is parsed (module docstring); refuse it with one line if bad.

    Returns:
        What was found; its ``notes`` are to be said on stderr by the caller.

    Raises:
        InputError: the file is not a ULog pyulog reads cleanly within the documented maxima; the message
            names the first fault and its byte offset.
    """
    p = Path(path)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        raise InputError(f"{p}: no such file") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot read ({exc.strerror})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise InputError(f"{p}: not a regular file")
        size = st.st_size
        if size > MAX_ULOG_BYTES:
            raise InputError(f"{p}: {size} bytes, larger than the limit for a ULog ({MAX_ULOG_BYTES})")
        if size < HEADER_BYTES:
            raise InputError(f"{p}: not a ULog file (shorter than its 16-byte header)")
        with mmap.mmap(fd, size, access=mmap.ACCESS_READ) as buf:
            return _check(p, buf, size)
    except OSError as exc:
        raise InputError(f"{p}: cannot read ({exc.strerror or exc})") from None
    finally:
        os.close(fd)


def _check(p: Path, buf, size: int) -> UlogCheck:
    if buf[:7] != MAGIC:
        raise InputError(f"{p}: not a ULog file (no ULog header)")
    if buf[7] > 1:
        raise InputError(f"{p}: ULog version {buf[7]}; only version 1 is known")
    start_us = struct.unpack_from("<Q", buf, 8)[0]
    if start_us > MAX_ULOG_TIME_US:
        raise InputError(f"{p}: not a readable ULog: a start time of {start_us} µs, beyond {MAX_ULOG_TIME_US}")
    w = _Walk(p, buf, size)
    stops = [size]
    if size >= HEADER_BYTES + 3 + 40 and buf[HEADER_BYTES + 2] == 66:  # the flag bits
        if struct.unpack_from("<H", buf, HEADER_BYTES)[0] < 40:
            raise w.fail(HEADER_BYTES, "a flag-bits message too short")
        incompat = buf[HEADER_BYTES + 3 + 8 : HEADER_BYTES + 3 + 16]
        if incompat[0] & ~1 or any(incompat[1:]):
            raise w.fail(HEADER_BYTES, "an incompatible flag this reader does not know")
        offsets = [o for o in struct.unpack_from("<3Q", buf, HEADER_BYTES + 3 + 16) if o]
        if incompat[0] & 1 and offsets:
            if any(not HEADER_BYTES < o <= size for o in offsets) or offsets != sorted(offsets):
                raise w.fail(HEADER_BYTES, f"appended-data offsets {offsets} outside the file or out of order")
            stops = [*offsets, size]
    pos, definitions = w.walk(HEADER_BYTES, stops[0], True)
    for a, b in zip(stops, stops[1:], strict=False):
        pos, definitions = w.walk(a, b, definitions)
    return UlogCheck(w.n, pos, tuple(w.notes))


_CHECKED: dict[tuple[int, int, int, int], UlogCheck] = {}


def guard(path: str | Path) -> UlogCheck:
    """:func:`check_ulog` once per file and process; its notes said on stderr the first time.

    A file read twice by one command (checked, then read) is walked once.
    """
    import sys

    p = Path(path)
    try:
        st = os.stat(p)
        key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
    except OSError:
        key = None
    if key is not None and key in _CHECKED:
        return _CHECKED[key]
    result = check_ulog(p)
    for note in result.notes:
        print(f"omnirotor: note: {p.name}: {note}", file=sys.stderr)
    if key is not None:
        _CHECKED[key] = result
    return result
