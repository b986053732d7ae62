//! Everything that reaches the gateway core, as one type.
//!
//! The shell hands each input to [`Core::handle`](super::Core::handle) with the host time it
//! happened at; a recording keeps exactly these (`flowgate run --record`), and a replay hands
//! them back in the same order with the same times (`flowgate replay`). Because the core
//! reads no clock and no I/O of its own, that reproduces every decision it made: the CAN
//! frames it asked for, byte for byte.

use flowgate_protocol::CanFrame;

use super::operator::{Refusal, Request, Status};
use crate::time::HostTime;

/// The most bytes one PSD read hands the core, and one input record holds.
pub const PSD_CHUNK: usize = 256;

/// What a CAN link delivers: frames, and what else the bus says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CanEvent {
    Frame(CanFrame),
    /// A SocketCAN error frame; `bus_off` when the controller went bus-off.
    ErrorFrame {
        bus_off: bool,
    },
    /// A line from an SLCAN adapter that did not parse.
    Garbled,
    /// An SLCAN adapter refused a line (BEL): after the channel is open, a transmit.
    TransmitRefused,
    /// An SLCAN adapter's status flags (`F`). LAWICEL has no bus-off flag: a bus error (bit 7)
    /// with the transmit FIFO full (bit 1) is the adapter's controller no longer sending,
    /// which is what bus-off means to the gateway.
    AdapterStatus {
        bus_off: bool,
        error_passive: bool,
    },
    /// The SocketCAN interface went down or away (`ip link set down`, a `slcand` that
    /// exited, a USB adapter pulled): not the bus, the host's own interface.
    InterfaceDown,
}

/// One input to the core.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Input<'a> {
    /// The PSD serial line opened (at start, or reopened after a loss).
    PsdConnected,
    /// The PSD serial line failed (read error, end of file, write timeout).
    PsdLost,
    /// Bytes read from the PSD serial line.
    PsdBytes(&'a [u8]),
    /// A CAN event: a frame, an error frame, an adapter's status.
    Can(CanEvent),
    /// The CAN link failed (a write error or timeout, the interface gone).
    CanFailed,
    /// The CAN link is open again.
    CanReopened,
    /// An operator's request (the core answers it).
    Request(&'a Request),
    /// An operator's request for one vehicle: 0 the robot, then the `[[vehicles]]` in order.
    VehicleRequest { vehicle: u8, request: &'a Request },
    /// Arm and start towards the rig's goal once the controller streams (`run --arm`).
    ArmAtStart,
    /// Stop in order and end the run.
    Shutdown,
    /// The core's deadline came (or the shell woke for its own reasons).
    Tick,
}

impl Input<'_> {
    /// The input's name in recordings.
    pub fn kind(&self) -> &'static str {
        match self {
            Input::PsdConnected => "psd_connected",
            Input::PsdLost => "psd_lost",
            Input::PsdBytes(_) => "psd_bytes",
            Input::Can(_) => "can",
            Input::CanFailed => "can_failed",
            Input::CanReopened => "can_reopened",
            Input::Request(_) => "request",
            Input::VehicleRequest { .. } => "vehicle_request",
            Input::ArmAtStart => "arm_at_start",
            Input::Shutdown => "shutdown",
            Input::Tick => "tick",
        }
    }
}

/// The core's answer to an operator's request: accepted or refused (and why), and the
/// status when the request asked for it or was accepted.
#[derive(Debug, Clone, PartialEq)]
pub struct Answer {
    pub result: Result<(), Refusal>,
    pub status: Option<Status>,
}

/// One input to the core as recorded: it owns its bytes (a fixed chunk: queueing it does
/// not allocate; requests are rare and boxed).
// Large by design: a record is copied into the queue, never boxed (no allocation per cycle).
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum RecordedInput {
    PsdConnected,
    PsdLost,
    PsdBytes { len: u16, bytes: [u8; PSD_CHUNK] },
    Can(CanEvent),
    CanFailed,
    CanReopened,
    Request(Box<Request>),
    VehicleRequest { vehicle: u8, request: Box<Request> },
    ArmAtStart,
    Shutdown,
    Tick,
}

impl RecordedInput {
    /// A copy of `input`. PSD reads longer than [`PSD_CHUNK`] are cut there (the shell never
    /// reads more at once).
    pub fn of(input: Input<'_>) -> Self {
        match input {
            Input::PsdConnected => Self::PsdConnected,
            Input::PsdLost => Self::PsdLost,
            Input::PsdBytes(b) => {
                let len = b.len().min(PSD_CHUNK);
                let mut bytes = [0; PSD_CHUNK];
                bytes[..len].copy_from_slice(&b[..len]);
                Self::PsdBytes { len: len as u16, bytes }
            }
            Input::Can(e) => Self::Can(e),
            Input::CanFailed => Self::CanFailed,
            Input::CanReopened => Self::CanReopened,
            Input::Request(r) => Self::Request(Box::new(r.clone())),
            Input::VehicleRequest { vehicle, request } => {
                Self::VehicleRequest { vehicle, request: Box::new(request.clone()) }
            }
            Input::ArmAtStart => Self::ArmAtStart,
            Input::Shutdown => Self::Shutdown,
            Input::Tick => Self::Tick,
        }
    }

    /// The input to hand the core.
    pub fn as_input(&self) -> Input<'_> {
        match self {
            Self::PsdConnected => Input::PsdConnected,
            Self::PsdLost => Input::PsdLost,
            Self::PsdBytes { len, bytes } => Input::PsdBytes(&bytes[..usize::from(*len)]),
            Self::Can(e) => Input::Can(*e),
            Self::CanFailed => Input::CanFailed,
            Self::CanReopened => Input::CanReopened,
            Self::Request(r) => Input::Request(r),
            Self::VehicleRequest { vehicle, request } => Input::VehicleRequest { vehicle: *vehicle, request },
            Self::ArmAtStart => Input::ArmAtStart,
            Self::Shutdown => Input::Shutdown,
            Self::Tick => Input::Tick,
        }
    }
}

/// An input with its place in the run: `seq` counts every input the loop took (a dropped
/// record leaves a gap), `at` is when.
#[derive(Debug, Clone, PartialEq)]
pub struct InputRecord {
    pub seq: u64,
    pub at: HostTime,
    pub input: RecordedInput,
}
