//! The streaming codecs: bad frames come out as error items, the stream resynchronises,
//! and every dropped byte is counted.
#![cfg(feature = "codec")]

use bytes::BytesMut;
use flowgate_protocol::codec::{PsdCodec, SlcanAdapterCodec, SlcanHostCodec, StreamError};
use flowgate_protocol::psd::{self, Message, Packet};
use flowgate_protocol::slcan::{Command, Response, SlcanError};
use flowgate_protocol::{CanFrame, CanId};
use proptest::prelude::*;
use tokio_util::codec::{Decoder, Encoder};

fn ping(seq: u16) -> Packet {
    Packet::new(seq, Message::Ping { nonce: u32::from(seq) * 7 })
}

fn wire(p: Packet) -> Vec<u8> {
    let mut buf = BytesMut::new();
    PsdCodec::new().encode(p, &mut buf).unwrap();
    buf.to_vec()
}

/// Drain every item the decoder yields from `bytes`, fed in chunks of `chunk` bytes.
fn decode_all<D: Decoder>(codec: &mut D, bytes: &[u8], chunk: usize) -> Vec<D::Item>
where
    D::Error: std::fmt::Debug,
{
    let mut buf = BytesMut::new();
    let mut out = Vec::new();
    for piece in bytes.chunks(chunk.max(1)) {
        buf.extend_from_slice(piece);
        while let Some(item) = codec.decode(&mut buf).unwrap() {
            out.push(item);
        }
    }
    out
}

#[test]
fn psd_resynchronises_after_garbage_and_counts_it() {
    let mut stream = wire(ping(1));
    stream.extend_from_slice(&[0x13, 0x37, 0xFF, 0x00]); // garbage, then a delimiter
    stream.extend(wire(ping(2)));
    let mut corrupted = wire(ping(3));
    corrupted[4] ^= 0x55; // flips bits inside the frame: CRC or COBS will object
    stream.extend(&corrupted);
    stream.extend(wire(ping(4)));

    let mut codec = PsdCodec::new();
    let items = decode_all(&mut codec, &stream, 5);
    let seqs: Vec<_> = items.iter().filter_map(|i| i.as_ref().ok()).map(|p| p.seq).collect();
    assert_eq!(seqs, [1, 2, 4]);
    assert_eq!(items.iter().filter(|i| i.is_err()).count(), 2);
    let stats = codec.stats();
    assert_eq!(stats.frames, 3);
    assert_eq!(stats.bad_frames, 2);
    assert_eq!(stats.dropped_bytes, 4 + corrupted.len() as u64);
}

#[test]
fn psd_overlong_run_is_dropped_and_reported_once() {
    let mut stream = vec![0xAA; 3 * psd::MAX_WIRE_LEN];
    stream.push(0);
    stream.extend(wire(ping(9)));
    let mut codec = PsdCodec::new();
    let items = decode_all(&mut codec, &stream, 7);
    assert!(matches!(items[0], Err(StreamError::Overlong { .. })));
    assert_eq!(items.len(), 2, "one overlong report, then the good frame: {items:?}");
    assert_eq!(items[1].as_ref().unwrap().seq, 9);
    assert_eq!(codec.stats().dropped_bytes, 3 * psd::MAX_WIRE_LEN as u64 + 1);
    assert_eq!(codec.stats().bad_frames, 1);
}

/// A controller's end reads a schedule of 64 LEDs; a gateway's end, which only ever reads
/// replies, cuts the same bytes as an overlong run.
#[test]
fn a_64_led_schedule_is_read_by_a_controller_and_is_overlong_to_a_gateway() {
    let slots: Vec<psd::LedSlot> = (1..=64).map(|led| psd::LedSlot { led, slot_us: 250 }).collect();
    let schedule = psd::Schedule::new(&slots, 1000, 1).unwrap();
    assert_eq!(schedule.frame_period_us(), 64 * 250 + 1000);
    let bytes = wire(Packet::new(5, Message::SetSchedule(schedule)));
    assert!(bytes.len() > psd::MAX_REPLY_WIRE_LEN && bytes.len() <= psd::MAX_WIRE_LEN, "{} bytes", bytes.len());
    let items = decode_all(&mut PsdCodec::controller(), &bytes, 16);
    assert!(matches!(&items[..], [Ok(Packet { seq: 5, message: Message::SetSchedule(s) })] if s.slots().len() == 64));
    let items = decode_all(&mut PsdCodec::new(), &bytes, 16);
    assert!(matches!(&items[..], [Err(StreamError::Overlong { .. })]), "{items:?}");
    assert!(psd::Schedule::new(&[slots.clone(), vec![psd::LedSlot { led: 65, slot_us: 250 }]].concat(), 0, 1).is_err());
}

#[test]
fn psd_idle_delimiters_are_not_errors() {
    let mut stream = vec![0, 0, 0];
    stream.extend(wire(ping(1)));
    stream.extend([0, 0]);
    let mut codec = PsdCodec::new();
    let items = decode_all(&mut codec, &stream, 64);
    assert_eq!(items.len(), 1);
    assert_eq!(codec.stats().bad_frames, 0);
}

#[test]
fn slcan_host_codec_reads_responses_and_recovers() {
    let stream = b"t701105\r\x07zz\rZ\rV1013\rtXYZ\rt2810EA5F\r";
    let mut codec = SlcanHostCodec::new();
    let items = decode_all(&mut codec, stream, 3);
    let frame = CanFrame::new(CanId::Standard(0x701), &[0x05]).unwrap();
    assert_eq!(items[0], Ok(Response::Frame { frame, timestamp_ms: None }));
    assert_eq!(items[1], Ok(Response::Error));
    assert!(matches!(items[2], Err(StreamError::Frame { error: SlcanError::UnknownCommand('z'), len: 3 })));
    assert_eq!(items[3], Ok(Response::TxAck { extended: true }));
    assert_eq!(items[4], Ok(Response::Version { hardware: 10, software: 13 }));
    assert!(items[5].is_err());
    assert!(matches!(items[6], Ok(Response::Frame { timestamp_ms: Some(0xEA5F), .. })));
    assert_eq!(codec.stats().bad_frames, 2);
}

#[test]
fn slcan_adapter_codec_reads_python_can_start_sequence() {
    // python-can's slcan interface: close, bitrate, an empty data-bitrate line, open.
    let mut codec = SlcanAdapterCodec::new();
    let items = decode_all(&mut codec, b"C\rS8\r\rO\rt101700000000000000\r", 4);
    let cmds: Vec<_> = items.into_iter().map(Result::unwrap).collect();
    assert_eq!(cmds.len(), 5);
    assert_eq!(cmds[0], Command::Close);
    assert_eq!(cmds[2], Command::Empty);
    assert!(matches!(cmds[4], Command::Transmit(f) if f.id() == CanId::Standard(0x101) && f.dlc() == 7));
}

proptest! {
    /// Whatever the chunking, a stream of good frames with garbage between them yields
    /// every good frame, in order.
    #[test]
    fn psd_stream_survives_any_garbage(
        garbage in proptest::collection::vec(proptest::collection::vec(1u8.., 0..100), 1..8),
        chunk in 1usize..50,
    ) {
        let mut stream = Vec::new();
        for (i, g) in garbage.iter().enumerate() {
            stream.extend(g);
            stream.push(0);
            stream.extend(wire(ping(i as u16)));
        }
        let mut codec = PsdCodec::new();
        let items = decode_all(&mut codec, &stream, chunk);
        let seqs: Vec<u16> = items.iter().filter_map(|i| i.as_ref().ok()).map(|p| p.seq).collect();
        prop_assert_eq!(seqs, (0..garbage.len() as u16).collect::<Vec<_>>());
    }

    /// Nothing is lost uncounted: every byte given to a decoder is taken (in a good frame
    /// or an idle delimiter), dropped (counted), or still in its buffer.
    #[test]
    fn every_byte_is_taken_dropped_or_buffered(
        pieces in proptest::collection::vec((any::<bool>(), proptest::collection::vec(any::<u8>(), 0..80)), 0..12),
        chunk in 1usize..64,
    ) {
        // Good frames among random bytes, so both ways are taken.
        let mut stream = Vec::new();
        for (i, (good, bytes)) in pieces.iter().enumerate() {
            if *good { stream.extend(wire(ping(i as u16))) } else { stream.extend(bytes) }
        }
        fn account<D: Decoder>(codec: &mut D, bytes: &[u8], chunk: usize) -> usize where D::Error: std::fmt::Debug {
            let mut buf = BytesMut::new();
            for piece in bytes.chunks(chunk) {
                buf.extend_from_slice(piece);
                while codec.decode(&mut buf).unwrap().is_some() {}
            }
            buf.len()
        }
        let mut psd = PsdCodec::new();
        let left = account(&mut psd, &stream, chunk) as u64;
        let s = psd.stats();
        prop_assert_eq!(s.taken_bytes + s.dropped_bytes + left, stream.len() as u64, "{:?}", s);
        let mut slcan = SlcanHostCodec::new();
        let left = account(&mut slcan, &stream, chunk) as u64;
        let s = slcan.stats();
        prop_assert_eq!(s.taken_bytes + s.dropped_bytes + left, stream.len() as u64, "{:?}", s);
    }

    #[test]
    fn codecs_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600), chunk in 1usize..64) {
        decode_all(&mut PsdCodec::new(), &bytes, chunk);
        decode_all(&mut SlcanHostCodec::new(), &bytes, chunk);
        decode_all(&mut SlcanAdapterCodec::new(), &bytes, chunk);
    }
}
