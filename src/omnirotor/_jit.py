"""Numba set-up shared by the compiled kernels of the 1 kHz loop (the blocks of ``control/`` and ``sim/``).

Every kernel is compiled with :data:`jit`: ``nopython``, ``cache=True`` (machine code is kept in the
``__pycache__`` folder next to the module, or under ``NUMBA_CACHE_DIR``, so only the first import on a machine
compiles), ``fastmath=False`` (IEEE arithmetic in the order written, so a kernel reproduces the NumPy / Python
float reference it replaces to the last bit or within a rounding) and NumPy's error model (a division by zero
gives inf or NaN as in NumPy; it never raises inside the loop). Kernels are compiled lazily, on their first
call. Small helpers called with constant arguments (which numba compiles once per constant value) and a few
large functions that take many arrays are inlined into their compiled callers instead (:func:`jit_inline`).
Kernels get numba's wrapper for calls from Python but not its C-pointer wrapper (``no_cfunc_wrapper``), which
only :func:`jit_entry` kernels need: the ones a compiled loop calls through a pointer (:class:`PointerCaller`,
numba's first-class function types, so that the loop does not compile the controller and the simulator into
its own machine code a second time).

Set ``NUMBA_DISABLE_JIT=1`` to run every kernel as plain Python (debugging, coverage).

No stale machine code (numba's open issue #1833): numba's own cache checks a kernel only against its own file,
so after an edit of a helper in *another* module a cached dependent kernel would still run the old helper
(whose code is compiled into it). The cache of every kernel here therefore stamps its index with a hash of
the sources the kernel's module depends on: its file and, transitively, every module of the package it
imports (:func:`source_closure`). An edit anywhere in that closure makes the kernel compile again on its next
use; an edit elsewhere (the CLI, the experiments) keeps the cache. Code a kernel reaches through a record's
type instead of an import (a block's kernel, which :func:`omnirotor.blocks.compiled_step` links into its caller
when the caller is compiled for that block's record) is declared by :func:`record_sources`
(:func:`omnirotor.blocks.register` does it for every block): a specialisation whose arguments hold such a record
from outside the kernel's closure (a user's or a test's block) is cached keyed on those files too, in a folder
of its own. This uses numba's cache-locator interface
only (:class:`DependencyLocator`: the locators numba ships, with another ``get_source_stamp``, the method a
locator exists to provide), through a :class:`DependencyCache` that is numba's ``FunctionCache`` with that
locator first; the one private detail is the dispatcher's ``_cache`` attribute, which numba's own
``enable_caching`` sets the same way. Nothing else of numba's internals is touched, so numba is pinned to a
range (``pyproject.toml``), not one release. Two attributes without an underscore that numba's user manual does
not list are read: a dispatcher's ``overloads`` (its compiled specialisations by signature, for
:class:`PointerCaller`'s function types) and a specialisation's ``entry_point`` (:func:`typed_entry`, which
falls back to the dispatcher if it is absent).

numba's LLVM optimisation level and vectorizers are not in numba's cache key: the cache keeps each setting in a
folder of its own (:func:`codegen_settings`; the ``omnirotor`` command compiles at level 1, the library at
numba's level or the user's). Python's cyclic garbage collector is paused while a kernel of the package compiles
(:class:`CollectorPause`, on numba's documented compile events): about a tenth of a first run's compile time.

C functions called from kernels are bound by symbol name (numba's ``ExternalFunction``), never by address, so
the cached machine code stays valid in a new process: :func:`mujoco_function` (MuJoCo's C API, from the shared
library the ``mujoco`` package ships and has loaded) and :func:`monotonic_ns` (the C library's
``clock_gettime``, to time a block inside a compiled loop). The one address a kernel is given at run time,
that of MuJoCo's profiler clock ``mjcb_time`` (:func:`mujoco_timer_address`), travels in its arguments.
"""

from __future__ import annotations

import contextlib
import functools
import gc
import hashlib
import os
import re
from pathlib import Path

import llvmlite.binding
import numba
import numpy as np
from numba import types
from numba.core import event, sigutils
from numba.core.caching import (
    CompileResultCacheImpl,
    FunctionCache,
    InTreeCacheLocator,
    UserProvidedCacheLocator,
)
from numba.core.dispatcher import Dispatcher
from numba.extending import intrinsic

__all__ = [
    "jit",
    "jit_inline",
    "jit_entry",
    "PointerCaller",
    "typed_entry",
    "DependencyCache",
    "DependencyLocator",
    "source_closure",
    "record_sources",
    "codegen_settings",
    "CollectorPause",
    "mujoco_function",
    "mujoco_timer_address",
    "monotonic_ns",
    "f64_at",
    "f64_at2",
    "i64_at",
]

_PACKAGE_DIR = Path(__file__).resolve().parent
_PACKAGE = __name__.split(".")[0]
_IMPORT_RE = re.compile(
    rf"^[ \t]*(?:from[ \t]+({_PACKAGE}(?:\.\w+)*)[ \t]+import[ \t]+(\([^)]*\)|[^\n]*)"
    rf"|import[ \t]+({_PACKAGE}(?:\.\w+)*))",
    re.M,
)


def _module_file(module: str) -> Path | None:
    """The source file of a module of this package (``None`` if it is not one)."""
    parts = module.split(".")
    if parts[0] != _PACKAGE:
        return None
    base = _PACKAGE_DIR.joinpath(*parts[1:])
    for f in (base.with_suffix(".py"), base / "__init__.py"):
        if f.is_file():
            return f
    return None


@functools.cache
def _file_bytes(f: Path) -> bytes:
    """A source file's bytes, read once per process: many kernels' closures share the same files."""
    return f.read_bytes()


@functools.cache
def _imported_files(f: Path) -> tuple[Path, ...]:
    """The package's source files that ``f`` imports directly (see :func:`source_closure`), parsed once."""
    deps = []
    for m in _IMPORT_RE.finditer(_file_bytes(f).decode()):
        module = m.group(1) or m.group(3)
        names = [n.split(" as ")[0].strip() for n in (m.group(2) or "").strip("()").split(",")]
        for cand in [module] + [f"{module}.{n}" for n in names if n.isidentifier()]:
            dep = _module_file(cand)
            if dep is not None:
                deps.append(dep)
    return tuple(deps)


@functools.cache
def source_closure(path: str) -> tuple[Path, ...]:
    """The package's source files a module depends on: ``path`` and every package module it imports, transitively.

    Imports are read from the text (``import omnirotor.x``, ``from omnirotor.x import a, b``, where ``a`` may
    be a module too), at any indentation, so imports inside functions count as well.
    """
    start = Path(path).resolve()
    if not start.is_file():  # a kernel defined in a string or at a prompt: numba's own key (its bytecode) only
        return ()
    todo, seen = [start], set()
    while todo:
        f = todo.pop()
        if f in seen:
            continue
        seen.add(f)
        todo.extend(dep for dep in _imported_files(f) if dep not in seen)
    return tuple(sorted(seen))


def _files_hash(files) -> str:
    """The hash of source files' names (the package's relative to it) and contents, in the order given."""
    h = hashlib.sha256()
    for f in files:
        name = f.relative_to(_PACKAGE_DIR) if f.is_relative_to(_PACKAGE_DIR) else f  # e.g. a benchmark's kernel
        h.update(str(name).encode() + b"\0" + _file_bytes(f) + b"\0")
    return h.hexdigest()


@functools.cache
def _closure_hash(path: str) -> str:
    return _files_hash(source_closure(path))


_RECORD_SOURCES: dict[np.dtype, frozenset[Path | None]] = {}
"""The source files of the code compiled code may run when given a record of each dtype (:func:`record_sources`)."""


def record_sources(dtype: np.dtype, files) -> None:
    """Declare that compiled code given a record of ``dtype`` may run code of ``files`` (and of their closures).

    For code chosen by a record's type rather than imported: a block's kernel, which
    :func:`omnirotor.blocks.compiled_step` links into the kernel that calls it when that kernel is compiled for a
    record of the block's ``state_dtype`` (:func:`omnirotor.blocks.register` declares every block). A kernel's
    specialisation whose arguments hold such a record (at any depth: a field of a field) and whose module's
    :func:`source_closure` does not cover these files is cached in a folder of its own, keyed on them too
    (:class:`DependencyCache`): a block written outside the package, by a user or a test, and edited later
    makes its callers compile again instead of running its old machine code. A file given as ``None`` (a class
    defined at a prompt, whose source cannot be hashed) makes such specialisations uncached.
    """
    key = np.dtype(dtype)
    known = {Path(f).resolve() if f is not None and os.path.isfile(f) else None for f in files}
    _RECORD_SOURCES[key] = _RECORD_SOURCES.get(key, frozenset()) | known
    _record_type_sources.cache_clear()


@functools.cache
def _record_type_sources() -> dict:
    """:data:`_RECORD_SOURCES` by numba's record type (numba's types compare and hash by layout)."""
    return {numba.from_dtype(d): files for d, files in _RECORD_SOURCES.items()}


def _signature_sources(arg_types) -> frozenset[Path | None]:
    """The declared sources (:func:`record_sources`) of every record type in ``arg_types``, at any depth."""
    by_type = _record_type_sources()
    if not by_type:
        return frozenset()
    found: set[Path | None] = set()
    todo, seen = list(arg_types), set()
    while todo:
        t = todo.pop()
        if not isinstance(t, types.Type) or t in seen:
            continue
        seen.add(t)
        if isinstance(t, types.Record):
            found |= by_type.get(t, frozenset())
            todo.extend(member for _, member in t.members)
        elif isinstance(t, types.BaseTuple):
            todo.extend(t.types)
        elif isinstance(getattr(t, "dtype", None), types.Type):  # an array or a record's array field
            todo.append(t.dtype)
    return frozenset(found)


_KEEP_CACHE_FOLDERS = 16
"""Cache folders of other source versions (one per hash and setting) kept beside each package folder's current ones;
older ones are removed. Sixteen hold the previous checkout of ``control`` whole (its eight closures at the command's
and the library's levels), so switching back compiles nothing there (at four, nine kernels compiled again)."""


def codegen_settings() -> str:
    """The settings of numba that change the machine code but not its cache key, as a folder-name suffix.

    numba keys a cached specialisation on its signature and the CPU only; its LLVM optimisation level
    (``NUMBA_OPT``) and vectorizers (``NUMBA_LOOP_VECTORIZE``, ``NUMBA_SLP_VECTORIZE``) are read from the
    environment and would not be told apart. The dependency cache keeps each combination in its own folder
    (``deps-<hash>-<settings>``), so a kernel compiled at one level is never loaded at another (the
    ``omnirotor`` command compiles at its own level, :data:`omnirotor.cli.NUMBA_OPT_DEFAULT`; the library at
    numba's, or the user's). Read from ``numba.config`` when a kernel is defined (its module imported).
    """
    c = numba.config
    opt = "max" if getattr(c.OPT, "is_opt_max", False) else str(int(c.OPT))
    return f"o{opt}v{int(c.LOOP_VECTORIZE)}{int(c.SLP_VECTORIZE)}"


_FOLDER_KEY = len("deps-") + 20
"""A cache folder's name up to its sources' hash (the settings' suffix follows)."""


@functools.cache
def _live_folders(source_dir: str) -> frozenset[str]:
    """The cache folder names, up to the settings, of the current sources of every module in ``source_dir``."""
    return frozenset("deps-" + _closure_hash(str(f))[:20] for f in Path(source_dir).glob("*.py"))


@functools.cache
def _prune_cache_folders(base: str, source_dir: str | None = None) -> None:
    """Remove all but the :data:`_KEEP_CACHE_FOLDERS` most recently written stale ``deps-*`` folders under ``base``.

    Once per folder and process. A folder is *live* when a module of ``source_dir`` (the kernels' package folder,
    whose modules share ``base``) hashes to it now: live folders are never removed, whatever their number (the
    modules of one package have closures of their own, eight in ``control``: keeping only the four newest folders
    of all deleted half of the current caches at every process's start, and each run compiled them again). A
    process still running older sources that loses its folder compiles again (numba treats a missing file as a
    cache miss); nothing else is affected. The current sources' folders of every code-generation setting
    (:func:`codegen_settings`) are live: the command line and the library may compile at different levels.
    """
    try:
        live = _live_folders(source_dir) if source_dir is not None else frozenset()
        folders = sorted(Path(base).glob("deps-*"), key=lambda f: f.stat().st_mtime_ns, reverse=True)
        stale = [f for f in folders if f.name[:_FOLDER_KEY] not in live]
        for old in stale[_KEEP_CACHE_FOLDERS:]:
            _remove_folder(old)
    except OSError:
        pass  # another process pruned it first, or the folder is read-only: a cache, never an error


_KEEP_EXTENSION_FOLDERS = 16
"""``ext-*`` folders (:func:`record_sources`) kept in each ``deps-*`` folder; older ones are removed."""


@functools.cache
def _prune_extension_folders(deps_folder: str) -> None:
    """Remove all but the :data:`_KEEP_EXTENSION_FOLDERS` most recently written ``ext-*`` folders of a ``deps-*``.

    Once per folder and process. Each is the cache of the module's kernels for one set of blocks from outside
    their closure (a user's or a test's, one version each); which are current cannot be told from here.
    """
    with contextlib.suppress(OSError):  # as in _prune_cache_folders: a cache, never an error
        folders = sorted(Path(deps_folder).glob("ext-*"), key=lambda f: f.stat().st_mtime_ns, reverse=True)
        for old in folders[_KEEP_EXTENSION_FOLDERS:]:
            _remove_folder(old)


def _remove_folder(folder: Path) -> None:
    """Remove a cache folder and the folders in it (raises OSError as ``unlink`` would)."""
    for f in folder.iterdir():
        if f.is_dir():
            _remove_folder(f)
        else:
            f.unlink(missing_ok=True)
    folder.rmdir()


class DependencyLocator:
    """Mixin of a numba cache locator keyed on the hash of the kernel's :func:`source_closure`.

    numba's locators stamp the function's own file only. Here the stamp is the closure's hash, and the cache
    lives in a folder named after that hash (``deps-<hash>-<settings>`` under numba's usual place, the settings
    those of :func:`codegen_settings`), so sources of another
    version never read an index written by this one: numba unpickles an index before it compares stamps, and
    an index whose signatures name a class that no longer exists (a NamedTuple type a kernel once took) would
    raise instead of missing. Switching between checkouts also keeps both versions' machine code. The
    :data:`_KEEP_CACHE_FOLDERS` newest folders are kept. The hash is taken when the kernel is defined (its
    module imported), so it describes the sources the process compiles from even if files change while it runs.
    """

    extension: tuple[Path, ...] = ()
    """Files beyond the closure that this cache's specialisations depend on (:func:`record_sources`)."""

    def get_source_stamp(self):
        stamp = ("omnirotor-closure", _closure_hash(self._py_file))
        return stamp + (_files_hash(self.extension),) if self.extension else stamp

    def get_cache_path(self):
        folder = f"deps-{_closure_hash(self._py_file)[:20]}-{codegen_settings()}"
        folder = os.path.join(super().get_cache_path(), folder)
        return os.path.join(folder, f"ext-{_files_hash(self.extension)[:20]}") if self.extension else folder

    def ensure_cache_path(self):
        super().ensure_cache_path()
        path = self.get_cache_path()
        if self.extension:
            _prune_extension_folders(os.path.dirname(path))
            path = os.path.dirname(path)
        _prune_cache_folders(os.path.dirname(path), os.path.dirname(os.path.abspath(self._py_file)))


class _UserDirDependencyLocator(DependencyLocator, UserProvidedCacheLocator):
    """Under ``NUMBA_CACHE_DIR``, when it is set."""


class _InTreeDependencyLocator(DependencyLocator, InTreeCacheLocator):
    """In the ``__pycache__`` folder beside the module."""


class _DependencyCacheImpl(CompileResultCacheImpl):
    _locator_classes = [_UserDirDependencyLocator, _InTreeDependencyLocator, *CompileResultCacheImpl._locator_classes]

    def __init__(self, py_func, extension: tuple[Path, ...] = ()):
        super().__init__(py_func)
        if extension and isinstance(self.locator, DependencyLocator):
            self.locator.extension = extension  # before numba's Cache asks it for its folder and stamp


class DependencyCache(FunctionCache):
    """numba's function cache, its index stamped with the hash of the kernel's sources (:class:`DependencyLocator`).

    A specialisation whose arguments hold a record of a block from outside the kernel's closure
    (:func:`record_sources`) goes to a cache of its own, made on first use: the same, with those files' hash in
    its stamp and in its folder (``deps-<hash>-<settings>/ext-<hash>``). numba asks a dispatcher's cache for one
    signature at a time (``load_overload``, ``save_overload``, the two methods of its cache interface that take
    the signature), and each is passed on to the cache of that signature's sources.
    """

    _impl_class = _DependencyCacheImpl

    def __init__(self, py_func, extension: tuple[Path, ...] = ()):
        self._extension = extension
        self._kernel_file = getattr(getattr(py_func, "__code__", None), "co_filename", "<unknown>")
        self._extended: dict[tuple[Path, ...], DependencyCache | None] = {}
        if extension:
            self._impl_class = functools.partial(_DependencyCacheImpl, extension=extension)
        super().__init__(py_func)
        self._py_function = py_func

    def _cache_of(self, sig):
        """The cache of a signature's sources: this one, one with an extension, or None (not cached)."""
        if self._extension:
            return self
        try:
            arg_types = sigutils.normalize_signature(sig)[0]
        except (TypeError, ValueError):  # not a signature numba would take: its own key decides
            return self
        files = _signature_sources(arg_types)
        if not files:
            return self
        if None in files:  # a block whose source cannot be hashed: never cached
            return None
        own = set(source_closure(self._kernel_file))
        extension = tuple(sorted({f for src in files for f in source_closure(str(src))} - own))
        if not extension:
            return self
        if extension not in self._extended:
            cache = DependencyCache(self._py_function, extension)
            # numba's fallback locators (no dependency folder: the package's folder and NUMBA_CACHE_DIR not
            # writable) would not key on the extension: not cached then
            keyed = os.path.basename(cache.cache_path).startswith("ext-")
            self._extended[extension] = cache if keyed else None
        return self._extended[extension]

    def load_overload(self, sig, target_context):
        cache = self._cache_of(sig)
        if cache is self:
            return super().load_overload(sig, target_context)
        return None if cache is None else cache.load_overload(sig, target_context)

    def save_overload(self, sig, data):
        cache = self._cache_of(sig)
        if cache is self:
            super().save_overload(sig, data)
        elif cache is not None:
            cache.save_overload(sig, data)

    def flush(self):
        super().flush()
        for cache in self._extended.values():
            if cache is not None:
                cache.flush()


class CollectorPause(event.Listener):
    """Python's cyclic garbage collector paused while numba compiles a kernel of this package (numba's event API).

    A compile allocates millions of short-lived objects (numba's IR, types, llvmlite's IR); the collector, run
    every few hundred allocations, walks every object alive in the process, numba's registries and the IR of the
    functions compiled so far included, over and over: about a tenth of a first run's compile time
    (BENCHMARKS.md, issue 23 item 6, session 14). It is disabled from the start of the outermost ``numba:compile``
    event of a function of this package to its end, and restored as it was (a caller that disabled it keeps it
    disabled); the cycles left by the compile are collected by the collector's next run as usual. Compiles of
    other code (a user's kernels) are left alone. Registered once, when this module is imported.
    """

    def __init__(self) -> None:
        self._depth = 0
        self._was_enabled = False

    def on_start(self, ev) -> None:
        if self._depth == 0:
            py_func = getattr(ev.data["dispatcher"], "py_func", None)
            if getattr(py_func, "__module__", "").split(".")[0] != _PACKAGE:
                return
            self._was_enabled = gc.isenabled()
            gc.disable()
        self._depth += 1

    def on_end(self, ev) -> None:
        if self._depth == 0:  # a compile of other code (not paused)
            return
        self._depth -= 1
        if self._depth == 0 and self._was_enabled:
            gc.enable()


event.register("numba:compile", CollectorPause())

_OPTIONS = {"cache": True, "fastmath": False, "error_model": "numpy"}
_njit_entry = numba.njit(**_OPTIONS)
# Kernels are called from Python and from compiled code, never through a C function pointer: numba's C wrapper of
# each (``no_cfunc_wrapper``, a documented option of its jit) would be one more function per specialisation to
# optimise and emit, and is emitted again in every kernel that links it.
_njit = numba.njit(**_OPTIONS, no_cfunc_wrapper=True)
_njit_inline = numba.njit(**_OPTIONS, no_cfunc_wrapper=True, inline="always")


def _leaf(signature: str):
    """Decorator of a leaf helper compiled for one signature only (eagerly, cached by numba's own cache).

    Calls with constant integers, which numba would otherwise compile once per value (as literals), all use
    the one compiled version. A leaf depends on nothing but this file, which numba's cache checks.
    """
    return numba.njit(signature, cache=True, fastmath=False, error_model="numpy")


def _with_dependency_cache(d):
    if isinstance(d, Dispatcher):  # not under NUMBA_DISABLE_JIT
        d._cache = DependencyCache(d.py_func)  # what Dispatcher.enable_caching does, with this cache class
    return d


def jit(fn):
    """The decorator of every kernel (see the module docstring): compiled, cached, keyed on its sources."""
    return _with_dependency_cache(_njit(fn))


def jit_entry(fn):
    """:func:`jit`, with numba's C wrapper too (the kernels a compiled loop calls through a pointer).

    For the kernels Python calls every period and those :class:`PointerCaller` is given (it takes a kernel's
    address from that wrapper).
    """
    return _with_dependency_cache(_njit_entry(fn))


def jit_inline(fn):
    """:func:`jit`, with the body inlined into every compiled caller (numba's ``inline="always"``).

    For a few large functions that take or return many arrays (a call passes each array's fields as separate
    machine arguments and counts its references, which costs more than the body it calls; inlined, the arrays
    stay where they are), and for small helpers called with constant arguments (numba would compile one
    version per constant value, as literal types, and call it). Each caller compiles the body again, so use it
    only where a benchmark shows the gain.
    """
    return _with_dependency_cache(_njit_inline(fn))


def _quick_type_key(a):
    """What numba's type of a value depends on, for arrays and scalars (a dict key, no numba typing)."""
    if isinstance(a, np.ndarray):
        f = a.flags
        return (a.dtype, a.ndim, f.c_contiguous, f.f_contiguous, f.writeable, f.aligned)
    return type(a)


class PointerCaller:
    """A kernel that calls other kernels through pointers, so that their machine code is not linked into it.

    numba links a callee's optimised module into its caller and optimises and emits it again there, so a kernel
    that calls the whole controller (the compiled closed loop) compiles the controller a second time. Passed as
    arguments of numba's first-class function type (``types.FunctionType``, documented in numba's "Types and
    signatures"), callees are called through their address instead: each is compiled once, on its own
    (and cached), the caller compiles only its own body, and a call costs an indirect jump.

    ``PointerCaller(fn, n)`` wraps ``fn(f_1, ..., f_n, *args)``, whose first ``n`` parameters are the kernels it
    calls; ``caller(kernels, *args)`` calls it with the given kernels (:func:`jit` dispatchers). The first call
    with new argument types compiles (or loads from the cache) each kernel for the types it is called with,
    as a call from Python would (the same specialisation, shared with Python callers), and ``fn`` with those
    kernels' function types in an explicit signature (numba's only way to type an argument as a function
    pointer; a kernel passed to a lazily compiled function would be typed as that one kernel and linked in).
    Nothing else of numba is used; under ``NUMBA_DISABLE_JIT`` the kernels are called as Python.

    Args:
        fn: the Python function (not decorated).
        callee_args: ``callee_args(*args)``: for each kernel, the tuple of the values (or values of the same
            numba types) it is called with inside ``fn``, from the caller's arguments.
    """

    def __init__(self, fn, callee_args):
        self.py_func = fn
        self._callee_args = callee_args
        self._dispatcher = jit(fn)
        self._signatures: dict = {}
        functools.update_wrapper(self, fn)

    def _compiled(self, kernels, args):
        quick = tuple(_quick_type_key(a) for a in args)  # per call: cheaper than numba.typeof of the records
        if quick not in self._signatures:
            key = tuple(numba.typeof(a) for a in args)
            fn_types = []
            for kernel, values in zip(kernels, self._callee_args(*args), strict=True):
                arg_types = tuple(numba.typeof(v) for v in values)
                kernel.compile(arg_types)  # as from Python: the one specialisation (cache key) of these types
                fn_types.append(types.FunctionType(kernel.overloads[arg_types].signature))
            d = self._dispatcher
            d.disable_compile(False)
            try:
                d.compile(tuple(fn_types) + key)
            finally:  # never compiled lazily: a kernel argument would be typed as itself (linked in)
                d.disable_compile(True)
            self._signatures[quick] = tuple(fn_types) + key
        return self._dispatcher

    @property
    def signatures(self) -> list:
        """The signatures compiled (numba's ``Dispatcher.signatures``)."""
        return list(self._dispatcher.signatures) if not _PURE_PYTHON else []

    def __call__(self, kernels: tuple, *args):
        if _PURE_PYTHON:
            return self.py_func(*kernels, *args)
        return self._compiled(kernels, args)(*kernels, *args)


def typed_entry(kernel, *args):
    """``kernel``'s compiled specialisation for the types of ``args``, callable without numba's typing per call.

    A call of a dispatcher from Python types every argument first (for a structured array, a lookup of its
    dtype per argument and call) and then calls the compiled specialisation's entry point (numba's
    ``Dispatcher.overloads[signature].entry_point``, the function that unboxes the arguments and calls the
    machine code). For a caller that calls one kernel every period with arrays whose types cannot change (its
    own records), this is that entry point, found once: compiled (or loaded from the cache) here, as a call
    with ``args`` would. **Only arrays of exactly these numba types may be passed to it**: the entry point does
    not check them (an array of another dtype, dimension or layout would be read as if it had these). Under
    ``NUMBA_DISABLE_JIT`` it is the Python function; should a numba release not expose the entry point, the
    dispatcher itself (typed per call, as before).

    Args:
        kernel: a :func:`jit` / :func:`jit_entry` dispatcher.
        args: values of the types it will be called with.
    """
    if _PURE_PYTHON:
        return kernel
    key = (kernel, *(_quick_type_key(a) for a in args))
    entry = _TYPED_ENTRIES.get(key)
    if entry is None:
        sig = tuple(numba.typeof(a) for a in args)  # tens of ms for a large record type: once per process
        kernel.compile(sig)
        entry = getattr(kernel.overloads.get(sig), "entry_point", None) or kernel
        _TYPED_ENTRIES[key] = entry
    return entry


_TYPED_ENTRIES: dict = {}
""":func:`typed_entry`'s answers by kernel and the arguments' quick type keys (:func:`_quick_type_key`)."""


@functools.cache
def _load_mujoco_library() -> None:
    """Make the symbols of the ``libmujoco`` of the installed ``mujoco`` package visible to compiled code."""
    # The same file the bindings loaded, so the process has one MuJoCo (one set of globals and callbacks).
    llvmlite.binding.load_library_permanently(_mujoco_library_path())


_PURE_PYTHON = bool(numba.config.DISABLE_JIT)
"""``NUMBA_DISABLE_JIT=1``: kernels run as Python, and the C calls below go through ctypes instead."""


def _mujoco_library_path() -> str:
    import mujoco

    folder = os.path.dirname(mujoco.__file__)
    names = sorted(f for f in os.listdir(folder) if f.startswith("libmujoco.so") or f.startswith("libmujoco."))
    if not names:
        raise ImportError(f"no libmujoco shared library in {folder}")
    return os.path.join(folder, names[0])


def mujoco_function(name: str, int_args: int = 0):
    """MuJoCo's ``void name(const mjModel* m, mjData* d, int...)``, callable from kernels with the two addresses.

    The addresses are ``MjModel._address`` and ``MjData._address`` of the Python bindings, passed as integers,
    followed by ``int_args`` C ``int`` arguments (e.g. ``mj_forwardSkip``'s ``skipstage, skipsensor``).
    MuJoCo's warnings land in ``MjData.warning`` as usual; a MuJoCo *error* inside such a call cannot be turned
    into a Python exception (the bindings' handler would unwind through compiled code), so only functions that
    raise none for a valid model are bound (the step functions). With ``NUMBA_DISABLE_JIT=1`` the same C
    function is called through ctypes.
    """
    if _PURE_PYTHON:
        import ctypes

        fn = getattr(ctypes.CDLL(_mujoco_library_path()), name)
        fn.argtypes = [ctypes.c_void_p, ctypes.c_void_p] + [ctypes.c_int] * int_args
        fn.restype = None
        return lambda m, d, *ints: fn(int(m), int(d), *(int(i) for i in ints))
    _load_mujoco_library()
    return types.ExternalFunction(name, types.void(types.uintp, types.uintp, *([types.int32] * int_args)))


@functools.cache
def mujoco_timer_address() -> int:
    """Address of MuJoCo's global ``mjcb_time`` (the clock of its profiler, ``MjData.timer``) in this process.

    Looked up once per process (every simulator asks for it; the library stays loaded, at the same address in a
    forked worker).

    The ``mujoco`` bindings install a default clock there whenever they create an ``MjData``; MuJoCo then reads
    it twice per pipeline stage (about 30 calls of ``clock_gettime`` per ``mj_Euler`` + ``mj_forward``). A
    kernel that steps MuJoCo and does not want the profile clears the word for its calls and restores it
    (:func:`omnirotor.sim.step.sim_step`). Only the profile depends on it, never the physics.
    """
    import ctypes

    return ctypes.addressof(ctypes.c_void_p.in_dll(ctypes.CDLL(_mujoco_library_path()), "mjcb_time"))


_clock_gettime = types.ExternalFunction("clock_gettime", types.int32(types.int32, types.uintp))
_CLOCK_MONOTONIC = 1  # Linux's CLOCK_MONOTONIC (the clock of time.perf_counter on Linux)
_NS_PER_S = 1_000_000_000


@jit
def monotonic_ns(ts) -> int:
    """Monotonic clock [ns] (``clock_gettime(CLOCK_MONOTONIC)``) for timing inside a compiled loop.

    Args:
        ts: (2,) int64 scratch array (a ``struct timespec``).
    """
    _clock_gettime(_CLOCK_MONOTONIC, ts.ctypes.data)
    return ts[0] * _NS_PER_S + ts[1]


# -- MuJoCo's arrays by address (the simulator's; the controller passes its one record instead) ----------------


@intrinsic
def _f64_pointer(typingctx, address):
    sig = types.CPointer(types.float64)(types.int64)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(types.CPointer(types.float64)))

    return sig, codegen


@intrinsic
def _i64_pointer(typingctx, address):
    sig = types.CPointer(types.int64)(types.int64)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(types.CPointer(types.int64)))

    return sig, codegen


@_leaf("float64[::1](int64, int64)")
def f64_at(address: int, n: int):
    """The 1-D float64 array of ``n`` entries at ``address`` (the caller keeps the memory alive)."""
    return numba.carray(_f64_pointer(address), (n,))


@_leaf("float64[:, ::1](int64, int64, int64)")
def f64_at2(address: int, rows: int, cols: int):
    """The C-ordered ``(rows, cols)`` float64 array at ``address`` (the caller keeps the memory alive)."""
    return numba.carray(_f64_pointer(address), (rows, cols))


@_leaf("int64[::1](int64, int64)")
def i64_at(address: int, n: int):
    """The 1-D int64 array of ``n`` entries at ``address`` (the caller keeps the memory alive)."""
    return numba.carray(_i64_pointer(address), (n,))


@jit
def profiler_clock_off(timer_adr: int) -> int:
    """Clear MuJoCo's profiler clock for the calls that follow; returns what to restore.

    Args:
        timer_adr: :func:`mujoco_timer_address`, or 0 to leave the clock alone.
    """
    if timer_adr == 0:
        return 0
    timer = i64_at(timer_adr, 1)
    clock = timer[0]
    timer[0] = 0
    return clock


@jit
def profiler_clock_restore(timer_adr: int, clock: int) -> None:
    """Put back the clock :func:`profiler_clock_off` cleared (nothing for ``timer_adr`` 0)."""
    if timer_adr != 0:
        i64_at(timer_adr, 1)[0] = clock


if _PURE_PYTHON:  # the same functions in Python (the intrinsics and the C clock exist only compiled)
    import ctypes
    import time

    def monotonic_ns(ts) -> int:  # noqa: F811 (the Python twin of the compiled one)
        """Monotonic clock [ns] (``time.perf_counter_ns``: CLOCK_MONOTONIC on Linux)."""
        return time.perf_counter_ns()

    def f64_at(address: int, n: int):  # noqa: F811
        """The 1-D float64 array of ``n`` entries at ``address``."""
        return np.ctypeslib.as_array((ctypes.c_double * int(n)).from_address(int(address)))

    def i64_at(address: int, n: int):  # noqa: F811
        """The 1-D int64 array of ``n`` entries at ``address``."""
        return np.ctypeslib.as_array((ctypes.c_int64 * int(n)).from_address(int(address)))

    def f64_at2(address: int, rows: int, cols: int):  # noqa: F811
        """The C-ordered ``(rows, cols)`` float64 array at ``address``."""
        return f64_at(address, int(rows) * int(cols)).reshape(int(rows), int(cols))
