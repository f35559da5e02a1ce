"""The controller's speed on this checkout and on another source tree, measured side by side, runs interleaved.

``python benchmarks/side_by_side.py --other DIR [--rounds 4] [--sliding-s 8]`` prints one JSON object and a
Markdown table. ``DIR`` is a whole source tree of another commit (``git archive COMMIT | tar -x -C DIR``); each
tree is measured by its own ``benchmarks/`` code in its own processes, with its own numba cache (the trees'
``__pycache__``; the first round of a tree that was never run compiles, so run it once first or read from the
second round on). Round ``r`` runs the two trees in the order A B when ``r`` is even and B A when odd, so that
a change of the machine's load during the measurement weighs on both alike; the figures are medians over the
rounds. One round of a tree, in one process:

* ``bypass_us``, ``ukf_us``: median wall time of ``InteractionController.step`` over 3000 recorded frames
  (``bench_controller.bench_controller_step``), the bypass estimator and the UKF;
* ``sliding_<kind>_rtf``, ``sliding_<kind>_rtf_cpu``: the closed loop (simulator and controller) on the sliding
  task's first ``--sliding-s`` seconds (quick scenario), real-time factor by wall and by CPU time
  (``workloads.run_sliding``); the simulator differs between commits, so
* ``sliding_<kind>_ctl_us``: the controller's step inside that compiled loop (median), which the simulator
  does not change; ``sliding_<kind>_plant_us``: the simulator's step there.
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
import json, sys
sys.path.insert(0, "benchmarks")
from bench_controller import bench_controller_step
import workloads
out = {}
step = bench_controller_step(3000)
out["bypass_us"] = step["bypass_us_median"]
out["ukf_us"] = step["ukf_us_median"]
for kind in ("ukf", "bypass"):
    r = workloads.run_sliding(kind, float(sys.argv[1]), True)
    out[f"sliding_{kind}_rtf"] = r["rtf"]
    out[f"sliding_{kind}_rtf_cpu"] = r["rtf_cpu"]
    out[f"sliding_{kind}_ctl_us"] = r["controller_step_us_median"]
    out[f"sliding_{kind}_plant_us"] = r["plant_step_us_median"]
print(json.dumps(out))
"""


def measure(tree: Path, sliding_s: float) -> dict:
    """One round of the figures (module docstring) of the source tree ``tree``, in a new process."""
    env = dict(os.environ, PYTHONPATH=str(tree / "src"))
    env.setdefault("MUJOCO_GL", "egl")
    proc = subprocess.run(
        [sys.executable, "-c", PROBE, str(sliding_s)], cwd=tree, env=env, capture_output=True, text=True, check=False
    )
    if proc.returncode != 0:
        raise RuntimeError(f"{tree}: {proc.stderr.strip()[-800:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def compare(other: Path, rounds: int, sliding_s: float) -> dict:
    """Interleaved rounds of this checkout ("this") and ``other``; medians and every round's figures."""
    trees = {"this": REPO, "other": other}
    runs: dict[str, list[dict]] = {"this": [], "other": []}
    for r in range(rounds):
        order = ("other", "this") if r % 2 == 0 else ("this", "other")
        for name in order:
            runs[name].append(measure(trees[name], sliding_s))
            print(f"round {r + 1}/{rounds} {name}: {json.dumps(runs[name][-1])}", file=sys.stderr)
    keys = list(runs["this"][0])
    out: dict = {"other": str(other), "rounds": rounds, "sliding_s": sliding_s}
    for name, rs in runs.items():
        out[name] = {k: statistics.median(x[k] for x in rs) for k in keys}
        out[name]["runs"] = rs
    out["ratio_this_over_other"] = {k: out["this"][k] / out["other"][k] for k in keys}
    return out


def markdown(result: dict) -> str:
    """A table of the medians: this checkout, the other tree, their ratio."""
    lines = ["| figure | other | this | this / other |", "|---|---|---|---|"]
    for k, ratio in result["ratio_this_over_other"].items():
        lines.append(f"| {k} | {result['other'][k]:.2f} | {result['this'][k]:.2f} | {ratio:.3f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Command line (module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--other", type=Path, required=True, help="source tree of the other commit")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--sliding-s", type=float, default=8.0, help="simulated seconds of each sliding run")
    args = ap.parse_args(argv)
    if not (args.other / "src" / "omnirotor").is_dir() or not (args.other / "benchmarks").is_dir():
        print(f"side_by_side: error: {args.other} is not a source tree (src/omnirotor, benchmarks/)", file=sys.stderr)
        return 2
    result = compare(args.other.resolve(), args.rounds, args.sliding_s)
    print(json.dumps(result, indent=1))
    print(markdown(result), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
