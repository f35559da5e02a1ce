"""A campaign's plots drawn on one reused figure (issue 16): the same PNG files, byte for byte, as one figure each."""

import numpy as np

from omnirotor.experiments.campaigns.report import plot_parameter, plot_parameters
from omnirotor.experiments.campaigns.runner import load_campaign


def _records(spec, n: int = 60) -> list[dict]:
    rng = np.random.default_rng(3)
    out = []
    for i in range(n):
        metrics: dict = {}
        node = metrics
        *parents, leaf = spec.key_metric.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = float(rng.uniform(0, 5)) if i % 7 else None  # some runs without the metric
        params = {"gamma": float(rng.uniform(2, 8)), "mocap_dropout_s": [0.0, 0.2, 0.5][i % 3]}
        if i % 2:
            params["mass_error"] = float(rng.normal(0, 0.03))
        out.append({"index": i, "status": "ok", "params": params, "metrics": metrics, "success": bool(i % 3)})
    return out


def test_reused_figure_draws_the_same_files(tmp_path):
    spec = load_campaign(None, "hover", quick=True)
    ok = _records(spec)
    names = ["no_such_param", "gamma", "mocap_dropout_s", "no_such_param", "mass_error", "gamma"]
    one, batch = tmp_path / "one", tmp_path / "batch"
    one.mkdir()
    batch.mkdir()
    singles = [plot_parameter(spec, ok, name, one).read_bytes() for name in names]
    drawn = [p.read_bytes() for p in plot_parameters(spec, ok, names, batch)]
    assert len(drawn) == len(names)
    assert drawn == singles
    assert singles[0] != singles[1]  # the plots differ: the comparison means something
    assert plot_parameters(spec, ok, [], batch) == []
