"""Message transports of the flight node and the software-in-the-loop simulator (issue 24).

:func:`open_transport` opens a session on a registered transport (Zenoh by default: :mod:`.zenoh_transport`);
:mod:`.base` holds the interface, the registry and the (de)serialisation by rosbags' CDR.
"""

from omnirotor.transport.base import (
    DEFAULT_TRANSPORT,
    TRANSPORTS,
    Publisher,
    Subscriber,
    Transport,
    open_transport,
    register_transport,
    ros_topic,
)
from omnirotor.transport.zenoh_transport import ZenohTransport, key_expression, liveliness_key

__all__ = [
    "DEFAULT_TRANSPORT",
    "TRANSPORTS",
    "Publisher",
    "Subscriber",
    "Transport",
    "ZenohTransport",
    "key_expression",
    "liveliness_key",
    "open_transport",
    "register_transport",
    "ros_topic",
]
