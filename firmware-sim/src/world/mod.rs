//! The simulated world: a differential-drive robot whose wheels turn by the pulses of a
//! two-axis pulse generator, obstacles that follow their scripts, optional lane walls, and
//! the truth a run is judged by (contact, clearance against the true radii).
//!
//! Time is an argument: [`World::step`] advances by `dt`, nothing reads a clock.

mod axis;
mod obstacle;
mod robot;
mod room;

pub use axis::{Axis, AxisConfig};
pub use obstacle::ObstaclePath;
pub use robot::{DiffDrive, Motion, Pose};
pub use room::{Room, RoomGap};

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
    /// The heading's direction, a unit complex number carried with the pose: no sine or
    /// cosine a step.
    facing: Point,
    drive: DiffDrive,
    axes: [Axis; 2],
    robot_radius: f64,
    obstacles: Vec<(ObstaclePath, f64)>,
    lane_half_width: Option<f64>,
    room: Room,
    truth: Truth,
    /// The judge's running state, kept in the form that is cheapest every millisecond.
    judge: Judge,
    /// A calibration wand: an LED someone holds on the floor (its id and where it stands;
    /// `None` = held out of sight).
    wand: Option<(u8, Option<Point>)>,
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
    /// A lane line (the lines bound the robot's centre) or a wall (its footprint).
    Wall,
    /// Static obstacle `k` (its index in the scenario's `static_obstacles`).
    StaticObstacle(usize),
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
    /// Smallest gap between the robot and a lane line, a wall or a static obstacle, m
    /// (`+inf` with none). The lane's lines bound the robot's centre, as the planning radii
    /// include the robot's radius; walls and static obstacles its footprint.
    pub min_wall_clearance: f64,
    /// When the robot first touched an obstacle or a wall, s.
    pub first_contact: Option<f64>,
    /// That first contact: what was touched, and how the robot was moving.
    pub contact: Option<Contact>,
    /// The first contact in which the robot drove into what it touched (a passive contact
    /// may come first: a stopped robot hit by an obstacle, which it may then drive into).
    pub first_active_contact: Option<Contact>,
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
            facing: Point::from_polar(1.0, r.heading_deg.to_radians()),
            drive,
            axes: [Axis::new(axis), Axis::new(axis)],
            robot_radius: r.radius,
            obstacles: scenario.obstacles.iter().map(|o| (ObstaclePath::new(o), o.radius)).collect(),
            lane_half_width: scenario.lane.map(|l| l.half_width),
            room: Room::new(scenario),
            truth: Truth {
                min_obstacle_clearance: f64::INFINITY,
                min_wall_clearance: f64::INFINITY,
                first_contact: None,
                contact: None,
                first_active_contact: None,
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
        };
        world.judge(world.pose, world.time);
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
    /// The heading as a unit vector (the pose's, integrated without angles).
    pub fn facing(&self) -> Point {
        self.facing
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
    /// The walls and static obstacles.
    pub fn room(&self) -> &Room {
        &self.room
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
        self.rim_speeds(&self.axes)
    }

    /// The rim speeds axes at `axes`' rates drive, m/s: left, right.
    fn rim_speeds(&self, axes: &[Axis; 2]) -> [f64; 2] {
        axes.map(|a| a.rate() / self.drive.pulses_per_metre)
    }

    /// Set both axes' target pulse rates (pulses/s), as a velocity command does.
    pub fn command_pulse_rates(&mut self, rates: [i32; 2]) {
        self.axes[LEFT].set_target(rates[LEFT]);
        self.axes[RIGHT].set_target(rates[RIGHT]);
    }

    /// One axis's target rate (one CiA 402 drive a wheel), clamped to its limit.
    pub fn command_axis(&mut self, axis: usize, rate: i32) {
        if let Some(a) = self.axes.get_mut(axis) {
            a.set_target(rate);
        }
    }

    /// One axis's ramp and rate limit.
    pub fn configure_axis(&mut self, axis: usize, config: AxisConfig) {
        if let Some(a) = self.axes.get_mut(axis) {
            a.set_config(config);
        }
    }

    /// Stop one axis at once (its drive lost power, or its wheel is blocked).
    pub fn stop_axis(&mut self, axis: usize) {
        if let Some(a) = self.axes.get_mut(axis) {
            a.stop_now();
        }
    }

    /// Set both axes' ramp and rate limit (pulses).
    pub fn configure_axes(&mut self, config: AxisConfig) {
        self.axes.iter_mut().for_each(|a| a.set_config(config));
    }

    /// Stop both axes at once (e-stop, command timeout).
    pub fn stop_axes(&mut self) {
        self.axes.iter_mut().for_each(Axis::stop_now);
    }

    /// Advance the world by `dt` seconds. The wheels follow the boards' ramps exactly and
    /// the pose is integrated along them (see [`DiffDrive::motion`]), in one piece between
    /// the ramps' ends however long `dt` is. The truth is judged on a grid of at most
    /// 1 ms (`dt` split evenly): at its end always, and at every point of it only where a
    /// contact or a new closest approach could fall between (`World::quiet`), which
    /// leaves the truth exactly as judging every point would. A control period of a sweep
    /// is then one integration and one judgement, except near a closest approach.
    pub fn step(&mut self, dt: f64) {
        self.step_judging(dt, Judging::WhereItMatters);
    }

    fn step_judging(&mut self, dt: f64, judging: Judging) {
        if dt.is_nan() || dt <= 0.0 {
            return;
        }
        let n = (dt / 1e-3).ceil().max(1.0) as usize;
        let (start, facing, axes, t0) = (self.pose, self.facing, self.axes, self.time);
        // Filled in place, as is the inner points' scratch below: a move would copy them.
        let mut pieces = Pieces::new();
        let (pose, facing_after, axes_after, travelled) = self.advanced(start, facing, axes, dt, &mut pieces);
        // Renormalised each step, so rounding cannot build up over a run.
        (self.pose, self.facing, self.axes) = (pose, facing_after / facing_after.norm_sqr().sqrt(), axes_after);
        self.time = t0 + dt;
        self.truth.path_length += travelled;
        for (peak, axis) in self.judge.peak_rate.iter_mut().zip(&self.axes) {
            // A ramp is monotone: the step's fastest rate is at one of its ends.
            *peak = peak.max(axis.rate().abs());
        }
        // A step within one millisecond has no inner points to pass over.
        let quiet = n > 1 && judging == Judging::WhereItMatters && self.quiet(start, t0, &pieces, n);
        #[cfg(test)]
        tests::PASSED_OVER.with(|steps| steps.set(steps.get() + usize::from(n > 1 && quiet)));
        if n > 1 && !quiet {
            let h = dt / n as f64;
            let (mut pose, mut facing, mut axes) = (start, facing, axes);
            let mut scratch = Pieces::new();
            // How fast the centre may swerve anywhere in the step (`DiffDrive::swerve`).
            let swerve = pieces.iter().fold((0.0f64, 0.0), |(most, from), p| {
                (most.max(self.drive.swerve(p.speeds[0], p.speeds[1], p.end - from)), p.end)
            });
            for k in 1..n {
                let t = t0 + k as f64 * h;
                (pose, facing, axes, _) = self.advanced(pose, facing, axes, h, &mut scratch);
                self.judge(pose, t);
                // Past a closest approach the rest of the step is often quiet: the poses
                // still to come are then left unjudged.
                if judging == Judging::WhereItMatters && k + 1 < n && self.quiet_after(pose, t, n - k, swerve.0) {
                    #[cfg(test)]
                    tests::CUT_SHORT.with(|steps| steps.set(steps.get() + 1));
                    break;
                }
            }
        }
        self.judge(self.pose, self.time);
    }

    /// The pose (facing `facing`) and the axes `span` seconds on from `pose` and `axes`, and
    /// the distance travelled; the pieces of the way (between the ramps' ends, at most
    /// three) into `pieces`.
    fn advanced(
        &self,
        mut pose: Pose,
        mut facing: Point,
        mut axes: [Axis; 2],
        span: f64,
        pieces: &mut Pieces,
    ) -> (Pose, Point, [Axis; 2], f64) {
        let [first, second] = axes.map(|a| a.ramp_left().min(span));
        let ends = if first <= second { [first, second] } else { [second, first] };
        let (mut at, mut travelled) = (0.0, 0.0);
        pieces.clear();
        // Each piece starts at the speeds the last one ended on.
        let mut from = self.rim_speeds(&axes);
        for end in ends.into_iter().chain([span]) {
            if end <= at {
                continue;
            }
            let length = end - at;
            axes.iter_mut().for_each(|a| {
                a.step(length);
            });
            let to = self.rim_speeds(&axes);
            let m = self.drive.motion(from, to, length);
            (pose, facing) = m.apply(pose, facing);
            travelled += m.length;
            pieces.push(Piece { end, pose, speeds: [from, to] });
            (at, from) = (end, to);
        }
        (pose, facing, axes, travelled)
    }

    /// Whether no point of the judging grid strictly inside the step just taken (from
    /// `start` at `t0` to the present pose, `n` points, along `pieces`) can hold a contact
    /// or a new smallest clearance.
    ///
    /// On each piece the robot's centre strays at most the piece's `bow` from its chord
    /// traversed at constant speed ([`DiffDrive::bow`]), and each obstacle keeps one
    /// velocity over the step (checked). So each gap is at least that of the straight-line
    /// relative motion between the piece's ends, less its bow; and that straight-line gap's
    /// smallest value over the grid points on the piece is exact (its distance is convex
    /// in time).
    fn quiet(&self, start: Pose, t0: f64, pieces: &Pieces, n: usize) -> bool {
        let t1 = self.time;
        let whole = pieces.last().map_or(0.0, |p| p.end);
        let h = whole / n as f64;
        // The inner points lie in [h, T - h] (from the step's start): on each piece, the
        // part of that span it holds, as fractions of the piece (None: no part).
        // How far the centre may stray from each piece's chord ([`DiffDrive::bow`]).
        let mut spans = [None; 3];
        let mut bows = [0.0; 3];
        let mut from: f64 = 0.0;
        for ((span, bow), piece) in spans.iter_mut().zip(&mut bows).zip(pieces) {
            let (lo, hi) = (from.max(h), piece.end.min(whole - h));
            let length = piece.end - from;
            if lo <= hi {
                *span = Some(((lo - from) / length, (hi - from) / length));
            }
            *bow = self.drive.bow(piece.speeds[0], piece.speeds[1], length);
            from = piece.end;
        }
        for ((path, _), (min, touch)) in
            self.obstacles.iter().zip(self.judge.min_distance_sqr.iter().zip(&self.judge.touch_sqr))
        {
            if !path.one_velocity_between(t0, t1) {
                return false;
            }
            let at_end = path.position(t1) - self.pose.position;
            let floor = min.min(at_end.norm_sqr()).max(*touch);
            // The offset at each piece's start is the last one's at its end; the last
            // piece ends where the step does.
            let mut r0 = path.position(t0) - start.position;
            for (k, ((piece, span), bow)) in pieces.iter().zip(spans).zip(bows).enumerate() {
                let r1 =
                    if k + 1 == pieces.len() { at_end } else { path.position(t0 + piece.end) - piece.pose.position };
                if span.is_some_and(|(lo, hi)| !chord_clears(r0, r1, lo, hi, bow, floor)) {
                    return false;
                }
                r0 = r1;
            }
        }
        if let Some(half_width) = self.lane_half_width {
            let floor = self.truth.min_wall_clearance.min(half_width - self.pose.position.im.abs()).max(0.0);
            let mut y0 = start.position.im;
            for ((piece, span), bow) in pieces.iter().zip(spans).zip(bows) {
                let y1 = piece.pose.position.im;
                if span.is_some_and(|(lo, hi)| !chord_clears_lines(y0, y1, lo, hi, bow, half_width, floor)) {
                    return false;
                }
                y0 = y1;
            }
        }
        // Off the room's parts the gap changes no faster than the centre moves: it stays
        // above the end's, less the way travelled (each piece's chord and bow).
        let mut from = start.position;
        let way: f64 = pieces
            .iter()
            .zip(bows)
            .map(|(piece, bow)| {
                let chord = (piece.pose.position - from).norm();
                from = piece.pose.position;
                chord + 2.0 * bow
            })
            .sum();
        self.room_quiet(way)
    }

    /// Whether the room's gap, which is at least the present one less `way` anywhere within
    /// `way` of the robot, can hold neither a contact nor a new smallest clearance there.
    fn room_quiet(&self, way: f64) -> bool {
        let Some(g) = self.room.gap(self.pose.position, self.robot_radius) else { return true };
        let floor = self.truth.min_wall_clearance.min(g.gap).max(0.0);
        g.gap - way - CHORD_FUZZ > floor
    }

    /// Whether none of the grid's `points - 1` points still to come, evenly between `pose`
    /// at `t` and the step's end (the present pose), can hold a contact or a new smallest
    /// clearance: `World::quiet`'s test on one chord from `pose` to the end, its bow
    /// from `swerve`, the most the centre's acceleration can be over the step (the chord
    /// may cross the pieces' ends: the speeds are continuous there, so a bound on the
    /// acceleration bounds the bow all the same).
    fn quiet_after(&self, pose: Pose, t: f64, points: usize, swerve: f64) -> bool {
        let t1 = self.time;
        let length = t1 - t;
        let bow = swerve * length * length / 8.0;
        let (lo, hi) = (1.0 / points as f64, (points - 1) as f64 / points as f64);
        for ((path, _), (min, touch)) in
            self.obstacles.iter().zip(self.judge.min_distance_sqr.iter().zip(&self.judge.touch_sqr))
        {
            if !path.one_velocity_between(t, t1) {
                return false;
            }
            let r0 = path.position(t) - pose.position;
            let r1 = path.position(t1) - self.pose.position;
            let floor = min.min(r1.norm_sqr()).max(*touch);
            if !chord_clears(r0, r1, lo, hi, bow, floor) {
                return false;
            }
        }
        if let Some(half_width) = self.lane_half_width {
            let floor = self.truth.min_wall_clearance.min(half_width - self.pose.position.im.abs()).max(0.0);
            let (y0, y1) = (pose.position.im, self.pose.position.im);
            if !chord_clears_lines(y0, y1, lo, hi, bow, half_width, floor) {
                return false;
            }
        }
        self.room_quiet((self.pose.position - pose.position).norm() + 2.0 * bow)
    }

    /// Clearances now: to each obstacle (footprints), and to the nearest wall.
    pub fn clearances(&self) -> impl Iterator<Item = f64> + '_ {
        self.clearances_at(self.pose, self.time)
    }

    fn clearances_at(&self, pose: Pose, t: f64) -> impl Iterator<Item = f64> + '_ {
        self.obstacles
            .iter()
            .map(move |(path, radius)| distance(pose.position, path.position(t)) - radius - self.robot_radius)
    }

    /// Gap between the robot's centre and the nearest lane line now (`+inf` in free space).
    pub fn wall_clearance(&self) -> f64 {
        self.wall_clearance_at(self.pose)
    }

    fn wall_clearance_at(&self, pose: Pose) -> f64 {
        let lane = self.lane_half_width.map_or(f64::INFINITY, |h| h - pose.position.im.abs());
        self.room.gap(pose.position, self.robot_radius).map_or(lane, |g| g.gap.min(lane))
    }

    /// Judge the robot at `pose` at time `t`, a sub-step of the grid.
    fn judge(&mut self, pose: Pose, t: f64) {
        let mut may_touch = false;
        for (((path, _), min), touch) in
            self.obstacles.iter().zip(&mut self.judge.min_distance_sqr).zip(&self.judge.touch_sqr)
        {
            let d = path.position(t) - pose.position;
            let d2 = d.re * d.re + d.im * d.im;
            *min = min.min(d2);
            may_touch |= d2 < *touch;
        }
        let wall = self.wall_clearance_at(pose);
        self.truth.min_wall_clearance = self.truth.min_wall_clearance.min(wall);
        let judged = self.truth.first_contact.is_some() && self.truth.first_active_contact.is_some();
        if !judged && (may_touch || wall < 0.0) {
            let obstacle = self.clearances_at(pose, t).fold(f64::INFINITY, f64::min);
            if obstacle < 0.0 || wall < 0.0 {
                let contact = self.contact(pose, t, obstacle, wall);
                if self.truth.first_contact.is_none() {
                    self.truth.first_contact = Some(t);
                    self.truth.contact = Some(contact);
                }
                if contact.active && self.truth.first_active_contact.is_none() {
                    self.truth.first_active_contact = Some(contact);
                }
            }
        }
    }

    /// The contact happening at `pose` at `t`: the deeper overlap is what was touched.
    fn contact(&self, pose: Pose, t: f64, obstacle: f64, wall: f64) -> Contact {
        let [left, right] = self.wheel_speeds();
        let velocity = Point::from_polar(0.5 * (left + right), pose.heading);
        let (with, normal) = if obstacle <= wall {
            let k = self
                .clearances_at(pose, t)
                .enumerate()
                .fold((0, f64::INFINITY), |m, (k, c)| if c < m.1 { (k, c) } else { m })
                .0;
            let d = self.obstacles[k].0.position(t) - pose.position;
            (Touched::Obstacle(k), d / d.norm())
        } else {
            let lane = self.lane_half_width.map_or(f64::INFINITY, |h| h - pose.position.im.abs());
            match self.room.gap(pose.position, self.robot_radius).filter(|g| g.gap < lane) {
                Some(g) => (g.with, g.toward),
                None => (Touched::Wall, Point::new(0.0, pose.position.im.signum())),
            }
        };
        let approach_speed = velocity.re * normal.re + velocity.im * normal.im;
        Contact { at: t, with, approach_speed, active: approach_speed > ACTIVE_CONTACT_SPEED }
    }
}

/// Euclidean distance. `sqrt` of the squares, not `hypot`: the world evaluates this every
/// millisecond of every run, and its points are far from overflow.
fn distance(a: Point, b: Point) -> f64 {
    let d = a - b;
    (d.re * d.re + d.im * d.im).sqrt()
}

/// Rounding in the chord tests is some 1e-16 m; a nanometre is far above it.
const CHORD_FUZZ: f64 = 1e-9;

/// Whether the offset to an obstacle, going along the chord from `r0` to `r1` and straying
/// from it by at most `bow`, stays above `floor` (a squared distance) at every fraction of
/// the chord in `[lo, hi]`: the chord's distance is convex, so its least value there is at
/// the clamped foot of the perpendicular.
fn chord_clears(r0: Point, r1: Point, lo: f64, hi: f64, bow: f64, floor: f64) -> bool {
    let change = r1 - r0;
    let along = change.norm_sqr();
    let tau = if along > 0.0 { (-(r0.re * change.re + r0.im * change.im) / along).clamp(lo, hi) } else { lo };
    let gap = (r0 + change * tau).norm_sqr().sqrt() - bow - CHORD_FUZZ;
    gap > 0.0 && gap * gap > floor
}

/// Whether the centre, going along the chord from `y0` to `y1` across the lane (straying by
/// at most `bow`), keeps more than `floor` from both lines at every fraction in `[lo, hi]`:
/// `|y|` is convex along the chord, so its largest value is at an end.
fn chord_clears_lines(y0: f64, y1: f64, lo: f64, hi: f64, bow: f64, half_width: f64, floor: f64) -> bool {
    let at = |tau: f64| (y0 + (y1 - y0) * tau).abs();
    half_width - at(lo).max(at(hi)) - bow - CHORD_FUZZ > floor
}

/// Which points of a step's grid are judged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Judging {
    /// The end, and the inner points only where they could change the truth.
    WhereItMatters,
    /// Every point (what the first is checked against).
    #[cfg_attr(not(test), allow(dead_code))]
    EveryPoint,
}

/// A piece of a step: where it ends (s from the step's start), the pose there, and the
/// wheels' speeds at its start and its end (linear between).
#[derive(Debug, Clone, Copy)]
struct Piece {
    end: f64,
    pose: Pose,
    speeds: [[f64; 2]; 2],
}

/// A step's pieces: up to the two ramps' ends, then on to the step's end.
type Pieces = arrayvec::ArrayVec<Piece, 3>;

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    thread_local! {
        /// Steps whose inner points were passed over, on this test's thread.
        pub static PASSED_OVER: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
        /// Steps whose inner points were judged only up to where the rest was quiet.
        pub static CUT_SHORT: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
    }

    /// A robot driven by random commands (held for 1-10 periods, so both ramps and steady
    /// arcs) among obstacles placed about its way, standing, moving straight or along
    /// waypoints, in free space or a lane.
    fn random_world(rng: &mut ChaCha8Rng) -> (World, Vec<[i32; 2]>) {
        // Drawn again until the loader takes it (no obstacle on the start or the goal).
        let scenario = loop {
            if let Ok(scenario) = Scenario::from_toml(&random_scenario(rng), "random") {
                break scenario;
            }
        };
        let world = World::new(&scenario);
        let max = world.axes()[LEFT].config().max_rate as i32;
        let mut commands = Vec::new();
        while commands.len() < 400 {
            let rates = [rng.random_range(-max / 4..max), rng.random_range(-max / 4..max)];
            let hold = rng.random_range(1..10);
            commands.extend(std::iter::repeat_n(rates, hold));
        }
        (world, commands)
    }

    fn random_scenario(rng: &mut ChaCha8Rng) -> String {
        let lane = rng.random_bool(0.3);
        let mut obstacles = String::new();
        for _ in 0..rng.random_range(1..4) {
            let start = [rng.random_range(-0.4..0.4), rng.random_range(-0.15..0.15)];
            let motion = match rng.random_range(0..3) {
                0 => "{ kind = \"stationary\" }".to_string(),
                1 => format!(
                    "{{ kind = \"constant\", velocity = [{}, {}] }}",
                    rng.random_range(-0.15..0.15),
                    rng.random_range(-0.15..0.15)
                ),
                _ => format!(
                    "{{ kind = \"waypoints\", points = [[{}, {}], [{}, {}]], speed = {}, repeat = {} }}",
                    rng.random_range(-0.4..0.4),
                    rng.random_range(-0.15..0.15),
                    rng.random_range(-0.4..0.4),
                    rng.random_range(-0.15..0.15),
                    rng.random_range(0.02..0.2),
                    rng.random_bool(0.5)
                ),
            };
            obstacles += &format!(
                "[[obstacles]]\nradius = {}\nstart = [{}, {}]\nmotion = {motion}\n",
                rng.random_range(0.03..0.1),
                start[0],
                start[1]
            );
        }
        format!(
            "name = \"random\"\ntime_limit = 30\n{}\
             [robot]\nstart = [-0.5, 0.0]\nheading_deg = {}\nradius = 0.07\nwheel_base = 0.108\n\
             wheel_radius = 0.025\nsteps_per_rev = 200\nmicrosteps = 8\nmax_wheel_speed = 0.25\n\
             wheel_accel = {}\nmax_speed = 0.25\n[goal]\nposition = [0.5, 0.0]\n{obstacles}\
             [sensing]\nsample_time = 0.02\n",
            if lane { "[lane]\nhalf_width = 0.2\n" } else { "" },
            rng.random_range(-30.0..30.0),
            rng.random_range(0.3..3.0),
        )
    }

    /// Judging only where it matters leaves the truth exactly as judging every point of the
    /// grid: the same smallest clearances, bit for bit, and the same first contact.
    #[test]
    fn judging_where_it_matters_is_judging_everywhere() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (mut contacts, mut close, mut steps) = (0, 0, 0);
        for case in 0..300 {
            let (mut quick, commands) = random_world(&mut rng);
            let mut every = quick.clone();
            // Periods of 20 ms, and now and then an odd one, as the full stack's events make.
            for (k, rates) in commands.iter().enumerate() {
                let dt = if k % 7 == 3 { 0.0173 } else { 0.02 };
                quick.command_pulse_rates(*rates);
                every.command_pulse_rates(*rates);
                quick.step(dt);
                every.step_judging(dt, Judging::EveryPoint);
                steps += 1;
                assert_eq!(quick.pose(), every.pose(), "case {case}, step {k}");
            }
            let (a, b) = (quick.truth(), every.truth());
            assert_eq!(a.min_obstacle_clearance.to_bits(), b.min_obstacle_clearance.to_bits(), "case {case}");
            assert_eq!(a.min_wall_clearance.to_bits(), b.min_wall_clearance.to_bits(), "case {case}");
            assert_eq!(a.contact, b.contact, "case {case}");
            contacts += usize::from(a.contact.is_some());
            close += usize::from(a.min_obstacle_clearance < 0.01);
        }
        // The cases reach what the check is about: contacts and close approaches (182 and
        // 157 of the 300), most steps passed over (68%), and a quarter of the rest cut short
        // (the seed fixes every figure).
        let passed_over = PASSED_OVER.with(|steps| steps.get());
        let cut_short = CUT_SHORT.with(|steps| steps.get());
        assert_eq!(
            (contacts, close, passed_over, cut_short, steps),
            (182, 157, 82_050, 9_959, 120_781),
            "contacts, close, passed over, cut short, steps"
        );
    }

    /// The same holds in a room: a random scenario's world between two walls with a table,
    /// where the random drive runs into them (the room's gap bounds what steps pass over).
    #[test]
    fn judging_where_it_matters_is_judging_everywhere_in_a_room() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut touched_room = 0;
        for case in 0..100 {
            let scenario = loop {
                let table_x = rng.random_range(-0.3..0.3);
                let text = random_scenario(&mut rng).replace("[lane]\nhalf_width = 0.2\n", "")
                    + &format!(
                        "[[walls]]\npoints = [[-1.0, 0.35], [1.0, 0.35]]\n[[walls]]\npoints = [[-1.0, -0.35], [0.2, -0.35], [0.2, -0.6]]\n\
                         [[static_obstacles]]\npoints = [[{table_x}, 0.12], [{}, 0.12], [{}, 0.3], [{table_x}, 0.3]]\n",
                        table_x + 0.2,
                        table_x + 0.2
                    );
                if let Ok(s) = Scenario::from_toml(&text, "random room") {
                    break s;
                }
            };
            let mut quick = World::new(&scenario);
            let mut every = quick.clone();
            let max = quick.axes()[LEFT].config().max_rate as i32;
            for k in 0..300 {
                let rates = [rng.random_range(-max / 4..max), rng.random_range(-max / 4..max)];
                let dt = if k % 7 == 3 { 0.0173 } else { 0.02 };
                for w in [&mut quick, &mut every] {
                    w.command_pulse_rates(rates);
                }
                quick.step(dt);
                every.step_judging(dt, Judging::EveryPoint);
            }
            let (a, b) = (quick.truth(), every.truth());
            assert_eq!(a.min_wall_clearance.to_bits(), b.min_wall_clearance.to_bits(), "case {case}");
            assert_eq!(a.contact, b.contact, "case {case}");
            touched_room += usize::from(a.contact.is_some_and(|c| !matches!(c.with, Touched::Obstacle(_))));
        }
        let passed = PASSED_OVER.with(|steps| steps.get());
        // 23 of the 100 drives touch a wall or the table first (the seed fixes it).
        assert!(touched_room >= 20, "the drives reach the walls and the table: {touched_room} of 100");
        assert!(passed > 0, "and steps away from them are passed over");
    }

    /// Driven straight into a wall, the robot's first contact is the wall's, active; into a
    /// table, the table's, named by its index.
    #[test]
    fn walls_and_static_obstacles_are_touched_and_named() {
        let base = "name = \"room\"\ntime_limit = 30\n[robot]\nstart = [0.0, 0.0]\nheading_deg = 90\nradius = 0.07\n\
                    wheel_base = 0.108\nwheel_radius = 0.025\nsteps_per_rev = 200\nmicrosteps = 8\nmax_wheel_speed = 0.25\n\
                    wheel_accel = 1.0\nmax_speed = 0.25\n[goal]\nposition = [0.5, 0.0]\n[sensing]\nsample_time = 0.02\n";
        let run = |room: &str| {
            let mut world = World::new(&Scenario::from_toml(&format!("{base}{room}"), "room").unwrap());
            let rate = (0.1 * world.drive.pulses_per_metre) as i32;
            world.command_pulse_rates([rate, rate]);
            for _ in 0..200 {
                world.step(0.02);
            }
            world.truth()
        };
        let wall = run("[[walls]]\npoints = [[-1.0, 0.3], [1.0, 0.3]]\n");
        let c = wall.contact.unwrap();
        assert_eq!(c.with, Touched::Wall);
        // 23 cm to go at 0.1 m/s, after a 0.1 s ramp at 1 m/s² (half of it lost).
        assert!(c.active && (c.approach_speed - 0.1).abs() < 1e-3 && (c.at - 2.35).abs() < 0.005, "{c:?}");
        assert!(wall.min_wall_clearance < 0.0);
        let table = run("[[static_obstacles]]\npoints = [[-0.2, 0.4], [0.2, 0.4], [0.0, 0.6]]\n");
        assert_eq!(table.contact.unwrap().with, Touched::StaticObstacle(0));
        let e = Scenario::from_toml(
            &format!("{base}[[static_obstacles]]\npoints = [[-0.2, -0.05], [0.2, -0.05], [0.0, 0.2]]\n"),
            "room",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("robot.start") && e.contains("static_obstacles[0]"), "{e}");
    }
}
