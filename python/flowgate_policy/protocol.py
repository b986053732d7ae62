"""The messages of flowgate's policy protocol (docs/policies.md, "In the simulator"), one JSON
object a line: flowgate sends a `Hello`, then an `Observation` each control period, answered
by a `Command`, and an `Ending` last. Metres, seconds and radians throughout."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import List, Optional, Union


@dataclass(frozen=True)
class Limits:
    max_speed: float
    max_wheel_speed: float
    wheel_base: float
    radius: float
    period: float
    goal_tolerance: float

    @property
    def max_turn_rate(self) -> float:
        """The fastest turn on the spot, rad/s."""
        return 2.0 * self.max_wheel_speed / self.wheel_base


@dataclass(frozen=True)
class Hello:
    flowgate: str
    scenario: str
    limits: Limits
    walls: List[List[List[float]]] = field(default_factory=list)
    furniture: List[List[List[float]]] = field(default_factory=list)
    view: List[List[List[float]]] = field(default_factory=list)


@dataclass(frozen=True)
class Robot:
    x: float
    y: float
    heading: float
    v: float
    w: float


@dataclass(frozen=True)
class Obstacle:
    x: float
    y: float
    vx: float
    vy: float
    radius: float

    def distance(self, robot: Robot) -> float:
        """From the robot's centre to the obstacle's, m."""
        return math.hypot(self.x - robot.x, self.y - robot.y)


@dataclass(frozen=True)
class Observation:
    t: float
    robot: Robot
    goal: List[float]
    obstacles: List[Obstacle]

    def goal_distance(self) -> float:
        return math.hypot(self.goal[0] - self.robot.x, self.goal[1] - self.robot.y)


@dataclass(frozen=True)
class Ending:
    outcome: str
    contact: bool
    stop: Optional[str]


@dataclass(frozen=True)
class Command:
    """A velocity command: forward speed `v` (m/s) and turn rate `w` (rad/s), or the wheels'
    rim speeds `left` and `right` (m/s). Beyond the robot's limits, flowgate scales it down."""

    v: Optional[float] = None
    w: Optional[float] = None
    left: Optional[float] = None
    right: Optional[float] = None

    def to_json(self) -> str:
        if self.left is not None and self.right is not None:
            return json.dumps({"left": self.left, "right": self.right})
        return json.dumps({"v": self.v or 0.0, "w": self.w or 0.0})


Message = Union[Hello, Observation, Ending]


def read_message(line: str) -> Message:
    """One line from flowgate, as its type."""
    o = json.loads(line)
    if "limits" in o:
        room = o.get("room", {})
        return Hello(o["flowgate"], o["scenario"], Limits(**o["limits"]), room.get("walls", []),
                     room.get("furniture", []), room.get("view", []))
    if "robot" in o:
        return Observation(o["t"], Robot(**o["robot"]), o["goal"], [Obstacle(**b) for b in o["obstacles"]])
    if "outcome" in o:
        return Ending(o["outcome"], o["contact"], o.get("stop"))
    raise ValueError(f"not a message of flowgate's policy protocol: {line.strip()}")
