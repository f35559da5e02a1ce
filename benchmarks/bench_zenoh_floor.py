"""The floor under the flight transport: a bare Python-to-Python round trip through Zenoh (issue 24, item 5).

``python benchmarks/bench_zenoh_floor.py [--n 5000] [--json]``: two processes on loopback, nothing computed. The
*pinger* (the simulator's role) puts a 320-byte payload every millisecond on the wall clock and takes the answer;
the *ponger* (the node's role) answers each payload with one of its own. Each receive mode of the ponger, and the
link (TCP or a Unix socket), express or not, is measured in turn, interleaved, the same way; the round trip is
seen by the pinger (put -> answer taken), which is what the simulator's ``round_trip_us`` measures in the SITL.

Receive modes (the ponger's; the pinger always sleeps in a queue fed by Zenoh's callback, as the simulator does):

* ``callback``: Zenoh's thread runs a Python callback that hands the payload to a queue the ponger sleeps on (the
  node's receive up to this session: two Python wake-ups per frame);
* ``channel``: the ponger sleeps in ``recv`` of Zenoh's own ring channel (one wake-up, no Python in Zenoh's
  thread);
* ``spin``: the ponger spins on the channel's ``try_recv`` from 150 µs before the payload is due (a short,
  bounded spin; then it waits in ``recv``).

What it shows: the receive path's own share of the round trip, before any message is decoded or any controller
stepped. Never part of the test suite.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import socket
import subprocess
import sys
import tempfile
import time

PAYLOAD = 320
PERIOD_S = 0.001
SPIN_S = 150e-6
MODES = ("callback", "channel", "spin")
_KEEP: list = []


def _session(listen: str | None, connect: str | None):
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([listen] if listen else []))
    conf.insert_json5("connect/endpoints", json.dumps([connect] if connect else []))
    return zenoh.open(conf)


def _receiver(session, key: str, mode: str):
    """``wait(due) -> bytes``: the next payload on ``key`` by the receive ``mode`` (module docstring)."""
    import zenoh

    if mode == "callback":
        q: queue.SimpleQueue = queue.SimpleQueue()
        _KEEP.append(session.declare_subscriber(key, lambda s: q.put(s.payload.to_bytes())))

        def get(due: float) -> bytes | None:
            try:
                return q.get(timeout=0.2)
            except queue.Empty:  # a payload dropped on the way (congestion control DROP): counted lost
                return None

        return get
    sub = session.declare_subscriber(key, zenoh.handlers.RingChannel(16))
    _KEEP.append(sub)  # a subscriber collected is undeclared, its ring deleted
    rx = sub.handler
    if mode == "channel":
        return lambda due: rx.recv().payload.to_bytes()

    def spin(due: float) -> bytes:
        mono, try_recv = time.monotonic, rx.try_recv
        left = due - SPIN_S - mono()
        if left > 0:
            time.sleep(left)
        end = due + SPIN_S
        while mono() < end:
            s = try_recv()
            if s is not None:
                return s.payload.to_bytes()
        return rx.recv().payload.to_bytes()

    return spin


def peer(role: str, mode: str, endpoint: str, express: bool, n: int) -> None:
    """One side of the ping-pong (``role`` ``ping`` listens, ``pong`` connects); the pinger prints its figures."""
    import numpy as np
    import zenoh

    s = _session(endpoint if role == "ping" else None, endpoint if role == "pong" else None)
    mine, theirs = ("floor/ping", "floor/pong") if role == "ping" else ("floor/pong", "floor/ping")
    pub = s.declare_publisher(mine, congestion_control=zenoh.CongestionControl.DROP,
                              priority=zenoh.Priority.REAL_TIME, express=express)  # fmt: skip
    wait = _receiver(s, theirs, "callback" if role == "ping" else mode)
    payload = bytes(PAYLOAD)
    time.sleep(1.0)  # the peers' declarations
    if role == "pong":
        last = time.monotonic()
        while (got := wait(last + PERIOD_S)) != b"end":
            last = time.monotonic()
            if got is not None:
                pub.put(payload)
        s.close()
        return
    rtt = np.zeros(n)
    cpu0 = time.process_time()
    t0 = time.monotonic()
    for k in range(n):
        due = t0 + k * PERIOD_S
        left = due - time.monotonic()
        if left > 0:
            time.sleep(left)
        sent = time.monotonic()
        pub.put(payload)
        rtt[k] = time.monotonic() - sent if wait(0.0) is not None else np.nan
    cpu = time.process_time() - cpu0
    for _ in range(3):
        pub.put(b"end")
        time.sleep(0.01)
    r = 1e6 * rtt[n // 10 :]
    lost = int(np.isnan(r).sum())
    r = r[~np.isnan(r)]
    p50, p99 = np.percentile(r, [50, 99])
    print(json.dumps({"p50": float(p50), "p99": float(p99), "max": float(r.max()), "over_500us": int((r > 500).sum()),
                      "n": int(r.size), "lost": lost, "pinger_cpu_us": 1e6 * cpu / n}))  # fmt: skip
    s.close()


def _free_endpoint(link: str, tmp: str) -> str:
    if link == "unix":
        return f"unixsock-stream/{tempfile.mktemp(dir=tmp, suffix='.sock')}"
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{sock.getsockname()[1]}"


def one(mode: str, link: str, express: bool, n: int, tmp: str) -> dict:
    """The pinger's figures for one configuration."""
    ep = _free_endpoint(link, tmp)
    args = [mode, ep, "1" if express else "0", str(n)]
    pong = subprocess.Popen([sys.executable, __file__, "--peer", "pong", *args])
    try:
        out = subprocess.run([sys.executable, __file__, "--peer", "ping", *args], capture_output=True, text=True,
                             timeout=120, check=True).stdout  # fmt: skip
    finally:
        pong.wait(timeout=10) if pong.poll() is None else None
        if pong.poll() is None:
            pong.kill()
    return json.loads(out.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    """Command line (module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer", nargs=5, help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, default=5000, help="round trips per configuration (1 per ms)")
    ap.add_argument("--rounds", type=int, default=2, help="interleaved repetitions of every configuration")
    ap.add_argument("--modes", default=",".join(MODES), help="receive modes to measure, comma-separated")
    ap.add_argument("--links", default="tcp,unix", help="links to measure, comma-separated (tcp, unix)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    if args.peer:
        role, mode, ep, express, n = args.peer
        peer(role, mode, ep, express == "1", int(n))
        return 0
    out = {"load_before": os.getloadavg(), "cpus": os.cpu_count(), "runs": []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for link in args.links.split(","):
                for mode in args.modes.split(","):
                    res = one(mode, link, True, args.n, tmp)
                    res.update(mode=mode, link=link, round=r)
                    out["runs"].append(res)
                    print(f"{link:4s} {mode:8s} p50 {res['p50']:6.0f}  p99 {res['p99']:6.0f}  max {res['max']:7.0f} µs"
                          f"  >0.5 ms {res['over_500us']}/{res['n']}  lost {res['lost']}", file=sys.stderr)  # fmt: skip
    out["load_after"] = os.getloadavg()
    if args.json:
        print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
