//! CANopen (CiA 301) as a CiA 402 drive speaks it: the frames a gateway exchanges with
//! off-the-shelf stepper and servo drives (Nanotec, Trinamic, Maxon EPOS, Faulhaber, ...),
//! and the drive profile's state machine.
//!
//! ## Identifiers (the predefined connection set)
//!
//! CAN 2.0A, 11-bit identifiers: a function code in the high four bits, the node id
//! (1-127) in the low seven.
//!
//! | COB-ID        | object               | dir            | DLC | payload (little-endian)                          |
//! |---------------|----------------------|----------------|-----|--------------------------------------------------|
//! | `0x000`       | NMT                  | master -> all  | 2   | `[0]` command, `[1]` node (0: every node)         |
//! | `0x080`       | SYNC                 | master -> all  | 0   |                                                  |
//! | `0x080 + n`   | EMCY                 | n -> master    | 8   | `[0..2]` error code, `[2]` error register, `[3..8]` vendor |
//! | `0x180 + n` … `0x480 + n` | TPDO1-4  | n -> master    | 0-8 | as mapped                                        |
//! | `0x200 + n` … `0x500 + n` | RPDO1-4  | master -> n    | 0-8 | as mapped                                        |
//! | `0x580 + n`   | SDO response         | n -> master    | 8   | `[0]` command, `[1..3]` index, `[3]` subindex, `[4..8]` data |
//! | `0x600 + n`   | SDO request          | master -> n    | 8   | the same                                         |
//! | `0x700 + n`   | heartbeat / boot-up  | n -> master    | 1   | `[0]` NMT state; `0x00` is the boot-up message    |
//!
//! SDO transfers here are expedited (at most four bytes, one frame each way): every object
//! a gateway writes to configure a drive and reads back fits. A segmented or block
//! transfer is refused by [`CanOpenMessage::parse`] as unsupported, not misread.
//!
//! ## The CiA 402 state machine
//!
//! A drive reports its state in the statusword (0x6041) and is moved by the controlword
//! (0x6040): switch on disabled → (shutdown) → ready to switch on → (switch on) → switched
//! on → (enable operation) → operation enabled, which is the only state in which the drive
//! follows a target. A fault goes to *fault* through *fault reaction active*; a *fault
//! reset* (a rising edge of controlword bit 7) returns it to switch on disabled. *Quick
//! stop* brakes on the quick-stop deceleration (0x6085). [`DriveState::from_statusword`]
//! decodes the state, [`DriveState::towards_operation`] says which command takes a drive
//! one step on the way to operation enabled.
//!
//! ## No-panic contract
//!
//! [`CanOpenMessage::parse`] accepts any [`CanFrame`] and returns a [`CanOpenError`] for a
//! frame it does not know or cannot read.

use crate::can::{node_id, CanFrame, CanId, IdUse};
use crate::psd::byte_enum;
use crate::wire::{Reader, Writer};

node_id! {
    /// A CANopen node id, 1 to 127.
    NodeId, 1..=127
}

mod drive;
pub use drive::statusword;
pub use drive::{DriveCommand, DriveState, VelocityCommand, VelocityReport};
/// Function codes of the predefined connection set: the COB-ID less the node id.
pub mod cob {
    pub const NMT: u16 = 0x000;
    pub const SYNC: u16 = 0x080;
    pub const EMCY: u16 = 0x080;
    pub const TPDO1: u16 = 0x180;
    pub const RPDO1: u16 = 0x200;
    pub const TPDO2: u16 = 0x280;
    pub const SDO_RESPONSE: u16 = 0x580;
    pub const SDO_REQUEST: u16 = 0x600;
    pub const HEARTBEAT: u16 = 0x700;
}

/// The identifiers a drive at `node` sends or listens on, as the gateway maps it (one RPDO,
/// two TPDOs, SDO, EMCY and its heartbeat; no SYNC).
pub fn drive_ids(node: NodeId) -> [IdUse; 7] {
    let n = u16::from(node.0);
    let at = |function: u16, what| IdUse { id: function + n, what };
    [
        at(cob::EMCY, "the drive's EMCY"),
        at(cob::TPDO1, "the drive's TPDO1 (statusword, velocity)"),
        at(cob::RPDO1, "RPDO1 to the drive (controlword, target velocity)"),
        at(cob::TPDO2, "the drive's TPDO2 (position)"),
        at(cob::SDO_RESPONSE, "the drive's SDO responses"),
        at(cob::SDO_REQUEST, "SDO requests to the drive"),
        at(cob::HEARTBEAT, "the drive's heartbeat"),
    ]
}

/// The identifiers the gateway, as CANopen node `gateway`, sends to every drive.
pub fn gateway_ids(gateway: NodeId) -> [IdUse; 2] {
    [
        IdUse { id: cob::NMT, what: "NMT to every drive" },
        IdUse { id: cob::HEARTBEAT + u16::from(gateway.0), what: "the gateway's heartbeat to the drives" },
    ]
}

/// The objects of the dictionary a gateway uses on a CiA 402 drive (index, and the
/// subindex where it is not 0).
pub mod object {
    /// Error register (u8).
    pub const ERROR_REGISTER: u16 = 0x1001;
    /// Consumer heartbeat time: sub 1.. = node << 16 | time ms (u32).
    pub const CONSUMER_HEARTBEAT_TIME: u16 = 0x1016;
    /// Producer heartbeat time, ms (u16).
    pub const PRODUCER_HEARTBEAT_TIME: u16 = 0x1017;
    /// RPDO1's communication parameters (sub 1: COB-ID u32, sub 2: transmission type u8);
    /// RPDO n is `+ n - 1`.
    pub const RPDO1_COMMUNICATION: u16 = 0x1400;
    /// RPDO1's mapping (sub 0: count u8, sub 1..: index << 16 | sub << 8 | bits, u32).
    pub const RPDO1_MAPPING: u16 = 0x1600;
    /// TPDO1's communication parameters (sub 1: COB-ID u32, sub 2: transmission type u8,
    /// sub 5: event timer ms u16); TPDO n is `+ n - 1`.
    pub const TPDO1_COMMUNICATION: u16 = 0x1800;
    pub const TPDO1_MAPPING: u16 = 0x1A00;
    pub const TPDO2_COMMUNICATION: u16 = 0x1801;
    pub const TPDO2_MAPPING: u16 = 0x1A01;
    /// Error code of the last fault (u16).
    pub const ERROR_CODE: u16 = 0x603F;
    /// Controlword (u16).
    pub const CONTROLWORD: u16 = 0x6040;
    /// Statusword (u16).
    pub const STATUSWORD: u16 = 0x6041;
    /// Quick stop option code (i16).
    pub const QUICK_STOP_OPTION: u16 = 0x605A;
    /// Modes of operation (i8), and what the drive runs (i8).
    pub const MODES_OF_OPERATION: u16 = 0x6060;
    pub const MODES_OF_OPERATION_DISPLAY: u16 = 0x6061;
    /// Position actual value (i32, increments).
    pub const POSITION_ACTUAL: u16 = 0x6064;
    /// Velocity actual value (i32, velocity units).
    pub const VELOCITY_ACTUAL: u16 = 0x606C;
    /// Max profile velocity (u32, velocity units): the drive clamps its target to it.
    pub const MAX_PROFILE_VELOCITY: u16 = 0x607F;
    /// Profile acceleration and deceleration (u32, velocity units per second).
    pub const PROFILE_ACCELERATION: u16 = 0x6083;
    pub const PROFILE_DECELERATION: u16 = 0x6084;
    /// Quick stop deceleration (u32).
    pub const QUICK_STOP_DECELERATION: u16 = 0x6085;
    /// Target velocity (i32, velocity units), followed in profile velocity mode.
    pub const TARGET_VELOCITY: u16 = 0x60FF;
}

/// Modes of operation (0x6060): profile velocity.
pub const PROFILE_VELOCITY_MODE: i8 = 3;

/// A PDO's COB-ID (sub 1 of its communication parameters) with this bit set: the PDO does
/// not exist (is not sent or taken), as its mapping must be while it is written.
pub const PDO_INVALID: u32 = 1 << 31;

/// Transmission type 255 (sub 2): event-driven, by the device profile (a CiA 402 drive
/// sends on a change of its statusword) and by the event timer (sub 5).
pub const TRANSMISSION_EVENT: u8 = 255;

/// Quick stop option code 2 (0x605A): brake on the quick-stop deceleration, then switch on
/// disabled (the motor unpowered once at rest).
pub const QUICK_STOP_THEN_DISABLE: i16 = 2;

byte_enum! {
    /// An NMT command (`0x000`, byte 0).
    NmtCommand {
        Start = 0x01,
        Stop = 0x02,
        EnterPreOperational = 0x80,
        ResetNode = 0x81,
        ResetCommunication = 0x82,
    }
}

byte_enum! {
    /// A node's NMT state, as its heartbeat carries it (`0x00` is the boot-up message).
    NmtState {
        BootUp = 0x00,
        Stopped = 0x04,
        Operational = 0x05,
        PreOperational = 0x7F,
    }
}

/// Who an NMT command is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtTarget {
    All,
    Node(NodeId),
}

/// An expedited SDO's data: one to four bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SdoData {
    bytes: [u8; 4],
    len: u8,
}

impl SdoData {
    /// One to four bytes; `None` otherwise.
    pub fn new(data: &[u8]) -> Option<Self> {
        if data.is_empty() || data.len() > 4 {
            return None;
        }
        let mut bytes = [0; 4];
        bytes[..data.len()].copy_from_slice(data);
        Some(Self { bytes, len: data.len() as u8 })
    }
    pub fn u8(v: u8) -> Self {
        Self { bytes: [v, 0, 0, 0], len: 1 }
    }
    pub fn i8(v: i8) -> Self {
        Self::u8(v as u8)
    }
    pub fn u16(v: u16) -> Self {
        let [a, b] = v.to_le_bytes();
        Self { bytes: [a, b, 0, 0], len: 2 }
    }
    pub fn i16(v: i16) -> Self {
        Self::u16(v as u16)
    }
    pub fn u32(v: u32) -> Self {
        Self { bytes: v.to_le_bytes(), len: 4 }
    }
    pub fn i32(v: i32) -> Self {
        Self::u32(v as u32)
    }
    pub fn bytes(&self) -> &[u8] {
        &self.bytes[..usize::from(self.len)]
    }
    /// How many bytes (1-4).
    pub fn size(&self) -> usize {
        usize::from(self.len)
    }
    /// The value, zero-extended to 32 bits (an object's natural reading whatever its size).
    pub fn value(&self) -> u32 {
        u32::from_le_bytes(self.bytes)
    }
}

/// An SDO request, client (the gateway) to server (the drive): `0x600 + n`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SdoRequest {
    /// Write `data` to `index:sub` (an expedited initiate-download).
    Download {
        index: u16,
        sub: u8,
        data: SdoData,
    },
    /// Read `index:sub` (an initiate-upload).
    Upload {
        index: u16,
        sub: u8,
    },
    Abort {
        index: u16,
        sub: u8,
        code: u32,
    },
}

/// An SDO response, server to client: `0x580 + n`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SdoResponse {
    /// The write was done.
    Downloaded {
        index: u16,
        sub: u8,
    },
    /// The object's value (an expedited initiate-upload response).
    Uploaded {
        index: u16,
        sub: u8,
        data: SdoData,
    },
    Abort {
        index: u16,
        sub: u8,
        code: u32,
    },
}

impl SdoRequest {
    pub const fn object(&self) -> (u16, u8) {
        match *self {
            Self::Download { index, sub, .. } | Self::Upload { index, sub } | Self::Abort { index, sub, .. } => {
                (index, sub)
            }
        }
    }
}

impl SdoResponse {
    pub const fn object(&self) -> (u16, u8) {
        match *self {
            Self::Downloaded { index, sub } | Self::Uploaded { index, sub, .. } | Self::Abort { index, sub, .. } => {
                (index, sub)
            }
        }
    }
}

/// What an SDO abort code means (CiA 301, 7.2.4.3.17), for messages.
pub fn sdo_abort_text(code: u32) -> &'static str {
    match code {
        0x0503_0000 => "toggle bit not alternated",
        0x0504_0000 => "SDO protocol timed out",
        0x0504_0001 => "command specifier not valid or unknown",
        0x0601_0000 => "unsupported access to an object",
        0x0601_0001 => "attempt to read a write-only object",
        0x0601_0002 => "attempt to write a read-only object",
        0x0602_0000 => "object does not exist in the object dictionary",
        0x0604_0041 => "object cannot be mapped to the PDO",
        0x0604_0042 => "the mapped objects would exceed the PDO length",
        0x0604_0043 => "general parameter incompatibility",
        0x0607_0010 => "data type does not match, length of service parameter does not match",
        0x0609_0011 => "subindex does not exist",
        0x0609_0030 => "value range of parameter exceeded",
        0x0609_0031 => "value of parameter written too high",
        0x0609_0032 => "value of parameter written too low",
        0x0800_0000 => "general error",
        0x0800_0020 => "data cannot be transferred or stored to the application",
        0x0800_0021 => "data cannot be transferred because of local control",
        0x0800_0022 => "data cannot be transferred in the present device state",
        _ => "unknown abort code",
    }
}

/// An emergency message (`0x080 + n`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Emcy {
    /// CiA 301 / CiA 402 error code; 0x0000 is "error reset or no error".
    pub error_code: u16,
    /// The error register (0x1001) as sent.
    pub error_register: u8,
    pub vendor: [u8; 5],
}

impl Emcy {
    /// What the error code means, by the codes a CiA 402 drive sends and else by class.
    pub fn describe(&self) -> &'static str {
        match self.error_code {
            0x0000 => "error reset or no error",
            0x2310 => "continuous over-current",
            0x3210 => "DC link over-voltage",
            0x3220 => "DC link under-voltage",
            0x4210 => "excess temperature device",
            0x5441 => "enable input inactive",
            0x7121 => "motor blocked",
            0x8110 => "CAN overrun (objects lost)",
            0x8120 => "CAN in error passive mode",
            0x8130 => "life guard or heartbeat error",
            0x8140 => "recovered from bus off",
            0x8611 => "following error",
            0x8612 => "reference limit",
            code => match code >> 12 {
                0x1 => "generic error",
                0x2 => "current",
                0x3 => "voltage",
                0x4 => "temperature",
                0x5 => "device hardware",
                0x6 => "device software",
                0x7 => "additional modules",
                0x8 => "monitoring",
                0x9 => "external error",
                0xF => "device specific",
                _ => "unknown error code",
            },
        }
    }
}

/// A frame of a CANopen network, as a gateway sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CanOpenMessage {
    Nmt {
        command: NmtCommand,
        target: NmtTarget,
    },
    Sync,
    Emcy {
        node: NodeId,
        emcy: Emcy,
    },
    /// A heartbeat, or with [`NmtState::BootUp`] the boot-up message.
    Heartbeat {
        node: NodeId,
        state: NmtState,
    },
    SdoRequest {
        node: NodeId,
        request: SdoRequest,
    },
    SdoResponse {
        node: NodeId,
        response: SdoResponse,
    },
    /// A process data object: `number` 1-4, as mapped.
    Pdo {
        direction: PdoDirection,
        number: u8,
        node: NodeId,
        data: PdoData,
    },
}

/// Which way a PDO goes, from the drive's side: a drive transmits TPDOs, receives RPDOs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PdoDirection {
    Transmit,
    Receive,
}

/// A PDO's bytes: zero to eight.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PdoData {
    bytes: [u8; 8],
    len: u8,
}

impl PdoData {
    /// Up to eight bytes; `None` for more.
    pub fn new(data: &[u8]) -> Option<Self> {
        let mut bytes = [0; 8];
        bytes.get_mut(..data.len())?.copy_from_slice(data);
        Some(Self { bytes, len: data.len() as u8 })
    }
    pub fn bytes(&self) -> &[u8] {
        &self.bytes[..usize::from(self.len)]
    }
}

/// Why a frame is not a CANopen message this module reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum CanOpenError {
    #[error("extended or remote frame: CANopen uses standard data frames")]
    NotStandardData,
    #[error("COB-ID 0x{0:03X} is no object of the predefined connection set")]
    UnknownCobId(u16),
    #[error("COB-ID 0x{cob_id:03X}: {len} data bytes, expected {expected}")]
    BadLength { cob_id: u16, len: usize, expected: usize },
    #[error("NMT command 0x{0:02X} unknown")]
    UnknownNmtCommand(u8),
    #[error("NMT node {0} out of range")]
    BadNmtNode(u8),
    #[error("heartbeat state 0x{0:02X} unknown")]
    UnknownNmtState(u8),
    #[error("SDO command 0x{0:02X}: segmented and block transfers are not supported, only expedited")]
    UnsupportedSdo(u8),
    #[error("SDO command 0x{0:02X} unknown")]
    UnknownSdoCommand(u8),
}

/// SDO command bytes (CiA 301 7.2.4.3): the command specifier in bits 7-5; for an expedited
/// transfer `e` (bit 1) and `s` (bit 0) set and the unused bytes `n` in bits 3-2.
mod sdo {
    pub const DOWNLOAD_EXPEDITED: u8 = 0x23; // ccs 1, e, s; | (4 - len) << 2
    pub const UPLOAD: u8 = 0x40; // ccs 2
    pub const UPLOADED_EXPEDITED: u8 = 0x43; // scs 2, e, s; | (4 - len) << 2
    pub const DOWNLOADED: u8 = 0x60; // scs 3
    pub const ABORT: u8 = 0x80;
    /// Command specifier: bits 7-5.
    pub const fn specifier(cmd: u8) -> u8 {
        cmd >> 5
    }
    /// An expedited transfer with its size given: `e` and `s`.
    pub const fn expedited_sized(cmd: u8) -> bool {
        cmd & 0x03 == 0x03
    }
    /// Data bytes of an expedited, sized transfer.
    pub const fn len(cmd: u8) -> usize {
        4 - ((cmd >> 2) & 0x03) as usize
    }
}

impl CanOpenMessage {
    /// Read a frame.
    pub fn parse(frame: &CanFrame) -> Result<Self, CanOpenError> {
        let CanId::Standard(id) = frame.id() else { return Err(CanOpenError::NotStandardData) };
        if frame.is_remote() {
            return Err(CanOpenError::NotStandardData);
        }
        let data = frame.data();
        let length = |expected: usize| {
            if data.len() == expected {
                Ok(())
            } else {
                Err(CanOpenError::BadLength { cob_id: id, len: data.len(), expected })
            }
        };
        let (function, node) = (id & 0x780, (id & 0x7F) as u8);
        if id == cob::NMT {
            length(2)?;
            let command = NmtCommand::from_u8(data[0]).ok_or(CanOpenError::UnknownNmtCommand(data[0]))?;
            let target = match data[1] {
                0 => NmtTarget::All,
                n => NmtTarget::Node(NodeId::new(n).ok_or(CanOpenError::BadNmtNode(n))?),
            };
            return Ok(Self::Nmt { command, target });
        }
        if id == cob::SYNC {
            length(0)?;
            return Ok(Self::Sync);
        }
        let Some(node) = NodeId::new(node) else { return Err(CanOpenError::UnknownCobId(id)) };
        match function {
            cob::EMCY => {
                length(8)?;
                let mut r = Reader::new(data);
                let error_code = r.u16().ok_or(CanOpenError::BadLength { cob_id: id, len: data.len(), expected: 8 })?;
                let error_register = data[2];
                let mut vendor = [0; 5];
                vendor.copy_from_slice(&data[3..8]);
                Ok(Self::Emcy { node, emcy: Emcy { error_code, error_register, vendor } })
            }
            cob::HEARTBEAT => {
                length(1)?;
                let state = NmtState::from_u8(data[0]).ok_or(CanOpenError::UnknownNmtState(data[0]))?;
                Ok(Self::Heartbeat { node, state })
            }
            cob::SDO_REQUEST => {
                length(8)?;
                Ok(Self::SdoRequest { node, request: parse_request(data)? })
            }
            cob::SDO_RESPONSE => {
                length(8)?;
                Ok(Self::SdoResponse { node, response: parse_response(data)? })
            }
            0x180..=0x500 => {
                let (direction, number) = match function {
                    0x180 | 0x280 | 0x380 | 0x480 => (PdoDirection::Transmit, ((function - 0x180) / 0x100 + 1) as u8),
                    _ => (PdoDirection::Receive, ((function - 0x200) / 0x100 + 1) as u8),
                };
                let data =
                    PdoData::new(data).ok_or(CanOpenError::BadLength { cob_id: id, len: data.len(), expected: 8 })?;
                Ok(Self::Pdo { direction, number, node, data })
            }
            _ => Err(CanOpenError::UnknownCobId(id)),
        }
    }

    /// The frame for this message. `None` for a PDO `number` outside 1-4.
    pub fn to_frame(&self) -> Option<CanFrame> {
        let mut buf = [0u8; 8];
        let (id, len) = match *self {
            Self::Nmt { command, target } => {
                buf[0] = command as u8;
                buf[1] = match target {
                    NmtTarget::All => 0,
                    NmtTarget::Node(n) => n.get(),
                };
                (cob::NMT, 2)
            }
            Self::Sync => (cob::SYNC, 0),
            Self::Emcy { node, emcy } => {
                let mut w = Writer::new(&mut buf);
                w.u16(emcy.error_code)?;
                w.u8(emcy.error_register)?;
                w.put(&emcy.vendor)?;
                (cob::EMCY + u16::from(node.get()), 8)
            }
            Self::Heartbeat { node, state } => {
                buf[0] = state as u8;
                (cob::HEARTBEAT + u16::from(node.get()), 1)
            }
            Self::SdoRequest { node, request } => {
                let (cmd, (index, sub), payload) = match request {
                    SdoRequest::Download { index, sub, data } => {
                        (sdo::DOWNLOAD_EXPEDITED | ((4 - data.len) << 2), (index, sub), data.bytes)
                    }
                    SdoRequest::Upload { index, sub } => (sdo::UPLOAD, (index, sub), [0; 4]),
                    SdoRequest::Abort { index, sub, code } => (sdo::ABORT, (index, sub), code.to_le_bytes()),
                };
                sdo_frame(&mut buf, cmd, index, sub, payload)?;
                (cob::SDO_REQUEST + u16::from(node.get()), 8)
            }
            Self::SdoResponse { node, response } => {
                let (cmd, (index, sub), payload) = match response {
                    SdoResponse::Downloaded { index, sub } => (sdo::DOWNLOADED, (index, sub), [0; 4]),
                    SdoResponse::Uploaded { index, sub, data } => {
                        (sdo::UPLOADED_EXPEDITED | ((4 - data.len) << 2), (index, sub), data.bytes)
                    }
                    SdoResponse::Abort { index, sub, code } => (sdo::ABORT, (index, sub), code.to_le_bytes()),
                };
                sdo_frame(&mut buf, cmd, index, sub, payload)?;
                (cob::SDO_RESPONSE + u16::from(node.get()), 8)
            }
            Self::Pdo { direction, number, node, data } => {
                if !(1..=4).contains(&number) {
                    return None;
                }
                let base = match direction {
                    PdoDirection::Transmit => cob::TPDO1,
                    PdoDirection::Receive => cob::RPDO1,
                };
                buf[..usize::from(data.len)].copy_from_slice(data.bytes());
                (base + 0x100 * u16::from(number - 1) + u16::from(node.get()), usize::from(data.len))
            }
        };
        CanFrame::new(CanId::Standard(id), &buf[..len]).ok()
    }
}

fn sdo_frame(buf: &mut [u8; 8], cmd: u8, index: u16, sub: u8, payload: [u8; 4]) -> Option<()> {
    let mut w = Writer::new(buf);
    w.u8(cmd)?;
    w.u16(index)?;
    w.u8(sub)?;
    w.put(&payload)
}

/// The object and the four data bytes of an SDO frame (eight bytes, checked by the caller).
fn sdo_fields(data: &[u8]) -> (u8, u16, u8, [u8; 4]) {
    let mut payload = [0; 4];
    payload.copy_from_slice(&data[4..8]);
    (data[0], u16::from_le_bytes([data[1], data[2]]), data[3], payload)
}

fn parse_request(data: &[u8]) -> Result<SdoRequest, CanOpenError> {
    let (cmd, index, sub, payload) = sdo_fields(data);
    match sdo::specifier(cmd) {
        1 if sdo::expedited_sized(cmd) => {
            let data = SdoData::new(&payload[..sdo::len(cmd)]).ok_or(CanOpenError::UnknownSdoCommand(cmd))?;
            Ok(SdoRequest::Download { index, sub, data })
        }
        1 => Err(CanOpenError::UnsupportedSdo(cmd)),
        2 => Ok(SdoRequest::Upload { index, sub }),
        4 => Ok(SdoRequest::Abort { index, sub, code: u32::from_le_bytes(payload) }),
        0 | 3 | 5 | 6 => Err(CanOpenError::UnsupportedSdo(cmd)),
        _ => Err(CanOpenError::UnknownSdoCommand(cmd)),
    }
}

fn parse_response(data: &[u8]) -> Result<SdoResponse, CanOpenError> {
    let (cmd, index, sub, payload) = sdo_fields(data);
    match sdo::specifier(cmd) {
        2 if sdo::expedited_sized(cmd) => {
            let data = SdoData::new(&payload[..sdo::len(cmd)]).ok_or(CanOpenError::UnknownSdoCommand(cmd))?;
            Ok(SdoResponse::Uploaded { index, sub, data })
        }
        2 => Err(CanOpenError::UnsupportedSdo(cmd)),
        3 => Ok(SdoResponse::Downloaded { index, sub }),
        4 => Ok(SdoResponse::Abort { index, sub, code: u32::from_le_bytes(payload) }),
        0 | 1 | 5 | 6 => Err(CanOpenError::UnsupportedSdo(cmd)),
        _ => Err(CanOpenError::UnknownSdoCommand(cmd)),
    }
}

/// A PDO mapping entry (the value written to 0x1600/0x1A00 sub n): object, sub, bits.
pub const fn mapping_entry(index: u16, sub: u8, bits: u8) -> u32 {
    (index as u32) << 16 | (sub as u32) << 8 | bits as u32
}

#[cfg(test)]
mod tests;
