//! The serial protocol between the host (flowgate) and the PSD camera controller.
//!
//! The controller fires the rig's infrared LEDs one at a time (time-division addressing)
//! and reports where each LED's spot falls on the PSD (position-sensitive detector).
//!
//! ## Framing
//!
//! On the wire every message is one COBS-encoded frame followed by a single `0x00`:
//!
//! ```text
//!  wire:   | COBS( frame ) | 0x00 |
//!
//!  frame:  0        1        2        3        4 ...        n-2      n-1
//!         +--------+--------+--------+--------+------------+--------+--------+
//!         |version |  type  |   seq (u16 LE)  |  payload   | CRC-16 (u16 LE) |
//!         +--------+--------+--------+--------+------------+--------+--------+
//! ```
//!
//! - `version` is [`PROTOCOL_VERSION`]; a frame of another version is rejected.
//! - `type` is a [`MessageType`]: `0x01..=0x7F` host to controller, `0x81..=0xFF` back.
//! - `seq` counts the sender's messages, wrapping. Acks, nacks and replies name the `seq`
//!   of the request they answer, so the host can match them and spot lost frames.
//! - CRC-16/IBM-3740 ([`crate::crc`]) over `version ..= payload`, little-endian.
//! - All multi-byte fields are little-endian. Payload layouts are on each [`Message`]
//!   variant and drawn in `protocol/README.md`.
//!
//! A receiver that sees garbage drops bytes up to the next `0x00` and carries on: COBS
//! guarantees that a frame never contains `0x00`.
//!
//! ## No-panic contract
//!
//! [`Packet::parse`] and [`Packet::decode`] accept any byte slice and return an [`Error`]
//! for anything they cannot accept.

use crate::{cobs, crc::crc16_ibm3740, wire::Reader, wire::Writer};

/// The protocol version carried in byte 0 of every frame.
pub const PROTOCOL_VERSION: u8 = 2;
/// Bytes before the payload: version, type, seq.
pub const HEADER_LEN: usize = 4;
/// The trailing CRC.
pub const CRC_LEN: usize = 2;
/// The shortest LED slot, µs: an LED's rise and one PSD conversion.
pub const MIN_SLOT_US: u16 = 100;
/// The most LEDs one schedule may hold; a controller drives [`Info::max_leds`] of them.
pub const MAX_SCHEDULE_LEDS: usize = 64;
/// The latest controller stamp (`t_ctrl_us`) a frame may carry: 2^53 µs, some 285 years of
/// uptime, and exact in an `f64`. A later one is refused at decode as absurd (a corrupted
/// stamp that passed the CRC), never mapped to host time.
pub const MAX_STAMP_US: u64 = 1 << 53;
/// The largest payload of any message (a full schedule).
pub const MAX_PAYLOAD_LEN: usize = 5 + 3 * MAX_SCHEDULE_LEDS;
/// The largest unencoded frame.
pub const MAX_FRAME_LEN: usize = HEADER_LEN + MAX_PAYLOAD_LEN + CRC_LEN;
/// The largest frame on the wire: COBS overhead plus the `0x00` delimiter.
pub const MAX_WIRE_LEN: usize = cobs::max_encoded_len(MAX_FRAME_LEN) + 1;
/// The longest frame a gateway reads, on the wire (replies are shorter: a sample is
/// [`SAMPLE_WIRE_LEN`]); a longer run is garbage, cut here. A 16-LED schedule's bound, kept
/// at 64 LEDs so that garbage is judged as before and recordings replay as they were made.
pub const MAX_REPLY_WIRE_LEN: usize = cobs::max_encoded_len(HEADER_LEN + 5 + 3 * 16 + CRC_LEN) + 1;
/// The wire length of a [`Message::Sample`] frame, for wire-time figures.
pub const SAMPLE_WIRE_LEN: usize = cobs::max_encoded_len(HEADER_LEN + SAMPLE_PAYLOAD_LEN + CRC_LEN) + 1;
const SAMPLE_PAYLOAD_LEN: usize = 25;

/// Why bytes could not be read as a message, or a message could not be written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Error {
    #[error("COBS: {0}")]
    Cobs(#[from] cobs::CobsError),
    #[error("frame of {0} bytes is shorter than header and CRC")]
    TooShort(usize),
    #[error("frame longer than {MAX_FRAME_LEN} bytes")]
    TooLong,
    #[error("CRC mismatch: frame says 0x{received:04X}, bytes give 0x{computed:04X}")]
    Crc { received: u16, computed: u16 },
    #[error("protocol version {0}, expected {PROTOCOL_VERSION}")]
    Version(u8),
    #[error("unknown message type 0x{0:02X}")]
    UnknownType(u8),
    #[error("{msg_type:?} payload of {len} bytes does not fit its layout")]
    PayloadLength { msg_type: MessageType, len: usize },
    #[error("{msg_type:?}: field `{field}` out of range")]
    Field { msg_type: MessageType, field: &'static str },
    #[error("output buffer too small")]
    BufferTooSmall,
}

impl Error {
    /// The nack reason a controller sends back for this error.
    pub fn nack_reason(&self) -> NackReason {
        match self {
            Error::Cobs(_) | Error::TooShort(_) | Error::TooLong | Error::PayloadLength { .. } => NackReason::BadLength,
            Error::Crc { .. } => NackReason::BadCrc,
            Error::Version(_) => NackReason::BadVersion,
            Error::UnknownType(_) => NackReason::UnknownType,
            Error::Field { .. } | Error::BufferTooSmall => NackReason::BadValue,
        }
    }
}

macro_rules! byte_enum {
    ($(#[$m:meta])* $name:ident { $($(#[$vm:meta])* $var:ident = $val:literal,)* }) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[repr(u8)]
        pub enum $name { $($(#[$vm])* $var = $val,)* }
        impl $name {
            /// The variant for a wire byte, if any.
            pub const fn from_u8(v: u8) -> Option<Self> {
                match v { $($val => Some(Self::$var),)* _ => None }
            }
        }
    };
}
pub(crate) use byte_enum;

byte_enum! {
    /// The type byte of a frame.
    MessageType {
        // host -> controller
        GetInfo = 0x01,
        SetSchedule = 0x02,
        StartStream = 0x03,
        StopStream = 0x04,
        Ping = 0x05,
        TimeSync = 0x06,
        // controller -> host
        Info = 0x81,
        Ack = 0x82,
        Nack = 0x83,
        Sample = 0x84,
        FrameEnd = 0x85,
        Fault = 0x86,
        Heartbeat = 0x87,
        Pong = 0x88,
        TimeSyncReply = 0x89,
    }
}

impl MessageType {
    /// True for messages the host sends to the controller.
    pub const fn is_request(self) -> bool {
        (self as u8) < 0x80
    }
}

byte_enum! {
    /// Why the controller refused a request.
    NackReason {
        UnknownType = 1,
        BadLength = 2,
        BadValue = 3,
        BadCrc = 4,
        /// The schedule cannot change while streaming: stop first.
        Busy = 5,
        /// Start requested before any schedule was configured.
        NotConfigured = 6,
        /// More LEDs than the controller drives (see [`Info::max_leds`]).
        TooManyLeds = 7,
        BadVersion = 8,
        /// The message is one the controller sends, not one it takes.
        WrongDirection = 9,
    }
}

byte_enum! {
    /// A fault the controller reports on its own.
    FaultCode {
        /// The controller (re)started; any schedule is gone. Sent once after boot.
        Reset = 1,
        /// Samples were lost inside the controller (host not reading fast enough).
        Overrun = 2,
        /// An LED driver sees an open or short circuit; `detail` is the LED id.
        LedDriver = 3,
        /// Ambient light saturates the PSD even in the dark slot.
        AmbientSaturation = 4,
        Internal = 5,
    }
}

byte_enum! {
    /// What the controller is doing, in its heartbeat.
    ControllerState {
        Idle = 0,
        Streaming = 1,
        Fault = 2,
    }
}

/// Per-sample quality flags.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SampleFlags(pub u8);

impl SampleFlags {
    /// The PSD current saturated: the position is unreliable.
    pub const SATURATED: u8 = 1 << 0;
    /// Too little light: the LED is out of view, occluded or dead.
    pub const WEAK_SIGNAL: u8 = 1 << 1;
    /// Ambient light is high relative to the LED signal.
    pub const AMBIENT_HIGH: u8 = 1 << 2;
    /// The dark-slot ambient reading was subtracted from this sample.
    pub const AMBIENT_SUBTRACTED: u8 = 1 << 3;
    const KNOWN: u8 = 0x0F;

    pub const fn contains(self, bit: u8) -> bool {
        self.0 & bit == bit
    }
    /// A sample fit for tracking: neither saturated nor weak.
    pub const fn is_usable(self) -> bool {
        self.0 & (Self::SATURATED | Self::WEAK_SIGNAL) == 0
    }
}

/// One LED's turn in the time-division frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct LedSlot {
    /// The LED's address on the controller's driver bus.
    pub led: u8,
    /// How long the LED is lit and integrated, µs.
    pub slot_us: u16,
}

/// The time-division LED schedule: which LEDs, in which order, for how long.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Schedule {
    slots: [LedSlot; MAX_SCHEDULE_LEDS],
    len: u8,
    /// Length of the dark slot (all LEDs off, ambient measured and subtracted), µs; 0 = none.
    pub dark_slot_us: u16,
    /// How many PSD conversions the controller averages per slot (1 = none).
    pub averaging: u8,
}

impl Schedule {
    /// A schedule of `slots`, in firing order. At least one, at most [`MAX_SCHEDULE_LEDS`],
    /// every slot time non-zero, every LED once, `averaging >= 1`.
    pub fn new(slots: &[LedSlot], dark_slot_us: u16, averaging: u8) -> Result<Self, ScheduleError> {
        if slots.is_empty() {
            return Err(ScheduleError::Empty);
        }
        if slots.len() > MAX_SCHEDULE_LEDS {
            return Err(ScheduleError::TooManyLeds(slots.len()));
        }
        if averaging == 0 {
            return Err(ScheduleError::ZeroAveraging);
        }
        for (i, s) in slots.iter().enumerate() {
            if s.led == 0 {
                return Err(ScheduleError::ZeroLed);
            }
            if s.slot_us < MIN_SLOT_US {
                return Err(ScheduleError::ZeroSlot(s.led));
            }
            if slots[..i].iter().any(|o| o.led == s.led) {
                return Err(ScheduleError::DuplicateLed(s.led));
            }
        }
        let mut all = [LedSlot::default(); MAX_SCHEDULE_LEDS];
        all[..slots.len()].copy_from_slice(slots);
        Ok(Self { slots: all, len: slots.len() as u8, dark_slot_us, averaging })
    }

    /// The LED slots in firing order.
    pub fn slots(&self) -> &[LedSlot] {
        &self.slots[..usize::from(self.len)]
    }

    /// The length of one time-division frame: every slot plus the dark slot, µs.
    pub fn frame_period_us(&self) -> u32 {
        self.slots().iter().map(|s| u32::from(s.slot_us)).sum::<u32>() + u32::from(self.dark_slot_us)
    }
}

/// Why a schedule is not valid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ScheduleError {
    #[error("schedule has no LEDs")]
    Empty,
    #[error("schedule has {0} LEDs, at most {MAX_SCHEDULE_LEDS} allowed")]
    TooManyLeds(usize),
    #[error("LED {0} has a slot shorter than {MIN_SLOT_US} µs (one PSD conversion)")]
    ZeroSlot(u8),
    #[error("LED id 0 is not an LED (the driver bus numbers them from 1)")]
    ZeroLed,
    #[error("LED {0} appears twice in the schedule")]
    DuplicateLed(u8),
    #[error("averaging must be at least 1")]
    ZeroAveraging,
}

/// The controller's identity and capabilities.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Info {
    pub firmware: [u8; 3],
    /// Full-scale raw PSD counts on x and y; raw coordinates lie in `-counts/2..counts/2`.
    pub psd_counts: [u16; 2],
    /// The most LEDs the controller can drive in one schedule.
    pub max_leds: u8,
    /// The controller's timestamp clock, Hz (timestamps are reported in µs).
    pub clock_hz: u32,
}

/// One LED position measurement.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Sample {
    /// The time-division frame counter (wraps).
    pub frame: u32,
    /// Position of this LED's slot in the schedule.
    pub slot: u8,
    pub led: u8,
    /// Controller clock at the middle of the slot's integration, µs.
    pub t_ctrl_us: u64,
    /// Raw PSD position, counts.
    pub x: i32,
    pub y: i32,
    /// Spot intensity, counts (after ambient subtraction when enabled).
    pub intensity: u16,
    pub flags: SampleFlags,
}

/// A message of either direction. Payload layouts (offsets into the payload, LE):
// A schedule travels inline: the crate needs no allocator, and one is sent once a session.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Message {
    /// `0x01`, empty. Answered by [`Message::Info`].
    GetInfo,
    /// `0x02`: `[0] flags (0) | [1] averaging | [2..4] dark_slot_us | [4] n |
    /// n x ([0] led, [1..3] slot_us)`. Answered by ack, or nack `Busy` while streaming.
    SetSchedule(Schedule),
    /// `0x03`, empty. Ack, or nack `NotConfigured`.
    StartStream,
    /// `0x04`, empty. Ack.
    StopStream,
    /// `0x05`: `[0..4] nonce`. Answered by [`Message::Pong`].
    Ping { nonce: u32 },
    /// `0x06`: `[0..8] host_time_us`. Answered by [`Message::TimeSyncReply`].
    TimeSync { host_time_us: u64 },
    /// `0x81`: `[0..2] seq of the GetInfo | [2..5] firmware | [5..7] psd x counts |
    /// [7..9] psd y counts | [9] max_leds | [10..14] clock_hz`.
    Info { request_seq: u16, info: Info },
    /// `0x82`: `[0..2] seq of the request | [2] its type`.
    Ack { seq: u16, msg_type: u8 },
    /// `0x83`: `[0..2] seq of the request | [2] its type | [3] reason`.
    Nack { seq: u16, msg_type: u8, reason: NackReason },
    /// `0x84`: `[0..4] frame | [4] slot | [5] led | [6..14] t_ctrl_us | [14..18] x (i32) |
    /// [18..22] y (i32) | [22..24] intensity | [24] flags`.
    Sample(Sample),
    /// `0x85`: `[0..4] frame | [4..12] t_ctrl_us (end of the frame) | [12] samples sent`.
    FrameEnd { frame: u32, t_ctrl_us: u64, samples: u8 },
    /// `0x86`: `[0] code | [1..5] detail`.
    Fault { code: FaultCode, detail: u32 },
    /// `0x87`: `[0..8] t_ctrl_us | [1] state`. Sent every 100 ms whatever the state.
    Heartbeat { t_ctrl_us: u64, state: ControllerState },
    /// `0x88`: `[0..2] seq of the Ping | [2..6] nonce | [6..14] t_ctrl_us`.
    Pong { request_seq: u16, nonce: u32, t_ctrl_us: u64 },
    /// `0x89`: `[0..2] seq of the TimeSync | [2..10] host_time_us (echoed) |
    /// [10..18] t_ctrl_us at receipt`.
    TimeSyncReply { request_seq: u16, host_time_us: u64, t_ctrl_us: u64 },
}

impl Message {
    pub fn msg_type(&self) -> MessageType {
        match self {
            Message::GetInfo => MessageType::GetInfo,
            Message::SetSchedule(_) => MessageType::SetSchedule,
            Message::StartStream => MessageType::StartStream,
            Message::StopStream => MessageType::StopStream,
            Message::Ping { .. } => MessageType::Ping,
            Message::TimeSync { .. } => MessageType::TimeSync,
            Message::Info { .. } => MessageType::Info,
            Message::Ack { .. } => MessageType::Ack,
            Message::Nack { .. } => MessageType::Nack,
            Message::Sample(_) => MessageType::Sample,
            Message::FrameEnd { .. } => MessageType::FrameEnd,
            Message::Fault { .. } => MessageType::Fault,
            Message::Heartbeat { .. } => MessageType::Heartbeat,
            Message::Pong { .. } => MessageType::Pong,
            Message::TimeSyncReply { .. } => MessageType::TimeSyncReply,
        }
    }

    /// The controller stamp the message carries, if any.
    pub fn stamp(&self) -> Option<u64> {
        match *self {
            Message::Sample(s) => Some(s.t_ctrl_us),
            Message::FrameEnd { t_ctrl_us, .. }
            | Message::Heartbeat { t_ctrl_us, .. }
            | Message::Pong { t_ctrl_us, .. }
            | Message::TimeSyncReply { t_ctrl_us, .. } => Some(t_ctrl_us),
            _ => None,
        }
    }

    /// A `SetSchedule`'s payload after its type; `field` names a bad field.
    fn schedule_payload(r: &mut Reader<'_>, field: impl Fn(&'static str) -> Error) -> Option<Result<Self, Error>> {
        let flags = r.u8()?;
        let averaging = r.u8()?;
        let dark_slot_us = r.u16()?;
        let n = usize::from(r.u8()?);
        if flags != 0 {
            return Some(Err(field("flags")));
        }
        if n > MAX_SCHEDULE_LEDS {
            return Some(Err(field("n")));
        }
        let mut slots = [LedSlot::default(); MAX_SCHEDULE_LEDS];
        for s in &mut slots[..n] {
            *s = LedSlot { led: r.u8()?, slot_us: r.u16()? };
        }
        Some(match Schedule::new(&slots[..n], dark_slot_us, averaging) {
            Ok(s) => Ok(Message::SetSchedule(s)),
            Err(_) => Err(field("slots")),
        })
    }

    /// A `Sample`'s payload after its type; `field` names a bad field.
    fn sample_payload(r: &mut Reader<'_>, field: impl Fn(&'static str) -> Error) -> Option<Result<Self, Error>> {
        let s = Sample {
            frame: r.u32()?,
            slot: r.u8()?,
            led: r.u8()?,
            t_ctrl_us: r.u64()?,
            x: r.i32()?,
            y: r.i32()?,
            intensity: r.u16()?,
            flags: SampleFlags(r.u8()?),
        };
        if s.flags.0 & !SampleFlags::KNOWN != 0 {
            return Some(Err(field("flags")));
        }
        Some(Ok(Message::Sample(s)))
    }

    fn parse_payload(msg_type: MessageType, payload: &[u8]) -> Result<Self, Error> {
        let mut r = Reader::new(payload);
        let short = Error::PayloadLength { msg_type, len: payload.len() };
        let field = |field| Error::Field { msg_type, field };
        let msg = (|| -> Option<Result<Message, Error>> {
            Some(Ok(match msg_type {
                MessageType::GetInfo => Message::GetInfo,
                MessageType::StartStream => Message::StartStream,
                MessageType::StopStream => Message::StopStream,
                MessageType::Ping => Message::Ping { nonce: r.u32()? },
                MessageType::TimeSync => Message::TimeSync { host_time_us: r.u64()? },
                MessageType::SetSchedule => return Self::schedule_payload(&mut r, field),
                MessageType::Info => Message::Info {
                    request_seq: r.u16()?,
                    info: Info {
                        firmware: r.take()?,
                        psd_counts: [r.u16()?, r.u16()?],
                        max_leds: r.u8()?,
                        clock_hz: r.u32()?,
                    },
                },
                MessageType::Ack => Message::Ack { seq: r.u16()?, msg_type: r.u8()? },
                MessageType::Nack => {
                    let (seq, msg_type_byte) = (r.u16()?, r.u8()?);
                    match NackReason::from_u8(r.u8()?) {
                        Some(reason) => Message::Nack { seq, msg_type: msg_type_byte, reason },
                        None => return Some(Err(field("reason"))),
                    }
                }
                MessageType::Sample => return Self::sample_payload(&mut r, field),
                MessageType::FrameEnd => Message::FrameEnd { frame: r.u32()?, t_ctrl_us: r.u64()?, samples: r.u8()? },
                MessageType::Fault => match FaultCode::from_u8(r.u8()?) {
                    Some(code) => Message::Fault { code, detail: r.u32()? },
                    None => return Some(Err(field("code"))),
                },
                MessageType::Heartbeat => {
                    let t_ctrl_us = r.u64()?;
                    match ControllerState::from_u8(r.u8()?) {
                        Some(state) => Message::Heartbeat { t_ctrl_us, state },
                        None => return Some(Err(field("state"))),
                    }
                }
                MessageType::Pong => Message::Pong { request_seq: r.u16()?, nonce: r.u32()?, t_ctrl_us: r.u64()? },
                MessageType::TimeSyncReply => {
                    Message::TimeSyncReply { request_seq: r.u16()?, host_time_us: r.u64()?, t_ctrl_us: r.u64()? }
                }
            }))
        })();
        match msg {
            Some(Ok(m)) if r.remaining() == 0 && m.stamp().is_some_and(|t| t > MAX_STAMP_US) => Err(field("t_ctrl_us")),
            Some(Ok(m)) if r.remaining() == 0 => Ok(m),
            Some(Ok(_)) | None => Err(short),
            Some(Err(e)) => Err(e),
        }
    }

    fn emit_payload(&self, w: &mut Writer<'_>) -> Option<()> {
        match *self {
            Message::GetInfo | Message::StartStream | Message::StopStream => Some(()),
            Message::Ping { nonce } => w.u32(nonce),
            Message::TimeSync { host_time_us } => w.u64(host_time_us),
            Message::SetSchedule(ref s) => {
                w.u8(0)?;
                w.u8(s.averaging)?;
                w.u16(s.dark_slot_us)?;
                w.u8(s.len)?;
                s.slots().iter().try_for_each(|slot| {
                    w.u8(slot.led)?;
                    w.u16(slot.slot_us)
                })
            }
            Message::Info { request_seq, info: ref i } => {
                w.u16(request_seq)?;
                w.put(&i.firmware)?;
                w.u16(i.psd_counts[0])?;
                w.u16(i.psd_counts[1])?;
                w.u8(i.max_leds)?;
                w.u32(i.clock_hz)
            }
            Message::Ack { seq, msg_type } => {
                w.u16(seq)?;
                w.u8(msg_type)
            }
            Message::Nack { seq, msg_type, reason } => {
                w.u16(seq)?;
                w.u8(msg_type)?;
                w.u8(reason as u8)
            }
            Message::Sample(ref s) => {
                w.u32(s.frame)?;
                w.u8(s.slot)?;
                w.u8(s.led)?;
                w.u64(s.t_ctrl_us)?;
                w.i32(s.x)?;
                w.i32(s.y)?;
                w.u16(s.intensity)?;
                w.u8(s.flags.0)
            }
            Message::FrameEnd { frame, t_ctrl_us, samples } => {
                w.u32(frame)?;
                w.u64(t_ctrl_us)?;
                w.u8(samples)
            }
            Message::Fault { code, detail } => {
                w.u8(code as u8)?;
                w.u32(detail)
            }
            Message::Heartbeat { t_ctrl_us, state } => {
                w.u64(t_ctrl_us)?;
                w.u8(state as u8)
            }
            Message::Pong { request_seq, nonce, t_ctrl_us } => {
                w.u16(request_seq)?;
                w.u32(nonce)?;
                w.u64(t_ctrl_us)
            }
            Message::TimeSyncReply { request_seq, host_time_us, t_ctrl_us } => {
                w.u16(request_seq)?;
                w.u64(host_time_us)?;
                w.u64(t_ctrl_us)
            }
        }
    }
}

/// The header of a frame that did not decode, when its bytes could be read: the request a
/// Nack names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Header {
    pub msg_type: u8,
    pub seq: u16,
}

impl Header {
    /// The header of a wire frame (the bytes between two delimiters), if COBS decodes it and
    /// it is long enough to hold one, whatever else is wrong with it.
    pub fn of_wire(wire: &[u8]) -> Option<Self> {
        let mut frame = [0u8; MAX_FRAME_LEN];
        let n = cobs::decode(wire, &mut frame).ok()?;
        (n >= HEADER_LEN).then(|| Header { msg_type: frame[1], seq: u16::from_le_bytes([frame[2], frame[3]]) })
    }
}

/// A message with its sequence number: the unit that goes into one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Packet {
    pub seq: u16,
    pub message: Message,
}

impl Packet {
    pub const fn new(seq: u16, message: Message) -> Self {
        Self { seq, message }
    }

    /// Parse an unencoded frame (COBS already removed): header, payload, CRC.
    pub fn parse(frame: &[u8]) -> Result<Self, Error> {
        if frame.len() < HEADER_LEN + CRC_LEN {
            return Err(Error::TooShort(frame.len()));
        }
        if frame.len() > MAX_FRAME_LEN {
            return Err(Error::TooLong);
        }
        let (body, crc_bytes) = frame.split_at(frame.len() - CRC_LEN);
        let received = u16::from_le_bytes([crc_bytes[0], crc_bytes[1]]);
        let computed = crc16_ibm3740(body);
        if received != computed {
            return Err(Error::Crc { received, computed });
        }
        if body[0] != PROTOCOL_VERSION {
            return Err(Error::Version(body[0]));
        }
        let msg_type = MessageType::from_u8(body[1]).ok_or(Error::UnknownType(body[1]))?;
        let seq = u16::from_le_bytes([body[2], body[3]]);
        let message = Message::parse_payload(msg_type, &body[HEADER_LEN..])?;
        Ok(Self { seq, message })
    }

    /// Write the unencoded frame into `buf`; returns its length.
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, Error> {
        let mut w = Writer::new(buf);
        (|| {
            w.u8(PROTOCOL_VERSION)?;
            w.u8(self.message.msg_type() as u8)?;
            w.u16(self.seq)?;
            self.message.emit_payload(&mut w)
        })()
        .ok_or(Error::BufferTooSmall)?;
        let body_len = w.len();
        let crc = crc16_ibm3740(&buf[..body_len]);
        buf.get_mut(body_len..body_len + CRC_LEN).ok_or(Error::BufferTooSmall)?.copy_from_slice(&crc.to_le_bytes());
        Ok(body_len + CRC_LEN)
    }

    /// Write the frame as it goes on the wire (COBS + `0x00`) into `out`; returns its length.
    /// An `out` of [`MAX_WIRE_LEN`] bytes always suffices.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, Error> {
        let mut frame = [0u8; MAX_FRAME_LEN];
        let n = self.emit(&mut frame)?;
        let m = cobs::encode(&frame[..n], out).map_err(|_| Error::BufferTooSmall)?;
        *out.get_mut(m).ok_or(Error::BufferTooSmall)? = 0;
        Ok(m + 1)
    }

    /// Decode one wire frame: the bytes between two `0x00` delimiters (neither included).
    pub fn decode(wire: &[u8]) -> Result<Self, Error> {
        if wire.len() > cobs::max_encoded_len(MAX_FRAME_LEN) {
            return Err(Error::TooLong);
        }
        let mut frame = [0u8; MAX_FRAME_LEN];
        let n = cobs::decode(wire, &mut frame).map_err(|e| match e {
            cobs::CobsError::BufferTooSmall => Error::TooLong,
            e => Error::Cobs(e),
        })?;
        Self::parse(&frame[..n])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Sample {
        Sample {
            frame: 0x0102_0304,
            slot: 1,
            led: 7,
            t_ctrl_us: 0x1122_3344_5566,
            x: -1000,
            y: 2000,
            intensity: 0x0BB8,
            flags: SampleFlags(SampleFlags::AMBIENT_SUBTRACTED),
        }
    }

    /// Golden bytes, both ways: a sample frame as it appears on the wire. The CRC and COBS
    /// bytes were computed independently (Python `binascii.crc_hqx(frame, 0xFFFF)`).
    #[test]
    fn golden_sample_frame() {
        let packet = Packet::new(0x0005, Message::Sample(sample()));
        let frame: [u8; 31] = [
            0x02, 0x84, 0x05, 0x00, // version, type, seq
            0x04, 0x03, 0x02, 0x01, // frame
            0x01, 0x07, // slot, led
            0x66, 0x55, 0x44, 0x33, 0x22, 0x11, 0x00, 0x00, // t_ctrl_us
            0x18, 0xFC, 0xFF, 0xFF, // x = -1000
            0xD0, 0x07, 0x00, 0x00, // y = 2000
            0xB8, 0x0B, // intensity
            0x08, // flags
            0xB6, 0x32, // CRC-16/IBM-3740, LE
        ];
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = packet.emit(&mut buf).unwrap();
        assert_eq!(&buf[..n], &frame[..]);
        assert_eq!(Packet::parse(&frame).unwrap(), packet);

        let wire: [u8; 33] = [
            0x04, 0x02, 0x84, 0x05, 0x0D, 0x04, 0x03, 0x02, 0x01, 0x01, 0x07, 0x66, 0x55, 0x44, 0x33, 0x22, 0x11, 0x01,
            0x07, 0x18, 0xFC, 0xFF, 0xFF, 0xD0, 0x07, 0x01, 0x06, 0xB8, 0x0B, 0x08, 0xB6, 0x32, 0x00,
        ];
        let mut out = [0u8; MAX_WIRE_LEN];
        let n = packet.encode(&mut out).unwrap();
        assert_eq!(&out[..n], &wire[..]);
        assert_eq!(n, SAMPLE_WIRE_LEN);
        assert_eq!(Packet::decode(&wire[..wire.len() - 1]).unwrap(), packet);
    }

    /// A stamp beyond [`MAX_STAMP_US`] is refused at decode (a time sync reply of 2^64 - 1
    /// would otherwise move the clock by centuries); the largest allowed one decodes.
    #[test]
    fn absurd_stamps_are_refused_at_decode() {
        for t_ctrl_us in [MAX_STAMP_US + 1, u64::MAX] {
            for message in [
                Message::TimeSyncReply { request_seq: 1, host_time_us: 2, t_ctrl_us },
                Message::Sample(Sample { t_ctrl_us, ..sample() }),
                Message::FrameEnd { frame: 1, t_ctrl_us, samples: 2 },
            ] {
                let mut buf = [0u8; MAX_FRAME_LEN];
                let n = Packet::new(7, message).emit(&mut buf).unwrap();
                assert!(
                    matches!(Packet::parse(&buf[..n]), Err(Error::Field { field: "t_ctrl_us", .. })),
                    "{message:?}"
                );
            }
        }
        let message = Message::TimeSyncReply { request_seq: 1, host_time_us: 2, t_ctrl_us: MAX_STAMP_US };
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = Packet::new(7, message).emit(&mut buf).unwrap();
        assert_eq!(Packet::parse(&buf[..n]).unwrap().message, message);
    }

    #[test]
    fn golden_schedule_frame() {
        let schedule =
            Schedule::new(&[LedSlot { led: 1, slot_us: 1000 }, LedSlot { led: 2, slot_us: 500 }], 250, 4).unwrap();
        let packet = Packet::new(0x1234, Message::SetSchedule(schedule));
        let frame: [u8; 17] = [
            0x02, 0x02, 0x34, 0x12, // header
            0x00, 0x04, 0xFA, 0x00, 0x02, // flags, averaging, dark slot 250 us, n
            0x01, 0xE8, 0x03, // LED 1, 1000 us
            0x02, 0xF4, 0x01, // LED 2, 500 us
            0x2D, 0x8A, // CRC
        ];
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = packet.emit(&mut buf).unwrap();
        assert_eq!(&buf[..n], &frame[..]);
        assert_eq!(Packet::parse(&frame).unwrap(), packet);
        assert_eq!(schedule.frame_period_us(), 1750);
    }

    #[test]
    fn rejects_what_it_cannot_accept() {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = Packet::new(1, Message::Ping { nonce: 9 }).emit(&mut buf).unwrap();
        let good = &buf[..n];

        let mut bad_crc = [0u8; MAX_FRAME_LEN];
        bad_crc[..n].copy_from_slice(good);
        bad_crc[5] ^= 0x40;
        assert!(matches!(Packet::parse(&bad_crc[..n]), Err(Error::Crc { .. })));

        assert_eq!(Packet::parse(&good[..3]), Err(Error::TooShort(3)));

        // A valid CRC over a wrong version, an unknown type, a short payload.
        for (body, want) in [
            (&[1u8, 0x05, 0, 0, 9, 0, 0, 0][..], Error::Version(1)),
            (&[2u8, 0x42, 0, 0][..], Error::UnknownType(0x42)),
            (&[2u8, 0x05, 0, 0, 9, 0][..], Error::PayloadLength { msg_type: MessageType::Ping, len: 2 }),
            (&[2u8, 0x01, 0, 0, 0][..], Error::PayloadLength { msg_type: MessageType::GetInfo, len: 1 }),
            (&[2u8, 0x83, 0, 0, 1, 0, 2, 99][..], Error::Field { msg_type: MessageType::Nack, field: "reason" }),
        ] {
            let mut f = [0u8; 16];
            f[..body.len()].copy_from_slice(body);
            let crc = crc16_ibm3740(body);
            f[body.len()..body.len() + 2].copy_from_slice(&crc.to_le_bytes());
            assert_eq!(Packet::parse(&f[..body.len() + 2]), Err(want));
        }
    }

    #[test]
    fn schedule_rules() {
        let s = |led, slot_us| LedSlot { led, slot_us };
        assert_eq!(Schedule::new(&[], 0, 1), Err(ScheduleError::Empty));
        assert_eq!(Schedule::new(&[s(1, 0)], 0, 1), Err(ScheduleError::ZeroSlot(1)));
        assert_eq!(Schedule::new(&[s(1, 99)], 0, 1), Err(ScheduleError::ZeroSlot(1)));
        assert!(Schedule::new(&[s(1, 100)], 0, 1).is_ok());
        assert_eq!(Schedule::new(&[s(0, 500)], 0, 1), Err(ScheduleError::ZeroLed));
        assert_eq!(Schedule::new(&[s(1, 500), s(1, 500)], 0, 1), Err(ScheduleError::DuplicateLed(1)));
        assert_eq!(Schedule::new(&[s(1, 500)], 0, 0), Err(ScheduleError::ZeroAveraging));
        let many: [LedSlot; 65] = core::array::from_fn(|i| s(i as u8 + 1, 500));
        assert_eq!(Schedule::new(&many, 0, 1), Err(ScheduleError::TooManyLeds(65)));
        assert!(Schedule::new(&many[..64], 0, 1).is_ok());
    }

    #[test]
    fn emit_into_small_buffer_is_an_error() {
        let p = Packet::new(1, Message::Sample(sample()));
        for cap in 0..31 {
            let mut buf = [0u8; 31];
            assert_eq!(p.emit(&mut buf[..cap]), Err(Error::BufferTooSmall), "cap {cap}");
        }
        let mut out = [0u8; 32];
        assert_eq!(p.encode(&mut out), Err(Error::BufferTooSmall));
    }
}
