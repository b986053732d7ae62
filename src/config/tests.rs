use super::planning::{default_clearance, default_uncertainty_sigmas};
use super::*;

const EXAMPLE: &str = include_str!("../../rig.example.toml");

fn rig(text: &str) -> Result<Rig, ConfigError> {
    RigFile::from_toml(text, "rig.toml")?.rig("rig.toml")
}

/// The planner's default room is twice what the supervisor keeps beyond its uncertainty
/// allowance, so the field steers round the supervisor's zone.
#[test]
fn the_planner_leaves_the_supervisor_room() {
    let supervisor = SupervisorConfig::new(1.0, 0.1, 0.07, 0.02, None);
    assert!((default_clearance() - 2.0 * supervisor.keep_out()).abs() < 1e-12);
    assert!(default_uncertainty_sigmas() >= supervisor.sigmas);
}

#[test]
fn the_stall_check_is_the_configured_one() {
    let r = rig(EXAMPLE).unwrap();
    assert_eq!((r.control.stall.window, r.control.stall.min_progress), (3.0, 0.01), "the defaults");
    let r = rig(&EXAMPLE.replace("stall_window_ms = 3000 ", "stall_window_ms = 3600000 ")).unwrap();
    assert_eq!(r.control.stall.window, 3600.0);
}

#[test]
fn the_example_is_valid() {
    let r = rig(EXAMPLE).unwrap();
    assert_eq!(r.can, CanUrl::Slcan { path: "/dev/flowgate-can".into(), bitrate: 1_000_000, baud: 921_600 });
    assert_eq!(r.obstacles.len(), 2);
    assert_eq!(r.schedule.slots().len(), 4);
    assert_eq!(r.sample_period, Duration::from_micros(4 * 4000 + 1000));
}

#[test]
fn bad_values_are_refused_naming_the_key() {
    let cases = [
        ("node = 1", "node = 16", "can.node"),
        ("endpoint = \"slcan:/dev/flowgate-can?bitrate=1000000\"", "endpoint = \"can0\"", "can.endpoint"),
        ("wheel_radius = 0.025", "wheel_radius = -0.025", "drive.wheel_radius"),
        ("robot_rear = 2", "robot_rear = 1", "leds.robot_rear"),
        ("factor = 1.1", "factor = 0.9", "planner.margin.factor"),
        ("uncertainty_sigmas = 1.0", "uncertainty_sigmas = -1", "planner.uncertainty_sigmas"),
        ("uncertainty_sigmas = 1.0", "uncertainty_sigmas = nan", "planner.uncertainty_sigmas"),
        ("clearance = 0.006", "clearance = 0.5", "planner.clearance"),
        ("clearance = 0.006", "clearance = -0.001", "planner.clearance"),
        ("goal_wait = 10.0", "goal_wait = -1.0", "planner.goal_wait"),
        ("goal_wait = 10.0", "goal_wait = inf", "planner.goal_wait"),
        ("anticipation = 3.0", "anticipation = -1", "planner.anticipation"),
        ("anticipation = 3.0", "anticipation = nan", "planner.anticipation"),
        ("lane_residual = 1e-4", "lane_residual = 1e-3", "planner.lane_residual"),
        ("lane_residual = 1e-4", "lane_residual = nan", "planner.lane_residual"),
        ("rule = \"factor\", factor = 1.1", "rule = \"delay\", extra_speed = nan", "planner.margin.extra_speed"),
        ("rule = \"factor\", factor = 1.1", "rule = \"delay\", extra_speed = -1", "planner.margin.extra_speed"),
        ("k1 = 0.0", "k1 = nan", "calibration.k1"),
        ("counts = 4096", "counts = 0", "calibration.counts"),
        ("queue = 8192", "queue = 9223372036854775807", "telemetry.queue"),
        ("pose_timeout_ms = 150", "pose_timeout_ms = 4000000000", "safety.pose_timeout_ms"),
        ("command_timeout_ms = 200", "command_timeout_ms = 10", "drive.command_timeout_ms"),
        // The gateway's watchdogs fire a cycle (17 ms) before the board's 200 ms timeout.
        ("pose_timeout_ms = 150", "pose_timeout_ms = 184", "safety.pose_timeout_ms"),
        ("sample_timeout_ms = 100", "sample_timeout_ms = 184", "safety.sample_timeout_ms"),
        ("command_timeout_ms = 200", "command_timeout_ms = 166", "safety.pose_timeout_ms"),
        ("slot_us = 4000", "slot_us = 70000", "schedule.slot_us"),
        ("pose_tolerance_m = 0.02", "pose_tolerance_m = nan", "safety.pose_tolerance_m"),
        ("stall_window_ms = 3000 ", "stall_window_ms = 50 ", "safety.stall_window_ms"),
        ("stall_progress_m = 0.01 ", "stall_progress_m = 0 ", "safety.stall_progress_m"),
        // The low-latency window, twice over, must fit in T = 17 ms or the loop never sleeps.
        ("spin_us = 0 ", "spin_us = 8500 ", "realtime.spin_us"),
        ("warm_up = false ", "warm_up = true ", "realtime.warm_up"),
        ("fifo_priority = 0 ", "fifo_priority = 100 ", "realtime.fifo_priority"),
        ("max_speed = 0.15 ", "max_speed = 0.26 ", "robot.max_speed"),
        ("microsteps = 8", "microsteps = 4000000000", "drive.microsteps"),
        ("cpus = [] ", "cpus = [1, 1] ", "realtime.cpus[1]"),
        ("cpus = [] ", "cpus = [5000] ", "realtime.cpus[0]"),
    ];
    for (from, to, key) in cases {
        assert!(EXAMPLE.contains(from), "example lacks {from}");
        let err = rig(&EXAMPLE.replace(from, to)).unwrap_err().to_string();
        assert!(err.contains(&format!("`{key}`")), "{to}: {err}");
    }
    assert!(rig(&EXAMPLE.replace("pose_timeout_ms = 150", "pose_timeout_ms = 183")).is_ok(), "183 + 17 = 200");
    assert_eq!(rig(EXAMPLE).unwrap().spin, None, "off by default");
    let spin = rig(&EXAMPLE.replace("spin_us = 0 ", "spin_us = 8499 ")).unwrap().spin;
    assert_eq!(spin, Some(Duration::from_micros(8499)));
    assert!(rig(EXAMPLE).unwrap().realtime.is_empty(), "no real-time settings by default");
    let rt = rig(&EXAMPLE.replace("fifo_priority = 0 ", "fifo_priority = 60 ").replace("cpus = [] ", "cpus = [3] "))
        .unwrap()
        .realtime;
    assert_eq!((rt.cpus, rt.fifo_priority, rt.lock_memory), (vec![3], Some(60), false));
    let err = rig(&EXAMPLE.replace("[safety]", "[safety]\nbogus = 1")).unwrap_err();
    assert!(err.to_string().contains("unknown field `bogus`"), "{err}");
}

/// A frame length that does not divide by the LED count still gives the exact period.
#[test]
fn frame_us_keeps_the_period_exact() {
    let text = EXAMPLE.replace("slot_us = 4000 ", "frame_us = 20000 ");
    let r = rig(&text).unwrap();
    assert_eq!(r.sample_period, Duration::from_millis(20));
    let slots: Vec<u16> = r.schedule.slots().iter().map(|s| s.slot_us).collect();
    assert_eq!(slots, [4750, 4750, 4750, 4750]);
    let odd = EXAMPLE.replace("slot_us = 4000 ", "frame_us = 20003 ");
    let slots: Vec<u16> = rig(&odd).unwrap().schedule.slots().iter().map(|s| s.slot_us).collect();
    assert_eq!(slots, [4751, 4751, 4751, 4750]);
}

/// What `to_toml` writes reads back as the same rig.
#[test]
fn round_trips_through_toml() {
    let c = RigFile::from_toml(EXAMPLE, "rig.toml").unwrap();
    let again = RigFile::from_toml(&c.to_toml(), "again").unwrap();
    assert_eq!(again.rig("again").unwrap().control, c.rig("rig.toml").unwrap().control);
}
