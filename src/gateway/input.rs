//! Everything that reaches the gateway core, as one type.
//!
//! The shell hands each input to [`Core::handle`](super::Core::handle) with the host time it
//! happened at; a recording keeps exactly these (`flowgate run --record`), and a replay hands
//! them back in the same order with the same times (`flowgate replay`). Because the core
//! reads no clock and no I/O of its own, that reproduces every decision it made: the CAN
//! frames it asked for, byte for byte.

use super::operator::{Refusal, Request, Status};
use crate::link::CanEvent;

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
