"""The simulator as a robot on the wire: software in the loop (``omnirotor sim --serve``, issue 24 item 3).

:mod:`.server` runs the MuJoCo plant in its own process on the flight topics; :mod:`.gate` decides which rotor
commands it obeys (one paired session, increasing sequence numbers: issue 26 item 5).
"""
