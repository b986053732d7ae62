//! Streaming decoders and encoders for `tokio_util::codec` (feature `codec`).
//!
//! Each decoder's `Item` is a `Result`: a frame that does not decode is yielded as an
//! `Err` item and the stream goes on, so one bad frame never ends a link. The decoder
//! resynchronises at the next delimiter (`0x00` for PSD frames, CR/BEL for SLCAN), bounds
//! its buffer, and counts in [`DecodeStats`] every frame it yields and every byte it drops.
//! The `io::Error` of the `Decoder` trait is reserved for I/O failures.

use bytes::{Buf, BufMut, BytesMut};
use core::marker::PhantomData;
use std::io;
use tokio_util::codec::{Decoder, Encoder};

use crate::psd::{self, Packet};
use crate::slcan::{self, Line, SlcanError};

/// What a decoder has seen so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DecodeStats {
    /// Frames decoded and yielded as `Ok`.
    pub frames: u64,
    /// Frames yielded as `Err` (bad CRC, bad COBS, unknown type, ...).
    pub bad_frames: u64,
    /// Bytes thrown away: bad frames' bytes, over-long runs with no delimiter.
    pub dropped_bytes: u64,
    /// Bytes taken: good frames' bytes with their delimiters, and idle delimiters. Every
    /// byte given to the decoder is taken, dropped, or still in its buffer.
    pub taken_bytes: u64,
}

/// A frame that did not decode: why, and how many bytes it cost.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum StreamError<E> {
    /// The bytes between two delimiters did not decode.
    #[error("bad frame ({len} bytes): {error}")]
    Frame { error: E, len: usize },
    /// More than the longest frame arrived without a delimiter; the bytes were dropped
    /// up to the next delimiter.
    #[error("{dropped} bytes without a delimiter dropped")]
    Overlong { dropped: usize },
}

/// Splits a byte stream into delimited chunks, bounding and counting garbage. Shared by
/// both codecs: only the delimiter test and the longest legal chunk differ.
#[derive(Debug)]
struct Splitter {
    max_len: usize,
    /// Inside an over-long run: drop everything up to the next delimiter.
    discarding: bool,
    stats: DecodeStats,
}

enum Chunk {
    /// `len` bytes of a chunk, `terminator` more bytes to drop after it.
    Line {
        len: usize,
        terminator: usize,
    },
    Overlong(usize),
}

impl Splitter {
    fn new(max_len: usize) -> Self {
        Self { max_len, discarding: false, stats: DecodeStats::default() }
    }

    /// The next chunk in `buf`, `None` when more bytes are needed. `is_delim` finds a
    /// delimiter; `keep_delim` says whether it belongs to the chunk (SLCAN keeps it).
    fn next(&mut self, buf: &mut BytesMut, is_delim: impl Fn(u8) -> bool, keep_delim: bool) -> Option<Chunk> {
        loop {
            match buf.iter().position(|&b| is_delim(b)) {
                Some(i) if self.discarding => {
                    buf.advance(i + 1);
                    self.stats.dropped_bytes += (i + 1) as u64;
                    self.discarding = false;
                    // The over-long run was already reported; look for the next chunk.
                }
                Some(i) if i + usize::from(keep_delim) > self.max_len => {
                    buf.advance(i + 1);
                    self.stats.dropped_bytes += (i + 1) as u64;
                    self.stats.bad_frames += 1;
                    return Some(Chunk::Overlong(i + 1));
                }
                Some(i) => {
                    let len = if keep_delim { i + 1 } else { i };
                    return Some(Chunk::Line { len, terminator: i + 1 - len });
                }
                None if buf.len() > self.max_len => {
                    let n = buf.len();
                    buf.advance(n);
                    self.stats.dropped_bytes += n as u64;
                    let first = !self.discarding;
                    self.discarding = true;
                    if first {
                        self.stats.bad_frames += 1;
                        return Some(Chunk::Overlong(n));
                    }
                    return None;
                }
                None => return None,
            }
        }
    }
}

/// PSD controller frames: COBS, `0x00`-delimited. Decodes [`Packet`]s, encodes them too.
#[derive(Debug)]
pub struct PsdCodec {
    splitter: Splitter,
    rejected: Option<psd::Header>,
}

impl Default for PsdCodec {
    fn default() -> Self {
        Self { splitter: Splitter::new(psd::MAX_REPLY_WIRE_LEN - 1), rejected: None }
    }
}

impl PsdCodec {
    /// A gateway's end: it reads a controller's replies, at most
    /// [`psd::MAX_REPLY_WIRE_LEN`] bytes a frame.
    pub fn new() -> Self {
        Self::default()
    }

    /// A controller's end: it reads a gateway's requests, up to a schedule of
    /// [`psd::MAX_SCHEDULE_LEDS`] LEDs.
    pub fn controller() -> Self {
        Self { splitter: Splitter::new(psd::MAX_WIRE_LEN - 1), rejected: None }
    }

    /// The header of the last frame that did not decode, if it could be read: a controller
    /// names the request in its Nack.
    pub fn rejected_header(&self) -> Option<psd::Header> {
        self.rejected
    }
    pub fn stats(&self) -> DecodeStats {
        self.splitter.stats
    }
}

impl Decoder for PsdCodec {
    type Item = Result<Packet, StreamError<psd::Error>>;
    type Error = io::Error;

    fn decode(&mut self, buf: &mut BytesMut) -> Result<Option<Self::Item>, io::Error> {
        loop {
            match self.splitter.next(buf, |b| b == 0, false) {
                None => return Ok(None),
                Some(Chunk::Overlong(dropped)) => return Ok(Some(Err(StreamError::Overlong { dropped }))),
                Some(Chunk::Line { len: 0, terminator }) => {
                    // Idle delimiters.
                    buf.advance(terminator);
                    self.splitter.stats.taken_bytes += terminator as u64;
                }
                Some(Chunk::Line { len, terminator }) => {
                    let result = Packet::decode(&buf[..len]);
                    self.rejected = result.is_err().then(|| psd::Header::of_wire(&buf[..len])).flatten();
                    buf.advance(len + terminator);
                    let stats = &mut self.splitter.stats;
                    return Ok(Some(match result {
                        Ok(p) => {
                            stats.frames += 1;
                            stats.taken_bytes += (len + terminator) as u64;
                            Ok(p)
                        }
                        Err(error) => {
                            stats.bad_frames += 1;
                            stats.dropped_bytes += (len + terminator) as u64;
                            Err(StreamError::Frame { error, len })
                        }
                    }));
                }
            }
        }
    }
}

impl Encoder<Packet> for PsdCodec {
    type Error = io::Error;
    fn encode(&mut self, packet: Packet, dst: &mut BytesMut) -> Result<(), io::Error> {
        let mut wire = [0u8; psd::MAX_WIRE_LEN];
        let n = packet.encode(&mut wire).map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
        dst.put_slice(&wire[..n]);
        Ok(())
    }
}

/// SLCAN lines. `D` is what this side decodes, `E` what it encodes:
/// [`SlcanHostCodec`] for a host driving an adapter, [`SlcanAdapterCodec`] for an adapter.
pub struct SlcanCodec<D, E> {
    splitter: Splitter,
    _lines: PhantomData<fn(E) -> D>,
}

/// The host end: decodes adapter [`slcan::Response`]s, encodes [`slcan::Command`]s.
pub type SlcanHostCodec = SlcanCodec<slcan::Response, slcan::Command>;
/// The adapter end: decodes [`slcan::Command`]s, encodes [`slcan::Response`]s.
pub type SlcanAdapterCodec = SlcanCodec<slcan::Command, slcan::Response>;

impl<D, E> Default for SlcanCodec<D, E> {
    fn default() -> Self {
        Self { splitter: Splitter::new(slcan::MAX_LINE_LEN), _lines: PhantomData }
    }
}

impl<D, E> core::fmt::Debug for SlcanCodec<D, E> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("SlcanCodec").field("stats", &self.splitter.stats).finish()
    }
}

impl<D, E> SlcanCodec<D, E> {
    pub fn new() -> Self {
        Self::default()
    }
    pub fn stats(&self) -> DecodeStats {
        self.splitter.stats
    }
}

impl<D: Line, E> Decoder for SlcanCodec<D, E> {
    type Item = Result<D, StreamError<SlcanError>>;
    type Error = io::Error;

    fn decode(&mut self, buf: &mut BytesMut) -> Result<Option<Self::Item>, io::Error> {
        match self.splitter.next(buf, |b| b == slcan::CR || b == slcan::BEL, true) {
            None => Ok(None),
            Some(Chunk::Overlong(dropped)) => Ok(Some(Err(StreamError::Overlong { dropped }))),
            Some(Chunk::Line { len, .. }) => {
                let result = D::parse(&buf[..len]);
                buf.advance(len);
                let stats = &mut self.splitter.stats;
                Ok(Some(match result {
                    Ok(line) => {
                        stats.frames += 1;
                        stats.taken_bytes += len as u64;
                        Ok(line)
                    }
                    Err(error) => {
                        stats.bad_frames += 1;
                        stats.dropped_bytes += len as u64;
                        Err(StreamError::Frame { error, len })
                    }
                }))
            }
        }
    }
}

impl<D, E: Line> Encoder<E> for SlcanCodec<D, E> {
    type Error = io::Error;
    fn encode(&mut self, line: E, dst: &mut BytesMut) -> Result<(), io::Error> {
        let mut buf = [0u8; slcan::MAX_LINE_LEN];
        let n = line.emit(&mut buf).map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
        dst.put_slice(&buf[..n]);
        Ok(())
    }
}
