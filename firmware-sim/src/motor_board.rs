//! The pulse-motor board's firmware (PCL-80K-like, two axes), as a state machine: CAN frames
//! in, CAN frames out, time an argument. Its axes are the world's wheels.
//!
//! States: BootUp -> Disabled <-> Enabled; Fault and EStop latch until a fault reset. The
//! board's own e-stop input latches EStop too, and refuses fault resets while it is open.
//! Velocity commands act only when Enabled. The board stops both axes by itself when no
//! velocity command arrives within its command timeout, or when the gateway's heartbeat
//! (once seen) stops for three timeouts.

use flowgate_protocol::motor::{BoardState, FaultBits, MotorMessage, NmtCommand, NodeId};
use flowgate_protocol::CanFrame;

use crate::faults::FaultPlan;
use crate::world::{AxisConfig, World};

/// Period of heartbeat and status frames, s.
pub const HEARTBEAT_PERIOD: f64 = 0.1;
pub const STATUS_PERIOD: f64 = 0.05;
/// Default command timeout, ms.
pub const DEFAULT_TIMEOUT_MS: u16 = 100;

/// Counters of what the board saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BoardCounters {
    pub frames_in: u64,
    pub velocity_commands: u64,
    /// Frames on this board's ids that did not decode.
    pub bad_frames: u64,
}

#[derive(Debug)]
pub struct MotorBoard {
    node: NodeId,
    state: BoardState,
    faults: FaultBits,
    last_seq: Option<u8>,
    seq_errors: u8,
    timeout_ms: u16,
    /// When the last velocity command arrived (or the board was enabled).
    last_command: f64,
    gateway_seen: Option<f64>,
    next_heartbeat: f64,
    next_status: f64,
    plan: FaultPlan,
    board_fault_done: bool,
    reboot_done: bool,
    /// When `poll` last ran (the e-stop input is read there).
    last_poll: f64,
    pub counters: BoardCounters,
}

impl MotorBoard {
    pub fn new(node: NodeId, plan: FaultPlan) -> Self {
        Self {
            node,
            state: BoardState::BootUp,
            faults: FaultBits::default(),
            last_seq: None,
            seq_errors: 0,
            timeout_ms: DEFAULT_TIMEOUT_MS,
            last_command: 0.0,
            gateway_seen: None,
            next_heartbeat: 0.0,
            next_status: 0.0,
            plan,
            board_fault_done: false,
            reboot_done: false,
            last_poll: 0.0,
            counters: BoardCounters::default(),
        }
    }

    pub fn node(&self) -> NodeId {
        self.node
    }
    pub fn state(&self) -> BoardState {
        self.state
    }
    pub fn faults(&self) -> FaultBits {
        self.faults
    }

    fn send(out: &mut Vec<CanFrame>, m: MotorMessage) {
        out.push(m.to_frame().expect("the board's own messages are in range"));
    }

    /// Power on: the boot-up message, then Disabled.
    pub fn boot(&mut self, t: f64, world: &mut World, out: &mut Vec<CanFrame>) {
        world.stop_axes();
        self.state = BoardState::BootUp;
        Self::send(out, MotorMessage::Heartbeat { node: self.node, state: BoardState::BootUp });
        self.state = BoardState::Disabled;
        self.faults = FaultBits::default();
        self.last_seq = None;
        self.seq_errors = 0;
        self.next_heartbeat = t + HEARTBEAT_PERIOD;
        self.next_status = t;
    }

    fn enter_fault(&mut self, bit: u8, state: BoardState, world: &mut World, out: &mut Vec<CanFrame>) {
        world.stop_axes();
        self.faults.0 |= bit;
        if self.state != state {
            self.state = state;
            Self::send(out, MotorMessage::Emergency { node: self.node, faults: self.faults });
        }
    }

    /// A frame from the bus (the board ignores ids that are not for it).
    pub fn handle(&mut self, t: f64, frame: &CanFrame, world: &mut World, out: &mut Vec<CanFrame>) {
        if self.plan.bus_off(t) {
            return;
        }
        self.counters.frames_in += 1;
        let msg = match MotorMessage::parse(frame) {
            Ok(m) => m,
            Err(_) => {
                // A frame on one of our ids that does not decode: count it, never act on it.
                // (An e-stop always decodes: any frame on its id is a stop.)
                if frame.id().raw() & 0x0F == u32::from(self.node.get()) && !frame.id().is_extended() {
                    self.counters.bad_frames += 1;
                }
                return;
            }
        };
        match msg {
            MotorMessage::EStop { target, .. } if target.includes(self.node) => {
                self.enter_fault(FaultBits::ESTOP, BoardState::EStop, world, out);
            }
            MotorMessage::Nmt { target, command } if target.includes(self.node) => match command {
                NmtCommand::Enable if self.state == BoardState::Disabled => {
                    self.state = BoardState::Enabled;
                    self.last_command = t;
                    self.last_seq = None;
                }
                NmtCommand::Disable if self.state == BoardState::Enabled => {
                    world.command_pulse_rates([0, 0]); // ramp down
                    self.state = BoardState::Disabled;
                }
                NmtCommand::Reset => self.boot(t, world, out),
                NmtCommand::FaultReset
                    if matches!(self.state, BoardState::Fault | BoardState::EStop)
                        && !self.faults.contains(FaultBits::ESTOP_INPUT) =>
                {
                    self.faults = FaultBits::default();
                    self.state = BoardState::Disabled;
                }
                _ => {}
            },
            MotorMessage::Velocity { node, left, right, seq } if node == self.node => {
                self.counters.velocity_commands += 1;
                if let Some(last) = self.last_seq {
                    if seq != last.wrapping_add(1) {
                        self.seq_errors = self.seq_errors.wrapping_add(1);
                    }
                }
                self.last_seq = Some(seq);
                if self.state == BoardState::Enabled {
                    self.last_command = t;
                    let max = world.axes()[0].config().max_rate;
                    if f64::from(left.abs()) > max || f64::from(right.abs()) > max {
                        self.faults.0 |= FaultBits::RATE_LIMIT; // clamped by the axes
                    }
                    world.command_pulse_rates([left, right]);
                }
            }
            MotorMessage::Config { node, accel, max_rate, timeout_ms } if node == self.node => {
                world.configure_axes(AxisConfig { accel: f64::from(accel), max_rate: f64::from(max_rate) });
                self.timeout_ms = timeout_ms;
            }
            MotorMessage::GatewayHeartbeat { .. } => self.gateway_seen = Some(t),
            _ => {}
        }
    }

    /// When [`MotorBoard::poll`] next has something to do.
    pub fn next_event(&self) -> f64 {
        let mut next = self.next_heartbeat.min(self.next_status);
        if let (Some(at), false) = (self.plan.board_reboot_at, self.reboot_done) {
            next = next.min(at);
        }
        // A driver fault and a bus-off happen when they happen, not at the next poll.
        if let (Some(at), false) = (self.plan.board_fault_at, self.board_fault_done) {
            next = next.min(at);
        }
        if let Some(at) = self.plan.bus_off_at.filter(|&at| at > self.last_poll) {
            next = next.min(at);
        }
        if self.state == BoardState::Enabled {
            next = next.min(self.last_command + f64::from(self.timeout_ms) * 1e-3);
        }
        // The input is read at every poll: the next edge is an event.
        if let Some(edge) = self.plan.board_estop.into_iter().flatten().find(|&edge| edge > self.last_poll) {
            next = next.min(edge);
        }
        next
    }

    /// Timeouts and periodic frames due by `t`.
    pub fn poll(&mut self, t: f64, world: &mut World, out: &mut Vec<CanFrame>) {
        self.last_poll = t;
        if self.plan.board_estop_open(t) {
            self.enter_fault(FaultBits::ESTOP | FaultBits::ESTOP_INPUT, BoardState::EStop, world, out);
        } else {
            // Closed again: the latch stays until a fault reset.
            self.faults.0 &= !FaultBits::ESTOP_INPUT;
        }
        if let (Some(at), false) = (self.plan.board_reboot_at, self.reboot_done) {
            if t >= at {
                self.reboot_done = true;
                self.boot(t, world, out);
            }
        }
        if let (Some(at), false) = (self.plan.board_fault_at, self.board_fault_done) {
            if t >= at {
                self.board_fault_done = true;
                self.enter_fault(FaultBits::DRIVER, BoardState::Fault, world, out);
            }
        }
        if self.plan.bus_off(t) {
            // A bus-off controller can neither send nor receive (the rig drops what the
            // board would send); the board stops its axes, since it cannot be commanded,
            // and reports BUS once it is back.
            if self.state == BoardState::Enabled {
                world.stop_axes();
                self.faults.0 |= FaultBits::BUS;
                self.state = BoardState::Fault;
            }
            // Its periodic frames fall silent, but their timers run on: `next_event` must
            // not stay in the past.
            while self.next_heartbeat <= t {
                self.next_heartbeat += HEARTBEAT_PERIOD;
            }
            while self.next_status <= t {
                self.next_status += STATUS_PERIOD;
            }
            return;
        }
        let timeout = f64::from(self.timeout_ms) * 1e-3;
        if self.state == BoardState::Enabled && t - self.last_command > timeout {
            self.enter_fault(FaultBits::CMD_TIMEOUT, BoardState::Fault, world, out);
        }
        if let Some(seen) = self.gateway_seen {
            if self.state == BoardState::Enabled && t - seen > 3.0 * timeout.max(HEARTBEAT_PERIOD) {
                self.enter_fault(FaultBits::GATEWAY_LOST, BoardState::Fault, world, out);
            }
        }
        let hb_stopped = self.plan.heartbeat_stopped(t);
        while self.next_heartbeat <= t {
            if !hb_stopped {
                Self::send(out, MotorMessage::Heartbeat { node: self.node, state: self.state });
            }
            self.next_heartbeat += HEARTBEAT_PERIOD;
        }
        while self.next_status <= t {
            let node = self.node;
            let [l, r] = world.axes();
            Self::send(
                out,
                MotorMessage::Status {
                    node,
                    state: self.state,
                    faults: self.faults,
                    last_seq: self.last_seq.unwrap_or(0),
                    seq_errors: self.seq_errors,
                },
            );
            Self::send(
                out,
                MotorMessage::AxisRates { node, left: l.rate().round() as i32, right: r.rate().round() as i32 },
            );
            Self::send(out, MotorMessage::Position { node, left: l.position() as i32, right: r.position() as i32 });
            self.next_status += STATUS_PERIOD;
        }
    }
}

#[cfg(test)]
mod tests {
    //! The board's timings and reactions as protocol/README.md states them.
    use super::*;
    use flowgate_protocol::motor::{EStopReason, GatewayState, NmtCommand, Target};
    use flowgate_protocol::CanId;

    const E1: &str = include_str!("../../scenarios/e1-standing-obstacle.toml");

    fn board() -> (MotorBoard, World, Vec<CanFrame>) {
        let scenario = crate::scenario::SimScenario::from_toml(E1, "e1").unwrap();
        let mut world = World::new(&scenario);
        let mut board = MotorBoard::new(NodeId::new(1).unwrap(), FaultPlan::default());
        let mut out = Vec::new();
        board.boot(0.0, &mut world, &mut out);
        (board, world, out)
    }

    fn messages(out: &mut Vec<CanFrame>) -> Vec<MotorMessage> {
        out.drain(..).filter_map(|f| MotorMessage::parse(&f).ok()).collect()
    }

    fn send(b: &mut MotorBoard, w: &mut World, t: f64, m: MotorMessage, out: &mut Vec<CanFrame>) {
        b.handle(t, &m.to_frame().unwrap(), w, out);
    }

    fn emergency(m: &[MotorMessage], bit: u8) -> bool {
        m.iter().any(|m| matches!(m, MotorMessage::Emergency { faults, .. } if faults.0 & bit != 0))
    }

    #[test]
    fn periods_default_timeout_and_emergencies_are_as_documented() {
        let (mut b, mut w, mut out) = board();
        let n = b.node();
        assert!(matches!(messages(&mut out)[..], [MotorMessage::Heartbeat { state: BoardState::BootUp, .. }, ..]));
        // One second: a heartbeat every 100 ms, a status every 50 ms.
        for k in 0..=1000 {
            b.poll(f64::from(k) * 1e-3, &mut w, &mut out);
        }
        let m = messages(&mut out);
        let count = |f: fn(&MotorMessage) -> bool| m.iter().filter(|m| f(m)).count();
        assert_eq!(count(|m| matches!(m, MotorMessage::Heartbeat { .. })), 10);
        assert_eq!(count(|m| matches!(m, MotorMessage::Status { .. })), 20);

        // A config frame with timeout 0 does not decode: ignored whole.
        let mut raw = [0u8; 8];
        raw[..3].copy_from_slice(&[0x20, 0x4E, 0]); // accel 20000
        raw[3..6].copy_from_slice(&[0x40, 0x1F, 0]); // max rate 8000
        let zero = CanFrame::new(CanId::standard(0x181).unwrap(), &raw).unwrap();
        b.handle(1.0, &zero, &mut w, &mut out);
        // The default 100 ms command timeout, from the enable.
        send(&mut b, &mut w, 1.0, MotorMessage::Nmt { target: Target::Node(n), command: NmtCommand::Enable }, &mut out);
        b.poll(1.0999, &mut w, &mut out);
        assert_eq!(b.state(), BoardState::Enabled);
        b.poll(1.1001, &mut w, &mut out);
        assert_eq!(b.state(), BoardState::Fault, "the timeout is still 100 ms");
        assert!(emergency(&messages(&mut out), FaultBits::CMD_TIMEOUT), "an emergency on entering Fault");

        // An e-stop sends the emergency frame too, with its bit.
        send(&mut b, &mut w, 1.2, MotorMessage::EStop { target: Target::All, reason: EStopReason::Operator }, &mut out);
        assert_eq!(b.state(), BoardState::EStop);
        assert!(emergency(&messages(&mut out), FaultBits::ESTOP));
    }

    #[test]
    fn the_gateway_heartbeat_is_watched_for_three_command_timeouts() {
        let (mut b, mut w, mut out) = board();
        let n = b.node();
        let config = MotorMessage::Config { node: n, accel: 20_000, max_rate: 8_000, timeout_ms: 200 };
        send(&mut b, &mut w, 0.0, config, &mut out);
        send(&mut b, &mut w, 0.0, MotorMessage::Nmt { target: Target::Node(n), command: NmtCommand::Enable }, &mut out);
        send(&mut b, &mut w, 0.0, MotorMessage::GatewayHeartbeat { state: GatewayState::Armed }, &mut out);
        // Commands keep coming every 50 ms; the gateway's heartbeat stops after 0.
        let mut seq = 0u8;
        let mut faulted_at = None;
        for k in 1..=40 {
            let t = f64::from(k) * 0.05;
            seq = seq.wrapping_add(1);
            send(&mut b, &mut w, t, MotorMessage::Velocity { node: n, left: 0, right: 0, seq }, &mut out);
            b.poll(t + 0.01, &mut w, &mut out);
            if faulted_at.is_none() && b.state() == BoardState::Fault {
                faulted_at = Some(t + 0.01);
            }
        }
        let at = faulted_at.expect("faulted");
        assert!((at - 0.61).abs() < 1e-9, "3 x 200 ms after the last gateway heartbeat (first poll past it): {at}");
        assert!(b.faults().0 & FaultBits::GATEWAY_LOST != 0);
    }
}
