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

Also measured, each the same way: the *placement* of the two processes (``--placements``: unpinned, one per core,
both on one core), Zenoh *tunings* of the session (``--tunings``: the defaults; tx batching off; Zenoh's
``lowlatency`` transport, QoS off), and, as the operating system's own floor, the same paced ping-pong through a
pair of pipes between two Python processes (``--pipe``: no Zenoh, same pacing, same payload).

What it shows: the receive path's own share of the round trip, before any message is decoded or any controller
stepped; and whether the rest is the machine's or Zenoh's. Never part of the test suite.
"""

from __future__ import annotations

import argparse
import itertools
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
TUNINGS = {  # name -> Zenoh configuration paths and JSON5 values set on both sessions
    "default": {},
    "nobatch": {"transport/link/tx/queue/batching/enabled": "false"},
    "lowlatency": {"transport/unicast/lowlatency": "true", "transport/unicast/qos/enabled": "false"},
}


def _session(listen: str | None, connect: str | None, tuning: str = "default"):
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([listen] if listen else []))
    conf.insert_json5("connect/endpoints", json.dumps([connect] if connect else []))
    for path, value in TUNINGS[tuning].items():
        conf.insert_json5(path, value)
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


def peer(role: str, mode: str, endpoint: str, express: bool, n: int, tuning: str = "default") -> None:
    """One side of the ping-pong (``role`` ``ping`` listens, ``pong`` connects); the pinger prints its figures."""
    import numpy as np
    import zenoh

    s = _session(endpoint if role == "ping" else None, endpoint if role == "pong" else None, tuning)
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
    print(json.dumps(_figures(rtt, cpu, n)))
    s.close()


def _free_endpoint(link: str, tmp: str) -> str:
    if link == "unix":
        return f"unixsock-stream/{tempfile.mktemp(dir=tmp, suffix='.sock')}"
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{sock.getsockname()[1]}"


PLACEMENTS = {"free": (None, None), "split": ({0}, {1}), "same": ({0}, {0})}
"""Where the pinger and the ponger run (their CPU sets, every thread included): unpinned, on two cores, on one."""


def _pinned(cpus: set[int] | None):
    return None if cpus is None else (lambda: os.sched_setaffinity(0, cpus))


def _figures(rtt_s, cpu_s: float, n: int) -> dict:
    """p50, p99, max, round trips over 0.5 ms and lost ones of the round trips ``rtt_s`` (NaN: lost), the first
    tenth (the warm-up) left out."""
    import numpy as np

    r = 1e6 * np.asarray(rtt_s)[n // 10 :]
    lost = int(np.isnan(r).sum())
    r = r[~np.isnan(r)]
    p50, p99 = np.percentile(r, [50, 99])
    return {"p50": float(p50), "p99": float(p99), "max": float(r.max()), "over_500us": int((r > 500).sum()),
            "n": int(r.size), "lost": lost, "pinger_cpu_us": 1e6 * cpu_s / n}  # fmt: skip


def pipe_floor(n: int, placement: str = "free") -> dict:
    """The same paced ping-pong through two pipes between this process's child and a forked one (no Zenoh)."""
    import numpy as np

    ping_cpus, pong_cpus = PLACEMENTS[placement]
    pong_in, ping_out = os.pipe()
    ping_in, pong_out = os.pipe()
    child = os.fork()
    if child == 0:  # the ponger: answer each payload with one of its own, until end-of-file
        os.close(ping_out)
        os.close(ping_in)
        if pong_cpus is not None:
            os.sched_setaffinity(0, pong_cpus)
        while payload := os.read(pong_in, PAYLOAD):
            os.write(pong_out, payload)
        os._exit(0)
    os.close(pong_in)
    os.close(pong_out)
    mask = os.sched_getaffinity(0)
    if ping_cpus is not None:
        os.sched_setaffinity(0, ping_cpus)
    payload, rtt = bytes(PAYLOAD), np.zeros(n)
    cpu0, t0 = time.process_time(), time.monotonic()
    for k in range(n):
        left = t0 + k * PERIOD_S - time.monotonic()
        if left > 0:
            time.sleep(left)
        sent = time.monotonic()
        os.write(ping_out, payload)
        os.read(ping_in, PAYLOAD)
        rtt[k] = time.monotonic() - sent
    cpu = time.process_time() - cpu0
    os.sched_setaffinity(0, mask)
    os.close(ping_out)  # the ponger reads end-of-file and leaves
    os.waitpid(child, 0)
    os.close(ping_in)
    return _figures(rtt, cpu, n)


def one(mode: str, link: str, express: bool, n: int, tmp: str, placement: str = "free", tuning: str = "default"):
    """The pinger's figures for one configuration."""
    ep = _free_endpoint(link, tmp)
    args = [mode, ep, "1" if express else "0", str(n), tuning]
    ping_cpus, pong_cpus = PLACEMENTS[placement]
    pong = subprocess.Popen([sys.executable, __file__, "--peer", "pong", *args], preexec_fn=_pinned(pong_cpus))
    try:
        out = subprocess.run([sys.executable, __file__, "--peer", "ping", *args], capture_output=True, text=True,
                             timeout=120, check=True, preexec_fn=_pinned(ping_cpus)).stdout  # fmt: skip
    finally:
        pong.wait(timeout=10) if pong.poll() is None else None
        if pong.poll() is None:
            pong.kill()
    return json.loads(out.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    """Command line (module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer", nargs=6, help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, default=5000, help="round trips per configuration (1 per ms)")
    ap.add_argument("--rounds", type=int, default=2, help="interleaved repetitions of every configuration")
    ap.add_argument("--modes", default=",".join(MODES), help="receive modes to measure, comma-separated")
    ap.add_argument("--links", default="tcp,unix", help="links to measure, comma-separated (tcp, unix)")
    ap.add_argument("--placements", default="free", help="CPU placements to measure, comma-separated "
                    "(free: unpinned; split: pinger on CPU 0, ponger on CPU 1; same: both on CPU 0)")  # fmt: skip
    ap.add_argument("--tunings", default="default", help="Zenoh tunings to measure, comma-separated "
                    f"({', '.join(TUNINGS)})")  # fmt: skip
    ap.add_argument("--pipe", action="store_true", help="also measure the same ping-pong through OS pipes")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    if args.peer:
        role, mode, ep, express, n, tuning = args.peer
        peer(role, mode, ep, express == "1", int(n), tuning)
        return 0
    for name, known in (("placements", PLACEMENTS), ("tunings", TUNINGS), ("modes", MODES)):
        if unknown := set(getattr(args, name).split(",")) - set(known):
            ap.error(f"unknown {name}: {', '.join(sorted(unknown))} (known: {', '.join(known)})")
    if (os.cpu_count() or 1) < 2 and {"split"} & set(args.placements.split(",")):
        ap.error("the split placement needs two CPUs")
    out = {"load_before": os.getloadavg(), "cpus": os.cpu_count(), "runs": []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            grid = itertools.product(args.placements.split(","), args.tunings.split(","), args.links.split(","),
                                     args.modes.split(","))  # fmt: skip
            runs = [(p, "pipe", "os", "-") for p in args.placements.split(",")] if args.pipe else []
            for place, tuning, link, mode in [*runs, *grid]:
                if link == "os":
                    res = pipe_floor(args.n, place)
                else:
                    res = one(mode, link, True, args.n, tmp, place, tuning)
                res.update(mode=mode, link=link, placement=place, tuning=tuning, round=r)
                out["runs"].append(res)
                print(f"{place:5s} {tuning:10s} {link:4s} {mode:8s} p50 {res['p50']:6.0f}  p99 {res['p99']:6.0f}  "
                      f"max {res['max']:7.0f} µs  >0.5 ms {res['over_500us']}/{res['n']}  lost {res['lost']}",
                      file=sys.stderr)  # fmt: skip
    out["load_after"] = os.getloadavg()
    if args.json:
        print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
