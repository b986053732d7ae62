//! The planner-only scenario runner: the control step in closed loop with the simulator's
//! world, in virtual time, with the rig's sensing chain modelled between them (a pure
//! delay, position noise on each LED, a low-pass filter) and the gateway's own
//! [`Tracker`] (Kalman filters, delay compensation). Faster than the full stack
//! ([`super::virtual_rig`]), which runs the gateway core through the firmware and the wire
//! protocols; outcomes of both are judged by the world's truth.

use std::collections::VecDeque;
use std::time::Instant;

use crate::Point;
use flowgate_sim::world::{Contact, World};
use hdrhistogram::Histogram;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;

pub use super::Outcome;
use super::Scenario;
use crate::control::{ControlStep, StepOutput, StepStatus, Supervision};
use crate::gateway::core::{State, StopReason};
use crate::planner::MAX_OBSTACLES;
use crate::track::{KalmanConfig, LedGeometry, LowPass, Pose, Tracker};

/// Which runner: the whole stack (the gateway core through the firmware and the wire
/// protocols, [`super::virtual_rig`]) or the planner alone against a modelled sensing chain.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    FullStack,
    PlannerOnly,
}

impl std::fmt::Display for Mode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Mode::FullStack => "full stack",
            Mode::PlannerOnly => "planner only",
        })
    }
}

/// What a sweep keeps of one episode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpisodeResult {
    pub outcome: Outcome,
    /// Smallest true clearance to an obstacle, m.
    pub min_obstacle_clearance: Option<f64>,
    /// Smallest true clearance to a wall or static obstacle, m.
    pub min_wall_clearance: Option<f64>,
    pub contact: Option<Contact>,
    /// When it ended, s.
    pub duration: f64,
    pub path_length: f64,
    /// The share of the run a person was within [`DISCOMFORT_RADII`] of the robot.
    pub discomfort: f64,
}

/// Nearer the robot's footprint than this many of its radii, a person is uncomfortable:
/// CrowdNav's 0.2 m for its 0.3 m robot, scaled.
pub const DISCOMFORT_RADII: f64 = 0.2 / 0.3;

impl Mode {
    /// One episode, in this mode.
    pub fn episode(self, s: &Scenario) -> EpisodeResult {
        match self {
            Mode::PlannerOnly => {
                let r = run_with(s, Keep::Outcome).summary;
                EpisodeResult {
                    outcome: r.outcome,
                    min_obstacle_clearance: r.min_obstacle_clearance,
                    min_wall_clearance: r.min_wall_clearance,
                    contact: r.contact,
                    duration: r.end_time,
                    path_length: r.path_length,
                    discomfort: r.discomfort,
                }
            }
            Mode::FullStack => {
                let options = super::virtual_rig::Options { stop_at_contact: true, ..Default::default() };
                EpisodeResult::of(s, &super::virtual_rig::run(s, options))
            }
        }
    }
}

impl EpisodeResult {
    /// A whole-stack run's result, of scenario `s`.
    pub fn of(s: &Scenario, e: &super::virtual_rig::VirtualRun) -> Self {
        let t = &e.truth.summary;
        Self {
            outcome: e.outcome,
            min_obstacle_clearance: t.min_obstacle_clearance,
            min_wall_clearance: t.min_wall_clearance,
            contact: t.contact,
            duration: t.duration,
            path_length: t.path_length,
            discomfort: discomfort(s, &e.truth.samples),
        }
    }
}

/// The share of the world's `samples` in which a person was within [`DISCOMFORT_RADII`] of
/// the robot of `s`.
fn discomfort(s: &Scenario, samples: &[flowgate_sim::truth::TruthSample]) -> f64 {
    let gap = DISCOMFORT_RADII * s.robot.radius;
    let near = samples.iter().filter(|x| x.min_clearance.is_some_and(|c| c < gap)).count();
    near as f64 / samples.len().max(1) as f64
}

impl Run {
    /// A full-stack episode as a run for the plots and the table, from the world's truth.
    pub fn from_episode(s: &Scenario, e: &super::virtual_rig::VirtualRun) -> Self {
        let t = &e.truth.summary;
        let straight = (s.goal() - s.robot_start()).norm();
        let trace: Vec<TraceRow> = e
            .truth
            .samples
            .iter()
            .map(|x| TraceRow {
                t: x.t,
                pose: Pose { position: Point::new(x.x, x.y), heading: x.heading },
                command: Point::default(),
                speed: 0.5 * (x.wheel_speeds[0] + x.wheel_speeds[1]),
                obstacles: x.obstacles.iter().map(|o| Point::new(o[0], o[1])).collect(),
            })
            .collect();
        let summary = Summary {
            scenario: s.name.clone(),
            outcome: e.outcome,
            end_time: t.duration,
            time_to_goal: e
                .report
                .transitions
                .iter()
                .find(|(_, st)| *st == State::Stopping(StopReason::GoalReached))
                .map(|(at, _)| *at)
                .filter(|_| e.outcome == Outcome::Goal),
            min_obstacle_clearance: t.min_obstacle_clearance,
            min_wall_clearance: t.min_wall_clearance,
            first_contact: t.first_contact,
            contact: t.contact,
            path_length: t.path_length,
            path_length_ratio: if straight > 0.0 { t.path_length / straight } else { 0.0 },
            discomfort: discomfort(s, &e.truth.samples),
            peak_wheel_speed: t.peak_wheel_speed,
            planner_compute: ComputeTime { p50_us: 0.0, p99_us: 0.0, max_us: 0.0 },
            cycles: e.report.counters.cycles,
            invalid_cycles: e.report.counters.planner_invalid,
            supervisor_slowed_cycles: e.report.counters.supervisor_slowed,
            supervisor_braking_cycles: e.report.counters.supervisor_braking,
            supervisor_evaded_cycles: e.report.counters.supervisor_evaded,
            goal_occupied_cycles: e.report.counters.goal_occupied,
            saturated_cycles: e.report.counters.planner_saturated,
            tie_break_cycles: e.report.counters.planner_tie_break,
            margin_shrunk_cycles: e.report.counters.planner_margin_shrunk,
            unclosed_at_a_wall_cycles: e.report.counters.planner_unclosed_at_a_wall,
            obstacle_faster_than_robot: e.report.counters.obstacle_outran_robot > 0,
            stop_reason: match &e.setup_error {
                Some(error) => Some(format!("PSD controller setup failed: {error}")),
                None => e.report.stop_reason.map(|_| e.report.final_state.to_string()),
            },
        };
        Run { summary, trace, cost: CycleCost::default() }
    }
}

/// Percentiles of the planner's compute time per cycle, µs.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ComputeTime {
    pub p50_us: f64,
    pub p99_us: f64,
    pub max_us: f64,
}

/// The result of one run (`summary.json`).
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub scenario: String,
    pub outcome: Outcome,
    /// Simulated time at the end of the run, s.
    pub end_time: f64,
    pub time_to_goal: Option<f64>,
    /// Smallest gap between the robot's and an obstacle's true footprints, m (None: no obstacles).
    pub min_obstacle_clearance: Option<f64>,
    /// Smallest gap between the robot's footprint and a wall, m (None: free space).
    pub min_wall_clearance: Option<f64>,
    pub first_contact: Option<f64>,
    /// The first contact: what was touched, the robot's speed toward it, and whether it drove
    /// into it (`active`: above 1 cm/s toward it) or was hit (stopped or moving away).
    pub contact: Option<Contact>,
    pub path_length: f64,
    /// Path length over the straight start-goal distance.
    pub path_length_ratio: f64,
    /// The share of the run a person was within [`DISCOMFORT_RADII`] of the robot's radius
    /// of its footprint (of the control cycles; of the world's samples through the whole
    /// stack).
    pub discomfort: f64,
    /// Largest wheel rim speeds, m/s: left, right.
    pub peak_wheel_speed: [f64; 2],
    pub planner_compute: ComputeTime,
    pub cycles: u64,
    /// Cycles in which the planner refused its input and the robot was stopped.
    pub invalid_cycles: u64,
    /// Cycles whose command the safety supervisor slowed.
    pub supervisor_slowed_cycles: u64,
    /// Cycles in which the supervisor braked, no slower command keeping its promise.
    pub supervisor_braking_cycles: u64,
    /// Cycles in which the robot evaded instead of slowing or braking in an obstacle's way.
    #[serde(default)]
    pub supervisor_evaded_cycles: u64,
    /// Cycles the robot held still while the goal was inside an obstacle's planning circle.
    pub goal_occupied_cycles: u64,
    pub saturated_cycles: u64,
    pub tie_break_cycles: u64,
    /// Cycles in which the robot or the goal was inside an obstacle's planning circle (its
    /// margin) but outside the true one, and the circle was shrunk to just short of it
    /// rather than freeze the robot (the supervisor guards what the margin gave up).
    pub margin_shrunk_cycles: u64,
    /// Cycles whose field left a circle reaching a lane wall unclosed (closing it would
    /// take in the robot or the goal), meeting its boundary less exactly.
    pub unclosed_at_a_wall_cycles: u64,
    /// Some obstacle outran what the robot can deliver at some point of the run (judged
    /// with hysteresis on its tracked speed): no guarantee.
    pub obstacle_faster_than_robot: bool,
    /// Why the gateway stopped, as its state says it (`fault: robot pose lost`), in a
    /// full-stack run; none in a planner-only run, which has no gateway.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stop_reason: Option<String>,
}

/// One cycle of a recorded run, for the plots.
#[derive(Debug, Clone)]
pub struct TraceRow {
    pub t: f64,
    pub pose: Pose,
    /// Commanded velocity (saturated), m/s.
    pub command: Point,
    /// Realised speed of the robot's centre, m/s.
    pub speed: f64,
    pub obstacles: Vec<Point>,
}

/// A finished run.
#[derive(Debug, Clone)]
pub struct Run {
    pub summary: Summary,
    pub trace: Vec<TraceRow>,
    /// Where its cycles' time went (zero unless timed: [`run`]).
    pub cost: CycleCost,
}

/// Where a timed planner-only run's time went, ns in all, on the host clock (each stage's
/// figure includes one clock read, some 25 ns): what a sweep's episode costs, by stage.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CycleCost {
    /// The sensing model (delay, noise, filters) and the tracker (Kalman filters, dead
    /// reckoning, the estimate).
    pub sense_and_track_ns: u64,
    /// The control step: the planner, the wheel speeds and the supervisor.
    pub control_ns: u64,
    /// The simulator's world: settling at each command (the way since the last integrated
    /// and judged for contact and clearance), and the check for a contact. The robot taken
    /// for the sensing counts there.
    pub world_ns: u64,
}

/// The LEDs on the simulated robot: half its radius ahead of and behind its centre.
pub fn led_geometry(s: &Scenario) -> LedGeometry {
    LedGeometry { front: 0.5 * s.robot.radius, rear: 0.5 * s.robot.radius }
}

impl From<flowgate_sim::world::Pose> for Pose {
    fn from(p: flowgate_sim::world::Pose) -> Self {
        Pose { position: p.position, heading: p.heading }
    }
}

/// The simulated sensing chain: what the gateway would see of the world.
struct Sensor {
    delay: f64,
    noise: Option<Normal<f64>>,
    rng: ChaCha8Rng,
    leds: LedGeometry,
    led_filters: [LowPass; 2],
    obstacle_filters: Vec<LowPass>,
    /// The robot's true centre and heading (a unit vector) over the last `delay` seconds.
    history: VecDeque<(f64, Point, Point)>,
}

impl Sensor {
    fn new(s: &Scenario) -> Self {
        let hz = s.sensing.lowpass_hz;
        Self {
            delay: s.sensing.delay,
            noise: (s.sensing.position_noise > 0.0).then(|| Normal::new(0.0, s.sensing.position_noise).unwrap()),
            rng: ChaCha8Rng::seed_from_u64(s.sensing.seed),
            leds: led_geometry(s),
            led_filters: [LowPass::new(hz), LowPass::new(hz)],
            obstacle_filters: s.obstacles.iter().map(|_| LowPass::new(hz)).collect(),
            history: VecDeque::with_capacity((s.sensing.delay / s.sensing.sample_time).ceil() as usize + 4),
        }
    }

    fn noisy(&mut self, p: Point) -> Point {
        match self.noise {
            Some(n) => p + Point::new(n.sample(&mut self.rng), n.sample(&mut self.rng)),
            None => p,
        }
    }

    /// Measure at world time `t`: the robot's LEDs and the obstacle centres as they were at
    /// `t - delay`, noisy and filtered. Returns the time of validity and the LEDs.
    fn measure(&mut self, world: &World, dt: f64, obstacles: &mut [Point]) -> (f64, Point, Point) {
        let t = world.time();
        self.history.push_back((t, world.pose().position, world.facing()));
        let t_valid = (t - self.delay).max(0.0);
        while self.history.len() > 1 && self.history[1].0 <= t_valid + 1e-9 {
            self.history.pop_front();
        }
        let (_, position, facing) = self.history[0];
        let (front, rear) = self.leds.leds(position, facing);
        let (front, rear) = (self.noisy(front), self.noisy(rear));
        let front = self.led_filters[0].filter(front, dt);
        let rear = self.led_filters[1].filter(rear, dt);
        for (k, slot) in obstacles.iter_mut().enumerate() {
            let p = self.noisy(world.obstacle_position(k, t_valid));
            *slot = self.obstacle_filters[k].filter(p, dt);
        }
        (t_valid, front, rear)
    }
}

/// Run a scenario to its end. With `record`, keep a trace row per cycle for the plots.
pub fn run(s: &Scenario, record: bool) -> Run {
    run_with(s, if record { Keep::Trace } else { Keep::Timing })
}

/// What a run keeps besides its outcome.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Keep {
    /// The outcome only, as a sweep's episode needs (its summary's compute times are 0):
    /// two clock reads a cycle were a thirtieth of a sweep.
    Outcome,
    /// The planner's compute time per cycle too.
    Timing,
    /// And a trace row per cycle for the plots.
    Trace,
}

/// What the step did, cycle by cycle, counted for the summary.
#[derive(Debug, Default)]
struct Tally {
    cycles: u64,
    invalid: u64,
    saturated: u64,
    tie_break: u64,
    shrunk: u64,
    unclosed: u64,
    slowed: u64,
    braking: u64,
    evaded: u64,
    goal_occupied: u64,
    faster: bool,
    /// Cycles in which a person was within [`DISCOMFORT_RADII`] of the robot.
    near: u64,
}

impl Tally {
    /// Count one step; the outcome it ends the run with, if any.
    fn count(&mut self, out: &StepOutput) -> Option<Outcome> {
        self.cycles += 1;
        if let Some(plan) = out.plan {
            self.saturated += u64::from(plan.flags.saturated);
            self.tie_break += u64::from(plan.flags.tie_break);
            self.shrunk += u64::from(plan.flags.margin_shrunk);
            self.unclosed += u64::from(plan.flags.unclosed_at_a_wall);
        }
        self.faster |= out.outrun;
        match out.supervision {
            Supervision::Passed => {}
            Supervision::Slowed { .. } => self.slowed += 1,
            Supervision::Braking { .. } => self.braking += 1,
            Supervision::Evaded { .. } => self.evaded += 1,
        }
        match out.status {
            StepStatus::AtGoal => return Some(Outcome::Goal),
            StepStatus::Stalled => return Some(Outcome::Stall),
            StepStatus::GoalOccupied { .. } => self.goal_occupied += 1,
            StepStatus::GoalBlocked { .. } | StepStatus::CommandStale => return Some(Outcome::Stopped),
            StepStatus::Invalid(_) => self.invalid += 1,
            StepStatus::Driving => {}
        }
        None
    }

    fn summary(self, s: &Scenario, outcome: Outcome, world: &World, compute: &Histogram<u64>) -> Summary {
        let truth = world.truth();
        let straight = (s.goal() - s.robot_start()).norm();
        let us = |q: f64| compute.value_at_quantile(q) as f64 / 1e3;
        Summary {
            scenario: s.name.clone(),
            outcome,
            end_time: world.time(),
            time_to_goal: (outcome == Outcome::Goal).then(|| world.time()),
            min_obstacle_clearance: (!s.obstacles.is_empty()).then_some(truth.min_obstacle_clearance),
            min_wall_clearance: truth.min_wall_clearance.is_finite().then_some(truth.min_wall_clearance),
            first_contact: truth.first_contact,
            contact: truth.contact,
            path_length: truth.path_length,
            path_length_ratio: if straight > 0.0 { truth.path_length / straight } else { 0.0 },
            discomfort: self.near as f64 / self.cycles.max(1) as f64,
            peak_wheel_speed: truth.peak_wheel_speed,
            planner_compute: ComputeTime { p50_us: us(0.5), p99_us: us(0.99), max_us: compute.max() as f64 / 1e3 },
            cycles: self.cycles,
            invalid_cycles: self.invalid,
            supervisor_slowed_cycles: self.slowed,
            supervisor_braking_cycles: self.braking,
            supervisor_evaded_cycles: self.evaded,
            goal_occupied_cycles: self.goal_occupied,
            saturated_cycles: self.saturated,
            tie_break_cycles: self.tie_break,
            margin_shrunk_cycles: self.shrunk,
            unclosed_at_a_wall_cycles: self.unclosed,
            obstacle_faster_than_robot: self.faster,
            stop_reason: None,
        }
    }
}

fn run_with(s: &Scenario, keep: Keep) -> Run {
    let record = keep == Keep::Trace;
    let timed = keep != Keep::Outcome;
    let mut rig = s.rig();
    rig.tracking.kalman = KalmanConfig { measurement_noise: s.sensing.position_noise.max(1e-3), ..rig.tracking.kalman };
    let config = rig.control;
    let mut control = ControlStep::new(config.clone());
    let mut world = World::new(s);
    let mut sensor = Sensor::new(s);
    let t_step = rig.sample_period.as_secs_f64();
    let n = s.obstacles.len().min(MAX_OBSTACLES);
    let radii: Vec<f64> = s.obstacles.iter().map(|o| o.radius).collect();
    let mut tracker = Tracker::new(rig.tracking, led_geometry(s), &radii);
    let mut measured = vec![Point::default(); n];
    let mut compute = Histogram::<u64>::new(3).expect("histogram");
    let mut cost = CycleCost::default();
    let clock = || timed.then(Instant::now);
    let lap = |from: Option<Instant>, total: &mut u64| {
        if let Some(from) = from {
            *total += from.elapsed().as_nanos() as u64;
        }
    };
    let mut trace = Vec::new();
    let mut tally = Tally::default();
    let discomfort_gap = DISCOMFORT_RADII * s.robot.radius;
    let outcome = loop {
        let t = world.time();
        let sensing = clock();
        let (t_valid, front, rear) = sensor.measure(&world, t_step, &mut measured);
        for (k, z) in measured.iter().enumerate() {
            tracker.observe_obstacle(k, t_valid, *z);
        }
        // A lost pose (coincident LEDs) keeps the last one; the gateway would stop instead.
        tracker.observe_robot(t_valid, front, rear);
        let Some(tracked) = tracker.estimate(t, t_step, config.drive.wheel_base) else { break Outcome::Timeout };
        lap(sensing, &mut cost.sense_and_track_ns);
        let started = clock();
        let out = control.step(t, &tracked.estimate);
        if let Some(started) = started {
            let ns = started.elapsed().as_nanos() as u64;
            let _ = compute.record(ns);
            cost.control_ns += ns;
        }
        if let Some(outcome) = tally.count(&out) {
            break outcome;
        }
        tally.near += u64::from(world.clearances().any(|c| c < discomfort_gap));
        // The world settles at the command: the way since the last one integrated and judged.
        let settling = clock();
        world.command_pulse_rates(out.pulses);
        lap(settling, &mut cost.world_ns);
        tracker.commanded(t, out.wheels.left, out.wheels.right);
        if record {
            trace.push(trace_row(&world, t, &out, n));
        }
        let stepping = clock();
        world.step(t_step);
        let touched = world.first_contact().is_some();
        lap(stepping, &mut cost.world_ns);
        if touched {
            break Outcome::Collision;
        }
        if world.time() >= s.time_limit {
            break Outcome::Timeout;
        }
    };
    let summary = tally.summary(s, outcome, &world, &compute);
    Run { summary, trace, cost }
}

/// A cycle's row for the plots.
fn trace_row(world: &World, t: f64, out: &StepOutput, n: usize) -> TraceRow {
    let w = world.wheel_speeds();
    TraceRow {
        t,
        pose: world.pose().into(),
        command: out.plan.map_or(Point::default(), |p| p.velocity),
        speed: 0.5 * (w[0] + w[1]),
        obstacles: (0..n).map(|k| world.obstacle_position(k, t)).collect(),
    }
}
