//! SLCAN (LAWICEL CAN232/CANUSB ASCII protocol), for both ends of the serial line:
//! the host that drives a USB-CAN adapter (CANable, USBtin, ...), and an adapter (the
//! simulator plays one on a pty).
//!
//! ## Lines
//!
//! Host -> adapter ([`Command`]), each ended by CR (`\r`):
//!
//! | line                   | meaning                                          |
//! |------------------------|--------------------------------------------------|
//! | `tiiildd..`            | send standard data frame: 3 hex id, DLC, 2 hex/byte |
//! | `Tiiiiiiiildd..`       | send extended data frame: 8 hex id               |
//! | `riiil` / `Riiiiiiiil` | send standard / extended remote frame            |
//! | `S0`..`S8`             | bitrate 10k 20k 50k 100k 125k 250k 500k 800k 1M  |
//! | `O` / `L` / `C`        | open / open listen-only / close the channel      |
//! | `V` / `N` / `F`        | version / serial number / status flags           |
//! | `Z0` / `Z1`            | receive timestamps off / on                      |
//! | (empty)                | no-op; python-can sends one after `Sn`           |
//!
//! Adapter -> host ([`Response`]):
//!
//! | line                   | meaning                                          |
//! |------------------------|--------------------------------------------------|
//! | `\r`                   | OK                                               |
//! | `\x07` (BEL, no CR)    | error                                            |
//! | `z\r` / `Z\r`          | transmit acknowledged (std / ext), some adapters |
//! | `t..`/`T..`/`r..`/`R..`| a received frame, then 4 hex ms (0-EA5F) when `Z1` |
//! | `Vhhss\r`              | hardware and software version, two digits each   |
//! | `Nxxxx\r`              | serial number, four characters                   |
//! | `Fxx\r`                | status flags, hex ([`status`])                   |
//!
//! Parsing takes one line *including* its terminator, accepts upper- or lower-case hex,
//! and never panics. Emitting writes upper-case hex, as adapters do.

use crate::can::{CanFrame, CanId, MAX_EXTENDED_ID, MAX_STANDARD_ID};

/// The longest line either side sends: `T` + 8 id + DLC + 16 data + 4 timestamp + CR.
pub const MAX_LINE_LEN: usize = 31;
pub const CR: u8 = b'\r';
pub const BEL: u8 = 0x07;

/// Status flag bits of the `F` reply (LAWICEL).
pub mod status {
    pub const RX_FIFO_FULL: u8 = 1 << 0;
    pub const TX_FIFO_FULL: u8 = 1 << 1;
    pub const ERROR_WARNING: u8 = 1 << 2;
    pub const DATA_OVERRUN: u8 = 1 << 3;
    pub const ERROR_PASSIVE: u8 = 1 << 5;
    pub const ARBITRATION_LOST: u8 = 1 << 6;
    pub const BUS_ERROR: u8 = 1 << 7;
}

/// The standard bitrates `S0`..`S8`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Bitrate {
    K10,
    K20,
    K50,
    K100,
    K125,
    K250,
    K500,
    K800,
    M1,
}

impl Bitrate {
    const ALL: [Bitrate; 9] =
        [Self::K10, Self::K20, Self::K50, Self::K100, Self::K125, Self::K250, Self::K500, Self::K800, Self::M1];
    const BPS: [u32; 9] = [10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000];

    /// Bits per second.
    pub fn bps(self) -> u32 {
        Self::BPS[self as usize]
    }
    /// The bitrate for exactly `bps`, if it is one of the nine.
    pub fn from_bps(bps: u32) -> Option<Self> {
        Self::BPS.iter().position(|&b| b == bps).map(|i| Self::ALL[i])
    }
    fn code(self) -> u8 {
        b'0' + self as u8
    }
}

/// Why a line is not valid SLCAN.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SlcanError {
    #[error("line is not terminated by CR")]
    Unterminated,
    #[error("line longer than {MAX_LINE_LEN} bytes")]
    TooLong,
    #[error("unknown command {0:?}")]
    UnknownCommand(char),
    #[error("bad hex digit in line")]
    BadHex,
    #[error("DLC {0} is not 0-8")]
    BadDlc(u8),
    #[error("line length does not match its DLC")]
    Length,
    #[error("identifier out of range")]
    IdRange,
    #[error("unknown bitrate code {0:?}")]
    BadBitrate(char),
    #[error("output buffer too small")]
    BufferTooSmall,
}

/// A line from the host to the adapter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    Transmit(CanFrame),
    SetBitrate(Bitrate),
    Open,
    ListenOnly,
    Close,
    Version,
    SerialNumber,
    StatusFlags,
    Timestamps(bool),
    Empty,
}

/// A line from the adapter to the host.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Response {
    Ok,
    Error,
    TxAck { extended: bool },
    Frame { frame: CanFrame, timestamp_ms: Option<u16> },
    Version { hardware: u8, software: u8 },
    SerialNumber([u8; 4]),
    StatusFlags(u8),
}

/// One side's view of a line: parse what arrives, emit what leaves.
pub trait Line: Sized {
    /// Parse one line, terminator included.
    fn parse(line: &[u8]) -> Result<Self, SlcanError>;
    /// Write the line, terminator included, into `buf`; returns its length.
    fn emit(&self, buf: &mut [u8]) -> Result<usize, SlcanError>;
}

/// Strip the CR; reject lines that are too long or unterminated.
fn body(line: &[u8]) -> Result<&[u8], SlcanError> {
    if line.len() > MAX_LINE_LEN {
        return Err(SlcanError::TooLong);
    }
    match line.split_last() {
        Some((&CR, body)) => Ok(body),
        _ => Err(SlcanError::Unterminated),
    }
}

fn hex_val(c: u8) -> Result<u8, SlcanError> {
    match c {
        b'0'..=b'9' => Ok(c - b'0'),
        b'a'..=b'f' => Ok(c - b'a' + 10),
        b'A'..=b'F' => Ok(c - b'A' + 10),
        _ => Err(SlcanError::BadHex),
    }
}

fn hex_u32(digits: &[u8]) -> Result<u32, SlcanError> {
    digits.iter().try_fold(0u32, |acc, &c| Ok(acc << 4 | u32::from(hex_val(c)?)))
}

const HEX: &[u8; 16] = b"0123456789ABCDEF";

/// Parse a frame line (`t`, `T`, `r`, `R`); returns the frame and what follows its data.
fn parse_frame(b: &[u8]) -> Result<(CanFrame, &[u8]), SlcanError> {
    let (kind, rest) = b.split_first().ok_or(SlcanError::Length)?;
    let (id_len, extended, remote) = match kind {
        b't' => (3, false, false),
        b'T' => (8, true, false),
        b'r' => (3, false, true),
        b'R' => (8, true, true),
        &c => return Err(SlcanError::UnknownCommand(char::from(c))),
    };
    if rest.len() < id_len + 1 {
        return Err(SlcanError::Length);
    }
    let raw_id = hex_u32(&rest[..id_len])?;
    let id = if extended {
        (raw_id <= MAX_EXTENDED_ID).then_some(CanId::Extended(raw_id))
    } else {
        (raw_id <= u32::from(MAX_STANDARD_ID)).then_some(CanId::Standard(raw_id as u16))
    }
    .ok_or(SlcanError::IdRange)?;
    let dlc = rest[id_len];
    let dlc = dlc.checked_sub(b'0').filter(|d| *d <= 8).ok_or(SlcanError::BadDlc(dlc.wrapping_sub(b'0')))?;
    let rest = &rest[id_len + 1..];
    if remote {
        let frame = CanFrame::remote(id, dlc).map_err(|_| SlcanError::BadDlc(dlc))?;
        return Ok((frame, rest));
    }
    let n = usize::from(dlc);
    let hex = rest.get(..2 * n).ok_or(SlcanError::Length)?;
    let mut data = [0u8; 8];
    for (i, pair) in hex.chunks_exact(2).enumerate() {
        data[i] = hex_val(pair[0])? << 4 | hex_val(pair[1])?;
    }
    let frame = CanFrame::new(id, &data[..n]).map_err(|_| SlcanError::Length)?;
    Ok((frame, &rest[2 * n..]))
}

/// Write a frame line body (no terminator) into `buf` at `*pos`.
fn emit_frame(frame: &CanFrame, out: &mut Out<'_>) -> Result<(), SlcanError> {
    let (kind, digits) = match (frame.id(), frame.is_remote()) {
        (CanId::Standard(_), false) => (b't', 3),
        (CanId::Extended(_), false) => (b'T', 8),
        (CanId::Standard(_), true) => (b'r', 3),
        (CanId::Extended(_), true) => (b'R', 8),
    };
    out.byte(kind)?;
    out.hex(frame.id().raw(), digits)?;
    out.byte(b'0' + frame.dlc())?;
    frame.data().iter().try_for_each(|&b| out.hex(b.into(), 2))
}

struct Out<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

impl Out<'_> {
    fn byte(&mut self, b: u8) -> Result<(), SlcanError> {
        *self.buf.get_mut(self.pos).ok_or(SlcanError::BufferTooSmall)? = b;
        self.pos += 1;
        Ok(())
    }
    fn hex(&mut self, v: u32, digits: u32) -> Result<(), SlcanError> {
        (0..digits).rev().try_for_each(|i| self.byte(HEX[(v >> (4 * i) & 0xF) as usize]))
    }
    fn done(mut self, terminator: bool) -> Result<usize, SlcanError> {
        if terminator {
            self.byte(CR)?;
        }
        Ok(self.pos)
    }
}

impl Line for Command {
    fn parse(line: &[u8]) -> Result<Self, SlcanError> {
        let b = body(line)?;
        let Some(&first) = b.first() else { return Ok(Command::Empty) };
        let rest = &b[1..];
        let bare = |cmd| if rest.is_empty() { Ok(cmd) } else { Err(SlcanError::Length) };
        match first {
            b't' | b'T' | b'r' | b'R' => {
                let (frame, tail) = parse_frame(b)?;
                if tail.is_empty() {
                    Ok(Command::Transmit(frame))
                } else {
                    Err(SlcanError::Length)
                }
            }
            b'S' => match rest {
                [c @ b'0'..=b'8'] => Ok(Command::SetBitrate(Bitrate::ALL[usize::from(c - b'0')])),
                [c] => Err(SlcanError::BadBitrate(char::from(*c))),
                _ => Err(SlcanError::Length),
            },
            b'Z' => match rest {
                [b'0'] => Ok(Command::Timestamps(false)),
                [b'1'] => Ok(Command::Timestamps(true)),
                _ => Err(SlcanError::Length),
            },
            b'O' => bare(Command::Open),
            b'L' => bare(Command::ListenOnly),
            b'C' => bare(Command::Close),
            b'V' => bare(Command::Version),
            b'N' => bare(Command::SerialNumber),
            b'F' => bare(Command::StatusFlags),
            c => Err(SlcanError::UnknownCommand(char::from(c))),
        }
    }

    fn emit(&self, buf: &mut [u8]) -> Result<usize, SlcanError> {
        let mut out = Out { buf, pos: 0 };
        match *self {
            Command::Transmit(ref frame) => emit_frame(frame, &mut out)?,
            Command::SetBitrate(b) => {
                out.byte(b'S')?;
                out.byte(b.code())?
            }
            Command::Timestamps(on) => {
                out.byte(b'Z')?;
                out.byte(if on { b'1' } else { b'0' })?
            }
            Command::Open => out.byte(b'O')?,
            Command::ListenOnly => out.byte(b'L')?,
            Command::Close => out.byte(b'C')?,
            Command::Version => out.byte(b'V')?,
            Command::SerialNumber => out.byte(b'N')?,
            Command::StatusFlags => out.byte(b'F')?,
            Command::Empty => {}
        }
        out.done(true)
    }
}

impl Line for Response {
    fn parse(line: &[u8]) -> Result<Self, SlcanError> {
        if line == [BEL] {
            return Ok(Response::Error);
        }
        let b = body(line)?;
        let Some(&first) = b.first() else { return Ok(Response::Ok) };
        let rest = &b[1..];
        match first {
            b'z' | b'Z' if rest.is_empty() => Ok(Response::TxAck { extended: first == b'Z' }),
            b't' | b'T' | b'r' | b'R' => {
                let (frame, tail) = parse_frame(b)?;
                let timestamp_ms = match tail.len() {
                    0 => None,
                    4 => Some(hex_u32(tail)? as u16),
                    _ => return Err(SlcanError::Length),
                };
                Ok(Response::Frame { frame, timestamp_ms })
            }
            b'V' => match rest {
                [h1, h2, s1, s2] if [h1, h2, s1, s2].iter().all(|c| c.is_ascii_digit()) => Ok(Response::Version {
                    hardware: (h1 - b'0') * 10 + (h2 - b'0'),
                    software: (s1 - b'0') * 10 + (s2 - b'0'),
                }),
                [_, _, _, _] => Err(SlcanError::BadHex),
                _ => Err(SlcanError::Length),
            },
            b'N' => match rest {
                [a, b, c, d] if [a, b, c, d].iter().all(|c| c.is_ascii_alphanumeric()) => {
                    Ok(Response::SerialNumber([*a, *b, *c, *d]))
                }
                [_, _, _, _] => Err(SlcanError::BadHex),
                _ => Err(SlcanError::Length),
            },
            b'F' => match rest {
                [_, _] => Ok(Response::StatusFlags(hex_u32(rest)? as u8)),
                _ => Err(SlcanError::Length),
            },
            c => Err(SlcanError::UnknownCommand(char::from(c))),
        }
    }

    fn emit(&self, buf: &mut [u8]) -> Result<usize, SlcanError> {
        let mut out = Out { buf, pos: 0 };
        match *self {
            Response::Ok => {}
            Response::Error => {
                out.byte(BEL)?;
                return out.done(false);
            }
            Response::TxAck { extended } => out.byte(if extended { b'Z' } else { b'z' })?,
            Response::Frame { ref frame, timestamp_ms } => {
                emit_frame(frame, &mut out)?;
                if let Some(ts) = timestamp_ms {
                    out.hex(u32::from(ts), 4)?;
                }
            }
            Response::Version { hardware, software } => {
                out.byte(b'V')?;
                for v in [hardware, software] {
                    out.byte(b'0' + (v / 10) % 10)?;
                    out.byte(b'0' + v % 10)?;
                }
            }
            Response::SerialNumber(sn) => {
                out.byte(b'N')?;
                sn.iter().try_for_each(|&c| out.byte(c))?;
            }
            Response::StatusFlags(f) => {
                out.byte(b'F')?;
                out.hex(f.into(), 2)?;
            }
        }
        out.done(true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn std_frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::new(CanId::Standard(id), data).unwrap()
    }

    fn round_trip<L: Line + PartialEq + core::fmt::Debug>(value: L, line: &[u8]) {
        let mut buf = [0u8; MAX_LINE_LEN];
        let n = value.emit(&mut buf).unwrap();
        assert_eq!(&buf[..n], line, "emit {value:?}");
        assert_eq!(L::parse(line).unwrap(), value, "parse {:?}", core::str::from_utf8(line));
    }

    #[test]
    fn golden_commands() {
        round_trip(Command::Transmit(std_frame(0x101, &[0xE8, 0x03, 0x00])), b"t1013E80300\r");
        round_trip(Command::Transmit(CanFrame::new(CanId::Extended(0x1234_5678), &[]).unwrap()), b"T123456780\r");
        round_trip(Command::Transmit(CanFrame::remote(CanId::Standard(0x7FF), 8).unwrap()), b"r7FF8\r");
        round_trip(Command::Transmit(CanFrame::remote(CanId::Extended(0x1FFF_FFFF), 0).unwrap()), b"R1FFFFFFF0\r");
        round_trip(Command::SetBitrate(Bitrate::M1), b"S8\r");
        round_trip(Command::SetBitrate(Bitrate::K10), b"S0\r");
        round_trip(Command::Open, b"O\r");
        round_trip(Command::ListenOnly, b"L\r");
        round_trip(Command::Close, b"C\r");
        round_trip(Command::Version, b"V\r");
        round_trip(Command::SerialNumber, b"N\r");
        round_trip(Command::StatusFlags, b"F\r");
        round_trip(Command::Timestamps(true), b"Z1\r");
        round_trip(Command::Empty, b"\r");
        // Lower-case hex is accepted.
        assert_eq!(Command::parse(b"t1012abcd\r").unwrap(), Command::Transmit(std_frame(0x101, &[0xAB, 0xCD])));
    }

    #[test]
    fn golden_responses() {
        round_trip(Response::Ok, b"\r");
        round_trip(Response::Error, b"\x07");
        round_trip(Response::TxAck { extended: false }, b"z\r");
        round_trip(Response::TxAck { extended: true }, b"Z\r");
        round_trip(Response::Frame { frame: std_frame(0x701, &[0x05]), timestamp_ms: None }, b"t701105\r");
        round_trip(Response::Frame { frame: std_frame(0x281, &[]), timestamp_ms: Some(0xEA5F) }, b"t2810EA5F\r");
        round_trip(Response::Version { hardware: 10, software: 13 }, b"V1013\r");
        round_trip(Response::SerialNumber(*b"FG01"), b"NFG01\r");
        round_trip(Response::StatusFlags(status::ERROR_PASSIVE | status::BUS_ERROR), b"FA0\r");
    }

    #[test]
    fn bitrates() {
        assert_eq!(Bitrate::from_bps(1_000_000), Some(Bitrate::M1));
        assert_eq!(Bitrate::from_bps(800_000).map(Bitrate::bps), Some(800_000));
        assert_eq!(Bitrate::from_bps(83_333), None);
    }

    #[test]
    fn rejects_malformed_lines() {
        use SlcanError::*;
        let cases: &[(&[u8], SlcanError)] = &[
            (b"t123", Unterminated),
            (b"t12G0\r", BadHex),
            (b"t1239\r", BadDlc(9)),
            (b"t1232AA\r", Length),
            (b"t1231AAB\r", Length),
            (b"t8000\r", IdRange),
            (b"T200000000\r", IdRange),
            (b"S9\r", BadBitrate('9')),
            (b"Ox\r", Length),
            (b"Q\r", UnknownCommand('Q')),
            (b"t1230000000000000000000000000000000\r", TooLong),
        ];
        for (line, want) in cases {
            assert_eq!(Command::parse(line), Err(*want), "{:?}", core::str::from_utf8(line));
        }
        assert_eq!(Response::parse(b"t12310102\r"), Err(Length));
        assert_eq!(Response::parse(b"V10x3\r"), Err(BadHex));
    }

    #[test]
    fn emit_into_small_buffer_is_an_error() {
        let cmd = Command::Transmit(std_frame(0x101, &[1, 2, 3, 4, 5, 6, 7, 8]));
        for cap in 0..22 {
            let mut buf = [0u8; 22];
            assert_eq!(cmd.emit(&mut buf[..cap]), Err(SlcanError::BufferTooSmall));
        }
    }
}
