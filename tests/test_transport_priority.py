"""``--transport-priority`` with real processes: the transport's threads in ``SCHED_FIFO`` below the loop's.

A real-time hover (``omnirotor sim --serve`` + ``omnirotor fly --mission-from-sim``, both loops at
``--fifo-priority 20``), read from outside while the node flies: each process's threads' policy and priority from
``/proc/<pid>/task`` (``os.sched_getscheduler``, ``os.sched_getparam``). The loop is each process's main thread.
Asserts policies, not speed (the figures it buys are bench_transport's: BENCHMARKS.md).
"""

from __future__ import annotations

import os
import time

import pytest

from sitl.procs import ZENOH_IO_THREADS, Pair, fifo_permitted, threads_of

LOOP, TRANSPORT = 20, 10


pytestmark = pytest.mark.skipif(
    not fifo_permitted(), reason="SCHED_FIFO not permitted here (needs CAP_SYS_NICE or an rtprio limit)"
)


def _flying(transport):
    from omnirotor.rosmsg.convert import LOOP_STATUS

    sub = transport.subscriber("/omnirotor/loop_status", LOOP_STATUS, depth=4)
    return lambda: (m := sub.take_latest(0.05)) is not None and m.frames >= 200


@pytest.mark.parametrize("asked", [True, False], ids=["with", "without"])
def test_the_transports_threads_run_fifo_below_the_loop_only_when_asked(tmp_path, asked):
    extra = ["--transport-priority", str(TRANSPORT)] if asked else []
    pair = Pair(tmp_path, "hover", ["--duration", "6", *extra], lockstep=False, node_args=tuple(extra))
    try:
        with pair.transport() as t:
            pair.until(_flying(t), 600.0, "the node flying its mission")
            time.sleep(0.5)  # a peer's tx/rx threads come when it connects: the test's own session connected too
            seen = {"node": (pair.node.pid, threads_of(pair.node.pid)), "sim": (pair.sim.pid, threads_of(pair.sim.pid))}
        pair.wait(600.0)
    finally:
        pair.kill()
    for who, (pid, threads) in seen.items():
        assert threads[pid][1:] == (os.SCHED_FIFO, LOOP), (who, threads[pid])  # the loop: its own priority
        others = {tid: v for tid, v in threads.items() if tid != pid}
        # Zenoh's I/O threads: reception (rx, which fills the loop's frame channel), transmission, network, acceptor
        io = {tid: v for tid, v in others.items() if v[0].startswith(ZENOH_IO_THREADS)}
        assert any(v[0].startswith("rx-") for v in io.values()), (who, others)
        want = (os.SCHED_FIFO, TRANSPORT) if asked else (os.SCHED_OTHER, 0)
        assert all(v[1:] == want for v in io.values()), (who, want, io)
        assert all(v[2] <= LOOP for v in others.values()), (who, others)  # none above the loop
        if asked:  # none left at normal priority (those the loop's thread started later have the loop's)
            assert all(v[1] == os.SCHED_FIFO for v in others.values()), (who, others)
