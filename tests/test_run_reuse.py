"""A campaign worker's controller and truth log reused from run to run (experiments.reuse): every logged value the same.

The whole logs of a run flown on the previous run's controller and truth log are compared with those of the same
run on new ones, column by column and bit for bit, less the two wall-clock columns (step times), which differ
between any two runs.
"""

import dataclasses

import numpy as np
import pytest

from omnirotor.experiments import reuse
from omnirotor.experiments.campaign import load_campaign, run_options
from omnirotor.experiments.closed_loop import run_task

WALL_CLOCK = ("plant_step_us", "controller_step_us")


def _jobs(task: str, duration_s: float, n: int) -> list:
    spec = load_campaign(None, task, quick=True)
    return [dataclasses.replace(run_options(spec, i).options, duration_s=duration_s) for i in range(n)]


def _assert_logs_equal(a, b):
    for rec_a, rec_b in ((a.controller_log, b.controller_log), (a.truth_log, b.truth_log)):
        assert rec_a.n == rec_b.n and rec_a.group_names == rec_b.group_names
        for g in rec_a.group_names:
            if g not in WALL_CLOCK:
                np.testing.assert_array_equal(rec_a.group(g), rec_b.group(g), err_msg=g)


@pytest.mark.parametrize(("task", "duration_s"), [("hover", 1.2), ("point-contact", 1.2)])
def test_a_run_on_the_previous_runs_controller_is_the_run_on_a_new_one(task, duration_s):
    first, second = _jobs(task, duration_s, 2)
    alone = run_task(task, second)
    with reuse.reusing():
        before = run_task(task, first)
        again = run_task(task, second)
    assert again.controller_log is before.controller_log  # reused, not rebuilt
    assert again.truth_log is before.truth_log
    _assert_logs_equal(again, alone)
    assert {k: v for k, v in again.summary().items() if k != "controller_step_us_median"} == {
        k: v for k, v in alone.summary().items() if k != "controller_step_us_median"
    }


def test_nothing_is_reused_outside_a_campaign_run():
    job = _jobs("hover", 0.3, 1)[0]
    a, b = run_task("hover", job), run_task("hover", job)
    assert a.controller_log is not b.controller_log and a.truth_log is not b.truth_log


def test_a_controller_told_of_a_failed_rotor_is_not_given_back():
    job = _jobs("hover", 0.3, 1)[0]
    with reuse.reusing():
        first = run_task("hover", job)
        ctl = reuse._state["controller"][0]
        mask = np.zeros(ctl.vehicle.n_rotors, dtype=bool)
        mask[2] = True
        ctl.set_failed_rotors(mask)
        reuse.give_back_controller(ctl, ctl.vehicle, ctl.params, None)  # what _fly does after such a run
        assert reuse._state["controller"] is None
        second = run_task("hover", job)
    assert second.controller_log is not first.controller_log
