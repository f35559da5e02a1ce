"""A trivial flight director for the tests of the wire (armed, flies the mission as the closed loop does).

The contract (FLY-INTERFACE.md) lets the wire's tests use it until the flight logic's director is in the tree;
it resets the controller on the first frame, sends its hold command for that period, then steps every frame,
and stops the rotors when the frames stop.
"""

from __future__ import annotations

import numpy as np


class PassThroughDirector:
    def __init__(self, controller, trajectory) -> None:
        self.controller = controller
        self.trajectory = trajectory
        self.out = np.zeros(controller.vehicle.n_rotors)
        self.plan = "first"
        self.started = False

    def on_frame(self, frame, ages) -> None:
        if ages.frames_stopped:
            self.plan = "stop"
            return
        if not self.started:
            self.controller.reset(frame, self.trajectory)
            self.out[:] = self.controller.hold_command().omega_hz
            self.started = True
            self.plan = "first"
            return
        if self.plan != "stop":
            self.plan = "step"

    def wants_step(self) -> bool:
        return self.plan == "step"

    def output(self, cmd):
        if self.plan == "stop":
            self.out.fill(0.0)
        elif self.plan == "step" and cmd is not None:
            self.out[:] = cmd.omega_hz
        return self.out
