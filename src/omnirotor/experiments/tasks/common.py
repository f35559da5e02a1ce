"""The paper's experiments as tasks of ``omnirotor run`` (SPEC §3.4, §5; issue "Experiments").

Every task flies a :class:`~omnirotor.experiments.tasks.scenarios.Scenario` (or a hover schedule) in the simulator
with the interaction controller and returns an :class:`ExperimentResult` whose :meth:`~ExperimentResult.summary`
is the run's JSON: Table 1 errors (SPEC §6), contact and force metrics from the simulator's ground truth,
a task-specific verdict (``success``) and, for the hover tasks, per-region statistics. Tasks:

* ``identify-flights``: the hover data-collection protocol; writes ``hover_points.csv`` (the format of
  ``omnirotor identify``);
* ``hover-validation``: new random attitudes per region, the estimated external wrench in hover (Fig. 3);
* ``point-contact``, ``point-contact-tilted``, ``sliding``, ``peg-in-hole`` (SPEC §5.2);
* ``hover``: hold the free scene's start pose (the shortest task; campaigns use it to measure throughput).

The truth model is never changed per experiment: every task runs the same simulator parameters.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from omnirotor.config import apply_values
from omnirotor.control.admittance import AdmittanceParams
from omnirotor.control.controller import ControllerParams, InteractionController
from omnirotor.control.maps import MapParams
from omnirotor.control.trajectory import PoseTrajectory, Waypoint, capacity_for
from omnirotor.errors import InputError
from omnirotor.experiments.faults import PlantPerturbation, plant_simulator, safety_stats
from omnirotor.experiments.loop import (
    HOVER_DURATION_S,
    TaskOptions,
    TaskResult,
    run_closed_loop,
    run_log,
    task_sim_params,
    video_sink,
)
from omnirotor.experiments.metrics import (
    PEG_DEPTH_GOAL_CM,
    PEG_TILT_GOAL_DEG,
    RunLog,
    contact_stats,
    force_stats,
    held_contact,
    peg_depth_tilt,
    table1_errors,
)
from omnirotor.experiments.tasks.scenarios import (
    Scenario,
    ScenarioParams,
    hover_attitudes,
    hover_schedule,
    peg_in_hole,
    point_contact,
    point_contact_tilted,
    sliding,
)
from omnirotor.identification import write_csv
from omnirotor.regions import load_partition
from omnirotor.safe_io import note
from omnirotor.sim import SimParams, default_start_pose, scene_anchors
from omnirotor.so3 import project_to_SO3
from omnirotor.vehicle import VehicleParams, load_vehicle
from omnirotor.wrench_maps import WrenchMapSet, load_wrench_maps

__all__ = [
    "ExperimentOptions",
    "ExperimentResult",
    "MAP_MODES",
    "HoverProtocol",
    "CONTACT_TASKS",
    "HOVER_TASKS",
    "base_metrics",
]

MAP_MODES = ("nominal", "global", "piecewise")
CONTACT_TASKS = ("point-contact", "point-contact-tilted", "sliding", "peg-in-hole")
HOVER_TASKS = ("identify-flights", "hover-validation")
HOVER_SUCCESS_CM = 5.0
"""The ``hover`` task succeeds when the end effector stays within this distance per axis after settling [cm]."""
SETTLE_S = 1.0
"""Metrics start after this time [s]: the estimator and observer transients at start-up."""


@dataclasses.dataclass(frozen=True)
class HoverProtocol:
    """The hover protocols of SPEC §3.4 (identification) and §3.4 validation.

    Attributes:
        regions: regions visited (the paper flew R1, R3 and R4).
        points_per_region: identification attitudes per region (paper: about 15).
        validation_per_region: validation attitudes per region (paper: 5).
        transition_s: time to rotate to the next attitude [s] (paper: 3).
        hold_s: hold at each attitude [s] (paper: 5).
        average_from_s: the hold's statistics use its samples after this many seconds [s].
        min_speed_hz: attitudes whose nominal hover needs a rotor below this speed are rejected [Hz].
    """

    regions: tuple[str, ...] = ("R1", "R3", "R4")
    points_per_region: int = 15
    validation_per_region: int = 5
    transition_s: float = 3.0
    hold_s: float = 5.0
    average_from_s: float = 1.0
    min_speed_hz: float = 50.0

    @staticmethod
    def quick() -> HoverProtocol:
        """A shortened protocol for ``--quick`` runs (fewer, shorter holds)."""
        return HoverProtocol(points_per_region=7, validation_per_region=2, transition_s=2.0, hold_s=3.0)


@dataclasses.dataclass(frozen=True)
class ExperimentOptions(TaskOptions):
    """Options of the experiment tasks (on top of :class:`TaskOptions`).

    Attributes:
        map_mode: wrench map in the loop: "nominal", "global" or "piecewise" (SPEC §3.3).
        maps: wrench-map JSON (``omnirotor identify --out``); needed for global and piecewise.
        blend: region switching of the piecewise map, "hard" (paper) or "smooth".
        quick: shortened protocols (``reproduce --quick``).
        out_dir: folder for figures and data files, or None.
        zero_observer: zero the observer at the start attitude (SPEC §4.3 [A]); None: the task's default —
            on for the contact tasks, whose references the paper shows free of the start bias (the sliding
            contact loss comes from a ~1 N *jump*, SPEC §5.2), off for the hover tasks (Fig. 3 shows the raw bias).
        sim_overrides: dotted ``key=value`` overrides of the simulator parameters (e.g. ``aero.gamma=8``),
            applied to every run alike.
        scenario: protocol knobs of the contact tasks (None: the paper's, or the quick ones).
        protocol: the hover protocol (None: the paper's, or the quick one).
        plant: how the simulated plant differs from what the controller and the reference believe (mass,
            inertia, scene pose, plant-only simulator overrides, faults; see :mod:`omnirotor.experiments.faults`);
            None: the plant is the model.
        controller_values: ``(dotted key, value)`` pairs set on the controller parameters after ``overrides``,
            typed (a campaign's drawn values: :func:`omnirotor.config.apply_values`).
    """

    map_mode: str = "nominal"
    maps: str | None = None
    blend: str = "hard"
    quick: bool = False
    out_dir: str | None = None
    zero_observer: bool | None = None
    sim_overrides: tuple[str, ...] = ()
    scenario: ScenarioParams | None = None
    protocol: HoverProtocol | None = None
    plant: PlantPerturbation | None = None
    controller_values: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        super().__post_init__()
        self.sim_params()  # validate the overrides now
        if self.map_mode not in MAP_MODES:
            raise InputError(f"map must be one of {', '.join(MAP_MODES)}, got {self.map_mode!r}")
        if self.map_mode != "nominal" and self.maps is None:
            raise InputError(
                f"--map {self.map_mode} needs --maps FILE (from `omnirotor identify DATA --out FILE`, e.g. on the "
                "hover_points.csv of `omnirotor run identify-flights`)"
            )

    def controller_params(self, admittance: AdmittanceParams | None = None) -> ControllerParams:
        """:meth:`TaskOptions.controller_params`, then ``controller_values``."""
        return apply_values(super().controller_params(admittance), self.controller_values)

    def sim_params(self) -> SimParams:
        """Simulator parameters: the chosen truth aerodynamics, then ``sim_overrides``."""
        return task_sim_params(self.truth, self.disturbances, tuple(self.sim_overrides))

    def plant_sim_params(self) -> SimParams:
        """The simulator parameters of the true plant: :meth:`sim_params` perturbed by ``plant``."""
        params = self.sim_params()
        return params if self.plant is None else self.plant.sim_params(params)

    def load_maps(self, vehicle: VehicleParams) -> WrenchMapSet | None:
        """The wrench maps named by ``maps`` (None when not given)."""
        return None if self.maps is None else load_wrench_maps(self.maps, n_rotors=vehicle.n_rotors)


def _options(options: TaskOptions) -> ExperimentOptions:
    if isinstance(options, ExperimentOptions):
        return options
    return ExperimentOptions(**{f.name: getattr(options, f.name) for f in dataclasses.fields(TaskOptions)})


@dataclasses.dataclass
class ExperimentResult(TaskResult):
    """A task run and its metrics (:meth:`summary` is the run's JSON)."""

    metrics: dict = dataclasses.field(default_factory=dict)
    log: RunLog | None = None
    scenario: Scenario | None = None
    region_names: tuple[str, ...] = ()
    force_samples: dict[str, np.ndarray] | None = None
    """Hover validation: (k, 3) estimated world-force samples per region, for the violin figure."""

    def summary(self) -> dict:
        """The run's JSON object (see the module docstring)."""
        return self.metrics


def _task_map_params(configured: MapParams, opts: ExperimentOptions) -> MapParams:
    """The controller file's ``[maps]`` with the run's ``--map`` and ``--blend``; a file value replaced is said."""
    chosen = dataclasses.replace(configured, mode=opts.map_mode, blend=opts.blend)
    for field, option in (("mode", "--map"), ("blend", "--blend")):
        given, used = getattr(configured, field), getattr(chosen, field)
        if given != used and given != getattr(MapParams(), field):
            note(f"maps.{field} = {given!r} of the controller configuration replaced by {option} {used!r}")
    return chosen


def _controller(
    vehicle: VehicleParams,
    opts: ExperimentOptions,
    admittance: str,
    zero: bool,
    maps: WrenchMapSet | None,
    n_waypoints: int = 1,
) -> InteractionController:
    params = opts.controller_params(AdmittanceParams.preset(admittance))
    waypoints = max(params.trajectory_waypoints, capacity_for(n_waypoints))  # room for the run's trajectory
    params = dataclasses.replace(params, maps=_task_map_params(params.maps, opts), trajectory_waypoints=waypoints)
    zero = zero if opts.zero_observer is None else opts.zero_observer
    if zero and not params.observer.zero_at_start:
        params = dataclasses.replace(params, observer=dataclasses.replace(params.observer, zero_at_start=True))
    return InteractionController(vehicle, params, maps)


def _fly(
    vehicle: VehicleParams,
    opts: ExperimentOptions,
    scene: str,
    admittance: str,
    trajectory: PoseTrajectory,
    duration_s: float,
    progress: Callable[[float], None] | None,
    zero: bool,
):
    maps = opts.load_maps(vehicle)
    controller = _controller(vehicle, opts, admittance, zero, maps, len(trajectory.waypoints))
    # run_closed_loop resets the plant at the trajectory's start first: no reset at the scene's start before it
    sim = plant_simulator(vehicle, scene, opts.sim_params(), opts.seed, opts.plant, controller, reset=False)
    with video_sink(sim, opts.video) as video:
        ctl_log, truth_log = run_closed_loop(sim, controller, trajectory, duration_s, progress=progress, video=video)
    names = tuple(maps.partition.names) if maps is not None and opts.map_mode == "piecewise" else ()
    return ctl_log, truth_log, names


def _metrics_from(duration_s: float) -> float:
    """Time from which a run's EE errors count [s]: after settling; short runs, their second half."""
    return min(SETTLE_S, 0.5 * duration_s)


def base_metrics(
    task: str,
    opts: ExperimentOptions,
    log: RunLog,
    duration_s: float,
    step_us: np.ndarray,
    vehicle: VehicleParams,
    errors: dict[str, dict] | None = None,
) -> dict:
    """The metrics every task reports: its options, EE errors after settling, step time, flags, safety.

    ``errors``: the EE errors from :func:`_metrics_from` if computed already.
    """
    if errors is None:
        errors = table1_errors(log, log.t >= _metrics_from(duration_s))
    flags = log.status.astype(int)
    return {
        "task": task,
        "map": opts.map_mode,
        "blend": opts.blend,
        "seed": opts.seed,
        "quick": opts.quick,
        "truth": opts.truth,
        "observer_zeroed": bool(opts.zero_observer),
        "estimator": opts.estimator,
        "solver": opts.solver,
        "duration_s": duration_s,
        **errors,
        "controller_step_us_median": float(np.median(step_us)),
        "steps_flagged": int(np.count_nonzero(flags)),
        "map_switches": int(np.count_nonzero(np.diff(log.region))),
        "safety": safety_stats(log.omega_hz, log.status, vehicle),
    }


def _scenario_params(opts: ExperimentOptions) -> ScenarioParams:
    if opts.scenario is not None:
        return opts.scenario
    return ScenarioParams(segment_s=2.0, settle_s=1.0) if opts.quick else ScenarioParams()


def _run_contact(task: str, opts: TaskOptions, progress) -> ExperimentResult:
    opts = _options(opts)
    vehicle = load_vehicle(opts.vehicle)
    scene_params = opts.sim_params().scene
    builders = {
        "point-contact": point_contact,
        "point-contact-tilted": point_contact_tilted,
        "sliding": sliding,
        "peg-in-hole": peg_in_hole,
    }
    sp = _scenario_params(opts)
    scenario = builders[task](scene_params, sp, quick=opts.quick)
    duration = opts.duration_s if opts.duration_s is not None else scenario.duration_s
    traj = PoseTrajectory(list(scenario.waypoints))
    ctl_log, truth_log, names = _fly(
        vehicle, opts, scenario.scene, scenario.admittance, traj, duration, progress, zero=True
    )
    log = run_log(ctl_log, truth_log)
    m = base_metrics(task, opts, log, duration, truth_log.group("controller_step_us"), vehicle)
    m["observer_zeroed"] = True if opts.zero_observer is None else opts.zero_observer
    phase = log.window(*scenario.contact_phase)
    m["contact_phase_s"] = list(scenario.contact_phase)
    m["contact"] = contact_stats(log, phase)
    touching = phase & held_contact(log.in_contact, log.t)
    m["force"] = force_stats(log, touching)
    m.update(_task_verdict(task, log, phase, scenario, sp, vehicle, opts))
    result = ExperimentResult(
        task=task,
        options=opts,
        duration_s=duration,
        controller_log=ctl_log,
        truth_log=truth_log,
        metrics_from_s=SETTLE_S,
        metrics=m,
        log=log,
        scenario=scenario,
        region_names=names,
    )
    _figures(result)
    return result


def _task_verdict(task, log: RunLog, phase, scenario: Scenario, sp: ScenarioParams, vehicle, opts) -> dict:
    """Task-specific measurements and the ``success`` verdict."""
    c = contact_stats(log, phase)
    out: dict = {}
    if task.startswith("point-contact"):
        n = _surface_normal(task, opts)
        touching = phase & held_contact(log.in_contact, log.t)
        # the surface pushes the robot along its outward normal: that component is the contact force [N]
        fn = log.f_contact_W[touching] @ n if touching.any() else np.zeros(1)
        fe = log.f_ext_hat_W[touching] @ n if touching.any() else np.zeros(1)
        k = AdmittanceParams.preset(scenario.admittance).stiffness_pos[0]
        out["normal_force"] = {
            "true_mean_N": float(np.mean(fn)),
            "true_std_N": float(np.std(fn)),
            "true_max_N": float(np.max(fn)),
            "estimated_mean_N": float(np.mean(fe)),
            "expected_N": float(k * sp.penetration),
            "underestimate_N": float(np.mean(fn) - np.mean(fe)),
        }
        out["success"] = bool(not c["lost"] and c["fraction"] > 0.95)
    elif task == "sliding":
        out["success"] = bool(not c["lost"] and c["fraction"] > 0.9)
    elif task == "peg-in-hole":
        scene = opts.plant_sim_params().scene  # the true hole, wherever the plan thought it was
        depth, tilt = peg_depth_tilt(log, scene.hole_entrance)
        inserted = log.window(scenario.waypoints[5].t, scenario.waypoints[6].t)
        approach = log.window(scenario.waypoints[2].t, scenario.waypoints[3].t)
        out["insertion"] = {
            "max_depth_m": float(depth.max()),
            "target_depth_m": sp.peg_insertion,
            "approach_tilt_deg": float(tilt[approach].mean()) if approach.any() else None,
            "inserted_tilt_deg": float(tilt[inserted].mean()) if inserted.any() else None,
            "commanded_misalignment_deg": sp.peg_misalignment_deg,
        }
        out["success"] = bool(depth.max() >= 0.9 * sp.peg_insertion)
    return out


def _surface_normal(task: str, opts: ExperimentOptions) -> np.ndarray:
    scene = opts.sim_params().scene
    if task == "point-contact":
        n = np.asarray(scene.wall_normal, dtype=float)
        return n / np.linalg.norm(n)
    a = math.radians(scene.tilted_wall_angle_deg)
    return np.array([0.0, math.cos(a), -math.sin(a)])


def _figures(result: ExperimentResult) -> None:
    opts = result.options
    if not isinstance(opts, ExperimentOptions) or opts.out_dir is None or result.log is None:
        return
    from omnirotor.experiments.figures import PegPanel, plot_run

    marks = result.scenario.marks if result.scenario is not None else ()
    title = f"{result.task} — {opts.map_mode} map"
    path = Path(opts.out_dir) / f"{result.task}-{opts.map_mode}.png"
    normal = result.metrics.get("normal_force")
    peg = None
    if result.task == "peg-in-hole":
        depth, tilt = peg_depth_tilt(result.log, opts.plant_sim_params().scene.hole_entrance)
        target = result.metrics["insertion"]["target_depth_m"]
        peg = PegPanel(depth, tilt, target, PEG_DEPTH_GOAL_CM / 100.0, PEG_TILT_GOAL_DEG)
    plot_run(
        result.log,
        title,
        path,
        marks=marks,
        region_names=result.region_names,
        force_target_N=normal["expected_N"] if normal else None,
        peg=peg,
    )
    result.metrics["figure"] = str(path)


def point_contact_task(options: TaskOptions, progress=None) -> ExperimentResult:
    """Push on the wall with the tool tip (SPEC §5.2)."""
    return _run_contact("point-contact", options, progress)


def point_contact_tilted_task(options: TaskOptions, progress=None) -> ExperimentResult:
    """Push on the 30° surface (SPEC §5.2)."""
    return _run_contact("point-contact-tilted", options, progress)


def sliding_task(options: TaskOptions, progress=None) -> ExperimentResult:
    """Slide over the pipe to 45° of roll and back (SPEC §5.2)."""
    return _run_contact("sliding", options, progress)


def peg_in_hole_task(options: TaskOptions, progress=None) -> ExperimentResult:
    """Insert the peg into the hole (SPEC §5.2)."""
    return _run_contact("peg-in-hole", options, progress)


# -- hover protocols ------------------------------------------------------------------------------------------


def _hover_run(opts: TaskOptions, progress, seed_offset: int, per_region_attr: str) -> tuple:
    opts = _options(opts)
    vehicle = load_vehicle(opts.vehicle)
    proto = opts.protocol or (HoverProtocol.quick() if opts.quick else HoverProtocol())
    partition = load_partition("paper")
    rng = np.random.default_rng([opts.seed, seed_offset])
    attitudes = hover_attitudes(
        partition, list(proto.regions), getattr(proto, per_region_attr), rng, vehicle, proto.min_speed_hz
    )
    scene = opts.sim_params().scene
    p_body, _ = default_start_pose(scene_anchors("free", scene), vehicle, scene)
    wps, holds = hover_schedule(attitudes, p_body, vehicle, proto.transition_s, proto.hold_s)
    duration = wps[-1].t + 0.5
    ctl_log, truth_log, names = _fly(
        vehicle, opts, "free", "free", PoseTrajectory(list(wps)), duration, progress, zero=False
    )
    log = run_log(ctl_log, truth_log)
    windows = [(name, log.window(t0 + proto.average_from_s, t1)) for name, t0, t1 in holds]
    return opts, vehicle, proto, log, ctl_log, truth_log, windows, duration, attitudes


def identify_flights(options: TaskOptions, progress=None) -> ExperimentResult:
    """Fly the identification protocol and write ``hover_points.csv`` into the out folder (SPEC §3.4).

    Each point is the mean rotor speed and the mean estimated attitude over the settled part of a hold. The
    rotor speeds are the simulator's true speeds (its speed sensor adds white noise of 0.5 Hz, which the
    average removes). The controller flies the nominal map, as the authors' did.
    """
    opts, vehicle, proto, log, ctl_log, truth_log, windows, duration, attitudes = _hover_run(
        options, progress, 1, "points_per_region"
    )
    rotor = truth_log.group("rotor_hz")[: log.t.size]
    R_est = ctl_log.group("R_WB")[: log.t.size].reshape(-1, 3, 3)
    Rs, speeds, names = [], [], []
    for name, mask in windows:
        Rs.append(project_to_SO3(R_est[mask].mean(axis=0)))
        speeds.append(rotor[mask].mean(axis=0))
        names.append(name)
    m = base_metrics("identify-flights", opts, log, duration, truth_log.group("controller_step_us"), vehicle)
    m["points"] = {r: names.count(r) for r in proto.regions}
    m["success"] = bool(len(names) == len(attitudes) and all(np.all(np.isfinite(s)) for s in speeds))
    if opts.out_dir is not None:
        path = Path(opts.out_dir) / "hover_points.csv"
        write_csv(path, Rs, np.array(speeds))
        m["hover_points_csv"] = str(path)
    return ExperimentResult(
        task="identify-flights",
        options=opts,
        duration_s=duration,
        controller_log=ctl_log,
        truth_log=truth_log,
        metrics=m,
        log=log,
    )


def hover_validation(options: TaskOptions, progress=None) -> ExperimentResult:
    """Hover at new random attitudes per region and record the estimated external wrench (paper Fig. 3).

    No external wrench acts: whatever the observer reports is model error seen through the map in use.
    """
    opts, vehicle, proto, log, ctl_log, truth_log, windows, duration, _ = _hover_run(
        options, progress, 2, "validation_per_region"
    )
    m = base_metrics("hover-validation", opts, log, duration, truth_log.group("controller_step_us"), vehicle)
    regions = {}
    samples = {}
    for r in proto.regions:
        mask = np.zeros(log.t.size, dtype=bool)
        for name, w in windows:
            if name == r:
                mask |= w
        if not mask.any():
            continue
        f, mo = log.f_ext_hat_W[mask], log.m_ext_hat_B[mask]
        # one mean per attitude: their spread is what a map can change (the samples' spread adds the noise)
        f_att = np.array([log.f_ext_hat_W[w].mean(axis=0) for name, w in windows if name == r])
        m_att = np.array([log.m_ext_hat_B[w].mean(axis=0) for name, w in windows if name == r])
        regions[r] = {
            "force_W_mean_N": f.mean(axis=0).tolist(),
            "force_W_std_N": f.std(axis=0).tolist(),
            "force_W_std_over_attitudes_N": f_att.std(axis=0).tolist(),
            "moment_B_mean_Nm": mo.mean(axis=0).tolist(),
            "moment_B_std_Nm": mo.std(axis=0).tolist(),
            "moment_B_std_over_attitudes_Nm": m_att.std(axis=0).tolist(),
            "moment_B_per_attitude_Nm": m_att.tolist(),
            "attitudes": sum(1 for name, _ in windows if name == r),
        }
        samples[r] = f[:: max(1, f.shape[0] // 400)]
    m["regions"] = regions
    m["success"] = bool(m["steps_flagged"] == 0)
    return ExperimentResult(
        task="hover-validation",
        options=opts,
        duration_s=duration,
        controller_log=ctl_log,
        truth_log=truth_log,
        metrics=m,
        log=log,
        force_samples=samples,
    )


def hover(options: TaskOptions, progress=None) -> ExperimentResult:
    """Start at rest at the free scene's start pose and hold it (free-flight admittance), on the true plant.

    The summary is :meth:`TaskResult.summary`'s with the experiment fields (map, safety) and ``success``: every
    position error within :data:`HOVER_SUCCESS_CM` after the settling time.
    """
    opts = _options(options)
    vehicle = load_vehicle(opts.vehicle)
    scene = opts.sim_params().scene
    p_body, R_WB = default_start_pose(scene_anchors("free", scene), vehicle, scene)
    duration = opts.duration_s if opts.duration_s is not None else HOVER_DURATION_S
    trajectory = PoseTrajectory([Waypoint(0.0, p_body + R_WB @ vehicle.p_E_B_array, R_WB)])
    ctl_log, truth_log, _ = _fly(vehicle, opts, "free", "free", trajectory, duration, progress, zero=False)
    result = ExperimentResult(
        task="hover",
        options=opts,
        duration_s=duration,
        controller_log=ctl_log,
        truth_log=truth_log,
        metrics_from_s=_metrics_from(duration),
    )
    log = run_log(ctl_log, truth_log)
    errors = table1_errors(log, log.t >= result.metrics_from_s)  # once, for both parts of the summary
    m = result.summary_of(log, errors)
    m.update(base_metrics("hover", opts, log, duration, truth_log.group("controller_step_us"), vehicle, errors))
    m["success"] = bool(max(m["ee_max_error"][a] for a in ("x_cm", "y_cm", "z_cm")) <= HOVER_SUCCESS_CM)
    result.metrics = m
    return result
