"""Parameters of the simulator: one frozen dataclass per block, loadable from TOML (SPEC §1.4, §5.2, §7).

Defaults are the SPEC values where the SPEC gives one; every other default is an assumption [A] of this
project, documented on its field. A simulator TOML file has one table per block::

    dt = 0.001
    provide_state = true
    [rotors]
    tau_m = 0.025
    [aero]
    model = "wake"              # or "spec7" (alias "interference"), "nominal"
    [sensors]
    mocap_rate_hz = 100.0
    [scene]
    wall_point = [0.637, -0.827, 1.429]
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from omnirotor.config import check_finite, check_positive, from_mapping, load_toml
from omnirotor.errors import InputError

__all__ = [
    "RotorDynamicsParams",
    "AeroParams",
    "SensorParams",
    "AirflowParams",
    "SceneParams",
    "SimParams",
    "load_sim_params",
    "AERO_MODELS",
    "TOOL_PIVOTS",
]

AERO_MODELS = ("wake", "spec7", "interference", "nominal")
"""Names of the truth aerodynamic models: the calibrated rotor-wake model, SPEC §7 slipstream interference
(``"spec7"``, also named ``"interference"``), or exactly ``A_nom u``."""


def _check_nonneg(name: str, *values: float) -> None:
    check_finite(name, *values)
    for v in values:
        if v < 0:
            raise InputError(f"{name} must be >= 0, got {v}")


def _check_unit_vector(name: str, v: tuple[float, float, float]) -> None:
    check_finite(name, *v)
    if math.hypot(*v) < 1e-9:
        raise InputError(f"{name} must be a non-zero vector")


@dataclasses.dataclass(frozen=True)
class RotorDynamicsParams:
    """First-order rotor speed loop with reversal, and the rotors' thrust fluctuation (SPEC §1.4; docs/fidelity.md).

    Attributes:
        tau_m: time constant of the speed loop [s] (SPEC §1.4 [A]: 0.025 s).
        dead_band: when True, a commanded speed with ``|omega| < dead_band_hz`` stops the rotor.
        dead_band_hz: width of the dead band around zero [Hz] (SPEC §1.4: 30 Hz, the MIQP's forbidden band).
        reversal_delay_s: time a reversing rotor stays stopped before it restarts in the other direction [s]
            (0 = it passes smoothly through zero) [A: 0.03 s: a sensorless ESC in bidirectional ("3D") mode
            brakes the motor to rest, aligns the rotor and ramps it open-loop until the back-EMF is readable,
            a few electrical start-up periods of ~5-10 ms each].
        reversal_stop_hz: speed below which a rotor braking towards the other direction is at rest [Hz]
            [A: 10 Hz = 600 rpm, about where a sensorless ESC loses the back-EMF of a 14-pole motor].
        thrust_noise_rel: standard deviation of each rotor's relative thrust and torque fluctuation [-]
            [A: 0, off: calibrated on Table 1's straight point-contact row together with the recirculation force
            it came out at 0, because it brings the rotors' lever-arm moments and so pitch errors the row does not
            show; docs/fidelity.md]. Propeller thrust measured on stands fluctuates by a few percent RMS, more in
            the wakes of neighbouring rotors.
        thrust_noise_corner_hz: corner frequency of the fluctuation's first-order spectrum [Hz] [A: 5 Hz:
            wake meandering at a Strouhal number ~0.15 of the rotor's induced speed (~6 m/s at hover) over its
            diameter (0.2 m); faster blade-passage loads are filtered by the airframe's mass].
    """

    tau_m: float = 0.025
    dead_band: bool = False
    dead_band_hz: float = 30.0
    reversal_delay_s: float = 0.03
    reversal_stop_hz: float = 10.0
    thrust_noise_rel: float = 0.0
    thrust_noise_corner_hz: float = 5.0

    def __post_init__(self) -> None:
        check_positive("rotors.tau_m", self.tau_m)
        _check_nonneg("rotors.dead_band_hz", self.dead_band_hz)
        _check_nonneg("rotors.reversal_delay_s", self.reversal_delay_s)
        _check_nonneg("rotors.reversal_stop_hz", self.reversal_stop_hz)
        _check_nonneg("rotors.thrust_noise_rel", self.thrust_noise_rel)
        check_positive("rotors.thrust_noise_corner_hz", self.thrust_noise_corner_hz)
        if self.thrust_noise_rel > 0.5:
            raise InputError(f"rotors.thrust_noise_rel must be <= 0.5, got {self.thrust_noise_rel}")


@dataclasses.dataclass(frozen=True)
class AeroParams:
    """Truth aerodynamics: the rotor-wake model (default), SPEC §7's slipstream interference, or the nominal map.

    The rotor-wake defaults were fitted by ``omnirotor calibrate-truth`` to the authors' 39 real flight hover
    points with the force-stand ratios of SPEC §3.5 as a prior (``docs/fidelity.md``: figures, sources,
    cross-validation); see :mod:`omnirotor.sim.aero`.

    Attributes:
        model: "wake" (calibrated rotor-wake model), "spec7" or "interference" (SPEC §7), or "nominal"
            (exactly ``A_nom u``).
        thrust_gain: wake model: isolated-rotor thrust over the nominal ``c_f |u|`` [-] (fitted; prior: the
            force-stand ratios 1.14-1.27 of SPEC §3.5).
        reverse_gain: wake model: relative thrust change of a rotor turning in reverse [-] (fitted; 0 = a
            symmetric bidirectional propeller).
        ingest_gain: wake model: efficiency lost per unit ``reach n_j / n_i`` when j's wake enters i's intake
            [-] (fitted; momentum theory: > 0, like a rotor in climb).
        counter_gain: wake model: the same when j's wake meets i's outlet [-] (fitted; < 0 is a gain).
        aim_exponent: wake model: ``m`` of the reach ``max(a_ij, 0)^m``, the wake's angular spread [-]
            (fitted; large = a narrow jet).
        facing_gain: wake model: efficiency lost per unit ``reach n_j / n_i`` when rotor i sits in j's intake
            field (``a_ij < 0``) with its own intake facing j (``c_ij > 0``): the two rotors draw air from the
            region between them [-] (0: the pair does nothing, the previous model).
        upstream_gain: wake model: the same with i's outlet facing j (``c_ij < 0``): j ingests i's wake, i is
            upstream of it [-] (0: nothing).
        side_exponent: wake model: ``q`` of the side factor ``max(|c_ij|, 0.05)^q``, the disk's projected area
            seen along the pair's line [-] (0: every side counts alike, the previous model).
        distance_exponent: wake model: ``k`` of the distance factor ``(L0 / L_ij)^k`` [-] (1: the previous
            model).
        wake_coupling: wake model: a neighbour's slipstream strength is ``n_j sqrt(factor_j)`` (True: momentum
            theory, the slipstream speed scales like the square root of the rotor's thrust, which its own
            neighbours reduce; ``factor_j`` to first order) or ``n_j`` (False: the previous model).
        handedness_gain: wake model: relative thrust difference of the two propeller handednesses: a rotor
            with drag-torque sign ``k_i = +1`` (SPEC §1.2) makes ``1 + handedness_gain``, one with ``k_i = -1``
            ``1 - handedness_gain`` times the common thrust [-] (fitted; the two are mirror-image propellers).
        frame_roll_deg: wake model: roll of the rotors' frame relative to the measured (motion-capture) body
            frame [deg] (0: fitting it does not cross-validate, docs/fidelity.md).
        frame_pitch_deg: wake model: the same, pitch [deg] (0, as roll).
        frame_yaw_deg: wake model: the same, yaw [deg] (fitted). The rotation ``Rz(yaw) Ry(pitch) Rx(roll)``
            turns the whole rotor geometry; linear in u, so any identified map absorbs it.
        kappa0: SPEC §7: isolated-rotor thrust gain over the nominal c_f (1.18).
        gamma: SPEC §7: inflow sensitivity of the propeller law (4.0).
        rho: air density [kg/m³].
        rotor_radius: propeller radius R [m]; 0 takes half the vehicle's ``propeller_diameter``.
        advance_ratio_ref: J0 of the linear propeller law ``eta = 1 - gamma V / (J0 n D)``.
        jet_spread: beta, growth of the jet radius with distance ``b(s) = R/sqrt(2) + beta s``.
        eta_min: lower clip of the efficiency (both interaction models) [A: 0.3].
        eta_max: upper clip of the efficiency [A: 1.7].
        gain_error_std: standard deviation of a per-rotor relative thrust-gain error (0 = none) [A].
        tilt_error_std_deg: standard deviation of a per-rotor axis tilt error [deg] (0 = none) [A].
        error_seed: seed of the manufacturing errors (a property of the airframe, so independent of the
            simulator's noise seed).
    """

    model: str = "wake"
    thrust_gain: float = 1.16097
    reverse_gain: float = 0.0199277
    ingest_gain: float = 0.914641
    counter_gain: float = -0.761531
    aim_exponent: float = 0.858829
    handedness_gain: float = 0.027829
    facing_gain: float = 0.0
    upstream_gain: float = 0.0
    side_exponent: float = 0.0
    distance_exponent: float = 1.0
    wake_coupling: bool = True
    frame_roll_deg: float = 0.0
    frame_pitch_deg: float = 0.0
    frame_yaw_deg: float = -5.11308
    kappa0: float = 1.18
    gamma: float = 4.0
    rho: float = 1.225
    rotor_radius: float = 0.0
    advance_ratio_ref: float = 0.6
    jet_spread: float = 0.10
    eta_min: float = 0.3
    eta_max: float = 1.7
    gain_error_std: float = 0.0
    tilt_error_std_deg: float = 0.0
    error_seed: int = 0

    def __post_init__(self) -> None:
        if self.model not in AERO_MODELS:
            raise InputError(f"aero.model must be one of {', '.join(AERO_MODELS)}, got {self.model!r}")
        for label in ("kappa0", "rho", "advance_ratio_ref", "thrust_gain"):
            check_positive(f"aero.{label}", getattr(self, label))
        _check_nonneg("aero.gamma", self.gamma)
        for label in ("ingest_gain", "counter_gain", "frame_roll_deg", "frame_pitch_deg", "frame_yaw_deg"):
            check_finite(f"aero.{label}", getattr(self, label))
        check_finite("aero.handedness_gain", self.handedness_gain)
        if not -1.0 < self.handedness_gain < 1.0:
            raise InputError(f"aero.handedness_gain must be in (-1, 1), got {self.handedness_gain}")
        _check_nonneg("aero.aim_exponent", self.aim_exponent)
        for label in ("facing_gain", "upstream_gain"):
            check_finite(f"aero.{label}", getattr(self, label))
        _check_nonneg("aero.side_exponent", self.side_exponent)
        _check_nonneg("aero.distance_exponent", self.distance_exponent)
        check_finite("aero.reverse_gain", self.reverse_gain)
        if self.reverse_gain <= -1.0:
            raise InputError(f"aero.reverse_gain must be > -1, got {self.reverse_gain}")
        _check_nonneg("aero.rotor_radius", self.rotor_radius)
        _check_nonneg("aero.jet_spread", self.jet_spread)
        _check_nonneg("aero.gain_error_std", self.gain_error_std)
        _check_nonneg("aero.tilt_error_std_deg", self.tilt_error_std_deg)
        check_positive("aero.eta_max", self.eta_max)
        _check_nonneg("aero.eta_min", self.eta_min)
        if self.eta_min > self.eta_max:
            raise InputError("aero.eta_min must be <= aero.eta_max")
        if self.error_seed < 0:
            raise InputError(f"aero.error_seed must be >= 0, got {self.error_seed}")


@dataclasses.dataclass(frozen=True)
class SensorParams:
    """Sensor models. Every noise level here is an assumption [A]; all standard deviations are per sample.

    Attributes:
        acc_noise_std: accelerometer white noise [m/s²] (MEMS density ~200 µg/√Hz over ~500 Hz, plus
            some airframe vibration).
        acc_bias_std: spread of the constant accelerometer bias drawn per run [m/s²] (~5 mg).
        gyro_noise_std: gyroscope white noise [rad/s] (~0.3 deg/s).
        gyro_bias_std: spread of the constant gyroscope bias drawn per run [rad/s] (~0.1 deg/s).
        imu_offset_B: (3,) IMU position relative to the CoM, body frame [m] (the real one: (0, 0, 0.041)).
        mocap_rate_hz: motion-capture sample rate [Hz].
        mocap_latency_s: delay from a sample's time to its delivery [s], rounded to the step (4 ms [A]:
            OptiTrack processing plus network).
        mocap_pos_noise_std: motion-capture position noise [m] (0.3 mm).
        mocap_att_noise_std: motion-capture attitude noise, per axis of a small body rotation [rad] (~0.1 deg).
        rotor_speed_noise_std_hz: noise of the measured rotor speeds [Hz] (ESC telemetry).
        state_pos_noise_std: noise of ``SensorFrame.state.p_W`` [m].
        state_vel_noise_std: noise of ``state.v_W`` [m/s].
        state_acc_noise_std: noise of ``state.a_W`` [m/s²].
        state_att_noise_std: noise of ``state.R_WB``, per axis of a small body rotation [rad].
        state_omega_noise_std: noise of ``state.omega_B`` [rad/s].
        acc_vib_noise_std: broadband accelerometer noise from the airframe's vibration [m/s²], added (in
            quadrature) to ``acc_noise_std``: the rotors' harmonics above the sensor's bandwidth, folded over the
            1 kHz samples by aliasing, arrive as noise across the whole band. Calibrated (with
            ``airflow.force_std`` and ``mocap_drift_pos_std``) on Table 1's straight point-contact row measured as
            the paper measures it (the believed pose, SPEC §6): 2.8 m/s² (docs/fidelity.md); it moves the pose the
            UKF believes, so the robot, and it feeds the acceleration-based observer directly.
        imu_vib_acc_amp: amplitude of one rotor's once-per-revolution vibration at the accelerometer, when
            the rotor turns at ``imu_vib_ref_hz`` [m/s²]; it grows with the square of the speed (an imbalance
            force), along a direction drawn per rotor and run [A: 0.8 m/s²: with eight rotors about
            0.9 m/s² RMS per axis, within the < 3 m/s² PX4's guidance counts as a well-isolated IMU].
        imu_vib_gyro_amp: the same at the gyroscope [rad/s] [A: 0.02 rad/s, ~1 deg/s].
        imu_vib_ref_hz: the reference rotor speed of the two amplitudes [Hz] (about the hover speed).
        mocap_latency_jitter_s: extra latency of each motion-capture sample, uniform in ``[0, jitter]`` and
            rounded to the step [s]; samples stay in order (a late one holds back the next, like a TCP/ROS
            stream) [A: 3 ms, Wi-Fi and ROS scheduling on top of the camera system's fixed delay].
        mocap_drift_pos_std: standard deviation of the motion capture's slow position error, per world axis [m]
            (calibrated with ``acc_vib_noise_std`` and ``airflow.force_std`` on Table 1's straight point-contact
            row as the paper measures it, the believed pose: 0 mm on the wake-coupled truth, 6 mm on the truth
            before it: the row does not pin the drift and the force apart; a slow error of the believed pose moves
            the true robot more than the believed one; docs/fidelity.md):
            a first-order Gauss-Markov process advanced at each sample (the rigid-body fit wandering as markers
            drop in and out of the cameras' views and the frame vibrates; docs/fidelity.md). Unlike the white
            ``mocap_pos_noise_std`` it is slow enough for the controller to follow: it moves the robot, while
            the wrench observer, which sees the true acceleration and the commanded wrench, stays right.
        mocap_drift_att_std: the same for the attitude, per axis of a small body rotation [rad] (0: the first
            calibration, on the true pose, found 0).
        mocap_drift_corner_hz: corner frequency of both drifts' first-order spectrum [Hz] [A: 0.1 Hz, slower than
            the position loop, so the controller follows it; at 0.3-0.5 Hz and centimetre sizes the UKF's gate
            rejects the samples].
    """

    acc_noise_std: float = 0.1
    acc_bias_std: float = 0.05
    gyro_noise_std: float = 0.005
    gyro_bias_std: float = 0.002
    imu_offset_B: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mocap_rate_hz: float = 100.0
    mocap_latency_s: float = 0.004
    mocap_pos_noise_std: float = 3e-4
    mocap_att_noise_std: float = 1.5e-3
    rotor_speed_noise_std_hz: float = 0.5
    state_pos_noise_std: float = 5e-4
    state_vel_noise_std: float = 5e-3
    state_acc_noise_std: float = 0.05
    state_att_noise_std: float = 2e-3
    state_omega_noise_std: float = 2e-3
    acc_vib_noise_std: float = 2.8
    imu_vib_acc_amp: float = 0.8
    imu_vib_gyro_amp: float = 0.02
    imu_vib_ref_hz: float = 100.0
    mocap_latency_jitter_s: float = 0.003
    mocap_drift_pos_std: float = 0.0
    mocap_drift_att_std: float = 0.0
    mocap_drift_corner_hz: float = 0.1

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            if f.name == "imu_offset_B":
                check_finite("sensors.imu_offset_B", *self.imu_offset_B)
            elif f.name in ("mocap_rate_hz", "imu_vib_ref_hz", "mocap_drift_corner_hz"):
                check_positive(f"sensors.{f.name}", getattr(self, f.name))
            else:
                _check_nonneg(f"sensors.{f.name}", getattr(self, f.name))


@dataclasses.dataclass(frozen=True)
class AirflowParams:
    """The vehicle's recirculating wake as a random force at the CoM (:mod:`omnirotor.sim.airflow`).

    Attributes:
        force_std: standard deviation of each world axis of the force next to one surface [N]; at a distance
            ``d`` of each surface it falls by ``l² / (l² + d²)`` (``l``: the vehicle's wake radius, 0.32 m for the
            Omnirotor; :mod:`omnirotor.sim.airflow`). Calibrated on Table 1's straight point-contact row,
            measured on the believed pose as the paper does, by ``omnirotor calibrate-disturbances``, with the
            accelerometer vibration and the motion-capture drift: 1.6 N (0.46 N in the straight point contact, 0.5 m
            off the wall; on the truth before the wake coupling the row took no force but 6 mm of drift instead: the
            row does not pin the two apart; docs/fidelity.md, docs/data/disturbance-calibration.json).
        corner_hz: corner frequency of its first-order spectrum [Hz] [A: 1 Hz: eddies of the vehicle's size,
            ~1 m, carried at the ~1 m/s of a wake that has spread over the floor and the wall].
        ref_weight_N: the vehicle weight at which ``force_std`` holds [N] (the Omnirotor's, 1.625 kg × 9.81
            m/s², on which it was calibrated). The simulator scales the force by the flown vehicle's weight over
            this [A: the recirculating wake carries the momentum flux of the vehicle's own downwash, which in
            hover equals its weight]: a 30 g quadrotor gets 1.8 % of it, not a force six times its weight.
        near_surfaces: the force depends on the distance to the scene's surfaces (the floor, the wall, the pipe);
            False: ``force_std`` everywhere, in free air too (the model before; for comparison).
    """

    force_std: float = 1.6
    corner_hz: float = 1.0
    ref_weight_N: float = 15.94125
    near_surfaces: bool = True

    def __post_init__(self) -> None:
        _check_nonneg("airflow.force_std", self.force_std)
        check_positive("airflow.corner_hz", self.corner_hz)
        check_positive("airflow.ref_weight_N", self.ref_weight_N)


TOOL_PIVOTS = ("com", "mount", "tip")
"""Where the compliant tool's bending hinges may sit (:attr:`SceneParams.tool_pivot`)."""


@dataclasses.dataclass(frozen=True)
class SceneParams:
    """Geometry and contact properties of every scene (SPEC §5.2), world frame [m].

    The anchors a controller needs (surface point, outward normal, ...) are derived from these by
    :func:`omnirotor.sim.scenes.scene_anchors`.

    Attributes:
        wall_point: a point of the straight wall's surface (SPEC §5.2).
        wall_normal: outward normal of the straight wall (the wall lies on the other side).
        tilted_wall_point: a point of the tilted wall's surface (SPEC §5.2).
        tilted_wall_angle_deg: downward inclination of its outward normal from world +y:
            ``n = (0, cos a, -sin a)`` (SPEC §5.2: 30 deg).
        wall_half_width: half-extent of a wall board within its plane [m] [A].
        wall_thickness: thickness of a wall board [m] [A].
        pipe_centre: a point of the pipe's axis (SPEC §5.2).
        pipe_radius: [m] (SPEC §5.2: 0.55 m).
        pipe_length: length of the pipe along world x [m] [A].
        hole_entrance: where the hole axis crosses the funnel mouth [A: reachable like the wall].
        funnel_length: [m] (SPEC §5.2: 0.10 m).
        funnel_entrance_diameter: inner diameter of the funnel mouth [m] (SPEC §5.2: 80 mm).
        hole_diameter: inner diameter of the straight hole [m] (SPEC §5.2: 19 mm).
        hole_depth: length of the straight hole after the funnel [m]; funnel plus hole must exceed the
            0.17 m insertion of SPEC §5.2 [A: 0.10 m, total 0.20 m].
        hole_wall_thickness: thickness of the plates that make the funnel and the hole [m] [A].
        ring_segments: number of plates in each ring of the funnel and the hole.
        floor: put a floor plane at z = 0.
        friction: sliding friction coefficient of every contact [A: 0.3, a 3D-printed PLA/PETG tip on painted
            steel, wood or PVC: published plastic-on-steel/plastic pairs lie at 0.2-0.4].
        contact_timeconst: MuJoCo ``solref`` time constant of contacts [s] [A: 5 ms; >= 2 steps].
        contact_dampratio: MuJoCo ``solref`` damping ratio of contacts [A: 1, critically damped].
        friction_cone: MuJoCo's friction cone, "elliptic" (Coulomb's cone) or "pyramidal" (its linearisation,
            with which the tip sliding over the pipe leaves it for single steps more often: docs/fidelity.md).
        friction_law: friction of the compliant tool's contacts: "stick-slip" (Coulomb's law applied as a force
            on the tool, :func:`omnirotor.sim.contact.friction_step`: no normal coupling) or "mujoco" (MuJoCo's
            ``friction_cone``, whose convex relaxation lifts a sliding tip off the surface: docs/fidelity.md). The
            rigid tool and every other contact always use MuJoCo's cone.
        tool_compliant: mount the tool (rod and tip) on the vehicle through a compliant coupling (paper §5.3: "a
            coupling between the EE and body ... to reduce vibrations"); False: the tool is part of the rigid body.
        tool_mass: moving mass of the tool, lumped at the tip [kg] [A: 10 g, a 3D-printed tip (~5 g) plus the
            effective mass of a Ø16 mm carbon tube at its tip (~1/4 of its ~25 g)]; taken from the body's mass, and
            its moment of inertia from the body's inertia, so that the vehicle weighs what the vehicle file says
            and has its inertia with the tool locked.
        tool_axial_stiffness: stiffness of the coupling along the tool axis [N/m] [A: 4000, elastomer isolators
            that a 3 N push compresses by 0.75 mm].
        tool_bending_stiffness: rotational stiffness of the coupling and the rod across the tool axis [N·m/rad]
            [A: 20: 1 N of friction at the tip, 0.5 m out, tilts the tool by 1.4°; a Ø16/14 mm carbon tube
            cantilevered 0.36 m out of the frame alone is ~40x stiffer, so the coupling sets it].
        tool_damping_ratio: damping ratio of the tool's axial and bending modes [A: 0.15, half the loss factor
            ~0.3 of damping elastomers].
        tool_pivot: where the coupling's bending hinges sit on the tool axis, its compliance centre: "com" (the
            vehicle's CoM, the default: a modelling choice, docs/fidelity.md), "mount" (where the rod leaves the
            frame: the paper's "coupling between the EE and body", §5.3) or "tip" (the tip sphere's centre: a
            remote-centre-compliance device, which the paper does not describe; for studies of Whitney's
            jamming). The tool's mass sits at the pivot and the vehicle's own CoM moves against it, so that the
            vehicle with its tool locked keeps the CoM, mass and inertia of its file whatever the pivot.
        start_standoff: distance of the EE tip from the contact surface in the default start pose [m].
        free_start: default start position of the body in the free scene [m].
    """

    wall_point: tuple[float, float, float] = (0.637, -0.827, 1.429)
    wall_normal: tuple[float, float, float] = (0.0, 1.0, 0.0)
    tilted_wall_point: tuple[float, float, float] = (0.639, -0.848, 1.365)
    tilted_wall_angle_deg: float = 30.0
    wall_half_width: float = 0.5
    wall_thickness: float = 0.04
    pipe_centre: tuple[float, float, float] = (0.0261, 1.4952, 0.7648)
    pipe_radius: float = 0.55
    pipe_length: float = 1.2
    hole_entrance: tuple[float, float, float] = (0.6, -0.85, 1.4)
    funnel_length: float = 0.10
    funnel_entrance_diameter: float = 0.080
    hole_diameter: float = 0.019
    hole_depth: float = 0.10
    hole_wall_thickness: float = 0.004
    ring_segments: int = 16
    floor: bool = True
    friction: float = 0.3
    contact_timeconst: float = 0.005
    contact_dampratio: float = 1.0
    friction_cone: str = "elliptic"
    friction_law: str = "stick-slip"
    tool_compliant: bool = True
    tool_mass: float = 0.010
    tool_axial_stiffness: float = 4000.0
    tool_bending_stiffness: float = 20.0
    tool_damping_ratio: float = 0.15
    tool_pivot: str = "com"
    start_standoff: float = 0.3
    free_start: tuple[float, float, float] = (0.0, 0.0, 1.5)

    def __post_init__(self) -> None:
        for label in ("wall_point", "tilted_wall_point", "pipe_centre", "hole_entrance", "free_start"):
            check_finite(f"scene.{label}", *getattr(self, label))
        _check_unit_vector("scene.wall_normal", self.wall_normal)
        check_finite("scene.tilted_wall_angle_deg", self.tilted_wall_angle_deg)
        if not -90.0 < self.tilted_wall_angle_deg < 90.0:
            raise InputError("scene.tilted_wall_angle_deg must lie in (-90, 90)")
        for label in (
            "wall_half_width",
            "wall_thickness",
            "pipe_radius",
            "pipe_length",
            "funnel_length",
            "funnel_entrance_diameter",
            "hole_diameter",
            "hole_depth",
            "hole_wall_thickness",
            "contact_timeconst",
            "contact_dampratio",
            "tool_mass",
            "tool_axial_stiffness",
            "tool_bending_stiffness",
            "start_standoff",
        ):
            check_positive(f"scene.{label}", getattr(self, label))
        _check_nonneg("scene.friction", self.friction)
        _check_nonneg("scene.tool_damping_ratio", self.tool_damping_ratio)
        if self.friction_cone not in ("elliptic", "pyramidal"):
            raise InputError(f"scene.friction_cone must be elliptic or pyramidal, got {self.friction_cone!r}")
        if self.friction_law not in ("stick-slip", "mujoco"):
            raise InputError(f"scene.friction_law must be stick-slip or mujoco, got {self.friction_law!r}")
        if self.tool_pivot not in TOOL_PIVOTS:
            raise InputError(f"scene.tool_pivot must be one of {', '.join(TOOL_PIVOTS)}, got {self.tool_pivot!r}")
        if self.funnel_entrance_diameter < self.hole_diameter:
            raise InputError("scene.funnel_entrance_diameter must be >= scene.hole_diameter")
        if self.ring_segments < 6:
            raise InputError(f"scene.ring_segments must be >= 6, got {self.ring_segments}")


@dataclasses.dataclass(frozen=True)
class SimParams:
    """The whole simulator.

    Attributes:
        dt: control period [s]: one :meth:`Simulator.step` (SPEC §4: 1 kHz).
        substeps: physics steps per control period (the rotor wrench is held, its world direction follows
            the attitude); two resolve the contact's 5 ms time constant by ten (docs/fidelity.md, "Physics
            steps per control period").
        provide_state: fill ``SensorFrame.state`` with ground truth plus ``sensors.state_*`` noise.
        rotors: rotor speed loop.
        aero: truth aerodynamics.
        sensors: sensor models.
        airflow: the recirculating wake's force.
        scene: scene geometry and contact properties.
    """

    dt: float = 1e-3
    substeps: int = 2
    provide_state: bool = True
    rotors: RotorDynamicsParams = dataclasses.field(default_factory=RotorDynamicsParams)
    aero: AeroParams = dataclasses.field(default_factory=AeroParams)
    sensors: SensorParams = dataclasses.field(default_factory=SensorParams)
    airflow: AirflowParams = dataclasses.field(default_factory=AirflowParams)
    scene: SceneParams = dataclasses.field(default_factory=SceneParams)

    def __post_init__(self) -> None:
        check_positive("dt", self.dt)
        if self.dt > 0.01:
            raise InputError(f"dt must be <= 0.01 s, got {self.dt}")
        if self.substeps < 1:
            raise InputError(f"substeps must be >= 1, got {self.substeps}")
        if 2.0 * self.dt / self.substeps > self.scene.contact_timeconst + 1e-12:
            raise InputError(
                "scene.contact_timeconst must be at least two physics steps (dt / substeps) for stable contact"
            )

    def undisturbed(self) -> SimParams:
        """These parameters without the disturbances (docs/fidelity.md).

        No thrust fluctuation, no recirculation force, no IMU vibration (broadband or at the rotor rates), no
        motion-capture jitter or drift; the rotor
        reversal, the white sensor noise and the biases stay. For the tests of the plant's physics and of the
        controller on a clean plant (``omnirotor run --no-disturbances``).
        """
        return dataclasses.replace(
            self,
            rotors=dataclasses.replace(self.rotors, thrust_noise_rel=0.0),
            airflow=dataclasses.replace(self.airflow, force_std=0.0),
            sensors=dataclasses.replace(
                self.sensors,
                acc_vib_noise_std=0.0,
                imu_vib_acc_amp=0.0,
                imu_vib_gyro_amp=0.0,
                mocap_latency_jitter_s=0.0,
                mocap_drift_pos_std=0.0,
                mocap_drift_att_std=0.0,
            ),
        )


def load_sim_params(path: str | Path) -> SimParams:
    """Read :class:`SimParams` from a TOML file; unknown keys raise :class:`InputError`."""
    return from_mapping(SimParams, load_toml(path), str(path))
