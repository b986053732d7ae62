//! The fleet's fault swarm through the whole stack (`flowgate plan --whole-stack --swarm N`):
//! the planner-level swarm's episodes and faults ([`super::faults`]), played on the gateway
//! core and the simulator's firmware in virtual time. A vehicle's link fails on the
//! simulated bus (its motors neither hear it nor are heard, and run on their last command
//! until their own timeout); the operator's stop of one vehicle and the fleet's e-stop are
//! the control socket's requests (`ctl --vehicle NAME stop`, `ctl estop`). Judged by the
//! same invariants, each stop named as the gateway names it ([`Level::WholeStack`]).

use super::{faults, judged, report, FleetFault, FleetSwarmReport, Level, Stopped, SwarmEpisode, WheelLog, RUN_ON_S};
use crate::gateway::core::operator::Request;
use crate::gateway::core::State;
use crate::lab::fleet::sweep::place;
use crate::lab::fleet::{motors_hold, stack, FleetSummary};
use crate::lab::sweep::{Shard, TooLarge};
use crate::lab::virtual_rig::{Options, VirtualRig};
use crate::lab::Scenario;

/// Run episode `i` through the whole stack and judge it.
pub fn episode(base: &Scenario, seed: u64, i: u64) -> (SwarmEpisode, FleetSummary) {
    let mut s = place(base, seed, i);
    let mut faults = faults(base, seed, i);
    let own = s.vehicles.iter().enumerate().filter_map(|(j, v)| Some((j + 1, v.link_lost_at?)));
    faults.extend(own.map(|(vehicle, at)| FleetFault::LinkLost { vehicle, at }));
    faults.sort_by(|a, b| a.at().total_cmp(&b.at()));
    // A link fails once, at its first failure: on the simulated bus from the start.
    let mut robot_link_lost_at = None;
    for f in &faults {
        if let FleetFault::LinkLost { vehicle, at } = *f {
            let lost = match vehicle {
                0 => &mut robot_link_lost_at,
                k => &mut s.sim.vehicles[k - 1].link_lost_at,
            };
            *lost = Some(lost.map_or(at, |was: f64| was.min(at)));
        }
    }
    let options = Options { robot_link_lost_at, ..Options::default() };
    let mut rig = VirtualRig::new(&s, options);
    let (stopped, log) = play(&s, &mut rig, &faults);
    let summary = stack::summary(&s, &rig);
    let episode = judged(&s, i, faults, &summary, stopped, &log, Level::WholeStack);
    (episode, summary)
}

/// Whether vehicle `k` is under way: armed or running.
fn under_way(rig: &VirtualRig, k: usize) -> bool {
    matches!(rig.core().vehicle_state(k), Some(State::Running | State::Armed))
}

/// Whether vehicle `k` is done: stopping, stopped or faulted. One not yet armed (the fleet
/// is armed at the first stream) is still to start, and the run goes on for it.
fn done(rig: &VirtualRig, k: usize) -> bool {
    matches!(rig.core().vehicle_state(k), Some(State::Stopping(_) | State::Stopped(_) | State::Fault(_)))
}

/// Run `rig` to the episode's end, each fault applied as the run reaches its time; whom
/// each stopped, and every vehicle's wheels each period.
fn play(s: &Scenario, rig: &mut VirtualRig, faults: &[FleetFault]) -> (Stopped, WheelLog) {
    let (mut next, mut stopped, mut log) = (0, Stopped::new(), WheelLog::default());
    let period = s.sensing.sample_time;
    let vehicles = rig.core().vehicle_count();
    // Past every lost link's motors' timeout: the judge sees each vehicle at rest.
    let hold = (0..vehicles).map(|k| motors_hold(s, k)).fold(0.0, f64::max);
    let (mut end, mut next_log) = (s.time_limit, 0.0);
    while rig.time() < end {
        rig.step();
        let t = rig.time();
        while let Some(&fault) = faults.get(next).filter(|f| f.at() <= t) {
            inject(fault, rig, t, &mut stopped);
            next += 1;
        }
        if t >= next_log {
            log.t.push(t);
            log.wheels.extend((0..vehicles).map(|k| rig.fleet().world(k).wheel_speeds()));
            next_log = t + period;
        }
        let all_done = (0..vehicles).all(|k| done(rig, k)) && next == faults.len();
        if all_done && end == s.time_limit {
            end = (t + hold + RUN_ON_S).min(s.time_limit);
        }
    }
    (stopped, log)
}

/// Apply `fault` at `t`, noting each vehicle it stops.
fn inject(fault: FleetFault, rig: &mut VirtualRig, t: f64, stopped: &mut Stopped) {
    match fault {
        FleetFault::LinkLost { vehicle, .. } => note(vehicle, fault, t, under_way(rig, vehicle), stopped),
        FleetFault::Stop { vehicle, .. } => {
            note(vehicle, fault, t, under_way(rig, vehicle), stopped);
            let _ = rig.vehicle_request(vehicle as u8, &Request::Stop);
        }
        FleetFault::EStop { .. } => {
            // The fleet's e-stop latches a vehicle not yet armed too: it never starts.
            for k in 0..rig.core().vehicle_count() {
                let reaches = under_way(rig, k) || rig.core().vehicle_state(k) == Some(State::Idle);
                note(k, fault, t, reaches, stopped);
            }
            let _ = rig.request(&Request::EStop);
        }
    }
}

/// Note that `fault` stopped vehicle `k` at `t`, if it `reaches` it and is the first to: a
/// stop sent after its link failed does not reach it, and that failure was its first.
fn note(k: usize, fault: FleetFault, t: f64, reaches: bool, stopped: &mut Stopped) {
    if reaches && !stopped.iter().any(|&(j, _, _)| j == k) {
        stopped.push((k, fault, t));
    }
}

/// `n` episodes through the whole stack on `threads` threads.
pub fn run(base: &Scenario, n: u64, seed: u64, threads: usize) -> Result<FleetSwarmReport, TooLarge> {
    let mut episodes = Shard::WHOLE.run(n, threads, |i| episode(base, seed, i).0)?;
    episodes.sort_by_key(|e| e.index);
    Ok(report(base, seed, &episodes, Level::WholeStack))
}
