//! The fleet's fault swarm (`flowgate plan --swarm N FLEET.toml`): each episode places the
//! fleet as a sweep does ([`place`]) and draws one to three faults, each on one vehicle or
//! on the fleet, at random times and overlapping: a vehicle's own link failing, the
//! operator stopping one vehicle, the fleet's e-stop. The fleet runs at the planner level
//! to the end (a contact does not end it) and is judged by invariants:
//!
//! - no vehicle in control drives into anything (a vehicle whose link failed coasts on its
//!   last command until its motors' timeout: its contacts are counted apart);
//! - every vehicle a fault stopped is at rest within its budget (its wheels' ramp down from
//!   the fastest they turn, or its motors' timeout after its link failed, also when the link
//!   fails while it brakes) and never turns a wheel again: nothing re-arms by itself;
//! - none reaches its goal after a fault stopped it;
//! - every vehicle not at its goal, nor out of time, names why, and one a fault stopped
//!   names that fault.
//!
//! An episode is a pure function of the scenario, the seed and its index: `--episode K`
//! runs one alone, to the same outcome. [`stack`] plays the same episodes through the whole
//! stack.

use std::fmt;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::sweep::place;
use super::{drive_with, motors_hold, FleetControl, FleetOptions, FleetSummary, FleetTrace};
use crate::lab::sweep::{Shard, TooLarge};
use crate::lab::{Outcome, Scenario};

pub mod stack;

/// Where the swarm runs, and so how a stop names its fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Level {
    /// Each vehicle's control step on the world's truth ([`episode`]).
    Planner,
    /// The gateway core and the simulator's firmware ([`stack::episode`]): a stop is named
    /// as the gateway names the vehicle's state.
    WholeStack,
}

impl Level {
    fn name(self) -> &'static str {
        match self {
            Self::Planner => "planner level",
            Self::WholeStack => "whole stack",
        }
    }
}

/// The stop reason of a vehicle the operator stopped.
pub const STOPPED_BY_THE_OPERATOR: &str = "stopped by the operator";
/// The stop reason of every vehicle the fleet's e-stop stopped.
pub const E_STOP: &str = "e-stop (every vehicle)";
/// The words a vehicle's stop reason starts with when its link failed.
const LINK_FAILED: &str = "its link failed";
/// Faults fall within this many seconds of the start (or the time limit, if shorter): the
/// vehicles are under way then.
const FAULT_WINDOW_S: f64 = 12.0;
/// How long an episode goes on once no vehicle has anywhere to go and the last stop (or a
/// lost link's motors' timeout) has come, s: longer than any vehicle's budget to come to
/// rest, so that the judge sees every one at rest.
const RUN_ON_S: f64 = 1.0;
/// The most faults an episode draws.
const MAX_FAULTS: u32 = 3;
/// How many broken episodes the report lists.
const LISTED: usize = 10;

/// One fault of an episode.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum FleetFault {
    /// Vehicle `vehicle`'s own CAN link fails: no command reaches it, its motors hold their
    /// last one for their timeout and then stop.
    LinkLost { vehicle: usize, at: f64 },
    /// The operator stops vehicle `vehicle` (`ctl --vehicle NAME stop`).
    Stop { vehicle: usize, at: f64 },
    /// The fleet's e-stop: every vehicle stops.
    EStop { at: f64 },
}

impl FleetFault {
    pub fn at(self) -> f64 {
        match self {
            Self::LinkLost { at, .. } | Self::Stop { at, .. } | Self::EStop { at } => at,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::LinkLost { .. } => "link_lost",
            Self::Stop { .. } => "stop",
            Self::EStop { .. } => "e_stop",
        }
    }

    /// Whether a stop reason names this fault. Through the whole stack the gateway names
    /// what it can know: a link's failure by the motors' heartbeat, once it is missed; a
    /// stop before then (the operator's, or an orderly stop of its own: its goal reached or
    /// blocked) names the vehicle's stop instead, and a stopped vehicle's heartbeat is not
    /// watched. An operator's stop is named as such, or as the fleet's e-stop after it.
    fn named_in(self, reason: &str, level: Level) -> bool {
        match (self, level) {
            (Self::LinkLost { .. }, Level::Planner) => reason.starts_with(LINK_FAILED),
            (Self::Stop { .. }, Level::Planner) => reason == STOPPED_BY_THE_OPERATOR,
            (Self::EStop { .. }, Level::Planner) => reason == E_STOP,
            (Self::LinkLost { .. }, Level::WholeStack) => {
                reason.contains("heartbeat lost") || reason.contains("operator") || reason.starts_with("stopped:")
            }
            (Self::Stop { .. }, Level::WholeStack) => reason.contains("operator"),
            (Self::EStop { .. }, Level::WholeStack) => reason.contains("operator emergency stop"),
        }
    }
}

/// Episode `i`'s faults, in time order, from the seed and `i` alone.
pub fn faults(base: &Scenario, seed: u64, i: u64) -> Vec<FleetFault> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0x5AA4_F1EE);
    let window = base.time_limit.min(FAULT_WINDOW_S);
    let vehicles = 1 + base.vehicles.len();
    let mut faults: Vec<FleetFault> = (0..rng.random_range(1..=MAX_FAULTS))
        .map(|_| {
            let (at, vehicle) = (rng.random_range(0.0..window), rng.random_range(0..vehicles));
            match rng.random_range(0..5) {
                0 | 1 => FleetFault::LinkLost { vehicle, at },
                2 | 3 => FleetFault::Stop { vehicle, at },
                _ => FleetFault::EStop { at },
            }
        })
        .collect();
    faults.sort_by(|a, b| a.at().total_cmp(&b.at()));
    faults
}

/// One judged episode.
#[derive(Debug, Clone, Serialize)]
pub struct SwarmEpisode {
    pub index: u64,
    /// The faults drawn, and the scenario's own, in time order.
    pub faults: Vec<FleetFault>,
    pub outcome: Outcome,
    /// Each vehicle a fault stopped: its index, the fault, and when it was applied (the
    /// first cycle at or after the fault's time), s.
    pub stopped: Vec<(usize, FleetFault, f64)>,
    /// Navigating vehicles no fault stopped, and of them those at their goal.
    pub unfaulted: usize,
    pub unfaulted_home: usize,
    /// Active contacts of vehicles coasting on their last command after their link failed.
    pub coasting_contacts: usize,
    /// What broke, one line an invariant and vehicle.
    pub broken: Vec<String>,
}

/// What each cycle's wheels did, for the judge.
#[derive(Debug, Default)]
struct WheelLog {
    t: Vec<f64>,
    /// Every vehicle's wheel speeds at each cycle's start, cycle by cycle.
    wheels: Vec<[f64; 2]>,
}

/// Run episode `i` and judge it; with `trace`, its trace too (for the plot).
pub fn episode(base: &Scenario, seed: u64, i: u64, trace: Option<&mut FleetTrace>) -> (SwarmEpisode, FleetSummary) {
    let s = place(base, seed, i);
    let mut faults = faults(base, seed, i);
    // The scenario's own (`link_lost_at`), judged as the drawn ones are.
    let own = s.vehicles.iter().enumerate().filter_map(|(j, v)| Some((j + 1, v.link_lost_at?)));
    faults.extend(own.map(|(vehicle, at)| FleetFault::LinkLost { vehicle, at }));
    faults.sort_by(|a, b| a.at().total_cmp(&b.at()));
    let (summary, stopped, log) = play(&s, &faults, trace);
    let episode = judged(&s, i, faults, &summary, stopped, &log, Level::Planner);
    (episode, summary)
}

/// Episode `index` judged: its faults, the run's summary, whom they stopped, its wheels.
fn judged(
    s: &Scenario,
    index: u64,
    faults: Vec<FleetFault>,
    summary: &FleetSummary,
    stopped: Stopped,
    log: &WheelLog,
    level: Level,
) -> SwarmEpisode {
    let mut episode = SwarmEpisode {
        index,
        faults,
        outcome: summary.outcome,
        stopped,
        unfaulted: 0,
        unfaulted_home: 0,
        coasting_contacts: 0,
        broken: Vec::new(),
    };
    judge(s, summary, log, &mut episode, level);
    episode
}

/// Each vehicle a fault stopped: its index, the fault, and the cycle time it was applied.
type Stopped = Vec<(usize, FleetFault, f64)>;

/// Run `s` to its end with `faults` (in time order), each applied at the first cycle at or
/// after its time.
fn play(s: &Scenario, faults: &[FleetFault], trace: Option<&mut FleetTrace>) -> (FleetSummary, Stopped, WheelLog) {
    let options = FleetOptions { stop_at_contact: false, run_on: RUN_ON_S, ..FleetOptions::default() };
    let (mut next, mut stopped, mut log) = (0, Vec::new(), WheelLog::default());
    let summary = drive_with(s, FleetControl::new(s, options), trace, |fleet, control| {
        let t = fleet.time();
        while let Some(&fault) = faults.get(next).filter(|f| f.at() <= t) {
            inject(fault, control, t, &mut stopped);
            next += 1;
        }
        log.t.push(t);
        log.wheels.extend((0..fleet.len()).map(|k| fleet.world(k).wheel_speeds()));
    });
    (summary, stopped, log)
}

/// Apply `fault` at cycle time `t`, noting each vehicle it stops: one not done already,
/// and reachable (a stop sent to a vehicle whose link has failed does not reach it).
fn inject(fault: FleetFault, control: &mut FleetControl, t: f64, stopped: &mut Stopped) {
    let hit = |k: usize, control: &FleetControl, stopped: &mut Vec<_>| {
        // A link fails once: at the first failure's time it is this fault's own.
        let reachable = control.link_lost_at(k).is_none_or(|lost| lost >= fault.at());
        let first = !control.is_done(k) && reachable;
        if first {
            stopped.push((k, fault, t));
        }
        first
    };
    match fault {
        FleetFault::LinkLost { vehicle, at } => {
            hit(vehicle, control, stopped);
            control.lose_link(vehicle, at);
        }
        FleetFault::Stop { vehicle, .. } => {
            if hit(vehicle, control, stopped) {
                control.stop(vehicle, t, STOPPED_BY_THE_OPERATOR.to_string());
            }
        }
        FleetFault::EStop { .. } => {
            for k in 0..control.vehicles() {
                if hit(k, control, stopped) {
                    control.stop(k, t, E_STOP.to_string());
                }
            }
        }
    }
}

/// The invariants (module docs), over the run's summary and its wheels cycle by cycle.
fn judge(s: &Scenario, summary: &FleetSummary, log: &WheelLog, e: &mut SwarmEpisode, level: Level) {
    let n = summary.vehicles.len();
    let dt = s.sensing.sample_time;
    for (k, v) in summary.vehicles.iter().enumerate() {
        let stop = e.stopped.iter().find(|&&(j, _, _)| j == k).map(|&(_, fault, at)| (fault, at));
        if let Some(c) = v.contact.as_ref().filter(|c| c.active) {
            match stop {
                Some((FleetFault::LinkLost { .. }, at)) if c.at >= at => e.coasting_contacts += 1,
                _ => e.broken.push(format!("{} drove into {} at {:.2} s", v.name, c.with, c.at)),
            }
        }
        let Some((fault, at)) = stop else {
            if v.role == flowgate_sim::scenario::vehicles::Role::Navigate {
                e.unfaulted += 1;
                e.unfaulted_home += usize::from(v.outcome == Outcome::Goal);
            }
            if !matches!(v.outcome, Outcome::Goal | Outcome::Timeout | Outcome::Collision) && v.stop_reason.is_none() {
                e.broken.push(format!("{} ended {:?} without naming why", v.name, v.outcome));
            }
            continue;
        };
        let body = s.vehicle(k).sim.robot;
        let budget = match fault {
            FleetFault::LinkLost { .. } => motors_hold(s, k),
            _ => body.max_wheel_speed / body.wheel_accel,
        };
        // A link that fails while the vehicle brakes leaves its motors on the brake's last
        // command (turning it on the spot) until their timeout stops them.
        let braked_by = at + budget + 2.0 * dt;
        let rest_by = e
            .faults
            .iter()
            .filter_map(|f| match *f {
                FleetFault::LinkLost { vehicle, at: lost } if vehicle == k && lost >= at && lost < braked_by => {
                    Some(lost + motors_hold(s, k) + 2.0 * dt)
                }
                _ => None,
            })
            .fold(braked_by, f64::max);
        if log.t.last().is_none_or(|&end| end <= rest_by) {
            e.broken.push(format!("{}: the run ended before it could be seen at rest ({rest_by:.2} s)", v.name));
        }
        let turning = log.t.iter().zip(log.wheels.chunks_exact(n)).find(|(&t, w)| t > rest_by && w[k] != [0.0; 2]);
        if let Some((t, _)) = turning {
            e.broken.push(format!(
                "{}, stopped by {} at {at:.2} s, still turns its wheels at {t:.2} s (at rest by {rest_by:.2} s)",
                v.name,
                fault.name()
            ));
        }
        // Its link lost, a vehicle coasts on its last command until its motors' timeout, and
        // is at rest from then on (judged below): the gateway, which cannot know of the loss
        // before the motors' heartbeat is missed, may see it come to its goal on the way and
        // stop it there.
        let coasted_home = matches!(fault, FleetFault::LinkLost { .. }) && v.outcome == Outcome::Goal;
        if v.outcome == Outcome::Goal && !coasted_home && v.time_to_goal.is_some_and(|g| g > at) {
            e.broken.push(format!("{} reached its goal after {} stopped it at {at:.2} s", v.name, fault.name()));
        }
        if !coasted_home && !v.stop_reason.as_deref().is_some_and(|r| fault.named_in(r, level)) {
            e.broken.push(format!("{}, stopped by {}, names its stop {:?}", v.name, fault.name(), v.stop_reason));
        }
    }
}

/// What a fleet's swarm found.
#[derive(Debug, Clone, Serialize)]
pub struct FleetSwarmReport {
    pub scenario: String,
    pub level: Level,
    pub vehicles: usize,
    pub episodes: usize,
    pub seed: u64,
    /// Faults drawn (and the scenario's own), by kind: link_lost, stop, e_stop.
    pub faults: [usize; 3],
    /// Vehicles a fault stopped, by the same kinds.
    pub stopped: [usize; 3],
    pub coasting_contacts: usize,
    /// The first episodes with such a contact, for `--episode K`.
    pub coasting_episodes: Vec<u64>,
    pub unfaulted: usize,
    pub unfaulted_home: usize,
    /// The first episodes in which a navigating vehicle no fault stopped missed its goal.
    pub unfaulted_short_episodes: Vec<u64>,
    /// Episodes that broke an invariant, and the first of them with what broke.
    pub broken_episodes: usize,
    pub broken: Vec<(u64, Vec<String>)>,
}

/// Run `n` episodes of the fleet's swarm on `threads` threads.
pub fn run(base: &Scenario, n: u64, seed: u64, threads: usize) -> Result<FleetSwarmReport, TooLarge> {
    let mut episodes = Shard::WHOLE.run(n, threads, |i| episode(base, seed, i, None).0)?;
    episodes.sort_by_key(|e| e.index);
    Ok(report(base, seed, &episodes, Level::Planner))
}

fn kind(f: FleetFault) -> usize {
    match f {
        FleetFault::LinkLost { .. } => 0,
        FleetFault::Stop { .. } => 1,
        FleetFault::EStop { .. } => 2,
    }
}

/// The first episodes that `matches`, for `--episode K`.
fn listed(episodes: &[SwarmEpisode], matches: impl Fn(&SwarmEpisode) -> bool) -> Vec<u64> {
    episodes.iter().filter(|e| matches(e)).take(LISTED).map(|e| e.index).collect()
}

fn report(base: &Scenario, seed: u64, episodes: &[SwarmEpisode], level: Level) -> FleetSwarmReport {
    let (mut faults, mut stopped) = ([0; 3], [0; 3]);
    for e in episodes {
        e.faults.iter().for_each(|&f| faults[kind(f)] += 1);
        e.stopped.iter().for_each(|&(_, f, _)| stopped[kind(f)] += 1);
    }
    let broken: Vec<&SwarmEpisode> = episodes.iter().filter(|e| !e.broken.is_empty()).collect();
    FleetSwarmReport {
        scenario: base.name.clone(),
        level,
        vehicles: 1 + base.vehicles.len(),
        episodes: episodes.len(),
        seed,
        faults,
        stopped,
        coasting_contacts: episodes.iter().map(|e| e.coasting_contacts).sum(),
        coasting_episodes: listed(episodes, |e| e.coasting_contacts > 0),
        unfaulted: episodes.iter().map(|e| e.unfaulted).sum(),
        unfaulted_home: episodes.iter().map(|e| e.unfaulted_home).sum(),
        unfaulted_short_episodes: listed(episodes, |e| e.unfaulted_home < e.unfaulted),
        broken_episodes: broken.len(),
        broken: broken.iter().take(LISTED).map(|e| (e.index, e.broken.clone())).collect(),
    }
}

impl fmt::Display for FleetSwarmReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [links, stops, estops] = self.faults;
        let [l, s, e] = self.stopped;
        writeln!(
            f,
            "fleet swarm of {} episodes around {} (seed {}, {}):",
            self.episodes,
            self.scenario,
            self.seed,
            self.level.name()
        )?;
        writeln!(f, "  faults: {links} links lost, {stops} operator's stops of one vehicle, {estops} e-stops")?;
        writeln!(f, "  vehicles stopped: {l} by their link, {s} by the operator, {e} by an e-stop")?;
        let home = 100.0 * self.unfaulted_home as f64 / self.unfaulted.max(1) as f64;
        write!(
            f,
            "  navigating vehicles no fault stopped: {} of {} at their goal ({home:.1}%)",
            self.unfaulted_home, self.unfaulted
        )?;
        write_listed(f, &self.unfaulted_short_episodes)?;
        write!(f, "  active contacts while coasting after a lost link: {}", self.coasting_contacts)?;
        write_listed(f, &self.coasting_episodes)?;
        write!(f, "  episodes that broke an invariant: {} of {}", self.broken_episodes, self.episodes)
    }
}

/// ` (episode a, b, ...)` and the line's end; the end alone when none is listed.
fn write_listed(f: &mut fmt::Formatter<'_>, episodes: &[u64]) -> fmt::Result {
    if let Some((first, rest)) = episodes.split_first() {
        write!(f, " (episode {first}")?;
        rest.iter().try_for_each(|i| write!(f, ", {i}"))?;
        write!(f, ")")?;
    }
    writeln!(f)
}

#[cfg(test)]
mod tests;
