"""PX4 in: frames, vehicles from airframes and ULogs, automatic hover windows, identification from a ULog."""

import json
import math

import numpy as np
import pytest

from conftest import SHARED
from omnirotor.cli import main
from omnirotor.errors import InputError
from omnirotor.px4.airframe import read_airframe_params, vehicle_from_px4_params
from omnirotor.px4.frames import R_WB_from_px4_quat, px4_quat_from_R_WB, vec_from_px4
from omnirotor.so3 import R_from_rpy, rot_x, rot_z
from omnirotor.vehicle import load_vehicle

PX4 = SHARED / "data" / "px4"
EVENTS = PX4 / "sample_px4_events.ulg"
SMALL = PX4 / "sample_log_small.ulg"
OMNICOPTER = PX4 / "10019_omnicopter"


def _need(path):
    if not path.is_file():
        pytest.skip(f"PX4 test file not found at {path} (../shared is not beside the checkout)")
    return path


# -- frames ---------------------------------------------------------------------------------------------------


def test_px4_yaw_east_is_our_yaw_minus_90_deg():
    # PX4: yaw 90 deg about NED down = nose to the east. Ours (x north, y west, z up): nose along -y.
    q = np.array([math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)])
    R = R_WB_from_px4_quat(q)[0]
    np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(R, rot_z(-math.pi / 2), atol=1e-12)


def test_px4_roll_right_is_our_roll_right():
    # PX4 roll +30 deg about forward: the right side (FRD +y) goes down. Our left side (FLU +y) goes up.
    a = math.radians(30.0)
    q = np.array([math.cos(a / 2), math.sin(a / 2), 0.0, 0.0])
    R = R_WB_from_px4_quat(q)[0]
    np.testing.assert_allclose(R, rot_x(a), atol=1e-12)
    assert (R @ [0.0, 1.0, 0.0])[2] > 0.49  # left wing up


def test_level_px4_attitude_is_level_and_down_is_minus_up():
    R = R_WB_from_px4_quat([1.0, 0.0, 0.0, 0.0])[0]
    np.testing.assert_allclose(R, np.eye(3))
    np.testing.assert_allclose(vec_from_px4([1.0, 2.0, 3.0]), [1.0, -2.0, -3.0])  # NED down 3 m = 3 m below


def test_quaternion_round_trip_on_random_attitudes():
    rng = np.random.default_rng(3)
    Rs = np.array([R_from_rpy(*rng.uniform(-3, 3, 3)) for _ in range(50)])
    q = px4_quat_from_R_WB(Rs)
    np.testing.assert_allclose(R_WB_from_px4_quat(q), Rs, atol=1e-12)
    # and the PX4 quaternion rotates NED vectors: R_NF = D R_WB D
    D = np.diag([1.0, -1.0, -1.0])
    w, x, y, z = q[7]
    R_nf = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    np.testing.assert_allclose(R_nf, D @ Rs[7] @ D, atol=1e-12)


# -- vehicles -------------------------------------------------------------------------------------------------


def _quad_params(km0=0.05, rev=0):
    p = {"CA_ROTOR_COUNT": 4, "CA_R_REV": rev}
    for i, (x, y, km) in enumerate([(0.2, 0.2, km0), (-0.2, -0.2, 0.05), (0.2, -0.2, -0.05), (-0.2, 0.2, -0.05)]):
        p.update({f"CA_ROTOR{i}_PX": x, f"CA_ROTOR{i}_PY": y, f"CA_ROTOR{i}_PZ": 0.0, f"CA_ROTOR{i}_KM": km})
        p.update({f"CA_ROTOR{i}_AX": 0.0, f"CA_ROTOR{i}_AY": 0.0, f"CA_ROTOR{i}_AZ": -1.0})
    return p


def test_px4_quadrotor_signs_follow_px4_effectiveness():
    v, assumed = vehicle_from_px4_params(_quad_params(), "q", "test", {"mass": 1.0, "c_f": 1e-4})
    assert v.actuated_dof == 4
    np.testing.assert_allclose(v.axes_B, [[0, 0, 1]] * 4)  # FRD up (0, 0, -1) is our +z
    np.testing.assert_allclose(v.positions_B[0], [0.2, -0.2, 0.0])  # front right in FRD = front, -y in FLU
    # PX4: moment = ct p x a - ct km a (FRD). Rotor 0 alone: compare in FRD after converting back.
    D = np.diag([1.0, -1.0, -1.0])
    a = np.array([0.0, 0.0, -1.0])
    p = np.array([0.2, 0.2, 0.0])
    m_px4 = np.cross(p, a) - 0.05 * a  # per unit thrust
    m_ours = v.A_nom[3:, 0] / v.c_f
    np.testing.assert_allclose(D @ m_ours, m_px4, atol=1e-12)
    assert math.isclose(v.c_tau, 0.05 * 1e-4)
    assert any(s.startswith("omega_max_hz") for s in assumed) and not any(s.startswith("mass") for s in assumed)


def test_mixed_reversible_rotors_are_refused():
    with pytest.raises(InputError, match="CA_R_REV"):
        vehicle_from_px4_params(_quad_params(rev=0b0011), "q", "test")


def test_unknown_overlay_key_is_refused():
    with pytest.raises(InputError, match="unknown key"):
        vehicle_from_px4_params(_quad_params(), "q", "test", {"mas": 1.0})


def test_omnicopter_airframe_is_fully_actuated(capsys):
    path = _need(OMNICOPTER)
    params = read_airframe_params(path)
    assert params["CA_ROTOR_COUNT"] == 8 and params["CA_R_REV"] == 255
    assert main(["info", "--vehicle", str(path), "--json"]) == 0
    out = capsys.readouterr()
    rep = json.loads(out.out)
    assert rep["rank"] == 6 and rep["n_rotors"] == 8
    assert rep["omega_limits_hz"][0] < 0  # reversible
    assert rep["hover_feasible"] and rep["min_zero_torque_force_N"] > rep["weight_N"]
    assert len(rep["hover_speeds_hz"]) == 8
    # the rotors are at the corners of a cube of half side 0.14435 m
    v = load_vehicle(str(path))
    np.testing.assert_allclose(np.abs(v.positions_B), 0.14435)


def test_assumed_values_are_said_on_stderr(tmp_path, capsys):
    path = _need(OMNICOPTER)
    overlay = tmp_path / "overlay.toml"
    overlay.write_text("mass = 2.0\nc_f = 2e-4\ninertia_diag = [0.02, 0.02, 0.03]\n")
    assert main(["info", "--vehicle", str(path), "--vehicle-overlay", str(overlay), "--json"]) == 0
    out = capsys.readouterr()
    rep = json.loads(out.out)
    assert rep["mass_kg"] == 2.0
    assert "assumed" in out.err and "omega_max_hz" in out.err and "mass =" not in out.err
    np.testing.assert_allclose(rep["A_nom"][2], np.asarray(load_vehicle(str(path), overlay).A_nom[2]))


def test_ulog_vehicle_is_the_logs_quadrotor(capsys):
    path = _need(EVENTS)
    assert main(["info", "--vehicle", str(path), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["rank"] == 4 and rep["n_rotors"] == 4
    v = load_vehicle(str(path))
    np.testing.assert_allclose(v.positions_B[0], [0.1515, -0.245, 0.0], atol=1e-6)  # CA_ROTOR0 (FRD y = +0.245)
    np.testing.assert_allclose(v.spins, [-1, -1, 1, 1])  # KM +0.05 (CCW) -> k = -1


def test_overlay_with_a_preset_is_refused(tmp_path):
    overlay = tmp_path / "o.toml"
    overlay.write_text("mass = 2.0\n")
    with pytest.raises(InputError, match="overlay"):
        load_vehicle("omnirotor", overlay)


# -- ULog in --------------------------------------------------------------------------------------------------


def test_windows_of_the_sample_are_the_steady_descent():
    from omnirotor.px4.flight import read_flight
    from omnirotor.px4.windows import hover_points

    flight = read_flight(_need(EVENTS))
    assert flight.speed_source == "esc_status"
    pts = hover_points(flight)
    assert len(pts.windows) == 1
    w = pts.windows[0]
    # docs/real-robot.md's steady descent, t = 23.3-26.0 s (rotors ~2930 rpm); not the ground, the climb or the
    # 0.5 s hover
    assert 22.8 < w.t0_s < 23.6 and 25.5 < w.t1_s < 26.6
    np.testing.assert_allclose(pts.omega_hz[0], 2930 / 60, rtol=0.02)
    # level flight: the mean up axis within a degree of world up
    assert pts.R_WB[0][2, 2] > math.cos(math.radians(1.0))
    assert any("too slow" in n for n in pts.notes)  # 4 Hz esc_status cannot take the 5 Hz low-pass


def test_stricter_duration_finds_nothing_and_identify_says_so(capsys):
    path = _need(EVENTS)
    from omnirotor.px4.flight import read_flight
    from omnirotor.px4.windows import WindowCriteria, hover_points

    assert hover_points(read_flight(path), WindowCriteria(min_duration_s=5.0)).windows == ()
    assert hover_points(read_flight(path), WindowCriteria(accel_max=0.01)).windows == ()


def test_hover_windows_command_writes_figure_and_csv(tmp_path, capsys):
    path = _need(EVENTS)
    png, csv = tmp_path / "w.png", tmp_path / "p.csv"
    assert main(["hover-windows", str(path), "--out", str(png), "--csv", str(csv)]) == 0
    assert png.stat().st_size > 10_000
    lines = csv.read_text().splitlines()
    assert lines[0] == "qw,qx,qy,qz,omega1_hz,omega2_hz,omega3_hz,omega4_hz"
    assert len(lines) == 2
    # the CSV identifies exactly as the ULog does
    capsys.readouterr()
    assert main(["identify", str(path), "--json"]) == 0
    from_log = json.loads(capsys.readouterr().out)
    assert main(["identify", str(csv), "--vehicle", str(path), "--json"]) == 0
    from_csv = json.loads(capsys.readouterr().out)
    assert from_log["global"]["points"] == 1
    assert math.isclose(
        from_log["global"]["force_residual_rms_N"], from_csv["global"]["force_residual_rms_N"], rel_tol=1e-9
    )


def test_log_with_only_pwm_outputs_maps_them_and_says_how(capsys):
    path = _need(SMALL)  # real hardware: actuator_outputs only, a VTOL without CA_ROTOR* parameters
    assert main(["identify", str(path), "--vehicle", "quadrotor"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    # the mapping is said with the log's own PWM range and thrust-model factor
    mapping = [e for e in err if "actuator_outputs" in e]
    assert len(mapping) == 1 and "PWM range 950-2000 µs" in mapping[0]
    assert "THR_MDL_FAC = 0 (from the log)" in mapping[0]
    # no hover window in the 6 s of outputs it logged: every criterion says what it rejected, then one error
    assert any("landed" in e and "rejected" in e for e in err) and any("--accel-max" in e for e in err)
    assert err[-1].startswith("omnirotor: error:") and "no steady hover window" in err[-1]
    assert sum(e.startswith("omnirotor: error:") for e in err) == 1


def test_log_without_rotor_geometry_says_to_pass_vehicle(capsys):
    path = _need(SMALL)
    for args in (["identify", str(path)], ["info", "--vehicle", str(path)]):
        assert main(args) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "CA_ROTOR_COUNT" in err[0] and "pass --vehicle" in err[0]


def test_pwm_mapping_follows_px4s_thrust_model(tmp_path, capsys):
    from omnirotor.px4.flight import read_flight
    from omnirotor.px4.ulog_writer import write_pwm_log

    path = tmp_path / "pwm.ulg"
    write_pwm_log(path, [1500.0, 1500.0, 1100.0, 2100.0],
                  params={"PWM_MIN": 1000, "PWM_MAX": 2000, "THR_MDL_FAC": 0.5, "PWM_MAIN_MIN3": 1100})  # fmt: skip
    flight = read_flight(path, 4, omega_max_hz=200.0)
    assert flight.speed_source == "actuator_outputs"
    # x = 0.5: thrust = 0.5 x² + 0.5 x = 0.375; output 3 sits at its own minimum (PWM_MAIN_MIN3), 4 above max
    np.testing.assert_allclose(flight.omega_hz.x[0], np.sqrt([0.375, 0.375, 0.0, 1.0]) * 200.0, rtol=1e-6)
    assert "THR_MDL_FAC = 0.5 (from the log)" in flight.notes[0] and "1100-2000 µs" in flight.notes[0]


def test_log_without_attitude_or_speeds_lists_both(tmp_path, capsys):
    from omnirotor.px4.ulog_writer import ULogWriter

    w = ULogWriter()
    bat = np.zeros(10, dtype=[("timestamp", "<u8"), ("voltage_v", "<f4")])
    bat["timestamp"] = np.arange(10) * 1000
    w.add_topic("battery_status", bat)
    path = tmp_path / "empty.ulg"
    w.write(path)
    assert main(["identify", str(path), "--vehicle", "quadrotor"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no attitude" in err[0] and "no rotor speeds" in err[0]


_X500 = """#!/bin/sh
# A quadrotor airframe that relies on PX4's defaults: no CA_ROTORn_PZ, _AX, _AY, _AZ, no CA_R_REV
. ${R}etc/init.d/rc.mc_defaults
param set-default CA_AIRFRAME 0
param set-default CA_ROTOR_COUNT 4
param set-default CA_ROTOR0_PX 0.13
param set-default CA_ROTOR0_PY 0.22
param set-default CA_ROTOR0_KM 0.05
param set-default CA_ROTOR1_PX -0.13
param set-default CA_ROTOR1_PY -0.20
param set-default CA_ROTOR1_KM 0.05
param set-default CA_ROTOR2_PX 0.13
param set-default CA_ROTOR2_PY -0.22
param set-default CA_ROTOR2_KM -0.05
param set-default CA_ROTOR3_PX -0.13
param set-default CA_ROTOR3_PY 0.20
param set-default CA_ROTOR3_KM -0.05
"""


def test_airframe_relying_on_px4_defaults_gets_them(tmp_path, capsys):
    frame = tmp_path / "4001_x500_like"
    frame.write_text(_X500)
    assert main(["info", "--vehicle", str(frame), "--json"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["n_rotors"] == 4
    assert "CA_ROTORn_AZ = -1 (PX4's default) for rotor(s) n = 0-3" in out.err
    assert "CA_ROTORn_PZ = 0 (PX4's default)" in out.err and "CA_R_REV = 0" in out.err
    # the same vehicle as one that states every value
    explicit = tmp_path / "explicit"
    lines = [_X500]
    for i in range(4):
        lines += [f"param set-default CA_ROTOR{i}_{k} {v}" for k, v in (("PZ", 0), ("AX", 0), ("AY", 0), ("AZ", -1))]
    explicit.write_text("\n".join(lines) + "\nparam set-default CA_R_REV 0\n")
    np.testing.assert_array_equal(load_vehicle(str(frame)).A_nom, load_vehicle(str(explicit)).A_nom)


def test_qgroundcontrol_params_file_is_read_as_the_airframe(tmp_path, capsys):
    path = _need(OMNICOPTER)
    params = read_airframe_params(path)
    qgc = tmp_path / "omnicopter.params"
    head = "# Onboard parameters for Vehicle 1\n#\n# Stack: PX4 Pro\n#\n# Vehicle-Id Component-Id Name Value Type\n"
    rows = [f"1\t1\t{k}\t{v:.18g}\t{6 if float(v).is_integer() else 9}" for k, v in sorted(params.items())]
    qgc.write_text(head + "\n".join(rows) + "\n")
    assert read_airframe_params(qgc) == params
    np.testing.assert_array_equal(load_vehicle(str(qgc)).A_nom, load_vehicle(str(path)).A_nom)
    assert main(["info", "--vehicle", str(qgc), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["rank"] == 6


def test_not_a_ulog_is_refused(tmp_path, capsys):
    fake = tmp_path / "fake.ulg"
    fake.write_text("hello")
    assert main(["identify", str(fake), "--vehicle", "omnirotor"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a ULog" in err[0]
    out = tmp_path / "w.png"
    assert main(["hover-windows", str(fake), "--vehicle", "omnirotor", "--out", str(out)]) == 2
    assert not out.exists()


def _write_log(path, with_attitude=True, with_esc=False, with_motors=False):
    from omnirotor.px4.ulog_writer import ULogWriter

    n, ts = 400, np.arange(400, dtype=np.uint64) * 10_000  # 4 s at 100 Hz, level hover
    w = ULogWriter()
    if with_attitude:
        att = np.zeros(n, dtype=[("timestamp", "<u8"), ("q", "<f4", (4,))])
        att["timestamp"], att["q"][:, 0] = ts, 1.0
        w.add_topic("vehicle_attitude", att)
    if with_esc:
        rep = np.dtype([("timestamp", "<u8"), ("esc_rpm", "<i4")])
        esc = np.zeros(n, dtype=[("timestamp", "<u8"), ("esc", rep, (4,))])
        esc["timestamp"], esc["esc"]["esc_rpm"] = ts, 6000
        w.add_topic("esc_status", esc, {"esc": "esc_report"})
    if with_motors:
        am = np.zeros(n, dtype=[("timestamp", "<u8"), ("control", "<f4", (12,))])
        am["timestamp"], am["control"][:, :4], am["control"][:, 4:] = ts, 0.25, np.nan
        w.add_topic("actuator_motors", am)
    w.write(path)


def test_log_without_attitude_is_refused(tmp_path, capsys):
    path = tmp_path / "noatt.ulg"
    _write_log(path, with_attitude=False, with_esc=True)
    assert main(["identify", str(path), "--vehicle", "quadrotor"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no attitude" in err[0] and "vehicle_attitude" in err[0]


def test_speeds_from_actuator_motors_are_mapped_and_said(tmp_path, capsys):
    from omnirotor.px4.flight import read_flight

    path = tmp_path / "motors.ulg"
    _write_log(path, with_motors=True)
    flight = read_flight(path, 4, omega_max_hz=200.0)
    assert flight.speed_source == "actuator_motors"
    np.testing.assert_allclose(flight.omega_hz.x, 100.0)  # sqrt(0.25) x 200 Hz
    png = tmp_path / "w.png"
    assert main(["hover-windows", str(path), "--vehicle", "quadrotor", "--out", str(png)]) == 0
    err = capsys.readouterr().err
    assert "actuator_motors" in err and "sqrt" in err
    assert png.is_file()


def test_esc_rpm_is_hz_times_60(tmp_path):
    from omnirotor.px4.flight import read_flight

    path = tmp_path / "esc.ulg"
    _write_log(path, with_esc=True)
    np.testing.assert_allclose(read_flight(path, 4).omega_hz.x, 100.0)  # 6000 rpm


def test_cli_start_does_not_import_pyulog_or_mcap():
    import subprocess
    import sys

    code = (
        "import sys, omnirotor.cli as c; c._register(); "
        "bad = [m for m in ('pyulog', 'mcap') if m in sys.modules]; print(bad); sys.exit(1 if bad else 0)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=None)
    assert r.returncode == 0, r.stdout + r.stderr


def _synthetic_flight(R_of_t, omega_of_t, duration=12.0, rate_hz=100.0):
    """A Flight sampled at rate_hz: attitude and speeds from functions of time, body rate from the attitude."""
    from omnirotor.px4.flight import Flight, Series
    from omnirotor.so3 import log_so3

    t = np.arange(0.0, duration, 1.0 / rate_hz)
    R = np.array([R_of_t(x) for x in t])
    w = np.array([log_so3(R[k].T @ R[min(k + 1, t.size - 1)]) * rate_hz for k in range(t.size)])
    omega = np.array([omega_of_t(x) for x in t])
    zeros = np.zeros((t.size, 3))
    return Flight(
        "synthetic", Series(t, R), Series(t, omega), "esc_status", None, Series(t, zeros), None, Series(t, w), None, {}
    )


def test_windows_split_at_rotations_and_average_signed_inputs():
    from omnirotor.px4.windows import hover_points

    def angle(x):  # level until 4 s, rotate 20 deg about x in 2 s (0.17 rad/s), hold
        return math.radians(20.0) * min(max((x - 4.0) / 2.0, 0.0), 1.0)

    def speeds(x):
        return np.array([100.0, -60.0, 80.0, 90.0]) if x < 5.0 else np.array([110.0, -40.0, 85.0, 95.0])

    pts = hover_points(_synthetic_flight(lambda x: rot_x(angle(x)), speeds))
    assert len(pts.windows) == 2
    (a, b) = pts.windows
    assert a.t0_s < 0.3 and 3.5 < a.t1_s <= 4.0 and 6.0 <= b.t0_s < 6.5 and b.t1_s > 11.6
    np.testing.assert_allclose(pts.R_WB[1], rot_x(math.radians(20.0)), atol=1e-9)
    np.testing.assert_allclose(pts.u_hz2[0], [1e4, -3600.0, 6400.0, 8100.0], rtol=1e-6)  # |w| w, sign kept
    np.testing.assert_allclose(pts.omega_hz[1], [110.0, -40.0, 85.0, 95.0], rtol=1e-6)


def test_slow_drift_and_speed_steps_cut_windows():
    from omnirotor.px4.windows import WindowCriteria, hover_points

    # a 0.5 deg/s yaw drift stays under the rate limit, so the 3 deg drift limit cuts every 6 s
    drift = _synthetic_flight(lambda x: rot_z(math.radians(0.5 * x)), lambda x: np.full(4, 100.0), duration=13.0)
    pts = hover_points(drift)
    assert len(pts.windows) == 2 and all(5.3 < w.t1_s - w.t0_s < 6.1 for w in pts.windows)
    # a 10 % step of one rotor's speed (21 % of its thrust, 20 % of the mean) is beyond the 10 % spread: two windows
    step = _synthetic_flight(lambda x: np.eye(3), lambda x: np.array([100.0, 100, 100, 110 if x > 6 else 100]))
    pts = hover_points(step, WindowCriteria(cutoff_hz=5.0))
    assert len(pts.windows) == 2 and pts.windows[0].t1_s < 5.85 and pts.windows[1].t0_s > 6.15
    # trimmed past the low-pass's smear of the step, each window averages one level (the Butterworth's ringing
    # beyond 0.2 s leaves 2e-5); without the trim the smear enters ten times more
    np.testing.assert_allclose(pts.u_hz2[:, 3], [100.0**2, 110.0**2], rtol=5e-5)
    untrimmed = hover_points(step, WindowCriteria(trim_s=0.0))
    assert np.abs(untrimmed.u_hz2[:, 3] / [100.0**2, 110.0**2] - 1).max() > 2e-4


def test_no_window_exits_2_in_both_commands_with_each_criterions_rejection(tmp_path, capsys):
    path = _need(EVENTS)
    png = tmp_path / "w.png"
    assert main(["hover-windows", str(path), "--out", str(png), "--min-duration", "5"]) == 2
    err_hw = capsys.readouterr().err.strip().splitlines()
    assert png.is_file()  # the figure shows why; no CSV of no points
    assert main(["identify", str(path), "--min-duration", "5"]) == 2
    err_id = capsys.readouterr().err.strip().splitlines()
    for err in (err_hw, err_id):
        assert err[-1].startswith("omnirotor: error:") and "no steady hover window" in err[-1]
        rejected = {e.split(":")[2].strip() for e in err if "rejected " in e}
        assert rejected == {"--accel-max", "--rate-max", "--spin-fraction", "landed"}, err
        assert any("--min-duration (5 s" in e and "dropped" in e for e in err)


def test_every_criterion_is_an_option_of_both_commands(capsys):
    from omnirotor.px4.criteria import OPTION_OF

    for command in ("hover-windows", "identify"):
        assert main([command, "--help"]) == 0
        text = capsys.readouterr().out
        assert all(opt in text for opt in OPTION_OF.values()), command
    path = _need(EVENTS)
    # a criterion given on the command line reaches the detector: a stricter rate limit removes the window
    assert main(["identify", str(path), "--rate-max", "0.001"]) == 2
    assert "no steady hover window" in capsys.readouterr().err
    assert main(["identify", str(path), "--accel-max", "-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--accel-max" in err[0]


def test_pwm_mapping_ignores_corrupt_parameters(tmp_path):
    from omnirotor.px4.flight import read_flight
    from omnirotor.px4.ulog_writer import write_pwm_log

    path = tmp_path / "bad_params.ulg"
    corrupt = {"PWM_MIN": math.nan, "PWM_MAX": math.inf, "PWM_MAIN_FUNC1": math.inf, "PWM_MAIN_MIN2": math.nan}
    write_pwm_log(path, 1500.0, seconds=0.5, params=corrupt)
    flight = read_flight(path, 4, omega_max_hz=200.0)  # no traceback: the corrupt values count as unset
    np.testing.assert_allclose(flight.omega_hz.x[0], np.sqrt(0.5) * 200.0, rtol=1e-6)  # PX4's 1000-2000 µs
    assert "PWM_MIN, PWM_MAX, THR_MDL_FAC: PX4's default, absent or invalid" in flight.notes[0]
