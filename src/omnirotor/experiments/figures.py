"""Figures of the experiments, as PNG (matplotlib, no display needed).

* :func:`plot_run`: one interaction run: end-effector position against the compliant and desired references,
  attitude error, the observer's force estimate against the true contact force (with the point contact's
  target force, the one its claim is judged by), contact phases shaded and wrench-map region switches marked
  (the paper's Figs. 5–9, plus the ground truth it could not show); for the peg, a fifth panel with the
  insertion depth and the peg's tilt over time against their goals (:class:`PegPanel`).
* :func:`plot_hover_violins`: the estimated external wrench in hover per map and region (the paper's Fig. 3).
* :func:`plot_table1`: our Table 1 beside the paper's.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from omnirotor.experiments.metrics import AXES, RunLog, held_contact, pose_errors, smoothed  # noqa: E402
from omnirotor.safe_io import atomic_path  # noqa: E402

__all__ = ["plot_run", "PegPanel", "plot_hover_violins", "plot_table1", "save_figure"]

_MAP_COLORS = {"nominal": "#c0392b", "global": "#2980b9", "piecewise": "#27ae60"}


def save_figure(fig, path: str | Path, dpi: int = 120, tight: bool = True, close: bool = True) -> Path:
    """Write a figure atomically as PNG and close it (unless ``close`` is False: the caller draws on it again).

    ``tight`` crops it to its contents (``bbox_inches="tight"``, which draws it twice); a figure with fixed
    margins and no layout engine is drawn once.
    """
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, bbox_inches="tight" if tight else None)
    finally:
        if close:
            plt.close(fig)
    return Path(path)


def _shade_contact(ax, t: np.ndarray, in_contact: np.ndarray) -> None:
    c = in_contact.astype(bool)
    if not c.any():
        return
    edges = np.flatnonzero(np.diff(np.concatenate([[0], c.astype(int), [0]])))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        ax.axvspan(t[a], t[min(b, t.size - 1)], color="#f5b041", alpha=0.18, lw=0)


def _switches(log: RunLog) -> np.ndarray:
    """Indices where the wrench-map region changed."""
    return np.flatnonzero(np.diff(log.region) != 0) + 1


def _mark(ax, log: RunLog, marks, region_names) -> None:
    for tm, _label in marks:
        ax.axvline(tm, color="0.6", lw=0.8, ls=":")
    for i in _switches(log):
        ax.axvline(log.t[i], color="#8e44ad", lw=1.0, ls="--")


class PegPanel(NamedTuple):
    """What the peg's panel of :func:`plot_run` draws.

    Attributes:
        depth_m: (N,) insertion depth past the hole's entrance [m].
        tilt_deg: (N,) the peg's angle to the hole's axis [deg].
        target_depth_m: the planned insertion [m].
        depth_goal_m: the depth the claim asks for [m].
        tilt_goal_deg: (lo, hi) the band the inserted tilt should settle in [deg].
    """

    depth_m: np.ndarray
    tilt_deg: np.ndarray
    target_depth_m: float
    depth_goal_m: float
    tilt_goal_deg: tuple[float, float]


def _peg_panel(ax, t: np.ndarray, peg: PegPanel) -> None:
    ax.plot(t, 100 * np.maximum(peg.depth_m, 0.0), color="k", lw=1.4, label="insertion depth")
    ax.axhline(100 * peg.target_depth_m, color="k", lw=0.8, ls=":", label=f"planned {100 * peg.target_depth_m:.0f} cm")
    ax.axhline(100 * peg.depth_goal_m, color="k", lw=1.0, ls="--", label=f"goal ≥ {100 * peg.depth_goal_m:.1f} cm")
    ax.set_ylabel("insertion depth [cm]")
    ax.set_ylim(-0.5, 100 * max(peg.target_depth_m, float(np.nanmax(peg.depth_m))) * 1.5)  # room for the legend
    tw = ax.twinx()
    tw.plot(t, peg.tilt_deg, color="#d35400", lw=1.0, label="peg tilt to hole axis")
    lo, hi = peg.tilt_goal_deg
    tw.axhspan(lo, hi, color="#d35400", alpha=0.12, lw=0, label=f"tilt goal {lo:g}–{hi:g}° (inserted)")
    tw.set_ylabel("tilt [deg]", color="#d35400")
    tw.set_ylim(0, max(15.0, float(np.nanmax(peg.tilt_deg[t > t[0] + 1.0])) * 1.1 if t.size else 15.0))
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = tw.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, fontsize=7, loc="upper left", ncol=3)


def plot_run(
    log: RunLog,
    title: str,
    path: str | Path,
    marks=(),
    region_names=(),
    force_target_N: float | None = None,
    peg: PegPanel | None = None,
) -> Path:
    """Four stacked panels of one run, five with the peg's (see module docstring).

    Args:
        log: the run.
        title: the figure's title.
        path: PNG path.
        marks: (time, label) of the protocol's phases (dotted lines).
        region_names: names of the map regions (the region axis).
        force_target_N: the contact force the task's claim is judged by (drawn on the force-norm panel).
        peg: the peg's depth and tilt and their goals (a fifth panel).
    """
    rows = 5 if peg is not None else 4
    fig, axs = plt.subplots(rows, 1, figsize=(9, 2.5 * rows), sharex=True, constrained_layout=True)
    t = log.t
    cols = ("x", "y", "z")
    colors = ("#c0392b", "#27ae60", "#2980b9")
    ax = axs[0]
    for k in range(3):
        ax.plot(t, log.p_E_W[:, k], color=colors[k], lw=1.4, label=f"{cols[k]} actual")
        ax.plot(t, log.p_Er_W[:, k], color=colors[k], lw=1.0, ls="--", label=f"{cols[k]} compliant ref.")
        ax.plot(t, log.p_Ed_W[:, k], color=colors[k], lw=0.8, ls=":", alpha=0.8)
    ax.set_ylabel("EE position [m]")
    ax.legend(ncol=3, fontsize=7, loc="upper right")
    e = pose_errors(log)
    ax = axs[1]
    for k in range(3):
        ax.plot(t, e[:, k], color=colors[k], lw=1.0, label=f"e_{cols[k]}")
    ax.set_ylabel("EE position error [cm]\n(believed pose, as Table 1)")
    ax.legend(ncol=3, fontsize=7)
    ax2 = ax.twinx()
    for k in range(3):
        ax2.plot(t, e[:, 3 + k], color=colors[k], lw=0.7, alpha=0.5)
    ax2.set_ylabel("attitude error [deg] (faint,\nbelieved pose)")
    ax = axs[2]
    f_true = smoothed(log.f_contact_W, t)
    for k in range(3):
        ax.plot(t, f_true[:, k], color=colors[k], lw=1.6, label=f"true f_{cols[k]}")
        ax.plot(t, log.f_ext_hat_W[:, k], color=colors[k], lw=1.0, ls="--", label=f"estimated f_{cols[k]}")
    ax.set_ylabel("contact force on robot,\nworld [N] (true: 20 ms mean)")
    ax.legend(ncol=3, fontsize=7)
    ax = axs[3]
    ax.plot(t, np.linalg.norm(f_true, axis=1), color="k", lw=1.5, label="|true contact force| (20 ms mean)")
    ax.plot(t, np.linalg.norm(log.f_ext_hat_W, axis=1), color="0.5", lw=1.0, ls="--", label="|estimate|")
    if force_target_N is not None:
        ax.axhline(force_target_N, color="#1abc9c", lw=1.4, label=f"target K_E × penetration ({force_target_N:.1f} N)")
        ax.set_ylim(top=max(ax.get_ylim()[1], 1.6 * force_target_N))  # room for the legend above the target
    ax.set_ylabel("force norm [N]")
    ax.set_xlabel("time [s]")
    if region_names and (log.region >= 0).any():
        ax3 = ax.twinx()
        ax3.step(t, log.region, where="post", color="#8e44ad", lw=0.8)
        ticks = sorted(set(int(r) for r in np.unique(log.region) if r >= 0))
        ax3.set_yticks(ticks, [region_names[i] for i in ticks])
        ax3.set_ylabel("map region", color="#8e44ad")
    ax.legend(fontsize=7, loc="upper left")
    if peg is not None:
        axs[3].set_xlabel("")
        _peg_panel(axs[4], t, peg)
        axs[4].set_xlabel("time [s]")
    held = held_contact(log.in_contact, t)
    for ax in axs:
        _shade_contact(ax, t, held)
        _mark(ax, log, marks, region_names)
        ax.grid(alpha=0.3)
    legend = "shaded: tip in contact" + ("; dashed purple: map switch" if _switches(log).size else "")
    fig.suptitle(f"{title}   ({legend})", fontsize=10)
    return save_figure(fig, path)


def plot_hover_violins(samples: dict[str, dict[str, np.ndarray]], path: str | Path) -> Path:
    """Violins of the estimated world force in hover, per region and map.

    Args:
        samples: ``samples[map][region]`` = (k, 3) estimated force samples ``f̂_ext^W`` [N].
        path: PNG path.
    """
    maps = list(samples)
    regions = sorted({r for m in maps for r in samples[m]}, key=lambda r: int(r[1:]) if r[1:].isdigit() else 99)
    fig, axs = plt.subplots(1, 3, figsize=(12, 4), sharey=True, constrained_layout=True)
    width = 0.8 / max(1, len(maps))
    for k, comp in enumerate(("f_x", "f_y", "f_z")):
        ax = axs[k]
        for i, m in enumerate(maps):
            pos, data = [], []
            for j, r in enumerate(regions):
                if r in samples[m] and len(samples[m][r]):
                    pos.append(j + (i - (len(maps) - 1) / 2) * width)
                    data.append(samples[m][r][:, k])
            if data:
                color = _MAP_COLORS.get(m, "0.5")
                parts = ax.violinplot(data, positions=pos, widths=width * 0.95, showmedians=True)
                for body in parts["bodies"]:
                    body.set_facecolor(color)
                    body.set_edgecolor(color)
                    body.set_alpha(0.6)
                for key in ("cmedians", "cmins", "cmaxes", "cbars"):  # the bars take the violin's colour
                    if key in parts:
                        parts[key].set_color(color)
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xticks(range(len(regions)), regions)
        ax.set_title(f"estimated {comp}^W in hover")
        ax.grid(alpha=0.3, axis="y")
    axs[0].set_ylabel("N")
    handles = [plt.Rectangle((0, 0), 1, 1, color=_MAP_COLORS.get(m, "0.5"), alpha=0.6) for m in maps]
    # one legend above the panels, clear of the data
    fig.legend(handles, [f"{m} map" for m in maps], loc="outside upper center", ncol=len(maps), fontsize=9)
    return save_figure(fig, path)


def plot_table1(ours: dict[str, dict], paper: dict[str, dict], path: str | Path) -> Path:
    """RMS errors per axis, ours beside the paper's, one group per run."""
    runs = [r for r in paper if r in ours]
    fig, axs = plt.subplots(1, 2, figsize=(12, 4), constrained_layout=True)
    for ax, sl, unit in ((axs[0], slice(0, 3), "cm"), (axs[1], slice(3, 6), "deg")):
        names = AXES[sl]
        x = np.arange(len(runs))
        w = 0.8 / (2 * len(names))
        for j, a in enumerate(names):
            ax.bar(x + (2 * j) * w, [paper[r]["rms"][AXES.index(a)] for r in runs], w, color=f"C{j}", alpha=0.45)
            ax.bar(x + (2 * j + 1) * w, [ours[r]["ee_rms_error"][a] for r in runs], w, color=f"C{j}", label=a)
        ax.set_xticks(x + 0.4 - w, [r.replace("/", "\n") for r in runs], fontsize=7)
        ax.set_ylabel(f"RMS error [{unit}]")
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3, axis="y")
    fig.suptitle("Table 1: RMS EE error vs compliant reference — pale: paper (real robot), solid: this simulation")
    return save_figure(fig, path)
