//! Several vehicles under one camera: `[[vehicles]]` beside the scenario's `[robot]` (which
//! stays the first vehicle), each one following a script or navigating to a goal, and
//! `[swap]`, the antipodal swap that places a fleet on a circle afresh for each episode.
//!
//! Everything that no run could begin from is refused here, naming the key and the numbers:
//! two vehicles overlapping at the start, goals closer together than their radii, a script
//! faster or sharper than its vehicle can follow within [`SCRIPT_PRECISION`] (the rule the
//! gateway's rig loader applies too, [`flowgate_protocol::plane::script`]), more LEDs than
//! the PSD schedule drives. (A script that leaves the room is cut where it leaves by
//! [`crate::world::fleet::cut_script`].)

use serde::Deserialize;

use super::{point, Motion, ObstacleSpec, RobotSpec, SimScenario};
use crate::Point;

use flowgate_protocol::plane::script::{followable, Unfollowable, Wheels};
pub use flowgate_protocol::plane::script::{
    DEFAULT_TOLERANCE as DEFAULT_SCRIPT_TOLERANCE, PRECISION as SCRIPT_PRECISION,
};
/// The most vehicles a scenario holds, the robot among them: each takes two of the
/// simulated controller's LEDs.
pub const MAX_VEHICLES: usize = super::CONTROLLER_LEDS as usize / 2;
/// A vehicle's name is a ROS name and a file name: lower-case letters, digits and `_`.
pub const MAX_NAME_LEN: usize = 32;
/// The name the scenario's `[robot]` goes by among the vehicles.
pub const ROBOT_NAME: &str = "robot";

/// What a vehicle does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// Follows `motion` (as an obstacle's), guarded by its supervisor.
    Script,
    /// Plans its way to `goal` with its own field.
    Navigate,
}

/// One `[[vehicles]]` entry. Any key of `[robot]` may be given; the rest are the robot's.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct VehicleSpec {
    pub name: String,
    pub start: [f64; 2],
    /// Default: a script's first direction, 0 for a navigating vehicle.
    #[serde(default)]
    pub heading_deg: Option<f64>,
    pub role: Role,
    /// A scripted vehicle's motion (`role = "script"`).
    #[serde(default)]
    pub motion: Option<Motion>,
    /// A navigating vehicle's goal (`role = "navigate"`).
    #[serde(default)]
    pub goal: Option<[f64; 2]>,
    #[serde(default)]
    pub goal_tolerance: Option<f64>,
    /// A scripted vehicle further than this from its script is stopped, m.
    #[serde(default)]
    pub script_tolerance: Option<f64>,
    /// A fault to inject: the vehicle's own CAN link fails at this time, s. Its motors hold
    /// the last command for their command timeout, then stop.
    #[serde(default)]
    pub link_lost_at: Option<f64>,
    #[serde(default)]
    pub radius: Option<f64>,
    #[serde(default)]
    pub wheel_base: Option<f64>,
    #[serde(default)]
    pub wheel_radius: Option<f64>,
    #[serde(default)]
    pub steps_per_rev: Option<u32>,
    #[serde(default)]
    pub microsteps: Option<u32>,
    #[serde(default)]
    pub max_wheel_speed: Option<f64>,
    #[serde(default)]
    pub wheel_accel: Option<f64>,
    #[serde(default)]
    pub max_speed: Option<f64>,
}

impl VehicleSpec {
    /// The vehicle's body: its own keys over the robot's.
    pub fn body(&self, robot: &RobotSpec) -> RobotSpec {
        RobotSpec {
            start: self.start,
            heading_deg: self.heading_deg.unwrap_or_else(|| self.first_direction().unwrap_or(0.0)),
            radius: self.radius.unwrap_or(robot.radius),
            wheel_base: self.wheel_base.unwrap_or(robot.wheel_base),
            wheel_radius: self.wheel_radius.unwrap_or(robot.wheel_radius),
            steps_per_rev: self.steps_per_rev.unwrap_or(robot.steps_per_rev),
            microsteps: self.microsteps.unwrap_or(robot.microsteps),
            max_wheel_speed: self.max_wheel_speed.unwrap_or(robot.max_wheel_speed),
            wheel_accel: self.wheel_accel.unwrap_or(robot.wheel_accel),
            max_speed: self.max_speed.unwrap_or(robot.max_speed),
        }
    }

    /// The script as an obstacle's path (a navigating vehicle's: standing at its start).
    pub fn script(&self, radius: f64) -> ObstacleSpec {
        ObstacleSpec::scripted(radius, self.start, self.motion.clone().unwrap_or_default())
    }

    /// The direction a script first moves in, degrees (`None`: it never moves).
    fn first_direction(&self) -> Option<f64> {
        let v = match self.motion.as_ref()? {
            Motion::Stationary => return None,
            Motion::Constant { velocity } => point(*velocity),
            Motion::Waypoints { points, .. } => {
                points.iter().map(|p| point(*p) - point(self.start)).find(|d| d.norm() > 0.0)?
            }
        };
        (v.norm() > 0.0).then(|| v.arg().to_degrees())
    }

    /// Where the vehicle is headed: a navigating vehicle's goal, a script's last point (its
    /// start for one that repeats or stands).
    pub fn destination(&self) -> Point {
        match (self.role, &self.motion, self.goal) {
            (Role::Navigate, _, Some(g)) => point(g),
            (Role::Script, Some(Motion::Waypoints { points, repeat: false, .. }), _) => {
                points.last().map_or(point(self.start), |p| point(*p))
            }
            _ => point(self.start),
        }
    }

    pub fn script_tolerance(&self) -> f64 {
        self.script_tolerance.unwrap_or(DEFAULT_SCRIPT_TOLERANCE)
    }
}

/// The antipodal swap: the robot and `vehicles - 1` navigating vehicles spread evenly on a
/// circle of `circle_radius` about `centre`, each driving to the opposite point; each
/// episode turns the circle by a random angle and moves every start and goal by up to
/// `jitter` in x and y.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SwapSpec {
    pub vehicles: usize,
    pub circle_radius: f64,
    #[serde(default)]
    pub centre: [f64; 2],
    #[serde(default)]
    pub jitter: f64,
}

/// A check's failure: the key and why.
type Refused = Result<(), (String, String)>;

impl SimScenario {
    /// The vehicles' bodies and roles, the robot first: `(name, body, role)`.
    pub fn fleet(&self) -> impl Iterator<Item = (&str, RobotSpec, Role)> + '_ {
        let robot = std::iter::once((ROBOT_NAME, self.robot, Role::Navigate));
        robot.chain(self.vehicles.iter().map(|v| (v.name.as_str(), v.body(&self.robot), v.role)))
    }

    /// Whether the scenario drives more than the robot.
    pub fn is_fleet(&self) -> bool {
        !self.vehicles.is_empty()
    }

    /// Vehicle `k` (0: the robot) as a scenario of its own: its body, start and goal, the
    /// same room and obstacles, no other vehicle. What a vehicle alone would do, and what the
    /// gateway's checks of one robot are run on.
    pub fn vehicle_alone(&self, k: usize) -> SimScenario {
        let mut s = self.clone();
        s.vehicles.clear();
        s.swap = None;
        if let Some(v) = k.checked_sub(1).and_then(|i| self.vehicles.get(i)) {
            s.robot = v.body(&self.robot);
            s.goal.position = [v.destination().re, v.destination().im];
            if let Some(t) = v.goal_tolerance {
                s.goal.tolerance = t;
            }
        }
        s
    }

    /// `[swap]` placed for episode `i` of seed `seed` (reproducibly from the two); the
    /// scenario as it is without one.
    pub fn swap_episode(&self, seed: u64, i: u64) -> SimScenario {
        use rand::{Rng, SeedableRng};
        let Some(swap) = self.swap else { return self.clone() };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0x5A9);
        let mut s = self.clone();
        let turn = if i == 0 && seed == self.sensing.seed { 0.0 } else { rng.random_range(0.0..std::f64::consts::TAU) };
        let j = swap.jitter;
        let mut jitter = move |p: Point| {
            if j > 0.0 {
                p + Point::new(rng.random_range(-j..j), rng.random_range(-j..j))
            } else {
                p
            }
        };
        let centre = point(swap.centre);
        let n = swap.vehicles;
        s.vehicles.clear();
        for k in 0..n {
            let a = turn - std::f64::consts::FRAC_PI_2 + std::f64::consts::TAU * k as f64 / n as f64;
            let on = Point::from_polar(swap.circle_radius, a);
            let (start, goal) = (jitter(centre + on), jitter(centre - on));
            let heading = (goal - start).arg().to_degrees();
            if k == 0 {
                s.robot.start = [start.re, start.im];
                s.robot.heading_deg = heading;
                s.goal.position = [goal.re, goal.im];
                continue;
            }
            s.vehicles.push(VehicleSpec {
                name: format!("v{k}"),
                start: [start.re, start.im],
                heading_deg: Some(heading),
                role: Role::Navigate,
                motion: None,
                goal: Some([goal.re, goal.im]),
                ..VehicleSpec::blank()
            });
        }
        s
    }

    pub(crate) fn validate_swap(&self) -> Refused {
        let Some(swap) = self.swap else { return Ok(()) };
        if !(2..=MAX_VEHICLES).contains(&swap.vehicles) {
            return Err(("swap.vehicles".into(), format!("must be 2-{MAX_VEHICLES}, is {}", swap.vehicles)));
        }
        if !(swap.circle_radius.is_finite() && swap.circle_radius > 0.0) {
            return Err(("swap.circle_radius".into(), format!("must be a positive number, is {}", swap.circle_radius)));
        }
        if !(swap.jitter.is_finite() && swap.jitter >= 0.0) {
            return Err(("swap.jitter".into(), format!("must be 0 or more, is {}", swap.jitter)));
        }
        // Neighbours on the circle, each jittered toward the other, must still stand apart.
        let spacing = 2.0 * swap.circle_radius * (std::f64::consts::PI / swap.vehicles as f64).sin();
        let needed = 2.0 * self.robot.radius + 2.0 * std::f64::consts::SQRT_2 * swap.jitter;
        if spacing <= needed {
            return Err((
                "swap.circle_radius".into(),
                format!(
                    "{} m puts {} vehicles {:.1} cm apart on the circle: their radii and the jitter need more than \
                     {:.1} cm",
                    swap.circle_radius,
                    swap.vehicles,
                    spacing * 100.0,
                    needed * 100.0
                ),
            ));
        }
        if !self.vehicles.is_empty() {
            return Err(("vehicles".into(), "a swap places its own vehicles: leave [[vehicles]] out".into()));
        }
        Ok(())
    }

    /// `[[vehicles]]`: each one's keys, then the fleet together.
    pub(crate) fn validate_vehicles(&self) -> Refused {
        let n = 1 + self.vehicles.len();
        if n > MAX_VEHICLES {
            return Err((
                "vehicles".into(),
                format!("has {} entries: at most {}", self.vehicles.len(), MAX_VEHICLES - 1),
            ));
        }
        let leds = 2 * n + self.obstacles.len();
        if leds > MAX_VEHICLES * 2 {
            return Err((
                "vehicles".into(),
                format!(
                    "{n} vehicles (two LEDs each) and {} obstacles take {leds} LEDs: the simulated PSD controller drives at most {}",
                    self.obstacles.len(),
                    MAX_VEHICLES * 2
                ),
            ));
        }
        for (i, v) in self.vehicles.iter().enumerate() {
            self.validate_vehicle(i, v)?;
        }
        self.validate_fleet_geometry()
    }

    fn validate_vehicle(&self, i: usize, v: &VehicleSpec) -> Refused {
        let key = |k: &str| format!("vehicles[{i}].{k}");
        let name_ok = !v.name.is_empty()
            && v.name.len() <= MAX_NAME_LEN
            && v.name.starts_with(|c: char| c.is_ascii_lowercase())
            && v.name.chars().all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
        if !name_ok {
            return Err((
                key("name"),
                format!(
                    "{:?}: 1-{MAX_NAME_LEN} lower-case letters, digits and `_`, starting with a letter (a valid ROS \
                     name and file name)",
                    v.name
                ),
            ));
        }
        if v.name == ROBOT_NAME || self.vehicles[..i].iter().any(|o| o.name == v.name) {
            return Err((key("name"), format!("{:?} is taken: every vehicle needs a name of its own", v.name)));
        }
        let body = v.body(&self.robot);
        super::validate_body(&body, &format!("vehicles[{i}]"))?;
        if let Some(t) = v.goal_tolerance {
            super::validate_length(&key("goal_tolerance"), t, super::MAX_GOAL_TOLERANCE_M)?;
        }
        if let Some(t) = v.script_tolerance {
            super::validate_length(&key("script_tolerance"), t, super::MAX_BODY_M)?;
            if t < SCRIPT_PRECISION {
                return Err((key("script_tolerance"), format!("must be at least {SCRIPT_PRECISION} m, is {t}")));
            }
        }
        if let Some(at) = v.link_lost_at.filter(|at| !(at.is_finite() && *at >= 0.0 && *at <= self.time_limit)) {
            return Err((key("link_lost_at"), format!("must be 0 to time_limit ({} s), is {at}", self.time_limit)));
        }
        match (v.role, &v.motion, v.goal) {
            (Role::Script, Some(motion), None) => self.validate_script(i, v, motion, &body),
            (Role::Navigate, None, Some(goal)) => super::validate_point(&key("goal"), goal),
            (Role::Script, _, _) => {
                Err((key("motion"), "a scripted vehicle needs a `motion` and no `goal` (role = \"script\")".into()))
            }
            (Role::Navigate, _, _) => {
                Err((key("goal"), "a navigating vehicle needs a `goal` and no `motion` (role = \"navigate\")".into()))
            }
        }
    }

    /// A script its vehicle can follow within [`SCRIPT_PRECISION`]: no faster than the
    /// vehicle's speed limit, a start its ramps reach, corners its wheels can turn; a
    /// heading given at the start along its first leg.
    fn validate_script(&self, i: usize, v: &VehicleSpec, motion: &Motion, body: &RobotSpec) -> Refused {
        let key = format!("vehicles[{i}].motion");
        super::validate_motion(&key, motion)?;
        if let (Some(given), Some(way)) = (v.heading_deg, v.first_direction()) {
            let off = crate::wrap_angle((given - way).to_radians()).abs().to_degrees();
            if off > 5.0 {
                return Err((
                    format!("vehicles[{i}].heading_deg"),
                    format!("{given}° is {off:.0}° off the script's first direction, {way:.0}° (leave it out)"),
                ));
            }
        }
        let (speed, directions) = match motion {
            Motion::Stationary => (0.0, Vec::new()),
            Motion::Constant { velocity } => (point(*velocity).norm(), vec![point(*velocity)]),
            Motion::Waypoints { speed, points, repeat } => {
                let mut way: Vec<Point> = std::iter::once(v.start).chain(points.iter().copied()).map(point).collect();
                if *repeat {
                    way.push(point(v.start));
                    way.push(way[1]);
                }
                way.dedup();
                (*speed, way.windows(2).map(|w| w[1] - w[0]).collect())
            }
        };
        let wheels = Wheels {
            max_speed: body.max_speed,
            max_wheel_speed: body.max_wheel_speed,
            wheel_accel: body.wheel_accel,
            wheel_base: body.wheel_base,
        };
        followable(speed, &directions, &wheels).map_err(|why| match why {
            Unfollowable::Corner { .. } => (format!("vehicles[{i}].motion.points"), why.to_string()),
            _ => (key, why.to_string()),
        })
    }

    /// The fleet together: no two vehicles (or a vehicle and an obstacle) overlap at the
    /// start, no two goals closer than the vehicles' radii, no goal or start against a wall.
    fn validate_fleet_geometry(&self) -> Refused {
        let bodies: Vec<(String, Point, f64, Option<Point>)> = std::iter::once((
            "robot.start".to_string(),
            point(self.robot.start),
            self.robot.radius,
            Some(point(self.goal.position)),
        ))
        .chain(self.vehicles.iter().enumerate().map(|(i, v)| {
            let goal = (v.role == Role::Navigate).then(|| v.destination());
            (format!("vehicles[{i}].start"), point(v.start), v.body(&self.robot).radius, goal)
        }))
        .collect();
        for (k, (key, at, radius, goal)) in bodies.iter().enumerate() {
            for (other, at2, radius2, goal2) in &bodies[..k] {
                let gap = (*at - *at2).norm();
                if gap < radius + radius2 {
                    return Err((
                        key.clone(),
                        format!(
                            "overlaps `{other}`: centres {:.1} cm apart, radii {:.1} cm together",
                            gap * 100.0,
                            (radius + radius2) * 100.0
                        ),
                    ));
                }
                if let (Some(g), Some(g2)) = (goal, goal2) {
                    let gap = (*g - *g2).norm();
                    if gap < radius + radius2 {
                        return Err((
                            key.replace(".start", ".goal").replace("robot.goal", "goal.position"),
                            format!(
                                "is {:.1} cm from the goal of `{}`: two vehicles cannot both stand there (radii {:.1} \
                                 cm together)",
                                gap * 100.0,
                                other.trim_end_matches(".start"),
                                (radius + radius2) * 100.0
                            ),
                        ));
                    }
                }
            }
            for (j, o) in self.obstacles.iter().enumerate().filter(|_| k > 0) {
                let gap = (*at - point(o.start)).norm();
                if gap < radius + o.radius {
                    return Err((key.clone(), format!("overlaps obstacles[{j}]: centres {:.1} cm apart", gap * 100.0)));
                }
            }
            if k > 0 {
                for (what, p) in [("start", Some(*at)), ("goal", *goal)] {
                    let Some(p) = p else { continue };
                    if let Some(touched) = self.touching(p, *radius) {
                        return Err((
                            key.replace(".start", &format!(".{what}")),
                            format!("[{}, {}] puts the vehicle against {touched}", p.re, p.im),
                        ));
                    }
                }
            }
        }
        Ok(())
    }
}

impl VehicleSpec {
    /// A navigating vehicle at the origin with every body key the robot's (for code that
    /// builds fleets).
    pub fn blank() -> Self {
        Self {
            name: String::new(),
            start: [0.0, 0.0],
            heading_deg: None,
            role: Role::Navigate,
            motion: None,
            goal: None,
            goal_tolerance: None,
            script_tolerance: None,
            link_lost_at: None,
            radius: None,
            wheel_base: None,
            wheel_radius: None,
            steps_per_rev: None,
            microsteps: None,
            max_wheel_speed: None,
            wheel_accel: None,
            max_speed: None,
        }
    }
}
