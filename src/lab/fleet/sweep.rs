//! Sweeps of a fleet scenario: each episode places the fleet afresh (a `[swap]` turns its
//! circle and jitters every start and goal; other fleets move every start by up to 3 cm),
//! runs it, and runs each navigating vehicle alone on the same start, goal and settings, so
//! that the fleet's makespan is measured against the slowest vehicle's time alone.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::{run, FleetOptions, FleetSummary};
use crate::lab::sweep::compare::Interval;
use crate::lab::sweep::{Shard, TooLarge};
use crate::lab::{Outcome, Scenario};
use flowgate_sim::scenario::vehicles::Role;
use flowgate_sim::scenario::Motion;

/// One episode of a fleet sweep.
#[derive(Debug, Clone, Serialize)]
pub struct FleetEpisode {
    pub index: u64,
    pub outcome: Outcome,
    /// Navigating vehicles at their goal, of how many.
    pub home: usize,
    pub navigating: usize,
    /// Vehicles that touched another vehicle, and of them those that drove into it.
    pub vehicle_contacts: usize,
    pub active_contacts: usize,
    /// Contacts with anything (vehicles, obstacles, walls).
    pub contacts: usize,
    pub makespan: Option<f64>,
    /// The slowest navigating vehicle's time to its goal alone, s (`None`: one did not
    /// reach it even alone).
    pub slowest_alone: Option<f64>,
    /// Largest script error of a scripted vehicle where its supervisor passed, m.
    pub script_error: Option<f64>,
}

impl FleetEpisode {
    pub fn makespan_ratio(&self) -> Option<f64> {
        Some(self.makespan? / self.slowest_alone?)
    }
}

/// Episode `i`'s fleet: a swap placed afresh; any other fleet with every navigating
/// vehicle's start moved by up to 3 cm in x and y and every script's and moving obstacle's
/// speed scaled by U(0.75, 1.25) (at most the vehicle's speed limit). A placement the
/// scenario's checks refuse (a start jittered onto another vehicle, a swap turned so that a
/// goal falls out of view or onto furniture) is said, and the episode runs the placement the
/// file was loaded with, as a crowd's does.
pub fn place(base: &Scenario, seed: u64, i: u64) -> Scenario {
    let placed = placed(base, seed, i);
    let checked = placed
        .sim
        .validate()
        .map_err(|(key, why)| format!("`{key}` {why}"))
        .and_then(|()| Scenario::new(placed.sim.clone(), &format!("episode {i}")).map_err(|e| e.to_string()));
    match checked {
        Ok(s) => Scenario { supervised: base.supervised, ..s },
        Err(why) => {
            tracing::warn!("episode {i}: {why}: the episode runs the placement the scenario was loaded with");
            base.clone()
        }
    }
}

fn placed(base: &Scenario, seed: u64, i: u64) -> Scenario {
    let mut s = base.clone();
    if base.swap.is_some() {
        s.sim = base.sim.swap_episode(seed, i);
        return s;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xF1EE7);
    let jitter = |p: &mut [f64; 2], rng: &mut ChaCha8Rng| {
        p[0] += rng.random_range(-0.03..0.03);
        p[1] += rng.random_range(-0.03..0.03);
    };
    jitter(&mut s.sim.robot.start, &mut rng);
    let robot = s.sim.robot;
    for v in s.sim.vehicles.iter_mut() {
        let limit = v.body(&robot).max_speed;
        match (v.role, v.motion.as_mut()) {
            (Role::Navigate, _) => jitter(&mut v.start, &mut rng),
            (Role::Script, Some(m)) => scale(m, rng.random_range(0.75..1.25), limit),
            (Role::Script, None) => {}
        }
    }
    for o in &mut s.sim.obstacles {
        scale(&mut o.motion, rng.random_range(0.75..1.25), f64::INFINITY);
    }
    s
}

/// A motion's speed times `factor`, at most `limit`.
fn scale(m: &mut Motion, factor: f64, limit: f64) {
    match m {
        Motion::Stationary => {}
        Motion::Constant { velocity } => {
            let speed = velocity[0].hypot(velocity[1]);
            let k = if speed > 0.0 { (factor * speed).min(limit) / speed } else { 1.0 };
            *velocity = velocity.map(|c| c * k);
        }
        Motion::Waypoints { speed, .. } => *speed = (*speed * factor).min(limit),
    }
}

/// The same scenario with every scripted vehicle an obstacle: a body of the same radius on
/// the same script, seen by the camera, driven by no one.
pub fn scripts_as_obstacles(s: &Scenario) -> Scenario {
    let mut out = s.clone();
    let robot = s.sim.robot;
    let (scripts, vehicles): (Vec<_>, Vec<_>) = s.sim.vehicles.iter().cloned().partition(|v| v.role == Role::Script);
    out.sim.obstacles.extend(scripts.iter().map(|v| v.script(v.body(&robot).radius)));
    out.sim.vehicles = vehicles;
    out
}

/// Run episode `i`.
pub fn episode(base: &Scenario, seed: u64, i: u64, options: FleetOptions) -> FleetEpisode {
    let s = place(base, seed, i);
    let fleet = run(&s, options);
    let alone = (fleet.outcome == Outcome::Goal).then(|| slowest_alone(&s, &fleet, options)).flatten();
    FleetEpisode::of(i, &fleet, alone)
}

/// The slowest navigating vehicle's time to its goal with no other vehicle about.
fn slowest_alone(s: &Scenario, fleet: &FleetSummary, options: FleetOptions) -> Option<f64> {
    let mut slowest: f64 = 0.0;
    for (k, v) in fleet.vehicles.iter().enumerate().filter(|(_, v)| v.role == Role::Navigate) {
        let alone = run(&s.vehicle(k), options);
        slowest = slowest.max(alone.vehicles[0].time_to_goal.filter(|_| v.role == Role::Navigate)?);
    }
    Some(slowest)
}

impl FleetEpisode {
    pub(super) fn of(index: u64, fleet: &FleetSummary, slowest_alone: Option<f64>) -> Self {
        let navigating = fleet.vehicles.iter().filter(|v| v.role == Role::Navigate);
        let contacts = fleet.vehicles.iter().filter_map(|v| v.contact.as_ref());
        let with_vehicles = || contacts.clone().filter(|c| c.with.starts_with("vehicle "));
        Self {
            index,
            outcome: fleet.outcome,
            home: navigating.clone().filter(|v| v.outcome == Outcome::Goal).count(),
            navigating: navigating.count(),
            vehicle_contacts: with_vehicles().count(),
            active_contacts: contacts.clone().filter(|c| c.active).count(),
            contacts: contacts.count(),
            makespan: fleet.makespan,
            slowest_alone,
            script_error: fleet.vehicles.iter().filter_map(|v| v.script_error).reduce(f64::max),
        }
    }
}

/// What a fleet sweep found.
#[derive(Debug, Clone, Serialize)]
pub struct FleetSweepReport {
    pub scenario: String,
    pub vehicles: usize,
    pub episodes: usize,
    pub seed: u64,
    /// Episodes in which every navigating vehicle reached its goal, with no contact.
    pub all_home: Interval,
    /// Episodes with a contact between vehicles; with an active contact of any kind.
    pub vehicle_contact_episodes: usize,
    pub active_contact_episodes: usize,
    /// Makespan over the slowest vehicle's time alone, in the episodes all home: p50, p99,
    /// max, and how many were within 1.5.
    pub makespan_ratio_p50: f64,
    pub makespan_ratio_p99: f64,
    pub makespan_ratio_max: f64,
    pub makespan_within_1_5: Interval,
    /// The largest script error of any scripted vehicle where its supervisor passed, m.
    pub script_error_max: Option<f64>,
    /// The first episodes not all home (at most ten), to look at one by one.
    pub failed: Vec<u64>,
}

/// Run `n` episodes of a fleet scenario on `threads` threads.
pub fn sweep(
    base: &Scenario,
    n: u64,
    seed: u64,
    threads: usize,
    options: FleetOptions,
) -> Result<(FleetSweepReport, Vec<FleetEpisode>), TooLarge> {
    let mut episodes = Shard::WHOLE.run(n, threads, |i| episode(base, seed, i, options))?;
    episodes.sort_by_key(|e| e.index);
    Ok((report(base, seed, &episodes), episodes))
}

/// The same with vehicle `k` driven by an outside policy, `command`, one process a worker
/// (each answer awaited at most `budget`). The makespan is not set against each vehicle's
/// time alone: the policy's own time alone is not the field's.
#[allow(clippy::too_many_arguments)] // a sweep's parameters, and the policy's
pub fn sweep_policy(
    base: &Scenario,
    n: u64,
    seed: u64,
    threads: usize,
    options: FleetOptions,
    k: usize,
    command: &str,
    budget: std::time::Duration,
) -> Result<(FleetSweepReport, Vec<FleetEpisode>), TooLarge> {
    let worker = || crate::lab::policy::Worker::new(command, budget);
    let mut episodes = Shard::WHOLE.run_with(n, threads, worker, |policy, i| {
        let s = place(base, seed, i);
        let (fleet, failure) = super::policy::run(&s, options, k, policy, None);
        if let Some(e) = failure {
            tracing::warn!("episode {i}: {e}");
        }
        FleetEpisode::of(i, &fleet, None)
    })?;
    episodes.sort_by_key(|e| e.index);
    Ok((report(base, seed, &episodes), episodes))
}

pub(super) fn report(base: &Scenario, seed: u64, episodes: &[FleetEpisode]) -> FleetSweepReport {
    let n = episodes.len();
    let home = episodes.iter().filter(|e| e.outcome == Outcome::Goal).count();
    let mut ratios: Vec<f64> = episodes.iter().filter_map(FleetEpisode::makespan_ratio).collect();
    ratios.sort_by(f64::total_cmp);
    let q =
        |p: f64| if ratios.is_empty() { f64::NAN } else { ratios[((ratios.len() - 1) as f64 * p).round() as usize] };
    let within = ratios.iter().filter(|&&r| r <= 1.5).count();
    FleetSweepReport {
        scenario: base.name.clone(),
        vehicles: 1 + base.vehicles.len(),
        episodes: n,
        seed,
        all_home: Interval::wilson(home, n),
        vehicle_contact_episodes: episodes.iter().filter(|e| e.vehicle_contacts > 0).count(),
        active_contact_episodes: episodes.iter().filter(|e| e.active_contacts > 0).count(),
        makespan_ratio_p50: q(0.5),
        makespan_ratio_p99: q(0.99),
        makespan_ratio_max: ratios.last().copied().unwrap_or(f64::NAN),
        makespan_within_1_5: Interval::wilson(within, ratios.len()),
        script_error_max: episodes.iter().filter_map(|e| e.script_error).reduce(f64::max),
        failed: episodes.iter().filter(|e| e.outcome != Outcome::Goal).map(|e| e.index).take(10).collect(),
    }
}

impl std::fmt::Display for FleetSweepReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let pct = |i: &Interval| format!("{:.2}% [{:.2}, {:.2}]", 100.0 * i.rate, 100.0 * i.low, 100.0 * i.high);
        writeln!(f, "{}: {} vehicles, {} episodes (seed {})", self.scenario, self.vehicles, self.episodes, self.seed)?;
        writeln!(f, "  every vehicle home, no contact: {}", pct(&self.all_home))?;
        writeln!(
            f,
            "  episodes with a contact between vehicles: {}; with an active contact: {}",
            self.vehicle_contact_episodes, self.active_contact_episodes
        )?;
        if self.all_home.count == 0 {
            write!(f, "  makespan / slowest alone: no episode had every vehicle home")?;
        } else if self.makespan_within_1_5.episodes == 0 {
            // A policy's vehicle (its time alone would be the field's), or a vehicle that
            // does not reach its goal alone.
            write!(f, "  makespan / slowest alone: not measured")?;
        } else {
            write!(
                f,
                "  makespan / slowest alone: p50 {:.2}, p99 {:.2}, max {:.2}; within 1.5: {}",
                self.makespan_ratio_p50,
                self.makespan_ratio_p99,
                self.makespan_ratio_max,
                pct(&self.makespan_within_1_5)
            )?;
        }
        if let Some(e) = self.script_error_max {
            write!(f, "\n  largest script error where not held: {:.1} mm", e * 1e3)?;
        }
        if !self.failed.is_empty() {
            write!(f, "\n  first episodes not all home: {:?}", self.failed)?;
        }
        Ok(())
    }
}

/// The robot with the scripted vehicles as vehicles and as obstacles, on the same episodes.
#[derive(Debug, Clone, Serialize)]
pub struct ScriptedComparison {
    pub scenario: String,
    pub episodes: usize,
    pub seed: u64,
    /// The robot at its goal with no contact: scripts as vehicles, and as obstacles.
    pub as_vehicles: Interval,
    pub as_obstacles: Interval,
    /// The robot's smallest clearance in each episode, p5 and p50, m: as vehicles, as
    /// obstacles.
    pub clearance_as_vehicles: [f64; 2],
    pub clearance_as_obstacles: [f64; 2],
    /// The largest script error where the supervisor passed the follower, m, and the
    /// episodes in which it passed 1 cm.
    pub script_error_max: f64,
    pub script_error_over_1cm: usize,
    /// Episodes in which a scripted vehicle was stopped for losing its script.
    pub scripts_lost: usize,
    /// The first episodes (at most ten) in which the robot did not reach its goal with no
    /// contact: scripts as vehicles, and as obstacles (`--episode K` on the same sweep runs
    /// one alone, the scripts as vehicles).
    pub failed_as_vehicles: Vec<u64>,
    pub failed_as_obstacles: Vec<u64>,
}

/// Run `n` episodes of a fleet with scripted vehicles twice: as written, and with every
/// scripted vehicle an obstacle on the same script.
pub fn compare_scripts(
    base: &Scenario,
    n: u64,
    seed: u64,
    threads: usize,
    options: FleetOptions,
) -> Result<ScriptedComparison, TooLarge> {
    compare_scripts_with(base, n, seed, threads, |s| run(s, options))
}

/// The same, each run by `run` (the planner level, or the whole stack).
pub fn compare_scripts_with(
    base: &Scenario,
    n: u64,
    seed: u64,
    threads: usize,
    run: impl Fn(&Scenario) -> FleetSummary + Sync,
) -> Result<ScriptedComparison, TooLarge> {
    let mut indexed = Shard::WHOLE.run(n, threads, |i| {
        let s = place(base, seed, i);
        (i, (run(&s), run(&scripts_as_obstacles(&s))))
    })?;
    // The workers finish in no particular order: each pair at its episode's index.
    indexed.sort_by_key(|&(i, _)| i);
    let pairs: Vec<(FleetSummary, FleetSummary)> = indexed.into_iter().map(|(_, pair)| pair).collect();
    let home = |f: &FleetSummary| f.vehicles[0].outcome == Outcome::Goal && f.vehicles[0].contact.is_none();
    let quantiles = |pick: &dyn Fn(&(FleetSummary, FleetSummary)) -> f64| {
        let mut v: Vec<f64> = pairs.iter().map(pick).collect();
        v.sort_by(f64::total_cmp);
        [0.05, 0.5].map(|q| v.get(((v.len().max(1) - 1) as f64 * q).round() as usize).copied().unwrap_or(f64::NAN))
    };
    let errors: Vec<f64> =
        pairs.iter().map(|(a, _)| a.vehicles.iter().filter_map(|v| v.script_error).fold(0.0, f64::max)).collect();
    let first_failed = |home: &dyn Fn(&(FleetSummary, FleetSummary)) -> bool| -> Vec<u64> {
        (0..).zip(&pairs).filter(|(_, pair)| !home(pair)).map(|(i, _)| i).take(10).collect()
    };
    let lost = pairs
        .iter()
        .filter(|(a, _)| a.vehicles.iter().any(|v| v.role == Role::Script && v.outcome == Outcome::Stopped))
        .count();
    Ok(ScriptedComparison {
        scenario: base.name.clone(),
        episodes: pairs.len(),
        seed,
        as_vehicles: Interval::wilson(pairs.iter().filter(|(a, _)| home(a)).count(), pairs.len()),
        as_obstacles: Interval::wilson(pairs.iter().filter(|(_, b)| home(b)).count(), pairs.len()),
        clearance_as_vehicles: quantiles(&|(a, _)| a.vehicles[0].min_clearance),
        clearance_as_obstacles: quantiles(&|(_, b)| b.vehicles[0].min_clearance),
        script_error_max: errors.iter().copied().fold(0.0, f64::max),
        script_error_over_1cm: errors.iter().filter(|&&e| e > 0.01).count(),
        scripts_lost: lost,
        failed_as_vehicles: first_failed(&|(a, _)| home(a)),
        failed_as_obstacles: first_failed(&|(_, b)| home(b)),
    })
}

impl std::fmt::Display for ScriptedComparison {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let pct = |i: &Interval| format!("{:.1}% [{:.1}, {:.1}]", 100.0 * i.rate, 100.0 * i.low, 100.0 * i.high);
        let cm = |c: &[f64; 2]| format!("p5 {:.1} cm, p50 {:.1} cm", c[0] * 100.0, c[1] * 100.0);
        writeln!(f, "{}: {} episodes (seed {}), the robot with the scripts", self.scenario, self.episodes, self.seed)?;
        writeln!(f, "  as vehicles:  goal {}, clearance {}", pct(&self.as_vehicles), cm(&self.clearance_as_vehicles))?;
        writeln!(
            f,
            "  as obstacles: goal {}, clearance {}",
            pct(&self.as_obstacles),
            cm(&self.clearance_as_obstacles)
        )?;
        write!(
            f,
            "  scripts: within {:.1} mm where not held; over 1 cm in {} episodes; lost in {}",
            self.script_error_max * 1e3,
            self.script_error_over_1cm,
            self.scripts_lost
        )?;
        for (mode, failed) in [("as vehicles", &self.failed_as_vehicles), ("as obstacles", &self.failed_as_obstacles)] {
            if !failed.is_empty() {
                write!(f, "\n  first episodes not home {mode}: {failed:?}")?;
            }
        }
        Ok(())
    }
}
