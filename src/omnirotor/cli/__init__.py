"""The ``omnirotor`` command line: a thin layer over library functions.

Each command lives in a module of this package, listed in :data:`COMMAND_MODULES`, and adds itself to
:data:`app`. :func:`main` turns every :class:`~omnirotor.errors.InputError` and usage error into one line on
stderr and exit status 2, and Ctrl-C into one line and exit status 130. Python warnings (numpy's overflow or
invalid-value warnings, say) never reach the terminal one by one: a command that fails says only its error;
one that succeeds says in one line how many numerical (``RuntimeWarning``) ones there were and the first;
others are dropped.

No code from the working folder (issue 26, item 4): before anything else is imported, :func:`drop_working_folder`
takes the folder the command runs in off ``sys.path`` (a ``numpy.py`` or ``queue.py`` there must not run as
code). The campaign's pool workers are forked, with this ``sys.path``; a local Ray's workers start with
``PYTHONSAFEPATH`` (:mod:`omnirotor.experiments.campaigns.runner`).
"""

# No `from __future__ import annotations` here: that imports the module __future__, before the working folder
# is off sys.path.
import os
import sys


def drop_working_folder(path: list[str] | None = None) -> list[str]:
    """Remove the working folder from ``path`` (``sys.path``): ``""``, ``"."`` and any entry that resolves to it.

    Returns the removed entries.
    """
    path = sys.path if path is None else path
    try:
        cwd = os.path.realpath(os.getcwd())
    except OSError:  # the working folder was deleted: only the relative entries can point into it
        cwd = None
    removed = [p for p in path if p in ("", ".") or (cwd is not None and os.path.realpath(p) == cwd)]
    path[:] = [p for p in path if p not in removed]
    return removed


drop_working_folder()

# Everything below is imported after the working folder is off sys.path (hence E402).
import warnings  # noqa: E402

import typer  # noqa: E402

# typer 0.29 vendors click; its exception classes are needed to print usage errors on one line, its line wrapper
# to keep hyphenated names whole in the help (_HelpWrapper).
from typer._click import _textwrap  # noqa: E402
from typer._click import exceptions as click_exc  # noqa: E402
from typer.core import TyperGroup  # noqa: E402

from omnirotor.errors import InputError  # noqa: E402

__all__ = [
    "app",
    "main",
    "number_option",
    "Interrupted",
    "EXIT_BAD_INPUT",
    "EXIT_INTERRUPTED",
    "CommandGroup",
    "NUMBA_OPT_DEFAULT",
    "use_numba_opt_default",
]

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130


class _HelpWrapper(_textwrap.TextWrapper):
    """The help's line wrapper, which never breaks a word at its hyphens.

    The help names tasks, options and files with hyphens (``identify-dynamic-cells``, ``--mocap-topic``); broken at
    a hyphen across two lines ("identify-dynamic-" / "cells") such a name can no longer be read or copied as it
    is typed. A word longer than the line is still broken (textwrap's ``break_long_words``).
    """

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("break_on_hyphens", False)
        super().__init__(*args, **kwargs)


_textwrap.TextWrapper = _HelpWrapper  # the help formatter (typer's click) looks it up each time it wraps


class CommandGroup(TyperGroup):
    """A group of commands whose ``--help`` flag is ``False`` when not given (typer's own is ``None``).

    typer 0.29 runs every parameter of a group that leads to a sub-command through its value coercion, which
    passes a ``bool`` flag through as it is but turns ``None`` into a pydantic ``TypeAdapter``: importing
    pydantic alone takes about 0.15 s, half of ``omnirotor identify --help``. Nothing else changes.
    """

    def get_help_option(self, ctx):  # noqa: D102  (click's documented hook)
        option = super().get_help_option(ctx)
        if option is not None:
            option.default = False
        return option


app = typer.Typer(
    cls=CommandGroup,
    name="omnirotor",
    help="Sensorless 6-D physical interaction with omnidirectional multirotors.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


def _version(value: bool) -> None:
    """``--version``: the installed package's version (its metadata; the source's when run from a checkout)."""
    if not value:
        return
    from importlib.metadata import PackageNotFoundError, version

    try:
        text = version("omnirotor")
    except PackageNotFoundError:
        text = "unknown (not installed)"
    print(f"omnirotor {text}")
    raise typer.Exit(0)


@app.callback()
def _root(
    show_version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Sensorless 6-D physical interaction with omnidirectional multirotors."""


class Interrupted(Exception):  # noqa: N818  (not an error: the user stopped the command)
    """Raised by a command stopped by Ctrl-C that has something to say (what was kept); exit status 130."""


def number_option(text: str) -> float:
    """Typer parser of a float option: ``1_0`` and other spellings Python's ``float`` accepts are refused."""
    from omnirotor.config import parse_float

    try:
        return parse_float(text, "")
    except InputError as exc:
        raise typer.BadParameter(str(exc).removeprefix(": ")) from None


COMMAND_MODULES = (
    "cmd_calibrate",
    "cmd_campaign",
    "cmd_ctl",
    "cmd_fly",
    "cmd_hover_windows",
    "cmd_identify",
    "cmd_info",
    "cmd_px4_bridge",
    "cmd_regions",
    "cmd_render",
    "cmd_reproduce",
    "cmd_run",
    "cmd_sim",
    "cmd_study",
)
"""The modules of this package whose commands :data:`app` offers: a new command's module gets a line here
(``tests/test_working_folder.py`` checks that every ``cmd_*.py`` has one)."""


def _register() -> None:
    """Import the command modules of :data:`COMMAND_MODULES` (each adds its commands to :data:`app`)."""
    import importlib

    for name in COMMAND_MODULES:
        importlib.import_module(f"{__name__}.{name}")


NUMBA_OPT_DEFAULT = "1"
"""numba's LLVM optimisation level (``NUMBA_OPT``) for the command's compiled kernels, unless the environment
sets one (a user's ``NUMBA_OPT`` wins). Level 1 compiles a first run's kernels in less CPU time than numba's
default 3 and the step runs as fast (BENCHMARKS.md, issue 23 item 6, session 14); the level does not change
the arithmetic (no fast-math: the controller's reference replays bit for bit at either). The library itself
leaves numba's setting alone; the kernel cache keeps each level apart (:func:`omnirotor._jit.codegen_settings`).
"""


def use_numba_opt_default() -> None:
    """Set ``NUMBA_OPT`` to :data:`NUMBA_OPT_DEFAULT` for this process unless it is set (before any compile).

    For the command's own process (:func:`main`) and its workers, which inherit the environment.
    """
    if "NUMBA_OPT" in os.environ:
        return
    os.environ["NUMBA_OPT"] = NUMBA_OPT_DEFAULT
    numba = sys.modules.get("numba")
    if numba is not None:  # imported already (an in-process caller): numba reads its settings again
        numba.core.config.reload_config()


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns (and exits with) the process status.

    Run as the command (``argv`` None: the process is the command's own), it first applies the command's numba
    optimisation level (:func:`use_numba_opt_default`); called in a process of the caller's, it leaves numba's
    settings as they are.
    """
    if argv is None:
        use_numba_opt_default()
    _register()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code = _invoke(argv)
    numeric = [w for w in caught if issubclass(w.category, RuntimeWarning)]  # others (plot legends) are harmless
    if code == 0 and numeric:
        first = numeric[0]
        print(
            f"omnirotor: note: {len(numeric)} numerical warning(s) while running, the first: "
            f"{first.category.__name__}: {str(first.message).splitlines()[0][:160]}",
            file=sys.stderr,
        )
    if argv is None:
        sys.exit(code)
    return code


def _caused_by_interrupt(exc: BaseException) -> bool:
    """True if a KeyboardInterrupt is in ``exc``'s chain of causes and contexts.

    A Ctrl-C that lands while a compiled extension initialises (the commands import MuJoCo and numba lazily)
    comes out of the import as ``ImportError: initialization failed`` raised from the KeyboardInterrupt.
    """
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def _invoke(argv: list[str] | None) -> int:
    """The command's exit status, with every error path reduced to one line on stderr."""
    try:
        rv = app(args=argv, standalone_mode=False)
    except InputError as exc:
        print(f"omnirotor: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Interrupted as exc:
        print(f"omnirotor: interrupted; {exc}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (typer.Abort, KeyboardInterrupt):
        rv = EXIT_INTERRUPTED
    except ImportError as exc:
        if not _caused_by_interrupt(exc):
            raise
        rv = EXIT_INTERRUPTED  # Ctrl-C inside a compiled module's initialisation (MuJoCo's, say)
    except typer.Exit as exc:
        rv = exc.exit_code
    except click_exc.ClickException as exc:
        print(f"omnirotor: error: {exc.format_message()}", file=sys.stderr)
        return EXIT_BAD_INPUT
    # typer turns Ctrl-C into Exit(130) and, outside standalone mode, returns its code
    code = rv if isinstance(rv, int) and not isinstance(rv, bool) else 0
    if code == EXIT_INTERRUPTED:
        print("omnirotor: interrupted", file=sys.stderr)
    return code
