"""The paper's claims, each checked on a shortened closed-loop run in the simulator (issue "Experiments").

The truth model is the default everywhere: the rotor-wake model calibrated on the real flight data
(``docs/fidelity.md``). The runs are single-seed and fly the clean plant (``disturbances=False``): with the
calibrated disturbances a claim is a statistical statement, reported over ten seeds per claim by
``omnirotor campaign TASK --campaign seeds`` (docs/fidelity.md, "The claims over ten seeds"). Where our
simulation disagrees with the paper the test says so (``xfail`` with the measured reason, strict: it turns red
if the disagreement disappears).
"""

import numpy as np
import pytest

from omnirotor.experiments.closed_loop import run_task
from omnirotor.experiments.scenarios import ScenarioParams, hover_attitudes
from omnirotor.experiments.tasks import ExperimentOptions, HoverProtocol
from omnirotor.identification import HoverData, identify, load_csv
from omnirotor.regions import load_partition
from omnirotor.sim import SimParams
from omnirotor.sim.aero import hover_equilibrium, make_aero
from omnirotor.vehicle import load_vehicle

pytestmark = pytest.mark.slow
VEHICLE = load_vehicle()
FAST = {"estimator": "bypass", "disturbances": False}
SHORT_HOVER = HoverProtocol(
    regions=("R1", "R3"), points_per_region=6, validation_per_region=1, transition_s=1.5, hold_s=2.5
)


@pytest.fixture(scope="module")
def truth_maps(tmp_path_factory):
    """Maps identified on exact hover equilibria of the simulator's truth model (no flight needed)."""
    aero = make_aero(VEHICLE, SimParams().aero)
    att = hover_attitudes(load_partition(), ["R1", "R3", "R4"], 8, np.random.default_rng(11), VEHICLE)
    u = np.array([hover_equilibrium(aero, VEHICLE, R) for _, R in att])
    w = np.array([np.concatenate([R.T @ [0, 0, VEHICLE.weight], np.zeros(3)]) for _, R in att])
    maps = identify(HoverData(u, w, ("",) * len(u), ("truth",) * len(u)), VEHICLE)
    path = tmp_path_factory.mktemp("maps") / "maps.json"
    maps.save(path)
    return str(path)


def hover_fz(mode, maps=None):
    opts = ExperimentOptions(map_mode=mode, maps=maps, protocol=SHORT_HOVER, **FAST)
    m = run_task("hover-validation", opts).summary()
    return {r: v["force_W_mean_N"] for r, v in m["regions"].items()}


def test_hover_bias_about_2N_with_nominal_removed_by_optimized_maps(truth_maps):
    # paper Fig. 3 / SPEC §3.4: nominal f_z^W ≈ +2 N in hover; the optimized maps nearly remove it
    nominal = hover_fz("nominal")
    for r, f in nominal.items():
        assert f[2] > 1.5 and f[2] < 2.6, (r, f)
    # the piecewise maps remove it; the global map only outperforms the nominal one (the paper's hypothesis):
    # under the calibrated rotor-wake truth one map cannot fit R1 and R3 at once (R1: f_z -0.60 N measured)
    for r, f in hover_fz("piecewise", truth_maps).items():
        assert abs(f[2]) < 0.25 * nominal[r][2], ("piecewise", r, f)
        assert np.linalg.norm(f) < 0.5, ("piecewise", r, f)
    for r, f in hover_fz("global", truth_maps).items():
        assert np.linalg.norm(f) < 0.5 * np.linalg.norm(nominal[r]), ("global", r, f)


def test_identification_flights_feed_identify(tmp_path):
    proto = HoverProtocol(regions=("R1",), points_per_region=6, transition_s=1.5, hold_s=2.5)
    m = run_task("identify-flights", ExperimentOptions(protocol=proto, out_dir=str(tmp_path), **FAST)).summary()
    assert m["points"] == {"R1": 6} and m["success"]
    data = load_csv(tmp_path / "hover_points.csv", VEHICLE)
    maps = identify(data, VEHICLE)
    e = maps.regions["R1"]
    # the simulated robot under-produces nothing: its truth thrust is ~14 % above nominal (SPEC §7)
    assert e.nominal_force_residual_rms_N > 1.5
    assert e.force_residual_rms_N < 0.1 * e.nominal_force_residual_rms_N


@pytest.fixture(scope="module")
def point_contact_runs():
    sp = ScenarioParams(segment_s=2.0, settle_s=1.0)
    return {
        task: run_task(task, ExperimentOptions(scenario=sp, quick=True, **FAST)).summary()
        for task in ("point-contact", "point-contact-tilted")
    }


def test_point_contact_holds_about_K_times_penetration(point_contact_runs):
    m = point_contact_runs["point-contact"]
    nf = m["normal_force"]
    assert not m["contact"]["lost"] and m["contact"]["fraction"] > 0.95
    assert nf["expected_N"] == pytest.approx(3.0)
    assert abs(nf["true_mean_N"] - 3.0) < 1.0, nf  # "near K_E x penetration"


@pytest.mark.xfail(
    strict=True,
    reason="with the compliant tool the true normal force in straight point contact has no chatter left "
    "(force_hf_ratio 0.0003) but still 0.69 N std (mean 3.55 N, peaks 5.70 N): below 20 Hz, as the +-20 deg tilts "
    "move the tip (MuJoCo's friction cone instead of the tool's friction law: 0.71 N)",
)
def test_point_contact_is_steady(point_contact_runs):
    nf = point_contact_runs["point-contact"]["normal_force"]
    assert nf["true_std_N"] < 0.5, nf  # steady, no bouncing


def test_point_contact_force_has_no_chatter(point_contact_runs):
    # issue 12 item 3: the true contact force's part above 20 Hz stays within 10 % of its mean (compliant tool)
    for task, m in point_contact_runs.items():
        assert m["contact"]["force_hf_ratio"] <= 0.10, (task, m["contact"])


@pytest.mark.xfail(
    strict=True,
    reason="calibrated rotor-wake truth: on the 30 deg surface the nominal map overestimates the normal force "
    "by 0.47 N (true 2.36 N, estimated 2.83 N; with MuJoCo's friction cone instead of the tool's friction law, "
    "whose exact stiction lets the tip carry part of the load along the surface: 0.28 N over; the previous "
    "calibration: 0.06 N under; SPEC §7's model gave 0.57 N under), the paper ~1 N under",
)
def test_tilted_surface_normal_force_is_underestimated(point_contact_runs):
    m = point_contact_runs["point-contact-tilted"]
    nf = m["normal_force"]
    assert not m["contact"]["lost"]
    # paper: ~1 N underestimate of the normal force on the 30 deg surface with the nominal map
    assert nf["underestimate_N"] > 0.3, nf


@pytest.mark.xfail(
    strict=True,
    reason="calibrated rotor-wake truth: with no disturbance the observer errs by 0.94 N RMS against the true "
    "contact force in straight point contact (quick, bypass; full protocol, UKF, seeds 0-3: 0.87-0.90 N): the "
    "nominal map's error at the contact's rotor speeds, which the start-attitude zeroing cannot know "
    "(docs/fidelity.md); the goal 0.5 N",
)
def test_observer_error_in_point_contact_within_half_a_newton(point_contact_runs):
    # issue 12 item 4: the observer's RMS error against the true contact force (the paper's ATI sensor) <= 0.5 N
    err = point_contact_runs["point-contact"]["force"]["estimate_rms_error_N"]
    assert err <= 0.5, err


@pytest.fixture(scope="module")
def sliding_runs(truth_maps):
    return {
        mode: run_task(
            "sliding",
            ExperimentOptions(map_mode=mode, maps=None if mode == "nominal" else truth_maps, quick=True, **FAST),
        ).summary()
        for mode in ("nominal", "global", "piecewise")
    }


def test_sliding_force_has_no_chatter(sliding_runs):
    # issue 12 item 3: the true contact force's part above 20 Hz within 10 % of its mean while sliding. MuJoCo's
    # friction cones lifted the sliding tip off for single steps (0.089-0.113); with the tool's own Coulomb law
    # (scene.friction_law = "stick-slip", docs/fidelity.md) 0.004-0.005
    for mode, m in sliding_runs.items():
        assert m["contact"]["force_hf_ratio"] <= 0.10, (mode, m["contact"])


def test_sliding_optimized_maps_keep_contact(sliding_runs):
    for mode in ("global", "piecewise"):
        c = sliding_runs[mode]["contact"]
        assert not c["lost"] and c["fraction"] > 0.9, (mode, c)
    assert sliding_runs["piecewise"]["map_switches"] >= 2  # R1 -> R3 -> R1 (SPEC §3.3: at 30 deg of roll)


@pytest.mark.xfail(
    strict=True,
    reason="calibrated rotor-wake truth: the nominal bias grows 0.8 N from upright to the apex (1.59 -> 2.42 N at "
    "-45 deg of roll; the paper's robot ~1 N), yet the quick slide with the nominal map keeps contact 99.9 % of "
    "the time",
)
def test_sliding_nominal_map_loses_contact(sliding_runs):
    assert sliding_runs["nominal"]["contact"]["lost"]


@pytest.fixture(scope="module")
def peg_run():
    return run_task("peg-in-hole", ExperimentOptions(quick=True, **FAST)).summary()


def test_peg_in_hole_passes_the_funnel(peg_run):
    ins = peg_run["insertion"]
    # the tip passes the 10 cm funnel into the 19 mm bore
    assert ins["max_depth_m"] > 0.12, ins


@pytest.mark.xfail(
    strict=True,
    reason="with Coulomb's law applied exactly (the tool's stick-slip friction) the jammed peg holds its roll: 9.1 deg "
    "in the hole after 9.9 deg on approach (MuJoCo's soft cone, which creeps under load, let it turn to 8.1 deg; "
    "frictionless it turns to 3.4 deg and goes in fully); the paper: 10 -> ~5 deg",
)
def test_peg_in_hole_roll_settles(peg_run):
    ins = peg_run["insertion"]
    # the hole turns the peg from the approach misalignment towards its axis
    assert ins["inserted_tilt_deg"] < ins["approach_tilt_deg"] - 1.0, ins


def test_peg_jams_by_friction_frictionless_peg_goes_in_and_roll_settles():
    # the diagnosis of the jam below (docs/fidelity.md, "The peg: what holds it"): the same run without friction
    # (scene.friction = 0) passes the bore's mouth to the full insertion and the admittance turns the body
    opts = ExperimentOptions(quick=True, sim_overrides=("scene.friction=0",), **FAST)
    ins = run_task("peg-in-hole", opts).summary()["insertion"]
    assert ins["max_depth_m"] >= 0.9 * 0.17, ins
    assert ins["inserted_tilt_deg"] < ins["approach_tilt_deg"] - 3.0, ins


@pytest.mark.xfail(
    strict=True,
    reason="with the paper's peg (the whole tool Ø16 mm, 1.5 mm of play in the Ø19 mm bore) the tip jams at 12.8 of "
    "17 cm with the roll at 9.1 deg (approach 9.9 deg; the paper ~5 deg): friction (0.3) at the two-point contact "
    "(tip on the bore, rod on the funnel-bore junction) holds it; frictionless it goes in to 17.5 cm with the roll at "
    "3.4 deg (docs/fidelity.md, 'The peg: what holds it')",
)
def test_peg_in_hole_inserts_fully(peg_run):
    assert peg_run["insertion"]["max_depth_m"] >= 0.9 * 0.17
