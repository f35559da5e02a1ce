"""A flood of ``omnirotor ctl`` requests at a flying node: the node serves a bounded number, answers the rest busy.

Real processes (``omnirotor sim --serve`` and ``omnirotor fly --mission-from-sim``) over Zenoh on loopback, and
four client threads of the test sending ``status`` requests back to back while the node flies the hover. What is
asserted are counts: the node served at most its ``--ctl-rate`` a second (a slower machine serves fewer, never
more), answered every other request busy without handing it to its loop, and the client's counts and the node's
agree. How the flood costs the loop's deadlines is a speed: ``benchmarks/bench_transport.py`` (its ctl modes).
"""

from __future__ import annotations

import threading
import time

import pytest

from omnirotor.fly.requests import CTL_TOPIC, FlightReply, FlightRequest
from omnirotor.rosmsg.convert import LOOP_STATUS
from omnirotor.transport import open_transport
from sitl.procs import Pair

RATE_HZ = 5.0
"""The node's ``--ctl-rate`` in the test: few enough that the bound shows in counts whatever the machine's speed."""
CLIENTS = 4
FLOOD_S = 3.0


def _flood(endpoint: str, namespace: str, counts: dict, lock: threading.Lock, until: float) -> None:
    """One client: ``status`` requests back to back until ``until``, each reply counted."""
    req = FlightRequest("status").to_msg()
    with open_transport(listen=[], connect=[endpoint], namespace=namespace) as t:
        while time.monotonic() < until:
            raw = t.request(CTL_TOPIC, "omnirotor_msgs/msg/FlightRequest", req, "omnirotor_msgs/msg/FlightReply", 2.0)
            reply = None if raw is None else FlightReply.from_msg(raw)
            with lock:
                counts["sent"] += 1
                if reply is None:
                    counts["unanswered"] += 1
                elif reply.accepted:
                    counts["served"] += 1
                else:
                    counts["busy" if reply.message.startswith("busy") else "refused"] += 1


@pytest.mark.slow
def test_a_ctl_flood_is_served_within_the_nodes_rate_and_the_rest_answered_busy(tmp_path):
    args = ("--ctl-rate", f"{RATE_HZ:g}")
    with Pair(tmp_path, "hover", ["--seed", "3", "--duration", "8"], lockstep=False, node_args=args) as pair:
        with pair.transport() as t:
            loop = t.subscriber("/omnirotor/loop_status", LOOP_STATUS, depth=4)
            pair.until(lambda: (m := loop.take_latest()) is not None and m.frames >= 200, 300, "the node flying")
        counts = {"sent": 0, "served": 0, "busy": 0, "refused": 0, "unanswered": 0}
        lock = threading.Lock()
        started = time.monotonic()
        clients = [
            threading.Thread(target=_flood, args=(pair.node_endpoint, pair.namespace, counts, lock, started + FLOOD_S))
            for _ in range(CLIENTS)
        ]
        for c in clients:
            c.start()
        for c in clients:
            c.join(timeout=60)
        elapsed = time.monotonic() - started
        # the simulator's verdict is not asked: a loaded runner may lose the link (a 50 ms frame gap) and the plant's
        # failsafe then cuts the run (exit 1), a speed; the counts are the node's and the clients'
        _, node = pair.wait(timeout_s=600, sim_ok=False)
    req = node["requests"]
    assert req["rate_hz"] == RATE_HZ
    # the bound: one request taken in per 1 / rate (a slower machine takes in fewer), the rest answered busy at once
    assert 1 <= req["served"] <= RATE_HZ * elapsed + 1, (req, counts, elapsed)
    assert counts["busy"] > 10 * counts["served"], counts
    # what the clients counted is what the node counted: every busy reply came from the node's bound, every
    # accepted one from its loop; none refused (a status request is always accepted)
    assert counts["served"] == req["served"] and counts["busy"] == req["busy"], (req, counts)
    assert counts["refused"] == 0 and req["bad"] == 0
    # the node flew through it (how well is the machine's: bench_transport's ctl modes)
    assert node["frames"] >= 200 and node["commands"] > 0
