"""A looping production program that the simulated controller runs by itself.

A real cell's robot runs its own program (pick, place, weld ...) while
``handeye monitor`` watches through a read-only connection. This is that
program for the simulator: ``movej`` through a list of waypoints, stopping at
each for ``pause_s`` (the tool works there: a "tool stop"), then on to the
next, around the loop until stopped. The passive monitor samples during the
stops.

Started over the dashboard port (``sim program <json>``, see
`mocks.ur_sim.server`), from Python (`mocks.ur_sim.SimProcess.start_program`)
or at start-up (``python -m mocks.ur_sim --program FILE.json``). JSON::

    {"waypoints": [{"q": [6 joint angles, rad], "pause_s": 0.8, "tool": "glue"}, ...],
     "speed": 1.0, "acceleration": 4.0}

``speed`` (rad/s) and ``acceleration`` (rad/s^2) are of the leading joint.
A client's control script (ur_rtde's RTDEControl) or a safety stop takes
precedence: the program holds while either is active.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.robot import ur_kinematics as kin
from mocks.ur_sim.motion import JointMotion


@dataclass
class Waypoint:
    """One stop of the program: joints (rad), how long the arm holds there (s), the tool's job there."""

    q: np.ndarray
    pause_s: float = 0.8
    tool: str = ""


class Program:
    """The program's state machine; `tick` is called by the controller once per control cycle.

    Parameters
    ----------
    waypoints : list of Waypoint (>= 2)
    speed, acceleration : float
        Of the leading joint, rad/s and rad/s^2 (> 0).

    Attributes
    ----------
    cycles : int
        Completed loops.
    stops : int
        Waypoints reached so far.
    """

    def __init__(self, waypoints: list[Waypoint], speed: float = 1.0, acceleration: float = 4.0):
        if len(waypoints) < 2:
            raise ValueError(f"a production program needs >= 2 waypoints, got {len(waypoints)}")
        if not (speed > 0 and acceleration > 0):
            raise ValueError(f"speed and acceleration must be > 0, got {speed}, {acceleration}")
        for i, w in enumerate(waypoints):
            w.q = kin.check_q(w.q, f"waypoints[{i}].q")
            if not (np.isfinite(w.pause_s) and w.pause_s >= 0):
                raise ValueError(f"waypoints[{i}].pause_s must be >= 0, got {w.pause_s}")
        self.waypoints, self.speed, self.acceleration = waypoints, float(speed), float(acceleration)
        self.index = 0
        self.hold_until: float | None = None
        self.moving = False
        self.cycles = 0
        self.stops = 0

    @classmethod
    def from_dict(cls, data: dict) -> "Program":
        """From the JSON form of the module docstring (raises ValueError naming the bad field)."""
        try:
            wps = [Waypoint(np.asarray(w["q"], dtype=float), float(w.get("pause_s", 0.8)), str(w.get("tool", "")))
                   for w in data["waypoints"]]
            return cls(wps, float(data.get("speed", 1.0)), float(data.get("acceleration", 4.0)))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"production program: bad or missing field {exc}") from None

    def to_dict(self) -> dict:
        return {"waypoints": [{"q": w.q.tolist(), "pause_s": w.pause_s, "tool": w.tool} for w in self.waypoints],
                "speed": self.speed, "acceleration": self.acceleration}

    def tick(self, ctl) -> None:
        """Advance the program by one control cycle of ``ctl`` (a `SimController`, idle or moving by us)."""
        now = ctl.timestamp
        if self.moving:
            if ctl.motion is not None:
                return
            # Arrived: the tool works while the arm holds still.
            self.moving = False
            self.stops += 1
            wp = self.waypoints[self.index]
            self.hold_until = now + wp.pause_s
            ctl.log.append({"t": now, "cmd": None, "name": f"program:stop {self.index}"
                            + (f" tool {wp.tool}" if wp.tool else ""), "args": []})
            return
        if ctl.motion is not None or (self.hold_until is not None and now < self.hold_until):
            return
        if self.hold_until is not None:
            self.index = (self.index + 1) % len(self.waypoints)
            if self.index == 0:
                self.cycles += 1
        ctl.motion = JointMotion(ctl.q, self.waypoints[self.index].q, self.speed, self.acceleration)
        ctl.motion_t0, ctl.motion_async = now, False
        self.moving = True

    def state(self) -> dict:
        return {"waypoints": len(self.waypoints), "index": self.index, "moving": self.moving,
                "cycles": self.cycles, "stops": self.stops}
