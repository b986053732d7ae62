//! One control cycle: the estimate in, the planner's velocity, the supervisor's verdict and
//! evasion, and the pulse rates out; with the stall and goal-occupied checks around them.

use super::baseline;
use super::orca::{self, OrcaRobot};
use super::outside::{CommandSource, OutsideCommand, OutsideCommands};
use super::social_force::SocialForceRobot;
use super::supervisor::{evade, supervise, Supervision, SupervisorConfig};
use crate::control::drive::{pulse_rates, wheel_speeds, DriveConfig, WheelSpeeds};
use crate::geometry::Length;
use flowgate_protocol::plane::orca::Body;
use std::sync::Arc;

use crate::planner::room::Room;
use crate::planner::{Field, ObstacleEstimate, Plan, PlanInput, Planner, PlannerConfig, PlannerError, MAX_OBSTACLES};
use crate::track::Estimate;
use crate::Point;

/// How fast the straight baseline turns toward the goal, rad/s a radian off it.
const STRAIGHT_TURN_GAIN: f64 = 3.0;

/// When the robot counts as stalled: it moved less than `min_progress` in `window` seconds
/// while away from the goal (a stagnation point, or a deadlock the field cannot resolve).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StallConfig {
    pub window: f64,
    pub min_progress: f64,
}

impl Default for StallConfig {
    fn default() -> Self {
        Self { window: 3.0, min_progress: 0.01 }
    }
}

/// Everything the control step is configured with.
#[derive(Debug, Clone, PartialEq)]
pub struct ControlConfig {
    pub planner: PlannerConfig,
    /// The room's walls, static obstacles and view's edge, solved once at load (the
    /// planner's field keeps to it, the supervisor keeps the robot off it).
    pub room: Option<Arc<Room>>,
    pub drive: DriveConfig,
    pub goal: Point,
    /// The goal counts as reached within this distance, m.
    pub goal_tolerance: f64,
    pub robot_radius: f64,
    pub stall: StallConfig,
    /// The safety supervisor between the planner and the wheels (always on a rig; `None`
    /// only in the lab's unsupervised comparisons).
    pub supervisor: Option<SupervisorConfig>,
    /// How long the robot holds still while the goal is inside an obstacle's planning
    /// circle before the run gives up on that goal, s (0: at once).
    pub goal_wait: f64,
    /// Evade where the robot would be run into ([`super::supervisor::evade`]).
    pub evasion: bool,
    /// The field, or a planner outside flowgate.
    pub source: CommandSource,
}

/// What the step decided.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StepStatus {
    Driving,
    AtGoal,
    Stalled,
    /// The goal is inside obstacle `index`'s planning circle (since `since`): there is no
    /// field to follow, and the robot is commanded to stop and wait for it to pass.
    GoalOccupied {
        index: usize,
        since: f64,
    },
    /// The goal has been occupied for longer than [`ControlConfig::goal_wait`]: give it up.
    GoalBlocked {
        index: usize,
    },
    /// The planner refused the input: the robot is commanded to stop.
    Invalid(PlannerError),
    /// Driven from outside, the latest command is older than the source's `max_age` (or
    /// none came since the start): the robot is commanded to stop.
    CommandStale,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepOutput {
    pub status: StepStatus,
    pub plan: Option<Plan>,
    /// What the safety supervisor did to the planner's command.
    pub supervision: Supervision,
    /// The wheel speeds the planner asked for, before the supervisor (`wheels`: what it
    /// passed).
    pub asked: WheelSpeeds,
    /// An outside command beyond the robot's limits was scaled down to them.
    pub saturated: bool,
    /// Some obstacle outruns what the robot can deliver: avoidance is not guaranteed
    /// (judged with hysteresis, see [`Envelope`]).
    pub outrun: bool,
    pub wheels: WheelSpeeds,
    /// Left and right pulse rates, pulses/s.
    pub pulses: [i32; 2],
}

impl StepOutput {
    fn stop(status: StepStatus, plan: Option<Plan>) -> Self {
        Self {
            status,
            plan,
            supervision: Supervision::Passed,
            asked: WheelSpeeds::default(),
            saturated: false,
            outrun: false,
            wheels: WheelSpeeds::default(),
            pulses: [0, 0],
        }
    }
}

/// Whether each obstacle outruns the robot: its tracked speed against the fastest the
/// robot can go (its speed limit, which the wheels' limit bounds: a config that asks more is
/// refused at load). An obstacle is flagged once its speed less one standard deviation
/// reaches that, and cleared once its speed plus one falls below it. So a noisy estimate of
/// a slower obstacle never raises it and one of a faster obstacle never drops it: it changes
/// only when the estimate says so with confidence.
#[derive(Debug, Clone, Copy)]
pub struct Envelope {
    outrun: [bool; MAX_OBSTACLES],
}

impl Default for Envelope {
    fn default() -> Self {
        Self { outrun: [false; MAX_OBSTACLES] }
    }
}

impl Envelope {
    /// Judge this cycle's estimates against the robot's `limit` (m/s): whether any obstacle
    /// now outruns it.
    pub fn update(&mut self, obstacles: &[ObstacleEstimate], limit: f64) -> bool {
        for (outrun, o) in self.outrun.iter_mut().zip(obstacles) {
            // Compared squared (no root a cycle): speed - sd >= limit is speed² >= (limit +
            // sd)², and speed + sd < limit is speed² < (limit - sd)² with limit > sd.
            let speed_sqr = o.velocity.norm_sqr();
            let (above, below) = (limit + o.velocity_sd, limit - o.velocity_sd);
            if speed_sqr >= above * above {
                *outrun = true;
            } else if below > 0.0 && speed_sqr < below * below {
                *outrun = false;
            }
        }
        self.outrun.iter().take(obstacles.len()).any(|&o| o)
    }
}

/// The control step with the little state it keeps (stall detection, the envelope flag).
#[derive(Debug, Clone)]
pub struct ControlStep {
    config: ControlConfig,
    planner: Planner,
    /// The field each cycle builds into (see [`Planner::plan_in`]).
    field: Field,
    /// Where and when the robot last made progress.
    progress_anchor: Option<(f64, Point)>,
    /// Since when the goal has been inside an obstacle's planning circle.
    goal_occupied_since: Option<f64>,
    envelope: Envelope,
    outside: OutsideCommands,
    /// Where the field heads instead of the goal ([`ControlStep::aim_at`]).
    aim: Option<Point>,
    /// The ORCA baseline's room and buffers (empty unless it drives).
    orca: OrcaRobot,
    /// The social-force baseline's room (empty unless it drives).
    social_force: SocialForceRobot,
}

impl ControlStep {
    pub fn new(config: ControlConfig) -> Self {
        let planner = Planner::in_room(config.planner, config.room.clone());
        let mut field = Field::empty(config.planner.space, planner.sink(config.goal));
        // The room's buffers are made here, not in the first cycle.
        field.set_room(config.room.as_ref());
        Self {
            planner,
            field,
            progress_anchor: None,
            goal_occupied_since: None,
            envelope: Envelope::default(),
            outside: OutsideCommands::default(),
            aim: None,
            orca: match config.source {
                CommandSource::Orca => OrcaRobot::new(config.room.as_deref(), config.planner.space),
                _ => OrcaRobot::default(),
            },
            social_force: match config.source {
                CommandSource::SocialForce => SocialForceRobot::new(config.room.as_deref(), config.planner.space),
                _ => SocialForceRobot::default(),
            },
            config,
        }
    }

    /// An outside planner's command, taken at `t` (driven on only with
    /// [`CommandSource::Outside`]).
    pub fn take_command(&mut self, t: f64, command: OutsideCommand) {
        self.outside.take(t, command);
    }

    /// Driving starts at `t` (the operator's `start`): an outside planner has its
    /// `max_age` from now to send its first command.
    pub fn start(&mut self, t: f64) {
        self.outside.start(t);
        self.progress_anchor = None;
    }
    /// Let the field head for `aim` instead of the goal (`None`: the goal again): a fleet's
    /// vehicle whose goal another vehicle still stands on. Reaching the goal is still what
    /// ends the drive.
    pub fn aim_at(&mut self, aim: Option<Point>) {
        self.aim = aim;
    }

    /// Where the field heads instead of the goal, if anywhere ([`ControlStep::aim_at`]).
    pub fn aim(&self) -> Option<Point> {
        self.aim
    }

    /// Drive to a new goal from the next step (progress is judged afresh).
    pub fn set_goal(&mut self, goal: Point, tolerance: f64) {
        self.config.goal = goal;
        self.config.goal_tolerance = tolerance;
        self.progress_anchor = None;
        self.goal_occupied_since = None;
    }

    pub fn config(&self) -> &ControlConfig {
        &self.config
    }
    pub fn planner(&self) -> &Planner {
        &self.planner
    }

    /// One control cycle at time `t`.
    pub fn step(&mut self, t: f64, estimate: &Estimate<'_>) -> StepOutput {
        let limit = self.config.planner.max_speed.min(self.config.drive.max_wheel_speed);
        let outrun = self.envelope.update(estimate.predicted, limit);
        StepOutput { outrun, ..self.decide(t, estimate, outrun) }
    }

    /// The work of [`step`](Self::step) on `estimate` (the plan, the wheel speeds, the
    /// supervisor's check), its result discarded and no state changed: the field it builds
    /// into is the step's scratch, which every plan rebuilds from nothing. Run just before a
    /// frame is due, it brings the step's code and data into cache.
    pub fn rehearse(&mut self, estimate: &Estimate<'_>) {
        let input = PlanInput {
            position: estimate.position,
            goal: self.aim.unwrap_or(self.config.goal),
            robot_radius: self.config.robot_radius,
            obstacles: estimate.obstacles,
            delay: estimate.delay,
        };
        if let Ok(plan) = self.planner.plan_in(&input, &mut self.field) {
            let proposed = wheel_speeds(plan.velocity, estimate.facing, &self.config.drive);
            if let Some(cfg) = &self.config.supervisor {
                std::hint::black_box(supervise(cfg, estimate, proposed));
            }
        }
    }

    fn decide(&mut self, t: f64, estimate: &Estimate<'_>, outrun: bool) -> StepOutput {
        let position = estimate.position;
        if (position - self.config.goal).length() <= self.config.goal_tolerance {
            return StepOutput::stop(StepStatus::AtGoal, None);
        }
        match self.config.source {
            CommandSource::Outside { max_age } => return self.drive_outside(t, estimate, outrun, max_age),
            CommandSource::Straight => return self.drive_straight(t, estimate, outrun),
            CommandSource::Orca | CommandSource::SocialForce => return self.drive_reactive(t, estimate, outrun),
            CommandSource::Field => {}
        }
        let input = PlanInput {
            position,
            goal: self.aim.unwrap_or(self.config.goal),
            robot_radius: self.config.robot_radius,
            obstacles: estimate.obstacles,
            delay: estimate.delay,
        };
        let plan = match self.planner.plan_in(&input, &mut self.field) {
            Ok(plan) => plan,
            Err(PlannerError::GoalInsideObstacle { index }) => {
                // A passing obstacle over the goal: hold still until it has gone, rather
                // than end the run. Waiting is not a stall: progress is judged afresh after.
                self.progress_anchor = None;
                let since = *self.goal_occupied_since.get_or_insert(t);
                let status = if t - since >= self.config.goal_wait {
                    StepStatus::GoalBlocked { index }
                } else {
                    StepStatus::GoalOccupied { index, since }
                };
                return StepOutput::stop(status, None);
            }
            Err(e) => return StepOutput::stop(StepStatus::Invalid(e), None),
        };
        self.goal_occupied_since = None;
        if self.stalled(t, position) {
            return StepOutput::stop(StepStatus::Stalled, Some(plan));
        }
        let proposed = wheel_speeds(plan.velocity, estimate.facing, &self.config.drive);
        self.driving(estimate, proposed, outrun, Some(plan), false)
    }

    /// The outside planner's latest command, within the robot's limits and supervised.
    fn drive_outside(&mut self, t: f64, estimate: &Estimate<'_>, outrun: bool, max_age: f64) -> StepOutput {
        let Some(command) = self.outside.current(t, max_age) else {
            return StepOutput::stop(StepStatus::CommandStale, None);
        };
        let (asked, saturated) = command.wheels(&self.config.drive, self.config.planner.max_speed);
        self.driving(estimate, asked, outrun, None, saturated)
    }

    /// The baseline: at the cruise speed straight for the goal, turning toward it (forward
    /// only within a quarter turn of it), supervised as the field's commands are.
    fn drive_straight(&mut self, t: f64, estimate: &Estimate<'_>, outrun: bool) -> StepOutput {
        if self.stalled(t, estimate.position) {
            return StepOutput::stop(StepStatus::Stalled, None);
        }
        let off = ((self.config.goal - estimate.position) * estimate.facing.conj()).arg();
        let v = self.config.planner.cruise_speed * off.cos().max(0.0);
        let w = STRAIGHT_TURN_GAIN * off;
        // Scaled to the limits as an outside command is (not counted as one).
        let (asked, _) = OutsideCommand::Twist { v, w }.wheels(&self.config.drive, self.config.planner.max_speed);
        self.driving(estimate, asked, outrun, None, false)
    }

    /// A reactive baseline (ORCA, or social force): the velocity it picks towards the goal
    /// at the cruise speed, steered to as the straight baseline steers (forward only within
    /// a quarter turn of it), supervised as the field's commands are.
    fn drive_reactive(&mut self, t: f64, estimate: &Estimate<'_>, outrun: bool) -> StepOutput {
        if self.stalled(t, estimate.position) {
            return StepOutput::stop(StepStatus::Stalled, None);
        }
        let (p, step) = (&self.config.planner, self.config.drive.sample_time);
        let moving = estimate.facing * ((estimate.wheels[0] + estimate.wheels[1]) / 2.0);
        let me = Body { position: estimate.position, velocity: moving, radius: self.config.robot_radius };
        let preferred = baseline::preferred(estimate.position, self.config.goal, p.cruise_speed, step);
        let want = if self.config.source == CommandSource::SocialForce {
            self.social_force.velocity(me, preferred, p.cruise_speed, p.max_speed, estimate.obstacles, step)
        } else {
            let horizon = orca::HORIZON_RADII * self.config.robot_radius / p.cruise_speed;
            self.orca.velocity(me, preferred, p.max_speed, estimate.obstacles, horizon, step)
        };
        let off = (want * estimate.facing.conj()).arg();
        let v = want.length() * off.cos().max(0.0);
        let (asked, _) =
            OutsideCommand::Twist { v, w: STRAIGHT_TURN_GAIN * off }.wheels(&self.config.drive, p.max_speed);
        self.driving(estimate, asked, outrun, None, false)
    }

    /// Drive on what was `asked` (the field's `plan`'s wheels, or a command's, `saturated`
    /// when it was scaled to the limits): what the supervisor passes of it, as pulse rates.
    fn driving(
        &self,
        estimate: &Estimate<'_>,
        asked: WheelSpeeds,
        outrun: bool,
        plan: Option<Plan>,
        saturated: bool,
    ) -> StepOutput {
        let (wheels, supervision) = self.supervised(estimate, asked, outrun);
        let pulses = pulse_rates(wheels, &self.config.drive);
        StepOutput { status: StepStatus::Driving, plan, supervision, asked, saturated, outrun: false, wheels, pulses }
    }

    /// What the supervisor (and evasion, where on) passes of `proposed`.
    fn supervised(&self, estimate: &Estimate<'_>, proposed: WheelSpeeds, outrun: bool) -> (WheelSpeeds, Supervision) {
        match &self.config.supervisor {
            Some(cfg) => {
                let (chosen, verdict) = supervise(cfg, estimate, proposed);
                let hazard = match verdict {
                    Supervision::Slowed { hazard } | Supervision::Braking { hazard } => Some(hazard),
                    Supervision::Passed => Some(None),
                    Supervision::Evaded { .. } => None,
                };
                // Against an obstacle that outruns the robot, running from it cannot work: the
                // field's way round is the better bet.
                let hazard = hazard.filter(|_| self.config.evasion && !outrun);
                // Evasion's wheels stay within the robot's speed limit, as the planner's do.
                let max_wheel = self.config.planner.max_speed.min(self.config.drive.max_wheel_speed);
                match hazard.and_then(|h| evade(cfg, estimate, proposed, chosen, max_wheel).map(|e| (e, h))) {
                    Some((evasive, hazard)) => (evasive.wheels, Supervision::Evaded { hazard }),
                    None => (chosen, verdict),
                }
            }
            None => (proposed, Supervision::Passed),
        }
    }

    fn stalled(&mut self, t: f64, position: Point) -> bool {
        match self.progress_anchor {
            Some((t0, p0)) if (position - p0).length() < self.config.stall.min_progress => {
                t - t0 > self.config.stall.window
            }
            _ => {
                self.progress_anchor = Some((t, position));
                false
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obstacle(speed: f64, sd: f64) -> ObstacleEstimate {
        ObstacleEstimate { velocity_sd: sd, ..ObstacleEstimate::exact(Point::default(), Point::new(speed, 0.0), 0.07) }
    }

    /// The envelope flag follows the estimate's confidence, not its noise: an obstacle at
    /// 6-7 cm/s whose estimate wanders by its 3.7 cm/s deviation never raises it against a
    /// 15 cm/s robot; a 20 cm/s one raises it once and keeps it through the same noise;
    /// it drops only once the obstacle is slower with confidence.
    #[test]
    fn the_envelope_flag_has_hysteresis() {
        let limit = 0.15;
        let mut e = Envelope::default();
        let wander = [0.0, 0.03, -0.03, 0.037, -0.02, 0.036];
        assert!(wander.iter().all(|w| !e.update(&[obstacle(0.065 + w, 0.037)], limit)));
        // The old rule (the speed alone against the limit) fires on it.
        assert!(wander.iter().any(|w| 0.065 + w + 0.05 >= limit), "a noisier estimate would have crossed");
        let mut e = Envelope::default();
        let flags: Vec<bool> =
            [0.20, 0.17, 0.14, 0.16, 0.13, 0.19].iter().map(|&v| e.update(&[obstacle(v, 0.037)], limit)).collect();
        // Raised at 0.20 (0.20 - 0.037 >= 0.15), held while 0.13 + 0.037 is not below 0.15.
        assert_eq!(flags, [true; 6]);
        assert!(!e.update(&[obstacle(0.10, 0.037)], limit), "cleared: 0.10 + 0.037 < 0.15");
        // An uncertain estimate (a filter just started, 0.5 m/s) decides nothing either way.
        assert!(!Envelope::default().update(&[obstacle(0.3, 0.5)], limit));
        let mut held = Envelope::default();
        assert!(held.update(&[obstacle(0.3, 0.01)], limit));
        assert!(held.update(&[obstacle(0.0, 0.5)], limit));
        // Which obstacle: the second of two.
        assert!(Envelope::default().update(&[obstacle(0.05, 0.01), obstacle(0.2, 0.01)], limit));
    }
}
