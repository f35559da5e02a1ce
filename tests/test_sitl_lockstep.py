"""Lockstep software in the loop gives the metrics of ``omnirotor run`` (issue 24, item 4(a)).

The simulator (``omnirotor sim --serve --lockstep``) and the flight node run as two processes over real Zenoh on
loopback; the run's JSON must equal the in-process run's (same task, seed, quick protocol) to 1e-9 relative,
except the wall-clock timing entries.
"""

from __future__ import annotations

import math

import pytest

from omnirotor.experiments.tasks import run_task
from omnirotor.experiments.tasks.common import ExperimentOptions
from sitl.procs import Pair

TIMING = {"controller_step_us_median", "sitl", "figure"}


def leaves(x, path=""):
    if isinstance(x, dict):
        for k, v in x.items():
            if k not in TIMING:
                yield from leaves(v, f"{path}/{k}")
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from leaves(v, f"{path}[{i}]")
    else:
        yield path, x


def assert_same_metrics(sitl: dict, ref: dict) -> None:
    a, b = dict(leaves(sitl)), dict(leaves(ref))
    assert a.keys() == b.keys()
    checked = 0
    for key, want in b.items():
        got = a[key]
        if isinstance(want, float) and isinstance(got, float):
            assert math.isclose(got, want, rel_tol=1e-9, abs_tol=1e-12) or (math.isnan(got) and math.isnan(want)), key
            checked += 1
        else:
            assert got == want, key
    assert checked > 10


@pytest.mark.slow
@pytest.mark.parametrize("task", ["hover", "point-contact", "sliding"])
def test_lockstep_sitl_gives_the_in_process_metrics(task, tmp_path):
    with Pair(tmp_path, task, ["--seed", "3", "--quick"], lockstep=True) as pair:
        ref = run_task(task, ExperimentOptions(seed=3, quick=True)).summary()
        sitl, node = pair.wait(timeout_s=1200)
    assert sitl["sitl"]["lockstep"] and not sitl["sitl"]["failsafe"]
    assert sitl["sitl"]["log_rows_missing"] == 0
    # one per frame it stepped on, none held; plus the start frame's answer again if the first was late (the
    # simulator repeats its start frame every 10 ms until it obeys an answer, and the node answers each)
    steps, obeyed = sitl["sitl"]["steps"], sitl["sitl"]["commands_obeyed"]
    assert steps <= obeyed <= steps + node["start_frame_answered_again"] and sitl["sitl"]["commands_held"] == 0
    assert node["missed"] == 0 and not node["link_lost"]
    assert_same_metrics(sitl, ref)
