//! The planner: estimated obstacles and robot position in, a velocity command out.
//!
//! Pure and allocation-free: the same call serves the live gateway, the offline scenario
//! runner, replay and the benchmarks. The field itself is in [`field`]; the conversion of
//! the command to wheel speeds and pulse rates (eq. 30) in [`crate::control::drive`].
//!
//! On top of the field the planner adds what a real rig needs:
//! - **Planning radius** `R = a_0 + a_r` grown by a [`Margin`] rule for sensing delay
//!   (eq. 29: `R > R_0 + U_a Δt`), fixed, by factor, or from the measured delay.
//! - **Tie-break** for the symmetric configurations where the field alone deadlocks
//!   (robot, obstacle and goal collinear with the robot behind the obstacle: every term is
//!   real on that axis, so the robot stalls at the rear stagnation point or, if the
//!   obstacle comes at it, is pushed straight back). Rule, deterministic: when the robot
//!   lies within [`TieBreak::angle`] of the goal-obstacle axis on the far side, that
//!   obstacle's planning circle is shifted toward the robot's left by up to
//!   [`TieBreak::shift`]·R and grown by the same amount (so it still covers the true
//!   circle). The robot then passes keeping the obstacle on its left ("keep right"). The
//!   shift fades linearly to zero at the edge of the cone and never exceeds half the
//!   robot's current gap, so the field stays continuous and the robot is never placed
//!   inside a planning circle.
//! - **Uncertainty**: the planning radius grows further by
//!   [`PlannerConfig::uncertainty_sigmas`] standard deviations of the obstacle's predicted
//!   centre (the tracker's Kalman covariance at the moment the command acts), and by
//!   [`PlannerConfig::clearance`], the supervisor's margin.
//! - **No freeze inside a margin**: a robot that finds itself inside a planning circle but
//!   outside the true one gets that circle shrunk to just short of it (never below what
//!   covers the true circle), so the field keeps steering it instead of stopping it while
//!   an obstacle slides past; a goal inside a margin likewise, so a margin never makes a
//!   goal beside an obstacle unreachable. The safety supervisor guards what a shrunk
//!   margin gives up.
//! - **Saturation** to the robot's speed limit, keeping the direction.
//! - **Flags**: tie-break active, margin shrunk, command saturated. (Whether an obstacle
//!   outruns the robot is judged over time, with hysteresis, in the control step.)

pub mod field;
pub mod lane_series;
pub mod room;
pub mod space;

use std::sync::Arc;

use crate::Point;
use arrayvec::ArrayVec;
pub use field::{streamlines, Field, FieldError, PlanObstacle, Sink, MAX_OBSTACLES};
use room::Room;
pub use space::Space;

use crate::geometry::Length;

/// How the planning radius grows from `R_0 = a_0 + a_r`. The one margin type: the rig
/// config and scenario files deserialise into it (`margin = { rule = "factor", factor = 1.1 }`).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(tag = "rule", rename_all = "snake_case", deny_unknown_fields)]
pub enum Margin {
    /// `R = R_0`.
    #[default]
    None,
    /// `R = R_0 + metres`.
    Fixed { metres: f64 },
    /// `R = factor · R_0`.
    Factor { factor: f64 },
    /// `R = R_0 + (|V̂_k| + extra_speed) Δt` (eq. 29), `Δt` the measured sensing-to-actuation delay.
    Delay {
        #[serde(default)]
        extra_speed: f64,
    },
}

impl Margin {
    /// The planning radius for an obstacle of `r0 = a_0 + a_r` moving at `speed`.
    pub fn radius(self, r0: f64, speed: f64, delay: f64) -> f64 {
        match self {
            Margin::None => r0,
            Margin::Fixed { metres } => r0 + metres,
            Margin::Factor { factor } => r0 * factor,
            Margin::Delay { extra_speed } => r0 + (speed + extra_speed) * delay,
        }
    }
}

/// How far inside a shrunk planning circle's edge the robot stays, m (at most half its
/// gap to the true circle).
pub const SHRUNK_GAP: f64 = 0.001;

/// The symmetric-configuration tie-break (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TieBreak {
    /// Half-angle of the cone behind the obstacle where it acts, rad.
    pub angle: f64,
    /// Largest shift of the planning circle, as a fraction of its radius.
    pub shift: f64,
}

impl Default for TieBreak {
    fn default() -> Self {
        Self { angle: 12f64.to_radians(), shift: 0.15 }
    }
}

/// Planner settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlannerConfig {
    pub space: Space,
    /// Far-field speed of the goal sink, m/s: the sink strength is `m = cruise_speed · R_ref`.
    pub cruise_speed: f64,
    /// `c1` of `K(r)`, 1/m: near the goal the speed falls off as `m c1 r / R_ref`.
    pub c1: f64,
    /// `R_ref` of `K(r)`, m.
    pub reference_radius: f64,
    /// The robot's largest speed; commands are saturated to it, m/s.
    pub max_speed: f64,
    pub margin: Margin,
    /// Standard deviations of each obstacle's predicted centre added to its planning
    /// radius (the prediction's uncertainty, from the tracker's Kalman covariance).
    pub uncertainty_sigmas: f64,
    /// Added to every planning radius, m: the room the safety supervisor keeps beyond its
    /// own uncertainty allowance, and as much again, so the field steers the robot round
    /// the zone the supervisor guards instead of into it (where it would be slowed).
    pub clearance: f64,
    pub tie_break: Option<TieBreak>,
    /// Anticipation horizon in a lane, s (0: off): each moving obstacle is planned at the
    /// edge, on the robot's side, of the band its drift sweeps while the robot passes it,
    /// at most this far ahead (`anticipate` in this module). Not used in free space.
    pub anticipation: f64,
    /// What the lane's series aim at: their truncation error on each circle, relative to
    /// the flow there ([`Field::set_lane_aim`]). Not used in free space or a room.
    pub lane_residual: f64,
}

/// An obstacle as estimated by tracking, at the time the command will act.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObstacleEstimate {
    pub center: Point,
    pub velocity: Point,
    /// The obstacle's own radius `a_0`, m.
    pub radius: f64,
    /// One standard deviation of `center` along its worst direction, m (the tracker's
    /// Kalman covariance, predicted as far as the centre is).
    pub position_sd: f64,
    /// One standard deviation of `velocity` along its worst direction, m/s.
    pub velocity_sd: f64,
    /// Its velocity averaged over the last second or so, m/s: steadier than `velocity`,
    /// which follows each sample, and what a look seconds ahead goes by (anticipation).
    pub drift: Point,
    /// How fast the region it may occupy grows beyond `radius`, m/s: 0 for a tracked
    /// obstacle; the top obstacle speed for one unseen inside the view, whose `radius`
    /// is then how far it may have gone since it was last seen (a region, not a body).
    pub spread: f64,
    /// Room the planner keeps from it beyond the margin, m: a margin like the rest, given up
    /// (shrunk) rather than freeze the robot or cover its goal. A fleet's vehicles keep it
    /// between each other.
    pub keep: f64,
}

impl ObstacleEstimate {
    /// An obstacle known exactly (a scripted one, a test's).
    pub const fn exact(center: Point, velocity: Point, radius: f64) -> Self {
        Self { center, velocity, radius, position_sd: 0.0, velocity_sd: 0.0, drift: velocity, spread: 0.0, keep: 0.0 }
    }
}

/// Everything the planner needs for one command.
#[derive(Debug, Clone, Copy)]
pub struct PlanInput<'a> {
    pub position: Point,
    pub goal: Point,
    /// The robot's radius `a_r`, m.
    pub robot_radius: f64,
    pub obstacles: &'a [ObstacleEstimate],
    /// Measured sensing-to-actuation delay `Δt`, s (for [`Margin::Delay`]).
    pub delay: f64,
}

/// Facts about a command worth logging.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PlanFlags {
    /// The field's speed exceeded the limit and was scaled down.
    pub saturated: bool,
    /// The tie-break shifted at least one planning circle.
    pub tie_break: bool,
    /// The robot or the goal stood inside a planning circle's margin, which was shrunk
    /// toward the true circle to leave it just outside (rather than stopping there).
    pub margin_shrunk: bool,
    /// A circle reaching a lane wall was left unclosed (closing it would take in the robot
    /// or the goal), and its boundary is met less exactly (see [`Field::unclosed_at_a_wall`]).
    pub unclosed_at_a_wall: bool,
}

/// One planner result.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plan {
    /// The raw field velocity `u + i v`, m/s.
    pub field: Point,
    /// The command after saturation, m/s.
    pub velocity: Point,
    pub flags: PlanFlags,
}

/// A planner input it cannot give a command for. The caller stops the robot.
pub type PlannerError = FieldError;

/// The planner.
#[derive(Debug, Clone)]
pub struct Planner {
    config: PlannerConfig,
    /// The room's walls, static obstacles and view's edge, solved once ([`room::Room`]).
    room: Option<Arc<Room>>,
}

impl Planner {
    pub fn new(config: PlannerConfig) -> Self {
        Self { config, room: None }
    }
    /// A planner whose field keeps to `room`.
    pub fn in_room(config: PlannerConfig, room: Option<Arc<Room>>) -> Self {
        Self { config, room }
    }
    pub fn config(&self) -> &PlannerConfig {
        &self.config
    }
    pub fn room(&self) -> Option<&Arc<Room>> {
        self.room.as_ref()
    }

    /// The sink for a goal.
    pub fn sink(&self, goal: Point) -> Sink {
        let c = &self.config;
        Sink { goal, strength: c.cruise_speed * c.reference_radius, c1: c.c1, reference_radius: c.reference_radius }
    }

    /// The obstacles as planned into `out` (emptied first): margins and tie-break applied.
    pub fn plan_obstacles(
        &self,
        input: &PlanInput<'_>,
        out: &mut ArrayVec<PlanObstacle, MAX_OBSTACLES>,
    ) -> Result<PlanFlags, PlannerError> {
        out.clear();
        if input.obstacles.len() > MAX_OBSTACLES {
            return Err(FieldError::TooManyObstacles);
        }
        let mut flags = PlanFlags::default();
        let to_goal = input.goal - input.position;
        let left = if to_goal.length() > 0.0 { Point::i() * to_goal / to_goal.length() } else { Point::default() };
        // In free space the field's doublets already bend the robot round a crossing
        // obstacle, and planning it ahead of itself costs more than it saves (the crowd and
        // E6 sweeps); in a lane the side is everything.
        let horizon = if matches!(self.config.space, Space::Lane { .. }) { self.config.anticipation } else { 0.0 };
        for o in input.obstacles {
            let speed = o.velocity.length();
            let mut r0 = o.radius + input.robot_radius;
            if o.spread > 0.0 {
                // A region is where an unseen obstacle may be, not where it is: planned
                // around only as far as it leaves the robot and the goal outside (the
                // supervisor judges the whole region).
                let room = (input.position - o.center).length().min((input.goal - o.center).length()) - SHRUNK_GAP;
                r0 = r0.min(room.max(0.0));
            }
            let anticipation = anticipate(horizon, self.config.max_speed, input, o);
            let anticipated = o.center + anticipation.shift;
            let mut p = PlanObstacle {
                center: anticipated,
                velocity: o.velocity,
                radius: self.config.margin.radius(r0, speed, input.delay)
                    + self.config.uncertainty_sigmas * o.position_sd
                    + self.config.clearance
                    + o.keep,
            };
            if let Some(tb) = self.config.tie_break {
                let shift = tie_break_shift(&tb, input.position, input.goal, &p);
                if shift > 0.0 {
                    // Keep right, unless the obstacle's drift chose the left.
                    let away = if anticipation.pass_left { -left } else { left };
                    p.center += away * shift;
                    p.radius += shift;
                    flags.tie_break = true;
                }
            }
            // A margin never freezes the robot nor blocks the goal: a robot or a goal inside
            // the planning circle but outside the true one (the sum of the radii) gets the
            // circle shrunk to just short of it, never below what covers the true circle
            // (the supervisor guards what the margin gives up). Inside the true circle they
            // stay invalid: a robot there is in contact, a goal there cannot be reached.
            let cover = r0 + (p.center - anticipated).length();
            flags.margin_shrunk |= give_up_spacing_behind(&mut p, o.keep, cover, input.position, to_goal);
            for point in [input.position, input.goal] {
                let distance = (point - p.center).length();
                if distance <= p.radius && distance > cover {
                    p.radius = cover.max(distance - SHRUNK_GAP.min(0.5 * (distance - cover)));
                    flags.margin_shrunk = true;
                }
            }
            out.push(p);
        }
        Ok(flags)
    }

    /// The field for this input, as [`plan`](Self::plan) builds it (margins and tie-break
    /// applied, no circle closed over the robot); for plots and reports.
    pub fn field(&self, input: &PlanInput<'_>) -> Result<(Field, PlanFlags), PlannerError> {
        let mut field = Field::empty(self.config.space, self.sink(input.goal));
        let flags = self.build(input, &mut field)?;
        Ok((field, flags))
    }

    /// Build the field for this input into `field` (it is large in a lane: a control cycle
    /// builds into one rather than copying a new one out).
    fn build(&self, input: &PlanInput<'_>, field: &mut Field) -> Result<PlanFlags, PlannerError> {
        // Filled in place, never initialised beyond what is planned.
        let mut planned = ArrayVec::new();
        let mut flags = self.plan_obstacles(input, &mut planned)?;
        field.set_room(self.room.as_ref());
        field.set_lane_aim(self.config.lane_residual)?;
        field.rebuild_clear_of(self.config.space, self.sink(input.goal), &planned, Some(input.position))?;
        flags.unclosed_at_a_wall = field.unclosed_at_a_wall();
        Ok(flags)
    }

    /// The velocity command at the robot's position.
    pub fn plan(&self, input: &PlanInput<'_>) -> Result<Plan, PlannerError> {
        self.plan_in(input, &mut Field::empty(self.config.space, self.sink(input.goal)))
    }

    /// [`plan`](Self::plan), building the field into `field` (whatever it held): a control
    /// loop keeps one, rather than setting up a kilobyte of empty field every cycle.
    pub fn plan_in(&self, input: &PlanInput<'_>, field: &mut Field) -> Result<Plan, PlannerError> {
        let mut flags = self.build(input, field)?;
        let v = field.velocity(input.position)?;
        let speed = v.length();
        let velocity = if speed > self.config.max_speed {
            flags.saturated = true;
            v * (self.config.max_speed / speed)
        } else {
            v
        };
        Ok(Plan { field: v, velocity, flags })
    }
}

/// The cosine of the half-angle, round straight behind a vehicle, in which another's
/// spacing is given up: 60°, where the flow along a circle's edge is still sin 60° (0.87)
/// of its most; nearer the still point it falls to nothing.
const STILL_CONE_COS: f64 = 0.5;

/// A vehicle inside another vehicle's spacing (`keep`) with the other behind it, within
/// [`STILL_CONE_COS`]'s angle of straight away from its goal, gives the spacing up whole,
/// not shrunk to a millimetre short of itself: between a circle and the sink, where the
/// vehicle would hug the circle's edge, the flow along the edge stops (the circle's still
/// point facing the sink), and the vehicle would crawl off it for seconds. Leaving the
/// other behind, it needs no room from it; anywhere else round it, the flow slides the
/// vehicle along the edge and the spacing is shrunk as every margin is. Returns whether it
/// gave the spacing up.
fn give_up_spacing_behind(p: &mut PlanObstacle, keep: f64, cover: f64, position: Point, to_goal: Point) -> bool {
    let from_here = p.center - position;
    let (distance, way) = (from_here.length(), to_goal.length());
    let behind = from_here.re * to_goal.re + from_here.im * to_goal.im < -STILL_CONE_COS * distance * way;
    let inside = keep > 0.0 && behind && distance <= p.radius;
    if inside {
        p.radius = (p.radius - keep).max(cover);
    }
    inside
}

/// Where obstacle `o` is planned relative to its estimate, for a robot heading for the goal
/// at `speed`. Over the window in which the robot would be abreast of the obstacle (from the
/// moment their circles first overlap along the robot's way to when they last do, at most
/// `horizon` ahead), the obstacle's motion across that way sweeps a band; the robot passes
/// on the side of the band that asks the smaller sideways move of it, and the obstacle is
/// planned at the band's edge on that side. An obstacle drifting across the robot's way is
/// thus passed behind, on the side it leaves, and planned where it will be nearest the robot
/// while they pass. The shift is across the robot's way, never along it; it is nothing for an
/// obstacle beside or behind the robot, or one that would then cover the goal.
fn anticipate(horizon: f64, speed: f64, input: &PlanInput<'_>, o: &ObstacleEstimate) -> Anticipation {
    let to_goal = input.goal - input.position;
    let none = Anticipation { shift: Point::default(), pass_left: false };
    if horizon <= 0.0 || o.spread > 0.0 || to_goal.length() == 0.0 {
        return none;
    }
    let way = to_goal / to_goal.length();
    let left = Point::i() * way;
    let relative = o.center - input.position;
    let (ahead, aside) = ((relative * way.conj()).re, (relative * way.conj()).im);
    let (v_along, v_across) = ((o.drift * way.conj()).re, (o.drift * way.conj()).im);
    let reach = o.radius + input.robot_radius;
    let closing = speed - v_along;
    if closing <= 0.0 || ahead <= 0.0 {
        return none;
    }
    let first = ((ahead - reach) / closing).clamp(0.0, horizon);
    let last = ((ahead + reach) / closing).min(horizon);
    let (at_first, at_last) = (aside + v_across * first, aside + v_across * last);
    // Passing with the obstacle on the right asks the robot to get left of the band's
    // left edge; with it on the left, right of the band's right edge.
    let (left_edge, right_edge) = (at_first.max(at_last), at_first.min(at_last));
    let pass_left = left_edge + reach < reach - right_edge && left_edge - right_edge > SIDED_BAND;
    let planned = if pass_left { left_edge } else { right_edge };
    let shift = left * (planned - aside);
    if (input.goal - o.center - shift).length() <= reach {
        return none;
    }
    Anticipation { shift, pass_left }
}

/// What anticipation makes of one obstacle.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Anticipation {
    /// From its estimate to where it is planned, m.
    shift: Point,
    /// Its drift across the robot's way has the robot pass it on the left (its band is
    /// wider than [`SIDED_BAND`], and leaves the robot less to do on that side); the
    /// symmetric-case tie-break then breaks the tie toward the left too.
    pass_left: bool,
}

/// How wide an obstacle's band must be for its drift to choose the left side, m (below
/// it, the keep-right rule of the tie-break stands).
const SIDED_BAND: f64 = 0.01;

/// How far the tie-break shifts obstacle `o`'s planning circle for a robot at `z`.
fn tie_break_shift(tb: &TieBreak, z: Point, goal: Point, o: &PlanObstacle) -> f64 {
    let p = z - o.center; // robot, seen from the obstacle
    let g = goal - o.center; // goal, seen from the obstacle
    let (np, ng) = (p.length(), g.length());
    if np == 0.0 || ng == 0.0 {
        return 0.0;
    }
    let cos = (p * g.conj()).re / (np * ng);
    let sin = (p * g.conj()).im / (np * ng);
    // Behind the obstacle: the angle between p and -g is small.
    if cos >= 0.0 {
        return 0.0;
    }
    let angle = sin.abs().asin();
    let fade = 1.0 - angle / tb.angle;
    if fade <= 0.0 {
        return 0.0;
    }
    let gap = np - o.radius;
    (tb.shift * o.radius * fade).min(0.5 * gap.max(0.0))
}

#[cfg(test)]
mod tests;
