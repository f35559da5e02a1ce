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

from omnirotor.experiments.paper.peg_wedge import wedge_jam
from omnirotor.experiments.tasks import run_task
from omnirotor.experiments.tasks.common import ExperimentOptions, HoverProtocol
from omnirotor.experiments.tasks.scenarios import ScenarioParams, hover_attitudes
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
    # under the calibrated rotor-wake truth one map cannot fit R1 and R3 at once (R1: f_z -0.54 N measured)
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


def test_point_contact_is_steady(point_contact_runs):
    # The bound moved with the plant, not with the claim: under the previous rotor-wake truth (no wake coupling)
    # the true normal force had 0.69 N std (mean 3.55 N, peaks 5.70 N; a strict xfail: below 20 Hz, as the
    # +-20 deg tilts move the tip); with the wake coupling (docs/fidelity.md) 0.48 N (mean 3.45 N, peaks 5.19 N),
    # a small margin under the 0.5 N bound.
    nf = point_contact_runs["point-contact"]["normal_force"]
    assert nf["true_std_N"] < 0.5, nf  # steady, no bouncing


def test_point_contact_force_has_no_chatter(point_contact_runs):
    # issue 12 item 3: the true contact force's part above 20 Hz stays within 10 % of its mean (compliant tool)
    for task, m in point_contact_runs.items():
        assert m["contact"]["force_hf_ratio"] <= 0.10, (task, m["contact"])


@pytest.mark.xfail(
    strict=True,
    reason="calibrated rotor-wake truth: on the 30 deg surface the nominal map overestimates the normal force "
    "by 0.07 N (true 2.76 N, estimated 2.83 N; the rotor-wake truth without the wake coupling: 0.47 N over; with "
    "MuJoCo's friction cone instead of the tool's friction law, whose exact stiction lets the tip carry part of "
    "the load along the surface, that one was 0.28 N over; the calibration before it: 0.06 N under; SPEC §7's "
    "model gave 0.57 N under), the paper ~1 N under",
)
def test_tilted_surface_normal_force_is_underestimated(point_contact_runs):
    m = point_contact_runs["point-contact-tilted"]
    nf = m["normal_force"]
    assert not m["contact"]["lost"]
    # paper: ~1 N underestimate of the normal force on the 30 deg surface with the nominal map
    assert nf["underestimate_N"] > 0.3, nf


@pytest.mark.xfail(
    strict=True,
    reason="calibrated rotor-wake truth: with no disturbance the observer errs by 0.76 N RMS against the true "
    "contact force in straight point contact (quick, bypass; full protocol, UKF, seeds 0-3: 0.74-0.76 N): the "
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
    reason="calibrated rotor-wake truth: the nominal bias grows 0.7 N from upright to the apex (1.62 -> 2.36 N at "
    "-45 deg of roll; the paper's robot ~1 N), yet the quick slide with the nominal map keeps contact 100 % of "
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
    reason="with Coulomb's law applied exactly (the tool's stick-slip friction) the jammed peg holds its roll: 9.5 deg "
    "in the hole after 9.9 deg on approach (9.1 deg under the rotor-wake truth without the wake coupling); the roll "
    "settles by 1 deg or more only for friction <= 0.15 (7.9 deg) and reaches the paper's ~5 deg at 0.05-0.06, below "
    "any published value for the likely materials (docs/fidelity.md, 'The peg: what the real robot must have had')",
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
    reason="with the paper's peg (the whole tool Ø16 mm, 1.5 mm of play in the Ø19 mm bore) the tip jams at 12.7 of "
    "17 cm with the roll at 9.5 deg (approach 9.9 deg; the paper ~5 deg; without the wake coupling 12.8 cm, 9.1 deg): "
    "friction (0.3) at the two-point contact (tip on the bore, rod on the funnel-bore junction) holds it; the peg "
    "reaches 16.5 cm only with friction <= 0.03 (0.045 without the wake coupling), below published values for "
    "printed polymers or plastic on metal (0.2 and above); the coupling's pivot (CoM, mount) and stiffness change "
    "nothing (docs/fidelity.md, 'The peg: what the real robot must have had')",
)
def test_peg_in_hole_inserts_fully(peg_run):
    assert peg_run["insertion"]["max_depth_m"] >= 0.9 * 0.17


def test_peg_jams_where_the_quasi_static_wedge_says():
    # Whitney's two-point wedge, from the paper's geometry and admittance alone (experiments.peg_wedge: rigid tool,
    # exact observer, reference at rest), predicts the simulated jam on the plant it assumes: the truth aerodynamics
    # equal to the controller's nominal map, so that the observer is exact (12.6 cm at 8.95 deg against 12.8 cm at
    # 8.93 deg). On the default truth the map's error in contact adds about 0.5 deg of roll (9.5 deg, 12.7 cm).
    ins = _peg("aero.model=nominal")
    jam = wedge_jam(SimParams().scene.friction, ins["approach_tilt_deg"], ins["target_depth_m"])
    assert jam.jammed
    assert abs(jam.depth - ins["max_depth_m"]) < 0.005, (jam, ins)
    assert abs(jam.roll_deg - ins["inserted_tilt_deg"]) < 0.5, (jam, ins)


def _peg(*overrides):
    opts = ExperimentOptions(quick=True, sim_overrides=overrides, **FAST)
    return run_task("peg-in-hole", opts).summary()["insertion"]


def test_peg_claim_holds_below_a_friction_threshold_and_jams_above(peg_run):
    # Whitney's wedge: the admittance's weak insertion force (K_p = 35 N/m) against the friction of the couple
    # that turns the peg (K_R = 2.29 N·m/rad, SPEC §5.1). With friction 0.02 the paper's result follows, both
    # numbers at once (inserted >= 16.5 cm, the body's roll settled to 3-7 deg: measured 16.8 cm, 4.1 deg; the
    # threshold is about 0.03, 16.5 cm; it was 0.045 before the truth's wake coupling, which leaves 16.2 cm at
    # 0.04); with 0.1, still below the 0.3 assumed, the peg jams short with the roll barely settled (14.1 cm, 6.8 deg)
    slippery, rough = _peg("scene.friction=0.02"), _peg("scene.friction=0.1")
    assert slippery["max_depth_m"] >= 16.5 / 17 * 0.17, slippery
    assert 3.0 <= slippery["inserted_tilt_deg"] <= 7.0, slippery
    assert rough["max_depth_m"] < 0.15, rough
    assert peg_run["insertion"]["max_depth_m"] < rough["max_depth_m"], (peg_run["insertion"], rough)


def test_peg_jam_does_not_depend_on_the_couplings_pivot_unless_it_sits_at_the_tip(peg_run):
    # The compliance centre (SceneParams.tool_pivot): at the frame's mount (the paper's "coupling between the EE
    # and body") the peg jams where it does with the pivot at the CoM; at the tip's centre a soft coupling (a
    # remote-centre compliance, Whitney) lets the tool align with the bore and the peg goes deeper, but the body
    # keeps its approach roll (the paper's body turned from 10 to ~5 deg)
    base = peg_run["insertion"]
    mount = _peg("scene.tool_pivot=mount")
    assert abs(mount["max_depth_m"] - base["max_depth_m"]) < 0.005, (mount, base)
    rcc = _peg("scene.tool_pivot=tip", "scene.tool_bending_stiffness=0.5")
    assert rcc["max_depth_m"] > base["max_depth_m"] + 0.02, (rcc, base)
    assert abs(rcc["inserted_tilt_deg"] - rcc["approach_tilt_deg"]) < 1.5, rcc
