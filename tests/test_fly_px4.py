"""The PX4 profile's mapping: speeds <-> ActuatorMotors controls, PX4's thrust model, ESC telemetry, CDR."""

import math

import numpy as np
import pytest

from omnirotor.errors import InputError
from omnirotor.fly.px4 import (
    NUM_CONTROLS,
    PX4_PROFILE,
    actuator_motors_msg,
    controls_from_speeds,
    esc_signal_from_control,
    imu_from_sensor_combined,
    reversible_flags,
    rotor_hz_from_esc_status,
    speeds_from_controls,
)
from omnirotor.rosmsg import msg_type, typestore
from omnirotor.vehicle import load_vehicle


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("omnirotor")


def test_hover_speeds_map_to_their_normalised_thrust_and_back(vehicle):
    w_max = vehicle.omega_max_hz
    u = vehicle.hover_input()
    hover = np.sign(u) * np.sqrt(np.abs(u))  # 143.8 Hz on every rotor (SPEC §1.2)
    c = controls_from_speeds(hover, w_max)
    assert c.shape == (NUM_CONTROLS,) and np.isnan(c[8:]).all()
    # normalised thrust = c_f u / (c_f w_max^2): the thrust the rotor makes over its largest thrust
    np.testing.assert_allclose(c[:8], vehicle.c_f * u / (vehicle.c_f * w_max**2), rtol=1e-14)
    assert c[0] == pytest.approx((143.8 / 220.0) ** 2, rel=1e-3)
    np.testing.assert_allclose(speeds_from_controls(c, w_max, 8), hover, rtol=1e-14)


def test_signed_speeds_round_trip_through_float32_and_cdr(vehicle):
    rng = np.random.default_rng(1)
    w_max = vehicle.omega_max_hz
    w = rng.uniform(-w_max, w_max, 8)
    c = controls_from_speeds(w, w_max)
    assert np.array_equal(np.sign(c[:8]), np.sign(w))  # reversible: the sign is the spin direction
    msg = actuator_motors_msg(c, 1_000_000, reversible_flags(vehicle.omega_min_hz, 8))
    store = typestore()
    name = "px4_msgs/msg/ActuatorMotors"
    back = store.deserialize_cdr(store.serialize_cdr(msg, name), name)
    assert back.reversible_flags == 0xFF and back.timestamp == 1_000_000 and np.isnan(back.control[8:]).all()
    w_back = speeds_from_controls(back.control, w_max, 8)
    np.testing.assert_allclose(w_back, w, rtol=2e-7, atol=1e-4)  # float32 on PX4's side


def test_out_of_range_nonfinite_and_stopped(vehicle):
    w_max = vehicle.omega_max_hz
    out = np.zeros(NUM_CONTROLS)
    c = controls_from_speeds(np.array([300.0, -300.0, np.nan, 0.0]), w_max, out)
    assert c is out and c[0] == 1.0 and c[1] == -1.0 and math.isnan(c[2]) and c[3] == 0.0
    assert np.isnan(controls_from_speeds(np.full(8, 100.0), w_max, stopped=True)).all()
    assert speeds_from_controls(np.full(12, np.nan), w_max, 8).tolist() == [0.0] * 8
    assert reversible_flags(0.0, 4) == 0 and reversible_flags(-220.0, 8) == 0xFF
    with pytest.raises(InputError, match="in \\[-1, 1\\]"):
        actuator_motors_msg(np.full(12, 1.5), 0, 0)


@pytest.mark.parametrize("f", [0.0, 0.3, 0.7, 1.0])
def test_px4_thrust_model_inverse(vehicle, f):
    w_max = vehicle.omega_max_hz
    w = np.linspace(-w_max, w_max, NUM_CONTROLS)
    c = controls_from_speeds(w, w_max)
    x = esc_signal_from_control(c, f)
    # PX4's model: |control| = f x^2 + (1 - f) |x|, the sign kept (reversible)
    np.testing.assert_allclose(f * x * x + (1 - f) * np.abs(x), np.abs(c), atol=1e-12)
    assert np.array_equal(np.sign(x), np.sign(c))
    if f == 1.0:  # THR_MDL_FAC = 1: the ESC receives the commanded speed over full scale
        np.testing.assert_allclose(x, w / w_max, atol=1e-12)


def test_esc_status_gives_signed_speeds_by_motor_number():
    report = msg_type("px4_msgs/msg/EscReport")
    status = msg_type("px4_msgs/msg/EscStatus")
    reports = [report(timestamp=0, esc_errorcount=0, esc_rpm=0, esc_voltage=0.0, esc_current=0.0, esc_temperature=0.0,
                      motor_temperature=0, esc_state=0, actuator_function=0, failures=0, esc_power=0)
               for _ in range(12)]  # fmt: skip
    for k, (motor, rpm) in enumerate([(2, 6000), (1, -8580), (4, 3000)]):
        reports[k].actuator_function = 100 + motor
        reports[k].esc_rpm = rpm
    msg = status(timestamp=0, counter=1, esc_count=3, esc_connectiontype=5, esc_online_flags=0b011,
                 esc_armed_flags=0b111, esc=reports)  # fmt: skip
    hz = rotor_hz_from_esc_status(msg, 4)
    assert hz[0] == -143.0 and hz[1] == 100.0 and np.isnan(hz[2]) and np.isnan(hz[3])  # motor 4's ESC offline


def test_sensor_combined_frd_to_flu():
    msg = msg_type("px4_msgs/msg/SensorCombined")(
        timestamp=0, gyro_rad=np.array([0.1, 0.2, 0.3], dtype=np.float32), gyro_integral_dt=0,
        accelerometer_timestamp_relative=0, accelerometer_m_s2=np.array([0.0, 0.0, -9.81], dtype=np.float32),
        accelerometer_integral_dt=0, accelerometer_clipping=0, gyro_clipping=0, accel_calibration_count=0,
        gyro_calibration_count=0,
    )  # fmt: skip
    acc, gyro = imu_from_sensor_combined(msg)
    np.testing.assert_allclose(acc, [0.0, 0.0, 9.81], rtol=1e-6)  # at rest the accelerometer reads +g up (FLU)
    np.testing.assert_allclose(gyro, [0.1, -0.2, -0.3], rtol=1e-6)


def test_profile_names_px4_topics_and_known_types():
    known = typestore().types
    for route in PX4_PROFILE:
        assert route.px4_topic.startswith("/fmu/in/" if route.to_px4 else "/fmu/out/")
    shipped = {r.msgtype for r in PX4_PROFILE if r.msgtype in known}
    assert {"px4_msgs/msg/SensorCombined", "px4_msgs/msg/EscStatus", "px4_msgs/msg/ActuatorMotors",
            "px4_msgs/msg/VehicleOdometry"} <= shipped  # fmt: skip


def _decoded(name: str, msg):
    """The message through CDR and back with the type store built from the shipped definitions."""
    store = typestore()
    return store.deserialize_cdr(bytes(store.serialize_cdr(msg, name)), name)


def test_offboard_sequence_streams_the_heartbeat_switches_mode_then_arms_then_disarms():
    """Decoded with the type store: heartbeat >= 2 Hz, mode switch after the lead, arm once offboard, disarm."""
    from omnirotor.fly.px4 import (
        PX4_CUSTOM_MAIN_MODE_OFFBOARD,
        VEHICLE_CMD_COMPONENT_ARM_DISARM,
        VEHICLE_CMD_DO_SET_MODE,
        Px4Offboard,
    )

    px4 = Px4Offboard(heartbeat_hz=10.0, lead_s=1.0, retry_s=0.5)
    beats, commands = [], []
    for k in range(5000):  # 5 s at 1 kHz from PX4 time 1 s; the node arms at 1.5 s and disarms at 5 s
        t_us = 1_000_000 + 1000 * k
        armed = 500 <= k < 4000
        if k == 2200:
            px4.px4_state(armed=False, offboard=True)  # PX4 reports the switch
        if k == 2600:
            px4.px4_state(armed=True, offboard=True)  # and the arming
        if k == 4300:
            px4.px4_state(armed=False, offboard=True)  # and the disarming
        for route, msg in px4.period(t_us, armed):
            if route == "offboard_control_mode":
                m = _decoded("px4_msgs/msg/OffboardControlMode", msg)
                assert m.direct_actuator and not (m.position or m.velocity or m.attitude or m.thrust_and_torque)
                beats.append(m.timestamp)
            else:
                commands.append(_decoded("px4_msgs/msg/VehicleCommand", msg))
    beats = np.array(beats)
    assert beats[0] == 1_500_000 and beats[-1] < 5_000_000  # while armed only
    assert np.all(np.diff(beats) == 100_000)  # 10 Hz, PX4 wants >= 2 Hz
    kinds = [(c.command, c.param1, c.param2, c.timestamp) for c in commands]
    modes = [k for k in kinds if k[0] == VEHICLE_CMD_DO_SET_MODE]
    arms = [k for k in kinds if k[0] == VEHICLE_CMD_COMPONENT_ARM_DISARM and k[1] == 1.0]
    disarms = [k for k in kinds if k[0] == VEHICLE_CMD_COMPONENT_ARM_DISARM and k[1] == 0.0]
    assert modes[0] == (VEHICLE_CMD_DO_SET_MODE, 1.0, PX4_CUSTOM_MAIN_MODE_OFFBOARD, 2_500_000)  # after 1 s of beats
    assert len(modes) == 2  # repeated every 0.5 s until PX4 reported offboard (at 3.2 s)
    assert arms[0][3] == 3_200_000 and len(arms) == 1  # armed once PX4 is in offboard; confirmed at 3.6 s
    assert max(m[3] for m in modes) < arms[0][3]
    assert [d[3] for d in disarms] == [5_000_000]  # at once (PX4 time 5 s), confirmed before the retry is due
    assert all(c.from_external and c.target_system == 1 and c.target_component == 1 for c in commands)


def test_offboard_gives_up_a_command_px4_never_confirms_and_says_so():
    from omnirotor.fly.px4 import Px4Offboard

    px4 = Px4Offboard(lead_s=0.0, retry_s=0.1, max_tries=3)
    sent = sum(route == "vehicle_command" for k in range(2000) for route, _ in px4.period(1000 * k, True))
    assert sent == 3 and px4.gave_up == ["mode switch to offboard"]
    with pytest.raises(InputError, match="2 Hz"):
        Px4Offboard(heartbeat_hz=1.0)


# --- the bridge's frame direction, sample by sample (omnirotor.fly.bridge; on real Zenoh in test_px4_bridge) ---


def _imu_msg(t_us: int, gyro=(0.1, 0.2, 0.3), acc=(0.0, 0.0, -9.81)):
    return msg_type("px4_msgs/msg/SensorCombined")(
        timestamp=t_us, gyro_rad=np.array(gyro, dtype=np.float32), gyro_integral_dt=0,
        accelerometer_timestamp_relative=0, accelerometer_m_s2=np.array(acc, dtype=np.float32),
        accelerometer_integral_dt=0, accelerometer_clipping=0, gyro_clipping=0, accel_calibration_count=0,
        gyro_calibration_count=0,
    )  # fmt: skip


def _esc_msg(t_us: int, rpm_by_motor: dict[int, int]):
    report = msg_type("px4_msgs/msg/EscReport")
    reports = [report(timestamp=0, esc_errorcount=0, esc_rpm=0, esc_voltage=0.0, esc_current=0.0, esc_temperature=0.0,
                      motor_temperature=0, esc_state=0, actuator_function=0, failures=0, esc_power=0)
               for _ in range(12)]  # fmt: skip
    for k, (motor, rpm) in enumerate(rpm_by_motor.items()):
        reports[k].actuator_function, reports[k].esc_rpm = 101 + motor, rpm
    return msg_type("px4_msgs/msg/EscStatus")(
        timestamp=t_us, counter=1, esc_count=len(rpm_by_motor), esc_connectiontype=5,
        esc_online_flags=(1 << len(rpm_by_motor)) - 1, esc_armed_flags=0, esc=reports,
    )  # fmt: skip


def _odometry_msg(t_us: int, position_ned, q_frd_ned):
    z3 = np.zeros(3, dtype=np.float32)
    return msg_type("px4_msgs/msg/VehicleOdometry")(
        timestamp=t_us + 3000, timestamp_sample=t_us, pose_frame=1, position=np.array(position_ned, np.float32),
        q=np.array(q_frd_ned, np.float32), velocity_frame=1, velocity=z3, angular_velocity=z3,
        position_variance=z3, orientation_variance=z3, velocity_variance=z3, reset_counter=0, quality=0,
    )  # fmt: skip


def test_odometry_ned_frd_to_our_world_and_body():
    from omnirotor.fly.px4 import pose_from_vehicle_odometry
    from omnirotor.so3 import R_from_quat_wxyz

    s = math.sqrt(0.5)
    # 1 m north, 2 m east, 3 m up; facing west: -90° about NED's down axis
    msg = _odometry_msg(2_500_000, (1.0, 2.0, -3.0), (s, 0.0, 0.0, -s))
    p, q = np.zeros(3), np.zeros(4)
    assert pose_from_vehicle_odometry(msg, p, q) == 2.5  # timestamp_sample [s], not timestamp
    np.testing.assert_allclose(p, [1.0, -2.0, 3.0])  # NWU: north, west, up
    R_WB = R_from_quat_wxyz(q)
    np.testing.assert_allclose(R_WB @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-7)  # the nose points west (NWU's +y)
    np.testing.assert_allclose(R_WB @ [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], atol=1e-7)  # level: body z up


def test_frame_assembler_fills_the_frame_record_from_px4s_samples():
    from omnirotor.fly.bridge import FrameAssembler
    from omnirotor.messages import SensorFrame, frame_dtype

    a = FrameAssembler(4, esc_timeout_s=0.1)
    assert a.record.dtype == frame_dtype(4)  # the node's frame record, no second format
    # no ESC report yet: NaN speeds; no motion capture: the record's convention (new 0, entries 0)
    a.imu(_imu_msg(1_000_000))
    r = a.frame()[0]
    assert r["t"] == 1.0 and np.isnan(r["rotor_hz"]).all() and a.esc_nan_frames == 1
    np.testing.assert_allclose(r["imu"]["acc_B"], [0.0, 0.0, 9.81], rtol=1e-6)
    np.testing.assert_allclose(r["imu"]["gyro_B"], [0.1, -0.2, -0.3], rtol=1e-6)
    assert r["mocap"]["new"] == 0.0 and not r["mocap"]["p_W"].any() and r["state"]["valid"] == 0.0
    # ESC by motor number, rpm / 60; two odometry samples before the next frame: the newer one goes
    a.esc(_esc_msg(1_000_500, {2: 6000, 0: -3000, 3: 60, 1: 120}))
    a.mocap_odometry(_odometry_msg(995_000, (9.0, 9.0, 9.0), (1.0, 0.0, 0.0, 0.0)))
    a.mocap_odometry(_odometry_msg(996_000, (1.0, 2.0, -3.0), (1.0, 0.0, 0.0, 0.0)))
    a.imu(_imu_msg(1_001_000, gyro=(math.nan, 0.0, 0.0)))
    r = a.frame()[0]
    np.testing.assert_array_equal(r["rotor_hz"], [-50.0, 2.0, 100.0, 1.0])
    assert r["mocap"]["new"] == 1.0 and r["mocap"]["t"] == 0.996 and a.mocap_replaced == 1
    np.testing.assert_allclose(r["mocap"]["p_W"], [1.0, -2.0, 3.0])
    assert np.isnan(r["imu"]["gyro_B"][0])  # passed as it is: the node's supervision judges it
    f = SensorFrame.from_record(a.record)
    assert f.mocap_new and f.mocap_t == 0.996 and f.state is None
    # the sample is carried once; the ESC report goes stale past its timeout (PX4's time)
    a.imu(_imu_msg(1_100_400))
    r = a.frame()[0]
    assert r["mocap"]["new"] == 0.0 and r["rotor_hz"][2] == 100.0
    assert r["mocap"]["t"] == 0.0 and not r["mocap"]["p_W"].any() and not r["mocap"]["q_WB"].any()  # zeroed
    a.imu(_imu_msg(1_100_600))
    assert np.isnan(a.frame()[0]["rotor_hz"]).all() and a.esc_nan_frames == 2
    # a pose (PoseStamped: our frames) is taken as it is
    pose = msg_type("geometry_msgs/msg/PoseStamped")(
        header=msg_type("std_msgs/msg/Header")(stamp=msg_type("builtin_interfaces/msg/Time")(sec=0, nanosec=0),
                                               frame_id="world"),
        pose=msg_type("geometry_msgs/msg/Pose")(
            position=msg_type("geometry_msgs/msg/Point")(x=0.3, y=-0.2, z=0.12),
            orientation=msg_type("geometry_msgs/msg/Quaternion")(x=0.0, y=0.0, z=0.5, w=math.sqrt(0.75)),
        ),
    )  # fmt: skip
    a.mocap_pose(pose, 1.1)
    a.imu(_imu_msg(1_101_000))
    r = a.frame()[0]
    np.testing.assert_array_equal(r["mocap"]["p_W"], [0.3, -0.2, 0.12])
    np.testing.assert_array_equal(r["mocap"]["q_WB"], [math.sqrt(0.75), 0.0, 0.0, 0.5])
    assert r["mocap"]["t"] == 1.1 and a.frames == 5 and a.mocap_samples == 2


def test_imu_rate_is_the_median_interval_of_px4s_stamps():
    from omnirotor.fly.bridge import imu_rate_hz

    t = np.arange(0, 1_000_001, 1000)
    assert imu_rate_hz(t) == 1000.0
    assert imu_rate_hz(np.delete(t, np.s_[100:400:3])) == 1000.0  # samples lost on the way do not change it
    assert imu_rate_hz(np.arange(0, 1_000_001, 4000)) == 250.0
    assert math.isnan(imu_rate_hz(np.array([5]))) and math.isnan(imu_rate_hz(np.array([5, 5])))


def _feed(watch, t_us: float, hz: float, seconds: float, arrival_s: float) -> tuple[float, float]:
    """``seconds`` of IMU samples at ``hz`` into ``watch`` (arrivals on time); the next stamp and arrival."""
    for _ in range(round(seconds * hz)):
        watch.sample(round(t_us), arrival_s)
        t_us += 1e6 / hz
        arrival_s += 1.0 / hz
    return t_us, arrival_s


def test_the_imu_rate_watch_says_a_rate_off_for_longer_than_its_window_once_and_its_recovery():
    from omnirotor.fly.bridge import ImuRateWatch

    said: list[str] = []
    w = ImuRateWatch(1000.0, 0.05, window_s=1.0, gap_s=0.02, name="IMU", say=said.append)
    t, arr = _feed(w, 5e6, 1000.0, 3.0, 100.0)
    assert w.rate_hz == pytest.approx(1000.0) and not said and w.episodes == 0
    # 960 Hz (4 % off): within the tolerance, nothing said
    t, arr = _feed(w, t, 960.0, 3.0, arr)
    assert w.rate_hz == pytest.approx(960.0, rel=1e-3) and not said  # PX4's stamps are whole µs
    # 800 Hz for 0.8 s: off in the window for less than a window, not an episode
    t, arr = _feed(w, t, 1000.0, 2.0, arr)
    t, arr = _feed(w, t, 800.0, 0.8, arr)
    t, arr = _feed(w, t, 1000.0, 2.0, arr)
    assert not said and w.episodes == 0 and w.off_s == 0.0 and w.worst_hz == 800.0
    # 800 Hz for 3 s: said once, while it lasts; then the recovery once
    t, arr = _feed(w, t, 800.0, 3.0, arr)
    assert len(said) == 1 and "IMU at 800.0 Hz for more than 1 s" in said[0] and "frames go on" in said[0]
    assert w.episodes == 1 and 0.5 < w.off_s < 3.0  # an open episode counts up to now
    t, arr = _feed(w, t, 1000.0, 2.0, arr)
    assert len(said) == 2 and said[1].startswith("IMU back at 1000.0 Hz after ")
    assert w.episodes == 1 and 2.0 < w.off_s < 3.5  # closed: from the first judgement off to the first within
    # too fast is off too (PX4 publishing at 2 kHz)
    t, arr = _feed(w, t, 2000.0, 2.5, arr)
    assert w.episodes == 2 and "IMU at 2000.0 Hz" in said[2] and w.worst_hz == pytest.approx(2000.0)
    assert w.gaps == 0  # regular arrivals throughout
    s = w.summary()
    assert s["off_episodes"] == 2 and s["gaps"] == 0 and s["worst_gap_ms"] == 0.0 and s["rate_hz"] == 2000.0


def test_the_imu_rate_watch_ignores_lost_samples_and_counts_gaps_with_the_worst():
    from omnirotor.fly.bridge import ImuRateWatch

    said: list[str] = []
    w = ImuRateWatch(1000.0, 0.05, window_s=1.0, gap_s=0.02, name="IMU", say=said.append)
    t, arr = 0.0, 10.0
    for k in range(5000):  # every third sample lost on the way for 5 s: the median interval stays 1 ms
        if k % 3 != 1:
            w.sample(round(t), arr)
        t, arr = t + 1000.0, arr + 1e-3
    assert w.rate_hz == pytest.approx(1000.0) and w.episodes == 0 and w.gaps == 0
    # no sample for 15 ms (not a gap), then 50 ms and 120 ms (PX4's stamps and the arrivals both jump)
    for pause_ms in (15, 50, 120):
        t, arr = t + 1000.0 * pause_ms, arr + 1e-3 * pause_ms
        t, arr = _feed(w, t, 1000.0, 0.5, arr)
    assert w.gaps == 2 and w.worst_gap_s == pytest.approx(0.121)
    assert len(said) == 1 and said[0].startswith("IMU: no sample for 51 ms")  # the first gap said, all counted
    # arrivals bunched by the transport (PX4's stamps regular): a gap at the bridge all the same
    w.sample(round(t), arr + 0.03)
    assert w.gaps == 3 and w.episodes == 0
    # NaN arrivals (the start's measurement) are never gaps; PX4's clock going back starts a new window, said
    w.sample(round(t + 1000), math.nan)
    assert w.gaps == 3
    _feed(w, 1000.0, 1000.0, 0.5, math.nan)
    assert w.span_s == pytest.approx(0.499) and w.window_us().size == 500
    assert len(said) == 2 and said[1].startswith("IMU: time stamps went back ") and "judged afresh" in said[1]


def test_the_imu_rate_watchs_diagnostic_level_follows_the_rate_and_the_gaps():
    from omnirotor.fly.bridge import ImuRateWatch
    from omnirotor.rosmsg import msg_type

    S = msg_type("diagnostic_msgs/msg/DiagnosticStatus")  # noqa: N806
    w = ImuRateWatch(1000.0, 0.05, window_s=1.0)
    assert w.diagnostic(0.0) == (S.STALE, "no sample yet")
    t, arr = _feed(w, 0.0, 1000.0, 2.0, 0.0)
    assert w.diagnostic(arr) == (S.OK, "1000.0 Hz")
    assert w.diagnostic(arr + 0.6) == (S.STALE, "no sample for 0.6 s")
    t, arr = _feed(w, t + 50_000, 1000.0, 0.5, arr + 0.05)  # a 51 ms gap: WARN once, at the next report
    level, message = w.diagnostic(arr)
    assert level == S.WARN and "1 gap(s) over 20 ms" in message and w.diagnostic(arr) == (S.OK, "1000.0 Hz")
    t, arr = _feed(w, t, 800.0, 2.0, arr)  # an episode: WARN while it lasts
    level, message = w.diagnostic(arr)
    assert level == S.WARN and message.startswith("800.0 Hz, off --rate-hz 1000 for ")
    t, arr = _feed(w, t, 1000.0, 1.0, arr)
    assert w.diagnostic(arr) == (S.OK, "1000.0 Hz")


def test_an_imu_rate_episode_open_when_px4s_clock_goes_back_ends_there():
    from omnirotor.fly.bridge import ImuRateWatch

    said: list[str] = []
    w = ImuRateWatch(1000.0, 0.05, window_s=1.0, name="IMU", say=said.append)
    t, arr = _feed(w, 0.0, 800.0, 3.0, 0.0)
    assert w.episodes == 1 and w._said
    off = w.off_s
    _feed(w, 0.0, 1000.0, 0.5, arr)  # PX4 restarted: its clock from 0 again
    assert w.episodes == 1 and w.off_s == pytest.approx(off, abs=2e-3) and not any("back at" in x for x in said)
    _feed(w, 5e5, 1000.0, 2.0, arr + 1.0)  # a healthy second: no new episode, the total unchanged
    assert w.episodes == 1 and w.off_s == pytest.approx(off, abs=2e-3)


def test_the_bridges_in_place_frames_are_rosbags_bytes_over_assembled_frames():
    """The bridge publishes :class:`FrameEncoder`'s payload of the assembler's record: the bytes rosbags gives for
    the same record (:meth:`WireMessages.fill_frame`), over frames with and without ESC speeds, motion capture and
    NaN samples, of PX4's clock from zero to past 2^31 s."""
    from omnirotor.fly.bridge import FrameAssembler
    from omnirotor.rosmsg import typestore
    from omnirotor.rosmsg.convert import FRAME, FrameEncoder, WireMessages

    rng = np.random.default_rng(7)
    store = typestore()
    a = FrameAssembler(8, esc_timeout_s=0.1)
    enc, msgs = FrameEncoder(8), WireMessages(8)
    kinds = set()
    for k in range(400):
        t_us = int(rng.choice([0, 1, 999_999, 2**31 * 10**6 + 5])) + 1000 * k
        gyro = rng.normal(size=3)
        if k % 17 == 3:
            gyro[1] = math.nan
        a.imu(_imu_msg(t_us, gyro=gyro, acc=rng.normal(size=3)))
        if k % 5 == 0:
            a.esc(_esc_msg(t_us, {m: int(rng.integers(-9000, 9000)) for m in rng.permutation(8)[: 1 + k % 8]}))
        if k % 7 == 0:
            a.mocap_odometry(_odometry_msg(t_us - 4000, rng.normal(size=3), rng.normal(size=4)))
        rec = a.frame()
        kinds.add((bool(rec[0]["mocap"]["new"]), bool(np.isnan(rec[0]["rotor_hz"]).all())))
        want = bytes(store.serialize_cdr(msgs.fill_frame(rec, k * 3), FRAME))
        assert enc.encode(rec, k * 3) == want, k
    assert kinds == {(False, False), (False, True), (True, False), (True, True)}


def test_px4s_clock_is_mapped_by_the_smallest_delay_of_its_imu_samples():
    from omnirotor.fly.bridge import _ClockOffset

    c = _ClockOffset(window_s=2.0)
    offset = 100.0  # PX4's clock minus the host's
    rng = np.random.default_rng(3)
    for k in range(3000):
        t_px4 = 5.0 + 1e-3 * k
        c.imu(t_px4, t_px4 - offset + 2e-4 + rng.uniform(0.0, 3e-3))  # each arrives 0.2-3.2 ms later
    assert offset - 2.2e-4 <= c.offset_s <= offset - 2e-4  # the offset minus (about) the smallest delay
    for k in range(3000, 6000):  # the host's clock steps 1 s back (NTP): followed within the window
        t_px4 = 5.0 + 1e-3 * k
        c.imu(t_px4, t_px4 - offset - 1.0 + 2e-4)
    assert c.offset_s == pytest.approx(offset + 1.0 - 2e-4, abs=1e-9)


def test_frame_options_refuse_what_cannot_work():
    from omnirotor.fly.bridge import FrameOptions

    with pytest.raises(InputError, match="one of pose, odometry"):
        FrameOptions(mocap="vicon")
    with pytest.raises(InputError, match="rate_hz"):
        FrameOptions(rate_hz=0.0)
    with pytest.raises(InputError, match="absolute"):
        FrameOptions(mocap_topic="mocap")


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--mocap", "vicon"], "one of pose, odometry"),
        (["--rate-hz", "-5"], "rate_hz"),
        (["--mocap-topic", "m"], "absolute"),
    ],
)
def test_px4_bridge_refuses_bad_frame_options_in_one_line_before_connecting(args, words, capsys):
    from omnirotor.cli import main

    assert main(["px4-bridge", "--connect", "tcp/127.0.0.1:1", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
