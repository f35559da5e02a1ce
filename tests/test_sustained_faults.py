"""Sustained sensor faults end safe and bounded (issue 26 item 1; :mod:`omnirotor.experiments.sustained_faults`).

Every scenario of the table is flown in the free scene's hover by the compiled closed loop (the simulator's
fault schedule injects it) and judged against its bound (the table's module docstring): a frozen or jumping
motion capture is rejected and never flown into, IMU losses and blackouts of up to 0.3 s are ridden through
(back within 5 cm in 2 s), longer ones end in the controller's hold-then-land failsafe near where they began,
clock resets are followed through a re-initialisation, slow biases within range are tracked and beyond it
flagged, random mixes of 30 % bad frames keep the hover within 5 cm; and no command is ever non-finite or
beyond the rotor limits. Bounds the controller does not meet are strict xfails with the measured figure.

Then the pieces on their own: the new injectors on a frame record, the new supervision checks on crafted
frames, the failsafe's landing (the rotors stop at touchdown) and a random mix's draws.
"""

import numpy as np
import pytest

from omnirotor.control import supervisor as sup
from omnirotor.control.estimator import EstimatorParams
from omnirotor.errors import InputError
from omnirotor.experiments import sustained_faults as sf
from omnirotor.experiments.faults import FRAME_GLITCHES, SensorCorruption, install_faults, random_mix
from omnirotor.messages import ESTIMATE_DTYPE, ControlStatus, new_frame
from omnirotor.sim import SimParams, Simulator
from omnirotor.sim import faults as sim_faults
from omnirotor.vehicle import load_vehicle

V = load_vehicle()
DT = 1e-3

# Measured on this tree (compiled closed loop, clean plant, seed 1); each stays a strict xfail until met.
KNOWN: dict[str, str] = {}


def _params(sc: sf.Scenario):
    marks = ()
    if sc.name in KNOWN:
        marks = (pytest.mark.xfail(strict=True, reason=KNOWN[sc.name]),)
    return pytest.param(sc, id=sc.name, marks=marks)


@pytest.mark.parametrize("scenario", [_params(sc) for sc in sf.SCENARIOS])
def test_each_sustained_fault_ends_within_its_bound(scenario):
    run = sf.run_scenario(V, scenario)
    v = sf.verdict(scenario, run)
    assert v["safe"], "a command was non-finite or beyond the rotor limits"
    assert v["flagged"] or scenario.bound == "track", f"not flagged: {v}"
    assert v["ok"], f"{scenario.name}: {v}"


def test_the_scenario_table_covers_every_fault_the_issue_lists():
    names = " | ".join(sc.name for sc in sf.SCENARIOS)
    for what in (
        "mocap frozen", "marker offset 0.2 m", "marker swap", "IMU NaN 50 ms", "IMU NaN 75 ms", "IMU NaN 100 ms",
        "blackout 100 ms", "blackout 200 ms", "blackout 300 ms", "blackout 2 s", "gyro inf 300 frames",
        "gyro NaN 100 frames", "accelerometer NaN 200 frames", "accelerometer growing to 1e300", "clock reset to 0",
        "clock jump back", "accelerometer bias ramp 3 m/s²", "gyro bias ramp 0.5 rad/s", "beyond range",
        "bypass position drifting", "random mix p = 0.3",
    ):  # fmt: skip
        assert what in names, what
    assert sum("random mix" in sc.name for sc in sf.SCENARIOS) >= 3


def test_a_long_blackout_lands_and_stops_the_rotors():
    sc = next(s for s in sf.SCENARIOS if s.name == "blackout 0.5 s")
    run = sf.run_scenario(V, sc)
    sv = run["ctl"].state["supervisor"][0]
    assert sv["fs_mode"] == sup.FS_LANDED
    assert sv["fs_cause"] & sup.CAUSE_IMU  # engaged by the blind IMU
    failsafe = (run["status"] & int(ControlStatus.FAILSAFE)) != 0
    first = int(np.argmax(failsafe))
    assert failsafe[first:].all()  # latched
    t_first = run["t"][first]
    assert sf.T_FAULT_S + 0.3 < t_first <= sf.T_FAULT_S + 0.5  # after 0.35 s blind, not before 0.3 s
    assert np.all(run["omega"][-1] == 0.0)  # touchdown: the rotors stop
    assert run["p_W"][-1, 2] < 0.5  # on the ground (the hover is at 1.5 m)


# -- the injectors --------------------------------------------------------------------------------------------


def _schedule(*faults) -> Simulator:
    sim = Simulator(V, "free", SimParams().undisturbed(), seed=0)
    return install_faults(sim, faults)


def _frame(t: float, x: float) -> np.ndarray:
    f = new_frame(V.n_rotors)
    f["t"] = t
    f["imu"]["acc_B"] = (x, x, x)
    m = f["mocap"]
    m["new"], m["t"], m["p_W"], m["q_WB"] = 1.0, t, (x, 2 * x, 3 * x), (1.0, 0.0, 0.0, 0.0)
    return f


def test_freeze_ramp_and_grow_edit_the_frame_as_documented():
    sim = _schedule(
        SensorCorruption("mocap", 1.0, 0.5, "freeze"),
        SensorCorruption("imu_acc", 1.0, 2.0, "ramp", 3.0, component=0, rise_s=1.0),
        SensorCorruption("imu_acc", 1.0, 2.0, "grow", -1e6, component=2, rise_s=1.0),
    )
    st = sim.faults.state[0]
    out = []
    for t in (0.9, 1.0, 1.25, 1.5, 2.5):
        f = _frame(t, t)
        sim_faults.faults_frame(st, f[0])
        out.append(f)
    assert out[0]["mocap"]["p_W"][0, 0] == 0.9  # before the window: untouched
    for f in out[1:3]:  # frozen on the first sample in the window, stamps fresh
        np.testing.assert_array_equal(f["mocap"]["p_W"][0], (1.0, 2.0, 3.0))
    assert out[2]["mocap"]["t"][0] == 1.25
    assert out[3]["mocap"]["p_W"][0, 0] == 1.5  # the window is over
    acc = [f["imu"]["acc_B"][0] for f in out]
    np.testing.assert_allclose([a[0] - t for a, t in zip(acc, (0.9, 1.0, 1.25, 1.5, 2.5), strict=True)],
                               [0.0, 0.0, 0.75, 1.5, 3.0])  # fmt: skip
    assert acc[1][1] == 1.0  # one component only
    np.testing.assert_allclose(acc[2][2] - 1.25, -(1e6**0.25))  # |m|^(tau / rise_s), with the magnitude's sign
    np.testing.assert_allclose(acc[4][2] - 2.5, -1e6)


def test_a_random_mix_hits_about_its_share_of_frames_with_one_glitch_each():
    glitches = sf.MIX_GLITCHES
    faults = random_mix(glitches, 0.3, 1.0, 1.0, seed=7)
    sim = _schedule(*faults)
    st = sim.faults.state[0]
    hits = np.zeros(len(glitches), int)
    bad = 0
    for k in range(1000):
        t = 1.0 + k * DT
        before = [sim_faults._hits(st["faults"][i], t) for i in range(len(glitches))]
        assert sum(before) <= 1
        hits += before
        bad += any(before)
    assert 250 <= bad <= 350
    assert np.all(hits > 0)  # every glitch drawn
    other = random_mix(glitches, 0.3, 1.0, 1.0, seed=8)
    st2 = _schedule(*other).faults.state[0]
    assert any(
        sim_faults._hits(st["faults"][0], 1.0 + k * DT) != sim_faults._hits(st2["faults"][0], 1.0 + k * DT)
        for k in range(1000)
    )  # another seed, other draws


def test_bad_sustained_corruptions_are_refused():
    with pytest.raises(InputError, match="does not apply to the time"):
        SensorCorruption("time", 1.0, 1.0, "ramp", 1.0)
    with pytest.raises(InputError, match="rise_s"):
        SensorCorruption("imu_acc", 1.0, 1.0, "ramp", 1.0, rise_s=0.0)
    with pytest.raises(InputError, match="probability"):
        SensorCorruption("imu_acc", 1.0, 1.0, random=(1.5, 0, 0, 0, 1))
    with pytest.raises(InputError, match="member must be below"):
        SensorCorruption("imu_acc", 1.0, 1.0, random=(0.3, 0, 0, 1, 1))
    assert len(FRAME_GLITCHES) > len(sf.MIX_GLITCHES) > 0


# -- the supervision's new checks on crafted frames --------------------------------------------------------------


def _supervisor():
    state = np.zeros(1, sup.STATE_DTYPE)
    est = EstimatorParams()
    sup.reset_supervisor(
        state, sup.SupervisorParams(), _hover_frame(1.0, 0.0), dt=DT, acc_range=est.acc_range,
        gyro_range=est.gyro_range, omega_min_hz=V.omega_min_hz, omega_max_hz=V.omega_max_hz, check_state=False,
        check_mocap=True, gravity=9.81, acc_physical=35.7,
    )  # fmt: skip
    estimate = np.zeros(1, ESTIMATE_DTYPE)
    estimate["p_W"][0, 2] = 1.5
    estimate["R_WB"] = np.eye(3)
    return state, estimate


def _hover_frame(t: float, noise: float, dx: float = 0.0) -> np.ndarray:
    f = new_frame(V.n_rotors)
    f["t"] = t
    f["imu"]["acc_B"][0, 2] = 9.81
    m = f["mocap"]
    m["new"], m["t"], m["p_W"], m["q_WB"] = 1.0, t - 0.002, (dx + noise, noise, 1.5), (1.0, 0.0, 0.0, 0.0)
    u = V.hover_input()
    f["rotor_hz"] = np.sign(u) * np.sqrt(np.abs(u))
    return f


def test_a_repeated_motion_capture_sample_is_rejected_as_frozen():
    state, est = _supervisor()
    rec = state[0]
    t = 1.0
    n = sup.SupervisorParams().mocap_frozen_samples
    for k, noise in enumerate([1e-4] + [2e-4] * (n + 2) + [3e-4]):
        t += 0.01
        sup.supervise(rec, _hover_frame(t, noise)[0], est[0])
        frozen = bool(rec["cause"] & sup.CAUSE_MOCAP_FROZEN)
        assert frozen == (n + 1 <= k <= n + 2), k
        assert (rec["clean"]["mocap"]["new"] == 0.0) == frozen


def test_an_offset_motion_capture_stays_rejected_while_it_lasts_and_is_taken_back_after():
    state, est = _supervisor()
    rec = state[0]
    t = 1.0
    causes = []
    for k in range(300):  # 3 s of 100 Hz samples; an offset of 0.5 m from 0.5 s to 2.5 s
        t += 0.01
        dx = 0.5 if 50 <= k < 250 else 0.0
        sup.supervise(rec, _hover_frame(t, 1e-4 * (k % 7), dx)[0], est[0])
        causes.append(int(rec["cause"]))
    jumped = [bool(c & sup.CAUSE_MOCAP_JUMP) for c in causes]
    assert not any(jumped[:50]) and all(jumped[50:250])  # however long it lasts: beyond the drift bound's 1.0 m
    assert not any(jumped[251:])  # agrees with the prediction again
    assert any(c & sup.CAUSE_REINIT for c in causes[250:])  # re-anchored after the long rejection


def test_the_imu_coasts_after_the_hold_and_the_acceleration_beyond_the_rotors_is_rejected():
    state, est = _supervisor()
    rec = state[0]
    assert rec["acc_range"] == pytest.approx(1.5 * 35.7)  # below the sensor's 156.9 m/s²
    t = 1.0
    f = _hover_frame(t + DT, 0.0)
    f["imu"]["acc_B"][0, 2] = 60.0  # within the sensor's range, beyond what the rotors can give
    sup.supervise(rec, f[0], est[0])
    assert rec["cause"] & sup.CAUSE_IMU
    assert rec["clean"]["imu"]["acc_B"][2] == 9.81  # the last good sample ...
    for k in range(2, 12):
        f = _hover_frame(t + k * DT, 0.0)
        f["mocap"]["new"] = 0.0
        f["imu"]["gyro_B"][0, 0] = np.nan
        f["imu"]["acc_B"][0, 2] = 12.0
        sup.supervise(rec, f[0], est[0])
    assert rec["coasting"] == 1  # ... then, after imu_hold_s, the coasting prediction
    np.testing.assert_allclose(rec["clean"]["imu"]["acc_B"], (0.0, 0.0, 9.81))
    np.testing.assert_allclose(rec["clean"]["imu"]["gyro_B"], 0.0)
    assert rec["blind"] == 0  # motion capture came 10 ms ago


def test_the_sign_of_a_motion_capture_quaternion_never_matters():
    """q and -q are the same attitude: neither the supervision nor the UKF's innovation tells them apart."""
    from omnirotor.control._estimator_kernels import mocap_sample_valid

    state, est = _supervisor()
    rec = state[0]
    t = 1.0
    for k in range(40):  # the sign flips every other sample
        t += 0.01
        f = _hover_frame(t, 1e-4 * (k % 5))
        if k % 2:
            f["mocap"]["q_WB"] *= -1.0
        sup.supervise(rec, f[0], est[0])
        assert rec["cause"] == 0, (k, sup.causes_of(int(rec["cause"])))
        assert rec["clean"]["mocap"]["new"] == 1.0
        assert mocap_sample_valid(f["mocap"]["p_W"][0], f["mocap"]["q_WB"][0], 0.1)
