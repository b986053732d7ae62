"""A Gymnasium environment in which Python drives flowgate's whole stack in virtual time.

`FlowgateEnv(scenario)` starts `flowgate plan --policy ... --sweep N --seed S` with itself
as the policy (over `flowgate_policy.relay`), so every step is a real control cycle of the
gateway: its tracker's estimate in, the command through its safety supervisor out. Each
`reset` is the next episode of the sweep (its perturbations drawn from the seed); `reset(seed=S)`
starts the sweep afresh from seed S, so the same seed gives the same episode.

Observation (fixed size, `float32`): the robot `x, y, cos(heading), sin(heading), v, w`, the
goal relative to the robot `dx, dy`, then the `n_obstacles` nearest obstacles, each
`dx, dy, vx, vy, radius, present` (relative to the robot; absent ones all zero).

Action: `[v, w]`, forward speed (m/s) and turn rate (rad/s), within the robot's limits.

Reward, each step: the metres the robot came nearer its goal, less 0.001; at the end +1 at the
goal, -1 for a contact or a fault. `terminated` at the goal, a contact or any stop of the
gateway; `truncated` at the scenario's time limit. `info`: `t`, and at the end `outcome`,
`contact` and `stop` (the gateway's words).
"""

from __future__ import annotations

import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
from typing import Any, Optional

import gymnasium as gym
import numpy as np

from .protocol import Command, Ending, Hello, Observation, read_message

PER_OBSTACLE = 6
#: The observation's bound, each element (m, m/s, rad/s).
BOUND = 100.0


class FlowgateEnv(gym.Env):
    metadata = {"render_modes": []}

    def __init__(self, scenario: str, n_obstacles: int = 4, flowgate: Optional[str] = None,
                 episodes: int = 100_000, budget_ms: int = 60_000):
        self.scenario = os.path.abspath(scenario)
        self.n_obstacles = n_obstacles
        self.flowgate = flowgate or os.environ.get("FLOWGATE", "flowgate")
        self.episodes = episodes
        self.budget_ms = budget_ms
        self._dir = tempfile.mkdtemp(prefix="flowgate-env-")
        self._process = None
        self._conn = None
        self._seed = 1
        self._start(self._seed)
        self._hello = self._expect(Hello)
        limits = self._hello.limits
        size = 8 + PER_OBSTACLE * n_obstacles
        # Metres, m/s and rad/s: a rig's floor is a few metres, its speeds below one.
        self.observation_space = gym.spaces.Box(-BOUND, BOUND, shape=(size,), dtype=np.float32)
        self.action_space = gym.spaces.Box(
            low=np.array([-limits.max_speed, -limits.max_turn_rate], dtype=np.float32),
            high=np.array([limits.max_speed, limits.max_turn_rate], dtype=np.float32),
        )
        self._pending_hello = self._hello
        self._last: Optional[Observation] = None
        self._in_episode = False

    def _start(self, seed: int) -> None:
        self._stop()
        path = os.path.join(self._dir, "policy.sock")
        if os.path.exists(path):
            os.unlink(path)
        listener = socket.socket(socket.AF_UNIX)
        listener.bind(path)
        listener.listen(1)
        relay = f"{sys.executable} -m flowgate_policy.relay {path}"
        self._process = subprocess.Popen(
            [self.flowgate, "plan", "--policy", relay, "--policy-budget-ms", str(self.budget_ms),
             "--sweep", str(self.episodes), "--seed", str(seed), "--threads", "1",
             "--out", os.path.join(self._dir, "out"), self.scenario],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        listener.settimeout(60)
        self._conn, _ = listener.accept()
        listener.close()
        self._reader = self._conn.makefile("r")
        self._writer = self._conn.makefile("w")

    def _stop(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        if self._process is not None:
            self._process.kill()
            self._process.wait()
            self._process = None

    def _expect(self, kind):
        line = self._reader.readline()
        if not line:
            raise RuntimeError("flowgate ended the environment's line")
        message = read_message(line)
        if not isinstance(message, kind):
            raise RuntimeError(f"expected {kind.__name__} from flowgate, got {message}")
        return message

    def _vector(self, o: Observation) -> np.ndarray:
        return np.clip(self._raw(o), -BOUND, BOUND)

    def _raw(self, o: Observation) -> np.ndarray:
        r = o.robot
        out = [r.x, r.y, math.cos(r.heading), math.sin(r.heading), r.v, r.w, o.goal[0] - r.x, o.goal[1] - r.y]
        nearest = sorted(o.obstacles, key=lambda b: b.distance(r))[: self.n_obstacles]
        for b in nearest:
            out += [b.x - r.x, b.y - r.y, b.vx, b.vy, b.radius, 1.0]
        out += [0.0] * (PER_OBSTACLE * (self.n_obstacles - len(nearest)))
        return np.array(out, dtype=np.float32)

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        super().reset(seed=seed)
        if seed is not None or self._in_episode:
            # A seed starts the sweep afresh; a reset mid-episode, at the next seed.
            self._seed = seed if seed is not None else self._seed + 1
            self._start(self._seed)
            self._pending_hello = self._expect(Hello)
        if self._pending_hello is None:
            self._pending_hello = self._expect(Hello)
        self._hello, self._pending_hello = self._pending_hello, None
        self._last = self._expect(Observation)
        self._in_episode = True
        return self._vector(self._last), {"t": self._last.t}

    def step(self, action):
        v, w = (float(a) for a in np.asarray(action, dtype=np.float64))
        self._writer.write(Command(v=v, w=w).to_json() + "\n")
        self._writer.flush()
        before = self._last.goal_distance()
        message = read_message(self._reader.readline() or '{"outcome": "fault", "contact": false, "stop": "flowgate ended"}')
        if isinstance(message, Ending):
            self._in_episode = False
            reward = {"goal": 1.0, "collision": -1.0, "fault": -1.0}.get(message.outcome, 0.0)
            info = {"t": self._last.t, "outcome": message.outcome, "contact": message.contact, "stop": message.stop}
            truncated = message.outcome == "timeout"
            return self._vector(self._last), reward, not truncated, truncated, info
        self._last = message
        reward = before - message.goal_distance() - 0.001
        return self._vector(message), reward, False, False, {"t": message.t}

    def close(self) -> None:
        self._stop()
        shutil.rmtree(self._dir, ignore_errors=True)
