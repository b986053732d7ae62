//! The CAN protocol between the gateway and the pulse-motor boards.
//!
//! A board is a PCL-80K-like two-axis stepper pulse generator: axis 0 drives the left
//! wheel, axis 1 the right. CAN 2.0A, 11-bit identifiers, at most 15 boards.
//!
//! ## Identifiers
//!
//! Borrowed from CANopen's predefined connection set: the id is a function code in the
//! high seven bits and the node id in the low four, so a lower function code wins
//! arbitration. Node 0 means "every board" (e-stop, NMT) or "the gateway" (heartbeat).
//!
//! ```text
//!   10        4 3      0
//!  +-----------+--------+
//!  | function  |  node  |     id = function << 4 | node
//!  +-----------+--------+
//! ```
//!
//! | id            | message      | dir        | DLC | payload (little-endian)                                  |
//! |---------------|--------------|------------|-----|----------------------------------------------------------|
//! | `0x000`       | e-stop all   | gw -> all  | 0-8 | `[0]` reason (optional)                                  |
//! | `0x000 + n`   | e-stop node  | gw -> n    | 0-8 | `[0]` reason (optional)                                  |
//! | `0x010 + n`   | NMT          | gw -> n/all| 1   | `[0]` command                                            |
//! | `0x080 + n`   | emergency    | n -> gw    | 1   | `[0]` fault bits, sent on entering fault                 |
//! | `0x100 + n`   | velocity     | gw -> n    | 7   | `[0..3]` left i24 pulses/s, `[3..6]` right i24, `[6]` seq |
//! | `0x180 + n`   | config       | gw -> n    | 8   | `[0..3]` accel u24 pulses/s², `[3..6]` max rate u24, `[6..8]` cmd timeout ms u16 |
//! | `0x200 + n`   | status       | n -> gw    | 4   | `[0]` state, `[1]` fault bits, `[2]` last seq, `[3]` seq errors |
//! | `0x280 + n`   | axis rates   | n -> gw    | 6   | `[0..3]` left i24 pulses/s, `[3..6]` right i24 (actual, after ramp) |
//! | `0x300 + n`   | position     | n -> gw    | 8   | `[0..4]` left i32 pulses, `[4..8]` right i32             |
//! | `0x700`       | gw heartbeat | gw -> all  | 1   | `[0]` gateway state                                      |
//! | `0x700 + n`   | heartbeat    | n -> gw    | 1   | `[0]` board state; `0x00` is the boot-up message         |
//!
//! ## Behaviour the frames carry
//!
//! - Any frame on an e-stop id is an emergency stop, whatever its length: a board must not
//!   ignore a stop because of a malformed payload. Both axes stop at once (no ramp) and the
//!   board latches `EStop` until a fault reset. So does the board's own e-stop input (a
//!   stop button wired to it), which also refuses the fault reset for as long as it is open.
//! - The velocity command sets both axes in one frame, so the wheels change together. Its
//!   `seq` increments by one per command; the board counts gaps and repeats in
//!   `seq errors` (wrapping at 256) and reports the last `seq` it applied.
//! - A board stops both axes by itself when no velocity command arrives for longer than its
//!   command timeout (config), sets the `CMD_TIMEOUT` fault and latches `Fault`.
//! - Boards send heartbeat, status, axis rates and position periodically; the gateway sends
//!   its heartbeat too. `protocol/motor.dbc` describes every frame for standard CAN tools.
//!
//! ## No-panic contract
//!
//! [`MotorMessage::parse`] accepts any [`CanFrame`] and returns a [`MotorError`] for a
//! frame it does not know.

use crate::can::{node_id, CanFrame, CanId, IdUse};
use crate::psd::byte_enum;
use crate::wire::{Reader, Writer};

/// Largest magnitude of a pulse rate in a velocity command (signed 24-bit).
pub const MAX_PULSE_RATE: i32 = (1 << 23) - 1;
/// Largest unsigned 24-bit config value.
pub const MAX_U24: u32 = (1 << 24) - 1;

/// Function codes: `id >> 4`.
pub mod function {
    pub const ESTOP: u16 = 0x00;
    pub const NMT: u16 = 0x01;
    pub const EMERGENCY: u16 = 0x08;
    pub const VELOCITY: u16 = 0x10;
    pub const CONFIG: u16 = 0x18;
    pub const STATUS: u16 = 0x20;
    pub const AXIS_RATES: u16 = 0x28;
    pub const POSITION: u16 = 0x30;
    pub const HEARTBEAT: u16 = 0x70;
}

/// The identifiers a board at `node` sends or listens on (the table above).
pub fn board_ids(node: NodeId) -> [IdUse; 9] {
    let n = node.0 as u16;
    let at = |function: u16, what| IdUse { id: (function << 4) | n, what };
    [
        at(function::ESTOP, "e-stop to the board"),
        at(function::NMT, "NMT to the board"),
        at(function::EMERGENCY, "the board's emergency"),
        at(function::VELOCITY, "velocity to the board"),
        at(function::CONFIG, "config to the board"),
        at(function::STATUS, "the board's status"),
        at(function::AXIS_RATES, "the board's axis rates"),
        at(function::POSITION, "the board's position"),
        at(function::HEARTBEAT, "the board's heartbeat"),
    ]
}

/// The identifiers the gateway broadcasts to every board.
pub const GATEWAY_IDS: [IdUse; 3] = [
    IdUse { id: function::ESTOP << 4, what: "e-stop to every board" },
    IdUse { id: function::NMT << 4, what: "NMT to every board" },
    IdUse { id: function::HEARTBEAT << 4, what: "the gateway's heartbeat to the boards" },
];

node_id! {
    /// A motor board's node id, 1 to 15.
    NodeId, 1..=15
}

/// Who a broadcastable command is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Target {
    All,
    Node(NodeId),
}

impl Target {
    const fn bits(self) -> u16 {
        match self {
            Target::All => 0,
            Target::Node(n) => n.0 as u16,
        }
    }
    const fn from_bits(bits: u8) -> Self {
        match NodeId::new(bits) {
            Some(n) => Target::Node(n),
            None => Target::All,
        }
    }
    /// Whether a board with this node id must act on the command.
    pub fn includes(self, node: NodeId) -> bool {
        match self {
            Target::All => true,
            Target::Node(n) => n == node,
        }
    }
}

byte_enum! {
    /// Why an emergency stop was sent.
    EStopReason {
        Unspecified = 0,
        Operator = 1,
        GatewayFault = 2,
        Shutdown = 3,
        External = 4,
    }
}

byte_enum! {
    /// NMT-like commands.
    NmtCommand {
        /// Disabled -> Enabled: the board accepts velocity commands.
        Enable = 0x01,
        /// Enabled -> Disabled: axes ramp to zero, commands are ignored.
        Disable = 0x02,
        /// Reboot the board (it sends a boot-up message).
        Reset = 0x81,
        /// Fault / EStop -> Disabled, clearing latched faults.
        FaultReset = 0x82,
    }
}

byte_enum! {
    /// A board's state, in its heartbeat and status.
    BoardState {
        /// Only in the boot-up message.
        BootUp = 0,
        Disabled = 1,
        Enabled = 2,
        Fault = 3,
        EStop = 4,
    }
}

byte_enum! {
    /// The gateway's state, in its heartbeat (mirrors the gateway's safety state machine).
    GatewayState {
        Idle = 1,
        Armed = 2,
        Running = 3,
        Stopping = 4,
        Stopped = 5,
        Fault = 6,
    }
}

/// A board's fault bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct FaultBits(pub u8);

impl FaultBits {
    /// Velocity commands stopped arriving for longer than the command timeout.
    pub const CMD_TIMEOUT: u8 = 1 << 0;
    /// An emergency stop was received.
    pub const ESTOP: u8 = 1 << 1;
    /// A command exceeded the configured rate limit (the board clamped it).
    pub const RATE_LIMIT: u8 = 1 << 2;
    /// The CAN controller went error-passive or bus-off.
    pub const BUS: u8 = 1 << 3;
    /// The stepper driver reported a fault.
    pub const DRIVER: u8 = 1 << 4;
    /// The gateway's heartbeat stopped.
    pub const GATEWAY_LOST: u8 = 1 << 5;
    /// The board's own e-stop input is open (a stop button wired to the board). The board
    /// holds `EStop` while it is, refusing fault resets; once it closes, a fault reset
    /// clears the latch.
    pub const ESTOP_INPUT: u8 = 1 << 6;

    pub const fn contains(self, bit: u8) -> bool {
        self.0 & bit == bit
    }
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
}

/// One motor-protocol message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MotorMessage {
    EStop { target: Target, reason: EStopReason },
    Nmt { target: Target, command: NmtCommand },
    Emergency { node: NodeId, faults: FaultBits },
    Velocity { node: NodeId, left: i32, right: i32, seq: u8 },
    Config { node: NodeId, accel: u32, max_rate: u32, timeout_ms: u16 },
    Status { node: NodeId, state: BoardState, faults: FaultBits, last_seq: u8, seq_errors: u8 },
    AxisRates { node: NodeId, left: i32, right: i32 },
    Position { node: NodeId, left: i32, right: i32 },
    GatewayHeartbeat { state: GatewayState },
    Heartbeat { node: NodeId, state: BoardState },
}

/// The kinds of message, for errors and counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MotorKind {
    EStop,
    Nmt,
    Emergency,
    Velocity,
    Config,
    Status,
    AxisRates,
    Position,
    Heartbeat,
}

/// Why a CAN frame is not a motor-protocol message, or a message cannot be sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum MotorError {
    #[error("extended id 0x{0:08X}: the motor protocol uses 11-bit ids")]
    ExtendedId(u32),
    #[error("remote frame on id 0x{0:03X}")]
    Remote(u16),
    #[error("id 0x{0:03X} is not a motor-protocol id")]
    UnknownId(u16),
    #[error("{kind:?} on id 0x{id:03X} with DLC {dlc}, expected {expected}")]
    Length { kind: MotorKind, id: u16, dlc: u8, expected: u8 },
    #[error("{kind:?}: field `{field}` out of range")]
    Field { kind: MotorKind, field: &'static str },
}

/// A frame's identifier and length read ([`MotorMessage::classify`]).
enum Classified {
    EStop(MotorMessage),
    Message { id: u16, kind: MotorKind, node: Option<NodeId>, node_bits: u8, expected: u8 },
}

impl MotorMessage {
    pub fn kind(&self) -> MotorKind {
        match self {
            Self::EStop { .. } => MotorKind::EStop,
            Self::Nmt { .. } => MotorKind::Nmt,
            Self::Emergency { .. } => MotorKind::Emergency,
            Self::Velocity { .. } => MotorKind::Velocity,
            Self::Config { .. } => MotorKind::Config,
            Self::Status { .. } => MotorKind::Status,
            Self::AxisRates { .. } => MotorKind::AxisRates,
            Self::Position { .. } => MotorKind::Position,
            Self::GatewayHeartbeat { .. } | Self::Heartbeat { .. } => MotorKind::Heartbeat,
        }
    }

    /// The board the message is from or for; `None` for broadcasts and the gateway heartbeat.
    pub fn node(&self) -> Option<NodeId> {
        match *self {
            Self::EStop { target, .. } | Self::Nmt { target, .. } => match target {
                Target::All => None,
                Target::Node(n) => Some(n),
            },
            Self::GatewayHeartbeat { .. } => None,
            Self::Emergency { node, .. }
            | Self::Velocity { node, .. }
            | Self::Config { node, .. }
            | Self::Status { node, .. }
            | Self::AxisRates { node, .. }
            | Self::Position { node, .. }
            | Self::Heartbeat { node, .. } => Some(node),
        }
    }

    /// What a frame's identifier and length say it is: an e-stop (read whole), or a kind
    /// of message for a node (or all), its length checked.
    fn classify(frame: &CanFrame) -> Result<Classified, MotorError> {
        let id = match frame.id() {
            CanId::Standard(id) => id,
            CanId::Extended(id) => return Err(MotorError::ExtendedId(id)),
        };
        if frame.is_remote() {
            return Err(MotorError::Remote(id));
        }
        let (func, node_bits) = (id >> 4, (id & 0x0F) as u8);
        // E-stop first and leniently: any length, any reason byte.
        if func == function::ESTOP {
            let reason =
                frame.data().first().and_then(|&b| EStopReason::from_u8(b)).unwrap_or(EStopReason::Unspecified);
            return Ok(Classified::EStop(Self::EStop { target: Target::from_bits(node_bits), reason }));
        }
        let (kind, expected) = match func {
            function::NMT => (MotorKind::Nmt, 1),
            function::EMERGENCY => (MotorKind::Emergency, 1),
            function::VELOCITY => (MotorKind::Velocity, 7),
            function::CONFIG => (MotorKind::Config, 8),
            function::STATUS => (MotorKind::Status, 4),
            function::AXIS_RATES => (MotorKind::AxisRates, 6),
            function::POSITION => (MotorKind::Position, 8),
            function::HEARTBEAT => (MotorKind::Heartbeat, 1),
            _ => return Err(MotorError::UnknownId(id)),
        };
        // Only NMT and heartbeat have a meaning for node 0.
        let node = match (NodeId::new(node_bits), kind) {
            (Some(n), _) => Some(n),
            (None, MotorKind::Nmt | MotorKind::Heartbeat) => None,
            (None, _) => return Err(MotorError::UnknownId(id)),
        };
        if frame.dlc() != expected {
            return Err(MotorError::Length { kind, id, dlc: frame.dlc(), expected });
        }
        Ok(Classified::Message { id, kind, node, node_bits, expected })
    }

    /// Read a CAN frame as a motor-protocol message.
    pub fn parse(frame: &CanFrame) -> Result<Self, MotorError> {
        let (id, kind, node, node_bits, expected) = match Self::classify(frame)? {
            Classified::EStop(estop) => return Ok(estop),
            Classified::Message { id, kind, node, node_bits, expected } => (id, kind, node, node_bits, expected),
        };
        let data = frame.data();
        let field = |field| MotorError::Field { kind, field };
        // i24 reads -2^23 too; the protocol's rates are symmetric, ±MAX_PULSE_RATE.
        let rate = |v: Option<i32>, name| match v {
            Some(v) if v >= -MAX_PULSE_RATE => Ok(v),
            Some(_) => Err(field(name)),
            None => Err(MotorError::Length { kind, id, dlc: frame.dlc(), expected }),
        };
        let mut r = Reader::new(data);
        // Lengths were checked above, so the reader cannot run short; map it to an error anyway.
        let short = MotorError::Length { kind, id, dlc: frame.dlc(), expected };
        let node_or_all = Target::from_bits(node_bits);
        let msg = match kind {
            MotorKind::Nmt => {
                let command = NmtCommand::from_u8(r.u8().ok_or(short)?).ok_or(field("command"))?;
                Self::Nmt { target: node_or_all, command }
            }
            MotorKind::Heartbeat => {
                let state = r.u8().ok_or(short)?;
                match node {
                    None => Self::GatewayHeartbeat { state: GatewayState::from_u8(state).ok_or(field("state"))? },
                    Some(node) => Self::Heartbeat { node, state: BoardState::from_u8(state).ok_or(field("state"))? },
                }
            }
            _ => {
                let node = node.ok_or(MotorError::UnknownId(id))?;
                match kind {
                    MotorKind::Emergency => Self::Emergency { node, faults: FaultBits(r.u8().ok_or(short)?) },
                    MotorKind::Velocity => Self::Velocity {
                        node,
                        left: rate(r.i24(), "left")?,
                        right: rate(r.i24(), "right")?,
                        seq: r.u8().ok_or(short)?,
                    },
                    MotorKind::Config => {
                        let (accel, max_rate, timeout_ms) =
                            (r.u24().ok_or(short)?, r.u24().ok_or(short)?, r.u16().ok_or(short)?);
                        if timeout_ms == 0 {
                            return Err(field("timeout_ms"));
                        }
                        Self::Config { node, accel, max_rate, timeout_ms }
                    }
                    MotorKind::Status => Self::Status {
                        node,
                        state: BoardState::from_u8(r.u8().ok_or(short)?).ok_or(field("state"))?,
                        faults: FaultBits(r.u8().ok_or(short)?),
                        last_seq: r.u8().ok_or(short)?,
                        seq_errors: r.u8().ok_or(short)?,
                    },
                    MotorKind::AxisRates => {
                        Self::AxisRates { node, left: rate(r.i24(), "left")?, right: rate(r.i24(), "right")? }
                    }
                    MotorKind::Position => {
                        Self::Position { node, left: r.i32().ok_or(short)?, right: r.i32().ok_or(short)? }
                    }
                    MotorKind::EStop | MotorKind::Nmt | MotorKind::Heartbeat => return Err(MotorError::UnknownId(id)),
                }
            }
        };
        Ok(msg)
    }

    /// The CAN frame for this message. Fails only for values outside their field's range
    /// (pulse rates beyond ±[`MAX_PULSE_RATE`], config values beyond 24 bits, a zero timeout).
    pub fn to_frame(&self) -> Result<CanFrame, MotorError> {
        let kind = self.kind();
        let field = |field| MotorError::Field { kind, field };
        let rate =
            |v: i32, name| if (-MAX_PULSE_RATE..=MAX_PULSE_RATE).contains(&v) { Ok(v) } else { Err(field(name)) };
        let mut data = [0u8; 8];
        let mut w = Writer::new(&mut data);
        let (func, node) = match *self {
            Self::EStop { target, reason } => {
                w.u8(reason as u8);
                (function::ESTOP, target.bits())
            }
            Self::Nmt { target, command } => {
                w.u8(command as u8);
                (function::NMT, target.bits())
            }
            Self::Emergency { node, faults } => {
                w.u8(faults.0);
                (function::EMERGENCY, node.0.into())
            }
            Self::Velocity { node, left, right, seq } => {
                w.i24(rate(left, "left")?);
                w.i24(rate(right, "right")?);
                w.u8(seq);
                (function::VELOCITY, node.0.into())
            }
            Self::Config { node, accel, max_rate, timeout_ms } => {
                if accel > MAX_U24 {
                    return Err(field("accel"));
                }
                if max_rate > MAX_U24 {
                    return Err(field("max_rate"));
                }
                if timeout_ms == 0 {
                    return Err(field("timeout_ms"));
                }
                w.u24(accel);
                w.u24(max_rate);
                w.u16(timeout_ms);
                (function::CONFIG, node.0.into())
            }
            Self::Status { node, state, faults, last_seq, seq_errors } => {
                w.put(&[state as u8, faults.0, last_seq, seq_errors]);
                (function::STATUS, node.0.into())
            }
            Self::AxisRates { node, left, right } => {
                w.i24(rate(left, "left")?);
                w.i24(rate(right, "right")?);
                (function::AXIS_RATES, node.0.into())
            }
            Self::Position { node, left, right } => {
                w.i32(left);
                w.i32(right);
                (function::POSITION, node.0.into())
            }
            Self::GatewayHeartbeat { state } => {
                w.u8(state as u8);
                (function::HEARTBEAT, 0)
            }
            Self::Heartbeat { node, state } => {
                w.u8(state as u8);
                (function::HEARTBEAT, node.0.into())
            }
        };
        let len = w.len();
        Ok(CanFrame::standard(func << 4 | node, &data[..len]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn n(id: u8) -> NodeId {
        NodeId::new(id).unwrap()
    }

    /// Golden frames, both directions.
    #[test]
    fn golden_frames() {
        let cases: &[(MotorMessage, u16, &[u8])] = &[
            (MotorMessage::EStop { target: Target::All, reason: EStopReason::Operator }, 0x000, &[0x01]),
            (MotorMessage::EStop { target: Target::Node(n(3)), reason: EStopReason::Shutdown }, 0x003, &[0x03]),
            (MotorMessage::Nmt { target: Target::All, command: NmtCommand::Enable }, 0x010, &[0x01]),
            (MotorMessage::Nmt { target: Target::Node(n(1)), command: NmtCommand::FaultReset }, 0x011, &[0x82]),
            (MotorMessage::Emergency { node: n(2), faults: FaultBits(FaultBits::CMD_TIMEOUT) }, 0x082, &[0x01]),
            (
                MotorMessage::Velocity { node: n(1), left: 1000, right: -1000, seq: 7 },
                0x101,
                &[0xE8, 0x03, 0x00, 0x18, 0xFC, 0xFF, 0x07],
            ),
            (
                MotorMessage::Config { node: n(1), accel: 20_000, max_rate: 8_000, timeout_ms: 100 },
                0x181,
                &[0x20, 0x4E, 0x00, 0x40, 0x1F, 0x00, 0x64, 0x00],
            ),
            (
                MotorMessage::Status {
                    node: n(15),
                    state: BoardState::Enabled,
                    faults: FaultBits(0),
                    last_seq: 200,
                    seq_errors: 1,
                },
                0x20F,
                &[0x02, 0x00, 0xC8, 0x01],
            ),
            (MotorMessage::AxisRates { node: n(1), left: -1, right: 1 }, 0x281, &[0xFF, 0xFF, 0xFF, 0x01, 0x00, 0x00]),
            (
                MotorMessage::Position { node: n(1), left: -2, right: 0x0102_0304 },
                0x301,
                &[0xFE, 0xFF, 0xFF, 0xFF, 0x04, 0x03, 0x02, 0x01],
            ),
            (MotorMessage::GatewayHeartbeat { state: GatewayState::Running }, 0x700, &[0x03]),
            (MotorMessage::Heartbeat { node: n(1), state: BoardState::BootUp }, 0x701, &[0x00]),
        ];
        for (msg, id, data) in cases {
            let frame = msg.to_frame().unwrap();
            assert_eq!(frame.id(), CanId::Standard(*id), "{msg:?}");
            assert_eq!(frame.data(), *data, "{msg:?}");
            let golden = CanFrame::new(CanId::Standard(*id), data).unwrap();
            assert_eq!(MotorMessage::parse(&golden).unwrap(), *msg);
        }
    }

    #[test]
    fn estop_is_lenient_about_its_payload() {
        for data in [&[][..], &[0xEE][..], &[1, 2, 3, 4, 5, 6, 7, 8][..]] {
            let f = CanFrame::new(CanId::Standard(0x002), data).unwrap();
            let m = MotorMessage::parse(&f).unwrap();
            assert!(matches!(m, MotorMessage::EStop { target: Target::Node(t), .. } if t.get() == 2));
        }
    }

    #[test]
    fn rejects_unknown_and_malformed() {
        let std = |id, d: &[u8]| CanFrame::new(CanId::Standard(id), d).unwrap();
        assert_eq!(MotorMessage::parse(&std(0x123, &[])), Err(MotorError::UnknownId(0x123)));
        assert_eq!(MotorMessage::parse(&std(0x100, &[0; 7])), Err(MotorError::UnknownId(0x100)));
        assert!(matches!(MotorMessage::parse(&std(0x101, &[0; 6])), Err(MotorError::Length { dlc: 6, .. })));
        assert!(matches!(MotorMessage::parse(&std(0x011, &[0x55])), Err(MotorError::Field { field: "command", .. })));
        assert!(matches!(
            MotorMessage::parse(&std(0x181, &[0; 8])),
            Err(MotorError::Field { field: "timeout_ms", .. })
        ));
        let ext = CanFrame::new(CanId::Extended(0x101), &[0; 7]).unwrap();
        assert_eq!(MotorMessage::parse(&ext), Err(MotorError::ExtendedId(0x101)));
        let rtr = CanFrame::remote(CanId::Standard(0x701), 1).unwrap();
        assert_eq!(MotorMessage::parse(&rtr), Err(MotorError::Remote(0x701)));
    }

    /// Found by fuzzing motor frames: -2^23 fits the i24 field but not the protocol's
    /// symmetric rate range, so it must be refused on parse as on emit.
    #[test]
    fn parse_refuses_the_one_rate_emit_cannot_write() {
        for id in [0x101, 0x281] {
            let mut data = [0u8; 7];
            data[..3].copy_from_slice(&[0x00, 0x00, 0x80]);
            let dlc = if id == 0x101 { 7 } else { 6 };
            let f = CanFrame::new(CanId::Standard(id), &data[..dlc]).unwrap();
            assert!(matches!(MotorMessage::parse(&f), Err(MotorError::Field { field: "left", .. })), "{id:x}");
        }
    }

    #[test]
    fn emit_refuses_out_of_range_values() {
        let v = MotorMessage::Velocity { node: n(1), left: MAX_PULSE_RATE + 1, right: 0, seq: 0 };
        assert!(matches!(v.to_frame(), Err(MotorError::Field { field: "left", .. })));
        let c = MotorMessage::Config { node: n(1), accel: MAX_U24 + 1, max_rate: 1, timeout_ms: 1 };
        assert!(matches!(c.to_frame(), Err(MotorError::Field { field: "accel", .. })));
    }

    #[test]
    fn priorities_follow_safety() {
        let id = |m: MotorMessage| m.to_frame().unwrap().id().raw();
        let estop = id(MotorMessage::EStop { target: Target::Node(n(15)), reason: EStopReason::Operator });
        let vel = id(MotorMessage::Velocity { node: n(1), left: 0, right: 0, seq: 0 });
        let status = id(MotorMessage::Status {
            node: n(1),
            state: BoardState::Enabled,
            faults: FaultBits(0),
            last_seq: 0,
            seq_errors: 0,
        });
        assert!(estop < vel && vel < status);
    }
}
