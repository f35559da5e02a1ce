"""The ``omnirotor`` command line: a thin layer over library functions.

Each command lives in a module of this package and registers itself on :data:`app`. :func:`main` turns
every :class:`~omnirotor.errors.InputError` and usage error into one line on stderr and exit status 2.
"""

from __future__ import annotations

import sys

import typer

# typer 0.29 vendors click; its exception classes are needed to print usage errors on one line.
from typer._click import exceptions as click_exc

from omnirotor.errors import InputError

__all__ = ["app", "main", "EXIT_BAD_INPUT"]

EXIT_BAD_INPUT = 2

app = typer.Typer(
    name="omnirotor",
    help="Sensorless 6-D physical interaction with omnidirectional multirotors.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


@app.callback()
def _root() -> None:
    """Sensorless 6-D physical interaction with omnidirectional multirotors."""


def _register() -> None:
    import importlib
    import pkgutil

    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("cmd_"):
            importlib.import_module(f"{__name__}.{info.name}")


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns (and exits with) the process status."""
    _register()
    try:
        app(args=argv, standalone_mode=False)
    except InputError as exc:
        print(f"omnirotor: error: {exc}", file=sys.stderr)
        code = EXIT_BAD_INPUT
    except (typer.Abort, KeyboardInterrupt):
        print("omnirotor: aborted", file=sys.stderr)
        code = 130
    except typer.Exit as exc:
        code = exc.exit_code
    except click_exc.ClickException as exc:
        print(f"omnirotor: error: {exc.format_message()}", file=sys.stderr)
        code = EXIT_BAD_INPUT
    else:
        code = 0
    if argv is None:
        sys.exit(code)
    return code
