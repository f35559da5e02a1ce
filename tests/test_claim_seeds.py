"""``omnirotor reproduce --seeds N``: the claims' goals checked per seed (issue 12, item 4)."""

import json

import pytest

from omnirotor.cli import main
from omnirotor.experiments.paper import claims
from omnirotor.experiments.paper import reproduce as rp


def _metrics(lost_nominal: bool, fz_nominal: float = 2.0, underestimate: float = 1.0, depth_m: float = 0.168):
    """The fields of one seed's metrics.json the goals read, as reproduce writes them."""

    def hover(fz):
        return {"regions": {r: {"force_W_mean_N": [0.0, 0.0, fz]} for r in ("R1", "R3", "R4")}}

    def sliding(lost):
        return {"contact": {"lost": lost}}

    return {
        "hover-validation/nominal": hover(fz_nominal),
        "hover-validation/global": hover(0.1),
        "hover-validation/piecewise": hover(-0.2),
        "sliding/nominal": sliding(lost_nominal),
        "sliding/global": sliding(False),
        "sliding/piecewise": sliding(False),
        "point-contact-tilted/nominal": {"normal_force": {"underestimate_N": underestimate}},
        "point-contact/nominal": {"force": {"estimate_rms_error_N": 0.4}},
        "peg-in-hole/nominal": {"insertion": {"max_depth_m": depth_m, "inserted_tilt_deg": 5.0}},
    }


def _by_name(goals):
    return {g["name"]: g for g in goals}


def test_sliding_loss_needs_eight_of_ten():
    eight = _by_name(claims.evaluate_goals({s: _metrics(lost_nominal=s < 8) for s in range(10)}))
    seven = _by_name(claims.evaluate_goals({s: _metrics(lost_nominal=s < 7) for s in range(10)}))
    assert eight["sliding_nominal_loses"]["passes"] == 8 and eight["sliding_nominal_loses"]["met"]
    assert seven["sliding_nominal_loses"]["passes"] == 7 and not seven["sliding_nominal_loses"]["met"]
    assert eight["sliding_piecewise_keeps"]["met"] and eight["sliding_global_keeps"]["need"] == 10


def test_band_goals_and_missing_runs():
    per_seed = {0: _metrics(True, fz_nominal=2.6), 1: _metrics(True, underestimate=0.69), 2: _metrics(True)}
    del per_seed[2]["peg-in-hole/nominal"]
    g = _by_name(claims.evaluate_goals(per_seed))
    assert g["hover_bias_nominal"]["passed"] == [False, True, True]
    assert not g["hover_bias_nominal"]["met"]  # 2 < ceil(0.8 × 3)
    assert g["tilted_underestimate"]["passed"] == [True, False, True]
    assert g["hover_bias_piecewise"]["values"] == [pytest.approx(0.2)] * 3 and g["hover_bias_piecewise"]["met"]
    assert g["peg_depth"]["values"][2] is None and not g["peg_depth"]["met"]  # a missing run never passes
    assert g["peg_depth"]["values"][0] == pytest.approx(16.8)


def test_cli_seeds_runs_each_seed_and_writes_the_report(tmp_path, monkeypatch, capsys):
    calls = []

    def fake_reproduce(out, quick, seed, estimator, workers, progress, disturbances):
        calls.append((seed, quick, out.name, disturbances))
        progress("interaction runs", 0.5)
        return _metrics(lost_nominal=seed != 5)

    monkeypatch.setattr(rp, "reproduce", fake_reproduce)
    out = tmp_path / "claims"
    code = main(["reproduce", "--quick", "--no-disturbances", "--seeds", "3", "--seed", "4", "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0
    assert calls == [(4, True, "seed-4", False), (5, True, "seed-5", False), (6, True, "seed-6", False)]
    data = json.loads((out / "claims-seeds.json").read_text())
    g = _by_name(data["goals"])
    assert g["sliding_nominal_loses"]["passes"] == 2 and g["sliding_nominal_loses"]["need"] == 3
    assert "2 of 3 seeds" in text and "not met" in text
    assert (out / "claims-seeds.png").stat().st_size > 10_000
    md = (out / "claims-seeds.md").read_text()
    assert "| **no** | 2 of 3 (need 3)" in md
    row = next(line for line in md.splitlines() if "piecewise maps' " in line)
    assert row.replace("\\|", "").count("|") == 5  # |f_z| in the text is escaped: still four cells


def test_cli_seeds_refuses_bad_counts(tmp_path, capsys):
    assert main(["reproduce", "--seeds", "0", "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()
