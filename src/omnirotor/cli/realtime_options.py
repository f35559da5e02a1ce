"""The real-time options of the commands with a periodic loop: ``fly``, ``sim --serve``, ``px4-bridge``.

Each command declares ``--cpu``, ``--fifo-priority`` and ``--transport-priority`` with these types (its own
defaults named in their help), checks them with :func:`check_realtime_options` before it opens anything (one line
and exit status 2), and hands them to :func:`omnirotor.realtime.set_realtime` and
:func:`omnirotor.realtime.set_transport_priority` once its transport is open.
"""

from __future__ import annotations

import os
from typing import Annotated

import typer

from omnirotor.errors import InputError
from omnirotor.realtime import FIFO_PRIORITY_MAX


def cpu_option(default: str = "the OS's choice") -> type:
    """``--cpu``: the CPU the loop is pinned to; ``default`` says the command's own (when the option is not given)."""
    return Annotated[int | None, typer.Option(help=f"Pin the loop to this CPU (default: {default}).")]


def fifo_priority_option(what: str = "the loop") -> type:
    """``--fifo-priority``: ``SCHED_FIFO`` priority of ``what`` (0: do not ask)."""
    return Annotated[int, typer.Option(help=f"SCHED_FIFO priority of {what}, 1-{FIFO_PRIORITY_MAX} (0: do not ask).")]


def transport_priority_option() -> type:
    """``--transport-priority``: ``SCHED_FIFO`` priority of the process's other threads (Zenoh's), below the loop's."""
    return Annotated[
        int,
        typer.Option(
            help="SCHED_FIFO priority of the transport's threads (Zenoh's), below --fifo-priority (0: do not ask).",
        ),
    ]


def n_cpus() -> int:
    """The CPUs ``--cpu`` may name (0 to this minus one)."""
    return os.cpu_count() or 1


def check_realtime_options(cpu: int | None, fifo_priority: int, transport_priority: int = 0) -> None:
    """``--cpu`` within this machine's CPUs, ``--fifo-priority`` within 0-99, ``--transport-priority`` below it.

    A transport's thread at or above the loop's priority could hold the loop; with the loop at normal priority
    (``--fifo-priority 0``) any ``SCHED_FIFO`` thread is above it.

    Raises:
        InputError: either is out of range (one line; the CLI exits with status 2).
    """
    if not 0 <= fifo_priority <= FIFO_PRIORITY_MAX:
        raise InputError(f"--fifo-priority must be in 0..{FIFO_PRIORITY_MAX}, got {fifo_priority}")
    if transport_priority < 0 or (fifo_priority and transport_priority >= fifo_priority):
        raise InputError(
            f"--transport-priority must be in 0..{max(fifo_priority - 1, 0)} (below the loop's --fifo-priority "
            f"{fifo_priority}), got {transport_priority}"
        )
    if transport_priority and not fifo_priority:
        raise InputError(
            f"--transport-priority {transport_priority} needs the loop in SCHED_FIFO above it (--fifo-priority is 0)"
        )
    n = n_cpus()
    if cpu is not None and not 0 <= cpu < n:
        raise InputError(f"--cpu must be in 0..{n - 1}, got {cpu}")
