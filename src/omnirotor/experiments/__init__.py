"""The paper's experiments in simulation: closed-loop runs, their metrics, and the tasks of ``omnirotor run``.

:func:`~omnirotor.experiments.closed_loop.run_closed_loop` flies an
:class:`~omnirotor.control.controller.InteractionController` in a
:class:`~omnirotor.sim.Simulator`; :data:`TASKS` is the registry of runnable tasks (``hover``, and those
other modules of this package register with :func:`register_task`).

The names below are imported on first use: a module of this package that needs none of them (the resident
pool's client, :mod:`omnirotor.experiments.campaign_pool`) loads without numpy, MuJoCo or numba.
"""

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from omnirotor.experiments.closed_loop import (
        TASKS,
        TaskOptions,
        TaskResult,
        register_task,
        run_closed_loop,
        run_log,
        run_task,
    )

__all__ = ["TASKS", "TaskOptions", "TaskResult", "register_task", "run_closed_loop", "run_log", "run_task"]


def __getattr__(name: str):
    if name in __all__:
        from omnirotor.experiments import closed_loop

        return getattr(closed_loop, name)
    raise AttributeError(f"module 'omnirotor.experiments' has no attribute {name!r}")
