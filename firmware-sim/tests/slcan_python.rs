//! A standard SLCAN client drives the simulated motor board: python-can's `slcan`
//! interface on the simulator's pty, with cantools and `protocol/motor.dbc` to build and
//! read the frames.

#[path = "../../tests/support/python.rs"]
mod python;

mod common;

use common::*;
use flowgate_sim::rig::RigConfig;
use std::process::Command;

#[tokio::test]
async fn python_can_slcan_drives_the_board() {
    let rig = rig(RigConfig::new(scenario("e1-standing-obstacle.toml"))).await;
    let can_path = rig.can_path.clone().expect("slcan pty");
    let python = python::python();
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let script = python::peer("slcan_python");
    let dbc = dir.join("../protocol/motor.dbc");
    let out = tokio::task::spawn_blocking(move || Command::new(python).arg(script).arg(can_path).arg(dbc).output())
        .await
        .unwrap()
        .expect("run python (scripts/test sets FLOWGATE_PYTHON to a venv with python-can and cantools)");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "python-can client failed:\n{stdout}\n{stderr}");
    for step in ["heartbeat", "enabled", "moving", "timeout-stop"] {
        assert!(stdout.contains(&format!("ok {step}")), "missing step {step}:\n{stdout}\n{stderr}");
    }
    // The world moved: the wheels turned while commanded.
    let truth = rig.stop().await;
    assert!(truth.summary.path_length > 0.005, "{:?}", truth.summary);
}
