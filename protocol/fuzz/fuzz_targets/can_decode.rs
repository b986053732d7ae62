//! CAN frames, for both CAN protocols (the motor boards' and CANopen's): any id, flags and
//! payload; never panic; whatever parses re-emits on the same id and parses back equal.
#![no_main]
use flowgate_protocol::canopen::CanOpenMessage;
use flowgate_protocol::motor::MotorMessage;
use flowgate_protocol::{CanFrame, CanId};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let [flags, a, b, c, d, payload @ ..] = data else { return };
    let raw = u32::from_le_bytes([*a, *b, *c, *d]);
    let id = if flags & 1 == 0 { CanId::Standard((raw & 0x7FF) as u16) } else { CanId::Extended(raw & 0x1FFF_FFFF) };
    let frame = if flags & 2 == 0 {
        CanFrame::new(id, &payload[..payload.len().min(8)])
    } else {
        CanFrame::remote(id, flags >> 4)
    };
    let Ok(frame) = frame else { return };
    if let Ok(msg) = MotorMessage::parse(&frame) {
        let again = msg.to_frame().expect("a parsed message re-emits");
        assert_eq!(again.id(), frame.id());
        assert_eq!(MotorMessage::parse(&again), Ok(msg));
    }
    if let Ok(msg) = CanOpenMessage::parse(&frame) {
        let again = msg.to_frame().expect("a parsed message re-emits");
        assert_eq!(again.id(), frame.id());
        assert_eq!(CanOpenMessage::parse(&again), Ok(msg));
    }
});
