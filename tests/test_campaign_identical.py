"""A pooled campaign's runs are the one-run path's runs, number for number (issue #16, campaign throughput).

The campaign's workers are forked, warmed up on a short run, and fly many runs each; none of that may change a
single result. Every metric is compared exactly (``==`` on the JSON numbers), except
``controller_step_us_median``: the wall-clock time of this machine's controller steps, which differs between
any two runs of the same seed.
"""

import json

import pytest

from omnirotor.cli import main
from omnirotor.experiments.campaigns.report import jsonable, load_results
from omnirotor.experiments.campaigns.runner import load_campaign, run_campaign, run_options
from omnirotor.experiments.tasks import run_task

TIMING = ("controller_step_us_median",)
"""Summary keys measured by the wall clock (never reproducible)."""

PERTURBED = """
task = "{task}"
seed = 3
[options]
quick = true
estimator = "ukf"
duration_s = {duration}
[vary.mass_error]
dist = "normal"
std = 0.03
[vary.gamma]
dist = "uniform"
low = 2.0
high = 8.0
[vary.rotor_gain_error_std]
dist = "uniform"
low = 0.0
high = 0.05
[vary.sensor_noise_scale]
dist = "loguniform"
low = 0.5
high = 3.0
[vary.mocap_latency_s]
dist = "uniform"
low = 0.002
high = 0.020
[vary.mocap_dropout_s]
dist = "choice"
values = [0.2]
[vary.gust_force_N]
dist = "uniform"
low = 1.0
high = 4.0
"""
"""The default campaign's parameters, its timed faults in every run (a dropout and a gust)."""


def comparable(summary: dict) -> dict:
    """A run summary as the results file holds it (JSON numbers), less the wall-clock timings."""
    out = json.loads(json.dumps(jsonable(summary)))
    for key in TIMING:
        out.pop(key, None)
    return out


@pytest.mark.parametrize(("task", "runs", "duration"), [("hover", 4, 3.0), ("sliding", 2, 7.0)])
def test_pooled_runs_equal_the_one_run_path_run_by_run(tmp_path, task, runs, duration):
    camp = tmp_path / f"{task}.toml"
    camp.write_text(PERTURBED.format(task=task, duration=duration))
    spec = load_campaign(camp)
    s = run_campaign(spec, tmp_path / "c", runs=runs, workers=2, plots=False)
    assert s["executed"] == runs and s["runs_error"] == 0
    records = load_results(tmp_path / "c")
    assert sorted(records) == list(range(runs))
    for i, rec in records.items():
        job = run_options(spec, i)
        assert job.derived["mocap_dropout_t_s"] < duration and job.derived["gust_t_s"] < duration  # faults fly
        alone = run_task(job.task, job.options).summary()
        assert comparable(rec["metrics"]) == comparable(alone), f"run {i} differs from the one-run path"


UNPERTURBED = """
task = "hover"
seed = 5
[options]
estimator = "ukf"
duration_s = 1.5
[vary.sensor_noise_scale]
dist = "constant"
value = 1.0
"""
"""A campaign whose runs fly the model itself: each run is ``omnirotor run hover`` with the run's seed."""


def test_pooled_runs_equal_omnirotor_run_of_the_same_seed(tmp_path, capsys):
    camp = tmp_path / "plain.toml"
    camp.write_text(UNPERTURBED)
    spec = load_campaign(camp)
    run_campaign(spec, tmp_path / "c", runs=3, workers=2, plots=False)
    for i, rec in load_results(tmp_path / "c").items():
        job = run_options(spec, i)
        assert job.options.plant is None
        capsys.readouterr()
        argv = ["run", "hover", "--seed", str(job.options.seed), "--duration", "1.5", "--json"]
        assert main(argv) == 0
        cli = json.loads(capsys.readouterr().out)
        assert comparable(rec["metrics"]) == comparable(cli)
