"""Smoke test of benchmarks/run.py: a tiny run produces every documented key, and the Markdown section renders.

No speed is asserted here (speed goals live in the benchmarks); only structure and the bookkeeping.
"""

from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path

import pytest

from omnirotor.control.allocation import SOLVERS

BENCH_DIR = Path(__file__).resolve().parents[1] / "benchmarks"


def _load_run():
    spec = importlib.util.spec_from_file_location("omnirotor_bench_run", BENCH_DIR / "run.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


bench = _load_run()

TOP_KEYS = (
    "controller_step_us",
    "allocation_us",
    "identify_region_us",
    "identify_region_data",
    "sim_step_us",
    "closed_loop_rtf_ukf",
    "closed_loop_rtf_fast",
    "quad_hover_rtf_ours",
    "quad_hover_rtf_rotorpy",
    "rtf_ratio_vs_rotorpy",
    "rotorpy_rtf_sweep",
    "crazyflow",
    "campaign_throughput_sim_s_per_s",
    "campaign_throughput_over_marginal_rtf",
    "campaign_sliding_speedup_2_workers",
    "machine",
    "date",
    "git_commit",
    "python",
    "numpy",
    "scaling",
    "breakdown",
    "goals",
)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> dict:
    missing = tmp_path_factory.mktemp("nodata") / "omnirotor-hover-flight"
    return bench.collect(bench.CONFIGS["tiny"], data_dir=missing)


def _positive(x) -> bool:
    return isinstance(x, float) and math.isfinite(x) and x > 0


def test_tiny_run_has_every_documented_key_and_is_json(tiny):
    for key in TOP_KEYS:
        assert key in tiny, key
    again = json.loads(json.dumps(tiny))
    assert again["controller_step_us"] == tiny["controller_step_us"]
    assert set(tiny["allocation_us"]) == set(SOLVERS)
    assert all(_positive(v) for v in tiny["allocation_us"].values())
    assert set(tiny["sim_step_us"]) >= {"with_truth_model", "without_truth_model"}
    for key in ("controller_step_us", "identify_region_us", "closed_loop_rtf_ukf", "closed_loop_rtf_fast"):
        assert _positive(tiny[key]), key
    assert _positive(tiny["quad_hover_rtf_ours"])
    for kind in ("ukf", "bypass"):
        d = tiny["closed_loop_detail"][kind]
        assert d["controller_step_us_in_loop_p99"] >= d["controller_step_us_in_loop"] > 0
    assert tiny["machine"]["cores"] >= 1 and tiny["machine"]["cpu_model"]
    assert tiny["python"].startswith("3.") and tiny["numpy"]


def test_identification_falls_back_to_synthetic_points_and_says_so(tiny):
    info = tiny["identify_region_data"]
    assert info["source"] == "synthetic" and info["path"] is None
    assert info["points"] >= 5  # n - 3 independent points are needed for the Omnirotor's 8 rotors


def test_identification_on_the_real_data(flight_data):
    us, info = bench.measure_identify_region(2, flight_data)
    assert _positive(us)
    # R4 holds the most points of the three files (16, per the data README)
    assert (info["source"], info["region"], info["points"]) == ("real", "R4", 16)


def test_rotorpy_figures_are_consistent(tiny):
    if tiny["quad_hover_detail"]["rotorpy_version"] is None:
        assert tiny["quad_hover_rtf_rotorpy"] is None and tiny["rtf_ratio_vs_rotorpy"] is None
        assert tiny["rtf_ratio_vs_rotorpy_cpu"] is None and tiny["rotorpy_rtf_sweep"] == {}
        assert tiny["goals"]["rtf_ratio_vs_rotorpy"]["met"] is None
        return
    ratio = tiny["quad_hover_rtf_ours"] / tiny["quad_hover_rtf_rotorpy"]
    assert tiny["rtf_ratio_vs_rotorpy"] == pytest.approx(ratio)
    q = tiny["quad_hover_detail"]
    so = q["sim_only"]
    assert so["ratio"] == pytest.approx(so["rtf_ours"] / so["rtf_rotorpy"])
    # the headline is the least favourable ratio: against RotorPy's fastest 1 kHz figure, step loop or sweep
    sweep = q["rotorpy_sweep"]
    assert [row["start"] for row in sweep] == [s.name for s in bench.peer.rotorpy_starts()]
    assert tiny["rotorpy_rtf_sweep"] == {row["start"]: row["rtf_median"] for row in sweep}
    fastest = max([q["rotorpy"]["rtf_median"]] + [row["rtf_median"] for row in sweep])
    assert tiny["quad_hover_rtf_rotorpy"] == fastest
    assert tiny["rtf_ratio_vs_rotorpy"] <= min(row["ratio"] for row in sweep)
    lf = q["least_favourable"]
    assert tiny["rtf_ratio_vs_rotorpy_cpu"] == pytest.approx(q["ours"]["rtf_cpu_median"] / lf["rtf_cpu_rotorpy"])
    assert q["rotorpy_default_rate"]["dt_s"] == 0.01  # reported, never the headline
    assert all(row["dt_s"] == bench.peer.DT_S for row in sweep)


def test_rotorpy_starts_are_what_they_say():
    pytest.importorskip("rotorpy", reason="RotorPy is in the bench extra (make bench installs it)")
    import numpy as np

    x0 = np.array([0.0, 0.0, 1.5])
    w = bench.peer.hover_speed_rad_s()
    assert w == pytest.approx(1788.5505, abs=1e-3)
    for start in bench.peer.rotorpy_starts():
        _, _, traj, state, _ = bench.peer._rotorpy_setup(x0, start)
        assert np.allclose(state["x"], x0 + np.asarray(start.offset_m))
        expected = w if start.rotor_speed_rad_s is None else start.rotor_speed_rad_s
        assert np.all(state["rotor_speeds"] == expected)
        assert np.allclose(traj.update(0.0)["x"], x0)  # every trajectory starts at the hover target
    circle = next(s for s in bench.peer.rotorpy_starts() if s.trajectory == "circle")
    _, _, traj, _, _ = bench.peer._rotorpy_setup(x0, circle)
    lap = 1.0 / bench.peer.CIRCLE_FREQ_HZ
    assert np.linalg.norm(traj.update(0.5 * lap)["x"] - x0) == pytest.approx(2.0 * bench.peer.CIRCLE_RADIUS_M)


def test_campaign_throughput_counts_every_run_and_reads_the_command_line(tiny):
    cfg = bench.CONFIGS["tiny"]
    ct = tiny["campaign_throughput"]
    assert ct["runs_ok"] == cfg.campaign_runs
    assert ct["sim_s"] == pytest.approx(cfg.campaign_runs * cfg.campaign_duration_s, abs=0.05)  # line rounds to 0.1
    assert tiny["campaign_throughput_sim_s_per_s"] == pytest.approx(ct["sim_s"] / ct["wall_s"])
    assert ct["line"]["wall_s"] < ct["wall_s"]  # the command's own line excludes interpreter start and imports
    su = tiny["startup"]
    assert su["first_run_s"] >= su["kernel_loading_s"] and _positive(su["imports_s"])
    assert ct["cpu_s"] > 0 and ct["sim_s_per_cpu_s"] == pytest.approx(ct["sim_s"] / ct["cpu_s"])
    assert tiny["campaign_throughput_over_marginal_rtf"] == pytest.approx(
        tiny["campaign_throughput_sim_s_per_s"] / ct["marginal_rtf_one_core"]
    )


def test_sliding_campaigns_one_and_two_workers_give_the_speedup(tiny):
    cfg = bench.CONFIGS["tiny"]
    sl = tiny["campaign_sliding_workers"]
    assert len(sl["wall_s"]["1"]) == len(sl["wall_s"]["2"]) == cfg.sliding_campaign_repeats
    assert sl["sim_s"] == pytest.approx(cfg.sliding_campaign_runs * cfg.sliding_campaign_duration_s, abs=0.05)
    w1, w2 = sl["wall_median_s"]["1"], sl["wall_median_s"]["2"]
    assert tiny["campaign_sliding_speedup_2_workers"] == pytest.approx(w1 / w2)
    c1, c2 = sl["cpu_median_s"]["1"], sl["cpu_median_s"]["2"]
    assert c1 == pytest.approx(bench._median(sl["cpu_s"]["1"])) and c2 == pytest.approx(bench._median(sl["cpu_s"]["2"]))
    assert sl["speedup_ceiling_by_cpu"] == pytest.approx(2 * c1 / c2)
    assert "campaign sliding" in sl["command"] and "--workers W" in sl["command"]


def test_crazyflow_in_its_own_venv_tiny():
    python = bench.crazyflow_python()
    if python is None:
        pytest.skip("crazyflow's venv is absent (make bench creates out/peer-venvs/crazyflow)")
    cfg = bench.dataclasses.replace(bench.CONFIGS["tiny"], crazyflow_calls=1, crazyflow_s=0.05, crazyflow_worlds=(3,))
    cf = bench.measure_crazyflow(cfg)
    assert cf["version"] == "0.4.0" and cf["float"] == "float32"
    for mode in ("scan", "python_100hz"):
        assert _positive(cf[mode]["rtf"])
        assert cf[mode]["ratio_ours_over_crazyflow"] == pytest.approx(cf["ours_rtf"] / cf[mode]["rtf"])
    assert [b["n_worlds"] for b in cf["batched"]] == [3] and _positive(cf["batched"][0]["drone_s_per_wall_s"])


def test_quadrotor_preset_matches_rotorpy_crazyflie():
    pytest.importorskip("rotorpy", reason="RotorPy is in the bench extra (make bench installs it)")
    rows = {r["quantity"]: r for r in bench.peer.crazyflie_comparison()}
    mismatched = {name for name, r in rows.items() if not r["match"]}
    # The preset reproduces the vehicle; only the simulator's default motor time constant differs, and the
    # benchmark runs the simulator with RotorPy's value.
    assert mismatched == {"motor time constant [s] (sim param)"}
    assert bench.peer.tau_m_s() == pytest.approx(rows["motor time constant [s] (sim param)"]["rotorpy"])


def test_scaling_rows_cover_every_campaign(tiny):
    cfg = bench.CONFIGS["tiny"]
    camp = tiny["scaling"]["campaign"]
    assert {(c["tasks"], c["workers"]) for c in camp} == {
        (n, w) for n in cfg.campaign_sizes for w in cfg.campaign_workers
    }
    for c in camp:
        if c["workers"] == min(cfg.campaign_workers):
            assert c["speedup"] == pytest.approx(1.0)
    assert [d["sim_s"] for d in tiny["scaling"]["duration"]] == list(cfg.scaling_s)


def test_goal_bookkeeping():
    goals = bench.evaluate_goals(
        {
            "controller_step_us": 5.0,
            "closed_loop_rtf_ukf": 20.0,
            "closed_loop_rtf_fast": 80.0,
            "rtf_ratio_vs_rotorpy": None,
        }
    )
    assert goals["controller_step_us"]["met"] and goals["controller_step_us"]["margin"] == pytest.approx(2.0)
    assert not goals["closed_loop_rtf_ukf"]["met"] and goals["closed_loop_rtf_ukf"]["margin"] == pytest.approx(0.5)
    assert goals["closed_loop_rtf_fast"]["met"]
    assert goals["rtf_ratio_vs_rotorpy"]["met"] is None


def test_markdown_section_is_replaced_in_place(tiny, tmp_path):
    doc = tmp_path / "BENCHMARKS.md"
    doc.write_text(f"# Title\n\nintro\n\n{bench.MARK_BEGIN}\nold figures\n{bench.MARK_END}\n\n## After\ntext\n")
    bench.write_markdown(doc, tiny)
    bench.write_markdown(doc, tiny)  # idempotent: one section, surroundings kept
    text = doc.read_text()
    assert text.count(bench.MARK_BEGIN) == 1 and text.count(bench.MARK_END) == 1
    assert "old figures" not in text
    assert text.startswith("# Title\n\nintro\n\n") and text.endswith("\n\n## After\ntext\n")
    assert f"{tiny['controller_step_us']:.1f}" in text or f"{tiny['controller_step_us']:,.0f}" in text
    assert (tiny["git_commit"] or "?")[:12] in text


def test_peer_comparison_without_rotorpy_reports_nulls_not_zeros():
    quad = bench.measure_peer(bench.CONFIGS["tiny"], with_rotorpy=False)
    assert quad["rotorpy"] is None and quad["rotorpy_version"] is None and quad["params_check"] is None
    assert quad["sim_only"]["rtf_rotorpy"] is None
    assert _positive(quad["ours"]["rtf_median"]) and _positive(quad["sim_only"]["rtf_ours"])
