//! The gateway core: everything the gateway decides, with no I/O and no clock.
//!
//! The core is a state machine in the manner of quinn-proto's `Connection`. There is one way
//! in and two ways out:
//!
//! - [`Core::handle`]`(now, input)`: every [`Input`] (PSD bytes as read, CAN events as
//!   received, the links opening and failing, an operator's request, a shutdown, a tick)
//!   with the host time at which it happened. An operator's request gets its [`Answer`].
//! - [`Core::poll`], after every `handle`, until it returns `None`: the [`Output`]s to carry
//!   out, in order (packets for the PSD controller, CAN frames, each cycle's command with its
//!   timing record, state changes).
//! - [`Core::next_deadline`], after draining: when to hand the core [`Input::Tick`] if
//!   nothing else happens first. Watchdogs, heartbeats and retries live there, so they fire
//!   however the I/O around the core behaves.
//!
//! The rig's tokio shell ([`crate::gateway::shell`]), replay of a recording
//! ([`crate::replay`]), the virtual rig of the deterministic simulation and the fuzz target
//! all drive it this way and no other, so a recording of the inputs of any of them replays
//! every decision, byte for byte. The queries ([`Core::state`], [`Core::counters`],
//! [`Core::scene`], ...) change nothing.
//!
//! ```
//! use flowgate::config::GatewayConfig;
//! use flowgate::gateway::{Core, Input, NoClock, Output};
//! use flowgate::time::HostTime;
//!
//! let config = GatewayConfig::from_toml(include_str!("../../../rig.example.toml"), "rig.toml").unwrap();
//! let mut core = Core::new(config.rig("rig.toml").unwrap(), NoClock);
//! let mut now = HostTime::ZERO;
//! core.handle(now, Input::PsdConnected);
//! let mut to_controller = 0;
//! for _ in 0..10 {
//!     // Carry out what the core asks: here, count the packets for the controller.
//!     while let Some(output) = core.poll() {
//!         if let Output::Psd(_packet) = output {
//!             to_controller += 1; // the shell encodes and writes it to the serial line
//!         }
//!     }
//!     // Nothing was read: sleep until the core's deadline and tick it.
//!     now = core.next_deadline();
//!     core.handle(now, Input::Tick);
//! }
//! // The handshake's request, asked again while the controller stays silent.
//! assert!(to_controller >= 2);
//! ```
//!
//! Per cycle (one PSD time-division frame, closed by its `FrameEnd`):
//! decode -> floor coordinates (calibration) -> [`Tracker`] -> control step -> one CAN
//! velocity frame. The same core runs on the rig, in deterministic virtual time against the
//! simulator's firmware, in replay and in the benchmarks: that is what makes a
//! virtual-time test evidence about the rig.

use std::collections::VecDeque;
use std::time::Duration;

use crate::Point;
use flowgate_protocol::codec::StreamError;
use flowgate_protocol::motor::{BoardState, EStopReason, FaultBits, MotorMessage, NmtCommand, Target};
use flowgate_protocol::psd::{FaultCode, Message, Packet};
use flowgate_protocol::CanFrame;

pub mod cia402;
pub mod counter_window;
mod counters;
pub mod input;
pub mod operator;
pub mod psd_session;
pub mod safety;
pub mod scene;
pub mod timing;

pub use counters::{Counters, Progress};
pub use input::{Answer, Input};
pub use psd_session::SetupError;
pub use safety::{State, StopReason};

use crate::config::{Motors, Rig};
use crate::control::{ControlStep, StepStatus, Supervision};
use crate::link::CanEvent;
use crate::planner::Space;
use crate::time::{CtrlTime, HostTime};
use crate::track::{Implausible, Pose, Tracker};
use cia402::{Cia402Master, Heard};
use counter_window::{CounterWindow, Verdict};
use operator::{Goal, ObstacleStatus, Refusal, Request, Status, MAX_GOALS};
use psd_session::{PsdSession, SessionEvent};
use safety::{Action, Safety};
use scene::{ObstacleView, SceneRecord};
use timing::CycleRecord;

/// How often the gateway sends its heartbeat.
pub const HEARTBEAT_PERIOD: Duration = Duration::from_millis(100);
/// How long an orderly stop may take before the gateway calls the axes at rest.
pub const STOP_GRACE: Duration = Duration::from_secs(1);
/// The window over which bad serial frames are counted against the budget.
const BAD_FRAME_WINDOW: Duration = Duration::from_secs(1);
/// How long an armed gateway waits for the board to report Enabled before it sends the
/// enable again (two status periods), and how many times it does.
const ENABLE_GRACE: Duration = Duration::from_millis(100);
const ENABLE_RETRIES: u8 = 3;
/// Sequence errors the board may count within a second (1% loss at 1 kHz is 10).
const BOARD_SEQ_ERRORS_PER_S: u32 = 10;
/// Transmits an SLCAN adapter may refuse within a second: beyond, the commands are not
/// reaching the board.
const TX_REFUSED_PER_S: u32 = 3;
/// How far a frame counter may lie from the last frame's, either way, and still be judged
/// against it (a second of frames at 1 kHz); beyond is a jump.
const FRAME_WINDOW: u32 = 1024;
/// Consecutive frame counters beyond the window that confirm the controller's counter
/// really moved.
const FRAME_CONFIRM: u8 = 3;
/// How often a lost serial line or CAN link is asked to be opened again.
pub const REOPEN_EVERY: Duration = Duration::from_millis(200);
/// A refused transmit asks for the adapter's status, at most this often.
const STATUS_REPOLL: Duration = Duration::from_millis(10);

/// Measures how long each stage of a cycle takes. The core reads no clock of its own: the
/// rig's shell hands it a monotonic one, the deterministic simulation [`NoClock`] (every
/// stage then takes zero time, and the outputs depend on the inputs alone).
pub trait StageClock {
    /// Nanoseconds from an arbitrary origin.
    fn now_ns(&mut self) -> u64;
}

/// A stage clock that always says zero.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoClock;

impl StageClock for NoClock {
    fn now_ns(&mut self) -> u64 {
        0
    }
}

/// What the core asks of its caller.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Output {
    /// A packet for the PSD controller.
    Psd(Packet),
    /// A CAN frame (board configuration, stops, heartbeats).
    Can(CanFrame),
    /// A cycle's velocity command: write `frame`, then complete `record` with
    /// [`CycleRecord::written`] and record it.
    Command { frame: CanFrame, record: CycleRecord },
    /// The safety state changed.
    State { at: HostTime, state: State },
    /// Ask the CAN link for its controller's state (an SLCAN adapter's status flags).
    PollCanStatus,
    /// The PSD controller is configured and streaming.
    Streaming,
    /// The PSD controller could not be configured; the caller closes the line and hands
    /// the core [`Input::PsdLost`] (or gives up, if it never streamed).
    SetupFailed(SetupError),
    /// Open the lost PSD serial line again, and hand the core [`Input::PsdConnected`] once
    /// it is open. A failed attempt needs no answer: the core asks again every
    /// [`REOPEN_EVERY`].
    OpenPsd,
    /// Open the lost CAN link again (it may take its time: an SLCAN adapter answers three
    /// commands), and hand the core [`Input::CanReopened`] once it is open. The core asks
    /// again every [`REOPEN_EVERY`]; an attempt still under way when it does goes on.
    OpenCan,
}

/// One LED's sample in the frame being collected.
#[derive(Debug, Clone, Copy)]
struct RawSample {
    x: i32,
    y: i32,
    at: CtrlTime,
    usable: bool,
}

/// Events counted over a sliding second against a budget (the window never grows past it).
#[derive(Debug)]
struct Budget {
    times: VecDeque<HostTime>,
    limit: usize,
}

impl Budget {
    fn new(per_second: u32) -> Self {
        let limit = per_second as usize;
        Self { times: VecDeque::with_capacity((limit + 1).min(4096)), limit }
    }

    /// Count one at `now`; whether more than the budget fell within the last second.
    fn exceeded(&mut self, now: HostTime) -> bool {
        while self.times.front().is_some_and(|&b| now.since(b) > BAD_FRAME_WINDOW) {
            self.times.pop_front();
        }
        if self.times.len() > self.limit.min(4095) {
            self.times.pop_front();
        }
        self.times.push_back(now);
        self.times.len() > self.limit
    }
}

/// What the core knows of the motor board.
#[derive(Debug, Default)]
struct BoardView {
    last_heartbeat: Option<HostTime>,
    state: Option<BoardState>,
    faults: FaultBits,
    rates: [i32; 2],
    /// The board's own count of sequence errors, as last reported.
    seq_errors: Option<u8>,
}

/// The gateway core. `K` times the stages of a cycle.
#[derive(Debug)]
pub struct Core<K: StageClock> {
    rig: Rig,
    clock: K,
    psd: PsdSession,
    tracker: Tracker,
    control: ControlStep,
    safety: Safety,
    board: BoardView,
    /// The CiA 402 drives, when the rig has them instead of a board (`can.protocol`).
    cia402: Option<Cia402Master>,
    /// Per LED id: this frame's sample.
    frame: [Option<RawSample>; 256],
    out: VecDeque<Output>,
    counters: Counters,
    progress: Progress,
    last_sample: HostTime,
    armed_at: HostTime,
    /// Why the last robot sample was discarded as implausible, until a plausible one comes.
    implausible: Option<Implausible>,
    /// When the last plausible robot pose arrived (host time, whatever its age).
    robot_arrived: HostTime,
    /// Bad serial frames, and sequence errors, within the last second.
    bad_frames: Budget,
    link_errors: Budget,
    /// Samples of LEDs the schedule does not have in their slot, and frame counters beyond
    /// the window, within the last second: each its own named fault beyond the budget.
    unscheduled: Budget,
    frame_jumps: Budget,
    /// Sequence errors the board counted (lost or foreign velocity commands).
    board_seq: Budget,
    /// Transmits the SLCAN adapter refused.
    tx_refused: Budget,
    /// When the SLCAN adapter's status was last asked for.
    status_polled: HostTime,
    /// When the board was last told to enable, and how often again since arming.
    enable_sent: HostTime,
    enable_retries: u8,
    /// The frame whose samples are being collected, and how many came.
    collecting: Option<(u32, u8)>,
    /// The frame counter, against the last frame that ended.
    frames: CounterWindow,
    /// When a robot sample was last discarded as stamped in the future (the clock, not the
    /// robot, is then what went wrong).
    robot_from_future: Option<HostTime>,
    /// The PSD session is being configured again for an operator's reset (not a reconnect).
    rehandshake: bool,
    /// When another device's velocity command to our board was last heard.
    second_master_heard: Option<HostTime>,
    /// The CAN link is open (not failed or down since it last opened).
    can_link_up: bool,
    /// When to ask for the lost PSD line, and the lost CAN link, to be opened again.
    psd_reopen_at: HostTime,
    can_reopen_at: HostTime,
    next_heartbeat: HostTime,
    stopping_since: Option<HostTime>,
    velocity_seq: u8,
    last_command: Option<HostTime>,
    /// Decode time, and check time (sequence, time mapping, schedule, frame assembly),
    /// since the last cycle, ns.
    decode_ns: u64,
    checks_ns: u64,
    /// When the packet being handled was decoded (stage clock): its checks run from here.
    checks_from: Option<u64>,
    shutdown: bool,
    streamed: bool,
    /// The goal being driven to, then the rest of the queue.
    goals: VecDeque<Goal>,
    /// The operator asked to start: go from Armed to Running once ready.
    start_requested: bool,
    /// Arm and start towards the rig's goal when the controller first streams (`--arm`).
    arm_at_start: bool,
    /// The last cycle's pose estimate and sensing delay (for [`Core::scene`]).
    last_estimate: Option<(Pose, f64)>,
}

impl<K: StageClock> Core<K> {
    pub fn new(rig: Rig, clock: K) -> Self {
        let radii: Vec<f64> = rig.obstacles.iter().map(|o| o.radius).collect();
        Self {
            psd: PsdSession::new(rig.schedule, rig.psd_counts),
            tracker: Tracker::new(rig.tracking, rig.led_geometry, &radii),
            control: ControlStep::new(rig.control),
            safety: Safety::default(),
            board: BoardView::default(),
            cia402: match rig.motors {
                Motors::Pcl80k => None,
                Motors::Cia402(settings) => Some(Cia402Master::new(settings)),
            },
            frame: [None; 256],
            out: VecDeque::with_capacity(64),
            counters: Counters::default(),
            progress: Progress::default(),
            last_sample: HostTime::ZERO,
            armed_at: HostTime::ZERO,
            implausible: None,
            robot_arrived: HostTime::ZERO,
            bad_frames: Budget::new(rig.safety.bad_frames_per_s),
            link_errors: Budget::new(rig.safety.bad_frames_per_s),
            unscheduled: Budget::new(rig.safety.bad_frames_per_s),
            frame_jumps: Budget::new(rig.safety.bad_frames_per_s),
            board_seq: Budget::new(BOARD_SEQ_ERRORS_PER_S),
            tx_refused: Budget::new(TX_REFUSED_PER_S),
            status_polled: HostTime::ZERO,
            enable_sent: HostTime::ZERO,
            enable_retries: 0,
            collecting: None,
            frames: CounterWindow::new(32, FRAME_WINDOW, FRAME_CONFIRM),
            robot_from_future: None,
            rehandshake: false,
            second_master_heard: None,
            can_link_up: true,
            psd_reopen_at: HostTime::NEVER,
            can_reopen_at: HostTime::NEVER,
            next_heartbeat: HostTime::ZERO,
            stopping_since: None,
            velocity_seq: 0,
            last_command: None,
            decode_ns: 0,
            checks_ns: 0,
            checks_from: None,
            shutdown: false,
            streamed: false,
            goals: VecDeque::with_capacity(MAX_GOALS),
            start_requested: false,
            arm_at_start: false,
            last_estimate: None,
            clock,
            rig,
        }
    }

    pub fn rig(&self) -> &Rig {
        &self.rig
    }
    pub fn state(&self) -> State {
        self.safety.state()
    }
    pub fn safety(&self) -> &Safety {
        &self.safety
    }
    pub fn counters(&self) -> Counters {
        self.counters
    }
    pub fn progress(&self) -> Progress {
        self.progress
    }
    /// Whether the controller has streamed at least once (a setup failure before that is a
    /// startup failure).
    pub fn has_streamed(&self) -> bool {
        self.streamed
    }
    /// Shutdown was asked for and the robot is at rest: the caller may end the run.
    pub fn finished(&self) -> bool {
        self.shutdown && matches!(self.state(), State::Idle | State::Stopped(_) | State::Fault(_))
    }
    /// What the core holds in its queues, in elements of capacity: the output queue, the
    /// budgets' windows, the goals. A soak asserts it stops growing once warm.
    pub fn footprint(&self) -> usize {
        self.out.capacity()
            + [&self.bad_frames, &self.link_errors, &self.board_seq, &self.tx_refused]
                .iter()
                .map(|b| b.times.capacity())
                .sum::<usize>()
            + self.goals.capacity()
    }

    /// The PSD receive buffer's capacity, bytes: it rises and falls as frames are taken
    /// out of it, so a soak holds it to a bound rather than to its warm size.
    pub fn psd_buffer_capacity(&self) -> usize {
        self.psd.buffered_capacity()
    }

    /// The next output, if any.
    pub fn poll(&mut self) -> Option<Output> {
        self.out.pop_front()
    }

    /// When the core next needs an [`Input::Tick`], whatever else happens.
    pub fn next_deadline(&self) -> HostTime {
        let mut next = self.next_heartbeat.min(self.psd.deadline()).min(self.psd_reopen_at).min(self.can_reopen_at);
        let state = self.state();
        if is_active(state) {
            next = next.min(self.last_sample + self.rig.safety.sample_timeout);
            next = next.min(self.heartbeat_deadline().0).min(self.psd.sync_deadline());
        }
        if state == State::Running {
            next = next.min(self.pose_deadline());
            if let Some((at, _)) = self.occlusion_deadline() {
                next = next.min(at);
            }
        }
        if let Some(since) = self.stopping_since {
            next = next.min(since + STOP_GRACE);
        }
        if let Some(at) = self.keep_alive_due() {
            next = next.min(at);
        }
        if let Some(m) = &self.cia402 {
            next = next.min(m.deadline());
        }
        next
    }

    /// When the motors' heartbeat watchdog fires, and for which node: the board's, or the
    /// drive heard longest ago (each counted from the arm at the earliest).
    fn heartbeat_deadline(&self) -> (HostTime, u8) {
        let from = |heard: Option<HostTime>| heard.map_or(self.armed_at, |h| h.max(self.armed_at));
        let (heard, node) = match &self.cia402 {
            None => (from(self.board.last_heartbeat), self.rig.node.get()),
            Some(m) => {
                let [l, r] = m.heard().map(from);
                let [ln, rn] = m.nodes().map(|n| n.get());
                if r < l {
                    (r, rn)
                } else {
                    (l, ln)
                }
            }
        };
        (heard + self.rig.safety.heartbeat_timeout, node)
    }

    /// When an enabled but idle board (Armed, Stopping) needs a zero command to keep its
    /// command timeout from firing: half its timeout after the last command. Cycles send
    /// commands as they come; this covers a pipeline that delivers none yet (a long sensing
    /// delay, the first pose still on its way).
    fn keep_alive_due(&self) -> Option<HostTime> {
        // CiA 402 drives have no command timeout: they watch the gateway's heartbeat.
        let idle_enabled = matches!(self.state(), State::Armed | State::Stopping(_)) && self.cia402.is_none();
        let half = Duration::from_millis(u64::from(self.rig.board.command_timeout_ms)) / 2;
        self.last_command.filter(|_| idle_enabled).map(|last| last + half)
    }

    /// One input at `now`: every input the core takes goes through here on the rig, so a
    /// recording of them replays the run (see [`super::input`]). An operator's request gets
    /// its answer back.
    pub fn handle(&mut self, now: HostTime, input: Input<'_>) -> Option<Answer> {
        match input {
            Input::PsdConnected => self.psd_connected(now),
            Input::PsdLost => self.psd_lost(now),
            Input::PsdBytes(bytes) => self.psd_bytes(now, bytes),
            Input::Can(event) => self.can_event(now, event),
            Input::CanFailed => self.can_failed(now),
            Input::CanReopened => self.can_reopened(),
            Input::Request(request) => return Some(self.answer(now, request)),
            Input::ArmAtStart => self.arm_at_start(),
            Input::Shutdown => self.shutdown(now),
            Input::Tick => self.tick(now),
        }
        None
    }

    /// An operator's request and its answer: the status comes with a query or an accepted
    /// request.
    fn answer(&mut self, now: HostTime, request: &Request) -> Answer {
        let result = self.request(now, request);
        let status = (request.is_query() || result.is_ok()).then(|| self.status(now));
        Answer { result, status }
    }

    /// The PSD line opened: configure the controller.
    fn psd_connected(&mut self, now: HostTime) {
        self.psd_reopen_at = HostTime::NEVER;
        let out = &mut self.out;
        self.psd.connect(now, &mut |p| out.push_back(Output::Psd(p)));
    }

    /// The PSD line failed (read error, end of file, write timeout): a serial fault.
    fn psd_lost(&mut self, now: HostTime) {
        if self.psd_reopen_at == HostTime::NEVER {
            self.psd_reopen_at = now + REOPEN_EVERY;
        }
        self.psd.down();
        self.counters.serial_dropped_bytes = self.psd.dropped_bytes();
        self.stop(now, StopReason::SerialLost);
    }

    /// Bytes read from the PSD line at `now`.
    fn psd_bytes(&mut self, now: HostTime, bytes: &[u8]) {
        if self.psd.is_down() {
            return;
        }
        self.psd.feed(bytes);
        loop {
            let started = self.clock.now_ns();
            let item = self.psd.next_item();
            let decoded = self.clock.now_ns();
            self.decode_ns += decoded.saturating_sub(started);
            match item {
                None => break,
                Some(Err(e)) => self.bad_frame(now, e),
                Some(Ok(packet)) => {
                    // A frame end's checks end where its cycle starts (`cycle` takes them).
                    self.checks_from = Some(decoded);
                    self.packet(now, packet);
                    if let Some(from) = self.checks_from.take() {
                        self.checks_ns += self.clock.now_ns().saturating_sub(from);
                    }
                }
            }
        }
        self.counters.serial_dropped_bytes = self.psd.dropped_bytes();
    }

    /// A CAN event at `now`.
    fn can_event(&mut self, now: HostTime, event: CanEvent) {
        match event {
            CanEvent::Frame(f) => self.can_frame(now, &f),
            CanEvent::Garbled => self.counters.can_undecodable += 1,
            CanEvent::TransmitRefused => {
                self.counters.can_tx_refused += 1;
                if self.tx_refused.exceeded(now) && is_active(self.state()) {
                    self.stop(now, StopReason::CanTransmitRefused);
                } else if now.since(self.status_polled) >= STATUS_REPOLL {
                    // Ask why at once: a bus-off adapter says so in its flags.
                    self.status_polled = now;
                    self.out.push_back(Output::PollCanStatus);
                }
            }
            CanEvent::AdapterStatus { bus_off, error_passive } => {
                if error_passive {
                    self.counters.can_error_passive += 1;
                }
                if bus_off {
                    self.counters.can_error_frames += 1;
                    if is_active(self.state()) {
                        self.stop(now, StopReason::BusOff);
                    }
                }
            }
            CanEvent::ErrorFrame { bus_off } => {
                self.counters.can_error_frames += 1;
                if bus_off {
                    self.stop(now, StopReason::BusOff);
                }
            }
            CanEvent::InterfaceDown => {
                self.can_lost(now);
                self.stop(now, StopReason::CanInterfaceDown);
            }
        }
    }

    /// The CAN link failed (a write error or timeout, the adapter gone).
    fn can_failed(&mut self, now: HostTime) {
        self.can_lost(now);
        self.stop(now, StopReason::CanLinkLost);
    }

    /// The CAN link is gone: ask for it again a little later (once per loss: a link
    /// failing again while it is lost changes nothing).
    fn can_lost(&mut self, now: HostTime) {
        if self.can_link_up {
            self.can_reopen_at = now + REOPEN_EVERY;
        }
        self.can_link_up = false;
    }

    /// The CAN link is open again after a loss (the core stays faulted until reset).
    fn can_reopened(&mut self) {
        self.counters.can_reconnects += 1;
        self.can_link_up = true;
        self.can_reopen_at = HostTime::NEVER;
    }

    /// An operator's request at `now`. Refusals say exactly why and change nothing.
    fn request(&mut self, now: HostTime, request: &Request) -> Result<(), Refusal> {
        let state = self.state();
        match request {
            Request::Status | Request::Stats { .. } => Ok(()),
            Request::Arm => match state {
                State::Idle | State::Stopped(_) => {
                    if let Some((index, o)) = self
                        .rig
                        .obstacles
                        .iter()
                        .enumerate()
                        .find(|&(k, o)| o.required && self.tracker.obstacle_time(k).is_none())
                    {
                        return Err(Refusal::RequiredObstacleUnseen { led: o.led, index });
                    }
                    let action = self.safety.arm(now.secs());
                    self.armed_at = now;
                    self.enable_retries = 0;
                    self.last_sample = now;
                    self.board.last_heartbeat = None;
                    self.start_requested = false;
                    self.act(now, action);
                    Ok(())
                }
                State::Fault(_) => Err(Refusal::Faulted(state)),
                _ => Err(Refusal::Already(state)),
            },
            Request::Start => match state {
                State::Armed if self.goals.is_empty() => Err(Refusal::NoGoal),
                State::Armed => {
                    self.start_requested = true;
                    Ok(())
                }
                State::Running => Err(Refusal::Already(state)),
                State::Fault(_) => Err(Refusal::Faulted(state)),
                _ => Err(Refusal::NotArmed(state)),
            },
            Request::Stop | Request::Cancel => {
                if matches!(request, Request::Cancel) {
                    self.goals.clear();
                }
                self.start_requested = false;
                if matches!(state, State::Running | State::Armed) {
                    self.stop(now, StopReason::Operator);
                }
                Ok(())
            }
            Request::EStop => {
                self.start_requested = false;
                // Accepted whatever the state. In a fault the board was e-stopped already; it
                // hears the operator's e-stop again all the same.
                if matches!(state, State::Fault(_)) {
                    match &mut self.cia402 {
                        None => {
                            let target = Target::Node(self.rig.node);
                            self.send(MotorMessage::EStop { target, reason: EStopReason::Operator });
                        }
                        Some(m) => {
                            let out = &mut self.out;
                            m.quick_stop(&mut |f| out.push_back(Output::Can(f)));
                        }
                    }
                } else {
                    self.stop(now, StopReason::OperatorEStop);
                }
                Ok(())
            }
            Request::Reset => match state {
                State::Fault(reason) if self.cause_present(now, reason) => Err(Refusal::CauseStillPresent(reason)),
                State::Fault(reason) => {
                    if let StopReason::ObstacleOccluded { led } = reason {
                        if let Some(k) = self.rig.obstacles.iter().position(|o| o.led == led) {
                            self.tracker.drop_obstacle(k);
                        }
                    }
                    // CiA 402 drives are reset on the way to operation enabled at the next arm.
                    if self.cia402.is_none() {
                        self.send(MotorMessage::Nmt {
                            target: Target::Node(self.rig.node),
                            command: NmtCommand::FaultReset,
                        });
                    }
                    // The PSD session starts afresh: sequence numbers, frame counter and clock
                    // taken anew, so no baseline a fault left behind outlives the reset.
                    if !self.psd.is_down() {
                        let out = &mut self.out;
                        self.psd.connect(now, &mut |p| out.push_back(Output::Psd(p)));
                        self.frames.reset();
                        self.robot_from_future = None;
                        self.rehandshake = true;
                    }
                    self.safety.reset(now.secs());
                    self.state_changed(now);
                    Ok(())
                }
                _ => Err(Refusal::NotFaulted(state)),
            },
            Request::Goal { goals } => self.set_goals(now, goals),
        }
    }

    /// Arm and start towards the rig's `[goal]` as soon as the controller first streams, with
    /// no operator (`flowgate run --arm`, the demo, the virtual rig; never a service).
    fn arm_at_start(&mut self) {
        self.arm_at_start = true;
    }

    /// Arm, set `goal` and start.
    fn arm_and_start(&mut self, now: HostTime, goal: Goal) -> Result<(), Refusal> {
        self.request(now, &Request::Arm)?;
        self.request(now, &Request::Goal { goals: vec![goal] })?;
        self.request(now, &Request::Start)
    }

    /// What the gateway knows now: state, goals, pose, obstacles.
    fn status(&mut self, now: HostTime) -> Status {
        let period = self.rig.sample_period.as_secs_f64();
        let (wheel_base, robot, margin) =
            (self.rig.control.drive.wheel_base, self.rig.control.robot_radius, self.rig.control.planner.margin);
        let tracked: Vec<usize> = self.tracker.tracked().collect();
        let (pose, obstacles) = match self.tracker.estimate(now.secs(), period, wheel_base) {
            Some(tr) => {
                let p = tr.estimate.pose();
                let delay = tr.estimate.delay;
                let obstacles = tr
                    .estimate
                    .obstacles
                    .iter()
                    .zip(tracked)
                    .map(|(o, k)| ObstacleStatus {
                        led: self.rig.obstacles[k].led,
                        occluded: o.spread > 0.0,
                        position: [o.center.re, o.center.im],
                        velocity: [o.velocity.re, o.velocity.im],
                        planning_radius: margin.radius(o.radius + robot, o.velocity.norm(), delay),
                    })
                    .collect();
                (Some([p.position.re, p.position.im, p.heading]), obstacles)
            }
            None => (None, Vec::new()),
        };
        Status {
            state: self.state(),
            last_stop: self.safety.history.iter().rev().find_map(|(_, s)| s.reason()),
            goals: self.goals.iter().copied().collect(),
            pose,
            obstacles,
            absent: (0..self.rig.obstacles.len())
                .filter(|&k| self.tracker.obstacle_time(k).is_none())
                .map(|k| self.rig.obstacles[k].led)
                .collect(),
            cycles: self.counters.cycles,
            latency_us: None,
            stages: None,
        }
    }

    /// What the last cycle believed: the robot's pose, the goal, each obstacle with its
    /// covariance and planning radius. Reads only (a recording takes one per command).
    pub fn scene(&self, now: HostTime) -> SceneRecord {
        // The last cycle's number (its `CycleRecord::cycle`): cycles count from 0.
        let cycle = self.counters.cycles.saturating_sub(1);
        let mut scene = SceneRecord { cycle, at: now, ..SceneRecord::default() };
        let Some((pose, delay)) = self.last_estimate else { return scene };
        let goal = self.control.config().goal;
        scene.pose = [pose.position.re, pose.position.im, pose.heading];
        scene.goal = [goal.re, goal.im];
        let (robot, margin) = (self.rig.control.robot_radius, self.rig.control.planner.margin);
        for (view, (o, cov)) in scene.obstacles.iter_mut().zip(self.tracker.obstacles_at(now.secs())) {
            *view = ObstacleView {
                position: [o.center.re as f32, o.center.im as f32],
                velocity: [o.velocity.re as f32, o.velocity.im as f32],
                covariance: cov.map(|c| c as f32),
                planning_radius: margin.radius(o.radius + robot, o.velocity.norm(), delay) as f32,
                radius: o.radius as f32,
            };
            scene.count += 1;
        }
        scene
    }

    /// Check and take a goal or a queue: each inside the calibrated arena, inside the lane,
    /// outside every obstacle's planning circle now.
    fn set_goals(&mut self, now: HostTime, goals: &[Goal]) -> Result<(), Refusal> {
        if goals.is_empty() {
            return Err(Refusal::EmptyQueue);
        }
        if goals.len() > MAX_GOALS {
            return Err(Refusal::TooManyGoals(goals.len()));
        }
        let obstacles = self.status(now).obstacles;
        for (index, g) in goals.iter().enumerate() {
            let [x, y] = g.position;
            let bad = |why: String| Refusal::BadGoal { index, x, y, why };
            let at = Point::new(x, y);
            if !(x.is_finite() && y.is_finite() && g.tolerance.is_finite() && g.tolerance > 0.0) {
                return Err(bad("position and tolerance must be finite, the tolerance positive".into()));
            }
            if !self.rig.calibration.in_view(at) {
                return Err(bad(format!("outside the calibrated arena: {}", self.rig.calibration.view_extent())));
            }
            if let Space::Lane { half_width } = self.rig.control.planner.space {
                if y.abs() >= half_width {
                    return Err(bad(format!("outside the lane (|y| >= {half_width} m)")));
                }
            }
            for o in &obstacles {
                let gap = (at - Point::new(o.position[0], o.position[1])).norm();
                if gap <= o.planning_radius {
                    return Err(bad(format!(
                        "inside obstacle LED {}'s planning circle ({gap:.3} m from it, radius {:.3} m)",
                        o.led, o.planning_radius
                    )));
                }
            }
        }
        self.goals.clear();
        self.goals.extend(goals.iter().copied());
        let first = goals[0];
        self.control.set_goal(Point::new(first.position[0], first.position[1]), first.tolerance);
        Ok(())
    }

    /// Whether a fault's cause persists now.
    fn cause_present(&self, now: HostTime, reason: StopReason) -> bool {
        let s = &self.rig.safety;
        let heard = match &self.cia402 {
            None => self.board.last_heartbeat.is_some_and(|h| now < h + s.heartbeat_timeout),
            Some(m) => m.heard().iter().all(|h| h.is_some_and(|h| now < h + s.heartbeat_timeout)),
        };
        let sampling = !self.psd.is_down() && now < self.last_sample + s.sample_timeout;
        match reason {
            StopReason::SerialLost => self.psd.is_down(),
            StopReason::SamplesStopped | StopReason::SerialGarbled => !sampling,
            StopReason::PoseLost => {
                !sampling || self.tracker.pose_time().is_none_or(|t| now.secs() - t >= s.pose_timeout.as_secs_f64())
            }
            StopReason::HeartbeatLost { .. } | StopReason::DriveHeartbeatLost { .. } => !heard,
            // The reset forgets the occluded track: the obstacle is absent until seen again
            // (and a required one refuses the arm until then).
            StopReason::ObstacleOccluded { .. } => false,
            StopReason::BusOff | StopReason::BoardBusOff { .. } => !heard || self.board.faults.contains(FaultBits::BUS),
            // The board refuses to leave its e-stop while its input is open; so does the gateway.
            StopReason::BoardEStop { .. } => !heard || self.board.faults.contains(FaultBits::ESTOP_INPUT),
            StopReason::CanLinkLost | StopReason::CanInterfaceDown => !self.can_link_up,
            // Two masters must never drive one board: refused while the other is heard.
            StopReason::SecondMaster { .. } | StopReason::DriveSecondMaster { .. } => {
                self.second_master_heard.is_some_and(|at| now < at + s.heartbeat_timeout)
            }
            // The reset clears the board's latched fault; a driver fault that persists
            // faults the gateway again once it runs.
            _ => false,
        }
    }

    /// Stop in order and end the run once at rest.
    fn shutdown(&mut self, now: HostTime) {
        self.shutdown = true;
        if !matches!(self.state(), State::Stopping(_)) {
            self.stop(now, StopReason::Shutdown);
        }
    }

    /// Time passed: heartbeats, retries, watchdogs, the end of an orderly stop.
    fn tick(&mut self, now: HostTime) {
        if now >= self.next_heartbeat {
            match &mut self.cia402 {
                None => self.send(MotorMessage::GatewayHeartbeat { state: self.state().wire() }),
                Some(m) => {
                    let out = &mut self.out;
                    m.heartbeat(&mut |f| out.push_back(Output::Can(f)));
                }
            }
            self.next_heartbeat = now + HEARTBEAT_PERIOD;
            // An SLCAN adapter reports bus-off only when asked: ask with each heartbeat.
            if self.rig.can.polls_status() {
                self.status_polled = now;
                self.out.push_back(Output::PollCanStatus);
            }
        }
        let out = &mut self.out;
        if let Some(e) = self.psd.tick(now, &mut |p| out.push_back(Output::Psd(p))) {
            self.out.push_back(Output::SetupFailed(e));
        }
        if now >= self.psd_reopen_at {
            self.psd_reopen_at = now + REOPEN_EVERY;
            self.out.push_back(Output::OpenPsd);
        }
        if now >= self.can_reopen_at {
            self.can_reopen_at = now + REOPEN_EVERY;
            self.out.push_back(Output::OpenCan);
        }
        if let Some(reason) = self.watchdog(now) {
            self.stop(now, reason);
        }
        if let Some(reason) = self.cia402.as_mut().and_then(|m| m.tick(now)) {
            self.stop(now, reason);
        }
        self.check_at_rest(now);
        if self.keep_alive_due().is_some_and(|at| now >= at) {
            self.last_command = Some(now);
            self.send(MotorMessage::Velocity { node: self.rig.node, left: 0, right: 0, seq: self.velocity_seq });
            self.velocity_seq = self.velocity_seq.wrapping_add(1);
        }
    }

    fn pose_deadline(&self) -> HostTime {
        let seen = self.tracker.pose_time().map_or(HostTime::ZERO, HostTime::from_secs_f64);
        seen + self.rig.safety.pose_timeout
    }

    /// When the longest-unseen tracked obstacle has been occluded too long (counted from
    /// its last sighting, or the arm if later), and which: the region it may have reached
    /// keeps growing, and a robot must not drive around a guess for ever. An obstacle never
    /// seen, or seen leaving the view, has no track and no deadline.
    fn occlusion_deadline(&self) -> Option<(HostTime, usize)> {
        self.tracker
            .tracked()
            .filter_map(|k| Some((HostTime::from_secs_f64(self.tracker.obstacle_time(k)?).max(self.armed_at), k)))
            .min_by_key(|&(seen, _)| seen)
            .map(|(seen, k)| (seen + self.rig.safety.occlusion_timeout, k))
    }

    /// The first watchdog that has expired, if any.
    fn watchdog(&self, now: HostTime) -> Option<StopReason> {
        let state = self.state();
        if !is_active(state) {
            return None;
        }
        let s = &self.rig.safety;
        let (heartbeat_deadline, heartbeat_node) = self.heartbeat_deadline();
        // Each fires at its deadline, the very time `next_deadline` asks to be ticked.
        if now >= self.last_sample + s.sample_timeout {
            Some(StopReason::SamplesStopped)
        } else if state == State::Running && now >= self.pose_deadline() {
            // Named by the first cause: the line gone quiet; the robot's samples stamped in
            // the future (the controller's clock jumped); seen where it cannot be; arriving,
            // but too old (delay); or not arriving.
            let quiet = now.since(self.last_sample) > 2 * self.rig.sample_period;
            Some(if quiet {
                StopReason::SamplesStopped
            } else if self.robot_from_future.is_some_and(|at| now.since(at) < s.sample_timeout) {
                StopReason::ClockJumped
            } else if self.implausible.is_some() {
                StopReason::PoseImplausible
            } else if now.since(self.robot_arrived) < s.sample_timeout {
                StopReason::PoseDelayed
            } else {
                StopReason::PoseLost
            })
        } else if let Some(k) = self.occlusion_deadline().filter(|&(at, _)| state == State::Running && now >= at) {
            Some(StopReason::ObstacleOccluded { led: self.rig.obstacles[k.1].led })
        } else if now >= heartbeat_deadline {
            Some(match self.cia402 {
                None => StopReason::HeartbeatLost { node: heartbeat_node },
                Some(_) => StopReason::DriveHeartbeatLost { node: heartbeat_node },
            })
        } else if now >= self.psd.sync_deadline() {
            Some(StopReason::ClockUnsynced)
        } else {
            None
        }
    }

    fn bad_frame(&mut self, now: HostTime, e: StreamError<flowgate_protocol::psd::Error>) {
        self.counters.bad_serial_frames += 1;
        tracing::debug!("bad serial frame: {e}");
        if self.bad_frames.exceeded(now) && is_active(self.state()) {
            self.stop(now, StopReason::SerialGarbled);
        }
    }

    /// A packet discarded for its place in the sequence or the schedule: counted (by the
    /// caller), and against the budget.
    fn link_error(&mut self, now: HostTime) {
        if self.link_errors.exceeded(now) && is_active(self.state()) {
            self.stop(now, StopReason::PsdSequence);
        }
    }

    /// The controller's sequence: duplicates and replays are discarded, gaps counted.
    fn in_sequence(&mut self, now: HostTime, packet: &Packet) -> bool {
        if let Message::Fault { code: FaultCode::Reset, .. } = packet.message {
            self.psd.forget_sequence(); // a rebooted controller counts from zero
        }
        match self.psd.sequence(packet.seq) {
            Verdict::Next => true,
            Verdict::Gap(n) => {
                self.counters.psd_packets_lost += u64::from(n);
                true
            }
            Verdict::Rebased => {
                self.counters.psd_seq_rebased += 1;
                tracing::warn!(
                    seq = packet.seq,
                    "PSD controller's sequence numbers moved: following them from {}",
                    packet.seq
                );
                true
            }
            Verdict::Repeat => {
                self.counters.psd_duplicates += 1;
                self.link_error(now);
                false
            }
            Verdict::Old => {
                self.counters.psd_out_of_order += 1;
                self.link_error(now);
                false
            }
            Verdict::Jump => {
                self.counters.psd_seq_jumps += 1;
                self.link_error(now);
                false
            }
        }
    }

    fn packet(&mut self, now: HostTime, packet: Packet) {
        if !self.in_sequence(now, &packet) {
            return;
        }
        let out = &mut self.out;
        match self.psd.on_packet(now, &packet, &mut |p| out.push_back(Output::Psd(p))) {
            SessionEvent::Consumed => return,
            SessionEvent::Failed(e) => {
                self.out.push_back(Output::SetupFailed(e));
                return;
            }
            SessionEvent::Streaming => {
                self.last_sample = now;
                self.frames.reset();
                self.collecting = None;
                self.clear_frame();
                if self.streamed && !std::mem::take(&mut self.rehandshake) {
                    self.counters.serial_reconnects += 1;
                    self.progress.serial_reconnects = self.counters.serial_reconnects;
                }
                self.streamed = true;
                if let Some(info) = self.psd.info() {
                    tracing::info!(firmware = ?info.firmware, max_leds = info.max_leds, "PSD controller streaming");
                }
                self.out.push_back(Output::Streaming);
                if std::mem::take(&mut self.arm_at_start) {
                    let result = match self.rig.goal {
                        Some(goal) => self.arm_and_start(now, goal),
                        None => Err(Refusal::NoGoal),
                    };
                    if let Err(e) = result {
                        tracing::error!("arming at start: {e}");
                    }
                }
                return;
            }
            SessionEvent::Resynced { accepted } => {
                if accepted {
                    self.counters.time_syncs += 1;
                } else {
                    self.counters.time_syncs_rejected += 1;
                }
                return;
            }
            SessionEvent::ClockStep { step_us, again } => {
                self.counters.time_syncs_implausible += 1;
                if again {
                    tracing::error!(
                        step_us,
                        "PSD controller's clock jumped by {step_us} µs (confirmed by a second sync)"
                    );
                    if is_active(self.state()) {
                        self.stop(now, StopReason::ClockJumped);
                    }
                } else {
                    tracing::warn!(
                        step_us,
                        "time sync refused: the controller's clock moved {step_us} µs, beyond drift; checking again"
                    );
                }
                return;
            }
            SessionEvent::Pass => {}
        }
        let timed = matches!(packet.message, Message::Sample(_) | Message::FrameEnd { .. });
        if timed && !self.psd.is_streaming() {
            // Before time sync its stamps mean nothing on our clock: discard, and count.
            self.counters.samples_unsynced += 1;
            return;
        }
        match packet.message {
            Message::Sample(s) => self.sample(now, &s),
            Message::FrameEnd { frame, t_ctrl_us, samples } if self.frame_end(now, frame, samples) => {
                self.cycle(now, frame, CtrlTime(t_ctrl_us));
            }
            Message::FrameEnd { .. } => {} // discarded and counted by frame_end
            Message::Fault { code: FaultCode::Reset, .. } => {
                // The controller rebooted (or announces its boot while we configure it): its
                // schedule and clock are gone. A robot driving on it stops, named for it (a
                // quick reconfigure must not hide a reboot); the controller is configured
                // again so an operator can reset and arm.
                let out = &mut self.out;
                if self.psd.restart(now, &mut |p| out.push_back(Output::Psd(p))) {
                    tracing::warn!("PSD controller reset; reconfiguring");
                    if is_active(self.state()) {
                        self.stop(now, StopReason::ControllerReset);
                    }
                }
            }
            Message::Fault { code: FaultCode::Overrun, .. } => {
                // Samples lost inside the controller: loss, counted against the budget.
                self.counters.controller_overruns += 1;
                self.link_error(now);
            }
            Message::Fault { code, detail } => {
                self.counters.controller_faults += 1;
                tracing::error!("PSD controller fault {code:?} (detail {detail})");
                if is_active(self.state()) {
                    self.stop(now, StopReason::ControllerFault);
                }
            }
            _ => {} // heartbeats
        }
    }

    /// A sample: from a scheduled LED in its slot, into the frame being collected.
    fn sample(&mut self, now: HostTime, s: &flowgate_protocol::psd::Sample) {
        let scheduled = self.rig.schedule.slots().get(usize::from(s.slot)).is_some_and(|slot| slot.led == s.led);
        if !scheduled {
            self.counters.samples_unscheduled += 1;
            if self.unscheduled.exceeded(now) && is_active(self.state()) {
                self.stop(now, StopReason::UnscheduledLed { led: s.led });
            }
            return;
        }
        match self.collecting {
            Some((frame, _)) if frame != s.frame => {
                // The frame before never ended: its samples go, this frame starts.
                self.counters.frames_lost += 1;
                self.clear_frame();
                self.collecting = Some((s.frame, 0));
            }
            None => self.collecting = Some((s.frame, 0)),
            Some(_) => {}
        }
        if let Some((_, n)) = &mut self.collecting {
            *n = n.saturating_add(1);
        }
        self.counters.samples += 1;
        self.last_sample = now;
        let at = CtrlTime(s.t_ctrl_us);
        self.frame[usize::from(s.led)] = Some(RawSample { x: s.x, y: s.y, at, usable: s.flags.is_usable() });
    }

    /// A frame's end: whether to run its cycle. A frame already done is discarded (no
    /// second command from it); samples of another frame are dropped; gaps are counted.
    fn frame_end(&mut self, now: HostTime, frame: u32, samples: u8) -> bool {
        match self.frames.check(frame) {
            Verdict::Next => {}
            Verdict::Gap(n) => self.counters.frames_lost += u64::from(n),
            Verdict::Rebased => {
                self.counters.frames_rebased += 1;
                tracing::warn!(frame, "PSD controller's frame counter moved: following it from {frame}");
            }
            Verdict::Repeat | Verdict::Old => {
                self.counters.frames_repeated += 1;
                self.link_error(now);
                self.drop_collected(frame);
                return false;
            }
            Verdict::Jump => {
                self.counters.frames_jumped += 1;
                if self.frame_jumps.exceeded(now) && is_active(self.state()) {
                    self.stop(now, StopReason::FrameCounterJump);
                }
                self.drop_collected(frame);
                return false;
            }
        }
        let received = match self.collecting.take() {
            Some((f, n)) if f == frame => n,
            Some(_) => {
                self.counters.frames_lost += 1;
                self.clear_frame();
                0
            }
            None => 0,
        };
        if received != samples {
            self.counters.frames_incomplete += 1;
        }
        true
    }

    /// A discarded frame's samples go with it (they must not join the next frame).
    fn drop_collected(&mut self, frame: u32) {
        if self.collecting.is_some_and(|(f, _)| f == frame) {
            self.collecting = None;
            self.clear_frame();
        }
    }

    /// Forget the scheduled LEDs' samples.
    fn clear_frame(&mut self) {
        for slot in self.rig.schedule.slots() {
            self.frame[usize::from(slot.led)] = None;
        }
    }

    /// One time-division frame is complete: track, decide, command.
    fn cycle(&mut self, now: HostTime, frame_no: u32, end: CtrlTime) {
        let track_start = self.clock.now_ns();
        if let Some(from) = self.checks_from.take() {
            self.checks_ns += track_start.saturating_sub(from);
        }
        // This frame's decode and checks, whether or not it ends in a command.
        let (decode_ns, checks_ns) = (std::mem::take(&mut self.decode_ns), std::mem::take(&mut self.checks_ns));
        self.track_frame(now);
        let t = now.secs();
        let period = self.rig.sample_period.as_secs_f64();
        let (robot_radius, wheel_base) = (self.rig.control.robot_radius, self.rig.control.drive.wheel_base);
        let pose_timeout = self.rig.safety.pose_timeout.as_secs_f64();
        // The tracker's estimate borrows it: decide inside, act on the decision after.
        let motors_ready = self.motors_ready();
        let (pose, delay, clearance, step, track_ns, plan_start, ready) = {
            let Some(tracked) =
                self.tracker.estimate(t, period, wheel_base).filter(|tr| t - tr.pose_valid_at < pose_timeout)
            else {
                // No fresh pose: no command (the pose watchdog stops a running robot; the
                // keep-alive feeds a board that waits for its first pose).
                return;
            };
            let track_ns = self.clock.now_ns().saturating_sub(track_start);
            let ready =
                self.safety.state() == State::Armed && self.start_requested && !self.goals.is_empty() && motors_ready;
            if ready {
                self.safety.ready(t);
            }
            let plan_start = self.clock.now_ns();
            let step = self.safety.state().may_move().then(|| self.control.step(t, &tracked.estimate));
            (tracked.estimate.pose(), tracked.estimate.delay, tracked.clearance, step, track_ns, plan_start, ready)
        };
        if ready {
            self.state_changed(now);
        }
        self.last_estimate = Some((pose, delay));
        self.progress.clearance = clearance.map(|c| c - robot_radius);
        let mut pulses = [0i32; 2];
        let mut wheels = (0.0, 0.0);
        if let Some(out) = step {
            self.counters.obstacle_outran_robot += u64::from(out.outrun);
            self.counters.obstacle_occluded_cycles +=
                u64::from(self.tracker.tracked().any(|k| self.tracker.obstacle_occluded(k, t)));
            if let Some(plan) = out.plan {
                let (c, f) = (&mut self.counters, plan.flags);
                c.planner_saturated += u64::from(f.saturated);
                c.planner_tie_break += u64::from(f.tie_break);
                c.planner_margin_shrunk += u64::from(f.margin_shrunk);
                c.planner_unclosed_at_a_wall += u64::from(f.unclosed_at_a_wall);
            }
            match out.status {
                StepStatus::Driving => {
                    pulses = out.pulses;
                    wheels = (out.wheels.left, out.wheels.right);
                    match out.supervision {
                        Supervision::Passed => {}
                        Supervision::Slowed { .. } => self.counters.supervisor_slowed += 1,
                        Supervision::Braking { .. } => self.counters.supervisor_braking += 1,
                        Supervision::Evaded { .. } => self.counters.supervisor_evaded += 1,
                    }
                }
                StepStatus::AtGoal => self.goal_reached(now),
                StepStatus::Stalled => self.stop(now, StopReason::Stalled),
                StepStatus::GoalOccupied { index, since } => {
                    self.counters.goal_occupied += 1;
                    if since == t {
                        let led = self.obstacle_led(index);
                        tracing::warn!(
                            "goal inside obstacle LED {led}'s planning circle: holding still until it passes"
                        );
                    }
                }
                StepStatus::GoalBlocked { index } => {
                    let wait = self.control.config().goal_wait;
                    let led = self.obstacle_led(index);
                    tracing::warn!("goal inside obstacle LED {led}'s planning circle for {wait} s: stopping");
                    self.stop(now, StopReason::GoalBlocked);
                }
                StepStatus::Invalid(e) => {
                    self.counters.planner_invalid += 1;
                    match e {
                        crate::planner::PlannerError::InsideObstacle { index }
                        | crate::planner::PlannerError::GoalInsideObstacle { index }
                        | crate::planner::PlannerError::BadRadius { index } => {
                            tracing::error!("planner: {e} (obstacle LED {})", self.obstacle_led(index));
                        }
                        _ => tracing::error!("planner: {e}"),
                    }
                    self.stop(now, StopReason::PlannerInvalid);
                }
            }
        }
        let plan_ns = self.clock.now_ns().saturating_sub(plan_start);
        // Commands go out in Running (motion), Armed and Stopping (zero, keeping the
        // enabled board's command timeout fed).
        if !matches!(self.state(), State::Running | State::Armed | State::Stopping(_)) {
            return;
        }
        self.tracker.commanded(t, wheels.0, wheels.1);
        let record = CycleRecord {
            decode_ns,
            checks_ns,
            track_ns,
            plan_ns,
            ..self.record(now, frame_no, end, pulses, delay, pose.position)
        };
        self.command(now, pulses, record, pose.position);
    }

    /// The LED of the obstacle the planner and the supervisor call `index` (they number
    /// the tracked obstacles only).
    fn obstacle_led(&self, index: usize) -> u8 {
        self.tracker.tracked().nth(index).map_or(u8::MAX, |k| self.rig.obstacles[k].led)
    }

    /// A cycle's record, its stage timings left at zero.
    fn record(
        &mut self,
        now: HostTime,
        frame: u32,
        end: CtrlTime,
        pulses: [i32; 2],
        delay: f64,
        at: Point,
    ) -> CycleRecord {
        CycleRecord {
            cycle: self.counters.cycles,
            frame,
            t_ctrl_us: end.0,
            rx_ns: now.as_nanos(),
            period_ns: self.last_command.map_or(0, |lc| now.since(lc).as_nanos() as u64),
            delay_s: delay,
            state: self.state(),
            pulses,
            x: at.re,
            y: at.im,
            goal_distance: (self.control.config().goal - at).norm(),
            ..CycleRecord::default()
        }
    }

    /// A goal is reached: on to the next in the queue, or stop.
    fn goal_reached(&mut self, now: HostTime) {
        self.goals.pop_front();
        match self.goals.front() {
            Some(next) => {
                tracing::info!("goal reached; next goal ({}, {})", next.position[0], next.position[1]);
                self.control.set_goal(Point::new(next.position[0], next.position[1]), next.tolerance);
            }
            None => {
                self.start_requested = false;
                self.stop(now, StopReason::GoalReached);
            }
        }
    }

    /// The frame's samples into the tracker, in floor coordinates on the host clock. A
    /// sample stamped after `now` (beyond a period of clock tolerance) is discarded and
    /// counted: one future stamp would otherwise make every later, true one look old.
    /// Run the cycle's work once on the last state and discard it, so that its code and
    /// data are in cache when the next frame comes (`[realtime] warm_up`: the shell calls it
    /// as each low-latency window opens, about a frame's worth of work ahead). A packet is
    /// encoded and decoded, a point calibrated, the state estimated, the control step
    /// planned and supervised, a velocity frame built. It is not an input: nothing the next
    /// cycle computes depends on it (the tracker's estimate and the plan's field are
    /// scratch, rebuilt every cycle), so a replay without rehearsals is the run's, byte for
    /// byte (`a_rehearsal_changes_nothing`). Only in Running, where cycles plan.
    pub fn rehearse(&mut self, now: HostTime) {
        if !self.safety.state().may_move() {
            return;
        }
        let sample = flowgate_protocol::psd::Sample {
            frame: 0,
            slot: 0,
            led: self.rig.robot_front,
            t_ctrl_us: 0,
            x: 0,
            y: 0,
            intensity: 0,
            flags: flowgate_protocol::psd::SampleFlags(0),
        };
        let mut wire = [0u8; flowgate_protocol::psd::MAX_WIRE_LEN];
        if let Ok(n) = Packet::new(0, Message::Sample(sample)).encode(&mut wire) {
            // Without its closing `0x00`, as the stream hands a frame over.
            let _ = std::hint::black_box(Packet::decode(&wire[..n - 1]));
        }
        std::hint::black_box(self.rig.calibration.to_floor(0.0, 0.0));
        let (period, wheel_base) = (self.rig.sample_period.as_secs_f64(), self.rig.control.drive.wheel_base);
        if let Some(tracked) = self.tracker.estimate(now.secs(), period, wheel_base) {
            self.control.rehearse(&tracked.estimate);
        }
        match &self.cia402 {
            None => {
                let message = MotorMessage::Velocity { node: self.rig.node, left: 0, right: 0, seq: self.velocity_seq };
                let _ = std::hint::black_box(message.to_frame());
            }
            Some(m) => m.rehearse(),
        }
    }

    /// The motors follow commands: the board Enabled, or both drives in operation enabled.
    fn motors_ready(&self) -> bool {
        match &self.cia402 {
            None => self.board.state == Some(BoardState::Enabled),
            Some(m) => m.ready(),
        }
    }

    fn track_frame(&mut self, now: HostTime) {
        let clock = self.psd.clock();
        let latest = now + self.rig.sample_period;
        for slot in self.rig.schedule.slots() {
            let entry = &mut self.frame[usize::from(slot.led)];
            if entry.is_some_and(|s| clock.to_host(s.at) > latest) {
                *entry = None;
                self.counters.samples_from_future += 1;
                if slot.led == self.rig.robot_front || slot.led == self.rig.robot_rear {
                    self.robot_from_future = Some(now);
                }
            }
        }
        let cal = &self.rig.calibration;
        let floor = |s: RawSample| {
            let p = cal.to_floor(f64::from(s.x), f64::from(s.y))?;
            Some((p, clock.to_host(s.at).secs()))
        };
        let usable = |led: u8| self.frame[usize::from(led)].filter(|s| s.usable);
        if let (Some(f), Some(r)) = (usable(self.rig.robot_front), usable(self.rig.robot_rear)) {
            if let (Some((fp, _)), Some((rp, _))) = (floor(f), floor(r)) {
                let at = clock.to_host(f.at.midpoint(r.at)).secs();
                let reach = self.rig.control.drive.max_wheel_speed;
                match self.tracker.plausible(at, fp, rp, reach, self.rig.safety.pose_tolerance) {
                    Ok(()) => {
                        self.implausible = None;
                        self.robot_arrived = now;
                        self.tracker.observe_robot(at, fp, rp);
                    }
                    Err(e) => {
                        self.counters.poses_implausible += 1;
                        if self.implausible.is_none() {
                            tracing::warn!("robot pose discarded: {e}");
                        }
                        self.implausible = Some(e);
                    }
                }
            }
        }
        let t = now.secs();
        for (k, o) in self.rig.obstacles.iter().enumerate() {
            let tracked = self.tracker.obstacle_time(k).is_some();
            if let Some((p, at)) = usable(o.led).and_then(floor) {
                if self.tracker.observe_obstacle(k, at, p) && !tracked {
                    self.counters.obstacles_entered_view += 1;
                    tracing::info!(
                        led = o.led,
                        "obstacle LED {} came into view at ({:.3}, {:.3}) m",
                        o.led,
                        p.re,
                        p.im
                    );
                }
            } else if self.tracker.obstacle_occluded(k, t) {
                // Unseen past the pose timeout: gone out of the view if its filter carries it
                // beyond the edge by now (it was at the edge, heading out); otherwise occluded,
                // and avoided as a region until it is seen again or the timeout faults.
                let beyond = self.tracker.obstacle_prediction(k, t).is_some_and(|p| !cal.in_view(p));
                if beyond {
                    self.tracker.drop_obstacle(k);
                    self.counters.obstacles_left_view += 1;
                    tracing::info!(led = o.led, "obstacle LED {} left the view: track dropped", o.led);
                }
            }
        }
        self.clear_frame();
    }

    fn command(&mut self, now: HostTime, pulses: [i32; 2], mut record: CycleRecord, position: Point) {
        // Until both CiA 402 drives are in operation enabled, the state machine's controlwords
        // alone go to them: a cycle's enable-operation RPDO would jump a step (or undo one).
        if self.cia402.as_ref().is_some_and(|m| !m.ready()) {
            return;
        }
        let encode_start = self.clock.now_ns();
        let frame = match &self.cia402 {
            None => {
                let (node, seq) = (self.rig.node, self.velocity_seq);
                MotorMessage::Velocity { node, left: pulses[0], right: pulses[1], seq }.to_frame().ok()
            }
            // One RPDO a drive: the left one goes first, the cycle's record closes on the right.
            Some(m) => match m.command(pulses) {
                [Some(left), right @ Some(_)] => {
                    self.out.push_back(Output::Can(left));
                    right
                }
                _ => None,
            },
        };
        self.velocity_seq = self.velocity_seq.wrapping_add(1);
        record.encode_ns = self.clock.now_ns().saturating_sub(encode_start);
        let Some(frame) = frame else {
            // Pulse rates come from the drive model clamped to the wheel limit, which the
            // config keeps in range; a frame that cannot be built is a planner fault.
            self.stop(now, StopReason::PlannerInvalid);
            return;
        };
        self.last_command = Some(now);
        self.counters.cycles += 1;
        self.progress.t = now.secs();
        self.progress.cycles = self.counters.cycles;
        self.progress.goal_distance = (self.control.config().goal - position).norm();
        self.out.push_back(Output::Command { frame, record });
    }

    fn can_frame(&mut self, now: HostTime, frame: &CanFrame) {
        self.counters.can_frames_in += 1;
        if let Some(m) = &mut self.cia402 {
            let active = is_active(self.safety.state());
            let out = &mut self.out;
            let (heard, stop) = m.frame(now, frame, active, &mut |f| out.push_back(Output::Can(f)));
            match heard {
                Heard::Ours => {}
                Heard::Foreign => self.counters.can_foreign += 1,
                Heard::Undecodable => self.counters.can_undecodable += 1,
            }
            if let Some(reason) = stop {
                if let StopReason::DriveSecondMaster { .. } = reason {
                    self.second_master_heard = Some(now);
                }
                self.stop(now, reason);
            }
            self.check_at_rest(now);
            return;
        }
        match MotorMessage::parse(frame) {
            Ok(m) if m.node() == Some(self.rig.node) => match m {
                MotorMessage::Heartbeat { state, .. } => {
                    self.board.last_heartbeat = Some(now);
                    self.board.state = Some(state);
                    if state == BoardState::BootUp && is_active(self.state()) {
                        self.stop(now, StopReason::BoardReboot { node: self.rig.node.get() });
                    }
                }
                MotorMessage::Velocity { .. } => {
                    // We never hear our own commands: this one is another device's.
                    self.second_master_heard = Some(now);
                    self.stop(now, StopReason::SecondMaster { node: self.rig.node.get() });
                }
                MotorMessage::Status { state, faults, seq_errors, .. } => {
                    let before = self.board.seq_errors.replace(seq_errors);
                    if let Some(before) = before {
                        let new = seq_errors.wrapping_sub(before);
                        self.counters.board_seq_errors += u64::from(new);
                        // Each counts against the budget: a lossy bus or another sender.
                        let exceeded = (0..new).fold(false, |over, _| self.board_seq.exceeded(now) | over);
                        if exceeded && is_active(self.state()) {
                            self.stop(now, StopReason::BoardSequence { node: self.rig.node.get() });
                        }
                    }
                    self.board.state = Some(state);
                    self.board.faults = faults;
                    // Just armed, a status older than the enable (and the fault reset before
                    // it) may still show the board as it was.
                    let settled = self.state() != State::Armed || now >= self.enable_sent + ENABLE_GRACE;
                    let node = self.rig.node.get();
                    let latched = if faults.contains(FaultBits::ESTOP_INPUT) {
                        StopReason::BoardEStop { node }
                    } else {
                        StopReason::BoardFault { node }
                    };
                    if faults.contains(FaultBits::BUS) && is_active(self.state()) && settled {
                        self.stop(now, StopReason::BoardBusOff { node });
                    } else if self.state() == State::Running && matches!(state, BoardState::Fault | BoardState::EStop) {
                        self.stop(now, latched);
                    } else if self.state() == State::Armed && now >= self.enable_sent + ENABLE_GRACE {
                        // A status older than the enable may still show the board as it was.
                        match state {
                            BoardState::Fault | BoardState::EStop => self.stop(now, latched),
                            BoardState::Disabled => self.board_still_disabled(now),
                            _ => {}
                        }
                    }
                }
                MotorMessage::AxisRates { left, right, .. } => {
                    self.board.rates = [left, right];
                    self.check_at_rest(now);
                }
                _ => {}
            },
            Ok(MotorMessage::GatewayHeartbeat { .. }) => {}
            Ok(m) if m.node().is_some() => self.counters.can_foreign += 1,
            Ok(_) => {}
            Err(_) => self.counters.can_undecodable += 1,
        }
    }

    /// Armed, but the board reports Disabled: the enable (or its config) was lost on the bus.
    /// Send them again, a status period's grace apart, a few times; then fault, named: an
    /// armed gateway must not wait silently for a board that never enables.
    fn board_still_disabled(&mut self, now: HostTime) {
        if self.enable_retries >= ENABLE_RETRIES {
            self.stop(now, StopReason::BoardNotEnabled { node: self.rig.node.get() });
            return;
        }
        self.enable_retries += 1;
        self.counters.board_enable_retries += 1;
        self.act(now, Action::EnableBoard);
    }

    fn check_at_rest(&mut self, now: HostTime) {
        if let (State::Stopping(_), Some(since)) = (self.state(), self.stopping_since) {
            let at_rest = match &self.cia402 {
                None => self.board.rates == [0, 0],
                Some(m) => m.at_rest(),
            };
            if at_rest || now >= since + STOP_GRACE {
                self.safety.at_rest(now.secs());
                self.stopping_since = None;
                match &mut self.cia402 {
                    None => self
                        .send(MotorMessage::Nmt { target: Target::Node(self.rig.node), command: NmtCommand::Disable }),
                    Some(m) => {
                        let out = &mut self.out;
                        m.disable(self.shutdown, &mut |f| out.push_back(Output::Can(f)));
                    }
                }
                self.state_changed(now);
            }
        }
    }

    fn stop(&mut self, now: HostTime, reason: StopReason) {
        let action = self.safety.stop(now.secs(), reason);
        self.act(now, action);
    }

    /// Carry out what a transition asks of the motor side.
    fn act(&mut self, now: HostTime, action: Action) {
        let node = self.rig.node;
        match action {
            Action::None => {}
            Action::EnableBoard if self.cia402.is_some() => {
                self.enable_sent = now;
                if let Some(m) = &mut self.cia402 {
                    let out = &mut self.out;
                    m.arm(now, &mut |f| out.push_back(Output::Can(f)));
                }
            }
            Action::EnableBoard => {
                self.enable_sent = now;
                let b = self.rig.board;
                self.send(MotorMessage::Nmt { target: Target::Node(node), command: NmtCommand::FaultReset });
                self.send(MotorMessage::Config {
                    node,
                    accel: b.accel,
                    max_rate: b.max_rate,
                    timeout_ms: b.command_timeout_ms,
                });
                self.send(MotorMessage::Nmt { target: Target::Node(node), command: NmtCommand::Enable });
                self.last_command = Some(now);
            }
            Action::OrderlyStop => self.stopping_since = Some(now),
            Action::EmergencyStop => {
                let reason = if self.state() == State::Fault(StopReason::OperatorEStop) {
                    EStopReason::Operator
                } else {
                    EStopReason::GatewayFault
                };
                match &mut self.cia402 {
                    None => self.send(MotorMessage::EStop { target: Target::Node(node), reason }),
                    Some(m) => {
                        let out = &mut self.out;
                        m.quick_stop(&mut |f| out.push_back(Output::Can(f)));
                    }
                }
                self.stopping_since = None;
                self.tracker.forget_pose();
                self.tracker.halted(); // the boards stop at once: dead reckoning starts from rest
                tracing::warn!("emergency stop: {}", self.state());
            }
        }
        self.state_changed(now);
    }

    fn state_changed(&mut self, now: HostTime) {
        let state = self.state();
        if self.progress.state != state {
            self.progress.state = state;
            self.out.push_back(Output::State { at: now, state });
        }
    }

    fn send(&mut self, message: MotorMessage) {
        // The gateway's own messages are built from validated settings and are in range.
        if let Ok(frame) = message.to_frame() {
            self.out.push_back(Output::Can(frame));
        }
    }
}

/// States in which the watchdogs are armed.
fn is_active(state: State) -> bool {
    matches!(state, State::Armed | State::Running | State::Stopping(_))
}

#[cfg(test)]
mod tests {
    //! The core driven by hand, byte by byte and in virtual time: no simulator, no I/O.

    use flowgate_protocol::psd::{Info, Sample, SampleFlags, MAX_WIRE_LEN};

    use super::*;
    use crate::config::GatewayConfig;

    const CTRL_EPOCH_US: u64 = 5_000_000; // the controller booted 5 s before us

    fn core() -> Core<NoClock> {
        let text = include_str!("../../../rig.example.toml");
        Core::new(GatewayConfig::from_toml(text, "rig").unwrap().rig("rig").unwrap(), NoClock)
    }

    /// An obstacle LED not seen is absent: the arm proceeds, unless the LED is required.
    #[test]
    fn a_required_obstacle_led_not_seen_refuses_the_arm_by_name() {
        let mut c = core();
        assert_eq!(c.request(ms(1), &Request::Arm), Ok(()));
        let text = include_str!("../../../rig.example.toml").replacen(
            "{ led = 4, radius = 0.07 }",
            "{ led = 4, radius = 0.07, required = true }",
            1,
        );
        let mut c = Core::new(GatewayConfig::from_toml(&text, "rig").unwrap().rig("rig").unwrap(), NoClock);
        let refusal = c.request(ms(1), &Request::Arm).unwrap_err();
        assert_eq!(refusal, Refusal::RequiredObstacleUnseen { led: 4, index: 1 });
        assert_eq!(
            refusal.to_string(),
            "obstacle LED 4 is required (leds.obstacles[1].required) and has not been seen"
        );
        assert_eq!(c.state(), State::Idle);
    }

    /// Every byte thrown away is counted: a whole megabyte with no delimiter (and the
    /// delimiter that ends it), a garbled frame's bytes with its delimiter.
    #[test]
    fn every_discarded_byte_is_counted() {
        let mut c = core();
        c.psd_connected(ms(0));
        let mut run = vec![0x55u8; 1 << 20];
        run.push(0);
        for chunk in run.chunks(1024) {
            c.psd_bytes(ms(1), chunk);
        }
        assert_eq!(c.counters().serial_dropped_bytes, (1 << 20) + 1);
        assert_eq!(c.counters().bad_serial_frames, 1);
        let mut garbled =
            bytes(Message::Heartbeat { t_ctrl_us: 5, state: flowgate_protocol::psd::ControllerState::Streaming });
        let i = garbled.len() - 3;
        garbled[i] ^= if garbled[i] == 0x80 { 0x40 } else { 0x80 };
        c.psd_bytes(ms(2), &garbled);
        assert_eq!(c.counters().serial_dropped_bytes, (1 << 20) + 1 + garbled.len() as u64);
        assert_eq!(c.counters().bad_serial_frames, 2);
    }

    /// A SocketCAN interface that goes down is named as such (not bus-off), and its fault
    /// cannot be reset until the link is open again.
    #[test]
    fn an_interface_gone_down_is_named_and_held_until_the_link_reopens() {
        let mut c = core();
        c.request(ms(1), &Request::Arm).unwrap();
        c.can_event(ms(2), CanEvent::InterfaceDown);
        assert_eq!(c.state(), State::Fault(StopReason::CanInterfaceDown));
        assert_eq!(StopReason::CanInterfaceDown.to_string(), "CAN interface went down");
        assert_eq!(c.request(ms(3), &Request::Reset), Err(Refusal::CauseStillPresent(StopReason::CanInterfaceDown)));
        c.can_reopened();
        assert_eq!(c.request(ms(4), &Request::Reset), Ok(()));
        assert_eq!(c.state(), State::Idle);
    }

    fn ms(v: u64) -> HostTime {
        HostTime::from_nanos(v * 1_000_000)
    }

    /// The controller's packets, numbered in order as its firmware does.
    fn bytes(message: Message) -> Vec<u8> {
        use std::sync::atomic::{AtomicU16, Ordering};
        static SEQ: AtomicU16 = AtomicU16::new(0);
        let mut wire = [0u8; MAX_WIRE_LEN];
        let n = Packet::new(SEQ.fetch_add(1, Ordering::Relaxed), message).encode(&mut wire).unwrap();
        wire[..n].to_vec()
    }

    /// Answer every request the core has queued, as a controller would, at `now`.
    fn answer(core: &mut Core<NoClock>, now: HostTime) -> Vec<Output> {
        let mut other = Vec::new();
        while let Some(o) = core.poll() {
            let Output::Psd(p) = o else {
                other.push(o);
                continue;
            };
            let reply = match p.message {
                Message::GetInfo => Message::Info {
                    request_seq: p.seq,
                    info: Info { firmware: [1, 0, 0], psd_counts: [4096; 2], max_leds: 16, clock_hz: 1_000_000 },
                },
                Message::TimeSync { host_time_us } => Message::TimeSyncReply {
                    request_seq: p.seq,
                    host_time_us,
                    t_ctrl_us: now.as_nanos() / 1000 + CTRL_EPOCH_US,
                },
                Message::StopStream => continue,
                m => Message::Ack { seq: p.seq, msg_type: m.msg_type() as u8 },
            };
            core.psd_bytes(now, &bytes(reply));
        }
        other
    }

    /// A frame of the robot's two LEDs at the floor origin, stamped `stamp_us` on the
    /// controller's clock.
    fn frame(core: &mut Core<NoClock>, now: HostTime, n: u32, stamp_us: u64) {
        let cal = core.rig().calibration;
        let mut out = Vec::new();
        for (slot, led, x) in [(0u8, 1u8, 0.035), (1, 2, -0.035)] {
            let (rx, ry) = cal.to_raw(Point::new(x, 0.0)).unwrap();
            let s = Sample {
                frame: n,
                slot,
                led,
                t_ctrl_us: stamp_us,
                x: rx.round() as i32,
                y: ry.round() as i32,
                intensity: 3000,
                flags: SampleFlags(0),
            };
            out.extend(bytes(Message::Sample(s)));
        }
        out.extend(bytes(Message::FrameEnd { frame: n, t_ctrl_us: stamp_us, samples: 2 }));
        core.psd_bytes(now, &out);
    }

    #[test]
    fn the_handshake_syncs_the_clock_and_samples_before_it_are_discarded() {
        let mut c = core();
        c.psd_connected(ms(0));
        // A stream already running before the handshake: its stamps mean nothing yet.
        frame(&mut c, ms(1), 0, CTRL_EPOCH_US + 1000);
        assert_eq!(c.counters().samples_unsynced, 3);
        assert_eq!(c.counters().samples, 0);
        let out = answer(&mut c, ms(2));
        assert!(out.contains(&Output::Streaming), "{out:?}");
        assert!(c.psd.is_streaming());
        // Synced: a frame stamped 1 ms ago is a pose 1 ms old.
        frame(&mut c, ms(10), 1, 9_000 + CTRL_EPOCH_US);
        assert_eq!(c.counters().samples, 2);
        let at = c.tracker.pose_time().unwrap();
        assert!((at - 0.009).abs() < 1e-6, "{at}");
    }

    /// Protocol 2: an answer names its request. An Info or a TimeSyncReply that names
    /// another seq (a late answer to an earlier try) is not taken; the matching one is.
    #[test]
    fn replies_naming_another_request_are_not_taken() {
        let mut c = core();
        c.psd_connected(ms(0));
        let mut streaming = false;
        let mut stale_replies = 0;
        for step in 1..20 {
            let now = ms(step);
            let requests: Vec<Packet> = std::iter::from_fn(|| c.poll())
                .filter_map(|o| match o {
                    Output::Psd(p) => Some(p),
                    Output::Streaming => {
                        streaming = true;
                        None
                    }
                    _ => None,
                })
                .collect();
            for p in requests {
                let info = Info { firmware: [1, 0, 0], psd_counts: [4096; 2], max_leds: 16, clock_hz: 1_000_000 };
                let (stale, good) = match p.message {
                    Message::GetInfo => (
                        Message::Info { request_seq: p.seq.wrapping_sub(1), info },
                        Message::Info { request_seq: p.seq, info },
                    ),
                    Message::TimeSync { host_time_us } => {
                        let t_ctrl_us = now.as_nanos() / 1000 + CTRL_EPOCH_US;
                        (
                            Message::TimeSyncReply { request_seq: p.seq.wrapping_add(7), host_time_us, t_ctrl_us },
                            Message::TimeSyncReply { request_seq: p.seq, host_time_us, t_ctrl_us },
                        )
                    }
                    m => {
                        c.psd_bytes(now, &bytes(Message::Ack { seq: p.seq, msg_type: m.msg_type() as u8 }));
                        continue;
                    }
                };
                // The stale answer alone moves nothing on; the true one does.
                // The handshake's step and the clock offset, as the session shows them.
                let phase = |c: &Core<NoClock>| {
                    let d = format!("{:?}", c.psd);
                    d[d.find("phase:").unwrap()..d.find(", info:").unwrap()].to_string()
                };
                let before = phase(&c);
                c.psd_bytes(now, &bytes(stale));
                assert_eq!(before, phase(&c), "a reply naming another request was taken");
                stale_replies += 1;
                c.psd_bytes(now, &bytes(good));
            }
        }
        assert!(streaming && stale_replies == 2, "{stale_replies}");
    }

    #[test]
    fn a_future_stamp_is_discarded_and_does_not_freeze_the_pose() {
        let mut c = core();
        c.psd_connected(ms(0));
        answer(&mut c, ms(1));
        frame(&mut c, ms(20), 0, CTRL_EPOCH_US + 19_000);
        // CRC-valid, stamped an hour ahead.
        frame(&mut c, ms(40), 1, CTRL_EPOCH_US + 3_600_000_000);
        assert_eq!(c.counters().samples_from_future, 2);
        frame(&mut c, ms(60), 2, CTRL_EPOCH_US + 59_000);
        let at = c.tracker.pose_time().unwrap();
        assert!((at - 0.059).abs() < 1e-6, "the true pose is taken: {at}");
    }

    #[test]
    fn a_silent_controller_fails_the_handshake_after_three_tries() {
        let mut c = core();
        c.psd_connected(ms(0));
        let mut failed = None;
        let mut now = ms(0);
        while failed.is_none() && now < ms(5000) {
            now = c.next_deadline();
            c.tick(now);
            while let Some(o) = c.poll() {
                if let Output::SetupFailed(e) = o {
                    failed = Some((now, e));
                }
            }
        }
        let (at, e) = failed.expect("gave up");
        assert_eq!(e, SetupError::Silent { request: "GetInfo" });
        assert_eq!(at, ms(1050), "three tries, 350 ms apart");
    }

    #[test]
    fn watchdogs_fire_at_their_deadline() {
        let mut c = core();
        c.psd_connected(ms(0));
        answer(&mut c, ms(1));
        c.request(ms(1), &Request::Arm).unwrap();
        let expected = ms(1) + c.rig().safety.sample_timeout;
        assert!(c.next_deadline() <= expected);
        let mut now = ms(1);
        while c.state() == State::Armed {
            now = c.next_deadline();
            c.tick(now);
        }
        // The first to expire: the board's heartbeat (never heard) or the samples.
        assert!(matches!(c.state(), State::Fault(StopReason::SamplesStopped | StopReason::HeartbeatLost { .. })));
        assert!(now <= expected, "{now} vs {expected}");
    }

    fn commands(c: &mut Core<NoClock>) -> usize {
        let mut n = 0;
        while let Some(o) = c.poll() {
            n += usize::from(matches!(o, Output::Command { .. }));
        }
        n
    }

    /// The same frame twice (same packets, same frame counter, as a line echoing itself):
    /// one command, the copy discarded and counted.
    #[test]
    fn a_duplicated_frame_gives_one_command() {
        let mut c = core();
        c.psd_connected(ms(0));
        answer(&mut c, ms(1));
        c.request(ms(1), &Request::Arm).unwrap();
        commands(&mut c);
        let cal = c.rig().calibration;
        let sample = |slot: u8, led: u8, x: f64| {
            let (rx, ry) = cal.to_raw(Point::new(x, 0.0)).unwrap();
            Message::Sample(Sample {
                frame: 7,
                slot,
                led,
                t_ctrl_us: CTRL_EPOCH_US + 19_000,
                x: rx.round() as i32,
                y: ry.round() as i32,
                intensity: 3000,
                flags: SampleFlags(0),
            })
        };
        let mut wire = Vec::new();
        for m in [
            sample(0, 1, 0.035),
            sample(1, 2, -0.035),
            Message::FrameEnd { frame: 7, t_ctrl_us: CTRL_EPOCH_US + 19_000, samples: 2 },
        ] {
            wire.extend(bytes(m));
        }
        c.psd_bytes(ms(20), &wire);
        c.psd_bytes(ms(20), &wire);
        assert_eq!(commands(&mut c), 1, "one command for one frame");
        // The copy of the block: its last packet repeats the last one seen, the two before
        // it are behind it.
        assert_eq!((c.counters().psd_duplicates, c.counters().psd_out_of_order), (1, 2));
        // The same frame again under new sequence numbers (a replayed frame): still no command.
        for m in [
            sample(0, 1, 0.035),
            sample(1, 2, -0.035),
            Message::FrameEnd { frame: 7, t_ctrl_us: CTRL_EPOCH_US + 19_000, samples: 2 },
        ] {
            c.psd_bytes(ms(21), &bytes(m));
        }
        assert_eq!(commands(&mut c), 0);
        assert_eq!(c.counters().frames_repeated, 1);
    }

    /// Samples from an LED or slot outside the schedule are discarded; a sample of another
    /// frame is not used for this one; gaps in frames and packets are counted.
    #[test]
    fn samples_are_checked_against_the_schedule_and_their_frame() {
        let mut c = core();
        c.psd_connected(ms(0));
        answer(&mut c, ms(1));
        let stray = |frame: u32, slot: u8, led: u8| {
            Message::Sample(Sample {
                frame,
                slot,
                led,
                t_ctrl_us: CTRL_EPOCH_US + 1_000,
                x: 0,
                y: 0,
                intensity: 3000,
                flags: SampleFlags(0),
            })
        };
        c.psd_bytes(ms(2), &bytes(stray(0, 0, 9))); // LED 9 is not scheduled
        c.psd_bytes(ms(2), &bytes(stray(0, 1, 1))); // LED 1 is slot 0, not 1
        assert_eq!(c.counters().samples_unscheduled, 2);
        assert_eq!(c.counters().samples, 0);
        c.psd_bytes(ms(3), &bytes(stray(4, 0, 1))); // a sample of frame 4 ...
        c.psd_bytes(ms(3), &bytes(Message::FrameEnd { frame: 5, t_ctrl_us: CTRL_EPOCH_US + 2_000, samples: 2 })); // ... ended as 5
        assert_eq!(c.counters().frames_lost, 1);
        assert_eq!(c.counters().frames_incomplete, 1);
        assert!(c.tracker.pose_time().is_none(), "no pose from another frame's sample");
        frame(&mut c, ms(40), 9, CTRL_EPOCH_US + 39_000);
        assert_eq!(c.counters().frames_lost, 1 + 3, "frames 6, 7 and 8 never came");
    }

    /// A controller that cannot run the schedule (here: 2 LEDs for a schedule of 4) is not
    /// the configured one: the handshake fails, naming why.
    #[test]
    fn a_controller_of_another_kind_is_refused_at_the_handshake() {
        let mut c = core();
        c.psd_connected(ms(0));
        let mut failed = None;
        while let Some(o) = c.poll() {
            if let Output::Psd(Packet { seq, message: Message::GetInfo }) = o {
                let info = Info { firmware: [1, 0, 0], psd_counts: [4096; 2], max_leds: 2, clock_hz: 1_000_000 };
                c.psd_bytes(ms(1), &bytes(Message::Info { request_seq: seq, info }));
            }
            if let Output::SetupFailed(e) = o {
                failed = Some(e);
            }
        }
        let e = failed.expect("refused");
        assert_eq!(
            e.to_string(),
            "PSD controller is not the one configured: it drives fewer LEDs than the schedule has"
        );
    }
}
