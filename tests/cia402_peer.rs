//! flowgate drives CiA 402 drives it did not write: two canopen `LocalNode`s with a small
//! drive model (tests/peers/cia402_peer.py, moved by canopen's own CiA 402 tables) behind an SLCAN
//! adapter on a pty. The gateway, armed at start against the simulator's PSD controller,
//! configures them by SDO, starts them, takes them to operation enabled, commands them by
//! RPDO, and at its shutdown brings them to rest and switches them off. What it wrote is
//! read back from the drives' own dictionaries.

#[path = "support/python.rs"]
mod python;

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use flowgate::config::Cia402Section;
use flowgate::gateway;
use flowgate::gateway::core::{Progress, State};
use flowgate::gateway::shell::Controls;
use flowgate::lab::Scenario;
use flowgate_sim::rig::{self, RigConfig};
use tokio::sync::{mpsc, watch};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn flowgate_commands_python_canopen_drives() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let python = python::python();
    let mut drives = Command::new(python)
        .arg(python::peer("cia402_peer"))
        .arg(dir.join("protocol/cia402-drive.eds"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run python (scripts/test sets FLOWGATE_PYTHON to a venv with canopen)");
    // The drives' lines, as they come.
    let (line_tx, mut lines) = mpsc::unbounded_channel::<String>();
    let stdout = drives.stdout.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = line_tx.send(line);
        }
    });
    let mut next_line = async || -> String {
        let line = tokio::time::timeout(Duration::from_secs(30), lines.recv()).await.ok().flatten();
        line.expect("the drives fell silent, or said nothing within 30 s")
    };
    let pty = next_line().await.strip_prefix("pty ").expect("the adapter's pty first").to_string();

    // The simulator plays the PSD controller and the world; its own board is not on this bus.
    let scenario = Scenario::load(&dir.join("scenarios/e1-standing-obstacle.toml")).unwrap();
    let sim = rig::spawn(RigConfig::new(scenario.sim.clone())).await.unwrap();
    let mut config = scenario.rig_file(&sim.psd_path, &format!("slcan:{pty}?bitrate=1000000"), None);
    config.use_cia402(Cia402Section::with_nodes(1, 2));
    let (stop_tx, stop_rx) = watch::channel(false);
    let (progress_tx, progress_rx) = watch::channel(Progress::default());
    let gw = tokio::spawn(gateway::shell::run(
        config.rig("cia402 peer").unwrap(),
        Controls::new(stop_rx, true),
        Some(progress_tx),
    ));

    for step in ["configured", "enabled", "moving"] {
        let line = next_line().await;
        assert_eq!(line, format!("ok {step}"), "the drives said");
    }
    assert_eq!(progress_rx.borrow().state, State::Running);
    // The shutdown: an orderly stop, the drives at rest, then switched off.
    stop_tx.send(true).unwrap();
    assert_eq!(next_line().await, "ok shutdown");
    let summary = next_line().await;
    let report = gw.await.unwrap().unwrap();
    sim.stop().await;
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut drives.stderr.take().unwrap(), &mut stderr).unwrap();
    let status = drives.wait().unwrap();
    assert!(status.success(), "{status}: {summary}\n{stderr}");
    assert_eq!(report.final_state, State::Stopped(flowgate::gateway::core::StopReason::Shutdown), "{report}");

    let s: serde_json::Value = serde_json::from_str(summary.strip_prefix("summary ").unwrap()).unwrap();
    assert_eq!(s["mode"], 3, "profile velocity");
    assert_eq!(s["rpdo1"], serde_json::json!([0x6040_0010u32, 0x60FF_0020u32]));
    assert_eq!(s["tpdo1"], serde_json::json!([0x6041_0010u32, 0x606C_0020u32]));
    assert_eq!(s["tpdo2"], serde_json::json!([0x6064_0020u32]));
    assert_eq!(s["consumer"], 127 << 16 | 300, "the gateway's heartbeat, 300 ms");
    assert_eq!(s["producer_ms"], 100);
    let path = serde_json::json!([
        "SWITCH ON DISABLED",
        "READY TO SWITCH ON",
        "SWITCHED ON",
        "OPERATION ENABLED",
        "READY TO SWITCH ON"
    ]);
    assert_eq!(s["paths"], serde_json::json!([path, path]));
    assert_eq!(s["nmt"], serde_json::json!(["STOPPED", "STOPPED"]), "NMT stop as the gateway ends");
    // The run lasts a few hundred milliseconds: a heartbeat every 100 ms.
    assert!(s["gateway_heartbeats"].as_u64().unwrap() >= 2, "{s}");
    assert_eq!(s["gateway_state"], "05", "operational");
}
