"""What a campaign worker keeps from one run to the next: the controller and the truth log (issue 16, throughput).

A campaign's runs build the same controller again and again (its parameters, the believed vehicle and the map are
the campaign's; what a run varies is the plant) and allocate the same two logs (the controller's, 120 000 rows
preallocated, and the simulator's truth log), whose fresh pages the kernel faults in and zeroes while the run
steps. Inside :func:`reusing` (what :func:`~omnirotor.experiments.campaign.execute_run` does), a finished run
hands its controller and truth log back here, and the next run with equal parameters resets them instead:
:meth:`~omnirotor.control.controller.InteractionController.reset` starts every block afresh, as on a new
controller, and the logs are cleared (a row is written whole before it is read). The runs' results are the
one-run path's, number for number (tests/test_campaign_identical.py, tests/test_run_reuse.py).

Kept only when nothing of the run outlives it in them: a run that told its controller of a failed rotor (the
allocator keeps that mask across a reset) or flew identified maps (their scheduler's map is the run's own) gives
nothing back, nor does one that raised. Outside :func:`reusing` every run builds its own, so a caller that keeps
a run's logs (``omnirotor run``, ``reproduce``) never sees them written again.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from omnirotor.recorder import GroupSpec, Recorder

__all__ = ["reusing", "active", "controller", "give_back_controller", "truth_log"]

_state: dict[str, Any] = {"depth": 0, "controller": None, "truth": None}


@contextlib.contextmanager
def reusing() -> Iterator[None]:
    """Let the runs inside the block take the controller and the truth log the previous run gave back."""
    _state["depth"] += 1
    try:
        yield
    finally:
        _state["depth"] -= 1


def active() -> bool:
    """True inside :func:`reusing`."""
    return _state["depth"] > 0


def _equal(a: Any, b: Any) -> bool:
    if a is b:
        return True
    try:
        return bool(a == b)
    except (ValueError, TypeError):  # fields that do not compare as one truth value: not the same
        return False


def controller(vehicle, params, maps, build: Callable[[], Any]):
    """The controller of a run: the one given back by the previous run when it was built alike, else ``build()``.

    Args:
        vehicle: the believed vehicle it is built for.
        params: its :class:`~omnirotor.control.controller.ControllerParams`.
        maps: its wrench maps (None: the nominal map); identified maps are never reused.
        build: makes a new one.
    """
    kept = _state["controller"]
    _state["controller"] = None  # taken: a run that fails gives nothing back
    if active() and maps is None and kept is not None:
        ctl, key_vehicle, key_params = kept
        if _equal(key_vehicle, vehicle) and _equal(key_params, params):
            return ctl
    return build()


def give_back_controller(ctl, vehicle, params, maps) -> None:
    """Keep ``ctl`` for the next run (inside :func:`reusing`, when nothing of this run stays in it)."""
    keep = active() and maps is None and not bool(np.any(ctl.allocator.failed_rotors))
    _state["controller"] = (ctl, vehicle, params) if keep else None


def truth_log(rows: int, groups: list[GroupSpec]) -> Recorder:
    """A cleared truth log of at least ``rows`` rows: the previous run's (inside :func:`reusing`), else a new one.

    The previous run's is kept until the next call (its summary reads it first).
    """
    kept = _state["truth"]
    if active() and kept is not None and kept[0] == groups:
        log = kept[1]
        log.clear()
        log.ensure_capacity(rows)
        return log
    log = Recorder(rows, groups)
    _state["truth"] = (groups, log) if active() else None
    return log
