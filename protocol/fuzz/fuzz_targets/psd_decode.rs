//! PSD frames: the one-frame decoder must never panic, whatever decodes must re-encode to
//! the same packet, and the streaming codec must survive any byte stream.
#![no_main]
use bytes::BytesMut;
use flowgate_protocol::codec::PsdCodec;
use flowgate_protocol::psd::{Packet, MAX_WIRE_LEN};
use libfuzzer_sys::fuzz_target;
use tokio_util::codec::Decoder;

fuzz_target!(|data: &[u8]| {
    if let Ok(packet) = Packet::decode(data) {
        let mut wire = [0u8; MAX_WIRE_LEN];
        let n = packet.encode(&mut wire).expect("a decoded packet re-encodes");
        assert_eq!(Packet::decode(&wire[..n - 1]), Ok(packet));
    }
    let _ = Packet::parse(data);
    let mut codec = PsdCodec::new();
    let mut buf = BytesMut::from(data);
    while let Ok(Some(_)) = codec.decode(&mut buf) {}
    let stats = codec.stats();
    assert!(stats.dropped_bytes <= data.len() as u64);
});
