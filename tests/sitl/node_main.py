"""A flight node process for the wire's tests: ``python -m tests.sitl.node_main SIM_ENDPOINT NAMESPACE LISTEN``.

Flies the simulator's mission with :class:`PassThroughDirector` (until the flight logic's director is in the
tree: then the tests run ``omnirotor fly --mission-from-sim``) and prints the loop's summary as JSON.
"""

from __future__ import annotations

import json
import sys

from tests.sitl.passthrough import PassThroughDirector

from omnirotor.fly.node import NodeOptions, fly_mission, mission_from_sim, set_realtime
from omnirotor.transport import open_transport


def main() -> None:
    connect, namespace, listen = sys.argv[1], sys.argv[2], sys.argv[3]
    with open_transport(listen=[listen], connect=[connect], namespace=namespace) as t:
        task, options, lockstep = mission_from_sim(t, timeout_s=60.0)
        realtime = (lambda: set_realtime(None, 20, print)) if "fifo" in sys.argv[4:] else None
        summary = fly_mission(t, task, options, NodeOptions(lockstep=lockstep), PassThroughDirector, realtime)
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
