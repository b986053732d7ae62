//! What the core noticed that an operator must be able to read after the run: its warnings
//! and errors, and the changes in what it sees. The core only returns them
//! ([`Output::Notice`](super::Output::Notice)); the shell logs each at its [`Level`] and keeps
//! it in the durable `events.jsonl` (and a recording's `/log`), with its time and fields.

use flowgate_protocol::psd::FaultCode;
use serde_json::{json, Value};

use super::operator::Refusal;
use super::safety::State;
use crate::planner::PlannerError;
use crate::track::Implausible;

/// How much a notice matters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    Info,
    Warning,
    Error,
}

impl Level {
    pub fn name(self) -> &'static str {
        match self {
            Self::Info => "info",
            Self::Warning => "warning",
            Self::Error => "error",
        }
    }
}

/// One notice, with what it is about.
#[derive(Debug, Clone, PartialEq)]
pub enum Notice {
    /// The controller streams (its firmware, when it said).
    Streaming { firmware: Option<[u8; 3]> },
    /// `--arm` could not arm when the controller first streamed.
    ArmAtStartRefused(Refusal),
    /// The controller's packet sequence moved beyond the window and is followed from here.
    SequenceRebased { seq: u16 },
    /// The controller's frame counter moved and is followed from here.
    FrameCounterRebased { frame: u32 },
    /// A time sync saw the controller's clock step beyond drift; a second sync checks it.
    ClockStepRefused { step_us: i64 },
    /// A second sync confirmed the step: the clock jumped.
    ClockJumped { step_us: i64 },
    /// The controller rebooted; it is configured again.
    ControllerReset,
    /// The controller streamed no sample for this long, unannounced (a reboot whose
    /// announcement was lost, say): it is configured again.
    ControllerSilent { silent_ms: u64 },
    /// The controller reported a fault.
    ControllerFault { code: FaultCode, detail: u32 },
    /// A robot pose was discarded as implausible (the first of a run of them).
    PoseDiscarded { why: Implausible },
    /// An obstacle came into view.
    ObstacleEntered { led: u8, at: [f64; 2] },
    /// An obstacle's track was dropped as it left the view.
    ObstacleLeft { led: u8 },
    /// The goal lies in an obstacle's planning circle: the robot holds still.
    GoalOccupied { led: u8 },
    /// ... for longer than `planner.goal_wait`: an orderly stop.
    GoalBlocked { led: u8, wait_s: f64 },
    /// A goal reached; on to the next in the queue.
    NextGoal { position: [f64; 2] },
    /// The planner refused its input (the obstacle's LED, when one is to blame).
    PlannerRefused { error: PlannerError, led: Option<u8> },
    /// An emergency stop: the boards told to stop at once.
    EmergencyStop { state: State },
    /// One of a vehicle's other than the robot's (which are named by the notice alone).
    OfVehicle { vehicle: String, notice: Box<Notice> },
}

impl Notice {
    pub fn level(&self) -> Level {
        match self {
            Self::OfVehicle { notice, .. } => notice.level(),
            Self::Streaming { .. }
            | Self::ObstacleEntered { .. }
            | Self::ObstacleLeft { .. }
            | Self::NextGoal { .. } => Level::Info,
            Self::SequenceRebased { .. }
            | Self::FrameCounterRebased { .. }
            | Self::ClockStepRefused { .. }
            | Self::ControllerReset
            | Self::ControllerSilent { .. }
            | Self::PoseDiscarded { .. }
            | Self::GoalOccupied { .. }
            | Self::GoalBlocked { .. }
            | Self::EmergencyStop { .. } => Level::Warning,
            Self::ArmAtStartRefused(_)
            | Self::ClockJumped { .. }
            | Self::ControllerFault { .. }
            | Self::PlannerRefused { .. } => Level::Error,
        }
    }

    /// Its name in `events.jsonl` (`snake_case`).
    pub fn kind(&self) -> &'static str {
        match self {
            Self::OfVehicle { notice, .. } => notice.kind(),
            Self::Streaming { .. } => "streaming",
            Self::ArmAtStartRefused(_) => "arm_at_start_refused",
            Self::SequenceRebased { .. } => "sequence_rebased",
            Self::FrameCounterRebased { .. } => "frame_counter_rebased",
            Self::ClockStepRefused { .. } => "clock_step_refused",
            Self::ClockJumped { .. } => "clock_jumped",
            Self::ControllerReset => "controller_reset",
            Self::ControllerSilent { .. } => "controller_silent",
            Self::ControllerFault { .. } => "controller_fault",
            Self::PoseDiscarded { .. } => "pose_discarded",
            Self::ObstacleEntered { .. } => "obstacle_entered",
            Self::ObstacleLeft { .. } => "obstacle_left",
            Self::GoalOccupied { .. } => "goal_occupied",
            Self::GoalBlocked { .. } => "goal_blocked",
            Self::NextGoal { .. } => "next_goal",
            Self::PlannerRefused { .. } => "planner_refused",
            Self::EmergencyStop { .. } => "emergency_stop",
        }
    }

    /// Its fields, for the durable log (the text says them too).
    pub fn fields(&self) -> Value {
        match self {
            Self::Streaming { firmware } => json!({ "firmware": firmware }),
            Self::ArmAtStartRefused(r) => json!({ "refusal": r.to_string() }),
            Self::SequenceRebased { seq } => json!({ "seq": seq }),
            Self::FrameCounterRebased { frame } => json!({ "frame": frame }),
            Self::ClockStepRefused { step_us } | Self::ClockJumped { step_us } => json!({ "step_us": step_us }),
            Self::ControllerReset => json!({}),
            Self::ControllerSilent { silent_ms } => json!({ "silent_ms": silent_ms }),
            Self::ControllerFault { code, detail } => json!({ "code": format!("{code:?}"), "detail": detail }),
            Self::PoseDiscarded { why } => json!({ "why": why.to_string() }),
            Self::ObstacleEntered { led, at } => json!({ "led": led, "at": at }),
            Self::ObstacleLeft { led } | Self::GoalOccupied { led } => json!({ "led": led }),
            Self::GoalBlocked { led, wait_s } => json!({ "led": led, "wait_s": wait_s }),
            Self::NextGoal { position } => json!({ "position": position }),
            Self::PlannerRefused { error, led } => json!({ "error": error.to_string(), "led": led }),
            Self::EmergencyStop { state } => json!({ "state": state.to_string() }),
            Self::OfVehicle { vehicle, notice } => {
                let mut fields = notice.fields();
                if let Value::Object(map) = &mut fields {
                    map.insert("vehicle".into(), json!(vehicle));
                }
                fields
            }
        }
    }
}

impl std::fmt::Display for Notice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Streaming { firmware: Some([a, b, c]) } => {
                write!(f, "PSD controller streaming (firmware {a}.{b}.{c})")
            }
            Self::Streaming { firmware: None } => f.write_str("PSD controller streaming"),
            Self::ArmAtStartRefused(r) => write!(f, "arming at start: {r}"),
            Self::SequenceRebased { seq } => {
                write!(f, "PSD controller's sequence numbers moved: following them from {seq}")
            }
            Self::FrameCounterRebased { frame } => {
                write!(f, "PSD controller's frame counter moved: following it from {frame}")
            }
            Self::ClockStepRefused { step_us } => {
                write!(f, "time sync refused: the controller's clock moved {step_us} µs, beyond drift; checking again")
            }
            Self::ClockJumped { step_us } => {
                write!(f, "PSD controller's clock jumped by {step_us} µs (confirmed by a second sync)")
            }
            Self::ControllerReset => f.write_str("PSD controller reset; reconfiguring"),
            Self::ControllerSilent { silent_ms } => {
                write!(f, "PSD controller streamed nothing for {silent_ms} ms; reconfiguring")
            }
            Self::ControllerFault { code, detail } => write!(f, "PSD controller fault {code:?} (detail {detail})"),
            Self::PoseDiscarded { why } => write!(f, "robot pose discarded: {why}"),
            Self::ObstacleEntered { led, at: [x, y] } => {
                write!(f, "obstacle LED {led} came into view at ({x:.3}, {y:.3}) m")
            }
            Self::ObstacleLeft { led } => write!(f, "obstacle LED {led} left the view: track dropped"),
            Self::GoalOccupied { led } => {
                write!(f, "goal inside obstacle LED {led}'s planning circle: holding still until it passes")
            }
            Self::GoalBlocked { led, wait_s } => {
                write!(f, "goal inside obstacle LED {led}'s planning circle for {wait_s} s: stopping")
            }
            Self::NextGoal { position: [x, y] } => write!(f, "goal reached; next goal ({x}, {y})"),
            Self::PlannerRefused { error, led: Some(led) } => write!(f, "planner: {error} (obstacle LED {led})"),
            Self::PlannerRefused { error, led: None } => write!(f, "planner: {error}"),
            Self::EmergencyStop { state } => write!(f, "emergency stop: {state}"),
            Self::OfVehicle { vehicle, notice } => write!(f, "vehicle {vehicle}: {notice}"),
        }
    }
}
