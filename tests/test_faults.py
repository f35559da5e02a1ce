"""Faults between simulator and controller: each one is survived, flagged, and never reaches the motors.

The simulator's step applies the fault schedule, so runs with faults fly the compiled loop; one test checks
that it gives bit for bit the run of the Python loop.
"""

import dataclasses

import numpy as np
import pytest

from omnirotor.control.admittance import AdmittanceParams
from omnirotor.control.controller import InteractionController
from omnirotor.control.trajectory import PoseTrajectory, Waypoint
from omnirotor.errors import InputError
from omnirotor.experiments.faults import (
    MocapDropout,
    PlantPerturbation,
    RotorFailure,
    SensorCorruption,
    WindGust,
    install_faults,
    plant_simulator,
    safety_stats,
    unreachable_reference,
)
from omnirotor.experiments.loop import TaskOptions, run_closed_loop
from omnirotor.experiments.tasks import run_task
from omnirotor.experiments.tasks.common import ExperimentOptions
from omnirotor.messages import ControlStatus
from omnirotor.sim import SimParams, Simulator
from omnirotor.so3 import log_so3
from omnirotor.vehicle import load_vehicle

V = load_vehicle()
DEGRADED = int(ControlStatus.ESTIMATE_DEGRADED)
NONFINITE = int(ControlStatus.NONFINITE_INPUT)
SATURATED = int(ControlStatus.SATURATED)
EXCLUDED = int(ControlStatus.ROTOR_EXCLUDED)
REJECTED = int(ControlStatus.FRAME_REJECTED)


def fly(faults=(), estimator="bypass", duration=3.0, trajectory=None, tell=True, plant=None, seed=1, sim_params=None):
    """Hover (or fly ``trajectory``) in the free scene with a fault schedule; returns the run's arrays.

    The plant is the undisturbed one (``sim_params`` replaces it), so the faults' effects stand out.
    """
    params = TaskOptions(estimator=estimator).controller_params(AdmittanceParams.preset("free"))
    ctl = InteractionController(V, params)
    sp = SimParams().undisturbed() if sim_params is None else sim_params
    sim = plant_simulator(V, "free", sp, seed, plant, ctl if tell else None)
    if plant is None:
        install_faults(sim, faults, ctl if tell else None)
    p0, R0 = sim.default_start()
    traj = trajectory or PoseTrajectory([Waypoint(0.0, p0 + R0 @ V.p_E_B_array, R0)])
    clog, tlog = run_closed_loop(sim, ctl, traj, duration)
    return {
        "sim": sim,
        "ctl": ctl,
        "p0": p0,
        "t": tlog.group("t").copy(),
        "p_W": tlog.group("p_W").copy(),
        "R_WB": tlog.group("R_WB").reshape(-1, 3, 3).copy(),
        "p_E_W": tlog.group("p_E_W").copy(),
        "rotor_hz": tlog.group("rotor_hz").copy(),
        "status": clog.group("status").astype(int),
        "omega": clog.group("omega_cmd_hz").copy(),
        "f_ext_W": clog.group("f_ext_W").copy(),
    }


def assert_safe(run):
    """Every command finite and within the rotor limits (what the motors would get)."""
    w = run["omega"]
    assert np.all(np.isfinite(w))
    assert w.min() >= V.omega_min_hz and w.max() <= V.omega_max_hz
    inj = run["sim"].faults
    assert inj.commands_nonfinite == 0 and inj.commands_out_of_limits == 0
    assert inj.commands_checked == w.shape[0]  # the hold command of the first period, then all but the last
    s = safety_stats(w, run["status"], V)
    assert s["commands_finite"] and s["commands_within_limits"]


def hover_error(run):
    return np.linalg.norm(run["p_W"] - run["p0"], axis=1)


@pytest.fixture(scope="module")
def baseline():
    return {est: fly(estimator=est) for est in ("bypass", "ukf")}


def test_injector_without_faults_flies_exactly_like_the_simulator(baseline):
    params = TaskOptions(estimator="bypass").controller_params(AdmittanceParams.preset("free"))
    ctl = InteractionController(V, params)
    sim = Simulator(V, "free", SimParams().undisturbed(), seed=1)
    p0, R0 = sim.default_start()
    clog, tlog = run_closed_loop(sim, ctl, PoseTrajectory([Waypoint(0.0, p0 + R0 @ V.p_E_B_array, R0)]), 3.0)
    np.testing.assert_array_equal(tlog.group("p_W"), baseline["bypass"]["p_W"])
    np.testing.assert_array_equal(clog.group("omega_cmd_hz"), baseline["bypass"]["omega"])
    assert baseline["bypass"]["sim"].faults.events == []
    assert_safe(baseline["bypass"])


def test_mocap_dropout_flies_on_the_imu_flags_degraded_and_recovers(baseline):
    run = fly([MocapDropout(1.5, 0.5)], estimator="ukf")
    t, degraded = run["t"], (run["status"] & DEGRADED) > 0
    timeout = run["ctl"].estimator.params.mocap_timeout_s
    # flagged once no sample was accepted for the timeout, cleared by the first sample after the dropout
    assert degraded.any()
    assert t[degraded].min() == pytest.approx(1.5 + timeout, abs=0.015)
    assert t[degraded].max() < 2.0 + 0.03
    assert not degraded[t > 2.05].any()
    # the IMU alone carried it through: the hover stays where the undisturbed one is
    drift = np.abs(hover_error(run) - hover_error(baseline["ukf"]))
    assert drift.max() < 0.01
    assert [e for _, e in run["sim"].faults.events] == ["motion-capture dropout starts", "motion-capture dropout ends"]
    assert_safe(run)


def test_state_dropout_with_the_bypass_estimator_is_flagged_and_held():
    run = fly([MocapDropout(1.0, 0.05, drop_state=True)])
    t, degraded = run["t"], (run["status"] & DEGRADED) > 0
    assert degraded[(t >= 1.0) & (t < 1.05)].all() and not degraded[t >= 1.06].any()
    assert hover_error(run).max() < 0.03
    assert_safe(run)


def test_rotor_failure_told_to_the_controller_keeps_the_hover(baseline):
    # Without the rotor reversal's stop (30 ms at rest when a rotor changes direction): the seven others
    # re-allocate through zero, and with the stop the hover deviates 11.4 mm from the baseline instead of 8.1 mm.
    no_stop = SimParams().undisturbed()
    no_stop = dataclasses.replace(no_stop, rotors=dataclasses.replace(no_stop.rotors, reversal_delay_s=0.0))
    run = fly([RotorFailure(3, 1.0, tell_controller=True, detect_delay_s=0.02)], duration=3.5, sim_params=no_stop)
    t = run["t"]
    after = t > 1.0
    # the motor stopped: its true speed decays to zero through the rotor lag
    assert abs(run["rotor_hz"][-1, 2]) < 1.0 and abs(run["rotor_hz"][0, 2]) > 100.0
    # once told, the allocation leaves it out and says so
    told = t >= 1.03
    assert np.all(run["omega"][told, 2] == 0.0)
    assert np.all(run["status"][told] & EXCLUDED) and not np.any(run["status"][t < 1.0] & EXCLUDED)
    # the seven others hold the hover within a couple of centimetres of the undisturbed one (16.5 mm measured
    # under the rotor-wake truth, where the stopped rotor's wake also leaves its neighbours: a change of the
    # true map that nobody tells the allocation; 8.1 mm under its previous calibration, whose pair gains were
    # 2.5-4x weaker; below 5 mm under SPEC §7's model)
    base = hover_error(baseline["bypass"])
    n = min(base.size, t.size)
    assert np.max(np.abs(hover_error(run)[:n] - base[:n])[after[:n]]) < 0.020
    assert "controller told rotor 3 failed" in [e for _, e in run["sim"].faults.events]
    assert_safe(run)


def test_rotor_failure_not_told_sags_saturated_but_safe(baseline):
    """Not told, the allocation keeps asking the dead rotor for thrust: the others saturate, the vehicle sags
    by ~15 cm to a new equilibrium (the pose loop has no integrator), and every command stays within limits."""
    run = fly([RotorFailure(3, 1.0, tell_controller=False)], duration=3.5, tell=False)
    t = run["t"]
    err = hover_error(run)
    assert err[t > 3.0].min() > 0.08  # clearly worse than told ...
    assert err.max() < 0.3  # ... but it does not fall
    assert np.any(run["status"][t > 1.0] & SATURATED) and not np.any(run["status"] & EXCLUDED)
    assert np.any(run["omega"][t > 1.2, 2] != 0.0)  # the controller still commands the dead rotor
    assert_safe(run)


CORRUPTIONS = [
    SensorCorruption("imu_acc", 1.0, 0.02, "nan"),
    SensorCorruption("imu_gyro", 1.2, 0.001, "inf"),
    SensorCorruption("rotor_hz", 1.4, 0.01, "nan", component=2),
    SensorCorruption("mocap", 1.6, 0.05, "spike", 1.0),  # a 1 m jump: the frame supervision rejects it
    SensorCorruption("imu_acc", 1.8, 0.005, "spike", 1e4),  # beyond the accelerometer's range
    SensorCorruption("imu_gyro", 2.0, 0.005, "spike", 1e3),
    SensorCorruption("mocap", 2.2, 0.03, "nan"),
]


@pytest.mark.parametrize("estimator", ["ukf", "bypass"])
def test_nonfinite_and_spiking_sensors_are_rejected_and_flagged(baseline, estimator):
    faults = list(CORRUPTIONS) + ([SensorCorruption("state", 2.6, 0.02, "inf")] if estimator == "bypass" else [])
    run = fly(faults, estimator=estimator)
    t, flagged = run["t"], (run["status"] & (NONFINITE | REJECTED)) > 0
    # the bad samples the estimator or the controller sees are flagged where they happen (the 1 m jump of motion
    # capture as FRAME_REJECTED by the frame supervision, the others also as NONFINITE_INPUT)
    seen = [f for f in faults if estimator == "ukf" or f.signal in ("rotor_hz", "state")]
    for f in seen:
        w = (t >= f.t_start_s) & (t < f.t_start_s + f.duration_s + 0.011)
        assert flagged[w].any(), f
    assert not flagged[t < 1.0].any()
    # nothing of it reaches the motors, and the hover does not notice
    assert_safe(run)
    drift = np.abs(hover_error(run) - hover_error(baseline[estimator]))
    assert drift.max() < 0.005


def test_unreachable_jump_saturates_safely_and_arrives():
    sim = Simulator(V, "free")
    p0, R0 = sim.default_start()
    pE = p0 + R0 @ V.p_E_B_array
    run = fly(trajectory=unreachable_reference(pE, R0, "jump", 1.0, 14.0), duration=15.5)
    assert np.any(run["status"] & SATURATED)
    assert_safe(run)
    target = pE + np.array([5.0, 0.0, 0.0])
    assert np.linalg.norm(run["p_E_W"][-1] - target) < 0.05
    assert np.all(np.diff(run["p_E_W"][run["t"] > 2.0, 0]) > -1e-3)  # it heads there, no overshoot back


def test_unreachable_flip_saturates_safely_and_turns_over():
    sim = Simulator(V, "free")
    p0, R0 = sim.default_start()
    pE = p0 + R0 @ V.p_E_B_array
    # the EE tip stays put, so the body must travel 1 m in 0.2 s: it takes ~4 s at the saturated speed
    run = fly(trajectory=unreachable_reference(pE, R0, "flip", 1.0, 4.8), duration=6.0)
    assert np.any(run["status"] & SATURATED)
    assert_safe(run)
    R1 = unreachable_reference(pE, R0, "flip").waypoints[-1].R_WB
    assert np.degrees(np.linalg.norm(log_so3(R1.T @ run["R_WB"][-1]))) < 2.0
    assert np.linalg.norm(run["p_E_W"][-1] - pE) < 0.05


def test_wind_gust_is_estimated_and_rejected(baseline):
    run = fly([WindGust(1.0, 1.0, (6.0, 0.0, 0.0))], duration=3.0)
    t, f = run["t"], run["f_ext_W"]
    during = (t > 1.0) & (t < 2.2)
    # the observer sees the gust (peak 6 N, through its ~10 Hz output filter; 4.27 N measured under the rotor-wake
    # truth, whose map error changes as the vehicle leans into the gust; 4.50 N under its previous calibration)
    assert 4.0 < f[during, 0].max() < 6.5
    assert abs(f[t < 1.0, 0]).max() < 0.3
    # pushed along the gust, and back afterwards
    dx = run["p_W"][:, 0] - run["p0"][0]
    assert dx[during].max() > 0.01
    assert abs(dx[-1] - (baseline["bypass"]["p_W"][-1, 0] - run["p0"][0])) < 0.005
    assert [e for _, e in run["sim"].faults.events] == ["wind gust starts", "wind gust ends"]


def test_heavier_plant_than_believed_shows_as_an_external_force(baseline):
    run = fly(plant=PlantPerturbation(mass_scale=1.1))
    assert run["sim"].vehicle.mass == pytest.approx(1.1 * V.mass)
    missing = 0.1 * V.weight
    df = baseline["bypass"]["f_ext_W"][-500:, 2].mean() - run["f_ext_W"][-500:, 2].mean()
    assert df == pytest.approx(missing, rel=0.2)


def test_plant_perturbation_moves_only_the_plant():
    plan = SimParams()
    plant = PlantPerturbation(scene_offset_W=(0.0, 0.02, -0.01), sim_overrides=("aero.gamma=9",))
    true = plant.sim_params(plan)
    assert true.scene.wall_point == pytest.approx(np.add(plan.scene.wall_point, (0.0, 0.02, -0.01)))
    assert true.scene.pipe_centre == pytest.approx(np.add(plan.scene.pipe_centre, (0.0, 0.02, -0.01)))
    assert true.aero.gamma == 9.0 and plan.aero.gamma == 4.0
    assert PlantPerturbation().is_identity and PlantPerturbation().vehicle(V) is V


def test_faults_through_experiment_options_reach_a_task_run():
    plant = PlantPerturbation(faults=(SensorCorruption("rotor_hz", 0.2, 0.01, "nan"),))
    m = run_task(
        "point-contact",
        ExperimentOptions(quick=True, estimator="bypass", duration_s=0.4, plant=plant, disturbances=False),
    )
    s = m.summary()["safety"]
    assert s["commands_finite"] and s["commands_within_limits"]
    assert 5 <= s["flags"]["nonfinite_input"] <= 12  # the 10 corrupted frames, and no others


@pytest.mark.parametrize(
    "make,needle",
    [
        (lambda: MocapDropout(-1.0, 0.5), "t_start_s must be >= 0"),
        (lambda: MocapDropout(1.0, 0.0), "duration_s must be a finite number > 0"),
        (lambda: RotorFailure(0, 1.0), "rotor must be an integer >= 1"),
        (lambda: RotorFailure(2, 1.0, detect_delay_s=float("nan")), "must be finite"),
        (lambda: SensorCorruption("lidar", 1.0, 0.1), "signal must be one of"),
        (lambda: SensorCorruption("imu_acc", 1.0, 0.1, "zero"), "kind must be one of"),
        (lambda: WindGust(1.0, 1.0, (1.0, float("inf"), 0.0)), "must be finite"),
        (lambda: WindGust(1.0, 1.0, (1.0, 0.0)), "3 components"),
        (lambda: PlantPerturbation(mass_scale=0.0), "mass_scale"),
        (lambda: PlantPerturbation(faults=("boom",)), "not a fault"),
        (lambda: install_faults(Simulator(V), [RotorFailure(9, 1.0)]), "the vehicle has 8 rotors"),
        (lambda: PlantPerturbation(inertia_scale=(1.0, 1.0, 5.0)).vehicle(V), "triangle inequality"),
        (lambda: unreachable_reference(np.zeros(3), np.eye(3), "teleport"), "jump' or 'flip"),
    ],
)
def test_bad_fault_definitions_are_input_errors(make, needle):
    with pytest.raises(InputError, match=None) as exc:
        make()
    assert needle in str(exc.value)


def test_faults_fly_the_compiled_loop_and_equal_the_python_loop(monkeypatch):
    import omnirotor.experiments._loop as loop

    calls = []
    compiled = loop.run_steps
    monkeypatch.setattr(loop, "run_steps", lambda *a: calls.append(1) or compiled(*a))
    faults = [
        SensorCorruption("imu_gyro", 0.5, 0.004),
        SensorCorruption("mocap", 0.7, 0.05, "spike", 0.05, component=1),
        SensorCorruption("rotor_hz", 1.1, 0.003, "inf", component=2),
        SensorCorruption("state", 1.2, 0.01, "spike", 0.02),
        MocapDropout(1.5, 0.3, drop_state=True),
        RotorFailure(3, 1.0, detect_delay_s=0.05),
        WindGust(2.0, 0.5, (3.0, 0.0, -1.0), (0.0, 0.1, 0.0)),
    ]
    runs = []
    for hook in (None, lambda sim, t: None):  # a no-op hook makes run_closed_loop take its Python loop
        n_calls = len(calls)
        params = TaskOptions(estimator="bypass").controller_params(AdmittanceParams.preset("free"))
        ctl = InteractionController(V, params)
        sim = install_faults(Simulator(V, "free", SimParams().undisturbed(), seed=1), faults, ctl)
        p0, R0 = sim.default_start()
        traj = PoseTrajectory([Waypoint(0.0, p0 + R0 @ V.p_E_B_array, R0)])
        clog, tlog = run_closed_loop(sim, ctl, traj, 2.6, on_step=hook)
        runs.append((clog.data[: clog.n].copy(), tlog.data[: tlog.n, :-2].copy(), sim.faults.events))
        assert (len(calls) > n_calls) == (hook is None)
        f = sim.faults
        assert f.commands_checked == clog.n and f.commands_nonfinite == f.commands_out_of_limits == 0
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
    assert runs[0][2] == runs[1][2]
    text = [e for _, e in runs[0][2]]
    assert "rotor 3 fails" in text and "controller told rotor 3 failed" in text
    assert text.count("wind gust starts") == 1 and "motion-capture dropout ends" in text
