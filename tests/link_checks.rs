//! The PSD link's checks through the whole stack in virtual time: duplicated, replayed and
//! lost packets on the serial line (injected by the simulator) are discarded or counted,
//! never turned into a second command; beyond the budget, a fault named for its cause.
//! Judged by the world's truth.

use std::path::Path;

use flowgate::gateway::{State, StopReason};
use flowgate::lab::offline::Outcome;
use flowgate::lab::sim::{self, Episode, Options};
use flowgate::lab::Scenario;

fn e1(faults: &[&str]) -> Episode {
    let mut s =
        Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e1-standing-obstacle.toml")).unwrap();
    s.faults = s.faults.with_settings(&faults.iter().map(|f| f.to_string()).collect::<Vec<_>>()).unwrap();
    sim::run(&s, Options { truth_samples: true, telemetry: true, ..Options::default() })
}

/// Each frame commanded once, in order: the `frame` column of cycles.csv strictly increases.
fn one_command_per_frame(e: &Episode) {
    let csv = String::from_utf8(e.telemetry.as_ref().unwrap().cycles_csv.clone()).unwrap();
    let frames: Vec<u32> = csv.lines().skip(1).map(|l| l.split(',').nth(1).unwrap().parse().unwrap()).collect();
    assert!(frames.len() > 300);
    assert!(frames.windows(2).all(|w| w[1] > w[0]), "a frame commanded twice or out of order");
}

#[test]
fn duplicated_packets_are_discarded_and_counted() {
    let e = e1(&["serial_duplicate=0.02"]);
    assert_eq!(e.outcome, Outcome::Goal, "{}", e.report);
    let c = e.report.counters;
    assert!(e.injected[0] > 30);
    assert_eq!(c.psd_duplicates, e.injected[0], "every injected duplicate is caught: {c:?}");
    one_command_per_frame(&e);
}

#[test]
fn replayed_packets_are_discarded_and_counted() {
    let e = e1(&["serial_replay=0.02"]);
    assert_eq!(e.outcome, Outcome::Goal, "{}", e.report);
    let c = e.report.counters;
    assert!(e.injected[1] > 30);
    // A replay of the packet just sent is a duplicate; of an earlier one, out of order.
    assert_eq!(c.psd_out_of_order + c.psd_duplicates, e.injected[1], "every replay is caught: {c:?}");
    one_command_per_frame(&e);
}

#[test]
fn lost_bytes_are_counted_as_lost_packets_and_frames() {
    let e = e1(&["serial_drop=0.0005"]);
    assert_eq!(e.outcome, Outcome::Goal, "{}", e.report);
    let c = e.report.counters;
    assert!(c.psd_packets_lost > 5 && c.bad_serial_frames > 5, "{c:?}");
    assert!(c.frames_lost + c.frames_incomplete > 0, "{c:?}");
    one_command_per_frame(&e);
}

/// Every packet doubled from 2 s: more than 20 discards a second fault the gateway, named
/// for the sequence, and the wheels stop within a cycle of it.
#[test]
fn a_line_repeating_itself_beyond_budget_faults_and_stops() {
    let e = e1(&["serial_duplicate=1.0", "serial_repeat_during=[2.0, 3.0]"]);
    assert_eq!(e.report.final_state, State::Fault(StopReason::PsdSequence), "{}", e.report);
    let fault = e.report.transitions.iter().find(|(_, s)| matches!(s, State::Fault(_))).unwrap().0;
    assert!(fault - 2.0 < 0.1, "21 duplicates take {:.1} ms", (fault - 2.0) * 1e3);
    let rest = e.at_rest_since.unwrap();
    assert!(rest - fault <= 0.017, "wheels at rest {:.1} ms after the fault", (rest - fault) * 1e3);
    eprintln!(
        "repeating line: fault {:.1} ms after it began, wheels at rest {:.1} ms after",
        (fault - 2.0) * 1e3,
        (rest - 2.0) * 1e3
    );
}

/// The fault's time and the wheels' rest, from the report and the world's truth.
fn fault_and_rest(e: &Episode) -> (f64, f64) {
    let fault = e.report.transitions.iter().find(|(_, s)| matches!(s, State::Fault(_))).unwrap().0;
    (fault, e.at_rest_since.expect("at rest"))
}

/// The board reboots at 2 s (a power glitch): its boot-up heartbeat names it at once.
#[test]
fn a_board_reboot_is_named() {
    let e = e1(&["board_reboot_at=2.0"]);
    assert_eq!(e.report.final_state, State::Fault(StopReason::BoardReboot), "{}", e.report);
    let (fault, rest) = fault_and_rest(&e);
    assert!(fault - 2.0 < 0.001, "{fault}");
    assert!(rest - 2.0 < 0.001, "the rebooting board stops its axes: {rest}");
}

/// Another device commands our board from 2 s: the first such frame faults the gateway.
#[test]
fn a_second_master_on_our_velocity_id_faults_at_once() {
    let e = e1(&["second_master_at=2.0"]);
    assert_eq!(e.report.final_state, State::Fault(StopReason::SecondMaster), "{}", e.report);
    let (fault, rest) = fault_and_rest(&e);
    assert!(fault - 2.0 < 0.001, "{fault}");
    assert!(rest - fault <= 0.017, "wheels at rest {:.1} ms after the fault", (rest - fault) * 1e3);
}

/// The obstacle's LED occluded from 2 s: its track expires with the pose timeout (300 ms),
/// and the robot does not drive on a guess of where the obstacle went.
#[test]
fn an_unseen_obstacle_expires_and_stops_the_robot() {
    let e = e1(&["occlusions=[[3, 2.0, 100.0]]"]);
    assert_eq!(e.report.final_state, State::Fault(StopReason::ObstacleLost), "{}", e.report);
    let (fault, rest) = fault_and_rest(&e);
    assert!(fault - 2.0 <= 0.300, "{fault}");
    assert!(rest - 2.0 <= 0.300 + 0.017, "wheels at rest {:.1} ms after the occlusion", (rest - 2.0) * 1e3);
    eprintln!(
        "obstacle unseen: fault {:.1} ms, rest {:.1} ms after the occlusion",
        (fault - 2.0) * 1e3,
        (rest - 2.0) * 1e3
    );
}

/// Lost CAN frames: the board's own sequence-error counter, as it reports it, is counted.
#[test]
fn the_boards_sequence_errors_are_counted() {
    let e = e1(&["can_loss=0.01"]);
    assert!(e.report.counters.board_seq_errors > 0, "{}", e.report);
    let quiet = e1(&[]);
    assert_eq!(quiet.report.counters.board_seq_errors, 0);
}

/// The controller's clock runs 1000 ppm fast (1 ms a second): the periodic time sync keeps
/// the measured sensing delay where it was, where one sync at start would let it drift by
/// 10 ms over the run.
#[test]
fn clock_drift_is_tracked_by_periodic_time_sync() {
    let e = e1(&["clock_drift_ppm=1000"]);
    assert_eq!(e.outcome, Outcome::Goal, "{}", e.report);
    let c = e.report.counters;
    let csv = String::from_utf8(e.telemetry.unwrap().cycles_csv).unwrap();
    let delays: Vec<f64> = csv.lines().skip(1).map(|l| l.split(',').nth(12).unwrap().parse().unwrap()).collect();
    let (lo, hi) = delays.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &d| (lo.min(d), hi.max(d)));
    assert!(delays.len() > 500);
    assert!(hi - lo < 0.0015, "measured delay spans {:.2} ms", (hi - lo) * 1e3);
    assert!(c.time_syncs >= 9 && c.time_syncs_rejected == 0, "{c:?}");
}

/// The controller reports an LED driver fault (open circuit on LED 3) at 2 s: a fault named
/// for it, the wheels at rest within a cycle. An overrun (samples lost inside it) is loss:
/// counted, and the run goes on.
#[test]
fn the_controllers_own_faults_are_named_and_overruns_counted() {
    let e = e1(&["controller_fault=[2.0, 3, 3]"]);
    assert_eq!(e.report.final_state, State::Fault(StopReason::ControllerFault), "{}", e.report);
    let (fault, rest) = fault_and_rest(&e);
    assert!(fault - 2.0 < 0.001, "{fault}");
    assert!(rest - fault <= 0.017, "wheels at rest {:.1} ms after the fault", (rest - fault) * 1e3);
    let e = e1(&["controller_fault=[2.0, 2, 0]"]);
    assert_eq!(e.outcome, Outcome::Goal, "{}", e.report);
    assert_eq!(e.report.counters.controller_overruns, 1);
}
