"""``omnirotor sim --serve``: the simulator as a robot on the flight topics (software in the loop, issue 24).

See :mod:`omnirotor.sitl.server` for the topics, the clocks and the failsafe. With ``--task`` the server flies
that task of ``omnirotor run`` (same options) with the controller of ``omnirotor fly --mission-from-sim`` and
prints the run's metrics as ``omnirotor run`` does, plus what the wire counted (``sitl``). When the
offboard-loss failsafe cut a task, its metrics cannot be computed (they are over the whole protocol): it says why on
one line and exits 1 (with ``--json``: the wire's counts and ``"metrics": null``; with ``--out``: what was flown).
"""

from __future__ import annotations

import signal
from pathlib import Path
from typing import Annotated

import typer

from omnirotor.cli import app, number_option
from omnirotor.cli.connection_options import (
    DomainId,
    Namespace,
    PairSession,
    PlantSessionId,
    ZenohConfig,
    connect_option,
    listen_option,
    session_id_arg,
    transport_args,
)
from omnirotor.cli.realtime_options import (
    check_realtime_options,
    cpu_option,
    fifo_priority_option,
    transport_priority_option,
)
from omnirotor.errors import InputError
from omnirotor.safe_io import check_input_file, check_output_dir, dumps_json, note

DEFAULT_SIM_ENDPOINT = "tcp/127.0.0.1:7447"
"""Where the simulator listens by default (loopback)."""
_Listen = listen_option(DEFAULT_SIM_ENDPOINT)
_Connect = connect_option()
_Cpu = cpu_option()
_FifoPriority = fifo_priority_option("the real-time plant loop")
_TransportPriority = transport_priority_option()


@app.command()
def sim(
    serve: Annotated[
        bool, typer.Option("--serve", help="Serve the simulator on the flight topics (required).")
    ] = False,
    task: Annotated[
        str | None, typer.Option(help="Task of `omnirotor run` to fly (hover, sliding, ...); none: interactive.")
    ] = None,
    scene: Annotated[str, typer.Option(help="Scene of an interactive flight: free, wall, pipe, ...")] = "free",
    lockstep: Annotated[
        bool, typer.Option(help="Step k+1 only when command k arrived (deterministic); default: the wall clock.")
    ] = False,
    listen: _Listen = None,
    connect: _Connect = None,
    zenoh_config: ZenohConfig = None,
    domain_id: DomainId = 0,
    namespace: Namespace = "",
    pair_session: PairSession = None,
    session_id: PlantSessionId = None,
    ros_views: Annotated[
        bool, typer.Option(help="Also publish sensor_msgs/Imu, PoseStamped and RotorSpeeds every period.")
    ] = True,
    offboard_loss: Annotated[float, typer.Option(help="No command for this long stops the rotors [s].")] = 0.5,
    wait: Annotated[float, typer.Option(help="How long to wait for the controller's first command [s].")] = 60.0,
    cpu: _Cpu = None,
    fifo_priority: _FifoPriority = 0,
    transport_priority: _TransportPriority = 0,
    map_mode: Annotated[str, typer.Option("--map", help="Wrench map: nominal, global, piecewise.")] = "nominal",
    maps: Annotated[Path | None, typer.Option(help="Wrench-map JSON of `omnirotor identify`.")] = None,
    blend: Annotated[str, typer.Option(help="Piecewise region switching: hard or smooth.")] = "hard",
    seed: Annotated[int, typer.Option(help="Simulator noise and protocol seed.")] = 0,
    quick: Annotated[bool, typer.Option(help="Shortened protocol.")] = False,
    zero: Annotated[bool | None, typer.Option("--zero/--no-zero", help="Zero the observer at the start.")] = None,
    solver: Annotated[str, typer.Option(help="Allocation QP backend.")] = "active-set",
    estimator: Annotated[str, typer.Option(help="State estimator: ukf or bypass.")] = "ukf",
    duration: Annotated[float | None, typer.Option(parser=number_option, help="Simulated time [s].")] = None,
    truth: Annotated[str, typer.Option(help="Truth aerodynamics: wake, spec7, nominal.")] = "wake",
    disturbances: Annotated[bool, typer.Option(help="The simulator's calibrated disturbances.")] = True,
    vehicle: Annotated[str, typer.Option(help="Vehicle preset or TOML file.")] = "omnirotor",
    config: Annotated[str | None, typer.Option(help="Controller parameters TOML file.")] = None,
    set_: Annotated[list[str] | None, typer.Option("--set", help="Controller parameter override key=value.")] = None,
    out: Annotated[Path | None, typer.Option(help="Folder for the run's JSON and truth log (truth.npz).")] = None,
    record: Annotated[
        Path | None, typer.Option(help="Record the plant every period into this new ROS 2 bag folder (MCAP).")
    ] = None,
    foxglove: Annotated[bool, typer.Option(help="Serve the live view (Foxglove WebSocket) on loopback.")] = False,
    foxglove_port: Annotated[int, typer.Option(help="Port of the live view (0: any free one, said).")] = 8766,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Serve the MuJoCo plant on the flight topics for `omnirotor fly` (software in the loop)."""
    if not serve:
        raise InputError("omnirotor sim needs --serve (the simulator on the flight topics)")
    # SIGTERM ends it as Ctrl-C does: the summary (and a recording) finished, not cut off
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    from omnirotor.fly.record import output_options

    outputs = output_options(record, foxglove, foxglove_port)
    outputs["pair_session"] = session_id_arg(pair_session, "--pair-session")  # ServeOptions' fields
    outputs["session_id"] = session_id_arg(session_id, "--session-id")
    outputs["transport_priority"] = (transport_priority or None) if not lockstep else None
    if outputs["session_id"] is None:
        from omnirotor.sitl.gate import new_session_id

        outputs["session_id"] = new_session_id()
    if task is None:
        _serve_free(scene, seed, truth, disturbances, vehicle, listen, connect, zenoh_config, domain_id, namespace,
                    ros_views, offboard_loss, cpu, fifo_priority, transport_priority, outputs)  # fmt: skip
        return
    from omnirotor.experiments.tasks import TASKS
    from omnirotor.experiments.tasks.common import ExperimentOptions
    from omnirotor.sitl.server import ServeOptions
    from omnirotor.transport import open_transport

    if task not in TASKS:
        raise InputError(f"unknown task {task!r}; tasks: {', '.join(sorted(TASKS))}")
    if maps is not None:
        check_input_file(maps, "--maps")
    if out is not None:
        check_output_dir(out, "--out")
    options = ExperimentOptions(
        solver=solver, estimator=estimator, duration_s=duration, seed=seed, truth=truth, disturbances=disturbances,
        vehicle=vehicle, controller_config=config, overrides=tuple(set_ or ()), map_mode=map_mode,
        maps=str(maps) if maps is not None else None, blend=blend, quick=quick, zero_observer=zero,
    )  # fmt: skip
    options.controller_params()  # validate before opening anything
    check_realtime_options(cpu, fifo_priority, transport_priority)
    serve_opts = ServeOptions(
        lockstep=lockstep, offboard_loss_s=offboard_loss, start_timeout_s=wait, ros_views=ros_views, **outputs
    )
    args = transport_args(listen=listen, connect=connect, zenoh_config=zenoh_config, domain_id=domain_id,
                          namespace=namespace, default_listen=[DEFAULT_SIM_ENDPOINT])  # fmt: skip
    endpoints = args["listen"]
    with open_transport(**args, node="omnirotor_sim") as t:
        note(f"serving {task} on {', '.join(endpoints)} ({'lockstep' if lockstep else 'real time'}); waiting for "
             "`omnirotor fly --mission-from-sim`")  # fmt: skip
        _say_pairing(serve_opts.pair_session, serve_opts.session_id)
        from omnirotor.realtime import set_realtime

        if lockstep and (fifo_priority or transport_priority):  # paced by the commands: no real-time class
            note("--fifo-priority and --transport-priority are for real time: the lockstep plant runs at normal "
                 "priority")  # fmt: skip
        set_realtime(cpu, None if lockstep else (fifo_priority or None), note)
        result, report = _serve(t, task, options, serve_opts)
    if result is None:  # the failsafe cut the run: what the wire counted, and why there are no metrics
        _say_missing_rows(report)
        _say_recording(report.recording)
        note(
            f"the offboard-loss failsafe stopped the rotors after {report.failsafe_after_s:.3f} s without a "
            f"command; the task's metrics cannot be computed from the part flown ({report.metrics_error})"
        )
        cut = {"task": task, "metrics": None, "sitl": report.as_dict()}
        if out is not None and report.flown is not None:  # what was flown is kept, as a run's would be
            _write_run(out, task, cut, *report.flown)
            note(f"what was flown: {out / 'truth.npz'} and {out / 'controller.npz'}")
        if as_json:
            print(dumps_json(cut))
        raise typer.Exit(1)
    rep = result.summary()
    rep["sitl"] = report.as_dict()
    _say_missing_rows(report)
    _say_recording(report.recording)
    if report.failsafe:
        note(f"the offboard-loss failsafe stopped the rotors after {report.failsafe_after_s:.3f} s without a command")
    if out is not None:
        _write_run(out, task, rep, result.controller_log, result.truth_log)
    if as_json:
        print(dumps_json(rep))
        return
    s = report
    print(
        f"{task}: {s.steps} steps, real-time factor {s.real_time_factor:.2f}, commands obeyed {s.commands_obeyed}, "
        f"held {s.commands_held}, refused {s.commands_refused}; round trip p50 "
        f"{s.round_trip_us.get('p50', float('nan')):.0f} µs, p99 {s.round_trip_us.get('p99', float('nan')):.0f} µs"
    )


def _say_pairing(pinned: int | None, own: int) -> None:
    """The plant's own session and whom it obeys, said at its start."""
    note(f"plant session {own:016x} (a node's --plant-session {own:016x} follows this plant only)")
    if pinned is not None:
        note(f"obeying the rotor commands of controller session {pinned:016x} only (--pair-session)")
    else:
        note("obeying the first controller session that commands (first come; --pair-session pins one)")


def _serve(transport, task, options, serve_opts):
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from omnirotor.sitl.server import serve_task

    with Progress(
        TextColumn(f"[bold]{task}[/bold] on the wire"), BarColumn(), TextColumn("{task.percentage:>5.1f} %"),
        TimeElapsedColumn(), console=Console(stderr=True), transient=True,
    ) as bar:  # fmt: skip
        bar_id = bar.add_task(task, total=1.0)
        return serve_task(transport, task, options, serve_opts, progress=lambda f: bar.update(bar_id, completed=f))


def _serve_free(scene, seed, truth, disturbances, vehicle, listen, connect, zenoh_config, domain_id, namespace,
                ros_views, offboard_loss, cpu, fifo_priority, transport_priority, outputs) -> None:  # fmt: skip
    """Interactive flight: the plant on its stand until the node takes off (omnirotor.sitl.server.serve_free)."""
    from omnirotor.experiments.loop import task_sim_params
    from omnirotor.sim import SCENES, Simulator
    from omnirotor.sitl.server import ServeOptions, serve_free
    from omnirotor.transport import open_transport
    from omnirotor.vehicle import load_vehicle

    if scene not in SCENES:
        raise InputError(f"unknown scene {scene!r}; scenes: {', '.join(SCENES)}")
    check_realtime_options(cpu, fifo_priority, transport_priority)
    args = transport_args(listen=listen, connect=connect, zenoh_config=zenoh_config, domain_id=domain_id,
                          namespace=namespace, default_listen=[DEFAULT_SIM_ENDPOINT])  # fmt: skip
    sim = Simulator(load_vehicle(vehicle), scene=scene, params=task_sim_params(truth, disturbances), seed=seed)
    endpoints = args["listen"]
    serve_opts = ServeOptions(offboard_loss_s=offboard_loss, ros_views=ros_views, **outputs)
    with open_transport(**args, node="omnirotor_sim") as t:
        from omnirotor.realtime import set_realtime

        set_realtime(cpu, fifo_priority or None, note)
        note(f"serving the {scene} scene on {', '.join(endpoints)}, the vehicle on its stand until `omnirotor fly` "
             "takes off (`omnirotor ctl arm`, `takeoff`); Ctrl-C ends")  # fmt: skip
        _say_pairing(serve_opts.pair_session, serve_opts.session_id)
        report = serve_free(t, sim, serve_opts)
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C must not cut the summary short
    print(
        f"{report.steps} steps flown, real-time factor {report.real_time_factor:.2f}, commands obeyed "
        f"{report.commands_obeyed}, held {report.commands_held}, refused {report.commands_refused}"
        + (f"; offboard-loss failsafe after {report.failsafe_after_s:.3f} s" if report.failsafe else "")
    )
    _say_recording(report.recording)


def _write_run(out: Path, task: str, rep: dict, controller_log, truth_log) -> None:
    """The run's JSON and its two logs into ``out``."""
    from omnirotor.safe_io import make_dir, write_json_atomic

    make_dir(out, "--out")
    write_json_atomic(out / f"{task}-sitl.json", rep)
    truth_log.to_npz(out / "truth.npz")
    controller_log.to_npz(out / "controller.npz")


def _say_missing_rows(report) -> None:
    """The node's controller-log rows that did not arrive: stood in, or past the log's end (after a failsafe)."""
    missing, cut = report.log_rows_missing, report.log_rows_cut
    if missing > cut:
        note(f"{missing - cut} controller log rows did not arrive; the previous row stands in for each, at its own "
             "period's time")  # fmt: skip
    if cut:
        note(f"the controller log ends with the node's last row: the {cut} periods after it (the failsafe cut the "
             "run) have no controller row")  # fmt: skip


def _say_recording(rec: dict) -> None:
    if rec:
        n = sum(rec.get("messages", {}).values())
        note(f"recording {rec['path']}: " + (rec["error"] if "error" in rec else f"{n} messages, {rec['dropped']} "
                                                "periods dropped"))  # fmt: skip
