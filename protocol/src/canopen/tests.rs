use super::*;

fn node(n: u8) -> NodeId {
    NodeId::new(n).unwrap()
}

fn round_trip(m: CanOpenMessage) -> CanFrame {
    let f = m.to_frame().unwrap();
    assert_eq!(CanOpenMessage::parse(&f), Ok(m), "{f:?}");
    f
}

#[test]
fn the_predefined_connection_set() {
    let f = round_trip(CanOpenMessage::Nmt { command: NmtCommand::Start, target: NmtTarget::Node(node(5)) });
    assert_eq!((f.id(), f.data()), (CanId::Standard(0x000), &[0x01, 5][..]));
    let f = round_trip(CanOpenMessage::Nmt { command: NmtCommand::ResetNode, target: NmtTarget::All });
    assert_eq!(f.data(), &[0x81, 0]);
    assert_eq!(round_trip(CanOpenMessage::Sync).id(), CanId::Standard(0x080));
    let f = round_trip(CanOpenMessage::Heartbeat { node: node(5), state: NmtState::Operational });
    assert_eq!((f.id(), f.data()), (CanId::Standard(0x705), &[0x05][..]));
    let boot = CanFrame::new(CanId::Standard(0x77F), &[0]).unwrap();
    assert_eq!(
        CanOpenMessage::parse(&boot),
        Ok(CanOpenMessage::Heartbeat { node: node(127), state: NmtState::BootUp })
    );
    let emcy = Emcy { error_code: 0x3220, error_register: 0x05, vendor: [1, 2, 3, 4, 5] };
    let f = round_trip(CanOpenMessage::Emcy { node: node(2), emcy });
    assert_eq!((f.id(), f.data()), (CanId::Standard(0x082), &[0x20, 0x32, 0x05, 1, 2, 3, 4, 5][..]));
    assert_eq!(emcy.describe(), "DC link under-voltage");
    let f = round_trip(CanOpenMessage::Pdo {
        direction: PdoDirection::Receive,
        number: 1,
        node: node(2),
        data: VelocityCommand { controlword: 0x000F, target_velocity: -1000 }.data(),
    });
    assert_eq!((f.id(), f.data()), (CanId::Standard(0x202), &[0x0F, 0, 0x18, 0xFC, 0xFF, 0xFF][..]));
    let f = round_trip(CanOpenMessage::Pdo {
        direction: PdoDirection::Transmit,
        number: 2,
        node: node(2),
        data: PdoData::new(&[1, 2, 3, 4]).unwrap(),
    });
    assert_eq!(f.id(), CanId::Standard(0x282));
}

/// Expedited SDO bytes as CiA 301 gives them, e.g. writing 3 (profile velocity) to
/// 0x6060:00 is `2F 60 60 00 03 00 00 00`, and its answer `60 60 60 00 00 00 00 00`.
#[test]
fn expedited_sdo_bytes() {
    let write =
        SdoRequest::Download { index: object::MODES_OF_OPERATION, sub: 0, data: SdoData::i8(PROFILE_VELOCITY_MODE) };
    let f = round_trip(CanOpenMessage::SdoRequest { node: node(3), request: write });
    assert_eq!((f.id(), f.data()), (CanId::Standard(0x603), &[0x2F, 0x60, 0x60, 0, 3, 0, 0, 0][..]));
    let done = SdoResponse::Downloaded { index: object::MODES_OF_OPERATION, sub: 0 };
    let f = round_trip(CanOpenMessage::SdoResponse { node: node(3), response: done });
    assert_eq!((f.id(), f.data()), (CanId::Standard(0x583), &[0x60, 0x60, 0x60, 0, 0, 0, 0, 0][..]));
    let write = SdoRequest::Download { index: 0x1017, sub: 0, data: SdoData::u16(100) };
    assert_eq!(
        CanOpenMessage::SdoRequest { node: node(3), request: write }.to_frame().unwrap().data(),
        &[0x2B, 0x17, 0x10, 0, 100, 0, 0, 0]
    );
    let write = SdoRequest::Download { index: 0x6083, sub: 0, data: SdoData::u32(5000) };
    assert_eq!(
        CanOpenMessage::SdoRequest { node: node(3), request: write }.to_frame().unwrap().data(),
        &[0x23, 0x83, 0x60, 0, 0x88, 0x13, 0, 0]
    );
    let read = SdoRequest::Upload { index: object::STATUSWORD, sub: 0 };
    assert_eq!(
        round_trip(CanOpenMessage::SdoRequest { node: node(3), request: read }).data(),
        &[0x40, 0x41, 0x60, 0, 0, 0, 0, 0]
    );
    let value = SdoResponse::Uploaded { index: object::STATUSWORD, sub: 0, data: SdoData::u16(0x0637) };
    let f = round_trip(CanOpenMessage::SdoResponse { node: node(3), response: value });
    assert_eq!(f.data(), &[0x4B, 0x41, 0x60, 0, 0x37, 0x06, 0, 0]);
    let abort = SdoResponse::Abort { index: 0x2000, sub: 1, code: 0x0602_0000 };
    let f = round_trip(CanOpenMessage::SdoResponse { node: node(3), response: abort });
    assert_eq!(f.data(), &[0x80, 0x00, 0x20, 1, 0, 0, 2, 6]);
    assert_eq!(sdo_abort_text(0x0602_0000), "object does not exist in the object dictionary");
}

#[test]
fn what_is_not_read_is_refused_by_name() {
    let f = |id: u16, data: &[u8]| CanOpenMessage::parse(&CanFrame::new(CanId::Standard(id), data).unwrap());
    // A segmented upload's initiate response (no `e`): not misread as a value.
    assert_eq!(f(0x583, &[0x41, 0x08, 0x10, 0, 20, 0, 0, 0]), Err(CanOpenError::UnsupportedSdo(0x41)));
    assert_eq!(f(0x583, &[0xE0, 0, 0, 0, 0, 0, 0, 0]), Err(CanOpenError::UnknownSdoCommand(0xE0)));
    assert_eq!(f(0x583, &[0x60, 0, 0]), Err(CanOpenError::BadLength { cob_id: 0x583, len: 3, expected: 8 }));
    assert_eq!(f(0x000, &[0x07, 1]), Err(CanOpenError::UnknownNmtCommand(7)));
    assert_eq!(f(0x000, &[0x01, 200]), Err(CanOpenError::BadNmtNode(200)));
    assert_eq!(f(0x705, &[0x33]), Err(CanOpenError::UnknownNmtState(0x33)));
    assert_eq!(f(0x780, &[0]), Err(CanOpenError::UnknownCobId(0x780)));
    assert_eq!(f(0x105, &[]), Err(CanOpenError::UnknownCobId(0x105)));
    let ext = CanFrame::new(CanId::Extended(0x705), &[5]).unwrap();
    assert_eq!(CanOpenMessage::parse(&ext), Err(CanOpenError::NotStandardData));
}

/// Every CAN frame id and payload length parses or is refused, never a panic; what
/// parses is emitted as a frame that parses to the same message (an expedited SDO's
/// unused bytes, which CiA 301 leaves undefined, are emitted as zeros).
#[test]
fn any_frame_parses_or_is_refused() {
    for id in 0..=0x7FF_u16 {
        for len in 0..=8usize {
            for data in [[0x2F, 0x40, 0x60, 0, 0x55, 0xAA, 0x0F, 0xF0], [0x05, 0x02, 0, 0, 0, 0, 0, 0]] {
                let frame = CanFrame::new(CanId::Standard(id), &data[..len]).unwrap();
                if let Ok(m) = CanOpenMessage::parse(&frame) {
                    let again = m.to_frame().expect("a parsed message has a frame");
                    assert_eq!(again.id(), frame.id());
                    assert_eq!(CanOpenMessage::parse(&again), Ok(m), "{m:?}");
                }
            }
        }
    }
}

/// The statusword table of CiA 402, with the bits beside the state's set (voltage,
/// remote, target reached) to show they do not move it.
#[test]
fn statuswords_decode_to_their_states() {
    use DriveState as S;
    let noise = statusword::VOLTAGE_ENABLED | statusword::REMOTE | statusword::TARGET_REACHED;
    for (sw, state) in [
        (0x0000, S::NotReadyToSwitchOn),
        (0x0040, S::SwitchOnDisabled),
        (0x0021, S::ReadyToSwitchOn),
        (0x0023, S::SwitchedOn),
        (0x0027, S::OperationEnabled),
        (0x0007, S::QuickStopActive),
        (0x000F, S::FaultReactionActive),
        (0x0008, S::Fault),
    ] {
        assert_eq!(DriveState::from_statusword(sw), state, "{sw:#06x}");
        assert_eq!(DriveState::from_statusword(sw | noise), state, "{sw:#06x} with other bits");
        assert_eq!(DriveState::from_statusword(state.statusword_bits()), state);
    }
    assert_eq!(DriveState::from_statusword(0x0637), S::OperationEnabled);
}

/// From every state, following `towards_operation` through the transitions the
/// controlword gives reaches operation enabled (the states the drive leaves by itself
/// aside).
#[test]
fn the_way_to_operation_enabled() {
    use DriveState as S;
    let after = |cmd: DriveCommand, state: S| match (cmd, state) {
        (DriveCommand::Shutdown, _) => S::ReadyToSwitchOn,
        (DriveCommand::SwitchOn | DriveCommand::DisableOperation, _) => S::SwitchedOn,
        (DriveCommand::EnableOperation, _) => S::OperationEnabled,
        (DriveCommand::DisableVoltage | DriveCommand::FaultReset, _) => S::SwitchOnDisabled,
        (DriveCommand::QuickStop, _) => S::QuickStopActive,
    };
    for start in [S::SwitchOnDisabled, S::ReadyToSwitchOn, S::SwitchedOn, S::QuickStopActive, S::Fault] {
        let (mut state, mut steps) = (start, 0);
        while let Some(cmd) = state.towards_operation() {
            assert_eq!(DriveCommand::decode(cmd.controlword(), state), Some(cmd), "{cmd:?} from {state:?}");
            state = after(cmd, state);
            steps += 1;
            assert!(steps <= 4, "from {start:?}");
        }
        assert_eq!(state, S::OperationEnabled, "from {start:?}");
    }
    assert_eq!(S::NotReadyToSwitchOn.towards_operation(), None);
    assert_eq!(S::FaultReactionActive.towards_operation(), None);
}

#[test]
fn controlwords_decode_by_the_state_they_meet() {
    use DriveState as S;
    let qs = DriveCommand::QuickStop.controlword();
    assert_eq!(DriveCommand::decode(qs, S::OperationEnabled), Some(DriveCommand::QuickStop));
    assert_eq!(DriveCommand::decode(qs, S::SwitchedOn), Some(DriveCommand::DisableVoltage));
    assert_eq!(DriveCommand::decode(0x0000, S::OperationEnabled), Some(DriveCommand::DisableVoltage));
    assert_eq!(DriveCommand::decode(0x0007, S::OperationEnabled), Some(DriveCommand::DisableOperation));
    assert_eq!(DriveCommand::decode(0x000F, S::ReadyToSwitchOn), Some(DriveCommand::EnableOperation));
    assert_eq!(DriveCommand::decode(0x000F, S::SwitchOnDisabled), None, "enable needs shutdown first");
    assert_eq!(
        DriveCommand::decode(0x0080, S::OperationEnabled),
        Some(DriveCommand::DisableVoltage),
        "outside a fault bit 7 is ignored: the other bits disable the voltage"
    );
    assert_eq!(DriveCommand::decode(0x000F, S::Fault), None, "a fault leaves only by its reset");
    assert_eq!(DriveCommand::decode(0x008F, S::Fault), Some(DriveCommand::FaultReset));
}

#[test]
fn the_velocity_pdos() {
    let c = VelocityCommand { controlword: 0x000F, target_velocity: 123_456 };
    assert_eq!(VelocityCommand::parse(&c.data()), Some(c));
    let r = VelocityReport { statusword: 0x0637, velocity_actual: -42 };
    assert_eq!(VelocityReport::parse(&r.data()), Some(r));
    assert_eq!(VelocityReport::parse(&PdoData::new(&[1, 2, 3]).unwrap()), None);
    assert_eq!(mapping_entry(object::TARGET_VELOCITY, 0, 32), 0x60FF_0020);
    assert_eq!(mapping_entry(object::CONTROLWORD, 0, 16), 0x6040_0010);
}
