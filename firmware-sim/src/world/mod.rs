//! The simulated world: a differential-drive robot whose wheels turn by the pulses of a
//! two-axis pulse generator, obstacles that follow their scripts, optional lane walls, and
//! the truth a run is judged by (contact, clearance against the true radii).
//!
//! Time is an argument: [`World::step`] advances by `dt`, nothing reads a clock.

mod axis;
mod obstacle;
mod robot;

pub use axis::{Axis, AxisConfig};
pub use obstacle::ObstaclePath;
pub use robot::{DiffDrive, Pose};

use crate::scenario::Scenario;
use crate::Point;

/// Which wheel an axis drives.
pub const LEFT: usize = 0;
pub const RIGHT: usize = 1;

/// The world of one scenario.
#[derive(Debug, Clone)]
pub struct World {
    time: f64,
    pose: Pose,
    drive: DiffDrive,
    axes: [Axis; 2],
    robot_radius: f64,
    obstacles: Vec<(ObstaclePath, f64)>,
    lane_half_width: Option<f64>,
    truth: Truth,
    /// The judge's running state, kept in the form that is cheapest every millisecond.
    judge: Judge,
    /// A calibration wand: an LED someone holds on the floor (its id and where it stands;
    /// `None` = held out of sight).
    wand: Option<(u8, Option<Point>)>,
    /// The last step's wheel pulses and the arc they drove (see [`robot::Arc`]).
    arc: ([f64; 2], robot::Arc),
}

/// What the world judges every millisecond, as squares and pulse rates: the truth's
/// clearances and peak speeds follow from these when asked for, exactly, because a square
/// root, subtracting a radius and dividing by a positive scale never reorder two numbers
/// (IEEE rounding is monotone). A square root and two divisions a millisecond were a
/// fifth of the world's cost.
#[derive(Debug, Clone)]
struct Judge {
    /// Per obstacle: the smallest squared distance between the centres so far, m².
    min_distance_sqr: Vec<f64>,
    /// Per obstacle: below this squared distance between the centres the footprints may
    /// touch (the sum of the radii, squared, and a hair more for rounding): only then is
    /// the clearance itself taken.
    touch_sqr: Vec<f64>,
    /// Largest pulse rate of each axis so far, pulses/s.
    peak_rate: [f64; 2],
}

/// Above this speed toward what it touches (m/s), the robot drove into it: an *active*
/// contact. At or below it the robot was stopped or moving away, and was hit: *passive*.
pub const ACTIVE_CONTACT_SPEED: f64 = 0.01;

/// What the robot touched.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Touched {
    /// Obstacle `k` (its index in the scenario).
    Obstacle(usize),
    /// A lane line (the lines bound the robot's centre).
    Wall,
}

/// The first contact of a run, judged at the millisecond it happened.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Contact {
    /// When, s.
    pub at: f64,
    pub with: Touched,
    /// The robot's velocity component toward what it touched, m/s (negative: away).
    pub approach_speed: f64,
    /// The robot drove into it: `approach_speed` above [`ACTIVE_CONTACT_SPEED`].
    pub active: bool,
}

/// What really happened, judged against the true radii.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Truth {
    /// Smallest gap between the robot's footprint and any obstacle's, m (negative: overlap).
    pub min_obstacle_clearance: f64,
    /// Smallest gap between the robot's centre and a lane line, m (`+inf` in free space).
    /// The lane bounds the robot's centre, as the planning radii include the robot's radius.
    pub min_wall_clearance: f64,
    /// When the robot first touched an obstacle or a wall, s.
    pub first_contact: Option<f64>,
    /// That first contact: what was touched, and how the robot was moving.
    pub contact: Option<Contact>,
    /// Path length travelled by the robot's centre, m.
    pub path_length: f64,
    /// Largest wheel rim speed reached, m/s: left, right.
    pub peak_wheel_speed: [f64; 2],
}

impl World {
    /// The world at time 0 of a scenario.
    pub fn new(scenario: &Scenario) -> Self {
        let r = &scenario.robot;
        let drive = DiffDrive { wheel_base: r.wheel_base, pulses_per_metre: r.pulses_per_metre() };
        let axis = AxisConfig {
            accel: r.wheel_accel * drive.pulses_per_metre,
            max_rate: r.max_wheel_speed * drive.pulses_per_metre,
        };
        let mut world = Self {
            time: 0.0,
            pose: Pose { position: scenario.robot_start(), heading: r.heading_deg.to_radians() },
            drive,
            axes: [Axis::new(axis), Axis::new(axis)],
            robot_radius: r.radius,
            obstacles: scenario.obstacles.iter().map(|o| (ObstaclePath::new(o), o.radius)).collect(),
            lane_half_width: scenario.lane.map(|l| l.half_width),
            truth: Truth {
                min_obstacle_clearance: f64::INFINITY,
                min_wall_clearance: f64::INFINITY,
                first_contact: None,
                contact: None,
                path_length: 0.0,
                peak_wheel_speed: [0.0; 2],
            },
            judge: Judge {
                min_distance_sqr: vec![f64::INFINITY; scenario.obstacles.len()],
                touch_sqr: scenario
                    .obstacles
                    .iter()
                    .map(|o| {
                        let touch = o.radius + r.radius;
                        touch * touch * (1.0 + 1e-9)
                    })
                    .collect(),
                peak_rate: [0.0; 2],
            },
            wand: None,
            arc: ([0.0; 2], robot::Arc::REST),
        };
        world.judge();
        world
    }

    /// Put the wand LED `led` at `at` on the floor (`None`: out of sight).
    pub fn place_wand(&mut self, led: u8, at: Option<Point>) {
        self.wand = Some((led, at));
    }

    /// The wand, if one is in use: its LED and where it stands.
    pub fn wand(&self) -> Option<(u8, Option<Point>)> {
        self.wand
    }

    pub fn time(&self) -> f64 {
        self.time
    }
    pub fn pose(&self) -> Pose {
        self.pose
    }
    pub fn robot_radius(&self) -> f64 {
        self.robot_radius
    }
    /// What really happened so far.
    pub fn truth(&self) -> Truth {
        let min_obstacle_clearance = self
            .judge
            .min_distance_sqr
            .iter()
            .zip(&self.obstacles)
            .map(|(d2, (_, radius))| d2.sqrt() - radius - self.robot_radius)
            .fold(f64::INFINITY, f64::min);
        Truth {
            min_obstacle_clearance,
            peak_wheel_speed: self.judge.peak_rate.map(|r| r / self.drive.pulses_per_metre),
            ..self.truth
        }
    }
    /// When the robot first touched an obstacle or a wall, s (as [`Truth::first_contact`],
    /// without assembling the rest).
    pub fn first_contact(&self) -> Option<f64> {
        self.truth.first_contact
    }
    pub fn axes(&self) -> &[Axis; 2] {
        &self.axes
    }
    pub fn lane_half_width(&self) -> Option<f64> {
        self.lane_half_width
    }
    /// Number of obstacles.
    pub fn obstacle_count(&self) -> usize {
        self.obstacles.len()
    }
    /// Obstacle `k`'s true centre at time `t` (any `t`, past or future).
    pub fn obstacle_position(&self, k: usize, t: f64) -> Point {
        self.obstacles[k].0.position(t)
    }
    /// Obstacle `k`'s true velocity at time `t`.
    pub fn obstacle_velocity(&self, k: usize, t: f64) -> Point {
        self.obstacles[k].0.velocity(t)
    }
    /// Obstacle `k`'s true radius.
    pub fn obstacle_radius(&self, k: usize) -> f64 {
        self.obstacles[k].1
    }
    /// Wheel rim speeds now, m/s: left, right.
    pub fn wheel_speeds(&self) -> [f64; 2] {
        self.axes.map(|a| a.rate() / self.drive.pulses_per_metre)
    }

    /// Set both axes' target pulse rates (pulses/s), as a velocity command does.
    pub fn command_pulse_rates(&mut self, rates: [i32; 2]) {
        self.axes[LEFT].set_target(rates[LEFT]);
        self.axes[RIGHT].set_target(rates[RIGHT]);
    }

    /// Set both axes' ramp and rate limit (pulses).
    pub fn configure_axes(&mut self, config: AxisConfig) {
        self.axes.iter_mut().for_each(|a| a.set_config(config));
    }

    /// Stop both axes at once (e-stop, command timeout).
    pub fn stop_axes(&mut self) {
        self.axes.iter_mut().for_each(Axis::stop_now);
    }

    /// Advance the world by `dt` seconds, in sub-steps of at most 1 ms so the kinematics
    /// and the contact check stay accurate whatever the control period.
    pub fn step(&mut self, dt: f64) {
        let n = (dt / 1e-3).ceil().max(1.0) as usize;
        let h = dt / n as f64;
        // The heading's direction, carried through the sub-steps and taken afresh from the
        // heading each call, so rounding cannot build up over a run.
        let mut facing = Point::from_polar(1.0, self.pose.heading);
        for _ in 0..n {
            let pulses = [self.axes[LEFT].step(h), self.axes[RIGHT].step(h)];
            if self.arc.0 != pulses {
                self.arc = (pulses, self.drive.motion(pulses));
            }
            (self.pose, facing) = self.arc.1.apply(self.pose, facing);
            self.time += h;
            self.truth.path_length += self.arc.1.length;
            for (peak, axis) in self.judge.peak_rate.iter_mut().zip(&self.axes) {
                *peak = peak.max(axis.rate().abs());
            }
            self.judge();
        }
    }

    /// Clearances now: to each obstacle (footprints), and to the nearest wall.
    pub fn clearances(&self) -> impl Iterator<Item = f64> + '_ {
        self.obstacles.iter().map(move |(path, radius)| {
            distance(self.pose.position, path.position(self.time)) - radius - self.robot_radius
        })
    }

    /// Gap between the robot's centre and the nearest lane line now (`+inf` in free space).
    pub fn wall_clearance(&self) -> f64 {
        self.lane_half_width.map_or(f64::INFINITY, |h| h - self.pose.position.im.abs())
    }

    fn judge(&mut self) {
        let mut may_touch = false;
        for (((path, _), min), touch) in
            self.obstacles.iter().zip(&mut self.judge.min_distance_sqr).zip(&self.judge.touch_sqr)
        {
            let d = path.position(self.time) - self.pose.position;
            let d2 = d.re * d.re + d.im * d.im;
            *min = min.min(d2);
            may_touch |= d2 < *touch;
        }
        let wall = self.wall_clearance();
        self.truth.min_wall_clearance = self.truth.min_wall_clearance.min(wall);
        if self.truth.first_contact.is_none() && (may_touch || wall < 0.0) {
            let obstacle = self.clearances().fold(f64::INFINITY, f64::min);
            if obstacle < 0.0 || wall < 0.0 {
                self.truth.first_contact = Some(self.time);
                self.truth.contact = Some(self.contact(obstacle, wall));
            }
        }
    }

    /// The contact happening now: the deeper overlap is what was touched.
    fn contact(&self, obstacle: f64, wall: f64) -> Contact {
        let [left, right] = self.wheel_speeds();
        let velocity = Point::from_polar(0.5 * (left + right), self.pose.heading);
        let (with, normal) = if obstacle <= wall {
            let k =
                self.clearances().enumerate().fold((0, f64::INFINITY), |m, (k, c)| if c < m.1 { (k, c) } else { m }).0;
            let d = self.obstacles[k].0.position(self.time) - self.pose.position;
            (Touched::Obstacle(k), d / d.norm())
        } else {
            (Touched::Wall, Point::new(0.0, self.pose.position.im.signum()))
        };
        let approach_speed = velocity.re * normal.re + velocity.im * normal.im;
        Contact { at: self.time, with, approach_speed, active: approach_speed > ACTIVE_CONTACT_SPEED }
    }
}

/// Euclidean distance. `sqrt` of the squares, not `hypot`: the world evaluates this every
/// millisecond of every run, and its points are far from overflow.
fn distance(a: Point, b: Point) -> f64 {
    let d = a - b;
    (d.re * d.re + d.im * d.im).sqrt()
}
