"""``omnirotor ctl``: one request to the flight node (``omnirotor fly``), and its answer (issue 24).

Each subcommand sends one ``omnirotor_msgs/msg/FlightRequest`` on ``/omnirotor/ctl`` (request/reply over the
transport) and prints the node's answer on one line: the transition accepted (``accepted: takeoff: armed ->
takeoff (0.50 m in 3.1 s)``) or refused and why (``refused: takeoff: disarmed (arm first)``). Exit status 0
accepted, 1 refused, 2 bad input or no node answering.
"""

from __future__ import annotations

import math
from typing import Annotated

import typer

from omnirotor.cli import CommandGroup, app, number_option
from omnirotor.errors import InputError

CTL_ENDPOINT = "tcp/127.0.0.1:7448"
"""Where ``omnirotor fly`` listens by default (loopback): where ``ctl`` connects unless told otherwise."""
EXIT_REFUSED = 1

_CONNECTION = ("--connect", "--zenoh-config", "--domain-id", "--namespace", "--timeout")
"""The group's options, each with a value: also accepted after the request (``ctl arm --connect ...``)."""


class CtlGroup(CommandGroup):
    """``ctl``'s group: its connection options may also follow the request, as a user types them."""

    def parse_args(self, ctx, args: list[str]) -> list[str]:  # noqa: D102  (click's documented hook)
        before, after, i, seen_request = [], [], 0, False
        while i < len(args):
            a = args[i]
            if a == "--":
                after += args[i:]
                break
            if a.split("=", 1)[0] in _CONNECTION:  # wherever it is: the group's, with its value
                n = 1 if "=" in a else 2
                before += args[i : i + n]
                i += n
                continue
            if seen_request or not a.startswith("-"):
                seen_request = True
                after.append(a)
            else:
                before.append(a)
            i += 1
        return super().parse_args(ctx, before + after)


ctl_app = typer.Typer(
    cls=CtlGroup,
    help="Send one request to the flight node (omnirotor fly) and print its answer; exit 0 accepted, 1 refused.",
    no_args_is_help=True,
)
app.add_typer(ctl_app, name="ctl")


@ctl_app.callback()
def _connection(
    ctx: typer.Context,
    connect: Annotated[
        list[str] | None, typer.Option(help=f"Zenoh endpoint of the node (repeatable); default {CTL_ENDPOINT}.")
    ] = None,
    zenoh_config: Annotated[
        str | None,
        typer.Option(
            help="Zenoh configuration file (JSON5): the login a node that requires one accepts "
            "(examples/zenoh-auth/ctl.json5)."
        ),
    ] = None,
    domain_id: Annotated[int, typer.Option(help="ROS 2 domain id (0-232), as the node's.")] = 0,
    namespace: Annotated[str, typer.Option(help="ROS 2 namespace, as the node's (e.g. /robot1).")] = "",
    timeout: Annotated[
        float | None, typer.Option(help="Seconds to wait for the answer [default: 2].", parser=number_option)
    ] = None,
) -> None:
    """Where the flight node is."""
    ctx.obj = {"connect": list(connect) if connect else [CTL_ENDPOINT], "domain_id": domain_id,
               "namespace": namespace, "timeout": 2.0 if timeout is None else timeout,
               "zenoh_config": zenoh_config}  # fmt: skip


def send(request, *, connect: list[str], domain_id: int = 0, namespace: str = "", timeout: float = 2.0,
         zenoh_config: str | None = None):  # fmt: skip
    """Send one :class:`~omnirotor.fly.requests.FlightRequest` and return the node's :class:`FlightReply`.

    ``zenoh_config``: a Zenoh configuration file (its login, docs/transport.md); ``connect`` stands over its
    endpoints.

    Raises:
        InputError: a bad timeout or configuration file, a transport that cannot open, or no answer within
            ``timeout`` seconds.
    """
    from pathlib import Path

    from omnirotor.fly.requests import CTL_TOPIC, FlightReply
    from omnirotor.safe_io import check_input_file
    from omnirotor.transport import open_transport

    if not (math.isfinite(timeout) and 0.0 < timeout <= 60.0):
        raise InputError(f"--timeout must be in (0, 60] s, got {timeout}")
    if zenoh_config is not None:
        check_input_file(Path(zenoh_config), "--zenoh-config")
    with open_transport(domain_id=domain_id, namespace=namespace, listen=[], connect=connect,
                        config_file=zenoh_config) as t:  # fmt: skip
        raw = t.request(
            CTL_TOPIC, "omnirotor_msgs/msg/FlightRequest", request.to_msg(), "omnirotor_msgs/msg/FlightReply", timeout
        )
    if raw is None:
        where = f"{namespace}{CTL_TOPIC} via {', '.join(connect)}"
        raise InputError(
            f"no answer from a flight node on {where} within {timeout:g} s (is `omnirotor fly` running there?)"
        )
    try:
        return FlightReply.from_msg(raw)
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(f"the node's answer is not a flight reply: {exc}") from None


def _run(ctx: typer.Context, kind: str, **fields) -> None:
    from omnirotor.fly.requests import FlightRequest

    reply = send(FlightRequest(kind, **fields), **ctx.obj)
    print(reply.line())
    if not reply.accepted:
        raise typer.Exit(EXIT_REFUSED)


def _finite(name: str, value: float | None) -> float | None:
    if value is not None and not math.isfinite(value):
        raise InputError(f"{name} must be a finite number, got {value}")
    return value


@ctl_app.command()
def status(ctx: typer.Context) -> None:
    """The node's mode, preset, map mode, failsafe and last transition."""
    _run(ctx, "status")


@ctl_app.command()
def arm(ctx: typer.Context) -> None:
    """Arm on the ground (needs fresh motion capture and IMU): the armed pose is the take-off's ground."""
    _run(ctx, "arm")


@ctl_app.command()
def takeoff(
    ctx: typer.Context,
    height: Annotated[
        float | None,
        typer.Option(help="Height above the armed pose [m]; default the flight file's.", parser=number_option),
    ] = None,
) -> None:
    """Climb to the take-off height, then hold."""
    _run(ctx, "takeoff", height_m=_finite("--height", height))


@ctl_app.command(context_settings={"ignore_unknown_options": True})  # negative coordinates are numbers, not options
def goto(
    ctx: typer.Context,
    x: Annotated[float, typer.Argument(help="Tool-tip x [m], world frame.", parser=number_option)],
    y: Annotated[float, typer.Argument(help="Tool-tip y [m].", parser=number_option)],
    z: Annotated[float, typer.Argument(help="Tool-tip z [m].", parser=number_option)],
    yaw: Annotated[float | None, typer.Option(help="Yaw [deg] (ZYX); default: keep.", parser=number_option)] = None,
    roll: Annotated[float | None, typer.Option(help="Roll [deg]; default: keep.", parser=number_option)] = None,
    pitch: Annotated[float | None, typer.Option(help="Pitch [deg]; default: keep.", parser=number_option)] = None,
    duration: Annotated[
        float | None,
        typer.Option(help="Segment duration [s]; default the shortest within the limits.", parser=number_option),
    ] = None,
) -> None:
    """Fly the tool tip to (X, Y, Z) on a minimum-jerk segment (in contact: slide, keeping the depth)."""
    from omnirotor.fly.requests import Setpoint

    for name, v in (("X", x), ("Y", y), ("Z", z), ("--yaw", yaw), ("--roll", roll), ("--pitch", pitch)):
        _finite(name, v)
    sp = Setpoint((x, y, z), roll_deg=roll, pitch_deg=pitch, yaw_deg=yaw, duration_s=_finite("--duration", duration))
    _run(ctx, "goto", setpoint=sp)


@ctl_app.command()
def hold(ctx: typer.Context) -> None:
    """Stop the reference where it is (in contact: keep the depth)."""
    _run(ctx, "hold")


@ctl_app.command()
def push(
    ctx: typer.Context,
    depth: Annotated[
        float, typer.Argument(help="Penetration depth along the tool axis [m]; 0 leaves contact.", parser=number_option)
    ],
) -> None:
    """Push the tool DEPTH past where it is, with the contact preset (steady force about K_E^p x DEPTH)."""
    _run(ctx, "push", depth_m=_finite("DEPTH", depth))


@ctl_app.command()
def preset(
    ctx: typer.Context,
    name: Annotated[str, typer.Argument(help="Admittance preset: PC, SD, PiH, free, or the flight file's.")],
) -> None:
    """Switch the admittance parameters (Table 2's sets), keeping the compliant reference."""
    _run(ctx, "preset", name=name)


@ctl_app.command("map")
def map_mode(
    ctx: typer.Context, mode: Annotated[str, typer.Argument(help="Wrench-map mode: nominal, global or piecewise.")]
) -> None:
    """Switch the wrench-map mode in flight."""
    _run(ctx, "map", name=mode)


@ctl_app.command()
def land(ctx: typer.Context) -> None:
    """Descend to the armed height (from contact: first withdraw), disarm on touchdown."""
    _run(ctx, "land")


@ctl_app.command()
def disarm(
    ctx: typer.Context,
    force: Annotated[bool, typer.Option(help="Stop the rotors even in flight (a kill switch).")] = False,
) -> None:
    """Stop the rotors (on the ground; in flight only with --force)."""
    _run(ctx, "disarm", force=force)
