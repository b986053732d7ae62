//! An independent CiA 402 master drives the simulated drive: Python's `canopen`
//! (`BaseNode402`, with protocol/cia402-drive.eds) through python-can's `slcan` interface
//! on the simulator's pty.

#[path = "../../tests/support/python.rs"]
mod python;

mod common;

use common::*;
use flowgate_protocol::canopen::NodeId;
use flowgate_sim::rig::RigConfig;
use std::process::Command;

#[tokio::test]
async fn python_canopen_drives_the_simulated_cia402_drive() {
    let mut config = RigConfig::new(scenario("e1-standing-obstacle.toml"));
    config.cia402 = Some([NodeId::new(1).unwrap(), NodeId::new(2).unwrap()]);
    let rig = rig(config).await;
    let can_path = rig.can_path.clone().expect("slcan pty");
    let python = python::python();
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let script = python::peer("cia402_python");
    let eds = dir.join("../protocol/cia402-drive.eds");
    let out = tokio::task::spawn_blocking(move || Command::new(python).arg(script).arg(can_path).arg(eds).output())
        .await
        .unwrap()
        .expect("run python (scripts/test sets FLOWGATE_PYTHON to a venv with canopen)");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "canopen master failed:\n{stdout}\n{stderr}");
    for step in ["boot-up", "heartbeat", "configured", "pdos", "enabled", "velocity", "quick-stop"] {
        assert!(stdout.contains(&format!("ok {step}")), "missing step {step}:\n{stdout}\n{stderr}");
    }
    // The left wheel turned while commanded.
    let truth = rig.stop().await;
    assert!(truth.summary.path_length > 0.001, "{:?}", truth.summary);
}
