//! Scenario files as the lab tools run them: the simulator's part (world, sensing, faults,
//! checked by the simulator) and the gateway's `[planner]` settings, parsed and checked by
//! the same type and rules as a rig config. A scenario also implies a rig config (the
//! simulator's camera and LEDs, the scenario's robot, goal and planner), built here once
//! and checked by [`RigFile::validate`] like any rig's.

use std::ops::{Deref, DerefMut};
use std::path::{Path, PathBuf};

use flowgate_sim::psd_controller::LedMap;
use serde::Deserialize;

use crate::config::*;

/// A scenario: the simulator's part and the gateway's planner settings.
#[derive(Debug, Clone)]
pub struct Scenario {
    pub sim: flowgate_sim::scenario::SimScenario,
    pub planner: PlannerSection,
    /// The gateway's `[room]` settings.
    pub room: RoomSection,
    /// The safety supervisor checks every command (the default). `false` lets the planner
    /// drive alone, for before-and-after comparisons (`flowgate plan --unsupervised`); a rig
    /// config has no such switch.
    pub supervised: bool,
}

/// A scenario reads like the simulator's (`s.robot`, `s.obstacles`, `s.sensing`, ...), with
/// the planner settings typed.
impl Deref for Scenario {
    type Target = flowgate_sim::scenario::SimScenario;
    fn deref(&self) -> &Self::Target {
        &self.sim
    }
}

impl DerefMut for Scenario {
    fn deref_mut(&mut self) -> &mut Self::Target {
        &mut self.sim
    }
}

/// A scenario that could not be loaded, naming the file and the key.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    #[error(transparent)]
    Sim(#[from] flowgate_sim::scenario::ScenarioError),
    #[error("scenario {path}: [planner]: {source}")]
    Planner { path: String, source: Box<toml::de::Error> },
    #[error("scenario {path}: [room]: {source}")]
    Room { path: String, source: Box<toml::de::Error> },
    #[error("scenario {path}: {invalid}")]
    Invalid { path: String, invalid: Invalid },
    #[error("scenario {path}: setting `{setting}`: {why}")]
    Setting { path: String, setting: String, why: String },
}

/// `text` (a scenario's TOML) with `setting` (`KEY=VALUE`) set, or why it cannot be.
fn with_setting(text: &str, setting: &str) -> Result<String, String> {
    let (key, value) = setting.split_once('=').ok_or("is not KEY=VALUE")?;
    let (key, value) = (key.trim(), value.trim());
    let value: toml::Table =
        toml::from_str(&format!("value = {value}")).map_err(|e| format!("the value is not TOML: {}", e.message()))?;
    let value = value.get("value").cloned().ok_or("no value")?;
    let mut table: toml::Table = toml::from_str(text).map_err(|e| e.message().to_owned())?;
    let mut parts: Vec<&str> = key.split('.').collect();
    let last = parts.pop().filter(|k| !k.is_empty()).ok_or("no key")?;
    let mut here = &mut table;
    for part in parts {
        let next = here.entry(part).or_insert_with(|| toml::Value::Table(toml::Table::new()));
        here = next.as_table_mut().ok_or_else(|| format!("`{part}` is not a table"))?;
    }
    here.insert(last.to_owned(), value);
    toml::to_string(&table).map_err(|e| e.to_string())
}

/// The board's command timeout in the simulated rig: ten cycles of 20 ms, so a shared test
/// machine can stall a cycle or two without the board stopping the robot.
const SIM_COMMAND_TIMEOUT_MS: u16 = 200;

impl Scenario {
    /// Read, parse and check a scenario file.
    pub fn load(path: &Path) -> Result<Self, ScenarioError> {
        let sim = flowgate_sim::scenario::SimScenario::load(path)?;
        Self::new(sim, &path.display().to_string())
    }

    /// [`load`](Self::load), with one setting changed: `setting` is `KEY=VALUE`, the key
    /// dotted (`planner.lane_residual`), the value TOML (`1e-4`, `true`, `"text"`). The
    /// scenario is checked with it as if the file said so.
    pub fn load_with(path: &Path, setting: &str) -> Result<Self, ScenarioError> {
        let origin = path.display().to_string();
        let text = flowgate_sim::scenario::read_text(path, flowgate_sim::scenario::MAX_FILE_BYTES)
            .map_err(|source| flowgate_sim::scenario::ScenarioError::Read { path: origin.clone(), source })?;
        let changed = with_setting(&text, setting).map_err(|why| ScenarioError::Setting {
            path: origin.clone(),
            setting: setting.into(),
            why,
        })?;
        Self::from_toml(&changed, &format!("{origin} with {setting}"))
    }

    /// Parse and check scenario text; `origin` names it in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, ScenarioError> {
        Self::new(flowgate_sim::scenario::SimScenario::from_toml(text, origin)?, origin)
    }

    /// The gateway's part of a parsed simulator scenario, checked.
    pub fn new(sim: flowgate_sim::scenario::SimScenario, origin: &str) -> Result<Self, ScenarioError> {
        let planner = PlannerSection::deserialize(toml::Value::Table(sim.planner.clone()))
            .map_err(|e| ScenarioError::Planner { path: origin.into(), source: Box::new(e) })?;
        let room = RoomSection::deserialize(toml::Value::Table(sim.room.clone()))
            .map_err(|e| ScenarioError::Room { path: origin.into(), source: Box::new(e) })?;
        let mut s = Self { sim, planner, room, supervised: true };
        let frame_us = s.frame_us().map_err(|invalid| ScenarioError::Invalid { path: origin.into(), invalid })?;
        s.cut_scripts_at_the_room(frame_us)
            .map_err(|invalid| ScenarioError::Invalid { path: origin.into(), invalid })?;
        let rig = s
            .config_with(Path::new("/dev/null"), "slcan:/dev/null", None, frame_us)
            .validate()
            .map_err(|invalid| ScenarioError::Invalid { path: origin.into(), invalid })?;
        s.robot_in_view(&rig).map_err(|invalid| ScenarioError::Invalid { path: origin.into(), invalid })?;
        s.start_reaches_the_goal(&rig).map_err(|invalid| ScenarioError::Invalid { path: origin.into(), invalid })?;
        for k in 1..=s.vehicles.len() {
            s.vehicle(k)
                .check_as_vehicle(k, frame_us)
                .map_err(|invalid| ScenarioError::Invalid { path: origin.into(), invalid })?;
        }
        Ok(s)
    }

    /// Vehicle `k` (0: the robot) alone: its body, start and goal in this scenario's room,
    /// with its obstacles and planner settings.
    pub fn vehicle(&self, k: usize) -> Scenario {
        Scenario { sim: self.sim.vehicle_alone(k), ..self.clone() }
    }

    /// Cut each script where its vehicle would leave the room the gateway plans in (the
    /// view's edge less the LEDs' reach and `room.view_inset`, the walls, the furniture), or
    /// without a room where the camera would lose either LED: the vehicle stops at its last
    /// point inside, and a note says so.
    fn cut_scripts_at_the_room(&mut self, frame_us: u32) -> Result<(), Invalid> {
        use flowgate_sim::world::fleet::cut_script;
        for i in 0..self.vehicles.len() {
            let mut alone = self.vehicle(i + 1);
            alone.sim.goal.position = alone.sim.robot.start;
            let rig = alone.config_with(Path::new("/dev/null"), "slcan:/dev/null", None, frame_us).validate();
            let rig = rig.map_err(|e| vehicle_key(i + 1, e))?;
            let note = match &rig.control.room {
                Some(room) => {
                    let start = alone.robot_start();
                    cut_script(&mut self.sim, i, "leaves the room", |p, _| {
                        room.blocked_at(p).is_none() && room.reachable(start, p)
                    })
                }
                None => cut_script(&mut self.sim, i, "leaves the camera's view", |p, way| {
                    let along = if way.norm() > 0.0 { way / way.norm() } else { way };
                    let (front, rear) = rig.led_geometry.leds(p, along);
                    way.norm() == 0.0 || (rig.calibration.in_view(front) && rig.calibration.in_view(rear))
                }),
            };
            self.sim.notes.extend(note);
        }
        Ok(())
    }

    /// The checks of a robot, on vehicle `k` of a fleet (this scenario its alone), naming
    /// its keys.
    fn check_as_vehicle(&self, k: usize, frame_us: u32) -> Result<(), Invalid> {
        let name = |invalid: Invalid| vehicle_key(k, invalid);
        let rig =
            self.config_with(Path::new("/dev/null"), "slcan:/dev/null", None, frame_us).validate().map_err(name)?;
        self.robot_in_view(&rig).map_err(name)?;
        self.start_reaches_the_goal(&rig).map_err(name)
    }

    /// In a room, the robot's start must be clear of it and the goal within its reach.
    fn start_reaches_the_goal(&self, rig: &Rig) -> Result<(), Invalid> {
        let Some(room) = &rig.control.room else { return Ok(()) };
        let (start, goal) = (self.robot_start(), self.goal());
        if let Some(why) = room.blocked_at(start) {
            return Err(Invalid { key: "robot.start".into(), why: format!("{:?} {why}", self.robot.start) });
        }
        if !room.reachable(start, goal) {
            return Err(Invalid {
                key: "goal.position".into(),
                why: format!(
                    "{:?} is out of the robot's reach from robot.start {:?}: the walls, static obstacles or the view's \
                     edge close it off",
                    self.goal.position, self.robot.start
                ),
            });
        }
        Ok(())
    }

    /// The robot must start where the simulated camera sees both its LEDs: a robot it cannot
    /// see never gets a pose. (The goal is checked with the rig config; obstacles may start
    /// outside the view and come into it.)
    fn robot_in_view(&self, rig: &Rig) -> Result<(), Invalid> {
        let r = &self.robot;
        let facing = num_complex::Complex64::from_polar(1.0, r.heading_deg.to_radians());
        let centre = num_complex::Complex64::new(r.start[0], r.start[1]);
        let (front, rear) = rig.led_geometry.leds(centre, facing);
        match [front, rear].into_iter().find(|&p| !rig.calibration.in_view(p)) {
            None => Ok(()),
            Some(p) => Err(Invalid {
                key: "robot.start".into(),
                why: format!(
                    "{:?}: the robot's LED at ({:.3}, {:.3}) lies outside the simulated camera's view: {}",
                    r.start,
                    p.re,
                    p.im,
                    rig.calibration.view_extent()
                ),
            }),
        }
    }

    /// The fastest any of the scenario's obstacles moves, m/s (0 when none moves).
    fn fastest_obstacle(&self) -> f64 {
        self.obstacles.iter().map(|o| o.top_speed()).fold(0.0, f64::max)
    }

    /// The control period as whole microseconds (the PSD schedule's unit).
    fn frame_us(&self) -> Result<u32, Invalid> {
        let us = self.sensing.sample_time * 1e6;
        let whole = us.round();
        if (us - whole).abs() > 1e-6 || !(1.0..=f64::from(u32::MAX)).contains(&whole) {
            return Err(Invalid {
                key: "sensing.sample_time".into(),
                why: format!(
                    "must be a whole number of microseconds from 1 µs to {} s (the PSD schedule's unit and \
                     range), is {:e} s",
                    f64::from(u32::MAX) / 1e6,
                    self.sensing.sample_time
                ),
            });
        }
        Ok(whole as u32)
    }

    /// The rig config of this scenario's simulated rig, with the PSD controller at `psd`
    /// and the CAN bus at `can`; a fleet's other vehicles as `flowgate-sim` wires them.
    pub fn rig_file(&self, psd: &Path, can: &str, out_dir: Option<PathBuf>) -> RigFile {
        self.rig_file_wired(psd, can, out_dir, &flowgate_sim::rig::RigConfig::new(self.sim.clone()))
    }

    /// The same, the fleet's vehicles as `wiring` wires them.
    pub fn rig_file_wired(
        &self,
        psd: &Path,
        can: &str,
        out_dir: Option<PathBuf>,
        wiring: &flowgate_sim::rig::RigConfig,
    ) -> RigFile {
        let frame_us = self.frame_us().expect("checked when loaded");
        let vehicles = self.sim_vehicles(wiring).expect("loading refused a fleet past the simulated controller's LEDs");
        RigFile { vehicles, ..self.config_with(psd, can, out_dir, frame_us) }
    }

    /// The fleet's other vehicles as the simulated rig `wiring` wires them (by default their
    /// LEDs after the obstacles', their boards at the nodes after the robot's node 1), their
    /// bodies and a navigating vehicle's goal the scenario's. Empty without a fleet.
    pub fn sim_vehicles(
        &self,
        wiring: &flowgate_sim::rig::RigConfig,
    ) -> Result<Vec<VehicleSection>, flowgate_sim::rig::RigError> {
        let wired = wiring.vehicles()?;
        let bodies = self.sim.fleet().map(|(_, body, _)| body);
        let vehicles = (wired.into_iter().zip(bodies).enumerate().skip(1))
            .map(|(k, (v, body))| {
                use flowgate_sim::motors::MotorKind;
                let (node, left_node, right_node, protocol) = match v.motors {
                    MotorKind::Board(node) => (Some(node.get()), None, None, None),
                    MotorKind::Cia402 { left, right } => {
                        (None, Some(left.get()), Some(right.get()), Some(MotorProtocolName::Cia402))
                    }
                };
                // A navigating vehicle's goal, for `flowgate run --arm` (a script is not one).
                let navigates = self.sim.vehicles[k - 1].role == flowgate_sim::scenario::vehicles::Role::Navigate;
                let goal = navigates.then(|| self.vehicle(k).sim.goal);
                VehicleSection {
                    name: v.name,
                    front_led: v.front_led,
                    rear_led: v.rear_led,
                    front_offset: Some(0.5 * body.radius),
                    rear_offset: Some(0.5 * body.radius),
                    node,
                    left_node,
                    right_node,
                    protocol,
                    radius: Some(body.radius),
                    max_speed: Some(body.max_speed),
                    wheel_radius: Some(body.wheel_radius),
                    steps_per_rev: Some(body.steps_per_rev),
                    microsteps: Some(body.microsteps),
                    wheel_base: Some(body.wheel_base),
                    max_wheel_speed: Some(body.max_wheel_speed),
                    wheel_accel: Some(body.wheel_accel),
                    goal: goal.map(|g| g.position),
                    goal_tolerance: goal.map(|g| g.tolerance),
                    ..crate::lab::fleet::stack::script_keys(&self.sim.vehicles[k - 1])
                }
            })
            .collect();
        Ok(vehicles)
    }

    /// The typed rig of this scenario (endpoints unused: for the virtual-time tools).
    pub fn rig(&self) -> Rig {
        self.rig_on("slcan:/dev/null")
    }

    /// The typed rig of this scenario with its CAN link at `can` (a valid endpoint URL).
    pub fn rig_on(&self, can: &str) -> Rig {
        self.rig_with(can, false)
    }

    /// The typed rig, its motors the simulator's CiA 402 drives (nodes 1 and 2) when
    /// `cia402`.
    pub fn rig_with(&self, can: &str, cia402: bool) -> Rig {
        let mut wiring = flowgate_sim::rig::RigConfig::new(self.sim.clone());
        if cia402 {
            let node = |n| flowgate_protocol::canopen::NodeId::new(n).expect("1-127");
            wiring.cia402 = Some([node(1), node(2)]);
        }
        self.rig_wired(can, &wiring)
    }

    /// The gateway's rig for the simulated rig `wiring`: the robot's motors and every
    /// vehicle's as it wires them.
    pub fn rig_wired(&self, can: &str, wiring: &flowgate_sim::rig::RigConfig) -> Rig {
        let mut config = self.rig_file_wired(Path::new("/dev/null"), can, None, wiring);
        if let Some([left, right]) = wiring.cia402 {
            config.use_cia402(crate::config::Cia402Section::with_nodes(left.get(), right.get()));
        }
        let mut rig = config.validate().expect("checked when loaded");
        if !self.supervised {
            rig.control.supervisor = None;
        }
        rig
    }

    fn config_with(&self, psd: &Path, can: &str, out_dir: Option<PathBuf>, frame_us: u32) -> RigFile {
        let leds = LedMap::standard(self.robot.radius);
        let cam = self.camera;
        let r = &self.robot;
        let delay_ms = (self.sensing.delay * 1e3).ceil().clamp(0.0, 60_000.0) as u32;
        // A rig with a known sensing delay accepts poses that old (and no older), and its
        // first samples come that much later.
        let safety = SafetySection::default();
        let (pose_timeout_ms, sample_timeout_ms) =
            (safety.pose_timeout_ms + delay_ms, safety.sample_timeout_ms + delay_ms);
        // The board's timeout must leave the gateway's watchdogs a cycle to fire first.
        let timeout_ms = (pose_timeout_ms.max(sample_timeout_ms) + 2 * frame_us.div_ceil(1000))
            .max(3 * frame_us / 1000 + 1)
            .max(u32::from(SIM_COMMAND_TIMEOUT_MS));
        RigFile {
            serial: SerialSection { port: psd.to_path_buf(), baud: 921_600 },
            leds: LedSection {
                robot_front: leds.robot_front,
                robot_rear: leds.robot_rear,
                front_offset: leds.robot_led_offset,
                rear_offset: leds.robot_led_offset,
                obstacles: self
                    .obstacles
                    .iter()
                    .enumerate()
                    .map(|(k, o)| ObstacleLed {
                        led: leds.first_obstacle.saturating_add(u8::try_from(k).unwrap_or(u8::MAX)),
                        radius: o.radius,
                        required: false,
                    })
                    .collect(),
            },
            schedule: ScheduleSection { slot_us: None, frame_us: Some(frame_us), dark_slot_us: 0, averaging: 1 },
            calibration: CalibrationSection {
                homography: Some(cam.homography),
                points: Vec::new(),
                k1: cam.k1,
                counts: cam.counts,
            },
            can: CanSection { endpoint: can.to_string(), protocol: Default::default(), node: 1 },
            cia402: None,
            drive: DriveSection {
                wheel_radius: r.wheel_radius,
                steps_per_rev: r.steps_per_rev,
                microsteps: r.microsteps,
                wheel_base: r.wheel_base,
                max_wheel_speed: r.max_wheel_speed,
                wheel_accel: r.wheel_accel,
                command_timeout_ms: u16::try_from(timeout_ms).unwrap_or(u16::MAX),
            },
            robot: RobotSection { radius: r.radius, max_speed: r.max_speed },
            goal: Some(Goal { position: self.goal.position, tolerance: self.goal.tolerance }),
            planner: self.planner,
            lane: self.lane.map(|l| LaneSection { half_width: l.half_width }),
            walls: self.walls.iter().map(|w| PointsSection { points: w.points.clone() }).collect(),
            static_obstacles: self
                .static_obstacles
                .iter()
                .map(|o| PointsSection { points: o.points.clone() })
                .collect(),
            room: self.room,
            // An unseen obstacle's region grows at the fastest any of them can go.
            safety: SafetySection {
                pose_timeout_ms,
                sample_timeout_ms,
                occlusion_timeout_ms: safety.occlusion_timeout_ms + delay_ms,
                max_obstacle_speed: safety.max_obstacle_speed.max(self.fastest_obstacle()),
                ..safety
            },
            telemetry: TelemetrySection { out_dir, ..TelemetrySection::default() },
            operator: OperatorSection::default(),
            realtime: Default::default(),
            ros2: None,
            vehicles: Vec::new(),
        }
    }
}

/// A robot's check failed on vehicle `k` of a fleet: its key named as the vehicle's.
fn vehicle_key(k: usize, invalid: Invalid) -> Invalid {
    let prefix = format!("vehicles[{}]", k - 1);
    let key = match invalid.key.as_str() {
        "goal.position" => format!("{prefix}.goal"),
        "goal.tolerance" => format!("{prefix}.goal_tolerance"),
        key => key.replacen("robot.", &format!("{prefix}."), 1),
    };
    Invalid { key, ..invalid }
}

#[cfg(test)]
mod tests {
    use super::*;

    const E2: &str = include_str!("../../scenarios/e2-lane-head-on.toml");

    #[test]
    fn planner_settings_share_the_rig_rules() {
        let s = Scenario::from_toml(E2, "e2").unwrap();
        assert_eq!(s.rig().sample_period, std::time::Duration::from_millis(20), "exact, not 19.998 ms");
        for (from, to, key) in [
            ("kc = ", "kc = -", "planner.kc"),
            ("rule = \"none\"", "rule = \"delay\", extra_speed = nan", "planner.margin.extra_speed"),
            ("sample_time = 0.02", "sample_time = 0.0200005", "sensing.sample_time"),
            ("sample_time = 0.02", "sample_time = 1e9", "sensing.sample_time"),
        ] {
            assert!(E2.contains(from), "{from}");
            let err = Scenario::from_toml(&E2.replacen(from, to, 1), "e2").unwrap_err().to_string();
            assert!(err.contains(&format!("`{key}`")), "{to}: {err}");
        }
        let err = Scenario::from_toml(&E2.replacen("sample_time = 0.02", "sample_time = 1e9", 1), "e2").unwrap_err();
        assert!(
            err.to_string().contains("from 1 µs to 4294.967295 s (the PSD schedule's unit and range), is 1e9 s"),
            "{err}"
        );
        let err = Scenario::from_toml(&E2.replace("[planner]", "[planner]\nbogus = 1"), "e2").unwrap_err();
        assert!(err.to_string().contains("unknown field `bogus`"), "{err}");
    }

    const E1: &str = include_str!("../../scenarios/e1-standing-obstacle.toml");

    /// A start or goal the simulated camera cannot see is refused at load, naming the key,
    /// the point and the arena's extent; an obstacle may start out of view.
    #[test]
    fn points_the_camera_cannot_see_are_refused_at_load() {
        let far_start = E1.replacen("start = [-0.35, -0.06]", "start = [-1.5, -0.06]", 1);
        let err = Scenario::from_toml(&far_start, "e1").unwrap_err().to_string();
        assert!(err.contains("`robot.start`") && err.contains("[-1.5, -0.06]"), "{err}");
        assert!(err.contains("the PSD sees the floor within the corners ("), "{err}");
        let far_goal = E1.replacen("position = [0.35, 0.05]", "position = [50.0, 0.0]", 1);
        let err = Scenario::from_toml(&far_goal, "e1").unwrap_err().to_string();
        assert!(
            err.contains("`goal.position`") && err.contains("[50.0, 0.0] lies outside the calibrated arena"),
            "{err}"
        );
        let far_obstacle = E1.replacen("start = [0.0, 0.0]", "start = [0.0, 1.5]", 1);
        Scenario::from_toml(&far_obstacle, "e1").unwrap();
    }
}
