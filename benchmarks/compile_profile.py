"""Where the first run's compilation goes: CPU time per compiled function and per LLVM phase, cold numba cache.

``python benchmarks/compile_profile.py [--out FILE] [--top N]`` runs the first-run workload of
``bench_startup.py`` (``omnirotor run hover --quick --duration 0.2``) in this process with ``NUMBA_CACHE_DIR``
set to a new empty folder, and prints a table (JSON with ``--out``):

* per compiled function (module-qualified name; ``inline`` = ``_jit.jit_inline``, ``jit`` = the others): how
  many specialisations, the CPU time of their compiles without the compiles they started (``excl_s``: typing,
  lowering, LLVM of its own module with its linked callees) and with them (``incl_s``), of it the LLVM phases
  below (``llvm_s``: the rest of ``excl_s`` is numba's front end), and who asked for each compile
  (``callers``: the function whose compile started it, or ``(Python)``), from numba's ``numba:compile`` events;
* the CPU time of numba's LLVM phases over all functions: per-function optimisation while adding IR
  (``add_ir_module``, parsing included), the module-level optimisation of a library with its linked
  callees (``optimize_module``) and the emission of machine code (``emit_machine_code``), with their counts.

Everything not in those phases is numba's front end (bytecode analysis, typing, lowering to IR). CPU time,
as the machine is shared; a profile runs a little slower than the plain run (the event listener).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
_PHASES = (
    ("CPUCodeLibrary", "add_ir_module", "add_ir_module"),
    ("CPUCodeLibrary", "_optimize_final_module", "optimize_module"),
    ("JITCodeLibrary", "_finalize_specific", "emit_machine_code"),
)


def _time_phases(phase_s: dict, phase_n: collections.Counter, stack: list) -> None:
    """Wrap numba's LLVM phase methods to add their CPU time to ``phase_s`` (and count calls).

    The time of a phase is also added to the compile on top of ``stack`` (its last item, a dict by phase).
    """
    from numba.core import codegen

    for cls_name, method, key in _PHASES:
        cls = getattr(codegen, cls_name)
        orig = getattr(cls, method)

        def timed(self, *args, _orig=orig, _key=key, **kwargs):
            t0 = time.process_time()
            try:
                return _orig(self, *args, **kwargs)
            finally:
                dt = time.process_time() - t0
                phase_s[_key] += dt
                phase_n[_key] += 1
                if stack:
                    stack[-1][3][_key] += dt

        setattr(cls, method, timed)


def profile(args: tuple[str, ...]) -> dict:
    """Run ``omnirotor ARGS`` here, cold, and return the profile (module docstring)."""
    from numba.core import event

    phase_s: dict[str, float] = collections.defaultdict(float)
    phase_n: collections.Counter = collections.Counter()
    funcs: dict[tuple[str, str], dict] = {}
    stack: list[list] = []
    _time_phases(phase_s, phase_n, stack)

    def name_of(d) -> str:
        return f"{d.py_func.__module__}.{d.py_func.__qualname__}"

    class Listener(event.Listener):
        def on_start(self, ev):
            stack.append([ev.data["dispatcher"], time.process_time(), 0.0, collections.defaultdict(float)])

        def on_end(self, ev):
            d, t0, children, phases = stack.pop()
            incl = time.process_time() - t0
            if stack:
                stack[-1][2] += incl
            kind = "inline" if d.targetoptions.get("inline") == "always" else "jit"
            row = funcs.setdefault(
                (name_of(d), kind), {"n": 0, "excl_s": 0.0, "incl_s": 0.0, "llvm_s": 0.0, "callers": []}
            )
            row["n"] += 1
            row["excl_s"] += incl - children
            row["incl_s"] += incl
            row["llvm_s"] += sum(phases.values())
            row["callers"].append(name_of(stack[-1][0]) if stack else "(Python)")

    event.register("numba:compile", Listener())
    from omnirotor.cli import main

    t0 = time.process_time()
    try:
        code = main(list(args))
    except SystemExit as e:
        code = e.code
    if code not in (0, None):
        raise RuntimeError(f"omnirotor {' '.join(args)} failed ({code})")
    total = time.process_time() - t0
    rows = sorted(({"name": n, "kind": k, **v} for (n, k), v in funcs.items()), key=lambda r: -r["excl_s"])
    return {
        "workload": "omnirotor " + " ".join(args),
        "total_cpu_s": total,
        "compile_excl_cpu_s": sum(r["excl_s"] for r in rows),
        "specialisations": sum(r["n"] for r in rows),
        "phases_cpu_s": dict(phase_s),
        "phases_count": dict(phase_n),
        "functions": rows,
    }


def main(argv: list[str] | None = None) -> int:
    """Command line (module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="write the whole profile as JSON to this file")
    ap.add_argument("--top", type=int, default=25, help="functions in the printed table")
    a = ap.parse_args(argv)
    if "numba" in sys.modules:
        raise SystemExit("compile_profile: numba was imported before NUMBA_CACHE_DIR could be set")
    with tempfile.TemporaryDirectory(prefix="omnirotor-numba-cache-") as cache:
        os.environ["NUMBA_CACHE_DIR"] = cache
        from omnirotor.cli import use_numba_opt_default

        use_numba_opt_default()  # as the command's own process does (its numba level, unless NUMBA_OPT is set)
        sys.path.insert(0, str(HERE))
        from bench_startup import FIRST_RUN_ARGS

        result = profile(tuple(x for x in FIRST_RUN_ARGS if x != "--json"))
    if a.out:
        a.out.write_text(json.dumps(result, indent=1))
    print(
        f"{result['workload']}: {result['total_cpu_s']:.1f} s CPU, {result['specialisations']} compiles",
        file=sys.stderr,
    )
    print(
        "phases [s CPU]: "
        + ", ".join(f"{k} {v:.1f} ({result['phases_count'][k]})" for k, v in result["phases_cpu_s"].items())
    )
    print("| function | kind | n | excl [s] | of it LLVM [s] | incl [s] | asked by |\n|---|---|---|---|---|---|---|")
    for r in result["functions"][: a.top]:
        callers = ", ".join(sorted({c.rsplit(".", 1)[-1] for c in r["callers"]}))
        print(
            f"| `{r['name']}` | {r['kind']} | {r['n']} | {r['excl_s']:.2f} | {r['llvm_s']:.2f} | {r['incl_s']:.2f} "
            f"| {callers} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
