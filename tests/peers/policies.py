"""The repository's Python package (python/, `flowgate_policy`) as a user writes with it.

Usage: policies.py helper               a policy written with `serve` (flowgate runs it: --policy)
       policies.py push                 an adversary: at top speed straight at the nearest obstacle
       policies.py gym SCENARIO FLOWGATE  Gymnasium's check_env on FlowgateEnv, then one episode
                                          steered at the goal; prints JSON."""
import json
import math
import sys

from flowgate_policy import Command, serve

if sys.argv[1] == "helper":
    def policy(o, hello):
        r = o.robot
        turn = math.atan2(o.goal[1] - r.y, o.goal[0] - r.x) - r.heading
        turn = math.atan2(math.sin(turn), math.cos(turn))
        return Command(v=min(hello.limits.max_speed, o.goal_distance()) * max(math.cos(turn), 0.0), w=2 * turn)

    serve(policy)
    sys.exit(0)

if sys.argv[1] == "push":
    def push(o, hello):
        r = o.robot
        if not o.obstacles:
            return Command(v=hello.limits.max_speed, w=0.0)
        b = min(o.obstacles, key=lambda b: b.distance(r))
        turn = math.atan2(b.y - r.y, b.x - r.x) - r.heading
        return Command(v=hello.limits.max_speed, w=2 * math.atan2(math.sin(turn), math.cos(turn)))

    serve(push)
    sys.exit(0)

from gymnasium.utils.env_checker import check_env
from flowgate_policy.env import FlowgateEnv

env = FlowgateEnv(sys.argv[2], flowgate=sys.argv[3])
check_env(env, skip_render_check=True)
obs, info = env.reset(seed=7)
again, _ = env.reset(seed=7)
same = bool((obs == again).all())
steps, total = 0, 0.0
while True:
    heading = math.atan2(obs[3], obs[2])
    turn = math.atan2(obs[7], obs[6]) - heading
    turn = math.atan2(math.sin(turn), math.cos(turn))
    obs, reward, terminated, truncated, info = env.step([0.1 * max(math.cos(turn), 0.0), 2 * turn])
    steps, total = steps + 1, total + reward
    if terminated or truncated:
        break
env.close()
print(json.dumps({"checked": True, "same_on_same_seed": same, "steps": steps, "reward": total, "info": info,
                  "observation": len(obs), "action": list(env.action_space.shape)}))
