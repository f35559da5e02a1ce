"""The shared quadrotor hover task, in omnirotor and in RotorPy (https://github.com/spencerfolk/rotorpy).

Both sides hover RotorPy's default Crazyflie from rest at 1 kHz simulation and control rate, at the free
scene's start position (0, 0, 1.5) m:

* RotorPy (optional dependency, the ``bench`` extra pins 3.0.0): ``Multirotor`` with the Crazyflie
  parameters and its defaults (``aero=True``: rotor drag and induced inflow; SciPy ``solve_ivp`` RK45 over
  one 1 ms step, rotor speeds as first-order states) and ``SE3Control`` with the true state, driven step by
  step here: ``flat = traj.update(t); u = ctl.update(t, state, flat); state = veh.step(state, u, dt)``.
  That is the core of ``rotorpy.simulate.simulate`` without its IMU, motion capture, estimator, extra
  ``statedot`` call and per-step list appends, so it is RotorPy's cheapest closed loop.
  :func:`rotorpy_simulate` times ``simulate()`` itself, for reference.
* omnirotor: the ``quadrotor`` vehicle preset in :class:`~omnirotor.sim.Simulator` (MuJoCo rigid body, the
  first-order rotor loop with RotorPy's ``tau_m``, the slipstream-interference truth aerodynamics, IMU,
  motion capture and noisy ground-truth state) and the whole
  :class:`~omnirotor.control.controller.InteractionController` (trajectory, admittance, wrench observer,
  pose control, QP allocation; the estimator is the ground-truth bypass, as SE3Control reads the true state)
  inside ``run_closed_loop``, which also logs every step of both sides.

The interaction controller is for fully actuated vehicles: on the coplanar quadrotor its allocation returns
the best least-squares wrench, which holds a hover from rest (no lateral force is ever needed) but cannot
correct a lateral offset. Its regulariser is the default one, scaled to the quadrotor's thrust coefficient
(:func:`quad_reg_lambda`).
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from omnirotor.control.admittance import AdmittanceParams
from omnirotor.control.controller import ControllerParams, InteractionController
from omnirotor.control.estimator import EstimatorParams
from omnirotor.control.trajectory import PoseTrajectory, Waypoint
from omnirotor.experiments.loop import run_closed_loop
from omnirotor.messages import RotorCommand
from omnirotor.sim import SimParams, Simulator
from omnirotor.sim.params import RotorDynamicsParams
from omnirotor.vehicle import VehicleParams, load_vehicle

DT_S = 1e-3
"""Simulation and control period of the shared task [s]."""
QUAD_PRESET = "quadrotor"
ROTORPY_TAU_M_S = 0.072
"""The Crazyflie's motor time constant in RotorPy's ``crazyflie_params`` (used when RotorPy is absent)."""


def rotorpy_version() -> str | None:
    """Installed RotorPy version, or None when it is not installed."""
    try:
        from importlib.metadata import PackageNotFoundError, version

        return version("rotorpy")
    except PackageNotFoundError:
        return None


def _crazyflie() -> dict:
    from rotorpy.vehicles.crazyflie_params import quad_params

    return quad_params


def quad_reg_lambda(quad: VehicleParams) -> float:
    """The allocation regulariser the quadrotor gets by default [N²/Hz⁴] (reported with the figures).

    SPEC §4.2 gives lambda = 1e-12 [N²/Hz⁴] for the Omnirotor (c_f = 1.5e-4 N/Hz²); ``AllocationParams``
    scales it by (c_f / 1.5e-4)², so the Crazyflie, whose c_f is 165 times smaller, gets 3.7e-17 and the
    regulariser weighs as much against the wrench error as on the Omnirotor.
    """
    from omnirotor.control.allocation import Allocator

    return Allocator(quad).reg_lambda_used


def tau_m_s() -> float:
    """RotorPy's Crazyflie motor time constant [s] (the pinned value if RotorPy is absent)."""
    return float(_crazyflie()["tau_m"]) if rotorpy_version() else ROTORPY_TAU_M_S


# -- parameter check ------------------------------------------------------------------------------------


def crazyflie_comparison(quad: VehicleParams | None = None) -> list[dict]:
    """Compare the ``quadrotor`` preset with RotorPy's ``crazyflie_params`` (needs RotorPy).

    Rotor speeds convert from rad/s to Hz by 1/(2π), so ``c_f = k_eta (2π)²`` and ``c_tau = k_m (2π)²``.

    Returns:
        Rows ``{"quantity", "rotorpy", "preset", "rel_diff", "match"}`` (rel_diff = |preset/rotorpy − 1|;
        match when below 1e-4, the preset's rounding to 5–7 digits).
    """
    quad = quad or load_vehicle(QUAD_PRESET)
    qp = _crazyflie()
    two_pi = 2.0 * math.pi
    d = float(np.linalg.norm(qp["rotor_pos"]["r1"]))
    rotorpy_pos = np.array([qp["rotor_pos"][k] for k in ("r1", "r2", "r3", "r4")])
    pairs = [
        ("mass [kg]", qp["mass"], quad.mass),
        ("Ixx [kg m²]", qp["Ixx"], quad.inertia_diag[0]),
        ("Iyy [kg m²]", qp["Iyy"], quad.inertia_diag[1]),
        ("Izz [kg m²]", qp["Izz"], quad.inertia_diag[2]),
        ("arm length [m]", d, float(np.mean(np.linalg.norm(quad.positions_B, axis=1)))),
        ("c_f = k_eta (2π)² [N/Hz²]", qp["k_eta"] * two_pi**2, quad.c_f),
        ("c_tau = k_m (2π)² [N m/Hz²]", qp["k_m"] * two_pi**2, quad.c_tau),
        ("max rotor speed [Hz]", qp["rotor_speed_max"] / two_pi, quad.omega_max_hz),
        ("min rotor speed [Hz]", qp["rotor_speed_min"] / two_pi, quad.omega_min_hz),
        ("rotor positions, max abs. diff. [m]", 0.0, float(np.max(np.abs(rotorpy_pos - quad.positions_B)))),
        ("spin directions equal", 1.0, float(np.array_equal(qp["rotor_directions"], quad.spins))),
        ("motor time constant [s] (sim param)", qp["tau_m"], RotorDynamicsParams().tau_m),
    ]
    rows = []
    for name, theirs, ours in pairs:
        theirs, ours = float(theirs), float(ours)
        if name.startswith("rotor positions"):
            rel = ours  # an absolute difference [m]
            ok = ours < 1e-6
        elif theirs == 0.0:
            rel = abs(ours)
            ok = ours == 0.0
        else:
            rel = abs(ours / theirs - 1.0)
            ok = rel < 1e-4
        rows.append({"quantity": name, "rotorpy": theirs, "preset": ours, "rel_diff": rel, "match": bool(ok)})
    return rows


# -- omnirotor side -------------------------------------------------------------------------------------


def _quad_sim(seed: int) -> tuple[VehicleParams, Simulator]:
    quad = load_vehicle(QUAD_PRESET)
    # the clean plant (sensor noise and biases kept, no calibrated disturbances): RotorPy flies no disturbance
    # either, and the Omnirotor's calibrated vibration is not a Crazyflie's. One physics step per 1 ms period,
    # as RotorPy integrates at 1 kHz: the default plant's second step per period is there for the stiffness of
    # contact (docs/fidelity.md), and the hover touches nothing.
    params = SimParams(dt=DT_S, substeps=1, rotors=RotorDynamicsParams(tau_m=tau_m_s())).undisturbed()
    return quad, Simulator(quad, "free", params, seed=seed)


def ours_hover(duration_s: float, estimator: str = "bypass", seed: int = 0) -> dict:
    """Hover the quadrotor with the interaction controller; time ``run_closed_loop`` only.

    Returns:
        ``wall_s``, ``rtf``, ``final_pos_err_mm`` and ``max_pos_err_mm`` (true CoM against the start).
    """
    quad, sim = _quad_sim(seed)
    p0, R0 = sim.default_start()
    trajectory = PoseTrajectory([Waypoint(0.0, p0 + R0 @ quad.p_E_B_array, R0)])
    cparams = ControllerParams(
        dt=DT_S,
        admittance=AdmittanceParams.preset("free"),
        estimator=EstimatorParams(kind=estimator),
    )
    ctl = InteractionController(quad, cparams)
    tic, cpu0 = time.perf_counter(), time.process_time()
    _, truth_log = run_closed_loop(sim, ctl, trajectory, duration_s)
    wall, cpu = time.perf_counter() - tic, time.process_time() - cpu0
    err = np.linalg.norm(truth_log.group("p_W") - p0, axis=1) * 1e3
    return {
        "wall_s": wall,
        "rtf": duration_s / wall,
        "rtf_cpu": duration_s / cpu,
        "final_pos_err_mm": float(err[-1]),
        "max_pos_err_mm": float(err.max()),
    }


def ours_sim_only(duration_s: float, seed: int = 0) -> dict:
    """Step the quadrotor's simulator alone under its constant hover command (timed loop only)."""
    _, sim = _quad_sim(seed)
    sim.reset()
    cmd = RotorCommand(0.0, sim.hover_speeds_hz())
    n = int(round(duration_s / DT_S))
    step = sim.step
    tic, cpu0 = time.perf_counter(), time.process_time()
    for _ in range(n):
        step(cmd)
    wall, cpu = time.perf_counter() - tic, time.process_time() - cpu0
    return {"wall_s": wall, "rtf": duration_s / wall, "rtf_cpu": duration_s / cpu}


# -- RotorPy side ---------------------------------------------------------------------------------------


def hover_speed_rad_s() -> float:
    """RotorPy's Crazyflie hover rotor speed sqrt(m g / (4 k_eta)) [rad/s] (g = 9.81, as RotorPy)."""
    qp = _crazyflie()
    return math.sqrt(qp["mass"] * 9.81 / (qp["num_rotors"] * qp["k_eta"]))


EXAMPLE_ROTOR_SPEED_RAD_S = 1788.53
"""The initial rotor speed of RotorPy's own examples [rad/s] (hover is 1788.5505: a 1e-5 relative offset)."""
CIRCLE_RADIUS_M = 1.0
CIRCLE_FREQ_HZ = 0.2
"""The tracked circle: radius and lap frequency of ``ThreeDCircularTraj`` in the horizontal plane."""


@dataclasses.dataclass(frozen=True)
class RotorPyStart:
    """One start of the RotorPy sweep.

    Attributes:
        name: label in the tables.
        rotor_speed_rad_s: initial speed of every rotor [rad/s] (None: exactly the hover speed).
        offset_m: initial position minus the hover target [m].
        trajectory: "hover" (``HoverTraj`` at the target) or "circle" (``ThreeDCircularTraj`` centred so that
            the circle starts at the target).
    """

    name: str
    rotor_speed_rad_s: float | None = EXAMPLE_ROTOR_SPEED_RAD_S
    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    trajectory: str = "hover"


def rotorpy_starts() -> list[RotorPyStart]:
    """The sweep of starts: rotor speeds around hover, an offset position, the circle, and exact hover."""
    w = hover_speed_rad_s() if rotorpy_version() else EXAMPLE_ROTOR_SPEED_RAD_S
    return [
        RotorPyStart("examples' 1788.53 rad/s"),
        RotorPyStart("hover -0.1 %", w * (1.0 - 1e-3)),
        RotorPyStart("hover +0.1 %", w * (1.0 + 1e-3)),
        RotorPyStart("hover -1 %", w * (1.0 - 1e-2)),
        RotorPyStart("hover +1 %", w * (1.0 + 1e-2)),
        RotorPyStart("offset (0.1, -0.1, -0.2) m", offset_m=(0.1, -0.1, -0.2)),
        RotorPyStart("circle r 1 m, 0.2 Hz", trajectory="circle"),
        RotorPyStart("exactly hover (slow RK45 case)", rotor_speed_rad_s=None),
    ]


def _rotorpy_setup(x0: np.ndarray, start: RotorPyStart | None = None):
    """Vehicle, SE3Control, trajectory, initial state and hover speed of a RotorPy run.

    ``start`` None: the hover target ``x0`` started exactly at the hover rotor speed (the first version of
    this benchmark, RotorPy's slowest case).
    """
    from rotorpy.controllers.quadrotor_control import SE3Control
    from rotorpy.trajectories.circular_traj import ThreeDCircularTraj
    from rotorpy.trajectories.hover_traj import HoverTraj
    from rotorpy.vehicles.multirotor import Multirotor

    qp = _crazyflie()
    w_hover = hover_speed_rad_s()
    start = start or RotorPyStart("exactly hover", rotor_speed_rad_s=None)
    w0 = w_hover if start.rotor_speed_rad_s is None else start.rotor_speed_rad_s
    state = {
        "x": x0 + np.asarray(start.offset_m),
        "v": np.zeros(3),
        "q": np.array([0.0, 0.0, 0.0, 1.0]),  # xyzw
        "w": np.zeros(3),
        "wind": np.zeros(3),
        "rotor_speeds": np.full(qp["num_rotors"], w0),
    }
    if start.trajectory == "circle":  # starts at the target: x(0) = centre + (r, 0, 0)
        r = CIRCLE_RADIUS_M
        trajectory = ThreeDCircularTraj(
            center=x0 - np.array([r, 0.0, 0.0]),
            radius=np.array([r, r, 0.0]),
            freq=np.array([CIRCLE_FREQ_HZ, CIRCLE_FREQ_HZ, 0.0]),
        )
    else:
        trajectory = HoverTraj(x0=x0.copy())
    vehicle = Multirotor(qp, initial_state=state)  # defaults: cmd_motor_speeds, aero=True, RK45
    return vehicle, SE3Control(qp), trajectory, state, w_hover


def rotorpy_environment(duration_s: float, x0: np.ndarray, start: RotorPyStart, sim_rate_hz: float = 1.0 / DT_S):
    """RotorPy's documented usage: ``Environment(vehicle, controller, trajectory, sim_rate).run(t_final)``.

    ``run`` calls ``simulate()`` (its default IMU, motion capture and null estimator, no wind) and builds its
    result and ``Plotter`` without plotting. Timed: the ``run`` call.

    Returns:
        ``wall_s``, ``rtf``, ``rtf_cpu``, ``final_pos_err_mm`` (against the trajectory's final point).
    """
    from rotorpy.environments import Environment

    vehicle, controller, trajectory, _, _ = _rotorpy_setup(x0, start)
    env = Environment(vehicle=vehicle, controller=controller, trajectory=trajectory, sim_rate=sim_rate_hz)
    tic, cpu0 = time.perf_counter(), time.process_time()
    result = env.run(t_final=duration_s, plot=False, animate_bool=False, verbose=False)
    wall, cpu = time.perf_counter() - tic, time.process_time() - cpu0
    err = np.linalg.norm(result["state"]["x"][-1] - result["flat"]["x"][-1]) * 1e3
    return {"wall_s": wall, "rtf": duration_s / wall, "rtf_cpu": duration_s / cpu, "final_pos_err_mm": float(err)}


def start_position() -> np.ndarray:
    _, sim = _quad_sim(0)
    return sim.default_start()[0]


def rotorpy_hover(duration_s: float, x0: np.ndarray | None = None) -> dict:
    """Hover RotorPy's Crazyflie with SE3Control, stepping ``Multirotor.step`` at 1 kHz (timed loop only)."""
    x0 = start_position() if x0 is None else x0
    vehicle, controller, trajectory, state, _ = _rotorpy_setup(x0)
    n = int(round(duration_s / DT_S))
    xs = [None] * n
    tic, cpu0 = time.perf_counter(), time.process_time()
    for k in range(n):
        t = k * DT_S
        control = controller.update(t, state, trajectory.update(t))
        state = vehicle.step(state, control, DT_S)
        xs[k] = state["x"]
    wall, cpu = time.perf_counter() - tic, time.process_time() - cpu0
    err = np.linalg.norm(np.asarray(xs) - x0, axis=1) * 1e3
    return {
        "wall_s": wall,
        "rtf": duration_s / wall,
        "rtf_cpu": duration_s / cpu,
        "final_pos_err_mm": float(err[-1]),
        "max_pos_err_mm": float(err.max()),
    }


def rotorpy_sim_only(duration_s: float, x0: np.ndarray | None = None) -> dict:
    """Step RotorPy's ``Multirotor`` alone under the constant hover speeds (timed loop only)."""
    x0 = start_position() if x0 is None else x0
    vehicle, _, _, state, w_hover = _rotorpy_setup(x0)
    control = {"cmd_motor_speeds": np.full(4, w_hover)}
    n = int(round(duration_s / DT_S))
    tic, cpu0 = time.perf_counter(), time.process_time()
    for _ in range(n):
        state = vehicle.step(state, control, DT_S)
    wall, cpu = time.perf_counter() - tic, time.process_time() - cpu0
    return {"wall_s": wall, "rtf": duration_s / wall, "rtf_cpu": duration_s / cpu}


def rotorpy_simulate(duration_s: float, x0: np.ndarray | None = None) -> dict:
    """RotorPy's own ``simulate()`` loop on the same hover (its default IMU, mocap and null estimator)."""
    from rotorpy.estimators.nullestimator import NullEstimator
    from rotorpy.sensors.external_mocap import MotionCapture
    from rotorpy.sensors.imu import Imu
    from rotorpy.simulate import simulate
    from rotorpy.wind.default_winds import NoWind
    from rotorpy.world import World

    x0 = start_position() if x0 is None else x0
    vehicle, controller, trajectory, state, _ = _rotorpy_setup(x0)
    rate = 1.0 / DT_S
    world = World.empty((-3.0, 3.0, -3.0, 3.0, -3.0, 3.0))
    imu = Imu(p_BS=np.zeros(3), R_BS=np.eye(3), sampling_rate=rate)
    mocap = MotionCapture(sampling_rate=rate, with_artifacts=False)
    tic, cpu0 = time.perf_counter(), time.process_time()
    simulate(world, state, vehicle, controller, trajectory, NoWind(), imu, mocap, NullEstimator(), duration_s, DT_S,
             0.25, use_mocap=False, terminate=False)  # fmt: skip
    wall, cpu = time.perf_counter() - tic, time.process_time() - cpu0
    return {"wall_s": wall, "rtf": duration_s / wall, "rtf_cpu": duration_s / cpu}
