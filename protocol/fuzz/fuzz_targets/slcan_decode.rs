//! SLCAN lines in both directions: never panic; whatever parses re-emits and re-parses equal.
#![no_main]
use bytes::BytesMut;
use flowgate_protocol::codec::{SlcanAdapterCodec, SlcanHostCodec};
use flowgate_protocol::slcan::{Command, Line, Response, MAX_LINE_LEN};
use libfuzzer_sys::fuzz_target;
use tokio_util::codec::Decoder;

fn check<L: Line + PartialEq + core::fmt::Debug>(data: &[u8]) {
    if let Ok(line) = L::parse(data) {
        let mut buf = [0u8; MAX_LINE_LEN];
        let n = line.emit(&mut buf).expect("a parsed line re-emits");
        assert_eq!(L::parse(&buf[..n]), Ok(line));
    }
}

fuzz_target!(|data: &[u8]| {
    check::<Command>(data);
    check::<Response>(data);
    let mut host = SlcanHostCodec::new();
    let mut buf = BytesMut::from(data);
    while let Ok(Some(_)) = host.decode(&mut buf) {}
    let mut adapter = SlcanAdapterCodec::new();
    let mut buf = BytesMut::from(data);
    while let Ok(Some(_)) = adapter.decode(&mut buf) {}
});
