//! A USB-CAN adapter in SLCAN (LAWICEL) mode, as the simulator plays it on a pty: the host
//! side speaks SLCAN, the bus side is the simulated CAN bus with the motor board on it.

use flowgate_protocol::slcan::{Bitrate, Command, Response};
use flowgate_protocol::CanFrame;

/// Adapter identity in `V` and `N` replies.
pub const VERSION: (u8, u8) = (10, 13);
pub const SERIAL: [u8; 4] = *b"FG01";

#[derive(Debug)]
pub struct SlcanAdapter {
    open: bool,
    listen_only: bool,
    bitrate: Option<Bitrate>,
    timestamps: bool,
    /// Lines the adapter refused (BEL).
    pub errors: u64,
    /// The adapter's own CAN controller is held bus-off (a fault the simulator injects): it
    /// sends nothing, refuses transmits and says so in its status flags.
    pub bus_off: bool,
    /// The bitrate the bus runs at. An adapter opened at another rate sees only bit errors:
    /// nothing it receives is a frame, and nothing it sends is acknowledged.
    pub bus_bitrate: Bitrate,
    /// The controller's transmit error counter (ISO 11898-1: +8 an error, error passive from
    /// 128, bus-off at 256); closing the channel resets the controller.
    tec: u16,
}

impl Default for SlcanAdapter {
    fn default() -> Self {
        Self {
            open: false,
            listen_only: false,
            bitrate: None,
            timestamps: false,
            errors: 0,
            bus_off: false,
            bus_bitrate: Bitrate::M1,
            tec: 0,
        }
    }
}

/// Status flags while bus-off: bus error, error passive, transmit FIFO full.
pub const BUS_OFF_FLAGS: u8 = 0x80 | 0x20 | 0x02;
/// Status flags while error passive: bus error, error passive.
pub const ERROR_PASSIVE_FLAGS: u8 = 0x80 | 0x20;
/// A frame the controller cannot get acknowledged is sent again at once, some sixteen times
/// before the host asks anything more: each adds 8 to the transmit error counter.
const TEC_PER_FAILED_TRANSMIT: u16 = 16 * 8;

impl SlcanAdapter {
    pub fn is_open(&self) -> bool {
        self.open
    }
    pub fn bitrate(&self) -> Option<Bitrate> {
        self.bitrate
    }

    /// Whether its controller is off the bus: held there by a fault, or by its own errors.
    fn off(&self) -> bool {
        self.bus_off || self.tec >= 256
    }

    /// Opened at another rate than the bus's: every bit on the wire is an error to it.
    fn mismatched(&self) -> bool {
        self.open && self.bitrate.is_some_and(|b| b != self.bus_bitrate)
    }

    /// The LAWICEL status flags (`F`).
    pub fn status_flags(&self) -> u8 {
        if self.off() {
            BUS_OFF_FLAGS
        } else if self.tec >= 128 {
            ERROR_PASSIVE_FLAGS
        } else {
            0
        }
    }

    /// One line from the host (or the error it decoded to). Replies go to `to_host`, a
    /// frame to transmit goes to `to_bus`.
    pub fn handle(&mut self, line: Option<Command>, to_host: &mut Vec<Response>, to_bus: &mut Vec<CanFrame>) {
        let ok = match line {
            None => false,
            Some(Command::Transmit(frame)) if self.open && !self.listen_only && !self.off() => {
                if self.mismatched() {
                    // Queued, but never acknowledged on the bus: retried until error passive,
                    // and at the next such frame bus-off.
                    self.tec = (self.tec + TEC_PER_FAILED_TRANSMIT).min(256);
                } else {
                    to_bus.push(frame);
                }
                to_host.push(Response::TxAck { extended: frame.id().is_extended() });
                return;
            }
            Some(Command::Transmit(_)) => false,
            Some(Command::SetBitrate(b)) if !self.open => {
                self.bitrate = Some(b);
                true
            }
            Some(Command::Timestamps(on)) if !self.open => {
                self.timestamps = on;
                true
            }
            Some(Command::SetBitrate(_) | Command::Timestamps(_)) => false,
            Some(Command::Open) | Some(Command::ListenOnly) if self.open => false,
            Some(Command::Open) => {
                self.open = true;
                self.listen_only = false;
                true
            }
            Some(Command::ListenOnly) => {
                self.open = true;
                self.listen_only = true;
                true
            }
            Some(Command::Close) => {
                self.open = false;
                self.tec = 0;
                true
            }
            Some(Command::Version) => {
                to_host.push(Response::Version { hardware: VERSION.0, software: VERSION.1 });
                return;
            }
            Some(Command::SerialNumber) => {
                to_host.push(Response::SerialNumber(SERIAL));
                return;
            }
            Some(Command::StatusFlags) => {
                to_host.push(Response::StatusFlags(self.status_flags()));
                return;
            }
            Some(Command::Empty) => true,
        };
        if ok {
            to_host.push(Response::Ok);
        } else {
            self.errors += 1;
            to_host.push(Response::Error);
        }
    }

    /// A frame seen on the bus, as the host receives it (only while the channel is open).
    pub fn from_bus(&self, frame: CanFrame, t: f64) -> Option<Response> {
        (self.open && !self.off() && !self.mismatched()).then(|| Response::Frame {
            frame,
            timestamp_ms: self.timestamps.then_some(((t * 1000.0) as u64 % 60_000) as u16),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowgate_protocol::CanId;

    #[test]
    fn python_can_start_sequence_then_traffic() {
        let mut a = SlcanAdapter { bus_bitrate: Bitrate::K500, ..SlcanAdapter::default() };
        let (mut host, mut bus) = (Vec::new(), Vec::new());
        for cmd in [Command::Close, Command::SetBitrate(Bitrate::K500), Command::Empty, Command::Open] {
            a.handle(Some(cmd), &mut host, &mut bus);
        }
        assert_eq!(host, vec![Response::Ok; 4]);
        let f = CanFrame::new(CanId::Standard(0x101), &[1, 2, 3]).unwrap();
        host.clear();
        a.handle(Some(Command::Transmit(f)), &mut host, &mut bus);
        assert_eq!(bus, vec![f]);
        assert_eq!(host, vec![Response::TxAck { extended: false }]);
        assert!(a.from_bus(f, 1.0).is_some());
    }

    /// As protocol/README.md says: remote frames are answered like data frames (`z`),
    /// timestamps are set only while the channel is closed, and a bus-off adapter refuses
    /// transmits and says so in its status flags.
    #[test]
    fn answers_as_documented() {
        let mut a = SlcanAdapter::default();
        let (mut host, mut bus) = (Vec::new(), Vec::new());
        for cmd in [Command::Timestamps(true), Command::Open, Command::Timestamps(false)] {
            a.handle(Some(cmd), &mut host, &mut bus);
        }
        assert_eq!(host, vec![Response::Ok, Response::Ok, Response::Error], "Z1 closed: ok; Z0 open: BEL");
        host.clear();
        let remote = CanFrame::remote(CanId::Standard(0x201), 4).unwrap();
        a.handle(Some(Command::Transmit(remote)), &mut host, &mut bus);
        assert_eq!(host, vec![Response::TxAck { extended: false }], "a remote frame is acked `z`");
        assert_eq!(bus, vec![remote]);
        host.clear();
        a.bus_off = true;
        a.handle(Some(Command::Transmit(remote)), &mut host, &mut bus);
        a.handle(Some(Command::StatusFlags), &mut host, &mut bus);
        assert_eq!(host, vec![Response::Error, Response::StatusFlags(BUS_OFF_FLAGS)]);
        assert_eq!(bus.len(), 1, "nothing sent while bus-off");
    }

    /// An adapter opened at another rate than the bus's receives nothing, and its transmits,
    /// never acknowledged, take it error passive and then bus-off, as a CAN controller's
    /// error counters do; closing the channel resets it.
    #[test]
    fn a_bitrate_other_than_the_buss_ends_bus_off() {
        let mut a = SlcanAdapter::default();
        let (mut host, mut bus) = (Vec::new(), Vec::new());
        for cmd in [Command::SetBitrate(Bitrate::K500), Command::Open] {
            a.handle(Some(cmd), &mut host, &mut bus);
        }
        let f = CanFrame::new(CanId::Standard(0x101), &[1]).unwrap();
        assert!(a.from_bus(f, 0.0).is_none(), "nothing received at the wrong rate");
        host.clear();
        a.handle(Some(Command::Transmit(f)), &mut host, &mut bus);
        a.handle(Some(Command::StatusFlags), &mut host, &mut bus);
        a.handle(Some(Command::Transmit(f)), &mut host, &mut bus);
        a.handle(Some(Command::StatusFlags), &mut host, &mut bus);
        a.handle(Some(Command::Transmit(f)), &mut host, &mut bus);
        assert_eq!(
            host,
            vec![
                Response::TxAck { extended: false },
                Response::StatusFlags(ERROR_PASSIVE_FLAGS),
                Response::TxAck { extended: false },
                Response::StatusFlags(BUS_OFF_FLAGS),
                Response::Error,
            ]
        );
        assert!(bus.is_empty(), "nothing reached the bus");
        host.clear();
        for cmd in [Command::Close, Command::SetBitrate(Bitrate::M1), Command::Open, Command::StatusFlags] {
            a.handle(Some(cmd), &mut host, &mut bus);
        }
        assert_eq!(host.last(), Some(&Response::StatusFlags(0)), "reopened at the bus's rate");
        assert!(a.from_bus(f, 0.0).is_some());
    }

    #[test]
    fn refuses_what_lawicel_refuses() {
        let mut a = SlcanAdapter::default();
        let (mut host, mut bus) = (Vec::new(), Vec::new());
        let f = CanFrame::new(CanId::Standard(0x101), &[]).unwrap();
        a.handle(Some(Command::Transmit(f)), &mut host, &mut bus); // closed
        a.handle(None, &mut host, &mut bus); // garbage
        a.handle(Some(Command::Open), &mut host, &mut bus);
        a.handle(Some(Command::SetBitrate(Bitrate::M1)), &mut host, &mut bus); // while open
        assert_eq!(host, vec![Response::Error, Response::Error, Response::Ok, Response::Error]);
        assert!(bus.is_empty());
        assert_eq!(a.errors, 3);
        assert!(SlcanAdapter::default().from_bus(f, 0.0).is_none(), "closed: nothing goes to the host");
    }
}
