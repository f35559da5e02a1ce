"""Kernels only kernels call emit no machine code of their own (``_jit.LinkOnlyLibrary``), cold or cached.

A toy package (an entry point Python calls, a kernel it calls, a helper both call) runs in new interpreters
on one cache folder: compiled cold, loaded warm, and with the entry's cache entry deleted (a new entry point
links the kernels' cached bitcode). Every run checks the values against Python and which compiled functions
have machine code in numba's execution engine.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parent.parent / "src"

TOY = """
from omnirotor._jit import jit, jit_entry


@jit
def helper(a, i):
    return a[i] * 2.0 + 1.0


@jit
def kernel(a):
    s = 0.0
    for i in range(a.size):
        s += helper(a, i)
    return s


@jit_entry
def entry(a):
    return kernel(a) - helper(a, 1)
"""

PROBE = """
import json
import numpy as np
from numba.core.registry import cpu_target
import toy_kernels as t

a = np.arange(5.0)
value = t.entry(a)
engine = cpu_target.target_context.codegen()._engine


def emitted(d):
    return [engine.is_symbol_defined(c.fndesc.mangled_name) for c in d.overloads.values()]


print(json.dumps({
    "value": value,
    "kernel": float(t.kernel(a)),  # through the kernel's Python twin
    "entry_hits": sum(t.entry.stats.cache_hits.values()),
    "entry_emitted": emitted(t.entry),
    "kernel_emitted": emitted(t.kernel),
    "helper_emitted": emitted(t.helper),
    "kernel_library": [type(c.library).__name__ for c in t.kernel.overloads.values()],
}))
"""


def _probe(folder: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(folder), str(SRC)]), NUMBA_CACHE_DIR=str(folder / "cache"))
    proc = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="nothing is compiled or cached")
def test_kernels_called_only_by_kernels_emit_no_machine_code_cold_warm_and_relinked(tmp_path: Path) -> None:
    (tmp_path / "toy_kernels.py").write_text(TOY)
    expected = sum(2.0 * x + 1.0 for x in range(5)) - 3.0

    cold = _probe(tmp_path)
    assert cold["value"] == expected and cold["kernel"] == expected + 3.0
    assert cold["entry_hits"] == 0 and cold["entry_emitted"] == [True]
    assert cold["kernel_emitted"] == [False] and cold["helper_emitted"] == [False, False]  # (array, int) and literal 1
    assert cold["kernel_library"] == ["LinkOnlyLibrary"]

    warm = _probe(tmp_path)
    assert warm["value"] == expected and warm["kernel"] == expected + 3.0
    assert warm["entry_hits"] == 1 and warm["entry_emitted"] == [True]
    assert warm["kernel_emitted"] == []  # the entry's machine code is loaded; the kernels are not even read

    for f in (tmp_path / "cache").rglob("toy_kernels.entry-*"):
        f.unlink()
    relinked = _probe(tmp_path)  # the entry compiles again and links the kernels' cached bitcode
    assert relinked["value"] == expected and relinked["entry_hits"] == 0 and relinked["entry_emitted"] == [True]
    assert relinked["kernel_emitted"] == [False] and relinked["kernel_library"] == ["LinkOnlyLibrary"]
