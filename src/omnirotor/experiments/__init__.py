"""The paper's experiments in simulation: closed-loop runs, their metrics, and the tasks of ``omnirotor run``.

:func:`~omnirotor.experiments.closed_loop.run_closed_loop` flies an
:class:`~omnirotor.control.controller.InteractionController` in a
:class:`~omnirotor.sim.Simulator`; :data:`TASKS` is the registry of runnable tasks (``hover``, and those
other modules of this package register with :func:`register_task`).
"""

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
