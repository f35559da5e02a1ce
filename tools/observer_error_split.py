"""Split the observer's error against the true contact force of one run (issue 12: the clean plant's 0.76 N).

Flies a contact task (clean plant by default) and splits ``f̂ − f_contact`` (world, while touching in the contact
phase) into the nominal map's error at the flown rotor speeds, ``R (F_true(u) − A₁ u)`` less its value in the
start hover (what the observer's zeroing captured, SPEC §4.3), passed through the observer's own filters
(first order at L, then the output low-pass), and what remains (filter lag on force changes, touch-down, noise).

Run: ``python tools/observer_error_split.py [TASK] [--seed N] [--disturbances]`` (docs/fidelity.md).
"""

from __future__ import annotations

import argparse

import numpy as np

from omnirotor.control.observer import ObserverParams, lowpass_coefficient
from omnirotor.experiments.metrics import held_contact
from omnirotor.experiments.tasks import run_task
from omnirotor.experiments.tasks.common import ExperimentOptions
from omnirotor.sim import SimParams
from omnirotor.sim.aero import make_aero
from omnirotor.vehicle import load_vehicle


def _first_order(x: np.ndarray, a: float) -> np.ndarray:
    y = np.empty_like(x)
    y[0] = x[0]
    for k in range(1, len(x)):
        y[k] = y[k - 1] + a * (x[k] - y[k - 1])
    return y


def _rms(x: np.ndarray, mask: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(x[mask] ** 2, axis=1))))


def main() -> None:
    """Fly the task and print the split."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("task", nargs="?", default="point-contact")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--disturbances", action="store_true", help="fly the calibrated disturbances too")
    a = ap.parse_args()
    res = run_task(a.task, ExperimentOptions(seed=a.seed, disturbances=a.disturbances))
    log, truth = res.log, res.truth_log
    vehicle = load_vehicle("omnirotor")
    aero = make_aero(vehicle, SimParams().aero)
    n = log.t.size
    w = truth.group("rotor_hz")[:n]
    u = np.abs(w) * w
    R = truth.group("R_WB")[:n].reshape(n, 3, 3)
    F_B = np.array([aero.wrench_B(ui)[:3] for ui in u]) - u @ vehicle.A_nom[:3].T
    eps = np.einsum("nij,nj->ni", R, F_B)  # the nominal map's force error, world [N]
    obs = ObserverParams(zero_at_start=True)
    dt = float(np.median(np.diff(log.t)))
    t0 = obs.zero_settle_s
    eps0 = eps[(log.t >= t0) & (log.t <= t0 + obs.zero_window_s)].mean(axis=0)
    lam = lowpass_coefficient(obs.cutoff_hz, dt)
    map_part = _first_order(_first_order(eps, float(obs.gain_force[0]) * dt), lam) - eps0
    touch = log.window(*res.scenario.contact_phase) & held_contact(log.in_contact, log.t)
    e = log.f_ext_hat_W - log.f_contact_W
    after = touch & (log.t >= log.t[touch][0] + 1.0)
    print(f"{a.task}, seed {a.seed}, {'disturbed' if a.disturbances else 'clean'} plant, {touch.sum()} samples")
    print(f"observer error RMS               {_rms(e, touch):.3f} N")
    print(f"  the nominal map's error part   {_rms(map_part, touch):.3f} N")
    print(f"  the rest                       {_rms(e - map_part, touch):.3f} N")
    print(f"  from 1 s after touch-down      {_rms(e, after):.3f} N")
    print(f"  mean per world axis            {np.round(e[touch].mean(axis=0), 3).tolist()} N")
    print(f"  the map's part, mean per axis  {np.round(map_part[touch].mean(axis=0), 3).tolist()} N")
    print(f"  true contact force, mean       {np.round(log.f_contact_W[touch].mean(axis=0), 3).tolist()} N")


if __name__ == "__main__":
    main()
