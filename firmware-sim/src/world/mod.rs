//! The simulated world: a differential-drive robot whose wheels turn by the pulses of a
//! two-axis pulse generator, obstacles that follow their scripts, optional lane walls, and
//! the truth a run is judged by (contact, clearance against the true radii).
//!
//! Time is an argument: [`World::step`] advances by `dt`, nothing reads a clock. Between
//! commands the robot's way is a closed-form function of the time from where it was last
//! commanded, so the world costs the same however many instants it is asked about; what
//! happened over the way (contact, clearance) is judged exactly (`judge.rs`), not at
//! sampled instants.

mod axis;
pub mod fleet;
mod judge;
mod obstacle;
pub mod people;
mod robot;
mod room;

use std::cell::Cell;

use judge::{Judge, Moment, Scene, Settled, Way};

pub use axis::{Axis, AxisConfig};
pub use obstacle::ObstaclePath;
pub use robot::{DiffDrive, Motion, Pose};
pub use room::{Room, RoomGap};

use crate::scenario::SimScenario;
use crate::Point;

/// Which wheel an axis drives.
pub const LEFT: usize = 0;
pub const RIGHT: usize = 1;

/// The world of one scenario.
///
/// It holds the state it was last *settled* at (when a command last changed the axes) and
/// the time now; the robot now, and at any instant between, follows from the settled state
/// in closed form. The truth is judged up to the settled state, and from there to now when
/// asked, without settling: what the world is asked never changes what it does.
#[derive(Debug, Clone)]
pub struct World {
    time: f64,
    settled: Settled,
    /// Time since the settled state, s: the steps' sum, so that one step from it is its
    /// `dt` exactly.
    since_settled: f64,
    /// The robot now (`time`), once asked for.
    now: Cell<Option<Moment>>,
    drive: DiffDrive,
    robot_radius: f64,
    obstacles: Vec<(ObstaclePath, f64)>,
    /// People who see the robot, walking as the world runs (`None`: none do, and every way
    /// was walked when the world was made).
    people: Option<people::Crowd>,
    lane_half_width: Option<f64>,
    room: Room,
    /// What happened up to the settled state.
    judge: Judge,
    path_length: f64,
    /// Largest pulse rate of each axis up to the settled state, pulses/s.
    peak_rate: [f64; 2],
    /// No contact can begin before this time, s: each gap at the settled state, closed at
    /// the most the robot and the obstacle can move.
    contact_free_until: f64,
    /// A calibration wand: an LED someone holds on the floor (its id and where it stands;
    /// `None` = held out of sight).
    wand: Option<(u8, Option<Point>)>,
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

/// The first contact of a run, judged at the instant it began.
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
    pub fn new(scenario: &SimScenario) -> Self {
        let r = &scenario.robot;
        let drive = DiffDrive { wheel_base: r.wheel_base, pulses_per_metre: r.pulses_per_metre() };
        let axis = AxisConfig {
            accel: r.wheel_accel * drive.pulses_per_metre,
            max_rate: r.max_wheel_speed * drive.pulses_per_metre,
        };
        let heading = r.heading_deg.to_radians();
        let (ways, people) = people::start(scenario);
        let mut world = Self {
            time: 0.0,
            since_settled: 0.0,
            settled: Settled {
                time: 0.0,
                pose: Pose { position: scenario.robot_start(), heading },
                facing: Point::from_polar(1.0, heading),
                axes: [Axis::new(axis), Axis::new(axis)],
            },
            now: Cell::new(None),
            drive,
            robot_radius: r.radius,
            obstacles: ways.into_iter().zip(&scenario.obstacles).map(|(p, o)| (p, o.radius)).collect(),
            people,
            lane_half_width: scenario.lane.map(|l| l.half_width),
            room: Room::new(scenario),
            judge: Judge::new(scenario.obstacles.len()),
            path_length: 0.0,
            peak_rate: [0.0; 2],
            contact_free_until: 0.0,
            wand: None,
        };
        let start = world.moment_settled();
        let mut judge = std::mem::replace(&mut world.judge, Judge::new(0));
        judge.instant(&world.scene(), &start);
        world.judge = judge;
        world.contact_free_until = world.contact_free_from(&start);
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
        self.moment().pose
    }
    /// The heading as a unit vector (the pose's, integrated without angles).
    pub fn facing(&self) -> Point {
        self.moment().facing
    }
    pub fn robot_radius(&self) -> f64 {
        self.robot_radius
    }

    /// The robot now: from the settled state in closed form, once per instant asked.
    #[inline(never)] // an entry point `scripts/sweep-instructions` counts
    fn moment(&self) -> Moment {
        if let Some(m) = self.now.get() {
            return m;
        }
        let m = Way::from(self.settled, self.drive).after(self.since_settled, self.time);
        self.now.set(Some(m));
        m
    }

    /// The way from the settled state as far as now, and the robot now.
    fn way_now(&self) -> (Way, Moment) {
        let way = Way::to(self.settled, self.drive, self.since_settled);
        // The robot now as `moment` has it, taken without it (it is counted on its own).
        (way, self.now.get().unwrap_or_else(|| way.after(self.since_settled, self.time)))
    }

    fn scene(&self) -> Scene<'_> {
        Scene {
            obstacles: &self.obstacles,
            lane_half_width: self.lane_half_width,
            room: &self.room,
            robot_radius: self.robot_radius,
        }
    }

    /// What happened up to now: the settled judgement, and the way since judged on a copy.
    #[inline(never)] // an entry point `scripts/sweep-instructions` counts
    fn judged_now(&self) -> (Judge, Moment) {
        let (way, end) = self.way_now();
        let mut judge = self.judge.clone();
        if self.since_settled > 0.0 {
            judge.interval(&self.scene(), &way, &way.after(0.0, self.settled.time), &end);
        }
        (judge, end)
    }

    /// What really happened so far.
    pub fn truth(&self) -> Truth {
        let (judge, now) = self.judged_now();
        let min_obstacle_clearance = judge
            .min_distance
            .iter()
            .zip(&self.obstacles)
            .map(|(d, (_, radius))| d - radius - self.robot_radius)
            .fold(f64::INFINITY, f64::min);
        let peak_rate = [0, 1].map(|k| self.peak_rate[k].max(now.axes[k].rate().abs()));
        Truth {
            min_obstacle_clearance,
            min_wall_clearance: judge.min_wall_clearance,
            first_contact: judge.contact.map(|c| c.at),
            contact: judge.contact,
            first_active_contact: judge.active_contact,
            path_length: self.path_length + now.travelled,
            peak_wheel_speed: peak_rate.map(|r| r / self.drive.pulses_per_metre),
        }
    }
    /// When the robot first touched an obstacle or a wall, s (as [`Truth::first_contact`]),
    /// cheaply while no contact can have begun.
    pub fn first_contact(&self) -> Option<f64> {
        if let Some(c) = self.judge.contact {
            return Some(c.at);
        }
        if self.time < self.contact_free_until {
            return None;
        }
        self.judged_now().0.contact.map(|c| c.at)
    }
    /// The axes now.
    #[inline(never)] // an entry point `scripts/sweep-instructions` counts
    pub fn axes(&self) -> [Axis; 2] {
        let span = self.since_settled;
        self.settled.axes.map(|mut a| {
            if span > 0.0 {
                a.step(span);
            }
            a
        })
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
    #[inline(never)] // an entry point `scripts/sweep-instructions` counts
    pub fn wheel_speeds(&self) -> [f64; 2] {
        let span = self.since_settled;
        self.settled.axes.map(|a| a.rate_after(span) / self.drive.pulses_per_metre)
    }

    /// Set both axes' target pulse rates (pulses/s), as a velocity command does.
    pub fn command_pulse_rates(&mut self, rates: [i32; 2]) {
        self.change_axes(|axes| {
            axes[LEFT].set_target(rates[LEFT]);
            axes[RIGHT].set_target(rates[RIGHT]);
        });
    }

    /// One axis's target rate (one CiA 402 drive a wheel), clamped to its limit.
    pub fn command_axis(&mut self, axis: usize, rate: i32) {
        self.change_axes(|axes| {
            if let Some(a) = axes.get_mut(axis) {
                a.set_target(rate);
            }
        });
    }

    /// One axis's ramp and rate limit.
    pub fn configure_axis(&mut self, axis: usize, config: AxisConfig) {
        self.change_axes(|axes| {
            if let Some(a) = axes.get_mut(axis) {
                a.set_config(config);
            }
        });
    }

    /// Stop one axis at once (its drive lost power, or its wheel is blocked).
    pub fn stop_axis(&mut self, axis: usize) {
        self.change_axes(|axes| {
            if let Some(a) = axes.get_mut(axis) {
                a.stop_now();
            }
        });
    }

    /// Set both axes' ramp and rate limit (pulses).
    pub fn configure_axes(&mut self, config: AxisConfig) {
        self.change_axes(|axes| axes.iter_mut().for_each(|a| a.set_config(config)));
    }

    /// Stop both axes at once (e-stop, command timeout).
    pub fn stop_axes(&mut self) {
        self.change_axes(|axes| axes.iter_mut().for_each(Axis::stop_now));
    }

    /// Settle, then change the axes: the way on starts from here.
    fn change_axes(&mut self, change: impl FnOnce(&mut [Axis; 2])) {
        self.settle();
        change(&mut self.settled.axes);
        let now = self.moment_settled();
        self.now.set(Some(now));
        // A new rate limit changes how soon a contact can begin.
        self.contact_free_until = self.contact_free_from(&now);
    }

    /// The robot at the settled state.
    fn moment_settled(&self) -> Moment {
        let Settled { time, pose, facing, axes } = self.settled;
        let [left, right] = axes.map(|a| a.rate() / self.drive.pulses_per_metre);
        Moment { t: time, pose, facing, velocity: facing * (0.5 * (left + right)), axes, travelled: 0.0 }
    }

    /// Advance the world by `dt` seconds: nothing is computed until asked for.
    pub fn step(&mut self, dt: f64) {
        if dt.is_nan() || dt <= 0.0 {
            return;
        }
        self.walk_people(self.time + dt);
        self.time += dt;
        self.since_settled += dt;
        self.now.set(None);
    }

    /// People who walk as the world runs walk each step that begins by `until`, those who
    /// see the robot seeing it where it is at the step's start (the axes hold from the
    /// settled state to `until`: a command settles the world first), so that their ways
    /// are known up to `until`.
    fn walk_people(&mut self, until: f64) {
        // A step to no finite time walks nobody (they would walk for ever).
        let Some(crowd) = self.people.as_mut().filter(|_| until.is_finite()) else { return };
        let sees = crowd.sees_vehicles();
        while crowd.time() <= until {
            let t = crowd.time();
            if sees {
                let (position, velocity) = Self::body_at(self.settled, self.drive, t);
                crowd.step_beside(&[(position, velocity, self.robot_radius)]);
            } else {
                crowd.step();
            }
            // Known up to the crowd's time now: past `until`, whatever the rounding of
            // `t + STEP` (at `until` itself a way would otherwise read as standing).
            let walked = crowd.time();
            for (k, t0, from, v) in crowd.last_legs() {
                self.obstacles[k].0.walk_on(t0, from, v, walked);
            }
        }
    }

    /// Where the robot is at `t` and how fast it goes, from the `settled` state on its axes
    /// as they are (no command comes between).
    fn body_at(settled: Settled, drive: DiffDrive, t: f64) -> (Point, Point) {
        let span = t - settled.time;
        let robot = Way::to(settled, drive, span).after(span, t);
        (robot.pose.position, robot.velocity)
    }

    /// The robot at `t`, at or after the world's time (position, velocity, radius): what a
    /// person who sees it sees.
    pub fn body_seen_at(&self, t: f64) -> (Point, Point, f64) {
        let (position, velocity) = Self::body_at(self.settled, self.drive, t);
        (position, velocity, self.robot_radius)
    }

    /// The people who walk as this world runs, taken out: a fleet walks them once, beside
    /// every vehicle, and hands each world their legs ([`World::walk_on`]).
    pub fn take_people(&mut self) -> Option<people::Crowd> {
        self.people.take()
    }

    /// Obstacle `k`, a person walking, goes on at `t` from `from` at `v` until `until`.
    pub fn walk_on(&mut self, k: usize, t: f64, from: Point, v: Point, until: f64) {
        self.obstacles[k].0.walk_on(t, from, v, until);
    }

    /// Bring the settled state up to now, judging the way there, before a command changes
    /// the axes. The wheels follow the boards' ramps exactly and the pose is integrated
    /// along them (see [`DiffDrive::motion`]) in one piece between the ramps' ends, however
    /// many instants the world was asked about on the way.
    #[inline(never)] // an entry point `scripts/sweep-instructions` counts
    fn settle(&mut self) {
        if self.since_settled <= 0.0 {
            return;
        }
        let (way, end) = self.way_now();
        let start = way.after(0.0, self.settled.time);
        // Taken out while it judges what the rest of the world holds.
        let mut judge = std::mem::replace(&mut self.judge, Judge::new(0));
        judge.interval(&self.scene(), &way, &start, &end);
        self.judge = judge;
        self.path_length += end.travelled;
        for (peak, axis) in self.peak_rate.iter_mut().zip(&end.axes) {
            // A ramp is monotone: the way's fastest rate is at one of its ends.
            *peak = peak.max(axis.rate().abs());
        }
        self.settled = Settled { time: end.t, pose: end.pose, facing: end.facing, axes: end.axes };
        self.since_settled = 0.0;
    }

    /// The earliest a contact can begin after the robot was at `m` (as the axes are now):
    /// each obstacle's gap closed at the robot's top speed and the obstacle's, each wall's
    /// at the robot's.
    fn contact_free_from(&self, m: &Moment) -> f64 {
        if self.judge.contact.is_some() {
            return f64::INFINITY;
        }
        let top = m.axes.iter().map(|a| a.rate().abs().max(a.config().max_rate)).fold(0.0, f64::max)
            / self.drive.pulses_per_metre;
        let mut soonest = f64::INFINITY;
        for (path, radius) in &self.obstacles {
            let gap = (path.position(m.t) - m.pose.position).norm() - radius - self.robot_radius;
            soonest = soonest.min(gap / (top + path.top_speed()));
        }
        let wall = self.wall_clearance_at(m.pose);
        soonest = soonest.min(wall / top);
        // A gap of zero or less, or nothing moving toward it: the division says so.
        if soonest.is_nan() || soonest <= 0.0 {
            return m.t;
        }
        m.t + soonest
    }

    /// Clearances now: to each obstacle (footprints), and to the nearest wall.
    pub fn clearances(&self) -> impl Iterator<Item = f64> + '_ {
        let (pose, t) = (self.pose(), self.time);
        self.obstacles
            .iter()
            .map(move |(path, radius)| (path.position(t) - pose.position).norm() - radius - self.robot_radius)
    }

    /// Gap between the robot's centre and the nearest lane line now (`+inf` in free space).
    pub fn wall_clearance(&self) -> f64 {
        self.wall_clearance_at(self.pose())
    }

    fn wall_clearance_at(&self, pose: Pose) -> f64 {
        let lane = self.lane_half_width.map_or(f64::INFINITY, |h| h - pose.position.im.abs());
        self.room.gap(pose.position, self.robot_radius).map_or(lane, |g| g.gap.min(lane))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A robot driven by random commands (held for 1-10 periods, so both ramps and steady
    /// arcs) among obstacles placed about its way, standing, moving straight or along
    /// waypoints, in free space or a lane.
    fn random_world(rng: &mut ChaCha8Rng) -> (World, Vec<[i32; 2]>) {
        // Drawn again until the loader takes it (no obstacle on the start or the goal).
        let scenario = loop {
            if let Ok(scenario) = SimScenario::from_toml(&random_scenario(rng), "random") {
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

    /// The truth found by brute force: the world sampled every `GRAIN` seconds along each
    /// command's way, each least value (and each contact's beginning) then refined between
    /// the samples about it. Slow and independent of the judge: it shares only the way.
    struct Reference {
        min_obstacle_clearance: f64,
        min_wall_clearance: f64,
        first_contact: Option<f64>,
    }

    const GRAIN: f64 = 1e-4;

    /// Every gap at `t` on the way from `world`'s settled state: each obstacle's clearance,
    /// then the wall's.
    fn gaps(world: &World, t: f64) -> Vec<f64> {
        let mut probe = world.clone();
        probe.step(t - world.time);
        probe.clearances().chain([probe.wall_clearance()]).collect()
    }

    fn least_near(world: &World, k: usize, lo: f64, hi: f64) -> f64 {
        let (mut lo, mut hi) = (lo, hi);
        // Golden-section search: each gap is unimodal so near its least value.
        for _ in 0..80 {
            let (m1, m2) = (lo + (hi - lo) * 0.382, lo + (hi - lo) * 0.618);
            if gaps(world, m1)[k] < gaps(world, m2)[k] {
                hi = m2;
            } else {
                lo = m1;
            }
        }
        gaps(world, 0.5 * (lo + hi))[k]
    }

    /// Drive `world` by `commands`, each held `dt`, judging by brute force as it goes.
    fn drive_by_reference(world: &mut World, commands: &[[i32; 2]], dt: f64) -> Reference {
        let mut least: Vec<f64> = gaps(world, 0.0);
        let mut first_contact = least.iter().any(|g| *g < 0.0).then_some(0.0);
        for rates in commands {
            world.command_pulse_rates(*rates);
            let t0 = world.time;
            let n = (dt / GRAIN).round() as usize;
            let at = |j: usize| t0 + dt * j as f64 / n as f64;
            let samples: Vec<Vec<f64>> = (0..=n).map(|j| gaps(world, at(j))).collect();
            for k in 0..least.len() {
                let j = (0..=n).min_by(|&x, &y| samples[x][k].total_cmp(&samples[y][k])).unwrap_or(0);
                let refined = least_near(world, k, at(j.saturating_sub(1)), at((j + 1).min(n)));
                least[k] = least[k].min(samples[j][k]).min(refined);
            }
            if first_contact.is_none() {
                if let Some(j) = (1..=n).find(|&j| samples[j].iter().any(|g| *g < 0.0)) {
                    let (mut lo, mut hi) = (at(j - 1), at(j));
                    while hi - lo > 1e-10 {
                        let mid = 0.5 * (lo + hi);
                        if gaps(world, mid).iter().any(|g| *g < 0.0) {
                            hi = mid;
                        } else {
                            lo = mid;
                        }
                    }
                    first_contact = Some(hi);
                }
            }
            world.step(dt);
        }
        let (obstacles, wall) = least.split_at(least.len() - 1);
        Reference {
            min_obstacle_clearance: obstacles.iter().copied().fold(f64::INFINITY, f64::min),
            min_wall_clearance: wall[0],
            first_contact,
        }
    }

    /// The judge's truth is the brute force's: every least clearance within two nanometres
    /// (the judge's within one of the exact value, the reference's refined about its least
    /// sample of every 0.1 ms), and the first contact at the same instant.
    fn judged_as_by_brute_force(world: World, commands: &[[i32; 2]], dt: f64) -> Truth {
        let mut judged = world.clone();
        let mut brute = world;
        for rates in commands {
            judged.command_pulse_rates(*rates);
            judged.step(dt);
        }
        let reference = drive_by_reference(&mut brute, commands, dt);
        let truth = judged.truth();
        for (what, exact, sampled) in [
            ("obstacle", truth.min_obstacle_clearance, reference.min_obstacle_clearance),
            ("wall", truth.min_wall_clearance, reference.min_wall_clearance),
        ] {
            if sampled.is_finite() {
                assert!((exact - sampled).abs() < 2e-9, "{what}: judged {exact}, brute force {sampled}");
            }
        }
        match (truth.first_contact, reference.first_contact) {
            (Some(a), Some(b)) => assert!((a - b).abs() < 1e-8, "contact at {a}, brute force {b}"),
            (a, b) => assert_eq!(a, b, "a contact judged, and by brute force"),
        }
        truth
    }

    /// Judged exactly, the truth is the brute force's, in free space and between lane lines,
    /// among obstacles standing, moving straight and along waypoints (their legs' ends
    /// falling inside the ways).
    #[test]
    fn the_judge_finds_what_brute_force_finds() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (mut contacts, mut close) = (0, 0);
        for _ in 0..24 {
            let (world, commands) = random_world(&mut rng);
            let truth = judged_as_by_brute_force(world, &commands, 0.0173);
            contacts += usize::from(truth.contact.is_some());
            close += usize::from(truth.min_obstacle_clearance < 0.01);
        }
        // The cases reach what the check is about: contacts, and approaches within a
        // centimetre (the seed fixes the counts).
        assert_eq!((contacts, close), (14, 12), "contacts, close approaches of 24");
    }

    /// The same in a room: two walls and a table the random drives run into.
    #[test]
    fn the_judge_finds_what_brute_force_finds_in_a_room() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut touched_room = 0;
        for _ in 0..40 {
            let (world, commands) = random_room(&mut rng);
            let truth = judged_as_by_brute_force(world, &commands, 0.02);
            touched_room += usize::from(truth.contact.is_some_and(|c| !matches!(c.with, Touched::Obstacle(_))));
        }
        assert_eq!(touched_room, 11, "of the 40 drives, those that touch a wall or the table first");
    }

    /// What the world is asked, and how often its time is advanced, changes nothing it does:
    /// a world asked its pose, axes and truth at every millisecond ends bit for bit as one
    /// stepped once a command.
    #[test]
    fn asking_changes_nothing() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for case in 0..20 {
            let (mut quiet, commands) = random_world(&mut rng);
            let mut asked = quiet.clone();
            for (k, rates) in commands.iter().take(100).enumerate() {
                quiet.command_pulse_rates(*rates);
                asked.command_pulse_rates(*rates);
                // Binary fractions, so the times add up exactly either way.
                quiet.step(1.0 / 64.0);
                for _ in 0..16 {
                    asked.step(1.0 / 1024.0);
                    let _ = (asked.pose(), asked.axes(), asked.truth(), asked.first_contact());
                }
                assert_eq!(asked.time().to_bits(), quiet.time().to_bits(), "case {case}, command {k}");
                assert_eq!((asked.pose(), asked.axes()), (quiet.pose(), quiet.axes()), "case {case}, command {k}");
            }
            let (a, b) = (asked.truth(), quiet.truth());
            assert_eq!(format!("{a:?}"), format!("{b:?}"), "case {case}");
        }
    }

    fn random_room(rng: &mut ChaCha8Rng) -> (World, Vec<[i32; 2]>) {
        let scenario = loop {
            let table_x = rng.random_range(-0.3..0.3);
            let text = random_scenario(rng).replace("[lane]\nhalf_width = 0.2\n", "")
                + &format!(
                    "[[walls]]\npoints = [[-1.0, 0.35], [1.0, 0.35]]\n[[walls]]\npoints = [[-1.0, -0.35], [0.2, -0.35], [0.2, -0.6]]\n\
                     [[static_obstacles]]\npoints = [[{table_x}, 0.12], [{}, 0.12], [{}, 0.3], [{table_x}, 0.3]]\n",
                    table_x + 0.2,
                    table_x + 0.2
                );
            if let Ok(s) = SimScenario::from_toml(&text, "random room") {
                break s;
            }
        };
        let world = World::new(&scenario);
        let max = world.axes()[LEFT].config().max_rate as i32;
        let commands = (0..300).map(|_| [rng.random_range(-max / 4..max), rng.random_range(-max / 4..max)]).collect();
        (world, commands)
    }

    /// Driven straight into a wall, the robot's first contact is the wall's, active; into a
    /// table, the table's, named by its index.
    #[test]
    fn walls_and_static_obstacles_are_touched_and_named() {
        let base = "name = \"room\"\ntime_limit = 30\n[robot]\nstart = [0.0, 0.0]\nheading_deg = 90\nradius = 0.07\n\
                    wheel_base = 0.108\nwheel_radius = 0.025\nsteps_per_rev = 200\nmicrosteps = 8\nmax_wheel_speed = 0.25\n\
                    wheel_accel = 1.0\nmax_speed = 0.25\n[goal]\nposition = [0.5, 0.0]\n[sensing]\nsample_time = 0.02\n";
        let run = |room: &str| {
            let mut world = World::new(&SimScenario::from_toml(&format!("{base}{room}"), "room").unwrap());
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
        let e = SimScenario::from_toml(
            &format!("{base}[[static_obstacles]]\npoints = [[-0.2, -0.05], [0.2, -0.05], [0.0, 0.2]]\n"),
            "room",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("robot.start") && e.contains("static_obstacles[0]"), "{e}");
    }
}
