"""Sensor-frame supervision (issue 14 item 1, :mod:`omnirotor.control.supervisor`).

Each check is shown on the supervision kernel with a crafted frame (its cause, nothing else, and a clean frame
never flagged); then closed-loop hovers (UKF and bypass, the compiled loop) take seeded random draws of the
glitches a real robot sees, injected by the simulator's fault schedule: after any single bad frame the vehicle
is back within 5 cm of its reference within 2 s, bursts are flagged with their cause, and no corruption ever
gives a non-finite or out-of-limit command.
"""

import math

import numpy as np
import pytest

from omnirotor.control import supervisor as sup
from omnirotor.control.admittance import AdmittanceParams
from omnirotor.control.controller import ControllerParams, InteractionController
from omnirotor.control.estimator import EstimatorParams
from omnirotor.control.trajectory import PoseTrajectory, Waypoint
from omnirotor.errors import InputError
from omnirotor.experiments.faults import FRAME_GLITCHES, MocapDropout, SensorCorruption, glitch_fault
from omnirotor.experiments.loop import TaskOptions
from omnirotor.experiments.tasks.fault_hovers import glitch_hover
from omnirotor.messages import ESTIMATE_DTYPE, FRAME_HEAD_DTYPE, ControlStatus, SensorFrame, frame_dtype, new_frame
from omnirotor.sim import Simulator
from omnirotor.vehicle import load_vehicle

V = load_vehicle()
REJECTED = int(ControlStatus.FRAME_REJECTED)
DEGRADED = int(ControlStatus.ESTIMATE_DEGRADED)
DT = 1e-3
TOL_M = 0.05  # the bound: back within 5 cm of the reference ...
RECOVER_S = 2.0  # ... within 2 s


# -- the checks, one by one, on the kernel ------------------------------------------------------------------------


def clean_frame(t: float = 1.0) -> np.ndarray:
    """A plausible frame record at rest in hover: IMU, a motion-capture sample, a bypass state, hover speeds."""
    f = new_frame(V.n_rotors)
    f["t"] = t
    f["imu"]["acc_B"][0, 2] = 9.81
    m = f["mocap"]
    m["new"], m["t"], m["p_W"], m["q_WB"] = 1.0, t - 0.005, (0.0, 0.0, 1.5), (1.0, 0.0, 0.0, 0.0)
    s = f["state"]
    s["valid"] = 1.0
    s["p_W"][0, 2] = 1.5
    s["R_WB"] = np.eye(3)
    u = V.hover_input()
    f["rotor_hz"] = np.sign(u) * np.sqrt(np.abs(u))
    return f


def supervise(rec, frame: np.ndarray, estimate: np.ndarray) -> int:
    """The supervision kernel on a (1,) frame record and a (1,) estimate record."""
    return sup.supervise(rec, frame[0], estimate[0])


def head(frame: np.ndarray) -> bytes:
    """The frame without its rotor speeds, as the bytes of the supervisor's ``clean``."""
    out = np.zeros(1, FRAME_HEAD_DTYPE)
    for name in FRAME_HEAD_DTYPE.names:
        out[name] = frame[name]
    return out.tobytes()


def floats(record) -> np.ndarray:
    """Every entry of a record whose fields are all float64."""
    return np.frombuffer(record.tobytes(), dtype=np.float64)


def supervisor(check_state: bool, check_mocap: bool, params=None):
    """A supervisor record reset on a clean frame at t = 1 s; the estimate it checks against (at rest)."""
    state = np.zeros(1, sup.STATE_DTYPE)
    est = EstimatorParams()
    sup.reset_supervisor(
        state, params or sup.SupervisorParams(), clean_frame(1.0), dt=DT, acc_range=est.acc_range,
        gyro_range=est.gyro_range, omega_min_hz=V.omega_min_hz, omega_max_hz=V.omega_max_hz,
        check_state=check_state, check_mocap=check_mocap,
    )  # fmt: skip
    estimate = np.zeros(1, ESTIMATE_DTYPE)
    estimate["p_W"][0, 2] = 1.5
    estimate["R_WB"] = np.eye(3)
    return state, estimate


def _set(path, i, v):
    """An edit of the frame record: entry ``i`` (None: the scalar field) of the field at ``path``."""

    def edit(f):
        for name in path[:-1]:
            f = f[name]
        if i is None:
            f[path[-1]] = v
        else:
            f[path[-1]][0].flat[i] = v

    return edit


def _rot_scaled(f):
    f["state"]["R_WB"] *= 1.2  # orthogonal directions, not unit: not a rotation


def _reflection(f):
    f["state"]["R_WB"][0, 0, 0] = -1.0  # orthonormal, det -1


def _zero_attitude(f):
    f["state"]["R_WB"] = 0.0


PER_CHECK = [
    ("time NaN", _set(("t",), None, math.nan), sup.CAUSE_TIME),
    ("time repeated", _set(("t",), None, 1.001), sup.CAUSE_TIME),
    ("time a rounding above the last", _set(("t",), None, 1.001 + 1e-15), sup.CAUSE_TIME),
    ("time back 0.5 s", _set(("t",), None, 0.501), sup.CAUSE_TIME),
    ("time +1000 s", _set(("t",), None, 1001.001), sup.CAUSE_TIME),
    ("accelerometer NaN", _set(("imu", "acc_B"), 0, math.nan), sup.CAUSE_IMU),
    ("accelerometer beyond range", _set(("imu", "acc_B"), 1, 1e4), sup.CAUSE_IMU),
    ("gyroscope inf", _set(("imu", "gyro_B"), 2, math.inf), sup.CAUSE_IMU),
    ("mocap position NaN", _set(("mocap", "p_W"), 0, math.nan), sup.CAUSE_MOCAP),
    ("mocap time NaN", _set(("mocap", "t"), None, math.nan), sup.CAUSE_MOCAP),
    ("mocap taken after the frame", _set(("mocap", "t"), None, 1.1), sup.CAUSE_MOCAP),
    ("mocap quaternion not unit", _set(("mocap", "q_WB"), 0, 1.5), sup.CAUSE_MOCAP),
    ("mocap quaternion zero", _set(("mocap", "q_WB"), 0, 0.0), sup.CAUSE_MOCAP),
    ("mocap position 1 km away", _set(("mocap", "p_W"), 0, 1000.0), sup.CAUSE_MOCAP_JUMP),
    ("mocap position 0.2 m away", _set(("mocap", "p_W"), 1, 0.2), sup.CAUSE_MOCAP_JUMP),
    ("state NaN attitude", _set(("state", "R_WB"), 3, math.nan), sup.CAUSE_STATE),
    ("state attitude zeros", _zero_attitude, sup.CAUSE_STATE),
    ("state attitude not orthogonal", _rot_scaled, sup.CAUSE_STATE),
    ("state attitude a reflection", _reflection, sup.CAUSE_STATE),
    ("state position 1 km away", _set(("state", "p_W"), 0, 1000.0), sup.CAUSE_STATE_JUMP),
    ("state velocity jump 3 m/s", _set(("state", "v_W"), 1, 3.0), sup.CAUSE_STATE_JUMP),
    ("rotor 5000 Hz", _set(("rotor_hz",), 3, 5000.0), sup.CAUSE_ROTOR),
    ("rotor -5000 Hz", _set(("rotor_hz",), 0, -5000.0), sup.CAUSE_ROTOR),
    ("rotor NaN", _set(("rotor_hz",), 7, math.nan), sup.CAUSE_ROTOR),
]


@pytest.mark.parametrize("name, edit, cause", PER_CHECK, ids=[c[0] for c in PER_CHECK])
def test_each_check_flags_its_own_cause_and_replaces_the_part(name, edit, cause):
    state, estimate = supervisor(check_state=True, check_mocap=True)
    rec = state[0]
    good = clean_frame(1.001)
    assert supervise(rec, good, estimate) == 0 and rec["cause"] == 0  # a clean frame is never flagged
    assert rec["clean"].tobytes() == head(good)  # and passes unchanged
    bad = clean_frame(1.002)
    edit(bad)
    code = supervise(rec, bad, estimate)
    assert code == cause and rec["cause"] == cause, sup.causes_of(code)
    clean = rec["clean"]
    assert np.all(np.isfinite(floats(clean)))  # what the estimator reads is finite
    if cause == sup.CAUSE_TIME:
        assert clean["t"] == pytest.approx(1.002) and clean["mocap"]["new"] == 0.0
    if cause == sup.CAUSE_IMU:
        assert clean["imu"].tobytes() == good[0]["imu"].tobytes()
    if cause in (sup.CAUSE_MOCAP, sup.CAUSE_MOCAP_JUMP):
        assert clean["mocap"]["new"] == 0.0  # dropped: the UKF predicts
    if cause in (sup.CAUSE_STATE, sup.CAUSE_STATE_JUMP):
        np.testing.assert_array_equal(clean["state"]["p_W"], good[0]["state"]["p_W"])
    counts = dict(zip([n for n, _ in sup.CAUSES], rec["counts"], strict=True))
    assert sum(counts.values()) == 1 and rec["n_rejected"] == 1
    # the next good frame is accepted again (a single bad frame leaves nothing behind)
    assert supervise(rec, clean_frame(1.003), estimate) == 0


def _moving_state(t: float, offset_x: float = 0.0) -> np.ndarray:
    """A clean frame of a vehicle flying at (1, -0.5, 0) m/s since t = 1 s, its bypass velocity offset along x."""
    f = clean_frame(t)
    v = np.array([1.0, -0.5, 0.0])
    f["state"]["p_W"] += v * (t - 1.0)
    f["state"]["v_W"] = v + (offset_x, 0.0, 0.0)
    return f


def test_a_persistent_bypass_velocity_offset_is_found_and_subtracted():
    state, estimate = supervisor(check_state=True, check_mocap=False)
    rec = state[0]
    rec["state_last"]["v_W"] = (1.0, -0.5, 0.0)  # the reset frame flew as the frames below
    window = sup.SupervisorParams().velocity_window_s
    codes, vx = [], []
    for k in range(1, 1001):  # 1 s in motion, consistent: never flagged, velocity passed unchanged
        code = supervise(rec, _moving_state(1.0 + k * DT), estimate)
        codes.append(code)
    assert not any(codes) and rec["clean"]["state"]["v_W"][0] == 1.0
    codes = []
    for k in range(1001, 2001):  # then 1 s with 3 m/s more on the bypass velocity than the vehicle flies
        t = 1.0 + k * DT
        codes.append(supervise(rec, _moving_state(t, 3.0), estimate))
        vx.append(rec["clean"]["state"]["v_W"][0])
    codes, vx = np.array(codes), np.array(vx)
    found = np.flatnonzero(codes & sup.CAUSE_STATE_VELOCITY)
    assert found.size and found[0] * DT <= 2 * window + 2 * DT  # found within two windows
    assert np.all(codes[found[0] + int(2 * window / DT) :] == sup.CAUSE_STATE_VELOCITY)  # and flagged throughout
    np.testing.assert_allclose(vx[found[0] + int(window / DT) :], 1.0, atol=1e-6)  # the vehicle's own velocity
    codes = [supervise(rec, _moving_state(1.0 + k * DT), estimate) for k in range(2001, 2301)]
    assert not any(codes[-100:]) and rec["clean"]["state"]["v_W"][0] == 1.0  # the offset ended: cleared again


def test_a_drifting_bypass_position_is_told_from_a_velocity_offset_by_the_imu():
    """Position and velocity disagree alike whether the velocity is offset or the position drifts; the IMU's
    acceleration (the third vote, SPEC §4.5) says which: here the velocity changed as the IMU says (not at all),
    so the position drifts. It is replaced by the velocity's integral (flagged ``state_drift``, never followed),
    and accepted again once it agrees with that."""
    state, estimate = supervisor(check_state=True, check_mocap=False)
    rec = state[0]
    rec["state_last"]["v_W"] = (1.0, -0.5, 0.0)
    for k in range(1, 201):  # consistent motion first
        assert supervise(rec, _moving_state(1.0 + k * DT), estimate) == 0
    codes, px, truth = [], [], []
    for k in range(201, 701):  # then 0.5 s of a position drifting 1 mm per frame along x (1 m/s)
        t = 1.0 + k * DT
        f = _moving_state(t)
        truth.append(f["state"]["p_W"][0, 0])
        f["state"]["p_W"][0, 0] += 1e-3 * (k - 200)
        codes.append(supervise(rec, f, estimate))
        px.append(rec["clean"]["state"]["p_W"][0])
        assert rec["clean"]["state"]["v_W"][0] == 1.0  # the velocity is believed, not "corrected"
    codes, err = np.array(codes), np.abs(np.array(px) - np.array(truth))
    found = np.flatnonzero(codes & sup.CAUSE_STATE_DRIFT)
    assert found.size and found[0] < 20 and np.all(codes[found[0] :] == sup.CAUSE_STATE_DRIFT)
    assert not np.any(codes & sup.CAUSE_STATE_VELOCITY)
    assert err.max() < 0.02 and err[-1] < 0.02  # what the estimator reads stays by the truth (the drift: 0.5 m)
    codes = [supervise(rec, _moving_state(1.0 + k * DT), estimate) for k in range(701, 801)]
    assert codes[0] == 0 and not any(codes)  # the drift ended: the position agrees again, accepted
    assert rec["clean"]["state"]["p_W"][0] == _moving_state(1.0 + 800 * DT)["state"]["p_W"][0, 0]


def test_a_bypass_velocity_offset_no_longer_flies_the_vehicle_away():
    run = fly([SensorCorruption("state_v", 1.0, 1.0, "spike", 3.0, component=0)], "bypass", 4.5)
    t, err, cause = run["t"], run["err"], run["cause"]
    # believed, 3 m/s for 1 s flew the vehicle 2.7 m away; found, it stays within the glitch tolerance
    assert err.max() < TOL_M
    assert np.count_nonzero(cause[(t >= 1.1) & (t < 2.0)] & sup.CAUSE_STATE_VELOCITY) > 850
    assert err[t > 2.0 + RECOVER_S].max() < TOL_M and not np.any(cause[t > 2.5])


def test_a_clock_that_stepped_is_followed_continuously_and_the_estimator_reinitialised():
    state, estimate = supervisor(check_state=False, check_mocap=True)
    rec = state[0]
    settle = sup.SupervisorParams().clock_settle_frames
    codes, times = [], []
    for k in range(1, settle + 4):  # the clock jumped back 0.5 s before the first of these frames
        f = clean_frame(1.0 + k * DT - 0.5)
        codes.append(supervise(rec, f, estimate))
        times.append(rec["clean"]["t"])
    np.testing.assert_allclose(np.diff(times), DT, rtol=1e-9)  # the controller's time stays continuous
    assert all(c & sup.CAUSE_TIME for c in codes[: settle + 1])  # the frame that jumped, then `settle` more
    assert codes[settle] & sup.CAUSE_CLOCK_RESET and not any(c & sup.CAUSE_CLOCK_RESET for c in codes[:settle])
    # after the reset: motion capture (in the plant's clock) is mapped, and two agreeing samples re-initialise
    assert codes[settle + 1] == 0 and codes[settle + 2] == sup.CAUSE_REINIT | sup.ACT_REINIT
    assert rec["clean"]["mocap"]["t"] == pytest.approx(times[settle + 2] - 0.005)


def test_rotor_speeds_within_the_margin_pass_and_beyond_it_are_rejected():
    state, estimate = supervisor(check_state=False, check_mocap=False)
    rec = state[0]
    margin = sup.SupervisorParams().rotor_margin * max(abs(V.omega_min_hz), abs(V.omega_max_hz))
    f = clean_frame(1.001)
    f["rotor_hz"][0, 0] = V.omega_max_hz + 0.9 * margin
    assert supervise(rec, f, estimate) == 0
    f = clean_frame(1.002)
    f["rotor_hz"][0, 0] = V.omega_max_hz + 1.1 * margin
    assert supervise(rec, f, estimate) == sup.CAUSE_ROTOR


def test_parameters_are_checked():
    with pytest.raises(InputError, match="rotor_margin"):
        sup.SupervisorParams(rotor_margin=-0.1)
    with pytest.raises(InputError, match="clock_settle_frames"):
        sup.SupervisorParams(clock_settle_frames=0)


# -- the API boundary ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("solver", ["active-set", "daqp"])
def test_a_frame_with_the_wrong_rotor_count_is_refused_on_every_path(solver):
    sim = Simulator(V, "free", seed=1)
    params = TaskOptions(estimator="bypass", solver=solver).controller_params(AdmittanceParams.preset("free"))
    ctl = InteractionController(V, params)
    frame = sim.reset()
    p0, R0 = sim.default_start()
    ctl.reset(frame, PoseTrajectory([Waypoint(0.0, p0 + R0 @ V.p_E_B_array, R0)]))
    ctl.step(sim.step(ctl.hold_command()))
    bad = sim.step(ctl.hold_command())
    for hz in (bad.rotor_hz[:7].copy(), np.r_[bad.rotor_hz, 0.0], [100.0] * 7, np.array([100.0]), 100.0):
        with pytest.raises(InputError, match="rotor_hz has shape"):
            ctl.step(SensorFrame(bad.t, bad.imu_acc_B, bad.imu_gyro_B, hz, state=bad.state))
    record = np.zeros(1, frame_dtype(V.n_rotors - 1))
    with pytest.raises(InputError, match="rotor_hz has shape"):  # a frame record of a 7-rotor vehicle
        ctl.step(SensorFrame.from_record(record))
    assert ctl.log.n == 1  # nothing logged, nothing half-done


def test_a_motion_capture_sample_in_the_first_frame_is_checked_against_the_start_pose():
    sim = Simulator(V, "free", seed=1)
    ctl = InteractionController(V, ControllerParams())
    first = sim.reset()
    p0, R0 = sim.default_start()
    ctl.reset(first, PoseTrajectory([Waypoint(0.0, p0 + R0 @ V.p_E_B_array, R0)]))
    f = sim.step(ctl.hold_command())
    f = SensorFrame(f.t, f.imu_acc_B, f.imu_gyro_B, f.rotor_hz, True, f.t - 0.005, p0.copy(), np.r_[1.0, 0, 0, 0])
    cmd = ctl.step(f)
    assert not cmd.status & REJECTED and ctl.log.group("frame_reject")[0] == 0


# -- closed loop: the fuzz ----------------------------------------------------------------------------------------


def fly(faults, estimator: str, duration: float, seed: int = 1) -> dict:
    """Hover under a fault schedule (the compiled loop); every command finite and within the limits."""
    run = glitch_hover(V, estimator, faults, duration, seed)
    omega = run["omega"]
    assert np.all(np.isfinite(omega))
    assert omega.min() >= V.omega_min_hz and omega.max() <= V.omega_max_hz
    assert run["sim"].faults.commands_nonfinite == 0 and run["sim"].faults.commands_out_of_limits == 0
    return run


BIT = dict(sup.CAUSES)
SLOT_S = 2.5  # one glitch per slot: 2 s to recover, checked over the slot's last 0.5 s
N_DRAWN = 12  # glitches per run, drawn from FRAME_GLITCHES


@pytest.mark.parametrize("estimator, seed", [(e, s) for e in ("ukf", "bypass") for s in (14, 114, 214)])
def test_after_any_single_bad_frame_the_vehicle_is_back_within_5_cm_in_2_s(estimator, seed):
    rng = np.random.default_rng(seed)
    column = 6 if estimator == "ukf" else 7  # the cause the estimator in use must report
    pool = [g for g in FRAME_GLITCHES if g[column] is not None]
    drawn = [pool[i] for i in rng.choice(len(pool), N_DRAWN, replace=False)]
    starts = [1.0 + SLOT_S * i + rng.uniform(0.0, 0.01) for i in range(N_DRAWN)]
    run = fly([glitch_fault(g, t0) for g, t0 in zip(drawn, starts, strict=True)], estimator, 1.0 + SLOT_S * N_DRAWN)
    t, err, status, cause = run["t"], run["err"], run["status"], run["cause"]
    assert not np.any(status[t < starts[0]] & REJECTED) and err[t < starts[0]][-500:].max() < TOL_M
    rejecting = (cause & sup.REJECTING) > 0
    assert np.all(status[rejecting] & REJECTED)
    for i, glitch in enumerate(drawn):
        t0, frames = starts[i], glitch[5]
        hit = (t >= t0 - DT) & (t < t0 + (frames + 1) * DT)
        assert np.any(cause[hit] & BIT[glitch[column]]), (glitch, sup.causes_of(int(np.bitwise_or.reduce(cause[hit]))))
        back = (t >= t0 + RECOVER_S) & (t < 1.0 + SLOT_S * (i + 1))
        assert err[back].max() < TOL_M, (glitch, err[back].max())
        assert not np.any(status[back] & (REJECTED | DEGRADED)), glitch  # and nothing is left flagged


@pytest.mark.parametrize("estimator, seed", [(e, s) for e in ("ukf", "bypass") for s in (24, 124, 224)])
def test_bursts_are_flagged_with_their_cause_and_never_reach_the_motors(estimator, seed):
    rng = np.random.default_rng(seed)
    column = 6 if estimator == "ukf" else 7
    pool = [g for g in FRAME_GLITCHES if g[column] is not None]
    n, slot = 6, 3.5
    drawn = [pool[i] for i in rng.choice(len(pool), n, replace=False)]
    lengths = rng.choice([5, 50, 300, 1000], n)  # frames
    starts = [1.0 + slot * i for i in range(n)]
    faults = [glitch_fault(g[:5] + (int(m),) + g[6:], t0) for g, m, t0 in zip(drawn, lengths, starts, strict=True)]
    run = fly(faults, estimator, 1.0 + slot * n)  # fly() asserts every command finite and within the limits
    t, status, cause = run["t"], run["status"], run["cause"]
    for i, glitch in enumerate(drawn):
        window = (t >= starts[i]) & (t < starts[i] + lengths[i] * DT)
        assert np.any(status[window] & REJECTED) and np.any(cause[window] & BIT[glitch[column]]), (glitch, lengths[i])


def test_a_long_state_loss_in_bypass_holds_the_command_flags_the_timeout_and_resumes():
    timeout = sup.SupervisorParams().bypass_hold_timeout_s
    run = fly([SensorCorruption("state", 1.0, 1.0, "nan")], "bypass", 4.5)
    t, status, cause, omega = run["t"], run["status"], run["cause"], run["ctl"].log.group("omega_cmd_hz")
    lost = (t >= 1.0) & (t < 2.0)
    assert np.all(status[lost] & DEGRADED) and np.all(cause[lost] & sup.CAUSE_STATE)
    timed_out = lost & (t > 1.0 + timeout + 2 * DT)
    assert np.all(cause[timed_out] & sup.CAUSE_HOLD_TIMEOUT) and not np.any(
        cause[lost & (t < 1.0 + timeout - 2 * DT)] & sup.CAUSE_HOLD_TIMEOUT
    )
    np.testing.assert_array_equal(omega[lost], np.broadcast_to(omega[lost][0], omega[lost].shape))  # held
    assert not np.any(status[t > 2.5] & (REJECTED | DEGRADED))  # resumed with the next good state
    assert run["err"][t > 2.0 + RECOVER_S].max() < TOL_M


@pytest.mark.parametrize("estimator", ["ukf", "bypass"])
@pytest.mark.parametrize("step_s", [-0.5, 1000.0])
def test_a_clock_step_is_followed_and_the_run_recovers(estimator, step_s):
    run = fly([SensorCorruption("time", 1.0, 10.0, "spike", step_s)], estimator, 4.0)
    t, status, cause = run["t"], run["status"], run["cause"]
    assert np.any(cause & sup.CAUSE_CLOCK_RESET)
    assert np.count_nonzero(cause & sup.CAUSE_TIME) == sup.SupervisorParams().clock_settle_frames + 1
    if estimator == "ukf":
        assert np.any(cause & sup.CAUSE_REINIT)  # from the next good motion-capture samples
    after = t > 1.0 + RECOVER_S
    assert not np.any(status[after] & (REJECTED | DEGRADED))  # not degraded for good
    assert run["err"][after].max() < TOL_M
    log_t = run["ctl"].log.group("t")
    assert np.diff(log_t).max() < 1.5 * DT and np.diff(log_t).min() > 0.5 * DT  # the trajectory time goes on


def test_after_a_long_dropout_the_ukf_reinitialises_from_motion_capture():
    run = fly([MocapDropout(1.0, 1.0)], "ukf", 4.0)
    t, status, cause = run["t"], run["status"], run["cause"]
    assert np.count_nonzero(cause & sup.CAUSE_REINIT) == 1 == run["ctl"].frame_causes["reinit"]
    k = np.flatnonzero(cause & sup.CAUSE_REINIT)[0]
    assert 2.0 <= t[k] < 2.05 and np.all(status[(t > 1.2) & (t < 2.0)] & DEGRADED)
    assert not np.any(status[t > t[k]] & DEGRADED)
    assert run["err"].max() < TOL_M


@pytest.mark.parametrize("estimator", ["ukf", "bypass"])
def test_a_clean_contact_run_is_never_flagged(estimator):
    from omnirotor.experiments.tasks import run_task

    res = run_task("point-contact", TaskOptions(duration_s=6.0, estimator=estimator))
    log = res.controller_log
    assert log.n > 5000
    assert not np.any(log.group("frame_reject")) and not np.any(log.group("status").astype(int) & REJECTED)


def test_supervisor_parameters_come_from_the_controller_toml(tmp_path):
    from omnirotor.control.controller import load_controller_params

    (tmp_path / "c.toml").write_text("[supervisor]\nrotor_margin = 0.2\ndropout_reinit_s = 1.5\n")
    p = load_controller_params(tmp_path / "c.toml")
    assert p.supervisor.rotor_margin == 0.2 and p.supervisor.dropout_reinit_s == 1.5
    assert ControllerParams().supervisor == sup.SupervisorParams()
    with pytest.raises(InputError):
        load_controller_params(None, ["supervisor.max_clock_step_s=-1"])
