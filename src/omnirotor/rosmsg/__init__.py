"""The project's ROS 2 message definitions and a rosbags type store that knows them.

``omnirotor_msgs/`` is a ROS 2 interface package (``package.xml``, ``CMakeLists.txt``, ``msg/*.msg``): copy or
link it into a workspace's ``src/`` and ``colcon build`` it, and a ROS 2 node sees the flight node's and the
simulator's topics with their own types. ``px4_msgs/msg/`` holds the subset of PX4's uORB messages the PX4
profile uses (field lists as PX4 defines them; on a ROS 2 machine, PX4's own ``px4_msgs`` package).

:func:`typestore` returns a rosbags ``Typestore`` with the standard ROS 2 types (Jazzy) and every ``.msg`` file
of both folders registered, so that everything the project puts on the wire or in a bag is (de)serialised as
CDR by rosbags, never by hand::

    ts = typestore()
    raw = ts.serialize_cdr(msg, "omnirotor_msgs/msg/RotorCommand")
    msg = ts.deserialize_cdr(raw, "omnirotor_msgs/msg/RotorCommand")
"""

from __future__ import annotations

import functools
from pathlib import Path

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

__all__ = ["MSG_PACKAGES", "ROS_DISTRIBUTION", "msg_files", "typestore", "msg_type"]

ROS_DISTRIBUTION = Stores.ROS2_JAZZY
"""The standard ROS 2 types the store starts from (std_msgs, geometry_msgs, sensor_msgs, ...)."""

_ROOT = Path(__file__).resolve().parent

MSG_PACKAGES = ("omnirotor_msgs", "px4_msgs")
"""The packages whose ``msg/*.msg`` files ship here."""


def msg_files() -> dict[str, Path]:
    """Every shipped message definition by its ROS 2 type name (``pkg/msg/Name``), sorted by name."""
    found = {}
    for package in MSG_PACKAGES:
        for path in sorted((_ROOT / package / "msg").glob("*.msg")):
            found[f"{package}/msg/{path.stem}"] = path
    return found


@functools.cache
def typestore() -> Typestore:
    """A rosbags type store with ROS 2 Jazzy's standard types and every shipped ``.msg`` registered.

    Built once per process and shared: callers must not register further types on it (build their own with
    ``get_typestore`` and :func:`msg_files` for that).
    """
    store = get_typestore(ROS_DISTRIBUTION)
    types = {}
    for name, path in msg_files().items():
        types.update(get_types_from_msg(path.read_text(encoding="utf-8"), name))
    store.register(types)
    return store


def msg_type(name: str) -> type:
    """The message class of the type ``name`` (``pkg/msg/Name``) in :func:`typestore`.

    Raises:
        KeyError: the store does not know ``name``.
    """
    return typestore().types[name]
