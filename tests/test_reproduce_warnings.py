"""``reproduce``'s pool workers record their warnings for the parent instead of printing them (issue 14)."""

import warnings

from omnirotor.experiments.paper import reproduce as rp


def test_worker_records_warnings_and_prints_nothing(monkeypatch, capfd):
    def noisy(task, options):
        warnings.warn("overflow encountered in multiply", RuntimeWarning, stacklevel=1)
        return f"{task}/nominal", {"ok": True}, None

    monkeypatch.setattr(rp, "run_one", noisy)
    result, caught = rp._run_in_worker("hover", None)
    out, err = capfd.readouterr()
    assert result == ("hover/nominal", {"ok": True}, None)
    assert caught == [(RuntimeWarning, "overflow encountered in multiply")]
    assert out == "" and err == ""


def test_the_hover_figure_keeps_the_plans_map_order_whatever_finished_first():
    modes = list(dict.fromkeys(mode for _, mode in rp.plan().runs))
    assert len(modes) >= 2, "the plan compares maps"
    finished = {m: {"R1": [[0.0, 0.0, 0.0]]} for m in reversed(modes)}  # the last planned finished first
    assert list(rp.in_plan_order(finished)) == modes
    assert list(rp.in_plan_order(dict(reversed(list(finished.items()))))) == modes
