"""A resident campaign worker pool that outlives the command (``omnirotor workers start|status|stop``).

A campaign of short runs pays its start-up on every command: the interpreter's imports (numpy, MuJoCo, numba,
the package: about a second), each worker's kernel loading, the plots' matplotlib. Build tools face the same
and keep a warm process between commands (Gradle's daemon, ccache's server); so does this module.

``omnirotor workers start`` starts a background process, detached from the terminal, that imports everything,
forks its workers (two by default) and warms each on a 10 ms run of a hover and a sliding job and a tiny figure
(:func:`omnirotor.experiments.campaign.warm_up`), then listens on a Unix socket in the user's cache folder
(``$XDG_CACHE_HOME/omnirotor``, else ``~/.cache/omnirotor``; the folder is the user's alone). While it runs,
``omnirotor campaign`` (local backend) hands its campaign to it and says so on stderr: the pool's process plans
the runs, writes the results and the summary exactly as the command would, draws the plots on its workers, and
streams each finished run back to the command's progress bar. When no pool runs, or it is busy with another
campaign, or it was started from other sources, the command runs its own pool as before.

Same results: a run's record depends only on its job (:func:`~omnirotor.experiments.campaign.execute_run` builds
the plant and the controller afresh from the run's seed), never on the process that flew it; tested against the
command's own pool, record by record.

Stale code never serves: the pool's socket is named after this package's folder and the interpreter (so each
checkout has its own pool), and every request carries :func:`source_digest`, a hash of the package's sources and
presets, the interpreter, the compiled dependencies' files and the ``NUMBA_*`` settings; a pool whose digest
differs (its sources were edited since it started) refuses, and the command says so and runs locally.

The pool exits after ``--idle-timeout`` seconds without a campaign (default :data:`IDLE_TIMEOUT_S`), on
``omnirotor workers stop``, or on SIGTERM; its workers die with it (parent-death signal). Its log is
``workers-ID.log`` beside the socket.

Protocol: one JSON object per line over the socket. The request is ``{"op": "status" | "stop" | "campaign",
"digest": ...}`` (a campaign adds ``cwd`` and ``args``, the command's options); a campaign's answer is
``refused`` (why), or ``start``, one ``run`` per finished run, then ``done`` (the summary) or ``error``.

This module imports only the standard library at its top: the command talks to the pool before, and instead of,
importing numpy, MuJoCo and numba.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import json
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from omnirotor.errors import InputError
from omnirotor.limits import MAX_WORKERS
from omnirotor.safe_io import note

__all__ = [
    "BACKENDS",
    "IDLE_TIMEOUT_S",
    "PoolStatus",
    "cache_dir",
    "pool_id",
    "source_digest",
    "socket_path",
    "pool_status",
    "start_pool",
    "stop_pool",
    "resident_campaign",
    "serve",
]

BACKENDS = ("local", "ray")
"""Backends of ``omnirotor campaign``: a process pool on this machine (the resident one when it runs), or Ray."""
IDLE_TIMEOUT_S = 1800.0
"""Default time the resident pool waits for a campaign before it exits [s]."""
MAX_IDLE_TIMEOUT_S = 7 * 86400.0
"""Longest idle timeout accepted [s]."""
START_TIMEOUT_S = 1800.0
"""How long ``workers start`` waits for the pool to be ready [s] (a fresh machine compiles the kernels first)."""
CONNECT_TIMEOUT_S = 2.0
"""A pool that does not answer a request within this time counts as not running [s]."""
STOP_TIMEOUT_S = 10.0
"""How long ``workers stop`` waits for the pool to exit before it is killed [s]."""
EXECUTOR_STOP_TIMEOUT_S = 5.0
"""How long a stopped process pool's manager thread gets to close its pipes [s]."""

_DIGEST_MODULES = ("numpy", "numba", "mujoco", "llvmlite")
"""Compiled dependencies whose installed files enter the digest (a reinstall changes their time stamps)."""
_SOCKET_MAX = 104
"""Longest Unix socket path used (the kernel's limit is 107 bytes on Linux, 103 on macOS)."""


# -- identity ----------------------------------------------------------------------------------------------------


def stop_executor(executor: Any, kill: bool = True) -> None:
    """Stop a process pool at once: kill its workers, cancel what waits, let its manager thread end.

    ``kill`` kills the workers' processes first (runs under way stop now); the manager thread gets
    :data:`EXECUTOR_STOP_TIMEOUT_S`.

    The wait matters at exit. Python 3.11's exit hook wakes each live manager thread through a pipe that the thread
    closes itself as it winds down; a Ctrl-C landing between the two printed ``OSError: Bad file descriptor`` under
    the one-line message. Once the thread has ended the hook has nothing to wake.
    """
    if kill:
        for proc in list((getattr(executor, "_processes", None) or {}).values()):
            with contextlib.suppress(Exception):
                proc.kill()
    manager = getattr(executor, "_executor_manager_thread", None)  # shutdown() forgets it
    executor.shutdown(wait=False, cancel_futures=True)
    if manager is not None and manager is not threading.current_thread():
        manager.join(EXECUTOR_STOP_TIMEOUT_S)


def _package_dir() -> Path:
    return Path(__file__).resolve().parent.parent


def cache_dir() -> Path:
    """The user's cache folder of omnirotor (``$XDG_CACHE_HOME/omnirotor``, else ``~/.cache/omnirotor``)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "omnirotor"


def pool_id() -> str:
    """Identifier of this checkout's pool: a hash of the package folder and the interpreter."""
    return hashlib.sha256(f"{_package_dir()}\0{sys.executable}".encode()).hexdigest()[:12]


def socket_path() -> Path:
    """The Unix socket of this checkout's resident pool."""
    return cache_dir() / f"workers-{pool_id()}.sock"


def source_digest() -> str:
    """Hash of what a run's results depend on besides its job (see the module docstring); a few milliseconds."""
    h = hashlib.sha256()
    root = _package_dir()
    for folder, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")
        for name in sorted(files):
            if name.endswith((".py", ".toml", ".json", ".csv", ".xml")):
                path = os.path.join(folder, name)
                h.update(os.path.relpath(path, root).encode() + b"\0")
                with open(path, "rb") as f:
                    h.update(hashlib.sha256(f.read()).digest())
    h.update(f"{sys.executable}\0{sys.version}\0".encode())
    for name in _DIGEST_MODULES:
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.origin:
            st = os.stat(spec.origin)
            h.update(f"{name}\0{spec.origin}\0{st.st_mtime_ns}\0{st.st_size}\0".encode())
    for key in sorted(k for k in os.environ if k.startswith("NUMBA_")):
        h.update(f"{key}={os.environ[key]}\0".encode())
    return h.hexdigest()[:16]


# -- client side -------------------------------------------------------------------------------------------------


class PoolStatus(dict):
    """The pool's answer to ``status`` (``pid``, ``state``, ``workers``, ``digest``, ...).

    Plus ``current``: whether its digest is this process's (it would serve this process).
    """


def _connect(path: Path, timeout: float | None = CONNECT_TIMEOUT_S) -> socket.socket | None:
    """A connection to the pool's socket, or None when nobody listens there."""
    if not path.exists():
        return None
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(timeout)
    try:
        s.connect(str(path))
    except OSError:
        s.close()
        return None
    return s


def _send(f, obj: dict) -> None:
    f.write((json.dumps(obj, separators=(",", ":")) + "\n").encode())
    f.flush()


def _recv(f) -> dict | None:
    line = f.readline()
    return json.loads(line) if line else None


def _ask(op: str, path: Path | None = None, timeout: float = CONNECT_TIMEOUT_S) -> dict | None:
    """One request and its one answer (None: no pool answers)."""
    s = _connect(path or socket_path(), timeout)
    if s is None:
        return None
    with s, s.makefile("rwb") as f:
        try:
            _send(f, {"op": op})
            return _recv(f)
        except (OSError, ValueError):
            return None


def pool_status() -> PoolStatus | None:
    """The running pool's status, or None when none answers on :func:`socket_path`."""
    answer = _ask("status")
    if answer is None:
        return None
    out = PoolStatus(answer)
    out["current"] = answer.get("digest") == source_digest()
    return out


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    with contextlib.suppress(OSError):  # a zombie (our own child not yet reaped) is gone
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    return True


def stop_pool(timeout_s: float = STOP_TIMEOUT_S) -> int | None:
    """Stop the running pool (asked, then killed if it does not exit in time); its pid, or None if none ran."""
    path = socket_path()
    st = _ask("status", path)
    if st is None:
        with contextlib.suppress(FileNotFoundError):  # a socket file nobody listens on: left by a killed pool
            if _connect(path) is None:
                path.unlink()
        return None
    pid = int(st["pid"])
    _ask("stop", path)
    deadline = time.monotonic() + timeout_s
    while _pid_alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    for sig in (signal.SIGTERM, signal.SIGKILL):
        if not _pid_alive(pid):
            break
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, sig)
        time.sleep(0.5)
    return pid


def start_pool(workers: int, idle_timeout_s: float, warm: bool = True, wait: bool = True) -> PoolStatus:
    """Start this checkout's resident pool in the background (replacing one started from other sources).

    Args:
        workers: worker processes.
        idle_timeout_s: exit after this long without a campaign [s].
        warm: load the kernels now (else on the first campaign).
        wait: return once the pool is ready (else once it answers).

    Returns:
        The pool's status (``already`` is True when a current pool was running already).

    Raises:
        InputError: bad arguments, a socket path too long, or a pool that failed to start (its log's last line).
    """
    if not 1 <= workers <= MAX_WORKERS:
        raise InputError(f"--workers must be in 1..{MAX_WORKERS}, got {workers}")
    if not 1.0 <= idle_timeout_s <= MAX_IDLE_TIMEOUT_S:
        raise InputError(f"--idle-timeout must be in [1, {MAX_IDLE_TIMEOUT_S:g}] s, got {idle_timeout_s:g}")
    path = socket_path()
    if len(os.fsencode(path)) > _SOCKET_MAX:
        raise InputError(f"{path}: socket path longer than {_SOCKET_MAX} bytes (set XDG_CACHE_HOME to a shorter one)")
    st = pool_status()
    if st is not None and st["current"]:
        st["already"] = True
        return st
    if st is not None:
        note(f"stopping the resident pool started from other sources (pid {st['pid']})")
        stop_pool()
    folder = path.parent
    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    os.chmod(folder, 0o700)
    log = path.with_suffix(".log")
    entry = "import sys; from omnirotor.experiments.campaign_pool import _main; sys.exit(_main(sys.argv[1:]))"
    cmd = [sys.executable, "-c", entry, "--serve", str(workers), str(idle_timeout_s)]
    cmd += [] if warm else ["--lazy"]
    with open(log, "ab") as out:
        proc = subprocess.Popen(
            cmd, stdin=subprocess.DEVNULL, stdout=out, stderr=out, start_new_session=True, close_fds=True
        )
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        st = pool_status()
        if st is not None and st.get("pid") == proc.pid and (not wait or st.get("state") == "ready"):
            st["already"] = False
            return st
        code = proc.poll()
        if code is not None:
            tail = log.read_text(errors="replace").strip().splitlines()[-1:] if log.exists() else []
            raise InputError(f"the resident pool exited ({code}) while starting: {' '.join(tail) or 'no log'}")
        if time.monotonic() > deadline:
            proc.kill()
            raise InputError(f"the resident pool was not ready in {START_TIMEOUT_S:g} s (see {log})")
        time.sleep(0.05)


class _Campaign:
    """A campaign handed to the pool: its ``start`` message, then the iterator of its ``run`` messages."""

    def __init__(self, sock: socket.socket, f, start: dict) -> None:
        self._sock, self._f, self.start = sock, f, start
        self.result: dict | None = None

    def runs(self) -> Iterator[dict]:
        """Each finished run's message; then :attr:`result` holds the ``done`` or ``error`` message."""
        while True:
            msg = _recv(self._f)
            if msg is None:
                raise InputError("the resident pool stopped during the campaign (the finished runs are kept)")
            if msg["type"] == "run":
                yield msg
            else:
                self.result = msg
                return

    def close(self) -> None:
        """Hang up (the pool then stops the campaign's runs not yet started)."""
        with contextlib.suppress(OSError):
            self._f.close()
            self._sock.close()


def resident_campaign(args: dict[str, Any], workers: int | None) -> _Campaign | None:
    """Hand a campaign to the running pool; None (after saying why on stderr) when it cannot take it.

    Args:
        args: the command's options (``task``, ``runs``, ``quick``, ``out``, ``campaign_file``, ``map_mode``,
            ``maps``, ``seed``, ``restart``), resolved by the pool in this process's working folder.
        workers: runs in parallel (None: all the pool's workers).

    Raises:
        InputError: the pool found the options bad (the same message as the command's own checks).
    """
    path = socket_path()
    s = _connect(path)
    if s is None:
        return None
    s.settimeout(None)  # the answer comes once the pool's workers are warm (after a worker died: a while)
    f = s.makefile("rwb")
    request = {"op": "campaign", "digest": source_digest(), "cwd": os.getcwd(), "args": args, "workers": workers}
    try:
        _send(f, request)
        first = _recv(f)
    except (OSError, ValueError):
        first = None
    if first is None or first.get("type") != "start":
        f.close()
        s.close()
        if first is not None and first.get("type") == "error":
            raise InputError(first["message"])
        why = (first or {}).get("why", "it did not answer")
        note(f"not using the resident worker pool ({why}); running a local pool")
        return None
    return _Campaign(s, f, first)


# -- the pool's process ------------------------------------------------------------------------------------------


def _cpu_s(pids: list[int]) -> float:
    """User + system CPU time of processes [s] (Linux ``/proc``; 0 for those gone)."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    for pid in pids:
        with contextlib.suppress(OSError, IndexError, ValueError):
            with open(f"/proc/{pid}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / tick
    return total


def _warm_jobs() -> list:
    """A hover and a sliding job of the default campaign (their runs load every kernel a campaign uses)."""
    from omnirotor.experiments.campaign import load_campaign, run_options

    return [run_options(load_campaign(None, task, quick=True), 0) for task in ("hover", "sliding")]


def _worker_init(parent_pid: int, close_fds: tuple[int, ...], ready, warm: bool) -> None:
    """Pool-worker initializer: die with the pool, load the kernels and matplotlib, then say ready."""
    from omnirotor.experiments.campaign import _die_with_parent, warm_up
    from omnirotor.experiments.campaign_report import warm_plots

    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _die_with_parent(parent_pid, close_fds)
    if warm:
        for job in _warm_jobs():
            warm_up(job)
        warm_plots()
    ready.put(os.getpid())


def _resident_run(cwd: str, out: str, job) -> dict:
    """Fly one job in a pool worker, in the command's working folder, MuJoCo's log into the campaign folder."""
    from omnirotor.experiments.campaign import execute_run
    from omnirotor.safe_io import route_mujoco_log

    os.chdir(cwd)
    route_mujoco_log(out)
    return execute_run(job)


class _HungUp(Exception):
    """The command hung up (Ctrl-C, or killed) while its campaign ran."""


class _Daemon:
    """The pool's process: its socket, its workers, one campaign at a time."""

    def __init__(self, server: socket.socket, fds: tuple[int, ...], workers: int, idle_timeout_s: float) -> None:
        self.server, self.fds, self.workers, self.idle_timeout_s = server, fds, workers, idle_timeout_s
        self.digest = source_digest()
        self.started = time.time()
        self.last_active = time.monotonic()
        self.state = "starting"
        self.executor = None
        self.worker_pids: list[int] = []
        self.campaign_lock = threading.Lock()
        self.pool_lock = threading.Lock()
        self.stopping = threading.Event()
        self.served = 0

    # the workers

    def ensure_pool(self, warm: bool = True) -> None:
        """Fork the workers and wait until each is warm (once; again after a worker died)."""
        with self.pool_lock:
            if self.executor is not None and not getattr(self.executor, "_broken", False):
                return
            import concurrent.futures as cf
            import multiprocessing as mp

            import omnirotor.experiments.campaign  # noqa: F401  (the workers inherit the imports)

            self.state = "starting"
            if self.executor is not None:
                stop_executor(self.executor, kill=False)
            ctx = mp.get_context("fork")
            ready = ctx.Queue()
            self.executor = cf.ProcessPoolExecutor(
                self.workers, mp_context=ctx, initializer=_worker_init, initargs=(os.getpid(), self.fds, ready, warm)
            )
            self.executor.submit(int, 0).result()  # forks all the workers (fork start method)
            pids: list[int] = []
            while len(pids) < self.workers:
                with contextlib.suppress(queue.Empty):
                    pids.append(ready.get(timeout=1.0))
                if getattr(self.executor, "_broken", False):
                    raise RuntimeError(f"a worker failed while warming up: {self.executor._broken}")
            self.worker_pids = sorted(pids)
            if source_digest() != self.digest:  # edited while this process imported them: trust neither
                self.digest = "sources-changed-while-starting"
            self.state = "ready"

    def status(self) -> dict:
        busy = self.campaign_lock.locked()
        return {
            "type": "status",
            "pid": os.getpid(),
            "state": self.state,
            "busy": busy,
            "workers": self.workers,
            "worker_pids": self.worker_pids,
            "digest": self.digest,
            "started": self.started,
            "idle_s": 0.0 if busy else time.monotonic() - self.last_active,
            "idle_timeout_s": self.idle_timeout_s,
            "campaigns_served": self.served,
            "cpu_s": _cpu_s([os.getpid(), *self.worker_pids]),
            "socket": str(socket_path()),
        }

    # requests

    def accept_loop(self) -> None:
        while not self.stopping.is_set():
            try:
                conn, _ = self.server.accept()
            except OSError:
                return
            threading.Thread(target=self.handle, args=(conn,), daemon=True).start()

    def handle(self, conn: socket.socket) -> None:
        # a command that hangs up (Ctrl-C) or sends nonsense is forgotten
        with conn, conn.makefile("rwb") as f, contextlib.suppress(OSError, ValueError):
            req = _recv(f)
            op = (req or {}).get("op")
            if op == "status":
                _send(f, self.status())
            elif op == "stop":
                _send(f, {"type": "stopping", "pid": os.getpid()})
                self.stopping.set()
            elif op == "campaign":
                self.campaign(f, req)

    def campaign(self, f, req: dict) -> None:
        if req.get("digest") != self.digest:
            _send(f, {"type": "refused", "why": f"it was started from other sources (pid {os.getpid()})"})
            return
        if not self.campaign_lock.acquire(blocking=False):
            _send(f, {"type": "refused", "why": f"it is busy with another campaign (pid {os.getpid()})"})
            return
        try:
            self.ensure_pool()
            if self.stopping.is_set():
                _send(f, {"type": "refused", "why": "it is stopping"})
                return
            self._run(f, req)
            self.served += 1
        finally:
            self.last_active = time.monotonic()
            self.campaign_lock.release()

    def _run(self, f, req: dict) -> None:
        """Run the campaign of ``req`` as ``omnirotor campaign`` would, streaming its runs into ``f``."""
        import functools

        from omnirotor.experiments.campaign import load_campaign, run_campaign
        from omnirotor.safe_io import check_output_dir

        args = req["args"]
        try:
            os.chdir(req["cwd"])
            spec = load_campaign(
                args.get("campaign_file"), args.get("task"), seed=args.get("seed"), maps=args.get("maps"),
                map=args.get("map_mode"), quick=args.get("quick") or None,
            )  # fmt: skip
            out = args.get("out")
            if out is None:
                name = Path(args["campaign_file"]).stem if args.get("campaign_file") else f"{spec.task}-default"
                out = str(Path("out") / "campaigns" / f"{name}-{spec.options.map}")
            check_output_dir(out, "--out")
        except InputError as exc:
            _send(f, {"type": "error", "kind": "input", "message": str(exc)})
            return
        except OSError as exc:
            _send(f, {"type": "error", "kind": "input", "message": f"{req['cwd']}: {exc.strerror}"})
            return
        workers = min(req.get("workers") or self.workers, self.workers)
        _send(f, {"type": "start", "task": spec.task, "map": spec.options.map, "runs": args.get("runs") or spec.runs,
                  "out": out, "workers": workers, "pid": os.getpid()})  # fmt: skip

        def progress(done: int, total: int, rec: dict | None) -> None:
            slim = None
            if rec is not None:
                duration = (rec.get("metrics") or {}).get("duration_s")
                slim = {"status": rec.get("status"), "success": rec.get("success"), "metrics": {"duration_s": duration}}
            try:
                _send(f, {"type": "run", "done": done, "total": total, "record": slim})
            except OSError as exc:
                raise _HungUp from exc

        try:
            summary = run_campaign(
                spec, out, runs=args.get("runs"), workers=workers, restart=bool(args.get("restart")),
                progress=progress, executor=self.executor,
                run_fn=functools.partial(_resident_run, os.getcwd(), str(Path(out).resolve())),
            )  # fmt: skip
        except InputError as exc:
            _send(f, {"type": "error", "kind": "input", "message": str(exc)})
            return
        except _HungUp:
            return  # the campaign stopped with the command (its finished runs are kept)
        except Exception as exc:  # a worker died, or a bug: say it, and give the next campaign fresh workers
            with contextlib.suppress(OSError, ValueError):
                _send(f, {"type": "error", "kind": "internal", "message": f"{type(exc).__name__}: {exc}"})
            stop_executor(self.executor, kill=False)
            self.executor = None
            return
        _send(f, {"type": "done", "summary": summary, "out": out})

    def shutdown(self) -> None:
        self.stopping.set()
        with contextlib.suppress(OSError):
            self.server.close()
        if self.executor is not None:
            stop_executor(self.executor)


def serve(workers: int, idle_timeout_s: float, warm: bool = True) -> int:
    """The resident pool's process (started by :func:`start_pool`); returns its exit status.

    Holds ``workers-ID.lock`` for its life (a second pool of the same checkout exits at once), listens on
    :func:`socket_path`, and exits on ``stop``, SIGTERM, or ``idle_timeout_s`` without a campaign.
    """
    import fcntl

    path = socket_path()
    sys.path[:] = [os.path.abspath(p) if p else p for p in sys.path]  # campaigns change the working folder
    lock_fd = os.open(path.with_suffix(".lock"), os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
    try:
        fcntl.flock(lock_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        print(f"omnirotor workers: another pool holds {path.with_suffix('.lock')}", file=sys.stderr)
        return 1
    os.ftruncate(lock_fd, 0)
    os.write(lock_fd, f"{os.getpid()}\n".encode())
    with contextlib.suppress(FileNotFoundError):
        path.unlink()  # left by a pool that was killed: the lock is ours, so nobody listens there
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(str(path))
    os.chmod(path, 0o600)
    inode = os.stat(path).st_ino
    server.listen(16)
    daemon = _Daemon(server, (server.fileno(), lock_fd), workers, idle_timeout_s)
    signal.signal(signal.SIGTERM, lambda *_: daemon.stopping.set())
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=daemon.accept_loop, name="omnirotor-workers-accept", daemon=True).start()
    print(f"omnirotor workers: pid {os.getpid()} listening on {path}", file=sys.stderr, flush=True)
    try:
        if warm:
            tic = time.perf_counter()
            daemon.ensure_pool()
            print(f"omnirotor workers: {workers} workers warm in {time.perf_counter() - tic:.1f} s", file=sys.stderr)
        else:
            daemon.state = "ready"
        while not daemon.stopping.wait(0.2):
            idle = not daemon.campaign_lock.locked() and time.monotonic() - daemon.last_active > idle_timeout_s
            if idle:
                print(f"omnirotor workers: idle for {idle_timeout_s:g} s, exiting", file=sys.stderr)
                break
    finally:
        with contextlib.suppress(OSError):
            if os.stat(path).st_ino == inode:  # not a newer pool's
                path.unlink()
        daemon.shutdown()
        print(f"omnirotor workers: pid {os.getpid()} stopped", file=sys.stderr, flush=True)
    return 0


def _main(argv: list[str]) -> int:
    if len(argv) >= 3 and argv[0] == "--serve":
        return serve(int(argv[1]), float(argv[2]), warm="--lazy" not in argv[3:])
    print("usage: omnirotor workers start|status|stop", file=sys.stderr)
    return 2
