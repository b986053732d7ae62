//! flowgate's CANopen codec against CANopen's own Python stack (`canopen`,
//! protocol/tests/peers/canopen_peer.py): SDO requests encoded here are served by a
//! `canopen.LocalNode` holding a CiA 402 drive's objects, which takes the values and
//! answers in frames this codec reads; `canopen`'s own SDO client and server exchange frames
//! this codec reads as the same transfers; `canopen`'s CiA 402 tables (statusword masks,
//! controlword codes) agree with this crate's; and `canopen` loads protocol/cia402-drive.eds,
//! the drive's dictionary both nodes run on, with the PDO mappings this crate encodes.

#[path = "../../tests/support/python.rs"]
mod python;

use std::collections::BTreeMap;
use std::process::Command;

use flowgate_protocol::canopen::*;
use flowgate_protocol::{CanFrame, CanId};

/// `ID#HEX`, as candump writes a standard frame.
fn candump(f: &CanFrame) -> String {
    let CanId::Standard(id) = f.id() else { panic!("standard ids only") };
    let hex: String = f.data().iter().map(|b| format!("{b:02X}")).collect();
    format!("{id:03X}#{hex}")
}

fn frame(text: &str) -> CanFrame {
    let (id, hex) = text.split_once('#').unwrap();
    let data: Vec<u8> = (0..hex.len()).step_by(2).map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap()).collect();
    CanFrame::new(CanId::Standard(u16::from_str_radix(id, 16).unwrap()), &data).unwrap()
}

fn parse(text: &str) -> CanOpenMessage {
    CanOpenMessage::parse(&frame(text)).unwrap_or_else(|e| panic!("{text}: {e}"))
}

#[test]
fn canopen_serves_our_requests_and_we_read_its_frames() {
    let node = NodeId::new(3).unwrap();
    let writes = [
        (object::MODES_OF_OPERATION, SdoData::i8(PROFILE_VELOCITY_MODE)),
        (object::PROFILE_ACCELERATION, SdoData::u32(5000)),
        (object::PRODUCER_HEARTBEAT_TIME, SdoData::u16(100)),
        (object::TARGET_VELOCITY, SdoData::i32(-1000)),
    ];
    let mut requests: Vec<SdoRequest> =
        writes.iter().map(|&(index, data)| SdoRequest::Download { index, sub: 0, data }).collect();
    requests.push(SdoRequest::Upload { index: object::STATUSWORD, sub: 0 });
    let frames: Vec<String> = requests
        .iter()
        .map(|&request| candump(&CanOpenMessage::SdoRequest { node, request }.to_frame().unwrap()))
        .collect();
    let out = Command::new(python::python())
        .arg(python::peer("canopen_peer"))
        .arg("3")
        .args(&frames)
        .output()
        .expect("could not run python3 (set FLOWGATE_PYTHON, or run the tests with scripts/test)");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();

    // The LocalNode took every write and answered each request; its answers read here.
    let server = &v["server"];
    let answers: Vec<CanOpenMessage> =
        server["answers"].as_array().unwrap().iter().map(|a| parse(a.as_str().unwrap())).collect();
    assert_eq!(answers.len(), requests.len(), "{server}");
    for (&(index, _), answer) in writes.iter().zip(&answers) {
        assert_eq!(*answer, CanOpenMessage::SdoResponse { node, response: SdoResponse::Downloaded { index, sub: 0 } });
    }
    let CanOpenMessage::SdoResponse { response: SdoResponse::Uploaded { index, data, .. }, .. } = answers[4] else {
        panic!("{:?}", answers[4])
    };
    assert_eq!((index, data.value()), (object::STATUSWORD, 0x0637));
    assert_eq!(DriveState::from_statusword(data.value() as u16), DriveState::OperationEnabled);
    let values: BTreeMap<String, i64> = serde_json::from_value(server["values"].clone()).unwrap();
    assert_eq!(
        values,
        BTreeMap::from([("1017".into(), 100), ("6060".into(), 3), ("6083".into(), 5000), ("60FF".into(), -1000)])
    );
    // Writing the producer heartbeat time started canopen's heartbeat: a frame read here
    // as node 3's, every 100 ms.
    let producer = &server["producers"][0];
    assert!(
        matches!(parse(producer["frame"].as_str().unwrap()), CanOpenMessage::Heartbeat { node: n, .. } if n == node)
    );
    assert_eq!(producer["period_s"], 0.1);

    // canopen's own client and server: the same transfers, read here frame by frame.
    let client: Vec<CanOpenMessage> =
        v["client"]["frames"].as_array().unwrap().iter().map(|f| parse(f.as_str().unwrap())).collect();
    let expected = [
        (object::MODES_OF_OPERATION, SdoData::i8(3)),
        (object::PROFILE_ACCELERATION, SdoData::u32(5000)),
        (object::TARGET_VELOCITY, SdoData::i32(-1000)),
    ];
    for (k, &(index, data)) in expected.iter().enumerate() {
        assert_eq!(
            client[2 * k],
            CanOpenMessage::SdoRequest { node, request: SdoRequest::Download { index, sub: 0, data } }
        );
        assert_eq!(
            client[2 * k + 1],
            CanOpenMessage::SdoResponse { node, response: SdoResponse::Downloaded { index, sub: 0 } }
        );
    }
    assert_eq!(
        client[6],
        CanOpenMessage::SdoRequest { node, request: SdoRequest::Upload { index: object::STATUSWORD, sub: 0 } }
    );
    assert_eq!(v["client"]["statusword"], 0x0637);

    // CiA 402 as canopen's BaseNode402 reads and commands it.
    let states = [
        ("NOT READY TO SWITCH ON", DriveState::NotReadyToSwitchOn),
        ("SWITCH ON DISABLED", DriveState::SwitchOnDisabled),
        ("READY TO SWITCH ON", DriveState::ReadyToSwitchOn),
        ("SWITCHED ON", DriveState::SwitchedOn),
        ("OPERATION ENABLED", DriveState::OperationEnabled),
        ("QUICK STOP ACTIVE", DriveState::QuickStopActive),
        ("FAULT REACTION ACTIVE", DriveState::FaultReactionActive),
        ("FAULT", DriveState::Fault),
    ];
    let masks = v["p402"]["statusword_masks"].as_object().unwrap();
    assert_eq!(masks.len(), states.len());
    for (name, state) in states {
        let mask_value = &masks[name];
        let (mask, value) = (mask_value[0].as_u64().unwrap() as u16, mask_value[1].as_u64().unwrap() as u16);
        assert_eq!(DriveState::from_statusword(value), state, "{name}");
        assert_eq!(state.statusword_bits() & mask, value, "{name}");
    }
    // The EDS: the velocity PDOs as this crate lays them out, on node 3's COB-IDs, and a
    // CiA 402 (0x192) stepper drive.
    let eds = &v["eds"];
    assert_eq!(
        eds["rpdo1"],
        serde_json::json!([mapping_entry(object::CONTROLWORD, 0, 16), mapping_entry(object::TARGET_VELOCITY, 0, 32)])
    );
    assert_eq!(
        eds["tpdo1"],
        serde_json::json!([mapping_entry(object::STATUSWORD, 0, 16), mapping_entry(object::VELOCITY_ACTUAL, 0, 32)])
    );
    assert_eq!((eds["rpdo1_cob_id"].as_u64(), eds["tpdo1_cob_id"].as_u64()), (Some(0x203), Some(0x183)));
    assert_eq!(eds["device_type"].as_u64().unwrap() & 0xFFFF, 402);
    let controlwords = &v["p402"]["controlwords"];
    for (name, command) in [
        ("READY TO SWITCH ON", DriveCommand::Shutdown),
        ("SWITCHED ON", DriveCommand::SwitchOn),
        ("OPERATION ENABLED", DriveCommand::EnableOperation),
        ("DISABLE VOLTAGE", DriveCommand::DisableVoltage),
        ("QUICK STOP ACTIVE", DriveCommand::QuickStop),
        ("SWITCH ON DISABLED", DriveCommand::FaultReset),
    ] {
        assert_eq!(controlwords[name], command.controlword(), "{name}");
    }
}
