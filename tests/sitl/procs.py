"""Spawning the simulator and the flight node as real processes on loopback, for the wire's tests.

Every test gets free ports and its own namespace, every wait is bounded, and children are killed on failure.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CLI = "import sys; from omnirotor.cli import main; sys.argv[0] = 'omnirotor'; main()"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def env() -> dict:
    e = dict(os.environ)
    e["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), str(ROOT)] + ([e["PYTHONPATH"]] if "PYTHONPATH" in e else []))
    e.setdefault("MUJOCO_GL", "egl")
    return e


ZENOH_IO_THREADS = ("rx-", "tx-", "net-", "acc-")
"""Zenoh 1.10's I/O threads (reception, transmission, network, acceptor), by the names its runtimes give them."""


def fifo_permitted() -> bool:
    """Whether this process may take ``SCHED_FIFO`` (asked for a moment, then given back)."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except (OSError, AttributeError):
        return False
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return True


def threads_of(pid: int) -> dict[int, tuple[str, int, int]]:
    """``{tid: (name, policy, priority)}`` of a running process's threads (those ending meanwhile left out)."""
    out = {}
    for t in os.listdir(f"/proc/{pid}/task"):
        tid = int(t)
        try:
            with open(f"/proc/{pid}/task/{t}/comm") as f:
                name = f.read().strip()
            out[tid] = (name, os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority)
        except (ProcessLookupError, FileNotFoundError):
            continue
    return out


class Pair:
    """A simulator (``omnirotor sim --serve``) and a node on a fresh port and namespace."""

    def __init__(
        self,
        tmp: Path,
        task: str,
        sim_args: list[str],
        lockstep: bool,
        node_args: tuple[str, ...] = (),
        start_node: bool = True,
        cwd: Path | None = None,
        link: str = "tcp",
    ) -> None:
        self.port = free_port()
        self.namespace = f"/t{secrets.token_hex(4)}"
        self.endpoint = f"{link}/127.0.0.1:{self.port}"
        self.tmp = tmp
        self.out = tmp / "sim-out"
        args = ["sim", "--serve", "--task", task, "--listen", self.endpoint, "--namespace", self.namespace, "--json"]
        args += ["--out", str(self.out), "--wait", "900"] + (["--lockstep"] if lockstep else ["--fifo-priority", "20"])
        args += sim_args
        self.sim_err = open(tmp / "sim.err", "w+")  # noqa: SIM115
        self.node_err = open(tmp / "node.err", "w+")  # noqa: SIM115
        self.cwd = cwd
        self.sim = subprocess.Popen(
            [sys.executable, "-c", CLI, *args], stdout=subprocess.PIPE, stderr=self.sim_err, env=env(), text=True,
            cwd=None if cwd is None else str(cwd),
        )  # fmt: skip
        self.node_endpoint = f"tcp/127.0.0.1:{free_port()}"
        self._node_cmd = [sys.executable, "-c", CLI, "fly", "--mission-from-sim", "--connect", self.endpoint,
                          "--listen", self.node_endpoint, "--namespace", self.namespace, "--json",
                          "--fifo-priority", "20" if not lockstep else "0", *node_args]  # fmt: skip
        self.node: subprocess.Popen | None = None
        if start_node:
            self.start_node()

    def start_node(self) -> None:
        """Start the node (at once unless the pair was made with ``start_node=False``)."""
        self.node = subprocess.Popen(
            self._node_cmd, stdout=subprocess.PIPE, stderr=self.node_err, env=env(), text=True,
            cwd=str(self.cwd or ROOT),
        )  # fmt: skip

    def plant_transport(self):
        """A session of the test's own, connected to the simulator only (the node may not be up yet)."""
        from omnirotor.transport import open_transport

        return open_transport(listen=[], connect=[self.endpoint], namespace=self.namespace)

    def transport(self):
        """A session of the test's own, connected to both processes."""
        from omnirotor.transport import open_transport

        return open_transport(listen=[], connect=[self.endpoint, self.node_endpoint], namespace=self.namespace)

    def wait(self, timeout_s: float, sim_ok: bool = True, node_ok: bool = True) -> tuple[dict | None, dict | None]:
        """Both processes' JSON (the simulator's run, the node's summary) after both exit (None if killed)."""
        try:
            sim_out, _ = self.sim.communicate(timeout=timeout_s)
            node_out, _ = self.node.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            self.kill()
            raise AssertionError(
                f"timed out; sim: {self.text('sim')[-2000:]}\nnode: {self.text('node')[-2000:]}"
            ) from None
        if sim_ok:
            assert self.sim.returncode == 0, self.text("sim")[-3000:]
        if node_ok:
            assert self.node.returncode == 0, self.text("node")[-3000:]
        sim_json = json.loads(sim_out) if sim_ok else None
        node_json = json.loads(node_out.strip().splitlines()[-1]) if node_ok else None
        return sim_json, node_json

    def until(self, fn, timeout_s: float, what: str):
        """``fn()``'s first truthy answer, asked while both processes run (:func:`wait_until`).

        Fails at once, with both processes' last words, when one of them exits first (a node that lost its link at
        the start and ended its mission, a simulator that refused its arguments), and at ``timeout_s`` with the
        same: a node whose last word is its mission line was still compiling or loading its kernels (a first run
        after a checkout compiles them here: a minute or more of CPU on each side).
        """
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            out = fn()
            if out:
                return out
            for name, proc in (("simulator", self.sim), ("node", self.node)):
                if proc is not None and proc.poll() is not None:
                    raise AssertionError(
                        f"{what}: the {name} exited first (status {proc.returncode})\n{self.last_words()}"
                    )
            time.sleep(0.005)
        raise AssertionError(f"{what}: not within {timeout_s:g} s\n{self.last_words()}")

    def last_words(self) -> str:
        """The end of both processes' stderr, for a failure's message."""
        return f"sim: {self.text('sim')[-2000:]}\nnode: {self.text('node')[-2000:]}"

    def text(self, which: str) -> str:
        f = self.sim_err if which == "sim" else self.node_err
        if not f.closed:
            f.flush()
        return Path(f.name).read_text()

    def kill(self) -> None:
        for p in (self.sim, self.node):
            if p is not None and p.poll() is None:
                p.kill()
                with contextlib.suppress(subprocess.TimeoutExpired):
                    p.wait(timeout=10)

    def __enter__(self) -> Pair:
        return self

    def __exit__(self, *exc) -> None:
        self.kill()
        self.sim_err.close()
        self.node_err.close()


def wait_until(fn, timeout_s: float, step_s: float = 0.005):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        out = fn()
        if out:
            return out
        time.sleep(step_s)
    return None
