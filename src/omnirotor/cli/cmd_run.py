"""``omnirotor run TASK``: fly a task of the registry in closed loop in the simulator and report EE errors.

The tasks live in :data:`omnirotor.experiments.TASKS` (``hover``, plus what the experiment modules
register). The errors are those of SPEC §6 (true EE pose against the compliant EE reference).
"""

from __future__ import annotations

import json
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from omnirotor.cli import app
from omnirotor.errors import InputError


@app.command()
def run(
    task: Annotated[str, typer.Argument(help="Task to fly, e.g. hover.")],
    solver: Annotated[str, typer.Option(help="Allocation QP backend: daqp or proxsuite.")] = "daqp",
    estimator: Annotated[str, typer.Option(help="State estimator: ukf or bypass (truth plus noise).")] = "ukf",
    duration: Annotated[float | None, typer.Option(help="Simulated time [s]; default: the task's.")] = None,
    seed: Annotated[int, typer.Option(help="Simulator noise seed.")] = 0,
    truth: Annotated[str, typer.Option(help="Simulator aerodynamics: interference or nominal.")] = "interference",
    vehicle: Annotated[str, typer.Option(help="Vehicle preset or TOML file.")] = "omnirotor",
    config: Annotated[str | None, typer.Option(help="Controller parameters TOML file.")] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option("--set", help="Controller parameter override key=value (repeatable), e.g. observer.cutoff_hz=5."),
    ] = None,
    video: Annotated[str | None, typer.Option(help="Film the run into this MP4 file (offscreen rendering).")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Fly TASK in the simulator with the interaction controller; print the EE tracking errors."""
    from omnirotor.experiments.closed_loop import TASKS, TaskOptions, discover_tasks, run_task

    discover_tasks()
    if task not in TASKS:
        raise InputError(f"unknown task {task!r}; tasks: {', '.join(sorted(TASKS))}")
    options = TaskOptions(
        solver=solver,
        estimator=estimator,
        duration_s=duration,
        seed=seed,
        truth=truth,
        vehicle=vehicle,
        controller_config=config,
        overrides=tuple(set_ or ()),
        video=video,
    )
    options.controller_params()  # validate solver, config and overrides before flying
    err = Console(stderr=True)
    with Progress(
        TextColumn(f"[bold]{task}[/bold]"),
        BarColumn(),
        TextColumn("{task.percentage:>5.1f} %"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=True,
    ) as bar:
        bar_id = bar.add_task(task, total=1.0)
        result = run_task(task, options, progress=lambda frac: bar.update(bar_id, completed=frac))
    rep = result.summary()
    if as_json:
        print(json.dumps(rep, indent=1))
        return
    table = Table(
        title=f"{task}: {rep['duration_s']:.1f} s, solver {rep['solver']}, estimator {rep['estimator']}, "
        f"truth {rep['truth']}"
    )
    table.add_column("EE error")
    for name in ("x (cm)", "y (cm)", "z (cm)", "roll (deg)", "pitch (deg)", "yaw (deg)"):
        table.add_column(name, justify="right")
    for label, key in (("RMS", "ee_rms_error"), ("max", "ee_max_error")):
        table.add_row(label, *(f"{v:.3f}" for v in rep[key].values()))
    con = Console()
    con.print(table)
    con.print(
        f"controller step: median {rep['controller_step_us_median']:.1f} µs; "
        f"steps flagged: {rep['steps_flagged']} of {rep['steps']}"
    )
