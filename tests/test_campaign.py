"""Monte-Carlo campaigns: reproducible draws, results saved as they arrive, resume, hash refusal, summary, plots."""

import dataclasses
import importlib.util
import json
import re

import numpy as np
import pytest

from omnirotor.cli import main
from omnirotor.errors import InputError
from omnirotor.experiments.campaigns.runner import (
    PARAMETERS,
    execute_run,
    identify_truth_maps,
    load_campaign,
    load_results,
    plot_comparison,
    run_campaign,
    run_options,
    wilson_interval,
)
from omnirotor.experiments.faults import MocapDropout, RotorFailure, WindGust
from omnirotor.experiments.tasks.common import ExperimentOptions
from omnirotor.vehicle import load_vehicle

TINY = """
task = "sliding"
seed = 7
runs = 3
bins = 2

[options]
quick = true
estimator = "bypass"
duration_s = 0.3

[vary.gamma]
dist = "uniform"
low = 2.0
high = {high}

[vary.friction]
dist = "choice"
values = [0.2, 0.5]
"""


def tiny(tmp_path, high=14.0, name="tiny.toml"):
    path = tmp_path / name
    path.write_text(TINY.format(high=high))
    return path


def lines(folder):
    return (folder / "results.jsonl").read_text().splitlines()


def test_draws_are_reproducible_per_run_index_and_within_the_distributions(tmp_path):
    spec = load_campaign(tiny(tmp_path))
    a = [run_options(spec, i) for i in range(6)]
    b = [run_options(spec, i) for i in (5, 2, 0)]  # any order, alone
    assert [j.params for j in b] == [a[5].params, a[2].params, a[0].params]
    assert [j.derived for j in b] == [a[5].derived, a[2].derived, a[0].derived]
    gammas = [j.params["gamma"] for j in a]
    assert all(2.0 <= g <= 14.0 for g in gammas) and len(set(gammas)) == 6
    assert {j.params["friction"] for j in a} <= {0.2, 0.5}
    # the plant sees the drawn values, the plan does not
    j = a[0]
    plant = j.options.plant_sim_params()
    assert plant.aero.gamma == pytest.approx(j.params["gamma"])
    assert plant.aero.model == "spec7"  # varying SPEC §7's gamma makes SPEC §7's model the plant's truth
    assert j.options.sim_params().aero.model == "wake"
    assert plant.scene.friction == j.params["friction"]
    assert j.options.sim_params().aero.gamma == 4.0
    other = load_campaign(tiny(tmp_path), seed=8)
    assert run_options(other, 0).params != j.params


def test_named_parameters_reach_plant_controller_and_faults(tmp_path):
    path = tmp_path / "all.toml"
    path.write_text(
        """
task = "peg-in-hole"
[options]
quick = true
estimator = "ukf"
[vary.mass_error]
dist = "constant"
value = 0.1
[vary.inertia_error]
dist = "constant"
value = -0.2
[vary.scene_offset_x]
dist = "constant"
value = 0.01
[vary.sensor_noise_scale]
dist = "constant"
value = 2.0
[vary.mocap_dropout_s]
dist = "constant"
value = 0.3
[vary.gust_force_N]
dist = "constant"
value = 3.0
[vary.failed_rotor]
dist = "constant"
value = 4
[vary.rotor_failure_told]
dist = "constant"
value = false
[vary.peg_misalignment_deg]
dist = "constant"
value = 12.0
[vary."controller.observer.cutoff_hz"]
dist = "constant"
value = 5.0
"""
    )
    job = run_options(load_campaign(path), 0)
    o = job.options
    veh = load_vehicle()
    true = o.plant.vehicle(veh)
    assert true.mass == pytest.approx(1.1 * veh.mass)
    np.testing.assert_allclose(true.inertia_diag, 0.8 * np.array(veh.inertia_diag))
    assert o.plant_sim_params().scene.hole_entrance[0] == pytest.approx(o.sim_params().scene.hole_entrance[0] + 0.01)
    assert o.plant_sim_params().sensors.acc_noise_std == pytest.approx(2 * o.sim_params().sensors.acc_noise_std)
    assert o.scenario.peg_misalignment_deg == 12.0
    assert o.controller_params().observer.cutoff_hz == 5.0
    kinds = {type(f): f for f in o.plant.faults}
    assert kinds[MocapDropout].duration_s == 0.3
    assert np.hypot(*kinds[WindGust].force_W[:2]) == pytest.approx(3.0)
    assert kinds[RotorFailure].rotor == 4 and not kinds[RotorFailure].tell_controller
    # events start inside the contact phase of the task
    t0, t1 = (job.derived[k] for k in ("mocap_dropout_t_s", "gust_t_s"))
    assert (1.0 + 6.0 <= t0 <= 1.0 + 21.0) and (1.0 + 6.0 <= t1 <= 1.0 + 21.0)


def test_campaign_runs_saves_summarises_and_plots(tmp_path):
    spec = load_campaign(tiny(tmp_path))
    out = tmp_path / "c"
    seen = []
    s = run_campaign(spec, out, workers=1, progress=lambda k, n, rec: seen.append((k, n, rec is not None)))
    recs = [json.loads(x) for x in lines(out)]
    assert sorted(r["index"] for r in recs) == [0, 1, 2]
    assert all(r["status"] == "ok" and r["metrics"]["duration_s"] == 0.3 for r in recs)
    assert seen[-1] == (3, 3, True)
    # the record's parameters are the draws of its index
    for r in recs:
        assert r["params"] == pytest.approx(run_options(spec, r["index"]).params)
    assert s["runs_done"] == 3 and s["executed"] == 3
    wins = sum(r["success"] for r in recs)
    assert s["successes"] == wins and s["success_rate"] == pytest.approx(wins / 3)
    assert s["success_rate_ci95"] == pytest.approx(list(wilson_interval(wins, 3)))
    g = [r["metrics"]["ee_rms_error"]["z_cm"] for r in recs]
    m = s["metrics"]["ee_rms_error.z_cm"]
    assert m["mean"] == pytest.approx(np.mean(g)) and m["max"] == pytest.approx(max(g))
    assert sum(b["runs"] for b in s["parameters"]["gamma"]) == 3
    assert json.loads((out / "summary.json").read_text())["hash"] == spec.digest()
    for name in ("gamma", "friction"):
        png = out / "plots" / f"success-vs-{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_resume_runs_only_the_missing_indices(tmp_path):
    spec = load_campaign(tiny(tmp_path))
    out = tmp_path / "c"
    assert run_campaign(spec, out, runs=2, workers=1, plots=False)["executed"] == 2
    first = lines(out)
    s = run_campaign(spec, out, runs=4, workers=1, plots=False)
    assert s["executed"] == 2 and s["runs_done"] == 4
    now = lines(out)
    assert now[:2] == first  # earlier results untouched
    assert sorted(json.loads(x)["index"] for x in now[2:]) == [2, 3]
    assert run_campaign(spec, out, runs=4, workers=1, plots=False)["executed"] == 0


def test_killed_campaign_resumes_where_it_stopped(tmp_path):
    spec = load_campaign(tiny(tmp_path))
    out = tmp_path / "c"

    def kill_after_first(k, n, rec):
        if rec is not None:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_campaign(spec, out, runs=3, workers=1, progress=kill_after_first)
    assert len(lines(out)) == 1 and not (out / "summary.json").exists()
    # a kill in the middle of a write leaves a line without its newline: ignored and cut off
    with (out / "results.jsonl").open("a") as fh:
        fh.write('{"index": 2, "status": "ok", "par')
    assert set(load_results(out)) == {0}
    s = run_campaign(spec, out, runs=3, workers=1, plots=False)
    assert s["executed"] == 2
    assert sorted(json.loads(x)["index"] for x in lines(out)) == [0, 1, 2]


def test_changed_definition_is_refused_unless_restarted(tmp_path):
    out = tmp_path / "c"
    run_campaign(load_campaign(tiny(tmp_path)), out, runs=1, workers=1, plots=False)
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    changed = load_campaign(tiny(tmp_path, high=10.0))
    with pytest.raises(InputError, match=r"another campaign.*changed: vary.*--restart"):
        run_campaign(changed, out, runs=1, workers=1)
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    with pytest.raises(InputError, match="another campaign"):  # --quick changes the definition too
        run_campaign(dataclasses.replace(changed, options=dataclasses.replace(changed.options, quick=False)), out)
    s = run_campaign(changed, out, runs=1, workers=1, plots=False, restart=True)
    assert s["executed"] == 1 and s["hash"] == changed.digest()
    rec = json.loads(lines(out)[0])
    assert rec["params"]["gamma"] <= 10.0


def test_execute_run_is_deterministic_and_records_failures():
    spec_opts = ExperimentOptions(quick=True, estimator="bypass", duration_s=0.2)
    from omnirotor.experiments.campaigns.runner import RunJob

    job = RunJob(0, "point-contact", spec_opts, {}, {"sim_seed": 3})
    a, b = execute_run(job), execute_run(job)
    assert a["status"] == "ok" and a["metrics"]["ee_rms_error"] == b["metrics"]["ee_rms_error"]
    bad = RunJob(1, "point-contact", dataclasses.replace(spec_opts, vehicle="no-such-vehicle"), {}, {})
    rec = execute_run(bad)
    assert rec["status"] == "error" and "unknown vehicle preset" in rec["error"] and rec["metrics"] is None


def test_identify_truth_maps_follow_the_runs_interference():
    from omnirotor.experiments.faults import PlantPerturbation

    res = {}
    for g in (2.0, 14.0):
        # gamma is a parameter of SPEC §7's model: name that model as the truth
        opts = ExperimentOptions(plant=PlantPerturbation(sim_overrides=(f"aero.gamma={g}", "aero.model=spec7")))
        maps = identify_truth_maps(opts)
        res[g] = maps
        for e in maps.regions.values():  # each region's map explains its own truth hover points
            assert e.force_residual_rms_N < 0.1 * e.nominal_force_residual_rms_N
    # stronger interference, more attitude dependence: one global map explains the points ever worse,
    # while each region's map still fits (the case for piecewise maps, SPEC §7)
    glob = {g: m.global_.force_residual_rms_N for g, m in res.items()}
    assert glob[14.0] > 3 * glob[2.0]
    assert max(e.force_residual_rms_N for e in res[14.0].regions.values()) < 0.5 * glob[14.0]


HEAD = 'task = "sliding"\n'
BYPASS = '[options]\nestimator = "bypass"\n'


@pytest.mark.parametrize(
    "text,needle",
    [
        (HEAD + "bogus = 1\n", "unknown key(s) bogus"),
        (HEAD + "seed = -1\n", "seed must be an integer >= 0"),
        (HEAD + 'maps = "nowhere.json"\n', "no such file"),
        ('task = "hover-dance"\n', "campaigns run the tasks"),
        ("runs = 3\n", "no task"),
        (HEAD + '[vary.gravity_well]\ndist = "uniform"\nlow = 0\nhigh = 1\n', "unknown parameter 'gravity_well'"),
        (HEAD + '[vary.gamma]\ndist = "uniform"\nlow = 1\nhigh = 2\nstd = 3\n', "takes no std"),
        (HEAD + '[vary.gamma]\ndist = "gauss"\nstd = 3\n', "dist must be one of"),
        (HEAD + '[vary.gamma]\ndist = "uniform"\nlow = 3\nhigh = 2\n', "low must be < high"),
        (HEAD + '[vary.gamma]\ndist = "uniform"\nlow = -3\nhigh = 2\n', "outside [0, inf]"),
        (HEAD + '[vary.gamma]\ndist = "normal"\n', "needs std"),
        (HEAD + '[vary.gamma]\ndist = "uniform"\nlow = 1\nhigh = inf\n', "must be finite"),
        (HEAD + "[vary]\ngamma = 3\n", "must be a table"),
        (HEAD + '[vary.failed_rotor]\ndist = "uniform"\nlow = 0\nhigh = 3\n', "takes integers"),
        (HEAD + '[vary.peg_misalignment_deg]\ndist = "constant"\nvalue = 5\n', "applies to peg-in-hole only"),
        (HEAD + BYPASS + '[vary.mocap_dropout_s]\ndist = "constant"\nvalue = 0.2\n', 'only the "ukf" estimator'),
        (HEAD + '[vary."sim.aero.gama"]\ndist = "constant"\nvalue = 5\n', "unknown key 'gama'"),
        (HEAD + '[vary.friction]\ndist = "choice"\nvalues = [0.1, "x"]\n', "all numbers"),
        (HEAD + '[vary.friction]\ndist = "choice"\nvalues = [0.1, 0.2]\nweights = [1]\n', "weights must be"),
        (HEAD + '[vary.gust_duration_s]\ndist = "constant"\nvalue = 2.0\n', "does nothing without vary.gust_force_N"),
        (HEAD + '[options]\nmap = "piecewise"\n', "needs maps"),
        (HEAD + '[options]\nestimator = "magic"\n', "estimator must be one of"),
        (HEAD + "[options]\nduration_s = -1.0\n", "duration must be"),
        (HEAD + '[options]\ncontroller_overrides = ["pose.nope=1"]\n', "unknown key 'nope'"),
        (HEAD + '[scenario]\npenetration = "deep"\n', "expected a number"),
        (HEAD + "[scenario]\ndepth = 1.0\n", "unknown key(s) depth"),
    ],
)
def test_bad_campaign_files_are_input_errors(tmp_path, text, needle):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError) as exc:
        load_campaign(path)
    assert needle in str(exc.value)


def test_task_on_the_command_line_must_agree_with_the_file(tmp_path):
    with pytest.raises(InputError, match="campaign of task 'sliding', not 'peg-in-hole'"):
        load_campaign(tiny(tmp_path), "peg-in-hole")
    assert set(PARAMETERS) >= {"mass_error", "gamma", "friction", "mocap_latency_s", "gust_force_N"}


def test_cli_local_backend_two_workers_then_compare(tmp_path, capsys):
    camp = tiny(tmp_path)
    out = tmp_path / "c2"
    code = main(["campaign", "--campaign", str(camp), "--runs", "3", "--workers", "2", "--out", str(out), "--json"])
    assert code == 0, capsys.readouterr().err
    s = json.loads(capsys.readouterr().out)
    assert s["executed"] == 3 and s["runs_done"] == 3 and s["runs_error"] == 0
    assert sorted(json.loads(x)["index"] for x in lines(out)) == [0, 1, 2]
    # the same runs in one process give the same records (workers change nothing)
    solo = tmp_path / "c1"
    run_campaign(load_campaign(camp), solo, workers=1, plots=False)
    by_index = {json.loads(x)["index"]: json.loads(x)["metrics"] for x in lines(solo)}
    for x in lines(out):
        r = json.loads(x)
        assert r["metrics"]["ee_rms_error"] == by_index[r["index"]]["ee_rms_error"]
    png = tmp_path / "cmp.png"
    code = main(["campaign-compare", str(out), str(solo), "--param", "gamma", "--out", str(png)])
    assert code == 0 and png.read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(InputError, match="does not vary 'kappa0'"):
        plot_comparison([out], "kappa0", tmp_path / "x.png")


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--runs", "0"], "--runs must be >= 1"),
        (["--workers", "0"], "--workers must be >= 1"),
        (["--backend", "dask"], "--backend must be one of"),
        (["--address", "ray://x:1"], "--address needs --backend ray"),
        (["--map", "piecewise"], "needs maps"),
        (["--map", "bent"], "options.map must be one of"),
        (["--maps", "{tmp}/none.json"], "no such file"),
        (["--seed", "-2"], "--seed must be >= 0"),
        (["--campaign", "{tmp}/missing.toml"], "no such file"),
        (["--campaign", "nonexistent-preset"], "unknown campaign"),
        (["--runs", "many"], "Invalid value"),
    ],
)
def test_cli_bad_options_exit_2_and_leave_nothing(tmp_path, capsys, args, needle):
    out = tmp_path / "never"
    argv = ["campaign", "sliding", "--out", str(out)] + [a.format(tmp=tmp_path) for a in args]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and err.startswith("omnirotor: error:") and needle in err, err
    assert not out.exists()


def test_cli_hash_mismatch_exits_2_and_keeps_the_folder(tmp_path, capsys):
    out = tmp_path / "c"
    assert (
        main(["campaign", "--campaign", str(tiny(tmp_path)), "--runs", "1", "--workers", "1", "--out", str(out)]) == 0
    )
    before = (out / "results.jsonl").read_bytes()
    capsys.readouterr()
    code = main(["campaign", "--campaign", str(tiny(tmp_path, 9.0)), "--runs", "1", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "--restart" in err and len(err.strip().splitlines()) == 1
    assert (out / "results.jsonl").read_bytes() == before


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="ray (the optional 'ray' extra) is not installed")
def test_ray_backend_matches_local(tmp_path):
    spec = load_campaign(tiny(tmp_path))
    s = run_campaign(spec, tmp_path / "r", runs=2, backend="ray", workers=2, plots=False)
    assert s["executed"] == 2
    local = run_campaign(spec, tmp_path / "l", runs=2, workers=1, plots=False)
    assert s["metrics"]["ee_rms_error.z_cm"] == local["metrics"]["ee_rms_error.z_cm"]


def test_unreachable_ray_address_is_refused_quickly():
    from omnirotor.experiments.campaigns.runner import _check_reachable

    with pytest.raises(InputError, match="cannot reach the Ray cluster"):
        _check_reachable("127.0.0.1:1")
    with pytest.raises(InputError, match="expected host:port"):
        _check_reachable("somewhere")
    _check_reachable("auto")  # Ray's own discovery: nothing to check here


def test_wilson_interval_holds_the_rate_and_matches_the_textbook():
    assert wilson_interval(0, 0) is None
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(0.2775, abs=1e-4)  # the 95 % upper bound of 0 in 10
    for n in range(1, 40):
        for k in range(n + 1):
            a, b = wilson_interval(k, n)
            assert 0.0 <= a <= k / n <= b <= 1.0
            assert (a, b) == pytest.approx(tuple(1 - x for x in wilson_interval(n - k, n)[::-1]))


HOVER = """
task = "hover"
runs = 2
[options]
estimator = "bypass"
duration_s = 0.6
# the clean plant (no disturbances): the mass error's sag stands out of the noise
sim_overrides = ["airflow.force_std=0", "rotors.thrust_noise_rel=0", "sensors.imu_vib_acc_amp=0",
                 "sensors.imu_vib_gyro_amp=0", "sensors.mocap_latency_jitter_s=0", "sensors.acc_vib_noise_std=0"]
[vary.mass_error]
dist = "constant"
value = 0.4
"""


def test_hover_campaign_flies_the_perturbed_plant_and_ends_with_its_throughput(tmp_path, capsys):
    from omnirotor.experiments.tasks import run_task

    camp = tmp_path / "hover.toml"
    camp.write_text(HOVER)
    job = run_options(load_campaign(camp), 0)
    assert job.task == "hover" and job.options.plant.mass_scale == pytest.approx(1.4)
    heavy = execute_run(job)["metrics"]
    believed = run_task("hover", dataclasses.replace(job.options, plant=None)).summary()
    # 40 % more mass than the controller believes: it sags until the wrench observer has learnt the weight
    # (same seed and noise: a task that ignored the plant would give identical numbers)
    assert heavy["ee_rms_error"]["z_cm"] > 1.2 * believed["ee_rms_error"]["z_cm"]
    assert heavy["task"] == "hover" and isinstance(heavy["success"], bool)
    out = tmp_path / "c"
    assert main(["campaign", "--campaign", str(camp), "--workers", "1", "--out", str(out)]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    m = re.fullmatch(r"throughput: ([0-9.]+) simulated s in ([0-9.]+) s wall \(([0-9.]+) per s\)", last)
    assert m, last
    assert float(m.group(1)) == pytest.approx(1.2)  # 2 runs of 0.6 s
    sim_s, wall_s, per_s = (float(m.group(k)) for k in (1, 2, 3))
    # the line rounds the wall time to 0.01 s and the rate to 0.1 per s: the rate within what that allows
    assert sim_s / (wall_s + 0.005) - 0.05 <= per_s <= sim_s / max(wall_s - 0.005, 1e-9) + 0.05
