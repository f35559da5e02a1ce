"""A small ULog writer, from PX4's "ULog File Format" specification (version 1).

A file is a 16-byte header (magic ``ULog`` and bytes 0x01 0x12 0x35, version 1, start time [µs]), the
definitions section (flag bits 'B', formats 'F' ``name:type field;...``, information 'I' and parameters 'P', each a key
``"type name"`` and its little-endian value), then the data section: 'A' (add logged message: multi id, message
id, format name) and 'D' (message id, then the packed fields, ``uint64_t timestamp`` [µs] first). Every message
starts with ``uint16 msg_size`` (bytes after the 3-byte header) and ``uint8 msg_type``.

A topic is given as a NumPy structured array whose field order, types and sub-arrays are the message format;
a nested struct field (e.g. PX4's ``esc_report[8] esc``) is written as its own format. Data messages of all
topics are written in timestamp order. pyulog reads the result back (tests/test_px4_export.py).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from omnirotor.errors import InputError

__all__ = ["ULogWriter", "write_hover_log", "write_pwm_log", "patch_format"]

_MAGIC = b"ULog\x01\x12\x35"
_C_TYPES = {
    np.dtype("<u8"): "uint64_t",
    np.dtype("<i8"): "int64_t",
    np.dtype("<u4"): "uint32_t",
    np.dtype("<i4"): "int32_t",
    np.dtype("<u2"): "uint16_t",
    np.dtype("<i2"): "int16_t",
    np.dtype("u1"): "uint8_t",
    np.dtype("i1"): "int8_t",
    np.dtype("<f4"): "float",
    np.dtype("<f8"): "double",
    np.dtype("bool"): "bool",
}


def _msg(kind: bytes, payload: bytes) -> bytes:
    if len(payload) > 0xFFFF:
        raise InputError(f"ULog message of {len(payload)} bytes is too long")
    return struct.pack("<HB", len(payload), kind[0]) + payload


class ULogWriter:
    """Collects formats, information, parameters and topics, then writes one ULog file.

    Args:
        start_us: the header's timestamp [µs] (the log's start).
    """

    def __init__(self, start_us: int = 0) -> None:
        self.start_us = int(start_us)
        self._formats: dict[str, str] = {}
        self._info: list[bytes] = []
        self._params: list[bytes] = []
        self._topics: list[tuple[str, int, np.ndarray]] = []

    def _format_of(self, name: str, dtype: np.dtype, nested: dict[str, str]) -> str:
        parts = []
        for field in dtype.names:
            sub, _ = dtype.fields[field][:2]
            shape = sub.shape
            base = sub.base if shape else sub
            if base.names is not None:
                type_name = nested.get(field)
                if type_name is None:
                    raise InputError(f"ULog topic {name}: nested field {field!r} needs a format name")
                self._formats[type_name] = self._format_of(type_name, base, nested)
            else:
                type_name = _C_TYPES.get(base.newbyteorder("<") if base.byteorder == ">" else base)
                if type_name is None:
                    raise InputError(f"ULog topic {name}: field {field!r} has unsupported type {base}")
            count = int(np.prod(shape)) if shape else 0
            parts.append(f"{type_name}[{count}] {field};" if count else f"{type_name} {field};")
        return "".join(parts)

    def add_topic(self, name: str, rows: np.ndarray, nested: dict[str, str] | None = None, multi_id: int = 0) -> None:
        """Log a topic: ``rows`` is a structured array whose first field is ``timestamp`` (uint64, µs)."""
        if rows.dtype.names is None or rows.dtype.names[0] != "timestamp" or rows.dtype["timestamp"] != np.uint64:
            raise InputError(f"ULog topic {name}: the first field must be uint64 'timestamp'")
        packed = np.ascontiguousarray(rows.astype(_packed(rows.dtype)))
        self._formats[name] = self._format_of(name, packed.dtype, nested or {})
        self._topics.append((name, multi_id, packed))

    def add_info(self, key: str, value: str) -> None:
        """An information message with a string value (e.g. ``sys_name``)."""
        v = value.encode()
        k = f"char[{len(v)}] {key}".encode()
        self._info.append(_msg(b"I", struct.pack("<B", len(k)) + k + v))

    def add_param(self, name: str, value: float | int) -> None:
        """A parameter: ``int32_t`` for Python ints, ``float`` otherwise (PX4's two parameter types)."""
        if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
            k, v = f"int32_t {name}".encode(), struct.pack("<i", int(value))
        else:
            k, v = f"float {name}".encode(), struct.pack("<f", float(value))
        self._params.append(_msg(b"P", struct.pack("<B", len(k)) + k + v))

    def write(self, path: str | Path) -> None:
        """Write the file (atomically: a temporary file renamed into place)."""
        out = [_MAGIC, b"\x01", struct.pack("<Q", self.start_us)]
        out.append(_msg(b"B", bytes(8) + bytes(8) + struct.pack("<3Q", 0, 0, 0)))
        for name, fmt in self._formats.items():
            out.append(_msg(b"F", f"{name}:{fmt}".encode()))
        out.extend(self._info)
        out.extend(self._params)
        blobs, stamps, topic_idx, row_idx = [], [], [], []
        for msg_id, (name, multi_id, rows) in enumerate(self._topics):
            out.append(_msg(b"A", struct.pack("<BH", multi_id, msg_id) + name.encode()))
            size = 2 + rows.dtype.itemsize
            head = np.zeros(rows.size, dtype=np.dtype([("size", "<u2"), ("type", "u1"), ("id", "<u2")]))
            head["size"], head["type"], head["id"] = size, ord("D"), msg_id
            both = np.empty((rows.size, 5 + rows.dtype.itemsize), dtype=np.uint8)
            both[:, :5] = head.view(np.uint8).reshape(rows.size, 5)
            both[:, 5:] = rows.view(np.uint8).reshape(rows.size, rows.dtype.itemsize)
            blobs.append(both)
            stamps.append(rows["timestamp"].astype(np.uint64))
            topic_idx.append(np.full(rows.size, msg_id))
            row_idx.append(np.arange(rows.size))
        if blobs:
            ts, ti, ri = np.concatenate(stamps), np.concatenate(topic_idx), np.concatenate(row_idx)
            order = np.lexsort((ri, ti, ts))
            out.extend(blobs[ti[k]][ri[k]].tobytes() for k in order)
        from omnirotor.safe_io import write_bytes_atomic

        write_bytes_atomic(path, b"".join(out), "--ulog")


def _packed(dtype: np.dtype) -> np.dtype:
    """The same fields, little-endian and without padding (ULog data are packed)."""
    fields = []
    for name in dtype.names:
        sub = dtype.fields[name][0]
        base, shape = (sub.base, sub.shape) if sub.shape else (sub, ())
        base = _packed(base) if base.names is not None else base.newbyteorder("<")
        fields.append((name, base, shape) if shape else (name, base))
    return np.dtype(fields, align=False)


def write_hover_log(path: str | Path, rotor_count: float = 4, seconds: float = 6.0) -> None:
    """Write a level hover of a quadrotor at 100 Hz as PX4 logs it.

    Attitude, ESC reports (6000 rpm), local position, gyro, land detector and the ``CA_*`` geometry
    (``CA_ROTOR_COUNT = rotor_count``). The base of the PX4-file fuzzing (tests/test_ulog_fuzz.py,
    tools/reliability_report.py).
    """
    n = int(round(seconds * 100))
    ts = 1_000_000 + np.arange(n, dtype=np.uint64) * 10_000
    w = ULogWriter(start_us=1_000_000)
    att = np.zeros(n, dtype=[("timestamp", "<u8"), ("q", "<f4", (4,))])
    att["timestamp"], att["q"][:, 0] = ts, 1.0
    w.add_topic("vehicle_attitude", att)
    rep = np.dtype([("timestamp", "<u8"), ("esc_rpm", "<i4")])
    esc = np.zeros(n, dtype=[("timestamp", "<u8"), ("esc", rep, (4,))])
    esc["timestamp"], esc["esc"]["esc_rpm"] = ts, 6000
    w.add_topic("esc_status", esc, {"esc": "esc_report"})
    lp = np.zeros(n, dtype=[("timestamp", "<u8")] + [(k, "<f4") for k in ("x", "y", "z", "vx", "vy", "vz")])
    lp["timestamp"], lp["z"] = ts, -1.0
    w.add_topic("vehicle_local_position", lp)
    sc = np.zeros(n, dtype=[("timestamp", "<u8"), ("gyro_rad", "<f4", (3,))])
    sc["timestamp"] = ts
    w.add_topic("sensor_combined", sc)
    ld = np.zeros(4, dtype=[("timestamp", "<u8"), ("landed", "u1")])
    ld["timestamp"] = ts[:: n // 4][:4]
    w.add_topic("vehicle_land_detected", ld)
    w.add_param("CA_ROTOR_COUNT", rotor_count)
    for i, (x, y, km) in enumerate([(0.2, 0.2, 0.05), (-0.2, -0.2, 0.05), (0.2, -0.2, -0.05), (-0.2, 0.2, -0.05)]):
        for key, v in (("PX", x), ("PY", y), ("PZ", 0.0), ("KM", km), ("AX", 0.0), ("AY", 0.0), ("AZ", -1.0)):
            w.add_param(f"CA_ROTOR{i}_{key}", v)
    w.write(path)


def write_pwm_log(
    path: str | Path, pwm_us: float | Sequence[float] = 1500.0, seconds: float = 4.0, params: dict | None = None
) -> None:
    """Write a level hover of a quadrotor at 100 Hz whose rotor speeds are only PX4's PWM outputs (no ESC telemetry).

    ``vehicle_attitude`` (level) and ``actuator_outputs`` (4 outputs at ``pwm_us`` [µs]: one value, or one per
    output), time stamps from 0, and the parameters ``params`` (e.g. ``PWM_MIN``, ``THR_MDL_FAC``). The base of the
    PWM tests (tests/test_px4_in.py, tests/test_ulog_fuzz.py).
    """
    n = int(round(seconds * 100))
    ts = np.arange(n, dtype=np.uint64) * 10_000
    w = ULogWriter()
    att = np.zeros(n, dtype=[("timestamp", "<u8"), ("q", "<f4", (4,))])
    att["timestamp"], att["q"][:, 0] = ts, 1.0
    w.add_topic("vehicle_attitude", att)
    out = np.zeros(n, dtype=[("timestamp", "<u8"), ("noutputs", "<u4"), ("output", "<f4", (16,))])
    out["timestamp"], out["noutputs"], out["output"][:, :4] = ts, 4, pwm_us
    w.add_topic("actuator_outputs", out)
    for key, v in (params or {}).items():
        w.add_param(key, v)
    w.write(path)


def patch_format(data: bytes, topic: str, old: str, new: str) -> bytes:
    """A ULog's bytes with ``old`` replaced by ``new`` in the format definition of ``topic``, its size fixed up.

    For fuzzing (fields renamed, retyped, resized): the data messages are left as they were.

    Raises:
        KeyError: no format of ``topic`` holds ``old``.
    """
    pos = 16
    while pos + 3 <= len(data):
        size, kind = struct.unpack_from("<HB", data, pos)
        payload = data[pos + 3 : pos + 3 + size]
        if kind == ord("F") and payload.startswith(topic.encode() + b":") and old.encode() in payload:
            p2 = payload.replace(old.encode(), new.encode(), 1)
            return data[:pos] + struct.pack("<HB", len(p2), kind) + p2 + data[pos + 3 + size :]
        pos += 3 + size
    raise KeyError(f"no format {topic} with {old!r}")
