//! The CAN link as the core sees it: frames to the motors' master, the bus's and the
//! adapter's errors named, the link's loss and return.

use flowgate_protocol::CanFrame;

use super::{CanEvent, Core, Output, StageClock, StopReason, REOPEN_EVERY};
use crate::time::HostTime;

/// Transmits an SLCAN adapter may refuse within a second: beyond, the commands are not
/// reaching the board.
pub(super) const TX_REFUSED_PER_S: u32 = 3;
/// A refused transmit asks for the adapter's status, at most this often.
const STATUS_REPOLL: std::time::Duration = std::time::Duration::from_millis(10);

impl<K: StageClock> Core<K> {
    /// A CAN event at `now`.
    pub(super) fn can_event(&mut self, now: HostTime, event: CanEvent) {
        match event {
            CanEvent::Frame(f) => self.can_frame(now, &f),
            CanEvent::Garbled => self.counters.can_undecodable += 1,
            CanEvent::TransmitRefused => {
                self.counters.can_tx_refused += 1;
                if self.links.tx_refused.exceeded(now) && self.state().is_active() {
                    self.stop(now, StopReason::CanTransmitRefused);
                } else if now.since(self.links.status_polled) >= STATUS_REPOLL {
                    // Ask why at once: a bus-off adapter says so in its flags.
                    self.links.status_polled = now;
                    self.out.push(Output::PollCanStatus);
                }
            }
            CanEvent::AdapterStatus { bus_off, error_passive } => {
                if error_passive {
                    self.counters.can_error_passive += 1;
                }
                if bus_off {
                    self.counters.can_error_frames += 1;
                    self.links.bus_off = true;
                    self.stop_if_active(now, StopReason::BusOff);
                } else {
                    self.links.bus_off = false;
                }
            }
            CanEvent::ErrorFrame { bus_off } => {
                self.counters.can_error_frames += 1;
                if bus_off {
                    self.links.bus_off = true;
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
    pub(super) fn can_failed(&mut self, now: HostTime) {
        self.can_lost(now);
        self.stop(now, StopReason::CanLinkLost);
    }

    /// The CAN link is gone: ask for it again a little later (once per loss: a link
    /// failing again while it is lost changes nothing).
    fn can_lost(&mut self, now: HostTime) {
        if self.links.can_up {
            self.links.can_reopen_at = now + REOPEN_EVERY;
        }
        self.links.can_up = false;
    }

    /// The CAN link is open again after a loss (the core stays faulted until reset).
    pub(super) fn can_reopened(&mut self) {
        self.counters.can_reconnects += 1;
        self.links.can_up = true;
        self.links.can_reopen_at = HostTime::NEVER;
    }

    /// A frame from the bus: the motors' master says what it was and what it asks for.
    fn can_frame(&mut self, now: HostTime, frame: &CanFrame) {
        self.counters.can_frames_in += 1;
        self.links.bus_off = false;
        let state = self.state();
        let effect = self.motors.frame(now, frame, state, &mut self.counters, &mut self.out.can());
        if effect.second_master {
            self.links.second_master_heard = Some(now);
        }
        if let Some(reason) = effect.stop {
            self.stop(now, reason);
        }
        if effect.enable_again {
            self.act(now, super::safety::Action::EnableBoard);
        }
        if effect.settle {
            self.check_at_rest(now);
        }
    }
}
