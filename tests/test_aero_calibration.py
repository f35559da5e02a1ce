"""The rotor-wake truth model: its formula, its compiled step, its calibration on real and synthetic data."""

import dataclasses
import math

import numpy as np
import pytest

from omnirotor.cli import main
from omnirotor.experiments.calibration.truth import (
    FIT_PARAMETERS,
    FRAME_TILT_PARAMETERS,
    INTAKE_FIELD_PARAMETERS,
    MOMENT_WEIGHT_PER_M,
    calibrate,
    com_offset,
    fit_wake,
    model_forces,
    model_wrenches,
    moment_residual,
    repeat_noise_floor,
)
from omnirotor.identification import HoverData, load_hover_data
from omnirotor.sim import step
from omnirotor.sim.aero import AERO_WAKE, EDGE_ON_COS, InterferenceAero, WakeAero, frame_rotation, make_aero
from omnirotor.sim.params import AeroParams, load_sim_params
from omnirotor.vehicle import load_vehicle

V = load_vehicle("omnirotor")

FIGURE_REACHED_N = 0.462
"""Force RMS of the calibrated default model over the 39 real flight points (docs/fidelity.md)."""
GOAL_N = 0.40
"""The issue's goal for that figure (issue 12, item 1)."""


def reference_wake_wrench(vehicle, u, p):
    """The rotor-wake formula of omnirotor.sim.aero written out pair by pair, without precomputation."""
    r, pi, y = (math.radians(a) for a in (p.frame_roll_deg, p.frame_pitch_deg, p.frame_yaw_deg))
    Rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    Ry = np.array([[math.cos(pi), 0, math.sin(pi)], [0, 1, 0], [-math.sin(pi), 0, math.cos(pi)]])
    Rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    Q = Rz @ Ry @ Rx
    P = vehicle.positions_B @ Q.T
    Z = vehicle.axes_B @ Q.T
    n = len(u)
    L0 = min(np.linalg.norm(P[i] - P[j]) for i in range(n) for j in range(n) if i != j)
    d = [-(1.0 if u[j] >= 0 else -1.0) * Z[j] for j in range(n)]

    def factors(strength):
        out = np.zeros(n)
        for i in range(n):
            ni = max(math.sqrt(abs(u[i])), 1e-6)
            acc = 0.0
            for j in range(n):
                if j == i:
                    continue
                L = np.linalg.norm(P[i] - P[j])
                e = (P[i] - P[j]) / L
                a, c = d[j] @ e, d[i] @ e
                if a == 0:
                    continue
                inner, outer = (p.ingest_gain, p.counter_gain) if a > 0 else (p.facing_gain, p.upstream_gain)
                G = inner if c > EDGE_ON_COS else outer if c < -EDGE_ON_COS else 0.5 * (inner + outer)
                side = max(abs(c), EDGE_ON_COS) ** p.side_exponent
                acc += G * abs(a) ** p.aim_exponent * side * (L0 / L) ** p.distance_exponent * strength[j]
            eta = min(max(1 - acc / ni, p.eta_min), p.eta_max)
            out[i] = eta * (1 + p.reverse_gain if u[i] < 0 else 1.0)
        return out

    speed = np.sqrt(np.abs(u))
    first = factors(speed)  # every slipstream as strong as its rotor's speed
    # momentum theory: a slipstream's speed goes like the square root of its rotor's thrust (first order)
    factor = factors(speed * np.sqrt(first)) if p.wake_coupling else first
    factor = factor * (1 + p.handedness_gain * np.asarray(vehicle.spins))
    A = np.zeros((6, n))
    for i in range(n):
        f = vehicle.c_f * Z[i]
        A[:3, i] = f
        A[3:, i] = np.cross(P[i], f) + vehicle.spins[i] * vehicle.c_tau * Z[i]
    return A @ (p.thrust_gain * factor * u)


def random_inputs(rng, n_points, n=8):
    """Inputs with mixed signs and speeds 40..210 Hz, as on the real robot's regions."""
    speed = rng.uniform(40.0, 210.0, (n_points, n))
    sign = np.where(rng.random((n_points, n)) < 0.3, -1.0, 1.0)
    return sign * speed * speed


INTAKE_FIELD = {"facing_gain": -0.3, "upstream_gain": 0.45, "side_exponent": 0.6, "distance_exponent": 1.4}
"""Values of the intake-field terms (off in the default) that the formula and recovery tests switch on."""


@pytest.mark.parametrize(
    ("seed", "intake_field", "coupling"),
    [(0, False, True), (1, False, False), (2, False, True), (3, True, True), (4, True, False)],
)
def test_wake_model_matches_the_pair_by_pair_formula(seed, intake_field, coupling):
    rng = np.random.default_rng(seed)
    p = AeroParams(thrust_gain=1.1, reverse_gain=0.07, ingest_gain=0.6, counter_gain=-0.4, aim_exponent=1.7,
                   handedness_gain=0.04, frame_roll_deg=0.7, frame_pitch_deg=-1.2, frame_yaw_deg=2.5)  # fmt: skip
    if intake_field:
        p = dataclasses.replace(p, **INTAKE_FIELD)
    p = dataclasses.replace(p, wake_coupling=coupling)
    aero = make_aero(V, p)
    for u in random_inputs(rng, 5):
        np.testing.assert_allclose(aero.wrench_B(u), reference_wake_wrench(V, u, p), rtol=1e-12, atol=1e-12)


def test_default_truth_is_the_calibrated_wake_model_and_spec7_stays_by_name():
    assert AeroParams().model == "wake"
    assert isinstance(make_aero(V), WakeAero)
    assert isinstance(make_aero(V, AeroParams(model="spec7")), InterferenceAero)
    assert isinstance(make_aero(V, AeroParams(model="interference")), InterferenceAero)


def test_compiled_step_evaluates_the_wake_model():
    """The simulator's compiled aero dispatch (sim.step.aero_wrench, as the step wires it) gives the model's wrench."""
    aero = make_aero(V)
    rng = np.random.default_rng(3)
    u = random_inputs(rng, 1)[0]
    assert aero.kernel_kind == AERO_WAKE
    model = np.ascontiguousarray(aero.kernel_model)
    rec = np.zeros(1, step.AERO_DTYPE)
    rec["kind"], rec["model"] = aero.kernel_kind, model.ctypes.data
    rec["rows"], rec["cols"] = model.shape
    w_B = np.zeros(6)
    step.aero_wrench(rec[0], u, w_B)
    np.testing.assert_allclose(w_B, aero.wrench_B(u), rtol=1e-12, atol=1e-12)
    assert not np.allclose(w_B, V.A_nom @ u)  # not the nominal branch


def test_stopped_rotors_make_no_force_and_reversal_changes_thrust():
    aero = make_aero(V)
    assert np.all(aero.wrench_B(np.zeros(8)) == 0.0)
    u = np.full(8, 140.0**2)
    eta = aero.efficiency(u)
    u_rev = u.copy()
    u_rev[3] = -u[3]
    eta_rev = aero.efficiency(u_rev)
    assert eta_rev[3] != eta[3]


def test_calibration_recovers_known_parameters_from_synthetic_data():
    rng = np.random.default_rng(7)
    true = AeroParams(thrust_gain=1.21, reverse_gain=0.06, ingest_gain=0.8, counter_gain=-0.35, aim_exponent=1.4,
                      handedness_gain=0.03, frame_yaw_deg=-2.0)  # fmt: skip
    U = random_inputs(rng, 30)
    w = np.zeros((30, 6))
    w[:, :3] = model_forces(V, true, U)
    data = HoverData(U, w, ("",) * 30, ("synthetic",) * 30)
    fitted = fit_wake(V, data, stand_prior=False)
    for name in FIT_PARAMETERS:
        assert getattr(fitted, name) == pytest.approx(getattr(true, name), rel=1e-4, abs=1e-5), name


def test_calibration_recovers_the_intake_field_terms_from_synthetic_data():
    """The report's intake-field fit (facing, upstream, side and distance exponents) recovers a known model."""
    rng = np.random.default_rng(11)
    true = AeroParams(thrust_gain=1.16, reverse_gain=0.03, ingest_gain=0.9, counter_gain=-0.6, aim_exponent=0.8,
                      handedness_gain=0.025, frame_yaw_deg=-4.0, **INTAKE_FIELD)  # fmt: skip
    U = random_inputs(rng, 40)
    w = np.zeros((40, 6))
    w[:, :3] = model_forces(V, true, U)
    data = HoverData(U, w, ("",) * 40, ("synthetic",) * 40)
    names = (*FIT_PARAMETERS, *INTAKE_FIELD_PARAMETERS)
    fitted = fit_wake(V, data, names=names, stand_prior=False)
    for name in names:
        assert getattr(fitted, name) == pytest.approx(getattr(true, name), rel=1e-4, abs=1e-5), name


def test_intake_field_terms_off_leave_the_previous_model():
    """With the intake-field terms at their neutral values, a rotor in a neighbour's intake field feels nothing."""
    p = AeroParams()
    assert (p.facing_gain, p.upstream_gain, p.side_exponent, p.distance_exponent) == (0.0, 0.0, 0.0, 1.0)
    aero = make_aero(V, p)
    on = make_aero(V, dataclasses.replace(p, facing_gain=0.4))
    u = np.full(8, 140.0**2)
    assert not np.allclose(on.efficiency(u), aero.efficiency(u))


def test_com_offset_balances_the_hover_moments():
    """Moments made by the weight acting at a known offset are explained by exactly that offset."""
    rng = np.random.default_rng(9)
    f = 16.0 * rng.standard_normal((20, 3))
    r_c = np.array([0.004, -0.003, 0.006])
    m = np.cross(r_c, f)
    np.testing.assert_allclose(com_offset(f, m), r_c, rtol=1e-10)
    np.testing.assert_allclose(moment_residual(f, m), 0.0, atol=1e-12)
    # A moment no offset can make (along the force) stays in the residual.
    along = 0.05 * f / np.linalg.norm(f, axis=1)[:, None]
    assert np.linalg.norm(moment_residual(f, m + along)) > 0.5 * np.linalg.norm(along)


def test_moment_fit_recovers_known_parameters_and_ignores_the_com_offset():
    """With the hover moments in the fit, a known model is recovered whatever the centre of mass's offset."""
    rng = np.random.default_rng(10)
    true = AeroParams(thrust_gain=1.17, reverse_gain=0.04, ingest_gain=0.7, counter_gain=-0.5, aim_exponent=1.2,
                      handedness_gain=0.02, frame_yaw_deg=-3.0)  # fmt: skip
    U = random_inputs(rng, 30)
    w = model_wrenches(V, true, U)
    w[:, 3:] -= np.cross(np.array([0.003, -0.004, 0.002]), w[:, :3])  # measured about an offset centre of mass
    data = HoverData(U, w, ("",) * 30, ("synthetic",) * 30)
    fitted = fit_wake(V, data, stand_prior=False, moment_weight=MOMENT_WEIGHT_PER_M)
    for name in FIT_PARAMETERS:
        assert getattr(fitted, name) == pytest.approx(getattr(true, name), rel=1e-4, abs=1e-5), name


def test_calibration_recovers_a_three_axis_frame_rotation():
    rng = np.random.default_rng(8)
    true = AeroParams(thrust_gain=1.18, reverse_gain=0.02, ingest_gain=0.7, counter_gain=-0.5, aim_exponent=0.9,
                      handedness_gain=-0.02, frame_roll_deg=0.8, frame_pitch_deg=-0.6, frame_yaw_deg=3.0)  # fmt: skip
    U = random_inputs(rng, 30)
    w = np.zeros((30, 6))
    w[:, :3] = model_forces(V, true, U)
    data = HoverData(U, w, ("",) * 30, ("synthetic",) * 30)
    fitted = fit_wake(V, data, names=(*FIT_PARAMETERS, *FRAME_TILT_PARAMETERS), stand_prior=False)
    for name in (*FIT_PARAMETERS, *FRAME_TILT_PARAMETERS):
        assert getattr(fitted, name) == pytest.approx(getattr(true, name), rel=1e-4, abs=1e-5), name


def test_frame_rotation_turns_the_wrench_and_keeps_the_interaction():
    """A rotation between the rotors' frame and the measured frame turns the whole wrench, nothing else."""
    rng = np.random.default_rng(4)
    base = AeroParams(frame_roll_deg=0.0, frame_pitch_deg=0.0, frame_yaw_deg=0.0)
    turned = dataclasses.replace(base, frame_roll_deg=1.5, frame_pitch_deg=-2.0, frame_yaw_deg=4.0)
    Q = frame_rotation(1.5, -2.0, 4.0)
    a, b = make_aero(V, base), make_aero(V, turned)
    for u in random_inputs(rng, 4):
        w0, w1 = a.wrench_B(u), b.wrench_B(u)
        assert not np.allclose(w1, w0)  # the rotation is applied, not ignored
        np.testing.assert_allclose(w1[:3], Q @ w0[:3], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(w1[3:], Q @ w0[3:], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(a.efficiency(u), b.efficiency(u), rtol=1e-11)


def test_handedness_gain_scales_the_two_propeller_handednesses_apart():
    u = np.full(8, 140.0**2)
    base = AeroParams(handedness_gain=0.0)
    eta = make_aero(V, base).efficiency(u)
    aero = make_aero(V, dataclasses.replace(base, handedness_gain=0.05))
    np.testing.assert_allclose(aero.gains, 1.0 + 0.05 * V.spins)
    assert aero.gains[V.spins > 0].min() > aero.gains[V.spins < 0].max()  # the k = +1 rotors make more thrust
    # The thrust factors of the interaction are unchanged; the columns of the map carry the gain.
    np.testing.assert_array_equal(aero.efficiency(u), eta)
    np.testing.assert_allclose(aero.A_true, make_aero(V, base).A_true * (1.0 + 0.05 * V.spins)[None, :])


def test_repeat_noise_floor_recovers_a_known_spread():
    """Points in groups of one attitude, residuals with a known scatter about each group's own offset."""
    rng = np.random.default_rng(5)
    n_groups, reps, sigma = 300, 3, np.array([0.1, 0.2, 0.15])
    k = np.arange(n_groups) + 0.5  # a Fibonacci lattice: attitudes about 12 deg apart
    z, phi = 1.0 - 2.0 * k / n_groups, math.pi * (1.0 + math.sqrt(5.0)) * k
    dirs = np.column_stack([np.sqrt(1.0 - z * z) * np.cos(phi), np.sqrt(1.0 - z * z) * np.sin(phi), z])
    f = np.repeat(16.0 * dirs, reps, axis=0)
    offset = np.repeat(rng.standard_normal((n_groups, 3)), reps, axis=0)  # any model error of the attitude
    residual = offset + sigma * rng.standard_normal((n_groups * reps, 3))
    floor = repeat_noise_floor(f, residual)
    assert len(floor.groups) == n_groups and floor.dof == n_groups * (reps - 1)
    np.testing.assert_allclose(floor.std_axis, sigma, rtol=0.08)
    assert floor.ci90[0] < np.linalg.norm(sigma) < floor.ci90[1]
    # Distinct attitudes are no repeats: no floor.
    single = repeat_noise_floor(16.0 * dirs, rng.standard_normal((n_groups, 3)))
    assert single.dof == 0 and math.isnan(single.per_point)


def _real_rms(flight_data, params):
    data = load_hover_data([flight_data], V)
    f = data.w_B[:, :3]
    return math.sqrt(np.mean(np.sum((model_forces(V, params, data.u_hz2) - f) ** 2, axis=1)))


def test_calibrated_default_explains_the_real_flight_data(flight_data):
    data = load_hover_data([flight_data], V)
    assert _real_rms(flight_data, AeroParams()) <= FIGURE_REACHED_N + 5e-4
    assert _real_rms(flight_data, AeroParams(model="spec7")) > 0.67  # SPEC §7.1's figure: the new model is better
    # The default is what the calibration gives from its neutral start (reproducible).
    fitted = calibrate(V, data, leave_one_point=False)
    for name in (*FIT_PARAMETERS, *FRAME_TILT_PARAMETERS):
        assert getattr(fitted.params, name) == pytest.approx(getattr(AeroParams(), name), rel=2e-3, abs=2e-3), name
    # Cross-validation: every held-out region is predicted better than SPEC §7 predicts it, and better than
    # by the previous rotor-wake model (no wake coupling: 0.550, 0.459, 0.530 N; LOPO 0.488 N, docs/fidelity.md).
    previous = {"R1": 0.550, "R3": 0.459, "R4": 0.530}
    for region, cv in fitted.cv_region.items():
        assert cv < fitted.table["SPEC §7 model"][region], region
        assert cv < previous[region], region
    # Roll and pitch of the frame do not cross-validate: fitted too, they predict no held-out region better.
    _, _, cv3 = fitted.tilt_fit
    assert all(cv3[r] >= fitted.cv_region[r] for r in cv3)
    # The repeat noise floor (R1's attitudes flown two or three times): 0.29 N per point.
    assert fitted.floor.dof == 9 and fitted.floor.per_point == pytest.approx(0.287, abs=5e-3)
    # The force-stand pattern (SPEC §3.5): upside down above upright, the mixed-direction regions above both,
    # within 0.03 of the stand's range 1.22-1.27 (a soft prior: a 1 % miss costs like 0.2 N of force residual).
    s = fitted.stand
    assert s["R1"] < s["R6"] < min(v for r, v in s.items() if r not in ("R1", "R6"))
    assert all(1.19 < v < 1.30 for r, v in s.items() if r not in ("R1", "R6"))
    # The hover moments (about the centre of mass that balances each model best): the thrust redistribution the
    # forces ask of the pair interaction makes moments the robot did not have, 0.195 N·m (the previous model
    # without the wake coupling: 0.220) against the nominal map's 0.093 N·m and a repeat floor of 0.043 N·m.
    # Fitted with the moments too, the model predicts every held-out region's force worse (0.721, 0.565,
    # 0.583 N): the moments do not pin the interaction better.
    assert fitted.moments["rotor-wake model (calibrated)"] == pytest.approx(0.195, abs=2e-3)
    assert fitted.moments["nominal"] == pytest.approx(0.093, abs=2e-3)
    assert fitted.moment_floor.per_point == pytest.approx(0.043, abs=2e-3)
    assert fitted.moment_fit.moment_rms < 0.6 * fitted.moments["rotor-wake model (calibrated)"]
    assert all(fitted.moment_fit.cv_region[r] > fitted.cv_region[r] for r in fitted.cv_region)
    # The intake-field terms (with the moments at 2 N per N·m) do not predict held-out R1 better (0.704 N): neutral.
    assert fitted.intake_fit.cv_region["R1"] > fitted.cv_region["R1"]
    assert AeroParams().wake_coupling and (AeroParams().facing_gain, AeroParams().upstream_gain) == (0.0, 0.0)


@pytest.mark.xfail(
    strict=True,
    reason="issue 12 goal: 0.40 N over the 39 points; reached 0.462 N (LORO 0.45-0.52 N, LOPO 0.483 N) with a "
    "repeat noise floor of 0.29 N per point (90 % 0.24-0.37 N), 0.17 N of it a common scale of all rotors: the rest "
    "is attitude-dependent thrust no tried physical term explains in cross-validation (frame download, intake "
    "field in four flow configurations, per-handedness reverse gain, the hover moments in the fit, speed ripple, "
    "central-body blockage, wake contraction, vehicle downwash, reversed wake, edge-on lift, mounts bent by their "
    "thrust: docs/fidelity.md)",
)
def test_truth_model_reaches_the_issue_goal_on_the_real_flight_data(flight_data):
    assert _real_rms(flight_data, AeroParams()) <= GOAL_N


def test_calibrate_truth_cli_writes_a_loadable_truth_and_the_report(flight_data, tmp_path, capsys):
    out = tmp_path / "truth.toml"
    assert (
        main(["calibrate-truth", str(flight_data), "--out", str(out), "--report", str(tmp_path / "r"), "--no-loo"]) == 0
    )
    p = load_sim_params(out).aero
    assert p.model == "wake" and p.thrust_gain == pytest.approx(AeroParams().thrust_gain, rel=2e-3)
    assert (tmp_path / "r" / "measured-vs-predicted.png").stat().st_size > 10_000
    text = (tmp_path / "r" / "report.md").read_text()
    assert "Leave-one-region-out" in text and "identified per-region maps" in text
    assert "Hover moments" in text and "forces and moments" in text
    assert "| R1 |" in text
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rotor-wake truth: force RMS") and str(out) in lines[0]


def test_calibrate_truth_without_report_folder_writes_the_report_beside_the_table(flight_data, tmp_path, capsys):
    out = tmp_path / "truth.toml"
    assert main(["calibrate-truth", str(flight_data), "--out", str(out), "--no-loo"]) == 0
    report = tmp_path / "truth-report.md"
    assert "Leave-one-region-out" in report.read_text()
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1 and str(report) in lines[0]


@pytest.mark.parametrize(
    "args, message",
    [
        (["calibrate-truth", "/no/such/folder", "--out", "OUT"], "no such file"),
        (["calibrate-truth", "DATA", "--out", "/no/such/dir/t.toml"], "does not exist"),
    ],
)
def test_calibrate_truth_bad_input_is_one_line_and_writes_nothing(args, message, tmp_path, capsys):
    data = tmp_path / "d.csv"
    data.write_text("roll_deg,pitch_deg,yaw_deg," + ",".join(f"omega{i}_hz" for i in range(1, 9)) + "\n")
    out = tmp_path / "t.toml"
    argv = [str(out) if a == "OUT" else str(data) if a == "DATA" else a for a in args]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_wake_params_are_checked():
    from omnirotor.errors import InputError

    for bad in ({"thrust_gain": 0.0}, {"reverse_gain": -1.0}, {"aim_exponent": -1.0}, {"ingest_gain": float("nan")}):
        with pytest.raises(InputError):
            AeroParams(**bad)
    assert dataclasses.replace(AeroParams(), model="nominal").model == "nominal"
