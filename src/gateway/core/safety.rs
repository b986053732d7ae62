//! The gateway's safety state machine.
//!
//! ```text
//!  Idle --arm--> Armed --start (pose, board, goal ready)--> Running --goal/stall/stop--> Stopping --> Stopped
//!  Stopped --arm--> Armed;  any state --fault or e-stop--> Fault (axes stopped at once)
//!  Fault --reset (cause gone)--> Idle
//! ```
//!
//! The gateway starts in `Idle` and moves nothing until an operator arms it and starts it
//! (`flowgate ctl arm`, `start`; `flowgate run --arm` does both at start, for the demo and
//! tests only). Motion is commanded only in `Running`. A fault never clears itself: the
//! operator resets it, which is refused while its cause persists, and then arms again.

use flowgate_protocol::canopen::DriveState;
use flowgate_protocol::motor::GatewayState;

/// How the robot moved when an obstacle reached it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RobotMotion {
    /// Slower than [`Self::STANDING_SPEED`].
    Standing,
    /// Closing on the obstacle at [`Self::STANDING_SPEED`] or more.
    Towards,
    /// Driving otherwise: turning, or away from the obstacle.
    Away,
}

impl RobotMotion {
    /// Below this the robot counts as standing, m/s: the speed towards an obstacle above
    /// which the simulator's world judges a contact active.
    pub const STANDING_SPEED: f64 = 0.01;
}

/// The robot as a stop names it: "the standing robot", "the robot driving towards it".
impl std::fmt::Display for RobotMotion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Standing => "standing robot",
            Self::Towards => "robot driving towards it",
            Self::Away => "robot driving, not towards it",
        })
    }
}

/// Why the gateway stopped or faulted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum StopReason {
    GoalReached,
    Stalled,
    Operator,
    Shutdown,
    /// The goal lay inside an obstacle's planning circle for longer than the robot waits
    /// for it to pass (`planner.goal_wait`; orderly stop).
    GoalBlocked,
    /// An operator's emergency stop (a fault: latched until reset).
    OperatorEStop,
    PoseLost,
    /// The robot's samples kept failing the plausibility checks until the pose timed out.
    PoseImplausible,
    /// The robot's poses kept arriving, but older than the pose timeout (sensing delay).
    PoseDelayed,
    SamplesStopped,
    /// Garbage on the serial line (bad frames, bytes dropped between frames): bad frames
    /// beyond budget, or garbage where the samples or the robot's poses stopped. The counts
    /// since the last sample (the last pose, for `Garbled::NoPose`).
    SerialGarbled {
        frames: u32,
        bytes: u32,
        found: Garbled,
    },
    /// Duplicated, replayed, reordered or far-jumped PSD packets beyond budget; or, with
    /// `handshake`, packets discarded for their sequence numbers while a handshake waited
    /// for its answer and no sample came (its answer among them, maybe).
    PsdSequence {
        handshake: bool,
    },
    /// Samples of an LED the schedule does not have in that slot beyond budget (the last
    /// one's LED named).
    UnscheduledLed {
        led: u8,
    },
    /// Frame counters beyond the window (jumps, not a run that confirms a new count) beyond
    /// budget.
    FrameCounterJump,
    /// The controller's clock stepped beyond drift, confirmed by a second sync, or the
    /// robot's samples came stamped in the future.
    ClockJumped,
    /// The PSD controller reported a fault (an LED driver, ambient saturation, internal).
    ControllerFault,
    /// The PSD controller rebooted while the gateway was driving on it.
    ControllerReset,
    SerialLost,
    /// No time sync with a round trip within bound for `SYNC_STALE`: stamps cannot be trusted.
    ClockUnsynced,
    /// The motor board counted more lost or foreign commands than the budget allows.
    BoardSequence {
        node: u8,
    },
    /// The SLCAN adapter refused more transmits than the budget allows.
    CanTransmitRefused,
    /// The CAN link itself failed: a write error or timeout, the adapter gone.
    CanLinkLost,
    /// The SocketCAN interface went down or away (not the bus: the host's interface).
    CanInterfaceDown,
    /// The motor board's heartbeat stopped for longer than `safety.heartbeat_timeout_ms`.
    HeartbeatLost {
        node: u8,
    },
    /// The motor board announced a boot while the gateway drove it.
    BoardReboot {
        node: u8,
    },
    /// Another device sent velocity commands to our board.
    SecondMaster {
        node: u8,
    },
    /// A tracked obstacle stayed unseen inside the view for longer than
    /// `safety.occlusion_timeout_ms` while running; `at_edge`: last seen at the view's edge,
    /// where it may have gone out (which the camera cannot tell from hidden there).
    ObstacleOccluded {
        led: u8,
        at_edge: bool,
    },
    /// A moving obstacle's planning circle took in the robot: the obstacle came to it (the
    /// supervisor keeps the robot from driving into one), and the field is not defined
    /// there. Which obstacle, and how the robot moved relative to it.
    ObstacleReachedRobot {
        led: u8,
        robot: RobotMotion,
    },
    /// The gateway's own CAN controller went bus-off (an error frame or the adapter's flags).
    BusOff,
    /// The motor board reports its CAN controller error passive or bus-off.
    BoardBusOff {
        node: u8,
    },
    /// The motor board latched a fault (its driver, its command timeout, an e-stop).
    BoardFault {
        node: u8,
    },
    /// The motor board's own e-stop input (a stop button wired to it) latched its e-stop:
    /// the reset is refused while the input stays open.
    BoardEStop {
        node: u8,
    },
    /// Armed, the board stayed Disabled through every enable sent.
    BoardNotEnabled {
        node: u8,
    },
    PlannerInvalid,
    /// Driven by a planner outside flowgate (`planner.method`), its latest command was older
    /// than `planner.command_max_age_ms` when a cycle would drive on it (orderly stop).
    CommandStale,
    /// A planner outside flowgate sent a command that is not a number (NaN) or infinite.
    CommandNotFinite,
    /// A scripted vehicle came to rest at its script's last point (orderly stop).
    ScriptEnded,
    /// A scripted vehicle was further from its script than its `script_tolerance`, mm:
    /// held by its supervisor, or pushed (orderly stop).
    OffScript {
        error_mm: u16,
        tolerance_mm: u16,
    },
    /// A CiA 402 drive's heartbeat stopped for longer than `safety.heartbeat_timeout_ms`.
    DriveHeartbeatLost {
        node: u8,
    },
    /// A CiA 402 drive sent its boot-up message while the gateway drove it.
    DriveRebooted {
        node: u8,
    },
    /// Another device sent an RPDO or an SDO request to one of our CiA 402 drives.
    DriveSecondMaster {
        node: u8,
    },
    /// A CiA 402 drive did not answer an SDO within `cia402.sdo_timeout_ms`.
    DriveSdoTimeout {
        node: u8,
        index: u16,
        sub: u8,
    },
    /// A CiA 402 drive refused an SDO (its abort code).
    DriveSdoAbort {
        node: u8,
        index: u16,
        sub: u8,
        code: u32,
    },
    /// A CiA 402 drive did not reach operation enabled within `cia402.enable_timeout_ms` of
    /// the arm (the state it stayed in).
    DriveNotEnabled {
        node: u8,
        state: DriveState,
    },
    /// A CiA 402 drive sent an emergency (its error code).
    DriveEmergency {
        node: u8,
        code: u16,
    },
    /// A CiA 402 drive left operation enabled by itself (its statusword's state).
    DriveLeftOperation {
        node: u8,
        state: DriveState,
    },
}

impl StopReason {
    /// One of each reason (the LED or node 0): every label `/metrics` carries from the start.
    pub const ALL: [StopReason; 46] = [
        Self::GoalReached,
        Self::Stalled,
        Self::Operator,
        Self::Shutdown,
        Self::GoalBlocked,
        Self::OperatorEStop,
        Self::PoseLost,
        Self::PoseImplausible,
        Self::PoseDelayed,
        Self::SamplesStopped,
        Self::SerialGarbled { frames: 0, bytes: 0, found: Garbled::NoSample },
        Self::PsdSequence { handshake: false },
        Self::UnscheduledLed { led: 0 },
        Self::FrameCounterJump,
        Self::ClockJumped,
        Self::ControllerFault,
        Self::ControllerReset,
        Self::SerialLost,
        Self::ClockUnsynced,
        Self::BoardSequence { node: 0 },
        Self::CanTransmitRefused,
        Self::CanLinkLost,
        Self::CanInterfaceDown,
        Self::HeartbeatLost { node: 0 },
        Self::BoardReboot { node: 0 },
        Self::SecondMaster { node: 0 },
        Self::ObstacleOccluded { led: 0, at_edge: false },
        Self::ObstacleReachedRobot { led: 0, robot: RobotMotion::Standing },
        Self::BusOff,
        Self::BoardBusOff { node: 0 },
        Self::BoardFault { node: 0 },
        Self::BoardEStop { node: 0 },
        Self::BoardNotEnabled { node: 0 },
        Self::PlannerInvalid,
        Self::CommandStale,
        Self::CommandNotFinite,
        Self::ScriptEnded,
        Self::OffScript { error_mm: 0, tolerance_mm: 0 },
        Self::DriveHeartbeatLost { node: 0 },
        Self::DriveRebooted { node: 0 },
        Self::DriveSecondMaster { node: 0 },
        Self::DriveSdoTimeout { node: 0, index: 0, sub: 0 },
        Self::DriveSdoAbort { node: 0, index: 0, sub: 0, code: 0 },
        Self::DriveNotEnabled { node: 0, state: DriveState::NotReadyToSwitchOn },
        Self::DriveEmergency { node: 0, code: 0 },
        Self::DriveLeftOperation { node: 0, state: DriveState::NotReadyToSwitchOn },
    ];

    /// Whether this is a fault (stop at once, latch) rather than an orderly stop.
    /// The reason's name in `snake_case` (a metrics label): `PoseLost` is `pose_lost`.
    pub fn snake_name(self) -> String {
        let debug = format!("{self:?}");
        // The variant's name, without the data some carry (`ObstacleOccluded { led: 3 }`).
        let name = debug.split([' ', '{', '(']).next().unwrap_or_default();
        let mut out = String::with_capacity(name.len() + 4);
        for (i, c) in name.chars().enumerate() {
            if c.is_ascii_uppercase() && i > 0 {
                out.push('_');
            }
            out.push(c.to_ascii_lowercase());
        }
        out
    }

    /// Whether the stop may not have reached the motors: they went unheard, or the gateway's
    /// own link to the bus failed. They then run on their last command until their own
    /// timeout stops them.
    pub fn motors_unreachable(self) -> bool {
        matches!(
            self,
            Self::HeartbeatLost { .. }
                | Self::DriveHeartbeatLost { .. }
                | Self::BoardBusOff { .. }
                | Self::BusOff
                | Self::CanLinkLost
                | Self::CanInterfaceDown
                | Self::CanTransmitRefused
        )
    }

    pub fn is_fault(self) -> bool {
        !matches!(
            self,
            Self::GoalReached
                | Self::Stalled
                | Self::Operator
                | Self::Shutdown
                | Self::GoalBlocked
                | Self::CommandStale
                | Self::ScriptEnded
                | Self::OffScript { .. }
        )
    }
}

impl serde::Serialize for StopReason {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

/// A state serialises as `"running"`, or `"fault: robot pose lost"` with its reason.
impl serde::Serialize for State {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl std::fmt::Display for State {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.reason() {
            Some(r) => write!(f, "{}: {r}", self.name()),
            None => f.write_str(self.name()),
        }
    }
}

impl StopReason {
    /// The text of a reason that carries no data.
    fn fixed_text(&self) -> Option<&'static str> {
        Some(match self {
            Self::GoalReached => "goal reached",
            Self::GoalBlocked => "goal inside an obstacle's planning circle for longer than planner.goal_wait",
            Self::OperatorEStop => "operator emergency stop",
            Self::Stalled => "stalled (no progress)",
            Self::CommandStale => "the outside planner's command older than planner.command_max_age_ms",
            Self::CommandNotFinite => "the outside planner's command not finite (NaN or infinite)",
            Self::ScriptEnded => "script ended at its last point",
            Self::Operator => "operator stop",
            Self::Shutdown => "shutdown signal",
            Self::PoseLost => "robot pose lost",
            Self::PoseImplausible => "robot pose implausible (LED spacing, jump or turn)",
            Self::PoseDelayed => "robot pose delayed beyond the pose timeout",
            Self::SamplesStopped => "no samples from the PSD controller",
            Self::PsdSequence { handshake: false } => "PSD packets out of sequence beyond budget",
            Self::PsdSequence { handshake: true } => {
                "PSD packets discarded for their sequence numbers while the handshake waited for its answer"
            }
            Self::FrameCounterJump => "PSD frame counter jumped beyond its window, beyond budget",
            Self::ClockJumped => "PSD controller's clock jumped (beyond the 1000 ppm drift bound)",
            Self::ControllerFault => "the PSD controller reports a fault",
            Self::ControllerReset => "the PSD controller rebooted",
            Self::SerialLost => "serial device lost",
            Self::ClockUnsynced => "controller clock unsynchronised (time sync round trips too long)",
            Self::CanTransmitRefused => "CAN adapter refuses to transmit beyond budget",
            Self::CanLinkLost => "CAN link lost",
            Self::CanInterfaceDown => "CAN interface went down",
            Self::BusOff => "CAN bus-off",
            Self::PlannerInvalid => "planner refused its input",
            _ => return None,
        })
    }
}

/// How garbage on the serial line stopped the robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Garbled {
    /// More bad frames than `safety.bad_frames_per_s` allows.
    BeyondBudget,
    /// No sample came through it for the sample timeout.
    NoSample,
    /// No robot pose came through it for the pose timeout (the frames that carried the
    /// robot's samples were lost in it; others may have come).
    NoPose,
}

impl Garbled {
    /// A garbled-serial stop in words, with its counts.
    fn describe(self, f: &mut std::fmt::Formatter<'_>, frames: u32, bytes: u32) -> std::fmt::Result {
        let s = |n: u32| if n == 1 { "" } else { "s" };
        let (fs, bs) = (s(frames), s(bytes));
        let since = if self == Garbled::NoPose { "pose" } else { "sample" };
        let counts = format!("{frames} bad frame{fs}, {bytes} byte{bs} dropped since the last {since}");
        match self {
            Garbled::BeyondBudget => write!(f, "garbled serial frames beyond budget ({counts})"),
            Garbled::NoSample => write!(f, "garbled serial data and no sample through it ({counts})"),
            Garbled::NoPose => write!(f, "garbled serial data and no robot pose through it ({counts})"),
        }
    }
}

/// How an obstacle is said to be unseen: inside the view, or last seen at its edge.
const UNSEEN: [&str; 2] = ["unseen inside the view", "lost at the view's edge (gone out, or hidden there) and unseen"];

impl std::fmt::Display for StopReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(text) = self.fixed_text() {
            return f.write_str(text);
        }
        match self {
            Self::SerialGarbled { frames, bytes, found } => found.describe(f, *frames, *bytes),
            Self::UnscheduledLed { led } => {
                write!(f, "samples of LED {led}, not in the schedule's slot, beyond budget")
            }
            Self::HeartbeatLost { node } => write!(f, "motor board {node} heartbeat lost"),
            Self::BoardSequence { node } => {
                write!(f, "motor board {node} counts lost or foreign commands beyond budget")
            }
            Self::BoardReboot { node } => write!(f, "motor board {node} rebooted"),
            Self::SecondMaster { node } => write!(f, "another device commands motor board {node}"),
            Self::ObstacleOccluded { led, at_edge } => {
                write!(f, "obstacle LED {led} {} beyond safety.occlusion_timeout_ms", UNSEEN[usize::from(*at_edge)])
            }
            Self::ObstacleReachedRobot { led, robot } => write!(f, "obstacle LED {led} reached the {robot}"),
            Self::OffScript { error_mm, tolerance_mm } => {
                write!(f, "{error_mm} mm off its script (script_tolerance {tolerance_mm} mm)")
            }
            Self::BoardBusOff { node } => write!(f, "motor board {node} CAN bus-off"),
            Self::BoardFault { node } => write!(f, "motor board {node} fault"),
            Self::BoardEStop { node } => write!(f, "e-stop latched by motor board {node} (its e-stop input)"),
            Self::BoardNotEnabled { node } => write!(f, "motor board {node} did not enable"),
            Self::DriveHeartbeatLost { node } => write!(f, "drive {node} heartbeat lost"),
            Self::DriveRebooted { node } => write!(f, "drive {node} rebooted (boot-up message)"),
            Self::DriveSecondMaster { node } => write!(f, "another device commands drive {node}"),
            Self::DriveSdoTimeout { node, index, sub } => {
                write!(f, "drive {node} did not answer SDO 0x{index:04X}:{sub} within cia402.sdo_timeout_ms")
            }
            Self::DriveSdoAbort { node, index, sub, code } => {
                let why = flowgate_protocol::canopen::sdo_abort_text(*code);
                write!(f, "drive {node} refused SDO 0x{index:04X}:{sub}: abort 0x{code:08X} ({why})")
            }
            Self::DriveNotEnabled { node, state } => {
                write!(
                    f,
                    "drive {node} stayed in '{}' (statusword 0x6041), not operation enabled within cia402.enable_timeout_ms",
                    state.name()
                )
            }
            Self::DriveEmergency { node, code } => {
                let emcy = flowgate_protocol::canopen::Emcy { error_code: *code, error_register: 0, vendor: [0; 5] };
                write!(f, "drive {node} emergency 0x{code:04X} ({})", emcy.describe())
            }
            Self::DriveLeftOperation { node, state } => {
                write!(f, "drive {node} left operation enabled for '{}'", state.name())
            }
            _ => Ok(()),
        }
    }
}

/// The states' names, as a client matches on them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StateName {
    Idle,
    Armed,
    Running,
    Stopping,
    Stopped,
    Fault,
}

impl StateName {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Idle => "idle",
            Self::Armed => "armed",
            Self::Running => "running",
            Self::Stopping => "stopping",
            Self::Stopped => "stopped",
            Self::Fault => "fault",
        }
    }
}

impl std::str::FromStr for StateName {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        [Self::Idle, Self::Armed, Self::Running, Self::Stopping, Self::Stopped, Self::Fault]
            .into_iter()
            .find(|n| n.as_str() == s)
            .ok_or_else(|| format!("`{s}` is not a state (idle, armed, running, stopping, stopped, fault)"))
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum State {
    #[default]
    Idle,
    Armed,
    Running,
    Stopping(StopReason),
    Stopped(StopReason),
    Fault(StopReason),
}

impl State {
    /// Its name in logs, CSV and JSON.
    pub fn name(self) -> &'static str {
        self.kind().as_str()
    }

    /// Which state, without its reason.
    pub fn kind(self) -> StateName {
        match self {
            State::Idle => StateName::Idle,
            State::Armed => StateName::Armed,
            State::Running => StateName::Running,
            State::Stopping(_) => StateName::Stopping,
            State::Stopped(_) => StateName::Stopped,
            State::Fault(_) => StateName::Fault,
        }
    }

    /// Why it stopped, in the states that have a reason.
    pub fn reason(self) -> Option<StopReason> {
        match self {
            State::Stopping(r) | State::Stopped(r) | State::Fault(r) => Some(r),
            _ => None,
        }
    }

    /// Stopped or faulted: nothing more will happen without an operator.
    pub fn is_terminal(self) -> bool {
        matches!(self, State::Stopped(_) | State::Fault(_))
    }

    /// The state as the gateway heartbeat carries it.
    pub fn wire(self) -> GatewayState {
        match self {
            State::Idle => GatewayState::Idle,
            State::Armed => GatewayState::Armed,
            State::Running => GatewayState::Running,
            State::Stopping(_) => GatewayState::Stopping,
            State::Stopped(_) => GatewayState::Stopped,
            State::Fault(_) => GatewayState::Fault,
        }
    }
    pub fn may_move(self) -> bool {
        self == State::Running
    }

    /// The motors are enabled (or being stopped): the watchdogs are armed.
    pub fn is_active(self) -> bool {
        matches!(self, State::Armed | State::Running | State::Stopping(_))
    }
}

/// What the state machine asks the motor side to do on a transition.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    None,
    /// Reset faults and enable the board.
    EnableBoard,
    /// Ramp to zero and disable.
    OrderlyStop,
    /// Emergency stop, at once.
    EmergencyStop,
}

#[derive(Debug, Clone)]
pub struct Safety {
    state: State,
    /// Every transition with its time, for the report.
    pub history: Vec<(f64, State)>,
}

impl Default for Safety {
    fn default() -> Self {
        Self { state: State::Idle, history: vec![(0.0, State::Idle)] }
    }
}

impl Safety {
    pub fn state(&self) -> State {
        self.state
    }

    fn go(&mut self, t: f64, s: State) {
        if s != self.state {
            self.state = s;
            self.history.push((t, s));
        }
    }

    /// The operator arms (or re-arms after a stop or fault).
    pub fn arm(&mut self, t: f64) -> Action {
        match self.state {
            State::Idle | State::Stopped(_) => {
                self.go(t, State::Armed);
                Action::EnableBoard
            }
            _ => Action::None,
        }
    }

    /// Pose and board are ready: start moving (only from Armed).
    pub fn ready(&mut self, t: f64) {
        if self.state == State::Armed {
            self.go(t, State::Running);
        }
    }

    /// An orderly stop (goal, stall, operator, shutdown) or a fault.
    pub fn stop(&mut self, t: f64, reason: StopReason) -> Action {
        match (self.state, reason.is_fault()) {
            (State::Fault(_), _) => Action::None,
            (_, true) => {
                self.go(t, State::Fault(reason));
                Action::EmergencyStop
            }
            (State::Running | State::Armed, false) => {
                self.go(t, State::Stopping(reason));
                Action::OrderlyStop
            }
            (State::Idle, false) => {
                self.go(t, State::Stopped(reason));
                Action::None
            }
            _ => Action::None,
        }
    }

    /// Leave a fault for Idle (the caller has checked that its cause is gone).
    pub fn reset(&mut self, t: f64) -> bool {
        let faulted = matches!(self.state, State::Fault(_));
        if faulted {
            self.go(t, State::Idle);
        }
        faulted
    }

    /// The axes have come to rest after an orderly stop.
    pub fn at_rest(&mut self, t: f64) {
        if let State::Stopping(r) = self.state {
            self.go(t, State::Stopped(r));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `ALL` holds each reason once. The match is exhaustive: a new reason does not compile
    /// here until it is added, and so to `ALL`.
    #[test]
    fn all_holds_every_reason_once() {
        let names: std::collections::BTreeSet<String> = StopReason::ALL.iter().map(|r| r.snake_name()).collect();
        assert_eq!(names.len(), StopReason::ALL.len());
        for reason in StopReason::ALL {
            match reason {
                StopReason::GoalReached
                | StopReason::Stalled
                | StopReason::Operator
                | StopReason::Shutdown
                | StopReason::GoalBlocked
                | StopReason::OperatorEStop
                | StopReason::PoseLost
                | StopReason::PoseImplausible
                | StopReason::PoseDelayed
                | StopReason::SamplesStopped
                | StopReason::SerialGarbled { .. }
                | StopReason::PsdSequence { .. }
                | StopReason::UnscheduledLed { .. }
                | StopReason::FrameCounterJump
                | StopReason::ClockJumped
                | StopReason::ControllerFault
                | StopReason::ControllerReset
                | StopReason::SerialLost
                | StopReason::ClockUnsynced
                | StopReason::BoardSequence { .. }
                | StopReason::CanTransmitRefused
                | StopReason::CanLinkLost
                | StopReason::CanInterfaceDown
                | StopReason::HeartbeatLost { .. }
                | StopReason::BoardReboot { .. }
                | StopReason::SecondMaster { .. }
                | StopReason::ObstacleOccluded { .. }
                | StopReason::ObstacleReachedRobot { .. }
                | StopReason::BusOff
                | StopReason::BoardBusOff { .. }
                | StopReason::BoardFault { .. }
                | StopReason::BoardEStop { .. }
                | StopReason::BoardNotEnabled { .. }
                | StopReason::PlannerInvalid
                | StopReason::ScriptEnded
                | StopReason::OffScript { .. }
                | StopReason::CommandStale
                | StopReason::CommandNotFinite
                | StopReason::DriveHeartbeatLost { .. }
                | StopReason::DriveRebooted { .. }
                | StopReason::DriveSecondMaster { .. }
                | StopReason::DriveSdoTimeout { .. }
                | StopReason::DriveSdoAbort { .. }
                | StopReason::DriveNotEnabled { .. }
                | StopReason::DriveEmergency { .. }
                | StopReason::DriveLeftOperation { .. } => {}
            }
        }
    }

    #[test]
    fn runs_only_after_arming_and_readiness() {
        let mut s = Safety::default();
        s.ready(0.0);
        assert_eq!(s.state(), State::Idle, "not armed: no motion");
        assert_eq!(s.arm(0.1), Action::EnableBoard);
        assert!(!s.state().may_move());
        s.ready(0.2);
        assert!(s.state().may_move());
        assert_eq!(s.stop(1.0, StopReason::GoalReached), Action::OrderlyStop);
        assert_eq!(s.state(), State::Stopping(StopReason::GoalReached));
        s.at_rest(1.5);
        assert_eq!(s.state(), State::Stopped(StopReason::GoalReached));
    }

    #[test]
    fn faults_latch_until_rearmed() {
        let mut s = Safety::default();
        s.arm(0.0);
        s.ready(0.0);
        assert_eq!(s.stop(1.0, StopReason::HeartbeatLost { node: 1 }), Action::EmergencyStop);
        assert_eq!(s.state(), State::Fault(StopReason::HeartbeatLost { node: 1 }));
        // Nothing but an arm leaves Fault: not readiness, not another stop.
        s.ready(2.0);
        assert_eq!(s.stop(2.0, StopReason::GoalReached), Action::None);
        assert_eq!(s.state(), State::Fault(StopReason::HeartbeatLost { node: 1 }));
        assert_eq!(s.arm(2.5), Action::None, "arming does not clear a fault");
        assert!(s.reset(2.9));
        assert_eq!(s.arm(3.0), Action::EnableBoard);
        s.ready(3.1);
        assert_eq!(s.state(), State::Running);
        assert_eq!(s.history.len(), 7);
    }

    #[test]
    fn an_orderly_stop_while_stopping_does_not_restart_anything() {
        let mut s = Safety::default();
        s.arm(0.0);
        s.ready(0.0);
        s.stop(1.0, StopReason::Shutdown);
        assert_eq!(s.stop(1.1, StopReason::GoalReached), Action::None);
        assert_eq!(s.stop(1.2, StopReason::PoseLost), Action::EmergencyStop, "a fault still wins");
    }
}
