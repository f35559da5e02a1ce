"""Safe reading and writing (omnirotor.safe_io): atomic, normal modes, never over a link, device or FIFO."""

import json
import os
import stat
import threading

import pytest

from omnirotor.errors import InputError
from omnirotor.safe_io import (
    append_bytes,
    atomic_path,
    check_input_file,
    check_output_file,
    dumps_json,
    load_json,
    read_text,
    truncate_file,
    write_json_atomic,
    write_text_atomic,
)


def test_atomic_write_replaces_a_regular_file_with_normal_mode(tmp_path):
    p = tmp_path / "a.json"
    p.write_text("old")
    old = os.umask(0o027)
    try:
        write_json_atomic(p, {"x": 1})
    finally:
        os.umask(old)
    assert json.loads(p.read_text()) == {"x": 1}
    assert stat.S_IMODE(p.stat().st_mode) == 0o640  # 0o666 minus the umask, not mkstemp's 0o600
    assert sorted(q.name for q in tmp_path.iterdir()) == ["a.json"]  # no temporary file left


def test_a_failing_writer_leaves_the_old_file_and_no_temporary(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("old")
    with pytest.raises(RuntimeError), atomic_path(p) as tmp:
        tmp.write_text("half")
        raise RuntimeError("writer crashed")
    assert p.read_text() == "old"
    assert [q.name for q in tmp_path.iterdir()] == ["a.txt"]


@pytest.mark.parametrize("kind", ["symlink", "fifo", "dir"])
def test_outputs_never_replace_links_fifos_or_folders(tmp_path, kind):
    target = tmp_path / "target"
    target.write_text("keep")
    p = tmp_path / "out.json"
    if kind == "symlink":
        p.symlink_to(target)
    elif kind == "fifo":
        os.mkfifo(p)
    else:
        p.mkdir()
    with pytest.raises(InputError, match="refusing"):
        write_text_atomic(p, "new")
    assert target.read_text() == "keep"
    assert os.path.lexists(p)


def test_a_device_is_refused_as_an_output():
    with pytest.raises(InputError, match="device"):
        check_output_file("/dev/null")


def test_append_and_truncate_never_follow_a_symlink(tmp_path):
    target = tmp_path / "elsewhere.jsonl"
    target.write_text('{"index": 0}\n{"ind')
    link = tmp_path / "results.jsonl"
    link.symlink_to(target)
    with pytest.raises(InputError, match="symbolic link"):
        append_bytes(link, b"x\n")
    with pytest.raises(InputError, match="symbolic link"):
        truncate_file(link, 3)
    assert target.read_text() == '{"index": 0}\n{"ind'


def test_append_creates_with_normal_mode(tmp_path):
    p = tmp_path / "r.jsonl"
    old = os.umask(0o022)
    try:
        append_bytes(p, b"a\n")
        append_bytes(p, b"b\n")
    finally:
        os.umask(old)
    assert p.read_bytes() == b"a\nb\n"
    assert stat.S_IMODE(p.stat().st_mode) == 0o644


def test_a_fifo_input_is_refused_without_blocking(tmp_path):
    p = tmp_path / "data.csv"
    os.mkfifo(p)
    result = {}

    def read():
        try:
            read_text(p)
        except InputError as exc:
            result["error"] = str(exc)

    t = threading.Thread(target=read, daemon=True)
    t.start()
    t.join(10)
    assert not t.is_alive(), "reading a FIFO blocked"
    assert "FIFO" in result["error"]


def test_inputs_must_be_regular_files(tmp_path):
    with pytest.raises(InputError, match="device"):
        check_input_file("/dev/zero")
    with pytest.raises(InputError, match="folder"):
        check_input_file(tmp_path)
    with pytest.raises(InputError, match="no such file"):
        check_input_file(tmp_path / "missing.toml")
    with pytest.raises(InputError, match="longer than 255"):
        check_input_file(tmp_path / ("x" * 300))


def test_json_limits(tmp_path):
    p = tmp_path / "deep.json"
    p.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(InputError, match="nested deeper"):
        load_json(p)
    p.write_text('{"a": ' + "7" * 5000 + "}")
    with pytest.raises(InputError, match="not usable JSON"):
        load_json(p)
    p.write_text('{"a": "[[[[", "b": [1]}')  # brackets inside strings do not count as nesting
    assert load_json(p) == {"a": "[[[[", "b": [1]}


def test_json_output_has_null_for_non_finite_numbers():
    import numpy as np

    text = dumps_json({"a": float("nan"), "b": [np.inf, 1.0], "c": np.float64(2.5)})
    assert json.loads(text) == {"a": None, "b": [None, 1.0], "c": 2.5}
    assert "NaN" not in text and "Infinity" not in text
