//! The whole stack in deterministic virtual time: the gateway core, the simulator's PSD
//! controller, SLCAN adapter and motor board, and its world, through the real encoders and
//! decoders (src/lab/virtual_rig.rs). Judged by the world's truth. Every figure asserted here is
//! exact for its seed: docs/architecture.md quotes these assertions.

use std::path::Path;
use std::time::Duration;

use flowgate::gateway::core::operator::{Refusal, Request};
use flowgate::gateway::core::{State, StopReason};
use flowgate::gateway::shell::telemetry::CycleRecord;
use flowgate::lab::planner_only::Outcome;
use flowgate::lab::virtual_rig::{self, Options, VirtualRig, VirtualRun};
use flowgate::lab::Scenario;
use flowgate_sim::scenario::Motion;

fn scenario(name: &str) -> Scenario {
    Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios").join(name)).unwrap()
}

fn with_faults(name: &str, faults: &[&str]) -> Scenario {
    let mut s = scenario(name);
    s.faults = s.faults.with_settings(&faults.iter().map(|f| f.to_string()).collect::<Vec<_>>()).unwrap();
    s
}

fn options() -> Options {
    Options { truth_samples: true, telemetry: true, ..Options::default() }
}

fn assert_goal(name: &str) {
    let e = virtual_rig::run(&scenario(name), options());
    assert_eq!(e.outcome, Outcome::Goal, "{name}: {}\n{:?}", e.report, e.truth.summary);
    assert!(!e.contact && e.reached_goal);
    assert_eq!(e.report.stop_reason, Some(StopReason::GoalReached));
    assert!(e.report.counters.cycles > 300, "{}", e.report);
}

#[test]
fn e1_standing_obstacle_reaches_the_goal() {
    assert_goal("e1-standing-obstacle.toml");
}

#[test]
fn e2_lane_head_on_reaches_the_goal() {
    assert_goal("e2-lane-head-on.toml");
}

#[test]
fn e4_lowpass_lag_reaches_the_goal_with_its_delay_on_the_wire() {
    assert_goal("e4-lowpass-lag.toml");
}

#[test]
fn e5_moving_and_standing_reaches_the_goal() {
    assert_goal("e5-moving-and-standing.toml");
}

#[test]
fn e6_two_moving_reaches_the_goal() {
    assert_goal("e6-two-moving.toml");
}

/// One seed, one run: byte-identical `cycles.csv` and `can.log`. Another seed differs.
#[test]
fn the_same_seed_gives_byte_identical_telemetry() {
    let a = virtual_rig::run(&scenario("e2-lane-head-on.toml"), options()).telemetry.unwrap();
    let b = virtual_rig::run(&scenario("e2-lane-head-on.toml"), options()).telemetry.unwrap();
    assert!(a.cycles_csv.len() > 20_000 && a.can_log.len() > 20_000);
    assert_eq!(a, b, "same seed, same bytes");
    let mut other = scenario("e2-lane-head-on.toml");
    other.sensing.seed = 2;
    let c = virtual_rig::run(&other, options()).telemetry.unwrap();
    assert_ne!(a.cycles_csv, c.cycles_csv, "another seed, other noise");
}

/// The low-latency mode's warm-up (`[realtime] warm_up`, `Core::rehearse`) runs the cycle's
/// work on the last state and throws it away: rehearsed at every event of a run, far more
/// often than a rig does, it changes nothing. The same `cycles.csv` and `can.log`, byte for
/// byte, in the lane (E2) and in free space with two moving obstacles (E6).
#[test]
fn a_rehearsal_changes_nothing() {
    for name in ["e2-lane-head-on.toml", "e6-two-moving.toml"] {
        let plain = virtual_rig::run(&scenario(name), options());
        let rehearsed = virtual_rig::run(&scenario(name), Options { rehearse: true, ..options() });
        assert_eq!(plain.outcome, Outcome::Goal, "{name}");
        assert!(plain.report.counters.cycles > 300, "{name}");
        assert_eq!(plain.telemetry.unwrap(), rehearsed.telemetry.unwrap(), "{name}: the same bytes");
    }
}

/// The period is exact on the rig path: E2's 20 ms frame is 20.000 ms, not 19.998.
#[test]
fn the_control_period_is_exact() {
    let e = virtual_rig::run(&scenario("e2-lane-head-on.toml"), options());
    assert_eq!(e.report.sample_time, 0.020);
    let csv = String::from_utf8(e.telemetry.unwrap().cycles_csv).unwrap();
    let col = CycleRecord::column("period_ns").unwrap();
    let periods: Vec<u64> = csv.lines().skip(2).map(|l| l.split(',').nth(col).unwrap().parse().unwrap()).collect();
    // Exact to the virtual clock's resolution: firmware times are rounded up to whole ns.
    assert!(periods.iter().all(|&p| p.abs_diff(20_000_000) <= 1), "{:?}", &periods[..5]);
}

/// The time of the first transition into `state`.
fn when(e: &VirtualRun, pred: impl Fn(State) -> bool) -> f64 {
    e.report.transitions.iter().find(|(_, s)| pred(*s)).map(|(t, _)| *t).unwrap_or_else(|| panic!("{}", e.report))
}

/// The wheels stood still from `by` on, and turned before `fault`; returns when they stopped.
fn stopped(e: &VirtualRun, fault: f64, by: f64) -> f64 {
    let moving = e.truth.samples.iter().any(|s| s.t > 1.0 && s.t < fault && s.wheel_speeds[0].abs() > 0.02);
    assert!(moving, "the robot was not moving before the fault");
    let rest = e.at_rest_since.unwrap_or_else(|| panic!("still turning at the end: {}", e.report));
    assert!(rest <= by, "wheels at rest only from {rest:.4} s, budget until {by:.4} s\n{}", e.report);
    rest
}

/// One cycle of E1 (T = 17 ms).
const T_E1: f64 = 0.017;

/// An orderly stop (what SIGINT asks of the rig's gateway) at 3 s: the wheels ramp down at
/// the board's acceleration (0.25 m/s at 1 m/s² takes 0.25 s) and the board is disabled.
#[test]
fn an_orderly_stop_ramps_the_wheels_down() {
    let s = scenario("e1-standing-obstacle.toml");
    let mut rig = VirtualRig::new(&s, options());
    rig.run_until(3.0);
    assert_eq!(rig.core().state(), State::Running);
    rig.shutdown();
    rig.run_until(4.0);
    assert!(rig.core().finished());
    let e = rig.finish(s.goal.position, s.goal.tolerance);
    assert_eq!(e.report.final_state, State::Stopped(StopReason::Shutdown), "{}", e.report);
    let rest = stopped(&e, 3.0, 3.0 + T_E1 + s.robot.max_wheel_speed / s.robot.wheel_accel);
    // docs/architecture.md's figure, exact for the seed.
    assert!(((rest - 3.0) * 1e3 - 112.0).abs() < 0.05, "wheels at rest {:.2} ms after the request", (rest - 3.0) * 1e3);
}

/// The serial device vanishes at 2 s for 0.6 s: a serial fault at once; the gateway reopens
/// the line by itself, stays in fault (no automatic re-arm), and drives on only when re-armed.
#[test]
fn serial_vanishing_faults_reconnects_and_waits_for_rearm() {
    let s = with_faults("e1-standing-obstacle.toml", &["serial_vanish_at=2.0", "serial_vanish_s=0.6"]);
    let mut rig = VirtualRig::new(&s, options());
    rig.run_until(4.0);
    assert_eq!(rig.core().state(), State::Fault(StopReason::SerialLost));
    assert_eq!(rig.core().counters().serial_reconnects, 1);
    assert_eq!(
        rig.request(&Request::Arm),
        Err(Refusal::Faulted(State::Fault(StopReason::SerialLost))),
        "a fault is reset first"
    );
    rig.request(&Request::Reset).unwrap();
    rig.request(&Request::Arm).unwrap();
    rig.request(&Request::Start).unwrap();
    rig.run_until(s.time_limit);
    let e = rig.finish(s.goal.position, s.goal.tolerance);
    let fault = when(&e, |st| st == State::Fault(StopReason::SerialLost));
    assert!((fault - 2.0).abs() < 1e-6, "{fault}");
    let resting: Vec<_> = e.truth.samples.iter().filter(|x| x.t > fault + T_E1 && x.t < 4.0).collect();
    assert!(!resting.is_empty() && resting.iter().all(|x| x.wheel_speeds.iter().all(|v| v.abs() < 1e-9)));
    assert_eq!(e.report.stop_reason, Some(StopReason::GoalReached), "{}", e.report);
    assert!(e.reached_goal && !e.contact);
}

/// A controller that never answers is a startup failure naming the request.
#[test]
fn a_silent_controller_is_a_startup_failure() {
    let mut s = scenario("e1-standing-obstacle.toml");
    s.faults.serial_drop = 1.0;
    let e = virtual_rig::run(&s, options());
    let err = e.setup_error.expect("no setup").to_string();
    assert!(err.contains("did not answer GetInfo"), "{err}");
    let _ = Duration::ZERO;
}

/// E1 with its obstacle crossing the goal at 10 cm/s instead of standing: its planning
/// circle covers the goal from about 3 s to 5 s, while the robot is still 40 cm away.
fn obstacle_crossing_the_goal(goal_wait: f64) -> Scenario {
    let mut s = scenario("e1-standing-obstacle.toml");
    s.obstacles[0].start = [0.35, -0.35];
    s.obstacles[0].motion = Motion::Constant { velocity: [0.0, 0.1] };
    s.planner.goal_wait = goal_wait;
    s
}

/// An obstacle passing over the goal: the gateway holds the robot still (zero commands, in
/// Running) while the goal is inside its planning circle, then drives on to the goal by
/// itself; with no wait allowed it stops in order, saying why. The planner-only runner
/// does the same.
#[test]
fn the_robot_waits_for_an_obstacle_to_leave_the_goal() {
    let e = virtual_rig::run(&obstacle_crossing_the_goal(10.0), options());
    assert_eq!(e.outcome, Outcome::Goal, "{}", e.report);
    assert_eq!(e.report.stop_reason, Some(StopReason::GoalReached));
    assert!(!e.contact && e.motion_outside_running == 0);
    // 165 cycles of 17 ms (2.81 s, exact for the seed): the obstacle's planning circle
    // (R_0 = 14 cm with its allowances) crossing the goal at 10 cm/s.
    assert_eq!(e.report.counters.goal_occupied, 165, "{}", e.report);
    // It stood still while it waited, but for the ramp down (at most 0.15 m/s at 1 m/s²)
    // and back up: the world's truth, sampled every 20 ms, has the wheels at rest for all
    // but 0.3 s of the 2.81 s.
    let still = e.truth.samples.iter().filter(|s| s.t > 2.0 && s.t < 7.0 && s.wheel_speeds == [0.0; 2]).count();
    assert!(still as f64 * 0.02 >= 2.81 - 0.3, "stood still for {still} samples");

    let e = virtual_rig::run(&obstacle_crossing_the_goal(0.0), options());
    assert_eq!(e.outcome, Outcome::Stopped, "{}", e.report);
    assert_eq!(e.report.stop_reason, Some(StopReason::GoalBlocked));
    assert!(!e.reached_goal);

    let run = flowgate::lab::planner_only::run(&obstacle_crossing_the_goal(10.0), false).summary;
    assert_eq!(run.outcome, Outcome::Goal);
    assert!(run.goal_occupied_cycles > 0);
    let run = flowgate::lab::planner_only::run(&obstacle_crossing_the_goal(0.0), false).summary;
    assert_eq!(run.outcome, Outcome::Stopped);
}

/// The gateway counts the planner's flags as the planner-only runner does, and `/metrics`
/// exports them: E2's circle is left unclosed at
/// the wall while closing it would take in the goal (49 of its 417 cycles here; 51 of 411
/// on the planner-only runner's own sensing model), its field's speed is cut to the limit
/// most of the way, and E1 breaks the tie behind its obstacle and has no wall.
#[test]
fn the_gateway_counts_the_planners_flags() {
    let e2 = virtual_rig::run(&scenario("e2-lane-head-on.toml"), options());
    let c = e2.report.counters;
    assert_eq!(c.planner_unclosed_at_a_wall, 49, "{}", e2.report);
    assert!(c.planner_saturated > c.cycles / 2 && c.planner_tie_break == 0, "{}", e2.report);
    let e1 = virtual_rig::run(&scenario("e1-standing-obstacle.toml"), options());
    let c = e1.report.counters;
    assert!(c.planner_tie_break > 0 && c.planner_unclosed_at_a_wall == 0, "{}", e1.report);
    let summary = flowgate::lab::planner_only::Run::from_episode(&scenario("e2-lane-head-on.toml"), &e2).summary;
    assert_eq!(summary.unclosed_at_a_wall_cycles, 49);
    assert_eq!(summary.saturated_cycles, e2.report.counters.planner_saturated);
}

/// One way into the core: the virtual rig hands it the same `Input`s the rig's shell does,
/// so the inputs it fed, replayed into a fresh core (as `flowgate replay` replays a
/// recording), give every CAN frame again, byte for byte: here E5 with serial corruption,
/// duplicates and a board reboot, which reach the handshake, the windows and a fault.
#[test]
fn the_virtual_rigs_inputs_replay_to_the_same_frames() {
    let s = with_faults(
        "e5-moving-and-standing.toml",
        &["serial_corrupt=0.0002", "serial_duplicate=0.02", "board_reboot_at=6.0"],
    );
    let rig = VirtualRig::new(&s, Options { record_inputs: true, ..Options::default() });
    let gateway_rig = rig.core().rig().clone();
    let e = rig.run(s.time_limit, s.goal.position, s.goal.tolerance);
    assert_eq!(e.report.final_state, State::Fault(StopReason::BoardReboot { node: 1 }), "{}", e.report);
    let c = &e.report.counters;
    assert!(c.bad_serial_frames > 0 && c.psd_duplicates > 0, "{}", e.report);
    assert!(e.inputs.len() > 2000 && e.can_sent.len() > 300, "{} inputs, {} frames", e.inputs.len(), e.can_sent.len());
    let replayed = flowgate::replay::run(gateway_rig, &e.inputs);
    assert_eq!(replayed.can.len(), e.can_sent.len());
    assert!(replayed.can == e.can_sent, "the replay's frames differ from the run's");
    assert_eq!(replayed.final_state, e.report.final_state.to_string());
}
