"""The compiled closed loop: simulator and controller alternate inside one compiled call (no Python per step).

:func:`run_steps` is the fast path of :func:`omnirotor.experiments.loop.run_closed_loop`. Each step is
exactly what the Python loop does, through the same kernels: the simulator's step
(:func:`omnirotor.sim.step.sim_step`, which calls MuJoCo's C step functions) writes the packed sensor frame
(:mod:`omnirotor.messages`) and the truth row; the controller's step
(:func:`omnirotor.control.composer.controller_step`) reads that frame and writes its command, which the
next simulator step reads. The two sides meet only through the packed frame and the command array, as their
Python methods meet through :class:`~omnirotor.messages.SensorFrame` and
:class:`~omnirotor.messages.RotorCommand`; this module (an experiment) is the only place that holds both.

A call runs until ``stop`` or until a noise stream of the simulator has no row left for the next step; the
caller then refills the streams (:attr:`omnirotor.sim.simulator.Simulator.noise_streams`), reports progress
and calls again.
"""

from __future__ import annotations

from omnirotor._jit import PointerCaller, monotonic_ns
from omnirotor.control.composer import controller_step
from omnirotor.sim.sensors import needs_refill
from omnirotor.sim.step import sim_step

__all__ = ["run_steps"]

_NS_PER_US = 1e3


def _run_steps(
    plant_step, control_step, sim, ctl_state, cmd_hz, frame, k: int, stop: int, k_sim0: int, dt: float, truth, log, ts
) -> int:
    """:func:`run_steps`, with the simulator's and the controller's steps called through their addresses."""
    sensors = sim[0]["sensors"]
    timing = truth.shape[1] - 1
    while k < stop:
        if needs_refill(sensors):
            break
        row = truth[k]
        tic0 = monotonic_ns(ts)
        plant_step(sim, cmd_hz, k_sim0 + k, dt, frame, row)
        tic = monotonic_ns(ts)
        control_step(ctl_state, frame, log[k : k + 1])
        toc = monotonic_ns(ts)
        row[timing - 1] = (tic - tic0) / _NS_PER_US
        row[timing] = (toc - tic) / _NS_PER_US
        k += 1
    return k


def _callee_args(sim, ctl_state, cmd_hz, frame, k, stop, k_sim0, dt, truth, log, ts) -> tuple:
    """The values :func:`_run_steps` calls the simulator's and the controller's steps with (their types)."""
    return (sim, cmd_hz, k_sim0 + k, dt, frame, truth[0]), (ctl_state, frame, log[0:1])


_run_steps_compiled = PointerCaller(_run_steps, _callee_args)


def run_steps(sim, ctl_state, cmd_hz, frame, k: int, stop: int, k_sim0: int, dt: float, truth, log, ts) -> int:
    """Steps ``k, k+1, ...`` of a closed-loop run, up to ``stop`` or the end of a noise block.

    One compiled call. The simulator's step (:func:`~omnirotor.sim.step.sim_step`) and the controller's
    (:func:`~omnirotor.control.composer.controller_step`) are compiled on their own, for the same types as
    from Python (one specialisation each, shared with ``Simulator.step`` and ``InteractionController.step``),
    and called through their addresses (:class:`omnirotor._jit.PointerCaller`): the loop does not compile the
    controller and the simulator a second time into its own machine code.

    Args:
        sim: :attr:`omnirotor.sim.simulator.Simulator.kernel_state` (the simulator's record).
        ctl_state: :attr:`omnirotor.control.controller.InteractionController.kernel_state` (its record).
        cmd_hz: (n,) the controller's command array [Hz] (the simulator's input; the controller writes it).
        frame: the simulator's packed frame.
        k: first step of this call (row of both logs).
        stop: step to stop before.
        k_sim0: the simulator's step index at k = 0.
        dt: control period [s].
        truth: (rows, TRUTH_ROW_SIZE + n + 2) truth log data; the last two columns get the simulator's and the
            controller's step times [µs].
        log: the controller log's rows as records (``InteractionController.log_dtype``, one per step).
        ts: (2,) int64 scratch of the clock.

    Returns:
        The next step to run (== ``stop`` when done).
    """
    return _run_steps_compiled(
        (sim_step, controller_step), sim, ctl_state, cmd_hz, frame, k, stop, k_sim0, dt, truth, log, ts
    )
