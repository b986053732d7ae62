//! The rig configuration (`flowgate run --config rig.toml`), parsed once into a typed
//! [`Rig`].
//!
//! [`GatewayConfig`] is the file as written (`rig.example.toml` documents every key):
//! unknown keys are refused, and [`GatewayConfig::validate`] names the key of any bad value
//! and says why. [`Rig`] is what the gateway runs with: the CAN URL parsed, the node id
//! checked, the LED schedule built, the calibration fitted, the control settings made,
//! every duration a `Duration`. The lab tools build the same `GatewayConfig` from a
//! scenario file, so rig configs and scenarios share one set of rules and one
//! constructor of the control settings.

use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::Point;
use flowgate_protocol::canopen;
use flowgate_protocol::motor::{NodeId, MAX_U24};
use flowgate_protocol::psd::{LedSlot, Schedule, MAX_SCHEDULE_LEDS};
use serde::{Deserialize, Serialize};

mod can_url;
mod room;
mod ros2;
pub use can_url::CanUrl;
pub use room::{PointsSection, RoomSection};
pub use ros2::{DiscoveryRange, Ros2Config, Ros2Settings, MAX_DOMAIN_ID};

use crate::calibration::Calibration;
use crate::control::drive::DriveConfig;
use crate::control::{ControlConfig, StallConfig, SupervisorConfig};
use crate::planner::{Margin, PlannerConfig, Space, TieBreak, MAX_OBSTACLES};
pub use crate::track::TrackingSettings;
use crate::track::{KalmanConfig, LedGeometry};

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GatewayConfig {
    pub serial: SerialConfig,
    pub leds: LedConfig,
    #[serde(default)]
    pub schedule: ScheduleConfig,
    pub calibration: CalibrationConfig,
    pub can: CanConfig,
    /// The CiA 402 drives, with `can.protocol = "cia402"`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cia402: Option<Cia402Section>,
    pub drive: DriveSection,
    pub robot: RobotSection,
    /// The goal `flowgate run --arm` drives to at start; goals otherwise come from the
    /// operator at run time (`flowgate ctl goal X Y`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub goal: Option<Goal>,
    pub planner: PlannerSettings,
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
    pub safety: SafetyConfig,
    #[serde(default)]
    pub telemetry: TelemetryConfig,
    #[serde(default)]
    pub operator: OperatorConfig,
    #[serde(default)]
    pub realtime: RealtimeConfig,
    /// flowgate as a ROS 2 node (`[ros2]`, off without it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ros2: Option<Ros2Config>,
}

/// How the gateway trades CPU for latency on a rig that gives it a core.
#[derive(Debug, Clone, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RealtimeConfig {
    /// Low-latency mode: poll for the next frame from this long before it is due until this
    /// long after, instead of sleeping (src/gateway/shell/low_latency.rs); 0 = off (default). Costs
    /// about (spin_us + 1 ms) / T of a core (`flowgate bench` measures it).
    #[serde(default)]
    pub spin_us: u32,
    /// With the low-latency mode: as each window opens, run the cycle's code (decode,
    /// calibration, tracking, the plan, the supervisor, encoding) once on the last state and
    /// discard the result, so that code and its data are in cache when the frame comes
    /// ([`crate::gateway::core::Core::rehearse`]). Off by default.
    #[serde(default)]
    pub warm_up: bool,
    /// Run the control loop on these CPUs only (e.g. `[3]`, a core kept free with
    /// `isolcpus=`); empty = anywhere (default).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cpus: Vec<usize>,
    /// `SCHED_FIFO` priority of the control loop, 1-99; 0 = the normal policy (default).
    /// Needs CAP_SYS_NICE or `LimitRTPRIO=` in the unit.
    #[serde(default)]
    pub fifo_priority: u8,
    /// Lock the gateway's memory (`mlockall`): no page faults on the rig path. Needs
    /// CAP_IPC_LOCK or `LimitMEMLOCK=infinity` in the unit.
    #[serde(default)]
    pub lock_memory: bool,
}

/// The local control interface: the only way to command motion.
#[derive(Debug, Clone, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct OperatorConfig {
    /// The control socket (a unix socket, mode 0660); none = no control interface.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub socket: Option<PathBuf>,
    /// The group that may use it (by name, from /etc/group); default: the gateway's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub group: Option<String>,
    /// Serve `/metrics` (OpenMetrics text, for Prometheus) here, e.g. `127.0.0.1:9187`; none = not served.
    /// Read-only; keep it on loopback unless the network is the lab's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub metrics: Option<std::net::SocketAddr>,
    /// Serve the live view (a page drawing the arena, updated live) here, e.g.
    /// `127.0.0.1:8080`; none = not served. Read-only, like `metrics`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view: Option<std::net::SocketAddr>,
    /// Serve the recording's channels live over the Foxglove WebSocket protocol here, e.g.
    /// `127.0.0.1:8765` (Foxglove's default): Foxglove connects to the running gateway.
    /// None = not served. Read-only, like `metrics`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub foxglove: Option<std::net::SocketAddr>,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SerialConfig {
    pub port: PathBuf,
    #[serde(default = "default_baud")]
    pub baud: u32,
}

fn default_baud() -> u32 {
    921_600
}

#[derive(Debug, Clone, Deserialize, Serialize)]
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

#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleLed {
    pub led: u8,
    /// The obstacle's radius `a_0`, m.
    pub radius: f64,
    /// Whether the gateway may arm only once this LED has been seen. By default an obstacle
    /// not seen yet is absent (parked outside the arena, not switched on) and is avoided
    /// from its first sample.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub required: bool,
}

/// The time-division schedule: each LED's slot (`slot_us`), or the whole frame
/// (`frame_us`, split over the LEDs to the microsecond so the period is exact).
#[derive(Debug, Clone, Copy, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ScheduleConfig {
    /// Each LED's slot, µs (default 4000 when `frame_us` is not given).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub slot_us: Option<u32>,
    /// The whole frame, µs, dark slot included: the control period T.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_us: Option<u32>,
    /// Dark slot for ambient subtraction, µs; 0 = none.
    #[serde(default)]
    pub dark_slot_us: u16,
    #[serde(default = "default_one")]
    pub averaging: u8,
}

fn default_one() -> u8 {
    1
}

const DEFAULT_SLOT_US: u32 = 4000;

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationConfig {
    /// Floor metres -> PSD counts, row-major. Either this or `points`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
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

#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RefPoint {
    pub raw: [f64; 2],
    pub floor: [f64; 2],
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CanConfig {
    /// `socketcan:can0`, `slcan:/dev/ttyACM0?bitrate=1000000`.
    pub endpoint: String,
    /// What the motors speak: one PCL-80K-like board for both wheels (the default), or one
    /// CiA 402 drive a wheel (`[cia402]`).
    #[serde(default)]
    pub protocol: MotorProtocolName,
    /// The motor board's node id, 1-15.
    #[serde(default = "default_node")]
    pub node: u8,
}

fn default_node() -> u8 {
    1
}

/// `can.protocol`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MotorProtocolName {
    #[default]
    Pcl80k,
    Cia402,
}

/// `[cia402]`: one CiA 402 drive a wheel, in profile velocity mode (docs/cia402.md).
#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Cia402Section {
    /// The left and right wheels' drives' node ids, 1-127.
    pub left_node: u8,
    pub right_node: u8,
    /// The gateway's own node id: its heartbeat is `0x700 +` this, consumed by the drives.
    #[serde(default = "default_gateway_node")]
    pub gateway_node: u8,
    /// How long each configuration SDO may go unanswered, ms.
    #[serde(default = "default_sdo_timeout")]
    pub sdo_timeout_ms: u32,
    /// From the arm, how long the drives may take to reach operation enabled, ms.
    #[serde(default = "default_enable_timeout")]
    pub enable_timeout_ms: u32,
    /// Each drive's heartbeat period (0x1017), ms.
    #[serde(default = "default_drive_heartbeat")]
    pub heartbeat_ms: u16,
    /// Each drive's TPDO event timer (statusword, velocity, position), ms.
    #[serde(default = "default_report")]
    pub report_ms: u16,
    /// Drive velocity units per pulse (microstep) a second; accelerations take the same
    /// unit per second. 1 when the drive counts in microsteps.
    #[serde(default = "default_velocity_scale")]
    pub velocity_scale: f64,
    /// The wheels' quick-stop deceleration (e-stop), m/s².
    #[serde(default = "default_quick_stop_decel")]
    pub quick_stop_decel: f64,
}

fn default_gateway_node() -> u8 {
    127
}
fn default_sdo_timeout() -> u32 {
    100
}
fn default_enable_timeout() -> u32 {
    1000
}
fn default_drive_heartbeat() -> u16 {
    100
}
fn default_report() -> u16 {
    10
}
fn default_velocity_scale() -> f64 {
    1.0
}
fn default_quick_stop_decel() -> f64 {
    4.0
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
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
    /// The board's command timeout, ms: the board stops by itself after this silence. The
    /// last line of defence (the gateway's own watchdogs must fire first, checked at load).
    #[serde(default = "default_cmd_timeout")]
    pub command_timeout_ms: u16,
}

fn default_cmd_timeout() -> u16 {
    200
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RobotSection {
    /// `a_r`, m.
    pub radius: f64,
    /// Speed limit of the robot's centre, m/s.
    pub max_speed: f64,
}

/// A goal: where, and how close counts as there (the rig config's `[goal]`, and each goal an
/// operator sets).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Goal {
    /// Floor coordinates, m.
    pub position: [f64; 2],
    /// m (default 0.02).
    #[serde(default = "default_tolerance")]
    pub tolerance: f64,
}

pub fn default_tolerance() -> f64 {
    0.02
}

/// The planner's settings: the `[planner]` section of rig configs and scenario files alike.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PlannerSettings {
    /// Far-field speed of the goal sink, m/s (`m = cruise_speed · R_ref`).
    pub cruise_speed: f64,
    /// Goal smoothing factor `c1` of `K(r)`, 1/m.
    pub c1: f64,
    /// Steering gain `K_c` of eq. 30.
    pub kc: f64,
    /// Safety margin rule for the planning radius.
    #[serde(default)]
    pub margin: Margin,
    /// Standard deviations of each obstacle's predicted centre (its Kalman covariance at
    /// the moment the command acts) added to the planning radius; 0 plans on the estimate
    /// as if it were exact.
    #[serde(default = "default_uncertainty_sigmas")]
    pub uncertainty_sigmas: f64,
    /// Added to every planning radius, m: room for the safety supervisor, which keeps
    /// 3 mm beyond the radii and one standard deviation (the default is twice that, so the
    /// field steers the robot round the supervisor's zone rather than into it).
    #[serde(default = "default_clearance")]
    pub clearance: f64,
    /// How long the robot holds still while the goal is inside an obstacle's planning
    /// circle (an obstacle passing over it) before the run stops with `goal blocked`, s;
    /// 0 stops at once.
    #[serde(default = "default_goal_wait")]
    pub goal_wait: f64,
    /// The deterministic keep-right tie-break for symmetric configurations.
    #[serde(default = "default_true")]
    pub tie_break: bool,
    /// Delay compensation for the robot: dead-reckon its delayed pose forward with its own
    /// recent commands to the moment the command acts.
    #[serde(default = "default_true")]
    pub predict_robot: bool,
    /// Delay compensation for the obstacles: predict them with their Kalman filters to the
    /// moment the command acts. `false` reproduces the paper's E3, which planned on the
    /// delayed obstacle positions.
    #[serde(default = "default_true")]
    pub predict_obstacles: bool,
    /// Evasion: where the robot would be run into by a moving obstacle within a second,
    /// standing or holding its command, it takes the clear reachable command (reversing
    /// included) that gives up least, instead of slowing in the obstacle's way. It keeps the
    /// supervisor's promise. Unset: on, except in a lane, where passing on the side the
    /// obstacle leaves does better (docs/supervisor.md, "Evasion").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub evasion: Option<bool>,
    /// Anticipation in a lane, s (0: off): a moving obstacle is passed on the side its
    /// drift across the robot's way leaves, and planned where it will be nearest the robot
    /// while they pass, looking at most this far ahead (docs/planner.md). Not used in free
    /// space.
    #[serde(default = "default_anticipation")]
    pub anticipation: f64,
    /// In a lane: the boundary residual the obstacles' series aim at, relative to the flow
    /// on each circle, from 1e-10 to 1e-4 (docs/simulation.md, "How exact a rig's lane is"). A looser aim
    /// fits fewer orders, for a cheaper cycle.
    #[serde(default = "default_lane_residual")]
    pub lane_residual: f64,
}

fn default_true() -> bool {
    true
}

fn default_uncertainty_sigmas() -> f64 {
    1.0
}

fn default_clearance() -> f64 {
    0.006
}

fn default_anticipation() -> f64 {
    3.0
}

fn default_lane_residual() -> f64 {
    crate::planner::multipole::LOOSEST_AIM
}

fn default_goal_wait() -> f64 {
    10.0
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LaneSection {
    pub half_width: f64,
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
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
    /// How far a robot pose may be off what the rig allows (the LEDs' mounted spacing, the
    /// distance the robot can drive since the last pose) before it is discarded, m.
    #[serde(default = "default_pose_tolerance")]
    pub pose_tolerance_m: f64,
    /// Stop when a tracked obstacle stays unseen inside the view for this long, ms. Past the
    /// pose timeout it is avoided as the region it may have reached; an obstacle seen
    /// leaving the view is dropped instead.
    #[serde(default = "default_occlusion_timeout")]
    pub occlusion_timeout_ms: u32,
    /// The fastest any obstacle on the rig moves, m/s: how fast an unseen obstacle's region
    /// grows.
    #[serde(default = "default_max_obstacle_speed")]
    pub max_obstacle_speed: f64,
    /// Stop, "stalled (no progress)", when the robot has moved less than
    /// `stall_progress_m` in this long while driving, ms.
    #[serde(default = "default_stall_window")]
    pub stall_window_ms: u32,
    #[serde(default = "default_stall_progress")]
    pub stall_progress_m: f64,
}

fn default_stall_window() -> u32 {
    (StallConfig::default().window * 1e3) as u32
}
fn default_stall_progress() -> f64 {
    StallConfig::default().min_progress
}
/// The longest stall window: an hour.
const MAX_STALL_WINDOW_MS: u32 = 3_600_000;

fn default_occlusion_timeout() -> u32 {
    1000
}
fn default_max_obstacle_speed() -> f64 {
    0.5
}

fn default_pose_tolerance() -> f64 {
    0.02
}

fn default_pose_timeout() -> u32 {
    150
}
fn default_bad_budget() -> u32 {
    20
}
fn default_heartbeat_timeout() -> u32 {
    400
}
fn default_sample_timeout() -> u32 {
    100
}

impl Default for SafetyConfig {
    fn default() -> Self {
        Self {
            pose_timeout_ms: default_pose_timeout(),
            bad_frames_per_s: default_bad_budget(),
            heartbeat_timeout_ms: default_heartbeat_timeout(),
            sample_timeout_ms: default_sample_timeout(),
            pose_tolerance_m: default_pose_tolerance(),
            occlusion_timeout_ms: default_occlusion_timeout(),
            max_obstacle_speed: default_max_obstacle_speed(),
            stall_window_ms: default_stall_window(),
            stall_progress_m: default_stall_progress(),
        }
    }
}

/// The finest microstepping of a stepper driver, and the most full steps per revolution.
const MAX_MICROSTEPS: u32 = 256;
const MAX_STEPS_PER_REV: u32 = 10_000;

/// Longest watchdog accepted, ms: a minute. Longer is a typo, not a rig.
const MAX_WATCHDOG_MS: u32 = 60_000;
/// The fastest obstacle speed a config may give, m/s (a running person is about 5).
const MAX_OBSTACLE_SPEED: f64 = 10.0;
/// Largest telemetry queue accepted, records.
const MAX_QUEUE: usize = 1 << 20;

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TelemetryConfig {
    /// Where trace.json, cycles.csv and can.log go; none = no files.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub out_dir: Option<PathBuf>,
    /// An MCAP recording of the run (`flowgate run --record`): every input the core took,
    /// what it sent, each cycle's scene; `flowgate replay` plays it back.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub record: Option<PathBuf>,
    /// How the recording's chunks are compressed: `zstd` (default), `lz4` or `none`.
    /// Recordings are read whatever their compression.
    #[serde(default)]
    pub record_compression: RecordCompression,
    /// Capacity of the queue to the writer task (records beyond it are dropped and counted).
    #[serde(default = "default_queue")]
    pub queue: usize,
}

/// The compression of a recording's chunks.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum RecordCompression {
    #[default]
    Zstd,
    Lz4,
    None,
}

fn default_queue() -> usize {
    8192
}

impl Default for TelemetryConfig {
    fn default() -> Self {
        Self { out_dir: None, record: None, record_compression: RecordCompression::default(), queue: default_queue() }
    }
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

/// The largest config (or scenario) file read, bytes: real ones are a few kB.
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

/// A bad value: its key and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("`{key}` {why}")]
pub struct Invalid {
    pub key: String,
    pub why: String,
}

fn invalid<T>(key: &str, why: impl Into<String>) -> Result<T, Invalid> {
    Err(Invalid { key: key.to_string(), why: why.into() })
}

/// An upper bound of plausibility, with its unit: far beyond any rig a PSD camera watches,
/// a value is a typo (a wheel base of 1e308 m) that would only turn into infinities later.
#[derive(Debug, Clone, Copy)]
struct Most(f64, &'static str);

/// A body's or a noise's size, m.
const BODY: Most = Most(2.0, "m");
/// A speed, m/s; an acceleration, m/s².
const SPEED: Most = Most(10.0, "m/s");
const ACCEL: Most = Most(100.0, "m/s²");
/// A gain of the planner's (dimensionless).
const GAIN: Most = Most(1e6, "");
/// The largest goal tolerance, m (a goal set by an operator or a config).
pub const MAX_GOAL_TOLERANCE: f64 = 1.0;

/// A number as an error shows it: huge and tiny ones in exponent form, not 300 digits.
pub fn shown(v: f64) -> String {
    if v != 0.0 && !(1e-4..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        v.to_string()
    }
}

fn at_most(key: &str, v: f64, Most(most, unit): Most) -> Result<(), Invalid> {
    if v > most {
        let unit = if unit.is_empty() { String::new() } else { format!(" {unit}") };
        invalid(key, format!("must be at most {most}{unit}, is {}", shown(v)))
    } else {
        Ok(())
    }
}

fn positive(key: &str, v: f64, most: Most) -> Result<(), Invalid> {
    if v.is_finite() && v > 0.0 {
        at_most(key, v, most)
    } else {
        invalid(key, format!("must be a positive number, is {v}"))
    }
}

fn non_negative(key: &str, v: f64, most: Most) -> Result<(), Invalid> {
    if v.is_finite() && v >= 0.0 {
        at_most(key, v, most)
    } else {
        invalid(key, format!("must be a number >= 0, is {v}"))
    }
}

fn ms(v: u32) -> Duration {
    Duration::from_millis(u64::from(v))
}

impl SerialConfig {
    fn validate(&self) -> Result<(), Invalid> {
        if self.baud == 0 {
            return invalid("serial.baud", "must be positive");
        }
        if self.port.as_os_str().is_empty() {
            return invalid("serial.port", "is empty");
        }
        Ok(())
    }
}

impl LedConfig {
    /// The LEDs' ids in firing order: the robot's two, then the obstacles'.
    fn validate(&self) -> Result<Vec<u8>, Invalid> {
        if self.robot_front == self.robot_rear {
            return invalid("leds.robot_rear", format!("must differ from leds.robot_front ({})", self.robot_front));
        }
        non_negative("leds.front_offset", self.front_offset, BODY)?;
        non_negative("leds.rear_offset", self.rear_offset, BODY)?;
        positive("leds.front_offset", self.front_offset + self.rear_offset, BODY)?;
        // Counted first: a list of thousands is refused before its entries are looked at.
        let most = MAX_OBSTACLES.min(MAX_SCHEDULE_LEDS - 2);
        if self.obstacles.len() > most {
            return invalid(
                "leds.obstacles",
                format!(
                    "{} obstacles ({} LEDs in all): at most {most} obstacles and {MAX_SCHEDULE_LEDS} LEDs",
                    self.obstacles.len(),
                    self.obstacles.len() + 2,
                ),
            );
        }
        let mut ids = vec![self.robot_front, self.robot_rear];
        for (i, o) in self.obstacles.iter().enumerate() {
            if ids.contains(&o.led) {
                return invalid(&format!("leds.obstacles[{i}].led"), format!("LED {} is used twice", o.led));
            }
            ids.push(o.led);
            positive(&format!("leds.obstacles[{i}].radius"), o.radius, BODY)?;
        }
        Ok(ids)
    }
}

impl CanConfig {
    fn validate(&self) -> Result<(CanUrl, NodeId), Invalid> {
        let can: CanUrl = self.endpoint.parse().or_else(|e: String| invalid("can.endpoint", e))?;
        let Some(node) = NodeId::new(self.node) else {
            return invalid("can.node", format!("must be 1-15, is {}", self.node));
        };
        Ok((can, node))
    }
}

impl Cia402Section {
    /// Drives at `left` and `right`, every other key at its default.
    pub fn with_nodes(left: u8, right: u8) -> Self {
        Self {
            left_node: left,
            right_node: right,
            gateway_node: default_gateway_node(),
            sdo_timeout_ms: default_sdo_timeout(),
            enable_timeout_ms: default_enable_timeout(),
            heartbeat_ms: default_drive_heartbeat(),
            report_ms: default_report(),
            velocity_scale: default_velocity_scale(),
            quick_stop_decel: default_quick_stop_decel(),
        }
    }

    /// The nodes, the timeouts against the gateway's heartbeat watchdog, the units against
    /// the drives' 32-bit objects.
    fn settings(
        &self,
        safety: &SafetyConfig,
        drive: &DriveSection,
        pulses_per_metre: f64,
    ) -> Result<Cia402Settings, Invalid> {
        let node = |key: &str, v: u8| {
            canopen::NodeId::new(v).map_or_else(|| invalid(key, format!("must be 1-127, is {v}")), Ok)
        };
        let (left, right) = (node("cia402.left_node", self.left_node)?, node("cia402.right_node", self.right_node)?);
        let gateway = node("cia402.gateway_node", self.gateway_node)?;
        if left == right {
            return invalid("cia402.right_node", format!("is {}, the left wheel's drive's too", self.right_node));
        }
        if gateway == left || gateway == right {
            return invalid("cia402.gateway_node", format!("is {}, a drive's node id", self.gateway_node));
        }
        for (key, v) in
            [("cia402.sdo_timeout_ms", self.sdo_timeout_ms), ("cia402.enable_timeout_ms", self.enable_timeout_ms)]
        {
            if v == 0 || v > MAX_WATCHDOG_MS {
                return invalid(key, format!("must be 1-{MAX_WATCHDOG_MS} ms, is {v}"));
            }
        }
        // Two heartbeats at least within the gateway's watchdog, so one lost is no fault.
        if self.heartbeat_ms == 0 || 2 * u32::from(self.heartbeat_ms) > safety.heartbeat_timeout_ms {
            return invalid(
                "cia402.heartbeat_ms",
                format!(
                    "must be 1 ms to half of safety.heartbeat_timeout_ms = {} ms, is {}",
                    safety.heartbeat_timeout_ms, self.heartbeat_ms
                ),
            );
        }
        if !(1..=1000).contains(&self.report_ms) {
            return invalid("cia402.report_ms", format!("must be 1-1000 ms, is {}", self.report_ms));
        }
        if !(self.velocity_scale.is_finite() && self.velocity_scale > 0.0) {
            return invalid("cia402.velocity_scale", format!("must be positive, is {}", self.velocity_scale));
        }
        let scale = self.velocity_scale;
        let to_units = |key: &str, metres: f64| {
            let v = (metres * pulses_per_metre * scale).round();
            if v >= 1.0 && v <= f64::from(i32::MAX) {
                Ok(v as u32)
            } else {
                invalid(
                    key,
                    format!(
                        "is {v} drive units at this wheel, stepper and cia402.velocity_scale: must be 1-{}",
                        i32::MAX
                    ),
                )
            }
        };
        positive("cia402.quick_stop_decel", self.quick_stop_decel, ACCEL)?;
        Ok(Cia402Settings {
            left,
            right,
            gateway,
            sdo_timeout: ms(self.sdo_timeout_ms),
            enable_timeout: ms(self.enable_timeout_ms),
            heartbeat_ms: self.heartbeat_ms,
            report_ms: self.report_ms,
            velocity_scale: scale,
            max_velocity: to_units("drive.max_wheel_speed", drive.max_wheel_speed)?,
            accel: to_units("drive.wheel_accel", drive.wheel_accel)?,
            quick_stop_decel: to_units("cia402.quick_stop_decel", self.quick_stop_decel)?,
        })
    }
}

impl DriveSection {
    fn validate(&self, sample_period: Duration) -> Result<(), Invalid> {
        positive("drive.wheel_radius", self.wheel_radius, BODY)?;
        positive("drive.wheel_base", self.wheel_base, BODY)?;
        positive("drive.max_wheel_speed", self.max_wheel_speed, SPEED)?;
        positive("drive.wheel_accel", self.wheel_accel, ACCEL)?;
        if self.steps_per_rev == 0 || self.microsteps == 0 {
            return invalid("drive.steps_per_rev", "steps_per_rev and microsteps must be at least 1");
        }
        if self.microsteps > MAX_MICROSTEPS {
            return invalid(
                "drive.microsteps",
                format!("must be 1-{MAX_MICROSTEPS} (what stepper drivers do), is {}", self.microsteps),
            );
        }
        if self.steps_per_rev > MAX_STEPS_PER_REV {
            return invalid("drive.steps_per_rev", format!("must be 1-{MAX_STEPS_PER_REV}, is {}", self.steps_per_rev));
        }
        if self.command_timeout_ms == 0 {
            return invalid("drive.command_timeout_ms", "must be positive");
        }
        if sample_period >= ms(self.command_timeout_ms.into()) {
            return invalid(
                "drive.command_timeout_ms",
                format!(
                    "{} ms is not longer than the control period T = {} µs: the board would stop between commands",
                    self.command_timeout_ms,
                    sample_period.as_micros()
                ),
            );
        }
        Ok(())
    }

    /// What the board is configured with, in its pulses: each must fit its 24 bits.
    fn board_settings(&self, pulses_per_metre: f64) -> Result<BoardSettings, Invalid> {
        let to_rate = |key: &str, v: f64| {
            let rate = (v * pulses_per_metre).round();
            if rate >= 1.0 && rate <= f64::from(MAX_U24) {
                Ok(rate as u32)
            } else {
                invalid(key, format!("is {rate} pulses/s at this wheel and stepper: must be 1-{MAX_U24}"))
            }
        };
        Ok(BoardSettings {
            accel: to_rate("drive.wheel_accel", self.wheel_accel)?,
            max_rate: to_rate("drive.max_wheel_speed", self.max_wheel_speed)?,
            command_timeout_ms: self.command_timeout_ms,
        })
    }
}

impl RobotSection {
    fn validate(&self, drive: &DriveSection) -> Result<(), Invalid> {
        positive("robot.radius", self.radius, BODY)?;
        positive("robot.max_speed", self.max_speed, SPEED)?;
        // The centre moves at the mean of the wheels' rim speeds: never faster than they go.
        if self.max_speed > drive.max_wheel_speed {
            return invalid(
                "robot.max_speed",
                format!(
                    "{} m/s is above drive.max_wheel_speed = {} m/s: the wheels cannot carry the robot that fast",
                    self.max_speed, drive.max_wheel_speed
                ),
            );
        }
        Ok(())
    }
}

impl OperatorConfig {
    fn validate(&self) -> Result<(), Invalid> {
        if self.socket.as_ref().is_some_and(|p| p.as_os_str().is_empty()) {
            return invalid("operator.socket", "is empty");
        }
        Ok(())
    }
}

impl SafetyConfig {
    /// The watchdogs, against each other and against the board's command timeout.
    fn validate(&self, sample_period: Duration, board_timeout_ms: u16) -> Result<(), Invalid> {
        for (key, v) in [
            ("safety.pose_timeout_ms", self.pose_timeout_ms),
            ("safety.heartbeat_timeout_ms", self.heartbeat_timeout_ms),
            ("safety.sample_timeout_ms", self.sample_timeout_ms),
            ("safety.occlusion_timeout_ms", self.occlusion_timeout_ms),
        ] {
            if v == 0 || v > MAX_WATCHDOG_MS {
                return invalid(key, format!("must be 1-{MAX_WATCHDOG_MS} ms, is {v}"));
            }
        }
        if !(self.pose_tolerance_m.is_finite() && self.pose_tolerance_m > 0.0 && self.pose_tolerance_m <= 1.0) {
            return invalid("safety.pose_tolerance_m", format!("must be 0-1 m, is {}", self.pose_tolerance_m));
        }
        if self.occlusion_timeout_ms <= self.pose_timeout_ms {
            return invalid(
                "safety.occlusion_timeout_ms",
                format!(
                    "{} ms must exceed safety.pose_timeout_ms = {} ms: an obstacle is judged occluded only past the pose timeout",
                    self.occlusion_timeout_ms, self.pose_timeout_ms
                ),
            );
        }
        if !(self.max_obstacle_speed.is_finite()
            && self.max_obstacle_speed > 0.0
            && self.max_obstacle_speed <= MAX_OBSTACLE_SPEED)
        {
            return invalid(
                "safety.max_obstacle_speed",
                format!("must be 0-{MAX_OBSTACLE_SPEED} m/s, is {}", self.max_obstacle_speed),
            );
        }
        if !(100..=MAX_STALL_WINDOW_MS).contains(&self.stall_window_ms) {
            return invalid(
                "safety.stall_window_ms",
                format!("must be 100-{MAX_STALL_WINDOW_MS} ms, is {}", self.stall_window_ms),
            );
        }
        if !(self.stall_progress_m.is_finite() && self.stall_progress_m > 0.0 && self.stall_progress_m <= 1.0) {
            return invalid("safety.stall_progress_m", format!("must be 0-1 m, is {}", self.stall_progress_m));
        }
        // Without samples or a fresh pose the gateway sends no command, and the board stops
        // by itself after its command timeout. The gateway's own watchdog must fire first,
        // with a cycle to spare, so the stop is named by its cause (serial, pose), not as a
        // board fault.
        let board_timeout = ms(board_timeout_ms.into());
        for (key, v) in
            [("safety.sample_timeout_ms", self.sample_timeout_ms), ("safety.pose_timeout_ms", self.pose_timeout_ms)]
        {
            if ms(v) + sample_period > board_timeout {
                return invalid(
                    key,
                    format!(
                        "{v} ms plus the period T = {} µs exceeds drive.command_timeout_ms = {} ms: the board would \
                         stop the robot before the gateway names the cause",
                        sample_period.as_micros(),
                        board_timeout_ms
                    ),
                );
            }
        }
        Ok(())
    }

    fn settings(&self) -> SafetySettings {
        SafetySettings {
            pose_timeout: ms(self.pose_timeout_ms),
            bad_frames_per_s: self.bad_frames_per_s,
            heartbeat_timeout: ms(self.heartbeat_timeout_ms),
            sample_timeout: ms(self.sample_timeout_ms),
            pose_tolerance: self.pose_tolerance_m,
            occlusion_timeout: ms(self.occlusion_timeout_ms),
        }
    }
}

impl TelemetryConfig {
    fn validate(&self) -> Result<(), Invalid> {
        if self.queue == 0 || self.queue > MAX_QUEUE {
            return invalid("telemetry.queue", format!("must be 1-{MAX_QUEUE} records, is {}", self.queue));
        }
        Ok(())
    }
}

impl RealtimeConfig {
    fn validate(&self, sample_period: Duration) -> Result<(), Invalid> {
        let spin = Duration::from_micros(u64::from(self.spin_us));
        if spin * 2 >= sample_period {
            return invalid(
                "realtime.spin_us",
                format!(
                    "{} µs: the window (twice it) must be shorter than the control period T = {} µs, or the gateway \
                     never sleeps",
                    self.spin_us,
                    sample_period.as_micros()
                ),
            );
        }
        if self.warm_up && self.spin_us == 0 {
            return invalid(
                "realtime.warm_up",
                "warms the cycle up as the low-latency window opens: set realtime.spin_us too",
            );
        }
        if self.fifo_priority > 99 {
            return invalid("realtime.fifo_priority", format!("must be 1-99 (0: off), is {}", self.fifo_priority));
        }
        for (i, &cpu) in self.cpus.iter().enumerate() {
            if cpu >= rustix::thread::CpuSet::MAX_CPU {
                return invalid(&format!("realtime.cpus[{i}]"), format!("CPU {cpu} is beyond what Linux numbers"));
            }
            if self.cpus[..i].contains(&cpu) {
                return invalid(&format!("realtime.cpus[{i}]"), format!("CPU {cpu} is listed twice"));
            }
        }
        Ok(())
    }

    fn settings(&self) -> RealtimeSettings {
        RealtimeSettings {
            cpus: self.cpus.clone(),
            fifo_priority: (self.fifo_priority > 0).then_some(self.fifo_priority),
            lock_memory: self.lock_memory,
        }
    }
}

impl PlannerSettings {
    /// The planner's rules, shared by rig configs and scenario files.
    pub fn validate(&self) -> Result<(), Invalid> {
        positive("planner.cruise_speed", self.cruise_speed, SPEED)?;
        positive("planner.c1", self.c1, GAIN)?;
        positive("planner.kc", self.kc, GAIN)?;
        if !(self.uncertainty_sigmas.is_finite() && (0.0..=10.0).contains(&self.uncertainty_sigmas)) {
            return invalid(
                "planner.uncertainty_sigmas",
                format!("must be from 0 to 10 standard deviations, is {}", self.uncertainty_sigmas),
            );
        }
        if !(self.clearance.is_finite() && (0.0..=0.1).contains(&self.clearance)) {
            return invalid("planner.clearance", format!("must be from 0 to 0.1 m, is {}", self.clearance));
        }
        if !(self.anticipation.is_finite() && (0.0..=30.0).contains(&self.anticipation)) {
            return invalid("planner.anticipation", format!("must be from 0 to 30 s, is {}", self.anticipation));
        }
        if !crate::planner::multipole::aim_allowed(self.lane_residual) {
            return invalid(
                "planner.lane_residual",
                format!("must be from 1e-10 to 1e-4, is {:e}", self.lane_residual),
            );
        }
        if !(self.goal_wait.is_finite() && (0.0..=3600.0).contains(&self.goal_wait)) {
            return invalid("planner.goal_wait", format!("must be from 0 to 3600 s, is {}", self.goal_wait));
        }
        match self.margin {
            Margin::None => Ok(()),
            Margin::Fixed { metres } => non_negative("planner.margin.metres", metres, BODY),
            Margin::Factor { factor } if factor.is_finite() && factor >= 1.0 => Ok(()),
            Margin::Factor { factor } => invalid("planner.margin.factor", format!("must be >= 1, is {factor}")),
            Margin::Delay { extra_speed } => non_negative("planner.margin.extra_speed", extra_speed, SPEED),
        }
    }
}

impl ScheduleConfig {
    /// The schedule for `leds` in firing order.
    fn build(&self, leds: &[u8]) -> Result<Schedule, Invalid> {
        let n = leds.len() as u32;
        let slots: Vec<u32> = match (self.slot_us, self.frame_us) {
            (Some(_), Some(_)) => return invalid("schedule", "give `slot_us` or `frame_us`, not both"),
            (slot, None) => vec![slot.unwrap_or(DEFAULT_SLOT_US); leds.len()],
            (None, Some(frame)) => {
                let lit =
                    frame.checked_sub(u32::from(self.dark_slot_us)).filter(|&lit| lit >= n).ok_or_else(|| Invalid {
                        key: "schedule.frame_us".into(),
                        why: format!("{frame} µs leaves less than 1 µs per LED after the dark slot"),
                    })?;
                // The remainder goes one microsecond at a time to the first slots: exact T.
                (0..n).map(|i| lit / n + u32::from(i < lit % n)).collect()
            }
        };
        let key = if self.frame_us.is_some() { "schedule.frame_us" } else { "schedule.slot_us" };
        let mut wire = Vec::with_capacity(leds.len());
        for (&led, &us) in leds.iter().zip(&slots) {
            let slot_us = u16::try_from(us).ok().filter(|&us| us > 0).ok_or_else(|| Invalid {
                key: key.into(),
                why: format!("a slot of {us} µs is outside 1-{} µs", u16::MAX),
            })?;
            wire.push(LedSlot { led, slot_us });
        }
        if self.averaging == 0 {
            return invalid("schedule.averaging", "must be at least 1");
        }
        Schedule::new(&wire, self.dark_slot_us, self.averaging).or_else(|e| invalid(key, e.to_string()))
    }
}

impl GatewayConfig {
    /// Read, parse and check a rig config, into the typed rig.
    pub fn load(path: &Path) -> Result<Rig, ConfigError> {
        Self::read(path)?.rig(&path.display().to_string())
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
        let schedule = self.schedule.build(&leds)?;
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
            safety: self.safety.settings(),
            telemetry: self.telemetry.clone(),
            goal: self.goal,
            operator: self.operator.clone(),
            spin: (!spin.is_zero()).then_some(spin),
            warm_up: self.realtime.warm_up,
            realtime: self.realtime.settings(),
            ros2: self.ros2.clone().filter(|r| r.enabled),
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
        }
    }
}

/// The real-time settings of `[realtime]`, as checked at load (applied by
/// `gateway::realtime`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RealtimeSettings {
    /// Run the control loop on these CPUs only (empty: wherever the scheduler likes).
    pub cpus: Vec<usize>,
    /// `SCHED_FIFO` at this priority (1-99) for the control loop.
    pub fifo_priority: Option<u8>,
    /// `mlockall(MCL_CURRENT | MCL_FUTURE)`: no page fault on the rig path.
    pub lock_memory: bool,
}

impl RealtimeSettings {
    pub fn is_empty(&self) -> bool {
        self.cpus.is_empty() && self.fifo_priority.is_none() && !self.lock_memory
    }
}

impl fmt::Display for RealtimeSettings {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut parts = Vec::new();
        if !self.cpus.is_empty() {
            parts.push(format!("CPUs {:?}", self.cpus));
        }
        if let Some(p) = self.fifo_priority {
            parts.push(format!("SCHED_FIFO {p}"));
        }
        if self.lock_memory {
            parts.push("memory locked".to_string());
        }
        if parts.is_empty() {
            f.write_str("none")
        } else {
            f.write_str(&parts.join(", "))
        }
    }
}

/// The motors the gateway drives, as checked at load.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Motors {
    /// One PCL-80K-like board for both wheels, at [`Rig::node`].
    Pcl80k,
    /// One CiA 402 drive a wheel.
    Cia402(Cia402Settings),
}

/// `[cia402]`, typed: what the drives are configured with, in their units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cia402Settings {
    pub left: canopen::NodeId,
    pub right: canopen::NodeId,
    pub gateway: canopen::NodeId,
    pub sdo_timeout: Duration,
    pub enable_timeout: Duration,
    pub heartbeat_ms: u16,
    pub report_ms: u16,
    /// Drive velocity units per pulse a second.
    pub velocity_scale: f64,
    /// Max profile velocity (0x607F), velocity units.
    pub max_velocity: u32,
    /// Profile acceleration and deceleration (0x6083, 0x6084), velocity units per second.
    pub accel: u32,
    /// Quick-stop deceleration (0x6085), velocity units per second.
    pub quick_stop_decel: u32,
}

/// What the motor board is configured with, in its units.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BoardSettings {
    /// Acceleration ramp, pulses/s².
    pub accel: u32,
    /// Rate limit, pulses/s.
    pub max_rate: u32,
    pub command_timeout_ms: u16,
}

/// The gateway's watchdogs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SafetySettings {
    pub pose_timeout: Duration,
    pub bad_frames_per_s: u32,
    pub heartbeat_timeout: Duration,
    pub sample_timeout: Duration,
    pub pose_tolerance: f64,
    pub occlusion_timeout: Duration,
}

/// The rig as the gateway runs it: every setting parsed, checked and typed, once.
#[derive(Debug, Clone)]
pub struct Rig {
    pub serial: SerialConfig,
    pub can: CanUrl,
    pub node: NodeId,
    /// What the motors speak.
    pub motors: Motors,
    /// The LED schedule: robot front, robot rear, then each obstacle's LED.
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
    pub telemetry: TelemetryConfig,
    /// The goal to drive to when armed at start (`flowgate run --arm`).
    pub goal: Option<Goal>,
    pub operator: OperatorConfig,
    /// The low-latency mode's polling window either side of the next frame (`None`: off).
    pub spin: Option<Duration>,
    /// Rehearse the cycle as each low-latency window opens (`[realtime] warm_up`).
    pub warm_up: bool,
    /// CPU affinity, `SCHED_FIFO` and locked memory, applied at start.
    pub realtime: RealtimeSettings,
    /// `[ros2]` when enabled.
    pub ros2: Option<Ros2Config>,
    /// The configuration this rig was built from (a recording keeps it as TOML, so a
    /// replay rebuilds the same rig). Kept as it is, not as text: the offline runner builds
    /// a rig every episode, and writing TOML was a twentieth of a sweep.
    pub config: GatewayConfig,
}

impl Rig {
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
mod tests {
    use super::*;

    const EXAMPLE: &str = include_str!("../../rig.example.toml");

    fn rig(text: &str) -> Result<Rig, ConfigError> {
        GatewayConfig::from_toml(text, "rig.toml")?.rig("rig.toml")
    }

    /// The planner's default room is twice what the supervisor keeps beyond its uncertainty
    /// allowance, so the field steers round the supervisor's zone.
    #[test]
    fn the_planner_leaves_the_supervisor_room() {
        let supervisor = SupervisorConfig::new(1.0, 0.1, 0.07, 0.02, None);
        assert!((default_clearance() - 2.0 * supervisor.keep_out()).abs() < 1e-12);
        assert!(default_uncertainty_sigmas() >= supervisor.sigmas);
    }

    #[test]
    fn the_stall_check_is_the_configured_one() {
        let r = rig(EXAMPLE).unwrap();
        assert_eq!((r.control.stall.window, r.control.stall.min_progress), (3.0, 0.01), "the defaults");
        let r = rig(&EXAMPLE.replace("stall_window_ms = 3000 ", "stall_window_ms = 3600000 ")).unwrap();
        assert_eq!(r.control.stall.window, 3600.0);
    }

    #[test]
    fn the_example_is_valid() {
        let r = rig(EXAMPLE).unwrap();
        assert_eq!(r.can, CanUrl::Slcan { path: "/dev/flowgate-can".into(), bitrate: 1_000_000, baud: 921_600 });
        assert_eq!(r.obstacles.len(), 2);
        assert_eq!(r.schedule.slots().len(), 4);
        assert_eq!(r.sample_period, Duration::from_micros(4 * 4000 + 1000));
    }

    #[test]
    fn bad_values_are_refused_naming_the_key() {
        let cases = [
            ("node = 1", "node = 16", "can.node"),
            ("endpoint = \"slcan:/dev/flowgate-can?bitrate=1000000\"", "endpoint = \"can0\"", "can.endpoint"),
            ("wheel_radius = 0.025", "wheel_radius = -0.025", "drive.wheel_radius"),
            ("robot_rear = 2", "robot_rear = 1", "leds.robot_rear"),
            ("factor = 1.1", "factor = 0.9", "planner.margin.factor"),
            ("uncertainty_sigmas = 1.0", "uncertainty_sigmas = -1", "planner.uncertainty_sigmas"),
            ("uncertainty_sigmas = 1.0", "uncertainty_sigmas = nan", "planner.uncertainty_sigmas"),
            ("clearance = 0.006", "clearance = 0.5", "planner.clearance"),
            ("clearance = 0.006", "clearance = -0.001", "planner.clearance"),
            ("goal_wait = 10.0", "goal_wait = -1.0", "planner.goal_wait"),
            ("goal_wait = 10.0", "goal_wait = inf", "planner.goal_wait"),
            ("anticipation = 3.0", "anticipation = -1", "planner.anticipation"),
            ("anticipation = 3.0", "anticipation = nan", "planner.anticipation"),
            ("lane_residual = 1e-4", "lane_residual = 1e-3", "planner.lane_residual"),
            ("lane_residual = 1e-4", "lane_residual = nan", "planner.lane_residual"),
            ("rule = \"factor\", factor = 1.1", "rule = \"delay\", extra_speed = nan", "planner.margin.extra_speed"),
            ("rule = \"factor\", factor = 1.1", "rule = \"delay\", extra_speed = -1", "planner.margin.extra_speed"),
            ("k1 = 0.0", "k1 = nan", "calibration.k1"),
            ("counts = 4096", "counts = 0", "calibration.counts"),
            ("queue = 8192", "queue = 9223372036854775807", "telemetry.queue"),
            ("pose_timeout_ms = 150", "pose_timeout_ms = 4000000000", "safety.pose_timeout_ms"),
            ("command_timeout_ms = 200", "command_timeout_ms = 10", "drive.command_timeout_ms"),
            // The gateway's watchdogs fire a cycle (17 ms) before the board's 200 ms timeout.
            ("pose_timeout_ms = 150", "pose_timeout_ms = 184", "safety.pose_timeout_ms"),
            ("sample_timeout_ms = 100", "sample_timeout_ms = 184", "safety.sample_timeout_ms"),
            ("command_timeout_ms = 200", "command_timeout_ms = 166", "safety.pose_timeout_ms"),
            ("slot_us = 4000", "slot_us = 70000", "schedule.slot_us"),
            ("pose_tolerance_m = 0.02", "pose_tolerance_m = nan", "safety.pose_tolerance_m"),
            ("stall_window_ms = 3000 ", "stall_window_ms = 50 ", "safety.stall_window_ms"),
            ("stall_progress_m = 0.01 ", "stall_progress_m = 0 ", "safety.stall_progress_m"),
            // The low-latency window, twice over, must fit in T = 17 ms or the loop never sleeps.
            ("spin_us = 0 ", "spin_us = 8500 ", "realtime.spin_us"),
            ("warm_up = false ", "warm_up = true ", "realtime.warm_up"),
            ("fifo_priority = 0 ", "fifo_priority = 100 ", "realtime.fifo_priority"),
            ("max_speed = 0.15 ", "max_speed = 0.26 ", "robot.max_speed"),
            ("microsteps = 8", "microsteps = 4000000000", "drive.microsteps"),
            ("cpus = [] ", "cpus = [1, 1] ", "realtime.cpus[1]"),
            ("cpus = [] ", "cpus = [5000] ", "realtime.cpus[0]"),
        ];
        for (from, to, key) in cases {
            assert!(EXAMPLE.contains(from), "example lacks {from}");
            let err = rig(&EXAMPLE.replace(from, to)).unwrap_err().to_string();
            assert!(err.contains(&format!("`{key}`")), "{to}: {err}");
        }
        assert!(rig(&EXAMPLE.replace("pose_timeout_ms = 150", "pose_timeout_ms = 183")).is_ok(), "183 + 17 = 200");
        assert_eq!(rig(EXAMPLE).unwrap().spin, None, "off by default");
        let spin = rig(&EXAMPLE.replace("spin_us = 0 ", "spin_us = 8499 ")).unwrap().spin;
        assert_eq!(spin, Some(Duration::from_micros(8499)));
        assert!(rig(EXAMPLE).unwrap().realtime.is_empty(), "no real-time settings by default");
        let rt =
            rig(&EXAMPLE.replace("fifo_priority = 0 ", "fifo_priority = 60 ").replace("cpus = [] ", "cpus = [3] "))
                .unwrap()
                .realtime;
        assert_eq!((rt.cpus, rt.fifo_priority, rt.lock_memory), (vec![3], Some(60), false));
        let err = rig(&EXAMPLE.replace("[safety]", "[safety]\nbogus = 1")).unwrap_err();
        assert!(err.to_string().contains("unknown field `bogus`"), "{err}");
    }

    /// A frame length that does not divide by the LED count still gives the exact period.
    #[test]
    fn frame_us_keeps_the_period_exact() {
        let text = EXAMPLE.replace("slot_us = 4000 ", "frame_us = 20000 ");
        let r = rig(&text).unwrap();
        assert_eq!(r.sample_period, Duration::from_millis(20));
        let slots: Vec<u16> = r.schedule.slots().iter().map(|s| s.slot_us).collect();
        assert_eq!(slots, [4750, 4750, 4750, 4750]);
        let odd = EXAMPLE.replace("slot_us = 4000 ", "frame_us = 20003 ");
        let slots: Vec<u16> = rig(&odd).unwrap().schedule.slots().iter().map(|s| s.slot_us).collect();
        assert_eq!(slots, [4751, 4751, 4751, 4750]);
    }

    /// What `to_toml` writes reads back as the same rig.
    #[test]
    fn round_trips_through_toml() {
        let c = GatewayConfig::from_toml(EXAMPLE, "rig.toml").unwrap();
        let again = GatewayConfig::from_toml(&c.to_toml(), "again").unwrap();
        assert_eq!(again.rig("again").unwrap().control, c.rig("rig.toml").unwrap().control);
    }
}
