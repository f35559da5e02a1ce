"""``omnirotor px4-bridge``: the flight node and a PX4 vehicle over PX4's Zenoh bridge (docs/fly.md).

:class:`omnirotor.fly.bridge.Px4Bridge` between the node's topics (``--namespace``) and PX4's (``--px4-namespace``),
in one Zenoh session when the two namespaces are equal: the node's rotor commands to PX4, and (unless
``--no-frames``) PX4's IMU, ESC telemetry and the motion capture into the node's sensor frames. Frames are on by
default because a node on a PX4 robot has no other source of them; ``--no-frames`` is for a robot whose own driver
publishes ``/omnirotor/frame`` (two frame publishers would interleave their numbers). Ctrl-C (or SIGTERM) stops the
motors, disarms PX4 if the node had it armed, and prints what the bridge counted. PX4's IMU at another rate than
the node's (``--rate-hz``): one line on stderr and exit status 2, before any frame or command is bridged; later in
the flight, a rate off for longer than a second, and gaps, are said and counted (frames go on). ``--cpu`` and
``--fifo-priority`` pin the bridge's threads and ask for ``SCHED_FIFO`` (:func:`omnirotor.realtime.set_realtime`;
a refusal is said in one line and the bridge runs on at normal priority).

The node's side and PX4's side share one set of connection options (``--connect``, ``--zenoh-config``: one Zenoh
network) unless ``--px4-connect`` or ``--px4-zenoh-config`` is given: PX4's side then has a session of its own
with those (a plain one without ``--px4-zenoh-config``), so that the node's side can require a login or mutual TLS
with access control (examples/zenoh-auth/, examples/zenoh-tls/: ``plant.json5``) that PX4's own Zenoh peer, on its
link to the flight controller, is not asked for (docs/transport.md, "On a shared network").
"""

from __future__ import annotations

import contextlib
import json
import math
import signal
import sys
from typing import Annotated

import typer

from omnirotor.cli import app
from omnirotor.cli.connection_options import (
    DomainId,
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

_Connect = connect_option("tcp/127.0.0.1:7448", "the node's, and PX4's unless --px4-connect or --px4-zenoh-config")
_Px4Connect = connect_option(what="PX4's Zenoh peer or router, in a session of PX4's side's own")
_Px4ZenohConfig = Annotated[
    str | None,
    typer.Option(
        help="Zenoh configuration file (JSON5) of PX4's side's own session (its login or TLS, if any); without it "
        "and without --px4-connect PX4's side shares the node's session options (--zenoh-config)."
    ),
]
_Listen = listen_option()
_Cpu = cpu_option()
_FifoPriority = fifo_priority_option("the bridge's threads")
_TransportPriority = transport_priority_option()


@app.command("px4-bridge")
def px4_bridge(
    connect: _Connect = None,
    listen: _Listen = None,
    zenoh_config: ZenohConfig = None,
    domain_id: DomainId = 0,
    namespace: Annotated[str, typer.Option(help="ROS 2 namespace of the node's topics, e.g. /robot1.")] = "",
    px4_namespace: Annotated[str, typer.Option(help="ROS 2 namespace of PX4's topics (its bridge's).")] = "",
    px4_connect: _Px4Connect = None,
    px4_zenoh_config: _Px4ZenohConfig = None,
    pair_session: PairSession = None,
    session_id: PlantSessionId = None,
    vehicle: Annotated[str, typer.Option(help="Vehicle preset or TOML file (rotors, speed limits).")] = "omnirotor",
    command_loss: Annotated[float, typer.Option(help="No command for this long stops the motors [s].")] = 0.5,
    frames: Annotated[
        bool,
        typer.Option(
            "--frames/--no-frames",
            help="Assemble the node's sensor frames from PX4 (one per IMU sample); --no-frames when another driver "
            "publishes /omnirotor/frame.",
        ),
    ] = True,
    mocap: Annotated[
        str,
        typer.Option(
            help="Motion capture of the frames: 'pose' (geometry_msgs/msg/PoseStamped on --mocap-topic, the mocap "
            "driver's: z-up world = the node's W, FLU body, stamps on a clock synchronised with this host) or "
            "'odometry' (PX4's /fmu/out/vehicle_odometry: NED world, FRD body, converted to NWU/FLU).",
        ),
    ] = "pose",
    mocap_topic: Annotated[
        str, typer.Option(help="The PoseStamped topic of --mocap pose, in the node's namespace.")
    ] = "/omnirotor/mocap",
    rate_hz: Annotated[
        float,
        typer.Option(
            help="The node's control rate [Hz] (its controller's 1/dt): PX4's IMU (sensor_combined), measured over "
            "its first second, must publish within 5 % of it, else exit 2; watched for the whole flight after that "
            "(a rate off for over 1 s, and gaps over 20 ms, are said and counted; frames go on)."
        ),
    ] = 1000.0,
    esc_timeout: Annotated[
        float, typer.Option(help="ESC telemetry older than this reads NaN in the frames [s of PX4's time].")
    ] = 0.1,
    cpu: _Cpu = None,
    fifo_priority: _FifoPriority = 0,
    transport_priority: _TransportPriority = 0,
    as_json: Annotated[bool, typer.Option("--json", help="Print the exit summary as one JSON object.")] = False,
) -> None:
    """Bridge the flight node and PX4: commands to ActuatorMotors, PX4's sensors to the node's frames.

    The node's rotor commands go to PX4 in offboard direct actuator control; PX4's IMU, ESC telemetry and the
    motion capture come back as the node's sensor frames (docs/fly.md, "PX4").
    """
    from omnirotor.fly.bridge import BridgeOptions, FrameOptions, Px4Bridge
    from omnirotor.realtime import set_realtime, set_transport_priority
    from omnirotor.transport import open_transport
    from omnirotor.vehicle import load_vehicle

    check_realtime_options(cpu, fifo_priority, transport_priority)
    pinned = session_id_arg(pair_session, "--pair-session")
    own = session_id_arg(session_id, "--session-id")

    def say(line: str) -> None:
        print(f"omnirotor px4-bridge: {line}", file=sys.stderr)

    options = BridgeOptions(command_loss_s=command_loss, pair_session=pinned, session_id=own)
    frame_options = (
        FrameOptions(mocap=mocap, mocap_topic=mocap_topic, rate_hz=rate_hz, esc_timeout_s=esc_timeout)
        if frames
        else None
    )
    veh = load_vehicle(vehicle)
    if veh.n_rotors > 12:
        raise InputError(f"PX4 drives at most 12 motors, the vehicle has {veh.n_rotors}")
    args = transport_args(listen=listen, connect=connect, zenoh_config=zenoh_config, domain_id=domain_id,
                          namespace=namespace, default_connect=["tcp/127.0.0.1:7448"])  # fmt: skip
    if px4_connect or px4_zenoh_config is not None:  # PX4's side in a session of its own (module docstring)
        px4_args = transport_args(listen=None, connect=px4_connect, zenoh_config=px4_zenoh_config,
                                  domain_id=domain_id, namespace=px4_namespace)  # fmt: skip
    elif px4_namespace != namespace:
        px4_args = {**args, "namespace": px4_namespace, "listen": []}
    else:
        px4_args = None  # one session for both sides
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    with contextlib.ExitStack() as stack:
        node = stack.enter_context(open_transport(**args, node="omnirotor_px4_bridge"))
        px4 = node
        if px4_args is not None:
            px4 = stack.enter_context(open_transport(**px4_args, node="omnirotor_px4_bridge_px4"))
        bridge = Px4Bridge(node, px4, veh.n_rotors, float(veh.omega_min_hz), float(veh.omega_max_hz), options,
                           say=say, frames=frame_options)  # fmt: skip
        set_transport_priority(transport_priority or None, say)  # its publishers and subscribers declared
        set_realtime(cpu, fifo_priority or None, say)  # after the transport's threads started: they keep theirs
        what = "no frames" if frame_options is None else f"frames from PX4, motion capture: {bridge.frames.mocap_where}"
        who = f"controller session {pinned:016x} only" if pinned is not None else "the first controller session"
        say(f"up; {veh.n_rotors} motors, reversible flags {bridge.flags:#x}; {what}; obeying {who}")
        if frame_options is not None:
            say(f"plant session {bridge.session_id:016x} (a node's --plant-session {bridge.session_id:016x} follows "
                "these frames only)")  # fmt: skip
        summary = bridge.run()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if as_json:
        print(json.dumps(summary))
        return
    print(
        f"commands obeyed {summary['commands_obeyed']}, refused {summary['commands_refused']} "
        f"({summary['foreign_sessions']} other sessions); sent {summary['sent']}; "
        f"failsafe: {summary['cause'] or 'none'}"
    )
    f = summary["frames"]
    if f is not None:
        w = f["imu_watch"]
        print(
            f"frames {f['frames']} (IMU {f['imu_rate_hz'] or math.nan:.1f} Hz at the start, "
            f"{w['rate_hz'] or math.nan:.1f} Hz at the end; off the rate {w['off_episodes']} times for "
            f"{w['off_s']:.1f} s, gaps over 20 ms {w['gaps']} (worst {w['worst_gap_ms']:.0f} ms)), "
            f"rotor speeds NaN in {f['esc_nan_frames']}, "
            f"motion capture samples {f['mocap_samples']}; bad payloads {f['bad_payloads']}"
        )
