"""A plot's metric read from a run record without flattening it (issue 16): the flattened record's value, always."""

import json
from pathlib import Path

import pytest

from omnirotor.experiments.campaigns.report import _flatten, metric_value

EDGES = {
    "a": {"b": 1.0, "c": [1, 2, 3], "d": [4, 5], "e": [1, "x"], "f": True, "g": None, "h": "text"},
    "a.b": 7,  # flattens to the same key as a -> b, after it: wins
    "p.q": 2.5,
    "p": {"q": 9.0},  # the nested one comes last here: it wins
    "": {"": 3, "z": 4},
    "long": list(range(9)),  # more than 8 numbers: not flattened
    "n": {"m": {"k": [0.5, 1.5, 2.5]}},
}


def _paths(metrics: dict) -> list[str]:
    flat = set(_flatten(metrics))
    extra = {"a", "a.c", "a.c.w", "a.c.xy", "a.d.2", "a.e.0", "a.f", "a.g", "a.h", "long.0", "n.m", "n.m.k", "zz", ""}
    return sorted(flat | extra | {k + ".x" for k in flat} | {k[:-1] for k in flat if k})


@pytest.mark.parametrize("metrics", [EDGES, {"x": 1}, {}])
def test_lookup_equals_the_flattened_value(metrics):
    for path in _paths(metrics):
        assert metric_value({"metrics": metrics}, path) == _flatten(metrics).get(path), path


def test_lookup_equals_the_flattened_value_on_a_run_record(tmp_path: Path):
    from omnirotor.experiments.campaigns.runner import execute_run, load_campaign, run_options

    spec = load_campaign(None, "hover", quick=True)
    job = run_options(spec, 3)
    record = json.loads(json.dumps(execute_run(job)))
    assert record["status"] == "ok"
    flat = _flatten(record["metrics"])
    assert len(flat) > 20
    for path in _paths(record["metrics"]):
        assert metric_value(record, path) == flat.get(path), path
    assert metric_value({"metrics": None}, "duration_s") is None
