//! A standard SLCAN client drives the simulated motor board: python-can's `slcan`
//! interface on the simulator's pty, with cantools and `protocol/motor.dbc` to build and
//! read the frames.

#[path = "../../tests/support/python.rs"]
mod python;

mod common;

use common::*;
use flowgate_sim::rig::RigConfig;
use std::process::Command;

/// The peer on the rig's SLCAN pty drives the board at `node` through its steps: heard,
/// enabled, moving, stopped by its command timeout.
async fn drive_board(rig: &flowgate_sim::rig::RigHandle, node: u8) {
    let can_path = rig.can_path.clone().expect("slcan pty");
    let (python, script) = (python::python(), python::peer("slcan_python"));
    let dbc = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../protocol/motor.dbc");
    let run = move || Command::new(python).arg(script).arg(can_path).arg(dbc).arg(node.to_string()).output();
    let out = tokio::task::spawn_blocking(run)
        .await
        .unwrap()
        .expect("run python (scripts/test sets FLOWGATE_PYTHON to a venv with python-can and cantools)");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "python-can client failed:\n{stdout}\n{stderr}");
    for step in ["heartbeat", "enabled", "moving", "timeout-stop"] {
        assert!(stdout.contains(&format!("ok {step}")), "missing step {step}:\n{stdout}\n{stderr}");
    }
}

#[tokio::test]
async fn python_can_slcan_drives_the_board() {
    let rig = rig(RigConfig::new(scenario("e1-standing-obstacle.toml"))).await;
    drive_board(&rig, 1).await;
    // The world moved: the wheels turned while commanded.
    let truth = rig.stop().await;
    assert!(truth.summary.path_length > 0.005, "{:?}", truth.summary);
}

/// A fleet on the one bus: each vehicle's board answers at its own node (`flowgate-sim`
/// prints them), and commanding one moves that vehicle alone.
#[tokio::test]
async fn python_can_drives_one_vehicle_of_a_fleet() {
    let config = RigConfig::new(scenario("fleet/swap-4.toml"));
    let wired = config.vehicles().unwrap();
    let names: Vec<&str> = wired.iter().map(|v| v.name.as_str()).collect();
    assert_eq!(names, ["robot", "v1", "v2", "v3"]);
    let node_of = |k: usize| match wired[k].motors {
        flowgate_sim::motors::MotorKind::Board(node) => node.get(),
        other => panic!("{other:?}"),
    };
    assert_eq!((0..4).map(node_of).collect::<Vec<_>>(), [1, 2, 3, 4]);
    assert_eq!((wired[2].front_led, wired[2].rear_led), (5, 6));
    let rig = rig(config).await;
    drive_board(&rig, 3).await;
    let truth = rig.stop().await;
    let vehicles = &truth.summary.vehicles;
    assert_eq!(vehicles.iter().map(|v| v.name.as_str()).collect::<Vec<_>>(), names);
    // Node 3 is v2's board: v2 drove (about 1000 pulses/s, 0.1 m/s, for 0.6 s), no other moved.
    for v in vehicles {
        if v.name == "v2" {
            assert!(v.path_length > 0.03, "{v:?}");
        } else {
            assert_eq!(v.path_length, 0.0, "{v:?}");
        }
    }
    assert_eq!(truth.summary.path_length, vehicles[0].path_length, "the robot's own summary is vehicle 0's");
    let last = truth.samples.last().unwrap();
    assert_eq!(last.vehicles.iter().map(|v| v.name.as_str()).collect::<Vec<_>>(), ["v1", "v2", "v3"]);
}
