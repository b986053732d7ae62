"""Peer of tests/ros2.rs: a ROS 2 node in rclpy (Jazzy, Fast DDS) beside a running
`flowgate demo --ros2`, as a lab's own node would be.

It hears /odom, ~/obstacles, ~/path and /diagnostics and finds /tf's type in the graph; sends a
goal out of the camera's view on /goal_pose and reads the refusal off /diagnostics; calls
~/arm twice (the second is refused); compares both refusals with `flowgate ctl`'s words on the
control socket; sends a reachable goal, calls ~/start, and waits for the gateway to stop at
it. Prints one JSON object with what it saw.

usage: ros2.py FLOWGATE SOCKET GOAL_X GOAL_Y
       ros2.py --cmd-vel at_obstacle|to_goal|to_goal_stamped GOAL_X GOAL_Y
                          (an outside planner on /cmd_vel, flowgate's planner.method = "ros2":
                          straight at E1's obstacle for 8 s then silent, or steering round it
                          to the goal, in Twist or TwistStamped; arms and starts over the
                          services, waits for the stop)
       ros2.py --fleet FLOWGATE SOCKET  (swap-2's vehicle v1 over its own namespace: arm, goal,
                          start, its e-stop, reset; then the robot to a goal; the states as
                          `flowgate ctl status` prints them at each step; v1's /v1/odom and
                          its markers in ~/obstacles)
       ros2.py --bag DIR      (reads a `flowgate record export --ros2` bag with rosbags)
       ros2.py --rviz FILE    (the RViz configuration's fixed frame and topics, as JSON)
"""

import json
import subprocess
import sys
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
import math

from geometry_msgs.msg import PoseStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry, Path
from rclpy.node import Node
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray


def fail(why):
    print(f"ros2 peer: {why}", file=sys.stderr)
    sys.exit(1)


class Peer(Node):
    def __init__(self):
        super().__init__("flowgate_peer")
        self.odom, self.obstacles, self.paths, self.diagnostics = [], [], [], []
        self.create_subscription(Odometry, "/odom", lambda m: self.odom.append((time.monotonic(), m)), 10)
        self.create_subscription(MarkerArray, "/flowgate/obstacles", self.obstacles.append, 10)
        self.create_subscription(Path, "/flowgate/path", self.paths.append, 10)
        self.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, 10)
        self.goal = self.create_publisher(PoseStamped, "/goal_pose", 10)
        self.triggers = {n: self.create_client(Trigger, f"/flowgate/{n}") for n in ["arm", "start", "stop", "reset", "estop"]}

    def spin_until(self, what, deadline_s, why):
        end = time.monotonic() + deadline_s
        while time.monotonic() < end:
            rclpy.spin_once(self, timeout_sec=0.05)
            found = what()
            if found:
                return found
        fail(f"waited {deadline_s} s for {why}")

    def call(self, name):
        client = self.triggers[name]
        self.spin_until(lambda: client.service_is_ready(), 20, f"/flowgate/{name}")
        future = client.call_async(Trigger.Request())
        self.spin_until(lambda: future.done(), 10, f"an answer from /flowgate/{name}")
        r = future.result()
        return {"success": r.success, "message": r.message}

    def send_goal(self, x, y):
        self.spin_until(lambda: self.goal.get_subscription_count() > 0, 20, "flowgate to hear /goal_pose")
        msg = PoseStamped()
        msg.header.frame_id = "map"
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.pose.position.x, msg.pose.position.y = x, y
        msg.pose.orientation.w = 1.0
        self.goal.publish(msg)

    def refusal(self, since):
        for d in self.diagnostics[since:]:
            for s in d.status:
                if s.name == "flowgate: requests":
                    return s.message
        return None

    def state(self):
        for d in reversed(self.diagnostics):
            for s in d.status:
                if s.name == "flowgate: gateway":
                    return s.message
        return None


def ctl(flowgate, socket, *args):
    out = subprocess.run([flowgate, "ctl", "--socket", socket, *args], capture_output=True, text=True, timeout=10)
    return (out.stdout + out.stderr).strip()


def read_bag(folder):
    """Every message of a rosbag2, decoded by rosbags from the bag's own definitions."""
    from pathlib import Path

    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    out = {"types": {}, "counts": {}, "odom": [], "tf": [], "namespaces": set(), "states": [], "paths": [],
           "obstacles": [], "diagnostics": [], "tf_children": set(), "vehicle_odom": {}}
    with AnyReader([Path(folder)], default_typestore=get_typestore(Stores.EMPTY)) as reader:
        for c in reader.connections:
            out["types"][c.topic] = c.msgtype
        for conn, log_time, raw in reader.messages():
            m = reader.deserialize(raw, conn.msgtype)
            out["counts"][conn.topic] = out["counts"].get(conn.topic, 0) + 1
            stamp = None
            if conn.topic == "/odom":
                stamp = m.header.stamp
                p = m.pose.pose.position
                out["odom"].append({"ns": log_time, "x": p.x, "y": p.y, "frame": m.header.frame_id, "child": m.child_frame_id})
            elif conn.topic == "/tf":
                t = m.transforms[0]
                stamp = t.header.stamp
                out["tf_children"].update(t.child_frame_id for t in m.transforms)
                if t.child_frame_id == "base_link":  # the robot's (a fleet's other vehicles come apart)
                    out["tf"].append({"ns": log_time, "x": t.transform.translation.x,
                                      "y": t.transform.translation.y, "frame": t.header.frame_id,
                                      "child": t.child_frame_id})
            elif conn.topic.endswith("/odom"):  # a fleet's other vehicle's, /<name>/odom
                stamp = m.header.stamp
                p = m.pose.pose.position
                out["vehicle_odom"].setdefault(conn.topic, []).append(
                    {"ns": log_time, "x": p.x, "y": p.y, "frame": m.header.frame_id, "child": m.child_frame_id})
            elif conn.topic.endswith("/obstacles"):
                out["namespaces"].update(mk.ns for mk in m.markers if mk.ns)
                bodies = [mk for mk in m.markers if mk.ns == "obstacle"]
                circles = {mk.id: mk.scale.x / 2 for mk in m.markers if mk.ns == "planning_circle"}
                out["obstacles"].append({"ns": log_time, "at": [[mk.pose.position.x, mk.pose.position.y] for mk in bodies],
                                         "planning_radius": [circles.get(mk.id) for mk in bodies]})
            elif conn.topic.endswith("/path"):
                stamp = m.header.stamp
                out["paths"].append(len(m.poses))
            elif conn.topic == "/diagnostics":
                out["states"].append(m.status[0].message)
                out["diagnostics"].append({"ns": log_time, "state": m.status[0].message})
            if stamp is not None and stamp.sec * 10**9 + stamp.nanosec != log_time:
                fail(f"{conn.topic}: stamp {stamp} is not its log time {log_time}")
    out["namespaces"] = sorted(out["namespaces"])
    out["tf_children"] = sorted(out["tf_children"])
    print(json.dumps(out))


def rviz(path):
    import yaml

    manager = yaml.safe_load(open(path))["Visualization Manager"]
    topics = {d["Class"]: d["Topic"]["Value"] for d in manager["Displays"] if "Topic" in d}
    tools = {t["Class"]: t["Topic"]["Value"] for t in manager["Tools"] if "Topic" in t}
    print(json.dumps({"fixed_frame": manager["Global Options"]["Fixed Frame"], "displays": topics, "tools": tools}))


def drive(mode, gx, gy):
    """An outside planner publishing /cmd_vel at 20 Hz from before the start."""
    rclpy.init()
    peer = Peer()
    stamped = mode.endswith("_stamped")
    cmd_vel = peer.create_publisher(TwistStamped if stamped else Twist, "/cmd_vel", 10)
    plan = {"started": None, "past": False, "silent": False, "sent": 0}

    def command():
        msg = Twist()
        if plan["started"] is not None and peer.odom:
            p = peer.odom[-1][1].pose.pose
            x, y = p.position.x, p.position.y
            heading = 2 * math.atan2(p.orientation.z, p.orientation.w)
            if mode == "at_obstacle":
                if time.monotonic() - plan["started"] > 8.0:
                    plan["silent"] = True
                    return
                msg.linear.x = 0.15
            else:
                plan["past"] = plan["past"] or math.hypot(x, y + 0.25) < 0.05
                aim = (gx, gy) if plan["past"] else (0.0, -0.25)
                turn = math.atan2(aim[1] - y, aim[0] - x) - heading
                turn = math.atan2(math.sin(turn), math.cos(turn))
                msg.linear.x, msg.angular.z = 0.1 * max(math.cos(turn), 0.0), 3.0 * turn
        if stamped:
            msg = TwistStamped(twist=msg)
            msg.header.stamp = peer.get_clock().now().to_msg()
            msg.header.frame_id = "base_link"
        cmd_vel.publish(msg)
        plan["sent"] += 1

    peer.create_timer(0.05, command)
    peer.spin_until(lambda: len(peer.odom) >= 5 and peer.diagnostics, 30, "the topics")
    peer.spin_until(lambda: cmd_vel.get_subscription_count() > 0, 20, "flowgate to hear /cmd_vel")
    arm = peer.call("arm")
    peer.send_goal(gx, gy)
    time.sleep(0.3)  # the goal travels on its topic; the start below goes through a service
    start = peer.call("start")
    plan["started"] = time.monotonic()
    peer.spin_until(lambda: (s := peer.state()) and s.startswith("running"), 20, "the gateway to run")
    stopped = peer.spin_until(lambda: (s := peer.state()) and s.startswith("stopped") and s, 60, "the gateway to stop")
    last = peer.odom[-1][1].pose.pose.position
    print(json.dumps({"arm": arm, "start": start, "stopped": stopped, "sent": plan["sent"], "silent": plan["silent"],
                      "last_pose": [last.x, last.y]}))
    peer.destroy_node()
    rclpy.shutdown()


def fleet(flowgate, socket):
    """Vehicle v1 of a fleet driven over /v1/*, the robot left idle until the end."""
    rclpy.init()
    peer = Peer()
    v1 = {n: peer.create_client(Trigger, f"/v1/{n}") for n in ["arm", "start", "estop", "reset"]}
    v1_goal = peer.create_publisher(PoseStamped, "/v1/goal_pose", 10)
    v1_odom = []
    peer.create_subscription(Odometry, "/v1/odom", v1_odom.append, 10)

    def call(name):
        client = v1[name]
        peer.spin_until(lambda: client.service_is_ready(), 20, f"/v1/{name}")
        future = client.call_async(Trigger.Request())
        peer.spin_until(lambda: future.done(), 10, f"an answer from /v1/{name}")
        return {"success": future.result().success, "message": future.result().message}

    def lines():
        out = ctl(flowgate, socket, "status").splitlines()
        robot = next(l.split(None, 1)[1] for l in out if l.startswith("state "))
        vehicle = next(l for l in out if l.startswith("vehicle v1"))
        return robot, vehicle

    def wait_for(text):
        end = time.monotonic() + 40
        while time.monotonic() < end:
            robot, vehicle = lines()
            if text in vehicle:
                return robot, vehicle
            rclpy.spin_once(peer, timeout_sec=0.2)
        fail(f"waited for v1 to be `{text}`: {lines()}")

    peer.spin_until(lambda: len(peer.odom) >= 5, 30, "/odom")
    seen = {"types": dict(peer.get_topic_names_and_types())}
    seen["arm"] = call("arm")
    peer.spin_until(lambda: v1_goal.get_subscription_count() > 0, 20, "flowgate to hear /v1/goal_pose")
    msg = PoseStamped()
    msg.header.frame_id = "map"
    msg.pose.position.x, msg.pose.position.y = 0.2, 0.3
    msg.pose.orientation.w = 1.0
    v1_goal.publish(msg)
    seen["goal"] = wait_for("goal (0.2, 0.3)")
    seen["start"] = call("start")
    seen["reached"] = wait_for("stopped: goal reached")
    peer.spin_until(lambda: len(v1_odom) >= 5, 10, "/v1/odom")
    at = lambda m: [m.pose.pose.position.x, m.pose.pose.position.y]
    seen["v1_odom"] = {"count": len(v1_odom), "first": at(v1_odom[0]), "last": at(v1_odom[-1]),
                       "frames": sorted({(m.header.frame_id, m.child_frame_id) for m in v1_odom}),
                       "fastest": max(m.twist.twist.linear.x for m in v1_odom)}
    markers = peer.obstacles[-1].markers if peer.obstacles else []
    seen["v1_markers"] = sorted({(mk.ns, mk.id, mk.text) for mk in markers if mk.ns.startswith("vehicle")})
    seen["arm_again"] = call("arm")
    seen["estop"] = call("estop")
    seen["estopped"] = wait_for("fault: operator emergency stop")
    seen["reset"] = call("reset")
    seen["after_reset"] = wait_for("idle")
    # The robot, over the node's own services, to a goal of its own: the demo ends there.
    peer.call("arm")
    peer.send_goal(0.0, -0.1)
    time.sleep(0.3)  # the goal travels on its topic; the start below goes through a service
    peer.call("start")
    seen["robot_stopped"] = peer.spin_until(lambda: (s := peer.state()) and s.startswith("stopped") and s, 60, "the robot to stop")
    print(json.dumps(seen))
    peer.destroy_node()
    rclpy.shutdown()


def main():
    if sys.argv[1] == "--fleet":
        return fleet(sys.argv[2], sys.argv[3])
    if sys.argv[1] == "--cmd-vel":
        return drive(sys.argv[2], float(sys.argv[3]), float(sys.argv[4]))
    if sys.argv[1] == "--rviz":
        return rviz(sys.argv[2])
    if sys.argv[1] == "--bag":
        return read_bag(sys.argv[2])
    flowgate, socket, gx, gy = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
    rclpy.init()
    peer = Peer()
    peer.spin_until(lambda: len(peer.odom) >= 5 and peer.diagnostics and peer.paths and peer.obstacles, 30, "the topics")
    types = dict(peer.get_topic_names_and_types())
    seen = len(peer.diagnostics)
    peer.send_goal(5.0, 5.0)
    goal_refused = peer.spin_until(lambda: peer.refusal(seen), 10, "the out-of-view goal's refusal")
    goal_refused_ctl = ctl(flowgate, socket, "goal", "5", "5")
    arm = peer.call("arm")
    arm_again = peer.call("arm")
    arm_again_ctl = ctl(flowgate, socket, "arm")
    peer.send_goal(gx, gy)
    time.sleep(0.3)  # the goal travels on its topic; the start below goes through a service
    start = peer.call("start")
    started = time.monotonic()
    stopped = peer.spin_until(lambda: (s := peer.state()) and s.startswith("stopped") and s, 60, "the gateway to stop")
    ran = time.monotonic() - started
    odom = peer.odom
    span = odom[-1][0] - odom[0][0]
    last = odom[-1][1]
    print(json.dumps({
        "types": {k: v for k, v in types.items() if k in ["/odom", "/tf", "/diagnostics", "/goal_pose", "/flowgate/obstacles", "/flowgate/path"]},
        "odom": [
            {"t": m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, "x": m.pose.pose.position.x, "y": m.pose.pose.position.y,
             "frame": m.header.frame_id, "child": m.child_frame_id, "v": m.twist.twist.linear.x}
            for _, m in odom
        ],
        "odom_rate_hz": (len(odom) - 1) / span if span > 0 else 0,
        "obstacle_namespaces": sorted({mk.ns for a in peer.obstacles for mk in a.markers if mk.ns}),
        "path_frames": sorted({p.header.frame_id for p in peer.paths}),
        "path_longest": max(len(p.poses) for p in peer.paths),
        "goal_refused": goal_refused,
        "goal_refused_ctl": goal_refused_ctl,
        "arm": arm,
        "arm_again": arm_again,
        "arm_again_ctl": arm_again_ctl,
        "start": start,
        "stopped": stopped,
        "ran_s": ran,
        "last_pose": [last.pose.pose.position.x, last.pose.pose.position.y],
    }))
    peer.destroy_node()
    rclpy.shutdown()


main()
