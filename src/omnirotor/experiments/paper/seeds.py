"""The paper's claims over many seeds: ``omnirotor reproduce --seeds N`` (issue 12, item 4; SPEC §6).

One seed's ``reproduce`` gives one verdict per claim, which says little when a claim sits near its threshold
(the sliding contact loss with the nominal map, for one). Here the whole campaign (identification flights,
identification, every interaction run) is repeated for seeds ``seed, seed + 1, …``, each into its own folder
``seed-S/``, and each claim's goal is checked on every seed. A goal is met when it holds in at least ``need``
of the seeds: the optimised maps must keep the sliding contact in every seed (the paper's central result), the
other goals in 8 of 10, the rule of the ten-seed campaigns of ``tools/claims_over_seeds.py`` (docs/fidelity.md).

The goals are the issue's, stated beside the paper's numbers; each gives the measured value per seed, so a
goal missed by a little reads differently from one missed by far. Nothing here is tuned: the runs use the
calibrated defaults of the simulator.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from omnirotor.experiments.paper.claims import GOALS, evaluate_goals
from omnirotor.experiments.paper.reproduce import reproduce
from omnirotor.safe_io import atomic_path, make_dir, write_json_atomic, write_text_atomic

__all__ = ["reproduce_seeds", "write_seeds_report", "plot_goals"]


def _fmt(v: float | None) -> str:
    return "—" if v is None else f"{v:.2f}"


def write_seeds_report(path: Path, goals: list[dict], quick: bool) -> Path:
    """Markdown: one row per goal with its value per seed (✓/✗) and the verdict over the seeds."""
    n = len(goals[0]["seeds"]) if goals else 0
    lines = [f"# The paper's claims over {n} seeds", ""]
    lines.append(
        ("**Quick runs** (shortened protocols). " if quick else "")
        + "Each seed is a whole `omnirotor reproduce` (its own identification flights and maps) in `seed-S/`; "
        "the simulator's calibrated defaults, never tuned per experiment."
    )
    lines += ["", "| goal | met | passes | values per seed |", "|---|---|---|---|"]
    for g in goals:
        vals = ", ".join(f"{_fmt(v)}{'✓' if p else '✗'}" for v, p in zip(g["values"], g["passed"], strict=True))
        text = g["text"].replace("|", "\\|")  # a bar inside a cell ends it in Markdown
        lines.append(
            f"| {text} | **{'yes' if g['met'] else 'no'}** | {g['passes']} of {len(g['seeds'])} "
            f"(need {g['need']}) | {vals} [{g['unit']}] |"
        )
    lines += ["", f"Seeds: {', '.join(str(s) for s in goals[0]['seeds'])}." if goals else "", ""]
    lines.append("![goals over seeds](claims-seeds.png)")
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path


def plot_goals(goals: list[dict], path: Path) -> Path:
    """Figure: one panel per goal, the value of every seed against the goal's band (green pass, red miss)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = 3
    rows = max(1, math.ceil(len(goals) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.6 * rows), squeeze=False)
    for ax, g in zip(axes.flat, goals, strict=False):
        seeds = np.asarray(g["seeds"])
        vals = np.array([np.nan if v is None else v for v in g["values"]], dtype=float)
        by_goal = next(x for x in GOALS if x.name == g["name"])
        finite = vals[np.isfinite(vals)]
        lo_plot = min([*finite, by_goal.lo if math.isfinite(by_goal.lo) else np.inf, 0.0])
        hi_plot = max([*finite, by_goal.hi if math.isfinite(by_goal.hi) else -np.inf, 1.0])
        band_lo = by_goal.lo if math.isfinite(by_goal.lo) else lo_plot - 1.0
        band_hi = by_goal.hi if math.isfinite(by_goal.hi) else hi_plot + 1.0
        ax.axhspan(band_lo, band_hi, color="tab:green", alpha=0.12, lw=0)
        ax.scatter(seeds, vals, c=["tab:green" if p else "tab:red" for p in g["passed"]], s=24, zorder=3)
        pad = 0.1 * (hi_plot - lo_plot) + 1e-3
        ax.set_ylim(lo_plot - pad, hi_plot + pad)
        ax.set_title(f"{g['name']}: {g['passes']}/{len(seeds)} ({'met' if g['met'] else 'not met'})", fontsize=9)
        ax.set_xlabel("seed", fontsize=8)
        ax.set_ylabel(g["unit"], fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(goals) :]:
        ax.set_visible(False)
    fig.suptitle("the paper's claims per seed (green band: the goal)", fontsize=10)
    fig.tight_layout()
    with atomic_path(path, "--out") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return path


def reproduce_seeds(
    out_dir: str | Path,
    seeds: int,
    quick: bool = False,
    seed: int = 0,
    estimator: str = "ukf",
    workers: int | None = None,
    progress: Callable[[str, float], None] | None = None,
    disturbances: bool = True,
) -> list[dict]:
    """Run ``reproduce`` for ``seeds`` consecutive seeds and check the goals over them (module docstring).

    Writes ``seed-S/`` per seed, then ``claims-seeds.json``, ``claims-seeds.md`` and ``claims-seeds.png``.

    Returns:
        :func:`evaluate_goals`'s list.
    """
    out = make_dir(out_dir, "--out")
    report = progress or (lambda stage, frac: None)
    per_seed: dict[int, dict] = {}
    for k in range(seeds):
        s = seed + k

        def sub(stage: str, frac: float, k=k, s=s) -> None:
            report(f"seed {s} ({k + 1}/{seeds}): {stage}", (k + frac) / seeds)

        per_seed[s] = reproduce(out / f"seed-{s}", quick=quick, seed=s, estimator=estimator, workers=workers,
                                progress=sub, disturbances=disturbances)  # fmt: skip
    goals = evaluate_goals(per_seed)
    meta = {"quick": quick, "estimator": estimator, "disturbances": disturbances}
    write_json_atomic(out / "claims-seeds.json", meta | {"goals": goals})
    write_seeds_report(out / "claims-seeds.md", goals, quick)
    plot_goals(goals, out / "claims-seeds.png")
    report("done", 1.0)
    return goals
