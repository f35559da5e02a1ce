"""The composed controller (without a simulator), its parameters, and the Recorder."""

import dataclasses
import math

import numpy as np
import pytest

from omnirotor.control.admittance import AdmittanceParams
from omnirotor.control.controller import (
    LOG_GROUPS,
    ControllerParams,
    InteractionController,
    load_controller_params,
)
from omnirotor.control.estimator import EstimatorParams
from omnirotor.control.trajectory import PoseTrajectory, Waypoint
from omnirotor.errors import InputError
from omnirotor.messages import ControlStatus, SensorFrame, StateEstimate
from omnirotor.recorder import Recorder
from omnirotor.so3 import R_from_rpy, quat_wxyz_from_R
from omnirotor.vehicle import load_vehicle

DT = 1e-3


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("omnirotor")


def _bypass_params(**kw) -> ControllerParams:
    return ControllerParams(estimator=EstimatorParams(kind="bypass"), log_capacity=5000, **kw)


def _frame(vehicle, t, p_W, R_WB, v_W=(0.0, 0.0, 0.0), a_W=(0.0, 0.0, 0.0), omega_B=(0.0, 0.0, 0.0), rotor_hz=None):
    """A consistent frame: IMU from the state, mocap every step, full state for the bypass estimator."""
    R = np.asarray(R_WB, float)
    a = np.asarray(a_W, float)
    if rotor_hz is None:
        u = vehicle.hover_input(R)
        rotor_hz = np.sign(u) * np.sqrt(np.abs(u))
    state = StateEstimate(
        t=t,
        p_W=np.asarray(p_W, float),
        v_W=np.asarray(v_W, float),
        a_W=a,
        R_WB=R,
        omega_B=np.asarray(omega_B, float),
    )
    return SensorFrame(
        t=t,
        imu_acc_B=R.T @ (a + [0.0, 0.0, vehicle.gravity]),
        imu_gyro_B=np.asarray(omega_B, float),
        rotor_hz=np.asarray(rotor_hz, float),
        mocap_new=True,
        mocap_t=t,
        mocap_p_W=np.asarray(p_W, float),
        mocap_q_WB=quat_wxyz_from_R(R),
        state=state,
    )


def _hover_setup(vehicle, params=None, R=None):
    R = np.eye(3) if R is None else R
    p = np.array([0.0, 0.0, 1.5])
    traj = PoseTrajectory([Waypoint(0.0, p + R @ vehicle.p_E_B_array, R)])
    ctl = InteractionController(vehicle, params or _bypass_params())
    ctl.reset(_frame(vehicle, 0.0, p, R), traj)
    return ctl, p, R


# -- Recorder ---------------------------------------------------------------------------------------------


def test_recorder_groups_columns_and_npz_round_trip(tmp_path):
    rec = Recorder(4, [("t", 1), ("p", ("x", "y", "z")), ("u", 2)])
    assert rec.column_names == ["t", "p.x", "p.y", "p.z", "u.0", "u.1"]
    assert rec.record(0.0, np.array([1.0, 2.0, 3.0]), [4.0, 5.0])
    assert rec.record(0.5, (6.0, 7.0, 8.0), np.array([9.0, 10.0]))
    assert rec.n == 2
    np.testing.assert_array_equal(rec.group("t"), [0.0, 0.5])
    np.testing.assert_array_equal(rec.group("p"), [[1, 2, 3], [6, 7, 8]])
    np.testing.assert_array_equal(rec.column("p.y"), [2.0, 7.0])
    np.testing.assert_array_equal(rec.column("u.1"), [5.0, 10.0])
    assert np.shares_memory(rec.group("p"), rec.data)  # views, not copies
    rec.to_npz(tmp_path / "log.npz")
    back = Recorder.from_npz(tmp_path / "log.npz")
    assert back.column_names == rec.column_names and back.n == 2
    np.testing.assert_array_equal(back.data[: back.n], rec.data[: rec.n])
    with pytest.raises(InputError):
        rec.group("q")
    with pytest.raises(InputError):
        rec.column("p.w")


def test_recorder_bound_sources_and_overflow():
    rec = Recorder(2, [("a", 2), ("b", 1)])
    a, b = np.array([1.0, 2.0]), np.array([3.0])
    rec.bind(a, b)
    assert rec.record_bound()
    a[:] = [4.0, 5.0]
    b[0] = 6.0
    assert rec.record_bound()
    assert not rec.record_bound()  # full: dropped, not raised
    assert rec.dropped == 1 and rec.n == 2
    np.testing.assert_array_equal(rec.data, [[1, 2, 3], [4, 5, 6]])
    rec.ensure_capacity(5)
    assert rec.capacity == 5 and rec.n == 2
    np.testing.assert_array_equal(rec.data[:2], [[1, 2, 3], [4, 5, 6]])
    with pytest.raises(InputError):
        rec.bind(np.zeros(3), b)  # wrong width
    ab = np.array([7.0, 8.0, 9.0])
    rec.bind(ab)  # one array may span several groups
    rec.record_bound()
    np.testing.assert_array_equal(rec.group("a")[-1], [7.0, 8.0])
    assert rec.group("b")[-1] == 9.0
    with pytest.raises(InputError):
        Recorder(3, [("a", 1), ("a", 2)])


# -- parameters -------------------------------------------------------------------------------------------


def test_params_from_toml_and_overrides(tmp_path):
    f = tmp_path / "ctl.toml"
    f.write_text(
        "dt = 0.001\nobserver_input = 'commanded'\n"
        "[pose]\nk_p = [20.0, 21.0, 22.0]\ncompensate_ext_wrench = false\n"
        "[observer]\ncutoff_hz = 5.0\n"
        "[admittance]\nstiffness_pos = [30.0, 30.0, 30.0]\n"
        "[allocation]\nsolver = 'proxsuite'\n"
        "[maps]\nmode = 'nominal'\n"
        "[estimator]\nkind = 'bypass'\n"
    )
    p = load_controller_params(f)
    assert p.pose.k_p == (20.0, 21.0, 22.0) and p.pose.compensate_ext_wrench is False
    assert p.observer.cutoff_hz == 5.0 and p.observer_input == "commanded"
    assert p.admittance.stiffness_pos == (30.0, 30.0, 30.0)
    assert p.allocation.solver == "proxsuite" and p.estimator.kind == "bypass"
    assert p.pose.k_v == ControllerParams().pose.k_v  # untouched keys keep the paper's values
    p2 = load_controller_params(f, ["observer.cutoff_hz=12", "admittance.damping_pos=[1, 2, 3]"])
    assert p2.observer.cutoff_hz == 12.0 and p2.admittance.damping_pos == (1.0, 2.0, 3.0)
    assert load_controller_params(None, ["pose.max_integral=0.2"]).pose.max_integral == 0.2


@pytest.mark.parametrize(
    "text",
    [
        "[pose]\nkp = [1.0, 1.0, 1.0]\n",  # unknown key in a section
        "[posee]\n",  # unknown section
        "dt = -1.0\n",
        "observer_input = 'guessed'\n",
        "[allocation]\nsolver = 'cvxopt'\n",
        "[observer]\ngain_force = [1.0, 1.0]\n",
    ],
)
def test_params_reject_bad_files(tmp_path, text):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(InputError):
        load_controller_params(f)


def test_params_reject_bad_overrides():
    with pytest.raises(InputError):
        load_controller_params(None, ["pose.nope=1"])
    with pytest.raises(InputError):
        load_controller_params(None, ["observer.cutoff_hz"])


# -- the composed step ------------------------------------------------------------------------------------


def test_hover_at_rest_commands_the_hover_speeds(vehicle):
    ctl, p, R = _hover_setup(vehicle)
    for k in range(1, 50):
        cmd = ctl.step(_frame(vehicle, k * DT, p, R))
    u = vehicle.hover_input(R)
    np.testing.assert_allclose(cmd.omega_hz, np.sign(u) * np.sqrt(np.abs(u)), rtol=1e-4)
    assert cmd.status == ControlStatus.OK
    assert cmd.t == pytest.approx(49 * DT)
    np.testing.assert_allclose(ctl.observer.output, 0.0, atol=1e-6)
    assert ctl.log.n == 49


def test_command_arrays_are_fresh_and_runs_are_deterministic(vehicle):
    rng = np.random.default_rng(11)
    frames = []
    p0 = np.array([0.0, 0.0, 1.5])
    for k in range(1, 40):
        frames.append(
            _frame(
                vehicle,
                k * DT,
                p0 + 0.01 * rng.normal(size=3),
                R_from_rpy(*(0.02 * rng.normal(size=3))),
                v_W=0.1 * rng.normal(size=3),
                a_W=0.5 * rng.normal(size=3),
                omega_B=0.1 * rng.normal(size=3),
            )
        )
    outs = []
    for _ in range(2):
        ctl, _, _ = _hover_setup(vehicle)
        cmds = [ctl.step(f) for f in frames]
        assert not any(np.shares_memory(a.omega_hz, b.omega_hz) for a, b in zip(cmds[:-1], cmds[1:], strict=True))
        outs.append(np.array([c.omega_hz for c in cmds]))
    np.testing.assert_array_equal(outs[0], outs[1])


def test_log_records_references_estimates_and_commands(vehicle):
    R = R_from_rpy(0.1, -0.2, 0.5)
    ctl, p, _ = _hover_setup(vehicle, R=R)
    cmd = None
    for k in range(1, 11):
        cmd = ctl.step(_frame(vehicle, k * DT, p + [0.01, 0.0, 0.0], R))
    log = ctl.log
    assert log.n == 10
    assert [g for g, _ in LOG_GROUPS(vehicle.n_rotors)] == log.group_names
    np.testing.assert_allclose(log.group("t"), np.arange(1, 11) * DT)
    np.testing.assert_allclose(log.group("p_W")[-1], p + [0.01, 0.0, 0.0])
    np.testing.assert_allclose(log.group("p_E_W")[-1], p + [0.01, 0.0, 0.0] + R @ vehicle.p_E_B_array)
    np.testing.assert_allclose(log.group("R_WB")[-1].reshape(3, 3), R)
    wp = ctl.trajectory.waypoints[0]
    np.testing.assert_allclose(log.group("p_E_des_W")[-1], wp.p_W)
    np.testing.assert_allclose(log.group("R_E_des")[-1].reshape(3, 3), wp.R_WB)
    np.testing.assert_allclose(log.group("omega_cmd_hz")[-1], cmd.omega_hz)
    np.testing.assert_allclose(log.group("u_hz2")[-1], np.abs(cmd.omega_hz) * cmd.omega_hz, rtol=1e-12)
    # body position error of 1 cm along -x appears in the pose errors
    assert log.group("pose_err")[-1, 0] == pytest.approx(-0.01, abs=1e-9)
    assert np.all(log.group("status") == 0) and np.all(log.group("region") == -1)


def test_bad_sensor_samples_are_flagged_and_never_reach_the_motors(vehicle):
    # The estimator replaces a NaN/inf sample by the last good one; the controller flags it and flies on.
    ctl, p, R = _hover_setup(vehicle)
    good = None
    for k in range(1, 20):
        good = ctl.step(_frame(vehicle, k * DT, p + [0.0, 0.0, -0.02], R))
    for k, bad in enumerate(
        (dict(p_W=[math.nan, 0.0, 1.5]), dict(omega_B=[0.0, math.inf, 0.0]), dict(a_W=[0.0, 0.0, math.nan]))
    ):
        kw = dict(p_W=p, R_WB=R)
        kw.update(bad)
        cmd = ctl.step(_frame(vehicle, (20 + k) * DT, **kw))
        assert cmd.status & ControlStatus.NONFINITE_INPUT
        assert np.all(np.isfinite(cmd.omega_hz))
        np.testing.assert_allclose(cmd.omega_hz, good.omega_hz, atol=1.0)
    cmd = ctl.step(_frame(vehicle, 0.023, p, R, rotor_hz=np.full(8, math.nan)))  # measured speeds broken
    assert cmd.status & ControlStatus.NONFINITE_INPUT
    assert np.all(np.isfinite(cmd.omega_hz))
    cmd = ctl.step(_frame(vehicle, 0.024, p, R))
    assert not cmd.status & ControlStatus.NONFINITE_INPUT
    assert np.all(np.isfinite(ctl.observer.output)) and np.all(np.isfinite(ctl.admittance.xi_p_W))


class _NanEstimator:
    """Stands in for a faulty estimator that lets a NaN through (defence in depth of the controller)."""

    degraded = False
    last_input_rejected = False

    def __init__(self, inner):
        self.inner = inner
        self.poison = False

    def reset(self, frame):
        self.inner.reset(frame)

    def step(self, frame):
        st = self.inner.step(frame)
        if not self.poison:
            return st
        return dataclasses.replace(st, v_W=np.array([0.0, math.nan, 0.0]))


def test_nonfinite_estimate_holds_the_last_safe_command(vehicle):
    ctl, p, R = _hover_setup(vehicle)
    ctl.estimator = _NanEstimator(ctl.estimator)
    good = None
    for k in range(1, 20):
        good = ctl.step(_frame(vehicle, k * DT, p + [0.0, 0.0, -0.02], R))
    xi_before = ctl.admittance.xi_p_W.copy()
    obs_before = ctl.observer.output.copy()
    ctl.estimator.poison = True
    for k in range(20, 25):
        cmd = ctl.step(_frame(vehicle, k * DT, p, R))
        assert cmd.status & ControlStatus.NONFINITE_INPUT
        np.testing.assert_array_equal(cmd.omega_hz, good.omega_hz)
    # No stateful block swallowed the NaN.
    np.testing.assert_array_equal(ctl.admittance.xi_p_W, xi_before)
    np.testing.assert_array_equal(ctl.observer.output, obs_before)
    ctl.estimator.poison = False
    cmd = ctl.step(_frame(vehicle, 25 * DT, p, R))
    assert not cmd.status & ControlStatus.NONFINITE_INPUT
    assert np.all(np.isfinite(cmd.omega_hz))


def test_failed_rotor_is_excluded_and_flagged(vehicle):
    ctl, p, R = _hover_setup(vehicle)
    mask = np.zeros(8, dtype=bool)
    mask[2] = True
    ctl.set_failed_rotors(mask)
    for k in range(1, 5):
        cmd = ctl.step(_frame(vehicle, k * DT, p, R))
    assert cmd.status & ControlStatus.ROTOR_EXCLUDED
    assert cmd.omega_hz[2] == 0.0
    ctl.set_failed_rotors(None)
    cmd = ctl.step(_frame(vehicle, 5 * DT, p, R))
    assert not cmd.status & ControlStatus.ROTOR_EXCLUDED


def test_infeasible_wrench_saturates_within_limits(vehicle):
    # A 3 g acceleration feed-forward cannot be produced: rotors at their limits, flagged, never beyond.
    ctl, p, R = _hover_setup(vehicle, _bypass_params(admittance=AdmittanceParams.preset("PC")))
    traj = PoseTrajectory([Waypoint(0.0, p + vehicle.p_E_B_array, R), Waypoint(0.3, p + [3.0, 0.0, 3.0], R)])
    ctl.reset(_frame(vehicle, 0.0, p, R), traj)
    statuses = []
    for k in range(1, 60):
        cmd = ctl.step(_frame(vehicle, k * DT, p, R))
        statuses.append(cmd.status)
        assert np.all(cmd.omega_hz <= vehicle.omega_max_hz) and np.all(cmd.omega_hz >= vehicle.omega_min_hz)
    assert any(s & ControlStatus.SATURATED for s in statuses)


def test_observer_input_choice(vehicle):
    # With the commanded input the observer ignores the (here deliberately wrong) measured speeds.
    for mode, expect_zero in (("commanded", True), ("measured", False)):
        ctl, p, R = _hover_setup(vehicle, _bypass_params(observer_input=mode))
        u = vehicle.hover_input(R)
        wrong = 1.1 * np.sign(u) * np.sqrt(np.abs(u))
        for k in range(1, 300):
            ctl.step(_frame(vehicle, k * DT, p, R, rotor_hz=wrong))
        assert (np.abs(ctl.observer.f_ext_W).max() < 0.05) == expect_zero, mode


def test_step_before_reset_and_bad_trajectory(vehicle):
    ctl = InteractionController(vehicle, _bypass_params())
    R = np.eye(3)
    with pytest.raises(InputError):
        ctl.step(_frame(vehicle, 0.0, np.zeros(3), R))
    with pytest.raises(InputError):
        ctl.reset(_frame(vehicle, 0.0, np.zeros(3), R), [Waypoint(0.0, np.zeros(3), R)])
    hold = PoseTrajectory([Waypoint(0.0, np.zeros(3), R)])
    with pytest.raises(InputError):
        ctl.reset(_frame(vehicle, 0.0, np.zeros(3), R, rotor_hz=np.zeros(6)), hold)
    # A reset frame without finite rotor speeds starts from the upright hover speeds.
    ctl.reset(_frame(vehicle, 0.0, np.zeros(3), R, rotor_hz=np.full(8, math.nan)), hold)
    u = vehicle.hover_input()
    np.testing.assert_allclose(ctl.hold_command().omega_hz, np.sign(u) * np.sqrt(np.abs(u)))
    assert ctl.hold_command(2.0).t == 2.0


def test_params_validation():
    with pytest.raises(InputError):
        ControllerParams(dt=0.0)
    with pytest.raises(InputError):
        ControllerParams(log_capacity=-1)
    with pytest.raises(InputError):
        ControllerParams(observer_input="both")
    p = dataclasses.replace(ControllerParams(), admittance=AdmittanceParams.preset("PiH"))
    assert p.admittance.stiffness_rot == (2.29,) * 3


def test_the_log_row_is_the_log_record_of_the_blocks_declarations(vehicle):
    """The log's rows are records of ``log_dtype``, whose fields are the blocks' ``log_fields`` (issue 23 item 2):
    the flat row (what exports and ControllerLog carry) is that record's floats, in the groups' order."""
    from omnirotor.blocks import log_dtype

    ctl = InteractionController(vehicle, _bypass_params())
    assert ctl.log_dtype == log_dtype(ctl.log_groups) and ctl.log_dtype.itemsize == 8 * ctl.log.n_signals
    names = [g.name for g in ctl.log_groups]
    assert names == ctl.log.group_names == [name for name, _ in LOG_GROUPS(vehicle.n_rotors)]
    by_name = {g.name: g for g in ctl.log_groups}
    assert by_name["w_ref"].paths == ("pose.f_ref_W", "pose.m_ref_B")  # PoseController.log_fields, renamed
    assert by_name["f_ext_W"].paths == ("observer.f_ext_W",) and by_name["frame_reject"].paths == ("supervisor.cause",)
    p0 = np.array([0.0, 0.0, 1.0])
    ctl.reset(_frame(vehicle, 0.0, p0, np.eye(3)), PoseTrajectory([Waypoint(0.0, p0 + vehicle.p_E_B_array, np.eye(3))]))
    for k in range(1, 6):
        ctl.step(_frame(vehicle, DT * k, p0 + [0.001 * k, 0.0, 0.0], np.eye(3)))
    records = ctl.log.data[: ctl.log.n].view(ctl.log_dtype).reshape(-1)
    w_ref = np.r_[ctl.pose.state["f_ref_W"][0], ctl.pose.state["m_ref_B"][0]]
    np.testing.assert_array_equal(records["w_ref"][-1], w_ref)
    np.testing.assert_array_equal(records["R_E_des"][-1], ctl.desired_ee.R_WB)
    np.testing.assert_array_equal(records["u_hz2"][-1], ctl.log.group("u_hz2")[-1])
    np.testing.assert_array_equal(records["p_W"][:, 0], p0[0] + 0.001 * np.arange(1, 6))
    assert records["t"][-1] == ctl.time == ctl.log.group("t")[-1]
