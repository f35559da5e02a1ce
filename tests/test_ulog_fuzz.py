"""Every fuzzed PX4 flight log fails cleanly (issue 26 item 2): one line on stderr and exit 2, or a correct result.

The corpus: the project's own ULog writer's hover log (attitude, nested ESC reports, local position, gyro,
land detector, a quadrotor's ``CA_*`` parameters) and the real logs of ../shared/data/px4 (skipped when
absent), mutated by bytes flipped (hypothesis), truncation at every structural offset (each message's start,
inside its header, inside its payload), format fields renamed, retyped and resized (``q`` as ``char[16]`` or
``uint8_t[16]``, time stamps as doubles, arrays of 2³¹ elements), huge declared sizes and times (a start of
2⁶⁴−1 µs, a sparse file of 2 GiB of zeros) and parameters out of range (``CA_ROTOR_COUNT = 100000000``), run
through ``hover-windows``, ``identify`` and ``info`` in this process. The guard is
:mod:`omnirotor.px4.ulog_guard`.
"""

import os
import struct
import uuid

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import SHARED
from omnirotor.cli import main
from omnirotor.errors import InputError
from omnirotor.px4.flight import read_flight
from omnirotor.px4.ulog_guard import HEADER_BYTES, check_ulog
from omnirotor.px4.ulog_writer import patch_format

REAL = [SHARED / "data" / "px4" / n for n in ("sample_log_small.ulg", "sample_px4_events.ulg")]
SETTINGS = settings(
    max_examples=40,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


def hover_log_bytes(tmp_path, n_rotor_count: float = 4) -> bytes:
    """A 6 s level hover at 100 Hz of a quadrotor, as the project's ULog writer writes it."""
    from omnirotor.px4.ulog_writer import write_hover_log

    path = tmp_path / f"base-{uuid.uuid4().hex}.ulg"
    write_hover_log(path, n_rotor_count)
    return path.read_bytes()


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> bytes:
    return hover_log_bytes(tmp_path_factory.mktemp("ulog"))


def offsets(data: bytes) -> list[int]:
    """Where each message starts (after the 16-byte header)."""
    out, pos = [], HEADER_BYTES
    while pos + 3 <= len(data):
        out.append(pos)
        pos += 3 + struct.unpack_from("<H", data, pos)[0]
    return out


def write(tmp_path, data: bytes) -> str:
    path = tmp_path / f"{uuid.uuid4().hex}.ulg"  # a new file each time: the guard remembers files it walked
    path.write_bytes(data)
    return str(path)


COMMANDS = {
    "identify": lambda f, t: ["identify", f, "--vehicle", "quadrotor", "--out", f"{t}/m.json"],
    "info": lambda f, t: ["info", "--vehicle", f],
    "hover-windows": lambda f, t: ["hover-windows", f, "--vehicle", "quadrotor", "--out", f"{t}/w.png"],
}


def outcome(capsys, command: str, path: str, tmp_path) -> tuple[int, list[str]]:
    """Run one command in this process; assert it failed cleanly or succeeded without noise."""
    for name in ("m.json", "w.png"):
        (tmp_path / name).unlink(missing_ok=True)
    capsys.readouterr()
    code = main(COMMANDS[command](path, tmp_path))
    err = capsys.readouterr().err.strip().splitlines()
    assert code in (0, 2), (command, code, err)
    if code == 2:
        assert len(err) == 1 and err[0].startswith("omnirotor: error:"), err
        assert not (tmp_path / "m.json").exists() and not (tmp_path / "w.png").exists()
    else:
        assert all(line.startswith("omnirotor:") for line in err), err  # notes only, never a warning's noise
    return code, err


# -- the unmutated logs read --------------------------------------------------------------------------------------


def test_writer_log_reads_and_its_hover_is_found(base, tmp_path, capsys):
    f = write(tmp_path, base)
    assert check_ulog(f).notes == ()
    assert outcome(capsys, "hover-windows", f, tmp_path)[0] == 0
    assert outcome(capsys, "info", f, tmp_path)[0] == 0
    flight = read_flight(f, 4)
    np.testing.assert_allclose(flight.omega_hz.x, 100.0)


@pytest.mark.parametrize("path", REAL, ids=lambda p: p.name)
def test_real_logs_pass_the_guard_unchanged(path):
    if not path.is_file():
        pytest.skip(f"PX4 sample log not found at {path}")
    r = check_ulog(path)
    assert r.notes == () and r.end == path.stat().st_size and r.n_messages > 10_000


# -- truncation at every structural offset --------------------------------------------------------------------------


def test_truncation_at_every_structural_offset(base, tmp_path):
    """Cut inside the definitions: refused; cut inside the last message of the data section: read up to it, said.

    Every message of the definitions and every 20th of the data section (and the last 20) is cut at its start,
    inside its header and inside its payload.
    """
    starts = offsets(base)
    first_sub = next(p for p in starts if base[p + 2] == ord("A"))
    first_sub_end = first_sub + 3 + struct.unpack_from("<H", base, first_sub)[0]
    k_sub = starts.index(first_sub)
    chosen = starts[: k_sub + 10] + starts[k_sub + 10 :: 20] + starts[-20:]
    cuts = sorted({c for p in chosen for c in (p, p + 1, p + 2, p + 3, p + 5) if c < len(base)} | {0, 7, 15})
    seen = {"refused": 0, "read": 0}
    for cut in cuts:
        f = write(tmp_path, base[:cut])
        if cut < first_sub_end:  # no whole subscription yet: the definitions are cut
            with pytest.raises(InputError) as exc:
                read_flight(f, 4)
            assert "\n" not in str(exc.value)
            seen["refused"] += 1
        else:
            try:
                r = check_ulog(f)
            except InputError:
                raise AssertionError(f"a data section cut at {cut} must be read up to the cut") from None
            assert (r.notes == ()) == (cut in starts)
            assert r.end == max(p for p in starts if p <= cut)
            seen["read"] += 1
        os.unlink(f)
    assert seen["refused"] > 100 and seen["read"] > 500


@pytest.mark.parametrize("command", list(COMMANDS))
def test_truncated_logs_through_the_commands(base, tmp_path, capsys, command):
    starts = offsets(base)
    first_data = next(p for p in starts if base[p + 2] == ord("A"))
    for cut in (5, 16, 18, starts[3] + 4, first_data + 1, starts[-40] + 9, len(base) - 3):
        outcome(capsys, command, write(tmp_path, base[:cut]), tmp_path)


# -- bytes flipped -------------------------------------------------------------------------------------------------


@SETTINGS
@given(st.data())
def test_flipped_bytes_fail_cleanly(base, tmp_path, capsys, data):
    buf = bytearray(base)
    for _ in range(data.draw(st.integers(1, 8), label="flips")):
        at = data.draw(st.integers(0, len(buf) - 1), label="at")
        buf[at] ^= data.draw(st.integers(1, 255), label="xor")
    command = data.draw(st.sampled_from(["identify", "info"]), label="command")
    outcome(capsys, command, write(tmp_path, bytes(buf)), tmp_path)


@SETTINGS
@given(st.data())
def test_flipped_bytes_of_the_headers_fail_cleanly(base, tmp_path, capsys, data):
    """The bytes that steer a parser: the file header and every message's size and type."""
    buf = bytearray(base)
    targets = list(range(HEADER_BYTES)) + [p + k for p in offsets(base) for k in (0, 1, 2)]
    for _ in range(data.draw(st.integers(1, 3), label="flips")):
        at = data.draw(st.sampled_from(targets), label="at")
        buf[at] = data.draw(st.integers(0, 255), label="value")
    outcome(capsys, data.draw(st.sampled_from(["identify", "info"])), write(tmp_path, bytes(buf)), tmp_path)


@pytest.mark.parametrize("path", REAL, ids=lambda p: p.name)
def test_flipped_bytes_of_a_real_log_fail_cleanly(path, tmp_path, capsys):
    if not path.is_file():
        pytest.skip(f"PX4 sample log not found at {path}")
    real = path.read_bytes()
    rng = np.random.default_rng(26)
    starts = offsets(real)
    for k in range(6):
        buf = bytearray(real)
        at = int(rng.choice(starts[:200])) + int(rng.integers(0, 3)) if k % 2 else int(rng.integers(0, len(buf)))
        buf[at] ^= int(rng.integers(1, 256))
        outcome(capsys, "info", write(tmp_path, bytes(buf)), tmp_path)


# -- fields renamed, retyped, resized --------------------------------------------------------------------------------

FIELD_CASES = [
    # (topic, old, new, words of the one line)
    ("vehicle_attitude", "float[4] q", "char[16] q", "field q is char[16]"),
    ("vehicle_attitude", "float[4] q", "uint8_t[16] q", "field q is uint8_t[16]"),
    ("vehicle_attitude", "float[4] q", "float[4] quat", "has no field q"),
    ("vehicle_attitude", "float[4] q", "float[2] q;double q2", "field q is float[2]"),
    ("vehicle_attitude", "float[4] q", "float[2147483648] q", "declares 2147483648 elements"),
    ("vehicle_attitude", "float[4] q", "float[16383] q", "larger than a message can hold"),
    ("vehicle_attitude", "uint64_t timestamp", "double timestamp", "timestamp is double"),
    ("vehicle_attitude", "uint64_t timestamp", "uint64_t time", "has no uint64_t timestamp"),
    ("esc_status", "uint64_t timestamp", "double timestamp", "timestamp is double"),
    ("esc_report", "int32_t esc_rpm", "char[4] esc_rpm", "field esc_rpm is char[4]"),
    ("esc_status", "esc_report[4] esc", "esc_status[4] esc", "nests deeper"),
    ("esc_status", "esc_report[4] esc", "nothing[4] esc", "unknown format or type 'nothing'"),
    ("vehicle_local_position", "float z", "float zz", "has no field z"),
    ("sensor_combined", "float[3] gyro_rad", "float[4] gyro_rad", "is float[4], expected float[3] or double[3]"),
    ("sensor_combined", "float[3] gyro_rad", "int32_t[3] gyro_rad", "field gyro_rad is int32_t[3]"),
    ("vehicle_land_detected", "uint8_t landed", "float landed", "field landed is float"),
    ("vehicle_land_detected", "uint8_t landed", "uint16_t landed", "field landed is uint16_t"),
    ("vehicle_local_position", "float z", "float z;float extra", "of 32 bytes, its format has 36"),
    ("vehicle_attitude", "float[4] q", "float[4] q;", None),  # an empty field: harmless
]


@pytest.mark.parametrize("case", FIELD_CASES, ids=lambda c: f"{c[0]}:{c[2]}")
def test_fields_renamed_retyped_resized(base, tmp_path, capsys, case):
    topic, old, new, words = case
    f = write(tmp_path, patch_format(base, topic, old, new))
    if words is None:
        assert outcome(capsys, "hover-windows", f, tmp_path)[0] == 0
        return
    for command in COMMANDS:
        code, err = outcome(capsys, command, f, tmp_path)
        assert code == 2 and words in err[0], (command, err)


# -- huge declared sizes and times, parameters out of range -------------------------------------------------------


def pwm_log_bytes(tmp_path) -> bytes:
    """A level 4 s hover whose rotor speeds are only PX4's ``actuator_outputs`` PWM (no ESC telemetry)."""
    from omnirotor.px4.ulog_writer import write_pwm_log

    path = tmp_path / f"pwm-{uuid.uuid4().hex}.ulg"
    write_pwm_log(path)
    return path.read_bytes()


@pytest.mark.parametrize(
    ("new", "words"),
    [
        ("char[64] output", "field output is char[64]"),  # PWM bytes read as numbers: a wrong flight, not an error
        ("uint8_t[64] output", "field output is uint8_t[64]"),
        ("float output;float[15] pad", "field output is float, expected"),
        ("float[16] outputs", "has no field output"),
    ],
)
def test_pwm_outputs_retyped_fail_with_the_field_named(tmp_path, capsys, new, words):
    f = write(tmp_path, patch_format(pwm_log_bytes(tmp_path), "actuator_outputs", "float[16] output", new))
    for command in ("identify", "hover-windows"):
        code, err = outcome(capsys, command, f, tmp_path)
        assert code == 2 and words in err[0], (command, err)


def test_start_time_of_2_64_minus_1(base, tmp_path, capsys):
    f = write(tmp_path, base[:8] + struct.pack("<Q", 2**64 - 1) + base[16:])
    for command in COMMANDS:
        code, err = outcome(capsys, command, f, tmp_path)
        assert code == 2 and "start time" in err[0]


def test_data_time_stamp_of_2_64_minus_1(base, tmp_path, capsys):
    at = next(p for p in offsets(base) if base[p + 2] == ord("D"))
    f = write(tmp_path, base[: at + 5] + struct.pack("<Q", 2**64 - 1) + base[at + 13 :])
    code, err = outcome(capsys, "identify", f, tmp_path)
    assert code == 2 and "time stamp" in err[0]


def test_message_size_declared_past_the_end(base, tmp_path, capsys):
    at = offsets(base)[2]  # a format definition
    f = write(tmp_path, base[:at] + struct.pack("<H", 0xFFFF) + base[at + 2 :])
    code, err = outcome(capsys, "info", f, tmp_path)
    assert code == 2


def test_sparse_file_of_zeros_after_the_header(base, tmp_path, capsys):
    """2 GiB of zeros (sparse: no disk used): refused at the first message, not walked for minutes."""
    path = tmp_path / "sparse.ulg"
    with path.open("wb") as fh:
        fh.write(base[:HEADER_BYTES])
        fh.truncate(2 * 2**30)
    code, err = outcome(capsys, "identify", str(path), tmp_path)
    assert code == 2 and "not a letter" in err[0] and "byte 16" in err[0]
    with path.open("r+b") as fh:
        fh.truncate(3 * 2**30)
    code, err = outcome(capsys, "info", str(path), tmp_path)
    assert code == 2 and "larger than the limit" in err[0]


@pytest.mark.parametrize("count", [100_000_000, 0, -1, 2.5, 65])
def test_rotor_count_out_of_range(tmp_path, capsys, count):
    f = write(tmp_path, hover_log_bytes(tmp_path, count))
    for command in ("info", "hover-windows"):
        argv = ["info", "--vehicle", f] if command == "info" else ["hover-windows", f, "--out", f"{tmp_path}/w.png"]
        capsys.readouterr()
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "CA_ROTOR_COUNT" in err[0], err
