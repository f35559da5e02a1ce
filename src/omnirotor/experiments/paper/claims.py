"""The paper's claims as goals checked on runs' metrics (SPEC §6; issue 12, item 4).

Each :class:`Goal` reads one value from a run's ``metrics.json`` (``omnirotor reproduce``) and says whether it
passes; :data:`GOALS` are the goals of the claims, stated beside the paper's numbers; :func:`evaluate_goals`
checks them over seeds (:mod:`omnirotor.experiments.paper.seeds`). ``reproduce``'s one-run verdicts use the same
goals (:mod:`omnirotor.experiments.paper.reproduce`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from omnirotor.experiments.metrics import PEG_DEPTH_GOAL_CM, PEG_TILT_GOAL_DEG

__all__ = ["Goal", "GOALS", "evaluate_goals"]


def _mean_fz(m: dict, mode: str) -> list[float] | None:
    hv = m.get(f"hover-validation/{mode}")
    return None if hv is None else [r["force_W_mean_N"][2] for r in hv["regions"].values()]


def _hover_nominal(m: dict) -> float | None:
    fz = _mean_fz(m, "nominal")
    return None if fz is None else float(np.mean(fz))


def _hover_piecewise(m: dict) -> float | None:
    fz = _mean_fz(m, "piecewise")
    return None if fz is None else float(np.max(np.abs(fz)))


def _lost(mode: str) -> Callable[[dict], float | None]:
    def value(m: dict) -> float | None:
        s = m.get(f"sliding/{mode}")
        return None if s is None else float(bool(s["contact"]["lost"]))

    return value


def _underestimate(m: dict) -> float | None:
    pt = m.get("point-contact-tilted/nominal")
    return None if pt is None or "normal_force" not in pt else float(pt["normal_force"]["underestimate_N"])


def _observer_error(m: dict) -> float | None:
    pc = m.get("point-contact/nominal")
    err = None if pc is None else pc.get("force", {}).get("estimate_rms_error_N")
    return None if err is None else float(err)


def _peg_depth(m: dict) -> float | None:
    ph = m.get("peg-in-hole/nominal")
    return None if ph is None else 100.0 * float(ph["insertion"]["max_depth_m"])


def _peg_tilt(m: dict) -> float | None:
    ph = m.get("peg-in-hole/nominal")
    tilt = None if ph is None else ph["insertion"]["inserted_tilt_deg"]
    return None if tilt is None else float(tilt)


@dataclasses.dataclass(frozen=True)
class Goal:
    """One claim's goal, checked per seed.

    Attributes:
        name: short name (JSON key).
        text: the goal in words, with the paper's figure.
        unit: unit of the value.
        value: the measured value of one seed's ``metrics.json`` (None: the run is missing).
        lo: lowest passing value (inclusive; -inf for none).
        hi: highest passing value (inclusive; inf for none).
        need_fraction: fraction of the seeds that must pass (1.0: all).
    """

    name: str
    text: str
    unit: str
    value: Callable[[dict], float | None]
    lo: float = -math.inf
    hi: float = math.inf
    need_fraction: float = 1.0

    def passes(self, v: float | None) -> bool:
        """Whether one seed's value passes."""
        return v is not None and math.isfinite(v) and self.lo <= v <= self.hi


GOALS: tuple[Goal, ...] = (
    Goal("hover_bias_nominal", "hover: nominal map's mean f_z over regions 1.5–2.5 N (paper ~2 N), ≥ 8 of 10",
         "N", _hover_nominal, 1.5, 2.5, 0.8),
    Goal("hover_bias_piecewise", "hover: piecewise maps' |f_z| ≤ 0.3 N in every region, ≥ 8 of 10", "N",
         _hover_piecewise, hi=0.3, need_fraction=0.8),
    Goal("sliding_nominal_loses", "sliding to 45°: the nominal map loses contact, ≥ 8 of 10", "lost",
         _lost("nominal"), 1.0, 1.0, 0.8),
    Goal("sliding_global_keeps", "sliding to 45°: the global map keeps contact, 10 of 10", "lost",
         _lost("global"), 0.0, 0.0),
    Goal("sliding_piecewise_keeps", "sliding to 45°: the piecewise maps keep contact, 10 of 10", "lost",
         _lost("piecewise"), 0.0, 0.0),
    Goal("tilted_underestimate", "30° tilted point contact: the nominal map underestimates the normal force by "
         "0.7–1.3 N (paper ~1 N), ≥ 8 of 10", "N", _underestimate, 0.7, 1.3, 0.8),
    Goal("observer_error_point", "straight point contact: observer RMS error against the true force ≤ 0.5 N, "
         "≥ 8 of 10", "N", _observer_error, hi=0.5, need_fraction=0.8),
    Goal("peg_depth", f"peg inserted ≥ {PEG_DEPTH_GOAL_CM:g} of 17 cm, ≥ 8 of 10", "cm", _peg_depth,
         lo=PEG_DEPTH_GOAL_CM, need_fraction=0.8),
    Goal("peg_tilt", f"peg's roll settles from the 10° approach to {PEG_TILT_GOAL_DEG[0]:g}–{PEG_TILT_GOAL_DEG[1]:g}° "
         "inserted (paper ~5°), ≥ 8 of 10", "deg", _peg_tilt, *PEG_TILT_GOAL_DEG, 0.8),
)  # fmt: skip
"""The issue's goals for the claims (module docstring)."""


def evaluate_goals(per_seed: dict[int, dict], goals: tuple[Goal, ...] = GOALS) -> list[dict]:
    """Each goal's values and verdicts per seed, and whether it is met over the seeds.

    Args:
        per_seed: seed → that seed's ``metrics.json`` content.
        goals: the goals.

    Returns:
        One dict per goal: ``name``, ``text``, ``unit``, ``values`` and ``passed`` (lists over the seeds in
        order), ``seeds``, ``passes``, ``need`` (passes needed), ``met``.
    """
    seeds = sorted(per_seed)
    out = []
    for g in goals:
        values = [g.value(per_seed[s]) for s in seeds]
        passed = [g.passes(v) for v in values]
        need = math.ceil(g.need_fraction * len(seeds) - 1e-9)
        out.append(
            {
                "name": g.name,
                "text": g.text,
                "unit": g.unit,
                "seeds": seeds,
                "values": values,
                "passed": passed,
                "passes": int(sum(passed)),
                "need": need,
                "met": bool(sum(passed) >= need and all(v is not None for v in values)),
            }
        )
    return out
