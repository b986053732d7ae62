//! The gateway's side of one PCL-80K-like board driving both wheels: what it sends (enable,
//! configuration, velocity commands, heartbeats, e-stop), and what its frames tell the core
//! (heartbeat, status with latched faults and sequence errors, axis rates).
//!
//! The board stops by itself when commands stop coming (its command timeout): an enabled but
//! idle board is fed zero commands ([`BoardMaster::keep_alive_due`]).

use std::time::Duration;

use flowgate_protocol::motor::NodeId;
use flowgate_protocol::motor::{BoardState, EStopReason, FaultBits, MotorMessage, NmtCommand, Target};
use flowgate_protocol::CanFrame;

use super::FrameEffect;
use super::MotorCounters;
use crate::config::BoardSettings;
use crate::gateway::core::budget::Budget;
use crate::gateway::core::safety::{State, StopReason};
use crate::time::HostTime;

/// How long an armed gateway waits for the board to report Enabled before it sends the
/// enable again (two status periods), and how many times it does.
const ENABLE_GRACE: Duration = Duration::from_millis(100);
const ENABLE_RETRIES: u8 = 3;
/// Sequence errors the board may count within a second (1% loss at 1 kHz is 10).
const BOARD_SEQ_ERRORS_PER_S: u32 = 10;

/// The board as the gateway knows it, and what the gateway last sent it.
#[derive(Debug)]
pub struct BoardMaster {
    node: NodeId,
    settings: BoardSettings,
    last_heartbeat: Option<HostTime>,
    state: Option<BoardState>,
    faults: FaultBits,
    rates: [i32; 2],
    /// The board's own count of sequence errors, as last reported.
    seq_errors: Option<u8>,
    /// Sequence errors the board counted (lost or foreign velocity commands), per second.
    seq_budget: Budget,
    /// When the board was last told to enable, and how often again since arming.
    enable_sent: HostTime,
    enable_retries: u8,
    velocity_seq: u8,
}

impl BoardMaster {
    pub fn new(node: NodeId, settings: BoardSettings) -> Self {
        Self {
            node,
            settings,
            last_heartbeat: None,
            state: None,
            faults: FaultBits::default(),
            rates: [0; 2],
            seq_errors: None,
            seq_budget: Budget::new(BOARD_SEQ_ERRORS_PER_S),
            enable_sent: HostTime::ZERO,
            enable_retries: 0,
            velocity_seq: 0,
        }
    }

    /// Whether `frame` is one of this board's (from it, or to it).
    pub fn addresses(&self, frame: &CanFrame) -> bool {
        MotorMessage::parse(frame).is_ok_and(|m| m.node() == Some(self.node))
    }

    pub fn command_timeout_ms(&self) -> u16 {
        self.settings.command_timeout_ms
    }

    pub fn node(&self) -> NodeId {
        self.node
    }

    pub fn last_heartbeat(&self) -> Option<HostTime> {
        self.last_heartbeat
    }

    pub fn ready(&self) -> bool {
        self.state == Some(BoardState::Enabled)
    }

    pub fn at_rest(&self) -> bool {
        self.rates == [0, 0]
    }

    /// The operator armed: the retries and the heartbeat are counted afresh.
    pub fn armed(&mut self) {
        self.enable_retries = 0;
        self.last_heartbeat = None;
    }

    /// Reset faults, configure and enable.
    pub fn enable(&mut self, now: HostTime, send: &mut impl FnMut(CanFrame)) {
        self.enable_sent = now;
        let (node, b) = (self.node, self.settings);
        emit(send, MotorMessage::Nmt { target: Target::Node(node), command: NmtCommand::FaultReset });
        emit(
            send,
            MotorMessage::Config { node, accel: b.accel, max_rate: b.max_rate, timeout_ms: b.command_timeout_ms },
        );
        emit(send, MotorMessage::Nmt { target: Target::Node(node), command: NmtCommand::Enable });
    }

    pub fn emergency_stop(&mut self, reason: EStopReason, send: &mut impl FnMut(CanFrame)) {
        emit(send, MotorMessage::EStop { target: Target::Node(self.node), reason });
    }

    pub fn disable(&mut self, send: &mut impl FnMut(CanFrame)) {
        emit(send, MotorMessage::Nmt { target: Target::Node(self.node), command: NmtCommand::Disable });
    }

    pub fn fault_reset(&mut self, send: &mut impl FnMut(CanFrame)) {
        emit(send, MotorMessage::Nmt { target: Target::Node(self.node), command: NmtCommand::FaultReset });
    }

    pub fn heartbeat(&mut self, state: State, send: &mut impl FnMut(CanFrame)) {
        emit(send, MotorMessage::GatewayHeartbeat { state: state.wire() });
    }

    /// A cycle's velocity command (`None` if it cannot be built: a planner fault).
    pub fn command(&mut self, pulses: [i32; 2]) -> Option<CanFrame> {
        let seq = self.next_seq();
        MotorMessage::Velocity { node: self.node, left: pulses[0], right: pulses[1], seq }.to_frame().ok()
    }

    /// A zero command that keeps the board's command timeout from firing.
    pub fn keep_alive(&mut self, send: &mut impl FnMut(CanFrame)) {
        let seq = self.next_seq();
        emit(send, MotorMessage::Velocity { node: self.node, left: 0, right: 0, seq });
    }

    /// When an enabled but idle board needs its zero command: half its timeout after the
    /// last command.
    pub fn keep_alive_due(&self, last_command: Option<HostTime>) -> Option<HostTime> {
        let half = Duration::from_millis(u64::from(self.settings.command_timeout_ms)) / 2;
        last_command.map(|last| last + half)
    }

    pub fn rehearse(&self) {
        let message = MotorMessage::Velocity { node: self.node, left: 0, right: 0, seq: self.velocity_seq };
        let _ = std::hint::black_box(message.to_frame());
    }

    fn next_seq(&mut self) -> u8 {
        let seq = self.velocity_seq;
        self.velocity_seq = seq.wrapping_add(1);
        seq
    }

    /// Whether the board still latches the fault bit behind `reason`.
    pub fn latched(&self, reason: StopReason) -> bool {
        match reason {
            // The board refuses to leave its e-stop while its input is open; so does the gateway.
            StopReason::BoardEStop { .. } => self.faults.contains(FaultBits::ESTOP_INPUT),
            _ => false,
        }
    }

    /// A frame from the bus at `now`, in gateway state `state`.
    pub fn frame(
        &mut self,
        now: HostTime,
        frame: &CanFrame,
        state: State,
        counters: &mut MotorCounters,
    ) -> FrameEffect {
        let mut effect = FrameEffect::default();
        let node = self.node.get();
        match MotorMessage::parse(frame) {
            Ok(m) if m.node() == Some(self.node) => match m {
                MotorMessage::Heartbeat { state: board, .. } => {
                    // Booted while being enabled (powered up with the gateway, its boot-up
                    // heard after the arm): it missed the enable and nothing moves yet, so it
                    // is enabled afresh. Once it has reported Enabled, a boot-up is a reboot.
                    let enabling = state == State::Armed && self.state != Some(BoardState::Enabled);
                    self.last_heartbeat = Some(now);
                    self.state = Some(board);
                    if board == BoardState::BootUp && enabling {
                        effect.enable_again = true;
                    } else if board == BoardState::BootUp && state.is_active() {
                        effect.stop = Some(StopReason::BoardReboot { node });
                    }
                }
                MotorMessage::Velocity { .. } => {
                    // We never hear our own commands: this one is another device's.
                    effect.second_master = true;
                    effect.stop = Some(StopReason::SecondMaster { node });
                }
                MotorMessage::Status { state: board, faults, seq_errors, .. } => {
                    effect = self.status(now, state, board, faults, seq_errors, counters);
                }
                MotorMessage::AxisRates { left, right, .. } => {
                    self.rates = [left, right];
                    effect.settle = true;
                }
                _ => {}
            },
            Ok(MotorMessage::GatewayHeartbeat { .. }) => {}
            Ok(m) if m.node().is_some() => counters.foreign += 1,
            Ok(_) => {}
            Err(_) => counters.undecodable += 1,
        }
        effect
    }

    /// The board's status: its sequence errors against the budget, its latched faults, and
    /// whether an armed board enabled.
    fn status(
        &mut self,
        now: HostTime,
        state: State,
        board: BoardState,
        faults: FaultBits,
        seq_errors: u8,
        counters: &mut MotorCounters,
    ) -> FrameEffect {
        let node = self.node.get();
        let mut effect = FrameEffect::default();
        if let Some(before) = self.seq_errors.replace(seq_errors) {
            let new = seq_errors.wrapping_sub(before);
            counters.board_seq_errors += u64::from(new);
            // Each counts against the budget: a lossy bus or another sender.
            let exceeded = (0..new).fold(false, |over, _| self.seq_budget.exceeded(now) | over);
            if exceeded && state.is_active() {
                // A fault: nothing below can change the state after it.
                self.state = Some(board);
                self.faults = faults;
                effect.stop = Some(StopReason::BoardSequence { node });
                return effect;
            }
        }
        self.state = Some(board);
        self.faults = faults;
        // Just armed, a status older than the enable (and the fault reset before it) may
        // still show the board as it was.
        let settled = state != State::Armed || now >= self.enable_sent + ENABLE_GRACE;
        let latched = if faults.contains(FaultBits::ESTOP_INPUT) {
            StopReason::BoardEStop { node }
        } else if faults.contains(FaultBits::BUS) {
            StopReason::BoardBusOff { node }
        } else {
            StopReason::BoardFault { node }
        };
        let faulted = matches!(board, BoardState::Fault | BoardState::EStop);
        if faults.contains(FaultBits::BUS) && state.is_active() && settled {
            effect.stop = Some(StopReason::BoardBusOff { node });
        } else if state == State::Running && faulted {
            effect.stop = Some(latched);
        } else if state == State::Armed && settled {
            if faulted {
                effect.stop = Some(latched);
            } else if board == BoardState::Disabled {
                // The enable (or its config) was lost on the bus: sent again a few times,
                // then a named fault: an armed gateway must not wait silently for a board that
                // never enables.
                if self.enable_retries >= ENABLE_RETRIES {
                    effect.stop = Some(StopReason::BoardNotEnabled { node });
                } else {
                    self.enable_retries += 1;
                    counters.board_enable_retries += 1;
                    effect.enable_again = true;
                }
            }
        }
        effect
    }
}

/// The gateway's own messages are built from validated settings and are in range.
fn emit(send: &mut impl FnMut(CanFrame), message: MotorMessage) {
    if let Ok(frame) = message.to_frame() {
        send(frame);
    }
}
