"""Compare two ``metrics.json`` of ``omnirotor reproduce`` to a relative tolerance (issue 11, "same numbers").

Every number must agree to ``rtol`` (relative; exact for integers, booleans and None), every key must be
present in both. Not compared: wall-clock timings (keys ending in ``_us_median``, which measure the machine)
and the folder part of file paths (a run into another ``--out`` folder names other files).

Usage (exit status 0: same numbers; 1: the differences are printed)::

    python tests/reference/compare_metrics.py BEFORE/metrics.json AFTER/metrics.json [--rtol 1e-9]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from typing import Any

TIMING_SUFFIXES = ("_us_median",)


def differences(a: Any, b: Any, rtol: float = 1e-9, path: str = "") -> list[str]:
    """The places where ``a`` and ``b`` (parsed metrics) differ, as ``path: a != b`` lines."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            sub = f"{path}/{key}"
            if key not in a or key not in b:
                out.append(f"{sub}: present in only one file")
            elif not key.endswith(TIMING_SUFFIXES):
                out.extend(differences(a[key], b[key], rtol, sub))
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: lengths {len(a)} != {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True)) for d in differences(x, y, rtol, f"{path}[{i}]")]
    if isinstance(a, float) and isinstance(b, float) and not isinstance(a, bool):
        if math.isnan(a) and math.isnan(b):
            return []
        if a == b or abs(a - b) <= rtol * max(abs(a), abs(b)):
            return []
        return [f"{path}: {a!r} != {b!r} (relative {abs(a - b) / max(abs(a), abs(b)):.3g})"]
    if isinstance(a, str) and isinstance(b, str) and os.sep in a and os.sep in b:
        return [] if os.path.basename(a) == os.path.basename(b) else [f"{path}: {a!r} != {b!r}"]
    if type(a) is not type(b) or a != b:
        return [f"{path}: {a!r} != {b!r}"]
    return []


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before")
    parser.add_argument("after")
    parser.add_argument("--rtol", type=float, default=1e-9)
    args = parser.parse_args(argv)
    with open(args.before) as fa, open(args.after) as fb:
        diffs = differences(json.load(fa), json.load(fb), args.rtol)
    for line in diffs:
        print(line)
    print(f"{len(diffs)} difference(s) at rtol {args.rtol:g}")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
