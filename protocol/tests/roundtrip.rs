//! Property tests: every message of every protocol survives emit -> parse unchanged, and
//! the parsers survive any bytes at all.

use flowgate_protocol::can::{CanFrame, CanId};
use flowgate_protocol::motor::*;
use flowgate_protocol::psd::{self, *};
use flowgate_protocol::slcan::{self, Bitrate, Command, Line, Response};
use proptest::prelude::*;

fn schedule() -> impl Strategy<Value = Schedule> {
    (proptest::collection::btree_map(1u8.., MIN_SLOT_US.., 1..=MAX_SCHEDULE_LEDS), any::<u16>(), 1u8..).prop_map(
        |(leds, dark, avg)| {
            let slots: Vec<LedSlot> = leds.into_iter().map(|(led, slot_us)| LedSlot { led, slot_us }).collect();
            Schedule::new(&slots, dark, avg).unwrap()
        },
    )
}

/// A controller stamp a frame may carry (later ones are refused as absurd).
fn stamp() -> impl Strategy<Value = u64> {
    0..=flowgate_protocol::psd::MAX_STAMP_US
}

fn psd_message() -> impl Strategy<Value = Message> {
    let nack = (1u8..=9).prop_map(|r| NackReason::from_u8(r).unwrap());
    let fault = (1u8..=5).prop_map(|r| FaultCode::from_u8(r).unwrap());
    let state = (0u8..=2).prop_map(|r| ControllerState::from_u8(r).unwrap());
    prop_oneof![
        Just(Message::GetInfo),
        schedule().prop_map(Message::SetSchedule),
        Just(Message::StartStream),
        Just(Message::StopStream),
        any::<u32>().prop_map(|nonce| Message::Ping { nonce }),
        any::<u64>().prop_map(|host_time_us| Message::TimeSync { host_time_us }),
        (any::<u16>(), any::<[u8; 3]>(), any::<[u16; 2]>(), any::<u8>(), any::<u32>()).prop_map(
            |(request_seq, firmware, psd_counts, max_leds, clock_hz)| {
                Message::Info { request_seq, info: Info { firmware, psd_counts, max_leds, clock_hz } }
            }
        ),
        (any::<u16>(), any::<u8>()).prop_map(|(seq, msg_type)| Message::Ack { seq, msg_type }),
        (any::<u16>(), any::<u8>(), nack).prop_map(|(seq, msg_type, reason)| Message::Nack { seq, msg_type, reason }),
        (any::<u32>(), any::<u8>(), any::<u8>(), stamp(), any::<i32>(), any::<i32>(), any::<u16>(), 0u8..16).prop_map(
            |(frame, slot, led, t_ctrl_us, x, y, intensity, flags)| Message::Sample(Sample {
                frame,
                slot,
                led,
                t_ctrl_us,
                x,
                y,
                intensity,
                flags: SampleFlags(flags)
            })
        ),
        (any::<u32>(), stamp(), any::<u8>()).prop_map(|(frame, t_ctrl_us, samples)| Message::FrameEnd {
            frame,
            t_ctrl_us,
            samples
        }),
        (fault, any::<u32>()).prop_map(|(code, detail)| Message::Fault { code, detail }),
        (stamp(), state).prop_map(|(t_ctrl_us, state)| Message::Heartbeat { t_ctrl_us, state }),
        (any::<u16>(), any::<u32>(), stamp()).prop_map(|(request_seq, nonce, t_ctrl_us)| Message::Pong {
            request_seq,
            nonce,
            t_ctrl_us
        }),
        (any::<u16>(), any::<u64>(), stamp()).prop_map(|(request_seq, host_time_us, t_ctrl_us)| {
            Message::TimeSyncReply { request_seq, host_time_us, t_ctrl_us }
        }),
    ]
}

fn node() -> impl Strategy<Value = NodeId> {
    (1u8..=15).prop_map(|n| NodeId::new(n).unwrap())
}

fn target() -> impl Strategy<Value = Target> {
    prop_oneof![Just(Target::All), node().prop_map(Target::Node)]
}

pub fn motor_message() -> impl Strategy<Value = MotorMessage> {
    let rate = -MAX_PULSE_RATE..=MAX_PULSE_RATE;
    let board_state = (0u8..=4).prop_map(|s| BoardState::from_u8(s).unwrap());
    prop_oneof![
        (target(), (0u8..=4).prop_map(|r| EStopReason::from_u8(r).unwrap()))
            .prop_map(|(target, reason)| MotorMessage::EStop { target, reason }),
        (
            target(),
            prop_oneof![
                Just(NmtCommand::Enable),
                Just(NmtCommand::Disable),
                Just(NmtCommand::Reset),
                Just(NmtCommand::FaultReset)
            ]
        )
            .prop_map(|(target, command)| MotorMessage::Nmt { target, command }),
        (node(), any::<u8>()).prop_map(|(node, f)| MotorMessage::Emergency { node, faults: FaultBits(f) }),
        (node(), rate.clone(), rate.clone(), any::<u8>()).prop_map(|(node, left, right, seq)| MotorMessage::Velocity {
            node,
            left,
            right,
            seq
        }),
        (node(), 0..=MAX_U24, 0..=MAX_U24, 1u16..)
            .prop_map(|(node, accel, max_rate, timeout_ms)| MotorMessage::Config { node, accel, max_rate, timeout_ms }),
        (node(), board_state.clone(), any::<u8>(), any::<u8>(), any::<u8>()).prop_map(
            |(node, state, f, last_seq, seq_errors)| {
                MotorMessage::Status { node, state, faults: FaultBits(f), last_seq, seq_errors }
            }
        ),
        (node(), rate.clone(), rate).prop_map(|(node, left, right)| MotorMessage::AxisRates { node, left, right }),
        (node(), any::<i32>(), any::<i32>()).prop_map(|(node, left, right)| MotorMessage::Position {
            node,
            left,
            right
        }),
        (1u8..=6).prop_map(|s| MotorMessage::GatewayHeartbeat { state: GatewayState::from_u8(s).unwrap() }),
        (node(), board_state).prop_map(|(node, state)| MotorMessage::Heartbeat { node, state }),
    ]
}

fn can_frame() -> impl Strategy<Value = CanFrame> {
    let id = prop_oneof![(0u16..=0x7FF).prop_map(CanId::Standard), (0u32..=0x1FFF_FFFF).prop_map(CanId::Extended)];
    prop_oneof![
        (id.clone(), proptest::collection::vec(any::<u8>(), 0..=8)).prop_map(|(id, d)| CanFrame::new(id, &d).unwrap()),
        (id, 0u8..=8).prop_map(|(id, n)| CanFrame::remote(id, n).unwrap()),
    ]
}

fn bitrate() -> impl Strategy<Value = Bitrate> {
    prop_oneof![
        Just(Bitrate::K10),
        Just(Bitrate::K20),
        Just(Bitrate::K50),
        Just(Bitrate::K100),
        Just(Bitrate::K125),
        Just(Bitrate::K250),
        Just(Bitrate::K500),
        Just(Bitrate::K800),
        Just(Bitrate::M1)
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn psd_round_trip(seq in any::<u16>(), message in psd_message()) {
        let packet = Packet::new(seq, message);
        let mut wire = [0u8; psd::MAX_WIRE_LEN];
        let n = packet.encode(&mut wire).unwrap();
        prop_assert_eq!(wire[n - 1], 0);
        prop_assert!(!wire[..n - 1].contains(&0));
        prop_assert_eq!(Packet::decode(&wire[..n - 1]).unwrap(), packet);
    }

    #[test]
    fn psd_single_bit_errors_are_caught(seq in any::<u16>(), message in psd_message(), bit in any::<usize>()) {
        let packet = Packet::new(seq, message);
        let mut frame = [0u8; psd::MAX_FRAME_LEN];
        let n = packet.emit(&mut frame).unwrap();
        let bit = bit % (n * 8);
        frame[bit / 8] ^= 1 << (bit % 8);
        prop_assert!(Packet::parse(&frame[..n]).is_err());
    }

    #[test]
    fn psd_parsers_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
        let _ = Packet::decode(&bytes);
        let _ = Packet::parse(&bytes);
    }

    #[test]
    fn motor_round_trip(message in motor_message()) {
        let frame = message.to_frame().unwrap();
        prop_assert_eq!(MotorMessage::parse(&frame).unwrap(), message);
    }

    #[test]
    fn motor_parser_never_panics(frame in can_frame()) {
        if let Ok(m) = MotorMessage::parse(&frame) {
            // Whatever parses re-emits to a frame on the same id.
            prop_assert_eq!(m.to_frame().unwrap().id(), frame.id());
        }
    }

    #[test]
    fn slcan_command_round_trip(cmd in prop_oneof![
        can_frame().prop_map(Command::Transmit),
        bitrate().prop_map(Command::SetBitrate),
        any::<bool>().prop_map(Command::Timestamps),
        Just(Command::Open), Just(Command::ListenOnly), Just(Command::Close), Just(Command::Version),
        Just(Command::SerialNumber), Just(Command::StatusFlags), Just(Command::Empty),
    ]) {
        let mut buf = [0u8; slcan::MAX_LINE_LEN];
        let n = cmd.emit(&mut buf).unwrap();
        prop_assert_eq!(Command::parse(&buf[..n]).unwrap(), cmd);
    }

    #[test]
    fn slcan_response_round_trip(resp in prop_oneof![
        (can_frame(), proptest::option::of(0u16..60_000)).prop_map(|(frame, timestamp_ms)| Response::Frame { frame, timestamp_ms }),
        Just(Response::Ok), Just(Response::Error),
        any::<bool>().prop_map(|extended| Response::TxAck { extended }),
        (0u8..100, 0u8..100).prop_map(|(hardware, software)| Response::Version { hardware, software }),
        "[A-Z0-9]{4}".prop_map(|s| Response::SerialNumber(s.as_bytes().try_into().unwrap())),
        any::<u8>().prop_map(Response::StatusFlags),
    ]) {
        let mut buf = [0u8; slcan::MAX_LINE_LEN];
        let n = resp.emit(&mut buf).unwrap();
        prop_assert_eq!(Response::parse(&buf[..n]).unwrap(), resp);
    }

    #[test]
    fn slcan_parsers_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..40)) {
        let _ = Command::parse(&bytes);
        let _ = Response::parse(&bytes);
    }
}
