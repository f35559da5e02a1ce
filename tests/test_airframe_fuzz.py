"""Every fuzzed PX4 airframe, QGroundControl .params file and vehicle overlay fails cleanly (issue 26 item 2).

The corpus: the omnicopter airframe of ../shared/data/px4 (skipped when absent) and the quadrotor written
here as an airframe and as a QGroundControl ``.params`` file, with values replaced (NaN, inf, 1e400, a
400-digit integer, -0, huge and tiny numbers, words), lines dropped or repeated, bytes flipped
(hypothesis), and overlays with the same values and wrong types, run through the vehicle loader
(hypothesis: only :class:`~omnirotor.errors.InputError` may escape; the CLI turns it into one line and exit
2) and through ``info`` for every value (one line on stderr and exit 2, or exit 0 with notes only). A ULog's
own parameters are fuzzed through ``info`` and ``hover-windows`` in tests/test_ulog_fuzz.py.
"""

import os
import uuid

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import SHARED
from omnirotor.cli import main
from omnirotor.errors import InputError
from omnirotor.vehicle import load_vehicle

OMNICOPTER = SHARED / "data" / "px4" / "10019_omnicopter"
SETTINGS = settings(
    max_examples=60,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
QUAD = "\n".join(
    ["param set-default CA_ROTOR_COUNT 4"]
    + [
        f"param set-default CA_ROTOR{i}_{k} {v}"
        for i, (x, y, km) in enumerate([(0.2, 0.2, 0.05), (-0.2, -0.2, 0.05), (0.2, -0.2, -0.05), (-0.2, 0.2, -0.05)])
        for k, v in (("PX", x), ("PY", y), ("PZ", 0.0), ("KM", km), ("AX", 0.0), ("AY", 0.0), ("AZ", -1.0))
    ]
)
VALUES = ["nan", "-nan", "inf", "-inf", "1e400", "9" * 400, "-0", "1e300", "-1e300", "1e-320", "x", "0x10", "1_0", ""]


QGC = "".join(
    f"1\t1\t{line.split()[2]}\t{line.split()[3]}\t{6 if 'COUNT' in line else 9}\n" for line in QUAD.splitlines()
)
"""The quadrotor as a QGroundControl ``.params`` file (vehicle id, component id, name, value, MAVLink type)."""


def airframes() -> list[str]:
    out = [QUAD + "\n", QGC]
    if OMNICOPTER.is_file():
        out.append(OMNICOPTER.read_text())
    return out


def outcome(capsys, argv) -> int:
    capsys.readouterr()
    code = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert code in (0, 2), (argv, code, err)
    if code == 2:
        assert len(err) == 1 and err[0].startswith("omnirotor: error:"), err
    else:
        assert all(line.startswith("omnirotor:") for line in err), err
    return code


def loads_or_refuses(path: str, overlay: str | None = None) -> None:
    """The vehicle loads, or InputError (one line): nothing else escapes."""
    try:
        v = load_vehicle(path, overlay)
    except InputError as exc:
        assert "\n" not in str(exc)
        return
    assert v.n_rotors >= 1


def write(tmp_path, text: str | bytes, suffix: str = "") -> str:
    p = tmp_path / f"{uuid.uuid4().hex}{suffix}"
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    return str(p)


@SETTINGS
@given(st.data())
def test_airframe_values_replaced(tmp_path, capsys, data):
    text = data.draw(st.sampled_from(airframes()), label="airframe")
    lines = text.splitlines()
    params = [i for i, line in enumerate(lines) if line.startswith(("param set", "1\t1\t"))]
    for _ in range(data.draw(st.integers(1, 3))):
        i = data.draw(st.sampled_from(params), label="line")
        value = data.draw(st.sampled_from(VALUES), label="value")
        words = lines[i].split()
        if words[0] == "param":
            lines[i] = " ".join([*words[:3], value])
        else:  # a .params line: the value is the fourth of five columns
            lines[i] = "\t".join([*words[:3], value, words[4]])
    loads_or_refuses(write(tmp_path, "\n".join(lines)))


@SETTINGS
@given(st.data())
def test_airframe_lines_dropped_repeated_and_bytes_flipped(tmp_path, capsys, data):
    text = data.draw(st.sampled_from(airframes()), label="airframe")
    lines = text.splitlines()
    for _ in range(data.draw(st.integers(0, 3))):
        i = data.draw(st.integers(0, len(lines) - 1))
        if data.draw(st.booleans()):
            del lines[i]
        else:
            lines.insert(i, lines[i])
    raw = bytearray("\n".join(lines).encode())
    for _ in range(data.draw(st.integers(0, 4))):
        raw[data.draw(st.integers(0, len(raw) - 1))] ^= data.draw(st.integers(1, 255))
    loads_or_refuses(write(tmp_path, bytes(raw)))


OVERLAY_VALUES = ["nan", "inf", "-inf", "1e400", "9" * 400, "0", "-1", "1e-320", '"x"', "[1, 2]", "true", "{a = 1}"]


@SETTINGS
@given(st.data())
def test_overlays(tmp_path, capsys, data):
    keys = ["mass", "c_f", "c_tau", "omega_max_hz", "omega_min_hz", "propeller_diameter", "gravity", "frame_size"]
    keys += ["inertia_diag", "p_E_B", "name", "bogus"]
    chosen = data.draw(st.lists(st.sampled_from(keys), min_size=1, max_size=4, unique=True), label="keys")
    body = "".join(f"{k} = {data.draw(st.sampled_from(OVERLAY_VALUES), label=k)}\n" for k in chosen)
    af = write(tmp_path, QUAD + "\n")
    loads_or_refuses(af, write(tmp_path, body, ".toml"))


def test_airframe_special_files(tmp_path, capsys):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    assert outcome(capsys, ["info", "--vehicle", str(fifo)]) == 2
    assert outcome(capsys, ["info", "--vehicle", "/dev/zero"]) == 2
    big = tmp_path / "big"
    with big.open("wb") as fh:
        fh.write((QUAD + "\n").encode())
        fh.truncate(3 * 2**30)  # sparse
    assert outcome(capsys, ["info", "--vehicle", str(big)]) == 2


@pytest.mark.parametrize("value", VALUES)
def test_each_value_through_info(tmp_path, capsys, value):
    """The value in the rotor count, a position, a KM and an axis; and as an overlay's mass."""
    lines = QUAD.splitlines()
    for i in (0, 1, 4, 7):
        edited = lines.copy()
        edited[i] = " ".join([*lines[i].split()[:3], value])
        outcome(capsys, ["info", "--vehicle", write(tmp_path, "\n".join(edited))])
    qgc = QGC.splitlines()
    qgc[1] = "\t".join([*qgc[1].split()[:3], value, "9"])
    outcome(capsys, ["info", "--vehicle", write(tmp_path, "\n".join(qgc) + "\n", ".params")])
    if value:
        overlay = write(tmp_path, f"mass = {value}\n", ".toml")
        outcome(capsys, ["info", "--vehicle", write(tmp_path, QUAD), "--vehicle-overlay", overlay])
