"""Set-points in flight, the public methods the flight node calls between steps (issue 23 item 6, issue 24 item 2).

* :meth:`InteractionController.retarget` replaces the trajectory by a minimum-jerk segment from the current
  desired reference: position, velocity and acceleration continuous, the controller's time running on, the
  target reached and held;
* :meth:`InteractionController.set_admittance` changes the admittance set (a Table 2 preset) under a pushing
  force without a jump of the compliant reference;
* :meth:`InteractionController.set_map_mode` switches nominal -> piecewise in flight (the region follows the
  attitude from the next step), and refuses a mode whose maps it was not given, keeping the running one.
"""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from omnirotor.control.admittance import ADMITTANCE_PRESETS
from omnirotor.control.controller import ControllerParams, InteractionController
from omnirotor.control.estimator import EstimatorParams
from omnirotor.control.trajectory import PoseTrajectory, ReferenceSample, Waypoint, segment_sample
from omnirotor.errors import InputError
from omnirotor.sim import SimParams, Simulator
from omnirotor.so3 import rot_z
from omnirotor.vehicle import load_vehicle

sys.path.insert(0, str(Path(__file__).parent / "reference"))
from record_controller import maps as region_maps  # noqa: E402 (a different map in every region)

V = load_vehicle("omnirotor")
DT = 1e-3


def _hover(params: ControllerParams | None = None, maps=None, move=(0.0, 0.0, 0.0), move_s: float = 2.0):
    """A simulator in free space and a bypass controller reset on it, flying from the start (moving by ``move``)."""
    sim = Simulator(V, "free", SimParams().undisturbed(), seed=4)
    p, R = sim.default_start()
    p_E = p + R @ V.p_E_B_array
    traj = PoseTrajectory([Waypoint(0.0, p_E, R), Waypoint(move_s, p_E + np.asarray(move), R)])
    params = params or ControllerParams(estimator=EstimatorParams(kind="bypass"))
    ctl = InteractionController(V, params, maps=maps)
    ctl.reset(sim.reset(p, R), traj)
    return sim, ctl, ctl.hold_command()


def _fly(sim, ctl, cmd, steps: int):
    """``steps`` periods; the desired and compliant EE positions and the controller times of each."""
    des, comp, times = [], [], []
    for _ in range(steps):
        cmd = ctl.step(sim.step(cmd))
        des.append(np.r_[ctl.desired_ee.p_W, ctl.desired_ee.v_W, ctl.desired_ee.a_W])
        comp.append(ctl.compliant_ee.p_W.copy())
        times.append(ctl.time)
        assert np.all(np.isfinite(cmd.omega_hz))
    return cmd, np.array(des), np.array(comp), np.array(times)


def test_retarget_continues_the_reference_and_reaches_the_target():
    sim, ctl, cmd = _hover(move=(0.3, -0.2, 0.1), move_s=1.0)
    cmd, before, _, t_before = _fly(sim, ctl, cmd, 400)  # in the segment: the reference moves and accelerates
    current = ctl.desired_ee.copy()
    assert np.linalg.norm(current.v_W) > 0.1 and np.linalg.norm(current.a_W) > 0.1
    target = current.p_W + np.array([-0.2, 0.1, 0.05])
    R_target = rot_z(0.3) @ current.R_WB
    ctl.retarget(target, R_target, duration_s=1.5)
    # The segment leaves exactly the reference it replaces (position, velocity, acceleration, attitude).
    start = ReferenceSample()
    segment_sample(ctl.state[0]["segment"], ctl.time, start.state[0])
    for name in ("p_W", "v_W", "a_W", "R_WB"):
        np.testing.assert_allclose(getattr(start, name), getattr(current, name), rtol=0, atol=1e-12)
    cmd, after, _, t_after = _fly(sim, ctl, cmd, 2500)
    # The controller's time runs on across the switch; the desired position, velocity and acceleration change
    # from step to step across it no more than they did just before it.
    np.testing.assert_allclose(np.diff(np.r_[t_before, t_after]), DT, rtol=1e-9)
    jumps = np.abs(np.diff(np.r_[before, after], axis=0))
    assert np.all(jumps[399] <= 3.0 * jumps[380:399].max(axis=0) + 1e-12)
    # Reached and held at rest; the vehicle's EE flew there.
    np.testing.assert_allclose(ctl.desired_ee.p_W, target, atol=1e-12)
    np.testing.assert_allclose(ctl.desired_ee.R_WB, R_target, atol=1e-12)
    assert np.all(ctl.desired_ee.v_W == 0.0) and np.all(ctl.desired_ee.a_W == 0.0)
    assert np.linalg.norm(sim.truth.p_E_W - target) < 0.02


def test_retarget_refuses_bad_targets_and_keeps_flying():
    sim, ctl, cmd = _hover()
    cmd, *_ = _fly(sim, ctl, cmd, 10)
    before = ctl.state["segment"].copy()
    for args in (([np.nan, 0.0, 1.0], None, 1.0), ([0.0, 0.0, 1.0], np.eye(3) * 2.0, 1.0), ([0, 0, 1.0], None, 0.0)):
        with pytest.raises(InputError):
            ctl.retarget(*args)
    assert ctl.state["segment"].tobytes() == before.tobytes()  # nothing half-written


def test_an_admittance_preset_in_flight_moves_the_compliant_reference_without_a_jump():
    sim, ctl, cmd = _hover(ControllerParams(estimator=EstimatorParams(kind="bypass")))
    sim.set_external_wrench(np.array([2.0, 0.0, 0.0]))  # a steady push at the EE: the compliant reference yields
    cmd, _, comp0, _ = _fly(sim, ctl, cmd, 1500)
    xi_before = ctl.admittance.xi_p_W.copy()
    assert abs(xi_before[0]) > 5e-3
    ctl.set_admittance("PC")  # Table 2: softer (K 30 N/m against 100)
    assert ctl.params.admittance == ADMITTANCE_PRESETS["PC"]
    np.testing.assert_array_equal(ctl.state[0]["admittance"]["stiffness_pos"], ADMITTANCE_PRESETS["PC"].stiffness_pos)
    np.testing.assert_array_equal(ctl.admittance.xi_p_W, xi_before)  # the offset carries on
    cmd, _, comp1, _ = _fly(sim, ctl, cmd, 3000)
    steps = np.linalg.norm(np.diff(np.r_[comp0, comp1], axis=0), axis=1)
    assert steps[1499] <= 3.0 * steps[1480:1499].max() + 1e-9  # no jump at the switch
    # ... and the softer spring lets the reference yield further under the same push.
    assert abs(ctl.admittance.xi_p_W[0]) > 2.0 * abs(xi_before[0])
    with pytest.raises(InputError, match="unknown admittance preset"):
        ctl.set_admittance("stiff")


def test_the_map_mode_switches_in_flight():
    sim, ctl, cmd = _hover(ControllerParams(estimator=EstimatorParams(kind="bypass")), maps=region_maps())
    cmd, *_ = _fly(sim, ctl, cmd, 200)
    assert ctl.scheduler.region_index == -1 and int(ctl.state[0]["own"]["region"]) == -1
    A_nominal = ctl.scheduler.select(np.eye(3)).copy()
    ctl.set_map_mode("piecewise")
    cmd, *_ = _fly(sim, ctl, cmd, 200)
    assert ctl.params.maps.mode == "piecewise"
    assert ctl.scheduler.region_index >= 0 and int(ctl.state[0]["own"]["region"]) == ctl.scheduler.region_index
    assert not np.array_equal(ctl.scheduler.select(np.eye(3)), A_nominal)  # the region's own map flies now
    region = ctl.log.group("region")
    assert np.all(region[:200] == -1) and np.all(region[200:] >= 0)
    with pytest.raises(InputError, match="global"):  # these maps have no global map: refused, nothing changed
        ctl.set_map_mode("global")
    assert ctl.params.maps.mode == "piecewise" and ctl.scheduler.region_index >= 0
    cmd, *_ = _fly(sim, ctl, cmd, 100)
    assert int(ctl.state[0]["own"]["region"]) >= 0
    ctl.set_map_mode("nominal")
    cmd, *_ = _fly(sim, ctl, cmd, 100)
    assert ctl.scheduler.region_index == -1 and np.all(ctl.log.group("region")[-100:] == -1)
    assert math.isfinite(float(np.abs(cmd.omega_hz).sum()))


def test_a_trajectory_beyond_the_capacity_is_refused_and_the_record_kept():
    """The trajectory capacity is fixed when the controller is built: a reset with more waypoints is refused with
    one line, before anything changed (the record, its type and the flight go on); a controller built with a
    larger ``trajectory_waypoints`` flies the same trajectory whole."""
    from omnirotor.control.trajectory import MIN_CAPACITY_WAYPOINTS, packed_size

    sim, ctl, cmd = _hover()
    state, dtype = ctl.state, ctl.state.dtype
    assert ctl.sizes.trajectory_capacity == packed_size(MIN_CAPACITY_WAYPOINTS)
    p, R = sim.default_start()
    p_E = p + R @ V.p_E_B_array
    n_wp = 2 * MIN_CAPACITY_WAYPOINTS + 1
    traj = PoseTrajectory([Waypoint(0.05 * i, p_E + [0.002 * i, 0.0, 0.0], R) for i in range(n_wp)])
    before = state.tobytes()
    with pytest.raises(InputError, match=f"trajectory of {n_wp} waypoints exceeds the controller's capacity of 32"):
        ctl.reset(sim.reset(p, R), traj)
    assert ctl.state is state and ctl.state.dtype is dtype and state.tobytes() == before  # nothing changed
    _fly(sim, ctl, cmd, 50)  # and the controller flies on with what it had
    # Room for it when the controller is built so.
    big = InteractionController(V, ControllerParams(trajectory_waypoints=n_wp))
    assert big.sizes.trajectory_capacity == packed_size(n_wp)
    big.reset(sim.reset(p, R), traj)
    _, des, _, times = _fly(sim, big, big.hold_command(), 900)
    want = np.array([traj(t).p_W for t in times])
    np.testing.assert_array_equal(des[:, :3], want)  # the same compiled sampling on the whole packed trajectory
    assert des[-1, 0] - des[0, 0] > 0.02


def test_a_trajectory_capacity_too_small_for_a_move_is_one_line_and_exit_2(tmp_path, capsys):
    """The capacity is a controller parameter (``trajectory_waypoints``): one that cannot hold a move (two
    waypoints, the flight node's take-off and set-points) is refused by the CLI in one line, nothing written."""
    from omnirotor.cli import main

    out = tmp_path / "run"
    capsys.readouterr()
    code = main(["run", "hover-validation", "--quick", "--set", "trajectory_waypoints=1", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == ["omnirotor: error: controller trajectory_waypoints must be an integer >= 2, got 1"]
    assert not out.exists()
    with pytest.raises(InputError, match="trajectory_waypoints must be an integer >= 2"):
        ControllerParams(trajectory_waypoints=0)
