"""Real-time scheduling of a periodic loop's thread: CPU affinity, ``SCHED_FIFO``, the garbage collector held.

One module for the three real-time processes on the flight topics: the flight node's loop
(:mod:`omnirotor.fly.node`), the simulator's real-time plant (:mod:`omnirotor.sitl.server`, ``omnirotor sim
--serve``) and the PX4 bridge (:mod:`omnirotor.fly.bridge`). It sits on the package's ground floor and imports
nothing of it (docs/architecture.md), so that the bridge and the simulator take it without the controller.

* :func:`set_realtime` asks the OS for CPU affinity and ``SCHED_FIFO`` for the calling thread; where the OS refuses
  (no ``CAP_SYS_NICE`` or ``rtprio`` limit, a CPU outside the process's set, another OS), the refusal is said in one
  line and the loop runs on at normal priority: the caller decides whether that is acceptable (it is for a bench
  or a SITL run; on a robot, the checklist in docs/fly.md asks to see no such line).
* :func:`set_transport_priority` gives every other thread of the process (the transport's: Zenoh's runtime threads
  and the session's waker) ``SCHED_FIFO`` at a priority below the loop's, as real-time ROS 2 and PX4 set-ups place
  their middleware's threads: a frame is then not held in a normal-priority thread behind the machine's other work
  before it reaches the loop (docs/transport.md, "The transport's threads").
* :func:`freeze_gc` / :func:`thaw_gc` (or :func:`frozen_gc` around a block): the objects alive when a loop starts
  are moved out of the collector's reach and the collector is disabled, so that no collection pauses a period.
  The loops allocate no reference cycles per period; objects freed by reference counting are freed as always.
"""

from __future__ import annotations

import contextlib
import gc
import os
import threading
from collections.abc import Callable, Iterator

__all__ = ["set_realtime", "set_transport_priority", "freeze_gc", "thaw_gc", "frozen_gc", "FIFO_PRIORITY_MAX"]

FIFO_PRIORITY_MAX = 99
"""The largest ``SCHED_FIFO`` priority Linux accepts (1 is the lowest; 0 means: do not ask)."""


def set_realtime(cpu: int | None, priority: int | None, say: Callable[[str], None]) -> None:
    """Ask for CPU affinity (``cpu``) and ``SCHED_FIFO`` at ``priority`` for the calling thread; refusals are said.

    Threads the caller starts afterwards inherit both (Linux: a new thread copies its creator's policy and
    affinity); threads started before keep theirs. Call it after the transport is open, so that the transport's
    own threads keep their CPUs and their normal priority.

    Args:
        cpu: the CPU to pin the thread to; None: the OS's choice.
        priority: the ``SCHED_FIFO`` priority (1-99); None: not asked.
        say: where a refusal is said (one line each).
    """
    if cpu is not None:
        try:
            os.sched_setaffinity(0, {cpu})
        except (OSError, AttributeError, ValueError) as exc:
            say(f"CPU affinity to CPU {cpu} not permitted ({exc.__class__.__name__}): the OS schedules the loop")
    if priority is not None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except (OSError, AttributeError) as exc:
            why = "needs CAP_SYS_NICE or an rtprio limit" if isinstance(exc, PermissionError) else str(exc)
            say(f"SCHED_FIFO not permitted ({why}): the loop runs at normal priority")


def set_transport_priority(priority: int | None, say: Callable[[str], None]) -> int:
    """Ask for ``SCHED_FIFO`` at ``priority`` for every thread of this process but the caller's (the loop's).

    Called once from the loop's thread, after the transport is open and its publishers and subscribers declared:
    the threads then alive are Zenoh's runtime threads (``app``, ``net``, ``acc``, ``tx``, ``rx``, and the one a
    publisher's declaration starts), the session's waker and whatever else the command started (a recording's
    writer, the live view's server). Threads created afterwards inherit their creator's policy (Linux copies it
    into a new thread; checked with Zenoh 1.10: the ``tx``/``rx``/``acc`` threads it starts when a peer connects come
    at the priority given here, since Zenoh's own threads start them), except those the loop's thread starts, which
    take the loop's. No thread watches for new ones.

    Args:
        priority: the ``SCHED_FIFO`` priority (1-99, below the loop's); None: not asked.
        say: where a refusal is said (one line).

    Returns:
        How many threads were given the priority.
    """
    if priority is None:
        return 0
    me = threading.get_native_id()
    try:
        tids = sorted(int(t) for t in os.listdir("/proc/self/task"))
    except OSError as exc:  # no /proc (another OS)
        say(f"the transport's threads cannot be listed ({exc.__class__.__name__}): they run at normal priority")
        return 0
    given = 0
    for tid in tids:
        if tid == me:
            continue
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
        except ProcessLookupError:  # the thread ended meanwhile
            continue
        except (OSError, AttributeError) as exc:
            why = "needs CAP_SYS_NICE or an rtprio limit" if isinstance(exc, PermissionError) else str(exc)
            say(f"SCHED_FIFO for the transport's threads not permitted ({why}): they run at normal priority")
            return given
        given += 1
    return given


def freeze_gc() -> None:
    """Collect now, move every live object out of the collector's reach, and disable it (a loop starts)."""
    gc.collect()
    gc.freeze()
    gc.disable()


def thaw_gc() -> None:
    """Undo :func:`freeze_gc` (the loop ended)."""
    gc.enable()
    gc.unfreeze()


@contextlib.contextmanager
def frozen_gc() -> Iterator[None]:
    """:func:`freeze_gc` for the block, :func:`thaw_gc` after it (however it ends)."""
    freeze_gc()
    try:
        yield
    finally:
        thaw_gc()
