"""``omnirotor run TASK``: fly one task in closed loop in the simulator and report its metrics.

Tasks: ``hover`` and the paper's experiments (``identify-flights``, ``hover-validation``, ``point-contact``,
``point-contact-tilted``, ``sliding``, ``peg-in-hole``), from :data:`omnirotor.experiments.tasks.TASKS`.
Errors are those of SPEC §6 (the believed EE pose against the compliant EE reference, as the paper's; the
true pose's too).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from omnirotor.cli import app, number_option
from omnirotor.cli.texts import VEHICLE_HELP
from omnirotor.errors import InputError
from omnirotor.safe_io import check_input_file, check_output_dir, check_output_file, dumps_json, note


@app.command()
def run(
    task: Annotated[
        str,
        typer.Argument(
            help="Task: hover (free hover); identify-flights (the hover protocol of SPEC §3.4, writes "
            "hover_points.csv); hover-validation (the paper's Fig. 3); point-contact, point-contact-tilted, "
            "sliding, peg-in-hole (SPEC §5.2); identify-dynamic, identify-dynamic-cells (attitude-sweep flights "
            "for identify --torque)."
        ),
    ],
    map_mode: Annotated[str, typer.Option("--map", help="Wrench map in the loop: nominal, global, piecewise.")] = (
        "nominal"
    ),
    maps: Annotated[
        Path | None, typer.Option(help="Wrench-map JSON of `omnirotor identify` (global/piecewise).")
    ] = None,
    blend: Annotated[str, typer.Option(help="Piecewise region switching: hard (paper) or smooth.")] = "hard",
    seed: Annotated[int, typer.Option(help="Simulator noise and protocol seed.")] = 0,
    out: Annotated[Path | None, typer.Option(help="Folder for the run's JSON, figures and data files.")] = None,
    quick: Annotated[bool, typer.Option(help="Shortened protocol.")] = False,
    zero: Annotated[
        bool | None,
        typer.Option("--zero/--no-zero", help="Zero the observer at the start attitude (default: per task)."),
    ] = None,
    solver: Annotated[
        str, typer.Option(help="Allocation QP backend: active-set (compiled, default), daqp or proxsuite.")
    ] = "active-set",
    estimator: Annotated[str, typer.Option(help="State estimator: ukf or bypass (truth plus noise).")] = "ukf",
    duration: Annotated[
        float | None, typer.Option(parser=number_option, help="Simulated time [s]; default: the task's.")
    ] = None,
    truth: Annotated[str, typer.Option(help="Truth aerodynamics: wake, spec7 (= interference), nominal.")] = "wake",
    disturbances: Annotated[
        bool, typer.Option(help="The simulator's calibrated disturbances (docs/fidelity.md); off: a clean plant.")
    ] = True,
    vehicle: Annotated[str, typer.Option(help=VEHICLE_HELP)] = "omnirotor",
    config: Annotated[str | None, typer.Option(help="Controller parameters TOML file.")] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option("--set", help="Controller parameter override key=value (repeatable), e.g. observer.cutoff_hz=5."),
    ] = None,
    video: Annotated[str | None, typer.Option(help="Film the run into this MP4 file (offscreen rendering).")] = None,
    ulog: Annotated[
        Path | None, typer.Option(help="Write the flight as a PX4 ULog (Flight Review, PlotJuggler, identify).")
    ] = None,
    mcap: Annotated[Path | None, typer.Option(help="Write the flight as MCAP with Foxglove schemas.")] = None,
    rosbag: Annotated[
        Path | None,
        typer.Option(
            help="Write the flight as a ROS 2 bag folder (MCAP storage) with the types the flight node publishes "
            "(ros2 bag, PlotJuggler, identify)."
        ),
    ] = None,
    vehicle_overlay: Annotated[
        Path | None, typer.Option(help="TOML of what a PX4 vehicle does not store (mass, inertia, c_f, ...).")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Fly TASK in the simulator with the interaction controller; print its metrics."""
    from omnirotor.experiments.tasks import TASKS
    from omnirotor.experiments.tasks.common import ExperimentOptions

    if task not in TASKS:
        raise InputError(f"unknown task {task!r}; tasks: {', '.join(sorted(TASKS))}")
    if maps is not None:
        check_input_file(maps, "--maps")
    if out is not None:
        check_output_dir(out, "--out")
    if video is not None and not video.lower().endswith(".mp4"):
        raise InputError(f"--video {video}: expected a .mp4 file name")
    if video is not None and check_output_file(video, "--video"):
        note(f"--video {video}: the existing file will be replaced")
    for flag, target, suffix in (("--ulog", ulog, ".ulg"), ("--mcap", mcap, ".mcap")):
        if target is not None and (target.suffix.lower() != suffix or target.is_dir()):
            raise InputError(f"{flag} {target}: expected a {suffix} file name")
        if target is not None and check_output_file(target, flag):
            note(f"{flag} {target}: the existing file will be replaced")
    if rosbag is not None:
        from omnirotor.px4.rosbag_io import is_rosbag

        if rosbag.exists() and not is_rosbag(rosbag):
            raise InputError(f"--rosbag {rosbag}: exists and is not a ROS 2 bag folder")
        if rosbag.exists():
            note(f"--rosbag {rosbag}: the existing bag will be replaced")
    if vehicle_overlay is not None:
        from omnirotor.vehicle import load_vehicle, vehicle_spec

        vehicle = vehicle_spec(vehicle, vehicle_overlay)
        load_vehicle(vehicle)  # validate the vehicle and its overlay before flying
    if blend not in ("hard", "smooth"):
        raise InputError(f"--blend must be hard or smooth, got {blend!r}")
    options = ExperimentOptions(
        solver=solver,
        estimator=estimator,
        duration_s=duration,
        seed=seed,
        truth=truth,
        disturbances=disturbances,
        vehicle=vehicle,
        controller_config=config,
        overrides=tuple(set_ or ()),
        video=video,
        map_mode=map_mode,
        maps=str(maps) if maps is not None else None,
        blend=blend,
        quick=quick,
        out_dir=str(out) if out is not None else None,
        zero_observer=zero,
    )
    from omnirotor.safe_io import make_dir, route_mujoco_log
    from omnirotor.vehicle import load_vehicle

    veh = load_vehicle(vehicle)  # validate the vehicle, parameters and map file before flying
    options.controller_params()
    if options.maps is not None:
        options.load_maps(veh)
    new_folder = out is not None and not out.exists()
    if out is not None:
        make_dir(out, "--out")
    route_mujoco_log(out)  # MuJoCo's log goes under --out, or nowhere
    try:
        result = _fly(task, map_mode, options)
    except InputError:
        if new_folder and not any(out.iterdir()):
            out.rmdir()  # bad input found while setting up the run: leave nothing behind
        raise
    rep = result.summary()
    raised = rep.get("safety", {}).get("flags", {}).get("mocap_noise_raised", 0)
    if raised:
        note(
            f"the estimator found motion capture noisier than configured and weighed it so in {raised} of "
            f"{rep['safety']['steps']} steps: set estimator.mocap_pos_std / mocap_att_std_deg to the system's noise"
        )
    flags = rep.get("safety", {}).get("flags", {})
    if flags.get("failsafe", 0):
        note(
            f"the controller's failsafe took over (held, then landed) in {flags['failsafe']} steps: a sensor was "
            "lost for too long (the log's frame_reject says which); the task's metrics include the landing"
        )
    if flags.get("bias_beyond_range", 0):
        note(
            f"an estimated IMU bias was beyond the range the estimator follows in {flags['bias_beyond_range']} "
            "steps (accelerometer 3 m/s², gyroscope 0.5 rad/s)"
        )
    if out is not None:
        from omnirotor.safe_io import write_json_atomic

        write_json_atomic(out / f"{task}-{map_mode}.json", rep)
    if ulog is not None or mcap is not None or rosbag is not None:
        _export(result, options, ulog, mcap, rosbag)
    if as_json:
        print(dumps_json(rep))
        return
    _print_table(task, rep)


def _fly(task: str, map_mode: str, options):
    """Run the task under a progress bar on stderr; returns its result."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from omnirotor.experiments.tasks import run_task

    err = Console(stderr=True)
    with Progress(
        TextColumn(f"[bold]{task}[/bold] ({map_mode} map)"),
        BarColumn(),
        TextColumn("{task.percentage:>5.1f} %"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=True,
    ) as bar:
        bar_id = bar.add_task(task, total=1.0)
        result = run_task(task, options, progress=lambda frac: bar.update(bar_id, completed=frac))
    return result


def _export(result, options, ulog: Path | None, mcap: Path | None, rosbag: Path | None = None) -> None:
    """Write the run as ULog, MCAP and/or a ROS 2 bag (omnirotor.px4.run_export, omnirotor.px4.rosbag_io)."""
    from omnirotor.px4.mcap_export import write_run_mcap
    from omnirotor.px4.run_export import run_signals, write_run_ulog
    from omnirotor.vehicle import load_vehicle

    vehicle = load_vehicle(options.vehicle)
    signals = run_signals(result.controller_log, result.truth_log, rate_hz=100.0)
    if ulog is not None:
        write_run_ulog(ulog, signals, vehicle, task=result.task)
    if mcap is not None:
        scenario = getattr(result, "scenario", None)
        scene = scenario.scene if scenario is not None else "free"
        write_run_mcap(mcap, signals, vehicle, scene, options.sim_params().scene)
    if rosbag is not None:
        from omnirotor.px4.rosbag_io import write_run_rosbag

        write_run_rosbag(rosbag, signals, vehicle)


def _print_table(task: str, rep: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console()
    table = Table(title=f"{task}: {rep['duration_s']:.1f} s simulated, {rep.get('map', 'nominal')} map")
    table.add_column("EE error")
    for name in ("x (cm)", "y (cm)", "z (cm)", "roll (deg)", "pitch (deg)", "yaw (deg)"):
        table.add_column(name, justify="right")
    rows = (("RMS", "ee_rms_error"), ("max", "ee_max_error"), ("RMS, true", "ee_rms_error_true"))
    for label, key in rows:
        if key in rep:
            table.add_row(label, *(f"{v:.3f}" for v in rep[key].values()))
    con.print(table)
    if "contact" in rep:
        c, f = rep["contact"], rep["force"]
        con.print(
            f"contact: {100 * c['fraction']:.0f} % of the contact phase, lost: {c['lost']}"
            + (f" (first at {c['first_loss_s']:.1f} s)" if c["first_loss_s"] is not None else "")
        )
        if f["true_mean_N"] is not None:
            tm = ", ".join(f"{x:+.2f}" for x in f["true_mean_N"])
            em = ", ".join(f"{x:+.2f}" for x in f["estimated_mean_N"])
            con.print(f"force while touching (world, N): true ({tm}), estimated ({em})")
    if "insertion" in rep:
        i = rep["insertion"]
        con.print(f"insertion depth {100 * i['max_depth_m']:.1f} cm of {100 * i['target_depth_m']:.0f} cm")
    if "regions" in rep:
        for r, v in rep["regions"].items():
            con.print(f"{r}: estimated f^W mean (" + ", ".join(f"{x:+.2f}" for x in v["force_W_mean_N"]) + ") N")
    if "success" in rep:
        con.print(f"success: {rep['success']}")
    con.print(
        f"controller step: median {rep['controller_step_us_median']:.1f} µs; steps flagged: {rep['steps_flagged']}"
    )
