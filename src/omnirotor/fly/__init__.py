"""The flight node's logic: flight modes, live setpoints, failsafes, recording, live view, PX4 mapping.

:class:`~omnirotor.fly.director.FlightDirector` is what the node's process loop (:mod:`omnirotor.fly.node`)
calls once per period; it does no I/O besides recording and the live view. See docs/fly.md.
"""
