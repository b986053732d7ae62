//! Everything the core asks of its caller, and the queue it is drained from.

use std::collections::VecDeque;

use flowgate_protocol::psd::Packet;
use flowgate_protocol::CanFrame;

use super::notice::Notice;
use super::psd_session::SetupError;
use super::safety::State;
use super::timing::CycleRecord;
use crate::time::HostTime;

/// What the core asks of its caller.
#[derive(Debug, Clone, PartialEq)]
pub enum Output {
    /// A packet for the PSD controller.
    Psd(Packet),
    /// A CAN frame (board configuration, stops, heartbeats).
    Can(CanFrame),
    /// A cycle's velocity command: write `frame`, then complete `record` with
    /// [`CycleRecord::written`] and record it.
    Command { frame: CanFrame, record: CycleRecord },
    /// Vehicle `vehicle`'s safety state changed (0: the robot's; then `[[vehicles]]` in
    /// order).
    State { at: HostTime, vehicle: usize, state: State },
    /// Ask the CAN link for its controller's state (an SLCAN adapter's status flags).
    PollCanStatus,
    /// The PSD controller is configured and streaming.
    Streaming,
    /// The PSD controller could not be configured; the caller closes the line and hands
    /// the core [`Input::PsdLost`](super::Input::PsdLost) (or gives up, if it never streamed).
    SetupFailed(SetupError),
    /// Open the lost PSD serial line again, and hand the core
    /// [`Input::PsdConnected`](super::Input::PsdConnected) once it is open. A failed attempt
    /// needs no answer: the core asks again every [`REOPEN_EVERY`](super::REOPEN_EVERY).
    OpenPsd,
    /// Open the lost CAN link again (it may take its time: an SLCAN adapter answers three
    /// commands), and hand the core [`Input::CanReopened`](super::Input::CanReopened) once it
    /// is open. The core asks again every [`REOPEN_EVERY`](super::REOPEN_EVERY); an attempt
    /// still under way when it does goes on.
    OpenCan,
    /// Something to log and keep in the durable event log, at `at`.
    Notice { at: HostTime, notice: Notice },
}

/// The outputs waiting to be drained, in order (allocated once: a cycle pushes a handful).
#[derive(Debug)]
pub struct Outbox(VecDeque<Output>);

impl Outbox {
    pub fn new() -> Self {
        Self(VecDeque::with_capacity(64))
    }

    pub fn push(&mut self, output: Output) {
        self.0.push_back(output);
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    pub fn pop(&mut self) -> Option<Output> {
        self.0.pop_front()
    }

    pub fn capacity(&self) -> usize {
        self.0.capacity()
    }

    /// A sink for packets to the PSD controller.
    pub fn psd(&mut self) -> impl FnMut(Packet) + '_ {
        |p| self.0.push_back(Output::Psd(p))
    }

    /// A sink for CAN frames.
    pub fn can(&mut self) -> impl FnMut(CanFrame) + '_ {
        |f| self.0.push_back(Output::Can(f))
    }
}
