//! A USB-CAN adapter in SLCAN (LAWICEL) mode, as the simulator plays it on a pty: the host
//! side speaks SLCAN, the bus side is the simulated CAN bus with the motor board on it.

use flowgate_protocol::slcan::{Bitrate, Command, Response};
use flowgate_protocol::CanFrame;

/// Adapter identity in `V` and `N` replies.
pub const VERSION: (u8, u8) = (10, 13);
pub const SERIAL: [u8; 4] = *b"FG01";

#[derive(Debug, Default)]
pub struct SlcanAdapter {
    open: bool,
    listen_only: bool,
    bitrate: Option<Bitrate>,
    timestamps: bool,
    /// Lines the adapter refused (BEL).
    pub errors: u64,
    /// The adapter's own CAN controller is bus-off: it sends nothing, refuses transmits and
    /// says so in its status flags.
    pub bus_off: bool,
}

/// Status flags while bus-off: bus error, error passive, transmit FIFO full.
pub const BUS_OFF_FLAGS: u8 = 0x80 | 0x20 | 0x02;

impl SlcanAdapter {
    pub fn is_open(&self) -> bool {
        self.open
    }
    pub fn bitrate(&self) -> Option<Bitrate> {
        self.bitrate
    }

    /// One line from the host (or the error it decoded to). Replies go to `to_host`, a
    /// frame to transmit goes to `to_bus`.
    pub fn handle(&mut self, line: Option<Command>, to_host: &mut Vec<Response>, to_bus: &mut Vec<CanFrame>) {
        let ok = match line {
            None => false,
            Some(Command::Transmit(frame)) if self.open && !self.listen_only && !self.bus_off => {
                to_bus.push(frame);
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
                to_host.push(Response::StatusFlags(if self.bus_off { BUS_OFF_FLAGS } else { 0 }));
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
        (self.open && !self.bus_off).then(|| Response::Frame {
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
        let mut a = SlcanAdapter::default();
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
