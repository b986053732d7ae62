//! The CAN link as the core sees it: frames to the motors' master, the bus's and the
//! adapter's errors named, the link's loss and return.

use flowgate_protocol::CanFrame;

use super::budget::Budget;
use super::ROBOT;
use super::{CanEvent, Core, Output, StageClock, StopReason, REOPEN_EVERY};
use crate::time::HostTime;

/// Transmits an SLCAN adapter may refuse within a second: beyond, the commands are not
/// reaching the board.
pub(super) const TX_REFUSED_PER_S: u32 = 3;
/// A refused transmit asks for the adapter's status, at most this often.
const STATUS_REPOLL: std::time::Duration = std::time::Duration::from_millis(10);

/// The CAN link's health: up or lost (and when to ask for it again), the adapter's refused
/// transmits, our controller's bus-off, another master heard. One value a link: its fields
/// change only through its methods.
#[derive(Debug)]
pub(super) struct CanLinkHealth {
    /// Transmits the SLCAN adapter refused within the last second, and when its status was
    /// last asked for.
    tx_refused: Budget,
    status_polled: HostTime,
    /// Open (not failed or down since it last opened).
    up: bool,
    /// When to ask for the lost link to be opened again.
    reopen_at: HostTime,
    /// When another device's command to our motors was last heard.
    second_master_heard: Option<HostTime>,
    /// Our CAN controller reported bus-off, and nothing has been heard on the bus since:
    /// what goes unheard meanwhile is the bus-off's doing.
    bus_off: bool,
}

/// What a refused transmit calls for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Refused {
    /// More than the budget within a second: the commands are not reaching the board.
    BeyondBudget,
    /// Ask the adapter why (a bus-off adapter says so in its flags).
    PollStatus,
    /// Asked very recently already.
    Counted,
}

impl CanLinkHealth {
    /// A link just opened.
    pub(super) fn new() -> Self {
        Self {
            tx_refused: Budget::new(TX_REFUSED_PER_S),
            status_polled: HostTime::ZERO,
            up: true,
            reopen_at: HostTime::NEVER,
            second_master_heard: None,
            bus_off: false,
        }
    }

    /// A transmit refused at `now`; `active`: the gateway's watchdogs are armed.
    pub(super) fn transmit_refused(&mut self, now: HostTime, active: bool) -> Refused {
        if self.tx_refused.exceeded(now) && active {
            Refused::BeyondBudget
        } else if now.since(self.status_polled) >= STATUS_REPOLL {
            self.status_polled = now;
            Refused::PollStatus
        } else {
            Refused::Counted
        }
    }

    /// The adapter's status was asked for at `now`.
    pub(super) fn status_asked(&mut self, now: HostTime) {
        self.status_polled = now;
    }

    /// Our controller is bus-off, or back on the bus.
    pub(super) fn set_bus_off(&mut self, bus_off: bool) {
        self.bus_off = bus_off;
    }

    /// A frame heard at `now`; `second_master`: it was another device commanding our motors.
    pub(super) fn heard(&mut self, now: HostTime, second_master: bool) {
        self.bus_off = false;
        if second_master {
            self.second_master_heard = Some(now);
        }
    }

    /// The link is gone: ask for it again a little later (once per loss: a link failing
    /// again while it is lost changes nothing).
    pub(super) fn lost(&mut self, now: HostTime) {
        if self.up {
            self.reopen_at = now + REOPEN_EVERY;
        }
        self.up = false;
    }

    /// The link opened again.
    pub(super) fn reopened(&mut self) {
        self.up = true;
        self.reopen_at = HostTime::NEVER;
    }

    /// The reopen was asked for at `now`: the next ask, should this one fail.
    pub(super) fn reopen_asked(&mut self, now: HostTime) {
        self.reopen_at = now + REOPEN_EVERY;
    }

    pub(super) fn is_up(&self) -> bool {
        self.up
    }

    pub(super) fn is_bus_off(&self) -> bool {
        self.bus_off
    }

    pub(super) fn reopen_at(&self) -> HostTime {
        self.reopen_at
    }

    /// Another master was heard within `window` of `now`.
    pub(super) fn second_master_within(&self, now: HostTime, window: std::time::Duration) -> bool {
        self.second_master_heard.is_some_and(|at| now < at + window)
    }

    /// The refused transmits' window, in elements of capacity.
    pub(super) fn footprint(&self) -> usize {
        self.tx_refused.capacity()
    }
}

impl<K: StageClock> Core<K> {
    /// A CAN event at `now`.
    pub(super) fn can_event(&mut self, now: HostTime, event: CanEvent) {
        match event {
            CanEvent::Frame(f) => self.can_frame(now, &f),
            CanEvent::Garbled => self.counters.can_undecodable += 1,
            CanEvent::TransmitRefused => {
                self.counters.can_tx_refused += 1;
                match self.can_link.transmit_refused(now, self.any_active()) {
                    Refused::BeyondBudget => self.stop(now, StopReason::CanTransmitRefused),
                    // Ask why at once: a bus-off adapter says so in its flags.
                    Refused::PollStatus => self.out.push(Output::PollCanStatus),
                    Refused::Counted => {}
                }
            }
            CanEvent::AdapterStatus { bus_off, error_passive } => {
                if error_passive {
                    self.counters.can_error_passive += 1;
                }
                self.can_link.set_bus_off(bus_off);
                if bus_off {
                    self.counters.can_error_frames += 1;
                    self.stop_if_active(now, StopReason::BusOff);
                }
            }
            CanEvent::ErrorFrame { bus_off } => {
                self.counters.can_error_frames += 1;
                if bus_off {
                    self.can_link.set_bus_off(true);
                    self.stop(now, StopReason::BusOff);
                }
            }
            CanEvent::InterfaceDown => {
                self.can_link.lost(now);
                self.stop(now, StopReason::CanInterfaceDown);
            }
        }
    }

    /// The CAN link failed (a write error or timeout, the adapter gone).
    pub(super) fn can_failed(&mut self, now: HostTime) {
        self.can_link.lost(now);
        self.stop(now, StopReason::CanLinkLost);
    }

    /// The CAN link is open again after a loss (the core stays faulted until reset).
    pub(super) fn can_reopened(&mut self) {
        self.counters.can_reconnects += 1;
        self.can_link.reopened();
    }

    /// A frame from the bus: the vehicle whose motors it addresses takes it (the robot any
    /// that none does, to count it), and their master says what it was and asks for. A
    /// board's e-stop input stops every vehicle.
    fn can_frame(&mut self, now: HostTime, frame: &CanFrame) {
        self.counters.can_frames_in += 1;
        let k = (ROBOT + 1..self.vehicles.len()).find(|&k| self.vehicles[k].motors.addresses(frame)).unwrap_or(ROBOT);
        let state = self.vehicles[k].state();
        let effect = self.vehicles[k].motors.frame(now, frame, state, &mut self.motor_counters, &mut self.out.can());
        self.can_link.heard(now, effect.second_master);
        match effect.stop {
            // A board's e-stop input is the rig's e-stop: every vehicle stops.
            Some(reason @ StopReason::BoardEStop { .. }) => self.stop(now, reason),
            Some(reason) => self.stop_vehicle(k, now, reason),
            None => {}
        }
        if effect.enable_again {
            self.act(k, now, super::safety::Action::EnableBoard);
        }
        if effect.settle {
            self.check_at_rest(k, now);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two links are two values: one lost, refused and bus-off changes nothing of the other.
    #[test]
    fn two_can_links_side_by_side() {
        let t = |ms: u64| HostTime::from_nanos(ms * 1_000_000);
        let (mut a, mut b) = (CanLinkHealth::new(), CanLinkHealth::new());
        a.lost(t(10));
        a.lost(t(50)); // lost again while lost: the first reopen stands
        a.set_bus_off(true);
        assert!(!a.is_up() && a.is_bus_off());
        assert_eq!(a.reopen_at(), t(10) + REOPEN_EVERY);
        assert!(b.is_up() && !b.is_bus_off() && b.reopen_at() == HostTime::NEVER);
        // The refused transmits count against each link's own budget.
        for k in 0..=TX_REFUSED_PER_S {
            let refused = a.transmit_refused(t(100 + u64::from(k) * 20), true);
            assert_eq!(refused == Refused::BeyondBudget, k == TX_REFUSED_PER_S, "transmit {k}");
        }
        assert_eq!(b.transmit_refused(t(200), true), Refused::PollStatus);
        b.heard(t(210), true);
        assert!(b.second_master_within(t(300), std::time::Duration::from_millis(100)));
        assert!(!a.second_master_within(t(300), std::time::Duration::from_millis(100)));
        a.reopened();
        a.heard(t(400), false);
        assert!(a.is_up() && !a.is_bus_off() && a.reopen_at() == HostTime::NEVER);
    }
}
