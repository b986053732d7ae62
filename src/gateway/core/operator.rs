//! What an operator may ask of the gateway, and what it answers: the vocabulary of the
//! control socket (`flowgate ctl`). One JSON object per line each way:
//!
//! ```text
//! {"cmd":"status"}   {"cmd":"arm"}   {"cmd":"start"}   {"cmd":"stop"}   {"cmd":"estop"}
//! {"cmd":"reset"}    {"cmd":"cancel"}    {"cmd":"stats"}    {"cmd":"stats","reset":true}
//! {"cmd":"goal","goals":[{"position":[0.6,0.0],"tolerance":0.02}, ...]}   (one goal, or a queue)
//! {"cmd":"drive","v":0.1,"w":0.0}    {"cmd":"wheels","left":0.1,"right":0.12}   (planner.method = "socket")
//! ```
//!
//! Answers are `{"ok":true,"status":{...}}` or `{"ok":false,"error":"not armed",...}`. The
//! rules live in the core ([`Core::handle`](super::Core::handle)); this module only names things.

use serde::{Deserialize, Serialize};

pub use super::safety::StateName;
use super::safety::{State, StopReason};

pub use crate::config::Goal;

/// Longest goal queue accepted.
pub const MAX_GOALS: usize = 64;

/// One operator request.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(tag = "cmd", rename_all = "snake_case", deny_unknown_fields)]
pub enum Request {
    /// The state, the last stop's reason, goals, pose, obstacles, counters.
    Status,
    /// Enable the board (Idle or Stopped -> Armed). Nothing moves yet.
    Arm,
    /// Drive to the goal (Armed -> Running once the pose and the board are ready).
    Start,
    /// Orderly stop: ramp down, disable.
    Stop,
    /// Emergency stop, at once, whatever the state. Always accepted.
    #[serde(rename = "estop")]
    EStop,
    /// Leave Fault for Idle, only when the fault's cause is gone.
    Reset,
    /// Set the goal, or a queue of goals driven in order (replaces any queue).
    Goal { goals: Vec<Goal> },
    /// Drop the goals; a running robot stops in order.
    Cancel,
    /// The status with the cycle latency and each stage's statistics since the start (or
    /// the last reset); with `reset`, a new window starts after the answer. Changes nothing
    /// else: the run's report still covers the whole run.
    Stats {
        #[serde(default)]
        reset: bool,
    },
    /// Drive on this command, with `planner.method = "socket"`: the robot's forward speed
    /// `v`, m/s, and turn rate `w`, rad/s. Held until the next; the supervisor checks it
    /// every cycle. It never arms or starts the robot.
    Drive {
        #[serde(deserialize_with = "number_or_nan")]
        v: f64,
        #[serde(deserialize_with = "number_or_nan")]
        w: f64,
    },
    /// The same as the wheels' rim speeds, m/s.
    Wheels {
        #[serde(deserialize_with = "number_or_nan")]
        left: f64,
        #[serde(deserialize_with = "number_or_nan")]
        right: f64,
    },
}

/// `text` with Python's `NaN`, `Infinity` and `-Infinity` (which JSON has no words for) as
/// `null`, when it has any: for reading a command that carries one as not finite.
pub fn non_finite_as_null(text: &str) -> Option<String> {
    (text.contains("NaN") || text.contains("Infinity"))
        .then(|| text.replace("-Infinity", "null").replace("Infinity", "null").replace("NaN", "null"))
}

/// A number, or `null` for one JSON cannot carry (a NaN or an infinity: the control socket
/// reads Python's `NaN` and `Infinity` as `null`), which is then NaN and stops the robot.
pub fn number_or_nan<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

impl Request {
    /// Asks only for information: changes nothing, goes unlogged.
    pub fn is_query(&self) -> bool {
        matches!(self, Request::Status | Request::Stats { .. })
    }

    /// A command from a planner outside flowgate: answered without the status, unlogged (one
    /// a cycle).
    pub fn is_command(&self) -> bool {
        matches!(self, Request::Drive { .. } | Request::Wheels { .. })
    }

    /// The outside command it carries.
    pub fn command(&self) -> Option<crate::control::OutsideCommand> {
        use crate::control::OutsideCommand;
        match *self {
            Request::Drive { v, w } => Some(OutsideCommand::Twist { v, w }),
            Request::Wheels { left, right } => Some(OutsideCommand::Wheels { left, right }),
            _ => None,
        }
    }

    /// `stop` and `estop`: obeyed whenever they arrive, however late, and never queued behind
    /// other requests.
    pub fn always_obeyed(&self) -> bool {
        matches!(self, Request::Stop | Request::EStop)
    }
}

/// Why a request was refused: exactly, so the operator knows what to do.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Refusal {
    #[error("not armed (state {0}): arm first")]
    NotArmed(State),
    #[error("already {0}")]
    Already(State),
    #[error("{0}: reset first")]
    Faulted(State),
    #[error("not in fault (state {0})")]
    NotFaulted(State),
    #[error("fault: {0}, cause still present")]
    CauseStillPresent(StopReason),
    #[error("drive {node} still reports its wheel turning: reset once it stands")]
    StillMoving { node: u8 },
    #[error("obstacle LED {led} is required (leds.obstacles[{index}].required) and has not been seen")]
    RequiredObstacleUnseen { led: u8, index: usize },
    #[error("no goal: set one with `goal X Y`")]
    NoGoal,
    #[error("no goals given")]
    EmptyQueue,
    #[error("{0} goals: at most {MAX_GOALS}")]
    TooManyGoals(usize),
    #[error("goal {index} ({x}, {y}): {why}")]
    BadGoal { index: usize, x: f64, y: f64, why: String },
    #[error("planner.method is \"field\": the field drives (set planner.method = \"socket\" to drive from outside)")]
    FieldDrives,
    #[error("planner.method is \"{0}\": the baseline drives (set planner.method = \"socket\" to drive from outside)")]
    BaselineDrives(&'static str),
    #[error("command not finite (NaN or infinite): the robot stops")]
    CommandNotFinite,
    #[error("{name} follows its script: it takes no goals or commands")]
    Scripted { name: String },
    #[error("{name} stands {distance:.3} m from its script's start ({x:.3}, {y:.3}), beyond its script_tolerance ({tolerance} m): bring it there first")]
    AwayFromScript { name: String, distance: f64, x: f64, y: f64, tolerance: f64 },
    #[error("no vehicle {index}: the rig drives {count} (the robot and its [[vehicles]])")]
    NoVehicle { index: usize, count: usize },
}

/// An obstacle as the gateway estimates it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ObstacleStatus {
    /// The obstacle's LED.
    pub led: u8,
    /// Unseen inside the view past the pose timeout: `position` is where it was last
    /// seen, and `planning_radius` takes in the region it may have reached since.
    pub occluded: bool,
    pub position: [f64; 2],
    pub velocity: [f64; 2],
    /// The obstacle's radius plus the robot's, grown by the margin rule now, m.
    pub planning_radius: f64,
}

/// The answer to `status`, as the control socket carries it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Status {
    pub state: StateReport,
    /// Why the gateway last stopped or faulted, in words.
    pub last_stop: Option<String>,
    /// The goal being driven to, then the rest of the queue.
    pub goals: Vec<Goal>,
    /// x, y (m), heading (rad), when the gateway has a pose.
    pub pose: Option<[f64; 3]>,
    /// The tracked obstacles (seen, or occluded inside the view).
    pub obstacles: Vec<ObstacleStatus>,
    /// The obstacle LEDs not tracked: not seen yet, or seen leaving the view.
    pub absent: Vec<u8>,
    pub cycles: u64,
    /// Cycle latency so far, serial read to CAN write done (filled in by the rig's shell,
    /// which measures it; none in virtual time).
    pub latency_us: Option<super::timing::Distribution>,
    /// Each stage's statistics over the same cycles (`stats` only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stages: Option<Vec<super::timing::StageSummary>>,
    /// The rig's other vehicles (`[[vehicles]]`), in order; the fields above are the robot's.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub vehicles: Vec<VehicleStatus>,
}

/// One of the rig's other vehicles, as the control socket reports it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VehicleStatus {
    pub name: String,
    pub state: StateReport,
    pub last_stop: Option<String>,
    pub goals: Vec<Goal>,
    /// x, y (m), heading (rad), when the gateway has its pose.
    pub pose: Option<[f64; 3]>,
    /// A scripted vehicle's distance from its script.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub script: Option<super::ScriptStatus>,
}

/// One reply line of the control socket: `{"ok":true,"status":{...}}`, or
/// `{"ok":false,"error":"not armed (state idle): arm first"}` (with the status when the
/// gateway had one to give).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Reply {
    pub ok: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub status: Option<Status>,
}

impl Reply {
    pub fn error(why: impl Into<String>) -> Self {
        Self { ok: false, error: Some(why.into()), status: None }
    }
}

/// A state as the control socket reports it: its name, and its reason in words. On the
/// wire it is the state's text, `"running"` or `"fault: robot pose lost"`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StateReport {
    pub name: StateName,
    pub reason: Option<String>,
}

impl StateReport {
    /// Stopped or faulted: nothing more will happen without an operator.
    pub fn is_terminal(&self) -> bool {
        matches!(self.name, StateName::Stopped | StateName::Fault)
    }
}

impl From<State> for StateReport {
    fn from(state: State) -> Self {
        Self { name: state.kind(), reason: state.reason().map(|r| r.to_string()) }
    }
}

impl std::fmt::Display for StateReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.reason {
            Some(r) => write!(f, "{}: {r}", self.name.as_str()),
            None => f.write_str(self.name.as_str()),
        }
    }
}

impl Serialize for StateReport {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for StateReport {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let text = String::deserialize(d)?;
        let (name, reason) = match text.split_once(": ") {
            Some((name, reason)) => (name, Some(reason.to_owned())),
            None => (text.as_str(), None),
        };
        Ok(Self { name: name.parse().map_err(serde::de::Error::custom)?, reason })
    }
}
