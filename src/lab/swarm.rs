//! The fault swarm (`flowgate plan --swarm N`): random schedules of overlapping faults on
//! both links and in the world, each run through the whole stack in virtual time with an
//! operator who resets, arms and starts after every stop, and judged against the
//! simulator's world truth.
//!
//! Each episode draws, from `(seed, episode)` alone, how the gateway reaches the wheels
//! (a board over SLCAN or SocketCAN, CiA 402 drives over SLCAN) and one to four faults of
//! the kinds in [`Kind`], at random times and overlapping. The invariants, checked on every
//! episode ([`run_episode`]):
//!
//! - never an active contact (the robot driving into what it touches);
//! - every fault state is named for a fault present then, with its LED or node;
//! - the wheels at rest within the budget of the fault table for that reason;
//! - no motion while faulted, Armed only when the operator armed, Running only when started;
//! - after the last fault ends, the operator's reset, arm and start bring the robot to its
//!   goal (a cause that never ends must end in a fault naming it);
//! - every byte the PSD line delivered is taken, dropped and counted, or still buffered,
//!   and every CAN frame the bus delivered is counted;
//! - the run advances.
//!
//! An episode is a pure function of the scenario, the seed and its index: a violation is
//! replayed alone, to the same bytes ([`JudgedEpisode::digest`]), with `--episode K`.

use std::collections::BTreeMap;

use serde::Serialize;

use super::policy::{driven_from_outside, Worker};
use super::sweep::{Shard, TooLarge};
use super::virtual_rig::{Options, VirtualRig};
use super::Scenario;
use crate::gateway::core::operator::{Goal, Request};
use crate::gateway::core::{State, StopReason};

mod faults;
mod judge;
pub use faults::{schedule, Backend, FaultSchedule, Injected, Kind};
use judge::{judge, EpisodeLog, Settings, REACTION_S, SETTLE_S, STEPS_PER_S};
pub use judge::{JudgedEpisode, Stop};

/// Run episode `index` of the swarm around `base`, and judge it. With `keep`, the run's
/// telemetry and truth samples come back too (for a replay's files).
pub fn run_episode(
    base: &Scenario,
    seed: u64,
    index: u64,
    keep: bool,
    policy: Option<&mut Worker>,
) -> (JudgedEpisode, super::virtual_rig::VirtualRun) {
    let schedule = schedule(base, seed, index);
    let backend = schedule.backend;
    let mut options = Options { telemetry: keep, truth_samples: keep, ..backend.options() };
    if schedule.faults.iter().any(|f| f.kind == Kind::BitrateMismatch) {
        options.adjust_rig = Some(|rig: &mut crate::config::Rig| {
            if let crate::config::CanUrl::Slcan { bitrate, .. } = &mut rig.can {
                *bitrate = 500_000;
            }
        });
    }
    let driven = policy.is_some().then(|| driven_from_outside(&schedule.scenario));
    let s = driven.as_ref().unwrap_or(&schedule.scenario);
    let mut rig = VirtualRig::new(s, options);
    let goal_is_the_policys = policy.is_some();
    let (watch, policy) = match policy {
        Some(worker) => {
            let failure = worker.begin(s, &rig).err();
            let mut failure = failure;
            let watch = operate(&mut rig, &schedule, &mut |rig| {
                if failure.is_none() {
                    failure = worker.turn(rig, s.goal.position).err();
                }
            });
            (watch, Some((worker, failure)))
        }
        None => (operate(&mut rig, &schedule, &mut |_| {}), None),
    };
    let core = rig.core();
    let history = core.safety().history.clone();
    let settings = Settings {
        period: core.rig().sample_period.as_secs_f64(),
        safety: core.rig().safety,
        board_timeout: f64::from(core.rig().board.command_timeout_ms) * 1e-3,
        backend,
    };
    let final_state = core.state();
    let mut accounting = accounting(&rig);
    let digest = format!("{:016x}", rig.sent_digest());
    let run = rig.finish(s.goal.position, s.goal.tolerance);
    if let Some((worker, failure)) = policy {
        worker.end(&run, failure.as_ref());
    }
    let reached_goal = final_state == State::Stopped(StopReason::GoalReached) && run.reached_goal;
    // Driven by a policy, reaching the goal is the policy's part, not the gateway's.
    let judged_goal = reached_goal || goal_is_the_policys;
    let (mut violations, stops) = judge(&schedule, &settings, &history, &watch, judged_goal, final_state);
    violations.append(&mut accounting);
    let outcome = JudgedEpisode {
        index,
        backend,
        faults: schedule.faults,
        stops,
        refusals: watch.refusals,
        last_refusal: watch.last_refusal,
        reached_goal,
        duration: run.truth.summary.duration,
        violations,
        digest,
        states: if keep { history.iter().map(|(t, state)| (*t, state.to_string())).collect() } else { Vec::new() },
    };
    (outcome, run)
}

/// Run `rig` to the goal after the schedule's last fault (or its time limit past it), the
/// operator resetting, arming, setting the goal and starting after each stop; what it saw.
fn operate(rig: &mut VirtualRig, schedule: &FaultSchedule, turn: &mut dyn FnMut(&mut VirtualRig)) -> EpisodeLog {
    let s = &schedule.scenario;
    let period = rig.core().rig().sample_period.as_secs_f64();
    let goal = Request::Goal { goals: vec![Goal { position: s.goal.position, tolerance: s.goal.tolerance }] };
    let last_end = schedule.last_end();
    let limit = last_end + s.time_limit;
    let mut watch = EpisodeLog::default();
    let (mut next_try, mut shown) = (f64::INFINITY, State::Idle);
    // Liveness: a run that takes far more events than a rig has (a few thousand a second)
    // is stuck, and said so.
    let most_steps = (limit * STEPS_PER_S) as u64;
    let mut steps = 0u64;
    let mut next_turn = 0.0;
    while rig.time() < limit {
        steps += 1;
        if steps > most_steps {
            watch.stuck = Some(rig.time());
            break;
        }
        if rig.time() >= next_turn {
            next_turn += period;
            turn(rig);
        }
        rig.step();
        let (t, state) = (rig.time(), rig.core().state());
        if state != shown {
            if matches!(state, State::Fault(_) | State::Stopped(_) | State::Idle | State::Armed) {
                next_try = t + REACTION_S;
            }
            if let State::Fault(reason) = state {
                watch.faulted(t, reason, rig.at_rest_since());
            }
            shown = state;
        }
        watch.observe(t, state, rig.at_rest_since(), period);
        match state {
            State::Stopped(StopReason::GoalReached) if t >= last_end + SETTLE_S => break,
            State::Stopped(StopReason::GoalReached) => {}
            State::Fault(_) | State::Stopped(_) | State::Idle | State::Armed if t >= next_try => {
                next_try = t + REACTION_S;
                let steps: &[&Request] = match state {
                    State::Fault(_) => &[&Request::Reset, &Request::Arm, &goal, &Request::Start],
                    // Armed and not started (the goal refused, say): the goal and start again.
                    State::Armed => &[&goal, &Request::Start],
                    _ => &[&Request::Arm, &goal, &Request::Start],
                };
                for &request in steps {
                    if let Err(refusal) = rig.request(request) {
                        watch.refusals += 1;
                        watch.last_refusal = Some(format!("{} at {t:.2} s: {refusal}", request_name(request)));
                        break;
                    }
                    watch.asked(t, request);
                }
            }
            _ => {}
        }
    }
    watch
}

/// The world's and the lines' invariants at the end: no active contact, no motion command
/// outside Running, every byte and frame accounted for.
fn accounting(rig: &VirtualRig) -> Vec<String> {
    let mut v = Vec::new();
    if let Some(c) = rig.world().truth().first_active_contact {
        v.push(format!(
            "active contact with {:?} at {:.3} s, driving into it at {:.3} m/s",
            c.with, c.at, c.approach_speed
        ));
    }
    let motion = rig.motion_outside_running();
    if motion > 0 {
        v.push(format!("{motion} motion commands outside Running"));
    }
    let (bytes, delivered, counters) = (rig.core().serial_bytes(), rig.delivered(), rig.core().counters());
    if !bytes.balanced() || bytes.received != delivered.0 {
        v.push(format!(
            "PSD bytes unaccounted for: the line delivered {}, the gateway received {}, took {}, dropped {}, holds {}",
            delivered.0, bytes.received, bytes.taken, bytes.dropped, bytes.buffered
        ));
    }
    if counters.can_frames_in != delivered.1 {
        v.push(format!(
            "CAN frames unaccounted for: the bus delivered {}, the gateway counted {}",
            delivered.1, counters.can_frames_in
        ));
    }
    v
}

fn request_name(request: &Request) -> &'static str {
    match request {
        Request::Reset => "reset",
        Request::Arm => "arm",
        Request::Start => "start",
        Request::Goal { .. } => "goal",
        _ => "request",
    }
}

/// How often each kind was drawn, and the fault states named for it.
#[derive(Debug, Clone, Default, Serialize)]
pub struct KindRow {
    pub episodes: usize,
    pub stops: usize,
    /// The reasons its stops were named, and how many of each.
    pub reasons: BTreeMap<String, usize>,
}

/// A swarm's report (printed, and written as swarm.json).
#[derive(Debug, Clone, Serialize)]
pub struct SwarmReport {
    pub scenario: String,
    pub seed: u64,
    pub shard: String,
    pub episodes: usize,
    /// Episodes that broke an invariant.
    pub violated: usize,
    pub reached_goal: usize,
    /// Episodes with a cause that never ends (they must end faulted, naming it).
    pub lasting: usize,
    pub faults: usize,
    pub stops: usize,
    pub by_backend: BTreeMap<Backend, usize>,
    pub by_kind: BTreeMap<Kind, KindRow>,
    /// The virtual time run, s.
    pub virtual_s: f64,
    /// Every episode that broke an invariant, in full.
    pub failures: Vec<JudgedEpisode>,
    /// Every episode in one line: what a replay must reproduce.
    pub episode_lines: Vec<EpisodeLine>,
}

/// One episode of a swarm, in brief.
#[derive(Debug, Clone, Serialize)]
pub struct EpisodeLine {
    pub index: u64,
    pub backend: Backend,
    pub faults: Vec<Kind>,
    pub stops: usize,
    pub reached_goal: bool,
    pub violations: usize,
    /// FNV-1a of every byte the gateway sent, in hex.
    pub digest: String,
}

/// Run `n` episodes of the swarm (the shard's) around `base` on `threads` threads.
pub fn run(
    base: &Scenario,
    n: u64,
    seed: u64,
    threads: usize,
    shard: Shard,
    policy: Option<(&str, std::time::Duration)>,
) -> Result<Vec<JudgedEpisode>, TooLarge> {
    let worker = || policy.map(|(command, budget)| Worker::new(command, budget));
    let mut outcomes = shard.run_with(n, threads, worker, |w, i| run_episode(base, seed, i, false, w.as_mut()).0)?;
    outcomes.sort_by_key(|o| o.index);
    Ok(outcomes)
}

/// The report of a swarm's episodes.
pub fn report(base: &Scenario, seed: u64, shard: Shard, outcomes: &[JudgedEpisode]) -> SwarmReport {
    let mut by_kind: BTreeMap<Kind, KindRow> = BTreeMap::new();
    let mut by_backend = BTreeMap::new();
    for o in outcomes {
        *by_backend.entry(o.backend).or_default() += 1;
        for f in &o.faults {
            by_kind.entry(f.kind).or_default().episodes += 1;
        }
        for s in &o.stops {
            if let Some(kind) = s.named_for {
                let row = by_kind.entry(kind).or_default();
                row.stops += 1;
                // The reason's name without its counts (garbled frames differ every time).
                let name = s.reason.split(" (").next().unwrap_or(&s.reason).to_string();
                *row.reasons.entry(name).or_default() += 1;
            }
        }
    }
    SwarmReport {
        scenario: base.name.clone(),
        seed,
        shard: shard.to_string(),
        episodes: outcomes.len(),
        violated: outcomes.iter().filter(|o| !o.violations.is_empty()).count(),
        reached_goal: outcomes.iter().filter(|o| o.reached_goal).count(),
        lasting: outcomes.iter().filter(|o| o.faults.iter().any(|f| f.to.is_infinite())).count(),
        faults: outcomes.iter().map(|o| o.faults.len()).sum(),
        stops: outcomes.iter().map(|o| o.stops.len()).sum(),
        by_backend,
        by_kind,
        virtual_s: outcomes.iter().map(|o| o.duration).sum(),
        failures: outcomes.iter().filter(|o| !o.violations.is_empty()).cloned().collect(),
        episode_lines: outcomes
            .iter()
            .map(|o| EpisodeLine {
                index: o.index,
                backend: o.backend,
                faults: o.faults.iter().map(|f| f.kind).collect(),
                stops: o.stops.len(),
                reached_goal: o.reached_goal,
                violations: o.violations.len(),
                digest: o.digest.clone(),
            })
            .collect(),
    }
}

impl std::fmt::Display for SwarmReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "fault swarm around {}: {} episodes (seed {}, shard {}), {} faults, {} fault states",
            self.scenario, self.episodes, self.seed, self.shard, self.faults, self.stops
        )?;
        let backends: Vec<String> = self.by_backend.iter().map(|(b, n)| format!("{} {n}", b.name())).collect();
        writeln!(f, "  backends: {}", backends.join(", "))?;
        writeln!(
            f,
            "  goal reached after the last fault: {} of {} ({} with a cause that never ends: faulted, naming it)",
            self.reached_goal,
            self.episodes - self.lasting,
            self.lasting
        )?;
        writeln!(f, "  invariants broken: {} episodes", self.violated)?;
        writeln!(f, "  {:<20} {:>8} {:>6}  named", "fault", "episodes", "stops")?;
        for (kind, row) in &self.by_kind {
            let reasons: Vec<String> = row.reasons.iter().map(|(r, n)| format!("{r} {n}")).collect();
            writeln!(f, "  {:<20} {:>8} {:>6}  {}", format!("{kind:?}"), row.episodes, row.stops, reasons.join("; "))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
