"""The shipped ROS 2 message definitions and their rosbags type store (issue 24, item 1)."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
import zlib
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from omnirotor.rosmsg import MSG_PACKAGES, msg_files, typestore

ROOT = Path(__file__).resolve().parents[1] / "src" / "omnirotor" / "rosmsg"

# The type hashes px4_msgs' own generated code carries (rosidl_generator_c's *__description.c of PX4's
# px4_msgs for the v1.18 line): ours must be the same types, or a ROS 2 node using px4_msgs would not match.
PX4_RIHS01 = {
    "px4_msgs/msg/EscStatus": "85dc04703b64002f2a39e5909078ae7b7301da32ef14a04329f4ca9e40e635a2",
    "px4_msgs/msg/EscReport": "130a8d15dc9de33bf51236702851aea8277ab76b6ce54ab07e25ba79d8911dcb",
}


def _example(store, name: str):
    """A message of type ``name`` whose every field holds a non-default value (recursively)."""
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    cls = store.types[name]
    fields = store.fielddefs[name][1]
    values = {}
    for fname, (kind, spec) in fields:
        values[fname] = _value(store, kind, spec, rng)
    return cls(**values)


def _value(store, kind, spec, rng):
    from rosbags.interfaces import Nodetype

    if kind == Nodetype.BASE:
        typ = spec[0]
        if typ == "string":
            return "cause é"
        if typ == "bool":
            return True
        if typ.startswith("float"):
            return float(rng.normal()) if typ == "float64" else float(np.float32(rng.normal()))
        info = np.iinfo(typ if typ not in ("byte", "char", "octet") else "uint8")
        return int(rng.integers(max(info.min, -1000), min(info.max, 1000), endpoint=True)) or 1
    if kind == Nodetype.NAME:
        return _example(store, spec)
    sub_kind, sub_spec = spec[0]
    n = spec[1] if kind == Nodetype.ARRAY else 3
    if sub_kind == Nodetype.BASE and sub_spec[0] not in ("string", "bool"):
        dtype = {"float64": np.float64, "float32": np.float32}.get(sub_spec[0], sub_spec[0])
        return np.asarray([_value(store, sub_kind, sub_spec, rng) for _ in range(n)], dtype=dtype)
    return [_value(store, sub_kind, sub_spec, rng) for _ in range(n)]


def _equal(a, b) -> bool:
    if hasattr(a, "__dataclass_fields__"):
        return all(_equal(getattr(a, f), getattr(b, f)) for f in a.__dataclass_fields__ if f != "__msgtype__")
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and np.array_equal(a, b)
    if isinstance(a, list):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def test_every_shipped_message_is_registered():
    names = msg_files()
    assert {n.split("/")[0] for n in names} == set(MSG_PACKAGES)
    for required in ("SensorFrame", "RotorSpeeds", "RotorCommand", "SimStatus", "LoopStatus"):
        assert f"omnirotor_msgs/msg/{required}" in names
    for required in (
        "SensorCombined", "VehicleOdometry", "EscStatus", "EscReport", "ActuatorMotors", "VehicleAttitude",
        "VehicleLocalPosition",
    ):  # fmt: skip
        assert f"px4_msgs/msg/{required}" in names
    store = typestore()
    for name in names:
        assert name in store.types
    assert "geometry_msgs/msg/WrenchStamped" in store.types  # the standard types are there too


@pytest.mark.parametrize("name", sorted(msg_files()))
def test_cdr_round_trip_is_exact(name):
    store = typestore()
    msg = _example(store, name)
    raw = store.serialize_cdr(msg, name)
    back = store.deserialize_cdr(raw, name)
    assert _equal(msg, back)
    assert store.serialize_cdr(back, name) == raw


def test_px4_subset_hashes_match_px4_msgs():
    store = typestore()
    for name, digest in PX4_RIHS01.items():
        assert store.hash_rihs01(name) == f"RIHS01_{digest}"


def test_float64_frame_time_survives_exactly():
    """The lockstep path relies on the frame's time and numbers passing through CDR bit for bit."""
    store = typestore()
    name = "omnirotor_msgs/msg/SensorFrame"
    msg = _example(store, name)
    t = 1234.000999999999976
    msg.t = t
    msg.state[:] = np.nextafter(np.arange(21.0), np.inf)
    back = store.deserialize_cdr(store.serialize_cdr(msg, name), name)
    assert back.t == t
    assert np.array_equal(back.state, msg.state)


def test_field_names_follow_ros2_rules():
    """rosidl accepts lower-case field names and upper-case constants only: a workspace must build these."""
    field = re.compile(r"^[a-z][a-z0-9]*(_[a-z0-9]+)*$")
    const = re.compile(r"^[A-Z][A-Z0-9_]*$")
    for name, path in msg_files().items():
        for line in path.read_text().splitlines():
            body = line.split("#", 1)[0].strip()
            if not body:
                continue
            parts = body.split()
            assert len(parts) >= 2, (name, line)
            ident = parts[1].split("=")[0]
            if "=" in body:
                assert const.match(ident), (name, line)
            else:
                assert field.match(ident), (name, line)


def test_ros_package_is_buildable_in_form():
    pkg = ROOT / "omnirotor_msgs"
    tree = ET.parse(pkg / "package.xml")
    assert tree.getroot().attrib["format"] == "3"
    assert tree.findtext("name") == "omnirotor_msgs"
    assert tree.find("member_of_group").text == "rosidl_interface_packages"
    depends = {e.text for e in tree.findall("depend")}
    cmake = (pkg / "CMakeLists.txt").read_text()
    assert "project(omnirotor_msgs)" in cmake and "rosidl_generate_interfaces" in cmake
    # every package a message refers to is a dependency of the package
    used = set()
    for path in (pkg / "msg").glob("*.msg"):
        used |= set(re.findall(r"^([a-z_]+)/[A-Z]\w*", path.read_text(), flags=re.M))
    assert used - {"omnirotor_msgs"} <= depends


def test_independent_store_from_the_files_alone():
    """A store built only from the shipped files (as a ROS 2 listener would) gives the same types and hashes."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for name, path in msg_files().items():
        types.update(get_types_from_msg(path.read_text(), name))
    store.register(types)
    for name in msg_files():
        assert store.hash_rihs01(name) == typestore().hash_rihs01(name)


def test_frame_codec_decodes_exactly_into_its_record():
    """A frame message decoded in place gives the record and the frame from_record gives, bit for bit."""
    from omnirotor.messages import SensorFrame, new_frame
    from omnirotor.rosmsg.convert import FrameCodec, WireMessages

    rng = np.random.default_rng(3)
    codec, wire = FrameCodec(6), WireMessages(6)
    for mocap, state in ((1.0, 1.0), (0.0, 0.0), (1.0, 0.0)):
        rec = new_frame(6)
        rec.view(np.float64)[:] = rng.normal(size=rec.view(np.float64).size)
        rec[0]["mocap"]["new"], rec[0]["state"]["valid"] = mocap, state
        if not mocap:
            rec[0]["mocap"] = 0.0
        if not state:
            rec[0]["state"] = 0.0
        msg = typestore().deserialize_cdr(
            bytes(typestore().serialize_cdr(wire.fill_frame(rec, 9), "omnirotor_msgs/msg/SensorFrame")),
            "omnirotor_msgs/msg/SensorFrame",
        )
        frame, ref = codec.decode(msg), SensorFrame.from_record(rec)
        assert codec.record.tobytes() == rec.tobytes()
        assert frame.record is codec.record
        for name in ("t", "imu_acc_B", "imu_gyro_B", "rotor_hz", "mocap_new", "mocap_t", "mocap_p_W", "mocap_q_WB"):
            a, b = getattr(frame, name), getattr(ref, name)
            assert (a is None and b is None) or np.array_equal(a, b), name
        assert (frame.state is None) == (ref.state is None)
        if ref.state is not None:
            assert np.array_equal(frame.state.R_WB, ref.state.R_WB)


def _random_frame(store, rng, n: int, frame_id: str):
    T = store.types
    bits = rng.integers(0, 2**63, 64, dtype=np.int64).view(np.float64)  # any float64 bits, NaN and inf included
    return T["omnirotor_msgs/msg/SensorFrame"](
        header=T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=int(rng.integers(0, 2**31)), nanosec=7), frame_id=frame_id
        ),
        session_id=int(rng.integers(0, 2**64, dtype=np.uint64)), seq=int(rng.integers(0, 2**63)), t=float(bits[0]),
        imu_acc_b=bits[1:4].copy(), imu_gyro_b=bits[4:7].copy(),
        mocap_new=bool(rng.integers(0, 2)), mocap_t=float(bits[7]), mocap_p_w=bits[8:11].copy(),
        mocap_q_wb=bits[11:15].copy(), has_state=bool(rng.integers(0, 2)), state=bits[15:36].copy(),
        rotor_hz=bits[36 : 36 + n].copy(),
    )  # fmt: skip


_FRAME_FIELDS = ("session_id", "seq", "t", "imu_acc_b", "imu_gyro_b", "mocap_new", "mocap_t", "mocap_p_w", "mocap_q_wb",
                 "has_state", "state", "rotor_hz")  # fmt: skip


def _same_bits(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind == "f":
        return a.shape == b.shape and a.tobytes() == b.astype(a.dtype).tobytes()
    return a.shape == b.shape and bool(np.all(a == b))


def test_frame_wire_reads_what_rosbags_reads_for_any_frame_id_and_values():
    """The node's in-place frame decoding gives rosbags' values, bit for bit (NaN and inf too), for any frame_id."""
    from omnirotor.rosmsg.convert import FrameWire

    store = typestore()
    rng = np.random.default_rng(3)
    for n in (4, 6, 8, 12):
        wire = FrameWire(n)
        for frame_id in ("", "b", "base_link", "world_12345", "é" * 5, "x" * 37):
            for _ in range(5):
                msg = _random_frame(store, rng, n, frame_id)
                payload = bytes(store.serialize_cdr(msg, "omnirotor_msgs/msg/SensorFrame"))
                fast = wire.decode(payload)
                ref = store.deserialize_cdr(payload, "omnirotor_msgs/msg/SensorFrame")
                assert fast is not None
                for f in _FRAME_FIELDS:
                    assert _same_bits(getattr(fast, f), getattr(ref, f)), (n, frame_id, f)
        # another rotor count, or big-endian CDR: left to rosbags
        other = bytes(store.serialize_cdr(_random_frame(store, rng, n + 1, "b"), "omnirotor_msgs/msg/SensorFrame"))
        assert wire.decode(other) is None
        big = store.serialize_cdr(
            _random_frame(store, rng, n, "b"), "omnirotor_msgs/msg/SensorFrame", little_endian=False
        )
        assert wire.decode(bytes(big)) is None


def test_command_wire_writes_rosbags_bytes():
    """The node's command payload, updated in place, is rosbags' serialisation of the same fields, byte for byte."""
    from omnirotor.rosmsg.convert import COMMAND, CommandWire, set_stamp

    store = typestore()
    T = store.types
    rng = np.random.default_rng(9)
    for n in (4, 8, 12):
        for frame_id in ("base_link", "", "robot_7"):
            wire = CommandWire(n, frame_id)
            for t in (0.0, 1.2345678912345, 12345.000000001, -1.0, float("nan"), float("inf"), 3e9):
                hz = rng.normal(0.0, 300.0, n)
                fields = dict(control_status=int(rng.integers(0, 2**32)), state=int(rng.integers(0, 3)),
                              session_id=int(rng.integers(1, 2**63)), seq=int(rng.integers(0, 2**63)),
                              frame_seq=int(rng.integers(0, 2**63)))  # fmt: skip
                got = wire.fill(hz, t, **fields)
                header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0),
                                                  frame_id=frame_id)  # fmt: skip
                set_stamp(header, t)
                ref = T[COMMAND](header=header, t=t, hz=hz.copy(), **fields)
                assert got == bytes(store.serialize_cdr(ref, COMMAND)), (n, frame_id, t)
                ref.seq = 77
                assert wire.with_seq(77) == bytes(store.serialize_cdr(ref, COMMAND))


def test_frame_encoder_writes_rosbags_bytes_of_the_record():
    """The simulator's frame payload, written in place from its record, is rosbags' serialisation of the message
    :meth:`WireMessages.fill_frame` builds from the same record, byte for byte (with and without a sample or a
    state, any float64 bits)."""
    from omnirotor.messages import new_frame
    from omnirotor.rosmsg.convert import FRAME, FrameEncoder, WireMessages, flat_view

    store = typestore()
    rng = np.random.default_rng(13)
    for n, session in ((4, 0), (8, 0xFEDCBA9876543211), (8, 1)):
        enc, msgs = FrameEncoder(n, session_id=session), WireMessages(n)
        msgs.frame.session_id = session  # the plant's session: set once, not part of the record
        assert enc.session_id == session
        record = new_frame(n)
        x = flat_view(record)
        for k in range(40):
            x[:] = rng.integers(0, 2**63, x.size, dtype=np.int64).view(np.float64)
            x[0] = abs(rng.normal(100.0, 100.0)) if k % 3 else x[0]  # a plain time, or any bits
            x[7] = float(k % 2)  # mocap.new
            x[16] = float((k // 2) % 2)  # state.valid
            seq = int(rng.integers(0, 2**63))
            assert enc.encode(record, seq) == bytes(store.serialize_cdr(msgs.fill_frame(record, seq), FRAME)), (n, k)


_COMMAND_FIELDS = ("t", "hz", "control_status", "state", "session_id", "seq", "frame_seq")


def _random_command(store, rng, n: int, frame_id: str):
    """A RotorCommand of any float64 bits and random numbers."""
    T = store.types
    bits = rng.integers(0, 2**63, n + 1, dtype=np.int64).view(np.float64)
    header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=3, nanosec=4), frame_id=frame_id)
    return T["omnirotor_msgs/msg/RotorCommand"](header=header, t=float(bits[0]), hz=bits[1:].copy(),
                                                control_status=int(rng.integers(0, 2**32)),
                                                state=int(rng.integers(0, 256)),
                                                session_id=int(rng.integers(0, 2**63)),
                                                seq=int(rng.integers(0, 2**63)),
                                                frame_seq=int(rng.integers(0, 2**63)))  # fmt: skip


def test_command_wire_decode_reads_what_rosbags_reads():
    """The simulator's in-place command decoding: rosbags' values for any frame_id; another rotor count refused."""
    from omnirotor.rosmsg.convert import COMMAND, CommandWire

    store = typestore()
    rng = np.random.default_rng(21)
    for n in (4, 8):
        wire = CommandWire(n)
        for frame_id in ("", "base_link", "é" * 3, "x" * 20):
            payload = bytes(store.serialize_cdr(_random_command(store, rng, n, frame_id), COMMAND))
            fast, ref = wire.decode(payload), store.deserialize_cdr(payload, COMMAND)
            assert fast is not None
            for f in _COMMAND_FIELDS:
                assert _same_bits(getattr(fast, f), getattr(ref, f)), (n, frame_id, f)
        assert wire.decode(bytes(store.serialize_cdr(_random_command(store, rng, n + 1, "b"), COMMAND))) is None


@pytest.mark.parametrize("kind", ["frame", "command"])
def test_wire_decoders_never_accept_what_rosbags_refuses(kind):
    """Over truncations, extensions, bit flips and random bytes: whatever a fast path (the node's FrameWire, the
    simulator's CommandWire) accepts, rosbags accepts too (with the subscriber's rule on trailing bytes) and reads
    the same numbers; the rest it leaves to rosbags."""
    from omnirotor.rosmsg.convert import COMMAND, FRAME, CommandWire, FrameWire

    store = typestore()
    if kind == "frame":
        rng, msgtype, fields, wire, longest = np.random.default_rng(5), FRAME, _FRAME_FIELDS, FrameWire(8), 600
        msg = _random_frame(store, rng, 8, "base_link")
    else:
        rng, msgtype, fields, wire, longest = np.random.default_rng(21), COMMAND, _COMMAND_FIELDS, CommandWire(8), 300
        msg = _random_command(store, rng, 8, "base_link")
    valid = bytes(store.serialize_cdr(msg, msgtype))
    corpus = [valid[:k] for k in range(len(valid))] + [valid + b"\x00" * k for k in range(1, 9)]
    for _ in range(2000):
        b = bytearray(valid)
        for i in rng.integers(0, len(b), int(rng.integers(1, 4))):
            b[i] ^= 1 << int(rng.integers(0, 8))
        corpus.append(bytes(b))
    corpus += [rng.bytes(int(k)) for k in rng.integers(0, longest, 200)]
    accepted = 0
    for payload in corpus:
        fast = wire.decode(payload)
        if fast is None:
            continue
        accepted += 1
        ref, end = store.get_msgdef(msgtype).deserialize_cdr_le(memoryview(payload)[4:], 0, store.types[msgtype], store)
        assert end + 4 + 3 >= len(payload)
        for f in fields:
            assert _same_bits(getattr(fast, f), getattr(ref, f)), f
    assert accepted > 1000  # flips in the numbers are messages too; flips in the lengths are not
