"""``omnirotor workers start|status|stop``: the resident campaign worker pool.

A thin layer over :mod:`omnirotor.experiments.campaign_pool` (its docstring says what the pool is, and when
``omnirotor campaign`` uses it).
"""

from __future__ import annotations

import json
import os
import time
from typing import Annotated

import typer

from omnirotor.cli import CommandGroup, app, number_option

workers_app = typer.Typer(
    cls=CommandGroup,
    help="A resident pool of warm campaign workers that outlives the command (omnirotor campaign uses it).",
    no_args_is_help=True,
    add_completion=False,
    rich_markup_mode=None,
)
app.add_typer(workers_app, name="workers")


@workers_app.command()
def start(
    workers: Annotated[int | None, typer.Option(help="Worker processes (default: the CPU count).")] = None,
    idle_timeout: Annotated[
        float | None,
        typer.Option(parser=number_option, help="Exit after this many seconds without a campaign (default 1800)."),
    ] = None,
) -> None:
    """Start this checkout's resident pool in the background and wait until its workers are warm."""
    from omnirotor.experiments.campaign_pool import IDLE_TIMEOUT_S, start_pool

    n = workers if workers is not None else (os.cpu_count() or 1)
    tic = time.perf_counter()
    st = start_pool(n, IDLE_TIMEOUT_S if idle_timeout is None else idle_timeout)
    if st["already"]:
        print(f"resident pool already running: pid {st['pid']}, {st['workers']} workers ({st['state']})")
        return
    print(
        f"resident pool ready: pid {st['pid']}, {st['workers']} warm workers in {time.perf_counter() - tic:.1f} s; "
        f"exits after {st['idle_timeout_s']:g} s without a campaign; socket {st['socket']}"
    )


@workers_app.command()
def status(
    as_json: Annotated[bool, typer.Option("--json", help="Print the status as one JSON object.")] = False,
) -> None:
    """Say whether this checkout's resident pool runs, and whether it would serve (same sources)."""
    from omnirotor.experiments.campaign_pool import pool_status, socket_path

    st = pool_status()
    if as_json:
        print(json.dumps(st if st is not None else {"running": False, "socket": str(socket_path())}))
        return
    if st is None:
        print(f"resident pool: not running (socket {socket_path()})")
        return
    serves = "serves this checkout" if st["current"] else "started from other sources: will not serve (restart it)"
    print(
        f"resident pool: pid {st['pid']}, {st['workers']} workers, {st['state']}"
        f"{', busy' if st['busy'] else ''}; {serves}; {st['campaigns_served']} campaigns served; "
        f"idle {st['idle_s']:.0f} s of {st['idle_timeout_s']:g} s; CPU {st['cpu_s']:.1f} s"
    )


@workers_app.command()
def stop() -> None:
    """Stop this checkout's resident pool (its workers with it)."""
    from omnirotor.experiments.campaign_pool import stop_pool

    pid = stop_pool()
    print("resident pool: not running" if pid is None else f"resident pool stopped (pid {pid})")
