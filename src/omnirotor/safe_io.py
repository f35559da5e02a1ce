"""Safe reading and writing of every file omnirotor touches (issue 14, "Files").

Rules, the same for every command and writer of the project:

* **Outputs** replace only a regular file or go into a folder: a device, a FIFO, a socket or a symbolic link
  at the destination is refused with an :class:`~omnirotor.errors.InputError` (so ``--out /dev/full`` run
  as root never replaces the device, and a symlink's target is never truncated).
* **Atomic**: a file is written to a temporary file in the same folder, flushed to disk (``fsync``) and
  renamed over the destination; a failure leaves the old file (or nothing) behind, never half a file.
* **Modes** are the usual ones: ``0o666`` minus the process umask (not the ``0o600`` of ``mkstemp``).
* **Appending** (``results.jsonl``) opens with ``O_NOFOLLOW`` and checks the file is regular.
* **Inputs** must be regular files: a FIFO named ``*.csv`` is refused at once instead of blocking the reader,
  a device or a folder likewise; names longer than the file system allows are refused with one line.
* **JSON outputs** hold plain JSON: a non-finite number is written as ``null`` (never bare ``NaN``).

The size limits are those of :mod:`omnirotor.limits`.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import stat
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from omnirotor.errors import InputError
from omnirotor.limits import MAX_INPUT_BYTES, MAX_JSON_DEPTH

__all__ = [
    "check_input_file",
    "read_bytes",
    "read_text",
    "load_json",
    "check_output_file",
    "check_output_dir",
    "make_dir",
    "atomic_path",
    "reserve_temp",
    "commit_temp",
    "write_bytes_atomic",
    "write_text_atomic",
    "write_json_atomic",
    "plain_json",
    "dumps_json",
    "append_bytes",
    "truncate_file",
    "file_mode",
    "note",
    "route_mujoco_log",
]

NAME_MAX = 255
"""Longest file-name component in bytes (Linux file systems)."""
PATH_MAX = 4096
"""Longest path in bytes."""


def note(message: str) -> None:
    """Say on stderr, in one line, a value changed or assumed on the user's behalf."""
    print(f"omnirotor: note: {message}", file=sys.stderr)


def _label(path: Path, label: str) -> str:
    return f"{label} {path}" if label else str(path)


def _check_name(path: Path, label: str) -> None:
    raw = os.fsencode(path)
    if len(raw) >= PATH_MAX:
        raise InputError(f"{_label(path, label)[:80]}...: path longer than {PATH_MAX} bytes")
    for part in path.parts:
        if len(os.fsencode(part)) > NAME_MAX:
            raise InputError(f"{_label(path, label)[:80]}...: a file name is longer than {NAME_MAX} bytes")


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    return "a special file"


def _os_error(path: Path, label: str, exc: OSError, doing: str) -> InputError:
    if exc.errno == errno.ENAMETOOLONG:
        return InputError(f"{_label(path, label)[:80]}...: file name too long")
    if exc.errno == errno.ENOENT and doing == "read":
        return InputError(f"{_label(path, label)}: no such file")
    return InputError(f"{_label(path, label)}: cannot {doing} ({exc.strerror or exc})")


# -- inputs ------------------------------------------------------------------------------------------------------


def check_input_file(path: str | Path, label: str = "", max_bytes: int = MAX_INPUT_BYTES) -> Path:
    """The path of an existing regular file (symbolic links followed) of at most ``max_bytes``.

    Raises:
        InputError: no such file, not a regular file, or larger than ``max_bytes``.
    """
    p = Path(path)
    _check_name(p, label)
    try:
        st = os.stat(p)
    except OSError as exc:
        raise _os_error(p, label, exc, "read") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{_label(p, label)}: is {_kind(st.st_mode)}, expected a regular file")
    if st.st_size > max_bytes:
        raise InputError(f"{_label(p, label)}: {st.st_size} bytes, larger than the limit {max_bytes}")
    return p


def read_bytes(path: str | Path, label: str = "") -> bytes:
    """The content of a regular file (never blocks on a FIFO; at most :data:`MAX_INPUT_BYTES`)."""
    p = check_input_file(path, label)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as exc:
        raise _os_error(p, label, exc, "read") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):  # replaced between the check and the open
            raise InputError(f"{_label(p, label)}: is {_kind(st.st_mode)}, expected a regular file")
        with os.fdopen(os.dup(fd), "rb") as fh:
            data = fh.read(MAX_INPUT_BYTES + 1)
    except OSError as exc:
        raise _os_error(p, label, exc, "read") from None
    finally:
        os.close(fd)
    if len(data) > MAX_INPUT_BYTES:
        raise InputError(f"{_label(p, label)}: larger than the limit of {MAX_INPUT_BYTES} bytes")
    return data


def read_text(path: str | Path, label: str = "") -> str:
    """The UTF-8 text of a regular file (see :func:`read_bytes`)."""
    p = Path(path)
    try:
        return read_bytes(p, label).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{_label(p, label)}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None


def _depth(text: str) -> int:
    depth = best = 0
    in_str = esc = False
    for ch in text:
        if in_str:
            if esc:
                esc = False
            elif ch == "\\":
                esc = True
            elif ch == '"':
                in_str = False
        elif ch == '"':
            in_str = True
        elif ch in "[{":
            depth += 1
            best = max(best, depth)
        elif ch in "]}":
            depth -= 1
    return best


def load_json(path: str | Path, label: str = "") -> Any:
    """Parse a JSON file: deep nesting, huge numbers and syntax errors are :class:`InputError`.

    Nesting deeper than :data:`MAX_JSON_DEPTH` is refused before parsing. ``NaN``/``Infinity`` literals
    parse (the schema's validator refuses them).
    """
    p = Path(path)
    text = read_text(p, label)
    if _depth(text) > MAX_JSON_DEPTH:
        raise InputError(f"{_label(p, label)}: JSON nested deeper than {MAX_JSON_DEPTH} levels")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{_label(p, label)}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except (ValueError, RecursionError) as exc:  # e.g. an integer of more digits than Python converts
        raise InputError(f"{_label(p, label)}: not usable JSON ({str(exc).split(';')[0]})") from None


# -- outputs -----------------------------------------------------------------------------------------------------


def file_mode() -> int:
    """Mode of a new file: ``0o666`` minus the umask."""
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def check_output_file(path: str | Path, label: str = "--out") -> bool:
    """Check a file destination before any work: True if a regular file will be replaced.

    The folder it goes in (or its nearest existing ancestor) must take a new file: one is created and removed.

    Raises:
        InputError: a name too long, a folder, a device, a FIFO, a socket or a symbolic link at ``path``, a
            parent that is not a folder, or a folder that cannot be written (read-only, ``/proc``, no
            permission).
    """
    p = Path(path)
    _check_name(p, label)
    try:
        st = os.lstat(p)
    except FileNotFoundError:
        parent = p.parent
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
        if parent.exists() and not parent.is_dir():
            raise InputError(f"{_label(p, label)}: {parent} is not a folder") from None
        _probe_writable(parent, p, label)
        return False
    except OSError as exc:
        raise _os_error(p, label, exc, "write") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{_label(p, label)}: is {_kind(st.st_mode)}; refusing to write over it")
    _probe_writable(p.parent if str(p.parent) else Path("."), p, label)
    return True


def _probe_writable(folder: Path, p: Path, label: str) -> None:
    """Create and remove an empty file in ``folder``, so that a folder that cannot be written is refused early.

    A read-only folder or file system, ``/proc`` or a folder without write permission is refused before any
    work, not after it.
    """
    probe = folder / f".omnirotor-probe-{os.getpid()}-{os.urandom(6).hex()}"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    except OSError as exc:
        raise _os_error(p, label, exc, "write") from None
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(probe)


def check_output_dir(path: str | Path, label: str = "--out") -> bool:
    """Check a folder destination before any work: True if it exists (a folder, or a link to one)."""
    p = Path(path)
    _check_name(p, label)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        return check_output_file(p, label)  # its parents must be folders
    except OSError as exc:
        raise _os_error(p, label, exc, "write") from None
    if not stat.S_ISDIR(st.st_mode):
        raise InputError(f"{_label(p, label)}: exists and is not a folder")
    _probe_writable(p, p, label)
    return True


def make_dir(path: str | Path, label: str = "--out") -> Path:
    """Create a folder (and its parents) if needed; an :class:`InputError` if it cannot."""
    p = Path(path)
    check_output_dir(p, label)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _os_error(p, label, exc, "create the folder") from None
    return p


def _fsync_path(path: str | Path, directory: bool = False) -> None:
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if directory else 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def reserve_temp(path: str | Path, label: str = "") -> Path:
    """Create, exclusively and under an unpredictable name, an empty temporary file beside ``path``.

    The name is ``.omnirotor-<pid>-<random><k><suffix>`` in the destination's folder, created with
    ``O_CREAT | O_EXCL | O_NOFOLLOW``: a file or link planted there in advance is never opened, let alone
    written through. The destination's extension is kept (writers pick the format from it). Finish with
    :func:`commit_temp` or remove it.

    Raises:
        InputError: see :func:`check_output_file`; or the folder cannot be created or written (read-only,
            ``/proc``, full).
    """
    p = Path(path)
    check_output_file(p, label)
    make_dir(p.parent if str(p.parent) else Path("."), label)
    suffix = p.suffix if len(p.suffix) <= 16 else ".tmp"
    for k in range(100):
        candidate = p.parent / f".omnirotor-{os.getpid()}-{os.urandom(6).hex()}{k}{suffix}"
        try:
            fd = os.open(candidate, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, file_mode())
        except FileExistsError:
            continue
        except OSError as exc:
            raise _os_error(p, label, exc, "write") from None
        os.close(fd)
        return candidate
    raise InputError(f"{_label(p, label)}: cannot create a temporary file beside it")


def commit_temp(tmp: Path, path: str | Path, label: str = "") -> Path:
    """Sync a temporary file of :func:`reserve_temp` to disk and rename it over ``path``; on failure remove it.

    Raises:
        InputError: the destination became a link or special file meanwhile, or the disk refused the data
            (e.g. full: nothing partial is left behind).
    """
    p = Path(path)
    try:
        _fsync_path(tmp)
        check_output_file(p, label)  # again: something may have appeared there meanwhile
        os.replace(tmp, p)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise _os_error(p, label, exc, "write") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    with contextlib.suppress(OSError):
        _fsync_path(p.parent if str(p.parent) else ".", directory=True)
    return p


@contextlib.contextmanager
def atomic_path(path: str | Path, label: str = "") -> Iterator[Path]:
    """A temporary path beside ``path`` for a writer; on success synced and renamed over ``path``.

    The file is made by :func:`reserve_temp` and put in place by :func:`commit_temp`. If the body raises, the
    temporary file is removed and the destination is untouched.

    Raises:
        InputError: see :func:`check_output_file`; or the folder cannot be created or written.
    """
    tmp = reserve_temp(path, label)
    try:
        yield tmp
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise _os_error(Path(path), label, exc, "write") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    commit_temp(tmp, path, label)


def write_bytes_atomic(path: str | Path, data: bytes, label: str = "") -> Path:
    """Write bytes atomically (see :func:`atomic_path`)."""
    with atomic_path(path, label) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
    return Path(path)


def write_text_atomic(path: str | Path, text: str, label: str = "") -> Path:
    """Write UTF-8 text atomically (see :func:`atomic_path`)."""
    return write_bytes_atomic(path, text.encode("utf-8"), label)


def plain_json(obj: Any) -> Any:
    """Plain JSON data: numpy scalars and arrays converted, tuples as lists, non-finite floats as None."""
    if isinstance(obj, dict):
        return {str(k): plain_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [plain_json(v) for v in obj]
    import numpy as np  # here, not at import: the CLI's help must stay light

    if isinstance(obj, np.ndarray):
        return plain_json(obj.tolist())
    if isinstance(obj, np.generic):
        return plain_json(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def dumps_json(obj: Any, indent: int | None = 1) -> str:
    """JSON text of ``obj`` with every non-finite number written as ``null`` (see :func:`plain_json`)."""
    return json.dumps(plain_json(obj), indent=indent, allow_nan=False)


def write_json_atomic(path: str | Path, obj: Any, label: str = "") -> Path:
    """Write ``obj`` as JSON atomically; non-finite numbers become ``null``."""
    return write_text_atomic(path, dumps_json(obj) + "\n", label)


def _open_regular(path: Path, flags: int, label: str) -> int:
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise _os_error(path, label, exc, "write") from None
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise InputError(f"{_label(path, label)}: is {_kind(st.st_mode)}; refusing to write to it")
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW | os.O_NONBLOCK, file_mode())
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise InputError(f"{_label(path, label)}: is a symbolic link; refusing to write to it") from None
        raise _os_error(path, label, exc, "write") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise InputError(f"{_label(path, label)}: not a regular file; refusing to write to it")
    return fd


def append_bytes(path: str | Path, data: bytes, label: str = "") -> None:
    """Append ``data`` with one write, synced to disk; ``path`` must be a regular file (or absent)."""
    fd = _open_regular(Path(path), os.O_WRONLY | os.O_APPEND | os.O_CREAT, label)
    try:
        os.write(fd, data)
        os.fsync(fd)
    finally:
        os.close(fd)


def truncate_file(path: str | Path, size: int, label: str = "") -> None:
    """Cut a regular file to ``size`` bytes (never through a symbolic link)."""
    fd = _open_regular(Path(path), os.O_WRONLY, label)
    try:
        os.ftruncate(fd, size)
        os.fsync(fd)
    finally:
        os.close(fd)


def route_mujoco_log(folder: str | Path | None) -> None:
    """Send MuJoCo's own log into ``folder/MUJOCO_LOG.TXT``, or nowhere when ``folder`` is None.

    MuJoCo otherwise writes ``MUJOCO_LOG.TXT`` into the working folder and prints on the terminal. Its
    warnings are still counted in each simulator's ``data.warning``.
    """
    import mujoco

    cfg = mujoco.MjLogConfig.get()
    cfg.logto_console = False
    if folder is None:
        cfg.logto_file = False
    else:
        cfg.logto_file = True
        cfg.logfile = str(Path(folder).resolve() / "MUJOCO_LOG.TXT")
    cfg.set()
