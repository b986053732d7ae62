//! The safety supervisor: the last word on every wheel command, independent of the field.
//!
//! **Its promise:** the robot is never driving toward an obstacle (faster than
//! [`APPROACH_TOLERANCE`], a fifth of what the world calls active) or a lane line when it
//! touches it. A contact can still happen, when an obstacle runs into a robot that has
//! stopped or is moving away (a *passive* contact); the field and the margins are what
//! avoid those.
//!
//! **Its rule.** A command passes when the path the robot would take, holding it for one
//! reaction time `τ` and then braking, never brings it against a hazard while it moves
//! toward it:
//!
//! - the path: each wheel ramps at the boards' acceleration `a` from its present speed (the
//!   tracker's ramp model) toward the command for `τ`, which is exact for the boards; then
//!   the brake holds the turn and lowers both wheels together, so the centre slows at `a`
//!   until it stops, going forward or backing (the wheels may go on turning the robot on
//!   the spot). The pose is integrated along it in steps of [`STEP`]. Backing up drives
//!   into what lies behind as driving on does into what lies ahead;
//! - an obstacle: its predicted centre moves on at its estimated velocity; the robot must
//!   keep the sum of the radii, `sigmas` standard deviations of the centre, `sigmas`
//!   standard deviations of the velocity times the time ahead, a fixed `clearance` and one
//!   step's travel of both from it (each step is judged at its start), or else be moving
//!   away from it (or toward it no faster than [`APPROACH_TOLERANCE`]). Once the centre
//!   has stopped it drives into nothing. Another vehicle of a fleet may stop dead anywhere
//!   on its way (its link lost, its motors holding their last command until their timeout)
//!   before anyone knows: it is kept clear of wherever between where it stands now and
//!   where its command would take it, so a follower keeps its stop's length behind where
//!   the vehicle ahead stands, not where it will be;
//! - a line (a lane's line, or the edge of a wall, a static obstacle or the view near the
//!   robot: the line that touches it, grown by the robot's radius, nearest the robot): the
//!   robot's centre keeps `clearance` and a step's travel from it, or moves away from it
//!   (at any speed toward it a robot would creep up to the line, its estimate cross it, and
//!   the planner refuse it: a line does not move, so no stop ever needs the tolerance
//!   there). Each such line leaves the whole wall, obstacle or view's outside beyond it
//!   (a grown segment is convex, and a view is too), so keeping off the lines keeps off
//!   the room.
//!
//! A command that fails is slowed: the largest forward speed that passes with the command's
//! turn (bisection), else with the turn the wheels hold now (the brake above), else the
//! brake itself, which is then reported as [`Supervision::Braking`]: the estimate changed
//! faster than one reaction time allows for. A robot at rest, turning on the spot or
//! moving away from every hazard always passes: the supervisor never traps it.
//!
//! The supervisor keeps no state: the estimate carries the wheels' present speeds. So the
//! gateway, the offline runner, replay and the benchmarks apply the same rule.

use crate::Point;

use arrayvec::ArrayVec;

use crate::control::drive::WheelSpeeds;
use crate::geometry::{rotation, Length};
use crate::planner::room::Room;
use crate::planner::{ObstacleEstimate, MAX_OBSTACLES};
use crate::track::{ramp, Estimate};

mod evasion;
mod ramp;
pub use evasion::{evade, Evasion, EVASION_HORIZON, EVASION_TRIGGER};
use ramp::{dot, BeyondRamp};
/// What the supervisor is configured with.
#[derive(Debug, Clone, PartialEq)]
pub struct SupervisorConfig {
    /// The boards' acceleration ramp on each wheel, m/s².
    pub wheel_accel: f64,
    /// `l_w`, m.
    pub wheel_base: f64,
    pub robot_radius: f64,
    /// From a decision to the next decision taking effect, s: the control period and the
    /// command's way to the wheels.
    pub reaction_time: f64,
    /// The lane's half-width `h` (the lines bound the robot's centre); `None`: free space.
    pub lane_half_width: Option<f64>,
    /// Standard deviations of an obstacle's estimate kept clear.
    pub sigmas: f64,
    /// Gap kept beyond the uncertainty, m.
    pub clearance: f64,
    /// Where the camera sees the robot's centre, `[x_min, x_max, y_min, y_max]` (m): an
    /// evasion keeps it inside (the promise does not depend on it). `None`: anywhere.
    pub arena: Option<[f64; 4]>,
    /// The room's walls, static obstacles and view's edge: the robot keeps off them as off
    /// a lane's lines. `None`: no room.
    pub room: Option<std::sync::Arc<Room>>,
    /// How fast the robot may still move toward an obstacle within its reach, m/s:
    /// [`APPROACH_TOLERANCE`] behind the field, which never pushes into an obstacle; 0
    /// behind a planner outside flowgate, which may push for as long as it likes, and at
    /// any speed above 0 would creep into what it pushes at.
    pub approach_tolerance: f64,
    /// How fast it may close on another vehicle of a fleet within its reach (an obstacle
    /// that keeps room, `ObstacleEstimate::keep > 0`) while its speed is not coming down
    /// (holding a command, or speeding up), m/s: `approach_tolerance` for the robot alone;
    /// 0 for a fleet's vehicles, which touch each other not even passively, and which at
    /// any speed above 0 would creep into a vehicle they are held beside while their field
    /// pushes on. A stop's last sliver of speed is judged by `approach_tolerance`.
    pub vehicle_approach_tolerance: f64,
}

impl SupervisorConfig {
    /// One standard deviation and 2 mm beyond it (see docs/supervisor.md: three keep robots so far
    /// off that most episodes around E5 stall); reaction time one period and a half
    /// (the command's way to the wheels and the period's jitter, well within half a period).
    pub fn new(wheel_accel: f64, wheel_base: f64, robot_radius: f64, period: f64, lane: Option<f64>) -> Self {
        Self {
            wheel_accel,
            wheel_base,
            robot_radius,
            reaction_time: 1.5 * period,
            lane_half_width: lane,
            room: None,
            sigmas: 1.0,
            clearance: 0.002,
            arena: None,
            approach_tolerance: APPROACH_TOLERANCE,
            vehicle_approach_tolerance: APPROACH_TOLERANCE,
        }
    }
}

impl SupervisorConfig {
    /// What it keeps from an obstacle beyond the radii and the uncertainty allowance when
    /// it certifies a command, m.
    pub fn keep_out(&self) -> f64 {
        self.clearance + ROBUSTNESS
    }
}

/// What the supervisor did to a command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Supervision {
    /// It passed unchanged.
    Passed,
    /// It was slowed (`hazard`: the obstacle's index, `None` for a line: a lane's, a wall's,
    /// a static obstacle's or the view's edge).
    Slowed { hazard: Option<usize> },
    /// Even braking cannot keep the promise under the estimate: the robot brakes.
    Braking { hazard: Option<usize> },
    /// Slowed or braking, the robot would stand in an obstacle's way: it evades instead,
    /// with the reachable command that keeps the largest predicted clearance (see
    /// [`evade`]).
    Evaded { hazard: Option<usize> },
}

impl Supervision {
    pub fn intervened(self) -> bool {
        self != Supervision::Passed
    }
}

/// Something the robot must not drive into.
#[derive(Debug, Clone, Copy)]
enum Hazard {
    /// An obstacle: where it is predicted now, its velocity, the distance to keep from its
    /// centre now, how fast that distance grows with the time ahead (its velocity's
    /// uncertainty), and whether it is another vehicle of a fleet.
    Obstacle { index: usize, center: Point, velocity: Point, speed: f64, keep: f64, growth: f64, vehicle: bool },
    /// A line the centre keeps `keep` from, on the side where `normal · z < offset`
    /// (`normal` a unit vector pointing across it, away from the robot).
    Line { normal: Point, offset: f64, keep: f64 },
}

impl Hazard {
    fn is_vehicle(&self) -> bool {
        matches!(self, Hazard::Obstacle { vehicle: true, .. })
    }

    fn index(&self) -> Option<usize> {
        match self {
            Hazard::Obstacle { index, .. } => Some(*index),
            Hazard::Line { .. } => None,
        }
    }

    /// Whether a robot at `position` moving at `velocity` over the step of `h` seconds
    /// that starts `s` seconds ahead drives into it, keeping `slack` more than it must.
    /// An obstacle is judged where it is at the step's start, so its reach takes in what
    /// it can close over the step (its speed and its uncertainty's growth): a contact
    /// anywhere in the step is then seen at its start, the last one included.
    fn driven_into(&self, s: f64, h: f64, position: Point, velocity: Point, slack: f64, tolerance: f64) -> bool {
        match *self {
            Hazard::Obstacle { center, velocity: v, speed, keep, growth, vehicle, .. } => {
                let d = center + v * s - position;
                let reach = keep + slack + growth * (s + h) + speed * h;
                if vehicle {
                    return toward_the_way(center - position, d, reach, velocity, tolerance);
                }
                // Toward it faster than the tolerance: `d · v > tol |d|`.
                let toward = d.re * velocity.re + d.im * velocity.im;
                let distance_sqr = d.norm_sqr();
                distance_sqr < reach * reach && toward > 0.0 && toward * toward > tolerance * tolerance * distance_sqr
            }
            Hazard::Line { normal, offset, keep } => {
                offset - dot(normal, position) < keep + slack && dot(normal, velocity) > 0.0
            }
        }
    }
}

/// Whether a robot moving at `velocity` is within `reach` of some point of the segment from
/// offset `from` to offset `to` (relative to the robot) and moves toward it faster than
/// `tolerance`: [`Hazard::driven_into`] for another vehicle, which may stop dead anywhere
/// on its way (its link lost, its motors timing out) before anyone knows. The points
/// within reach form one piece of the segment; the approach `p · velocity` is linear along
/// it, so largest at one of its ends, and is weighed against the piece's nearest point
/// (more cautious than the point it is largest at, which is no nearer).
fn toward_the_way(from: Point, to: Point, reach: f64, velocity: Point, tolerance: f64) -> bool {
    let way = to - from;
    let length_sqr = way.norm_sqr();
    let (first, last) = if length_sqr == 0.0 {
        if from.norm_sqr() >= reach * reach {
            return false;
        }
        (0.0, 0.0)
    } else {
        // |from + way u|² < reach²: between the roots of a quadratic in u, within [0, 1].
        let half_b = dot(from, way);
        let disc = half_b * half_b - length_sqr * (from.norm_sqr() - reach * reach);
        if disc <= 0.0 {
            return false;
        }
        let root = disc.sqrt();
        let (first, last) = (((-half_b - root) / length_sqr).max(0.0), ((-half_b + root) / length_sqr).min(1.0));
        if first > last {
            return false;
        }
        (first, last)
    };
    let approach = |u: f64| dot(from + way * u, velocity);
    let toward = approach(first).max(approach(last));
    let nearest = nearest_between(from, way, (first, last));
    toward > 0.0 && toward * toward > tolerance * tolerance * nearest.norm_sqr()
}

/// The point `from + way u`, `u` within `lo..=hi`, nearest the robot (offsets from it):
/// `from` itself when `way` is zero.
fn nearest_between(from: Point, way: Point, (lo, hi): (f64, f64)) -> Point {
    let length_sqr = way.norm_sqr();
    if length_sqr == 0.0 {
        return from;
    }
    from + way * (-dot(from, way) / length_sqr).clamp(lo, hi)
}

/// How fast the robot may still be moving toward an obstacle within its reach, m/s: a fifth
/// of the 1 cm/s above which the world classes a contact active. A stop's last step leaves a
/// sliver of speed (up to the ramp's step, `a · STEP`) in whatever direction the turn has
/// left the robot facing; judged as driving into an obstacle closing in from beside, that
/// sliver made every stop unsafe, and the supervisor braked for want of a safe command
/// (`tests/supervisor.rs`, an obstacle closing from behind in the narrowest lane).
pub const APPROACH_TOLERANCE: f64 = 0.002;

/// The step along the predicted path, s.
pub const STEP: f64 = 0.005;

/// The most steps a predicted path takes (a board ramp so slow that its stop would need
/// more gets longer steps: the verdict's cost stays bounded whatever the config).
const MAX_PATH_STEPS: f64 = 128.0;

/// Bisection steps for the allowed speed: 2^-16 of the command, below 3 µm/s.
const BISECTIONS: usize = 16;

/// The supervisor's verdict on the command `proposed` in the state `estimate` (judged on
/// its obstacles predicted to now, whatever the planner plans on).
pub fn supervise(cfg: &SupervisorConfig, estimate: &Estimate<'_>, proposed: WheelSpeeds) -> (WheelSpeeds, Supervision) {
    judged(cfg, estimate, |ctx| verdict(ctx, proposed))
}

/// `f` judged in the state `estimate`: its hazards and the robot's pose and wheels.
fn judged<R>(cfg: &SupervisorConfig, estimate: &Estimate<'_>, f: impl FnOnce(&Context<'_>) -> R) -> R {
    // Filled in place: a kilobyte and more, which a move would copy every verdict.
    let mut hazards = ArrayVec::new();
    fill_hazards(&mut hazards, estimate.position, cfg, estimate.predicted);
    let ctx = Context {
        cfg,
        position: estimate.position,
        facing: estimate.facing,
        wheels: estimate.wheels,
        hazards: &hazards,
    };
    f(&ctx)
}

/// The verdict on `proposed` in `ctx` (see [`supervise`]).
fn verdict(ctx: &Context<'_>, proposed: WheelSpeeds) -> (WheelSpeeds, Supervision) {
    let Some(hazard) = ctx.first_driven_into(proposed, ROBUSTNESS) else { return (proposed, Supervision::Passed) };
    let forward = 0.5 * (proposed.left + proposed.right);
    let turn = 0.5 * (proposed.right - proposed.left);
    let held_turn = 0.5 * (ctx.wheels[1] - ctx.wheels[0]);
    let with = |turn: f64| move |v: f64| WheelSpeeds { left: v - turn, right: v + turn };
    // Slow down keeping the command's turn, else keeping the wheels' present one. A stop
    // that keeps the promise as it stands is taken; a speed above it must keep it with
    // [`ROBUSTNESS`] to spare.
    for command in [with(turn), with(held_turn)] {
        if ctx.first_driven_into(command(0.0), 0.0).is_none() {
            let mut beyond_ramp = BeyondRamp::new(ctx);
            let (mut lo, mut hi) = (0.0, forward.max(0.0));
            for _ in 0..BISECTIONS {
                let mid = 0.5 * (lo + hi);
                if ctx.passes(command(mid), &mut beyond_ramp) {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            return (command(lo), Supervision::Slowed { hazard: hazard.index() });
        }
    }
    (with(held_turn)(0.0), Supervision::Braking { hazard: hazard.index() })
}

/// The least length of `from + s · step` for `s` in `[0, 1]`: how close two points moving
/// straight come, `from` apart at the start and closing by `step`.
fn closest_approach(from: Point, step: Point) -> f64 {
    let along = step.norm_sqr();
    let s = if along > 0.0 { (-(from.conj() * step).re / along).clamp(0.0, 1.0) } else { 0.0 };
    (from + step * s).length()
}

/// Evasion's prediction step, s.
const EVASION_STEP: f64 = 0.05;

/// How close an obstacle's keep-out circle may be for evasion to move toward it, m.
const EVASION_NEAR: f64 = 0.15;
/// How close a lane line may be for evasion to move toward it, m.
const EVASION_NEAR_WALL: f64 = 0.05;

/// Which hazards a look ahead judges.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ahead {
    /// Only obstacles that move (what can run into a robot).
    Moving,
    All,
}

/// Below this speed an obstacle counts as standing for evasion's trigger, m/s.
const STANDING: f64 = 0.02;

/// What a command is certified with beyond the promise, m: the next cycle judges the brake
/// it relied on from a state a little off the model's (whole pulses, the cycle's jitter),
/// and must still find it safe.
const ROBUSTNESS: f64 = 0.001;

/// The state one verdict is judged in.
struct Context<'a> {
    cfg: &'a SupervisorConfig,
    position: Point,
    /// The heading as a unit vector.
    facing: Point,
    wheels: [f64; 2],
    hazards: &'a [Hazard],
}

/// What the robot must not drive into: each obstacle, and each lane line.
fn fill_hazards(
    hazards: &mut ArrayVec<Hazard, { MAX_OBSTACLES + 2 + ROOM_LINES }>,
    position: Point,
    cfg: &SupervisorConfig,
    obstacles: &[ObstacleEstimate],
) {
    for (index, o) in obstacles.iter().enumerate().take(MAX_OBSTACLES) {
        hazards.push(Hazard::Obstacle {
            index,
            center: o.center,
            velocity: o.velocity,
            speed: o.velocity.length(),
            keep: o.radius + cfg.robot_radius + cfg.sigmas * o.position_sd + cfg.clearance,
            growth: cfg.sigmas * o.velocity_sd + o.spread,
            vehicle: o.keep > 0.0,
        });
    }
    if let Some(h) = cfg.lane_half_width {
        for side in [1.0, -1.0] {
            hazards.push(Hazard::Line { normal: Point::new(0.0, side), offset: h, keep: cfg.clearance });
        }
    }
    if let Some(room) = &cfg.room {
        let mut lines = ArrayVec::<(f64, Point, f64), ROOM_LINES>::new();
        room.lines_near(position, cfg.robot_radius, ROOM_REACH, &mut lines);
        for (_, normal, offset) in lines {
            hazards.push(Hazard::Line { normal, offset, keep: cfg.clearance + ROOM_ALLOWANCE });
        }
    }
}

/// What the robot keeps from the room's edges beyond `clearance`, m: the error of its own
/// estimated position, which a wall, unlike an obstacle, has no uncertainty of its own to
/// cover (a wall is met straight on, along the estimate's error).
const ROOM_ALLOWANCE: f64 = 0.003;

/// The most lines of the room the supervisor weighs at once (the nearest).
pub const ROOM_LINES: usize = 8;

/// How far from the robot's centre the room's edges are weighed, m: beyond any path the
/// supervisor or an evasion looks along.
const ROOM_REACH: f64 = 0.5;

impl Context<'_> {
    /// The fastest a wheel goes on the path of `command`: no wheel goes faster than the
    /// fastest of its speed now and its command, m/s.
    fn fastest(&self, command: WheelSpeeds) -> f64 {
        [self.wheels[0], self.wheels[1], command.left, command.right].iter().fold(0.0f64, |m, v| m.max(v.abs()))
    }

    /// The step along a path whose wheels go no faster than `fastest`: [`STEP`], longer
    /// where a slow ramp makes the stop long (its travel is kept as slack, so a longer step
    /// is only more cautious).
    fn path_step(&self, fastest: f64) -> f64 {
        STEP.max((self.cfg.reaction_time + fastest / self.cfg.wheel_accel) / MAX_PATH_STEPS)
    }

    /// Whether `command` passes with [`ROBUSTNESS`] to spare, by the verdict of one beyond
    /// the ramp's reach like it if there was one.
    fn passes(&self, command: WheelSpeeds, beyond_ramp: &mut BeyondRamp) -> bool {
        let Some([left, right]) = beyond_ramp.sense(self, command) else {
            return self.first_driven_into(command, ROBUSTNESS).is_none();
        };
        *beyond_ramp.verdicts[left][right].get_or_insert_with(|| self.first_driven_into(command, ROBUSTNESS).is_none())
    }

    /// Whether a path braking from `position`, `s` seconds ahead, at centre speed `mean`
    /// along `facing` (a backing path gives its facing reversed and its speed's size) in
    /// steps of `h`, can no longer come within any hazard's reach: it travels at most
    /// `mean²/2a` and a step more, each check keeps a step's travel and `spare` more, it
    /// ends within `mean/a` and two steps (the last drop can leave a rounding's worth of
    /// speed for one more), and each obstacle comes at most its speed and growth
    /// meanwhile. Most braking tails end here, long before the robot stops.
    ///
    /// Or, hazard by hazard, the robot never again moves toward it: see
    /// [`Context::never_toward`], the brake holding its turn rate `turn_rate`.
    #[allow(clippy::too_many_arguments)]
    fn out_of_reach(
        &self,
        s: f64,
        position: Point,
        facing: Point,
        mean: f64,
        turn_rate: f64,
        h: f64,
        spare: f64,
    ) -> bool {
        let a = self.cfg.wheel_accel;
        let left = mean / a + 2.0 * h;
        let margin = mean * mean / (2.0 * a) + 2.0 * mean * h + spare;
        let turned = turn_rate.abs() * left;
        self.hazards.iter().all(|hz| {
            let far = match *hz {
                Hazard::Obstacle { center, velocity, speed, keep, growth, vehicle, .. } => {
                    let reach = keep + margin + growth * (s + left) + speed * left;
                    let ahead = center + velocity * s - position;
                    let from = center - position;
                    let nearest = if vehicle { nearest_between(from, ahead - from, (0.0, 1.0)) } else { ahead };
                    nearest.norm_sqr() > reach * reach
                }
                Hazard::Line { normal, offset, keep } => offset - dot(normal, position) > keep + margin,
            };
            far || never_toward(hz, s, position, facing, left, turned)
        })
    }

    /// Whether `command` would move the robot's centre toward an obstacle within
    /// [`EVASION_NEAR`] of its keep-out circle, or toward a lane line within
    /// [`EVASION_NEAR_WALL`]: an evasion only ever moves away from what is close, so an
    /// estimate a little off cannot turn it into driving into that obstacle or line.
    fn approaches_a_near_obstacle(&self, command: WheelSpeeds) -> bool {
        let velocity = self.facing * (0.5 * (command.left + command.right));
        let p = self.position;
        let near_edge = self.cfg.arena.is_some_and(|[x0, x1, y0, y1]| {
            (p.re - x0 < EVASION_NEAR_WALL && velocity.re < 0.0)
                || (x1 - p.re < EVASION_NEAR_WALL && velocity.re > 0.0)
                || (p.im - y0 < EVASION_NEAR_WALL && velocity.im < 0.0)
                || (y1 - p.im < EVASION_NEAR_WALL && velocity.im > 0.0)
        });
        near_edge
            || self.hazards.iter().any(|h| match *h {
                Hazard::Obstacle { center, keep, .. } => {
                    let offset = center - self.position;
                    offset.length() - keep < EVASION_NEAR && (velocity.conj() * offset).re > 0.0
                }
                Hazard::Line { normal, offset, keep } => {
                    offset - dot(normal, self.position) - keep < EVASION_NEAR_WALL && dot(normal, velocity) > 0.0
                }
            })
    }

    /// The least margin to any hazard (the gap beyond what the robot must keep from it) over
    /// [`EVASION_HORIZON`], the wheels ramping to `command` and holding it, each obstacle
    /// moving on at its estimated velocity, its keep-out growing with its uncertainty.
    ///
    /// Judged over each [`EVASION_STEP`] as a whole, not at its ends: the robot moves along
    /// the step's chord at the mean of its speeds at the step's ends (exact on a ramp), the
    /// obstacle along its course, and the gap is their closest approach within the step
    /// (the keep-out as grown by the step's end).
    ///
    /// Once the margin falls below `matters`, the rest of the way is not judged: what is
    /// returned is then below `matters`, not the least.
    fn least_margin_ahead(&self, command: WheelSpeeds, which: Ahead, horizon: f64, matters: f64) -> f64 {
        let a = self.cfg.wheel_accel * EVASION_STEP;
        let (mut wheels, mut position, mut facing) = (self.wheels, self.position, self.facing);
        let mut least = f64::INFINITY;
        let steps = (horizon / EVASION_STEP).round() as usize;
        // The turn a step is the same once both wheels are at the command: its half is
        // worked out again only when it changes.
        let mut halves: Option<(u64, Point)> = None;
        for k in 0..steps {
            if least < matters {
                break;
            }
            let (t, end) = (k as f64 * EVASION_STEP, (k + 1) as f64 * EVASION_STEP);
            let next = [ramp(wheels[0], command.left, a), ramp(wheels[1], command.right, a)];
            let speed = 0.25 * (wheels[0] + wheels[1] + next[0] + next[1]);
            let turn = 0.5 * ((wheels[1] - wheels[0]) + (next[1] - next[0])) / self.cfg.wheel_base * EVASION_STEP;
            // Along the chord: the heading half way through the step's turn.
            let half_turn = match halves {
                Some((bits, half)) if bits == turn.to_bits() => half,
                _ => halves.insert((turn.to_bits(), Point::from_polar(1.0, 0.5 * turn))).1,
            };
            let moved = facing * half_turn * (speed * EVASION_STEP);
            let arrived = position + moved;
            for h in self.hazards {
                let margin = match *h {
                    Hazard::Obstacle { speed, growth, .. } if which == Ahead::Moving && speed < STANDING + growth => {
                        continue
                    }
                    Hazard::Line { .. } if which == Ahead::Moving => continue,
                    Hazard::Obstacle { center, velocity, keep, growth, .. } => {
                        let from = position - (center + velocity * t);
                        closest_approach(from, moved - velocity * EVASION_STEP) - keep - growth * end
                    }
                    // Straight motion toward a line is nearest it at an end.
                    Hazard::Line { normal, offset, keep } => {
                        offset - dot(normal, position).max(dot(normal, arrived)) - keep
                    }
                };
                least = least.min(margin);
            }
            if let (Some([x0, x1, y0, y1]), Ahead::All) = (self.cfg.arena, which) {
                for p in [position, arrived] {
                    least = least.min((p.re - x0).min(x1 - p.re).min(p.im - y0).min(y1 - p.im));
                }
            }
            position = arrived;
            facing *= half_turn * half_turn;
            wheels = next;
        }
        least
    }

    /// Most cycles nothing is within reach. No wheel goes faster than the fastest of its
    /// speed now and its command (`fastest`), so the centre travels at most that for `τ`
    /// (and the step that crosses it), then `u²/2a` braking; a check keeps a step's travel
    /// more. The path ends by `τ + u/a` and three steps (the one crossing `τ`, the brake's
    /// last, part-filled one, and one more where that leaves a rounding's worth of speed:
    /// `stop`), and each obstacle comes at most its speed and growth meanwhile.
    fn nothing_within_reach(&self, fastest: f64, h: f64, stop: f64, spare: f64) -> bool {
        let (a, tau) = (self.cfg.wheel_accel, self.cfg.reaction_time);
        let reach = fastest * (tau + 2.0 * h) + fastest * fastest / (2.0 * a) + spare + fastest * h;
        let near = |hz: &Hazard| match *hz {
            Hazard::Obstacle { center, speed, keep, growth, .. } => {
                (center - self.position).length() <= keep + reach + (speed + growth) * stop
            }
            Hazard::Line { normal, offset, keep } => offset - dot(normal, self.position) <= keep + reach,
        };
        !self.hazards.iter().any(near)
    }

    /// Nor is anything driven into when the robot never moves toward it along the whole
    /// path, as long as the centre never reverses (each wheel ramps monotonically from its
    /// speed now to the command, so their slower ends summing to zero or more is enough).
    /// The turn rate is linear between the moments a wheel reaches its command (the ramp
    /// lasts until the step that crosses `τ` ends), so it is largest in size at one of them,
    /// and the brake holds the one it starts with.
    fn never_moves_toward(&self, target: [f64; 2], h: f64, stop: f64) -> bool {
        let (a, tau, base) = (self.cfg.wheel_accel, self.cfg.reaction_time, self.cfg.wheel_base);
        if self.wheels[0].min(target[0]) + self.wheels[1].min(target[1]) < 0.0 {
            return false;
        }
        let ramp_end = tau + h;
        let turn_rate_at = |t: f64| {
            let step = a * t.min(ramp_end);
            (ramp(self.wheels[1], target[1], step) - ramp(self.wheels[0], target[0], step)) / base
        };
        let reached = |k: usize| (target[k] - self.wheels[k]).abs() / a;
        let fastest_turn =
            [0.0, reached(0), reached(1), ramp_end].iter().fold(0.0f64, |m, &t| m.max(turn_rate_at(t).abs()));
        let turned = fastest_turn * stop;
        self.hazards.iter().all(|hz| never_toward(hz, 0.0, self.position, self.facing, stop, turned))
    }

    /// The first hazard `command` drives into along its path (see the module docs).
    fn first_driven_into(&self, command: WheelSpeeds, spare: f64) -> Option<Hazard> {
        self.first_driven_into_by(command, spare, Shortcuts::Taken)
    }

    /// As [`Context::first_driven_into`]; with [`Shortcuts::Untaken`], the whole path
    /// walked to the stop, which is what the shortcuts are tested against.
    fn first_driven_into_by(&self, command: WheelSpeeds, spare: f64, shortcuts: Shortcuts) -> Option<Hazard> {
        let taken = shortcuts == Shortcuts::Taken;
        let (a, tau, base) = (self.cfg.wheel_accel, self.cfg.reaction_time, self.cfg.wheel_base);
        // Most cycles nothing is within reach. No wheel goes faster than the fastest of its
        // speed now and its command (`u`), so the centre travels at most `u` for `τ` (and
        // the step that crosses it), then `u²/2a` braking; a check keeps a step's travel
        // more. The path ends by `τ + u/a` and three steps (the one crossing `τ`, the
        // brake's last, part-filled one, and one more where that leaves a rounding's worth
        // of speed), and each obstacle comes at most its speed and growth meanwhile.
        let fastest = self.fastest(command);
        let h = self.path_step(fastest);
        let stop = tau + fastest / a + 3.0 * h;
        let target = [command.left, command.right];
        if taken && (self.nothing_within_reach(fastest, h, stop, spare) || self.never_moves_toward(target, h, stop)) {
            return None;
        }
        let mut path = Path {
            position: self.position,
            facing: self.facing,
            wheels: self.wheels,
            s: 0.0,
            turning: (0.0, Point::new(1.0, 0.0), Point::new(1.0, 0.0)),
        };
        // Toward the command until τ (the step that crosses it included).
        if tau > 0.0 {
            while path.s < tau {
                let wheels = path.wheels;
                let next = [ramp(wheels[0], target[0], a * h), ramp(wheels[1], target[1], a * h)];
                let omega = 0.5 * (next[1] - next[0] + wheels[1] - wheels[0]) / base;
                if let Some(hit) = self.step(&mut path, next, omega, h, spare) {
                    return Some(hit);
                }
            }
            if path.speed() == 0.0 {
                return None; // at rest already (see below)
            }
        }
        // The way the centre moves as the brake starts: forward (1) or backing (-1). The
        // brake slows it either way, and either way it may drive into something.
        let sense = path.speed().signum();
        // Then the brake. It lowers both wheels alike, so it holds the turn rate it starts
        // with (taken once: the wheels' difference, recomputed, would wander by rounding and
        // cost a rotation every step).
        let braking_turn = (path.wheels[1] - path.wheels[0]) / base;
        // The brake stops the centre within `u/a` and a step or two (`h` is at least
        // 1/MAX_PATH_STEPS of that): a bound on the loop whatever the rounding does. A path
        // that were to outlast it is judged driven into its first hazard (a brake), not
        // passed.
        for k in 0..MAX_PATH_STEPS as usize + 4 {
            let mean = path.speed();
            // Asked every fourth step: it ends few of the walks it is asked of (around E1 and
            // E5) and costs about half a step, so asking every step cost more than the steps
            // it saved. Any step may ask: it only ends a walk that would pass.
            if taken
                && k % 4 == 0
                && self.out_of_reach(path.s, path.position, path.facing * sense, mean * sense, braking_turn, h, spare)
            {
                return None;
            }
            let drop = sense * (a * h).min((mean * sense).max(0.0));
            let next = [path.wheels[0] - drop, path.wheels[1] - drop];
            if let Some(hit) = self.step(&mut path, next, braking_turn, h, spare) {
                return Some(hit);
            }
            if path.speed() * sense <= 0.0 {
                // Stopped: the centre is at rest (the wheels may still turn it on the
                // spot), so it drives into nothing from here; the last step's check saw
                // what the obstacles close over it.
                return None;
            }
        }
        self.hazards.first().copied()
    }

    /// One step of `h` along the path, the wheels going to `next` and the robot turning
    /// at `omega`: the first hazard it drives into over the step, judged at its start.
    #[inline(always)]
    fn step(&self, path: &mut Path, next: [f64; 2], omega: f64, h: f64, spare: f64) -> Option<Hazard> {
        let (wheels, s, position, facing) = (path.wheels, path.s, path.position, path.facing);
        let v = 0.25 * (wheels[0] + next[0] + wheels[1] + next[1]);
        // One step's travel is kept beside the radii: the check runs at the step's ends.
        let slack = v.abs() * h + spare;
        let velocity = facing * v;
        // Backing up drives into what lies behind as driving on does into what lies ahead.
        if v != 0.0 {
            // The tolerance is for a stop's last sliver of speed: a steady or growing approach
            // on another vehicle keeps the stricter one.
            let slowing = (next[0] + next[1]).abs() < (wheels[0] + wheels[1]).abs();
            let (any, vehicle) = (self.cfg.approach_tolerance, self.cfg.vehicle_approach_tolerance);
            let hit = self.hazards.iter().find(|hz| {
                let tolerance = if !slowing && hz.is_vehicle() { vehicle } else { any };
                hz.driven_into(s, h, position, velocity, slack, tolerance)
            });
            if hit.is_some() {
                return hit.copied();
            }
        }
        if omega != path.turning.0 {
            let half = rotation(0.5 * omega * h);
            path.turning = (omega, half, half * half);
        }
        path.position += facing * path.turning.1 * (v * h);
        path.facing *= path.turning.2;
        path.wheels = next;
        path.s += h;
        None
    }
}

/// Where a verdict's path has come to, `s` seconds ahead.
struct Path {
    position: Point,
    /// The heading as a unit complex number, turned by each step's small rotation: no
    /// sine or cosine a step (a verdict can take a hundred steps).
    facing: Point,
    wheels: [f64; 2],
    s: f64,
    /// The last turn rate's half-step and step rotations: once the wheels reach the
    /// command, and all through the brake, the turn rate holds, and so do they.
    turning: (f64, Point, Point),
}

impl Path {
    /// The centre's speed now, m/s.
    fn speed(&self) -> f64 {
        0.5 * (self.wheels[0] + self.wheels[1])
    }
}

/// Whether a verdict may end early, where nothing is within reach or the robot never
/// moves toward anything: it must decide exactly as walking the whole path would.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Shortcuts {
    Taken,
    #[cfg_attr(not(test), allow(dead_code))]
    Untaken,
}

/// Whether a robot at `position` facing `facing`, `s` seconds ahead, moving forward (or
/// not at all) for at most `span` seconds more and turning by at most `turned` radians
/// meanwhile, never moves toward `hazard` (so can never drive into it, wherever it goes).
///
/// An obstacle: its offset `d` from the robot, dotted with the heading `f` at any later
/// moment, is at most `d·f₀ cos θ + |d × f₀| sin θ` (the turn `θ`, within `turned`) plus
/// the obstacle's own travel toward it (its speed times `span`); the robot's own travel
/// only lowers it while it turns by no more than a right angle, each bit of it within
/// `turned` of the heading then. Bounded with `cos θ ≥ 1 - θ²/2` and `sin θ ≤ θ`, and
/// required below a nanometre's worth short of zero, where rounding is some 1e-17 m. A lane
/// line: the heading's component across it, by the same bound.
fn never_toward(hazard: &Hazard, s: f64, position: Point, facing: Point, span: f64, turned: f64) -> bool {
    // Beyond a radian the robot's own travel may turn toward what it left behind.
    if turned > 1.0 {
        return false;
    }
    let shrink = 1.0 - 0.5 * turned * turned;
    // The largest `x cos θ + |y| sin θ` over |θ| ≤ `turned`, for `x`, `y` as given.
    let bound = |along: f64, across: f64| if along < 0.0 { along * shrink } else { along } + across.abs() * turned;
    const FUZZ: f64 = 1e-9;
    match *hazard {
        Hazard::Obstacle { center, velocity, speed, vehicle, .. } => {
            let bound_at = |d: Point| {
                let along = d.re * facing.re + d.im * facing.im;
                let across = d.im * facing.re - d.re * facing.im;
                bound(along, across)
            };
            // Another vehicle may stand anywhere on its way so far: the bound is convex in
            // the offset, so it is largest at one end of it.
            let ahead = bound_at(center + velocity * s - position);
            let worst = if vehicle { ahead.max(bound_at(center - position)) } else { ahead };
            worst + speed * span < -FUZZ
        }
        Hazard::Line { normal, .. } => {
            bound(dot(normal, facing), normal.re * facing.im - normal.im * facing.re) < -FUZZ
        }
    }
}

#[cfg(test)]
mod tests;
