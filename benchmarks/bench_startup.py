"""Start-up benchmarks: the CLI's help (imports only) and the first run on a fresh machine (cold numba cache).

``python benchmarks/bench_startup.py [--repeats N] [--no-compile] [--against SRC --rounds K]`` prints one JSON
object. Each figure runs the CLI in a subprocess (the source tree of this checkout on ``PYTHONPATH``), so it
measures what a user waits for, interpreter start-up included.

* ``cli_help_s``: median wall time of ``omnirotor --help`` and of ``omnirotor identify --help`` (the larger;
  ``*_cpu_s_median``: their CPU times).
* ``first_run_compile_s``: wall time of a short hover run with an empty numba cache (``NUMBA_CACHE_DIR`` set to
  a fresh temporary folder) minus the same run again with the cache it left behind: the compilation a fresh
  machine pays once (``first_run_compile_cpu_s``: the same in CPU time, steadier on a loaded machine).
* ``--against SRC``: the first-run compilation of this checkout and of another source tree (``SRC``, e.g.
  ``../main/src``: before a change) alternated ``--rounds`` times, each in its own empty cache
  (``compile_vs``: every CPU and wall figure, the medians and the ratio new / old of the CPU medians). On a
  shared machine only an interleaved comparison says what a change did; the CPU time of the child is the figure.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
FIRST_RUN_ARGS = ("run", "hover", "--quick", "--duration", "0.2", "--json")
"""The first-run workload: the hover task with the default controller (UKF) and truth model, 0.2 s simulated."""


def _env(src: Path = REPO / "src", **extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(src) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.setdefault("MUJOCO_GL", "egl")
    env.update(extra)
    return env


def _cli_times(args: tuple[str, ...], env: dict[str, str]) -> tuple[float, float]:
    """Wall and CPU time [s] of one ``omnirotor ARGS`` in a new interpreter (raises if it fails)."""
    cmd = [sys.executable, "-c", "import sys; from omnirotor.cli import main; sys.exit(main())", *args]
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f"omnirotor {' '.join(args)} failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def _cli(args: tuple[str, ...], env: dict[str, str]) -> float:
    """Wall time [s] of one ``omnirotor ARGS`` in a new interpreter (raises if it fails)."""
    return _cli_times(args, env)[0]


def measure_cli_help(repeats: int) -> dict:
    """Median and all wall times [s] of ``omnirotor --help`` and ``omnirotor identify --help``, interleaved.

    Also the median CPU time (user + system) of each, which the load of a shared machine disturbs less.
    """
    env = _env()
    out = {}
    cases = (("help", ("--help",)), ("identify_help", ("identify", "--help")))
    for _, args in cases:
        _cli(args, env)  # warm the OS file cache and Python's bytecode cache
    times: dict[str, list[tuple[float, float]]] = {key: [] for key, _ in cases}
    for _ in range(repeats):
        for key, args in cases:
            times[key].append(_cli_times(args, env))
    for key, _ in cases:
        walls = [w for w, _ in times[key]]
        out[f"{key}_s_median"] = statistics.median(walls)
        out[f"{key}_cpu_s_median"] = statistics.median(c for _, c in times[key])
        out[f"{key}_s"] = walls
    out["cli_help_s"] = max(out["help_s_median"], out["identify_help_s_median"])
    return out


def measure_first_run_compile(src: Path = REPO / "src") -> dict:
    """Cold-cache and warm-cache wall times [s] of the first-run workload (sources ``src``), and their difference."""
    with tempfile.TemporaryDirectory(prefix="omnirotor-numba-cache-") as cache:
        env = _env(src, NUMBA_CACHE_DIR=cache)
        cold, cold_cpu = _cli_times(FIRST_RUN_ARGS, env)
        warm, warm_cpu = _cli_times(FIRST_RUN_ARGS, env)
        files = sum(1 for _ in Path(cache).rglob("*.nbc"))
    return {
        "first_run_compile_s": cold - warm,
        "first_run_compile_cpu_s": cold_cpu - warm_cpu,
        "cold_wall_s": cold,
        "warm_wall_s": warm,
        "compiled_specialisations": files,
        "workload": "omnirotor " + " ".join(FIRST_RUN_ARGS),
    }


def compare_first_run_compile(old_src: Path, rounds: int) -> dict:
    """:func:`measure_first_run_compile` of this checkout and of ``old_src``, alternated ``rounds`` times."""
    runs: dict[str, list[dict]] = {"new": [], "old": []}
    pair = (("new", REPO / "src"), ("old", old_src))
    for r in range(rounds):
        for key, src in pair if r % 2 == 0 else pair[::-1]:  # each goes first in every other round
            runs[key].append(measure_first_run_compile(src))
            cpu = runs[key][-1]["first_run_compile_cpu_s"]
            print(f"round {r + 1}/{rounds} {key}: {cpu:.1f} s CPU", file=sys.stderr)
    out: dict = {"old_src": str(old_src), "new_src": str(REPO / "src"), "rounds": rounds, "load_avg": os.getloadavg()}
    for key in runs:
        out[f"{key}_cpu_s"] = [x["first_run_compile_cpu_s"] for x in runs[key]]
        out[f"{key}_wall_s"] = [x["first_run_compile_s"] for x in runs[key]]
        out[f"{key}_specialisations"] = runs[key][0]["compiled_specialisations"]
        out[f"{key}_cpu_s_median"] = statistics.median(out[f"{key}_cpu_s"])
    out["ratio_new_over_old_cpu"] = out["new_cpu_s_median"] / out["old_cpu_s_median"]
    return out


def main(argv: list[str] | None = None) -> int:
    """Command line (module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7, help="runs of each help command")
    ap.add_argument("--no-compile", action="store_true", help="skip the cold-cache first run")
    ap.add_argument("--against", type=Path, help="another source tree: compare its first-run compilation")
    ap.add_argument("--rounds", type=int, default=2, help="alternations with --against")
    args = ap.parse_args(argv)
    if args.against is not None:
        if not (args.against / "omnirotor").is_dir():
            print(f"bench_startup: {args.against} holds no omnirotor package", file=sys.stderr)
            return 2
        print(json.dumps({"compile_vs": compare_first_run_compile(args.against.resolve(), args.rounds)}, indent=1))
        return 0
    out = measure_cli_help(args.repeats)
    if not args.no_compile:
        out.update(measure_first_run_compile())
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
