"""The Zenoh connection options of the commands on the flight topics: ``fly``, ``sim --serve``, ``px4-bridge``.

Each command declares ``--listen``, ``--connect``, ``--zenoh-config``, ``--domain-id`` and ``--namespace`` with
these types (its own default endpoints named in their help) and opens its session with the keyword arguments of
:func:`transport_args` (docs/transport.md). ``omnirotor ctl`` has its own (a client: connect only, a timeout).
The pairing options (:mod:`omnirotor.sitl.gate`), both ways, read by :func:`session_id_arg`: the node's
``--session-id`` (its commands) and ``--plant-session`` (the frames it follows); the plants' ``--session-id``
(their frames) and ``--pair-session`` (the commands they obey).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Annotated

import typer

from omnirotor.errors import InputError
from omnirotor.safe_io import check_input_file


def listen_option(default: str | None = None) -> type:
    """``--listen``: Zenoh endpoints to listen on; ``default`` is said in the help (the command's own)."""
    where = f"; {default}" if default else ""
    return Annotated[list[str] | None, typer.Option(help=f"Zenoh endpoint to listen on (repeatable){where}.")]


def connect_option(default: str | None = None, what: str = "") -> type:
    """``--connect``: Zenoh endpoints to connect to (``what`` they are, ``default`` the command's own)."""
    text = (
        "Zenoh endpoint to connect to (repeatable)"
        + (f": {what}" if what else "")
        + (f"; {default}" if default else "")
    )
    return Annotated[list[str] | None, typer.Option(help=text + ".")]


ZenohConfig = Annotated[
    str | None,
    typer.Option(
        help="Zenoh configuration file (JSON5): login or mutual TLS, access control (examples/zenoh-auth/, "
        "examples/zenoh-tls/, docs/transport.md)."
    ),
]
DomainId = Annotated[int, typer.Option(help="ROS 2 domain id (0-232).")]
Namespace = Annotated[str, typer.Option(help="ROS 2 namespace of every topic, e.g. /robot1.")]
SessionId = Annotated[
    str | None,
    typer.Option(
        metavar="HEX",
        help="The controller session id of this node's rotor commands (hex, as printed at its start); default: "
        "random. Give the same to the plant's --pair-session.",
    ),
]
PlantSessionId = Annotated[
    str | None,
    typer.Option(
        "--session-id",
        metavar="HEX",
        help="This plant's session id, carried by every sensor frame (hex, printed at its start); default: random. "
        "Give the same to the node's --plant-session.",
    ),
]
PlantSession = Annotated[
    str | None,
    typer.Option(
        metavar="HEX",
        help="Follow the sensor frames of this plant session only (hex, as `omnirotor sim --serve` or `omnirotor "
        "px4-bridge` prints it, or its --session-id), from the first frame on. Default: the first plant that sends "
        "frames is followed (first come: a foreign publisher that starts first is followed).",
    ),
]
PairSession = Annotated[
    str | None,
    typer.Option(
        metavar="HEX",
        help="Obey the rotor commands of this controller session only (hex, as `omnirotor fly` prints it, or its "
        "--session-id), from the first command on. Default: the first session that commands is paired (first "
        "come: a foreign publisher that starts first takes the pairing).",
    ),
]


def session_id_arg(text: str | None, option: str) -> int | None:
    """The session id of ``--session-id`` or ``--pair-session`` (None when not given); one line when malformed."""
    if text is None:
        return None
    from omnirotor.sitl.gate import parse_session_id

    try:
        return parse_session_id(text, option)
    except ValueError as exc:
        raise InputError(str(exc)) from None


def transport_args(
    *,
    listen: Sequence[str] | None,
    connect: Sequence[str] | None,
    zenoh_config: str | None,
    domain_id: int,
    namespace: str,
    default_listen: Sequence[str] = (),
    default_connect: Sequence[str] = (),
) -> dict:
    """:func:`omnirotor.transport.open_transport`'s keyword arguments of the options (without ``node``).

    Endpoints given on the command line stand; otherwise the command's defaults, unless a Zenoh configuration
    file is given (its own endpoints then stand). The file is checked first (one line and exit 2 when it is not
    a readable file).
    """
    if zenoh_config is not None:
        check_input_file(Path(zenoh_config), "--zenoh-config")
    from_file = zenoh_config is not None
    return {
        "domain_id": domain_id,
        "namespace": namespace,
        "listen": list(listen) if listen else ([] if from_file else list(default_listen)),
        "connect": list(connect) if connect else ([] if from_file else list(default_connect)),
        "config_file": zenoh_config,
    }
