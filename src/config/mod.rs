//! The rig configuration (`flowgate run --config rig.toml`), parsed once into a typed
//! [`Rig`].
//!
//! [`RigFile`] is the file as written (`rig.example.toml` documents every key):
//! unknown keys are refused, and [`RigFile::validate`] names the key of any bad value
//! and says why. [`Rig`] is what the gateway runs with: the CAN URL parsed, the node id
//! checked, the LED schedule built, the calibration fitted, the control settings made,
//! every duration a `Duration`. The lab tools build the same `RigFile` from a
//! scenario file, so rig configs and scenarios share one set of rules and one
//! constructor of the control settings.

use std::path::Path;
use std::time::Duration;

use crate::Point;
use flowgate_protocol::motor::NodeId;
use flowgate_protocol::psd::Schedule;
use serde::{Deserialize, Serialize};

mod camera;
mod checks;
mod motors;
mod planning;
mod safety;
mod service;
mod vehicles;
pub use camera::{CalibrationSection, LedSection, ObstacleLed, RefPoint, ScheduleSection, SerialSection};
use checks::{invalid, ms, positive, Most};
pub use checks::{read_text, shown, Invalid, MAX_FILE_BYTES, MAX_GOAL_TOLERANCE};
pub use motors::{
    BoardSettings, CanSection, Cia402Section, Cia402Settings, DriveSection, MotorProtocolName, Motors,
    CIA402_CONSUMER_TIME_MS,
};
pub use planning::{default_tolerance, Goal, LaneSection, PlannerMethod, PlannerSection, RobotSection};
pub use safety::{SafetySection, SafetySettings, StopBrake};
pub use service::{OperatorSection, RealtimeSection, RealtimeSettings, RecordCompression, TelemetrySection};
pub use vehicles::{DrivenSettings, MotionSection, RoleName, Vehicle, VehicleMotors, VehicleScript, VehicleSection};
mod can_url;
mod room;
mod ros2;
pub use can_url::CanUrl;
pub use room::{PointsSection, RoomSection};
pub use ros2::{DiscoveryRange, Ros2Section, Ros2Settings, MAX_DOMAIN_ID};

use crate::calibration::Calibration;
use crate::control::drive::DriveConfig;
use crate::control::{CommandSource, ControlConfig, StallConfig, SupervisorConfig};
use crate::planner::{PlannerConfig, Space, TieBreak};
pub use crate::track::TrackingSettings;
use crate::track::{KalmanConfig, LedGeometry, PoseReach};

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RigFile {
    pub serial: SerialSection,
    pub leds: LedSection,
    #[serde(default)]
    pub schedule: ScheduleSection,
    pub calibration: CalibrationSection,
    pub can: CanSection,
    /// The CiA 402 drives, with `can.protocol = "cia402"`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cia402: Option<Cia402Section>,
    pub drive: DriveSection,
    pub robot: RobotSection,
    /// The goal `flowgate run --arm` drives to at start; goals otherwise come from the
    /// operator at run time (`flowgate ctl goal X Y`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub goal: Option<Goal>,
    pub planner: PlannerSection,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lane: Option<LaneSection>,
    /// Walls: polylines the robot keeps off (`[[walls]] points = [[x, y], ...]`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub walls: Vec<PointsSection>,
    /// Static obstacles (shelves, tables): polygons, closed by their last edge.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub static_obstacles: Vec<PointsSection>,
    /// How the room's boundary is made (the view's edge, the panels).
    #[serde(default)]
    pub room: RoomSection,
    #[serde(default)]
    pub safety: SafetySection,
    #[serde(default)]
    pub telemetry: TelemetrySection,
    #[serde(default)]
    pub operator: OperatorSection,
    #[serde(default)]
    pub realtime: RealtimeSection,
    /// flowgate as a ROS 2 node (`[ros2]`, off without it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ros2: Option<Ros2Section>,
    /// The rig's other vehicles, under the same camera and on the same bus.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub vehicles: Vec<VehicleSection>,
}

/// A configuration that cannot be used, naming the file and the key.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config {path}: {source}")]
    Read { path: String, source: std::io::Error },
    #[error("config {path}: {source}")]
    Parse { path: String, source: Box<toml::de::Error> },
    #[error("config {path}: {invalid}")]
    Invalid { path: String, invalid: Invalid },
}

impl RigFile {
    /// Read, parse and check a rig config, into the typed rig.
    pub fn load(path: &Path) -> Result<Rig, ConfigError> {
        let file = Self::read(path)?;
        let origin = path.display().to_string();
        file.check_command_source().map_err(|invalid| ConfigError::Invalid { path: origin.clone(), invalid })?;
        file.rig(&origin)
    }

    /// An outside planner reaches a rig on the control socket or on ROS 2 (a scenario's, in
    /// the lab, through the virtual rig's requests): that way must be open.
    pub fn check_command_source(&self) -> Result<(), Invalid> {
        match self.planner.method {
            PlannerMethod::Socket if self.operator.socket.is_none() => invalid(
                "planner.method",
                "\"socket\" takes the robot's commands on the control socket: set [operator] socket",
            ),
            PlannerMethod::Ros2 if !self.ros2.as_ref().is_some_and(|r| r.enabled) => {
                invalid("planner.method", "\"ros2\" takes the robot's commands on cmd_vel: set [ros2] enabled = true")
            }
            _ => Ok(()),
        }
    }

    /// Read and parse (not yet check) a config file.
    pub fn read(path: &Path) -> Result<Self, ConfigError> {
        let text = read_text(path, MAX_FILE_BYTES)
            .map_err(|source| ConfigError::Read { path: path.display().to_string(), source })?;
        Self::from_toml(&text, &path.display().to_string())
    }

    /// Parse (not yet check) config text; `origin` names it in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, ConfigError> {
        toml::from_str(text).map_err(|e| ConfigError::Parse { path: origin.into(), source: Box::new(e) })
    }

    /// Drive CiA 402 drives, as `section` says, instead of a PCL-80K-like board.
    pub fn use_cia402(&mut self, section: Cia402Section) {
        self.can.protocol = MotorProtocolName::Cia402;
        self.cia402 = Some(section);
    }

    /// The config as TOML (what an operator would write).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a config always serialises")
    }

    /// The time-division schedule this config gives `leds` (in firing order): the
    /// calibration streams its one LED with the rig's own slot settings.
    pub fn schedule_for(&self, leds: &[u8]) -> Result<Schedule, Invalid> {
        self.schedule.build(leds)
    }

    /// Check every value and build the rig; `origin` names the config in errors.
    pub fn rig(&self, origin: &str) -> Result<Rig, ConfigError> {
        self.validate().map_err(|invalid| ConfigError::Invalid { path: origin.into(), invalid })
    }

    /// Check every value; on success, the typed rig. On error, the key and why. Each section
    /// checks its own keys; the checks that tie sections together (the period against the
    /// board's timeout, the goal against the view and the lane) say which keys they weigh.
    pub fn validate(&self) -> Result<Rig, Invalid> {
        self.serial.validate()?;
        let leds = self.leds.validate()?;
        let schedule = self.schedule_with_vehicles(leds)?;
        let sample_period = Duration::from_micros(u64::from(schedule.frame_period_us()));
        let calibration = self.calibration()?;
        let (can, node) = self.can.validate()?;
        self.drive.validate(sample_period)?;
        self.robot.validate(&self.drive)?;
        self.validate_goal(&calibration)?;
        self.planner.validate()?;
        // Two walls that make a lane are the lane, in what follows.
        let lane_walls =
            self.walls_lane(&calibration).map(|lane| Self { lane: Some(lane), walls: Vec::new(), ..self.clone() });
        let this = lane_walls.as_ref().unwrap_or(self);
        this.validate_lane()?;
        let room = this.room(&calibration)?;
        self.operator.validate()?;
        self.safety.validate(sample_period, self.drive.command_timeout_ms)?;
        self.telemetry.validate()?;
        self.realtime.validate(sample_period)?;
        if let Some(r) = &self.ros2 {
            r.validate()?;
        }
        let vehicles = self.validate_vehicles(
            sample_period,
            &vehicles::Room { file: this, calibration: &calibration, room: room.clone() },
        )?;
        let control = this.control_config(sample_period, &calibration, room);
        let board = self.drive.board_settings(control.drive.pulses_per_metre())?;
        let motors = match (self.can.protocol, &self.cia402) {
            (MotorProtocolName::Pcl80k, None) => Motors::Pcl80k,
            (MotorProtocolName::Pcl80k, Some(_)) => {
                return invalid("cia402", "is set, but can.protocol is not \"cia402\"");
            }
            (MotorProtocolName::Cia402, None) => {
                return invalid("can.protocol", "is \"cia402\": the drives' [cia402] section is missing");
            }
            (MotorProtocolName::Cia402, Some(c)) => {
                Motors::Cia402(c.settings(&self.safety, &self.drive, control.drive.pulses_per_metre())?)
            }
        };
        let l = &self.leds;
        let spin = Duration::from_micros(u64::from(self.realtime.spin_us));
        Ok(Rig {
            serial: self.serial.clone(),
            can,
            node,
            motors,
            schedule,
            sample_period,
            robot_front: l.robot_front,
            robot_rear: l.robot_rear,
            led_geometry: LedGeometry { front: l.front_offset, rear: l.rear_offset },
            obstacles: l.obstacles.clone(),
            calibration,
            psd_counts: self.calibration.counts,
            control,
            board,
            tracking: self.tracking_settings(),
            safety: self.safety.settings(!self.vehicles.is_empty()),
            telemetry: self.telemetry.clone(),
            goal: self.goal,
            operator: self.operator.clone(),
            spin: (!spin.is_zero()).then_some(spin),
            warm_up: self.realtime.warm_up,
            realtime: self.realtime.settings(),
            ros2: self.ros2.clone().filter(|r| r.enabled),
            vehicles,
            config: self.clone(),
        })
    }

    /// `[goal]`: finite, with a tolerance, and where the camera sees it.
    fn validate_goal(&self, calibration: &Calibration) -> Result<(), Invalid> {
        let Some(g) = &self.goal else { return Ok(()) };
        if !g.position.iter().all(|v| v.is_finite()) {
            return invalid("goal.position", "must be finite");
        }
        positive("goal.tolerance", g.tolerance, Most(MAX_GOAL_TOLERANCE, "m"))?;
        if !calibration.in_view(Point::new(g.position[0], g.position[1])) {
            return invalid(
                "goal.position",
                format!("{:?} lies outside the calibrated arena: {}", g.position, calibration.view_extent()),
            );
        }
        Ok(())
    }

    /// `[lane]`: a width, and the goal inside it.
    fn validate_lane(&self) -> Result<(), Invalid> {
        let Some(lane) = self.lane else { return Ok(()) };
        positive("lane.half_width", lane.half_width, Most(100.0, "m"))?;
        if let Some(g) = self.goal.filter(|g| g.position[1].abs() >= lane.half_width) {
            return invalid(
                "goal.position",
                format!("{:?} lies outside the lane (|y| >= {})", g.position, lane.half_width),
            );
        }
        Ok(())
    }

    fn tracking_settings(&self) -> TrackingSettings {
        TrackingSettings {
            predict_robot: self.planner.predict_robot,
            predict_obstacles: self.planner.predict_obstacles,
            wheel_accel: self.drive.wheel_accel,
            kalman: KalmanConfig::default(),
            occluded_after: ms(self.safety.pose_timeout_ms).as_secs_f64(),
            max_obstacle_speed: self.safety.max_obstacle_speed,
        }
    }

    fn calibration(&self) -> Result<Calibration, Invalid> {
        let c = &self.calibration;
        if !c.k1.is_finite() {
            return invalid("calibration.k1", format!("must be finite, is {}", c.k1));
        }
        if c.counts < 2 {
            return invalid("calibration.counts", format!("must be at least 2, is {}", c.counts));
        }
        match (c.homography, c.points.len()) {
            (Some(_), n) if n > 0 => invalid("calibration", "give either `homography` or `points`, not both"),
            (Some(h), _) => Calibration::from_homography(h, c.k1, c.counts)
                .or_else(|e| invalid("calibration.homography", e.to_string())),
            (None, _) => {
                let pts: Vec<_> = c.points.iter().map(|p| (p.raw, p.floor)).collect();
                Calibration::fit(&pts, c.k1, c.counts)
                    .map(|(cal, _rms)| cal)
                    .or_else(|e| invalid("calibration.points", e.to_string()))
            }
        }
    }

    /// The control settings: the one place a config becomes a [`ControlConfig`].
    fn control_config(
        &self,
        sample_period: Duration,
        calibration: &Calibration,
        room: Option<std::sync::Arc<crate::planner::room::Room>>,
    ) -> ControlConfig {
        let robot = self.robot.radius;
        let reference_radius = robot + self.leds.obstacles.iter().map(|o| o.radius).fold(robot, f64::max);
        let p = &self.planner;
        let d = &self.drive;
        let mut supervisor = SupervisorConfig::new(
            d.wheel_accel,
            d.wheel_base,
            robot,
            sample_period.as_secs_f64(),
            self.lane.map(|l| l.half_width),
        );
        // Both LEDs in view: the centre keeps the farther LED's offset from the view's edge.
        let led = self.leds.front_offset.max(self.leds.rear_offset);
        supervisor.arena = calibration.inner_rect().map(|[x0, x1, y0, y1]| [x0 + led, x1 - led, y0 + led, y1 - led]);
        supervisor.room = room.clone();
        if matches!(p.method, PlannerMethod::Socket | PlannerMethod::Ros2) {
            // An outside planner may drive straight at an obstacle, so the supervisor's
            // promise must hold when the commands stop reaching the wheels (the bus off,
            // the adapter gone): the motors then hold the last one until their own timeout.
            supervisor.approach_tolerance = 0.0;
            supervisor.vehicle_approach_tolerance = 0.0;
            let motors_hold_s = match self.can.protocol {
                MotorProtocolName::Cia402 => f64::from(CIA402_CONSUMER_TIME_MS) * 1e-3,
                _ => f64::from(d.command_timeout_ms) * 1e-3,
            };
            supervisor.reaction_time += motors_hold_s;
        }
        ControlConfig {
            room,
            planner: PlannerConfig {
                space: self.lane.map_or(Space::Free, |l| Space::Lane { half_width: l.half_width }),
                cruise_speed: p.cruise_speed,
                c1: p.c1,
                reference_radius,
                max_speed: self.robot.max_speed,
                margin: p.margin,
                uncertainty_sigmas: p.uncertainty_sigmas,
                clearance: p.clearance,
                tie_break: p.tie_break.then(TieBreak::default),
                anticipation: p.anticipation,
                lane_residual: p.lane_residual,
            },
            drive: DriveConfig {
                wheel_base: d.wheel_base,
                wheel_radius: d.wheel_radius,
                steps_per_rev: d.steps_per_rev,
                microsteps: d.microsteps,
                max_wheel_speed: d.max_wheel_speed,
                steering_gain: p.kc,
                sample_time: sample_period.as_secs_f64(),
            },
            goal: self.goal.map_or(Point::default(), |g| Point::new(g.position[0], g.position[1])),
            goal_tolerance: self.goal.map_or(default_tolerance(), |g| g.tolerance),
            robot_radius: robot,
            stall: StallConfig {
                window: f64::from(self.safety.stall_window_ms) * 1e-3,
                min_progress: self.safety.stall_progress_m,
            },
            supervisor: Some(supervisor),
            goal_wait: p.goal_wait,
            evasion: p.evasion.unwrap_or(self.lane.is_none()),
            source: match p.method {
                PlannerMethod::Field => CommandSource::Field,
                PlannerMethod::Straight => CommandSource::Straight,
                PlannerMethod::Orca => CommandSource::Orca,
                PlannerMethod::SocialForce => CommandSource::SocialForce,
                PlannerMethod::Socket | PlannerMethod::Ros2 => {
                    CommandSource::Outside { max_age: f64::from(p.command_max_age_ms) * 1e-3 }
                }
            },
        }
    }
}

/// The rig as the gateway runs it: every setting parsed, checked and typed, once.
#[derive(Debug, Clone)]
pub struct Rig {
    pub serial: SerialSection,
    pub can: CanUrl,
    pub node: NodeId,
    /// What the motors speak.
    pub motors: Motors,
    /// The LED schedule: robot front, robot rear, each obstacle's LED, then each vehicle's
    /// front and rear.
    pub schedule: Schedule,
    /// One time-division frame: the control period T, exact to the microsecond.
    pub sample_period: Duration,
    pub robot_front: u8,
    pub robot_rear: u8,
    pub led_geometry: LedGeometry,
    pub obstacles: Vec<ObstacleLed>,
    pub calibration: Calibration,
    /// The PSD's full-scale counts the calibration assumes (the controller must agree).
    pub psd_counts: u16,
    pub control: ControlConfig,
    pub board: BoardSettings,
    pub tracking: TrackingSettings,
    pub safety: SafetySettings,
    pub telemetry: TelemetrySection,
    /// The goal to drive to when armed at start (`flowgate run --arm`).
    pub goal: Option<Goal>,
    pub operator: OperatorSection,
    /// The low-latency mode's polling window either side of the next frame (`None`: off).
    pub spin: Option<Duration>,
    /// Rehearse the cycle as each low-latency window opens (`[realtime] warm_up`).
    pub warm_up: bool,
    /// CPU affinity, `SCHED_FIFO` and locked memory, applied at start.
    pub realtime: RealtimeSettings,
    /// `[ros2]` when enabled.
    pub ros2: Option<Ros2Section>,
    /// The other vehicles (`[[vehicles]]`), whose LEDs follow the obstacles' in the schedule.
    pub vehicles: Vec<Vehicle>,
    /// The configuration this rig was built from (a recording keeps it as TOML, so a
    /// replay rebuilds the same rig). Kept as it is, not as text: the offline runner builds
    /// a rig every episode, and writing TOML was a twentieth of a sweep.
    pub config: RigFile,
}

impl Rig {
    /// What each robot pose is checked against: the wheels' limits and the pose tolerance.
    pub fn pose_reach(&self) -> PoseReach {
        self.pose_reach_of(&self.control.drive)
    }

    /// The same for a vehicle driven by `d`.
    pub fn pose_reach_of(&self, d: &crate::control::drive::DriveConfig) -> PoseReach {
        PoseReach {
            speed: d.max_wheel_speed,
            turn_rate: 2.0 * d.max_wheel_speed / d.wheel_base,
            tolerance: self.safety.pose_tolerance,
        }
    }

    /// The room as the drawings show it: the solved room's walls, static obstacles and
    /// view's edge, or the two walls a lane was made from (`room.walls_as_lane`).
    pub fn room_outline(&self) -> Option<crate::planner::room::RoomShape> {
        let walls = || crate::planner::room::RoomShape {
            walls: self
                .config
                .walls
                .iter()
                .map(|w| w.points.iter().map(|&[x, y]| Point::new(x, y)).collect())
                .collect(),
            obstacles: Vec::new(),
            view: None,
        };
        match &self.control.room {
            Some(room) => Some(room.shape().clone()),
            None => (!self.config.walls.is_empty()).then(walls),
        }
    }
}

#[cfg(test)]
mod tests;
