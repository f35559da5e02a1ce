"""The flight director (omnirotor.fly): modes, live setpoints, failsafes, through the real controller.

Synthetic frame streams (a vehicle at rest at a pose, IMU and motion capture as a plant would send them) drive
the director and the real InteractionController without a transport; one test flies the whole sequence
(arm, take-off, goto, push, land) in the MuJoCo simulator, and one checks that a mission flies exactly what
the in-process closed loop flies.
"""

import dataclasses
import math

import numpy as np
import pytest

from omnirotor.control.admittance import ADMITTANCE_PRESETS
from omnirotor.control.controller import ControllerParams, InteractionController
from omnirotor.control.trajectory import PoseTrajectory, Waypoint
from omnirotor.errors import InputError
from omnirotor.fly.director import FlightDirector
from omnirotor.fly.failsafe import Cause, Failsafe, FailsafeMonitor, LinkAges
from omnirotor.fly.modes import FlightMode
from omnirotor.fly.presets import DEFAULT_FLY_FILE, FlyParams, admittance_presets, load_fly_params
from omnirotor.fly.requests import FlightReply, FlightRequest, FlightStatus, Setpoint
from omnirotor.fly.setpoints import PEAK_ACC, PEAK_SPEED, segment_duration
from omnirotor.messages import ControlStatus, RotorCommand, SensorFrame
from omnirotor.so3 import quat_wxyz_from_R, rot_z
from omnirotor.vehicle import load_vehicle

M = FlightMode
G = 9.81


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("omnirotor")


def _controller(vehicle, **kw):
    return InteractionController(vehicle, ControllerParams(log_capacity=0, **kw))


def _hover_hz(vehicle, R):
    u = vehicle.hover_input(R)
    return np.sign(u) * np.sqrt(np.abs(u))


class Stream:
    """Frames of a vehicle at rest at ``p`` (body) with attitude ``R``: IMU every period, motion capture at 100 Hz.

    The motion capture carries picometre noise: a real one never repeats a pose exactly (the controller's
    supervision takes exact repeats with fresh stamps for a frozen system, issue 26), and the references these
    tests check stay exact to 1e-9.
    """

    def __init__(self, vehicle, p=(0.0, 0.0, 1.0), R=None, dt=1e-3):
        self.p = np.array(p, dtype=float)
        self.R = np.eye(3) if R is None else np.array(R)
        self.dt = dt
        self.k = 0
        self.hz = _hover_hz(vehicle, self.R)
        self.t_imu = 0.0
        self.t_mocap = 0.0
        self.imu_on = True
        self.mocap_on = True
        self._rng = np.random.default_rng(11)

    def next(self):
        t = self.k * self.dt
        self.k += 1
        mocap = self.mocap_on and self.k % 10 == 1
        if self.imu_on:
            self.t_imu = t
        if mocap:
            self.t_mocap = t
        frame = SensorFrame(
            t, self.R.T @ np.array([0.0, 0.0, G]), np.zeros(3), self.hz.copy(), mocap, t,
            self.p + self._rng.normal(0.0, 1e-12, 3) if mocap else None,
            quat_wxyz_from_R(self.R) + self._rng.normal(0.0, 1e-12, 4) if mocap else None,
        )  # fmt: skip
        return frame, LinkAges(t - self.t_imu, t - self.t_mocap)


def _period(d, ctl, frame, ages, outputs=None):
    d.on_frame(frame, ages)
    cmd = ctl.step(frame) if d.wants_step() else None
    out = d.output(cmd)
    assert np.isfinite(out).all()
    assert (out >= ctl.vehicle.omega_min_hz).all() and (out <= ctl.vehicle.omega_max_hz).all()
    if outputs is not None:
        outputs.append(out.copy())
    return out


def _run(d, ctl, stream, seconds, outputs=None, until=None):
    for _ in range(int(round(seconds / stream.dt))):
        frame, ages = stream.next()
        _period(d, ctl, frame, ages, outputs)
        if until is not None and until(d):
            return True
    return False


def _req(d, kind, **kw):
    return d.request(FlightRequest(kind, **kw))


def _armed_in_hover(vehicle, params=None, p=(0.0, 0.0, 1.0)):
    """A director that armed on the stream's pose and took off to hover (the stream keeps the vehicle still)."""
    ctl = _controller(vehicle)
    d = FlightDirector(ctl, params or FlyParams(min_segment_s=0.2))
    s = Stream(vehicle, p)
    _run(d, ctl, s, 0.02)
    assert _req(d, "arm").accepted
    assert _req(d, "takeoff", height_m=0.1).accepted
    assert _run(d, ctl, s, 5.0, until=lambda d: d.mode == M.HOLD)
    return d, ctl, s


# -- parameters and presets ------------------------------------------------------------------------------


def test_default_flight_file_loads_with_the_dataclass_defaults():
    assert load_fly_params() == FlyParams()
    assert load_fly_params(DEFAULT_FLY_FILE, ["max_speed_mps=0.3"]).max_speed_mps == 0.3


@pytest.mark.parametrize(
    "change, text",
    [
        ({"hold_after_s": 3.0}, "land_after_s must be > hold_after_s"),
        ({"workspace_min_m": (0.0, 0.0, 3.0)}, "must be below workspace_max_m"),
        ({"contact_preset": "nope"}, "is not a preset"),
        ({"max_depth_m": -0.1}, "max_depth_m must be a finite number > 0"),
        ({"takeoff_height_m": 3.0}, "takeoff_height_m must be <= max_takeoff_height_m"),
    ],
)
def test_bad_flight_parameters_are_refused(change, text):
    with pytest.raises(InputError, match=text):
        dataclasses.replace(FlyParams(), **change)


def test_flight_file_adds_admittance_presets_and_rejects_unknown_keys(tmp_path):
    path = tmp_path / "fly.toml"
    path.write_text(
        'contact_preset = "soft"\n[admittance_presets.soft]\nstiffness_pos = [15.0, 15.0, 15.0]\n'
        "damping_pos = [9.5, 9.5, 9.5]\n"
    )
    params = load_fly_params(path)
    presets = admittance_presets(params)
    assert presets["soft"].stiffness_pos == (15.0, 15.0, 15.0)
    assert presets["PC"] is ADMITTANCE_PRESETS["PC"]  # Table 2's, written once
    path.write_text("max_speed = 1.0\n")
    with pytest.raises(InputError, match="unknown key"):
        load_fly_params(path)
    path.write_text("[admittance_presets.PC]\nstiffness_pos = [1.0, 1.0, 1.0]\n")
    with pytest.raises(InputError, match="redefine a built-in preset"):
        load_fly_params(path)


@pytest.mark.parametrize("distance, angle, binding", [(1.0, 0.0, "speed"), (0.05, 0.0, "acc"), (0.0, 1.0, "rate")])
def test_segment_durations_keep_the_reference_within_the_limits(distance, angle, binding):
    p = FlyParams(min_segment_s=0.01, max_speed_mps=0.5, max_acc_mps2=1.0, max_rate_dps=30.0)
    T = segment_duration(distance, angle, p)
    R1 = rot_z(angle)
    traj = PoseTrajectory([Waypoint(0.0, np.zeros(3), np.eye(3)), Waypoint(T, [distance, 0.0, 0.0], R1)])
    samples = [traj(t) for t in np.linspace(0.0, T, 2001)]
    v = max(np.linalg.norm(s.v_W) for s in samples)
    a = max(np.linalg.norm(s.a_W) for s in samples)
    w = max(np.linalg.norm(s.omega_W) for s in samples)
    assert v <= p.max_speed_mps * (1 + 1e-9) and a <= p.max_acc_mps2 * (1 + 1e-6)
    assert w <= math.radians(p.max_rate_dps) * (1 + 1e-9)
    reached = {"speed": v / p.max_speed_mps, "acc": a / p.max_acc_mps2, "rate": w / math.radians(p.max_rate_dps)}
    assert reached[binding] == pytest.approx(1.0, rel=1e-3)  # the binding limit is reached, not undercut
    assert PEAK_SPEED == 1.875 and PEAK_ACC == pytest.approx(5.7735, rel=1e-4)


# -- requests and refusals -------------------------------------------------------------------------------


def test_every_transition_is_accepted_or_refused_with_a_reason(vehicle):
    ctl = _controller(vehicle)
    d = FlightDirector(ctl, FlyParams(min_segment_s=0.2))
    s = Stream(vehicle)
    s.mocap_on = False
    _run(d, ctl, s, 0.005)
    r = _req(d, "takeoff")
    assert (r.accepted, r.message) == (False, "disarmed (arm first)")
    assert "refused: takeoff: disarmed (arm first)" == r.line()
    assert "take off first" in _req(d, "push", depth_m=0.05).message
    assert "no valid estimate" in _req(d, "arm").message  # no motion capture yet
    s.mocap_on = True
    _run(d, ctl, s, 0.02)
    r = _req(d, "arm")
    assert r.accepted and (r.mode_from, r.mode) == (M.DISARMED, M.ARMED), r
    assert r.line().startswith("accepted: arm: disarmed -> armed")
    assert _req(d, "arm").message == "already armed"
    assert "disarm instead" in _req(d, "land").message
    assert "must be in (0, 2.0] m" in _req(d, "takeoff", height_m=5.0).message
    assert "outside the workspace" in _req(d, "takeoff", height_m=1.8).message  # 1 m + 1.8 m > 2.5 m
    out = _run(d, ctl, s, 0.01) or d.output(None)
    assert not out.any()  # idle 0 Hz while armed on the ground
    assert _req(d, "takeoff", height_m=0.2).accepted
    assert "still taking off" in _req(d, "push", depth_m=0.05).message
    assert "in flight (mode takeoff)" in _req(d, "disarm").message
    assert _run(d, ctl, s, 5.0, until=lambda d: d.mode == M.HOLD)
    goto = FlightRequest("goto", setpoint=Setpoint((5.0, 0.0, 1.2)))
    assert "outside the workspace" in d.request(goto).message
    r = d.request(FlightRequest("goto", setpoint=Setpoint((0.0, 0.5, 1.2), duration_s=0.01)))
    assert "shorter than the limits allow" in r.message
    assert "depth 0.5 m: must be in [0, 0.15] m" in _req(d, "push", depth_m=0.5).message
    assert "not in contact" in _req(d, "push", depth_m=0.0).message
    assert "unknown preset 'X'; presets: PC, SD, PiH, free" in _req(d, "preset", name="X").message
    r = _req(d, "map", name="piecewise")  # no maps given to this controller (or, before its in-flight API: none)
    assert not r.accepted and ("wrench-map file" in r.message or "cannot switch the map mode" in r.message), r
    assert _req(d, "map", name="nominal").accepted  # the mode flown
    r = d.request({"kind": 0})  # status, as a message with an integer kind
    assert r.accepted and r.message.startswith("mode hold, preset free, map nominal")
    r = d.request({"kind": 42})
    assert not r.accepted and "malformed flight request" in r.message
    r = d.request(object())  # not a request at all: refused, never raised
    assert not r.accepted and "malformed flight request" in r.message
    status = d.status()
    assert status.requests_refused == 17 and status.requests_accepted == 3  # status requests are not counted
    r = _req(d, "disarm", force=True)
    assert r.accepted and r.message == "rotors stopped in flight (forced)" and d.mode == M.DISARMED
    assert not _run(d, ctl, s, 0.002) and not d.output(None).any()


def test_requests_and_status_convert_to_message_fields_and_back():
    req = FlightRequest("goto", setpoint=Setpoint((1.0, 2.0, 3.0), yaw_deg=20.0))
    fields = req.to_fields()
    assert fields["kind"] == 3 and math.isnan(fields["height_m"]) and fields["setpoint"]["q_wb"] == [0.0] * 4
    assert FlightRequest.from_msg(fields) == req
    reply = FlightReply(True, "takeoff", M.ARMED, M.TAKEOFF, "0.50 m in 3.1 s")
    assert FlightReply.from_msg(reply.to_fields()) == reply
    assert reply.line() == "accepted: takeoff: armed -> takeoff (0.50 m in 3.1 s)"
    with pytest.raises(InputError, match="unknown request"):
        FlightRequest("fly")


def test_requests_replies_and_status_go_through_cdr_with_the_shipped_definitions():
    from omnirotor.rosmsg import typestore

    store = typestore()

    def cdr(msg, name):
        return store.deserialize_cdr(
            store.serialize_cdr(msg, f"omnirotor_msgs/msg/{name}"), f"omnirotor_msgs/msg/{name}"
        )

    req = FlightRequest("goto", setpoint=Setpoint((1.0, 2.0, 3.0), q_WB=(1.0, 0.0, 0.0, 0.0), duration_s=2.0))
    assert FlightRequest.from_msg(cdr(req.to_msg(), "FlightRequest")) == req
    push = FlightRequest("push", depth_m=0.1)
    assert FlightRequest.from_msg(cdr(push.to_msg(), "FlightRequest")) == push
    reply = FlightReply(False, "push", M.TRACK, M.TRACK, "not hovering (wait until the goto arrives)")
    assert FlightReply.from_msg(cdr(reply.to_msg(), "FlightReply")) == reply
    status = FlightStatus(
        t=12.5, mode=M.CONTACT, failsafe=int(Failsafe.DEGRADED), cause=int(Cause.MOCAP_STALE), control_status=4,
        preset="PC", map_mode="nominal", depth_m=0.1, target=Setpoint((0.0, 0.5, 1.0), (1.0, 0.0, 0.0, 0.0), None),
        frames=10, steps=9, requests_accepted=3, requests_refused=1, failsafe_events=0, bad_commands=0, message="m",
    )  # fmt: skip
    back = cdr(status.to_msg(), "FlightStatus")
    built = store.types["omnirotor_msgs/msg/FlightStatus"](**status.to_fields())  # as the node publishes it
    assert FlightStatus.from_msg(cdr(built, "FlightStatus")) == status
    assert FlightStatus.from_msg(back) == status
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == (12, 500_000_000)
    assert back.mode == back.MODE_CONTACT and back.cause == back.CAUSE_MOCAP_STALE  # the constants agree
    assert FlightStatus.from_msg(cdr(dataclasses.replace(status, target=None).to_msg(), "FlightStatus")).target is None


# -- flights -----------------------------------------------------------------------------------------------


def test_push_enters_contact_with_table_2_preset_and_leaves_it(vehicle):
    d, ctl, s = _armed_in_hover(vehicle)
    xi_before = ctl.admittance.xi_p_W.copy()
    r = _req(d, "push", depth_m=0.1)
    assert r.accepted and d.mode == M.CONTACT and d.preset == "PC", r
    assert "about 3.0 N at steady state" in r.message  # K_E^p 30 N/m x 0.1 m (SPEC §5.1)
    st = ctl.admittance.state[0]
    np.testing.assert_array_equal(st["stiffness_pos"], ADMITTANCE_PRESETS["PC"].stiffness_pos)
    np.testing.assert_array_equal(st["inv_mass_pos"], [1 / 1.5] * 3)
    np.testing.assert_array_equal(ctl.admittance.xi_p_W, xi_before)  # the switch moves no offset
    anchor = d.status().target
    _run(d, ctl, s, 4.0)  # 0.1 m at 0.05 m/s: 3.75 s
    # The reference went 0.1 m along the tool axis (body +y, the EE offset's direction), then holds there.
    tool_W = np.array([0.0, 1.0, 0.0])
    ref = d.inflight.reference().p_W
    ee0 = s.p + vehicle.p_E_B_array + [0.0, 0.0, 0.1]  # where the take-off went
    np.testing.assert_allclose(ref, ee0 + 0.1 * tool_W, atol=1e-9)
    assert anchor.p_W == pytest.approx(tuple(ee0 + 0.1 * tool_W))
    assert _req(d, "push", depth_m=0.0).accepted and d.mode == M.CONTACT
    assert _run(d, ctl, s, 5.0, until=lambda d: d.mode == M.HOLD)
    assert d.preset == "free"
    np.testing.assert_array_equal(ctl.admittance.state[0]["stiffness_pos"], [100.0] * 3)
    np.testing.assert_allclose(d.inflight.reference().p_W, ee0, atol=1e-9)


def test_land_disarms_on_touchdown_or_after_its_bounded_time(vehicle):
    params = FlyParams(min_segment_s=0.2, touchdown_dwell_s=0.3, land_timeout_s=0.5)
    d, ctl, s = _armed_in_hover(vehicle, params)
    r = _req(d, "land")
    assert r.accepted and d.mode == M.LAND, r
    # The stream stays 0.1 m above the ground height (never touches down): disarmed land_timeout_s after the
    # reference reached the ground.
    s.p[2] += 0.1
    outputs = []
    assert _run(d, ctl, s, 5.0, outputs, until=lambda d: d.mode == M.DISARMED)
    assert d.message == "landed: no touchdown within 0.5 s, disarmed"
    assert d.status().cause & Cause.LAND_TIMEOUT
    assert not d.output(None).any()
    # Again, the vehicle now at the ground height: touchdown after the dwell, long before the timeout.
    d, ctl, s = _armed_in_hover(vehicle, dataclasses.replace(params, land_timeout_s=30.0))
    assert _req(d, "land").accepted
    assert _run(d, ctl, s, 5.0, until=lambda d: d.mode == M.DISARMED)
    assert d.message == "landed: touchdown, disarmed"


def test_touchdown_is_never_judged_from_a_stale_motion_capture_sample(vehicle):
    """Motion capture stops during the landing: its last sample (at the ground height) is no proof of touchdown;
    the landing ends by its bounded time instead, said."""
    params = FlyParams(min_segment_s=0.2, touchdown_dwell_s=0.3, land_timeout_s=1.5)
    d, ctl, s = _armed_in_hover(vehicle, params)
    assert _req(d, "land").accepted
    s.mocap_on = False
    assert _run(d, ctl, s, 5.0, until=lambda d: d.mode == M.DISARMED)
    assert d.message == "landed: no touchdown within 1.5 s, disarmed"


def test_whole_flight_in_the_simulator(vehicle):
    from omnirotor.sim import SimParams, Simulator

    sim = Simulator(vehicle, "free", SimParams().undisturbed(), seed=0)
    ctl = _controller(vehicle)
    params = FlyParams(min_segment_s=0.5, climb_speed_mps=0.5, depth_speed_mps=0.1, touchdown_dwell_s=0.5)
    d = FlightDirector(ctl, params)
    frame = sim.reset()  # hovering at (0, 0, 1.5): the "ground" of this test is where it was armed
    modes, t_mocap = [], -1.0
    target = np.array([0.3, 0.5, 2.0])
    script = {
        3: ("arm", {}),
        4: ("takeoff", {"height_m": 0.3}),
        2500: ("goto", {"setpoint": Setpoint(tuple(target), yaw_deg=20.0)}),
        5500: ("push", {"depth_m": 0.05}),
        7500: ("push", {"depth_m": 0.0}),
        9500: ("land", {}),
    }
    for k in range(16000):
        if frame.mocap_new:
            t_mocap = frame.t
        d.on_frame(frame, LinkAges(0.0, frame.t - t_mocap))
        if k in script:
            kind, kw = script[k]
            r = d.request(FlightRequest(kind, **kw))
            assert r.accepted, r
        out = d.output(ctl.step(frame) if d.wants_step() else None)
        assert np.isfinite(out).all() and np.abs(out).max() <= vehicle.omega_max_hz
        if not modes or modes[-1] != d.mode:
            modes.append(d.mode)
        frame = sim.step(RotorCommand(frame.t, out.copy()))
        if k == 5499:  # the goto arrived: the vehicle is at the target
            np.testing.assert_allclose(sim.truth.p_E_W, target, atol=0.02)
        if d.mode == M.DISARMED and k > 10:
            break
    assert modes == [M.DISARMED, M.ARMED, M.TAKEOFF, M.HOLD, M.TRACK, M.HOLD, M.CONTACT, M.HOLD, M.LAND, M.DISARMED]
    assert d.message == "landed: touchdown, disarmed"
    assert d.status().bad_commands == 0 and d.status().failsafe_events == 0


def test_mission_flies_exactly_what_the_in_process_loop_flies(vehicle):
    from omnirotor.experiments.loop import start_pose_of
    from omnirotor.sim import SimParams, Simulator

    def sim_at(traj):
        sim = Simulator(vehicle, "free", SimParams(), seed=3)
        p0, R0 = start_pose_of(traj, vehicle)
        return sim, sim.reset(p_W=p0, R_WB=R0)

    p0 = np.array([0.0, 0.5, 1.5])
    traj = PoseTrajectory([Waypoint(0.0, p0, np.eye(3)), Waypoint(0.4, p0 + [0.05, 0.0, 0.0], np.eye(3))])
    # The plain loop of omnirotor run (closed_loop.run_closed_loop's Python loop).
    sim, frame = sim_at(traj)
    ctl = _controller(vehicle)
    ctl.reset(frame, traj)
    cmd = ctl.hold_command()
    plain = []
    for _ in range(500):
        plain.append(cmd.omega_hz.copy())
        frame = sim.step(cmd)
        cmd = ctl.step(frame)
    # The same through a director with the mission.
    sim, frame = sim_at(traj)
    ctl = _controller(vehicle)
    d = FlightDirector(ctl, FlyParams(), trajectory=traj)
    flown = []
    for _ in range(500):
        d.on_frame(frame, LinkAges())
        out = d.output(ctl.step(frame) if d.wants_step() else None)
        flown.append(out.copy())
        frame = sim.step(RotorCommand(frame.t, out.copy()))
    np.testing.assert_array_equal(np.array(flown), np.array(plain))
    assert d.mode == M.HOLD and d.preset == "task"  # the trajectory ended at 0.4 s


# -- failsafes -------------------------------------------------------------------------------------------


def test_failsafe_levels_follow_the_ages():
    m = FailsafeMonitor(FlyParams())
    assert m.level(LinkAges(0.020, 0.200)) == (Failsafe.NONE, Cause.NONE)  # at the limits: fresh
    assert m.level(LinkAges(0.0201, 0.0)) == (Failsafe.DEGRADED, Cause.IMU_STALE)
    assert m.level(LinkAges(0.0, 0.2001)) == (Failsafe.DEGRADED, Cause.MOCAP_STALE)
    assert m.level(LinkAges(0.0, 0.71)) == (Failsafe.HOLD, Cause.MOCAP_STALE)
    assert m.level(LinkAges(2.03, 0.3)) == (Failsafe.LAND, Cause.IMU_STALE | Cause.MOCAP_STALE)
    assert m.level(LinkAges(math.nan, 0.0)) == (Failsafe.LAND, Cause.BAD_AGES)
    assert m.level(LinkAges(0.0, 0.0, frames_stopped=True)) == (Failsafe.STOP, Cause.FRAMES_STOPPED)


@pytest.mark.parametrize("link", ["mocap", "imu"])
def test_a_stale_link_degrades_then_holds_then_lands(vehicle, link):
    d, ctl, s = _armed_in_hover(vehicle, FlyParams(min_segment_s=0.2, land_timeout_s=30.0))
    assert _req(d, "goto", setpoint=Setpoint((0.0, 0.5, 1.2))).accepted and d.mode == M.TRACK
    setattr(s, f"{link}_on", False)
    limit = 0.2 if link == "mocap" else 0.02
    cause = Cause.MOCAP_STALE if link == "mocap" else Cause.IMU_STALE
    history = []
    outputs = []
    for _ in range(int((limit + 2.2) / s.dt)):
        frame, ages = s.next()
        _period(d, ctl, frame, ages, outputs)
        st = d.status()
        history.append((frame.t, st.failsafe, st.cause, d.mode))
    t_stale = history[0][0] - 1e-3  # the last sample was the period before the first of this loop

    def first(level):
        return next(t for t, f, _, _ in history if f == level) - t_stale

    assert first(Failsafe.DEGRADED) == pytest.approx(limit, abs=2e-3)
    assert first(Failsafe.HOLD) == pytest.approx(limit + 0.5, abs=2e-3)
    assert first(Failsafe.LAND) == pytest.approx(limit + 2.0, abs=2e-3)
    assert all(c & cause for t, f, c, _ in history if f != Failsafe.NONE)
    modes = [m for t, f, _, m in history]
    assert M.LAND in modes and modes[-1] == M.LAND
    assert d.status().failsafe_events == 2  # hold, land
    # While degraded, new setpoints are refused; land is accepted.
    assert "failsafe land (" in d.message
    assert "only land or disarm" in _req(d, "goto", setpoint=Setpoint((0.0, 0.5, 1.1))).message
    assert np.isfinite(np.array(outputs)).all()
    # The link comes back: the flag clears, the landing goes on (the operator decides).
    setattr(s, f"{link}_on", True)
    _run(d, ctl, s, 0.05)
    assert d.status().failsafe == Failsafe.NONE and d.status().cause == 0 and d.mode == M.LAND


def test_frames_that_stop_stop_the_rotors(vehicle):
    d, ctl, s = _armed_in_hover(vehicle)
    frame, ages = s.next()
    d.on_frame(frame, LinkAges(ages.imu_age_s, ages.mocap_age_s, frames_stopped=True))
    assert not d.wants_step()
    assert not d.output(None).any()
    st = d.status()
    assert st.mode == M.DISARMED and st.failsafe == Failsafe.STOP and st.cause == Cause.FRAMES_STOPPED
    assert st.message == "frames stopped: rotors stopped, disarmed"
    # Frames again: still disarmed, zeros, until armed again.
    _run(d, ctl, s, 0.05)
    assert d.mode == M.DISARMED and not d.output(None).any()
    assert _req(d, "arm").accepted


def test_a_vehicle_outside_the_geofence_is_terminated(vehicle):
    """Motion capture puts the body more than geofence_margin_m outside the workspace box: rotors stopped at once."""
    d, ctl, s = _armed_in_hover(vehicle)
    _run(d, ctl, s, 0.05)
    assert d.mode == M.HOLD
    s.p = np.array([0.0, 0.0, 2.5 + 0.45])  # outside the box, inside the margin: flown on (the estimate follows)
    _run(d, ctl, s, 0.03)
    assert d.mode == M.HOLD and d.armed
    s.p = np.array([0.0, 0.0, 2.5 + 0.55])
    assert _run(d, ctl, s, 0.011, until=lambda d: d.mode == M.DISARMED)  # the next motion-capture sample
    st = d.status()
    assert not d.armed and st.failsafe == Failsafe.STOP and st.cause & Cause.GEOFENCE
    assert st.message.startswith("failsafe stop: the body at (") and "3.050) is more than 0.5 m outside" in st.message
    outs = []
    s.p = np.array([0.0, 0.0, 1.0])  # back inside: stays disarmed, zeros, until armed again
    _run(d, ctl, s, 0.1, outs)
    assert not np.any(outs) and d.mode == M.DISARMED


def test_a_mission_outside_the_workspace_box_is_flown_within_its_own_fence(vehicle):
    """A mission's trajectory is not held to the box: the geofence spans its poses, and still fences beyond them."""
    ctl = _controller(vehicle)
    p_tip = np.array([3.5, 0.0, 1.0]) + np.asarray(vehicle.p_E_B)
    traj = PoseTrajectory([Waypoint(0.0, p_tip, np.eye(3)), Waypoint(5.0, p_tip, np.eye(3))])
    d = FlightDirector(ctl, FlyParams(), trajectory=traj)
    s = Stream(vehicle, (3.5, 0.0, 1.0))
    _run(d, ctl, s, 0.2)
    assert d.mode == M.TRACK and d.armed
    s.p = np.array([3.5 + 0.6, 0.0, 1.0])  # 0.6 m beyond every pose of the mission: outside its fence
    assert _run(d, ctl, s, 0.05, until=lambda d: d.mode == M.DISARMED)
    assert d.status().cause & Cause.GEOFENCE


@pytest.mark.parametrize("offset_m, terminated", [(0.25, False), (0.5, True)])
def test_an_estimate_that_leaves_motion_capture_terminates_the_flight(vehicle, offset_m, terminated):
    """Motion capture moves away from the estimate (the supervision rejects it as a jump: the estimate stays) by
    more than divergence_m for divergence_s: the controller flies on an estimate that left the vehicle; stopped.
    """
    d, ctl, s = _armed_in_hover(vehicle)
    _run(d, ctl, s, 0.05)
    s.p = s.p + np.array([offset_m, 0.0, 0.0])
    outs = []
    stopped = _run(d, ctl, s, 0.3, outs, until=lambda d: d.mode == M.DISARMED)
    st = d.status()
    if not terminated:
        assert not stopped and d.mode == M.HOLD and st.failsafe == Failsafe.NONE
        assert np.all(np.any(np.array(outs), axis=1))
        return
    assert stopped and st.failsafe == Failsafe.STOP and st.cause & Cause.ESTIMATE_DIVERGED
    assert "the position estimate" in st.message and "m from motion capture" in st.message
    assert 0.09 <= len(outs) * s.dt <= 0.13  # divergence_s after the first sample that disagreed (10 ms apart)
    assert not outs[-1].any()
    later = []
    _run(d, ctl, s, 0.05, later)
    assert not np.any(later)


def test_a_plant_that_stops_obeying_disarms_the_director(vehicle):
    """The simulator's offboard-loss failsafe or PX4 out of offboard (the plant status the node reads)."""
    d, ctl, s = _armed_in_hover(vehicle)
    d.plant_failsafe("PX4 left offboard (nav_state 4)")
    st = d.status()
    assert not d.armed and st.failsafe == Failsafe.STOP and st.cause & Cause.PLANT_FAILSAFE
    assert st.message == "the robot stopped obeying (PX4 left offboard (nav_state 4)): disarmed"
    outs = []
    _run(d, ctl, s, 0.05, outs)
    assert not np.any(outs)
    assert _req(d, "arm").accepted  # the operator may arm again (the plant's status disarms it while it lasts)


def test_a_disarmed_director_outputs_zeros_and_says_so(vehicle):
    """The node's invariant (``armed``): after landing or a disarm, only zeros, whatever the controller says."""
    d, ctl, s = _armed_in_hover(vehicle)
    assert d.armed
    assert _req(d, "disarm", force=True).accepted
    assert not d.armed
    frame, ages = s.next()
    d.on_frame(frame, ages)
    assert not d.wants_step()
    assert not d.output(RotorCommand(frame.t, np.full(8, 300.0))).any()


def test_bad_commands_never_reach_the_rotors(vehicle):
    d, ctl, s = _armed_in_hover(vehicle)
    frame, ages = s.next()
    d.on_frame(frame, ages)
    good = d.output(ctl.step(frame)).copy()
    for cmd, cause in [
        (RotorCommand(0.0, np.full(8, np.nan)), Cause.NONFINITE_COMMAND),
        (RotorCommand(0.0, np.zeros(3)), Cause.NONFINITE_COMMAND),
        (None, Cause.NO_COMMAND),
    ]:
        frame, ages = s.next()
        d.on_frame(frame, ages)
        assert d.wants_step()
        np.testing.assert_array_equal(d.output(cmd), good)  # the last good speeds again
        frame, ages = s.next()
        d.on_frame(frame, ages)  # the flag is shown in the next period's status
        assert d.status().cause & cause
        good = d.output(ctl.step(frame)).copy()
    big = RotorCommand(0.0, np.full(8, 1e6), ControlStatus.SATURATED)
    frame, ages = s.next()
    d.on_frame(frame, ages)
    assert (d.output(big) == vehicle.omega_max_hz).all()
    assert d.status().bad_commands == 3 and d.status().control_status == ControlStatus.SATURATED


def test_random_streams_and_requests_never_raise_and_stay_within_limits(vehicle):
    rng = np.random.default_rng(7)
    d, ctl, s = _armed_in_hover(vehicle)
    kinds = ["status", "arm", "takeoff", "goto", "hold", "push", "preset", "map", "land", "disarm"]
    lo, hi = vehicle.omega_min_hz, vehicle.omega_max_hz
    for _ in range(3000):
        frame, ages = s.next()
        if rng.random() < 0.02:  # garbage ages: NaN, huge, stopped
            ages = LinkAges(float(rng.choice([math.nan, 1e9, 0.5])), float(rng.choice([math.nan, 0.0, 3.0])),
                            bool(rng.random() < 0.3))  # fmt: skip
        if rng.random() < 0.01:
            frame = SensorFrame(frame.t, np.full(3, np.nan), frame.imu_gyro_B, frame.rotor_hz)
        d.on_frame(frame, ages)
        if rng.random() < 0.02:
            kind = str(rng.choice(kinds))
            sp = Setpoint(tuple(rng.uniform(-3, 3, 3)), yaw_deg=float(rng.uniform(-400, 400)))
            reply = d.request(
                {"kind": kind, "height_m": float(rng.uniform(-1, 3)), "setpoint": sp.to_fields(),
                 "depth_m": float(rng.choice([math.nan, -1.0, 0.05, 0.2])), "name": str(rng.choice(["PC", "x", ""])),
                 "force": bool(rng.random() < 0.2)}
            )  # fmt: skip
            assert isinstance(reply, FlightReply) and reply.message
            if d.mode == M.DISARMED and rng.random() < 0.5:
                d.request({"kind": "arm"})
        out = d.output(ctl.step(frame) if d.wants_step() else None)
        assert np.isfinite(out).all() and (out >= lo).all() and (out <= hi).all()
        assert isinstance(d.status(), FlightStatus)


def test_a_request_of_an_unknown_kind_or_an_overlong_name_is_one_clear_refusal():
    """``ctl`` requests from any process are checked like the CLI's: an unknown kind index is named, and a name past
    the bound is refused without echoing it (issue 26 item 4)."""
    from omnirotor.fly.requests import MAX_NAME_CHARS, request_from

    with pytest.raises(InputError, match=r"unknown request kind 250 \(0 to 9: status, arm"):
        request_from({"kind": 250})
    with pytest.raises(InputError, match=r"unknown request kind -1 "):
        request_from({"kind": -1})  # not the last request by Python's negative index
    with pytest.raises(InputError, match=f"at most {MAX_NAME_CHARS} characters, got 100000") as exc:
        request_from({"kind": "preset", "name": "x" * 100_000})
    assert len(str(exc.value)) < 200
