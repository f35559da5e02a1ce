"""``omnirotor campaign``: Monte-Carlo robustness campaigns; ``omnirotor campaign-compare``: their plots.

A thin layer over :mod:`omnirotor.experiments.campaigns.runner` (its docstring documents the campaign file).
Everything is checked before the output folder is touched: a bad option leaves nothing behind.
"""

from __future__ import annotations

import importlib.util
import time
from pathlib import Path
from typing import Annotated

import typer

from omnirotor.cli import Interrupted, app
from omnirotor.errors import InputError
from omnirotor.limits import MAX_CAMPAIGN_RUNS, MAX_SEED, MAX_WORKERS
from omnirotor.safe_io import check_input_file, check_output_dir, check_output_file, dumps_json, note


@app.command()
def campaign(
    task: Annotated[
        str | None, typer.Argument(help="Task (sliding, peg-in-hole, point-contact, ...); default: the file's.")
    ] = None,
    runs: Annotated[int | None, typer.Option(help="Number of runs (default: the campaign file's).")] = None,
    backend: Annotated[str, typer.Option(help="local (process pool) or ray.")] = "local",
    address: Annotated[str | None, typer.Option(help="Ray cluster address (default: start a local Ray).")] = None,
    workers: Annotated[int | None, typer.Option(help="Runs in parallel (default: CPU count / cluster).")] = None,
    quick: Annotated[bool, typer.Option(help="Shortened protocols.")] = False,
    out: Annotated[Path | None, typer.Option(help="Campaign folder (default out/campaigns/NAME).")] = None,
    campaign_file: Annotated[
        str | None, typer.Option("--campaign", help="Campaign TOML file or preset name (default: 'default').")
    ] = None,
    map_mode: Annotated[str | None, typer.Option("--map", help="Wrench map: nominal, global, piecewise.")] = None,
    maps: Annotated[
        str | None, typer.Option(help="Wrench-map JSON, or identify-truth (each run identifies its own).")
    ] = None,
    seed: Annotated[int | None, typer.Option(help="Campaign seed (default: the file's).")] = None,
    restart: Annotated[bool, typer.Option(help="Discard the folder's results and start again.")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as one JSON object.")] = False,
) -> None:
    """Run N randomised, seeded runs of a task; save each result as it arrives; summarise and plot."""
    from rich.console import Console

    from omnirotor.experiments.campaigns.runner import BACKENDS

    if runs is not None and not 1 <= runs <= MAX_CAMPAIGN_RUNS:
        raise InputError(f"--runs must be >= 1 and <= {MAX_CAMPAIGN_RUNS} (omnirotor.limits), got {runs}")
    if workers is not None and not 1 <= workers <= MAX_WORKERS:
        raise InputError(f"--workers must be >= 1 and <= {MAX_WORKERS}, got {workers}")
    if backend not in BACKENDS:
        raise InputError(f"--backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if address is not None and backend != "ray":
        raise InputError("--address needs --backend ray")
    if backend == "ray" and importlib.util.find_spec("ray") is None:
        raise InputError("--backend ray needs the optional dependency ray: pip install 'omnirotor[ray]'")
    if maps is not None and maps != "identify-truth":
        check_input_file(maps, "--maps (a file, or identify-truth)")
    if seed is not None and not 0 <= seed <= MAX_SEED:
        raise InputError("--seed must be >= 0 and < 2^63")
    if out is not None:
        check_output_dir(out, "--out")
    err = Console(stderr=True)
    tic = time.perf_counter()
    from omnirotor.experiments.campaigns.runner import load_campaign

    spec = load_campaign(campaign_file, task, seed=seed, maps=maps, map=map_mode, quick=quick or None)
    if out is None:
        name = Path(campaign_file).stem if campaign_file is not None else f"{spec.task}-default"
        out = Path("out") / "campaigns" / f"{name}-{spec.options.map}"
    check_output_dir(out, "--out")
    label, total = f"{spec.task} ({spec.options.map} map)", runs or spec.runs
    state = {"ok": 0, "fail": 0, "error": 0}
    simulated = [0.0]  # simulated seconds of the runs finished by this call
    with _progress_bar(err, label) as bar:
        bar_id = bar.add_task("", total=total)

        def progress(done: int, total: int, rec: dict | None) -> None:
            if rec is not None:
                simulated[0] += float((rec.get("metrics") or {}).get("duration_s") or 0.0)
                key = "error" if rec.get("status") != "ok" else ("fail" if rec.get("success") is False else "ok")
                state[key] += 1
            bar.update(
                bar_id,
                completed=done,
                total=total,
                description=f"ok {state['ok']}  failed {state['fail']}  errors {state['error']}",
            )

        try:
            from omnirotor.experiments.campaigns.runner import run_campaign

            summary = run_campaign(
                spec, out, runs=runs, backend=backend, workers=workers, address=address, restart=restart,
                progress=progress,
            )  # fmt: skip
        except KeyboardInterrupt:
            raise Interrupted(
                f"the finished runs are kept in {out / 'results.jsonl'}; run the same command again to resume"
            ) from None
    wall = time.perf_counter() - tic
    line = (
        f"throughput: {simulated[0]:.1f} simulated s in {wall:.2f} s wall ({simulated[0] / max(wall, 1e-9):.1f} per s)"
    )
    if as_json:
        print(dumps_json(summary))
        err.print(line, highlight=False, soft_wrap=True)
        return
    _print_summary(summary, out)
    Console().print(line, highlight=False, soft_wrap=True)


def _progress_bar(err, label: str):
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(
        TextColumn(f"[bold]{label}[/bold]"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.description}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=True,
    )


def _print_summary(s: dict, out: Path) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console()
    rate = s["success_rate"]
    ci = s["success_rate_ci95"]
    head = (
        f"{s['task']}: {s['runs_done']} of {s['runs_requested']} runs done ({s['executed']} now), "
        f"{s['runs_error']} errors"
    )
    con.print(head)
    if rate is not None:
        con.print(
            f"success {s['successes']}/{s['runs_judged']} = {100 * rate:.0f} % "
            f"(95 % CI {100 * ci[0]:.0f}–{100 * ci[1]:.0f} %)"
        )
    if s["runs_with_unsafe_commands"]:
        con.print(f"[bold red]runs with non-finite or out-of-limit commands: {s['runs_with_unsafe_commands']}[/]")
    keys = [s["key_metric"]] + [f"ee_rms_error.{a}" for a in ("x_cm", "y_cm", "z_cm")]
    t = Table(title="metrics over the runs")
    for c in ("metric", "mean", "std", "p5", "median", "p95"):
        t.add_column(c, justify="left" if c == "metric" else "right")
    for k in keys:
        m = s["metrics"].get(k)
        if m:
            t.add_row(k, *(f"{m[c]:.3g}" for c in ("mean", "std", "p5", "median", "p95")))
    con.print(t)
    for name, bins in s["parameters"].items():
        cells = ", ".join(f"{_bin_label(b)}: {b['successes']}/{b['runs']}" for b in bins)
        if cells:
            con.print(f"success by {name}: {cells}")
    con.print(f"results: {out / 'results.jsonl'}; summary: {out / 'summary.json'}")
    for p in s.get("plots", []):
        con.print(f"plot: {p}")


def _bin_label(b: dict) -> str:
    lo, hi = b["low"], b["high"]
    if isinstance(lo, bool) or not isinstance(lo, (int, float)):
        return str(lo)
    return f"{lo:.3g}" if lo == hi else f"{lo:.3g}–{hi:.3g}"


@app.command("campaign-compare")
def campaign_compare(
    folders: Annotated[list[Path], typer.Argument(help="Campaign folders (from omnirotor campaign --out).")],
    param: Annotated[str, typer.Option(help="The varied parameter to plot against, e.g. gamma.")],
    out: Annotated[Path, typer.Option(help="PNG file.")],
    label: Annotated[list[str] | None, typer.Option(help="Legend label per folder (repeatable).")] = None,
    bins: Annotated[int, typer.Option(help="Equal bins over the drawn values.")] = 6,
) -> None:
    """Plot the success rate of several campaigns against one parameter, on shared bins."""
    from omnirotor.experiments.campaigns.runner import plot_comparison

    if not 1 <= bins <= 50:
        raise InputError(f"--bins must be in 1..50, got {bins}")
    if out.suffix.lower() != ".png":
        raise InputError(f"--out {out}: the output must be a .png file")
    replacing = check_output_file(out, "--out")
    print(plot_comparison([str(f) for f in folders], param, out, labels=label or None, bins=bins))
    if replacing:
        note(f"--out {out}: replaced the existing file")
