//! Scenario files (TOML) as the simulator reads them ([`SimScenario`]): the rig, the robot,
//! the goal, the obstacles' motion, the sensing chain and the planner settings of one run. The `[planner]` table is the gateway's: the
//! simulator carries it unread, and flowgate parses and checks it with the same type and
//! rules as a rig config's `[planner]`. Documented with examples in
//! `scenarios/README.md`. Unknown keys are refused, and [`SimScenario::validate`] names the
//! key of any bad value.

mod crowd;
pub mod people;
pub mod vehicles;

pub use crowd::CrowdSpec;
pub use people::{Behaviour, OnArrival, PeopleWalk, Walk};

use flowgate_protocol::plane::Point;
use serde::Deserialize;
use std::path::Path;

/// A whole scenario.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimScenario {
    pub name: String,
    #[serde(default)]
    pub description: String,
    /// Simulated time after which the run ends as a timeout, s.
    pub time_limit: f64,
    /// A lane between walls at `y = ±half_width`; absent for free space.
    #[serde(default)]
    pub lane: Option<LaneSpec>,
    /// Walls: polylines on the floor, judged against the robot's footprint.
    #[serde(default)]
    pub walls: Vec<WallSpec>,
    /// Static obstacles (shelves, tables): polygons, closed by their last edge.
    #[serde(default)]
    pub static_obstacles: Vec<StaticObstacleSpec>,
    pub robot: RobotSpec,
    pub goal: GoalSpec,
    #[serde(default)]
    pub obstacles: Vec<ObstacleSpec>,
    pub sensing: SensingSpec,
    /// The gateway's planner settings, not read by the simulator.
    #[serde(default)]
    pub planner: toml::Table,
    /// The gateway's `[room]` settings (the view's edge as a boundary, the panels), not
    /// read by the simulator.
    #[serde(default)]
    pub room: toml::Table,
    /// Faults the simulator injects when it runs this scenario (all off by default;
    /// `flowgate-sim --fault key=value` overrides single keys).
    #[serde(default)]
    pub faults: crate::faults::FaultPlan,
    /// The PSD camera over the floor (default: [`crate::camera::CameraModel::default`], which sees about
    /// ±0.8 m). A larger arena describes a camera that sees it.
    #[serde(default)]
    pub camera: crate::camera::CameraModel,
    /// A crowd crossing a circle (CrowdNav's circle crossing): the robot and the obstacles
    /// are placed by [`SimScenario::crowd_episode`], afresh for every episode of a sweep.
    #[serde(default)]
    pub crowd: Option<CrowdSpec>,
    /// Vehicles beside the robot (the first vehicle), each scripted or navigating.
    #[serde(default)]
    pub vehicles: Vec<vehicles::VehicleSpec>,
    /// The antipodal swap: a fleet placed on a circle for each episode.
    #[serde(default)]
    pub swap: Option<vehicles::SwapSpec>,
    /// When the people who do not see the robot walk (docs/people.md, "Speed").
    #[serde(default)]
    pub people_walk: people::PeopleWalk,
    /// What loading changed and the user should hear (a script cut where it leaves the
    /// room).
    #[serde(skip)]
    pub notes: Vec<String>,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaneSpec {
    /// Half the lane's width `h`, m: the lines at `y = ±h` bound the robot's *centre*
    /// (configuration space, as obstacles' planning radii `a_0 + a_r` include the robot).
    pub half_width: f64,
}

/// A wall: a polyline, `points = [[x, y], ...]` in floor metres.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct WallSpec {
    pub points: Vec<[f64; 2]>,
}

/// A static obstacle: a polygon, `points = [[x, y], ...]` in floor metres, closed by the
/// edge from its last point back to its first.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StaticObstacleSpec {
    pub points: Vec<[f64; 2]>,
}

/// The robot: a differential-drive base with stepper wheels.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotSpec {
    pub start: [f64; 2],
    #[serde(default)]
    pub heading_deg: f64,
    /// Radius of the robot's footprint `a_r`, m.
    pub radius: f64,
    /// Distance between the wheels `l_w`, m.
    pub wheel_base: f64,
    pub wheel_radius: f64,
    /// Stepper full steps per wheel revolution.
    pub steps_per_rev: u32,
    pub microsteps: u32,
    /// Largest wheel rim speed, m/s (the motor boards' rate limit).
    pub max_wheel_speed: f64,
    /// Wheel acceleration ramp, m/s² (the motor boards' ramp).
    pub wheel_accel: f64,
    /// Largest speed the planner commands for the robot's centre, m/s.
    pub max_speed: f64,
}

impl RobotSpec {
    /// Pulses per metre of wheel rim travel.
    pub fn pulses_per_metre(&self) -> f64 {
        f64::from(self.steps_per_rev) * f64::from(self.microsteps) / (2.0 * std::f64::consts::PI * self.wheel_radius)
    }
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GoalSpec {
    pub position: [f64; 2],
    /// The run succeeds when the robot's centre is this close to the goal, m.
    #[serde(default = "default_goal_tolerance")]
    pub tolerance: f64,
}

fn default_goal_tolerance() -> f64 {
    0.02
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleSpec {
    /// The obstacle's true radius `a_0`, m.
    pub radius: f64,
    pub start: [f64; 2],
    #[serde(default)]
    pub motion: Motion,
    /// Along its `motion` (`straight`), or as a person walking to `goal` (or each of
    /// `goals` in turn) at `preferred_speed`, avoiding the others (`orca`, `social_force`).
    #[serde(default)]
    pub behaviour: Behaviour,
    #[serde(default)]
    pub goal: Option<[f64; 2]>,
    #[serde(default)]
    pub goals: Vec<[f64; 2]>,
    #[serde(default)]
    pub preferred_speed: Option<f64>,
    #[serde(default)]
    pub on_arrival: OnArrival,
    /// A person who sees the robot and avoids it as it avoids a scripted obstacle (taking
    /// all the avoiding on itself); `false`, CrowdNav's invisible setting, by default.
    #[serde(default)]
    pub sees_robot: bool,
    /// People of one group (the same name) walk together, each to its own goals.
    #[serde(default)]
    pub group: Option<String>,
}

impl ObstacleSpec {
    /// An obstacle that follows `motion`.
    pub fn scripted(radius: f64, start: [f64; 2], motion: Motion) -> Self {
        Self {
            radius,
            start,
            motion,
            behaviour: Behaviour::Straight,
            goal: None,
            goals: Vec::new(),
            preferred_speed: None,
            on_arrival: OnArrival::Stop,
            sees_robot: false,
            group: None,
        }
    }
}

/// The finest microstepping of a stepper driver, and the most full steps a motor has per
/// revolution (a 0.036° stepper): beyond them a board could not be configured.
pub const MAX_MICROSTEPS: u32 = 256;
/// Most walls, and most static obstacles, a scenario holds: a room for one camera's view
/// with room to spare (the rooms in `scenarios/rooms` hold up to six). The planner's cost
/// grows with each.
pub const MAX_WALLS: usize = 64;
pub const MAX_STATIC_OBSTACLES: usize = 64;
/// Most points of one wall, one static obstacle or one obstacle's waypoints, and of all
/// walls and static obstacles together.
pub const MAX_POINTS: usize = 256;
pub const MAX_ROOM_POINTS: usize = 1024;
/// The LEDs the simulated PSD controller drives (its `Info::max_leds`, ids 1 to this): a
/// scenario's robot, vehicles and obstacles take at most these.
pub const CONTROLLER_LEDS: u8 = 16;
/// Most moving obstacles: the simulated controller's LEDs less the robot's two.
pub const MAX_OBSTACLES: usize = CONTROLLER_LEDS as usize - 2;
/// Plausibility bounds for a rig a PSD camera watches, far beyond any real one: a body or
/// a noise (m), a floor's extent (m), a speed, an acceleration and a filter's corner. (The
/// sample time is bounded by the PSD schedule's range, which the gateway checks.)
pub const MAX_BODY_M: f64 = 2.0;
/// The largest goal tolerance, m (the gateway's `config::MAX_GOAL_TOLERANCE`).
pub const MAX_GOAL_TOLERANCE_M: f64 = 1.0;
pub const MAX_LENGTH_M: f64 = 100.0;
pub const MAX_SPEED_M_S: f64 = 10.0;
pub const MAX_ACCEL_M_S2: f64 = 100.0;
pub const MAX_LOWPASS_HZ: f64 = 1000.0;
/// The largest scenario file read, bytes: real ones are a few kB.
pub const MAX_FILE_BYTES: u64 = 1 << 20;

/// Read a text file of at most `limit` bytes. A larger one, or an endless one (a device, a
/// pipe), is refused having read `limit` + 1 bytes of it.
pub fn read_text(path: &Path, limit: u64) -> std::io::Result<String> {
    use std::io::Read;
    let mut text = String::new();
    std::fs::File::open(path)?.take(limit + 1).read_to_string(&mut text)?;
    if text.len() as u64 > limit {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("longer than {limit} bytes, far beyond any real one: refused"),
        ));
    }
    Ok(text)
}

pub const MAX_STEPS_PER_REV: u32 = 10_000;

/// The longest sensing delay a scenario may model, s.
pub const MAX_DELAY_S: f64 = 10.0;
/// The longest episode, s (an hour of virtual time).
pub const MAX_TIME_LIMIT_S: f64 = 3600.0;

/// How an obstacle moves. Positions are analytic in time, so the truth at any past
/// moment (for a delayed sensor) is exact.
#[derive(Debug, Clone, Default, Deserialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Motion {
    #[default]
    Stationary,
    /// Constant velocity, m/s.
    Constant { velocity: [f64; 2] },
    /// From `start` through each point in turn at `speed` (m/s), then stop (or start over
    /// from `start` when `repeat`).
    Waypoints {
        points: Vec<[f64; 2]>,
        speed: f64,
        #[serde(default)]
        repeat: bool,
    },
}

/// The sensing chain between the world and the planner.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensingSpec {
    /// Control period `T`: one time-division frame, s.
    pub sample_time: f64,
    /// Pure delay from the world to the planner's input (processing, transport), s.
    #[serde(default)]
    pub delay: f64,
    /// Standard deviation of the position noise on every measured point, m.
    #[serde(default)]
    pub position_noise: f64,
    /// Cut-off of a first-order low-pass filter on measured positions, Hz; 0 = none.
    #[serde(default)]
    pub lowpass_hz: f64,
    /// Seed of the noise generator.
    #[serde(default = "default_seed")]
    pub seed: u64,
}

fn default_seed() -> u64 {
    1
}

/// A scenario that could not be loaded, naming the file and the key.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    #[error("cannot read scenario {path}: {source}")]
    Read { path: String, source: std::io::Error },
    #[error("scenario {path}: {source}")]
    Parse { path: String, source: Box<toml::de::Error> },
    #[error("scenario {path}: `{key}` {why}")]
    Invalid { path: String, key: String, why: String },
}

impl SimScenario {
    /// Read, parse and validate a scenario file.
    pub fn load(path: &Path) -> Result<Self, ScenarioError> {
        let text = read_text(path, MAX_FILE_BYTES)
            .map_err(|source| ScenarioError::Read { path: path.display().to_string(), source })?;
        Self::from_toml(&text, &path.display().to_string())
    }

    /// Parse and validate scenario text; `origin` names it in errors. A crowd is placed for
    /// its first episode, from `sensing.seed`.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, ScenarioError> {
        let mut s: SimScenario =
            toml::from_str(text).map_err(|e| ScenarioError::Parse { path: origin.into(), source: Box::new(e) })?;
        let invalid = |(key, why)| ScenarioError::Invalid { path: origin.into(), key, why };
        if s.crowd.is_some() {
            s.validate_crowd().map_err(invalid)?;
            s = s.crowd_episode(s.sensing.seed, 0).map_err(invalid)?;
        }
        if s.swap.is_some() {
            s.validate_swap().map_err(invalid)?;
            s = s.swap_episode(s.sensing.seed, 0);
        }
        s.validate().map_err(invalid)?;
        Ok(s)
    }

    /// Check every value; on error, the key and why.
    pub fn validate(&self) -> Result<(), (String, String)> {
        self.validate_counts()?;
        self.validate_text()?;
        positive("time_limit", self.time_limit)?;
        if self.time_limit > MAX_TIME_LIMIT_S {
            return Err(("time_limit".into(), format!("must be at most {MAX_TIME_LIMIT_S} s, is {}", self.time_limit)));
        }
        if let Some(lane) = self.lane {
            within("lane.half_width", lane.half_width, MAX_LENGTH_M, "m")?;
        }
        self.validate_robot()?;
        finite("goal.position", self.goal.position)?;
        within("goal.tolerance", self.goal.tolerance, MAX_GOAL_TOLERANCE_M, "m")?;
        self.validate_obstacles()?;
        self.validate_room()?;
        self.validate_geometry()?;
        self.validate_sensing()?;
        self.validate_vehicles()?;
        self.faults.validate()
    }

    /// The name and description are printed to terminals and into reports: no escape
    /// sequence may ride in on them.
    fn validate_text(&self) -> Result<(), (String, String)> {
        if let Some(c) = self.name.chars().find(|c| c.is_control()) {
            return Err(("name".into(), format!("holds the control character {c:?}: names are printed as they are")));
        }
        if let Some(c) = self.description.chars().find(|&c| c.is_control() && c != '\n' && c != '\t') {
            return Err(("description".into(), format!("holds the control character {c:?}: only new lines and tabs")));
        }
        Ok(())
    }

    fn validate_robot(&self) -> Result<(), (String, String)> {
        validate_body(&self.robot, "robot")
    }

    fn validate_obstacles(&self) -> Result<(), (String, String)> {
        for (i, o) in self.obstacles.iter().enumerate() {
            within(&format!("obstacles[{i}].radius"), o.radius, MAX_BODY_M, "m")?;
            finite(&format!("obstacles[{i}].start"), o.start)?;
            validate_motion(&format!("obstacles[{i}].motion"), &o.motion)?;
            o.validate_walk(&format!("obstacles[{i}]"))?;
            self.validate_goals_clear(i, o)?;
        }
        self.validate_groups()
    }

    /// A person's goals lie outside the furniture.
    fn validate_goals_clear(&self, i: usize, o: &ObstacleSpec) -> Refused {
        let goals = o.goal.iter().map(|g| (format!("obstacles[{i}].goal"), g));
        let goals = goals.chain(o.goals.iter().enumerate().map(|(k, g)| (format!("obstacles[{i}].goals[{k}]"), g)));
        for (key, g) in goals {
            let inside = self.static_obstacles.iter().position(|f| {
                let outline: Vec<Point> = f.points.iter().map(|&p| point(p)).collect();
                flowgate_protocol::plane::inside_polygon(point(*g), &outline)
            });
            if let Some(k) = inside {
                return Err((key, format!("{g:?} lies inside static_obstacles[{k}]: a person cannot stand there")));
            }
        }
        Ok(())
    }

    fn validate_sensing(&self) -> Result<(), (String, String)> {
        let s = &self.sensing;
        positive("sensing.sample_time", s.sample_time)?;
        non_negative("sensing.delay", s.delay)?;
        // The delay line holds delay / sample_time frames: a delay beyond any rig's (the
        // paper's is 0.6 s) would only make the simulator buffer for nothing.
        if s.delay > MAX_DELAY_S {
            return Err(("sensing.delay".into(), format!("must be 0-{MAX_DELAY_S} s, is {}", s.delay)));
        }
        non_negative("sensing.position_noise", s.position_noise)?;
        at_most("sensing.position_noise", s.position_noise, MAX_BODY_M, "m")?;
        non_negative("sensing.lowpass_hz", s.lowpass_hz)?;
        at_most("sensing.lowpass_hz", s.lowpass_hz, MAX_LOWPASS_HZ, "Hz")
    }

    /// How many of each thing: checked first, so that a file of a million walls is refused
    /// before anything is built from it.
    fn validate_counts(&self) -> Result<(), (String, String)> {
        let most = |key: &str, n: usize, limit: usize| {
            if n > limit {
                Err((key.to_string(), format!("has {n} entries: at most {limit}")))
            } else {
                Ok(())
            }
        };
        most("walls", self.walls.len(), MAX_WALLS)?;
        most("static_obstacles", self.static_obstacles.len(), MAX_STATIC_OBSTACLES)?;
        most("obstacles", self.obstacles.len(), MAX_OBSTACLES)?;
        let walls = self.walls.iter().enumerate().map(|(i, w)| (format!("walls[{i}].points"), w.points.len()));
        let polygons = (self.static_obstacles.iter().enumerate())
            .map(|(i, o)| (format!("static_obstacles[{i}].points"), o.points.len()));
        let mut total = 0;
        for (key, n) in walls.chain(polygons) {
            most(&key, n, MAX_POINTS)?;
            total += n;
        }
        if total > MAX_ROOM_POINTS {
            return Err((
                "walls".into(),
                format!("the walls and static obstacles have {total} points together: at most {MAX_ROOM_POINTS}"),
            ));
        }
        for (i, o) in self.obstacles.iter().enumerate() {
            if let Motion::Waypoints { points, .. } = &o.motion {
                most(&format!("obstacles[{i}].motion.points"), points.len(), MAX_POINTS)?;
            }
        }
        Ok(())
    }

    /// `[[walls]]` and `[[static_obstacles]]`: finite points, enough of them, no edge of no
    /// length; the robot's start and the goal clear of them by the robot's radius. (The
    /// gateway checks the rest of a room's shape with its own rules.)
    fn validate_room(&self) -> Result<(), (String, String)> {
        let items = self.walls.iter().enumerate().map(|(i, w)| (format!("walls[{i}].points"), &w.points, 2));
        let polygons = self
            .static_obstacles
            .iter()
            .enumerate()
            .map(|(i, o)| (format!("static_obstacles[{i}].points"), &o.points, 3));
        for (key, points, least) in items.chain(polygons) {
            if points.len() < least {
                return Err((key, format!("needs at least {least} points, has {}", points.len())));
            }
            if let Some(k) = points.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
                return Err((key, format!("point {k} is not finite")));
            }
            if let Some(k) = points.windows(2).position(|s| point(s[0]) == point(s[1])) {
                return Err((key, format!("the edge from point {k} to point {} has no length", k + 1)));
            }
        }
        for (key, at) in [("robot.start", self.robot.start), ("goal.position", self.goal.position)] {
            if let Some(what) = self.touching(point(at), self.robot.radius) {
                return Err((
                    key.into(),
                    format!("{at:?} puts the robot against {what} (its radius {} m)", self.robot.radius),
                ));
            }
        }
        Ok(())
    }

    /// What a footprint of `radius` at `centre` touches or overlaps, the walls first: "a
    /// wall" or "static_obstacles[k]".
    pub(crate) fn touching(&self, centre: Point, radius: f64) -> Option<String> {
        use flowgate_protocol::plane::{inside_polygon, polygon_edges, segment_distance_sqr};
        let reach = radius * radius;
        let wall = self.walls.iter().flat_map(|w| w.points.windows(2));
        if wall.into_iter().any(|s| segment_distance_sqr(centre, point(s[0]), point(s[1])) <= reach) {
            return Some("a wall".into());
        }
        self.static_obstacles.iter().enumerate().find_map(|(k, o)| {
            let polygon: Vec<Point> = o.points.iter().map(|&p| point(p)).collect();
            let touches = inside_polygon(centre, &polygon)
                || polygon_edges(&polygon).any(|(a, b)| segment_distance_sqr(centre, a, b) <= reach);
            touches.then(|| format!("static_obstacles[{k}]"))
        })
    }

    /// Where things stand at the start: what no run could begin from, or ever end in, is
    /// refused here rather than reported as a collision at t = 0 or a timeout.
    fn validate_geometry(&self) -> Result<(), (String, String)> {
        let r = &self.robot;
        let start = point(r.start);
        let goal = point(self.goal.position);
        if let Some(lane) = self.lane {
            // The lane bounds the robot's centre, and each obstacle's.
            let inside = |p: [f64; 2]| p[1].abs() < lane.half_width;
            if !inside(r.start) {
                return Err((
                    "robot.start".into(),
                    format!("{:?} lies outside the lane (|y| >= lane.half_width = {})", r.start, lane.half_width),
                ));
            }
            if !inside(self.goal.position) {
                return Err((
                    "goal.position".into(),
                    format!(
                        "{:?} lies outside the lane (|y| >= lane.half_width = {})",
                        self.goal.position, lane.half_width
                    ),
                ));
            }
            for (i, o) in self.obstacles.iter().enumerate() {
                if !inside(o.start) {
                    return Err((
                        format!("obstacles[{i}].start"),
                        format!("{:?} lies outside the lane (|y| >= lane.half_width = {})", o.start, lane.half_width),
                    ));
                }
                if let Motion::Waypoints { points, .. } = &o.motion {
                    if let Some(p) = points.iter().find(|p| !inside(**p)) {
                        return Err((
                            format!("obstacles[{i}].motion.points"),
                            format!("{p:?} lies outside the lane (|y| >= lane.half_width = {})", lane.half_width),
                        ));
                    }
                }
            }
        }
        for (i, o) in self.obstacles.iter().enumerate() {
            let reach = r.radius + o.radius;
            let gap = (start - point(o.start)).norm();
            if gap < reach {
                return Err((
                    "robot.start".into(),
                    format!(
                        "overlaps obstacles[{i}]: centres {:.1} cm apart, radii {:.1} cm together",
                        gap * 100.0,
                        reach * 100.0
                    ),
                ));
            }
            // A standing obstacle's footprint is never reachable: a goal there would run
            // to the time limit.
            let to_goal = (goal - point(o.start)).norm();
            if o.motion == Motion::Stationary && to_goal < reach {
                return Err((
                    "goal.position".into(),
                    format!(
                        "is within reach of the standing obstacles[{i}]: {:.1} cm from its centre, the robot's and its \
                         radii are {:.1} cm together",
                        to_goal * 100.0,
                        reach * 100.0
                    ),
                ));
            }
        }
        Ok(())
    }

    pub fn robot_start(&self) -> Point {
        point(self.robot.start)
    }
    pub fn goal(&self) -> Point {
        point(self.goal.position)
    }
}

/// A vehicle's body (`[robot]`'s keys) under `prefix`.
pub(crate) fn validate_body(r: &RobotSpec, prefix: &str) -> Refused {
    finite(&format!("{prefix}.start"), r.start)?;
    if !(r.heading_deg.is_finite() && r.heading_deg.abs() <= 360.0) {
        let h = r.heading_deg;
        let h = if h.abs() < 1e6 { h.to_string() } else { format!("{h:e}") };
        return Err((format!("{prefix}.heading_deg"), format!("must be within ±360°, is {h}")));
    }
    positive(&format!("{prefix}.radius"), r.radius)?;
    positive(&format!("{prefix}.wheel_base"), r.wheel_base)?;
    positive(&format!("{prefix}.wheel_radius"), r.wheel_radius)?;
    positive(&format!("{prefix}.max_wheel_speed"), r.max_wheel_speed)?;
    positive(&format!("{prefix}.wheel_accel"), r.wheel_accel)?;
    positive(&format!("{prefix}.max_speed"), r.max_speed)?;
    at_most(&format!("{prefix}.radius"), r.radius, MAX_BODY_M, "m")?;
    at_most(&format!("{prefix}.wheel_base"), r.wheel_base, MAX_BODY_M, "m")?;
    at_most(&format!("{prefix}.wheel_radius"), r.wheel_radius, MAX_BODY_M, "m")?;
    at_most(&format!("{prefix}.max_wheel_speed"), r.max_wheel_speed, MAX_SPEED_M_S, "m/s")?;
    at_most(&format!("{prefix}.wheel_accel"), r.wheel_accel, MAX_ACCEL_M_S2, "m/s²")?;
    at_most(&format!("{prefix}.max_speed"), r.max_speed, MAX_SPEED_M_S, "m/s")?;
    if r.steps_per_rev == 0 || r.microsteps == 0 {
        return Err((format!("{prefix}.steps_per_rev"), "steps_per_rev and microsteps must be at least 1".into()));
    }
    // What stepper drivers do: 1/256 is the finest microstep any common driver offers.
    if r.microsteps > MAX_MICROSTEPS {
        return Err((format!("{prefix}.microsteps"), format!("must be 1-{MAX_MICROSTEPS}, is {}", r.microsteps)));
    }
    if r.steps_per_rev > MAX_STEPS_PER_REV {
        return Err((
            format!("{prefix}.steps_per_rev"),
            format!("must be 1-{MAX_STEPS_PER_REV}, is {}", r.steps_per_rev),
        ));
    }
    Ok(())
}

/// A motion's numbers: finite, at most a plausible speed, waypoints to go to.
pub(crate) fn validate_motion(key: &str, motion: &Motion) -> Refused {
    match motion {
        Motion::Stationary => {}
        Motion::Constant { velocity } => {
            let key = format!("{key}.velocity");
            finite(&key, *velocity)?;
            at_most(&key, velocity[0].hypot(velocity[1]), MAX_SPEED_M_S, "m/s")?;
        }
        Motion::Waypoints { points, speed, .. } => {
            within(&format!("{key}.speed"), *speed, MAX_SPEED_M_S, "m/s")?;
            if points.is_empty() {
                return Err((format!("{key}.points"), "needs at least one point".into()));
            }
            if points.len() > MAX_POINTS {
                return Err((format!("{key}.points"), format!("has {} entries: at most {MAX_POINTS}", points.len())));
            }
            for p in points {
                finite(&format!("{key}.points"), *p)?;
            }
        }
    }
    Ok(())
}

/// A point: finite, within the plausible floor.
pub(crate) fn validate_point(key: &str, p: [f64; 2]) -> Refused {
    finite(key, p)
}

/// A length: positive, at most `most` m.
pub(crate) fn validate_length(key: &str, v: f64, most: f64) -> Refused {
    within(key, v, most, "m")
}

/// `[x, y]` as a point.
pub fn point(p: [f64; 2]) -> Point {
    Point::new(p[0], p[1])
}

/// A check's failure: the key and why.
pub(crate) type Refused = Result<(), (String, String)>;

fn positive(key: &str, v: f64) -> Refused {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err((key.to_string(), format!("must be a positive number, is {v}")))
    }
}

fn non_negative(key: &str, v: f64) -> Refused {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err((key.to_string(), format!("must be >= 0, is {v}")))
    }
}

/// Plausible for any rig a PSD camera watches: far beyond, a value is a typo (a wheel base
/// of 1e308 m) that would only turn into infinities downstream.
fn at_most(key: &str, v: f64, most: f64, unit: &str) -> Refused {
    if v > most {
        let v = if v < 1e6 { v.to_string() } else { format!("{v:e}") };
        Err((key.to_string(), format!("must be at most {most} {unit}, is {v}")))
    } else {
        Ok(())
    }
}

/// Positive, and at most `most`.
fn within(key: &str, v: f64, most: f64, unit: &str) -> Refused {
    positive(key, v)?;
    at_most(key, v, most, unit)
}

fn finite(key: &str, p: [f64; 2]) -> Refused {
    if p.iter().all(|v| v.is_finite() && v.abs() <= MAX_LENGTH_M) {
        Ok(())
    } else {
        Err((key.to_string(), format!("must be finite, within ±{MAX_LENGTH_M} m, is {p:?}")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = r#"
        name = "t"
        time_limit = 10
        [robot]
        start = [0, 0]
        radius = 0.07
        wheel_base = 0.108
        wheel_radius = 0.02
        steps_per_rev = 200
        microsteps = 8
        max_wheel_speed = 0.3
        wheel_accel = 2.0
        max_speed = 0.15
        [goal]
        position = [1, 0]
        [[obstacles]]
        radius = 0.07
        start = [0.5, 0]
        motion = { kind = "constant", velocity = [-0.05, 0] }
        [sensing]
        sample_time = 0.02
        [planner]
        cruise_speed = 0.1
        c1 = 20
        kc = 0.06
        margin = { rule = "factor", factor = 1.1 }
    "#;

    #[test]
    fn parses_a_scenario() {
        let s = SimScenario::from_toml(MINIMAL, "t").unwrap();
        assert_eq!(s.obstacles[0].motion, Motion::Constant { velocity: [-0.05, 0.0] });
        assert_eq!(s.planner["kc"].as_float(), Some(0.06), "carried for the gateway, unread");
        assert_eq!(s.goal.tolerance, 0.02);
    }

    #[test]
    fn refuses_bad_values_naming_the_key() {
        let bad = MINIMAL.replace("radius = 0.07\n        start = [0.5, 0]", "radius = -1\n        start = [0.5, 0]");
        let err = SimScenario::from_toml(&bad, "t").unwrap_err().to_string();
        assert!(err.contains("`obstacles[0].radius` must be a positive number"), "{err}");
    }

    #[test]
    fn carries_a_fault_plan() {
        let with = format!("{MINIMAL}\n[faults]\nserial_drop = 0.01\nboard_fault_at = 2.5\n");
        let s = SimScenario::from_toml(&with, "t").unwrap();
        assert_eq!(s.faults.serial_drop, 0.01);
        assert_eq!(s.faults.board_fault_at, Some(2.5));
        assert_eq!(SimScenario::from_toml(MINIMAL, "t").unwrap().faults, crate::faults::FaultPlan::default());
    }

    /// A person who walks, and what is refused of one, naming the key.
    #[test]
    fn a_person_walks_and_is_refused_naming_the_key() {
        let obstacle = r#"motion = { kind = "constant", velocity = [-0.05, 0] }"#;
        let person = |keys: &str| MINIMAL.replace(obstacle, keys);
        let walker = "behaviour = \"orca\"\n        goal = [-0.5, 0]\n        preferred_speed = 0.05";
        let s = SimScenario::from_toml(&person(walker), "t").unwrap();
        let walk = s.obstacles[0].walk().unwrap();
        assert_eq!(
            (walk.behaviour, walk.goals, walk.preferred_speed),
            (Behaviour::Orca, vec![Point::new(-0.5, 0.0)], 0.05)
        );
        assert!((s.obstacles[0].top_speed() - 0.05 * people::SPEED_CAP).abs() < 1e-12);
        let table = "[[static_obstacles]]\npoints = [[-0.6, -0.1], [-0.4, -0.1], [-0.4, 0.1], [-0.6, 0.1]]\n";
        for (keys, key, why) in [
            ("goal = [-0.5, 0]", "obstacles[0].goal", "is for a person who walks"),
            ("sees_robot = true", "obstacles[0].sees_robot", "is for a person who walks"),
            ("behaviour = \"orca\"\n preferred_speed = 0.05", "obstacles[0].goal", "walks to a goal"),
            ("behaviour = \"orca\"\n goal = [-0.5, 0]", "obstacles[0].preferred_speed", "preferred speed"),
            ("behaviour = \"orca\"\n goal = [-0.5, 0]\n preferred_speed = -1", "obstacles[0].preferred_speed", "positive"),
            (
                "behaviour = \"social_force\"\n goal = [-0.5, 0]\n goals = [[0, 0]]\n preferred_speed = 0.05",
                "obstacles[0].goals",
                "not both",
            ),
            (
                "behaviour = \"orca\"\n goal = [-0.5, 0]\n preferred_speed = 0.05\n motion = { kind = \"constant\", velocity = [1, 0] }",
                "obstacles[0].motion",
                "leave motion out",
            ),
        ] {
            let err = SimScenario::from_toml(&person(keys), "t").unwrap_err().to_string();
            assert!(err.contains(&format!("`{key}`")) && err.contains(why), "{keys}: {err}");
        }
        let err = SimScenario::from_toml(&format!("{}{table}", person(walker)), "t").unwrap_err().to_string();
        assert!(err.contains("`obstacles[0].goal`") && err.contains("inside static_obstacles[0]"), "{err}");
        let seeing = person(&format!("{walker}\n sees_robot = true"));
        assert!(SimScenario::from_toml(&seeing, "t").unwrap().obstacles[0].walk().unwrap().sees_robot);
        let err =
            SimScenario::from_toml(&person(&format!("{walker}\n group = \"pair\"")), "t").unwrap_err().to_string();
        assert!(err.contains("`obstacles[0].group`") && err.contains("no other member"), "{err}");
        let err = SimScenario::from_toml(&person("group = \"pair\""), "t").unwrap_err().to_string();
        assert!(err.contains("`obstacles[0].group`") && err.contains("is for a person who walks"), "{err}");
        let swap = "[swap]\nvehicles = 2\ncircle_radius = 0.3\n";
        // In a fleet, people who see the robot see every vehicle.
        assert!(SimScenario::from_toml(&format!("{seeing}{swap}"), "t").unwrap().obstacles[0].sees_robot);
    }

    #[test]
    fn refuses_unknown_keys() {
        let bad = MINIMAL.replace("[sensing]", "[sensing]\nbogus = 3");
        let err = SimScenario::from_toml(&bad, "t").unwrap_err().to_string();
        assert!(err.contains("unknown field `bogus`"), "{err}");
    }
}
