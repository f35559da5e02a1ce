"""``omnirotor px4-bridge``: the flight node's rotor commands to a PX4 vehicle over PX4's Zenoh bridge (docs/fly.md).

:class:`omnirotor.fly.bridge.Px4Bridge` between the node's topics (``--namespace``) and PX4's (``--px4-namespace``),
in one Zenoh session when the two namespaces are equal. Ctrl-C (or SIGTERM) stops the motors, disarms PX4 if the
node had it armed, and prints what the bridge counted.
"""

from __future__ import annotations

import contextlib
import json
import signal
import sys
from typing import Annotated

import typer

from omnirotor.cli import app
from omnirotor.errors import InputError


@app.command("px4-bridge")
def px4_bridge(
    connect: Annotated[
        list[str] | None,
        typer.Option(help="Zenoh endpoint to connect to (repeatable): the node's and PX4's; tcp/127.0.0.1:7448."),
    ] = None,
    listen: Annotated[list[str] | None, typer.Option(help="Zenoh endpoint to listen on (repeatable).")] = None,
    zenoh_config: Annotated[
        str | None, typer.Option(help="Zenoh configuration file (JSON5): access control, TLS (docs/transport.md).")
    ] = None,
    domain_id: Annotated[int, typer.Option(help="ROS 2 domain id (0-232) of both sides.")] = 0,
    namespace: Annotated[str, typer.Option(help="ROS 2 namespace of the node's topics, e.g. /robot1.")] = "",
    px4_namespace: Annotated[str, typer.Option(help="ROS 2 namespace of PX4's topics (its bridge's).")] = "",
    vehicle: Annotated[str, typer.Option(help="Vehicle preset or TOML file (rotors, speed limits).")] = "omnirotor",
    command_loss: Annotated[float, typer.Option(help="No command for this long stops the motors [s].")] = 0.5,
    as_json: Annotated[bool, typer.Option("--json", help="Print the exit summary as one JSON object.")] = False,
) -> None:
    """Bridge the flight node's rotor commands to PX4 (ActuatorMotors in offboard direct actuator control)."""
    from omnirotor.fly.bridge import BridgeOptions, Px4Bridge
    from omnirotor.transport import open_transport
    from omnirotor.vehicle import load_vehicle

    options = BridgeOptions(command_loss_s=command_loss)
    veh = load_vehicle(vehicle)
    if veh.n_rotors > 12:
        raise InputError(f"PX4 drives at most 12 motors, the vehicle has {veh.n_rotors}")
    from_file = zenoh_config is not None
    endpoints = list(connect) if connect else ([] if from_file else ["tcp/127.0.0.1:7448"])
    common = {"domain_id": domain_id, "listen": list(listen or ()), "config_file": zenoh_config}
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    with contextlib.ExitStack() as stack:
        node = stack.enter_context(
            open_transport(namespace=namespace, connect=endpoints, node="omnirotor_px4_bridge", **common)
        )
        px4 = node
        if px4_namespace != namespace:
            px4 = stack.enter_context(
                open_transport(namespace=px4_namespace, connect=endpoints, node="omnirotor_px4_bridge_px4",
                               **{**common, "listen": []})
            )  # fmt: skip
        bridge = Px4Bridge(node, px4, veh.n_rotors, float(veh.omega_min_hz), float(veh.omega_max_hz), options)
        print(f"omnirotor px4-bridge: up; {veh.n_rotors} motors, reversible flags {bridge.flags:#x}", file=sys.stderr)
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
