"""``omnirotor reproduce``: the paper's whole campaign in simulation, with a report."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from omnirotor.cli import app
from omnirotor.errors import InputError
from omnirotor.limits import MAX_SEED
from omnirotor.safe_io import check_output_dir


@app.command()
def reproduce(
    out: Annotated[Path, typer.Option(help="Output folder for report.md, metrics.json and the figures.")] = Path(
        "out/reproduce"
    ),
    quick: Annotated[bool, typer.Option(help="Shortened protocols (under a minute on 2 cores once compiled).")] = False,
    seed: Annotated[int, typer.Option(help="Base seed.")] = 0,
    estimator: Annotated[str, typer.Option(help="State estimator: ukf (paper) or bypass (faster).")] = "ukf",
    workers: Annotated[int | None, typer.Option(min=1, max=64, help="Processes for the independent runs.")] = None,
    disturbances: Annotated[
        bool, typer.Option(help="The simulator's calibrated disturbances (docs/fidelity.md); off: a clean plant.")
    ] = True,
    seeds: Annotated[
        int, typer.Option(min=1, max=1000, help="Repeat for this many seeds (seed, seed+1, ...); goals per seed.")
    ] = 1,
) -> None:
    """Identification flights, identification, hover validation, point contact, sliding, peg-in-hole; report.

    With ``--seeds N`` the whole campaign runs once per seed (``OUT/seed-S/``) and the claims' goals are checked
    on every seed: ``OUT/claims-seeds.md``, ``.json`` and ``.png``.
    """
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from omnirotor.experiments.paper.reproduce import claims
    from omnirotor.experiments.paper.reproduce import reproduce as run_all

    check_output_dir(out, "--out")
    if not 0 <= seed <= MAX_SEED - seeds:
        raise InputError("--seed (+ --seeds) must be an integer in [0, 2^63 - 1]")
    if estimator not in ("ukf", "bypass"):
        raise InputError(f"--estimator must be ukf or bypass, got {estimator!r}")
    con = Console(stderr=True)
    with Progress(
        TextColumn("[bold]reproduce[/bold] {task.description}"),
        BarColumn(),
        TextColumn("{task.percentage:>5.1f} %"),
        TimeElapsedColumn(),
        console=con,
    ) as bar:
        tid = bar.add_task("starting", total=1.0)

        def on_progress(stage: str, frac: float) -> None:
            bar.update(tid, completed=frac, description=stage)

        common = dict(
            quick=quick,
            seed=seed,
            estimator=estimator,
            workers=workers,
            progress=on_progress,
            disturbances=disturbances,
        )
        if seeds > 1:
            from omnirotor.experiments.paper.seeds import reproduce_seeds

            goals = reproduce_seeds(out, seeds, **common)
        else:
            metrics = run_all(out, **common)
    c = Console()
    if seeds > 1:
        for g in goals:
            verdict = "met" if g["met"] else "not met"
            c.print(f"[bold]{verdict:>8}[/bold]  {g['passes']:>3} of {len(g['seeds'])} seeds  {g['text']}")
        c.print(f"report: {out / 'claims-seeds.md'}")
        return
    for cl in claims(metrics):
        c.print(f"[bold]{cl['verdict']:>15}[/bold]  {cl['claim']}\n                 {cl['measured']}")
    c.print(f"report: {out / 'report.md'}")
