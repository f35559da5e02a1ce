"""Reading a campaign folder, summarising its runs, and plotting success against each varied parameter.

See :mod:`omnirotor.experiments.campaigns.runner` for the folder's layout. :func:`summarize` gives the success rate
with its 95 % Wilson interval, the distribution of every numeric metric of the runs' summaries (flattened
to dotted names, e.g. ``contact.fraction``), and the success rate per bin of each varied parameter;
:func:`plot_campaign` and :func:`plot_comparison` draw them.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from omnirotor.errors import InputError
from omnirotor.experiments.campaigns.spec import KEY_METRICS, PARAMETERS, CampaignSpec
from omnirotor.safe_io import load_json, plain_json, read_bytes, truncate_file

__all__ = [
    "RESULTS_FILE",
    "DEFINITION_FILE",
    "SUMMARY_FILE",
    "PLOTS_DIR",
    "load_results",
    "jsonable",
    "wilson_interval",
    "metric_value",
    "binned_success",
    "summarize",
    "plot_campaign",
    "plot_parameter",
    "plot_parameters",
    "plot_comparison",
    "warm_plots",
]

RESULTS_FILE = "results.jsonl"
DEFINITION_FILE = "campaign.json"
SUMMARY_FILE = "summary.json"
PLOTS_DIR = "plots"


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


jsonable = plain_json
"""Plain JSON data: numpy scalars and arrays converted, non-finite floats as None."""

_RECORD_TYPES = {"index": int, "status": str, "params": dict, "derived": dict, "metrics": dict, "error": str}


def _check_record(rec: Any, path: Path, n: int) -> dict:
    """A record of results.jsonl with the types the summary and the plots rely on, else an InputError."""
    where = f"{path}: line {n}"
    if not isinstance(rec, dict):
        raise InputError(f"{where}: not a JSON object (fix it or start again with --restart)")
    idx = rec.get("index")
    if isinstance(idx, bool) or not isinstance(idx, int) or idx < 0:
        raise InputError(f"{where} has no run index (fix it or start again with --restart)")
    for key, tp in _RECORD_TYPES.items():
        v = rec.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, tp)):
            raise InputError(f"{where}: {key} must be a {tp.__name__} (fix it or start again with --restart)")
    if rec.get("status") not in (None, "ok", "error"):
        raise InputError(f"{where}: status must be ok or error")
    if rec.get("success") not in (None, True, False):
        raise InputError(f"{where}: success must be true, false or null")
    if rec.get("status") == "ok" and not isinstance(rec.get("metrics"), dict):
        raise InputError(f"{where}: a finished run needs its metrics")
    return rec


def load_results(out_dir: str | Path, repair: bool = False) -> dict[int, dict]:
    """The records of ``DIR/results.jsonl`` by run index (the last record of an index wins).

    A last line without its newline is what a killed campaign leaves: it is ignored (and cut off with
    ``repair``). Any other unreadable line is an :class:`InputError`.
    """
    path = Path(out_dir) / RESULTS_FILE
    if not os.path.lexists(path):
        return {}
    raw = read_bytes(path)
    end = raw.rfind(b"\n") + 1
    if end < len(raw) and repair:
        truncate_file(path, end)  # never through a symbolic link
    out: dict[int, dict] = {}
    for n, line in enumerate(raw[:end].splitlines(), start=1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except (ValueError, RecursionError):  # also numbers of too many digits and nesting too deep
            raise InputError(f"{path}: line {n} is not valid JSON (fix it or start again with --restart)") from None
        rec = _check_record(rec, path, n)
        out[rec["index"]] = rec
    return out


# -- summary -----------------------------------------------------------------------------------------------------


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float] | None:
    """The 95 % Wilson score interval of a success rate (None when n = 0)."""
    if n == 0:
        return None
    p = successes / n
    den = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    # the interval always holds p; rounding could put an end a hair past it at p = 0 or 1
    return (min(p, max(0.0, centre - half)), max(p, min(1.0, centre + half)))


def _entry_names(obj: Any) -> tuple[str, ...] | None:
    """The names of a short list of numbers' entries in a flattened metric (x, y, z for three); None otherwise."""
    if isinstance(obj, list) and len(obj) <= 8 and all(_is_number(v) for v in obj):
        return ("x", "y", "z") if len(obj) == 3 else tuple(str(i) for i in range(len(obj)))
    return None


def _flatten(obj: Any, prefix: str = "") -> dict[str, float]:
    out: dict[str, float] = {}
    names = _entry_names(obj)
    if isinstance(obj, dict):
        for k, v in obj.items():
            out.update(_flatten(v, f"{prefix}{k}."))
    elif names is not None:
        for name, v in zip(names, obj, strict=True):
            out[f"{prefix}{name}"] = float(v)
    elif _is_number(obj):
        out[prefix[:-1]] = float(obj)
    return out


def metric_value(record: dict, metric: str) -> float | None:
    """The value of a dotted metric in a run record (None when absent).

    The value ``_flatten(record["metrics"])`` holds under ``metric``, found by walking down the keys that prefix it
    instead of flattening the whole record (a plot reads one metric of each of hundreds of records).
    """
    if record.get("metrics") is None:
        return None
    return _lookup(record["metrics"], metric)


def _lookup(obj: Any, path: str) -> float | None:
    """``_flatten(obj).get(path)`` for a dict ``obj``: where several keys flatten to ``path``, the last one wins."""
    found = None
    for k, v in obj.items():
        key = f"{k}"
        if path == key:
            if _is_number(v):
                found = float(v)
        elif path.startswith(key + "."):
            rest = path[len(key) + 1 :]
            names = _entry_names(v)
            if isinstance(v, dict):
                value = _lookup(v, rest)
            elif names is not None and rest in names:
                value = float(v[names.index(rest)])
            else:
                value = None
            if value is not None:
                found = value
    return found


def _bins(values: list[Any], k: int) -> list[tuple[Any, Any]]:
    nums = [v for v in values if _is_number(v)]
    if len(nums) != len(values) or len(set(nums)) <= k:
        return [(v, v) for v in sorted(set(values), key=lambda x: (str(type(x)), x))]
    lo, hi = min(nums), max(nums)
    edges = np.linspace(lo, hi, k + 1)
    return [(float(a), float(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def _in_bin(v: Any, b: tuple[Any, Any], last: bool) -> bool:
    if b[0] == b[1] or not _is_number(v):
        return v == b[0]
    return b[0] <= v < b[1] or (last and v == b[1])


def binned_success(records: list[dict], param: str, k: int) -> list[dict]:
    """Success rate of the runs with a verdict per bin of a parameter (numbers: k equal bins; else per value)."""
    rows = [
        (r["params"][param], bool(r["success"]))
        for r in records
        if r.get("success") is not None and param in r.get("params", {})
    ]
    if not rows:
        return []
    bins = _bins([v for v, _ in rows], k)
    out = []
    for j, b in enumerate(bins):
        hits = [s for v, s in rows if _in_bin(v, b, j == len(bins) - 1)]
        ci = wilson_interval(sum(hits), len(hits))
        out.append(
            {
                "low": b[0],
                "high": b[1],
                "runs": len(hits),
                "successes": int(sum(hits)),
                "rate": sum(hits) / len(hits) if hits else None,
                "ci95": list(ci) if ci else None,
            }
        )
    return out


def summarize(spec: CampaignSpec, records: list[dict], runs: int) -> dict:
    """The campaign's summary: counts, success rate, metric distributions, binned success per parameter."""
    ok = [r for r in records if r.get("status") == "ok"]
    judged = [r for r in ok if r.get("success") is not None]
    wins = sum(bool(r["success"]) for r in judged)
    ci = wilson_interval(wins, len(judged))
    flat = [_flatten(r["metrics"]) for r in ok]
    keys = sorted({k for f in flat for k in f})
    metrics = {}
    for k in keys:
        v = np.array([f[k] for f in flat if k in f])
        metrics[k] = {
            "n": int(v.size),
            "mean": float(v.mean()),
            "std": float(v.std()),
            "min": float(v.min()),
            "p5": float(np.percentile(v, 5)),
            "median": float(np.median(v)),
            "p95": float(np.percentile(v, 95)),
            "max": float(v.max()),
        }
    unsafe = [r["index"] for r in ok if not r["metrics"].get("safety", {}).get("commands_within_limits", True)]
    return jsonable(
        {
            "task": spec.task,
            "hash": spec.digest(),
            "runs_requested": runs,
            "runs_done": len(records),
            "runs_ok": len(ok),
            "runs_error": len(records) - len(ok),
            "errors": {str(r["index"]): r.get("error") for r in records if r.get("status") != "ok"},
            "runs_judged": len(judged),
            "successes": wins,
            "success_rate": wins / len(judged) if judged else None,
            "success_rate_ci95": list(ci) if ci else None,
            "runs_with_unsafe_commands": unsafe,
            "key_metric": spec.key_metric,
            "metrics": metrics,
            "parameters": {name: binned_success(ok, name, spec.bins) for name, _ in spec.vary},
        }
    )


# -- plots -------------------------------------------------------------------------------------------------------


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path, tight: bool = True, close: bool = True) -> Path:
    from omnirotor.experiments.figures import save_figure

    return save_figure(fig, path, tight=tight, close=close)


PANEL_MARGINS = {"left": 0.06, "right": 0.985, "bottom": 0.13, "top": 0.92, "wspace": 0.2}
"""Fixed margins of the two-panel campaign plots: no layout engine, so each is drawn once (constrained layout
and tight cropping drew each twice: the default campaign's eight plots took 5.7 s instead of 3.0 s under load)."""


def _draw_success(
    ax, bins: list[dict], label: str | None = None, color: str = "#2c3e50", shift: float = 0.0, counts: bool = True
) -> None:
    """Success rate per bin with its 95 % interval; ``shift`` moves numeric x (to tell overlapping series apart)."""
    rows = [b for b in bins if b["runs"]]
    if not rows:
        return
    numeric = all(_is_number(b["low"]) for b in rows)
    x = [0.5 * (b["low"] + b["high"]) + shift if numeric else str(b["low"]) for b in rows]
    y = [b["rate"] for b in rows]
    lo = [b["rate"] - b["ci95"][0] for b in rows]
    hi = [b["ci95"][1] - b["rate"] for b in rows]
    ax.errorbar(x, y, yerr=[lo, hi], marker="o", capsize=3, color=color, label=label)
    for xi, b in zip(x, rows, strict=True) if counts else ():
        ax.annotate(f"{b['successes']}/{b['runs']}", (xi, b["rate"]), textcoords="offset points", xytext=(4, 6),
                    fontsize=7, color=color)  # fmt: skip
    ax.set_ylim(-0.05, 1.12)
    ax.set_ylabel("success rate (95 % CI)")
    ax.grid(alpha=0.3)


def _scatter(
    ax,
    records: list[dict],
    param: str,
    metric: str,
    color: str | None = None,
    label: str | None = None,
    marker: str = "o",
    size: float = 16.0,
):
    """The metric of each run against the parameter: green/red by verdict, or one series in ``color``."""
    pts = [(r["params"].get(param), metric_value(r, metric), r.get("success")) for r in records]
    pts = [(x, y, s) for x, y, s in pts if x is not None and y is not None]
    if not pts:
        return
    if color is None:
        for flag, c, lab in ((True, "#27ae60", "success"), (False, "#c0392b", "failure"), (None, "0.5", "no verdict")):
            sel = [(x, y) for x, y, s in pts if s is flag]
            if sel:
                ax.scatter(*zip(*sel, strict=True), s=16, color=c, label=lab, alpha=0.8)
    else:
        ok = [(x, y) for x, y, s in pts if s is not False]
        bad = [(x, y) for x, y, s in pts if s is False]
        if ok:  # hollow, so that series lying on each other stay visible
            ax.scatter(*zip(*ok, strict=True), s=size, facecolors="none", edgecolors=color, marker=marker,
                       label=f"{label} success")  # fmt: skip
        if bad:
            ax.scatter(*zip(*bad, strict=True), s=22, color=color, marker="x", label=f"{label} failure")
    ax.set_ylabel(metric)
    ax.grid(alpha=0.3)


def _unit(param: str) -> str:
    p = PARAMETERS.get(param)
    return f"{param} [{p.unit}]" if p is not None and p.unit else param


def plot_campaign(
    spec: CampaignSpec, records: list[dict], out_dir: str | Path, executor=None, workers: int | None = None
) -> list[Path]:
    """One PNG per varied parameter: binned success rate, and the key metric of each run against it.

    Args:
        spec: the campaign.
        records: its run records.
        out_dir: folder of the PNG files.
        executor: warm workers (a ``concurrent.futures.Executor``) to draw the plots on in parallel, or None.
        workers: how many of them (None: all).
    """
    ok = [r for r in records if r.get("status") == "ok"]
    names = [name for name, _ in spec.vary]
    if executor is None:
        return plot_parameters(spec, ok, names, out_dir)
    k = max(1, min(workers or executor._max_workers, len(names)))
    futures = [executor.submit(plot_parameters, spec, ok, names[i::k], out_dir) for i in range(k)]
    drawn = {p.name: p for fut in futures for p in fut.result()}
    return [drawn[_plot_name(name)] for name in names]


def _plot_name(name: str) -> str:
    return f"success-vs-{name.replace('.', '_')}.png"


def plot_parameters(spec: CampaignSpec, ok: list[dict], names: list[str], out_dir: str | Path) -> list[Path]:
    """The plots of :func:`plot_campaign` for the varied parameters ``names`` (``ok``: the finished runs).

    They are drawn on one figure, its two panels cleared between plots: the same PNG files, byte for byte, as a
    new figure per plot (:func:`plot_parameter`; tested), without building the figure and its axes each time.
    """
    if not names:
        return []
    fig, axes = _parameter_figure()
    try:
        paths = []
        for name in names:
            for ax in axes:
                ax.cla()
            paths.append(_draw_parameter(fig, axes, spec, ok, name, out_dir, close=False))
        return paths
    finally:
        _plt().close(fig)


def plot_parameter(spec: CampaignSpec, ok: list[dict], name: str, out_dir: str | Path) -> Path:
    """The plot of :func:`plot_campaign` for the varied parameter ``name`` (``ok``: the finished runs)."""
    fig, axes = _parameter_figure()
    return _draw_parameter(fig, axes, spec, ok, name, out_dir, close=True)


def _parameter_figure():
    return _plt().subplots(1, 2, figsize=(11, 4), gridspec_kw=PANEL_MARGINS)


def _draw_parameter(fig, axes, spec: CampaignSpec, ok: list[dict], name: str, out_dir, close: bool) -> Path:
    a1, a2 = axes
    _draw_success(a1, binned_success(ok, name, spec.bins))
    a1.set_xlabel(_unit(name))
    a1.set_title(f"{spec.task}: success against {name}", y=1.0)  # y given: no search for a free place above
    _scatter(a2, ok, name, spec.key_metric)
    a2.set_xlabel(_unit(name))
    a2.set_title(f"{spec.key_metric} of each run", y=1.0)
    if a2.has_data():
        a2.legend(fontsize=8)
    return _save(fig, Path(out_dir) / _plot_name(name), tight=False, close=close)


def warm_plots() -> None:
    """Import matplotlib and draw a small figure (its fonts and caches), so that a warm worker's first plot is fast."""
    import io

    plt = _plt()
    fig, ax = plt.subplots(figsize=(2, 1))
    ax.errorbar([0, 1], [0, 1], yerr=[0.1, 0.1], marker="o")
    ax.scatter([0.5], [0.5])
    ax.set_title("warm", y=1.0)
    fig.savefig(io.BytesIO(), format="png", dpi=50)
    plt.close(fig)


def _load_folder(folder: str | Path) -> tuple[dict, list[dict]]:
    path = Path(folder) / DEFINITION_FILE
    if not os.path.lexists(path):
        raise InputError(f"{folder}: not a campaign folder (no {DEFINITION_FILE})")
    stored = load_json(path)
    definition = stored.get("definition") if isinstance(stored, dict) else None
    if (
        not isinstance(definition, dict)
        or not isinstance(definition.get("vary", {}), dict)
        or not isinstance(definition.get("options", {}), dict)
        or not isinstance(definition.get("task", ""), str)
    ):
        raise InputError(f"{path}: unreadable campaign definition")
    return definition, [r for r in load_results(folder).values() if r.get("status") == "ok"]


def plot_comparison(
    folders: list[str | Path], param: str, out: str | Path, labels: list[str] | None = None, bins: int = 6
) -> Path:
    """Success rate (and the key metric) against one parameter for several campaigns on shared bins.

    Args:
        folders: campaign folders.
        param: the varied parameter to plot against.
        out: PNG file.
        labels: legend labels (default: each campaign's map and folder name).
        bins: number of equal bins over the union of the drawn values.

    Raises:
        InputError: a folder is not a campaign, or does not vary ``param``.
    """
    if not str(out).lower().endswith(".png"):
        raise InputError(f"{out}: the output must be a .png file")
    if labels is not None and len(labels) != len(folders):
        raise InputError(f"{len(labels)} labels for {len(folders)} campaigns")
    loaded = [_load_folder(f) for f in folders]
    for f, (definition, _) in zip(folders, loaded, strict=True):
        if param not in definition.get("vary", {}):
            raise InputError(f"{f}: the campaign does not vary {param!r}")
    values = [r["params"][param] for _, recs in loaded for r in recs if param in r["params"]]
    if not values:
        raise InputError(f"no finished runs to plot in {', '.join(map(str, folders))}")
    edges = _bins(values, bins)
    numeric = all(_is_number(v) for v in values)
    step = 0.012 * (max(values) - min(values)) if numeric else 0.0
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    colors = ("#c0392b", "#27ae60", "#2980b9", "#8e44ad", "#d35400")
    task = loaded[0][0].get("task", "")
    metric = KEY_METRICS.get(task, "ee_rms_error.x_cm")
    for j, (folder, (definition, recs)) in enumerate(zip(folders, loaded, strict=True)):
        label = labels[j] if labels else f"{definition['options'].get('map', '?')} map ({Path(folder).name})"
        color = colors[j % len(colors)]
        rows = []
        judged = [(r["params"][param], bool(r["success"])) for r in recs if r.get("success") is not None]
        for i, b in enumerate(edges):
            hits = [s for v, s in judged if _in_bin(v, b, i == len(edges) - 1)]
            ci = wilson_interval(sum(hits), len(hits))
            rows.append({"low": b[0], "high": b[1], "runs": len(hits), "successes": sum(hits),
                         "rate": sum(hits) / len(hits) if hits else None, "ci95": ci})  # fmt: skip
        _draw_success(a1, rows, label=label, color=color, shift=(j - 0.5 * (len(folders) - 1)) * step, counts=False)
        _scatter(a2, recs, param, metric, color=color, label=label, marker="osD^v"[j % 5], size=14.0 + 22.0 * j)
    a1.set_xlabel(_unit(param))
    a1.set_title(f"{task}: success rate against {param} ({len(values)} runs, {len(edges)} bins)")
    a1.legend(fontsize=8, loc="lower left")
    a2.set_xlabel(_unit(param))
    a2.set_title(f"{metric} of each run")
    a2.legend(fontsize=8)
    return _save(fig, Path(out))
