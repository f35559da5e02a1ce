"""The closed loop of this checkout against an older source tree, both flying the same physics.

``python benchmarks/equal_physics.py --other DIR [--rounds 4]`` prints one JSON object. ``DIR`` is the source tree
of an older commit (``git archive COMMIT | tar -x -C DIR``). Later commits added physics that costs time per
step (the compliant tool, the disturbances); to see what the code's structure costs, this checkout flies the
older plant: the rigid tool and no disturbances (the rotor-wake truth costs nothing over SPEC §7's, measured at
its commit). A tree whose options do not know these settings flies its defaults, which are that plant.

Workload: the quick sliding task with the bypass estimator, 3 seeds per round after one warm-up run (each tree
compiles into its own ``__pycache__`` first), real-time factor by CPU time of the process (steadier than wall
time on a shared machine); rounds alternate the order of the trees; the figures are medians over the rounds.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

PROBE = """
import json, resource
from omnirotor.experiments.tasks import run_task
from omnirotor.experiments.tasks.common import ExperimentOptions

def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime

def options(seed):
    try:
        return ExperimentOptions(quick=True, estimator="bypass", seed=seed, disturbances=False,
                                 sim_overrides=("scene.tool_compliant=false",))
    except TypeError:  # an older tree: its defaults are the rigid tool without disturbances
        return ExperimentOptions(quick=True, estimator="bypass", seed=seed)

run_task("sliding", options(0))
rtf = []
for seed in range(3):
    c0 = cpu()
    res = run_task("sliding", options(seed))
    rtf.append(res.duration_s / (cpu() - c0))
print(json.dumps({"rtf_cpu": sorted(rtf)[1]}))
"""


def measure(tree: Path) -> float:
    """The median real-time factor by CPU time of one round of ``tree`` (module docstring)."""
    env = dict(os.environ, PYTHONPATH=str(tree / "src"))
    env.setdefault("MUJOCO_GL", "egl")
    proc = subprocess.run([sys.executable, "-c", PROBE], cwd=tree, env=env, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"{tree}: {proc.stderr.strip()[-800:]}")
    return float(json.loads(proc.stdout.strip().splitlines()[-1])["rtf_cpu"])


def main(argv: list[str] | None = None) -> int:
    """Command line (module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--other", type=Path, required=True, help="source tree of the older commit")
    ap.add_argument("--rounds", type=int, default=4)
    args = ap.parse_args(argv)
    trees = {"this": REPO, "other": args.other.resolve()}
    for tree in trees.values():  # compile both first
        measure(tree)
    runs: dict[str, list[float]] = {"this": [], "other": []}
    for r in range(args.rounds):
        for name in ("this", "other") if r % 2 == 0 else ("other", "this"):
            runs[name].append(measure(trees[name]))
    med = {k: statistics.median(v) for k, v in runs.items()}
    print(json.dumps({"rtf_cpu_median": med, "ratio_this_over_other": med["this"] / med["other"], "rounds": runs}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
