//! `flowgate check` against the simulator over real ptys: a healthy rig passes every line
//! and exits 0; each failure it knows is provoked (a bad key, a missing or busy port, a
//! silent or foreign controller, a refused schedule, slow clock syncs, a hidden robot LED,
//! a missing or bus-off CAN adapter, a board that is absent, faulted or silent, a second
//! master) and must come out as FAIL on its own line, naming the device or key, with a
//! non-zero exit.

use std::path::{Path, PathBuf};
use std::process::Command;

use flowgate::config::RigFile;
use flowgate::lab::Scenario;
use flowgate_sim::rig::{RigConfig, RigHandle};

/// What `flowgate check` printed and how it exited.
struct Outcome {
    ok: bool,
    stdout: String,
}

impl Outcome {
    /// The line for `item`: its verdict and the rest.
    fn line(&self, item: &str) -> &str {
        self.stdout
            .lines()
            .find(|l| l.get(6..).is_some_and(|rest| rest.starts_with(item)))
            .unwrap_or_else(|| panic!("no line for {item}:\n{}", self.stdout))
    }
    fn verdict(&self, item: &str) -> &str {
        &self.line(item)[..4]
    }
    /// Only `item` failed.
    fn fails_only(&self, item: &str, says: &[&str]) {
        assert!(!self.ok, "exit status 0 with a failure:\n{}", self.stdout);
        assert_eq!(self.verdict(item), "FAIL", "{}", self.stdout);
        for s in says {
            assert!(self.line(item).contains(s), "{item} does not say `{s}`:\n{}", self.stdout);
        }
        let fails = self.stdout.lines().filter(|l| l.starts_with("FAIL")).count();
        assert_eq!(fails, 1, "exactly one failure expected:\n{}", self.stdout);
    }
}

fn e1() -> Scenario {
    Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e1-standing-obstacle.toml")).unwrap()
}

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("flowgate-check-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The simulator with `faults` (key=value), and the gateway config for it.
async fn sim(faults: &[&str]) -> (RigHandle, RigFile) {
    sim_with(faults, false).await
}

/// The same with CiA 402 drives (nodes 1 and 2) in place of the board when `cia402`.
async fn sim_with(faults: &[&str], cia402: bool) -> (RigHandle, RigFile) {
    let s = e1();
    let mut rig = RigConfig::new(s.sim.clone());
    if cia402 {
        let node = |n| flowgate_protocol::canopen::NodeId::new(n).unwrap();
        rig.cia402 = Some([node(1), node(2)]);
    }
    let settings: Vec<String> = faults.iter().map(|f| f.to_string()).collect();
    rig.faults = rig.faults.with_settings(&settings).unwrap();
    let handle = flowgate_sim::rig::start(rig).await.unwrap();
    let can = format!("slcan:{}?bitrate=1000000", handle.can_path.as_ref().unwrap().display());
    let mut cfg = s.rig_file(&handle.psd_path, &can, None);
    if cia402 {
        cfg.use_cia402(flowgate::config::Cia402Section::with_nodes(1, 2));
    }
    (handle, cfg)
}

fn check_file(name: &str, text: &str) -> Outcome {
    let path = dir(name).join("rig.toml");
    std::fs::write(&path, text).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_flowgate")).args(["check", "--config"]).arg(&path).output().unwrap();
    let stdout = String::from_utf8(out.stdout).unwrap();
    Outcome { ok: out.status.success(), stdout }
}

fn check(name: &str, cfg: &RigFile) -> Outcome {
    check_file(name, &cfg.to_toml())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_healthy_rig_passes_every_line() {
    let (handle, cfg) = sim(&[]).await;
    let out = check("healthy", &cfg);
    handle.stop().await;
    assert!(out.ok, "{}", out.stdout);
    for item in [
        "config",
        "watchdogs vs board timeout",
        "LED schedule",
        "real-time settings",
        "serial port",
        "controller answers",
        "controller identity",
        "schedule accepted",
        "time sync",
        "sample stream",
        "LEDs in view",
        "CAN interface",
        "board heartbeat",
        "no other master",
        "board config",
    ] {
        assert_eq!(out.verdict(item), "PASS", "{item}:\n{}", out.stdout);
    }
    assert!(out.line("controller identity").contains("firmware 1.0.0, drives up to 16 LEDs, PSD 4096x4096"));
    assert!(out.line("board heartbeat").contains("node 1"), "{}", out.stdout);
    assert!(out.line("board config").contains("then Disabled, no faults, at rest"), "{}", out.stdout);
    assert_eq!(out.verdict("goal reachable"), "PASS", "{}", out.stdout);
    assert!(out.line("goal reachable").contains("[0.35, 0.05] reachable from the robot at (-0.35"), "{}", out.stdout);
    assert!(out.stdout.contains("all 16 checks passed"), "{}", out.stdout);
}

/// A rig with other vehicles: the config's lines show each vehicle, every slot of the one
/// schedule and the delay margin T gives; the controller takes the schedule. A vehicle
/// the rig does not have (the simulated world has the robot alone) fails by its LEDs and its
/// board's node.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fleet_rig_is_checked_vehicle_by_vehicle() {
    let (handle, mut cfg) = sim(&[]).await;
    cfg.vehicles = vec![
        flowgate::config::VehicleSection {
            name: "oncoming".into(),
            front_led: 5,
            rear_led: 6,
            node: Some(2),
            ..Default::default()
        },
        flowgate::config::VehicleSection {
            name: "b".into(),
            front_led: 7,
            rear_led: 8,
            node: Some(3),
            max_speed: Some(0.2),
            ..Default::default()
        },
    ];
    let out = check("fleet", &cfg);
    handle.stop().await;
    assert_eq!(out.verdict("config"), "PASS", "{}", out.stdout);
    // E1's rig: a frame of 17 ms, split over the robot's, the obstacle's and the vehicles' LEDs
    // (docs/fleet.md shows these lines).
    assert!(
        out.line("LED schedule").ends_with(
            "7 LEDs, frame T = 17.000 ms (58.8 Hz); slots 1: 2429 µs, 2: 2429 µs, 3: 2429 µs, 5: 2429 µs, 6: 2428 µs, \
             7: 2428 µs, 8: 2428 µs; delay margin U·T at T: 3.4 mm for a vehicle at 0.2 m/s, 8.5 mm for an obstacle \
             at safety.max_obstacle_speed = 0.5 m/s"
        ),
        "{}",
        out.stdout
    );
    assert!(
        out.line("vehicle").ends_with("LEDs 5 and 6, board node 2, radius 0.07 m, up to 0.15 m/s"),
        "{}",
        out.stdout
    );
    assert!(out.stdout.contains("vehicles: b"), "{}", out.stdout);
    assert_eq!(out.verdict("schedule accepted"), "PASS", "{}", out.stdout);
    // The simulated world has no vehicles: their LEDs are dark and their boards silent.
    assert!(!out.ok, "{}", out.stdout);
    assert_eq!(out.verdict("LEDs in view"), "FAIL", "{}", out.stdout);
    for led in ["LED 5 (vehicle oncoming)", "LED 6 (vehicle oncoming)", "LED 7 (vehicle b)", "LED 8 (vehicle b)"] {
        assert!(out.line("LEDs in view").contains(led), "{led}:\n{}", out.stdout);
    }
    for (vehicle, node) in [("oncoming", 2), ("b", 3)] {
        let line = out
            .stdout
            .lines()
            .find(|l| l.contains(&format!("vehicles: {vehicle}, ")) && l.contains("vehicle motors"))
            .unwrap_or_else(|| panic!("no motors line for {vehicle}:\n{}", out.stdout));
        assert!(line.starts_with("FAIL"), "{line}");
        assert!(line.contains(&format!("node {node}")) && line.contains("no heartbeat in 1000 ms"), "{line}");
    }
    let fails = out.stdout.lines().filter(|l| l.starts_with("FAIL")).count();
    assert_eq!(fails, 3, "the LEDs and the two vehicles' boards, nothing else:\n{}", out.stdout);
}

/// A fleet's scenario served by the simulator (every vehicle's LEDs under the camera, its
/// board or drives on the bus, wired as `flowgate-sim` prints): every line passes, each
/// vehicle's LEDs seen and its motors answering at their own nodes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fleet_the_simulator_serves_passes_every_line() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/fleet/swap-4.toml");
    let s = Scenario::load(&path).unwrap();
    for cia402 in [false, true] {
        let mut rig = RigConfig::new(s.sim.clone());
        if cia402 {
            let node = |n| flowgate_protocol::canopen::NodeId::new(n).unwrap();
            rig.cia402 = Some([node(1), node(2)]);
        }
        let wired = rig.vehicles().unwrap();
        let handle = flowgate_sim::rig::start(rig.clone()).await.unwrap();
        assert_eq!(handle.vehicles, wired);
        let can = format!("slcan:{}?bitrate=1000000", handle.can_path.as_ref().unwrap().display());
        let mut cfg = s.rig_file(&handle.psd_path, &can, None);
        if cia402 {
            cfg.use_cia402(flowgate::config::Cia402Section::with_nodes(1, 2));
            cfg.vehicles = s.sim_vehicles(&rig).unwrap();
        }
        let out = check(if cia402 { "fleet-served-cia402" } else { "fleet-served" }, &cfg);
        // A radius the config has wrong: where the camera sees `v1`, it would overlap a
        // neighbour, which no two bodies can.
        let wrong = (!cia402).then(|| {
            let mut cfg = cfg.clone();
            // Its goal goes too: the loader refuses goals closer than their radii.
            let v1 = &mut cfg.vehicles[0];
            (v1.radius, v1.goal, v1.goal_tolerance) = (Some(0.55), None, None);
            check("fleet-served-overlap", &cfg)
        });
        handle.stop().await;
        assert!(out.ok, "{}", out.stdout);
        assert!(!out.stdout.contains("FAIL") && !out.stdout.contains("WARN"), "{}", out.stdout);
        assert!(out.line("LEDs in view").contains("all 8 LEDs seen"), "{}", out.stdout);
        assert!(out.line("vehicles apart").contains("4 seen clear of each other, the closest"), "{}", out.stdout);
        if let Some(wrong) = wrong {
            wrong.fails_only("vehicles apart", &["v1 at (", "closer than their radii (55.0 + 7.0 cm)", "are wrong"]);
        }
        let motors: Vec<&str> = out.stdout.lines().filter(|l| l.contains("vehicle motors")).collect();
        let expected: &[&str] = if cia402 {
            &[
                "v1, ", "drive 3", "v1, ", "drive 4", "v2, ", "drive 5", "v2, ", "drive 6", "v3, ", "drive 7", "v3, ",
                "drive 8",
            ]
        } else {
            &["v1, ", "node 2", "v2, ", "node 3", "v3, ", "node 4"]
        };
        assert_eq!(motors.len(), expected.len() / 2, "{}", out.stdout);
        for (line, pair) in motors.iter().zip(expected.chunks(2)) {
            assert!(line.contains(pair[0]) && line.contains(pair[1]), "{line} is not {pair:?}");
        }
    }
}

/// More LEDs than the controller says it drives (the simulated one: 16): the handshake
/// refuses the schedule, with both numbers.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fleet_beyond_the_controllers_leds_fails_its_identity() {
    let (handle, mut cfg) = sim(&[]).await;
    cfg.vehicles = (0..10u8)
        .map(|k| flowgate::config::VehicleSection {
            name: format!("v{k}"),
            front_led: 20 + 2 * k,
            rear_led: 21 + 2 * k,
            node: Some(2 + k),
            ..Default::default()
        })
        .collect();
    let out = check("fleet-leds", &cfg);
    handle.stop().await;
    assert_eq!(out.verdict("config"), "PASS", "{}", out.stdout);
    assert!(!out.ok, "{}", out.stdout);
    assert_eq!(out.verdict("controller identity"), "FAIL", "{}", out.stdout);
    let says = "PSD controller drives 16 LEDs (its Info.max_leds); the schedule has 23 ([leds] and [[vehicles]])";
    assert!(out.line("controller identity").contains(says), "{}", out.stdout);
    // Beside it only the ten vehicles' boards, which the simulated bus does not have.
    let fails: Vec<&str> = out.stdout.lines().filter(|l| l.starts_with("FAIL")).collect();
    assert_eq!(fails.len(), 11, "{}", out.stdout);
    assert_eq!(fails.iter().filter(|l| l.contains("vehicle motors")).count(), 10, "{}", out.stdout);
}

#[test]
fn a_bad_key_is_named_and_nothing_is_opened() {
    let s = e1();
    let mut cfg = s.rig_file(Path::new("/dev/null"), "slcan:/dev/null", None);
    cfg.safety.pose_timeout_ms = 0;
    let out = check("bad-key", &cfg);
    out.fails_only("config", &["safety.pose_timeout_ms", "must be 1-60000 ms, is 0"]);
    assert_eq!(out.verdict("serial port"), "SKIP");
    assert_eq!(out.verdict("board config"), "SKIP");

    let out = check_file("unparsable", "[serial]\nport = 3\n");
    out.fails_only("config", &["rig.toml"]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn serial_port_missing_or_busy() {
    let (handle, mut cfg) = sim(&[]).await;
    let real = cfg.serial.port.clone();
    cfg.serial.port = "/dev/flowgate-no-such-port".into();
    let out = check("missing-port", &cfg);
    out.fails_only("serial port", &["/dev/flowgate-no-such-port", "does not exist"]);
    assert_eq!(out.verdict("controller answers"), "SKIP");
    // The CAN side is still checked.
    assert_eq!(out.verdict("board config"), "PASS", "{}", out.stdout);

    cfg.serial.port = real.clone();
    let held = flowgate::gateway::shell::link::open_serial(&real, 921_600).unwrap();
    let out = check("busy-port", &cfg);
    drop(held);
    handle.stop().await;
    out.fails_only("serial port", &[&real.display().to_string(), "in use"]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_controller() {
    let (handle, mut cfg) = sim(&[]).await;
    // A line nobody answers on.
    let (_master, _keep, path) = flowgate_sim::rig::pty().unwrap();
    cfg.serial.port = path.clone();
    let out = check("silent", &cfg);
    handle.stop().await;
    out.fails_only("controller answers", &[&path.display().to_string(), "did not answer GetInfo"]);
    assert_eq!(out.verdict("time sync"), "SKIP");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_controller_that_is_not_the_configured_one() {
    let (handle, mut cfg) = sim(&[]).await;
    cfg.calibration.counts = 2048;
    // A fitted calibration must still load at these counts: points in range.
    let out = check("identity", &cfg);
    handle.stop().await;
    out.fails_only("controller identity", &["calibration.counts", "counts differ"]);
    assert_eq!(out.verdict("controller answers"), "PASS");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_refused_schedule() {
    let (handle, mut cfg) = sim(&[]).await;
    // The simulated controller drives LEDs 1-16.
    cfg.leds.obstacles[0].led = 20;
    let out = check("schedule", &cfg);
    handle.stop().await;
    out.fails_only("schedule accepted", &["refused SetSchedule", "BadValue"]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_clock_syncs() {
    // Every sync reply held 30 ms: round trips the gateway would discard.
    let (handle, cfg) = sim(&["sync_reply_hold=[0.0, 1000.0, 30.0]"]).await;
    let out = check("sync", &cfg);
    handle.stop().await;
    out.fails_only("time sync", &["median 3", "over 10 ms"]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hidden_robot_led() {
    let (handle, cfg) = sim(&["occlusions=[[1.0, 0.0, 1000.0]]"]).await;
    let out = check("led", &cfg);
    handle.stop().await;
    out.fails_only("LEDs in view", &["LED 1 (robot)", "weak"]);
}

/// An obstacle's LED out of view is absent, not a fault: a warning naming it. Marked
/// required, the same LED fails the check, as the arm would be refused.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hidden_obstacle_led_warns_and_fails_when_required() {
    let (handle, mut cfg) = sim(&["occlusions=[[3.0, 0.0, 1000.0]]"]).await;
    let out = check("obstacle-led", &cfg);
    assert!(out.ok, "{}", out.stdout);
    assert_eq!(out.verdict("LEDs in view"), "WARN", "{}", out.stdout);
    assert!(
        out.line("LEDs in view").contains("LED 3: ") && out.line("LEDs in view").contains("samples weak"),
        "{}",
        out.stdout
    );
    assert!(out.line("LEDs in view").contains("absent until it comes into view"), "{}", out.stdout);
    cfg.leds.obstacles[0].required = true;
    let out = check("obstacle-led-required", &cfg);
    handle.stop().await;
    out.fails_only("LEDs in view", &["LED 3 (leds.obstacles[0].required)", "weak"]);
}

/// A goal the camera cannot see is refused with the config, naming the point and the
/// arena's extent.
#[test]
fn a_goal_outside_the_arena_fails_the_config() {
    let s = e1();
    let mut cfg = s.rig_file(Path::new("/dev/null"), "slcan:/dev/null", None);
    cfg.goal.as_mut().unwrap().position = [50.0, 0.0];
    let out = check("far-goal", &cfg);
    out.fails_only(
        "config",
        &[
            "goal.position",
            "[50.0, 0.0] lies outside the calibrated arena",
            "the PSD sees the floor within the corners (",
        ],
    );
    assert_eq!(out.verdict("serial port"), "SKIP");
}

/// A goal walled off from where the camera sees the robot: the config is sound (the goal
/// is clear of the walls), but the robot cannot get there.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_goal_walled_off_from_the_robot_fails() {
    let (handle, mut cfg) = sim(&[]).await;
    let ring = [[0.15, -0.15], [0.55, -0.15], [0.55, 0.25], [0.15, 0.25], [0.15, -0.15]];
    cfg.walls = vec![flowgate::config::PointsSection { points: ring.to_vec() }];
    let out = check("walled-goal", &cfg);
    handle.stop().await;
    out.fails_only(
        "goal reachable",
        &["goal.position", "[0.35, 0.05] is out of the robot's reach from (-0.35", "close it off"],
    );
}

/// In a lane (here two walls that make one) the robot must stand inside it: E1's robot, 6 cm
/// off the centre line, is outside a lane of half-width 5.5 cm that holds the goal.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_robot_outside_the_lane_fails() {
    let (handle, mut cfg) = sim(&[]).await;
    let y = 0.055 + cfg.robot.radius + cfg.planner.clearance;
    cfg.walls = [y, -y].map(|y| flowgate::config::PointsSection { points: vec![[-3.0, y], [3.0, y]] }).to_vec();
    let out = check("narrow-lane", &cfg);
    handle.stop().await;
    out.fails_only("goal reachable", &["goal.position", "the robot at (-0.35", "is outside the lane (|y| >= 0.055"]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn duplicates_on_the_line_are_a_warning() {
    let (handle, cfg) = sim(&["serial_duplicate=0.05"]).await;
    let out = check("duplicates", &cfg);
    handle.stop().await;
    assert!(out.ok, "{}", out.stdout);
    assert_eq!(out.verdict("sample stream"), "WARN", "{}", out.stdout);
    assert!(!out.line("sample stream").contains(" 0 duplicate"), "{}", out.stdout);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn can_adapter_missing_or_bus_off() {
    let (handle, mut cfg) = sim(&[]).await;
    cfg.can.endpoint = "slcan:/dev/flowgate-no-such-adapter?bitrate=1000000".into();
    let out = check("no-adapter", &cfg);
    handle.stop().await;
    out.fails_only("CAN interface", &["/dev/flowgate-no-such-adapter", "does not exist"]);
    assert_eq!(out.verdict("board heartbeat"), "SKIP");

    let (handle, cfg) = sim(&["adapter_bus_off=[0.0, 1000.0]"]).await;
    let out = check("bus-off", &cfg);
    handle.stop().await;
    assert_eq!(out.verdict("CAN interface"), "FAIL", "{}", out.stdout);
    assert!(out.line("CAN interface").contains("bus-off"), "{}", out.stdout);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_board_at_another_node() {
    let (handle, mut cfg) = sim(&[]).await;
    cfg.can.node = 5;
    let out = check("node", &cfg);
    handle.stop().await;
    out.fails_only("board heartbeat", &["node 5", "no heartbeat", "nodes heard: [1]"]);
    assert_eq!(out.verdict("board config"), "SKIP");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_faulted_board() {
    let (handle, cfg) = sim(&["board_fault_at=0.0"]).await;
    let out = check("board-fault", &cfg);
    handle.stop().await;
    out.fails_only("board heartbeat", &["Fault", "driver"]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_board_without_heartbeat() {
    let (handle, cfg) = sim(&["heartbeat_stop_at=0.0"]).await;
    let out = check("no-heartbeat", &cfg);
    handle.stop().await;
    out.fails_only("board heartbeat", &["no heartbeat in 1000 ms"]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_master_on_the_bus() {
    let (handle, cfg) = sim(&["second_master_at=0.0"]).await;
    let out = check("master", &cfg);
    handle.stop().await;
    assert_eq!(out.verdict("no other master"), "FAIL", "{}", out.stdout);
    assert!(out.line("no other master").contains("another gateway is running"), "{}", out.stdout);
    assert!(!out.ok);
}

/// Whether this host grants SCHED_FIFO and mlockall to a process like the test's.
fn realtime_granted() -> bool {
    Command::new("chrt").args(["-f", "10", "true"]).status().is_ok_and(|s| s.success())
}

/// `flowgate check` under `setpriv`/`prlimit` without CAP_SYS_NICE and CAP_IPC_LOCK, and
/// with RLIMIT_RTPRIO 0 and RLIMIT_MEMLOCK 64 KiB: what an unprivileged service meets.
fn check_unprivileged(name: &str, cfg: &RigFile) -> Outcome {
    let path = dir(name).join("rig.toml");
    std::fs::write(&path, cfg.to_toml()).unwrap();
    let out = Command::new("setpriv")
        .args(["--bounding-set=-sys_nice,-ipc_lock", "prlimit", "--rtprio=0", "--memlock=65536"])
        .arg(env!("CARGO_BIN_EXE_flowgate"))
        .args(["check", "--config"])
        .arg(&path)
        .output()
        .unwrap();
    Outcome { ok: out.status.success(), stdout: String::from_utf8(out.stdout).unwrap() }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn real_time_settings_granted_or_refused_by_name() {
    let (handle, mut cfg) = sim(&[]).await;
    cfg.realtime.cpus = vec![0];
    cfg.realtime.fifo_priority = 50;
    cfg.realtime.lock_memory = true;
    let out = check("realtime", &cfg);
    if realtime_granted() {
        assert!(out.ok, "{}", out.stdout);
        assert!(
            out.line("real-time settings").contains("CPUs [0], SCHED_FIFO 50, memory locked: granted"),
            "{}",
            out.stdout
        );
    } else {
        assert_eq!(out.verdict("real-time settings"), "FAIL", "{}", out.stdout);
    }

    cfg.realtime.lock_memory = false;
    let out = check_unprivileged("realtime-fifo", &cfg);
    out.fails_only(
        "real-time settings",
        &["realtime.fifo_priority = 50", "CAP_SYS_NICE", "it has 0", "LimitRTPRIO=50"],
    );

    cfg.realtime.fifo_priority = 0;
    cfg.realtime.lock_memory = true;
    let out = check_unprivileged("realtime-lock", &cfg);
    handle.stop().await;
    out.fails_only(
        "real-time settings",
        &["realtime.lock_memory", "CAP_IPC_LOCK", "it has 64 KiB", "LimitMEMLOCK=infinity"],
    );
}

/// `flowgate run` meets the same refusal at start, and does not start.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_gateway_does_not_start_without_its_real_time_settings() {
    let (handle, mut cfg) = sim(&[]).await;
    cfg.realtime.fifo_priority = 40;
    cfg.goal = None;
    let path = dir("realtime-run").join("rig.toml");
    std::fs::write(&path, cfg.to_toml()).unwrap();
    let out = Command::new("setpriv")
        .args(["--bounding-set=-sys_nice", "prlimit", "--rtprio=0"])
        .arg(env!("CARGO_BIN_EXE_flowgate"))
        .args(["run", "--config"])
        .arg(&path)
        .output()
        .unwrap();
    handle.stop().await;
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("Error: realtime.fifo_priority = 40: SCHED_FIFO refused") && stderr.contains("LimitRTPRIO=40"),
        "{stderr}"
    );
}

/// CiA 402 drives are read by SDO: device type, profile velocity supported, state.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cia402_drives_are_read_and_pass() {
    let (handle, cfg) = sim_with(&[], true).await;
    let out = check("cia402", &cfg);
    handle.stop().await;
    assert!(out.ok, "{}", out.stdout);
    for item in ["left drive", "right drive", "no other master"] {
        assert_eq!(out.verdict(item), "PASS", "{item}:\n{}", out.stdout);
    }
    assert!(out.line("left drive").contains("node 1"), "{}", out.stdout);
    assert!(
        out.line("right drive").contains("CiA 402, profile velocity supported, statusword 0x1250 (switch on disabled)"),
        "{}",
        out.stdout
    );
    assert!(!out.stdout.contains("board heartbeat"), "{}", out.stdout);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_faulted_or_absent_drive_fails_by_node() {
    let (handle, cfg) = sim_with(&["drive_undervoltage=[0.0, 60.0]"], true).await;
    let out = check("cia402-fault", &cfg);
    handle.stop().await;
    out.fails_only("left drive", &["node 1", "in fault"]);

    let (handle, mut cfg) = sim_with(&[], true).await;
    cfg.cia402.as_mut().unwrap().right_node = 5;
    let out = check("cia402-absent", &cfg);
    handle.stop().await;
    out.fails_only("right drive", &["node 5", "no answer to SDO 0x1000:0 within cia402.sdo_timeout_ms"]);
}
