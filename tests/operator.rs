//! Operator control in deterministic virtual time: the gateway starts idle, moves only when
//! armed and started, drives goals and queues, and answers every request exactly. The
//! robot's motion is judged by the simulator's world truth.

use std::path::Path;

use flowgate::gateway::core::operator::{Goal, Refusal, Request};
use flowgate::gateway::core::{State, StopReason};
use flowgate::lab::planner_only::Outcome;
use flowgate::lab::virtual_rig::{Options, VirtualRig};
use flowgate::lab::Scenario;
use flowgate_sim::scenario::Motion;

/// One cycle of E1 (T = 17 ms).
const T: f64 = 0.017;

fn scenario(name: &str) -> Scenario {
    Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios").join(name)).unwrap()
}

/// The rig's gateway as a service runs it: idle, waiting for an operator.
fn idle(s: &Scenario) -> VirtualRig {
    VirtualRig::new(s, Options { truth_samples: true, telemetry: true, wait_for_operator: true, ..Options::default() })
}

fn goal(x: f64, y: f64) -> Request {
    Request::Goal { goals: vec![Goal { position: [x, y], tolerance: 0.02 }] }
}

#[test]
fn it_starts_idle_and_moves_nothing_for_ten_seconds() {
    let s = scenario("e1-standing-obstacle.toml");
    let mut rig = idle(&s);
    rig.run_until(10.0);
    assert_eq!(rig.core().state(), State::Idle);
    let e = rig.finish(s.goal.position, s.goal.tolerance);
    let t = &e.truth.summary;
    assert!(t.duration >= 10.0);
    assert_eq!(t.path_length, 0.0, "the robot moved");
    assert_eq!(t.peak_wheel_speed, [0.0, 0.0]);
    assert!(e.truth.samples.len() > 400 && e.truth.samples.iter().all(|x| x.wheel_speeds == [0.0, 0.0]));
}

#[test]
fn arm_goal_and_start_reach_the_goal_and_each_refusal_says_why() {
    let s = scenario("e1-standing-obstacle.toml");
    let mut rig = idle(&s);
    rig.run_until(0.5);
    assert_eq!(rig.request(&Request::Start), Err(Refusal::NotArmed(State::Idle)));
    rig.request(&Request::Arm).unwrap();
    assert_eq!(rig.request(&Request::Arm), Err(Refusal::Already(State::Armed)));
    assert_eq!(rig.request(&Request::Start), Err(Refusal::NoGoal));
    assert_eq!(rig.request(&Request::Reset), Err(Refusal::NotFaulted(State::Armed)));
    rig.request(&goal(s.goal.position[0], s.goal.position[1])).unwrap();
    rig.run_until(2.0);
    assert_eq!(rig.core().state(), State::Armed, "armed with a goal, but not started: still");
    assert_eq!(rig.world().truth().path_length, 0.0);
    rig.request(&Request::Start).unwrap();
    let e = rig.run(s.time_limit, s.goal.position, s.goal.tolerance);
    assert_eq!(e.outcome, Outcome::Goal, "{}", e.report);
    assert_eq!(e.report.stop_reason, Some(StopReason::GoalReached));
}

#[test]
fn a_queue_of_three_goals_is_driven_in_order() {
    let s = scenario("e1-standing-obstacle.toml");
    let queue = [[-0.05, -0.3], [0.35, -0.25], [0.35, 0.05]];
    let mut rig = idle(&s);
    rig.run_until(0.5);
    rig.request(&Request::Arm).unwrap();
    let goals = queue.iter().map(|&p| Goal { position: p, tolerance: 0.02 }).collect();
    rig.request(&Request::Goal { goals }).unwrap();
    assert_eq!(rig.status().goals.len(), 3);
    rig.request(&Request::Start).unwrap();
    let last = queue[2];
    let e = rig.run(60.0, last, 0.02);
    assert_eq!(e.outcome, Outcome::Goal, "{}", e.report);
    assert!(!e.contact);
    // World truth: the robot passes each goal, in order.
    let mut from = 0;
    for g in queue {
        let i = e.truth.samples[from..]
            .iter()
            .position(|x| (x.x - g[0]).hypot(x.y - g[1]) < 0.03)
            .unwrap_or_else(|| panic!("never at {g:?} after sample {from}"));
        from += i;
    }
    // One stop only, at the end: the intermediate goals are passed through.
    let stops = e.report.transitions.iter().filter(|(_, s)| matches!(s, State::Stopping(_))).count();
    assert_eq!(stops, 1, "{:?}", e.report.transitions);
}

/// Running, stopping, armed or idle: an e-stop stops the wheels within one cycle and
/// latches, and a reset is accepted once its cause (the operator) is gone.
#[test]
fn estop_stops_the_wheels_within_a_cycle_from_any_state() {
    let s = scenario("e1-standing-obstacle.toml");
    for before in ["running", "stopping", "armed", "idle"] {
        let mut rig = VirtualRig::new(&s, Options { truth_samples: true, ..Options::default() });
        rig.run_until(3.0);
        match before {
            "stopping" => {
                rig.request(&Request::Stop).unwrap();
                rig.run_until(3.05);
                assert!(matches!(rig.core().state(), State::Stopping(_)));
            }
            "armed" => {
                rig.request(&Request::EStop).unwrap();
                rig.request(&Request::Reset).unwrap();
                rig.request(&Request::Arm).unwrap();
                rig.run_until(3.05);
            }
            "idle" => {
                rig.request(&Request::EStop).unwrap();
                rig.request(&Request::Reset).unwrap();
                rig.run_until(3.05);
            }
            _ => {}
        }
        let at = rig.time();
        let state = rig.core().state();
        rig.request(&Request::EStop).unwrap();
        rig.run_until(at + 0.5);
        assert_eq!(rig.core().state(), State::Fault(StopReason::OperatorEStop), "from {state}");
        let e = rig.finish(s.goal.position, s.goal.tolerance);
        let rest = e.at_rest_since.expect("at rest");
        assert!(rest <= at + T, "from {state}: at rest {:.1} ms after the e-stop", (rest - at) * 1e3);
    }
}

#[test]
fn stop_ramps_the_wheels_down_in_order() {
    let s = scenario("e1-standing-obstacle.toml");
    let mut rig = VirtualRig::new(&s, Options { truth_samples: true, ..Options::default() });
    rig.run_until(3.0);
    rig.request(&Request::Stop).unwrap();
    rig.run_until(4.5);
    assert_eq!(rig.core().state(), State::Stopped(StopReason::Operator));
    let e = rig.finish(s.goal.position, s.goal.tolerance);
    let rest = e.at_rest_since.unwrap();
    let ramp = s.robot.max_wheel_speed / s.robot.wheel_accel;
    assert!(rest > 3.0 + 0.05, "a ramp, not an e-stop: at rest {:.1} ms after", (rest - 3.0) * 1e3);
    assert!(rest <= 3.0 + T + ramp, "{rest}");
}

#[test]
fn goals_inside_an_obstacle_outside_the_lane_or_the_arena_are_refused() {
    let s = scenario("e1-standing-obstacle.toml");
    let mut rig = idle(&s);
    rig.run_until(1.0);
    let inside = rig.request(&goal(0.02, 0.0)).unwrap_err().to_string();
    assert!(inside.contains("inside obstacle LED 3's planning circle"), "{inside}");
    let far = rig.request(&goal(5.0, 0.0)).unwrap_err().to_string();
    assert!(far.contains("outside the calibrated arena: the PSD sees the floor within the corners ("), "{far}");
    let nan = rig.request(&goal(f64::NAN, 0.0)).unwrap_err().to_string();
    assert!(nan.contains("finite"), "{nan}");
    assert_eq!(rig.request(&Request::Goal { goals: vec![] }), Err(Refusal::EmptyQueue));
    assert!(rig.status().goals.is_empty(), "a refused goal changes nothing");
    let lane = scenario("e2-lane-head-on.toml");
    let mut rig = idle(&lane);
    rig.run_until(1.0);
    let out = rig.request(&goal(0.3, 0.25)).unwrap_err().to_string();
    assert!(out.contains("outside the lane"), "{out}");
}

/// An obstacle that comes to rest on the goal while the robot drives: the robot holds still
/// for `planner.goal_wait` (10 s by default) in case it passes, then an orderly stop, with
/// that reason.
#[test]
fn a_goal_that_becomes_blocked_stops_the_robot_in_order() {
    let mut s = scenario("e1-standing-obstacle.toml");
    s.obstacles[0].start = [0.35, 0.45];
    s.obstacles[0].motion = Motion::Waypoints { points: vec![[0.35, 0.05]], speed: 0.2, repeat: false };
    let e = VirtualRig::new(&s, Options { truth_samples: true, ..Options::default() }).run(
        s.time_limit,
        s.goal.position,
        s.goal.tolerance,
    );
    assert_eq!(e.report.final_state, State::Stopped(StopReason::GoalBlocked), "{}", e.report);
    assert!(!e.contact);
    // Held still for the wait: 10 s of 17 ms cycles, to the cycle.
    let waited = e.report.counters.goal_occupied as f64 * 0.017;
    assert!((waited - 10.0).abs() <= 0.017, "waited {waited:.3} s\n{}", e.report);
}

/// A fault's reset is refused while its cause persists (the board's heartbeat stays away).
#[test]
fn reset_is_refused_while_the_cause_persists() {
    let mut s = scenario("e1-standing-obstacle.toml");
    s.faults = s.faults.with_settings(&["heartbeat_stop_at=2.0".to_string()]).unwrap();
    let mut rig = VirtualRig::new(&s, Options::default());
    rig.run_until(3.0);
    assert_eq!(rig.core().state(), State::Fault(StopReason::HeartbeatLost { node: 1 }));
    let refusal = rig.request(&Request::Reset).unwrap_err();
    assert_eq!(refusal, Refusal::CauseStillPresent(StopReason::HeartbeatLost { node: 1 }));
    assert_eq!(refusal.to_string(), "fault: motor board 1 heartbeat lost, cause still present");
    assert_eq!(rig.request(&Request::Arm), Err(Refusal::Faulted(State::Fault(StopReason::HeartbeatLost { node: 1 }))));
    assert_eq!(rig.core().state(), State::Fault(StopReason::HeartbeatLost { node: 1 }));
}

/// An obstacle's LED hidden from 2 s to 4 s: driven around as the region it may have
/// reached, then a fault naming the LED at the occlusion timeout. The reset keeps the track
/// (still occluded: forgotten, the robot would drive blind into it), and once the LED is
/// seen again the operator's arm, goal and start take the robot back to Running and on to
/// its goal.
#[test]
fn an_occluded_obstacle_faults_by_its_led_and_the_operator_drives_on_after_reset() {
    let mut s = scenario("e1-standing-obstacle.toml");
    s.faults = s.faults.with_settings(&["occlusions=[[3, 2.0, 4.0]]".to_string()]).unwrap();
    let mut rig = VirtualRig::new(&s, Options { truth_samples: true, ..Options::default() });
    rig.run_until(3.5);
    let fault = StopReason::ObstacleOccluded { led: 3, at_edge: false };
    assert_eq!(rig.core().state(), State::Fault(fault));
    assert_eq!(fault.to_string(), "obstacle LED 3 unseen inside the view beyond safety.occlusion_timeout_ms");
    assert!(rig.status().obstacles.is_empty() || rig.status().obstacles.iter().all(|o| o.occluded));
    rig.request(&Request::Reset).unwrap();
    assert_eq!(rig.core().state(), State::Idle);
    let status = rig.status();
    assert!(status.absent.is_empty(), "the reset kept the track: {status:?}");
    assert!(status.obstacles.iter().any(|o| o.led == 3 && o.occluded), "{status:?}");
    rig.run_until(4.5);
    assert!(rig.status().absent.is_empty(), "seen again after the occlusion: {:?}", rig.status());
    rig.request(&Request::Arm).unwrap();
    rig.request(&goal(s.goal.position[0], s.goal.position[1])).unwrap();
    rig.request(&Request::Start).unwrap();
    rig.run_until(5.0);
    assert_eq!(rig.core().state(), State::Running);
    let e = rig.run(s.time_limit, s.goal.position, s.goal.tolerance);
    assert_eq!(e.outcome, Outcome::Goal, "{}", e.report);
    assert!(!e.contact);
}

/// An obstacle that starts outside the camera's view is absent, not a fault: the robot arms
/// and drives; the obstacle, crossing into the view, across the robot's way and out at the
/// far side, is tracked from its first samples, avoided, and dropped as it leaves.
#[test]
fn an_obstacle_entering_the_view_is_tracked_and_avoided() {
    let mut s = scenario("e1-standing-obstacle.toml");
    s.obstacles[0].start = [0.1, -0.95];
    s.obstacles[0].motion = Motion::Constant { velocity: [0.0, 0.3] };
    let e = VirtualRig::new(&s, Options { truth_samples: true, ..Options::default() }).run(
        s.time_limit,
        s.goal.position,
        s.goal.tolerance,
    );
    assert_eq!(e.outcome, Outcome::Goal, "{}", e.report);
    assert!(!e.contact);
    let c = e.report.counters;
    assert_eq!((c.obstacles_entered_view, c.obstacles_left_view), (1, 1), "{c:?}");
    assert!(e.truth.summary.min_obstacle_clearance.unwrap() > 0.0);
}

/// An obstacle that walks into the standing robot faults it, named for the obstacle; once it
/// has walked on past, the operator's reset, arm and start drive the robot on to its goal,
/// without a restart. (E2's obstacle on the centre line of a lane too narrow to pass.)
#[test]
fn after_an_obstacle_reached_the_robot_the_operator_drives_on() {
    let e2 =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e2-lane-head-on.toml")).unwrap();
    let narrow =
        e2.replace("half_width = 0.2", "half_width = 0.1").replace("start = [0.45, 0.06]", "start = [0.45, 0.0]");
    let s = Scenario::from_toml(&narrow, "narrow.toml").unwrap();
    let mut rig = VirtualRig::new(&s, Options { truth_samples: true, ..Options::default() });
    while !matches!(rig.core().state(), State::Fault(_)) {
        assert!(rig.time() < 10.0, "no fault: {}", rig.core().state());
        rig.step();
    }
    use flowgate::gateway::core::RobotMotion;
    assert_eq!(
        rig.core().state(),
        State::Fault(StopReason::ObstacleReachedRobot { led: 3, robot: RobotMotion::Standing })
    );
    // The obstacle walks on through and away behind the robot; then the way back.
    rig.run_until(rig.time() + 8.0);
    rig.request(&Request::Reset).unwrap();
    assert_eq!(rig.core().state(), State::Idle);
    rig.request(&Request::Arm).unwrap();
    rig.request(&goal(s.goal.position[0], s.goal.position[1])).unwrap();
    rig.request(&Request::Start).unwrap();
    let e = rig.run(s.time_limit, s.goal.position, s.goal.tolerance);
    assert!(e.reached_goal, "{}", e.report);
    assert_eq!(e.report.final_state, State::Stopped(StopReason::GoalReached), "{}", e.report);
    assert!(e.truth.summary.contact.is_some_and(|c| !c.active), "the one contact, passive");
}
