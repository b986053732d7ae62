//! The whole stack in deterministic virtual time with CiA 402 drives (one a wheel) in place
//! of the PCL-80K-like board: the gateway configures them by SDO, takes them to operation
//! enabled and commands them by RPDO; every drive fault a rig shows stops it, named by the
//! node and the object or error code, and the operator's way back to Running is shown.

use std::path::Path;

use flowgate::gateway::operator::Request;
use flowgate::gateway::{State, StopReason};
use flowgate::lab::offline::Outcome;
use flowgate::lab::sim::{self, Options, VirtualRig};
use flowgate::lab::Scenario;
use flowgate_protocol::canopen::{CanOpenMessage, DriveState, NmtCommand, PdoDirection, SdoRequest, VelocityCommand};

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
    let e = sim::run(&scenario("e2-lane-head-on.toml", &[]), options());
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
    assert!(rpdos as u64 >= e.report.counters.cycles, "{rpdos}");
}
