//! A planner outside flowgate (`planner.method = "socket"`) drives the robot through the
//! operator's channel, in deterministic virtual time: every command goes through the
//! supervisor; a command that stops coming stops the robot in order until the operator's
//! `start`; a command that is not a number faults it, named; commands never arm or start
//! it. The robot's motion is judged by the simulator's world truth.

#[path = "support/lines.rs"]
mod lines;
#[path = "support/python.rs"]
mod python;

use std::path::Path;

use lines::{await_line, lines};

use flowgate::config::PlannerMethod;
use flowgate::gateway::core::operator::{Goal, Refusal, Request};
use flowgate::gateway::core::{State, StopReason};
use flowgate::lab::virtual_rig::{Options, VirtualRig};
use flowgate::lab::Scenario;

/// One cycle of E1 (T = 17 ms).
const T: f64 = 0.017;

/// E1 (a standing obstacle between the robot and its goal), its commands from outside.
fn e1_driven_from_outside() -> Scenario {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e1-standing-obstacle.toml");
    let mut s = Scenario::load(&path).unwrap();
    s.planner.method = PlannerMethod::Socket;
    s
}

fn idle(s: &Scenario) -> VirtualRig {
    VirtualRig::new(s, Options { truth_samples: true, telemetry: true, wait_for_operator: true, ..Options::default() })
}

/// Arm, set E1's goal and start, as the operator does.
fn start(rig: &mut VirtualRig, s: &Scenario) {
    rig.request(&Request::Arm).unwrap();
    let goal = Goal { position: s.goal.position, tolerance: s.goal.tolerance };
    rig.request(&Request::Goal { goals: vec![goal] }).unwrap();
    rig.request(&Request::Start).unwrap();
}

/// Send `policy`'s command once a cycle until `until` (virtual time, s).
fn drive(rig: &mut VirtualRig, until: f64, mut policy: impl FnMut(&mut VirtualRig) -> Request) {
    while rig.time() < until {
        let command = policy(rig);
        let _ = rig.request(&command);
        let next = rig.time() + T;
        rig.run_until(next);
    }
}

/// A policy that drives straight at the standing obstacle, as fast as it can ask: the
/// supervisor stops the robot short of it, and the cycles record what was asked and what
/// passed.
#[test]
fn a_policy_driving_at_an_obstacle_is_stopped_short_of_it() {
    let s = e1_driven_from_outside();
    let mut rig = idle(&s);
    rig.run_until(0.5);
    // Commands alone never arm or start.
    rig.request(&Request::Drive { v: 0.15, w: 0.0 }).unwrap();
    rig.run_until(1.0);
    assert_eq!(rig.core().state(), State::Idle);
    assert_eq!(rig.world().truth().path_length, 0.0, "a command moved an idle robot");
    start(&mut rig, &s);
    // Twice the robot's speed limit: scaled down to it, and counted.
    drive(&mut rig, 8.0, |_| Request::Drive { v: 0.3, w: 0.0 });
    assert_eq!(rig.core().state(), State::Running, "held back, not stopped");
    let c = rig.core().counters();
    assert!(c.outside_commands > 400, "{c:?}");
    assert!(c.outside_commands_saturated > 100, "{c:?}");
    assert!(c.supervisor_slowed + c.supervisor_braking + c.supervisor_evaded > 50, "{c:?}");
    let e = rig.finish(s.goal.position, s.goal.tolerance);
    let truth = &e.truth.summary;
    // Stopped short: pushed at for seconds, it never creeps in.
    assert!(truth.contact.is_none(), "a contact: {truth:?}");
    assert!(truth.min_obstacle_clearance.is_some_and(|c| c > 0.0), "{truth:?}");
    assert!(truth.path_length > 0.1, "the robot drove towards it: {truth:?}");
    // The cycles record both: asked for 0.15 m/s a wheel (the limit), passed less.
    let csv = String::from_utf8(e.telemetry.unwrap().cycles_csv).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (asked, passed) = (col("asked_left"), col("passed_left"));
    let rows: Vec<Vec<f64>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap_or(f64::NAN)).collect())
        .filter(|r: &Vec<f64>| r[asked] > 0.0)
        .collect();
    assert!(rows.iter().all(|r| (r[asked] - 0.15).abs() < 1e-9), "asked within the limit");
    let changed = rows.iter().filter(|r| r[passed] < r[asked] - 1e-3).count();
    assert!(changed > 50, "{changed} cycles passed less than was asked");
}

/// A policy that steers to the goal by the gateway's own pose reaches it.
#[test]
fn a_policy_steering_to_the_goal_reaches_it() {
    let s = e1_driven_from_outside();
    let mut rig = idle(&s);
    rig.run_until(0.5);
    start(&mut rig, &s);
    let goal = s.goal.position;
    // Round the obstacle's south side: a waypoint below it, then the goal.
    let waypoint = [0.0, -0.25];
    let mut past = false;
    let mut steer = |rig: &mut VirtualRig| {
        let Some([x, y, heading]) = rig.status().pose else { return Request::Drive { v: 0.0, w: 0.0 } };
        past |= (x - waypoint[0]).hypot(y - waypoint[1]) < 0.05;
        let aim = if past { goal } else { waypoint };
        let bearing = (aim[1] - y).atan2(aim[0] - x);
        let turn =
            (bearing - heading + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI;
        Request::Drive { v: 0.1 * turn.cos().max(0.0), w: 3.0 * turn }
    };
    drive(&mut rig, 20.0, |rig| if rig.core().state() == State::Running { steer(rig) } else { Request::Status });
    assert_eq!(rig.core().state(), State::Stopped(StopReason::GoalReached), "at {}: {:?}", rig.time(), rig.status());
    let e = rig.finish(s.goal.position, s.goal.tolerance);
    assert!(e.reached_goal && !e.contact, "{}", e.report);
}

/// A policy that goes silent stops the robot in order; the stop holds until the operator's
/// `start`, which gives the policy its age again.
#[test]
fn a_silent_policy_stops_the_robot_until_the_operator_starts_again() {
    let s = e1_driven_from_outside();
    let mut rig = idle(&s);
    rig.run_until(0.5);
    start(&mut rig, &s);
    drive(&mut rig, 1.5, |_| Request::Drive { v: 0.05, w: 0.0 });
    assert_eq!(rig.core().state(), State::Running);
    // Silent: within the command's age (250 ms) and a cycle, the robot stops.
    let silent = rig.time();
    rig.run_until(silent + 0.25 + 2.0 * T);
    assert!(
        matches!(
            rig.core().state(),
            State::Stopping(StopReason::CommandStale) | State::Stopped(StopReason::CommandStale)
        ),
        "{:?}",
        rig.core().state()
    );
    rig.run_until(silent + 2.0);
    assert_eq!(rig.core().state(), State::Stopped(StopReason::CommandStale));
    // Commands again: nothing moves until the operator arms and starts.
    let stood = rig.world().truth().path_length;
    drive(&mut rig, silent + 3.0, |_| Request::Drive { v: 0.05, w: 0.0 });
    assert_eq!(rig.core().state(), State::Stopped(StopReason::CommandStale), "no automatic re-arm");
    assert!((rig.world().truth().path_length - stood).abs() < 1e-3);
    rig.request(&Request::Arm).unwrap();
    rig.request(&Request::Start).unwrap();
    drive(&mut rig, silent + 4.0, |_| Request::Drive { v: 0.05, w: 0.0 });
    assert_eq!(rig.core().state(), State::Running, "the way back is the operator's");
    assert!(rig.world().truth().path_length > stood + 0.02);
}

/// A command that is not a number (NaN, an infinity) faults the robot, named; the operator
/// resets, arms and starts, and it drives again.
#[test]
fn a_command_not_a_number_faults_the_robot_and_the_operator_brings_it_back() {
    let s = e1_driven_from_outside();
    let mut rig = idle(&s);
    rig.run_until(0.5);
    start(&mut rig, &s);
    drive(&mut rig, 1.5, |_| Request::Drive { v: 0.05, w: 0.0 });
    assert_eq!(rig.request(&Request::Wheels { left: f64::NAN, right: 0.1 }), Err(Refusal::CommandNotFinite));
    assert_eq!(rig.core().state(), State::Fault(StopReason::CommandNotFinite));
    assert_eq!(rig.core().state().to_string(), "fault: the outside planner's command not finite (NaN or infinite)");
    rig.run_until(2.5);
    rig.request(&Request::Reset).unwrap();
    rig.request(&Request::Arm).unwrap();
    rig.request(&Request::Start).unwrap();
    let before = rig.world().truth().path_length;
    drive(&mut rig, 4.0, |_| Request::Wheels { left: 0.05, right: 0.05 });
    assert_eq!(rig.core().state(), State::Running);
    assert!(rig.world().truth().path_length > before + 0.02);
}

/// With the field driving (the default), an outside command is refused and changes nothing.
#[test]
fn the_field_refuses_outside_commands() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e1-standing-obstacle.toml");
    let s = Scenario::load(&path).unwrap();
    let mut rig = idle(&s);
    rig.run_until(0.5);
    assert_eq!(rig.request(&Request::Drive { v: 0.1, w: 0.0 }), Err(Refusal::FieldDrives));
    assert_eq!(rig.core().counters().outside_commands, 0);
}

/// The real gateway (`flowgate run`) on E1's simulator over ptys, and a Python policy on
/// its control socket: the robot drives on the policy's commands once the operator starts
/// it, stops in order when the policy goes silent, and faults, named, on a NaN.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_python_policy_drives_the_real_gateway_over_its_control_socket() {
    use flowgate::gateway::shell::control_client::ControlClient;
    use std::process::{Command, Stdio};

    let s = e1_driven_from_outside();
    let handle = flowgate_sim::rig::start(flowgate_sim::rig::RigConfig::new(s.sim.clone())).await.unwrap();
    let can = format!("slcan:{}?bitrate=1000000", handle.can_path.as_ref().unwrap().display());
    let dir = std::env::temp_dir().join(format!("flowgate-command-sources-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let socket = dir.join("control.sock");
    let mut cfg = s.rig_file(&handle.psd_path, &can, Some(dir.join("telemetry")));
    cfg.goal = None;
    cfg.operator.socket = Some(socket.clone());
    std::fs::write(dir.join("rig.toml"), cfg.to_toml()).unwrap();
    let mut gateway = Command::new(env!("CARGO_BIN_EXE_flowgate"))
        .args(["run", "--config"])
        .arg(dir.join("rig.toml"))
        .env("RUST_LOG", "flowgate=info")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let out = lines(gateway.stdout.take().unwrap());
    let log = lines(gateway.stderr.take().unwrap());
    let mut seen = Vec::new();
    await_line(&log, "PSD controller streaming", &mut seen);

    let python = python::python();
    let policy = |args: &[&str]| {
        Command::new(&python)
            .arg(python::peer("command_sources"))
            .arg(&socket)
            .args(args)
            .stdout(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let operator = |requests: &[Request]| {
        let mut client = ControlClient::connect(&socket).unwrap();
        for r in requests {
            client.request(r).unwrap_or_else(|e| panic!("{r:?}: {e}"));
        }
    };
    let goal = Goal { position: s.goal.position, tolerance: s.goal.tolerance };
    // Two seconds of commands; the operator arms and starts meanwhile.
    let forward = policy(&["forward", "2"]);
    operator(&[Request::Arm, Request::Goal { goals: vec![goal] }, Request::Start]);
    await_line(&out, "state: running", &mut seen);
    let summary: serde_json::Value = serde_json::from_slice(&forward.wait_with_output().unwrap().stdout).unwrap();
    assert!(summary["ok"].as_u64().unwrap() > 20 && summary["refusals"].as_array().unwrap().is_empty(), "{summary}");
    await_line(&out, "state: stopped: the outside planner's command older than planner.command_max_age_ms", &mut seen);
    // The operator starts again; half a second into Running the policy sends a NaN.
    let nan = policy(&["nan"]);
    operator(&[Request::Arm, Request::Start]);
    await_line(&out, "state: fault: the outside planner's command not finite (NaN or infinite)", &mut seen);
    let summary: serde_json::Value = serde_json::from_slice(&nan.wait_with_output().unwrap().stdout).unwrap();
    assert_eq!(summary["nan_reply"]["error"], "command not finite (NaN or infinite): the robot stops", "{summary}");

    let _ = Command::new("kill").arg("-INT").arg(gateway.id().to_string()).status();
    assert!(gateway.wait().unwrap().success());
    let truth = handle.stop().await;
    assert!(truth.summary.path_length > 0.05, "the policy's commands drove the robot: {:?}", truth.summary);
    assert!(truth.summary.contact.is_none_or(|c| !c.active), "{:?}", truth.summary);
    let _ = std::fs::remove_dir_all(&dir);
}
