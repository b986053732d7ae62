//! A fleet through the whole stack: the gateway core driving every vehicle against the
//! simulator's firmware in deterministic virtual time ([`crate::lab::virtual_rig`]), each
//! navigating vehicle armed and started towards its goal at the first stream and each
//! scripted one along its script, judged by the world's truth as [`super::run`] judges the
//! planner-level fleet. Each vehicle is seen through the camera (its LEDs' noise and delay,
//! the frames' timing) and commanded over the bus; a scripted vehicle's follower runs in the
//! gateway core, its commands through its supervisor.

use flowgate_sim::scenario::vehicles::{Role, VehicleSpec};
use flowgate_sim::scenario::Motion;

use super::sweep::{place, report, FleetEpisode, FleetSweepReport};
use super::{contact_of, FleetSummary, VehicleSummary};
use crate::config::{MotionSection, RoleName, VehicleSection};
use crate::gateway::core::{State, StopReason};
use crate::lab::sweep::{Shard, TooLarge};
use crate::lab::virtual_rig::{Options, VirtualRig};
use crate::lab::{Outcome, Scenario};

/// A scenario's vehicle's script as rig.toml's `[[vehicles]]` keys (`role`, `start`,
/// `motion`, `script_tolerance`); none for a navigating vehicle.
pub fn script_keys(v: &VehicleSpec) -> VehicleSection {
    let Some(motion) = v.motion.as_ref().filter(|_| v.role == Role::Script) else { return VehicleSection::default() };
    let motion = match motion {
        Motion::Stationary => MotionSection::Stationary,
        Motion::Constant { velocity } => MotionSection::Constant { velocity: *velocity },
        Motion::Waypoints { points, speed, repeat } => {
            MotionSection::Waypoints { points: points.clone(), speed: *speed, repeat: *repeat }
        }
    };
    VehicleSection {
        role: Some(RoleName::Script),
        start: Some(v.start),
        motion: Some(motion),
        script_tolerance: Some(v.script_tolerance()),
        ..VehicleSection::default()
    }
}

/// Run `s` through the whole stack to its end: every vehicle stopped, faulted or at its goal
/// and the world run on a moment, or the time limit.
pub fn run(s: &Scenario) -> FleetSummary {
    let mut rig = VirtualRig::new(s, Options::default());
    let mut end = s.time_limit;
    while rig.time() < end {
        rig.step();
        let core = rig.core();
        let done = (0..core.vehicle_count()).all(|k| core.vehicle_state(k).is_some_and(State::is_terminal));
        if done && end == s.time_limit {
            end = (rig.time() + crate::lab::virtual_rig::LINGER).min(s.time_limit);
        }
    }
    summary(s, &rig)
}

/// What the run came to, vehicle by vehicle, as the planner-level fleet reports it.
pub(crate) fn summary(s: &Scenario, rig: &VirtualRig) -> FleetSummary {
    let (fleet, core) = (rig.fleet(), rig.core());
    let vehicles: Vec<VehicleSummary> = s
        .fleet()
        .enumerate()
        .map(|(k, (name, _, role))| {
            let contact = contact_of(fleet, &s.sim, k);
            let state = core.vehicle_state(k).unwrap_or_default();
            let goal = s.vehicle(k).sim.goal;
            let end = fleet.world(k).pose().position;
            let home = (end.re - goal.position[0]).hypot(end.im - goal.position[1]) <= goal.tolerance + 0.01;
            let script = core.vehicle_script(k);
            // At its goal, stopped there by the gateway: an e-stop after it changes nothing.
            let reached = rig.reached_at(k).is_some() && home;
            let outcome = match state {
                _ if contact.is_some() => Outcome::Collision,
                _ if reached => Outcome::Goal,
                // A script kept to its end, or to the run's.
                State::Stopped(StopReason::ScriptEnded) | State::Stopping(StopReason::ScriptEnded) | State::Running
                    if script.is_some() =>
                {
                    Outcome::Goal
                }
                State::Stopped(StopReason::Stalled) => Outcome::Stall,
                State::Fault(_) => Outcome::Fault,
                State::Stopped(_) | State::Stopping(_) => Outcome::Stopped,
                _ => Outcome::Timeout,
            };
            let truth = fleet.world(k).truth();
            VehicleSummary {
                name: name.to_string(),
                role,
                outcome,
                contact,
                script_error: script.map(|s| s.largest),
                script_error_held: script.map(|s| s.largest_held),
                time_to_goal: rig.reached_at(k).filter(|_| outcome == Outcome::Goal),
                path_length: truth.path_length,
                min_vehicle_gap: fleet.min_vehicle_gap(k),
                min_clearance: fleet.min_vehicle_gap(k).min(truth.min_obstacle_clearance),
                supervised_cycles: 0,
                stop_reason: (outcome != Outcome::Goal).then(|| stops(core.vehicle_history(k))),
            }
        })
        .collect();
    FleetSummary::of(s, rig.time(), vehicles)
}

/// Every stop or fault in `history`, in order, each named by the last state it gave
/// (`stopped: operator stop, then fault: motor board 2 heartbeat lost`); the state it ended
/// in when there was none.
fn stops(history: &[(f64, State)]) -> String {
    let mut named: Vec<State> = Vec::new();
    for &(_, state) in history {
        match named.last_mut() {
            Some(last) if state.reason().is_some() && last.reason() == state.reason() => *last = state,
            _ if state.reason().is_some() => named.push(state),
            _ => {}
        }
    }
    match named.is_empty() {
        true => history.last().map_or(String::new(), |(_, s)| s.to_string()),
        false => named.iter().map(State::to_string).collect::<Vec<_>>().join(", then "),
    }
}

/// Episode `i` of a sweep through the whole stack: the fleet placed as the planner-level
/// sweep places it, and, when every vehicle got home, each navigating vehicle alone through
/// the whole stack on the same start, goal and settings (its time to its goal, for the
/// makespan's ratio).
pub fn episode(base: &Scenario, seed: u64, i: u64) -> FleetEpisode {
    let s = place(base, seed, i);
    let fleet = run(&s);
    let alone = (fleet.outcome == Outcome::Goal).then(|| slowest_alone(&s)).flatten();
    FleetEpisode::of(i, &fleet, alone)
}

/// The slowest navigating vehicle's time to its goal alone, through the whole stack.
fn slowest_alone(s: &Scenario) -> Option<f64> {
    (0..=s.vehicles.len())
        .filter(|&k| k == 0 || s.vehicles[k - 1].role == Role::Navigate)
        .map(|k| run(&s.vehicle(k)).vehicles[0].time_to_goal)
        .try_fold(0.0, |m, t| Some(f64::max(m, t?)))
}

/// `n` episodes through the whole stack on `threads` threads.
pub fn sweep(
    base: &Scenario,
    n: u64,
    seed: u64,
    threads: usize,
) -> Result<(FleetSweepReport, Vec<FleetEpisode>), TooLarge> {
    let mut episodes = Shard::WHOLE.run(n, threads, |i| episode(base, seed, i))?;
    episodes.sort_by_key(|e| e.index);
    Ok((report(base, seed, &episodes), episodes))
}
