//! An episode judged against the world's truth: the stops it saw, each named for a fault
//! present then, and the wheels at rest within the fault table's budget.

use super::faults::{Backend, FaultSchedule, Injected, Kind};
use crate::gateway::core::operator::Request;
use crate::gateway::core::{State, StopReason};
use serde::Serialize;

/// The operator: after a stop this long, s, the reset, arm, goal and start; again this
/// often while refused.
pub(super) const REACTION_S: f64 = 0.5;
/// Once the last cause has ended and the goal is reached, the run goes on this long, s.
pub(super) const SETTLE_S: f64 = 1.0;
/// The CiA 402 drives' quick stop from the wheels' top speed (0.25 m/s at 4 m/s²), s.
pub(super) const QUICK_STOP_S: f64 = 0.0625;
/// How long CiA 402 drives wait for the gateway's heartbeat before they stop, s.
pub(super) const CONSUMER_S: f64 = crate::gateway::core::motors::cia402::CONSUMER_TIME_MS as f64 * 1e-3;
/// A reset's handshake takes its own time sync, within this of the reset, s.
pub(super) const HANDSHAKE_S: f64 = 0.1;
/// More events than this a second of virtual time is a stuck run.
pub(super) const STEPS_PER_S: f64 = 200_000.0;
/// Rounding of virtual time against the budgets, s.
pub(super) const FUZZ_S: f64 = 1e-4;

/// A fault state as the episode saw it.
#[derive(Debug, Clone, Serialize)]
pub struct Stop {
    /// When, s.
    pub at: f64,
    /// The reason, as the operator reads it.
    pub reason: String,
    /// The fault of the schedule it is named for (the earliest present that names it).
    pub named_for: Option<Kind>,
    /// How long after it the wheels were at rest, s (`None`: never).
    pub rest_after: Option<f64>,
}

/// An episode as run and judged.
#[derive(Debug, Clone, Serialize)]
pub struct JudgedEpisode {
    pub index: u64,
    pub backend: Backend,
    pub faults: Vec<Injected>,
    pub stops: Vec<Stop>,
    /// The operator's requests refused, and the last of them.
    pub refusals: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub last_refusal: Option<String>,
    pub reached_goal: bool,
    /// The virtual time the episode ran, s.
    pub duration: f64,
    /// The invariants it broke (none, in a good run).
    pub violations: Vec<String>,
    /// FNV-1a of every byte the gateway sent, in hex: a replay sends the same.
    pub digest: String,
    /// The gateway's states and when it entered each, s (kept with the episode's files).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub states: Vec<(f64, String)>,
}

/// What the episode's operator and the world showed over the run.
#[derive(Debug, Default)]
pub(super) struct EpisodeLog {
    pub(super) faults: Vec<Seen>,
    pub(super) refusals: usize,
    pub(super) last_refusal: Option<String>,
    /// When the operator's resets, arms and starts were accepted, s.
    pub(super) resets: Vec<f64>,
    pub(super) arms: Vec<f64>,
    pub(super) starts: Vec<f64>,
    /// The wheels turned again in a fault after they had come to rest (the first time).
    pub(super) turned_in_fault: Option<f64>,
    /// The run stopped advancing at this time (far too many events).
    pub(super) stuck: Option<f64>,
}

#[derive(Debug, Clone, Copy)]
pub(super) struct Seen {
    pub(super) at: f64,
    pub(super) reason: StopReason,
    /// Since when the wheels were at rest (before the fault, if they stood already).
    pub(super) rest: Option<f64>,
}

impl EpisodeLog {
    pub(super) fn faulted(&mut self, t: f64, reason: StopReason, at_rest: Option<f64>) {
        self.faults.push(Seen { at: t, reason, rest: at_rest });
    }

    /// After each step: the wheels in a fault. A command sent in Running and still on the
    /// wire at the fault may land after it (within a cycle): the rest is then timed again.
    pub(super) fn observe(&mut self, t: f64, state: State, at_rest: Option<f64>, period: f64) {
        let Some(last) = self.faults.last_mut() else { return };
        if !matches!(state, State::Fault(_)) {
            return;
        }
        match (last.rest, at_rest) {
            (None, Some(since)) => last.rest = Some(since),
            (Some(_), None) if t <= last.at + period => last.rest = None,
            (Some(_), None) if self.turned_in_fault.is_none() => self.turned_in_fault = Some(t),
            _ => {}
        }
    }

    pub(super) fn asked(&mut self, t: f64, request: &Request) {
        match request {
            Request::Reset => self.resets.push(t),
            Request::Arm => self.arms.push(t),
            Request::Start => self.starts.push(t),
            _ => {}
        }
    }
}

/// The rig's settings the budgets come from.
#[derive(Debug, Clone, Copy)]
pub(super) struct Settings {
    /// The control period T, s.
    pub(super) period: f64,
    pub(super) safety: crate::config::SafetySettings,
    /// The motors' own command timeout, s.
    pub(super) board_timeout: f64,
    pub(super) backend: Backend,
}

impl Settings {
    /// The watchdog that detects `reason`, s (`None`: detected on the input itself).
    fn watchdog(&self, reason: StopReason) -> Option<f64> {
        use StopReason as R;
        let s = &self.safety;
        Some(match reason {
            // Garbage may let a sample through now and then: the watchdog then counts from a
            // sample after the cause began, which the schedule does not know.
            // Found by the sample watchdog, or by the pose watchdog when the line went quiet
            // for less than the sample timeout but took the robot's poses with it.
            R::SamplesStopped => s.sample_timeout.max(s.pose_timeout).as_secs_f64(),
            R::PoseLost => s.pose_timeout.as_secs_f64(),
            R::HeartbeatLost { .. } | R::DriveHeartbeatLost { .. } => s.heartbeat_timeout.as_secs_f64(),
            R::ObstacleOccluded { .. } => s.occlusion_timeout.as_secs_f64(),
            R::ClockUnsynced => crate::gateway::core::psd_session::SYNC_STALE.as_secs_f64(),
            _ => return None,
        })
    }
}

/// The board stops its axes itself for these (within a millisecond of the cause).
pub(super) fn board_stops_itself(kind: Kind) -> bool {
    matches!(kind, Kind::BoardFault | Kind::BoardEStop | Kind::BoardReboot | Kind::BoardBusOff)
}

/// The latest the wheels may come to rest for a fault state at `at` named for `cause`,
/// s: the fault table's budgets. A board stopping itself: within 1 ms of its cause. CiA
/// 402 drives: their quick stop from top speed, and a cycle. Commands that may not reach
/// the motors (CAN loss, bus-off): the motors' own command timeout, and a cycle.
/// Otherwise: within a cycle of the fault.
pub(super) fn rest_by(settings: &Settings, schedule: &FaultSchedule, at: f64, cause: Option<&Injected>) -> f64 {
    if let Some(cause) = cause.filter(|c| settings.backend.board() && board_stops_itself(c.kind)) {
        return cause.from + 1e-3;
    }
    let cut =
        schedule.faults.iter().any(|f| f.kind.cuts_commands() && at >= f.from - FUZZ_S && at <= f.to + f.kind.grace());
    let stop = match (cut, settings.backend.board()) {
        (true, true) => settings.board_timeout,
        // Drives that stop hearing the gateway quick-stop by themselves.
        (true, false) => CONSUMER_S + QUICK_STOP_S,
        (false, false) => QUICK_STOP_S,
        (false, true) => 0.0,
    };
    at + stop + settings.period
}

/// The invariants on one episode's fault states, arms and end.
/// The schedule's faults, as a violation lists them.
pub(super) fn listed(schedule: &FaultSchedule) -> String {
    let each = schedule.faults.iter().map(|f| format!("{:?} {:.3}-{:.3} s", f.kind, f.from, f.to));
    each.collect::<Vec<_>>().join(", ")
}

/// The invariants on one fault state: named for a fault present, found within its
/// watchdog, the wheels at rest within budget. Violations go to `v`.
pub(super) fn judge_stop(
    schedule: &FaultSchedule,
    settings: &Settings,
    history: &[(f64, State)],
    watch: &EpisodeLog,
    seen: &Seen,
    v: &mut Vec<String>,
) -> Stop {
    let entered_before = |t: f64, state: State| {
        history.iter().rev().find(|(at, s)| *at <= t + FUZZ_S && *s == state).map_or(0.0, |x| x.0)
    };
    let present: Vec<&Injected> = schedule
        .faults
        .iter()
        .filter(|f| {
            f.kind.explains(f.led, seen.reason) && seen.at >= f.from - FUZZ_S && seen.at <= f.to + f.kind.grace()
        })
        .collect();
    let named_for = present.iter().min_by(|a, b| a.from.total_cmp(&b.from)).copied();
    let stop = Stop {
        at: seen.at,
        reason: seen.reason.to_string(),
        named_for: named_for.map(|f| f.kind),
        rest_after: seen.rest.map(|r| r - seen.at),
    };
    // The world's own: an obstacle that walked onto the robot (inside its planning circle
    // the field is not defined), or a planner refusing what the world made of its input.
    let worldly = matches!(seen.reason, StopReason::ObstacleReachedRobot { .. } | StopReason::PlannerInvalid);
    if named_for.is_none() && !worldly {
        v.push(format!(
            "fault at {:.3} s named \"{}\": no fault present names it ({})",
            seen.at,
            seen.reason,
            listed(schedule)
        ));
        return stop;
    }
    if let Some(watchdog) = settings.watchdog(seen.reason) {
        // The watchdogs start afresh at each arm; the time sync's at each reset.
        let restart = if seen.reason == StopReason::ClockUnsynced {
            watch.resets.iter().copied().filter(|r| *r <= seen.at).fold(0.0, f64::max) + HANDSHAKE_S
        } else {
            entered_before(seen.at, State::Armed)
        };
        // From the latest start of a cause that silences it entirely (partial ones let
        // some through, and the watchdog counts from the last).
        let since = present.iter().filter(|f| f.kind.total()).map(|f| f.from.max(restart)).fold(f64::NAN, f64::max);
        // The pose and occlusion watchdogs watch only a running robot, counting from the
        // arm: one that ran out while the robot stood armed fires as it starts to run.
        let running_only = matches!(seen.reason, StopReason::PoseLost | StopReason::ObstacleOccluded { .. });
        let running = if running_only { entered_before(seen.at, State::Running) } else { 0.0 };
        let by = (since + watchdog).max(running) + settings.period;
        if since.is_finite() && seen.at > by + FUZZ_S {
            v.push(format!(
                "fault \"{}\" at {:.3} s: {:.1} ms after its cause, beyond the {:.0} ms watchdog and a cycle",
                seen.reason,
                seen.at,
                (seen.at - since) * 1e3,
                watchdog * 1e3
            ));
        }
    }
    let by = if present.is_empty() {
        rest_by(settings, schedule, seen.at, None)
    } else {
        present.iter().map(|f| rest_by(settings, schedule, seen.at, Some(f))).fold(f64::NEG_INFINITY, f64::max)
    };
    match seen.rest {
        None => v.push(format!("fault \"{}\" at {:.3} s: the wheels never came to rest in it", seen.reason, seen.at)),
        Some(rest) if rest > by + FUZZ_S => v.push(format!(
            "fault \"{}\" at {:.3} s: wheels at rest {:.1} ms after it, the budget {:.1} ms",
            seen.reason,
            seen.at,
            (rest - seen.at) * 1e3,
            (by - seen.at) * 1e3
        )),
        Some(_) => {}
    }
    stop
}

/// Armed only when the operator armed (or at start, before any fault: `ArmAtStart`);
/// Running only after a start since the last arm.
pub(super) fn judge_arms(history: &[(f64, State)], watch: &EpisodeLog, v: &mut Vec<String>) {
    // Running only after a start since the last arm.
    let first_fault = history.iter().find(|(_, s)| matches!(s, State::Fault(_))).map_or(f64::INFINITY, |x| x.0);
    let mut last_armed = None;
    for (i, &(t, state)) in history.iter().enumerate() {
        match state {
            State::Armed => {
                let asked = watch.arms.iter().any(|a| (a - t).abs() <= FUZZ_S);
                let at_start = t < first_fault && !history[..i].iter().any(|(_, s)| *s == State::Armed);
                if !asked && !at_start {
                    v.push(format!("armed at {t:.3} s without the operator's arm"));
                }
                last_armed = Some((t, at_start && !asked));
            }
            State::Running => {
                let started = match last_armed {
                    Some((_, true)) => true,
                    Some((armed, false)) => watch.starts.iter().any(|s| *s >= armed - FUZZ_S && *s <= t + FUZZ_S),
                    None => false,
                };
                if !started {
                    v.push(format!("running at {t:.3} s without the operator's start"));
                }
            }
            _ => {}
        }
    }
}

pub(super) fn judge(
    schedule: &FaultSchedule,
    settings: &Settings,
    history: &[(f64, State)],
    watch: &EpisodeLog,
    reached_goal: bool,
    final_state: State,
) -> (Vec<String>, Vec<Stop>) {
    let mut v = Vec::new();
    let stops = watch.faults.iter().map(|seen| judge_stop(schedule, settings, history, watch, seen, &mut v)).collect();
    if let Some(t) = watch.stuck {
        v.push(format!("the run stopped advancing at {t:.6} s (more than {STEPS_PER_S} events a second)"));
    }
    if let Some(t) = watch.turned_in_fault {
        v.push(format!("the wheels turned in a fault at {t:.3} s, after coming to rest in it"));
    }
    judge_arms(history, watch, &mut v);
    let lasting: Vec<&Injected> = schedule.faults.iter().filter(|f| f.to.is_infinite()).collect();
    if lasting.is_empty() {
        if !reached_goal {
            v.push(format!(
                "the goal was not reached after the last fault ended at {:.3} s: {final_state}; the last refusal: {}",
                schedule.last_end(),
                watch.last_refusal.as_deref().unwrap_or("none")
            ));
        }
    } else {
        let named = matches!(final_state, State::Fault(r) if lasting.iter().any(|f| f.kind.explains(f.led, r)));
        if !named {
            v.push(format!("a cause that never ends, and the run ends {final_state}, not in a fault naming it"));
        }
    }
    (v, stops)
}
