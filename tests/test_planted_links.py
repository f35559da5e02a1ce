"""Temporary files cannot be hijacked; a full disk or an unwritable folder leaves nothing behind (issue 26 item 3).

The attack pass planted a symbolic link at the predictable temporary name (``.f.ulg.tmp`` beside the output)
and ``run --ulog`` wrote through it into another file. Every writer now goes through
:func:`omnirotor.safe_io.reserve_temp`: an exclusive create (``O_EXCL | O_NOFOLLOW``) under a random name.
"""

import errno
import os

import pytest

from omnirotor.errors import InputError
from omnirotor.px4.ulog_guard import check_ulog
from omnirotor.px4.ulog_writer import write_hover_log
from omnirotor.safe_io import check_output_file, reserve_temp, write_bytes_atomic


def test_a_link_at_the_old_temporary_name_is_not_written_through(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me\n")
    (tmp_path / ".f.ulg.tmp").symlink_to(victim)
    write_hover_log(tmp_path / "f.ulg")
    assert victim.read_text() == "keep me\n"
    assert check_ulog(tmp_path / "f.ulg").n_messages > 1000
    assert sorted(p.name for p in tmp_path.iterdir()) == [".f.ulg.tmp", "f.ulg", "victim.txt"]


def test_a_link_planted_at_the_temporary_name_itself_is_skipped(tmp_path, monkeypatch):
    """Even with the random part guessed, the exclusive create refuses the planted name and takes the next."""
    monkeypatch.setattr(os, "urandom", lambda n: b"\0" * n)
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me\n")
    guessed = tmp_path / f".omnirotor-{os.getpid()}-{'00' * 6}0.json"
    guessed.symlink_to(victim)
    tmp = reserve_temp(tmp_path / "out.json")
    assert tmp != guessed and tmp.is_file() and not tmp.is_symlink()
    tmp.unlink()
    write_bytes_atomic(tmp_path / "out.json", b"{}\n")
    assert victim.read_text() == "keep me\n" and (tmp_path / "out.json").read_bytes() == b"{}\n"


@pytest.mark.parametrize("target", ["/proc/omnirotor.ulg", "/proc/self/omnirotor.json", "/sys/omnirotor.png"])
def test_unwritable_folders_are_refused_before_any_work(target):
    if not os.path.isdir(os.path.dirname(target)):
        pytest.skip(f"{os.path.dirname(target)} is not on this system")
    with pytest.raises(InputError) as exc:
        check_output_file(target, "--out")
    assert "cannot write" in str(exc.value)


def test_a_full_disk_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    dest = tmp_path / "f.ulg"
    dest.write_bytes(b"old")

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(InputError) as exc:
        write_bytes_atomic(dest, b"new" * 1000, "--ulog")
    assert "No space left" in str(exc.value) and "\n" not in str(exc.value)
    assert dest.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["f.ulg"]
