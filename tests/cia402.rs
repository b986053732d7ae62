//! The whole stack in deterministic virtual time with CiA 402 drives (one a wheel) in place
//! of the PCL-80K-like board: the gateway configures them by SDO, takes them to operation
//! enabled and commands them by RPDO; every drive fault a rig shows stops it, named by the
//! node and the object or error code, and the operator's way back to Running is shown.

use std::path::Path;

use flowgate::gateway::core::operator::Request;
use flowgate::gateway::core::{State, StopReason};
use flowgate::lab::planner_only::Outcome;
use flowgate::lab::virtual_rig::{self, Options, VirtualRig};
use flowgate::lab::Scenario;
use flowgate_protocol::canopen::{
    CanOpenMessage, DriveState, NmtCommand, NmtTarget, PdoDirection, SdoRequest, VelocityCommand,
};

fn scenario(name: &str, faults: &[&str]) -> Scenario {
    let mut s = Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios").join(name)).unwrap();
    s.faults = s.faults.with_settings(&faults.iter().map(|f| f.to_string()).collect::<Vec<_>>()).unwrap();
    s
}

fn options() -> Options {
    Options { truth_samples: true, telemetry: true, record_inputs: true, cia402: true, ..Options::default() }
}

#[test]
fn e2_with_cia402_drives_reaches_the_goal() {
    let e = virtual_rig::run(&scenario("e2-lane-head-on.toml", &[]), options());
    assert_eq!(e.outcome, Outcome::Goal, "{}\n{:?}", e.report, e.truth.summary);
    assert!(!e.contact && e.reached_goal);
    assert_eq!(e.report.stop_reason, Some(StopReason::GoalReached));
    assert_eq!(e.motion_outside_running, 0);
    let messages: Vec<CanOpenMessage> = e.can_sent.iter().filter_map(|f| CanOpenMessage::parse(f).ok()).collect();
    let sdos = messages
        .iter()
        .filter(|m| matches!(m, CanOpenMessage::SdoRequest { request: SdoRequest::Download { .. }, .. }))
        .count();
    let starts =
        messages.iter().filter(|m| matches!(m, CanOpenMessage::Nmt { command: NmtCommand::Start, .. })).count();
    let rpdos = messages
        .iter()
        .filter_map(|m| match m {
            CanOpenMessage::Pdo { direction: PdoDirection::Receive, number: 1, data, .. } => {
                VelocityCommand::parse(data)
            }
            _ => None,
        })
        .filter(|c| c.target_velocity != 0)
        .count();
    println!("{}; {sdos} SDO writes, {starts} NMT starts, {rpdos} moving RPDOs", e.report);
    assert_eq!(starts, 2);
    state_machine_first(&messages);
    assert!(rpdos as u64 >= e.report.counters.cycles, "{rpdos}");
}

/// A drive that never answers one configuration write faults the arm, naming the node and
/// the object, one SDO timeout after the write; nothing moves.
#[test]
fn an_unanswered_sdo_faults_the_arm_naming_node_and_object() {
    let e = virtual_rig::run(&scenario("e1-standing-obstacle.toml", &["drive_ignores_object=0x6085"]), options());
    let reason = StopReason::DriveSdoTimeout { node: 1, index: 0x6085, sub: 0 };
    assert_eq!(e.report.final_state, State::Fault(reason), "{}", e.report);
    assert_eq!(reason.to_string(), "drive 1 did not answer SDO 0x6085:0 within cia402.sdo_timeout_ms");
    let (armed, faulted) = (transition(&e, State::Armed), transition(&e, State::Fault(reason)));
    // The quick-stop deceleration is the seventh write: six round trips, then 100 ms.
    let waited = faulted - armed;
    assert!((0.100..0.110).contains(&waited), "faulted {:.1} ms after the arm", waited * 1e3);
    assert_eq!(e.truth.summary.path_length, 0.0, "the robot moved");
}

/// A drive that cannot leave its fault (its DC link low through the arm) is named with the
/// state it stayed in, one enable timeout after the arm.
#[test]
fn a_drive_that_stays_faulted_is_named_with_its_state() {
    let e = virtual_rig::run(&scenario("e1-standing-obstacle.toml", &["drive_undervoltage=[0.0, 30.0]"]), options());
    let reason = StopReason::DriveNotEnabled { node: 1, state: DriveState::Fault };
    assert_eq!(e.report.final_state, State::Fault(reason), "{}", e.report);
    assert_eq!(
        reason.to_string(),
        "drive 1 stayed in 'fault' (statusword 0x6041), not operation enabled within cia402.enable_timeout_ms"
    );
    let waited = transition(&e, State::Fault(reason)) - transition(&e, State::Armed);
    assert!((waited - 1.0).abs() < 1e-3, "faulted {waited:.4} s after the arm");
    assert_eq!(e.truth.summary.path_length, 0.0, "the robot moved");
}

/// The operator's e-stop quick-stops both drives (controlword 0x0002 in their RPDO); the
/// drives brake and end switch on disabled; reset, arm and start take the robot on to its
/// goal.
#[test]
fn an_operator_estop_quick_stops_both_drives_and_the_way_back_reaches_the_goal() {
    let s = scenario("e1-standing-obstacle.toml", &[]);
    let mut rig = VirtualRig::new(&s, options());
    rig.run_until(2.0);
    assert_eq!(rig.core().state(), State::Running);
    let sent = rig.can_sent().len();
    rig.request(&Request::EStop).unwrap();
    let quick_stops: Vec<u8> = rig.can_sent()[sent..]
        .iter()
        .filter_map(|f| match CanOpenMessage::parse(f).ok()? {
            CanOpenMessage::Pdo { direction: PdoDirection::Receive, node, data, .. } => {
                (VelocityCommand::parse(&data)?.controlword == 0x0002).then_some(node.get())
            }
            _ => None,
        })
        .collect();
    assert_eq!(quick_stops, [1, 2]);
    rig.run_until(2.5);
    assert_eq!(rig.core().state(), State::Fault(StopReason::OperatorEStop));
    assert_eq!(rig.world().wheel_speeds(), [0.0, 0.0], "at rest within half a second");
    let goal = flowgate::gateway::core::operator::Goal { position: s.goal.position, tolerance: s.goal.tolerance };
    for request in [Request::Reset, Request::Arm, Request::Goal { goals: vec![goal] }, Request::Start] {
        rig.request(&request).unwrap();
    }
    let e = rig.run(s.time_limit, s.goal.position, s.goal.tolerance);
    assert_eq!(e.outcome, Outcome::Goal, "{}", e.report);
    assert_eq!(e.motion_outside_running, 0);
}

/// Each drive hears no RPDO before its NMT start, and then the state machine's steps in
/// order (shutdown, switch on, enable operation) before any cycle's command: a cycle's
/// enable operation sent early would jump a step, or a step sent late undo one.
fn state_machine_first(messages: &[CanOpenMessage]) {
    for node in [1u8, 2] {
        let mut started = false;
        let mut controlwords: Vec<u16> = Vec::new();
        for m in messages {
            match m {
                CanOpenMessage::Nmt { command: NmtCommand::Start, target: NmtTarget::Node(n) } if n.get() == node => {
                    started = true
                }
                CanOpenMessage::Pdo { direction: PdoDirection::Receive, node: n, data, .. } if n.get() == node => {
                    assert!(started, "an RPDO to drive {node} before its NMT start");
                    let cw = VelocityCommand::parse(data).unwrap().controlword;
                    if controlwords.last() != Some(&cw) {
                        controlwords.push(cw);
                    }
                }
                _ => {}
            }
        }
        assert_eq!(controlwords[..3], [0x0006, 0x0007, 0x000F], "drive {node}: {controlwords:04X?}");
    }
}

/// Armed by the operator while the robot's poses already flow, so that cycles come while
/// the drives are configured and enabled: they send nothing until both are in operation
/// enabled.
#[test]
fn cycles_wait_for_the_drives_to_be_enabled() {
    let s = scenario("e1-standing-obstacle.toml", &[]);
    let mut rig = VirtualRig::new(&s, Options { wait_for_operator: true, ..options() });
    rig.run_until(1.0);
    let goal = flowgate::gateway::core::operator::Goal { position: s.goal.position, tolerance: s.goal.tolerance };
    for request in [Request::Arm, Request::Goal { goals: vec![goal] }, Request::Start] {
        rig.request(&request).unwrap();
    }
    let e = rig.run(s.time_limit, s.goal.position, s.goal.tolerance);
    assert_eq!(e.outcome, Outcome::Goal, "{}", e.report);
    let messages: Vec<CanOpenMessage> = e.can_sent.iter().filter_map(|f| CanOpenMessage::parse(f).ok()).collect();
    state_machine_first(&messages);
}

fn transition(e: &flowgate::lab::virtual_rig::VirtualRun, state: State) -> f64 {
    e.report.transitions.iter().find(|(_, s)| *s == state).map(|(t, _)| *t).unwrap_or_else(|| panic!("never {state}"))
}
