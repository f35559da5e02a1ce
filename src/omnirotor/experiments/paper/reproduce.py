"""``omnirotor reproduce``: the paper's campaign end to end, with a report (issue "Experiments").

Identification flights → identification (global and per-region maps) → hover validation with the nominal,
global and piecewise maps → point contact (straight, tilted) → sliding with the three maps → peg-in-hole.
Runs go to a process pool (they are independent once the maps exist). Writes ``DIR/metrics.json`` (one object
keyed ``TASK/MAP``), the figures, and ``DIR/report.md`` with our Table 1 beside the paper's and a verdict on
each claim of the paper.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import os
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from omnirotor.experiments.metrics import AXES, PAPER_TABLE1
from omnirotor.experiments.paper.claims import GOALS
from omnirotor.experiments.tasks.common import ExperimentOptions
from omnirotor.identification import IdentificationParams, identify, load_hover_data
from omnirotor.safe_io import make_dir, route_mujoco_log, write_json_atomic, write_text_atomic
from omnirotor.vehicle import load_vehicle

__all__ = ["Plan", "plan", "in_plan_order", "run_one", "reproduce", "claims", "write_report"]


@dataclasses.dataclass(frozen=True)
class Plan:
    """The runs of the campaign after identification: (task, map) pairs."""

    runs: tuple[tuple[str, str], ...] = (
        ("hover-validation", "nominal"),
        ("hover-validation", "global"),
        ("hover-validation", "piecewise"),
        ("point-contact", "nominal"),
        ("point-contact-tilted", "nominal"),
        ("sliding", "nominal"),
        ("sliding", "global"),
        ("sliding", "piecewise"),
        ("peg-in-hole", "nominal"),
    )


def plan() -> Plan:
    """The paper's campaign."""
    return Plan()


def in_plan_order(samples: dict[str, dict]) -> dict[str, dict]:
    """``samples`` (keyed by map mode) in the order the plan first runs each mode.

    Not the order the workers finished in: the hover figure's maps keep their places from run to run.
    """
    order = list(dict.fromkeys(mode for _, mode in plan().runs))
    return {m: samples[m] for m in sorted(samples, key=lambda m: order.index(m) if m in order else len(order))}


def run_one(task: str, options: ExperimentOptions) -> tuple[str, dict, dict | None]:
    """Run one task in this process; returns (key, metrics JSON, hover force samples or None)."""
    from omnirotor.experiments.tasks import run_task

    result = run_task(task, options)
    samples = getattr(result, "force_samples", None)  # only experiment results carry them
    if samples is not None:
        samples = {r: np.asarray(v).tolist() for r, v in samples.items()}
    return f"{task}/{options.map_mode}", result.summary(), samples


def _run_in_worker(task: str, options: ExperimentOptions) -> tuple[tuple[str, dict, dict | None], list]:
    """:func:`run_one` in a pool worker, its warnings recorded instead of printed by the worker.

    Returns:
        ``run_one``'s result and the warnings as ``(category, message)`` pairs, which the parent warns again
        (the CLI reduces them to one line; a worker writing to the terminal would interleave noise).
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = run_one(task, options)
    return result, [(w.category, str(w.message)) for w in caught]


def reproduce(
    out_dir: str | Path,
    quick: bool = False,
    seed: int = 0,
    estimator: str = "ukf",
    workers: int | None = None,
    progress: Callable[[str, float], None] | None = None,
    sim_overrides: tuple[str, ...] = (),
    disturbances: bool = True,
) -> dict:
    """Run the whole campaign; returns the metrics dict (also written to ``out_dir/metrics.json``).

    Args:
        out_dir: output folder (created).
        quick: shortened protocols.
        seed: base seed of every run.
        estimator: "ukf" (the paper's) or "bypass" (faster).
        workers: processes for the independent runs (default: CPU count, at most 4).
        progress: called with (stage description, fraction of the campaign done).
        disturbances: fly the simulator's calibrated disturbances (False: the clean plant, ``--no-disturbances``).
        sim_overrides: dotted ``key=value`` simulator overrides applied to every run alike (the calibration of
            the disturbances, :mod:`omnirotor.experiments.calibration.disturbances`).
    """
    out = make_dir(out_dir, "--out")
    route_mujoco_log(out)  # MuJoCo's log goes under the output folder (the workers inherit it)
    report = progress or (lambda stage, frac: None)
    base = ExperimentOptions(
        quick=quick,
        seed=seed,
        estimator=estimator,
        out_dir=str(out),
        sim_overrides=tuple(sim_overrides),
        disturbances=disturbances,
    )
    metrics: dict = {}
    n_total = 2 + len(plan().runs)
    report("identification flights", 0.0)
    key, m, _ = run_one("identify-flights", base)
    metrics[key] = m
    report("identification", 1 / n_total)
    vehicle = load_vehicle(base.vehicle)
    data = load_hover_data([out / "hover_points.csv"], vehicle)
    maps = identify(data, vehicle, IdentificationParams())
    maps_path = out / "maps.json"
    maps.save(maps_path)
    metrics["identify"] = {
        "regions": {
            n: {
                "points": e.points,
                "nominal_force_residual_rms_N": e.nominal_force_residual_rms_N,
                "force_residual_rms_N": e.force_residual_rms_N,
            }
            for n, e in maps.regions.items()
        },
        "global": {
            "points": maps.global_.points,
            "nominal_force_residual_rms_N": maps.global_.nominal_force_residual_rms_N,
            "force_residual_rms_N": maps.global_.force_residual_rms_N,
        },
        "maps": str(maps_path),
    }
    done = 2
    report("interaction runs", done / n_total)
    jobs = [
        (task, dataclasses.replace(base, map_mode=mode, maps=None if mode == "nominal" else str(maps_path)))
        for task, mode in plan().runs
    ]
    n_workers = workers or min(4, os.cpu_count() or 1)
    samples: dict[str, dict] = {}
    with cf.ProcessPoolExecutor(max_workers=n_workers) as pool:
        futures = {pool.submit(_run_in_worker, task, opts): (task, opts.map_mode) for task, opts in jobs}
        for fut in cf.as_completed(futures):
            (key, m, s), caught = fut.result()
            for category, message in caught:
                warnings.warn(f"{key}: {message}", category, stacklevel=1)
            metrics[key] = m
            if s is not None:
                samples[key.split("/")[1]] = {r: np.asarray(v) for r, v in s.items()}
            done += 1
            report(f"finished {key}", done / n_total)
    ordered = {k: metrics[k] for k in ["identify-flights/nominal", "identify"] + [f"{t}/{m}" for t, m in plan().runs]}
    write_json_atomic(out / "metrics.json", ordered)
    figures = {}
    from omnirotor.experiments.figures import plot_hover_violins, plot_table1

    if samples:
        figures["hover"] = str(plot_hover_violins(in_plan_order(samples), out / "hover-validation.png"))
    figures["table1"] = str(plot_table1(ordered, PAPER_TABLE1, out / "table1.png"))
    write_report(out / "report.md", ordered, figures, quick=quick, disturbances=disturbances)
    return ordered


# -- claims and report -------------------------------------------------------------------------------------------


_GOALS = {g.name: g for g in GOALS}
_HOVER_NOMINAL, _HOVER_PIECEWISE = _GOALS["hover_bias_nominal"], _GOALS["hover_bias_piecewise"]
_SLIDING = tuple(_GOALS[f"sliding_{n}"] for n in ("nominal_loses", "global_keeps", "piecewise_keeps"))
_TILTED, _PEG_DEPTH, _PEG_TILT = _GOALS["tilted_underestimate"], _GOALS["peg_depth"], _GOALS["peg_tilt"]


def claims(metrics: dict) -> list[dict]:
    """The paper's claims, each with our measurement and a verdict ("reproduced", "not reproduced", "partly")."""
    out = []

    def get(key: str) -> dict | None:
        return metrics.get(key)

    hv = {m: get(f"hover-validation/{m}") for m in ("nominal", "global", "piecewise")}
    if all(hv.values()):
        fz = {m: [r["force_W_mean_N"][2] for r in hv[m]["regions"].values()] for m in hv}
        # the ten-seed goals (paper.claims.GOALS): nominal 1.5-2.5 N, piecewise |f_z| <= 0.3 N in every region
        nom, pw = _HOVER_NOMINAL.value(metrics), _HOVER_PIECEWISE.value(metrics)
        ok_nom, ok_pw = _HOVER_NOMINAL.passes(nom), _HOVER_PIECEWISE.passes(pw)
        out.append(
            {
                "claim": "Hover: the nominal map shows a positive thrust-direction force bias of about 2 N; "
                "the optimized maps nearly remove it (Fig. 3)",
                "measured": f"mean f_z^W over regions: nominal {nom:+.2f} N, global {np.mean(fz['global']):+.2f} N, "
                f"piecewise {np.mean(fz['piecewise']):+.2f} N (every region within ±{pw:.2f} N)",
                # without the bias there is nothing for the optimized maps to remove: that is not reproduced
                "verdict": "reproduced" if ok_nom and ok_pw else ("partly" if ok_nom else "not reproduced"),
            }
        )
    sl = {m: get(f"sliding/{m}") for m in ("nominal", "global", "piecewise")}
    if all(sl.values()):
        lost = {m: sl[m]["contact"]["lost"] for m in sl}
        # the ten-seed goals: the nominal map loses contact, the global and piecewise maps keep it
        held = [g.passes(g.value(metrics)) for g in _SLIDING]
        when = sl["nominal"]["contact"]["first_loss_s"]
        out.append(
            {
                "claim": "Sliding to 45° of roll: the nominal map loses contact; the single and piecewise optimized "
                "maps keep it",
                "measured": "contact lost: "
                + ", ".join(f"{m} {'yes' if lost[m] else 'no'}" for m in lost)
                + (f" (nominal first loss at {when:.1f} s)" if when is not None else ""),
                "verdict": "reproduced" if all(held) else ("partly" if any(held[1:]) else "not reproduced"),
            }
        )
    pc = get("point-contact/nominal")
    if pc:
        nf = pc["normal_force"]
        ok = (not pc["contact"]["lost"]) and abs(nf["true_mean_N"] - nf["expected_N"]) < 0.5 * nf["expected_N"]
        out.append(
            {
                "claim": "Point contact holds a steady force near K_E × penetration (3 N) without bouncing",
                "measured": f"true normal force {nf['true_mean_N']:.2f} ± {nf['true_std_N']:.2f} N "
                f"(expected {nf['expected_N']:.1f} N), in contact {100 * pc['contact']['fraction']:.0f} % "
                f"of the contact phase, lost: {pc['contact']['lost']}",
                "verdict": "reproduced" if ok else "not reproduced",
            }
        )
    pt = get("point-contact-tilted/nominal")
    if pt:
        nf = pt["normal_force"]
        under = nf["underestimate_N"]
        out.append(
            {
                "claim": "On the 30° tilted surface the nominal map underestimates the normal force (by ~1 N)",
                "measured": f"true {nf['true_mean_N']:.2f} N, estimated {nf['estimated_mean_N']:.2f} N "
                f"(underestimate {under:+.2f} N)",
                # the same band as the ten-seed goal (paper.claims.GOALS): ~1 N, not any underestimate
                "verdict": "reproduced" if _TILTED.passes(under) else ("partly" if under > 0 else "not reproduced"),
            }
        )
    ph = get("peg-in-hole/nominal")
    if ph:
        ins = ph["insertion"]
        # inserted and settled as the ten-seed goals say (paper.claims.GOALS: >= 16.5 cm, roll 3-7 deg); partly
        # when one holds, or when the roll at least turns toward the hole axis by a degree
        full, at_5 = _PEG_DEPTH.passes(_PEG_DEPTH.value(metrics)), _PEG_TILT.passes(_PEG_TILT.value(metrics))
        turns = ins["inserted_tilt_deg"] is not None and ins["inserted_tilt_deg"] < ins["approach_tilt_deg"] - 1.0
        out.append(
            {
                "claim": "Peg-in-hole inserts fully; the roll settles from the 10° approach misalignment towards "
                "the hole axis (~5°)",
                "measured": f"depth {100 * ins['max_depth_m']:.1f} of {100 * ins['target_depth_m']:.0f} cm; peg tilt "
                f"{ins['approach_tilt_deg']:.1f}° on approach, "
                + (f"{ins['inserted_tilt_deg']:.1f}° inserted" if ins["inserted_tilt_deg"] is not None else "n/a"),
                "verdict": "reproduced"
                if full and at_5
                else ("partly" if (full or at_5 or turns) else "not reproduced"),
            }
        )
    return out


def _fmt_row(vals) -> str:
    return " | ".join(f"{v:.2f}" for v in vals)


def write_report(path: Path, metrics: dict, figures: dict, quick: bool, disturbances: bool = True) -> Path:
    """Write the Markdown report: claims with verdicts, Table 1 ours vs the paper's, hover biases, figures."""
    lines = ["# omnirotor reproduction of Veenstra et al., Drones 2026", ""]
    lines.append(
        ("**Quick run** (shortened protocols: fewer hover attitudes, shorter holds and segments). " if quick else "")
        + "Simulation with the rotor-wake truth model calibrated on the authors' real hover data (docs/fidelity.md; "
        "never tuned per experiment), "
        + (
            "with the disturbances calibrated on Table 1's straight point-contact row (docs/fidelity.md)"
            if disturbances
            else "on the clean plant (no disturbances: `--no-disturbances`)"
        )
        + "; the paper's numbers are from the real robot."
    )
    lines += ["", "## Claims", "", "| claim | measured here | verdict |", "|---|---|---|"]
    for c in claims(metrics):
        lines.append(f"| {c['claim']} | {c['measured']} | **{c['verdict']}** |")
    lines += ["", "## Table 1: EE error against the compliant reference (RMS | max)", ""]
    lines.append(
        "Position in cm, attitude in degrees (controller attitude error). Ours, as the paper's (SPEC §6): the EE "
        "pose the robot believed (its state estimate); the true pose's RMS (which the paper could not measure) "
        "below it."
    )
    lines += ["", "| run | source | " + " | ".join(AXES) + " |", "|---|---|" + "---|" * len(AXES)]
    for key, ref in PAPER_TABLE1.items():
        m = metrics.get(key)
        lines.append(f"| {key} | paper RMS | {_fmt_row(ref['rms'])} |")
        if m:
            lines.append(f"| | ours RMS | {_fmt_row(m['ee_rms_error'][a] for a in AXES)} |")
            if "ee_rms_error_true" in m:
                lines.append(f"| | ours RMS, true pose | {_fmt_row(m['ee_rms_error_true'][a] for a in AXES)} |")
        lines.append(f"| | paper max | {_fmt_row(ref['max'])} |")
        if m:
            lines.append(f"| | ours max | {_fmt_row(m['ee_max_error'][a] for a in AXES)} |")
    lines += ["", "## Hover validation: estimated external force in hover (no external force acts)", ""]
    lines += ["| map | region | f^W mean (N) | f^W std (N) |", "|---|---|---|---|"]
    for mode in ("nominal", "global", "piecewise"):
        m = metrics.get(f"hover-validation/{mode}")
        if not m:
            continue
        for r, v in m["regions"].items():
            mean = ", ".join(f"{x:+.2f}" for x in v["force_W_mean_N"])
            std = ", ".join(f"{x:.2f}" for x in v["force_W_std_N"])
            lines.append(f"| {mode} | {r} | ({mean}) | ({std}) |")
    ident = metrics.get("identify")
    if ident:
        lines += ["", "## Identification (force residual RMS on the simulated hover data, N)", ""]
        lines += ["| map | points | nominal | identified |", "|---|---|---|---|"]
        for r, v in list(ident["regions"].items()) + [("global", ident["global"])]:
            lines.append(
                f"| {r} | {v['points']} | {v['nominal_force_residual_rms_N']:.3f} | {v['force_residual_rms_N']:.3f} |"
            )
    lines += ["", "## Contact and force (ground truth the paper could not measure)", ""]
    lines += [
        "| run | in contact (% of phase) | lost | first loss (s) | true mean force (N) | estimated (N) "
        "| est. RMS err (N) |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, m in metrics.items():
        if "contact" not in m:
            continue
        c, f = m["contact"], m["force"]

        def vec(v):
            return "—" if v is None else "(" + ", ".join(f"{x:+.2f}" for x in v) + ")"

        err = "—" if f["estimate_rms_error_N"] is None else f"{f['estimate_rms_error_N']:.2f}"
        first = "—" if c["first_loss_s"] is None else f"{c['first_loss_s']:.1f}"
        lines.append(
            f"| {key} | {100 * c['fraction']:.0f} | {c['lost']} | {first} | {vec(f['true_mean_N'])} | "
            f"{vec(f['estimated_mean_N'])} | {err} |"
        )
    lines += ["", "## Figures", ""]
    for name, p in figures.items():
        lines.append(f"![{name}]({Path(p).name})")
    for key, m in metrics.items():
        if "figure" in m:
            lines.append(f"![{key}]({Path(m['figure']).name})")
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path
