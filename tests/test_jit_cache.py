"""No stale compiled code: a cached kernel compiles again when a helper it calls changes in another module.

The package is copied to a temporary folder with two extra modules (a helper and a kernel calling it, in
different files); each step runs in a new interpreter, as a user's next run would.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parent.parent / "src" / "omnirotor"

HELPER = """
from omnirotor._jit import jit
from omnirotor.{consts} import OFFSET


@jit
def helper(x):
    return x + {inc} + OFFSET
"""
CONSTS = "OFFSET = {offset}\n"
KERNEL = """
from omnirotor._jit import jit
from omnirotor.{helper} import helper


@jit
def kernel(x):
    return 2.0 * helper(x)
"""
PROBE = """
import json
from omnirotor.{kernel} import kernel
value = kernel(1.0)
print(json.dumps({{"value": value, "hits": sum(kernel.stats.cache_hits.values()),
                   "misses": sum(kernel.stats.cache_misses.values())}}))
"""


def _run(root: Path, names: dict, **numba_env: str) -> dict:
    env = dict(os.environ, PYTHONPATH=str(root))
    env.pop("NUMBA_CACHE_DIR", None)  # the cache beside the copied sources
    env.update(numba_env)
    proc = subprocess.run(
        [sys.executable, "-c", PROBE.format(**names)], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _probe_package(tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """A copy of the package in ``tmp_path`` with a probe kernel, the helper it calls and the constants it reads."""
    pkg = tmp_path / "omnirotor"
    shutil.copytree(SRC, pkg, ignore=shutil.ignore_patterns("__pycache__"))
    names = {"kernel": "_probe_kernel", "helper": "_probe_helper", "consts": "_probe_consts"}
    (pkg / "_probe_consts.py").write_text(CONSTS.format(offset=0.0))
    (pkg / "_probe_helper.py").write_text(HELPER.format(consts=names["consts"], inc=1.0))
    (pkg / "_probe_kernel.py").write_text(KERNEL.format(helper=names["helper"]))
    return pkg, names


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="nothing is compiled or cached")
def test_editing_a_helper_in_another_module_recompiles_the_dependent_kernel(tmp_path: Path) -> None:
    pkg, names = _probe_package(tmp_path)
    kernel_stat = (pkg / "_probe_kernel.py").stat()

    first = _run(tmp_path, names)
    assert first == {"value": 4.0, "hits": 0, "misses": 1}
    again = _run(tmp_path, names)
    assert again == {"value": 4.0, "hits": 1, "misses": 0}  # unchanged sources: the cache is used

    (pkg / "_probe_helper.py").write_text(HELPER.format(consts=names["consts"], inc=5.0))
    assert (pkg / "_probe_kernel.py").stat().st_mtime_ns == kernel_stat.st_mtime_ns  # the kernel's file untouched
    assert _run(tmp_path, names)["value"] == 12.0

    (pkg / "_probe_consts.py").write_text(CONSTS.format(offset=10.0))  # a constant the helper reads, a third file
    assert _run(tmp_path, names)["value"] == 32.0


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="nothing is compiled or cached")
def test_a_kernel_compiled_at_one_optimisation_level_is_never_loaded_at_another(tmp_path: Path) -> None:
    """numba's own cache key has no optimisation level: the dependency cache keeps each level in its folder."""
    pkg, names = _probe_package(tmp_path)
    levels = {"NUMBA_LOOP_VECTORIZE": "1", "NUMBA_SLP_VECTORIZE": "0"}

    assert _run(tmp_path, names, NUMBA_OPT="3", **levels) == {"value": 4.0, "hits": 0, "misses": 1}
    assert _run(tmp_path, names, NUMBA_OPT="1", **levels) == {"value": 4.0, "hits": 0, "misses": 1}  # not O3's
    assert _run(tmp_path, names, NUMBA_OPT="1", NUMBA_LOOP_VECTORIZE="0", NUMBA_SLP_VECTORIZE="0")["misses"] == 1
    assert _run(tmp_path, names, NUMBA_OPT="3", **levels) == {"value": 4.0, "hits": 1, "misses": 0}  # O3's kept
    assert _run(tmp_path, names, NUMBA_OPT="1", **levels) == {"value": 4.0, "hits": 1, "misses": 0}
    suffixes = {f.name.rsplit("-", 1)[1] for f in (pkg / "__pycache__").glob("deps-*")}
    assert {"o3v10", "o1v10", "o1v00"} <= suffixes


BLOCK = """
import numba
import numpy as np

from omnirotor.blocks import register

DTYPE = np.dtype([(n, np.float64, 3) for n in ("f_ext_W", "m_ext_B", "f_filt_W", "m_filt_B")] + [("n_nonfinite", "f8")])


@numba.njit
def probe_observe(r, A, u_hz2, a_W, R_WB, omega_B, dt):
    r.f_ext_W[0] = {value}


@register("observer", "probe")
class ProbeObserver:
    state_dtype = DTYPE
    kernel = probe_observe
"""
CALLER = """
from omnirotor._jit import jit
from omnirotor.blocks import compiled_step

_observe = compiled_step("observer")


@jit
def caller(rec):
    _observe(rec[0], np.zeros((6, 8)), np.zeros(8), np.zeros(3), np.eye(3), np.zeros(3), 0.001)
    return rec[0].f_ext_W[0]
"""
BLOCK_PROBE = """
import json
import numpy as np
{block}
from omnirotor._probe_caller import caller
value = caller(np.zeros(1, DTYPE))
print(json.dumps({{"value": value, "hits": sum(caller.stats.cache_hits.values()),
                   "misses": sum(caller.stats.cache_misses.values())}}))
"""


def _run_block_probe(root: Path, block: str) -> dict:
    env = dict(os.environ, PYTHONPATH=str(root))
    env.pop("NUMBA_CACHE_DIR", None)
    code = BLOCK_PROBE.format(block=block)
    proc = subprocess.run([sys.executable, "-c", code], cwd=root, env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="nothing is compiled or cached")
def test_editing_a_block_registered_outside_the_package_recompiles_the_kernel_that_calls_it(tmp_path: Path) -> None:
    """A block reached through the registry (its record's type), not an import: a user's or a test's own block.

    The package's kernel that calls it through ``compiled_step`` links its machine code; its closure does not
    name the block's file. Before the block's sources were part of the key, the edited block's old code ran.
    """
    pkg, _ = _probe_package(tmp_path)
    (pkg / "_probe_caller.py").write_text("import numpy as np\n" + CALLER)
    block = tmp_path / "my_block.py"  # beside the package, as a user's module
    use = "from my_block import DTYPE"

    block.write_text(BLOCK.format(value=1.0))
    assert _run_block_probe(tmp_path, use) == {"value": 1.0, "hits": 0, "misses": 1}
    assert _run_block_probe(tmp_path, use) == {"value": 1.0, "hits": 1, "misses": 0}
    block.write_text(BLOCK.format(value=2.0))  # the same record type, another kernel body
    assert _run_block_probe(tmp_path, use)["value"] == 2.0
    assert _run_block_probe(tmp_path, use) == {"value": 2.0, "hits": 1, "misses": 0}
    block.write_text(BLOCK.format(value=1.0))  # back: that version's folder is still there
    assert _run_block_probe(tmp_path, use) == {"value": 1.0, "hits": 1, "misses": 0}
    assert len(list((pkg / "__pycache__").glob("deps-*/ext-*"))) == 2


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="nothing is compiled or cached")
def test_a_block_the_kernel_imports_keeps_the_kernels_own_cache_and_one_without_a_file_is_never_cached(
    tmp_path: Path,
) -> None:
    """The package's own blocks are in their callers' closures: no folder of their own (the command line and the
    tests share one cache). A block defined where no file holds it (a prompt) cannot be hashed: not cached."""
    pkg, _ = _probe_package(tmp_path)
    (pkg / "_probe_block.py").write_text(BLOCK.format(value=3.0))
    (pkg / "_probe_caller.py").write_text("import numpy as np\nfrom omnirotor._probe_block import DTYPE\n" + CALLER)
    use = "from omnirotor._probe_block import DTYPE"
    assert _run_block_probe(tmp_path, use) == {"value": 3.0, "hits": 0, "misses": 1}
    assert _run_block_probe(tmp_path, use) == {"value": 3.0, "hits": 1, "misses": 0}
    assert not list((pkg / "__pycache__").glob("deps-*/ext-*"))

    (pkg / "_probe_caller.py").write_text("import numpy as np\n" + CALLER)
    at_a_prompt = BLOCK.format(value=4.0)
    assert _run_block_probe(tmp_path, at_a_prompt) == {"value": 4.0, "hits": 0, "misses": 1}
    assert _run_block_probe(tmp_path, at_a_prompt) == {"value": 4.0, "hits": 0, "misses": 1}


def test_source_closure_follows_package_imports_only() -> None:
    from omnirotor._jit import source_closure

    files = {p.relative_to(SRC).as_posix() for p in source_closure(str(SRC / "sim" / "simulator.py"))}
    assert {"sim/simulator.py", "_jit.py"} <= files
    assert not any(f.startswith("cli/") for f in files)


def test_kernels_outside_the_package_are_keyed_on_their_own_file(tmp_path: Path) -> None:
    from omnirotor._jit import _closure_hash, source_closure

    f = tmp_path / "bench_kernel.py"
    f.write_text("from omnirotor._jit import jit\nimport omnirotor.so3\n")
    files = source_closure(str(f))
    assert f.resolve() in files and SRC / "so3.py" in files
    h = _closure_hash(str(f))
    assert source_closure("<string>") == () and len(h) == 64


NT_KERNEL_V1 = """
from typing import NamedTuple

import numpy as np

from omnirotor._jit import jit


class Pair(NamedTuple):
    a: np.ndarray
    b: np.ndarray


@jit
def kernel(p):
    return p.a[0] + p.b[0]


def call():
    return kernel(Pair(np.ones(1), np.ones(1)))
"""
NT_KERNEL_V2 = """
import numpy as np

from omnirotor._jit import jit

# The NamedTuple is gone; the kernel stays on the same line (numba names its index after the line).
#
#
#
#
#


@jit
def kernel(a):
    return 3.0 * a[0]


def call():
    return kernel(np.ones(1))
"""
NT_PROBE = "import json\nfrom omnirotor._probe_nt import call\nprint(json.dumps({'value': call()}))\n"


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="nothing is compiled or cached")
def test_a_cache_naming_a_removed_class_is_a_miss_not_an_error(tmp_path: Path) -> None:
    """A kernel once took a NamedTuple whose class a later version removed (as issue 23's records did).

    numba unpickles a cache index before it compares its stamp; an index naming the removed class raised
    ``AttributeError`` in every run after an update. Each source version has its own cache folder now.
    """
    pkg = tmp_path / "omnirotor"
    shutil.copytree(SRC, pkg, ignore=shutil.ignore_patterns("__pycache__"))
    env = dict(os.environ, PYTHONPATH=str(tmp_path))
    env.pop("NUMBA_CACHE_DIR", None)

    def run() -> float:
        proc = subprocess.run([sys.executable, "-c", NT_PROBE], env=env, capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return json.loads(proc.stdout.strip().splitlines()[-1])["value"]

    line = [i for i, t in enumerate(NT_KERNEL_V1.splitlines()) if t.startswith("def kernel")]
    assert line == [i for i, t in enumerate(NT_KERNEL_V2.splitlines()) if t.startswith("def kernel")]
    (pkg / "_probe_nt.py").write_text(NT_KERNEL_V1)
    assert run() == 2.0
    (pkg / "_probe_nt.py").write_text(NT_KERNEL_V2)
    assert run() == 3.0
    (pkg / "_probe_nt.py").write_text(NT_KERNEL_V1)  # back to the first version: its folder is still there
    assert run() == 2.0
    folders = list((pkg / "__pycache__").glob("deps-*"))
    assert 2 <= len(folders)


def test_old_cache_folders_are_pruned(tmp_path: Path) -> None:
    from omnirotor._jit import _KEEP_CACHE_FOLDERS, _prune_cache_folders

    for i in range(_KEEP_CACHE_FOLDERS + 3):
        d = tmp_path / f"deps-{i:02d}"
        d.mkdir()
        (d / "k.nbi").write_bytes(b"x")
        (d / "ext-a").mkdir()  # a block's folder inside (record_sources) goes with it
        (d / "ext-a" / "k.nbi").write_bytes(b"x")
        os.utime(d, ns=(i * 10**9, i * 10**9))
    _prune_cache_folders(str(tmp_path))
    kept = sorted(f.name for f in tmp_path.glob("deps-*"))
    assert kept == [f"deps-{i:02d}" for i in range(3, _KEEP_CACHE_FOLDERS + 3)]


def test_old_folders_of_blocks_outside_a_kernels_closure_are_pruned(tmp_path: Path) -> None:
    from omnirotor._jit import _KEEP_EXTENSION_FOLDERS, _prune_extension_folders

    for i in range(_KEEP_EXTENSION_FOLDERS + 2):
        d = tmp_path / f"ext-{i:02d}"
        d.mkdir()
        (d / "k.nbi").write_bytes(b"x")
        os.utime(d, ns=(i * 10**9, i * 10**9))
    _prune_extension_folders(str(tmp_path))
    kept = sorted(f.name for f in tmp_path.glob("ext-*"))
    assert kept == [f"ext-{i:02d}" for i in range(2, _KEEP_EXTENSION_FOLDERS + 2)]


def test_the_current_folders_of_every_module_beside_are_never_pruned(tmp_path: Path) -> None:
    """A package whose modules have more distinct closures than the folders kept: none of theirs is removed."""
    from omnirotor._jit import _KEEP_CACHE_FOLDERS, _closure_hash, _prune_cache_folders

    src = tmp_path / "pkg"
    src.mkdir()
    base = src / "__pycache__"
    base.mkdir()
    n_live = _KEEP_CACHE_FOLDERS + 2
    live = []
    for k in range(n_live):  # modules that import nothing of each other: one closure (and folder) each
        f = src / f"m{k}.py"
        f.write_text(f"X = {k}\n")
        live.append(f"deps-{_closure_hash(str(f))[:20]}-o{1 + k % 3}v10")  # at any optimisation level
    stale = [f"deps-stale{i:02d}" for i in range(_KEEP_CACHE_FOLDERS + 2)]
    for i, name in enumerate(live + stale):  # the live ones the oldest: they used to be removed first
        d = base / name
        d.mkdir()
        (d / "k.nbi").write_bytes(b"x")
        os.utime(d, ns=(i * 10**9, i * 10**9))
    _prune_cache_folders(str(base), str(src))
    kept = {f.name for f in base.glob("deps-*")}
    assert set(live) <= kept  # every module's current cache stays
    assert kept - set(live) == set(stale[-_KEEP_CACHE_FOLDERS:])  # of the others, the newest few


def test_switching_back_one_checkout_finds_every_control_folder(tmp_path: Path) -> None:
    """The previous sources of every module of ``control`` (one folder per closure, at the command's level and the
    library's) are all kept beside the current ones and older versions' folders: a checkout back compiles nothing."""
    import omnirotor.control
    from omnirotor._jit import _live_folders, _prune_cache_folders

    control = Path(omnirotor.control.__file__).parent
    base = tmp_path / "__pycache__"
    base.mkdir()
    current = sorted(_live_folders(str(control)))
    previous = [f"deps-prev{k:015d}-o{level}v10" for k in range(len(current)) for level in (1, 3)]
    older = [f"deps-old{k:016d}-o1v10" for k in range(8)]
    for i, name in enumerate(older + previous + [f"{c}-o1v10" for c in current]):  # the older the first written
        d = base / name
        d.mkdir()
        os.utime(d, ns=(i * 10**9, i * 10**9))
    _prune_cache_folders(str(base), str(control))
    kept = {f.name for f in base.glob("deps-*")}
    assert set(previous) <= kept and not set(older) <= kept


PAUSE_PROBE = """
import gc, json
import numba
from numba.core import event
from omnirotor import _jit

seen = []


class Seen(event.Listener):  # registered after _jit's: sees the collector as a compile has it
    def on_start(self, ev):
        seen.append([ev.data["dispatcher"].py_func.__name__, gc.isenabled()])

    def on_end(self, ev):
        return None  # only the start is watched (numba's Listener asks for both hooks)


event.register("numba:compile", Seen())


def ours(x):
    return x + 1.0


def theirs(x):
    return x * 2.0


def ours_again(x):
    return x - 1.0


ours.__module__ = ours_again.__module__ = "omnirotor._probe"
_jit.jit(ours)(1.0)
after_ours = gc.isenabled()
numba.njit(theirs)(1.0)
gc.disable()  # a caller that disabled the collector keeps it disabled
_jit.jit(ours_again)(1.0)
print(json.dumps({"seen": seen, "after_ours": after_ours, "after_disabled": gc.isenabled()}))
"""


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="nothing is compiled")
def test_the_collector_is_paused_while_a_kernel_of_the_package_compiles(tmp_path: Path) -> None:
    (tmp_path / "probe.py").write_text(PAUSE_PROBE)
    env = dict(os.environ, PYTHONPATH=str(SRC.parent), NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    proc = subprocess.run(
        [sys.executable, "probe.py"], cwd=tmp_path, env=env, capture_output=True, text=True, check=True
    )
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["seen"] == [["ours", False], ["theirs", True], ["ours_again", False]]
    assert out["after_ours"] is True  # restored after the compile
    assert out["after_disabled"] is False


def test_the_tests_compile_at_the_commands_level() -> None:
    """numba compiles this process's kernels at the level a command started from the same environment would use
    (the command's default unless the environment set one): the commands the tests start share the test process's
    kernel cache."""
    import numba

    from conftest import NUMBA_OPT_PRESET
    from omnirotor.cli import NUMBA_OPT_DEFAULT

    expected = NUMBA_OPT_DEFAULT if NUMBA_OPT_PRESET is None else NUMBA_OPT_PRESET
    assert int(numba.core.config.OPT) == int(expected)
