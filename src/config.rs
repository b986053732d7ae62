//! The gateway's configuration (`flowgate run --config rig.toml`). `rig.example.toml`
//! documents every key. Unknown keys are refused, and [`GatewayConfig::validate`] names
//! the key of any bad value and says why.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::calib::Calibration;
use crate::link::CanUrl;

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GatewayConfig {
    pub serial: SerialConfig,
    pub leds: LedConfig,
    #[serde(default)]
    pub schedule: ScheduleConfig,
    pub calibration: CalibrationConfig,
    pub can: CanConfig,
    pub drive: DriveSection,
    pub robot: RobotSection,
    pub planner: PlannerSection,
    #[serde(default)]
    pub lane: Option<LaneSection>,
    #[serde(default)]
    pub safety: SafetyConfig,
    #[serde(default)]
    pub telemetry: TelemetryConfig,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SerialConfig {
    pub port: PathBuf,
    #[serde(default = "default_baud")]
    pub baud: u32,
}

fn default_baud() -> u32 {
    921_600
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LedConfig {
    pub robot_front: u8,
    pub robot_rear: u8,
    /// Distance of the front LED ahead of the robot's centre, m.
    pub front_offset: f64,
    /// Distance of the rear LED behind the robot's centre, m.
    pub rear_offset: f64,
    #[serde(default)]
    pub obstacles: Vec<ObstacleLed>,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleLed {
    pub led: u8,
    /// The obstacle's radius `a_0`, m.
    pub radius: f64,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScheduleConfig {
    /// Each LED's slot, µs.
    #[serde(default = "default_slot")]
    pub slot_us: u16,
    /// Dark slot for ambient subtraction, µs; 0 = none.
    #[serde(default)]
    pub dark_slot_us: u16,
    #[serde(default = "default_one")]
    pub averaging: u8,
}

fn default_slot() -> u16 {
    4000
}
fn default_one() -> u8 {
    1
}

impl Default for ScheduleConfig {
    fn default() -> Self {
        Self { slot_us: default_slot(), dark_slot_us: 0, averaging: 1 }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationConfig {
    /// Floor metres -> PSD counts, row-major. Either this or `points`.
    #[serde(default)]
    pub homography: Option<[[f64; 3]; 3]>,
    /// Reference points measured on the rig, fitted by least squares (at least 4).
    #[serde(default)]
    pub points: Vec<RefPoint>,
    #[serde(default)]
    pub k1: f64,
    #[serde(default = "default_counts")]
    pub counts: u16,
}

fn default_counts() -> u16 {
    4096
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RefPoint {
    pub raw: [f64; 2],
    pub floor: [f64; 2],
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CanConfig {
    /// `socketcan:can0`, `slcan:/dev/ttyACM0?bitrate=1000000`.
    pub endpoint: String,
    /// The motor board's node id, 1-15.
    #[serde(default = "default_node")]
    pub node: u8,
}

fn default_node() -> u8 {
    1
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriveSection {
    pub wheel_radius: f64,
    pub steps_per_rev: u32,
    pub microsteps: u32,
    pub wheel_base: f64,
    /// Wheel rim speed limit, m/s (sent to the board as its rate limit).
    pub max_wheel_speed: f64,
    /// Wheel acceleration ramp, m/s² (sent to the board).
    pub wheel_accel: f64,
    /// The board's command timeout, ms.
    #[serde(default = "default_cmd_timeout")]
    pub command_timeout_ms: u16,
}

fn default_cmd_timeout() -> u16 {
    100
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotSection {
    /// `a_r`, m.
    pub radius: f64,
    /// Speed limit of the robot's centre, m/s.
    pub max_speed: f64,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlannerSection {
    pub goal: [f64; 2],
    #[serde(default = "default_tolerance")]
    pub goal_tolerance: f64,
    pub cruise_speed: f64,
    pub c1: f64,
    pub kc: f64,
    #[serde(default)]
    pub margin: MarginSection,
    #[serde(default = "default_true")]
    pub tie_break: bool,
}

fn default_tolerance() -> f64 {
    0.02
}
fn default_true() -> bool {
    true
}

#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq)]
#[serde(tag = "rule", rename_all = "snake_case", deny_unknown_fields)]
pub enum MarginSection {
    #[default]
    None,
    Fixed {
        metres: f64,
    },
    Factor {
        factor: f64,
    },
    /// `R0 + (|V| + extra_speed) Δt` with Δt measured online.
    Delay {
        #[serde(default)]
        extra_speed: f64,
    },
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaneSection {
    pub half_width: f64,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SafetyConfig {
    /// Stop when the robot's pose has not been seen for this long, ms.
    #[serde(default = "default_pose_timeout")]
    pub pose_timeout_ms: u32,
    /// Stop when more bad serial frames than this arrive within one second.
    #[serde(default = "default_bad_budget")]
    pub bad_frames_per_s: u32,
    /// Stop when the motor board's heartbeat is missing for this long, ms.
    #[serde(default = "default_heartbeat_timeout")]
    pub heartbeat_timeout_ms: u32,
    /// Stop when no sample arrives for this long, ms (serial line dead).
    #[serde(default = "default_sample_timeout")]
    pub sample_timeout_ms: u32,
}

fn default_pose_timeout() -> u32 {
    300
}
fn default_bad_budget() -> u32 {
    20
}
fn default_heartbeat_timeout() -> u32 {
    400
}
fn default_sample_timeout() -> u32 {
    250
}

impl Default for SafetyConfig {
    fn default() -> Self {
        Self {
            pose_timeout_ms: default_pose_timeout(),
            bad_frames_per_s: default_bad_budget(),
            heartbeat_timeout_ms: default_heartbeat_timeout(),
            sample_timeout_ms: default_sample_timeout(),
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TelemetryConfig {
    /// Where trace.json, cycles.csv and can.log go; none = no files.
    #[serde(default)]
    pub out_dir: Option<PathBuf>,
    /// Capacity of the queue to the writer task (records beyond it are dropped and counted).
    #[serde(default = "default_queue")]
    pub queue: usize,
}

fn default_queue() -> usize {
    8192
}

impl Default for TelemetryConfig {
    fn default() -> Self {
        Self { out_dir: None, queue: default_queue() }
    }
}

/// A configuration that cannot be used, naming the file and the key.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config {path}: {source}")]
    Read { path: String, source: std::io::Error },
    #[error("config {path}: {source}")]
    Parse { path: String, source: Box<toml::de::Error> },
    #[error("config {path}: `{key}` {why}")]
    Invalid { path: String, key: String, why: String },
}

impl GatewayConfig {
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| ConfigError::Read { path: path.display().to_string(), source })?;
        Self::from_toml(&text, &path.display().to_string())
    }

    pub fn from_toml(text: &str, origin: &str) -> Result<Self, ConfigError> {
        let c: Self =
            toml::from_str(text).map_err(|e| ConfigError::Parse { path: origin.into(), source: Box::new(e) })?;
        c.validate().map_err(|(key, why)| ConfigError::Invalid { path: origin.into(), key, why })?;
        Ok(c)
    }

    /// The CAN endpoint, parsed.
    pub fn can_url(&self) -> CanUrl {
        self.can.endpoint.parse().expect("validated")
    }

    /// The calibration, from the homography or fitted from the points.
    pub fn calibration(&self) -> Calibration {
        let c = &self.calibration;
        match c.homography {
            Some(h) => Calibration::from_homography(h, c.k1, c.counts).expect("validated"),
            None => {
                let pts: Vec<_> = c.points.iter().map(|p| (p.raw, p.floor)).collect();
                Calibration::fit(&pts, c.k1, c.counts).expect("validated").0
            }
        }
    }

    /// Check every value; on error, the key and why.
    pub fn validate(&self) -> Result<(), (String, String)> {
        let err = |key: &str, why: String| Err((key.to_string(), why));
        let positive = |key: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                err(key, format!("must be a positive number, is {v}"))
            }
        };
        if self.serial.baud == 0 {
            return err("serial.baud", "must be positive".into());
        }
        let l = &self.leds;
        if l.robot_front == l.robot_rear {
            return err("leds.robot_rear", format!("must differ from leds.robot_front ({})", l.robot_front));
        }
        positive("leds.front_offset", l.front_offset + l.rear_offset)?;
        let mut ids = vec![l.robot_front, l.robot_rear];
        for (i, o) in l.obstacles.iter().enumerate() {
            if ids.contains(&o.led) {
                return err(&format!("leds.obstacles[{i}].led"), format!("LED {} is used twice", o.led));
            }
            ids.push(o.led);
            positive(&format!("leds.obstacles[{i}].radius"), o.radius)?;
        }
        if ids.len() > flowgate_protocol::psd::MAX_SCHEDULE_LEDS {
            return err(
                "leds.obstacles",
                format!("{} LEDs in all, at most {}", ids.len(), flowgate_protocol::psd::MAX_SCHEDULE_LEDS),
            );
        }
        if self.schedule.slot_us == 0 {
            return err("schedule.slot_us", "must be positive".into());
        }
        if self.schedule.averaging == 0 {
            return err("schedule.averaging", "must be at least 1".into());
        }
        let c = &self.calibration;
        match (c.homography, c.points.len()) {
            (Some(_), n) if n > 0 => {
                return err("calibration", "give either `homography` or `points`, not both".into())
            }
            (Some(h), _) => {
                if let Err(e) = Calibration::from_homography(h, c.k1, c.counts) {
                    return err("calibration.homography", e.to_string());
                }
            }
            (None, _) => {
                let pts: Vec<_> = c.points.iter().map(|p| (p.raw, p.floor)).collect();
                if let Err(e) = Calibration::fit(&pts, c.k1, c.counts) {
                    return err("calibration.points", e.to_string());
                }
            }
        }
        if let Err(e) = self.can.endpoint.parse::<CanUrl>() {
            return err("can.endpoint", e);
        }
        if flowgate_protocol::motor::NodeId::new(self.can.node).is_none() {
            return err("can.node", format!("must be 1-15, is {}", self.can.node));
        }
        let d = &self.drive;
        positive("drive.wheel_radius", d.wheel_radius)?;
        positive("drive.wheel_base", d.wheel_base)?;
        positive("drive.max_wheel_speed", d.max_wheel_speed)?;
        positive("drive.wheel_accel", d.wheel_accel)?;
        if d.steps_per_rev == 0 || d.microsteps == 0 {
            return err("drive.steps_per_rev", "steps_per_rev and microsteps must be at least 1".into());
        }
        if d.command_timeout_ms == 0 {
            return err("drive.command_timeout_ms", "must be positive".into());
        }
        positive("robot.radius", self.robot.radius)?;
        positive("robot.max_speed", self.robot.max_speed)?;
        let p = &self.planner;
        if !p.goal.iter().all(|v| v.is_finite()) {
            return err("planner.goal", "must be finite".into());
        }
        positive("planner.goal_tolerance", p.goal_tolerance)?;
        positive("planner.cruise_speed", p.cruise_speed)?;
        positive("planner.c1", p.c1)?;
        positive("planner.kc", p.kc)?;
        match p.margin {
            MarginSection::Factor { factor } if factor.is_nan() || factor < 1.0 => {
                return err("planner.margin.factor", format!("must be >= 1, is {factor}"))
            }
            MarginSection::Fixed { metres } if metres.is_nan() || metres < 0.0 => {
                return err("planner.margin.metres", format!("must be >= 0, is {metres}"))
            }
            _ => {}
        }
        if let Some(lane) = self.lane {
            positive("lane.half_width", lane.half_width)?;
            if p.goal[1].abs() >= lane.half_width {
                return err("planner.goal", format!("lies outside the lane (|y| >= {})", lane.half_width));
            }
        }
        let s = &self.safety;
        for (key, v) in [
            ("safety.pose_timeout_ms", s.pose_timeout_ms),
            ("safety.heartbeat_timeout_ms", s.heartbeat_timeout_ms),
            ("safety.sample_timeout_ms", s.sample_timeout_ms),
        ] {
            if v == 0 {
                return err(key, "must be positive".into());
            }
        }
        if self.telemetry.queue == 0 {
            return err("telemetry.queue", "must be positive".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const EXAMPLE: &str = include_str!("../rig.example.toml");

    #[test]
    fn the_example_is_valid() {
        let c = GatewayConfig::from_toml(EXAMPLE, "rig.example.toml").unwrap();
        assert_eq!(c.can_url(), CanUrl::Slcan { path: "/dev/ttyACM0".into(), bitrate: 1_000_000, baud: 921_600 });
        assert_eq!(c.leds.obstacles.len(), 2);
        let _ = c.calibration();
    }

    #[test]
    fn bad_values_are_refused_naming_the_key() {
        let cases = [
            ("node = 1", "node = 16", "can.node"),
            ("endpoint = \"slcan:/dev/ttyACM0?bitrate=1000000\"", "endpoint = \"can0\"", "can.endpoint"),
            ("wheel_radius = 0.025", "wheel_radius = -0.025", "drive.wheel_radius"),
            ("robot_rear = 2", "robot_rear = 1", "leds.robot_rear"),
            ("factor = 1.1", "factor = 0.9", "planner.margin.factor"),
        ];
        for (from, to, key) in cases {
            assert!(EXAMPLE.contains(from), "example lacks {from}");
            let err = GatewayConfig::from_toml(&EXAMPLE.replace(from, to), "rig.toml").unwrap_err().to_string();
            assert!(err.contains(&format!("`{key}`")), "{to}: {err}");
        }
        let err =
            GatewayConfig::from_toml(&EXAMPLE.replace("[safety]", "[safety]\nbogus = 1"), "rig.toml").unwrap_err();
        assert!(err.to_string().contains("unknown field `bogus`"), "{err}");
    }
}
