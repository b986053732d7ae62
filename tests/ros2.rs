//! flowgate in a ROS 2 system: `flowgate demo --ros2` beside a node of rclpy (Jazzy's, Fast
//! DDS, from PyPI) that a lab would write: it hears every topic, its goal and its service
//! calls drive the robot to that goal, and refusals come back in the control socket's words.
//! Discovery stays on the loopback interface (`ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST` on
//! both sides), in a domain of the test's own.

#![cfg(feature = "ros2")]

#[path = "support/python.rs"]
mod python;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use serde_json::Value;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("flowgate-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Each `/cycle` of a recording: its log time (ns since the Unix epoch) and the robot's x, y.
fn recorded_cycles(path: &Path) -> Vec<(u64, f64, f64)> {
    recorded(path, "/cycle").into_iter().map(|(t, c)| (t, c["x"].as_f64().unwrap(), c["y"].as_f64().unwrap())).collect()
}

/// Every message of a JSON channel of a recording, with its log time.
fn recorded(path: &Path, topic: &str) -> Vec<(u64, Value)> {
    let bytes = std::fs::read(path).unwrap();
    let mut out = Vec::new();
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        if message.channel.topic == topic {
            out.push((message.log_time, serde_json::from_slice(&message.data).unwrap()));
        }
    }
    out
}

/// ROS 2's environment for a run of this file's tests: discovery on loopback, in domain
/// `100 + (pid + offset) % 100` (two runs of the suite, or two tests of it side by side, do
/// not hear each other).
fn ros_env(offset: u32) -> [(&'static str, String); 3] {
    [
        ("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST".into()),
        ("ROS_DOMAIN_ID", (100 + (std::process::id() + offset) % 100).to_string()),
        ("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp".into()),
    ]
}

/// `flowgate demo --ros2 --scenario SCENARIO` in `dir`, recording to `dir/run.mcap`, with
/// `extra` arguments, its output piped.
fn demo_ros2(
    dir: &Path,
    scenario: &Path,
    extra: &[&std::ffi::OsStr],
    env: &[(&'static str, String); 3],
) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_flowgate"))
        .args(["demo", "--ros2", "--scenario"])
        .arg(scenario)
        .args(extra)
        .arg("--out")
        .arg(dir.join("out"))
        .arg("--record")
        .arg(dir.join("run.mcap"))
        .envs(env.iter().map(|(k, v)| (*k, v.as_str())))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

#[test]
fn a_ros2_node_watches_and_drives_flowgate() {
    let dir = temp_dir("ros2");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let flowgate = env!("CARGO_BIN_EXE_flowgate");
    let socket = dir.join("control.sock");
    let recording = dir.join("run.mcap");
    let env = ros_env(0);
    let e1 = root.join("scenarios/e1-standing-obstacle.toml");
    let demo = demo_ros2(&dir, &e1, &["--socket".as_ref(), socket.as_os_str()], &env);
    // The peer waits on each topic and service with a deadline of its own.
    let (gx, gy) = (0.3, 0.06);
    let (seen, demo) = beside(demo, &[flowgate, socket.to_str().unwrap(), &gx.to_string(), &gy.to_string()], &env);
    assert!(demo.status.success(), "demo: {}", said(&demo));

    let types = &seen["types"];
    for (topic, kind) in [
        ("/odom", "nav_msgs/msg/Odometry"),
        ("/tf", "tf2_msgs/msg/TFMessage"),
        ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray"),
        ("/goal_pose", "geometry_msgs/msg/PoseStamped"),
        ("/flowgate/obstacles", "visualization_msgs/msg/MarkerArray"),
        ("/flowgate/path", "nav_msgs/msg/Path"),
    ] {
        assert_eq!(types[topic], serde_json::json!([kind]), "{topic}: {types}");
    }
    // The refusals, word for word as `flowgate ctl` prints the control socket's.
    let goal_refused = seen["goal_refused"].as_str().unwrap();
    assert!(goal_refused.contains("outside the calibrated arena"), "{goal_refused}");
    assert_eq!(seen["goal_refused_ctl"].as_str().unwrap(), format!("Error: refused: {goal_refused}"));
    assert_eq!(seen["arm"], serde_json::json!({"success": true, "message": "armed"}));
    assert_eq!(seen["arm_again"], serde_json::json!({"success": false, "message": "already armed"}));
    assert_eq!(seen["arm_again_ctl"], "Error: refused: already armed");
    assert_eq!(seen["start"]["success"], true);
    // The robot reached the peer's goal (not the scenario's, 0.35, 0.05), and said so.
    assert_eq!(seen["stopped"], "stopped: goal reached");
    let last = &seen["last_pose"];
    let off = (last[0].as_f64().unwrap() - gx).hypot(last[1].as_f64().unwrap() - gy);
    assert!(off < 0.03, "the robot stopped {off:.3} m from the peer's goal");

    let odom = seen["odom"].as_array().unwrap();
    assert!(odom.iter().all(|o| o["frame"] == "map" && o["child"] == "base_link"));
    let rate = seen["odom_rate_hz"].as_f64().unwrap();
    assert!((17.0..=23.0).contains(&rate), "/odom at {rate:.1} Hz, published at 20");
    assert!(odom.iter().any(|o| o["v"].as_f64().unwrap() > 0.05), "/odom's twist never moved");
    let namespaces = &seen["obstacle_namespaces"];
    for ns in ["obstacle", "planning_circle", "velocity", "view_edge"] {
        assert!(namespaces.as_array().unwrap().iter().any(|n| n == ns), "{ns} not in {namespaces}");
    }
    assert_eq!(seen["path_frames"], serde_json::json!(["map"]));
    assert!(seen["path_longest"].as_u64().unwrap() > 20, "~/path: {}", seen["path_longest"]);

    // Each /odom pose is the pose of a cycle recorded shortly before its stamp, the node
    // publishing as the shell's loop gets to it: within 100 ms on a loaded machine (cycles
    // are recorded from the arm on: before it, there is none to compare with).
    let cycles = recorded_cycles(&recording);
    assert!(!cycles.is_empty());
    let mut compared = 0;
    for o in odom {
        let t_ns = (o["t"].as_f64().unwrap() * 1e9) as u64;
        let recent: Vec<(f64, f64)> =
            cycles.iter().filter(|c| c.0 <= t_ns && t_ns - c.0 <= 100_000_000).map(|c| (c.1, c.2)).collect();
        if recent.is_empty() {
            continue;
        }
        let (ox, oy) = (o["x"].as_f64().unwrap(), o["y"].as_f64().unwrap());
        let matched = recent.iter().any(|&(x, y)| (ox - x).abs() < 1e-3 && (oy - y).abs() < 1e-3);
        assert!(matched, "/odom ({ox}, {oy}) at {t_ns} ns, cycles of the 100 ms before: {recent:?}");
        compared += 1;
    }
    let moving = odom.iter().filter(|o| o["v"].as_f64().unwrap() > 0.0).count();
    assert!(compared >= moving, "{compared} /odom poses compared, {moving} moving");

    // The recording as a ROS 2 bag, read by rosbags from the bag's own message definitions:
    // a /odom and a /tf for every recorded cycle, at its log time, at its pose.
    let bag = dir.join("bag");
    let export =
        Command::new(flowgate).args(["record", "export", "--ros2"]).arg(&bag).arg(&recording).output().unwrap();
    assert!(export.status.success(), "{}", said(&export));
    let read = Command::new(python::python()).arg(python::peer("ros2")).arg("--bag").arg(&bag).output().unwrap();
    assert!(read.status.success(), "rosbags: {}", said(&read));
    let bag: Value = serde_json::from_slice(&read.stdout).unwrap();
    assert_eq!(bag["types"]["/odom"], "nav_msgs/msg/Odometry");
    assert_eq!(bag["types"]["/tf"], "tf2_msgs/msg/TFMessage");
    assert_eq!(bag["types"]["/flowgate/obstacles"], "visualization_msgs/msg/MarkerArray");
    assert_eq!(bag["types"]["/flowgate/path"], "nav_msgs/msg/Path");
    assert_eq!(bag["types"]["/diagnostics"], "diagnostic_msgs/msg/DiagnosticArray");
    for topic in ["/odom", "/tf"] {
        let messages = bag[topic.trim_start_matches('/')].as_array().unwrap();
        assert_eq!(messages.len(), cycles.len(), "{topic}: one a recorded cycle");
        for (m, &(at, x, y)) in messages.iter().zip(&cycles) {
            assert_eq!(m["ns"].as_u64(), Some(at), "{topic}");
            let (mx, my) = (m["x"].as_f64().unwrap(), m["y"].as_f64().unwrap());
            assert!((mx - x).abs() < 1e-5 && (my - y).abs() < 1e-5, "{topic} ({mx}, {my}), cycle ({x}, {y})");
            assert!(m["frame"] == "map" && m["child"] == "base_link", "{m}");
        }
    }
    assert_eq!(bag["namespaces"], seen["obstacle_namespaces"]);
    // Each state in /diagnostics is its cycle's (the last is the recording's end, no cycle).
    let states: std::collections::HashMap<u64, String> =
        recorded(&recording, "/cycle").into_iter().map(|(t, c)| (t, c["state"].as_str().unwrap().to_owned())).collect();
    let diagnostics = bag["diagnostics"].as_array().unwrap();
    for d in &diagnostics[..diagnostics.len() - 1] {
        let state = &states[&d["ns"].as_u64().unwrap()];
        assert!(d["state"].as_str().unwrap().starts_with(state.as_str()), "{d} at a cycle in {state}");
    }
    // The bag's ~/obstacles take the first cycle of each 50 ms, the recording's /obstacles
    // the first of each 100 ms: each recorded one has its marker array, where it has it.
    let markers: std::collections::HashMap<u64, &Value> =
        bag["obstacles"].as_array().unwrap().iter().map(|m| (m["ns"].as_u64().unwrap(), m)).collect();
    let recorded_obstacles = recorded(&recording, "/obstacles");
    assert!(recorded_obstacles.len() > 50, "{} recorded /obstacles", recorded_obstacles.len());
    for (at, r) in &recorded_obstacles {
        let m = markers.get(at).unwrap_or_else(|| panic!("no ~/obstacles in the bag at {at} ns"));
        let (ours, theirs) = (m["at"].as_array().unwrap(), r["obstacles"].as_array().unwrap());
        assert_eq!(ours.len(), theirs.len(), "{m} / {r}");
        for (k, (a, b)) in ours.iter().zip(theirs).enumerate() {
            for i in 0..2 {
                let d = a[i].as_f64().unwrap() - b["position"][i].as_f64().unwrap();
                assert!(d.abs() < 1e-4, "obstacle {k}: {a} / {b}");
            }
            let radius = m["planning_radius"][k].as_f64().unwrap() - b["planning_radius"].as_f64().unwrap();
            assert!(radius.abs() < 1e-4, "obstacle {k}'s planning radius: {m} / {b}");
        }
    }
    assert!(bag["paths"].as_array().unwrap().iter().any(|n| n.as_u64().unwrap() > 20));
    let states = bag["states"].as_array().unwrap();
    assert_eq!(states.first().unwrap(), "armed");
    assert_eq!(states.last().unwrap(), "stopped: goal reached");
    let _ = std::fs::remove_dir_all(&dir);
}

/// deploy/rviz/flowgate.rviz, read as YAML: the floor as the fixed frame, a display on each
/// topic the node publishes, and RViz's goal tool on the topic the node takes.
#[test]
fn the_rviz_configuration_shows_what_the_node_publishes() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = Command::new(python::python())
        .arg(python::peer("ros2"))
        .arg("--rviz")
        .arg(root.join("deploy/rviz/flowgate.rviz"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rviz: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(rviz["fixed_frame"], "map");
    assert_eq!(
        rviz["displays"],
        serde_json::json!({
            "rviz_default_plugins/Odometry": "/odom",
            "rviz_default_plugins/MarkerArray": "/flowgate/obstacles",
            "rviz_default_plugins/Path": "/flowgate/path",
        })
    );
    assert_eq!(rviz["tools"], serde_json::json!({"rviz_default_plugins/SetGoal": "/goal_pose"}));
}

/// `flowgate demo --ros2` on E1 with `planner.method = "ros2"`, and an rclpy node driving
/// it on `/cmd_vel` (`mode`, see the peer): the demo's words and its recording.
fn drive_on_cmd_vel(name: &str, mode: &str, domain: u32) -> (Value, (bool, String), Vec<Value>) {
    let stamped: &[&std::ffi::OsStr] = if mode.ends_with("_stamped") { &["--cmd-vel-stamped".as_ref()] } else { &[] };
    let dir = temp_dir(name);
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let e1 = std::fs::read_to_string(root.join("scenarios/e1-standing-obstacle.toml")).unwrap();
    let scenario = dir.join("e1-ros2.toml");
    std::fs::write(&scenario, e1.replace("[planner]\n", "[planner]\nmethod = \"ros2\"\n")).unwrap();
    let recording = dir.join("run.mcap");
    let env = ros_env(domain);
    let demo = demo_ros2(&dir, &scenario, stamped, &env);
    let (seen, demo) = beside(demo, &["--cmd-vel", mode, "0.35", "0.05"], &env);
    let cycles = recorded(&recording, "/cycle").into_iter().map(|(_, c)| c).collect();
    let _ = std::fs::remove_dir_all(&dir);
    (seen, (demo.status.success(), said(&demo)), cycles)
}

/// What a process said, its output and its errors.
fn said(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr)
}

/// The rclpy peer run with `args` beside `demo` until it ends, then the demo's end: what
/// the peer saw (its JSON line), and the demo's output.
fn beside(
    demo: std::process::Child,
    args: &[&str],
    env: &[(&'static str, String); 3],
) -> (Value, std::process::Output) {
    let peer = Command::new(python::python())
        .arg(python::peer("ros2"))
        .args(args)
        .envs(env.iter().map(|(k, v)| (*k, v.as_str())))
        .output()
        .unwrap();
    let demo = demo.wait_with_output().unwrap();
    assert!(peer.status.success(), "peer: {}\ndemo: {}", said(&peer), said(&demo));
    (serde_json::from_slice(&peer.stdout).unwrap(), demo)
}

/// An rclpy node publishes `cmd_vel` straight at the standing obstacle: the supervisor
/// stops the robot short of it, each cycle recording what was asked and what passed; when
/// the node goes silent the robot stops in order, named.
#[test]
fn an_rclpy_node_driving_at_an_obstacle_is_stopped_short_and_its_silence_stops_the_robot() {
    let (seen, (_, demo), cycles) = drive_on_cmd_vel("cmd-vel-obstacle", "at_obstacle", 37);
    assert_eq!(seen["arm"]["success"], true, "{seen}");
    assert_eq!(seen["silent"], true, "{seen}");
    assert_eq!(
        seen["stopped"], "stopped: the outside planner's command older than planner.command_max_age_ms",
        "{seen}"
    );
    // Not at the goal (the demo says so), and clear of the obstacle it was driven at.
    assert!(demo.contains("outcome          goal not reached"), "{demo}");
    let clearance: f64 = demo
        .lines()
        .find_map(|l| l.strip_prefix("world truth      min clearance ")?.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| panic!("no clearance in {demo}"));
    assert!(clearance > 0.0, "{clearance} mm: {demo}");
    let held_back = cycles
        .iter()
        .filter(|c| c["asked_left"].as_f64().unwrap() > 0.1 && c["passed_left"].as_f64().unwrap() < 0.05)
        .count();
    assert!(held_back > 20, "{held_back} cycles where the supervisor held back what cmd_vel asked");
}

/// An rclpy node steering on `/odom` round the obstacle to the goal reaches it, in Twist
/// and, with `[ros2] cmd_vel_stamped`, in TwistStamped (as nav2's controllers publish).
#[test]
fn an_rclpy_node_steering_on_cmd_vel_reaches_the_goal() {
    for (name, mode, domain) in [("cmd-vel-goal", "to_goal", 71), ("cmd-vel-stamped", "to_goal_stamped", 73)] {
        steer_to_goal(name, mode, domain);
    }
}

fn steer_to_goal(name: &str, mode: &str, domain: u32) {
    let (seen, (finished, demo), _) = drive_on_cmd_vel(name, mode, domain);
    assert!(finished, "{demo}");
    assert_eq!(seen["stopped"], "stopped: goal reached", "{seen}");
    let last = &seen["last_pose"];
    let off = (last[0].as_f64().unwrap() - 0.35).hypot(last[1].as_f64().unwrap() - 0.05);
    assert!(off < 0.03, "{off}");
    assert!(demo.contains("no contact"), "{demo}");
}

/// A fleet as a ROS 2 system sees it: `flowgate demo --ros2` of the 2-vehicle swap, and an
/// rclpy node that drives vehicle `v1` over its own namespace (`/v1/arm`, `/v1/goal_pose`,
/// `/v1/start`, `/v1/estop`, `/v1/reset`) while the robot stands idle, then the robot over
/// the node's own services. Each answer names the vehicle's state, and `flowgate ctl status`
/// shows each step on v1 alone.
#[test]
fn each_vehicle_of_a_fleet_is_driven_over_its_own_namespace() {
    let dir = temp_dir("ros2-fleet");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let socket = dir.join("control.sock");
    let env = ros_env(53);
    let swap = root.join("scenarios/fleet/swap-2.toml");
    let demo = demo_ros2(&dir, &swap, &["--socket".as_ref(), socket.as_os_str()], &env);
    let (seen, demo) = beside(demo, &["--fleet", env!("CARGO_BIN_EXE_flowgate"), socket.to_str().unwrap()], &env);
    assert_eq!(seen["types"]["/v1/goal_pose"], serde_json::json!(["geometry_msgs/msg/PoseStamped"]), "{seen}");
    assert_eq!(seen["arm"], serde_json::json!({"success": true, "message": "armed"}));
    assert_eq!(seen["start"]["success"], true, "{seen}");
    assert_eq!(seen["estop"], serde_json::json!({"success": true, "message": "fault: operator emergency stop"}));
    assert_eq!(seen["reset"], serde_json::json!({"success": true, "message": "idle"}));
    // The robot stood idle while v1 was driven, e-stopped and reset.
    for step in ["goal", "reached", "estopped", "after_reset"] {
        assert_eq!(seen[step][0], "idle", "{step}: {seen}");
    }
    assert_eq!(seen["robot_stopped"], "stopped: goal reached", "{seen}");
    assert!(demo.status.success(), "demo: {}", said(&demo));
    // v1 on its own /v1/odom, in its own frame: from its start, (0, 0.3) in swap-2, to the
    // node's goal, with its name and goal in ~/obstacles.
    let odom = &seen["v1_odom"];
    assert_eq!(odom["frames"], serde_json::json!([["map", "v1/base_link"]]), "{odom}");
    let off = |p: &Value, [x, y]: [f64; 2]| (p[0].as_f64().unwrap() - x).hypot(p[1].as_f64().unwrap() - y);
    assert!(off(&odom["first"], [0.0, 0.3]) < 0.03, "{odom}");
    assert!(off(&odom["last"], [0.2, 0.3]) < 0.05, "{odom}");
    assert!(odom["fastest"].as_f64().unwrap() > 0.03, "{odom}");
    let markers: Vec<(String, i64, String)> = serde_json::from_value(seen["v1_markers"].clone()).unwrap();
    let named = |ns: &str, text: &str| markers.iter().any(|(n, id, t)| n == ns && *id == 0 && t == text);
    assert!(named("vehicle", "") && named("vehicle_name", "v1") && named("vehicle_goal", ""), "{markers:?}");

    // The recording as a bag: v1 has its /v1/odom and its frame in /tf at the node's 20 Hz
    // from the start, the robot standing or not: from its start, on its way, at its goal.
    let bag = dir.join("bag");
    let flowgate = env!("CARGO_BIN_EXE_flowgate");
    let export = Command::new(flowgate)
        .args(["record", "export", "--ros2"])
        .arg(&bag)
        .arg(dir.join("run.mcap"))
        .output()
        .unwrap();
    assert!(export.status.success(), "{}", said(&export));
    let read = Command::new(python::python()).arg(python::peer("ros2")).arg("--bag").arg(&bag).output().unwrap();
    assert!(read.status.success(), "rosbags: {}", said(&read));
    let bag: Value = serde_json::from_slice(&read.stdout).unwrap();
    assert_eq!(bag["types"]["/v1/odom"], "nav_msgs/msg/Odometry");
    assert_eq!(bag["tf_children"], serde_json::json!(["base_link", "v1/base_link"]));
    let v1 = bag["vehicle_odom"]["/v1/odom"].as_array().unwrap();
    assert!(v1.len() > 100, "{} /v1/odom", v1.len());
    assert!(v1.iter().all(|m| m["frame"] == "map" && m["child"] == "v1/base_link"));
    let ns: Vec<u64> = v1.iter().map(|m| m["ns"].as_u64().unwrap()).collect();
    assert!(ns.windows(2).all(|w| w[1] - w[0] >= 50_000_000), "at most 20 Hz");
    let at = |m: &Value| [m["x"].as_f64().unwrap(), m["y"].as_f64().unwrap()];
    let [first, last] = [at(&v1[0]), at(&v1[v1.len() - 1])];
    assert!((first[0] - 0.0).hypot(first[1] - 0.3) < 0.03 && (last[0] - 0.2).hypot(last[1] - 0.3) < 0.05, "{v1:?}");
    assert!(v1.iter().any(|m| (0.05..0.15).contains(&at(m)[0])), "v1 on its way, the robot standing");
    let _ = std::fs::remove_dir_all(&dir);
}
