//! Evasion: when the robot, holding the command the supervisor passed or standing, would be
//! run into, the command among those the wheels can reach that gives up least and keeps
//! clear of every hazard over the look-ahead (docs/supervisor.md, "Evasion").

use super::{judged, Ahead, Context, SupervisorConfig};
use crate::control::drive::WheelSpeeds;
use crate::track::Estimate;

/// What an evasive command is certified with beyond the promise, m: more than a command
/// the planner proposed ([`ROBUSTNESS`](super::ROBUSTNESS)), since an evasion turns and
/// reverses where the next cycle's brake must still find its way clear.
pub(super) const EVASION_SPARE: f64 = 0.01;

/// How far ahead evasion looks, s: long enough for an obstacle at the robot's speed to
/// cross its keep-out circle, short enough that the obstacles' straight courses hold.
pub const EVASION_HORIZON: f64 = 1.5;
/// How soon a contact must be predicted for evasion to act, s: an imminent one, not a
/// passing that the field's own way round will resolve.
pub const EVASION_TRIGGER: f64 = 1.0;
/// Each wheel's candidate speeds, as fractions of its limit: the commands evasion chooses
/// among (reversing included) are every pair of these.
const EVASION_WHEEL_FRACTIONS: [f64; 7] = [-1.0, -0.6, -0.3, 0.0, 0.3, 0.6, 1.0];
/// How many commands evasion chooses among.
const EVASION_CANDIDATES: usize = EVASION_WHEEL_FRACTIONS.len() * EVASION_WHEEL_FRACTIONS.len();

/// Evasion: when the command the supervisor passed would leave the robot inside a moving
/// obstacle's keep-out circle within [`EVASION_HORIZON`] (the obstacle running into it),
/// choose among the commands the wheels can reach, reversing included, that keep the
/// supervisor's promise (never driving into a hazard): the nearest to the planner's
/// `proposed` command that keeps clear of every hazard over the horizon, walls included;
/// if none does, the one that keeps the largest predicted clearance. `None`: the chosen
/// command is kept (no contact predicted, or nothing does better).
pub fn evade(
    cfg: &SupervisorConfig,
    estimate: &Estimate<'_>,
    proposed: WheelSpeeds,
    chosen: WheelSpeeds,
    max_wheel_speed: f64,
) -> Option<Evasion> {
    judged(cfg, estimate, |ctx| evasion(ctx, proposed, chosen, max_wheel_speed))
}

/// An evasive command, and whether the supervisor's model predicts it clear of every
/// hazard over [`EVASION_HORIZON`] (an escape), or only the largest clearance there is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Evasion {
    pub wheels: WheelSpeeds,
    pub clear: bool,
}

/// The evasion in `ctx` (see [`evade`]).
fn evasion(ctx: &Context<'_>, proposed: WheelSpeeds, chosen: WheelSpeeds, max_wheel_speed: f64) -> Option<Evasion> {
    // Only where the robot, holding its command or standing, would be run into.
    let standing = WheelSpeeds { left: 0.0, right: 0.0 };
    if ctx.least_margin_ahead(chosen, Ahead::Moving, EVASION_TRIGGER, 0.0) >= 0.0
        || ctx.least_margin_ahead(standing, Ahead::Moving, EVASION_TRIGGER, 0.0) >= 0.0
    {
        return None;
    }
    let allowed = match nearest_clear(ctx, proposed, max_wheel_speed) {
        Ok(command) => return (command != chosen).then_some(Evasion { wheels: command, clear: true }),
        Err(allowed) => allowed,
    };
    let kept = ctx.least_margin_ahead(chosen, Ahead::All, EVASION_HORIZON, f64::NEG_INFINITY);
    // The nearest clear command to the proposal, else the largest margin.
    let (mut nearest, mut widest): (Option<(f64, WheelSpeeds)>, (f64, WheelSpeeds)) = (None, (kept, chosen));
    for (k, command) in evasion_candidates(max_wheel_speed).enumerate() {
        if !allowed[k].unwrap_or_else(|| evasion_allows(ctx, command)) {
            continue;
        }
        // A command that is not clear matters only while nothing is, and then only if it
        // keeps more than the widest so far.
        let matters = if nearest.is_some() { 0.0 } else { (widest.0 + 1e-9).min(0.0) };
        let margin = ctx.least_margin_ahead(command, Ahead::All, EVASION_HORIZON, matters);
        if margin >= 0.0 {
            // Least cost: away from the proposal, and giving up forward progress.
            let off = (command.left - proposed.left).hypot(command.right - proposed.right);
            let cost = off - (command.left + command.right);
            if nearest.is_none_or(|(d, _)| cost < d) {
                nearest = Some((cost, command));
            }
        } else if margin > widest.0 + 1e-9 {
            widest = (margin, command);
        }
    }
    let (command, clear) = nearest.map_or((widest.1, false), |(_, c)| (c, true));
    (command != chosen).then_some(Evasion { wheels: command, clear })
}

/// Evasion's candidate commands, in the order they are judged.
pub(super) fn evasion_candidates(max_wheel_speed: f64) -> impl Iterator<Item = WheelSpeeds> {
    let pairs = EVASION_WHEEL_FRACTIONS.into_iter().flat_map(|l| EVASION_WHEEL_FRACTIONS.map(|r| (l, r)));
    pairs.map(move |(left, right)| WheelSpeeds { left: left * max_wheel_speed, right: right * max_wheel_speed })
}

/// Whether evasion may take `command` at all: it keeps the supervisor's promise with
/// [`EVASION_SPARE`] to spare, and moves toward nothing close by.
fn evasion_allows(ctx: &Context<'_>, command: WheelSpeeds) -> bool {
    ctx.first_driven_into(command, EVASION_SPARE).is_none() && !ctx.approaches_a_near_obstacle(command)
}

/// The clear command [`evasion`] chooses, if any, found by judging the candidates from the
/// least cost up and stopping at the first clear one (the same as judging them all: equal
/// costs in the candidates' own order). Else which candidates evasion allows, where judged
/// (none is, when the proposal is not finite: its costs would not order).
pub(super) fn nearest_clear(
    ctx: &Context<'_>,
    proposed: WheelSpeeds,
    max_wheel_speed: f64,
) -> Result<WheelSpeeds, [Option<bool>; EVASION_CANDIDATES]> {
    let mut allowed = [None; EVASION_CANDIDATES];
    if !(proposed.left.is_finite() && proposed.right.is_finite()) {
        return Err(allowed);
    }
    let mut by_cost = [(0.0, 0, WheelSpeeds { left: 0.0, right: 0.0 }); EVASION_CANDIDATES];
    for (k, command) in evasion_candidates(max_wheel_speed).enumerate() {
        let off = (command.left - proposed.left).hypot(command.right - proposed.right);
        by_cost[k] = (off - (command.left + command.right), k, command);
    }
    // Equal costs (-0 and +0 too) in the candidates' order, as judging them all keeps the first.
    by_cost.sort_unstable_by(|a, b| a.0.partial_cmp(&b.0).unwrap_or(std::cmp::Ordering::Equal).then(a.1.cmp(&b.1)));
    for (_, k, command) in by_cost {
        let allows = evasion_allows(ctx, command);
        allowed[k] = Some(allows);
        if allows && ctx.least_margin_ahead(command, Ahead::All, EVASION_HORIZON, 0.0) >= 0.0 {
            return Ok(command);
        }
    }
    Err(allowed)
}
