"""Runs of unequal length are sent longest first (issue 16): no worker is left alone with a long run at the end."""

from omnirotor.experiments.campaigns.runner import (
    campaign_from_mapping,
    execute_run,
    expected_duration_s,
    longest_first,
    run_options,
)


def _spec(task: str, vary: dict, **options):
    return campaign_from_mapping({"task": task, "runs": 12, "options": {"quick": True, **options}, "vary": vary})


def test_unequal_runs_go_longest_first_and_equal_ones_keep_their_order():
    spec = _spec("point-contact", {"scenario.segment_s": {"dist": "choice", "values": [1.0, 2.0, 3.0]}})
    jobs = [run_options(spec, i) for i in range(12)]
    lengths = [expected_duration_s(j) for j in jobs]
    assert len(set(lengths)) == 3  # the draw gave all three segment lengths
    order = longest_first(jobs)
    assert sorted(j.index for j in order) == list(range(12))  # every run once
    got = [expected_duration_s(j) for j in order]
    assert got == sorted(lengths, reverse=True)
    for d in set(lengths):  # among equal lengths: index order
        same = [j.index for j in order if expected_duration_s(j) == d]
        assert same == sorted(same)
    equal = [run_options(_spec("hover", {"gamma": {"dist": "uniform", "low": 2.0, "high": 8.0}}), i) for i in range(5)]
    assert [j.index for j in longest_first(equal)] == [0, 1, 2, 3, 4]


def test_expected_length_is_the_length_the_run_flies():
    spec = _spec("point-contact", {"scenario.segment_s": {"dist": "constant", "value": 0.5}})
    job = run_options(spec, 0)
    record = execute_run(job)
    assert record["status"] == "ok"
    assert expected_duration_s(job) == record["metrics"]["duration_s"]
    hover = run_options(_spec("hover", {"gamma": {"dist": "constant", "value": 4.0}}), 0)
    assert expected_duration_s(hover) == execute_run(hover)["metrics"]["duration_s"]
    short = run_options(_spec("hover", {"gamma": {"dist": "constant", "value": 4.0}}, duration_s=0.5), 0)
    assert expected_duration_s(short) == 0.5
