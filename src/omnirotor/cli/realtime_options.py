"""The real-time options of the commands with a periodic loop: ``fly``, ``sim --serve``, ``px4-bridge``.

Each command declares ``--cpu`` and ``--fifo-priority`` with these types (its own defaults named in their help),
checks them with :func:`check_realtime_options` before it opens anything (one line and exit status 2), and hands
them to :func:`omnirotor.realtime.set_realtime` once its transport is open.
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


def n_cpus() -> int:
    """The CPUs ``--cpu`` may name (0 to this minus one)."""
    return os.cpu_count() or 1


def check_realtime_options(cpu: int | None, fifo_priority: int) -> None:
    """``--cpu`` within this machine's CPUs and ``--fifo-priority`` within 0-99.

    Raises:
        InputError: either is out of range (one line; the CLI exits with status 2).
    """
    if not 0 <= fifo_priority <= FIFO_PRIORITY_MAX:
        raise InputError(f"--fifo-priority must be in 0..{FIFO_PRIORITY_MAX}, got {fifo_priority}")
    n = n_cpus()
    if cpu is not None and not 0 <= cpu < n:
        raise InputError(f"--cpu must be in 0..{n - 1}, got {cpu}")
