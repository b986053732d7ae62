use super::*;
use crate::gateway::core::input::CanEvent;
use crate::gateway::core::input::{InputRecord, RecordedInput};
use crate::gateway::core::operator::{Goal, Request};
use crate::gateway::core::Input;
use crate::time::HostTime;
use flowgate_protocol::{CanFrame, CanId};

#[test]
fn every_kind_of_input_survives_its_json() {
    let frame = CanFrame::new(CanId::Standard(0x181), &[1, 2, 3]).unwrap();
    let goal = Goal { position: [1.0, -0.25], tolerance: 0.05 };
    let inputs = [
        Input::PsdConnected,
        Input::PsdLost,
        Input::PsdBytes(&[0, 1, 0xfe, 0xff]),
        Input::Can(CanEvent::Frame(frame)),
        Input::Can(CanEvent::Frame(CanFrame::remote(CanId::Extended(0x1234567), 4).unwrap())),
        Input::Can(CanEvent::ErrorFrame { bus_off: true }),
        Input::Can(CanEvent::Garbled),
        Input::Can(CanEvent::TransmitRefused),
        Input::Can(CanEvent::InterfaceDown),
        Input::Can(CanEvent::AdapterStatus { bus_off: false, error_passive: true }),
        Input::CanFailed,
        Input::CanReopened,
        Input::Request(&Request::Goal { goals: vec![goal] }),
        Input::Request(&Request::Stats { reset: true }),
        Input::VehicleRequest { vehicle: 3, request: &Request::EStop },
        Input::ArmAtStart,
        Input::Shutdown,
        Input::Tick,
    ];
    for (k, input) in inputs.into_iter().enumerate() {
        let record =
            InputRecord { seq: k as u64, at: HostTime::from_nanos(123_456_789_012), input: RecordedInput::of(input) };
        let text = serde_json::to_string(&input_json(&record)).unwrap();
        let back = input_from_json(&serde_json::from_str(&text).unwrap(), record.seq, record.at).unwrap();
        assert_eq!(back, record, "{text}");
        assert_eq!(back.input.as_input(), input);
    }
}

#[test]
fn an_input_that_carries_its_own_sequence_and_time_is_read_by_them() {
    let v = serde_json::json!({ "seq": 9, "t_ns": 700, "kind": "tick" });
    let r = input_from_json(&v, 3, HostTime::from_nanos(5)).unwrap();
    assert_eq!((r.seq, r.at), (9, HostTime::from_nanos(700)));
    let r = input_from_json(&serde_json::json!({ "kind": "tick" }), 3, HostTime::from_nanos(5)).unwrap();
    assert_eq!((r.seq, r.at), (3, HostTime::from_nanos(5)));
}

#[test]
fn a_damaged_input_is_refused_saying_what_is_wrong() {
    let bad =
        |text: &str| input_from_json(&serde_json::from_str(text).unwrap(), 1, HostTime::from_nanos(5)).unwrap_err();
    assert_eq!(bad(r#"{"seq":1,"t_ns":-5,"kind":"tick"}"#), "`t_ns` is not a count");
    assert_eq!(bad(r#"{"bytes":"0g"}"#), "no `kind`");
    assert_eq!(bad(r#"{"kind":"psd_bytes","bytes":"0g"}"#), "`bytes` is not hex");
    assert_eq!(bad(r#"{"kind":"warp"}"#), "unknown input `warp`");
    assert_eq!(
        bad(r#"{"kind":"vehicle_request","vehicle":-1,"request":{"cmd":"arm"}}"#),
        "`vehicle` is not a vehicle's index"
    );
    let long = format!(r#"{{"kind":"psd_bytes","bytes":"{}"}}"#, "00".repeat(PSD_CHUNK + 1));
    assert_eq!(bad(&long), format!("{} bytes in one read: at most {PSD_CHUNK}", PSD_CHUNK + 1));
}

/// Each channel's topic and its messages' count in the recording at `path`.
fn channel_counts(path: &Path) -> BTreeMap<String, usize> {
    let bytes = std::fs::read(path).unwrap();
    let mut counts = BTreeMap::new();
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        *counts.entry(message.unwrap().channel.topic.clone()).or_insert(0) += 1;
    }
    counts
}

/// A scene written with `vehicles` in the setup; its channels and their counts.
fn record_a_scene(
    name: &str,
    vehicles: Vec<VehicleLabel>,
    scene: &SceneRecord,
    fleet: &FleetScene,
) -> BTreeMap<String, usize> {
    let path = std::env::temp_dir().join(format!("flowgate-scene-{name}-{}.mcap", std::process::id()));
    let setup = RecordingSetup {
        config_toml: String::new(),
        lane_half_width: Some(0.3),
        room: None,
        robot_radius: 0.07,
        vehicles,
        origin_unix_ns: 0,
        compression: RecordCompression::None,
    };
    let mut sink = McapSink::create(Some(&path), setup, None).unwrap();
    for chunk in fleet.chunks() {
        sink.vehicles_chunk(&chunk);
    }
    sink.scene(scene).unwrap();
    sink.finish(0, 0).unwrap();
    let counts = channel_counts(&path);
    let _ = std::fs::remove_file(&path);
    counts
}

/// A fleet's recording has `/vehicles` and a pose channel for each vehicle the camera has
/// shown; a single robot's has neither (its recordings are as they were).
#[test]
fn a_fleets_scene_names_each_vehicle_and_a_robots_alone_is_unchanged() {
    use crate::gateway::core::scene::SceneVehicle;
    let scene = SceneRecord { pose: [-0.4, 0.0, 0.0], goal: [0.4, 0.0], ..SceneRecord::default() };
    let mut fleet = FleetScene::default();
    fleet.push(SceneVehicle { seen: true, pose: [0.2, 0.1, 3.0], goal: [-0.4, 0.1], ..SceneVehicle::default() });
    fleet.push(SceneVehicle::default());
    let label = |name: &str| VehicleLabel { name: name.into(), radius: 0.06, scripted: false };
    let recorded = record_a_scene("fleet", vec![label("v1"), label("v2")], &scene, &fleet);
    assert_eq!(recorded.get(VEHICLES), Some(&1));
    assert_eq!(recorded.get("/v1/pose"), Some(&1));
    assert_eq!(recorded.get("/v2/pose"), None, "v2 not yet seen: no pose");
    let alone = record_a_scene("alone", Vec::new(), &scene, &FleetScene::default());
    let topics: Vec<&str> = alone.keys().map(String::as_str).collect();
    assert_eq!(topics, [ARENA, OBSTACLES, POSE]);
}
