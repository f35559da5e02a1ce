"""The tasks of ``omnirotor run`` and of campaigns: one explicit table, :data:`TASKS` (no registration by import).

A task is a function ``(TaskOptions, progress) -> TaskResult`` (:class:`~omnirotor.experiments.loop.TaskOptions`,
:class:`~omnirotor.experiments.loop.TaskResult`) in a module of this package; :data:`TASKS` names its module
and function, and :func:`run_task` imports that module when the task is first run (so ``omnirotor --help`` and
a campaign's planning import no simulator). To add a task: write its function, add its line to :data:`TASKS`
(``tests/test_import_layout.py`` checks that every line resolves to a function).

Modules: :mod:`~omnirotor.experiments.tasks.common` (the paper's contact and hover experiments, SPEC §3.4,
§5.2, and what every task shares), :mod:`~omnirotor.experiments.tasks.scenarios` (their references),
:mod:`~omnirotor.experiments.tasks.identify_dynamic` (the attitude excitation for torque identification).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TYPE_CHECKING

from omnirotor.errors import InputError

if TYPE_CHECKING:
    from omnirotor.experiments.loop import TaskOptions, TaskResult

__all__ = ["TASKS", "NOMINAL_MAP_TASKS", "task_function", "run_task"]

TASKS: dict[str, tuple[str, str]] = {
    "hover": ("common", "hover"),
    "identify-flights": ("common", "identify_flights"),
    "hover-validation": ("common", "hover_validation"),
    "point-contact": ("common", "point_contact_task"),
    "point-contact-tilted": ("common", "point_contact_tilted_task"),
    "sliding": ("common", "sliding_task"),
    "peg-in-hole": ("common", "peg_in_hole_task"),
    "identify-dynamic": ("identify_dynamic", "identify_dynamic"),
    "identify-dynamic-cells": ("identify_dynamic", "identify_dynamic_cells"),
}
"""Task name -> (module of this package, function)."""

NOMINAL_MAP_TASKS = frozenset({"hover"})
"""Tasks that fly the nominal map whatever the options say (:func:`run_task` refuses map options for them)."""
_MAP_OPTIONS = (("--map", "map_mode", "nominal"), ("--maps", "maps", None), ("--blend", "blend", "hard"))


def task_function(name: str) -> Callable:
    """The function of task ``name`` (its module imported now).

    Raises:
        InputError: unknown task name.
    """
    if name not in TASKS:
        raise InputError(f"unknown task {name!r}; tasks: {', '.join(sorted(TASKS))}")
    module, function = TASKS[name]
    return getattr(importlib.import_module(f"{__name__}.{module}"), function)


def run_task(
    name: str, options: TaskOptions | None = None, progress: Callable[[float], None] | None = None
) -> TaskResult:
    """Run a task of :data:`TASKS`.

    Raises:
        InputError: unknown task name or bad options.
    """
    fn = task_function(name)
    if options is not None and name in NOMINAL_MAP_TASKS:
        # the task flies the nominal map: say so rather than ignore the map options silently
        ignored = [flag for flag, field, default in _MAP_OPTIONS if getattr(options, field, default) != default]
        if ignored:
            raise InputError(f"task {name!r} flies the nominal map only; {', '.join(ignored)} do(es) not apply")
    if options is None:
        from omnirotor.experiments.loop import TaskOptions

        options = TaskOptions()
    return fn(options, progress)
