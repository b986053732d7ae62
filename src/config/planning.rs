//! `[robot]`, `[goal]`, `[planner]` and `[lane]`: the robot's body and what it plans for.

use super::checks::{invalid, non_negative, positive, Invalid, BODY, GAIN, SPEED};
use super::motors::DriveSection;
use crate::planner::Margin;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RobotSection {
    /// `a_r`, m.
    pub radius: f64,
    /// Speed limit of the robot's centre, m/s.
    pub max_speed: f64,
}

/// A goal: where, and how close counts as there (the rig config's `[goal]`, and each goal an
/// operator sets).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Goal {
    /// Floor coordinates, m.
    pub position: [f64; 2],
    /// m (default 0.02).
    #[serde(default = "default_tolerance")]
    pub tolerance: f64,
}

pub fn default_tolerance() -> f64 {
    0.02
}

/// The planner's settings: the `[planner]` section of rig configs and scenario files alike.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PlannerSection {
    /// Far-field speed of the goal sink, m/s (`m = cruise_speed · R_ref`).
    pub cruise_speed: f64,
    /// Goal smoothing factor `c1` of `K(r)`, 1/m.
    pub c1: f64,
    /// Steering gain `K_c` of eq. 30.
    pub kc: f64,
    /// Safety margin rule for the planning radius.
    #[serde(default)]
    pub margin: Margin,
    /// Standard deviations of each obstacle's predicted centre (its Kalman covariance at
    /// the moment the command acts) added to the planning radius; 0 plans on the estimate
    /// as if it were exact.
    #[serde(default = "default_uncertainty_sigmas")]
    pub uncertainty_sigmas: f64,
    /// Added to every planning radius, m: a margin for the safety supervisor, which keeps
    /// 3 mm beyond the radii and one standard deviation (the default is twice that, so the
    /// field steers the robot round the supervisor's zone rather than into it).
    #[serde(default = "default_clearance")]
    pub clearance: f64,
    /// How long the robot holds still while the goal is inside an obstacle's planning
    /// circle (an obstacle passing over it) before the run stops with `goal blocked`, s;
    /// 0 stops at once.
    #[serde(default = "default_goal_wait")]
    pub goal_wait: f64,
    /// The deterministic keep-right tie-break for symmetric configurations.
    #[serde(default = "default_true")]
    pub tie_break: bool,
    /// Delay compensation for the robot: dead-reckon its delayed pose forward with its own
    /// recent commands to the moment the command acts.
    #[serde(default = "default_true")]
    pub predict_robot: bool,
    /// Delay compensation for the obstacles: predict them with their Kalman filters to the
    /// moment the command acts. `false` reproduces the paper's E3, which planned on the
    /// delayed obstacle positions.
    #[serde(default = "default_true")]
    pub predict_obstacles: bool,
    /// Evasion: where the robot would be run into by a moving obstacle within a second,
    /// standing or holding its command, it takes the clear reachable command (reversing
    /// included) that gives up least, instead of slowing in the obstacle's way. It keeps the
    /// supervisor's promise. Unset: on, except in a lane, where passing on the side the
    /// obstacle leaves does better (docs/supervisor.md, "Evasion").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub evasion: Option<bool>,
    /// Anticipation in a lane, s (0: off): a moving obstacle is passed on the side its
    /// drift across the robot's way leaves, and planned where it will be nearest the robot
    /// while they pass, looking at most this far ahead (docs/planner.md). Not used in free
    /// space.
    #[serde(default = "default_anticipation")]
    pub anticipation: f64,
    /// In a lane: the boundary residual the obstacles' series aim at, relative to the flow
    /// on each circle, from 1e-10 to 1e-4 (docs/simulation.md, "How exact a rig's lane is"). A looser aim
    /// fits fewer orders, for a cheaper cycle.
    #[serde(default = "default_lane_residual")]
    pub lane_residual: f64,
    /// Where the robot's commands come from: `"field"`, the hydrodynamic field (the
    /// default); `"socket"`, a planner outside flowgate sending `drive` or `wheels` lines on
    /// the control socket; or `"ros2"`, one publishing `geometry_msgs/Twist` on
    /// `[ros2] cmd_vel` (docs/policies.md). Every command, whoever made it, goes through the
    /// safety supervisor.
    #[serde(default, skip_serializing_if = "PlannerMethod::is_field")]
    pub method: PlannerMethod,
    /// With an outside method: a command older than this when a cycle would drive on it
    /// stops the robot in order, and the stop holds until the operator's `start`, ms.
    #[serde(default = "default_command_max_age", skip_serializing_if = "is_default_command_max_age")]
    pub command_max_age_ms: u32,
}

/// `planner.method`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PlannerMethod {
    #[default]
    Field,
    Socket,
    Ros2,
    /// A baseline: straight at the goal at the cruise speed, turning toward it, the safety
    /// supervisor alone keeping the robot off what is in the way.
    Straight,
    /// A baseline: the robot as an ORCA agent among the obstacles as tracked and the room's
    /// walls (`control::orca`), the safety supervisor behind it.
    Orca,
    /// A baseline: the robot as a social-force pedestrian among the obstacles as tracked and
    /// the room's walls (`control::social_force`), the safety supervisor behind it.
    SocialForce,
}

impl PlannerMethod {
    fn is_field(&self) -> bool {
        *self == Self::Field
    }
}

pub(super) fn default_command_max_age() -> u32 {
    250
}

fn is_default_command_max_age(ms: &u32) -> bool {
    *ms == default_command_max_age()
}

/// The most and least `planner.command_max_age_ms` accepted.
const COMMAND_MAX_AGE_MS: std::ops::RangeInclusive<u32> = 20..=5000;

pub(super) fn default_true() -> bool {
    true
}

pub(super) fn default_uncertainty_sigmas() -> f64 {
    1.0
}

pub(super) fn default_clearance() -> f64 {
    0.006
}

pub(super) fn default_anticipation() -> f64 {
    3.0
}

pub(super) fn default_lane_residual() -> f64 {
    crate::planner::lane_series::LOOSEST_AIM
}

pub(super) fn default_goal_wait() -> f64 {
    10.0
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LaneSection {
    pub half_width: f64,
}

impl RobotSection {
    pub(super) fn validate(&self, drive: &DriveSection) -> Result<(), Invalid> {
        positive("robot.radius", self.radius, BODY)?;
        positive("robot.max_speed", self.max_speed, SPEED)?;
        // The centre moves at the mean of the wheels' rim speeds: never faster than they go.
        if self.max_speed > drive.max_wheel_speed {
            return invalid(
                "robot.max_speed",
                format!(
                    "{} m/s is above drive.max_wheel_speed = {} m/s: the wheels cannot carry the robot that fast",
                    self.max_speed, drive.max_wheel_speed
                ),
            );
        }
        Ok(())
    }
}

impl PlannerSection {
    /// The planner's rules, shared by rig configs and scenario files.
    pub fn validate(&self) -> Result<(), Invalid> {
        positive("planner.cruise_speed", self.cruise_speed, SPEED)?;
        positive("planner.c1", self.c1, GAIN)?;
        positive("planner.kc", self.kc, GAIN)?;
        if !(self.uncertainty_sigmas.is_finite() && (0.0..=10.0).contains(&self.uncertainty_sigmas)) {
            return invalid(
                "planner.uncertainty_sigmas",
                format!("must be from 0 to 10 standard deviations, is {}", self.uncertainty_sigmas),
            );
        }
        if !(self.clearance.is_finite() && (0.0..=0.1).contains(&self.clearance)) {
            return invalid("planner.clearance", format!("must be from 0 to 0.1 m, is {}", self.clearance));
        }
        if !(self.anticipation.is_finite() && (0.0..=30.0).contains(&self.anticipation)) {
            return invalid("planner.anticipation", format!("must be from 0 to 30 s, is {}", self.anticipation));
        }
        if !crate::planner::lane_series::aim_allowed(self.lane_residual) {
            return invalid(
                "planner.lane_residual",
                format!("must be from 1e-10 to 1e-4, is {:e}", self.lane_residual),
            );
        }
        if !COMMAND_MAX_AGE_MS.contains(&self.command_max_age_ms) {
            return invalid(
                "planner.command_max_age_ms",
                format!(
                    "must be from {} to {} ms, is {}",
                    COMMAND_MAX_AGE_MS.start(),
                    COMMAND_MAX_AGE_MS.end(),
                    self.command_max_age_ms
                ),
            );
        }
        if !(self.goal_wait.is_finite() && (0.0..=3600.0).contains(&self.goal_wait)) {
            return invalid("planner.goal_wait", format!("must be from 0 to 3600 s, is {}", self.goal_wait));
        }
        match self.margin {
            Margin::None => Ok(()),
            Margin::Fixed { metres } => non_negative("planner.margin.metres", metres, BODY),
            Margin::Factor { factor } if factor.is_finite() && factor >= 1.0 => Ok(()),
            Margin::Factor { factor } => invalid("planner.margin.factor", format!("must be >= 1, is {factor}")),
            Margin::Delay { extra_speed } => non_negative("planner.margin.extra_speed", extra_speed, SPEED),
        }
    }
}
