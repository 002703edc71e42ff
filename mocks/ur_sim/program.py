"""A looping production program that the simulated controller runs by itself.

A real cell's robot runs its own program (pick, place, weld ...) while
``handeye monitor`` watches through a read-only connection. This is that
program for the simulator: ``movej`` through a list of waypoints, stopping at
each for ``pause_s`` (the tool works there: a "tool stop"), then on to the
next, around the loop until stopped. The passive monitor samples during the
stops.

Started over the dashboard port (``sim program <json>``, see
`handeye.mocks.ur_sim.server`), from Python (`handeye.mocks.ur_sim.SimProcess.start_program`)
or at start-up (``python -m handeye.mocks.ur_sim --program FILE.json``). JSON::

    {"waypoints": [{"q": [6 joint angles, rad], "pause_s": 0.8, "tool": "glue"}, ...],
     "speed": 1.0, "acceleration": 4.0}

``speed`` (rad/s) and ``acceleration`` (rad/s^2) are of the leading joint.
A client's control script (ur_rtde's RTDEControl) or a safety stop takes
precedence: the program holds while either is active.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import Field, ValidationError

from handeye.calib.errors import ParameterError
from handeye.calib.params import NonNegativeFloat, Params, PositiveFloat, Str, Vector6, describe
from handeye.mocks.ur_sim.motion import JointMotion


class Waypoint(Params):
    """One stop of the program: joints (rad), how long the arm holds there (s), the tool's job there."""

    q: Vector6
    pause_s: NonNegativeFloat = 0.8
    tool: Str = ""


class ProgramSpec(Params):
    """The JSON form of the module docstring; speed (rad/s) and acceleration (rad/s^2) of the leading joint."""

    waypoints: Annotated[list[Waypoint], Field(min_length=2)]
    speed: PositiveFloat = 1.0
    acceleration: PositiveFloat = 4.0


class Program:
    """The program's state machine; `tick` is called by the controller once per control cycle.

    Parameters
    ----------
    spec : ProgramSpec

    Attributes
    ----------
    cycles : int
        Completed loops.
    stops : int
        Waypoints reached so far.
    """

    def __init__(self, spec: ProgramSpec):
        self.spec = spec
        self.targets = [np.array(w.q) for w in spec.waypoints]
        self.index = 0
        self.hold_until: float | None = None
        self.moving = False
        self.cycles = 0
        self.stops = 0

    @classmethod
    def from_dict(cls, data) -> "Program":
        """From the JSON form of the module docstring (`handeye.calib.errors.ParameterError`, a ValueError, names the field)."""
        try:
            return cls(ProgramSpec.model_validate(data))
        except ValidationError as e:
            raise ParameterError(describe(e, "program")) from None

    def to_dict(self) -> dict:
        return self.spec.model_dump()

    def tick(self, ctl) -> None:
        """Advance the program by one control cycle of ``ctl`` (a `SimController`, idle or moving by us)."""
        now = ctl.timestamp
        if self.moving:
            if ctl.motion is not None:
                return
            # Arrived: the tool works while the arm holds still.
            self.moving = False
            self.stops += 1
            wp = self.spec.waypoints[self.index]
            self.hold_until = now + wp.pause_s
            ctl.log.append({"t": now, "cmd": None, "name": f"program:stop {self.index}"
                            + (f" tool {wp.tool}" if wp.tool else ""), "args": []})
            return
        if ctl.motion is not None or (self.hold_until is not None and now < self.hold_until):
            return
        if self.hold_until is not None:
            self.index = (self.index + 1) % len(self.targets)
            if self.index == 0:
                self.cycles += 1
        ctl.motion = JointMotion(ctl.q, self.targets[self.index], self.spec.speed, self.spec.acceleration)
        ctl.motion_t0, ctl.motion_async = now, False
        self.moving = True

    def state(self) -> dict:
        return {"waypoints": len(self.targets), "index": self.index, "moving": self.moving,
                "cycles": self.cycles, "stops": self.stops}
