use crate::planner::drive::{pulse_rates, wheel_speeds, DriveConfig, WheelSpeeds};
use crate::planner::{Plan, PlanInput, Planner, PlannerConfig, PlannerError};
use crate::track::Estimate;
use num_complex::Complex64 as C;

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
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControlConfig {
    pub planner: PlannerConfig,
    pub drive: DriveConfig,
    pub goal: C,
    /// The goal counts as reached within this distance, m.
    pub goal_tolerance: f64,
    pub robot_radius: f64,
    pub stall: StallConfig,
}

/// What the step decided.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StepStatus {
    Driving,
    AtGoal,
    Stalled,
    /// The planner refused the input: the robot is commanded to stop.
    Invalid(PlannerError),
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepOutput {
    pub status: StepStatus,
    pub plan: Option<Plan>,
    pub wheels: WheelSpeeds,
    /// Left and right pulse rates, pulses/s.
    pub pulses: [i32; 2],
}

impl StepOutput {
    fn stop(status: StepStatus, plan: Option<Plan>) -> Self {
        Self { status, plan, wheels: WheelSpeeds::default(), pulses: [0, 0] }
    }
}

/// The control step with the little state it keeps (stall detection).
#[derive(Debug, Clone)]
pub struct ControlStep {
    config: ControlConfig,
    planner: Planner,
    /// Where and when the robot last made progress.
    progress_anchor: Option<(f64, C)>,
}

impl ControlStep {
    pub fn new(config: ControlConfig) -> Self {
        Self { config, planner: Planner::new(config.planner), progress_anchor: None }
    }
    /// Drive to a new goal from the next step (progress is judged afresh).
    pub fn set_goal(&mut self, goal: C, tolerance: f64) {
        self.config.goal = goal;
        self.config.goal_tolerance = tolerance;
        self.progress_anchor = None;
    }

    pub fn config(&self) -> &ControlConfig {
        &self.config
    }
    pub fn planner(&self) -> &Planner {
        &self.planner
    }

    /// One control cycle at time `t`.
    pub fn step(&mut self, t: f64, estimate: &Estimate<'_>) -> StepOutput {
        let position = estimate.pose.position;
        if (position - self.config.goal).norm() <= self.config.goal_tolerance {
            return StepOutput::stop(StepStatus::AtGoal, None);
        }
        let input = PlanInput {
            position,
            goal: self.config.goal,
            robot_radius: self.config.robot_radius,
            obstacles: estimate.obstacles,
            delay: estimate.delay,
        };
        let plan = match self.planner.plan(&input) {
            Ok(plan) => plan,
            Err(e) => return StepOutput::stop(StepStatus::Invalid(e), None),
        };
        if self.stalled(t, position) {
            return StepOutput::stop(StepStatus::Stalled, Some(plan));
        }
        let wheels = wheel_speeds(plan.velocity, estimate.pose.heading, &self.config.drive);
        let pulses = pulse_rates(wheels, &self.config.drive);
        StepOutput { status: StepStatus::Driving, plan: Some(plan), wheels, pulses }
    }

    fn stalled(&mut self, t: f64, position: C) -> bool {
        match self.progress_anchor {
            Some((t0, p0)) if (position - p0).norm() < self.config.stall.min_progress => {
                t - t0 > self.config.stall.window
            }
            _ => {
                self.progress_anchor = Some((t, position));
                false
            }
        }
    }
}
