//! Foxglove live: a real `flowgate run` driving the simulator over ptys serves the
//! recording's channels over the Foxglove WebSocket protocol, and an independent client
//! (Python's `websockets`, written from the published protocol: tests/peers/foxglove.py)
//! connects, sees every channel advertised with its schema, subscribes, and decodes what the
//! gateway is doing: its cycles, in order, with integers as integers, and the robot's pose.

#[path = "support/python.rs"]
mod python;

use std::process::Command;

mod support;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn foxglove_connects_to_a_running_gateway() {
    let addr = support::free_loopback_addr();
    let gateway = support::run_on_sim("foxglove", |cfg| cfg.operator.foxglove = Some(addr)).await;
    let python = python::python();
    // The client retries nothing: wait for the server to listen.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while std::net::TcpStream::connect(addr).is_err() {
        assert!(std::time::Instant::now() < deadline, "nothing listens on {addr}");
        tokio::time::sleep(std::time::Duration::from_millis(50)).await; // polling for the port to open
    }
    let out = tokio::task::spawn_blocking(move || {
        Command::new(python)
            .arg(python::peer("foxglove"))
            .args([&format!("ws://{addr}"), "50", "/cycle", "/robot/pose", "/arena"])
            .output()
            .unwrap()
    })
    .await
    .unwrap();
    gateway.stop().await;
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert!(v["server"].as_str().unwrap().starts_with("flowgate "), "{v}");
    assert_eq!(v["subprotocol"], "foxglove.sdk.v1", "{v}");
    // Every channel of the recording, JSON with a JSON Schema.
    for (topic, schema, encoding, schema_encoding) in [
        ("/psd/rx", "flowgate.Input", "json", "jsonschema"),
        ("/can/rx", "flowgate.Input", "json", "jsonschema"),
        ("/gateway/input", "flowgate.Input", "json", "jsonschema"),
        ("/psd/tx", "flowgate.PsdPacket", "json", "jsonschema"),
        ("/can/tx", "flowgate.CanFrame", "json", "jsonschema"),
        ("/cycle", "flowgate.Cycle", "json", "jsonschema"),
        ("/obstacles", "flowgate.Obstacles", "json", "jsonschema"),
        ("/robot/pose", "foxglove.PoseInFrame", "protobuf", "protobuf"),
        ("/arena", "foxglove.SceneUpdate", "protobuf", "protobuf"),
        ("/log", "foxglove.Log", "protobuf", "protobuf"),
    ] {
        let ch = &v["channels"][topic];
        assert_eq!(ch["schemaName"], schema, "{topic}: {ch}");
        assert_eq!((ch["encoding"].as_str(), ch["schemaEncoding"].as_str()), (Some(encoding), Some(schema_encoding)));
    }
    assert_eq!(v["channels"]["/cycle"]["schema"]["properties"]["cycle"]["type"], "integer");
    // The gateway's cycles as they run: consecutive, integers, timestamps rising.
    let cycles: Vec<u64> =
        v["messages"]["/cycle"].as_array().unwrap().iter().map(|c| c["cycle"].as_u64().unwrap()).collect();
    assert!(cycles.len() >= 50 && cycles.windows(2).all(|w| w[1] == w[0] + 1), "{cycles:?}");
    assert!(v["timestamps_rising"].as_bool().unwrap());
    let pose = &v["messages"]["/robot/pose"][0]["pose"]["position"];
    assert!(pose["x"].as_f64().unwrap().abs() < 2.0 && pose["y"].is_number(), "{pose}");
    // The scene, decoded by Google's protobuf from the descriptors the server advertised:
    // the arena entity (the robot's disc, the obstacles) in every update, and the goal in
    // one of every 20 at least (a second's updates; Foxglove keeps it in between).
    let arenas = v["messages"]["/arena"].as_array().unwrap();
    assert!(arenas.len() >= 50);
    let ids = |a: &serde_json::Value| -> Vec<String> {
        a["entities"].as_array().unwrap().iter().map(|e| e["id"].as_str().unwrap().to_string()).collect()
    };
    for a in arenas {
        let entities = a["entities"].as_array().unwrap();
        assert_eq!(entities[0]["id"], "arena");
        assert_eq!(entities[0]["frame_id"], "floor");
        assert!(!entities[0]["cylinders"].as_array().unwrap().is_empty(), "{}", entities[0]);
    }
    for second in arenas.windows(20) {
        assert!(second.iter().any(|a| ids(a).contains(&"goal".to_string())), "no goal in a second's updates");
    }
}
