"""Torque rows from dynamic flight (issue 15, item 1): derivative, fit, CSV, CLI, and a shortened closed-loop flight."""

import numpy as np
import pytest

from omnirotor.cli import main
from omnirotor.errors import InputError
from omnirotor.torque_identification import (
    FlightLog,
    TorqueIdParams,
    fit_torque_rows,
    load_flight_csv,
    moment_samples,
    write_flight_csv,
    zero_phase_derivative,
)
from omnirotor.vehicle import load_vehicle


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("omnirotor")


def test_zero_phase_derivative_has_no_lag():
    dt = 1e-3
    t = np.arange(0, 10, dt)
    x = np.sin(2 * np.pi * 1.0 * t)[:, None]
    xf, dx = zero_phase_derivative(x, dt, 8.0)
    mid = slice(2000, 8000)
    assert np.max(np.abs(xf[mid, 0] - x[mid, 0])) < 1e-3
    assert np.max(np.abs(dx[mid, 0] - 2 * np.pi * np.cos(2 * np.pi * t[mid]))) < 0.01 * 2 * np.pi


def _synthetic_flight(vehicle, A2_true, rng, span_all=True, T=20.0, dt=1e-3):
    """Rotational dynamics under A2_true from smooth random inputs; gyro and rotor speeds with noise."""
    n = vehicle.n_rotors
    t = np.arange(0, T, dt)
    u0 = vehicle.hover_input()
    basis = np.eye(n) if span_all else np.linalg.pinv(vehicle.A_nom) @ vehicle.A_nom  # row space only
    # smooth random excitation: sums of sines with random phases, 0.2-3 Hz
    freqs = rng.uniform(0.2, 3.0, (6, n))
    ph = rng.uniform(0, 2 * np.pi, (6, n))
    du = np.sum(np.sin(2 * np.pi * freqs[None] * t[:, None, None] + ph[None]), axis=1) * 1500.0
    u = u0 + du @ basis.T
    J = vehicle.inertia
    w = np.zeros((t.size, 3))
    for k in range(t.size - 1):
        m = A2_true @ u[k]
        w[k + 1] = w[k] + dt * np.linalg.solve(J, m - np.cross(w[k], J @ w[k]))
    gyro = w + 0.005 * rng.standard_normal(w.shape) + 0.002
    speed = np.sign(u) * np.sqrt(np.abs(u)) + 0.5 * rng.standard_normal(u.shape)
    return FlightLog(t, gyro, speed, ("R1",) * t.size)


def test_fit_recovers_the_torque_rows_of_a_known_plant(vehicle):
    rng = np.random.default_rng(0)
    A2_true = vehicle.A_nom[3:] * (1 + 0.3 * rng.standard_normal((3, vehicle.n_rotors)))
    log = _synthetic_flight(vehicle, A2_true, rng)
    p = TorqueIdParams()
    u, m, _ = moment_samples(log, vehicle, p)
    fit = fit_torque_rows(u, m, vehicle.A_nom, p)
    err_nom = np.abs(vehicle.A_nom[3:] - A2_true).mean()
    err_fit = np.abs(fit.A2 - A2_true).mean()
    assert err_fit < 0.1 * err_nom
    assert fit.residual_rms_Nm < 0.2 * fit.base_residual_rms_Nm


def test_unexcited_input_directions_stay_at_nominal(vehicle):
    rng = np.random.default_rng(1)
    A2_true = vehicle.A_nom[3:] * (1 + 0.3 * rng.standard_normal((3, vehicle.n_rotors)))
    log = _synthetic_flight(vehicle, A2_true, rng, span_all=False)
    p = TorqueIdParams()
    u, m, _ = moment_samples(log, vehicle, p)
    fit = fit_torque_rows(u, m, vehicle.A_nom, p)
    null = np.linalg.svd(vehicle.A_nom)[2][6:].T  # (n, 2): never excited
    moved = np.abs((fit.A2 - vehicle.A_nom[3:]) @ null).max()
    assert moved < 0.02 * np.abs(vehicle.A_nom[3:]).max()
    # on what the flight did excite, the fit still approaches the plant
    P = np.linalg.pinv(vehicle.A_nom) @ vehicle.A_nom
    assert np.abs((fit.A2 - A2_true) @ P).mean() < 0.3 * np.abs((vehicle.A_nom[3:] - A2_true) @ P).mean()


def test_flight_csv_round_trip_and_bad_files(vehicle, tmp_path):
    rng = np.random.default_rng(2)
    log = _synthetic_flight(vehicle, vehicle.A_nom[3:], rng, T=1.0)
    path = tmp_path / "flight.csv"
    write_flight_csv(path, log)
    back = load_flight_csv(path, vehicle)
    assert np.allclose(back.gyro_B, log.gyro_B, rtol=1e-6) and back.region == log.region
    text = path.read_text().splitlines()
    (tmp_path / "missing.csv").write_text("\n".join([text[0].replace("gyro_z_rad_s", "gz")] + text[1:]))
    with pytest.raises(InputError, match="gyro_z_rad_s"):
        load_flight_csv(tmp_path / "missing.csv", vehicle)
    rows = text[:3] + [text[3].replace(text[3].split(",")[0], "9.0", 1)] + text[4:]
    (tmp_path / "uneven.csv").write_text("\n".join(rows))
    with pytest.raises(InputError, match="constant rate"):
        load_flight_csv(tmp_path / "uneven.csv", vehicle)


def test_identify_torque_cli_bad_flight_log_exits_2(tmp_path, capsys, flight_data):
    (tmp_path / "flight.csv").write_text("t_s,foo\n0,1\n")
    out = tmp_path / "maps.json"
    code = main(["identify", str(flight_data), "--torque", str(tmp_path / "flight.csv"), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "not a flight log" in err and err.count("\n") == 1 and not out.exists()


def test_shortened_sweep_flight_identifies_torque_rows_nearer_the_truth(vehicle, tmp_path):
    from omnirotor.experiments.closed_loop import run_task
    from omnirotor.experiments.tasks import ExperimentOptions
    from omnirotor.sim.aero import make_aero
    from omnirotor.studies.torque_rows import truth_torque_rows

    result = run_task("identify-dynamic", ExperimentOptions(quick=True, out_dir=str(tmp_path)))
    assert result.metrics["success"] and result.metrics["tilt_max_deg"] > 8.0
    log = load_flight_csv(tmp_path / "flight.csv", vehicle)
    assert set(log.region) == {"R1"}
    p = TorqueIdParams()
    u, m, _ = moment_samples(log, vehicle, p)
    fit = fit_torque_rows(u, m, vehicle.A_nom, p)
    aero = make_aero(vehicle)
    A2_truth = truth_torque_rows(aero, u, np.random.default_rng(0))
    assert np.abs(fit.A2 - A2_truth).mean() < 0.6 * np.abs(vehicle.A_nom[3:] - A2_truth).mean()
    # the moment the truth makes at the flight's inputs is explained far better than by the nominal rows
    m_true = np.array([aero.wrench_B(x)[3:] for x in u])
    r_fit = np.sqrt(np.mean(np.sum((m_true - u @ fit.A2.T) ** 2, axis=1)))
    r_nom = np.sqrt(np.mean(np.sum((m_true - u @ vehicle.A_nom[3:].T) ** 2, axis=1)))
    assert r_fit < 0.2 * r_nom


def test_torque_rows_study_shrinks_the_hover_moment_bias(tmp_path):
    from omnirotor.studies.torque_rows import plot_torque_rows, torque_rows_study

    r = torque_rows_study(tmp_path, quick=True)
    assert set(r["torque_rows"]) == {"R1", "global"}  # the quick sweep flies R1 only
    e = r["torque_rows"]["R1"]
    assert e["truth_moment_residual_rms_Nm"]["identified"] < 0.2 * e["truth_moment_residual_rms_Nm"]["nominal"]
    hv = r["hover_validation_moments"]
    bias = {m: np.abs(hv[m]["R1"]["moment_B_mean_Nm"]).max() for m in hv}
    assert bias["hover+flight"] < 0.5 * bias["hover-only"]
    # no flight in R3: same map there (the run differs only by what it carries over from R1)
    assert np.allclose(
        hv["hover+flight"]["R3"]["moment_B_mean_Nm"], hv["hover-only"]["R3"]["moment_B_mean_Nm"], atol=1e-3
    )
    plot_torque_rows(r, tmp_path / "fig.png")
    assert (tmp_path / "fig.png").stat().st_size > 0
