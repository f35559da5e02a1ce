"""``omnirotor fly``: the interaction controller as a real-time node on the flight topics (issue 24).

The loop is :class:`omnirotor.fly.node.NodeLoop` around the flight director (:mod:`omnirotor.fly.director`).
``--mission-from-sim`` flies the task ``omnirotor sim --serve --task`` serves (its options, its clock);
otherwise the node waits for ``omnirotor ctl`` (arm, takeoff, goto, push, preset, land, disarm). Ctrl-C ends it
with the summary of its deadline accounting.
"""

from __future__ import annotations

import dataclasses
import json
import math
import signal
import sys
from pathlib import Path
from typing import Annotated

import typer

from omnirotor.cli import app, number_option
from omnirotor.cli.connection_options import (
    DomainId,
    Namespace,
    PlantSession,
    SessionId,
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
    n_cpus,
    transport_priority_option,
)
from omnirotor.errors import InputError
from omnirotor.safe_io import check_input_file

DEFAULT_NODE_ENDPOINT = "tcp/127.0.0.1:7448"
"""Where the node listens by default (loopback), for ``omnirotor ctl``."""
DEFAULT_PLANT_ENDPOINT = "tcp/127.0.0.1:7447"
"""Where the node connects by default: the plant's (``omnirotor sim --serve``, ``omnirotor px4-bridge``)."""
_Connect = connect_option(DEFAULT_PLANT_ENDPOINT)
_Listen = listen_option(DEFAULT_NODE_ENDPOINT)
_Cpu = cpu_option("the last one")
_FifoPriority = fifo_priority_option()
_TransportPriority = transport_priority_option()


def _director_factory(flight: str | None, overrides: list[str]):
    """``(controller, trajectory) -> FlightDirector`` of the flight logic, or a clear error where it is missing."""
    try:
        from omnirotor.fly.director import FlightDirector
        from omnirotor.fly.presets import load_fly_params
    except ImportError:
        raise InputError("the flight director (omnirotor.fly.director) is not installed in this tree") from None
    params = load_fly_params(flight, overrides) if flight is not None else load_fly_params(overrides=overrides)
    return lambda controller, trajectory: FlightDirector(controller, params, trajectory=trajectory)


@app.command()
def fly(
    mission_from_sim: Annotated[
        bool, typer.Option(help="Fly the task `omnirotor sim --serve --task` serves (its options and clock).")
    ] = False,
    connect: _Connect = None,
    listen: _Listen = None,
    zenoh_config: ZenohConfig = None,
    domain_id: DomainId = 0,
    namespace: Namespace = "",
    session_id: SessionId = None,
    plant_session: PlantSession = None,
    vehicle: Annotated[str, typer.Option(help="Vehicle preset or TOML file (interactive flight).")] = "omnirotor",
    config: Annotated[str | None, typer.Option(help="Controller parameters TOML file (interactive flight).")] = None,
    flight: Annotated[str | None, typer.Option(help="Flight parameters TOML file (limits, presets).")] = None,
    set_: Annotated[list[str] | None, typer.Option("--set", help="Flight parameter override key=value.")] = None,
    cpu: _Cpu = None,
    fifo_priority: _FifoPriority = 50,
    transport_priority: _TransportPriority = 0,
    maps: Annotated[
        Path | None, typer.Option(help="Wrench-map JSON of `omnirotor identify` (for `ctl map global|piecewise`).")
    ] = None,
    record: Annotated[
        Path | None, typer.Option(help="Record every period into this new ROS 2 bag folder (MCAP), streamed.")
    ] = None,
    foxglove: Annotated[bool, typer.Option(help="Serve the live view (Foxglove WebSocket) on loopback.")] = False,
    foxglove_port: Annotated[int, typer.Option(help="Port of the live view (0: any free one, said).")] = 8765,
    ctl_rate: Annotated[
        float | None,
        typer.Option(
            help="The most `omnirotor ctl` requests served per second (others answered busy) [default: 100; at "
            "most 1000].",
            parser=number_option,
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the exit summary as one JSON object.")] = False,
) -> None:
    """Run the interaction controller as the flight node (1 kHz, on the flight topics)."""
    from omnirotor.fly.node import CTL_RATE_HZ, MAX_CTL_RATE_HZ, NodeLoop, NodeOptions, fly_mission, warm_up
    from omnirotor.fly.node import mission_from_sim as ask
    from omnirotor.realtime import set_realtime, set_transport_priority
    from omnirotor.sitl.gate import new_session_id
    from omnirotor.transport import open_transport

    check_realtime_options(cpu, fifo_priority, transport_priority)
    ctl_rate = CTL_RATE_HZ if ctl_rate is None else ctl_rate
    if not (math.isfinite(ctl_rate) and 0.0 < ctl_rate <= MAX_CTL_RATE_HZ):
        raise InputError(f"--ctl-rate must be in (0, {MAX_CTL_RATE_HZ:g}] requests a second, got {ctl_rate}")
    session = session_id_arg(session_id, "--session-id")
    plant = session_id_arg(plant_session, "--plant-session")
    factory = _director_factory(flight, list(set_ or ()))
    if maps is not None:
        if mission_from_sim:
            raise InputError("--maps is for interactive flights; a mission flies the simulator's maps")
        check_input_file(maps, "--maps")
    from omnirotor.fly.record import output_options

    outputs = output_options(record, foxglove, foxglove_port)

    def say(line: str) -> None:
        print(f"omnirotor fly: {line}", file=sys.stderr)

    def realtime() -> None:  # in the loop's thread, its transport's publishers and subscribers declared
        set_transport_priority(transport_priority or None, say)
        set_realtime(cpu if cpu is not None else n_cpus() - 1, fifo_priority or None, say)

    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    args = transport_args(listen=listen, connect=connect, zenoh_config=zenoh_config, domain_id=domain_id,
                          namespace=namespace, default_listen=[DEFAULT_NODE_ENDPOINT],
                          default_connect=[DEFAULT_PLANT_ENDPOINT])  # fmt: skip
    listening = args["listen"]
    if session is None:
        session = new_session_id()
    say(f"controller session {session:016x} (a plant's --pair-session {session:016x} obeys this node only)")
    if plant is not None:
        say(f"following the sensor frames of plant session {plant:016x} only (--plant-session)")
    elif not mission_from_sim:  # a mission names its plant (below)
        say("following the first plant session that sends frames (first come; --plant-session pins one)")
    node_options = NodeOptions(session_id=session, plant_session=plant, ctl_rate_hz=ctl_rate, **outputs)
    with open_transport(**args, node="omnirotor_fly") as t:
        if mission_from_sim:
            task, options, lockstep, served_by = ask(t, timeout_s=30.0)
            if plant is not None and served_by is not None and served_by != plant:
                raise InputError(
                    f"the mission came from plant session {served_by:016x}, not the --plant-session {plant:016x} "
                    "(another simulator answered first; stop it, or follow that one)"
                )
            by = f", served by plant session {served_by:016x}" if served_by is not None else ""
            say(f"flying the simulator's mission: {task} ({'lockstep' if lockstep else 'real time'}){by}")
            node_options = dataclasses.replace(node_options, lockstep=lockstep)
            if plant is None and served_by is not None:  # the mission names its plant: pin it, not first come
                say(f"following the sensor frames of plant session {served_by:016x} only (the mission's plant)")
                node_options = dataclasses.replace(node_options, plant_session=served_by)
            elif plant is None:
                say("following the first plant session that sends frames (first come: the mission names no plant)")
            summary = fly_mission(t, task, options, node_options, factory, realtime)
        else:
            from omnirotor.control.controller import InteractionController, load_controller_params
            from omnirotor.vehicle import load_vehicle
            from omnirotor.wrench_maps import load_wrench_maps

            veh = load_vehicle(vehicle)
            params = load_controller_params(config) if config is not None else None
            wrench_maps = load_wrench_maps(str(maps), n_rotors=veh.n_rotors) if maps is not None else None
            controller = InteractionController(veh, params, wrench_maps)
            warm_up(controller)
            node = NodeLoop(t, controller, factory(controller, None), node_options)
            realtime()
            say(f"flight node up; `omnirotor ctl` on {', '.join(listening)}")
            summary = node.run()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C must not cut the summary short
    if as_json:
        print(json.dumps(summary))
        return
    _print_summary(summary)


def _print_summary(s: dict) -> None:
    lat = s.get("frame_to_command_us", {})
    print(
        f"frames {s['frames']}, periods {s['periods']}, late (> 0.5 ms) {s['periods_late']} "
        f"({s['late_per_1e5']:.1f} per 1e5), missed {s['missed']}, overruns {s['overruns']}, "
        f"worst lateness {s['worst_late_ms']:.2f} ms; frame to command p50 {lat.get('p50', float('nan')):.0f} µs, "
        f"p99 {lat.get('p99', float('nan')):.0f} µs; link lost: {s['link_lost']}"
    )
    plant, k = s.get("plant_session_id"), s.get("foreign_plant_sessions", 0)
    print(
        (f"plant session {plant} ({'pinned' if s.get('plant_session_pinned') else 'first come'})" if plant else
         "no plant session followed")
        + f"; frames of other plant sessions refused: {s.get('frames_foreign', 0)} (from {k} session"
        + ("" if k == 1 else "s") + ")"
    )  # fmt: skip
    imu = s.get("plant_imu")
    if imu and (imu["rate_off_episodes"] or imu["gaps"]):
        print(
            f"the plant's IMU: rate off {imu['rate_off_episodes']} time(s), {imu['rate_off_s']:.1f} s in all; "
            f"{imu['gaps']} gap(s), the worst {imu['worst_gap_ms']:.0f} ms"
        )
    req = s.get("requests")
    if req and (req["served"] or req["busy"] or req["bad"]):
        print(
            f"ctl requests: {req['served']} served, {req['busy']} answered busy (at most {req['rate_hz']:g} a "
            f"second), {req['bad']} malformed, {req['unserved']} not served in time"
        )
    rec = s.get("recording")
    if rec is not None:
        n = sum(rec.get("messages", {}).values())
        print(
            f"recording {rec['path']}: "
            + (rec["error"] if "error" in rec else f"{n} messages, {rec['dropped']} periods dropped")
        )
