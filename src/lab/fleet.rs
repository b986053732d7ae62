//! A fleet scenario run: every vehicle's control step (its field, or its script through the
//! script follower, and its supervisor) in closed loop with the simulator's [`Fleet`], in
//! virtual time, judged by the world's truth.
//!
//! Each vehicle plans on the others as [`crate::control::fleet`] states (known positions,
//! commanded velocities, the priority order), on the scenario's obstacles as they truly
//! move, and on its own true pose and wheel speeds: the camera's noise and delay are not
//! modelled here. Single-robot scenarios run as before ([`super::planner_only`],
//! [`super::virtual_rig`]).

use flowgate_sim::scenario::vehicles::Role;
use flowgate_sim::scenario::SimScenario;
use flowgate_sim::world::fleet::Fleet;
use flowgate_sim::world::{Contact, ObstaclePath, Touched, World};
use serde::Serialize;

use super::{Outcome, Scenario};
use crate::control::drive::braking_pulse_rates;
use crate::control::fleet::{follow, FleetRule, FollowerGains, VehicleView};
use crate::control::{CommandSource, ControlStep, OutsideCommand, StepOutput, StepStatus, Supervision};
use crate::planner::ObstacleEstimate;
use crate::track::Estimate;
use crate::Point;

pub mod policy;
pub mod stack;
pub mod swarm;
pub mod sweep;

/// What one vehicle touched first.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VehicleContactReport {
    pub at: f64,
    /// `vehicle NAME`, `obstacles[k]`, `static_obstacles[k]` or `a wall`.
    pub with: String,
    /// This vehicle's speed toward it, m/s.
    pub approach_speed: f64,
    /// This vehicle drove into it (above 1 cm/s toward it).
    pub active: bool,
}

/// One vehicle's run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VehicleSummary {
    pub name: String,
    pub role: Role,
    /// A navigating vehicle: `goal` at its goal. A scripted one: `goal` when it kept to its
    /// script to the end (or to the run's end), `stopped` when it lost it.
    pub outcome: Outcome,
    pub contact: Option<VehicleContactReport>,
    /// A scripted vehicle's largest distance from its script where its supervisor passed
    /// the follower's command, m.
    pub script_error: Option<f64>,
    /// The same over the whole run, held or not, m.
    pub script_error_held: Option<f64>,
    pub time_to_goal: Option<f64>,
    pub path_length: f64,
    /// Smallest gap to another vehicle's footprint, m.
    pub min_vehicle_gap: f64,
    /// Smallest gap to another vehicle's or an obstacle's footprint, m.
    pub min_clearance: f64,
    /// Cycles the supervisor slowed, braked or evaded this vehicle's command.
    pub supervised_cycles: u64,
    /// Why it stopped, when not at its goal.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stop_reason: Option<String>,
}

/// A fleet run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FleetSummary {
    pub scenario: String,
    /// `goal` only when every navigating vehicle reached its goal and no vehicle touched
    /// anything; else the first vehicle's other outcome, a collision first.
    pub outcome: Outcome,
    pub end_time: f64,
    /// When the last navigating vehicle reached its goal, s.
    pub makespan: Option<f64>,
    pub vehicles: Vec<VehicleSummary>,
}

/// One vehicle while the run goes on.
#[derive(Debug)]
struct Driver {
    step: ControlStep,
    role: Role,
    script: Option<ObstaclePath>,
    tolerance: f64,
    radius: f64,
    /// Commanded velocity, m/s.
    commanded: Point,
    done: Option<(Outcome, f64, Option<String>)>,
    /// What covered its goal too long (an index among what it avoids), to be named.
    blocked_by: Option<usize>,
    error: f64,
    error_held: f64,
    supervised: u64,
    /// When its own link fails (`link_lost_at`), and how long its motors then hold their
    /// last command before they stop by themselves (the board's command timeout), s.
    link_lost_at: Option<f64>,
    hold: f64,
}

impl Driver {
    /// Its link has failed by `t`.
    fn link_lost(&self, t: f64) -> bool {
        self.link_lost_at.is_some_and(|at| t >= at)
    }

    /// How far it may still move beyond where it is at `t`, going at `speed`: out of
    /// control, on its last command until its motors' timeout stops them.
    fn reach(&self, t: f64, speed: f64) -> f64 {
        match self.link_lost_at {
            Some(at) if t >= at => speed * (at + self.hold - t).max(0.0),
            _ => 0.0,
        }
    }

    /// No command reaches it: at its link's failure the run names it, and once its motors'
    /// timeout has run out they stop.
    fn out_of_control(&mut self, world: &mut World, t: f64) {
        let Some(at) = self.link_lost_at else { return };
        if self.done.is_none() {
            let why = format!(
                "its link failed at {at:.2} s: its motors held their last command {:.0} ms, then stopped",
                self.hold * 1e3
            );
            self.done = Some((Outcome::Fault, t, Some(why)));
        }
        if t >= at + self.hold && world.wheel_speeds() != [0.0; 2] {
            world.stop_axes();
        }
    }
}

/// The options of a fleet run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FleetOptions {
    pub rule: FleetRule,
    pub gains: FollowerGains,
    /// End the run at the first contact (sweeps); else run on to see what follows.
    pub stop_at_contact: bool,
    /// How long the run goes on once no vehicle has anywhere to go, counted from the later
    /// of that and the last stop (or a lost link's motors' timeout), s: a swarm watches the
    /// stopped vehicles come to rest and stay there.
    pub run_on: f64,
}

impl Default for FleetOptions {
    fn default() -> Self {
        Self { rule: FleetRule::default(), gains: FollowerGains::default(), stop_at_contact: true, run_on: 0.0 }
    }
}

/// Every vehicle's control, cycle by cycle: what a gateway driving the fleet decides.
#[derive(Debug)]
pub struct FleetControl {
    drivers: Vec<Driver>,
    /// Every vehicle's name, the robot first.
    names: Vec<String>,
    options: FleetOptions,
    /// The vehicle driven from outside, if any.
    outside: Option<usize>,
    /// When a vehicle was last stopped (by [`FleetControl::stop`], or by its motors' own
    /// timeout after its link failed), s: a run goes on `run_on` beyond it.
    last_stop: f64,
    /// Scratch: one vehicle's obstacles, as its field and as its supervisor see them, and
    /// every vehicle as the others see it.
    seen: Vec<ObstacleEstimate>,
    supervised: Vec<ObstacleEstimate>,
    views: Vec<VehicleView>,
}

impl FleetControl {
    pub fn new(s: &Scenario, options: FleetOptions) -> Self {
        Self::driven(s, options, None)
    }

    /// The fleet's control with vehicle `outside` (if any) driven from outside: its commands
    /// come through [`FleetControl::command`], and go through its supervisor.
    pub fn driven(s: &Scenario, options: FleetOptions, outside: Option<usize>) -> Self {
        let drivers: Vec<Driver> = (0..=s.vehicles.len()).map(|k| driver(s, k, outside == Some(k))).collect();
        let idle = VehicleView::standing(Point::default(), 0.0);
        Self {
            seen: Vec::with_capacity(s.obstacles.len() + drivers.len()),
            supervised: Vec::with_capacity(s.obstacles.len() + drivers.len()),
            views: vec![idle; drivers.len()],
            drivers,
            names: s.fleet().map(|(name, _, _)| name.to_string()).collect(),
            options,
            outside,
            last_stop: f64::NEG_INFINITY,
        }
    }

    /// One cycle at the fleet's time: every vehicle's command, in priority order, into its
    /// world's axes.
    pub fn cycle(&mut self, fleet: &mut Fleet) {
        let t = fleet.time();
        for (k, d) in self.drivers.iter().enumerate() {
            let moving = if d.done.is_some() { fleet.velocity(k) } else { d.commanded };
            let moving_on = d.done.is_none() && d.role == Role::Navigate;
            let position = fleet.world(k).pose().position;
            let reach = d.reach(t, fleet.velocity(k).norm());
            let toward = if d.done.is_some() { Point::default() } else { d.commanded };
            let lag = ramp_lag(fleet, k, toward);
            self.views[k] = VehicleView { position, velocity: moving, toward, lag, radius: d.radius, moving_on, reach };
        }
        for k in 0..self.drivers.len() {
            if self.drivers[k].link_lost(t) {
                self.drivers[k].out_of_control(fleet.world_mut(k), t);
                continue;
            }
            let vehicles_from = self.see(fleet, k, t);
            let d = &mut self.drivers[k];
            if d.role == Role::Navigate {
                let goal = d.step.config().goal;
                let aim = self.options.rule.aim(k, self.views[k].position, goal, &self.views, d.step.aim());
                d.step.aim_at(aim);
            }
            let pulses = drive_one(d, fleet, k, t, [&self.seen, &self.supervised], &self.options.gains);
            if let Some(index) = d.blocked_by.take() {
                // What covers its goal, by name: an obstacle, or another vehicle.
                let by = match index.checked_sub(vehicles_from) {
                    None => format!("obstacles[{index}]"),
                    Some(j) => format!("vehicle {}", self.names[if j >= k { j + 1 } else { j }]),
                };
                d.done = Some((Outcome::Stopped, t, Some(format!("goal blocked by {by}"))));
            }
            self.views[k].velocity = d.commanded;
            fleet.world_mut(k).command_pulse_rates(pulses);
            self.views[k].toward = d.commanded;
            self.views[k].lag = ramp_lag(fleet, k, d.commanded);
        }
    }

    /// What vehicle `k` avoids at `t`, for its field and for its supervisor: the obstacles
    /// as they truly are (every world holds the same ways), then every other vehicle; returns
    /// where the vehicles begin.
    fn see(&mut self, fleet: &Fleet, k: usize, t: f64) -> usize {
        self.seen.clear();
        let truth = fleet.world(0);
        self.seen.extend((0..truth.obstacle_count()).map(|o| {
            ObstacleEstimate::exact(
                truth.obstacle_position(o, t),
                truth.obstacle_velocity(o, t),
                truth.obstacle_radius(o),
            )
        }));
        let vehicles_from = self.seen.len();
        self.options.rule.others_as_obstacles(k, &self.views, &mut self.seen);
        self.supervised.clear();
        self.supervised.extend_from_slice(&self.seen[..vehicles_from]);
        if self.outside == Some(k) {
            // A vehicle driven from outside keeps no fleet rule, and the others' next
            // commands answer its moves: to its supervisor each is a region growing at its
            // speed (stopping, turning or going on), not a body bound to go on.
            for v in &mut self.seen[vehicles_from..] {
                v.spread = v.spread.max(v.velocity.norm().max(f64::MIN_POSITIVE));
            }
            self.supervised.extend_from_slice(&self.seen[vehicles_from..]);
        } else {
            self.options.rule.others_as_supervised(k, &self.views, &mut self.supervised);
        }
        vehicles_from
    }

    /// Vehicle `k`'s command from outside at `t`, for its next cycle.
    pub fn command(&mut self, k: usize, t: f64, command: OutsideCommand) {
        self.drivers[k].step.take_command(t, command);
    }

    /// Stop vehicle `k` at `t`, its outcome `stopped` and `why` its stop reason.
    pub fn stop(&mut self, k: usize, t: f64, why: String) {
        self.drivers[k].done.get_or_insert((Outcome::Stopped, t, Some(why)));
        self.last_stop = self.last_stop.max(t);
    }

    /// Vehicle `k`'s own link fails at `at` (as `link_lost_at` would have it, unless it
    /// failed earlier): no command reaches it from then on.
    pub fn lose_link(&mut self, k: usize, at: f64) {
        let d = &mut self.drivers[k];
        d.link_lost_at = Some(d.link_lost_at.map_or(at, |was| was.min(at)));
        self.last_stop = self.last_stop.max(at + d.hold);
    }

    /// When vehicle `k`'s own link fails (or failed): from then on nothing sent reaches it.
    pub fn link_lost_at(&self, k: usize) -> Option<f64> {
        self.drivers[k].link_lost_at
    }

    /// How many vehicles the fleet has, the robot included.
    pub fn vehicles(&self) -> usize {
        self.drivers.len()
    }

    /// Whether vehicle `k` is done (at its goal, stopped or faulted).
    pub fn is_done(&self, k: usize) -> bool {
        self.drivers[k].done.is_some()
    }

    /// Vehicle `k`'s goal.
    pub fn goal(&self, k: usize) -> Point {
        self.drivers[k].step.config().goal
    }

    /// Whether any vehicle still has somewhere to go at `t`.
    pub fn running(&self, t: f64) -> bool {
        self.drivers.iter().any(|d| d.done.is_none() && (d.role == Role::Navigate || d.script_runs(t)))
    }
}

/// How far behind the way `toward` would take vehicle `k` its wheels' ramps may leave it,
/// m. Each wheel ramps at one rate to its target and holds it, so the centre's speed holds
/// while the two ramp apart and then moves toward `toward`'s alone: it falls behind by at
/// most the gap times the longer ramp. (A scenario's `wheel_accel` is positive, so every
/// ramp ends.)
fn ramp_lag(fleet: &Fleet, k: usize, toward: Point) -> f64 {
    let gap = (toward - fleet.velocity(k)).norm();
    if gap == 0.0 {
        return 0.0;
    }
    gap * fleet.world(k).axes().iter().map(|a| a.ramp_left()).fold(0.0, f64::max)
}

/// Run a fleet scenario to its end.
pub fn run(s: &Scenario, options: FleetOptions) -> FleetSummary {
    drive(s, options, None)
}

/// Where each vehicle and each obstacle was, cycle by cycle, for the plot.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FleetTrace {
    /// The cycles' times, s.
    pub t: Vec<f64>,
    /// Each vehicle's centre, the robot first.
    pub vehicles: Vec<Vec<Point>>,
    pub obstacles: Vec<Vec<Point>>,
}

/// Run a fleet scenario to its end, keeping its trace.
pub fn run_traced(s: &Scenario, options: FleetOptions) -> (FleetSummary, FleetTrace) {
    let mut trace = FleetTrace::default();
    let summary = drive(s, options, Some(&mut trace));
    (summary, trace)
}

fn drive(s: &Scenario, options: FleetOptions, trace: Option<&mut FleetTrace>) -> FleetSummary {
    drive_with(s, FleetControl::new(s, options), trace, |_, _| {})
}

/// Run `control` over `s`'s fleet to its end, `before` each cycle given the fleet and the
/// control (an outside vehicle's command goes in there).
fn drive_with(
    s: &Scenario,
    mut control: FleetControl,
    mut trace: Option<&mut FleetTrace>,
    mut before: impl FnMut(&Fleet, &mut FleetControl),
) -> FleetSummary {
    let options = control.options;
    let mut fleet = Fleet::new(&s.sim);
    let mut idle_since = None;
    loop {
        let t = fleet.time();
        if let Some(trace) = trace.as_deref_mut() {
            trace.record(&fleet, t);
        }
        before(&fleet, &mut control);
        control.cycle(&mut fleet);
        fleet.step(s.sensing.sample_time);
        let touched = (0..fleet.len()).any(|k| contact_of(&fleet, s, k).is_some());
        if !control.running(t) {
            idle_since.get_or_insert(t);
        }
        let settled = idle_since.is_some_and(|since: f64| t - since.max(control.last_stop) >= options.run_on);
        if (touched && options.stop_at_contact) || settled || fleet.time() >= s.time_limit {
            return summary(s, &fleet, &control.drivers);
        }
    }
}

impl FleetTrace {
    fn record(&mut self, fleet: &Fleet, t: f64) {
        self.t.push(t);
        self.vehicles.resize(fleet.len(), Vec::new());
        for (k, path) in self.vehicles.iter_mut().enumerate() {
            path.push(fleet.world(k).pose().position);
        }
        let truth = fleet.world(0);
        self.obstacles.resize(truth.obstacle_count(), Vec::new());
        for (o, path) in self.obstacles.iter_mut().enumerate() {
            path.push(truth.obstacle_position(o, t));
        }
    }
}

impl Driver {
    /// Whether the script still moves at `t` (an endless one runs to the time limit).
    fn script_runs(&self, t: f64) -> bool {
        self.script.as_ref().is_some_and(|p| t < p.end_time())
    }
}

/// Vehicle `k`'s control step, from its rig as the robot's is; `outside`, its commands from
/// outside (a policy), each good for two cycles.
fn driver(s: &Scenario, k: usize, outside: bool) -> Driver {
    let alone = s.vehicle(k);
    let mut config = alone.rig().control;
    if outside {
        config.source = CommandSource::Outside { max_age: 2.0 * s.sensing.sample_time };
    }
    let role = if k == 0 { Role::Navigate } else { s.vehicles[k - 1].role };
    let (mut script, mut tolerance) = (None, 0.0);
    if role == Role::Script {
        let v = &s.vehicles[k - 1];
        script = Some(ObstaclePath::new(&v.script(alone.robot.radius)));
        tolerance = v.script_tolerance();
        // The follower's command, a cycle old at most, is what the supervisor checks.
        config.source = CommandSource::Outside { max_age: 2.0 * s.sensing.sample_time };
        config.goal_tolerance = 0.0;
    }
    if let Some(supervisor) = config.supervisor.as_mut() {
        // A vehicle closes on another within its reach only as it slows (a stop's last
        // sliver of speed): held by its supervisor beside a vehicle that stands, its field
        // pushing on, it crept into it at the robot's tolerance (`tests/fleet.rs`).
        supervisor.vehicle_approach_tolerance = 0.0;
    }
    let mut step = ControlStep::new(config);
    step.start(0.0);
    let hold = motors_hold(s, k);
    let link_lost_at = k.checked_sub(1).and_then(|i| s.vehicles[i].link_lost_at);
    Driver {
        step,
        role,
        script,
        tolerance,
        radius: alone.robot.radius,
        commanded: Point::default(),
        done: None,
        blocked_by: None,
        error: 0.0,
        error_held: 0.0,
        supervised: 0,
        link_lost_at,
        hold,
    }
}

/// How long vehicle `k`'s motors hold their last command once no command reaches them
/// (its rig's command timeout), s.
pub fn motors_hold(s: &Scenario, k: usize) -> f64 {
    let rig = s.vehicle(k).rig_file(std::path::Path::new("/dev/null"), "slcan:/dev/null", None);
    f64::from(rig.drive.command_timeout_ms) / 1e3
}

/// One vehicle's cycle: its pulse rates.
fn drive_one(
    d: &mut Driver,
    fleet: &Fleet,
    k: usize,
    t: f64,
    [seen, supervised]: [&[ObstacleEstimate]; 2],
    gains: &FollowerGains,
) -> [i32; 2] {
    let world = fleet.world(k);
    if d.done.is_some() {
        d.commanded = Point::default();
        return braking_pulse_rates(world.wheel_speeds(), &d.step.config().drive);
    }
    let (position, facing) = (world.pose().position, world.facing());
    let estimate =
        Estimate { position, facing, wheels: world.wheel_speeds(), obstacles: seen, predicted: supervised, delay: 0.0 };
    if let Some(path) = &d.script {
        let (reference, velocity) = (path.position(t), path.velocity(t));
        let error = (reference - position).norm();
        d.error_held = d.error_held.max(error);
        if error > d.tolerance {
            d.done = Some((
                Outcome::Stopped,
                t,
                Some(format!("{:.1} mm off its script (tolerance {:.1} mm)", error * 1e3, d.tolerance * 1e3)),
            ));
            return braking_pulse_rates(world.wheel_speeds(), &d.step.config().drive);
        }
        let (v, w) = follow(gains, position, facing, reference, velocity);
        d.step.take_command(t, OutsideCommand::Twist { v, w });
        let out = d.step.step(t, &estimate);
        if out.supervision == Supervision::Passed {
            d.error = d.error.max(error);
        }
        return carry_out(d, world, &out, t);
    }
    let out = d.step.step(t, &estimate);
    carry_out(d, world, &out, t)
}

/// The step's command, or, where the step stops the vehicle (waiting for its goal, at it,
/// stalled), the brake its supervisor certified: a stop holds the arc, as for a vehicle
/// that is done (zero on each wheel would pivot it off the arc, into a vehicle beside it).
fn carry_out(d: &mut Driver, world: &World, out: &StepOutput, t: f64) -> [i32; 2] {
    let facing = world.facing();
    if out.supervision != Supervision::Passed {
        d.supervised += 1;
    }
    let ended = match out.status {
        StepStatus::Driving | StepStatus::GoalOccupied { .. } | StepStatus::Invalid(_) => None,
        StepStatus::AtGoal => Some((Outcome::Goal, None)),
        StepStatus::Stalled => Some((Outcome::Stall, Some("stalled".to_string()))),
        StepStatus::GoalBlocked { index } => {
            d.blocked_by = Some(index); // named by the fleet, which knows what `index` is
            Some((Outcome::Stopped, None))
        }
        StepStatus::CommandStale => Some((Outcome::Stopped, Some("script command stale".to_string()))),
    };
    if let Some((outcome, why)) = ended {
        d.done = Some((outcome, t, why));
    }
    d.commanded = facing * (0.5 * (out.wheels.left + out.wheels.right));
    if matches!(out.status, StepStatus::Driving) {
        out.pulses
    } else {
        braking_pulse_rates(world.wheel_speeds(), &d.step.config().drive)
    }
}

/// Vehicle `k`'s first contact with anything: a vehicle, an obstacle or a wall.
pub(crate) fn contact_of(fleet: &Fleet, s: &SimScenario, k: usize) -> Option<VehicleContactReport> {
    let world: Option<Contact> = fleet.world(k).first_contact().and_then(|_| fleet.world(k).truth().contact);
    contact_report(s, world, fleet.vehicle_contact(k))
}

/// The first of a vehicle's contact with the world and with another vehicle, named.
pub(crate) fn contact_report(
    s: &SimScenario,
    world: Option<Contact>,
    vehicle: Option<flowgate_sim::world::fleet::VehicleContact>,
) -> Option<VehicleContactReport> {
    let with_world = world.map(|c| VehicleContactReport {
        at: c.at,
        with: match c.with {
            Touched::Obstacle(i) => format!("obstacles[{i}]"),
            Touched::StaticObstacle(i) => format!("static_obstacles[{i}]"),
            Touched::Wall => "a wall".to_string(),
        },
        approach_speed: c.approach_speed,
        active: c.active,
    });
    let with_vehicle = vehicle.map(|c| VehicleContactReport {
        at: c.at,
        with: format!("vehicle {}", s.fleet().nth(c.with).map_or("?", |v| v.0)),
        approach_speed: c.approach_speed,
        active: c.active,
    });
    match (with_world, with_vehicle) {
        (Some(a), Some(b)) => Some(if a.at <= b.at { a } else { b }),
        (a, b) => a.or(b),
    }
}

fn summary(s: &Scenario, fleet: &Fleet, drivers: &[Driver]) -> FleetSummary {
    let end = fleet.time();
    let vehicles: Vec<VehicleSummary> = s
        .fleet()
        .zip(drivers)
        .enumerate()
        .map(|(k, ((name, _, role), d))| {
            let contact = contact_of(fleet, s, k);
            let (mut outcome, at, why) = d.done.clone().unwrap_or((
                if role == Role::Script { Outcome::Goal } else { Outcome::Timeout },
                end,
                None,
            ));
            if contact.is_some() {
                outcome = Outcome::Collision;
            }
            VehicleSummary {
                name: name.to_string(),
                role,
                outcome,
                contact,
                script_error: (role == Role::Script).then_some(d.error),
                script_error_held: (role == Role::Script).then_some(d.error_held),
                time_to_goal: (outcome == Outcome::Goal && role == Role::Navigate).then_some(at),
                path_length: fleet.world(k).truth().path_length,
                min_vehicle_gap: fleet.min_vehicle_gap(k),
                min_clearance: fleet.min_vehicle_gap(k).min(fleet.world(k).truth().min_obstacle_clearance),
                supervised_cycles: d.supervised,
                stop_reason: why,
            }
        })
        .collect();
    FleetSummary::of(s, end, vehicles)
}

impl FleetSummary {
    /// The fleet's run from its vehicles': `goal` only when every vehicle's is, else a
    /// collision first, else the first vehicle's other outcome; the makespan when all are home.
    pub(crate) fn of(s: &Scenario, end_time: f64, vehicles: Vec<VehicleSummary>) -> Self {
        let all_home = vehicles.iter().all(|v| v.outcome == Outcome::Goal);
        let outcome = if all_home {
            Outcome::Goal
        } else if vehicles.iter().any(|v| v.outcome == Outcome::Collision) {
            Outcome::Collision
        } else {
            vehicles.iter().map(|v| v.outcome).find(|&o| o != Outcome::Goal).unwrap_or(Outcome::Goal)
        };
        let navigating = vehicles.iter().filter(|v| v.role == Role::Navigate);
        let makespan = all_home.then(|| navigating.filter_map(|v| v.time_to_goal).fold(0.0, f64::max));
        Self { scenario: s.name.clone(), outcome, end_time, makespan, vehicles }
    }
}

/// One line a vehicle, for the terminal.
pub fn lines(summary: &FleetSummary) -> Vec<String> {
    let mut out = vec![format!(
        "{}: {} after {:.2} s{}",
        summary.scenario,
        summary.outcome,
        summary.end_time,
        summary.makespan.map(|m| format!(", every navigating vehicle home at {m:.2} s")).unwrap_or_default()
    )];
    for v in &summary.vehicles {
        let mut line =
            format!("  {:<12} {:<8} {:<9}", v.name, format!("{:?}", v.role).to_lowercase(), v.outcome.to_string());
        if let Some(t) = v.time_to_goal {
            line += &format!(" at {t:.2} s");
        }
        if let Some(e) = v.script_error {
            line += &format!(" script within {:.1} mm", e * 1e3);
        }
        line += &format!(", {:.2} m, nearest vehicle {:.1} cm", v.path_length, v.min_vehicle_gap * 100.0);
        if let Some(c) = &v.contact {
            line += &format!(", touched {} at {:.2} s ({})", c.with, c.at, if c.active { "active" } else { "passive" });
        }
        if let Some(why) = &v.stop_reason {
            line += &format!(", {why}");
        }
        out.push(line);
    }
    out
}
